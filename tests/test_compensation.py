"""Compensation tables (issue 17, item 4): the table applied to data made another way gives
residuals within u; the interpolation bound by hand; the C header compiles; refusals."""

from __future__ import annotations

import json
import math
import shutil
import subprocess

import numpy as np
import pytest

from independent_bench import simulate_campaign
from triadcal import api
from triadcal.errors import InputError
from triadcal.estimation.result import CalibrationResult, ParameterValue
from triadcal.io.bench_csv import read_bench_csv
from triadcal.models.model import Model
from triadcal.reports.compensation import compensation_table, export_compensation, load_table, parse_grid

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("comp")
    text, truth = simulate_campaign(np.random.default_rng(21))
    path = tmp / "c.csv"
    path.write_text(text)
    r = api.fit(path, effects=EFFECTS)
    assert r.status == "ok"
    r.save(tmp / "r.json")
    return r, read_bench_csv(path), tmp


def test_table_applied_to_the_data_gives_residuals_within_u(fitted):
    r, campaign, tmp = fitted
    T = campaign.t.mean(axis=1)
    # a 5 degC grid spanning the visits (their mean temperatures lie inside the calibrated range)
    table = export_compensation(tmp / "r.json", tmp / "t.json", "json", f"{math.floor(T.min() * 1e4) / 1e4}:{math.ceil(T.max() * 1e4) / 1e4}:5")
    A = table.apply(campaign.w, T)
    # the table is the result's own model, interpolated: the same as applying the result
    assert np.max(np.abs(A - r.apply(campaign.w, np.repeat(T[:, None], 3, axis=1)))) < 1e-9
    # gravity's magnitude (standard g in the file) from every visit, against the u of a reading:
    # output noise of the mean plus the table's u of K and S at that temperature (unit vector: each
    # axis in turn carries gravity, so its own K and S set the magnitude)
    mag = np.linalg.norm(A, axis=1) - 1.0
    up = np.argmax(np.abs(A), axis=1)
    sd_mean = (campaign.sd / np.sqrt(campaign.n_samples)[:, None])[np.arange(len(up)), up]
    uK = np.array([np.interp(t, table.grid_C, table.u_K[:, a]) for t, a in zip(T, up)])
    uS = np.array([np.interp(t, table.grid_C, table.u_S[:, a]) for t, a in zip(T, up)])
    u = np.sqrt(sd_mean ** 2 + uK ** 2 + uS ** 2)
    z = mag / u
    assert np.sqrt(np.mean(z ** 2)) < 1.5 and np.max(np.abs(z)) < 4.5
    # the JSON reads back to the same table
    back = load_table(tmp / "t.json")
    assert np.array_equal(back.K, table.K) and np.array_equal(back.Ca_inv, table.Ca_inv)


def test_the_default_grid_covers_the_coldest_and_hottest_visits(fitted, tmp_path):
    """The rows end at the calibrated range's ends: every visit of the campaign (data made by the
    independent bench) lies inside the table, and the table there is the result's model (an outside
    probe: rows at the multiples of 5 only left -39.8..-35 degC without a row, 288 ug off when held)."""
    from triadcal.cli import main

    r, campaign, tmp = fitted
    assert main(["export-compensation", str(tmp / "r.json"), "-o", str(tmp_path / "d.json"), "--quiet"]) == 0
    table = load_table(tmp_path / "d.json")
    T = campaign.t.mean(axis=1)
    assert table.grid_C[0] <= T.min() and T.max() <= table.grid_C[-1]
    cold = T <= table.grid_C[1]
    assert cold.any()
    A = table.apply(campaign.w[cold], T[cold])
    assert np.max(np.abs(A - r.apply(campaign.w[cold], np.repeat(T[cold, None], 3, axis=1)))) < 1e-6
    assert not any("without a row" in n for n in table.notes)
    # a grid that stops short says which temperatures it leaves out
    short = compensation_table(r, parse_grid("-35:75:5"))
    assert any("without a row" in n and "-35" in n and "75" in n for n in short.notes)
    with pytest.raises(InputError, match="increasing"):
        compensation_table(r, [10.0, 0.0])


def test_u_at_the_reference_temperature_is_the_results_u(fitted):
    r, _, _ = fitted
    table = compensation_table(r, parse_grid("-30:60:10"))
    i = int(np.flatnonzero(table.grid_C == 20.0)[0])
    for j, a in enumerate("xyz"):
        assert table.u_K[i, j] == pytest.approx(r.parameters[f"K_{a}"].u, rel=1e-4)
        assert table.u_S[i, j] == pytest.approx(r.parameters[f"S_{a}"].u, rel=1e-4)
    assert table.u_angles[i, 0] == pytest.approx(r.parameters["Ca_xy"].u, rel=1e-4)
    # away from T0 the tempco's u adds: u(T) >= u(T0)
    assert np.all(table.u_angles[0] >= table.u_angles[i] - 1e-12)


