"""The measured rate of a ramp campaign (issue 20, "calibrate on a continuous ramp"): bench CSV's
optional column ``dTdt_C_per_min`` — written by the simulator's ramp campaigns (exact) and by
``capture --ramp`` (from the window's raw readings, :func:`triadcal.hardware.ramp_labels.visit_rate`;
checked against the emulated unit in tests/test_ramp_capture.py), read back, refused naming file, line and
column when bad, and taken by the fit as the rate of the thermal lag instead of the central
differences of the visit means (which are one-sided at a block's ends, where the unit turns)."""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from triadcal.api import fit
from triadcal.hardware.ramp_capture import visit_rate
from triadcal.io.bench_csv import BenchCSVError, format_bench_csv, read_bench_csv, write_bench_csv
from triadcal.models.simulate import RampSchedule, preset_truth, ramp_history, simulate_campaign

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis", "thermal_lag")
SCHEDULE = RampSchedule(program_C=(20.0, -40.0, 85.0, 20.0))


@pytest.fixture(scope="module")
def silicon():
    """A simulated ramp of the a18-silicon preset (thermal_lag 8 min, its large tempcos): the
    campaign whose fit the central differences spoil most."""
    truth = preset_truth("a18-silicon", EFFECTS)
    return truth, simulate_campaign(truth, schedule=SCHEDULE, seed=1)


def test_the_column_is_written_read_back_and_is_the_rate_the_campaign_gives(tmp_path, silicon):
    _, c = silicon
    # the simulator's rate: the exact mean rate of the readings over each window
    _, u0, _ = ramp_history(SCHEDULE, c.time_s - SCHEDULE.tau_s / 2)
    _, u1, _ = ramp_history(SCHEDULE, c.time_s + SCHEDULE.tau_s / 2)
    np.testing.assert_allclose(c.dTdt_C_per_min, (u1 - u0) / SCHEDULE.tau_s * 60.0, rtol=1e-12, atol=1e-12)
    assert c.metadata["dTdt_method"].startswith("exact")
    path = tmp_path / "ramp.csv"
    write_bench_csv(c, path)
    header = next(line for line in path.read_text().splitlines() if line.startswith("unit,"))
    assert header.split(",")[-1] == "dTdt_C_per_min"                # after the standard columns
    back = read_bench_csv(path)
    np.testing.assert_array_equal(back.dTdt_C_per_min, c.dTdt_C_per_min)     # repr: exact round trip
    assert format_bench_csv(back) == path.read_text()                         # a fixed point
    assert "dTdt_C_per_min" not in back.extra
    # the rate of all three sensors, degC/s; select keeps it
    np.testing.assert_array_equal(back.temperature_rate(), np.repeat(back.dTdt_C_per_min[:, None] / 60.0, 3, axis=1))
    np.testing.assert_array_equal(back.select(np.arange(5)).dTdt_C_per_min, back.dTdt_C_per_min[:5])
    # without it: the central differences, as before
    plain = replace(back, dTdt_C_per_min=None)
    np.testing.assert_array_equal(plain.temperature_rate(), back.central_difference_rate())
    # a stepped campaign has none
    stepped = simulate_campaign(preset_truth("ak18-quartz", ("bench_tilt",)), seed=0)
    assert stepped.dTdt_C_per_min is None and "dTdt_C_per_min" not in format_bench_csv(stepped)


@pytest.mark.parametrize("bad, problem", [
    ("fast", "not a number: 'fast'"),
    ("nan", "not a finite number: 'nan'"),
    ("", "empty field"),
    ("120", "dTdt_C_per_min 120 outside the accepted range [-100, 100]"),
    ("-1e3", "outside the accepted range [-100, 100]"),
])
def test_a_bad_rate_is_refused_naming_file_line_and_column(tmp_path, silicon, bad, problem):
    _, c = silicon
    lines = format_bench_csv(c).splitlines()
    h = next(k for k, line in enumerate(lines) if line.startswith("unit,"))
    j = lines[h].split(",").index("dTdt_C_per_min")
    row = lines[h + 7].split(",")
    row[j] = bad
    lines[h + 7] = ",".join(row)
    path = tmp_path / "bad_rate.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(BenchCSVError) as exc:
        read_bench_csv(path)
    e = exc.value
    assert (e.path, e.line, e.column) == (str(path), h + 8, "dTdt_C_per_min")
    assert problem in e.problem and str(exc.value).startswith(f"{path}:{h + 8}: column 'dTdt_C_per_min': ")


def test_the_fit_takes_the_measured_rate(silicon):
    """The rate is the thermal lag's dT/dt: twice the rate, half the lag (the same fit otherwise);
    on this campaign the measured rate gives chi2/dof 1.07 and the central differences 1.83 (noise
    of the readings between visits 50 s apart, and one-sided differences at the turns)."""
    truth, c = silicon
    measured = fit(c, effects=list(EFFECTS))
    doubled = fit(replace(c, dTdt_C_per_min=2.0 * c.dTdt_C_per_min), effects=list(EFFECTS))
    central = fit(replace(c, dTdt_C_per_min=None), effects=list(EFFECTS))
    lag = measured.parameters["thermal_lag"]
    assert measured.status == "ok" and abs(lag.value - truth.parameters["thermal_lag"]) < 3 * lag.u
    assert doubled.parameters["thermal_lag"].value == pytest.approx(lag.value / 2.0, rel=1e-3)
    assert measured.fit["chi2_dof"] < 1.2 < 1.5 < central.fit["chi2_dof"], (measured.fit["chi2_dof"],
                                                                          central.fit["chi2_dof"])
    # the result says which rate it used
    assert measured.fit["temperature_rate"].startswith("measured per visit")
    assert central.fit["temperature_rate"].startswith("central differences")


def test_visit_rate_is_the_windows_mean_rate():
    """capture --ramp's rate of a visit: the slope of the least-squares line through the window's mean
    readings, the window's mean rate (T(t1) - T(t0)) / tau exactly for a temperature quadratic over
    the window: 20 s at 2 Hz of a ramp bending towards a turn, sd 0.006 degC (three sensors' mean),
    100 draws: unbiased, SD 0.0095 degC/min as least squares gives (sd / sqrt(sum (t - mean t)^2))."""
    rng = np.random.default_rng(3)
    t = np.arange(300.0, 320.01, 0.5)                                        # 41 frames
    temp = 20.0 - 1.5 / 60.0 * (t - 100.0) + 2e-5 * (t - 100.0) ** 2
    exact = (temp[-1] - temp[0]) / (t[-1] - t[0])

    def frames(values):
        return [SimpleNamespace(time_s=x, t=(v + 0.01, v, v - 0.01)) for x, v in zip(t, values)]

    assert visit_rate(frames(temp)) == pytest.approx(exact, rel=1e-9)
    got = np.array([visit_rate(frames(temp + rng.normal(0.0, 0.006, t.size))) for _ in range(100)])
    se = 0.006 / np.sqrt(np.sum((t - t.mean()) ** 2))
    assert abs(got.mean() - exact) < 4 * se / 10 and 0.8 < got.std() / se < 1.2, (got.mean() - exact, got.std() / se)
    assert visit_rate(frames(temp)[:1]) == 0.0 and visit_rate(None) == 0.0
