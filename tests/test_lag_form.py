"""The `lag_form` answer gate (triadcal/estimation/lag_validity.py): the rate form of the thermal
lag, T - tau dT/dt, fitted to a stepped campaign whose thermometer approaches each setpoint
exponentially, is refused when its first-order bias exceeds u(tau).

The bias formula is checked against an ODE solution (scipy); the gate on campaigns of
tests/independent_bench.py, whose heat equations are integrated there (no project model code)."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from independent_bench import StepProgram, simulate_lag_campaign
from triadcal.estimation.joint import fit_joint
from triadcal.estimation.lag_validity import approach_time_constant
from triadcal.io.bench_csv import parse_bench_csv
from triadcal.models.effects import DEFAULT_EFFECTS
from triadcal.models.effects.thermal_lag import rate_form_time_constant


def test_rate_form_time_constant_against_the_heat_equation():
    """dT_e/dt = (T - T_e)/tau with T = T_inf + A exp(-t/tau_a), integrated: once the element's own
    transient is gone, T_e = T - tau_r dT/dt holds with tau_r = tau tau_a / (tau_a - tau), not tau."""
    tau, tau_a, A = 7.0, 20.0, 30.0
    sol = solve_ivp(lambda t, y: [(A * np.exp(-t / tau_a) - y[0]) / tau], (0.0, 200.0), [A],
                    t_eval=np.linspace(120.0, 160.0, 5), rtol=1e-11, atol=1e-13)
    T = A * np.exp(-sol.t / tau_a)
    dT = -T / tau_a
    tau_r = (T - sol.y[0]) / dT                       # the rate form's tau that reproduces T_e
    np.testing.assert_allclose(tau_r, rate_form_time_constant(tau, tau_a), rtol=1e-4)
    assert rate_form_time_constant(tau, tau_a) == pytest.approx(140.0 / 13.0)


def _campaign(seed, tau_element_min, soak_min=60.0):
    text, truth = simulate_lag_campaign(np.random.default_rng(seed), program=StepProgram(soak_min=soak_min),
                                        tau_element_min=tau_element_min, location="housing", tau_housing_min=20.0)
    return parse_bench_csv(text), truth


def _gate(r):
    return next(o for o in r.extra["gates"]["outcomes"] if o["gate"] == "lag_form")


@pytest.mark.parametrize("seed", [1, 2])
def test_a_lag_the_rate_form_biases_is_refused_and_the_true_lag_said(seed):
    """7 min behind a housing thermometer that settles with 20 min (1 h soaks): the rate form read
    10.5 +- 0.3 min with status ok (an outside probe). Now refused; the gate's estimate of the
    approach (the housing's, ~20 min) puts the physical lag within 15 % of 7."""
    c, truth = _campaign(seed, 7.0)
    r = fit_joint(c, effects=tuple(DEFAULT_EFFECTS) + ("thermal_lag",))
    lag = r["thermal_lag"]
    assert lag.value - truth["thermal_lag"] > 3 * lag.u                  # biased, as the formula says
    g = _gate(r)
    assert r.status == "model_mismatch" and g["passed"] is False, g
    a = approach_time_constant(c)
    implied = lag.value * a["tau_min"] / (a["tau_min"] + lag.value)
    assert implied == pytest.approx(truth["thermal_lag"], rel=0.15)
    assert "--thermal-lag-form" in g["reason"]


def test_a_short_lag_passes():
    """1 min behind the same thermometer: the rate form's bias, ~0.05 min, is within its u."""
    c, truth = _campaign(3, 1.0)
    r = fit_joint(c, effects=tuple(DEFAULT_EFFECTS) + ("thermal_lag",))
    assert _gate(r)["passed"] is True, _gate(r)
    assert r.status == "ok", [o["reason"] for o in r.extra["gates"]["outcomes"] if o["passed"] is False]


def test_the_rate_form_measures_a_play_of_the_elements_temperature():
    """The rate form takes up a play of the element's temperature as the history forms do (an outside
    probe's 1 degC play made a 10 min lag 11.6 min with status ok): on the independent bench's ramp
    (its backlash written sample by sample, the element 1 min behind) the gate thermal_play measures
    it; without the play the same campaign passes."""
    from independent_bench import RampProgram

    from triadcal.estimation.thermal_lag_form import PLAY_Z_MAX

    out = {}
    for play in (0.0, 1.0):
        text, _ = simulate_lag_campaign(np.random.default_rng(3000), program=RampProgram(), tau_element_min=1.0,
                                        location="housing", tau_housing_min=20.0, element_play_C=play)
        out[play] = fit_joint(parse_bench_csv(text), effects=tuple(DEFAULT_EFFECTS) + ("thermal_lag",))
    gate = next(o for o in out[1.0].extra["gates"]["outcomes"] if o["gate"] == "thermal_play")
    assert out[1.0].status == "model_mismatch" and gate["passed"] is False, gate
    assert out[1.0].fit["thermal_play"]["half_width_C"] == pytest.approx(1.0, abs=0.2)
    assert out[0.0].status == "ok" and abs(out[0.0].fit["thermal_play"]["z"]) < PLAY_Z_MAX
