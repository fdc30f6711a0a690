"""A campaign at one temperature (docs/joint.md, "One temperature"): no temperature coefficient can
be determined, so the values are at the data's mean temperature and the result says so
(``reference_temperature_C`` moved there, a note). Before, a campaign at 50 degC reported its K
at "20 degC" with status ok, 419 u from the unit's K at 20 degC (an outside probe). The data are
made by tests/independent_bench.py; the truth at the reference is derived by hand from its laws
(``K (1 + k1 dT)``, ``S + s1 dT``, ``Ca + c1 dT`` with dT from 20 degC)."""

from __future__ import annotations

import numpy as np
import pytest

from independent_bench import T0_C, simulate_campaign
from triadcal.errors import InputError
from triadcal.estimation.joint import fit_joint
from triadcal.io.bench_csv import parse_bench_csv
from triadcal.judgement.compare import compare

EFFECTS = ["bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco"]


def _at(setpoint, seed):
    text, truth = simulate_campaign(np.random.default_rng(seed), setpoints_C=(setpoint,))
    return parse_bench_csv(text), truth


def test_one_temperature_is_reported_at_that_temperature():
    c, truth = _at(50.0, 5)
    r = fit_joint(c, EFFECTS)
    assert r.status == "ok", r.notes
    Tm = float(np.mean(c.t))
    assert r.reference_temperature_C == pytest.approx(Tm, abs=0.006) and abs(Tm - 50.0) < 1.0
    assert any("one temperature" in n and f"{r.reference_temperature_C:.2f} degC" in n for n in r.notes), r.notes
    assert not any("_tempco" in n for n in r.parameters)                 # held: not in the result
    dT = r.reference_temperature_C - T0_C
    for a, i in zip("xyz", range(3)):
        K = truth[f"K_{a}"] * (1.0 + 1e-6 * truth[f"K_{a}_tempco"] * dT)
        S = truth[f"S_{a}"] + 1e-6 * truth[f"S_{a}_tempco"] * dT
        pk, ps = r.parameters[f"K_{a}"], r.parameters[f"S_{a}"]
        assert abs(pk.value - K) < 4 * pk.u, (a, pk, K)
        assert abs(ps.value - S) < 4 * ps.u, (a, ps, S)
        # and far from the unit at 20 degC, where the old label put these values
        K20 = truth[f"K_{a}"]
        assert abs(K - K20) < 4 * pk.u or abs(pk.value - K20) > 4 * pk.u
    # a campaign whose one temperature is the reference keeps it
    c20, _ = _at(20.0, 6)
    Tm20 = float(np.mean(c20.t))
    r20 = fit_joint(c20, EFFECTS, reference_temperature_C=round(Tm20, 2))
    assert r20.reference_temperature_C == round(Tm20, 2)
    assert not any("values are at the mean temperature" in n for n in r20.notes), r20.notes
    # several temperatures: the requested reference, whatever the data's mean
    cm, _ = simulate_campaign(np.random.default_rng(7), setpoints_C=(40.0, 60.0))
    assert fit_joint(parse_bench_csv(cm), EFFECTS).reference_temperature_C == 20.0


