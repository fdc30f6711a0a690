"""Joint least-squares fit: recovery, identifiability, robust loss, outputs."""

import json
import subprocess
import sys

import numpy as np
import pytest

from triadcal.estimation.joint import IdentifiabilityError, fit_joint
from triadcal.estimation.result import CalibrationResult
from triadcal.io.bench_csv import write_bench_csv
from triadcal.models.campaign import DEFAULT_PLAN, nominal_gravity
from triadcal.models.simulate import NoiseModel, Schedule, preset_truth, simulate_campaign


def z_scores(result, truth):
    return {n: (p.value - truth.parameters[n]) / p.u for n, p in result.parameters.items()
            if n in truth.parameters}


@pytest.mark.parametrize("preset", ["ak18-quartz", "a18-silicon"])
def test_joint_recovers_truth_within_4u(preset):
    truth = preset_truth(preset)
    result = fit_joint(simulate_campaign(truth, seed=11))
    assert result.status == "ok"
    z = z_scores(result, truth)
    assert set(z) == set(truth.parameters)
    bad = {n: round(v, 2) for n, v in z.items() if abs(v) > 4}
    assert not bad, bad
    assert 0.8 < result.fit["chi2_dof"] < 1.2
    # tilt in its polar form: 60" toward 30 deg
    assert abs(result["tilt_delta"].value - 60.0) < 4 * result["tilt_delta"].u
    assert abs(result["tilt_beta"].value - 30.0) < 4 * result["tilt_beta"].u


def test_every_effect_of_the_model_is_recovered():
    # not thermal_lag: the simulator writes it in the rate form T - tau dT/dt, which a stepped campaign's
    # exponential approach makes a biased form of the physical first-order lag, and the lag_form gate
    # refuses it (tests/test_lag_form.py); its recovery is tested on ramps (tests/test_ramp_rate.py) and
    # over the history (tests/test_thermal_lag_forms.py)
    effects = ["bench_tilt", "angle_tempco", "hysteresis", "scale_tempco", "bias_tempco",
               "bias_drift", "scale_nonlinearity", "scale_asymmetry"]
    truth = preset_truth("a18-silicon", effects, noise=NoiseModel(temp_noise_C=0.0))
    sched = Schedule(soak_s=1800.0)   # short soak: the unit is still moving, so the lag is seen
    result = fit_joint(simulate_campaign(truth, schedule=sched, seed=5), effects)
    assert result.status == "ok", result.notes
    z = z_scores(result, truth)
    assert set(z) == set(truth.parameters)
    assert max(abs(v) for v in z.values()) < 4.5, {n: v for n, v in z.items() if abs(v) > 4}


def test_heating_only_campaign_holds_hysteresis_and_says_why():
    truth = preset_truth()
    # the unit soaked at -40 degC (from 20 the first setpoint would be reached by cooling: both branches)
    c = simulate_campaign(truth, schedule=Schedule(setpoints_C=(-40.0, -10.0, 20.0, 50.0, 70.0), start_C=-40.0), seed=2)
    result = fit_joint(c)
    assert not any(n.endswith("_hysteresis") for n in result.parameters)
    assert sum("hysteresis" in note and "heating" in note for note in result.notes) == 6
    with pytest.raises(IdentifiabilityError, match="Ca_xy_hysteresis, Ca_xz_hysteresis.*: hysteresis needs visits on both"):
        fit_joint(c, unidentifiable="refuse")


def test_one_temperature_holds_the_tempcos():
    c = simulate_campaign(preset_truth(), schedule=Schedule(setpoints_C=(20.0,)), seed=2)
    result = fit_joint(c)
    assert not any(n.endswith("_tempco") for n in result.parameters)
    assert any("K_x_tempco" in note and "more than one temperature" in note for note in result.notes)
    assert {"Ca_xy", "K_x", "S_x", "tilt_x"} <= set(result.parameters)