def _quadratic_result(c2=0.004):
    model = Model(("angle_tempco", "angle_tempco2"))
    params = {n: ParameterValue(model.spec[n].nominal, 0.1, model.spec[n].unit) for n in model.names}
    for a in "xyz":
        params[f"K_{a}"] = ParameterValue(1.0, 1e-6, "g/V")
    params["Ca_xy_tempco2"] = ParameterValue(c2, 1e-4, "arcsec/degC2")
    return CalibrationResult(unit="SN-Q", method="joint", parameters=params, effects=model.effect_names,
                             temperature_range_C=(-40.0, 85.0), fit={"chi2_dof": 1.0, "n_obs": 540, "n_params": 30},
                             extra={"output_unit": "V"})


def test_interpolation_bound_of_a_quadratic_tempco_by_hand():
    """q(T) = c (T - T0)^2: linear interpolation over an interval of width D errs by D^2 |q''| / 8
    = D^2 2c / 8 at its middle: 0.025 arcsec for c = 0.004 arcsec/degC2 and D = 5 degC."""
    table = compensation_table(_quadratic_result(), parse_grid("-40:85:5"))
    j = 0   # Ca_xy
    assert table.interp_angles[:-1, j] == pytest.approx(np.full(len(table.grid_C) - 1, 0.025), rel=2e-3)
    assert table.interp_angles[-1, j] == 0.0 and np.all(table.interp_angles[:, 1:] == 0.0)
    assert np.all(table.interp_K == 0.0)
    # halving the step quarters the bound
    fine = compensation_table(_quadratic_result(), parse_grid("-40:85:2.5"))
    assert fine.interp_angles[0, 0] == pytest.approx(0.025 / 4, rel=2e-3)


def test_refusals_name_the_reason(fitted):
    r, _, _ = fitted
    with pytest.raises(InputError, match="outside the calibrated range"):
        compensation_table(r, parse_grid("-60:80:5"))
    t = compensation_table(r, parse_grid("-60:80:5"), allow_outside=True)
    assert any("EXTRAPOLATED" in n for n in t.notes)
    for bad in ("-40:85", "85:-40:5", "a:b:c", "-40:85:0"):
        with pytest.raises(InputError, match="--grid"):
            parse_grid(bad)
    d = r.to_dict()
    d["effects"] = list(d["effects"]) + ["bias_drift"]
    for a in "xyz":
        d["parameters"][f"S_{a}_drift"] = {"value": 1.0, "u": 0.1, "unit": "ug/h"}
    with pytest.raises(InputError, match="bias_drift"):
        compensation_table(CalibrationResult.from_dict(d), parse_grid("-30:60:10"))
    d = r.to_dict()
    d["status"] = "model_mismatch"
    with pytest.raises(InputError, match="refused"):
        compensation_table(CalibrationResult.from_dict(d), parse_grid("-30:60:10"))


def test_an_unhashed_edited_result_is_exported_with_a_note(fitted, tmp_path):
    """An outside probe deleted content_sha256 and edited K_x (1.00021 -> 1.0102): exported without a
    word. A hashed file says nothing; one without the hash carries the note into every format."""
    r, _, tmp = fitted
    d = json.loads((tmp / "r.json").read_text())
    assert "content_sha256" in d
    t = compensation_table(CalibrationResult.load(tmp / "r.json"), parse_grid("-30:60:10"))
    assert not any("content_sha256" in n for n in t.notes)
    d.pop("content_sha256")
    d["parameters"]["K_x"]["value"] += 0.01
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(d))
    t = compensation_table(CalibrationResult.load(path), parse_grid("-30:60:10"))
    assert any("no content_sha256" in n for n in t.notes)
    assert "no content_sha256" in t.to_csv() and "no content_sha256" in t.to_c_header()


