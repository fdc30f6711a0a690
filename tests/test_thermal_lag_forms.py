"""The thermal lag of the sensing element behind its thermometer, for both places the thermometer
can sit (docs/model.md, "Thermal lag: where the thermometer sits").

Campaigns are made by tests/independent_bench.py, which integrates the heat equations of chamber
air, housing and element by explicit Euler steps (not the project's lag functions), and fitted by
:func:`triadcal.estimation.thermal_lag_form.fit_thermal_lag`.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from independent_bench import RampProgram, StepProgram, simulate_lag_campaign
from triadcal.estimation.gates import result_gates
from triadcal.estimation.joint import fit_joint
from triadcal.estimation.result import ParameterValue
from triadcal.estimation.thermal_lag_form import fit_thermal_lag
from triadcal.api import fit as api_fit
from triadcal.io.bench_csv import parse_bench_csv, read_bench_csv
from triadcal.errors import InputError
from triadcal.models.effects.thermal_lag import bridge_record, element_temperature
from triadcal.models.thermal_history import two_stage_lag

EFFECTS = ["angle_tempco", "scale_tempco", "bias_tempco"]
TAU_HOUSING = 30.0       # min: the housing behind the air when the thermometer reads the air


def campaign(tmp_path, seed, **kw):
    text, truth = simulate_lag_campaign(np.random.default_rng(seed), **kw)
    p = tmp_path / f"lag_{seed}.csv"
    p.write_text(text)
    return read_bench_csv(p), truth


def z(result, name, truth):
    p = result.parameters[name]
    return (p.value - truth) / p.u


# -- the pure functions -------------------------------------------------------------------
def test_element_temperature_step_responses():
    t = np.arange(0.0, 20000.0, 5.0)
    T = np.where(t >= 1000.0, 10.0, 0.0)
    tau, tau_h = 600.0, 1500.0
    x = np.clip(t - 1000.0, 0.0, None)
    one = element_temperature(t, T, tau, "housing")
    two = element_temperature(t, T, tau, "air", tau_h)
    # the record steps between two samples (a 5 s ramp in the ramp-invariant lag): within 0.1 degC
    assert np.max(np.abs(one - 10.0 * (1 - np.exp(-x / tau)))) < 0.1
    exact2 = 10.0 * (1 - (tau_h * np.exp(-x / tau_h) - tau * np.exp(-x / tau)) / (tau_h - tau))
    assert np.max(np.abs(two - exact2)) < 0.1
    # two stages commute; order of the samples does not matter; the columns are lagged one by one
    assert np.allclose(two, two_stage_lag(t, T, tau, tau_h))
    perm = np.random.default_rng(0).permutation(len(t))
    assert np.allclose(element_temperature(t[perm], T[perm], tau, "air", tau_h), two[perm])
    both = element_temperature(t, np.c_[T, 2 * T], tau)
    assert np.allclose(both[:, 0], one) and np.allclose(both[:, 1], 2 * one)
    with pytest.raises(ValueError, match="housing, air"):
        element_temperature(t, T, tau, "element")


def test_the_bridge_is_the_chambers_first_order_response():
    """By hand: an air that steps toward T_new at the gap's start as a first-order response of tau_c,
    T_new + A exp(-s / tau_c), read at the gap's two ends, is the bridge of tau_b = tau_c exactly
    (T1 = T_new + A exp(-D / tau_c) fixes the normalisation). Its limits: a straight line for a long
    tau_b, a step for a short one. The samples of the record are kept, in order."""
    tau_c, D, A, T_new = 600.0, 1800.0, -30.0, 50.0
    t = np.array([0.0, 60.0, 60.0 + D, 60.0 + D + 50.0])
    air = lambda s: T_new + A * np.exp(-s / tau_c)            # noqa: E731 (s from the gap's start)
    T = np.array([T_new + A, T_new + A, air(D), air(D + 50.0)])
    times, values, kept = bridge_record(t, T, tau_c, 600.0)
    assert np.array_equal(times[kept], t) and np.array_equal(values[kept, 0], T)
    inside = (times > 60.0) & (times < 60.0 + D)
    assert inside.sum() >= 8 and np.all(np.diff(times) > 0)
    assert np.allclose(values[inside, 0], air(times[inside] - 60.0), rtol=0, atol=1e-9)
    # limits: a straight line (tau_b >> D), a step at the gap's start (tau_b << D)
    times, lin, _ = bridge_record(t, T, 1e9, 600.0)
    inside = (times > 60.0) & (times < 60.0 + D)
    assert np.allclose(lin[inside, 0], np.interp(times[inside], t, T), rtol=0, atol=1e-4)
    times, step, _ = bridge_record(t, T, 1.0, 600.0)
    inside = (times > 60.0) & (times < 60.0 + D)
    # (200 points at most per gap: the first 9 s after its start, where exp(-9) of the step is left)
    assert np.allclose(step[inside, 0], T[2], rtol=0, atol=30.0 * math.exp(-9.0))
    # no gap (the threshold above every interval): the record as it is
    times, values, kept = bridge_record(t, T, tau_c, 1e6)
    assert np.array_equal(times, t) and np.array_equal(kept, np.arange(4))
    with pytest.raises(ValueError):
        bridge_record(t, T, 0.0, 600.0)


def test_the_element_behind_a_bridged_step():
    """By hand: the record reads 20 degC, then 50 degC after a 30 min gap. Bridged as a step (tau_b
    1 s) the element's two stages (tau_h 20 min, tau 5 min) respond from the gap's start:
    50 - 30 (tau_h e^(-s/tau_h) - tau e^(-s/tau)) / (tau_h - tau) at the first sample after it; a
    straight line across the gap (no bridge) leaves the element much nearer 20 degC there."""
    D, tau, tau_h = 1800.0, 300.0, 1200.0
    t = np.array([0.0, 60.0, 60.0 + D, 60.0 + D + 50.0])
    T = np.array([20.0, 20.0, 50.0, 50.0])
    exact = lambda s: 50.0 - 30.0 * (tau_h * np.exp(-s / tau_h) - tau * np.exp(-s / tau)) / (tau_h - tau)  # noqa: E731
    e = element_temperature(t, T, tau, "air", tau_h, bridge=(1.0, 600.0))
    # the bridged step is a 9 s ramp (200 points per gap at most), 4.5 s late: 0.033 degC at the
    # element's slope of 0.0074 degC/s there
    assert e[2] == pytest.approx(exact(D - 4.5), abs=0.005) and e[3] == pytest.approx(exact(D + 45.5), abs=0.005)
    lin = element_temperature(t, T, tau, "air", tau_h)
    assert lin[2] < e[2] - 5.0


def test_bridging_is_refused_for_a_housing_thermometer_and_without_the_history_form(tmp_path):
    """The bridge is the air's first-order approach; a housing's is two stages (its 20 min lag came out
    20.52 +- 0.08 min, status ok, when it was allowed): refused, as is --bridge-gaps with the rate form."""
    from triadcal.api import fit

    c, _ = campaign(tmp_path, 42, tau_element_min=20.0, location="housing", tau_housing_min=TAU_HOUSING,
                    program=StepProgram(soak_min=20.0))
    with pytest.raises(InputError, match="chamber air"):
        fit_thermal_lag(c, EFFECTS, "housing", bridge_gaps=True)
    with pytest.raises(InputError, match="--thermal-lag-form housing, air or history"):
        fit(c, effects=EFFECTS, bridge_gaps=True)


#: stepped campaigns of the independent bench, thermometer in the air: (element, housing, chamber
#: tau in min, soak in min)
BRIDGED = [(4.0, 20.0, 10.0, 30.0), (4.0, 20.0, 5.0, 30.0), (10.0, 30.0, 5.0, 30.0), (2.0, 20.0, 10.0, 30.0),
           (20.0, 30.0, 5.0, 20.0), (5.0, 30.0, 5.0, 20.0), (5.0, 20.0, 5.0, 30.0), (20.0, 20.0, 5.0, 30.0)]


def _bridged_case(tmp_path, seed, case):
    te, th, tc, soak = case
    c, _ = campaign(tmp_path, seed, tau_element_min=te, location="air", tau_housing_min=th, tau_chamber_min=tc,
                    program=StepProgram(soak_min=soak))
    r = fit_thermal_lag(c, EFFECTS, "air", bridge_gaps=True)
    if r.status == "ok":
        assert abs(z(r, "thermal_lag", te)) < 3 and abs(z(r, "thermal_lag_housing", th)) < 3, (case, r.parameters)
        assert r.fit["thermal_lag"]["bridge"]["u_min"] is not None
        assert any("gate" not in n and "bridged by a first-order approach" in n for n in r.notes)
    else:
        # refused with the number: an unresolved stage, the pair not separable, or a misfit
        assert r.status in ("unidentifiable", "unphysical_term", "model_mismatch"), r.status
        assert any(n.startswith("gate ") for n in r.notes)
    return r.status


@pytest.mark.slow   # 10-18 s; CI runs it with the slow tests (CI-29: the quick suite took 635 s of its 600)
def test_the_bridged_air_form_answers_a_stepped_campaign(tmp_path):
    """A stepped campaign of tests/independent_bench.py (Euler-integrated chamber, housing and
    element; the thermometer in the air; 30 min soaks read only at the visits): with the gaps bridged
    the lags come back within 3u (measured: element 7.18 +- 2.78 for 4 min, housing 19.21 +- 0.73 for 20)."""
    assert _bridged_case(tmp_path, 61, BRIDGED[1]) == "ok"


@pytest.mark.slow
def test_the_bridged_air_form_is_right_or_refused(tmp_path):
    """Eight stepped campaigns of the independent bench (element 2-20 min, housing 20-30 min, chamber
    5-10 min, soaks 20-30 min): every ok answer within 3u of the truth, every other one refused by a
    gate (measured: 4 ok, |z| <= 2.34; 4 refused: the element's stage not resolved, or the pair not
    separable)."""
    statuses = [_bridged_case(tmp_path, 60 + k, case) for k, case in enumerate(BRIDGED)]
    assert "ok" in statuses, statuses


# -- recovery of each mechanism --------------------------------------------------------------
@pytest.mark.parametrize("tau", [2.0, 20.0, 90.0])
def test_housing_thermometer_lag_recovered(tmp_path, tau):
    c, truth = campaign(tmp_path, 11, tau_element_min=tau, location="housing", tau_housing_min=TAU_HOUSING)
    r = fit_thermal_lag(c, EFFECTS, "housing")
    assert r.status == "ok", r.notes
    assert abs(z(r, "thermal_lag", tau)) < 3, r.parameters["thermal_lag"]
    assert r.fit["chi2_dof"] < 1.2
    assert max(abs(z(r, n, truth[n])) for n in truth if n in r.parameters and n != "thermal_lag") < 4.5


#: the air form's fit of a 2 min element stage behind the 30 min housing takes ~12 s on 2 shared cores
#: (the others 2-5 s): with the slow tests (the quick suite's 10-minute budget); 20 and 90 min stay quick
SLOW_AIR_FIT = pytest.mark.slow


@pytest.mark.parametrize("tau", [pytest.param(2.0, marks=SLOW_AIR_FIT), 20.0, 90.0])
def test_air_thermometer_two_stages_recovered(tmp_path, tau):
    """Two stages commute: the fit gives the pair, the longer reported as the housing's."""
    c, truth = campaign(tmp_path, 12, tau_element_min=tau, location="air", tau_housing_min=TAU_HOUSING)
    r = fit_thermal_lag(c, EFFECTS, "air")
    assert r.status == "ok", r.notes
    short, long_ = sorted((tau, TAU_HOUSING))
    assert abs(z(r, "thermal_lag", short)) < 3, r.parameters["thermal_lag"]
    assert abs(z(r, "thermal_lag_housing", long_)) < 3, r.parameters["thermal_lag_housing"]
    assert r.fit["thermal_lag"]["location"] == "air" and r.fit["chi2_dof"] < 1.2


