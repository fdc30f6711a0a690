"""The paper's classical method (eq. 2-3 + linear thermal correction): fit_classical.

Tolerances come from theory: exact tilt cancellation (round-off only), first-order
propagation (finite-difference step error only), and sampling errors of simulated
spreads (stated at each test).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from triadcal.estimation.classical import ClassicalPlanError, fit_classical
from triadcal.uncertainty.classical_sd import classical_angle_sd, classical_angle_sd_default_plan
from triadcal.io.bench_csv import read_bench_csv, write_bench_csv
from triadcal.models.campaign import DEFAULT_PLAN, Campaign
from triadcal.models.model import Covariates
from triadcal.models.sensor import ANGLE_NAMES
from triadcal.models.simulate import NoiseModel, Schedule, preset_truth, simulate_campaign
from triadcal.models.units import ARCSEC

ANGLES = [f"Ca_{ab}" for ab in ANGLE_NAMES]
ONE_SETPOINT = Schedule(setpoints_C=(20.0,))


def test_tilt_cancels_without_noise():
    """60" bench tilt, no noise: the half-turn pairs cancel the tilt exactly (eq. 2-3)."""
    truth = preset_truth("ak18-quartz", effects=["bench_tilt"], noise=NoiseModel(Q_V2s=0, temp_noise_C=0))
    assert math.hypot(truth.parameters["tilt_x"], truth.parameters["tilt_y"]) == pytest.approx(60.0)
    result = fit_classical(simulate_campaign(truth, schedule=ONE_SETPOINT, seed=3))
    for n in ANGLES:
        assert abs(result[n].value - truth.parameters[n]) < 0.01, n
    # eq. 2 normalises by the measured norm, which a tilt shortens by cos(delta): K and S come out
    # divided by cos(delta) (4.2e-8 for 60"); the tilt estimated from the redundant positions
    # multiplies them back (2026-11-30), so without noise they are the truth
    assert result.extra["per_setpoint"][0]["tilt_arcsec"] == pytest.approx(60.0, abs=1e-3)
    for a in "xyz":
        assert result[f"K_{a}"].value == pytest.approx(truth.parameters[f"K_{a}"], rel=1e-12)
        assert result[f"S_{a}"].value == pytest.approx(truth.parameters[f"S_{a}"], rel=1e-9)
    assert result.method == "classical"
    assert "tilt_delta" not in result.parameters and "Ca_xy_tempco" not in result.parameters
    assert any("single setpoint" in n for n in result.notes)


def test_tilt_cancels_through_thermal_campaign_without_noise():
    """Same with tempcos over 15 setpoints: the line recovers values and slopes. The three
    sensors self-heat equally here, so the paper's mean temperature is each row's own."""
    effects = ["bench_tilt", "angle_tempco"]
    truth = preset_truth("ak18-quartz", effects=effects, noise=NoiseModel(Q_V2s=0, temp_noise_C=0))
    # a long soak so that the temperature is steady during the 12 visits of a setpoint
    schedule = Schedule(soak_s=30000.0, self_heating_C=(0.3, 0.3, 0.3))
    result = fit_classical(simulate_campaign(truth, schedule=schedule, seed=0))
    for n in ANGLES:
        assert abs(result[n].value - truth.parameters[n]) < 0.01, n
        assert abs(result[n + "_tempco"].value - truth.parameters[n + "_tempco"]) < 1e-3, n
    assert set(result.effects) == {"angle_tempco", "scale_tempco", "bias_tempco"}
    assert result.reference_temperature_C == 20.0
    assert len(result.extra["per_setpoint"]) == 15


def test_mean_versus_own_sensor_temperature():
    """Unequal self-heating (0.30, 0.35, 0.25 degC): regressing on the mean temperature
    shifts the value at 20 degC by tempco * (t_a - mean) (0.5"/degC * 0.05 degC = 0.025" for
    Ca_yx); regressing each row on its own sensor recovers the model's convention exactly."""
    truth = preset_truth("ak18-quartz", effects=["bench_tilt", "angle_tempco"],
                         noise=NoiseModel(Q_V2s=0, temp_noise_C=0))
    c = simulate_campaign(truth, schedule=Schedule(soak_s=30000.0), seed=0)
    mean, own = fit_classical(c, temperature="mean"), fit_classical(c)      # own: the default
    offsets = {"x": 0.0, "y": 0.05, "z": -0.05}   # self-heating minus its mean over the sensors
    for n in ANGLES:
        tc = truth.parameters[n + "_tempco"]
        assert abs(own[n].value - truth.parameters[n]) < 0.01, n
        assert mean[n].value - truth.parameters[n] == pytest.approx(tc * offsets[n[3]], abs=0.005), n
        assert mean[n + "_tempco"].value == pytest.approx(own[n + "_tempco"].value, abs=1e-6)


