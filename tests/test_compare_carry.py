"""A calibration over a temperature range compared with one at one temperature (docs/compare.md, "A
range calibration against one at one temperature"): the range calibration is carried by its own
temperature terms to the other's rows (triadcal.judgement.compare.carry). Before, compare refused the
pair unless the range calibration was refitted at the other's reference temperature, and then judged
the rows' remaining distance with the conservative tempco_bound although one side had measured the
tempcos. The data are made by tests/independent_bench.py, not by the project's simulator."""

from __future__ import annotations

import numpy as np
import pytest

from independent_bench import default_truth, simulate_campaign
from triadcal.errors import InputError
from triadcal.estimation.classical import fit_classical
from triadcal.estimation.joint import fit_joint
from triadcal.io.bench_csv import parse_bench_csv
from triadcal.judgement.compare import compare
from triadcal.judgement.compare.carry import ROW_QUANTITIES, carry_rows
from triadcal.judgement.compare.results import ComparisonResult

EFFECTS = ["bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco"]
ANGLES = ("xy", "xz", "yx", "yz", "zx", "zy")


def _truth(seed, **change):
    t = default_truth(np.random.default_rng(200 + seed))
    t.update({f"K_{a}_tempco": 120.0 for a in "xyz"})
    t.update({f"Ca_{ab}_tempco": 3.0 for ab in ANGLES})
    for k, v in change.items():
        t[k] = t[k] * (1.0 + v) if k.startswith("K_") else t[k] + v
    return t


def _campaign(truth, seed, setpoints_C=(-40, -10, 20, 50, 80), **kw):
    return parse_bench_csv(simulate_campaign(np.random.default_rng(seed), truth=truth, setpoints_C=setpoints_C, **kw)[0])


@pytest.mark.parametrize("method", ["joint", "classical"])
def test_carried_values_and_u_are_those_of_a_refit_at_the_other_temperature(method):
    """Linear tempcos: the fit at reference 60 degC carried to 23 degC is the same least squares as the
    fit at reference 23 degC, re-parameterised; so the carried values equal the refit's (1e-3 u) and
    the propagated u (GUM eq. 13, with the correlation of each value and its tempco) equal its u (1 %).
    Without that correlation (u of value and tempco x 37 degC in quadrature) the u are 20 % or more
    too large (the design's centre is 20 degC, far from 60)."""
    c = _campaign(_truth(0), 300)
    fit = (lambda T0: fit_joint(c, EFFECTS, reference_temperature_C=T0)) if method == "joint" else (
        lambda T0: fit_classical(c, reference_temperature_C=T0))
    r60, r23 = fit(60.0), fit(23.0)
    assert r60.status == r23.status == "ok"
    carried, bounds, names = carry_rows(r60, {"x": 23.0, "y": 23.0, "z": 23.0})
    assert set(names) == set(ROW_QUANTITIES) and bounds == {}
    naive = []
    for n in ROW_QUANTITIES:
        assert carried[n].value == pytest.approx(r23[n].value, abs=1e-3 * r23[n].u), n
        assert carried[n].u == pytest.approx(r23[n].u, rel=0.01), n
        per_unit = 1e-6 * r60[n].value if n[0] == "K" else 1e-6 if n[0] == "S" else 1.0
        naive.append(np.hypot(r60[n].u, 37.0 * r60[f"{n}_tempco"].u * per_unit) / r23[n].u)
    assert min(naive) > 1.2, naive
    # the correlation matrix is propagated too: the joint test's covariance of the angles
    C_c, C_r = carried.covariance([f"Ca_{ab}" for ab in ANGLES]), r23.covariance([f"Ca_{ab}" for ab in ANGLES])
    assert np.allclose(C_c, C_r, rtol=0.02, atol=1e-3 * np.max(np.abs(C_r)))


