"""The results-json reader refuses invalid results by itself (docs/results-json.md, "What a
reader requires"): each test takes a real result of the example campaign, mutates one thing
and checks the refusal is one line naming the file and the JSON path of the field. Before
these checks the readers accepted each of them and `certificate`, `compare`,
`export-compensation` and `history` answered from wrong numbers (an angle in deg read as
arcsec, the last of two `status` keys, a result without its angles, U = 0.1 with u = 3 and
k = 2, a correlation of 5 or null, a temperature range upside down)."""

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest

from triadcal import api
from triadcal.estimation.result import CalibrationResult, ResultFormatError
from triadcal.io.atomic import read_json

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "data"
MIKOFF = Path(__file__).parent / "data" / "real" / "mikoff_imu0.log"


@pytest.fixture(scope="module")
def joint():
    """A real joint result of the example campaign, as the JSON document the writer writes."""
    return json.loads(json.dumps(api.fit(None, method="joint").to_dict()))


@pytest.fixture(scope="module")
def joint_lab():
    """The same with the example lab file: every parameter has U, k and a budget."""
    return json.loads(json.dumps(api.fit(None, method="joint", lab=EXAMPLES / "lab.toml").to_dict()))


@pytest.fixture(scope="module")
def classical():
    return json.loads(json.dumps(api.fit(None, method="classical").to_dict()))


