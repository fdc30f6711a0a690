"""thermal-cycle against the thermometer's own reading error (estimation/thermal_reading.py).

An outside probe (its own simulator: a linear bias tempco of 2 mg/degC, no lag, no hysteresis) saw
a thermometer reading in 1 degC steps named ``lag_hysteresis``, "explained", on 14 of 15 axes, and
0.2 degC of white reading noise on 9 of 9: a lag is a low-pass filter of the reading and averages its
error away. Made another way here: the cycle of tests/test_thermal_cycle.py, the reading rounded or
noised with numpy, the lag by scipy's ODE solver."""
from __future__ import annotations

import numpy as np
import pytest

from test_thermal_cycle import _cycle, _ode_lag, _run
from triadcal.estimation.thermal_reading import reading_errors
from triadcal.models.thermal_history import centred_mean

LINE = lambda t, T: -9.6 + 0.0196 * (T - 20.0)   # noqa: E731  2 mg/degC on the vertical axis, m/s2


def test_a_centred_mean_of_a_staircase_over_one_step_is_the_ramp_by_hand():
    """A ramp of 1 degC/min sampled at 1 s, read in 1 degC steps (floor): averaged over the 60 s of
    one step the staircase is the ramp less half a step, exactly, away from the ends; a white noise of
    0.2 degC over 61 samples has SD 0.2 / sqrt 61."""
    t = np.arange(0.0, 3600.0, 1.0)
    T = t / 60.0
    m = centred_mean(t, np.floor(T), 60.0)
    inner = slice(60, -60)
    assert np.max(np.abs(m[inner] - (T[inner] - 0.5))) < 1.0 / 60.0 + 1e-12
    e = np.random.default_rng(1).normal(0.0, 0.2, t.size)
    assert np.std(centred_mean(t, e, 60.0)[inner]) == pytest.approx(0.2 / np.sqrt(61), rel=0.1)


def test_the_readings_errors_by_hand():
    """reading_errors: a staircase of 0.5 degC has that resolution and a white part near 0 (its second
    differences are 0 but at the steps); a white noise of 0.2 degC on a ramp reads 0.2 within 10 %."""
    t = np.arange(0.0, 6000.0, 1.0)
    T = 20.0 + t / 60.0
    e = reading_errors(np.round(T * 2.0) / 2.0)
    assert e["resolution_C"] == pytest.approx(0.5) and e["sigma_C"] < 0.01
    e = reading_errors(T + np.random.default_rng(2).normal(0.0, 0.2, t.size))
    assert e["resolution_C"] is None and e["sigma_C"] == pytest.approx(0.2, rel=0.1)


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("reading", ["steps_1C", "white_0.2C"])
def test_a_coarse_or_noisy_thermometer_is_no_lag_or_hysteresis(tmp_path, reading, seed):
    """A line in the true temperature; the reading rounded to 1 degC, or with 0.2 degC of white
    noise: the lag forms averaged the reading's error away and won (before: a delay or a hysteresis
    form named). Now the line is named, its reason naming the reading's error; the rival's window and
    the reading's measured resolution or noise in the result."""
    rd = ((lambda t, T: np.round(T)) if reading == "steps_1C" else
          (lambda t, T: T + np.random.default_rng(100 + seed).normal(0.0, 0.2, T.size)))
    a = _run(_cycle(tmp_path, LINE, f"{reading}_{seed}.csv", seed=seed, reading=rd))
    assert a.best == "linear", ([(f.name, f.cv_rms) for f in a.forms], a.floor_note)
    d = a.to_dict()
    if d.get("reading_rival"):
        assert d["reading_rival"]["beaten"] is False and "the thermometer's own reading error" in d["floor_rule"]
        assert ("resolution 1 degC" in d["floor_rule"]) == (reading == "steps_1C"), d["floor_rule"]


def test_a_true_lag_read_by_a_coarse_thermometer_is_still_a_lag(tmp_path):
    """An element lagging by 4 min (scipy's ODE solver), the reading in 0.5 degC steps: the lag beats
    the reading averaged without delay by far (a delay is a difference between the branches that no
    centred average makes), and is named at its time constant."""
    a = _run(_cycle(tmp_path, _ode_lag(240.0), "lag_steps.csv", reading=lambda t, T: np.round(2.0 * T) / 2.0))
    assert a.best in ("lag", "lag_quadratic"), ([(f.name, f.cv_rms) for f in a.forms], a.floor_note)
    assert a.form(a.best).parameter["tau_min"] == pytest.approx(4.0, rel=0.15)
    assert a.reading_rival["beaten"] is True and a.reading_rival["z"] > 10, a.reading_rival