def test_an_unmoved_unit_passes_and_a_moved_one_fails_against_a_check_at_23_degC():
    """Ten units (K tempco 120 ppm/degC, angles 3"/degC: 360 ppm and 9" between 20 and 23 degC) calibrated
    over -40...80 degC and checked at 23 degC, unmoved: never fail, every drift's z within 3.5 (72 z, SD
    of z within 0.7-1.3: its sampling SD ~ 0.09); before, the pair was refused (reference temperatures
    differ). A unit whose K_x moved 60 ppm and Ca_xy 40": fail on both."""
    z = []
    for seed in range(10):
        truth = _truth(seed)
        ranged = fit_joint(_campaign(truth, 300 + seed), EFFECTS)
        one = fit_joint(_campaign(truth, 400 + seed, setpoints_C=(23.0,)), EFFECTS)
        out = compare(ranged, one, tolerances={"K_x": 20e-6 * truth["K_x"]})
        assert out.overall != "fail", (seed, {n: p.verdict for n, p in out.parameters.items()})
        assert any("carried by its own temperature terms" in n for n in out.notes), out.notes
        assert out.before["rows_carried_to_C"] == {a: pytest.approx(one.reference_temperature_C, abs=0.05) for a in "xyz"}
        z += [out.parameters[n].z for n in ROW_QUANTITIES]
        if seed == 0:       # the range calibration after the check: carried the same way, the drift reversed
            back = compare(one, ranged)
            assert "rows_carried_to_C" in back.after and "rows_carried_to_C" not in back.before
            for n in ROW_QUANTITIES:
                assert back.parameters[n].drift == pytest.approx(-out.parameters[n].drift, rel=1e-9)
                assert back.parameters[n].u == pytest.approx(out.parameters[n].u, rel=1e-9)
    assert np.max(np.abs(z)) < 3.5 and 0.7 < np.std(z) < 1.3, (np.max(np.abs(z)), np.std(z))
    truth = _truth(0)
    ranged = fit_joint(_campaign(truth, 300), EFFECTS)
    moved = fit_joint(_campaign(_truth(0, K_x=60e-6, Ca_xy=40.0), 401, setpoints_C=(23.0,)), EFFECTS)
    out = compare(ranged, moved, tolerances={"K_x": 20e-6 * truth["K_x"]})
    assert out.parameters["K_x"].verdict == "fail" and out.parameters["Ca_xy"].verdict == "fail", out.parameters
    assert out.overall == "fail"
    # the JSON says where the rows were carried, and its reader checks it
    d = out.to_dict()
    from test_results_contract import assert_valid, errors

    assert_valid(d, "triadcal.comparison")
    assert errors({**d, "before": {**d["before"], "rows_carried_to_C": {"x": 23.0, "y": 23.0}}})
    back = ComparisonResult.from_dict(d)
    assert back.before["rows_carried_to_C"] == d["before"]["rows_carried_to_C"] and "rows_carried_to_C" not in d["after"]
    for bad in ({"x": 23.0, "y": 23.0}, {"x": 23.0, "y": 23.0, "z": float("nan")}, {"x": 23.0, "y": 23.0, "z": 900.0}):
        with pytest.raises(InputError, match="rows_carried_to_C"):
            ComparisonResult.from_dict({**d, "before": {**d["before"], "rows_carried_to_C": bad}})


def test_the_check_carries_each_row_to_its_own_sensor_and_the_range_is_not_extrapolated():
    """A check whose sensors read apart (rows at their own t_a): each row of the range calibration is
    carried to its own row's temperature. A check outside the calibrated range (90 degC against -40...80)
    is refused, naming the range; one at 50 degC after a range of 20...80 degC is compared."""
    truth = _truth(1)
    ranged = fit_joint(_campaign(truth, 301), EFFECTS)
    carried, _, _ = carry_rows(ranged, {"x": 23.5, "y": 22.8, "z": 23.1})
    assert carried["K_x"].value == pytest.approx(ranged["K_x"].value * (1 + 1e-6 * ranged["K_x_tempco"].value * 3.5))
    assert carried["K_y"].value == pytest.approx(ranged["K_y"].value * (1 + 1e-6 * ranged["K_y_tempco"].value * 2.8))
    assert carried["Ca_zx"].value == pytest.approx(ranged["Ca_zx"].value + ranged["Ca_zx_tempco"].value * 3.1)
    assert carried["S_z"].value == pytest.approx(ranged["S_z"].value + 1e-6 * ranged["S_z_tempco"].value * 3.1)
    hot = fit_joint(_campaign(truth, 402, setpoints_C=(90.0,)), EFFECTS)
    with pytest.raises(InputError, match=r"calibrated over -40\.\d\d\.\.\.80\.\d\d degC.*outside it"):
        compare(ranged, hot)
    upper = fit_joint(_campaign(truth, 302, setpoints_C=(20, 40, 60, 80)), EFFECTS)
    assert compare(upper, fit_joint(_campaign(truth, 403, setpoints_C=(50.0,)), EFFECTS)).overall != "fail"