def test_wrong_mechanism_is_flagged_by_chi2(tmp_path):
    """An air thermometer fitted as if it sat on the housing: one stage cannot follow two through
    the ramp's turns (chi2/dof ~9), and the gate says model_mismatch; the right form fits."""
    c, _ = campaign(tmp_path, 13, tau_element_min=20.0, location="air", tau_housing_min=TAU_HOUSING)
    wrong = fit_thermal_lag(c, EFFECTS, "housing")
    assert wrong.status == "model_mismatch" and wrong.fit["chi2_dof"] > 3, wrong.fit["chi2_dof"]
    # the rate form of the joint model (T_s - tau dT/dt) cannot follow a 20 min lag either
    rate = fit_joint(c, EFFECTS + ["thermal_lag"])
    assert rate.status != "ok" and rate.fit["chi2_dof"] > 3


@pytest.mark.slow          # 9 s: with the slow tests (the quick suite's 10-minute budget)
def test_housing_data_fitted_with_two_stages_drop_the_extra_stage(tmp_path):
    """The air form holds the housing form (a stage of zero): on housing data its second stage
    goes to the bottom of the search and the gate refuses it, naming the number."""
    c, _ = campaign(tmp_path, 14, tau_element_min=20.0, location="housing", tau_housing_min=TAU_HOUSING)
    r = fit_thermal_lag(c, EFFECTS, "air")
    assert abs(r.parameters["thermal_lag_housing"].value - 20.0) < 3 * r.parameters["thermal_lag_housing"].u
    assert r.parameters["thermal_lag"].value < 0.5
    assert r.status == "unphysical_term"
    assert any("thermal_lag = " in n and "outside [0.5, 300] min" in n for n in r.notes), r.notes