@pytest.mark.parametrize("seed", [1, 2])
def test_an_offset_hysteresis_read_in_one_degree_steps_is_no_lag(tmp_path, seed):
    """A line plus an offset hysteresis of 0.01 m/s2 (a relay written out here: the sign of the last
    move, held), the reading in 1 degC steps: an outside probe saw lag_play or lag_hysteresis (tau 0.15
    min) named, "explained", 12 of 12 axes, the rival without a branch beaten by 26-37 SE. A form with a
    delay and a branch now meets the same branch without delay in the averaged reading: the offset
    hysteresis is named, its h within 10 %."""
    def out(t, T):
        rate = np.gradient(T, t)
        b = np.zeros_like(T)
        cur = 0.0
        for k, v in enumerate(rate):
            cur = 1.0 if v < -1e-6 else -1.0 if v > 1e-6 else cur
            b[k] = cur
        return LINE(t, T) + 0.01 * b

    a = _run(_cycle(tmp_path, out, f"hyst_steps_{seed}.csv", seed=seed, reading=lambda t, T: np.round(T)))
    assert a.best == "offset_hysteresis", ([(f.name, f.cv_rms) for f in a.forms], a.floor_note)
    assert a.form("offset_hysteresis").coefficients[2] == pytest.approx(0.01, rel=0.1)


def test_the_noise_floor_leaves_out_the_steps_across_a_gap(tmp_path):
    """thermal_cycle.white_floor: a ramp's output with white noise 0.003 and two gaps in the record (the
    output moved 0.5 across each): the SD of the differences over sqrt 2 is 0.003 within 10 % (an outside
    probe's floor was doubled by them, and a held-out RMS of 3.5 floors passed as explained)."""
    from triadcal.estimation.thermal_cycle import white_floor

    t = np.arange(0.0, 3000.0, 5.0)
    keep = (t < 1000) | ((t > 1600) & (t < 2000)) | (t > 2300)
    t = t[keep]
    y = 0.0005 * t + np.random.default_rng(3).normal(0.0, 0.003, t.size)
    assert np.std(np.diff(y)) / np.sqrt(2) > 0.004
    assert white_floor(t, y) == pytest.approx(0.003, rel=0.1)


def test_the_noise_floor_of_a_coarsely_logged_record_is_the_noise(tmp_path):
    """thermal_cycle.white_floor on a record logged every 30 s through ramps of 1 and 3 degC/min with a
    tempco of 0.049 m/s2/degC (5 mg/degC) and white noise 0.003: the first differences hold the signal's
    change between samples (their floor is 5 times the noise), the second differences do not; an outside
    probe's such record had its floor at 7.4 times the noise and a bias step "explained"."""
    from triadcal.estimation.thermal_cycle import white_floor

    t = np.arange(0.0, 6 * 3600.0, 30.0)
    legs = np.interp(t, [0, 3600, 5400, 9000, 12600, 16200, 21600], [20, 80, 20, -40, 20, 50, 20])
    y = 0.049 * legs + np.random.default_rng(4).normal(0.0, 0.003, t.size)
    assert np.std(np.diff(y)) / np.sqrt(2) > 5 * 0.003
    assert white_floor(t, y) == pytest.approx(0.003, rel=0.15)
    # finely logged, the floor is the first differences' as before
    tf = np.arange(0.0, 3000.0, 2.0)
    yf = 0.0005 * tf + np.random.default_rng(5).normal(0.0, 0.003, tf.size)
    assert white_floor(tf, yf) == np.std(np.diff(yf)) / np.sqrt(2)


def test_three_axes_of_one_triad_in_another_unit_are_refused():
    """io.thermal_cycle_csv.check_outputs: three columns whose medians' norm is 1.00 "m/s2" (a triad in g
    under the default unit; an outside probe's was fitted, every value 9.8 times too small, exit 0) are
    refused naming the likely unit; the same in m/s2, or one column alone, pass."""
    from triadcal.errors import InputError
    from triadcal.io.thermal_cycle_csv import check_outputs

    rng = np.random.default_rng(1)
    up = np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93])
    y = up[None, :] + rng.normal(0.0, 1e-3, (500, 3))
    rows = np.arange(2, 502)
    with pytest.raises(InputError, match=r"norm of their medians is (1|0\.99\d*) m/s2 = 0.102 g.*\(in g\? give --unit\)"):
        check_outputs("c.csv", ["ax", "ay", "az"], y, rows, "m/s2")
    check_outputs("c.csv", ["ax", "ay", "az"], y * 9.80665, rows, "m/s2")
    check_outputs("c.csv", ["ax", "ay", "az"], y, rows, "g")
    check_outputs("c.csv", ["az"], y[:, 2:], rows, "m/s2")