def test_pairing_comes_from_kinematics_not_labels(tmp_path):
    """Relabelled and reordered positions give the same estimate."""
    truth = preset_truth("ak18-quartz", effects=["bench_tilt"], noise=NoiseModel(Q_V2s=3e-9))
    plan = {f"Q{k}": v for k, v in zip("ABCDEFGHIJKL", reversed(list(DEFAULT_PLAN.values())))}
    a = fit_classical(simulate_campaign(truth, schedule=ONE_SETPOINT, seed=5))
    b = fit_classical(simulate_campaign(truth, plan=plan, schedule=ONE_SETPOINT, seed=5))
    # different noise draws per visit order: compare with the truth at 5 sigma of the analytic SD
    sd = classical_angle_sd(Q_V2s=3e-9, tau_s=30.0)
    for n in ANGLES:
        assert abs(a[n].value - truth.parameters[n]) < 5 * sd[n]
        assert abs(b[n].value - truth.parameters[n]) < 5 * sd[n]


def test_general_plan_with_repeats():
    """A 24-position plan (every default position twice) works; u shrinks by about sqrt(2)."""
    plan = dict(DEFAULT_PLAN)
    plan.update({k + "r": v for k, v in DEFAULT_PLAN.items()})
    sd12 = classical_angle_sd(Q_V2s=3e-9, tau_s=30, sigma_position_arcsec=5, sigma_wobble_arcsec=2)
    sd24 = classical_angle_sd(plan, Q_V2s=3e-9, tau_s=30, sigma_position_arcsec=5, sigma_wobble_arcsec=2)
    for n in ANGLES:
        assert sd24[n] == pytest.approx(sd12[n] / math.sqrt(2), rel=1e-9)
    truth = preset_truth("ak18-quartz", effects=["bench_tilt"], noise=NoiseModel(Q_V2s=0, temp_noise_C=0))
    r = fit_classical(simulate_campaign(truth, plan=plan, schedule=ONE_SETPOINT, seed=0))
    for n in ANGLES:
        assert abs(r[n].value - truth.parameters[n]) < 0.01


def test_refuses_plan_without_down_positions():
    truth = preset_truth("ak18-quartz", effects=[], noise=NoiseModel())
    plan = {k: v for k, v in DEFAULT_PLAN.items() if k not in ("P07", "P08", "P11")}
    campaign = simulate_campaign(truth, plan=plan, schedule=ONE_SETPOINT, seed=0)
    with pytest.raises(ClassicalPlanError) as exc:
        fit_classical(campaign)
    msg = str(exc.value)
    assert "setpoint 20 degC" in msg
    missing = msg.split("missing:")[1].split("(")[0]
    assert "-X up" in missing and "-Z up" not in missing  # P12 still points -Z up


def test_refuses_two_units():
    truth = preset_truth("ak18-quartz", effects=[], noise=NoiseModel())
    c = simulate_campaign(truth, schedule=ONE_SETPOINT, seed=0)
    c.unit[:6] = "OTHER"
    with pytest.raises(ValueError, match="one unit"):
        fit_classical(c)


def _campaign_from_errors(truth, e1, e2, wob, noise_w):
    """A one-setpoint default-plan campaign with given per-visit bench errors (rad) and output noise."""
    model = truth.model()
    a1 = np.array([v[0] for v in DEFAULT_PLAN.values()])
    a2 = np.array([v[1] for v in DEFAULT_PLAN.values()])
    n = len(a1)
    T = np.full(n, 20.0)
    cov = Covariates(axis1=np.radians(a1), axis2=np.radians(a2), temp=(T, T, T), temp_rate=(0 * T,) * 3,
                     branch=0 * T, time_s=np.arange(n) * 50.0, axis1_error=e1, axis2_error=e2, wobble=wob)
    w = np.stack(model.predict(model.to_internal(truth.parameters), cov, 1.0), axis=1) + noise_w
    return Campaign(unit=np.full(n, "U"), setpoint_C=T.copy(), direction=np.full(n, "none"),
                    time_s=np.arange(n) * 50.0, position=np.array(list(DEFAULT_PLAN)),
                    axis1_deg=a1, axis2_deg=a2, tau_s=np.full(n, 30.0), w=w, t=np.stack([T] * 3, axis=1),
                    cycle=np.zeros(n, int), state=np.full(n, "initial"))


