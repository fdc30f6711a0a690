"""Continuous-ramp calibration (issue 20, item 2): the ramp simulator (the chamber's piecewise-linear
program through the two-lag thermal environment), the fit of a ramp campaign with thermal_lag,
the planner's ramp plans (predicted U against the U of fits of simulated ramps) and the CLI."""
from __future__ import annotations

import json

import numpy as np
import pytest

from triadcal.api import fit, simulate
from triadcal.cli import main
from triadcal.errors import InputError
from triadcal.models.effects import DEFAULT_EFFECTS
from triadcal.models.simulate import RampSchedule, ramp_history
from triadcal.models.thermal_environment import ramp_program, ramp_sequence, two_lag_step
from triadcal.planning import design, predict
from triadcal.planning.ramp import RampPlan, candidate_programs, load_plan, ramp_effects

EFFECTS = ramp_effects(DEFAULT_EFFECTS)          # the defaults plus thermal_lag (preset: 4 min)
TAU_C, TAU_U = 600.0, 1200.0                    # the simulator's chamber and unit time constants


def _ode(knot_t, knot_v, t_end, dt=2.0):
    """dc/dt = (r - c)/tau_c, du/dt = (c - u)/tau_u by classical RK4 (the check on the closed form)."""
    def f(t, y):
        r = np.interp(t, knot_t, knot_v)
        return np.array([(r - y[0]) / TAU_C, (y[0] - y[1]) / TAU_U])

    y, t, out_t, out = np.array([knot_v[0], knot_v[0]], float), 0.0, [0.0], [[knot_v[0], knot_v[0]]]
    while t < t_end - 1e-9:
        k1 = f(t, y)
        k2 = f(t + dt / 2, y + dt / 2 * k1)
        k3 = f(t + dt / 2, y + dt / 2 * k2)
        k4 = f(t + dt, y + dt * k3)
        y, t = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), t + dt
        out_t.append(t)
        out.append(y.copy())
    return np.array(out_t), np.array(out)


def test_ramp_closed_form_equals_the_ode_and_the_step_form():
    s = RampSchedule(program_C=(20.0, -40.0, 85.0, 20.0), rate_C_per_min=2.0, hold_s=600.0)
    kt, kv = s.knots()
    t, y = _ode(kt, kv, kt[-1] + 3000.0)
    c, u, rate = ramp_sequence(t, kt, kv, TAU_C, TAU_U)
    assert np.max(np.abs(c - y[:, 0])) < 1e-6
    assert np.max(np.abs(u - y[:, 1])) < 1e-6
    assert np.allclose(rate, (c - u) / TAU_U)
    # a zero slope is the step response
    x = np.linspace(0, 5000, 11)
    from triadcal.models.thermal_environment import two_lag_ramp
    a, b, r = two_lag_ramp(x, 70.0, 0.0, 30.0, 25.0, TAU_C, TAU_U)
    a2, b2, r2 = two_lag_step(x, 70.0, 30.0, 25.0, TAU_C, TAU_U)
    assert np.allclose(a, a2) and np.allclose(b, b2) and np.allclose(r, r2)