def test_two_calibrations_at_one_setpoint_are_compared_with_a_note():
    before, _ = _at(50.0, 8)
    after, _ = _at(50.1, 9)                     # the chamber held 0.1 degC higher
    rb, ra = fit_joint(before, EFFECTS), fit_joint(after, EFFECTS)
    dT = abs(rb.reference_temperature_C - ra.reference_temperature_C)
    assert 0 < dT <= 0.2
    out = compare(rb, ra)
    assert any("one temperature: the rows are at" in n for n in out.notes), out.notes
    # another setpoint is another temperature: refused
    other, _ = _at(60.0, 10)
    with pytest.raises(InputError, match="reference temperatures differ .*10.00 degC apart in row x.*calibrate again"):
        compare(rb, fit_joint(other, EFFECTS))
    # exactly 0.2 degC apart (written to 0.01 degC: 50.2 - 50.0 is 0.20000000000000284): compared
    shifted = parse_bench_csv(simulate_campaign(np.random.default_rng(9), setpoints_C=(50.1,))[0])
    shifted.t[:] = shifted.t + (rb.reference_temperature_C + 0.2 - np.mean(shifted.t))
    rs = fit_joint(shifted, EFFECTS)
    assert abs(rs.reference_temperature_C - rb.reference_temperature_C) == pytest.approx(0.2, abs=1e-9)
    compare(rb, rs)
    # against a calibration over a range: carried by its own tempcos to this one's rows, whatever its
    # reference (tests/test_compare_carry.py; it was refused before unless refitted at this temperature)
    text, _ = simulate_campaign(np.random.default_rng(11), setpoints_C=(40.0, 60.0))
    ranged = parse_bench_csv(text)
    out = compare(rb, fit_joint(ranged, EFFECTS, reference_temperature_C=rb.reference_temperature_C - 0.1))
    assert any("carried by its own temperature terms" in n for n in out.notes), out.notes
    assert all(p.bound == 0.0 for p in out.parameters.values())
    # two calibrations over ranges at different references: one must be refitted at the other's
    other = fit_joint(parse_bench_csv(simulate_campaign(np.random.default_rng(12), setpoints_C=(40.0, 60.0))[0]),
                      EFFECTS, reference_temperature_C=45.0)
    with pytest.raises(InputError, match="reference temperatures differ.*refit before or after, which has tempcos"):
        compare(fit_joint(ranged, EFFECTS, reference_temperature_C=50.0), other)


def _sensors_apart(offsets_C, seed=5, setpoints_C=(50.0,)):
    """Setpoints (one, 50 degC, by default) whose three sensors read ``offsets_C`` apart: the outputs are made at
    each accelerometer's own sensor temperature (K and S through independent_bench's tempco laws,
    applied by its extra_scale / extra_bias hooks), and the file's t_* carry the offsets."""
    off = np.asarray(offsets_C, float)
    truth0 = None

    def scale(k, t, temps):
        return 1e-6 * np.array([truth0[f"K_{a}_tempco"] for a in "xyz"]) * off / (
            1.0 + 1e-6 * np.array([truth0[f"K_{a}_tempco"] for a in "xyz"]) * (temps - T0_C))

    def bias(k, t, temps, G, direction):
        return 1e-6 * np.array([truth0[f"S_{a}_tempco"] for a in "xyz"]) * off

    from independent_bench import default_truth
    truth0 = default_truth(np.random.default_rng(100 + seed))
    text, truth = simulate_campaign(np.random.default_rng(seed), truth=truth0, setpoints_C=setpoints_C,
                                    extra_scale=scale, extra_bias=bias)
    c = parse_bench_csv(text)
    c.t[:] = c.t + off[None, :]
    return c, truth


def test_sensors_apart_at_one_temperature_name_each_rows_temperature():
    """Sensors 0.5, -0.3, 0 degC apart (self-heating): ok, and a note and fit.sensor_temperatures_C
    name each sensor's mean; K_a and S_a are the unit's at its own sensor's temperature within 4 u
    (the truth by hand from independent_bench's laws, K (1 + k1 dT), S + s1 dT)."""
    c, truth = _sensors_apart((0.5, -0.3, 0.0))
    r = fit_joint(c, EFFECTS)
    assert r.status == "ok", r.notes
    temps = r.fit["sensor_temperatures_C"]
    assert any("each accelerometer's K, S and angles Ca_ab are at its own sensor's" in n for n in r.notes), r.notes
    for i, a in enumerate("xyz"):
        Ta = float(np.mean(c.t[:, i]))
        assert temps[a] == pytest.approx(Ta, abs=0.006)
        K = truth[f"K_{a}"] * (1.0 + 1e-6 * truth[f"K_{a}_tempco"] * (Ta - T0_C))
        S = truth[f"S_{a}"] + 1e-6 * truth[f"S_{a}_tempco"] * (Ta - T0_C)
        assert abs(r[f"K_{a}"].value - K) < 4 * r[f"K_{a}"].u, (a, r[f"K_{a}"], K)
        assert abs(r[f"S_{a}"].value - S) < 4 * r[f"S_{a}"].u, (a, r[f"S_{a}"], S)