# -- time constants that are not answers ------------------------------------------------------
def test_no_lag_gives_a_refused_time_constant(tmp_path):
    """A thermometer on the element (no lag): the history form's tau runs below 0.5 min and is
    refused; forcing the joint model's rate form gives a tau near 0 (it was negative with status ok
    in issue 17): refused too."""
    c, _ = campaign(tmp_path, 15, tau_element_min=0.02, location="housing", tau_housing_min=TAU_HOUSING)
    r = fit_thermal_lag(c, EFFECTS, "housing")
    assert r.parameters["thermal_lag"].value < 0.5 and r.parameters["thermal_lag"].value > 0
    assert r.status == "unphysical_term"
    forced = fit_joint(c, EFFECTS + ["thermal_lag"])
    assert forced.status == "unphysical_term", (forced.parameters["thermal_lag"], forced.notes)
    assert any("thermal_lag = " in n for n in forced.notes)


def test_time_constant_gate():
    base = {f"K_{a}": ParameterValue(1.0, 1e-6, "g/V") for a in "xyz"}

    def failing(v, u=1.0, name="thermal_lag"):
        return [o for o in result_gates({**base, name: ParameterValue(v, u, "min")}, output_unit="V")
                if o.passed is False]

    assert failing(20.0) == [] and failing(0.5, 0.1) == [] and failing(300.0) == []
    for v in (-1.0, 0.1, 400.0):
        bad = failing(v, 2.0)
        assert [o.gate for o in bad] == ["time_constants"], v
        assert f"thermal_lag = {v:.4g} +- 2 min is outside [0.5, 300] min" in bad[0].reason
    # negative beyond 2u: the signs gate's refusal, not repeated
    assert [o.gate for o in failing(-12.0, 2.0)] == ["signs"]
    assert [o.gate for o in failing(1000.0, 5.0, "S_warmup_tau")] == ["time_constants"]
    # within the range but not measured: u above the value
    bad = failing(30.0, 155.0, "S_warmup_tau")
    assert [(o.gate, o.status) for o in bad] == [("time_constants_determined", "unidentifiable")]
    assert "S_warmup_tau = 30 +- 155 min" in bad[0].reason
    assert math.isclose(RampProgram().duration_s, 220 * 60.0)