def test_a_range_calibration_with_a_hysteresis_loop_bounds_the_angles_drift():
    """The check at one temperature is somewhere on the loop, on a branch it does not know: each
    angle's drift holds a bias within +-h, the loop's half-width (20" here), taken at its worst; K and
    S (no loop) carry none. An unmoved unit is not failed, with the angles' tolerance of 30"."""
    truth = {**_truth(2), **{f"Ca_{ab}_hysteresis": 20.0 for ab in ANGLES}}
    loop = {"form": "offset"}
    ranged = fit_joint(_campaign(truth, 303, setpoints_C=(-40, -10, 20, 50, 80, 50, 20, -10, -40), hysteresis=loop),
                       EFFECTS + ["hysteresis"])
    assert ranged.status == "ok", ranged.notes
    one = fit_joint(_campaign(truth, 404, setpoints_C=(23.0,)), EFFECTS)
    out = compare(ranged, one)
    for ab in ANGLES:
        assert out.parameters[f"Ca_{ab}"].bound == pytest.approx(abs(ranged[f"Ca_{ab}_hysteresis"].value), rel=1e-9)
        assert abs(ranged[f"Ca_{ab}_hysteresis"].value - 20.0) < 4 * ranged[f"Ca_{ab}_hysteresis"].u
    assert all(out.parameters[n].bound == 0.0 for n in ("K_x", "S_y"))
    assert any("hysteresis loop" in n for n in out.notes) and out.overall != "fail"


def test_posteriors_are_checked_against_the_results_as_given_and_carried_rows_judged_on_value_and_u(tmp_path):
    """A posterior of the range calibration holds draws at its reference temperature: it is checked
    against that result (not the carried one), and the carried rows are judged on (value, u), never
    on those draws; the parameters that are not carried (the tempcos are in one result only, so none
    here) would be judged on draws."""
    from test_compare_mutations import _posterior

    truth = _truth(3)
    ranged = fit_joint(_campaign(truth, 304), EFFECTS)
    one = fit_joint(_campaign(truth, 405, setpoints_C=(23.0,)), EFFECTS)
    pb, pa = _posterior(ranged, tmp_path / "pb.nc"), _posterior(one, tmp_path / "pa.nc")
    out = compare(ranged, one, posterior_before=pb, posterior_after=pa)
    assert all(out.parameters[n].basis == "normal" for n in ROW_QUANTITIES)
    assert any("judged on (value, u), not on posterior draws" in n and "Ca_xy" in n for n in out.notes), out.notes
    assert out.overall != "fail"