def test_unit_follows_the_program_within_the_steady_state_error():
    # Steady state by hand: on a ramp r = r0 + s t the chamber's first-order lag settles to
    # c = r - s tau_c (d/dt of the error e = r - c is s - e/tau_c, so e -> s tau_c); the unit lags
    # the chamber, itself a ramp of slope s, by s tau_u; so u = r - s (tau_c + tau_u). At 1 degC/min
    # (s = 1/60 degC/s) that is 1800 s / 60 = 30 degC. The error of the two-lag system to a change of
    # slope rises monotonically (two real poles, no overshoot), so |u - r| <= s (tau_c + tau_u)
    # everywhere on a program that starts at rest at its first temperature.
    s_rate = 1.0 / 60.0
    lag = s_rate * (TAU_C + TAU_U)
    assert lag == pytest.approx(30.0)
    long = RampSchedule(program_C=(20.0, 200.0), rate_C_per_min=1.0)      # 10800 s = 9 tau_u
    kt, kv = long.knots()
    _, u_end, rate_end = ramp_history(long, np.array([kt[-1] - 1e-6]))
    assert u_end[0] == pytest.approx(200.0 - lag, abs=0.02)
    assert rate_end[0] == pytest.approx(s_rate, rel=1e-3)

    sched = RampSchedule()                       # 20 -> -40 -> 85 -> 20 degC at 1 degC/min, tau 30 s
    kt, kv = sched.knots()
    t = np.linspace(0, kt[-1], 4001)
    _, u, _ = ramp_history(sched, t)
    assert np.max(np.abs(u - ramp_program(t, kt, kv))) <= lag + 1e-9

    truth, c = simulate(None, effects=EFFECTS, schedule=sched, seed=3)
    assert c.n_visits == int(sched.duration_s // (sched.move_s + sched.tau_s)) == 300
    # the readings: the window's mean unit temperature + self-heating + noise (0.01 degC); against the
    # program at the window's mid time, the window adds at most s tau / 2 (0.25 degC)
    dev = c.t - np.array(sched.self_heating_C)[None, :] - ramp_program(c.time_s, kt, kv)[:, None]
    assert np.max(np.abs(dev)) <= lag + s_rate * sched.tau_s / 2 + 5 * 0.01
    # the unit sees less than the program's range: it trails the turns
    assert -30.0 < c.t.min() < -20.0 and 60.0 < c.t.max() < 75.0
    # directions: the unit's own (heating while its temperature rises); the rate the fit takes is the
    # campaign's dTdt_C_per_min, the window's exact mean rate (the rate at its middle within the
    # curvature of a 30 s window); the central differences of the readings follow the true rate too
    _, _, true_rate = ramp_history(sched, c.time_s)
    heat = c.direction == "heating"
    assert np.all(true_rate[heat] > 0) and np.all(true_rate[c.direction == "cooling"] < 0)
    assert set(c.direction) == {"heating", "cooling"}
    _, u0, _ = ramp_history(sched, c.time_s - sched.tau_s / 2)
    _, u1, _ = ramp_history(sched, c.time_s + sched.tau_s / 2)
    np.testing.assert_allclose(c.dTdt_C_per_min, (u1 - u0) / sched.tau_s * 60.0, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(c.temperature_rate(), np.repeat(c.dTdt_C_per_min[:, None] / 60.0, 3, axis=1))
    assert np.max(np.abs(c.temperature_rate()[:, 0] - true_rate)) < 1e-3 * s_rate
    est = c.central_difference_rate().mean(axis=1)
    inner = np.abs(true_rate) > 0.3 * s_rate
    assert np.median(np.abs(est[inner] - true_rate[inner])) < 0.02 * s_rate
    assert c.metadata["ramp"].startswith("20:-40:85:20 degC at 1 degC/min")


def test_fit_of_a_ramp_campaign_recovers_the_truth():
    truth, c = simulate(None, effects=EFFECTS, schedule=RampSchedule(), seed=0)
    r = fit(c, effects=EFFECTS)
    assert r.status == "ok"
    assert 0.85 < r.fit["chi2_dof"] < 1.15               # 867 dof: SD of chi2/dof is 0.048
    assert set(truth.parameters) <= set(r.parameters)    # nothing held (+ tilt_delta, tilt_beta reported)
    for n, v in truth.parameters.items():
        assert abs(r.parameters[n].value - v) < 3 * r.parameters[n].u, n
    assert r.parameters["thermal_lag"].u < 0.05          # minutes, of the true 4


PLAN = RampPlan(program_C=(20.0, -40.0, 85.0), rate_C_per_min=1.0, tau_s=120.0)   # 3.1 h, 79 visits


def test_predicted_U_of_a_ramp_plan_matches_the_fits():
    d = design(PLAN, EFFECTS)
    assert not d.problems
    pred = predict(d, 3e-9)
    for seed in range(3):
        _, c = simulate(None, effects=EFFECTS, schedule=PLAN.schedule(), plan=PLAN.visit_positions(), seed=seed)
        r = fit(c, effects=EFFECTS)
        for n, U in zip(d.names, pred["U"]):
            assert 2 * r.parameters[n].u == pytest.approx(U, rel=0.15), (seed, n)
    assert PLAN.chamber_hours() == pytest.approx((60 + 125) / 60)
    assert PLAN.n_visits == 79


def test_candidate_programs():
    progs = dict(candidate_programs(-40, 70))
    assert progs["down-up, 3 legs"] == (20.0, -40.0, 70.0, 20.0)
    assert progs["up-down, 4 legs"] == (20.0, 70.0, -40.0, 70.0, -40.0)
    assert len(progs) == 8
    with pytest.raises(InputError):
        candidate_programs(10, 10)


def test_cli_simulate_ramp_and_plan_ramp(tmp_path):
    csv = tmp_path / "ramp.csv"
    assert main(["simulate", "--ramp", "20:-40:85:20", "--ramp-rate", "1degC/min", "-o", str(csv),
                 "--effects", ",".join(EFFECTS), "--seed", "2", "--quiet"]) == 0
    assert "# ramp = 20:-40:85:20 degC at 1 degC/min" in csv.read_text()
    out = tmp_path / "r.json"
    assert main(["fit", str(csv), "--method", "joint", "--effects", ",".join(EFFECTS), "--json", str(out),
                 "--quiet"]) == 0
    assert "thermal_lag" in json.loads(out.read_text())["parameters"]
    assert main(["simulate", "--ramp", "20:abc", "-o", str(tmp_path / "x.csv"), "--quiet"]) == 1

    plan, pred = tmp_path / "plan.json", tmp_path / "pred.json"
    assert main(["plan", "--ramp", "--target", "Ca:U<=5arcsec, Ca_tempco:U<=0.1arcsec/degC, K:U<=20ppm",
                 "--range", "-40:85", "-o", str(plan), "--json", str(pred), "--quiet"]) == 0
    doc, p = json.loads(pred.read_text()), load_plan(plan)
    assert isinstance(p, RampPlan) and doc["plan"]["kind"] == "ramp"
    assert doc["chamber_hours"] == pytest.approx(p.schedule().duration_s / 3600.0)
    assert "thermal_lag" in doc["assumptions"]["effects"]
    assert all(t["met"] for t in doc["target"].values())
    csv2 = tmp_path / "planned.csv"
    assert main(["simulate", "--plan", str(plan), "-o", str(csv2), "--effects", ",".join(EFFECTS), "--quiet"]) == 0
    assert len([ln for ln in csv2.read_text().splitlines() if ln.startswith("SN-")]) == p.n_visits


def _family(name: str) -> str:
    """Families of at least 1500 estimates over 500 seeds (SE of a 0.95 coverage 0.0056)."""
    if name.startswith("Ca_"):
        return "Ca" + name[5:]                        # Ca, Ca_tempco, Ca_hysteresis
    if name.endswith("_tempco"):
        return "K, S tempcos"
    if name.startswith(("tilt_", "thermal_lag")):
        return "tilt, thermal_lag"
    return name[0]                                     # K, S


@pytest.mark.slow
def test_ramp_prediction_and_coverage_over_500_seeds():
    d = design(PLAN, EFFECTS)
    pred = dict(zip(d.names, predict(d, 3e-9)["U"]))
    from triadcal.models.simulate import preset_truth

    truth = preset_truth("ak18-quartz", EFFECTS).parameters
    hits: dict = {}
    worst = 0.0
    for seed in range(500):
        _, c = simulate(None, effects=EFFECTS, schedule=PLAN.schedule(), plan=PLAN.visit_positions(), seed=seed)
        r = fit(c, effects=EFFECTS)
        for n in pred:
            p = r.parameters[n]
            worst = max(worst, abs(2 * p.u / pred[n] - 1))
            hits.setdefault(_family(n), []).append(abs(p.value - truth[n]) <= 2 * p.u)
    print(f"worst |U_fit / U_pred - 1| = {worst:.4f}; coverage " +
          ", ".join(f"{f} {np.mean(h):.3f} ({len(h)})" for f, h in hits.items()))
    assert worst < 0.15
    assert set(hits) == {"Ca", "Ca_tempco", "Ca_hysteresis", "K", "S", "K, S tempcos", "tilt, thermal_lag"}
    for fam, h in hits.items():
        assert 0.92 <= np.mean(h) <= 0.98, (fam, np.mean(h), len(h))