def test_a_record_with_unlogged_soaks_does_not_give_an_answer(tmp_path):
    """A stepped campaign whose thermometer is read only at the visits (2 h soaks between blocks):
    the element's history through the soaks is unknown, and the estimate is biased (20 min came
    out near 7 min with chi2/dof ~1): the history gate refuses it, naming the gaps."""
    c, _ = campaign(tmp_path, 16, tau_element_min=20.0, location="housing", tau_housing_min=TAU_HOUSING,
                    program=StepProgram())
    r = fit_thermal_lag(c, EFFECTS, "housing")
    assert r.status == "unidentifiable"
    assert any(re.search(r"gate history failed .*gap\(s\) of up to 12\d min", n) for n in r.notes), r.notes


def test_a_play_of_the_elements_temperature_is_refused(tmp_path):
    """An outside probe: the element 10 min behind a housing thermometer, its temperature through a
    play of 1 degC (a hysteresis of every thermal term), ramps at 1 degC/min: tau 11.5-11.75 +- 0.07
    min (22-25 u) and K_x's tempco 4-6 u off, status ok 9 of 10. Here the play is the independent
    bench's backlash, sample by sample on the integrated element: the gate thermal_play measures it
    and refuses the lag; without the play the same campaign passes it."""
    from triadcal.estimation.thermal_lag_form import PLAY_Z_MAX

    c, _ = campaign(tmp_path, 2001, tau_element_min=10.0, location="housing", tau_housing_min=TAU_HOUSING,
                    element_play_C=1.0)
    r = fit_thermal_lag(c, EFFECTS, "housing")
    play = r.fit["thermal_play"]
    assert r.status == "model_mismatch", r.notes
    assert any(n.startswith("gate thermal_play failed") for n in r.notes), r.notes
    assert play["z"] > PLAY_Z_MAX and play["half_width_C"] == pytest.approx(1.0, abs=3 * play["sd_C"] + 0.1), play
    assert play["moves_u_per_C"]["thermal_lag"] > 10
    c0, _ = campaign(tmp_path, 2001, tau_element_min=10.0, location="housing", tau_housing_min=TAU_HOUSING)
    r0 = fit_thermal_lag(c0, EFFECTS, "housing")
    assert r0.status == "ok" and abs(r0.fit["thermal_play"]["z"]) <= PLAY_Z_MAX, r0.notes