def test_sensors_apart_certificate_and_compare_use_each_rows_temperature(tmp_path):
    """Sensors +0.45, -0.4, 0 degC apart (an outside probe: S_x 7.6 u from the unit's at the stated mean
    temperature, status ok): the certificate states each row's temperature, and compare judges the
    rows' temperatures, not the means: against a calibration with its sensors alike at the same mean
    it notes 0.45 degC; against one whose rows are 0.85 degC off in X it refuses."""
    from triadcal.reports.certificate.content import build_certificate

    c, truth = _sensors_apart((0.45, -0.4, 0.0), seed=11)
    r = fit_joint(c, EFFECTS)
    assert r.status == "ok", r.notes
    # (with tempcos in the model the certificate refuses: the data cannot determine them)
    r_bt = fit_joint(c, ["bench_tilt"])
    assert r_bt.status == "ok" and r_bt.fit["sensor_temperatures_C"] == r.fit["sensor_temperatures_C"]
    cert = build_certificate(r_bt, campaign=c)
    rows = dict(cert.conditions)
    line = rows["Temperature of each accelerometer's values"]
    for a in "xyz":
        assert f"{a.upper()} (K_{a}, S_{a}" in line and f"{r.fit['sensor_temperatures_C'][a]:.2f} °C" in line, line
    assert "next row" in rows["Reference temperature"]
    # and every sentence that says where the values hold says it per accelerometer (an outside probe:
    # sections 4 and 6 and the console said "at the reference temperature 50.02 degC")
    from triadcal.reports.certificate.html import render_html, results_intro
    own = f"each accelerometer's own temperature (X {r.fit['sensor_temperatures_C']['x']:.2f}"
    assert own in results_intro(cert)
    page = render_html(cert)
    assert cert.issued and cert.inverse_matrix is not None and f"Ca⁻¹ at {own}" in page
    assert f"temperature {r.reference_temperature_C:g} °C" not in page.replace("Reference temperature", "")
    from triadcal.reports.compensation import compensation_table
    # (a model with tempcos at one temperature holds them fixed, and the table refuses it for lacking them)
    table = compensation_table(r_bt, [r.reference_temperature_C], allow_outside=True)
    assert any("sensors apart" in n and f"x {r.fit['sensor_temperatures_C']['x']:.2f}" in n for n in table.notes)
    # the same unit with its sensors alike at the same mean: row x 0.45 degC from it, which no tempco
    # carries: refused, naming the rows (before, the means agreed and compare said nothing)
    same, _ = _sensors_apart((0.0, 0.0, 0.0), seed=12)
    same.t[:] = same.t + (np.mean(c.t) - np.mean(same.t))
    r0 = fit_joint(same, EFFECTS)
    assert r0.status == "ok" and abs(r0.reference_temperature_C - r.reference_temperature_C) <= 0.011
    with pytest.raises(InputError, match="accelerometers' temperatures differ .*per accelerometer x 50.4"):
        compare(r, r0)
    # sensors +0.15, -0.1, 0 degC apart against alike: within 0.2 degC, compared with a note naming row x
    near, _ = _sensors_apart((0.15, -0.1, 0.0), seed=13)
    near.t[:] = near.t + (np.mean(same.t) - np.mean(near.t))
    out = compare(r0, fit_joint(near, EFFECTS))
    note = next(n for n in out.notes if "one temperature: the rows are at" in n)
    assert "(row x)" in note and "0.1" in note, note
    # a results file whose sensor temperatures were edited to 1 degC apart, status ok: refused by the readers
    from triadcal.estimation.result_checks import result_problems
    r.fit["sensor_temperatures_C"] = {"x": 51.0, "y": 50.0, "z": 50.0}
    assert any("one_reference_temperature" in w for w in result_problems(r))
    r.fit["sensor_temperatures_C"] = {"x": float("nan"), "y": 50.0, "z": 50.0}
    assert any("fit.sensor_temperatures_C.x" in w for w in result_problems(r))
    # edited apart from the file's other temperatures (a probe, with the checksum removed: compare judged
    # the edited rows, K_x z 11.6, fail): the sensors' mean against the reference, the readings' range
    good = dict(r0.fit["sensor_temperatures_C"])
    r0.fit["sensor_temperatures_C"] = {a: v + 0.2 for a, v in good.items()}
    assert any("average" in w and "reference_temperature_C" in w for w in result_problems(r0)), result_problems(r0)
    r0.fit["sensor_temperatures_C"] = good
    assert not result_problems(r0)
    r0.temperature_range_C = (20.0, 50.0)
    assert any("temperature_range_C spans 30.00 degC" in w for w in result_problems(r0)), result_problems(r0)