def test_shared_equipment_is_subtracted_from_the_carried_rows_as_from_a_refit(tmp_path):
    """With the lab's systematic errors: the carried rows' Type B rows are the parameters' rows
    combined by the carry's Jacobian (GUM 5.1.3), so ``--shared-equipment bench`` subtracts the bench's
    error from the carried drifts as from a refit of the range calibration at the check's temperature:
    u(d) within 3 % of the refit's, shared and not (the check's rows are within 0.05 degC of 23)."""
    from test_classical_typeb import LAB

    from triadcal import api

    truth = _truth(4)
    (tmp_path / "r.csv").write_text(simulate_campaign(np.random.default_rng(306), truth=truth, sigma_position_arcsec=5.0)[0])
    (tmp_path / "o.csv").write_text(simulate_campaign(np.random.default_rng(406), truth=truth, setpoints_C=(23.0,),
                                                      sigma_position_arcsec=5.0)[0])
    one = api.fit(tmp_path / "o.csv", method="joint", lab=LAB)
    ranged = api.fit(tmp_path / "r.csv", method="joint", lab=LAB)
    refit = api.fit(tmp_path / "r.csv", method="joint", lab=LAB, reference_temperature_C=one.reference_temperature_C)
    for shared in ((), ("bench",)):
        carried, direct = compare(ranged, one, shared_equipment=shared), compare(refit, one, shared_equipment=shared)
        for n in ROW_QUANTITIES:
            assert carried.parameters[n].u == pytest.approx(direct.parameters[n].u, rel=0.03), (shared, n)
    # the bench's non-orthogonality reaches Ca_xz and Ca_zx (u(d) 16.1" -> 14.5"); the mounting (an item's, not
    # shareable) dominates the others
    shared, alone = compare(ranged, one, shared_equipment=("bench",)), compare(ranged, one)
    ratio = {ab: shared.parameters[f"Ca_{ab}"].u / alone.parameters[f"Ca_{ab}"].u for ab in ANGLES}
    assert max(ratio.values()) <= 1 + 1e-9 and ratio["xz"] < 0.95 and ratio["zx"] < 0.95, ratio


def test_through_the_cli_from_result_files(tmp_path):
    """The result files as written (JSON round trip: correlation matrix, temperature range) through
    `triadcal compare`: the comparison file names the carried side's rows and its rule says how."""
    import json

    from triadcal.cli import main

    truth = _truth(5)
    fit_joint(_campaign(truth, 307), EFFECTS).save(tmp_path / "ranged.json")
    fit_joint(_campaign(truth, 407, setpoints_C=(23.0,)), EFFECTS).save(tmp_path / "check.json")
    assert main(["compare", str(tmp_path / "check.json"), str(tmp_path / "ranged.json"),
                 "--json", str(tmp_path / "cmp.json")]) == 0
    d = json.loads((tmp_path / "cmp.json").read_text())
    assert set(d["after"]["rows_carried_to_C"]) == {"x", "y", "z"} and "rows_carried_to_C" not in d["before"]
    assert "carried to the other's rows by its own temperature terms" in d["rule"] and d["overall"] != "fail"


def test_a_loop_on_an_angle_without_a_tempco_adds_to_its_unmeasured_tempco_bound():
    """A range calibration with a loop but no angle tempcos, against a check whose rows are 0.1 degC from
    its reference: K and S are carried (bound 0); each angle keeps the bound of its unmeasured tempco
    (10"/degC x dT) and adds the loop's half-width to it, both taken at their worst."""
    from triadcal.judgement.compare.pair import tempco_bound

    truth = {**_truth(6), **{f"Ca_{ab}_tempco": 0.0 for ab in ANGLES}, **{f"Ca_{ab}_hysteresis": 15.0 for ab in ANGLES}}
    effects = ["bench_tilt", "scale_tempco", "bias_tempco", "hysteresis"]
    check = fit_joint(_campaign(truth, 408, setpoints_C=(23.0,)), ["bench_tilt"])
    ranged = fit_joint(_campaign(truth, 308, setpoints_C=(-40, -10, 20, 50, 80, 50, 20, -10, -40), hysteresis={"form": "offset"}),
                       effects, reference_temperature_C=round(check.reference_temperature_C + 0.1, 2))
    assert ranged.status == check.status == "ok"
    out = compare(ranged, check)
    dT = {a: abs(ranged.reference_temperature_C - check.reference_temperature_C) for a in "xyz"}
    for ab in ANGLES:
        n = f"Ca_{ab}"
        expect = abs(ranged[f"{n}_hysteresis"].value) + tempco_bound(n, ranged[n].value, dT)
        assert out.parameters[n].bound == pytest.approx(expect, rel=1e-9), n
    assert out.parameters["K_x"].bound == 0.0 and out.parameters["S_z"].bound == 0.0