def test_a_lag_on_ramps_of_one_rate_says_what_tau_holds():
    """By hand: visits on ramps of 1.0 +- 0.05 degC/min make the lag a delay at that rate (a play of r
    adds r/v, 1 min per degC); ramps of 1 and 2 degC/min, or a stepped campaign, no note."""
    from types import SimpleNamespace

    from triadcal.estimation.thermal_lag_form import one_rate_note

    rng = np.random.default_rng(0)
    one = SimpleNamespace(dTdt_C_per_min=np.r_[rng.uniform(0.95, 1.05, 40) * np.sign(rng.normal(size=40)),
                                               np.zeros(10)])
    note = one_rate_note(one, 10.0, 0.07, {"half_width_C": 0.05, "sd_C": 0.1})
    assert "one rate" in note and "1 min per degC" in note and "tau holds to about 0.2 min (2.8 u)" in note, note
    assert "bias hysteresis" in note, note          # an offset of the biases between branches reads as a lag too
    two = SimpleNamespace(dTdt_C_per_min=np.r_[np.full(20, 1.0), np.full(20, -2.0)])
    assert one_rate_note(two, 10.0, 0.07, None) is None
    assert one_rate_note(SimpleNamespace(dTdt_C_per_min=None), 10.0, 0.07, None) is None