def test_sensors_a_degree_or_more_apart_at_one_temperature_are_refused():
    """Sensors +4, -3, 0 degC apart: no one reference temperature describes the result (an outside
    probe: ok 10 of 10, a median largest error of 17 u at the stated temperature); the gate
    one_reference_temperature refuses, status unidentifiable, naming the three temperatures."""
    c, _ = _sensors_apart((4.0, -3.0, 0.0))
    r = fit_joint(c, EFFECTS)
    gate = next(o for o in r.extra["gates"]["outcomes"] if o["gate"] == "one_reference_temperature")
    assert r.status == "unidentifiable" and gate["passed"] is False, gate
    assert gate["value"] == pytest.approx(7.0, abs=0.05) and "t_x 54." in gate["reason"]
    # sensors alike: no note, no gate
    c, _ = _at(50.0, 5)
    r = fit_joint(c, EFFECTS)
    assert not any(o["gate"] == "one_reference_temperature" for o in r.extra["gates"]["outcomes"])
    assert not any("sensors apart" in n for n in r.notes)


def test_classical_fits_each_row_on_its_own_sensor_by_default():
    """Five setpoints, sensors +1, -0.5, +0.3 degC apart (an outside probe: the paper's mean-temperature
    convention put K and S a median 8 u from the unit's at T_ref, status ok, 10 of 10): the classical
    method now regresses each row on its own sensor, as every result means, and K_a, S_a at 20 degC
    are the unit's within 4 u; the paper's convention (temperature="mean") is off by
    tempco * offset, more than 4 u for K_x here."""
    from triadcal.estimation.classical import fit_classical

    c, truth = _sensors_apart((1.0, -0.5, 0.3), seed=3, setpoints_C=(-40, -10, 20, 50, 80))
    own, mean = fit_classical(c), fit_classical(c, temperature="mean")
    assert own.status == "ok" and own.fit["temperature"] == "each accelerometer's own sensor t_a"
    for a in "xyz":
        assert abs(own[f"K_{a}"].value - truth[f"K_{a}"]) < 4 * own[f"K_{a}"].u, (a, own[f"K_{a}"], truth[f"K_{a}"])
        assert abs(own[f"S_{a}"].value - truth[f"S_{a}"]) < 4 * own[f"S_{a}"].u, (a, own[f"S_{a}"], truth[f"S_{a}"])
    worst = max(abs(mean[f"{q}_{a}"].value - truth[f"{q}_{a}"]) / mean[f"{q}_{a}"].u for q in "KS" for a in "xyz")
    assert worst > 4, worst