def test_plan_that_cannot_see_a_parameter_is_named():
    plan = {k: DEFAULT_PLAN[k] for k in ("P01", "P02", "P03", "P04")}   # only Y up and down
    truth = preset_truth(effects=["bench_tilt"])
    c = simulate_campaign(truth, plan=plan, schedule=Schedule(setpoints_C=(20.0,)), seed=1)
    with pytest.raises(IdentifiabilityError) as err:
        fit_joint(c, ["bench_tilt"], unidentifiable="refuse")
    # refused before the fit, naming the axes the poses never turn through gravity (2026-12-02; before,
    # by the null space: "K_x ... not separable")
    assert "K_x, K_z cannot be told from S_x, S_z" in str(err.value), str(err.value)


def test_weights_and_estimated_noise():
    truth = preset_truth()
    c = simulate_campaign(truth, seed=4)
    known = fit_joint(c)
    c.sd = None
    c.n_samples = None
    c.metadata.pop("Q_V2s")
    est = fit_joint(c)
    assert not est.fit["noise_known"] and known.fit["noise_known"]
    # with the noise estimated, its intensity Q is reported (weights 1/sqrt(tau)) ...
    # (the known weights are the sample sd of 3000 samples, 1.3 % scatter each: hence 2 %)
    assert est.fit["Q_estimate"] == pytest.approx(3e-9 * known.fit["chi2_dof"], rel=0.02)
    # ... and agree with the known-noise ones within the scatter of a variance estimate
    ratio = est["Ca_xy"].u / known["Ca_xy"].u
    assert abs(ratio - 1) < 4 * np.sqrt(1 / (2 * 508))


def test_robust_loss_resists_outliers_and_is_recorded():
    truth = preset_truth(noise=NoiseModel(heavy_tails_dof=2.5))
    c = simulate_campaign(truth, seed=8)
    c.w[17, 0] += 200 * np.sqrt(3e-9 / 30)   # one gross outlier on X, in a position where X is horizontal
    l2 = fit_joint(c)
    hub = fit_joint(c, loss="huber")
    assert hub.fit["loss"] == "huber"
    err = lambda r: np.mean([abs(r[n].value - truth.parameters[n]) / r[n].u for n in truth.parameters])
    assert err(hub) < err(l2)


def test_apply_returns_gravity_in_imu_frame():
    truth = preset_truth(noise=NoiseModel(Q_V2s=0.0, temp_noise_C=0.0))
    sched = Schedule(setpoints_C=(20.0, 45.0, -5.0))
    c = simulate_campaign(truth, schedule=sched, seed=0)
    result = fit_joint(c, ["angle_tempco", "scale_tempco", "bias_tempco", "bench_tilt"])
    a = result.apply(c.w, c.t)
    # the bench's tilt is not part of the unit's calibration: compare with the tilted gravity
    g = nominal_gravity(c.axis1_deg, c.axis2_deg)
    assert np.max(np.abs(np.linalg.norm(a, axis=1) - 1.0)) < 1e-6
    assert np.max(np.abs(a - g)) < 5e-4   # 60" tilt = 2.9e-4 rad