def test_analytic_sd_matches_numerical_linearisation():
    """classical_angle_sd (exact derivatives, closed form) vs finite differences of the
    whole estimator (Model.predict -> fit_classical) on a tilted bench with real angles.
    Agreement to 1e-3 relative: second-order terms (angle x error ~ 1e-3) only."""
    Q, tau, s1, s2 = 3e-9, 30.0, 5.0, 2.0
    truth = preset_truth("a18-silicon", effects=["bench_tilt"], noise=NoiseModel(Q_V2s=0))
    n = len(DEFAULT_PLAN)
    zero = np.zeros(n)
    base = fit_classical(_campaign_from_errors(truth, zero, zero, zero, np.zeros((n, 3))))
    var = {k: 0.0 for k in ANGLES}
    h = 1.0 * ARCSEC
    for kind, sigma in (("e1", s1 * ARCSEC), ("e2", s1 * ARCSEC), ("w", s2 * ARCSEC)):
        for i in range(n):
            vals = []
            for sgn in (1, -1):
                e = {"e1": zero.copy(), "e2": zero.copy(), "w": zero.copy()}
                e[kind][i] = sgn * h
                vals.append(fit_classical(_campaign_from_errors(truth, e["e1"], e["e2"], e["w"], np.zeros((n, 3)))))
            for k in ANGLES:
                d = (vals[0][k].value - vals[1][k].value) * ARCSEC / (2 * h)
                var[k] += (d * sigma / ARCSEC) ** 2
    hv = 1e-6
    for i in range(n):
        for a in range(3):
            dw = np.zeros((n, 3))
            dw[i, a] = hv
            r = fit_classical(_campaign_from_errors(truth, zero, zero, zero, dw))
            for k in ANGLES:
                d = (r[k].value - base[k].value) / hv
                var[k] += d ** 2 * Q / tau
    analytic = classical_angle_sd(Q_V2s=Q, tau_s=tau, sigma_position_arcsec=s1, sigma_wobble_arcsec=s2,
                                  K_g_per_V=1.0)
    closed = classical_angle_sd_default_plan(Q_V2s=Q, tau_s=tau, sigma_position_arcsec=s1,
                                             sigma_wobble_arcsec=s2)
    for k in ANGLES:
        assert math.sqrt(var[k]) == pytest.approx(analytic[k], rel=1e-3), k
        assert closed[k] == pytest.approx(analytic[k], rel=1e-12), k
    # the geometry: Ca_xy sees the wobble, the others one bench axis (docs/classical.md)
    assert analytic["Ca_xy"] == pytest.approx(0.5 * math.hypot(2.0627, 2.0), rel=1e-3)
    assert analytic["Ca_zy"] == pytest.approx(0.5 * math.hypot(2.0627, 5.0), rel=1e-3)


@pytest.mark.slow
def test_spread_over_500_campaigns_matches_analytic_sd():
    """SD of the classical angles over 500 simulated campaigns (one setpoint, 12 positions,
    60" tilt, no thermal effects, Q = 3e-9 V^2 s, tau = 30 s, sigma_1 = 5", sigma_2 = 2")
    agrees with classical_angle_sd within 10%. With 500 samples the relative sampling
    error of an SD is 1/sqrt(2 * 499) = 3.2%, so 10% is about 3 sigma (for each of the six
    angles; the chance that any one fails by sampling alone is about 1.6%)."""
    noise = NoiseModel(Q_V2s=3e-9, sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0)
    truth = preset_truth("ak18-quartz", effects=["bench_tilt"], noise=noise)
    est = np.array([[fit_classical(simulate_campaign(truth, schedule=ONE_SETPOINT, seed=1000 + s))[n].value
                     for n in ANGLES] for s in range(500)])
    sd = np.std(est, axis=0, ddof=1)
    analytic = classical_angle_sd(Q_V2s=3e-9, tau_s=30.0, sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0)
    for k, n in enumerate(ANGLES):
        assert abs(sd[k] / analytic[n] - 1) < 0.10, (n, sd[k], analytic[n])
        # and the mean is unbiased (3.5 standard errors of the mean)
        assert abs(np.mean(est[:, k]) - truth.parameters[n]) < 3.5 * analytic[n] / math.sqrt(500), n


