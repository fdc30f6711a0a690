"""A one-pose chamber cycle (issue 17, item 6): the operators by hand, the forms recovered on
cycles made another way (an ODE solver for the lag, an explicit relay loop for the play), and
the real recording of the shared data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from triadcal.cli import main
from triadcal.errors import InputError
from triadcal.estimation.thermal_cycle import thermal_cycle
from triadcal.models.thermal_history import first_order_lag, play_operator, thermometer_lead

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / "examples" / "data" / "tofupilot_imu_raw_data.csv"


def test_lag_of_a_ramp_by_hand():
    """On a ramp of slope s the element settles to T - s tau (the ramp's steady-state error)."""
    t = np.arange(0, 3600.0, 0.5)
    T = 20.0 + (3.0 / 60.0) * t
    y = first_order_lag(t, T, 300.0)
    # after 12 time constants the start transient (s tau e^-12 = 9e-5 degC) is gone to 1e-4
    assert y[-1] == pytest.approx(T[-1] - (3.0 / 60.0) * 300.0, abs=1e-4)
    assert first_order_lag(t, T, 0.0) is not T and np.array_equal(first_order_lag(t, T, 0.0), T)


def test_a_thermometer_lead_undoes_a_lag_by_hand():
    """A thermometer lagging by tau on a ramp of slope s reads T_e - s tau; the lead adds s tau back
    (the rate over 2 min of a straight line is exact), and undoes the lag once its transient is gone."""
    t = np.arange(0, 3600.0, 0.5)
    s = 3.0 / 60.0
    Te = 20.0 + s * t
    reading = Te - s * 300.0
    assert np.allclose(thermometer_lead(t, reading, 300.0), Te, atol=1e-9)
    lagged = first_order_lag(t, Te, 300.0)
    assert np.allclose(thermometer_lead(t, lagged, 300.0)[-2000:], Te[-2000:], atol=1e-3)
    assert np.array_equal(thermometer_lead(t, reading, 0.0), reading)


def test_play_of_a_triangle_by_hand():
    """Rising after the band is crossed: y = x - r; falling: y = x + r; inside the band y holds."""
    x = np.concatenate([np.linspace(0, 10, 101), np.linspace(10, 0, 101)[1:]])
    y = play_operator(x, 2.0, start=0.0)
    assert np.allclose(y[30:101], x[30:101] - 2.0)          # rising past 2: trails by r
    assert np.allclose(y[101:141], 8.0)                     # turned at 10: holds until x < 6
    assert np.allclose(y[145:], x[145:] + 2.0)              # falling: leads by r


def _cycle(tmp_path, output, name, noise=0.003, seed=0, reading=None, two_rates=False):
    """A chamber cycle like the real one: 50 -> -18 (-2.7 degC/min) -> 74 (+3.2) -> 36 degC, 2 Hz
    (``two_rates``: 50 -> -10 (-1.2) -> 100 (+2.4) -> 37.5 degC (-1.0), 1 Hz); ``output(t, T)`` gives
    the true output; white noise added; the thermometer reads ``reading(t, T)`` (default T);
    tab-separated, time in us."""
    if two_rates:
        t = np.arange(0.0, 12000.0, 1.0)
        T = np.interp(t, [0.0, 3000.0, 5750.0, 12000.0], [50.0, -10.0, 100.0, 37.5])
    else:
        t = np.arange(0.0, 4200.0, 0.5)
        T = np.interp(t, [0.0, 1500.0, 3220.0, 4200.0], [50.0, -17.5, 74.0, 36.0])
    y = output(t, T) + np.random.default_rng(seed).normal(0.0, noise, len(t))
    Tr = T if reading is None else reading(t, T)
    lines = ["timestamp\ttemp\tacc"] + [f"{int(1e6 * a) + 123456789}\t{b:.5f}\t{c:.6f}" for a, b, c in zip(t, Tr, y)]
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def _run(p):
    return thermal_cycle(p, ["acc"], time_column="timestamp", temperature_column="temp", time_unit="us").axes[0]


def _relay(Te):
    """A relay written out here: +1 after a move of the element of 0.05 degC down, -1 after one up,
    held in between (the sign of its last move beyond 0.05 degC)."""
    b, ref, state = np.empty_like(Te), Te[0], 1.0
    for k, x in enumerate(Te):
        if x < ref - 0.05:
            state, ref = 1.0, x
        elif x > ref + 0.05:
            state, ref = -1.0, x
        ref = min(ref, x) if state == 1.0 else max(ref, x)
        b[k] = state
    return b


def _ode_lag(tau):
    """The output of an element lagging the sensor by ``tau`` (s), solved by scipy's ODE solver."""
    def out(t, T):
        Tf = lambda s: np.interp(s, t, T)  # noqa: E731
        sol = solve_ivp(lambda s, y: (Tf(s) - y) / tau, (t[0], t[-1]), [T[0]], t_eval=t, rtol=1e-9, atol=1e-9,
                        max_step=5.0)
        return -9.6 + 0.004 * (sol.y[0] - 20.0)
    return out


def test_a_lag_made_by_an_ode_solver_is_named_with_its_time_constant(tmp_path):
    tau = 240.0
    a = _run(_cycle(tmp_path, _ode_lag(tau), "lag.csv"))
    assert a.best in ("lag", "lag_quadratic"), [(f.name, f.cv_rms) for f in a.forms]
    assert a.form(a.best).parameter["tau_min"] == pytest.approx(tau / 60.0, rel=0.15)
    assert a.form(a.best).cv_rms < 1.3 * a.noise_floor
    assert abs(a.form(a.best).branch_gap) < 0.1 * abs(a.branch_gap)


def test_a_lag_and_a_relay_hysteresis_on_a_quadratic_tempco_are_named_together(tmp_path):
    """An outside probe: a 4 min lag with an offset hysteresis (h 60 ug) on a quadratic tempco
    (0.3 ug/degC2) was lag_quadratic, tau 19 % long, the hysteresis lost, "explained" at 1.7 floors
    (no form held the three). lag_quadratic_hysteresis does: the element by an ODE solver, its relay
    written out here (the sign of its last move beyond 0.05 degC, held), on a quadratic: named, tau
    and h within 15 %, at the floor."""
    tau, h = 240.0, 0.003

    def out(t, T):
        Te = _ode_element(t, T, tau)
        return 0.1 + 0.002 * (Te - 20.0) + 3e-5 * (Te - 20.0) ** 2 + h * _relay(Te)

    a = _run(_cycle(tmp_path, out, "lagquadhyst.csv", noise=0.001))
    assert a.best == "lag_quadratic_hysteresis", [(f.name, f.cv_rms / a.noise_floor) for f in a.forms]
    f = a.form(a.best)
    assert f.parameter["tau_min"] == pytest.approx(tau / 60.0, rel=0.15) and f.coefficients[3] == pytest.approx(h, rel=0.15)
    assert f.cv_rms < 1.3 * a.noise_floor


def test_a_lag_between_the_grid_points_is_found_at_its_own_time_constant(tmp_path):
    """An outside probe: a cycle made with tau = 10.6 min (between the grid's 9.8 and 11.5) was fitted
    at 9.8 min, its held-out RMS 3.3 times the noise floor, and called unexplained. Now the time
    constant is refined between the grid points: the same ODE-made lag, named, at the noise floor."""
    tau = 636.0
    a = _run(_cycle(tmp_path, _ode_lag(tau), "lag10.csv"))
    assert a.best in ("lag", "lag_quadratic"), [(f.name, f.cv_rms) for f in a.forms]
    assert a.form(a.best).parameter["tau_min"] == pytest.approx(tau / 60.0, rel=0.02)
    assert a.form(a.best).cv_rms < 1.3 * a.noise_floor


def test_a_relay_hysteresis_on_a_quadratic_tempco_is_named(tmp_path):
    """The branch offset +-h switches where the temperature turns (a relay written out here,
    not the play operator): quadratic_hysteresis or quadratic_play, never a lag or a polynomial."""
    def out(t, T):
        rate = np.gradient(T, t)
        b = np.where(rate < 0, 1.0, -1.0)
        return 0.1 + 0.002 * (T - 20.0) - 2e-5 * (T - 20.0) ** 2 + 0.02 * b

    a = _run(_cycle(tmp_path, out, "hyst.csv"))
    assert a.best in ("quadratic_hysteresis", "quadratic_play"), [(f.name, f.cv_rms) for f in a.forms]
    assert a.form(a.best).cv_rms < 2.0 * a.noise_floor
    assert a.branch_gap == pytest.approx(0.04, abs=0.005)            # cooling - heating = 2 h


def _backlash(T, r, y0):
    """A mechanical backlash written out sample by sample (not the play operator): the output
    follows the input only once it pushes against one side of a gap 2 r wide."""
    y, out = y0, []
    for x in T:
        if x - y > r:
            y = x - r
        elif y - x > r:
            y = x + r
        out.append(y)
    return np.array(out)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_play_that_starts_on_its_heating_branch_is_a_play_not_a_lag(tmp_path, seed):
    """An outside probe: a play of 5 degC whose state before the record is that of a chamber that had
    heated up to the first temperature (y0 = T0 - r) was named a lag of 1.7 min, "explained", 20 of
    20; the play's start was held at the middle of its band. It is profiled now, as fit does."""
    def out(t, T):
        return 0.1 + 0.002 * (_backlash(T, 5.0, T[0] - 5.0) - 20.0)

    a = _run(_cycle(tmp_path, out, f"play_heat{seed}.csv", seed=seed))
    assert a.best in ("play", "play_quadratic"), [(f.name, f.cv_rms, f.parameter) for f in a.forms]
    par = a.form(a.best).parameter
    assert par["start"] == "heating" and par["half_width_C"] == pytest.approx(5.0, abs=0.3), par
    assert a.form(a.best).cv_rms < 1.5 * a.noise_floor


def test_a_cycle_of_one_rate_says_what_it_cannot_tell_and_one_of_two_rates_does_not(tmp_path):
    """An outside probe: on the README's cycle (2.7 and 3.2 degC/min) a lag of 4 min with a play of
    3 degC was named a lag of 5.1-5.5 min and a thermometer lagging the element an offset hysteresis,
    "explained", 10 of 10 each: at one rate a delay, a play and an offset give nearly the same
    branches. The named form now carries that caveat; a cycle with legs at 1 and 4 degC/min none."""
    from triadcal.estimation.thermal_cycle import rate_caveat

    lag = _run(_cycle(tmp_path, _ode_lag(240.0), "lag_one_rate.csv"))
    assert lag.best.startswith("lag"), lag.best
    lo, hi = (float(x) for x in lag.caveat.split("the ramps run at ")[1].split(" degC/min")[0].split("-"))
    assert 2.0 < lo < hi < 3.5 and hi / lo < 1.5, lag.caveat                  # the cycle's 2.7 and 3.2 degC/min
    assert "at one rate" in lag.caveat and "a leg at another rate" in lag.caveat
    assert lag.to_dict()["caveat"] == lag.caveat
    t = np.arange(0.0, 12000.0, 1.0)
    T = np.interp(t, [0.0, 3000.0, 5750.0, 12000.0], [50.0, -10.0, 100.0, 37.5])   # -1.2, +2.4, -1.0 degC/min
    from triadcal.estimation.thermal_cycle import branch_of

    assert rate_caveat(t, T, branch_of(t, T), "lag") is None
    assert rate_caveat(t, T, branch_of(t, T), "quadratic") is None


def _ode_element(t, T, tau):
    """The element's temperature lagging ``T`` by ``tau`` (s), by scipy's ODE solver."""
    Tf = lambda s: np.interp(s, t, T)  # noqa: E731
    return solve_ivp(lambda s, y: (Tf(s) - y) / tau, (t[0], t[-1]), [T[0]], t_eval=t, rtol=1e-9, atol=1e-9,
                     max_step=5.0).y[0]


def test_a_lag_and_a_relay_hysteresis_at_once_are_named_together(tmp_path):
    """An outside probe: a 5 min lag plus an offset hysteresis of 3 mm/s2 was named a lag alone,
    "explained", tau 24 % long (the branch gap taken up by the lag). Here the element by an ODE
    solver, its branch by a relay written out (the sign of its last move beyond 0.05 degC, held):
    lag_hysteresis, tau within 15 %, the branch gap closed."""
    tau, h = 300.0, 0.003

    def out(t, T):
        Te = _ode_element(t, T, tau)
        return 0.1 + 0.002 * (Te - 20.0) + h * _relay(Te)

    a = _run(_cycle(tmp_path, out, "laghyst.csv"))
    assert a.best == "lag_hysteresis", [(f.name, f.cv_rms / a.noise_floor) for f in a.forms]
    assert a.form(a.best).parameter["tau_min"] == pytest.approx(tau / 60.0, rel=0.15)
    assert a.form(a.best).coefficients[2] == pytest.approx(h, rel=0.15)
    assert a.form(a.best).cv_rms < 1.3 * a.noise_floor
    assert abs(a.form(a.best).branch_gap) < 0.1 * abs(a.branch_gap)


@pytest.mark.parametrize("two_rates", [False, True])
def test_a_thermometer_behind_the_element_is_named_so(tmp_path, two_rates):
    """An outside probe: a thermometer lagging the element by 2 min (the output linear in the element's
    temperature) was named an offset hysteresis, "explained", 10 of 10 on the README's cycle, and at
    2.1 times the floor on legs of two rates; the vocabulary had no such form. Here the reading by
    scipy's ODE solver behind the programme (the element's temperature)."""
    tau = 120.0
    a = _run(_cycle(tmp_path, lambda t, T: 0.1 + 0.002 * (T - 20.0), f"thermo{two_rates}.csv",
                    reading=lambda t, T: _ode_element(t, T, tau), two_rates=two_rates))
    assert a.best == "thermometer_lag", [(f.name, round(f.cv_rms / a.noise_floor, 2)) for f in a.forms]
    assert a.form(a.best).parameter["tau_min"] == pytest.approx(tau / 60.0, rel=0.1)
    assert a.form(a.best).cv_rms < 1.2 * a.noise_floor
    if two_rates:                                       # legs of 1.2, 2.4 and 1.0 degC/min: nothing to caution
        assert a.caveat is None, a.caveat


@pytest.mark.parametrize("two_rates", [False, True])
def test_a_lag_with_a_play_is_named_with_both(tmp_path, two_rates):
    """An outside probe: an element lagging by 4 min whose temperature also has a play of 3 degC was
    named a lag of 5.1-5.5 min or a lag with an offset hysteresis, "explained" (and on legs of 1.2 and
    2.4 degC/min a lag with a hysteresis, tau 5.5 min, 1.09 times the floor). Here the element by
    scipy's ODE solver, its play by the backlash written out above: lag_play, tau and r within 15 %."""
    tau, r = 240.0, 3.0

    def out(t, T):
        Te = _ode_element(t, T, tau)
        return -0.2 + 0.002 * (_backlash(Te, r, Te[0]) - 20.0)

    a = _run(_cycle(tmp_path, out, f"lagplay{two_rates}.csv", two_rates=two_rates))
    assert a.best == "lag_play", [(f.name, round(f.cv_rms / a.noise_floor, 2)) for f in a.forms]
    par = a.form(a.best).parameter
    assert par["tau_min"] == pytest.approx(tau / 60.0, rel=0.15) and par["half_width_C"] == pytest.approx(r, rel=0.15)
    assert a.form(a.best).cv_rms < 1.2 * a.noise_floor


def test_a_lag_shorter_than_half_a_minute_is_a_lag(tmp_path):
    """An outside probe: tau = 18 s was named a play or an offset hysteresis in 5 runs of 5 (the
    search started at 30 s)."""
    tau = 18.0
    a = _run(_cycle(tmp_path, lambda t, T: -9.6 + 0.02 * (_ode_element(t, T, tau) - 20.0), "short.csv"))
    assert a.best == "lag", [(f.name, f.cv_rms / a.noise_floor) for f in a.forms]
    assert a.form("lag").parameter["tau_min"] == pytest.approx(tau / 60.0, rel=0.15)


def test_a_duplicated_column_kelvin_and_a_nan_reference_are_refused(tmp_path):
    p = _cycle(tmp_path, lambda t, T: 0.1 + 0.002 * (T - 20.0), "ok.csv")
    lines = p.read_text().splitlines()
    dup = tmp_path / "dup.csv"
    dup.write_text("\n".join(["timestamp\ttemp\tacc\tacc"] + [f"{ln}\t0" for ln in lines[1:]]) + "\n")
    with pytest.raises(InputError, match=r"dup.csv:1: the header names column 'acc' more than once"):
        _run(dup)
    kelvin = tmp_path / "k.csv"
    rows = [ln.split("\t") for ln in lines[1:]]
    kelvin.write_text("\n".join([lines[0]] + [f"{a}\t{float(b) + 273.15:.5f}\t{c}" for a, b, c in rows]) + "\n")
    with pytest.raises(InputError, match=r"k.csv:\d+: column 'temp': .* not a chamber temperature .*kelvin"):
        _run(kelvin)
    for ref in (float("nan"), float("inf")):
        with pytest.raises(InputError, match="--reference-temperature"):
            thermal_cycle(p, ["acc"], time_column="timestamp", temperature_column="temp", time_unit="us",
                          reference_temperature_C=ref)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_a_clean_quadratic_is_named_a_quadratic(tmp_path, seed):
    """The simplest form within one standard error or 1 % of the best held-out error
    (``thermal_cycle.parsimonious_best``): a form with a hysteresis or a play that predicts the
    held-out blocks better by chance (1e-5 of the RMS, on 4 of 15 axes of an outside probe) is not
    named."""
    a = _run(_cycle(tmp_path, lambda t, T: 0.05 - 0.003 * (T - 20) + 4e-5 * (T - 20) ** 2, "quad.csv",
                    seed=seed))
    assert a.form("quadratic").cv_rms < 1.1 * a.noise_floor
    assert a.best == "quadratic", [(f.name, f.cv_rms) for f in a.forms]
    assert abs(a.branch_gap) < 0.003


@pytest.mark.slow
def test_the_real_chamber_cycle(tmp_path):
    """tofupilot's climate-chamber run: z's branches ~0.13 m/s^2 apart at 20 degC (the shared
    data's README); a line leaves 40x the noise floor on held-out blocks, the best form a sixth of
    that and most of the branch gap, but not the noise floor: said as unexplained."""
    out = tmp_path / "c.json"
    assert main(["thermal-cycle", str(REAL), "--columns", "imu.acc.x,imu.acc.y,imu.acc.z", "--time-column",
                 "timestamp", "--time-unit", "us", "--temperature-column", "imu.temperature", "--json", str(out),
                 "--plot", str(tmp_path / "c.png"), "--quiet"]) == 0
    d = json.loads(out.read_text())
    z = d["axes"][2]
    forms = {f["form"]: f for f in z["forms"]}
    assert z["branch_gap_linear"] == pytest.approx(-0.126, abs=0.01)
    assert forms["linear"]["cv_rms"] > 30 * z["noise_floor"]
    assert forms[z["best"]]["cv_rms"] < forms["linear"]["cv_rms"] / 4
    assert abs(forms[z["best"]]["branch_gap_after"]) < 0.3 * abs(z["branch_gap_linear"])
    assert z["explained"] is False and "UNEXPLAINED" in d["verdict"]
    assert (tmp_path / "c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from test_results_contract import assert_valid

    assert_valid(d, "triadcal.thermal_cycle")


def test_bad_inputs_name_the_place(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("timestamp,temp,acc\n0,20,1\n1000000,21,x\n")
    with pytest.raises(InputError, match=r"bad.csv:3: column 'acc'"):
        thermal_cycle(p, ["acc"], time_column="timestamp", temperature_column="temp", time_unit="us")
    p.write_text("timestamp,temp,acc\n0,20,1\n0,21,1\n")
    with pytest.raises(InputError, match="does not increase"):
        thermal_cycle(p, ["acc"], time_column="timestamp", temperature_column="temp", time_unit="us")
    with pytest.raises(InputError, match="names all of"):
        thermal_cycle(p, ["acc_q"], time_column="timestamp", temperature_column="temp", time_unit="us")
    flat = _cycle(tmp_path, lambda t, T: 0 * T, "flat.csv")
    flat.write_text(flat.read_text().replace("\t-", "\t"))     # temperatures all positive: still a cycle
    p.write_text("timestamp,temp,acc\n" + "".join(f"{k * 500000},{20 + 0.001 * k},{1 + 0.001 * (k % 7)}\n"
                                                 for k in range(500)))
    with pytest.raises(InputError, match="spans"):
        thermal_cycle(p, ["acc"], time_column="timestamp", temperature_column="temp", time_unit="us")


def test_a_hysteron_by_hand():
    """relay_branch: 0 until the reading has moved 2r from where it started, then +1 after a fall and -1
    after a rise, held through a still span and through noise smaller than the band."""
    from triadcal.models.thermal_history import relay_branch

    x = np.array([20.0, 20.05, 19.95, 20.0, 19.7, 19.0, 19.0, 19.02, 18.98, 19.1, 19.3, 20.0, 20.0])
    b = relay_branch(x, 0.1)
    assert b.tolist() == [0, 0, 0, 0, 1, 1, 1, 1, 1, 1, -1, -1, -1]


def _soaked_cycle(tmp_path, name, seed, h=0.0, slope=0.0, noise=0.003, t_noise=0.01):
    """A stepped chamber cycle with soaks, as a test chamber runs one (20 -> -20 -> 60 -> 20 degC at 2.5,
    3.0 and 2.0 degC/min, 20 min at each turn, a reading every 30 s; the outside probe's profile): the
    output a constant plus ``slope`` (per degC) plus an offset hysteresis ``h`` whose branch is written
    out here as the joint model defines it, +1 after a fall and -1 after a rise, held through the soaks
    (0 before the first move); white noise; the thermometer reads with ``t_noise`` degC of noise."""
    legs, rates, soak = [20.0, -20.0, 60.0, 20.0], [2.5, 3.0, 2.0], 1200.0
    knots_t, knots_T = [0.0, soak], [legs[0], legs[0]]
    for i in range(1, len(legs)):
        knots_t += [knots_t[-1] + abs(legs[i] - legs[i - 1]) / rates[i - 1] * 60.0]
        knots_T += [legs[i]]
        knots_t += [knots_t[-1] + soak]
        knots_T += [legs[i]]
    t = np.arange(0.0, knots_t[-1] + 1.0, 30.0)
    T = np.interp(t, knots_t, knots_T)
    branch = np.zeros_like(T)
    for k in range(1, len(T)):
        branch[k] = -1.0 if T[k] > T[k - 1] + 1e-9 else (1.0 if T[k] < T[k - 1] - 1e-9 else branch[k - 1])
    rng = np.random.default_rng(seed)
    y = 9.81 + slope * (T - 20.0) + h * branch + rng.normal(0.0, noise, len(t))
    Tr = T + rng.normal(0.0, t_noise, len(t))
    p = tmp_path / name
    p.write_text("time_s,temp,acc\n" + "".join(f"{a:.1f},{b:.4f},{c:.6f}\n" for a, b, c in zip(t, Tr, y)))
    return p


def _run_s(p):
    return thermal_cycle(p, ["acc"], time_column="time_s", temperature_column="temp").axes[0]


@pytest.mark.parametrize("seed", [1, 2])
def test_an_offset_hysteresis_held_through_soaks_is_named_so(tmp_path, seed):
    """An outside probe: the branch held through 20 min soaks was never named offset_hysteresis (0 of 6):
    the form's b was 0 while the chamber was still and switched on a 2 min rate, a minute before each turn;
    lag_hysteresis at its smallest tau or quadratic_play took it, "explained". Now b is the hysteron of the
    reading: 12 of 12 of the probe's cycles named offset_hysteresis, h within its noise."""
    a = _run_s(_soaked_cycle(tmp_path, f"h{seed}.csv", seed, h=0.01, slope=-0.0015))
    assert a.best == "offset_hysteresis", [(f.name, round(f.cv_rms / a.noise_floor, 3)) for f in a.forms]
    h = a.form("offset_hysteresis").coefficients[2]
    assert h == pytest.approx(0.01, abs=5e-4)       # SE of h: 0.003 / sqrt(~280) = 1.8e-4; 2.8 SE
    assert a.form(a.best).cv_rms < 1.2 * a.noise_floor


@pytest.mark.parametrize("seed", [3, 5])
def test_an_axis_with_no_thermal_effect_is_a_line(tmp_path, seed):
    """An outside probe: axes with no thermal effect (a constant, or a line, and white noise) were named a
    play, a lag, an offset hysteresis, a thermometer lag or a quadratic, "explained", 12 of 39, by 0.7-2 %
    of the RMS: the lowest of thirteen forms beats the line by one fold-standard-error by chance. Now a
    form beyond one at the white-noise floor must beat it by 3 standard errors of the paired held-out
    squared errors (the probe's 39 axes: 39 lines). Seed 3's line was named offset_hysteresis before."""
    for slope, name in ((0.0, "flat"), (-0.0015, "line")):
        a = _run_s(_soaked_cycle(tmp_path, f"{name}{seed}.csv", seed, slope=slope))
        assert a.best == "linear", (slope, a.best, [(f.name, round(f.cv_rms / a.noise_floor, 3)) for f in a.forms])


@pytest.mark.slow
def test_no_thermal_effect_is_rarely_given_a_form():
    """Over 30 cycles (60 axes: a constant and a line each) of white noise, a form other than linear is
    named on at most 4: the paired test's one-sided 0.13 % per rival over twelve rivals is about 1.6 %
    per axis (expected about 1 of 60; P(X > 4) < 0.2 % for a binomial of 1.6 %). The fold rule alone
    named 15 of these 60 (and 9 of 39 of the probe's own simulator); with the floor rule 0 of 60."""
    import tempfile

    wrong = []
    with tempfile.TemporaryDirectory() as d:
        for seed in range(100, 130):
            for slope, name in ((0.0, "flat"), (-0.0015, "line")):
                a = _run_s(_soaked_cycle(Path(d), f"{name}{seed}.csv", seed, slope=slope))
                if a.best != "linear":
                    wrong.append((seed, name, a.best))
    assert len(wrong) <= 4, wrong


def _one_way(tmp_path, output, name, falling=False, seed=0):
    """A soak at 20 degC (10 min), a ramp to 80 degC at 2 degC/min and a soak (10 min), 1 Hz, or the
    same ramp falling from 80 to 20; ``output(t, T)`` the true output, white noise 0.003."""
    t = np.arange(0.0, 3000.0, 1.0)
    T = np.interp(t, [0.0, 600.0, 2400.0, 3000.0], [20.0, 20.0, 80.0, 80.0])
    if falling:
        T = 100.0 - T
    y = output(t, T) + np.random.default_rng(seed).normal(0.0, 0.003, len(t))
    lines = ["timestamp\ttemp\tacc"] + [f"{int(1e6 * a) + 123456789}\t{b:.5f}\t{c:.6f}" for a, b, c in zip(t, T, y)]
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


@pytest.mark.parametrize("falling", [False, True])
def test_a_record_that_only_heats_or_only_cools_is_judged_on_the_forms_of_one_branch(tmp_path, falling):
    """An outside probe: a heating-only (or cooling-only) record was refused ("no heating and cooling
    branches"), though a tempco is measured on one ramp. Now the forms without a branch term are
    judged, and the notes say what a one-way record cannot tell: a line is a line, a quadratic a
    quadratic (its coefficient within 5 %), and an element lagging by 3 min (scipy's ODE solver)
    shows at the ramp's start and end and is named a lag."""
    line = _one_way(tmp_path, lambda t, T: -9.6 + 0.0196 * (T - 20.0), "line.csv", falling)
    c = thermal_cycle(line, ["acc"], time_column="timestamp", temperature_column="temp", time_unit="us")
    a = c.axes[0]
    assert a.best == "linear" and [f.name for f in a.forms] == ["linear", "quadratic", "cubic", "lag", "lag_quadratic",
                                                                  "thermometer_lag", "play", "play_quadratic"]
    assert any("no heating and cooling branches, so no hysteresis is judged" in n for n in c.notes), c.notes
    assert ("only falls" if falling else "only rises") in c.notes[-1]
    quad = _one_way(tmp_path, lambda t, T: -9.6 + 0.01 * (T - 20.0) + 2e-4 * (T - 20.0) ** 2, "quad.csv", falling)
    a = _run_one(quad)
    assert a.best == "quadratic" and a.form("quadratic").coefficients[2] == pytest.approx(2e-4, rel=0.05)
    lag = _one_way(tmp_path, _ode_lag(180.0), "lag.csv", falling)
    a = _run_one(lag)
    assert a.best in ("lag", "lag_quadratic"), [(f.name, f.cv_rms) for f in a.forms]
    assert a.form(a.best).parameter["tau_min"] == pytest.approx(3.0, rel=0.15)


def _run_one(p):
    return thermal_cycle(p, ["acc"], time_column="timestamp", temperature_column="temp", time_unit="us").axes[0]


def test_a_play_started_on_a_branch_is_explained_by_its_start_held(tmp_path):
    """An outside probe's cycle: -20, 60 and 20 degC at 1, 2 and 1.5 degC/min from 20 degC, soaks of
    20 min at each turn and at the ends, a play of 2 degC whose state before the record is that of a chamber that had heated
    (y0 = T0 - r; a backlash written out here). The play was named right, but "unexplained" at 4-4.6
    floors, 15 of 15 axes: its start, chosen on the training blocks, is seen only in the first block
    (the play forgets it at its first turn). The start is chosen on every sample and held: explained."""
    knots = np.cumsum([0.0, 1200.0, 2400.0, 1200.0, 2400.0, 1200.0, 1600.0, 1200.0])   # soaks of 20 min at the turns
    t = np.arange(0.0, knots[-1], 5.0)
    T = np.interp(t, knots, [20.0, 20.0, -20.0, -20.0, 60.0, 60.0, 20.0, 20.0])
    y = 0.1 + 0.0196 * (_backlash(T, 2.0, T[0] - 2.0) - 20.0) + np.random.default_rng(1).normal(0.0, 0.003, t.size)
    lines = ["timestamp\ttemp\tacc"] + [f"{int(1e6 * a) + 123456789}\t{b:.5f}\t{c:.6f}" for a, b, c in zip(t, T, y)]
    p = tmp_path / "play_start.csv"
    p.write_text("\n".join(lines) + "\n")
    a = _run(p)
    assert a.best == "play", [(f.name, f.cv_rms, f.parameter) for f in a.forms]
    par = a.form("play").parameter
    assert par["start"] == "heating" and par["half_width_C"] == pytest.approx(2.0, abs=0.1), par
    assert a.to_dict()["explained"] and a.form("play").cv_rms < 1.5 * a.noise_floor


# -- an outside probe's thermal-cycle findings (2026-12-02) ------------------------------------------
def test_an_output_drifting_in_time_is_named_a_drift_not_a_hysteresis(tmp_path):
    """An outside probe's output drifting 20 ug/h with no tempco (and with 50 ug/degC) was a play of
    30 degC at the edge of the search, "explained" at 1.2 floors, a branch gap of +17..+32 ug where
    there is none, 9 of 9 axes. The drift is its rival now (``linear_drift``, not thermal): the cycle
    written here (two rates, 3.3 h) with a drift of 0.01 m/s2/h and a tempco of 0.002 m/s2/degC, and
    with the drift alone: named ``linear_drift``, the drift within 5 %, the verdict says it is not
    thermal. A line without a drift stays ``linear``."""
    for slope in (0.0, 0.002):
        p = _cycle(tmp_path, lambda t, T, s=slope: 9.81 + s * (T - 20.0) + 0.01 * t / 3600.0, f"drift_{slope}.csv",
                   noise=0.001, seed=3, two_rates=True)
        c = thermal_cycle(p, ["acc"], time_column="timestamp", temperature_column="temp", time_unit="us")
        a = c.axes[0]
        assert a.best == "linear_drift", [(f.name, f.cv_rms) for f in a.forms]
        coef = a.form("linear_drift").coefficients
        assert abs(coef[2] - 0.01) < 0.05 * 0.01 and abs(coef[1] - slope) < 1e-4, coef
        assert "drifts in time by +0.01 m/s2/h" in c.verdict and "not a thermal form" in c.verdict
    a = _run(_cycle(tmp_path, lambda t, T: 9.81 + 0.002 * (T - 20.0), "line.csv", noise=0.001, seed=3))
    assert a.best == "linear"


def test_an_isolated_glitch_is_left_out_and_named(tmp_path):
    """One sample of 8400 raised by 5 m/s2 made an outside probe's 4 min lag a line, "explained" (the
    floor from sample differences took the spike: 1.00 floors) with a branch gap of +540 ug; 0.5 m/s2
    made tau 5.5 % short. The glitch (beyond 20 robust SDs of the running median of 9; the real cycle's
    largest is 9) is left out and its line named; the lag (ODE solver) comes out as without it."""
    p = _cycle(tmp_path, _ode_lag(240.0), "lag.csv")
    clean = _run(p)
    lines = p.read_text().splitlines()
    f = lines[1001].split("\t")
    f[2] = f"{float(f[2]) + 5.0:.6f}"
    lines[1001] = "\t".join(f)
    (tmp_path / "spike.csv").write_text("\n".join(lines) + "\n")
    c = thermal_cycle(tmp_path / "spike.csv", ["acc"], time_column="timestamp", temperature_column="temp",
                      time_unit="us")
    assert c.axes[0].best == clean.best == "lag"
    assert c.axes[0].form("lag").parameter["tau_min"] == pytest.approx(clean.form("lag").parameter["tau_min"], rel=0.01)
    assert any("1 isolated glitch(es) left out" in n and "line(s) 1002 " in n for n in c.notes), c.notes
    # every tenth sample a glitch: not isolated, refused
    for k in range(1, len(lines), 10):
        f = lines[k].split("\t")
        f[2] = f"{float(f[2]) + 5.0:.6f}"
        lines[k] = "\t".join(f)
    (tmp_path / "bursts.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="not isolated glitches"):
        thermal_cycle(tmp_path / "bursts.csv", ["acc"], time_column="timestamp", temperature_column="temp",
                      time_unit="us")


def test_outputs_no_unit_at_rest_gives_are_refused(tmp_path):
    """A stuck channel (0.0 on every row) was named ``linear``, "explained", floor 0; a value of 1e30
    was read (floor 1.7e28); m/s2 declared g (|z| 9.8 "g") exit 0. Refused, naming the column (and the
    line); an output in V is not checked for g but the note says so."""
    p = _cycle(tmp_path, lambda t, T: 9.81 + 0.002 * (T - 20.0), "ok.csv")
    with pytest.raises(InputError, match=r"its median \|9.8\d*\| g is 9.8\d* g.*in m/s2\? give --unit"):
        thermal_cycle(p, ["acc"], time_column="timestamp", temperature_column="temp", time_unit="us", unit="g")
    c = thermal_cycle(p, ["acc"], time_column="timestamp", temperature_column="temp", time_unit="us", unit="V")
    assert any("is not one whose g is known" in n for n in c.notes)
    lines = p.read_text().splitlines()
    f = lines[500].split("\t")
    f[2] = "1e30"
    (tmp_path / "huge.csv").write_text("\n".join(lines[:500] + ["\t".join(f)] + lines[501:]) + "\n")
    with pytest.raises(InputError, match=r"huge.csv:501: column 'acc': 1e\+30 m/s2"):
        thermal_cycle(tmp_path / "huge.csv", ["acc"], time_column="timestamp", temperature_column="temp",
                      time_unit="us")
    stuck = [lines[0]] + ["\t".join(ln.split("\t")[:2] + ["0.0"]) for ln in lines[1:]]
    (tmp_path / "stuck.csv").write_text("\n".join(stuck) + "\n")
    with pytest.raises(InputError, match="column 'acc' reads 0 on every row: a stuck"):
        thermal_cycle(tmp_path / "stuck.csv", ["acc"], time_column="timestamp", temperature_column="temp",
                      time_unit="us")


@pytest.mark.slow           # 12 cycles, ~20 s
def test_the_forms_parameters_carry_a_block_jackknife_uncertainty():
    """An outside probe: tau, r, h and the tempcos were given with no uncertainty, so a bias (a lag
    with a hysteresis: tau 2 % long, h 4 % short, 3-5 standard errors) could not be seen against it.
    Each form's parameter and coefficients now carry the delete-a-block jackknife over the six folds'
    training estimates (5 dof). A 4 min lag by scipy's ODE solver, seeds 0-11 (measured: RMS z 0.96
    against t(5)'s 1.29, 12 of 12 inside t(5)'s 95 % interval): every |z| < t(5; 0.995) = 4.03, at
    least 10 of 12 inside 2.571 (binomial, P(X <= 9 | 12, 0.95) = 0.02), and the verdict says +-."""
    from scipy import stats

    import tempfile

    z = []
    with tempfile.TemporaryDirectory() as d:
        for seed in range(12):
            c = thermal_cycle(_cycle(Path(d), _ode_lag(240.0), f"l{seed}.csv", seed=seed), ["acc"],
                              time_column="timestamp", temperature_column="temp", time_unit="us")
            f = c.axes[0].form("lag")
            assert c.axes[0].best == "lag" and len(f.u["coefficients"]) == 2 and f.u["coefficients"][1] > 0
            z.append((f.parameter["tau_min"] - 4.0) / f.u["tau_min"])
            assert "tau_min 4 +- " in c.verdict or "tau_min 3.99 +- " in c.verdict or "tau_min 4.01 +- " in c.verdict
    z = np.abs(np.array(z))
    assert np.all(z < stats.t.ppf(0.995, 5)) and np.sum(z < stats.t.ppf(0.975, 5)) >= 10, z