def test_cli_json_and_netcdf(tmp_path):
    csv = tmp_path / "c.csv"
    truth = preset_truth()
    write_bench_csv(simulate_campaign(truth, seed=21), csv)
    out, nc = tmp_path / "r.json", tmp_path / "r.nc"
    proc = subprocess.run([sys.executable, "-m", "triadcal.cli", "fit", str(csv), "--method", "joint",
                           "--json", str(out), "--netcdf", str(nc)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert "Ca_xy" in proc.stdout and "chi2/dof" in proc.stdout
    d = json.loads(out.read_text())
    assert d["format"] == "triadcal.result" and d["version"] == 1 and d["method"] == "joint"
    assert d["parameters"]["Ca_xy"]["unit"] == "arcsec"
    assert d["parameters"]["K_x_tempco"]["unit"] == "ppm/degC"
    assert d["parameters"]["tilt_beta"]["unit"] == "deg"
    assert len(d["correlation"]["names"]) == d["fit"]["n_params"]
    R = np.array(d["correlation"]["matrix"])
    assert np.allclose(np.diag(R), 1.0) and np.allclose(R, R.T)
    back = CalibrationResult.load(out)
    assert back["Ca_xy"].value == d["parameters"]["Ca_xy"]["value"]

    import xarray as xr
    ds = xr.open_dataset(nc, engine="h5netcdf")
    assert ds["residual_normalised"].shape == (180, 3)
    assert set(ds["direction"].values.tolist()) == {"none", "heating", "cooling"}
    assert float((ds["residual_normalised"] ** 2).mean()) == pytest.approx(d["fit"]["chi2_dof"], rel=0.1)


def test_cli_refuses_bad_effect_and_strict(tmp_path):
    csv = tmp_path / "c.csv"
    write_bench_csv(simulate_campaign(preset_truth(), schedule=Schedule(setpoints_C=(20.0,)), seed=1), csv)
    p = subprocess.run([sys.executable, "-m", "triadcal.cli", "fit", str(csv), "--effects", "bench_tilt,wobble"],
                       capture_output=True, text=True)
    assert p.returncode == 1 and "unknown effect(s) wobble" in p.stderr and "Traceback" not in p.stderr
    p = subprocess.run([sys.executable, "-m", "triadcal.cli", "fit", str(csv), "--strict"],
                       capture_output=True, text=True)
    assert p.returncode == 1 and "Ca_xy_tempco" in p.stderr and "more than one temperature" in p.stderr


def test_joint_model_brings_thermal_residuals_to_the_noise_where_the_linear_correction_leaves_hysteresis(capsys):
    """Issue 3: with hysteresis present (silicon A-18-like unit, +-22..40"), compare the
    per-setpoint angles of eq. 2 with (a) the paper's linear thermal correction and (b) the
    joint model (line + hysteresis branch), both in units of the per-setpoint uncertainty."""
    from triadcal.estimation.classical import fit_classical

    truth = preset_truth("a18-silicon")
    c = simulate_campaign(truth, seed=3)
    classical = fit_classical(c)
    joint = fit_joint(c)
    blocks = c.setpoint_blocks
    chi_lin, chi_joint, res_lin = [], [], {}
    for k, row in enumerate(classical.extra["per_setpoint"]):
        # the visits of this setpoint (time of the block's mid-visit identifies it)
        b = blocks[np.argmin(np.abs(c.time_s - row["time_s"]))]
        idx = blocks == b
        branch = {"heating": -1.0, "cooling": 1.0, "none": 0.0}[row["direction"]]
        for ab in ("xy", "xz", "yx", "yz", "zx", "zy"):
            name = f"Ca_{ab}"
            theta, u = row["parameters"][name]["value"], row["parameters"][name]["u"]
            T_mean = row["mean_temperature_C"]
            line = classical[name].value + classical[f"{name}_tempco"].value * (T_mean - 20.0)
            t_a = float(np.mean(c.t[idx, "xyz".index(ab[0])]))
            model = (joint[name].value + joint[f"{name}_tempco"].value * (t_a - 20.0)
                     + joint[f"{name}_hysteresis"].value * branch)
            chi_lin.append(((theta - line) / u) ** 2)
            chi_joint.append(((theta - model) / u) ** 2)
            res_lin.setdefault(name, []).append(theta - line)
    n = len(chi_joint)
    chi2_lin, chi2_joint = float(np.mean(chi_lin)), float(np.mean(chi_joint))
    rms_lin = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in res_lin.items()}
    with capsys.disabled():
        print(f"\nthermal residuals of the per-setpoint angles ({n} = 15 setpoints x 6 angles):"
              f"\n  paper's linear correction: chi2/N = {chi2_lin:.1f}, RMS by angle "
              + ", ".join(f"{k} {v:.1f}\"" for k, v in rms_lin.items())
              + f"\n  joint model (line + hysteresis): chi2/N = {chi2_joint:.2f}")
    # joint: chi2 of 90 terms at the noise; 99.9 % quantile of chi2_90 / 90 is 1.47
    assert chi2_joint < 1.47
    # linear: the hysteresis stays, of the size of the loop's half-width (22-40")
    assert chi2_lin > 100
    for ab, h in (("xy", 35.0), ("yx", 40.0), ("zy", 33.0)):
        assert 0.6 * h < rms_lin[f"Ca_{ab}"] < 1.2 * h


def test_a_fit_that_did_not_converge_says_so():
    c = simulate_campaign(preset_truth(), seed=1)
    result = fit_joint(c, max_iter=1)
    assert result.status == "not_converged"
    assert any("stopped after 1 iterations" in n for n in result.notes)
    assert fit_joint(c).status == "ok"


# -- the lab's own bench errors as variance components (issue 16, item 2) ----------------------
def test_bench_errors_from_the_lab_file_enter_the_fit(tmp_path):
    """A campaign whose bench errs by sigma_1 = 5", sigma_2 = 2" per visit (the paper's eq. 4
    example): the fit with output noise alone misses the data (chi2/dof ~ 4: model_mismatch,
    no answer); with the lab's figures as variance components chi2/dof is at the noise, the
    status ok, and the angles' u grows; the result says whether the bench is in its u."""
    from scipy import stats

    from triadcal.api import fit, simulate
    from triadcal.io.lab import EXAMPLE_LAB_TOML

    truth, campaign = simulate(sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0, seed=3)
    (tmp_path / "lab.toml").write_text(EXAMPLE_LAB_TOML)       # [bench] 5 and 2 arcsec
    a = fit(campaign, method="joint")
    b = fit(campaign, method="joint", lab=tmp_path / "lab.toml")
    assert a.status == "model_mismatch" and a.fit["chi2_dof"] > 2.5
    assert any(n.startswith("uncertainties are Type A only") for n in a.notes) and a.fit["bench_errors"] is None
    dof = b.fit["n_obs"] - b.fit["n_params"]
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], dof) / dof
    assert b.status == "ok" and lo < b.fit["chi2_dof"] < hi
    assert b.fit["bench_errors"] == {"sigma_position_arcsec": 5.0, "sigma_wobble_arcsec": 2.0,
                                     "source": f"lab file {tmp_path / 'lab.toml'}", "in_u": True}
    assert not any(n.startswith("uncertainties are Type A only") for n in b.notes)
    for n in ("Ca_xy", "Ca_zx"):
        assert b[n].u > 1.2 * a[n].u
        assert abs(b[n].value - truth.parameters[n]) < 4 * b[n].u
    # the certificate's budget does not count the bench twice
    from triadcal.uncertainty.angles import uncertainty_budget
    from triadcal.io.lab import load_lab

    budget = {c.source: c for c in uncertainty_budget(b, load_lab(tmp_path / "lab.toml")).components}
    assert budget["bench positioning"].contribution == 0.0 and "inside the angles' u" in budget["bench positioning"].basis