def test_library_roundtrip_recovers_angles_within_4u(tmp_path):
    """simulate -> bench CSV -> read -> fit_classical, with noise and bench errors, 15 setpoints."""
    noise = NoiseModel(Q_V2s=3e-9, sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0)
    truth = preset_truth("ak18-quartz", effects=["bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco"],
                         noise=noise)
    path = tmp_path / "c.csv"
    write_bench_csv(simulate_campaign(truth, seed=11), path)
    result = fit_classical(read_bench_csv(path))
    for n in ANGLES:
        assert abs(result[n].value - truth.parameters[n]) < 4 * result[n].u, n
        assert abs(result[n + "_tempco"].value - truth.parameters[n + "_tempco"]) < 4 * result[n + "_tempco"].u
    assert result.fit["noise_source"] == "residuals"
    # the per-setpoint estimates are there for the thermal residual test
    ps = result.extra["per_setpoint"]
    assert [p["setpoint_C"] for p in ps][:3] == [20.0, 35.0, 55.0]
    assert {"direction", "mean_temperature_C", "parameters"} <= set(ps[0])
    assert ps[0]["parameters"]["Ca_xy"]["unit"] == "arcsec" and ps[0]["parameters"]["Ca_xy"]["u"] > 0
    # the JSON round trip keeps the contract
    result.save(tmp_path / "r.json")
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["method"] == "classical" and d["parameters"]["Ca_xy_tempco"]["unit"] == "arcsec/degC"
    assert d["parameters"]["K_x_tempco"]["unit"] == "ppm/degC" and d["parameters"]["S_x_tempco"]["unit"] == "ug/degC"


def test_sd_noise_source_is_used_when_asked():
    truth = preset_truth("ak18-quartz", effects=["bench_tilt"], noise=NoiseModel(Q_V2s=3e-9))
    c = simulate_campaign(truth, schedule=ONE_SETPOINT, seed=2)
    r = fit_classical(c, noise="sd")
    assert r.fit["noise_source"] == "sd"
    expected = classical_angle_sd(Q_V2s=3e-9, tau_s=30.0)
    for n in ANGLES:  # sd/sqrt(n) from 3000 samples: u within a few % of the analytic noise-only SD
        assert r[n].u == pytest.approx(expected[n], rel=0.05), n


def _fit_is_registered() -> bool:
    from triadcal.cli import build_parser

    sub = [a for a in build_parser()._actions if a.dest == "command"]
    return bool(sub) and "fit" in sub[0].choices


@pytest.mark.skipif(not _fit_is_registered(), reason="`triadcal fit` is not registered yet")
def test_cli_simulate_then_fit_classical_within_4u(tmp_path):
    """`triadcal simulate` (default: quartz unit, 15 setpoints, tilt, tempcos, hysteresis)
    then `triadcal fit --method classical` recovers every simulated angle within 4 u."""
    csv, truth_path, out = tmp_path / "c.csv", tmp_path / "t.json", tmp_path / "r.json"
    exe = [sys.executable, "-m", "triadcal.cli"]
    subprocess.run(exe + ["simulate", "-o", str(csv), "--truth", str(truth_path), "--seed", "7"],
                   check=True, capture_output=True, text=True)
    run = subprocess.run(exe + ["fit", str(csv), "--method", "classical", "--json", str(out)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    result, truth = json.loads(out.read_text()), json.loads(truth_path.read_text())
    assert result["method"] == "classical"
    for n in ANGLES:
        p, true = result["parameters"][n], truth["parameters"][n]["value"]
        assert p["unit"] == "arcsec"
        assert abs(p["value"] - true) < 4 * p["u"], (n, p, true)


@pytest.mark.parametrize("extra", [["--effects", "bench_tilt,angle_tempco"], ["--thermal-order", "2"],
                                   ["--hysteresis-form", "play"], ["--loss", "huber"], ["--strict"],
                                   ["--effects", "bench_tilt,hysteresis_play"], ["--thermal-lag-form", "housing"]])
def test_cli_classical_refuses_what_it_would_ignore(extra, capsys):
    """The classical method is the paper's eq. 2 per setpoint and its linear thermal correction;
    the joint model's effects, forms, orders and losses were silently ignored with it. They are
    refused, named (the default --effects is the classical method's own and passes)."""
    from triadcal.cli import main

    assert main(["fit", "--example", "--method", "classical", *extra]) == 1
    err = capsys.readouterr().err
    assert "--method classical is the paper's eq. 2" in err and extra[0] in err, err
    assert main(["fit", "--example", "--method", "classical", "--quiet"]) == 0
