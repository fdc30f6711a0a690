"""The bench-campaign simulator and ``triadcal simulate`` (docs/model.md).

Statistical checks use fixed seeds and bounds from the sampling distribution of the
statistic (chi-square quantiles at 1e-3 / 1 - 1e-3), never tuned to the seed.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from triadcal.api import simulate
from triadcal.io.bench_csv import read_bench_csv
from triadcal.models.effects import DEFAULT_EFFECTS
from triadcal.models.simulate import (STANDARD_SETPOINTS_C, NoiseModel, Schedule, Truth, preset_truth,
                                      simulate_campaign, thermal_history)

TRIADCAL = str(Path(sys.executable).with_name("triadcal"))
ALPHA = 1e-3  # two-sided level of every statistical bound below


def cli(*args, cwd=None):
    return subprocess.run([TRIADCAL, *map(str, args)], capture_output=True, text=True, cwd=cwd)


def chi2_bounds(dof: int):
    return stats.chi2.ppf(ALPHA / 2, dof), stats.chi2.ppf(1 - ALPHA / 2, dof)


# -- the command line --------------------------------------------------------------------


def test_same_seed_same_file_different_seed_different(tmp_path):
    runs = {}
    for name, seed in (("a", 7), ("b", 7), ("c", 8)):
        r = cli("simulate", "-o", tmp_path / f"{name}.csv", "--truth", tmp_path / f"{name}.json",
                "--seed", seed)
        assert r.returncode == 0, r.stderr
        assert "wrote" in r.stdout and r.stderr == ""
        runs[name] = (tmp_path / f"{name}.csv").read_bytes()
    assert runs["a"] == runs["b"]
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    a, c = read_bench_csv(tmp_path / "a.csv"), read_bench_csv(tmp_path / "c.csv")
    assert a.n_visits == c.n_visits == 15 * 12
    np.testing.assert_array_equal(a.time_s, c.time_s)  # same schedule ...
    assert np.all(a.w != c.w)  # ... every reading drawn afresh
    assert np.all(a.t != c.t)


def test_cli_truth_matches_the_library(tmp_path):
    r = cli("simulate", "-o", tmp_path / "s.csv", "--truth", tmp_path / "t.json", "--preset", "a18-silicon",
            "--effects", "bench_tilt,angle_tempco,position_error", "--set", "Ca_xy=40",
            "--setpoints", "20,50", "--seed", 3)
    assert r.returncode == 0, r.stderr
    truth = Truth.load(tmp_path / "t.json")
    assert truth.effects == ("bench_tilt", "angle_tempco")
    assert truth.parameters["Ca_xy"] == 40.0
    assert (truth.noise.sigma_position_arcsec, truth.noise.sigma_wobble_arcsec) == (5.0, 2.0)
    lib_truth, lib = simulate(preset="a18-silicon", effects=["bench_tilt", "angle_tempco", "position_error"],
                              parameters={"Ca_xy": 40.0}, schedule=Schedule(setpoints_C=(20.0, 50.0)), seed=3)
    assert lib_truth == truth
    np.testing.assert_array_equal(read_bench_csv(tmp_path / "s.csv").w, lib.w)


def assert_clean_failure(r, *fragments, code=1):
    assert r.returncode == code, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout
    assert r.stdout == ""
    assert r.stderr.strip(), "the reason must be on stderr"
    for f in fragments:
        assert f in r.stderr, r.stderr


def test_unknown_effect_fails_cleanly(tmp_path):
    out = tmp_path / "x.csv"
    r = cli("simulate", "-o", out, "--effects", "bench_tilt,warp_drive")
    assert_clean_failure(r, "warp_drive", "bench_tilt, tilt_drift, tilt_settling, bench_nonorthogonality, thermal_lag")
    assert not out.exists()


def test_unknown_preset_fails_cleanly(tmp_path):
    out = tmp_path / "x.csv"
    r = cli("simulate", "-o", out, "--preset", "ak99-unobtainium")
    assert r.returncode != 0 and "Traceback" not in r.stderr and r.stdout == ""
    assert "ak99-unobtainium" in r.stderr and "ak18-quartz" in r.stderr
    assert not out.exists()


def test_unknown_preset_exit_code_is_one(tmp_path):
    r = cli("simulate", "-o", tmp_path / "x.csv", "--preset", "ak99-unobtainium")
    assert_clean_failure(r, "ak99-unobtainium", code=1)


@pytest.mark.parametrize("args, fragment", [
    (("--set", "K2_x=3"), "K2_x"),                 # a parameter of an effect that is off
    (("--set", "Ca_xy"), "NAME=VALUE"),
    (("--set", "Ca_xy=forty"), "not a number"),
    (("--setpoints", "20,hot"), "numbers"),
    (("--effects", "heavy_tails", "--heavy-tails-dof", "2"), "exceed 2"),
])
def test_bad_options_fail_cleanly(tmp_path, args, fragment):
    r = cli("simulate", "-o", tmp_path / "x.csv", *args)
    assert_clean_failure(r, fragment)
    assert not (tmp_path / "x.csv").exists()


def test_unwritable_output_fails_cleanly(tmp_path):
    r = cli("simulate", "-o", tmp_path / "no" / "such" / "dir.csv")
    assert_clean_failure(r, "dir.csv")


# -- schedule and thermal history ----------------------------------------------------------


def test_directions_of_the_standard_schedule():
    expected = ["none"] + ["heating"] * 3 + ["cooling"] * 7 + ["heating"] * 4
    assert tuple(Schedule().setpoints_C) == STANDARD_SETPOINTS_C
    assert Schedule().directions() == expected
    c = simulate_campaign(preset_truth(), seed=0)
    assert list(c.direction) == [d for d in expected for _ in range(12)]
    assert list(c.setpoint_C) == [s for s in STANDARD_SETPOINTS_C for _ in range(12)]
    branch = {"none": 0.0, "heating": -1.0, "cooling": 1.0}
    np.testing.assert_array_equal(c.branch, [branch[d] for d in c.direction])


def test_a_repeated_setpoint_keeps_its_direction():
    assert Schedule(setpoints_C=(20, 20, 40, 40, 10, 10)).directions() == [
        "none", "none", "heating", "heating", "cooling", "cooling"]


def test_visit_timing():
    s = Schedule(setpoints_C=(20.0, 35.0), soak_s=1000.0, tau_s=40.0, move_s=10.0)
    c = simulate_campaign(preset_truth(), schedule=s, seed=0)
    first = s.soak_s + s.move_s + s.tau_s / 2  # middle of the first averaging window
    step = s.move_s + s.tau_s
    block = s.soak_s + 12 * step
    expected = [b * block + first + k * step for b in range(2) for k in range(12)]
    np.testing.assert_allclose(c.time_s, expected, rtol=0, atol=1e-9)
    assert (c.tau_s == 40.0).all() and list(c.position[:12]) == [f"P{i:02d}" for i in range(1, 13)]


def test_unit_temperature_follows_two_first_order_lags():
    """After a step of the setpoint, the unit follows chamber (tau_c) and unit (tau_u) lags
    in series: T = T1 - dT (tau_u e^-t/tau_u - tau_c e^-t/tau_c) / (tau_u - tau_c)."""
    s = Schedule(setpoints_C=(20.0, 35.0), soak_s=3000.0)
    truth = preset_truth(noise=NoiseModel(temp_noise_C=0.0))
    c = simulate_campaign(truth, schedule=s, seed=0)
    unit_T = c.t - np.asarray(s.self_heating_C)
    np.testing.assert_allclose(unit_T[:12], 20.0, atol=1e-12)  # started at 20 degC, setpoint 20
    t0 = s.soak_s + 12 * (s.move_s + s.tau_s)  # the second setpoint is commanded here
    t = c.time_s[12:] - t0
    tc, tu = s.chamber_time_constant_s, s.unit_time_constant_s
    analytic = 35.0 - 15.0 * (tu * np.exp(-t / tu) - tc * np.exp(-t / tc)) / (tu - tc)
    rate = 15.0 * (np.exp(-t / tu) - np.exp(-t / tc)) / (tu - tc)
    assert np.all(np.diff(unit_T[12:, 0]) > 0)
    # integrated on a 5 s grid: the scheme's error is O(dt^2) per step, far below 1e-4 degC
    np.testing.assert_allclose(unit_T[12:, 0], analytic, rtol=0, atol=1e-4)
    _, _, sim_rate = thermal_history(s, c.time_s, np.array([0.0, t0]), np.array(s.setpoints_C))
    np.testing.assert_allclose(sim_rate[12:], rate, rtol=1e-3)


# -- noise ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def noise_pair():
    """The same campaign with and without output noise: their difference is the noise."""
    def run(Q, dof=None):
        return simulate(Q_V2s=Q, heavy_tails_dof=dof, seed=21)[1]
    return run


def test_output_noise_has_variance_Q_over_tau(noise_pair):
    Q, tau = 3e-9, 30.0
    noisy, clean = noise_pair(Q), noise_pair(0.0)
    assert (noisy.tau_s == tau).all()
    r = (noisy.w - clean.w).ravel()
    sigma = math.sqrt(Q / tau)
    statistic = np.sum((r / sigma) ** 2)  # known zero mean: chi-square with N dof
    lo, hi = chi2_bounds(r.size)
    assert lo < statistic < hi, (statistic, lo, hi, np.std(r) / sigma)
    # and the difference is centred (t-bound on the mean at the same level)
    assert abs(r.mean()) < stats.norm.ppf(1 - ALPHA / 2) * sigma / math.sqrt(r.size)


def test_sd_and_n_samples_describe_the_same_noise(noise_pair):
    """sd of the raw samples at f_s: sd^2 ~ Q f_s chi2(n-1)/(n-1), so sd/sqrt(n) = sqrt(Q/tau)."""
    Q = 3e-9
    c = noise_pair(Q)
    fs = NoiseModel().sample_rate_hz
    assert (c.n_samples == round(30.0 * fs)).all()
    dof = c.n_samples[:, None] - 1
    statistic = np.sum(c.sd ** 2 * dof / (Q * fs))
    lo, hi = chi2_bounds(int(np.sum(np.broadcast_to(dof, c.sd.shape))))
    assert lo < statistic < hi
    np.testing.assert_allclose(np.mean(c.output_sigma() ** 2), Q / 30.0, rtol=1e-2)


def test_temperature_reading_noise(noise_pair):
    truth = preset_truth(noise=NoiseModel(temp_noise_C=0.0))
    clean = simulate_campaign(truth, seed=5)
    truth.noise = NoiseModel(temp_noise_C=0.01)
    noisy = simulate_campaign(truth, seed=5)
    r = (noisy.t - clean.t).ravel() / 0.01
    lo, hi = chi2_bounds(r.size)
    assert lo < np.sum(r ** 2) < hi


def test_gaussian_noise_has_kurtosis_three(noise_pair):
    r = (noise_pair(3e-9).w - noise_pair(0.0).w).ravel()
    # sample kurtosis of N normal draws: mean 3, standard deviation sqrt(24 / N)
    bound = stats.norm.ppf(1 - ALPHA / 2) * math.sqrt(24.0 / r.size)
    assert abs(stats.kurtosis(r, fisher=False) - 3.0) < bound


def test_heavy_tails_produce_kurtosis_above_three(noise_pair):
    r = (noise_pair(3e-9, dof=3.0).w - noise_pair(0.0).w).ravel()
    gaussian_bound = 3.0 + stats.norm.ppf(1 - ALPHA / 2) * math.sqrt(24.0 / r.size)
    assert stats.kurtosis(r, fisher=False) > gaussian_bound
    # the heavy_tails effect switches Student-t (3 dof) on through the effect list too
    truth, c = simulate(effects=DEFAULT_EFFECTS + ("heavy_tails",), seed=21)
    assert truth.noise.heavy_tails_dof == 3.0
    np.testing.assert_array_equal(c.w, noise_pair(3e-9, dof=3.0).w)


def test_heavy_tails_need_a_finite_variance():
    with pytest.raises(ValueError, match="exceed 2"):
        simulate_campaign(preset_truth(noise=NoiseModel(heavy_tails_dof=2.0)))


def test_noiseless_campaign_is_the_model(noise_pair):
    """With Q = 0 the outputs are Model.predict at the campaign's covariates (no bench errors)."""
    truth = preset_truth("a18-silicon", DEFAULT_EFFECTS, noise=NoiseModel(Q_V2s=0.0, temp_noise_C=0.0))
    c = simulate_campaign(truth, schedule=Schedule(setpoints_C=(20.0, 60.0)), seed=0)
    model = truth.model()
    cov = c.covariates()  # temperatures as read (= true sensor temperatures here)
    w = np.stack(model.predict(model.to_internal(truth.parameters), cov, c.gravity_g), axis=1)
    # the simulator uses the true rate, the campaign a finite-difference one; no thermal_lag: no matter
    np.testing.assert_allclose(c.w, w, rtol=0, atol=1e-15)


def test_two_lag_step_solves_its_differential_equations():
    from triadcal.models.thermal_environment import step_sequence, two_lag_step

    tau_c, tau_u = 600.0, 1200.0
    x = np.linspace(0.0, 5000.0, 2001)
    c, u, rate = two_lag_step(x, 70.0, 20.0, 19.0, tau_c, tau_u)
    h = x[1] - x[0]
    assert np.allclose(np.gradient(c, h)[1:-1], ((70.0 - c) / tau_c)[1:-1], atol=1e-5)
    assert np.allclose(np.gradient(u, h)[1:-1], ((c - u) / tau_u)[1:-1], atol=1e-5)
    assert np.allclose(rate, (c - u) / tau_u)
    assert c[0] == 20.0 and u[0] == 19.0
    # a sequence of steps is continuous at each step
    starts, sps = [0.0, 3000.0], [70.0, -40.0]
    t = np.array([2999.999, 3000.0, 3000.001])
    cc, uu, _ = step_sequence(t, starts, sps, 20.0, tau_c, tau_u)
    assert np.ptp(cc) < 1e-3 and np.ptp(uu) < 1e-3