def _write(tmp_path, doc, name="r.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    return path


def refused(tmp_path, doc, *where, name="r.json") -> str:
    """Load ``doc`` from a file; assert a one-line ResultFormatError naming the file and ``where``."""
    path = _write(tmp_path, doc, name)
    with pytest.raises(ResultFormatError) as exc:
        CalibrationResult.load(path)
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg, msg
    for w in where:
        assert w in msg, (w, msg)
    return msg


def test_the_real_results_read(joint, joint_lab, classical, tmp_path):
    for doc in (joint, joint_lab, classical):
        r = CalibrationResult.load(_write(tmp_path, doc))
        assert {"Ca_xy", "K_x", "S_x"} <= set(r.parameters)


def test_a_gravity_norm_result_with_three_angles_reads(tmp_path):
    """fit-raw with unknown poses estimates only Ca_xy, Ca_xz, Ca_yz (the other three are 0 by
    the definition of its frame, listed under ``fixed``): complete as it is."""
    a = np.loadtxt(MIKOFF)[:, :3]
    csv = tmp_path / "mik.csv"
    np.savetxt(csv, np.round(a * 2048 / 9.81), delimiter=",", header="ax,ay,az", comments="", fmt="%d")
    doc = json.loads(json.dumps(api.fit_raw(str(csv), 100.0, poses="unknown", local_g_m_s2=9.81).result.to_dict()))
    assert {n for n in doc["parameters"] if n.startswith("Ca_")} == {"Ca_xy", "Ca_xz", "Ca_yz"}
    assert doc["parameters"]["K_x"]["unit"] == "g/count" and doc["output_unit"] == "counts"
    CalibrationResult.load(_write(tmp_path, doc))
    # without its `fixed` block it still says what it is (fit.model: the gravity norm)
    bare = copy.deepcopy(doc)
    bare.pop("fixed")
    CalibrationResult.load(_write(tmp_path, bare))
    # but it must not lose an angle it does estimate
    bad = copy.deepcopy(doc)
    bad["parameters"].pop("Ca_xz")
    refused(tmp_path, bad, "parameters.Ca_xz", "missing")


# -- 1. units ------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["Ca_xy", "Ca_xy_tempco", "Ca_xy_hysteresis"])
def test_an_angle_in_deg_is_refused(joint, tmp_path, name):
    bad = copy.deepcopy(joint)
    p = bad["parameters"][name]
    unit = {"Ca_xy": "deg"}.get(name, "deg")
    p["value"], p["u"], p["unit"] = p["value"] / 3600.0, p["u"] / 3600.0, unit
    refused(tmp_path, bad, f"parameters.{name}.unit", "'deg'", "'arcsec" if name != "Ca_xy_tempco" else "arcsec/degC")


def test_every_other_parameter_in_a_foreign_unit_is_refused(joint, tmp_path):
    for name, unit, expected in (("S_x", "ug", "'g'"), ("K_x_tempco", "ug/degC", "'ppm/degC'"),
                                 ("tilt_x", "deg", "'arcsec'"), ("tilt_beta", "arcsec", "'deg'")):
        bad = copy.deepcopy(joint)
        bad["parameters"][name]["unit"] = unit
        refused(tmp_path, bad, f"parameters.{name}.unit", expected)


def test_a_scale_factor_in_another_output_unit_is_not_relabelled(joint, tmp_path):
    bad = copy.deepcopy(joint)
    assert bad["output_unit"] == "V"
    for a in "xyz":
        bad["parameters"][f"K_{a}"]["unit"] = "g/mV"
    refused(tmp_path, bad, "parameters.K_x.unit", "'g/mV'", "output_unit is 'V'")
    # one K in another unit than the others: against output_unit (a result without one is refused by
    # itself, test_fields_the_probe_edited_are_refused)
    bad = copy.deepcopy(joint)
    bad["parameters"]["K_y"]["unit"] = "g/mV"
    refused(tmp_path, bad, "parameters.K_y.unit")
    # an output unit that says counts while K is per volt
    bad = copy.deepcopy(joint)
    bad["output_unit"] = "counts"
    refused(tmp_path, bad, "parameters.K_x.unit", "output_unit is 'counts'")


def test_a_deg_angle_never_reaches_compare(joint, tmp_path, capsys):
    from triadcal.cli import main

    good = _write(tmp_path, joint, "before.json")
    bad = copy.deepcopy(joint)
    p = bad["parameters"]["Ca_xy"]
    p["value"], p["u"], p["unit"] = (p["value"] + 40.0) / 3600.0, p["u"] / 3600.0, "deg"
    after = _write(tmp_path, bad, "after.json")
    assert main(["compare", str(good), str(after), "--tolerance", "30arcsec"]) == 1
    err = capsys.readouterr().err
    assert str(after) in err and "parameters.Ca_xy.unit" in err and "Traceback" not in err


# -- 2. duplicate keys ---------------------------------------------------------------------------
def test_a_duplicate_key_is_refused_with_file_line_and_key(joint, tmp_path):
    text = json.dumps(joint, indent=1)
    assert '"status": "ok"' in text
    path = tmp_path / "dup.json"
    path.write_text(text.replace('"status": "ok"', '"status": "model_mismatch", "status": "ok"', 1))
    line = text[:text.index('"status": "ok"')].count("\n") + 1
    with pytest.raises(ValueError) as exc:
        read_json(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}:{line}: status:") and "'status'" in msg and "twice" in msg, msg
    with pytest.raises(ValueError, match="twice"):
        CalibrationResult.load(path)


def test_a_duplicate_parameter_is_refused_with_its_path(joint, tmp_path):
    text = json.dumps(joint, indent=1)
    i = text.index('"Ca_xy": {')
    path = tmp_path / "dup_param.json"
    path.write_text(text[:i] + '"Ca_xy": {"value": 999, "u": 0.1, "unit": "arcsec"}, ' + text[i:])
    with pytest.raises(ValueError, match=r"parameters\.Ca_xy: the key 'Ca_xy' occurs twice"):
        read_json(path)
    # the same key in two different objects is not a duplicate
    path.write_text('{"a": {"k": 1}, "b": {"k": 2}, "c": [{"k": 1}, {"k": 2}]}')
    assert read_json(path) == {"a": {"k": 1}, "b": {"k": 2}, "c": [{"k": 1}, {"k": 2}]}


def test_a_duplicate_key_deep_in_a_list_names_its_path(tmp_path):
    path = tmp_path / "d.json"
    path.write_text('{"a": [1, {"b": "x\\"y"}, {"c\\"": 1,\n "c\\"": 2}]}')
    with pytest.raises(ValueError) as exc:
        read_json(path)
    assert str(exc.value).startswith(f"{path}:2: a[2].c\":"), str(exc.value)


# -- 3. incomplete results -----------------------------------------------------------------------
@pytest.mark.parametrize("drop", [("K_x",), ("Ca_xy",), ("Ca_xy", "Ca_xz", "Ca_yx", "Ca_yz", "Ca_zx", "Ca_zy"),
                                  ("S_z_tempco",), ("tilt_x",)])
def test_a_result_without_a_parameter_of_its_model_is_refused(joint, tmp_path, drop):
    bad = copy.deepcopy(joint)
    for n in drop:
        bad["parameters"].pop(n)
    refused(tmp_path, bad, f"parameters.{drop[0]}", "missing")


def test_a_classical_result_without_an_angle_is_refused(classical, tmp_path):
    bad = copy.deepcopy(classical)
    bad["parameters"].pop("Ca_zy_tempco")
    refused(tmp_path, bad, "parameters.Ca_zy_tempco", "missing")


def test_a_parameter_held_fixed_may_be_absent(joint, tmp_path):
    doc = copy.deepcopy(joint)
    doc["parameters"].pop("Ca_zy_hysteresis")
    doc["fixed"] = {"Ca_zy_hysteresis": {"value": 0.0, "unit": "arcsec"}}
    CalibrationResult.load(_write(tmp_path, doc))
    doc["fixed"] = {"Ca_zy_hysteresis": {"value": 0.0, "unit": "deg"}}
    refused(tmp_path, doc, "fixed.Ca_zy_hysteresis.unit")


def test_a_parameter_of_an_effect_not_in_effects_is_refused(joint, tmp_path):
    bad = copy.deepcopy(joint)
    bad["effects"] = [e for e in bad["effects"] if e != "hysteresis"]
    refused(tmp_path, bad, "parameters.Ca_xy_hysteresis", "not in effects")


# -- 4. U and k u --------------------------------------------------------------------------------
def test_U_that_is_not_k_u_is_refused(joint_lab, tmp_path):
    p = joint_lab["parameters"]["Ca_xy"]
    assert p["U"] == pytest.approx(p["k"] * p["u"], rel=1e-12)
    bad = copy.deepcopy(joint_lab)
    bad["parameters"]["Ca_xy"]["U"] = 0.1
    refused(tmp_path, bad, "parameters.Ca_xy.U", "k u")
    bad = copy.deepcopy(joint_lab)
    bad["parameters"]["Ca_xy"]["u"] = 1e9
    refused(tmp_path, bad, "parameters.Ca_xy.U")


def test_a_negative_u_is_refused_by_the_reader(joint, tmp_path):
    bad = copy.deepcopy(joint)
    bad["parameters"]["Ca_xy"]["u"] = -3.0
    refused(tmp_path, bad, "parameters.Ca_xy.u", "negative")


@pytest.mark.parametrize("serial", ["", "   "])
def test_a_result_without_a_serial_is_refused(joint, tmp_path, serial):
    """compare identifies the unit by its serial: two results with "" got a pass (an outside probe)."""
    bad = copy.deepcopy(joint)
    bad["unit"] = serial
    refused(tmp_path, bad, "unit", "empty")


# -- 5. schema violations ------------------------------------------------------------------------
def test_a_budget_row_that_breaks_the_schema_is_refused(joint_lab, tmp_path):
    for key, value, where in (("u", -3.0, "budget[0].u"), ("contribution", -1.0, "budget[0].contribution"),
                              ("type", "C", "budget[0].type"), ("distribution", "gaussian", "budget[0].distribution"),
                              ("dof", 0, "budget[0].dof"), ("sensitivity", "1", "budget[0].sensitivity")):
        bad = copy.deepcopy(joint_lab)
        bad["parameters"]["Ca_xy"]["budget"][0][key] = value
        refused(tmp_path, bad, f"parameters.Ca_xy.{where}")
    bad = copy.deepcopy(joint_lab)
    bad["parameters"]["Ca_xy"]["budget"][0].pop("unit")
    refused(tmp_path, bad, "parameters.Ca_xy.budget[0].unit", "missing")


@pytest.mark.parametrize("value", ["9.8", 0, -9.8, True])
def test_local_g_that_is_not_a_positive_number_is_refused(joint, tmp_path, value):
    bad = copy.deepcopy(joint)
    bad["local_g_m_s2"] = value
    refused(tmp_path, bad, "local_g_m_s2")


def test_local_g_null_reads(joint, tmp_path):
    doc = copy.deepcopy(joint)
    doc["local_g_m_s2"] = None
    CalibrationResult.load(_write(tmp_path, doc))


@pytest.mark.parametrize("key,value", [("angle_bound_arcsec", -1), ("angle_bound_arcsec", 0),
                                       ("gof_p_min", "0.001"), ("scale_band_rel", None)])
def test_a_gate_threshold_that_is_not_positive_is_refused_not_replaced(joint, tmp_path, key, value):
    bad = copy.deepcopy(joint)
    bad["gates"]["config"][key] = value
    refused(tmp_path, bad, f"gates.config.{key}")


def test_gates_that_break_the_schema_are_refused(joint, tmp_path):
    for mutate, where in ((lambda d: d["gates"]["config"].pop("gof_ratio_max"), "gates.config.gof_ratio_max"),
                          (lambda d: d["gates"].__setitem__("outcomes", []), "gates.outcomes"),
                          (lambda d: d["gates"]["outcomes"][0].__setitem__("passed", "yes"), "gates.outcomes[0].passed"),
                          (lambda d: d["gates"]["outcomes"][0].__setitem__("status", "ok"), "gates.outcomes[0].status"),
                          (lambda d: d.__setitem__("gates", None), "gates")):
        bad = copy.deepcopy(joint)
        mutate(bad)
        refused(tmp_path, bad, where)


def test_a_boolean_version_is_refused(joint, tmp_path):
    bad = copy.deepcopy(joint)
    bad["version"] = True
    with pytest.raises(ValueError, match="version True"):
        CalibrationResult.load(_write(tmp_path, bad))


@pytest.mark.parametrize("i,j,value,where", [(0, 1, 5.0, "[0][1]"), (1, 0, -1.5, "[0][1]"), (2, 2, 0.0, "[2][2]"),
                                             (2, 2, 0.5, "[2][2]")])
def test_a_correlation_that_is_not_one_is_refused(joint, tmp_path, i, j, value, where):
    bad = copy.deepcopy(joint)
    m = bad["correlation"]["matrix"]
    m[i][j] = value
    if i != j:
        m[j][i] = value
    refused(tmp_path, bad, f"correlation.matrix{where}")


def test_an_asymmetric_or_indefinite_correlation_is_refused(joint, tmp_path):
    bad = copy.deepcopy(joint)
    names = bad["correlation"]["names"]
    m = bad["correlation"]["matrix"]
    m[0][1] = 0.9 if m[1][0] < 0.5 else -0.9
    refused(tmp_path, bad, "correlation.matrix[0][1]", "symmetric")
    # entries each in [-1, 1] that no three parameters can have together
    bad = copy.deepcopy(joint)
    m = bad["correlation"]["matrix"]
    a, b, c = (names.index(n) for n in ("Ca_xy", "Ca_yx", "Ca_zx"))
    for (p, q), v in (((a, b), 0.99), ((a, c), 0.99), ((b, c), -0.99)):
        m[p][q] = m[q][p] = v
    refused(tmp_path, bad, "correlation.matrix", "positive semi-definite")
    bad = copy.deepcopy(joint)
    bad["correlation"]["names"][1] = bad["correlation"]["names"][0]
    refused(tmp_path, bad, "correlation.names[1]", "twice")


def test_a_null_correlation_is_refused_where_both_u_are_finite(joint, tmp_path):
    """The schema allows null (not finite) there; the writer only writes it for a parameter
    whose u is 0 or not finite (cov / (u u)): anywhere else it would reach compare's
    eigen-decomposition (LinAlgError) or be read as some number."""
    names = joint["correlation"]["names"]
    a, b = names.index("Ca_xy"), names.index("Ca_yx")
    bad = copy.deepcopy(joint)
    bad["correlation"]["matrix"][a][b] = bad["correlation"]["matrix"][b][a] = None
    refused(tmp_path, bad, f"correlation.matrix[{min(a, b)}][{max(a, b)}]", "null")
    # a parameter without a finite u: its row is null, which reads
    ok = copy.deepcopy(joint)
    ok["parameters"]["Ca_yx"]["u"] = None
    ok["status"] = "non_finite"
    m = ok["correlation"]["matrix"]
    for k in range(len(names)):
        m[b][k] = m[k][b] = None
    r = CalibrationResult.load(_write(tmp_path, ok))
    assert math.isnan(r.correlation[a, b])
    # a parameter with u = 0 (cov / (u u) undefined): null row, and its covariance is exactly 0
    zero = copy.deepcopy(ok)
    zero["parameters"]["Ca_yx"]["u"] = 0.0
    zero["status"] = "ok"
    r = CalibrationResult.load(_write(tmp_path, zero))
    C = r.covariance(["Ca_xy", "Ca_yx", "Ca_zx"])
    assert np.all(np.isfinite(C)) and C[0, 1] == 0.0 and C[1, 1] == 0.0 and C[0, 0] > 0


def test_unidentifiable_and_fixed_must_be_objects(joint, tmp_path):
    for key, value in (("unidentifiable", ["Ca_xy_hysteresis"]), ("unidentifiable", {"Ca_xy": 3}),
                       ("fixed", ["Ca_xy"]), ("fixed", {"Ca_xy_hysteresis": 0.0})):
        bad = copy.deepcopy(joint)
        bad[key] = value
        refused(tmp_path, bad, key)


def test_other_fields_that_break_the_schema_are_refused(joint, tmp_path):
    for mutate, where in ((lambda d: d["fit"].__setitem__("n_obs", "540"), "fit.n_obs"),
                          (lambda d: d["parameters"].__setitem__("bad name!", {"value": 1, "u": 1, "unit": "arcsec"}),
                           "parameters.bad name!"),
                          (lambda d: d.__setitem__("output_unit", ""), "output_unit"),
                          (lambda d: d.__setitem__("intervals", {"Ca_xy": {"level": 95, "low": 1, "high": 2}}),
                           "intervals.Ca_xy.level"),
                          (lambda d: d.__setitem__("intervals", {"Ca_xy": {"level": 0.95, "low": 3, "high": 2}}),
                           "intervals.Ca_xy")):
        bad = copy.deepcopy(joint)
        mutate(bad)
        refused(tmp_path, bad, where)


# -- 6. errors that name the field ---------------------------------------------------------------
def test_an_upside_down_temperature_range_is_refused_on_read(joint, tmp_path, capsys):
    from triadcal.cli import main

    bad = copy.deepcopy(joint)
    bad["temperature_range_C"] = [70.0, -40.0]
    refused(tmp_path, bad, "temperature_range_C", "low is above high")
    path = _write(tmp_path, bad, "upside_down.json")
    assert main(["export-compensation", str(path), "-o", str(tmp_path / "c.json"), "--format", "json"]) == 1
    err = capsys.readouterr().err
    assert "temperature_range_C" in err and "--grid" not in err, err
    # a single temperature (low == high) is a range
    ok = copy.deepcopy(joint)
    ok["temperature_range_C"] = [20.0, 20.0]
    CalibrationResult.load(_write(tmp_path, ok))


def test_a_correlation_above_one_is_named_not_reported_as_a_covariance(joint, tmp_path, capsys):
    from triadcal.cli import main

    names = joint["correlation"]["names"]
    a, b = names.index("Ca_xy"), names.index("Ca_yx")
    bad = copy.deepcopy(joint)
    bad["correlation"]["matrix"][a][b] = bad["correlation"]["matrix"][b][a] = 5.0
    good, after = _write(tmp_path, joint, "before.json"), _write(tmp_path, bad, "after.json")
    assert main(["compare", str(good), str(after)]) == 1
    err = capsys.readouterr().err
    assert f"correlation.matrix[{min(a, b)}][{max(a, b)}]" in err and "covariance" not in err, err


@pytest.mark.parametrize("mutation", ["dup_status", "corr_null", "drop_angles"])
def test_history_refuses_before_recording(joint, tmp_path, capsys, mutation):
    from triadcal.cli import main

    text = json.dumps(joint, indent=1)
    path = tmp_path / f"{mutation}.json"
    if mutation == "dup_status":
        path.write_text(text.replace('"status": "ok"', '"status": "model_mismatch", "status": "ok"', 1))
    else:
        bad = copy.deepcopy(joint)
        if mutation == "corr_null":
            bad["correlation"]["matrix"][0][1] = bad["correlation"]["matrix"][1][0] = None
        else:
            for ab in ("xy", "xz", "yx", "yz", "zx", "zy"):
                bad["parameters"].pop(f"Ca_{ab}")
        path.write_text(json.dumps(bad))
    db = tmp_path / "h.sqlite"
    assert main(["history", "--add", str(path), "--db", str(db)]) == 1
    err = capsys.readouterr().err
    assert str(path) in err and "Traceback" not in err and "internal error" not in err, err


# -- 6. an outside probe's re-signed results (its own checksum recomputed) -------------------------
def test_a_budget_that_contradicts_its_u_or_k_is_refused(joint_lab, tmp_path):
    """k = 0.1 at 95.45 % with U = k u (a certificate said Ca_xy +- 0.30 arcsec for 6.1); K_x's u and U
    divided by 100 beside its rows; u_type_a above u: each was certified or tabulated."""
    p = joint_lab["parameters"]["Ca_xy"]
    assert p["U_method"] == "GUM" and p["k"] == pytest.approx(2.0, rel=1e-3)
    bad = copy.deepcopy(joint_lab)
    q = bad["parameters"]["Ca_xy"]
    q["k"], q["U"] = 0.1, 0.1 * q["u"]
    refused(tmp_path, bad, "parameters.Ca_xy.k", "GUM coverage factor")
    bad = copy.deepcopy(joint_lab)
    q = bad["parameters"]["K_x"]
    q["u"], q["U"] = q["u"] / 100, q["U"] / 100
    refused(tmp_path, bad, "parameters.K_x.u", "root sum of squares")
    bad = copy.deepcopy(joint_lab)
    q = bad["parameters"]["S_x"]
    q["u_type_a"] = 2 * q["u"]
    refused(tmp_path, bad, "parameters.S_x.u_type_a", "exceeds")
    bad = copy.deepcopy(joint_lab)
    q = bad["parameters"]["Ca_xy"]
    q["U_method"], q["k"], q["U"] = "Monte Carlo", 0.5, 0.5 * q["u"]
    refused(tmp_path, bad, "parameters.Ca_xy.k", "below 1")


def test_fields_the_probe_edited_are_refused(joint, tmp_path):
    """temperature_range_C [null, 70] (printed "nan degC"), fit.chi2_dof -1, a parameter 'foo' (a
    36th row of a certificate), a correlation name that is no parameter, output_unit missing or
    empty, local g 98.0665 (m/s^2 and g mixed up) or 1.0: each went into a product."""
    for mutate, where, what in (
            (lambda d: d.__setitem__("temperature_range_C", [None, 70.0]), "temperature_range_C[0]", "is null"),
            (lambda d: d["fit"].__setitem__("chi2_dof", -1.0), "fit.chi2_dof", "negative"),
            (lambda d: d["parameters"].__setitem__("foo", {"value": 1.0, "u": 0.1, "unit": "arcsec"}),
             "parameters.foo", "not a parameter of triadcal's model"),
            (lambda d: d.pop("output_unit"), "output_unit", "missing"),
            (lambda d: d.__setitem__("output_unit", " "), "output_unit", "empty"),
            (lambda d: d.__setitem__("local_g_m_s2", 98.0665), "local_g_m_s2", "outside 9.76-9.84"),
            (lambda d: d.__setitem__("local_g_m_s2", 1.0), "local_g_m_s2", "no override")):
        bad = copy.deepcopy(joint)
        mutate(bad)
        refused(tmp_path, bad, where, what)
    bad = copy.deepcopy(joint)
    bad["correlation"]["names"][0] = "foo"
    refused(tmp_path, bad, "correlation.names[0]", "not a parameter of the result or of triadcal's model")


def test_a_fit_with_a_stated_override_of_local_g_writes_it_and_reads(tmp_path):
    """Data that stated an override (# local_g_override = true, fit-raw --local-g-override) reach a
    fit with a g outside Earth's range: the result records it and reads back."""
    r = api.fit(None, method="classical")
    r.extra["local_g_m_s2"] = 3.72
    doc = json.loads(json.dumps(r.to_dict()))
    assert doc["local_g_override"] is True
    CalibrationResult.load(_write(tmp_path, doc))