def test_bench_errors_need_a_known_output_noise():
    import pytest as _pytest

    from triadcal.api import simulate
    from triadcal.errors import InputError
    from triadcal.estimation.joint import BenchErrors, fit_joint

    _, campaign = simulate(seed=1)
    campaign.metadata.pop("Q_V2s", None)
    campaign.sd = None
    with _pytest.raises(InputError, match="add to a known output noise"):
        fit_joint(campaign, bench_errors=BenchErrors(5.0, 2.0))


def test_bench_errors_larger_than_the_data_show_are_said():
    """A campaign without bench errors fitted with the lab's 5"/2": u is conservative, and the
    result says the data scatter less than the stated errors predict (chi2 lower tail)."""
    from triadcal.api import simulate
    from triadcal.estimation.joint import BenchErrors, fit_joint

    _, campaign = simulate(seed=4)
    r = fit_joint(campaign, bench_errors=BenchErrors(5.0, 2.0))
    assert r.fit["chi2_dof"] < 0.7
    assert any("scatter less than the output noise plus the lab's bench errors" in n for n in r.notes)


def test_a_stuck_output_is_refused_naming_the_file_and_the_column(example, tmp_path):
    """A channel that reads one value in every visit, while the plan turns its axis through 2 g,
    is refused before the fit (it started the fit at K = 2e16 g/V, which ended in a non-finite
    Jacobian). The file is written with the project's writer and the value put in by hand."""
    import copy

    from triadcal.errors import InputError
    from triadcal.io.bench_csv import read_bench_csv

    c = copy.deepcopy(example)
    c.w[:, 1] = 0.25
    path = tmp_path / "stuck.csv"
    write_bench_csv(c, path)
    with pytest.raises(InputError, match=r"stuck\.csv: w_y is 0\.25 V in every one of the \d+ visits.*stuck"):
        fit_joint(read_bench_csv(path))