def test_rows_apart_carry_the_unmeasured_tempcos_as_a_bound_taken_at_its_worst():
    """An outside probe: two calibrations at one temperature each of a unit that did not move, its K_x
    tempco 100 ppm/degC, the second 0.15 degC warmer: K_x's drift (15 ppm, the tempco's) was judged
    against u(d) alone (z -5.1) and `--param-tolerance K_x` gave fail. With the tempco as a
    rectangular u (bound/sqrt 3) a unit at the bound still failed (a second probe: K tolerance 20 ppm,
    6 of 25; the angles' joint test, 14 of 25). Now each K, S and angle's drift holds a bias within
    +-compare.TEMPCO_BOUND x dT (tempco_bound), taken at its worst by the rule. Here every tempco is at
    its bound, one sign (K 300 ppm/degC, angles 10"/degC; S 100 ug/degC; K's 45 ppm is about 7 u(d)),
    over 5 seed pairs: never fail, with the K tolerance of 20 ppm or without any tolerance (the joint
    test); a unit that moved (K 500 ppm, an angle 60") still fails."""
    from independent_bench import default_truth

    from triadcal.judgement.compare.pair import TEMPCO_BOUND

    truth = default_truth(np.random.default_rng(100))
    truth.update({f"K_{a}_tempco": 300.0 for a in "xyz"})
    truth.update({f"S_{a}_tempco": 100.0 for a in "xyz"})     # 1 mg/degC: the 0.01 degC jitter of the readings fails chi2
    truth.update({f"Ca_{ab}_tempco": 10.0 for ab in ("xy", "xz", "yx", "yz", "zx", "zy")})

    def fit_at(setpoint, seed, **change):
        t = dict(truth)
        for k, v in change.items():
            t[k] = t[k] * (1.0 + v) if k.startswith("K_") else t[k] + v
        text, _ = simulate_campaign(np.random.default_rng(seed), truth=t, setpoints_C=(setpoint,))
        r = fit_joint(parse_bench_csv(text), EFFECTS)
        assert r.status == "ok", r.notes
        return r

    for seed in range(5):
        rb, ra = fit_at(50.0, 40 + 2 * seed), fit_at(50.15, 41 + 2 * seed)
        dT = abs(ra.reference_temperature_C - rb.reference_temperature_C)
        out = compare(rb, ra, tolerances={"K_x": 20e-6 * rb["K_x"].value})
        d = out.parameters["K_x"]
        assert d.bound == pytest.approx(TEMPCO_BOUND["K"] * rb["K_x"].value * dT, rel=1e-12)
        assert d.u == pytest.approx(np.hypot(rb["K_x"].u, ra["K_x"].u), rel=1e-9)
        assert abs(d.drift) / d.u > 3                            # the tempco's 45 ppm, ~7 u(d)
        assert d.verdict != "fail" and out.overall != "fail", (seed, d.verdict, out.overall)
        assert any("tempco_bound" in n and "bounds K 300 ppm" in n for n in out.notes), out.notes
        free = compare(rb, ra, tolerance_arcsec=None)
        assert free.overall != "fail" and not free.joint.significant, (seed, free.joint)
        for n in ("K_x", "K_y", "K_z", "Ca_xy", "Ca_zy"):       # at the bound: never significant beyond it
            assert abs(free.parameters[n].z) < 4, (seed, n, free.parameters[n])
    moved = fit_at(50.15, 99, K_x=500e-6, Ca_xy=60.0)
    out = compare(rb, moved, tolerances={"K_x": 50e-6 * rb["K_x"].value})
    assert out.parameters["K_x"].verdict == "fail" and out.parameters["Ca_xy"].verdict == "fail"
    assert out.overall == "fail"
    # the bound goes into the comparison's JSON and its reader checks the verdicts with it
    from triadcal.judgement.compare.results import ComparisonResult
    back = ComparisonResult.from_dict(out.to_dict())
    assert back.parameters["K_x"].bound == out.parameters["K_x"].bound > 0