def test_cli_formats_and_the_header_compiles(fitted, tmp_path):
    from triadcal.cli import main

    _, _, tmp = fitted
    assert main(["export-compensation", str(tmp / "r.json"), "--grid", "-35:75:5", "--format", "c-header",
                 "-o", str(tmp_path / "comp.h"), "--quiet"]) == 0
    assert main(["export-compensation", str(tmp / "r.json"), "--format", "csv", "-o", str(tmp_path / "c.csv"),
                 "--quiet"]) == 0
    rows = [ln for ln in (tmp_path / "c.csv").read_text().splitlines() if not ln.startswith("#")]
    # the default grid: the calibrated range's ends (-40.0x, 80.0x degC) and the multiples of 5 between
    lo, hi = CalibrationResult.load(tmp / "r.json").temperature_range_C
    assert rows[0].startswith("T_C,K_x,u_K_x,interp_K_x")
    T_rows = [float(r.split(",")[0]) for r in rows[1:]]
    assert T_rows[0] == pytest.approx(lo, abs=1e-6) and T_rows[-1] == pytest.approx(hi, abs=1e-6)   # CSV: 7 decimals
    assert T_rows[1:-1] == [5.0 * k for k in range(math.floor(lo / 5) + 1, math.ceil(hi / 5))]
    assert main(["export-compensation", str(tmp / "r.json"), "--format", "json", "--grid", "-35:75:5",
                 "-o", str(tmp_path / "c.json"), "--quiet"]) == 0
    from test_results_contract import assert_valid

    assert_valid(json.loads((tmp_path / "c.json").read_text()), "triadcal.compensation")
    text = (tmp_path / "comp.h").read_text()
    assert "#define TRIADCAL_COMP_N 23" in text and "-35.0f" in text
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler on this machine: the header's syntax is not checked")
    (tmp_path / "t.c").write_text('#include "comp.h"\nint main(void){return (int)(triadcal_comp_K[0][0] < 0.5f)'
                                  ' + (int)(triadcal_comp_Ca_inv[0][1][1] < 0.5f);}\n')
    p = subprocess.run([cc, "-Wall", "-Wextra", "-Werror", "-o", str(tmp_path / "t"), str(tmp_path / "t.c")],
                       capture_output=True, text=True, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert subprocess.run([str(tmp_path / "t")]).returncode == 0


@pytest.mark.parametrize("text, match", [("0:inf:5", r"HI = 'inf' is not a finite number"),
                                         ("nan:50:5", r"LO = 'nan' is not a finite number"),
                                         ("50:0:5", r"need LO < HI")])
def test_a_grid_that_is_not_finite_says_which_value(text, match):
    """An outside probe: --grid 0:inf:5 and nan:50:5 were told 'need LO < HI and STEP > 0'."""
    with pytest.raises(InputError, match=match):
        parse_grid(text)


# -- an outside probe's tables (2026-12-02) ----------------------------------------------------------
def test_a_table_is_refused_for_what_a_certificate_is_refused_for(fitted):
    """A result whose fit left a significant model-data gap (chi2/dof 1.18 with known noise, p 4e-4:
    status ok by the fit's gate, which also asks chi2/dof > 1.2) was refused a certificate and
    exported, exit 0. The same reasons refuse the table (a result without content_sha256 is still
    exported with a note, test above)."""
    from triadcal.estimation.result_checks import RefusedResult

    import copy

    r, _, _ = fitted
    d = copy.deepcopy(r.to_dict())           # (to_dict shares the result's fit block)
    d.pop("content_sha256", None)
    d["fit"]["gap_p_value"] = 4e-4
    with pytest.raises(RefusedResult, match=r"significant gap between the model and the data.*a certificate is "
                                            r"refused for"):
        compensation_table(CalibrationResult.from_dict(d), parse_grid("-30:60:10"))


def test_extrapolation_needs_temperature_terms_and_temperatures(fitted, tmp_path):
    """A one-temperature result (no tempco) exported over -40..85 degC with --allow-extrapolation
    repeated its 20 degC values with their u (K_x 4.6 ppm) where the truth was 1632 ppm off at 85 degC:
    refused. A grid below absolute zero or beyond 300 degC, or a row where the model's K is not above
    0 (an extrapolated scale tempco), is refused too: the probe's -1e300..1e300 grid wrote nan, inf
    and a C header that did not compile, exit 0."""
    text, _ = simulate_campaign(np.random.default_rng(5), setpoints_C=(20.0,))
    (tmp_path / "one.csv").write_text(text)
    one = api.fit(tmp_path / "one.csv", effects=("bench_tilt",))
    assert one.status == "ok"
    with pytest.raises(InputError, match="holds no temperature term"):
        compensation_table(one, parse_grid("-40:85:25"), allow_outside=True)
    r, _, _ = fitted
    for grid in ("-300:-280:5", "-1e6:1e6:1e5", "250:310:10"):
        with pytest.raises(InputError, match="no temperature a unit is used at"):
            compensation_table(r, parse_grid(grid), allow_outside=True)
    model = Model(("scale_tempco",))
    params = {n: ParameterValue(model.spec[n].nominal, 0.1, model.spec[n].unit) for n in model.names}
    for a in "xyz":
        params[f"K_{a}"] = ParameterValue(1.0, 1e-6, "g/V")
    params["K_x_tempco"] = ParameterValue(-5000.0, 1.0, model.spec["K_x_tempco"].unit)    # ppm/degC
    steep = CalibrationResult(unit="SN-T", method="joint", parameters=params, effects=model.effect_names,
                              temperature_range_C=(-40.0, 85.0), fit={"chi2_dof": 1.0, "n_obs": 540, "n_params": 30},
                              extra={"output_unit": "V"})
    assert compensation_table(steep, parse_grid("-40:85:5")).K[:, 0].min() > 0
    with pytest.raises(InputError, match=r"at 220 degC the model gives K = 0, 1, 1"):
        compensation_table(steep, parse_grid("200:290:10"), allow_outside=True)