# -- statistics (slow) ------------------------------------------------------------------------
@pytest.mark.slow
def test_coverage_of_the_time_constant(tmp_path):
    """20 campaigns at each of 2, 20 and 90 min (housing thermometer, ramp): the 2u interval holds
    the true tau as often as its 95.4 % says, within the 99.9 % binomial band of 60 draws.
    Measured 2026-11-25: 19/20, 19/20, 19/20 within 2u, 60/60 within 3u; SD of z 0.96, 0.85, 0.90.
    The gate thermal_play's z on these campaigns without a play: its SD within the 99.9 % band of
    a standard normal's over 60 draws (chi^2 with 60 dof)."""
    from scipy import stats

    zs, zp = [], []
    for tau in (2.0, 20.0, 90.0):
        for seed in range(20):
            c, _ = campaign(tmp_path, 1000 + seed, tau_element_min=tau, location="housing",
                            tau_housing_min=TAU_HOUSING)
            r = fit_thermal_lag(c, EFFECTS, "housing")
            assert r.status == "ok", (tau, seed, r.notes)
            zs.append(z(r, "thermal_lag", tau))
            zp.append(r.fit["thermal_play"]["z"])
    sd_lo, sd_hi = (math.sqrt(stats.chi2.ppf(q, len(zp)) / len(zp)) for q in (0.0005, 0.9995))
    assert sd_lo <= math.sqrt(np.mean(np.square(zp))) <= sd_hi, (np.round(zp, 2), sd_lo, sd_hi)
    zs = np.abs(np.array(zs))
    n, p = len(zs), stats.norm.cdf(2) - stats.norm.cdf(-2)
    lo, hi = stats.binom.ppf(0.0005, n, p), stats.binom.ppf(0.9995, n, p)
    assert lo <= np.sum(zs <= 2) <= hi, (np.sum(zs <= 2), lo, hi)
    assert np.sum(zs <= 3) >= n - 1


@pytest.mark.parametrize("location, tau", [("housing", 20.0), pytest.param("air", 2.0, marks=SLOW_AIR_FIT)])
def test_the_simulator_lags_over_the_history(location, tau):
    """`simulate_campaign(..., thermal_lag_location=...)`: the element lags the unit's housing over
    the whole history (the air form's first stage is the simulator's unit behind the chamber,
    20 min); the fit recovers both stages within 3u."""
    from triadcal.models.simulate import RampSchedule, preset_truth, simulate_campaign

    eff = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis")
    truth = preset_truth("a18-silicon", eff + ("thermal_lag",), thermal_lag=tau)
    c = simulate_campaign(truth, schedule=RampSchedule(program_C=(20.0, -40.0, 85.0, 20.0)), seed=3,
                          thermal_lag_location=location)
    r = fit_thermal_lag(c, eff, location)
    assert r.status == "ok", r.notes
    assert abs(z(r, "thermal_lag", tau)) < 3, r.parameters["thermal_lag"]
    if location == "air":
        assert abs(z(r, "thermal_lag_housing", 20.0)) < 3, r.parameters["thermal_lag_housing"]


def test_fit_command_takes_the_thermal_lag_form(tmp_path, capsys):
    """`triadcal fit --thermal-lag-form housing` is the history fit; combinations it does not do are
    refused by name."""
    import json

    from triadcal.cli import main

    text, _ = simulate_lag_campaign(np.random.default_rng(11), tau_element_min=20.0, location="housing",
                                    tau_housing_min=TAU_HOUSING)
    path = tmp_path / "lag.csv"
    path.write_text(text)
    out = tmp_path / "r.json"
    rc = main(["fit", str(path), "--effects", ",".join(EFFECTS), "--thermal-lag-form", "housing",
               "--json", str(out), "--quiet"])
    doc = json.loads(out.read_text())
    assert rc == 0 and doc["status"] == "ok"
    lag = doc["parameters"]["thermal_lag"]
    assert abs(lag["value"] - 20.0) < 3 * lag["u"] and lag["unit"] == "min"
    assert doc["fit"]["thermal_lag"]["location"] == "housing"
    capsys.readouterr()
    rc = main(["fit", str(path), "--effects", ",".join(EFFECTS), "--thermal-lag-form", "housing",
               "--thermal-order", "2", "--quiet"])
    assert rc == 1 and "--thermal-lag-form housing" in capsys.readouterr().err     # a refused input


@pytest.mark.slow   # 13 s; CI runs it with the slow tests (the quick suite's 10-minute budget)
def test_fit_command_bridges_the_gaps(tmp_path, capsys):
    """`triadcal fit --thermal-lag-form air --bridge-gaps` on a stepped campaign read at its visits:
    without the option the history gate refuses the record's gaps; with it the bridge is profiled
    and kept in fit.thermal_lag.bridge (min), not among the unit's parameters."""
    import json

    from triadcal.cli import main

    te, th, tc, soak = BRIDGED[1]
    text, _ = simulate_lag_campaign(np.random.default_rng(61), tau_element_min=te, location="air",
                                    tau_housing_min=th, tau_chamber_min=tc, program=StepProgram(soak_min=soak))
    path = tmp_path / "stepped.csv"
    path.write_text(text)
    plain, bridged = tmp_path / "plain.json", tmp_path / "bridged.json"
    base = ["fit", str(path), "--effects", ",".join(EFFECTS), "--thermal-lag-form", "air", "--quiet"]
    main(base + ["--json", str(plain)])
    main(base + ["--bridge-gaps", "--json", str(bridged)])
    capsys.readouterr()
    p, b = json.loads(plain.read_text()), json.loads(bridged.read_text())
    assert p["status"] == "unidentifiable" and p["fit"]["thermal_lag"]["bridge"] is None
    assert any("gate history failed" in n for n in p["notes"])
    assert b["status"] == "ok", b["notes"]
    blk = b["fit"]["thermal_lag"]["bridge"]
    assert blk["gaps"] == 8 and 0.1 <= blk["tau_min"] <= 300.0 and "thermal_lag_bridge" not in b["parameters"]
    assert abs(b["parameters"]["thermal_lag_housing"]["value"] - th) < 3 * b["parameters"]["thermal_lag_housing"]["u"]


def test_on_a_ramp_the_rate_form_is_right_or_refused_against_the_housing_form():
    """A ramp with the rate measured per visit (the least-squares slope of the reading over each window,
    as capture --ramp writes it): the gate ``lag_form`` compared nothing there ("straight legs make the
    rate form exact"), but a housing thermometer curves for tens of minutes after each turn. The element
    2 or 4 min behind a housing 20 min behind the air (tests/independent_bench.py, Euler-integrated),
    1 degC/min through 20 -> -40 -> 70 -> 20: the rate form said ok at 2 min with S_z -5.6 u, S_x_tempco
    -5.3 u (seeds 1, 3 of 3; an outside probe's own simulator: S_z_tempco -8 to -12 u in 9 of 10). Now
    refused naming the housing form, which is ok and right on the same data. The element at the rate
    form itself (H - tau dH/dt, same bench) at 4 min: the rate form beats the housing form by
    chi^2 62-214 (12 seeds) and stands, right. The price, at 2 min of rate-form truth: the forms differ
    by 2.4-3.3 u and the data prefer the rate form by chi^2 1-29, below 9 in 6 of 12 seeds: refused
    (a lag is a first-order stage physically; the rate form is its approximation)."""
    effects = ["angle_tempco", "scale_tempco", "bias_tempco", "thermal_lag"]
    for tau in (2.0, 4.0):
        for seed in range(1, 4):
            text, truth = simulate_lag_campaign(np.random.default_rng(seed), tau_element_min=tau, location="housing",
                                                tau_housing_min=20.0, measured_rate=True)
            c = parse_bench_csv(text, f"ramp_{seed}.csv")
            assert c.dTdt_C_per_min is not None
            rate = api_fit(c, effects=effects)
            failed = [o for o in rate.extra["gates"]["outcomes"] if o["gate"] == "lag_form" and o["passed"] is False]
            assert rate.status == "model_mismatch" and failed, (tau, seed, rate.status)
            assert "--thermal-lag-form housing" in failed[0]["reason"], failed[0]["reason"]
            housing = api_fit(c, effects=effects, thermal_lag_form="housing")
            assert housing.status == "ok", housing.notes
            assert max(abs(z(housing, n, truth[n])) for n in truth if n in housing.parameters) < 4.5
    for seed in range(1, 4):
        text, truth = simulate_lag_campaign(np.random.default_rng(seed), tau_element_min=4.0, location="housing",
                                            tau_housing_min=20.0, measured_rate=True, element_rate_form=True)
        rate = api_fit(parse_bench_csv(text, f"rate_{seed}.csv"), effects=effects)
        gate = [o for o in rate.extra["gates"]["outcomes"] if o["gate"] == "lag_form"][-1]
        assert rate.status == "ok" and gate["passed"] is True, (seed, rate.status, gate)
        assert max(abs(z(rate, n, truth[n])) for n in truth if n in rate.parameters) < 4.5
