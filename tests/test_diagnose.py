"""Tests of the diagnosis (triadcal diagnose / validate-diagnosis).

Statistical claims are checked by simulation with fixed seeds; the thresholds are the
issue's requirements, not tuned values. The validation over every effect (two magnitudes, the
left-out mode) is tests/test_diagnosis_validation.py.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from triadcal.errors import InputError
from triadcal.judgement.diagnose import FORM_CANDIDATES, diagnose
from triadcal.judgement.diagnosis_validation import VALIDATION_PLAN, VALIDATION_SOAK_S, scenario
from triadcal.models.campaign import Campaign, up_axis_label
from triadcal.models.effects import VOCABULARY
from triadcal.models.effects import heavy_tails as ht
from triadcal.models.effects import position_error as pe
from triadcal.models.model import Model
from triadcal.models.simulate import Schedule, preset_truth, simulate_campaign

REAL = Path("/work/shared/data/real")
REAL_CSV = REAL / "imucal_example_ferraris_session.csv"
REAL_LIST = REAL / "imucal_example_ferraris_session_list.json"
#: hand-placed poses of the Ferraris session -> bench angles giving that axis up (bench-csv.md)
FERRARIS_POSES = {"x_p": (90.0, 90.0), "x_a": (270.0, 90.0), "y_p": (0.0, 0.0), "y_a": (0.0, 180.0),
                  "z_p": (180.0, 90.0), "z_a": (0.0, 90.0)}
FERRARIS_RATE_HZ = 102.4   # README: the imucal session is sampled at 102.4 Hz


def ferraris_campaign(csv_path=REAL_CSV, list_path=REAL_LIST) -> Campaign:
    """A Campaign of the 6 static hand-placed poses of the imucal Ferraris session.

    Stand-in for `triadcal fit-raw` (not written yet): each pose's mean, sd and sample
    count; no temperature channel (a constant 20 degC), one 'none' setpoint, outputs in
    m/s^2. The pose is nominal (hand-placed: its true orientation is off by an unknown
    angle, which the diagnosis should find).
    """
    data = np.genfromtxt(csv_path, delimiter=",", names=True)
    poses = json.loads(Path(list_path).read_text())
    rows = []
    for name, (a1, a2) in FERRARIS_POSES.items():
        s, e = poses[name]["start"], poses[name]["end"]
        acc = np.column_stack([data["acc_x"][s:e], data["acc_y"][s:e], data["acc_z"][s:e]])
        rows.append((name, a1, a2, acc.mean(axis=0), acc.std(axis=0, ddof=1), len(acc),
                     0.5 * (s + e) / FERRARIS_RATE_HZ))
    n = len(rows)
    return Campaign(
        unit=np.full(n, "NilsPod-imucal"), setpoint_C=np.full(n, 20.0), direction=np.full(n, "none"),
        time_s=np.array([r[6] for r in rows]), position=np.array([r[0] for r in rows]),
        axis1_deg=np.array([r[1] for r in rows]), axis2_deg=np.array([r[2] for r in rows]),
        tau_s=np.array([r[5] / FERRARIS_RATE_HZ for r in rows]), w=np.array([r[3] for r in rows]),
        t=np.full((n, 3), 20.0), cycle=np.zeros(n, int), state=np.full(n, "initial"),
        sd=np.array([r[4] for r in rows]), n_samples=np.array([r[5] for r in rows]),
        metadata={"output_unit": "m/s2", "local_g_m_s2": "9.80665"}, source=str(csv_path))


def validation_campaign(effect: str, seed: int):
    truth, model = scenario(effect)
    return simulate_campaign(truth, plan=VALIDATION_PLAN, schedule=Schedule(soak_s=VALIDATION_SOAK_S),
                             seed=seed), model


# -- quick tests ----------------------------------------------------------------------------
def test_ferraris_poses_point_the_named_axis_up():
    labels = up_axis_label([v[0] for v in FERRARIS_POSES.values()], [v[1] for v in FERRARIS_POSES.values()])
    assert labels.tolist() == ["+X", "-X", "+Y", "-Y", "+Z", "-Z"]


def test_withheld_hysteresis_is_named_localised_and_the_gap_closes():
    c, model = validation_campaign("hysteresis", 7)
    d = diagnose(c, model, n_draws=200, seed=1)
    assert d.gap["significant"]
    assert d.verdict_effect == "hysteresis"
    top = [c_ for c_ in d.candidates if c_.effect == "hysteresis"][0]
    assert top.rank == 1 and top.refit["lr_p_value"] < 1e-6
    # localised: offsets per pose and branch explain the misfit best
    assert d.families[0]["family"] == "up_x_direction"
    assert any(s.family in ("up_x_direction", "direction") for s in d.where)
    after = top.refit["gap_after"]
    assert 0.8 <= after["chi2_dof"] <= 1.2 < d.gap["chi2_dof"]
    assert after["residual_rms_ug"] < top.refit["gap_before"]["residual_rms_ug"]
    assert after["significant_slices"] < top.refit["gap_before"]["significant_slices"]
    # the refit recovers the withheld half-widths (truth: ak18-quartz preset) within 4 u
    truth = preset_truth("ak18-quartz").parameters
    for n, p in top.refit["new_parameters"].items():
        assert abs(p["value"] - truth[n]) < 4 * p["u"], n
    # cross-branch prediction: hysteresis cannot be fitted on one branch -> nothing gained
    assert top.refit["cross_branch_delta_lpd"] == pytest.approx(0.0, abs=1e-6)


def test_clean_data_gives_a_null_verdict_and_a_valid_json(tmp_path):
    c, model = validation_campaign("clean", 3)
    d = diagnose(c, model, n_draws=200, seed=0)
    assert d.verdict_effect is None and not d.gap["significant"]
    path = tmp_path / "d.json"
    d.save(path)
    doc = json.loads(path.read_text())
    assert doc["format"] == "triadcal.diagnosis" and doc["version"] == 1
    assert doc["verdict"]["effect"] is None
    assert set(doc["model"]) == set(model)
    assert {"chi2_dof", "significant"} <= set(doc["gap"])
    for cand in doc["candidates"]:
        assert cand["effect"] in VOCABULARY + FORM_CANDIDATES and cand["effect"] not in model
    assert sorted(c_["rank"] for c_ in doc["candidates"]) == list(range(1, len(doc["candidates"]) + 1))


def test_thermal_lag_untestable_without_tempcos_and_invisible_without_rates():
    truth = preset_truth("ak18-quartz", ("bench_tilt", "bias_drift"))
    c = simulate_campaign(truth, schedule=Schedule(soak_s=1800), seed=2)
    d = diagnose(c, ("bench_tilt",), candidates=("thermal_lag", "bias_drift"), n_draws=100, cross_group=False)
    lag = [x for x in d.candidates if x.effect == "thermal_lag"][0]
    assert not lag.testable and "tempco" in lag.reason
    assert d.verdict_effect == "bias_drift"
    # a campaign at one temperature: tempcos and lag are invisible, said so, not faked
    one_T = simulate_campaign(preset_truth("ak18-quartz", ("bench_tilt",)),
                              schedule=Schedule(setpoints_C=(20.0, 20.0)), seed=1)
    d2 = diagnose(one_T, ("bench_tilt",), n_draws=100, cross_group=False)
    reasons = {x.effect: x.reason for x in d2.candidates if not x.testable}
    for e in ("angle_tempco", "scale_tempco", "bias_tempco", "hysteresis"):
        assert "invisible on this design" in reasons[e]


def test_position_error_variance_matches_a_monte_carlo_of_the_model():
    """The linearised variance of position_error.py against the model with drawn bench errors."""
    model = Model(("bench_tilt",))
    p = model.to_internal(preset_truth("ak18-quartz", ("bench_tilt",)).parameters)
    c = simulate_campaign(preset_truth("ak18-quartz", ("bench_tilt",)), plan=VALIDATION_PLAN,
                          schedule=Schedule(setpoints_C=(20.0,)), seed=0)
    cov = c.covariates()
    var = pe.output_variance(model, p, cov, 5.0, weights=(1.0, 1.0, 1.0))
    rng = np.random.default_rng(0)
    from dataclasses import replace
    from triadcal.models.units import ARCSEC
    draws = []
    for _ in range(400):
        e = rng.normal(0, 5.0 * ARCSEC, (3, c.n_visits))
        draws.append(np.stack(model.predict(p, replace(cov, axis1_error=e[0], axis2_error=e[1], wobble=e[2])), 1))
    mc = np.var(np.array(draws), axis=0, ddof=1)
    big = var > 0.1 * var.max()
    # 400 draws: relative sd of a variance sqrt(2/399) = 7 %; 5 sd
    assert np.all(np.abs(mc[big] / var[big] - 1) < 5 * math.sqrt(2 / 399))


def test_heavy_tails_density_is_normalised_with_unit_variance():
    z = np.linspace(-60, 60, 200001)
    for nu in (3.0, 5.0, math.inf):
        f = np.exp(ht.logpdf(z, nu))
        assert np.trapezoid(f, z) == pytest.approx(1.0, abs=2e-3)
        if nu > 4:
            assert np.trapezoid(z * z * f, z) == pytest.approx(1.0, abs=5e-3)


def test_scaled_student_t_is_scipys_and_its_scale_is_recovered():
    """The heavy_tails density with a scale is scipy's location-scale t (an independent code), and
    profile_scale recovers the scale of seeded draws within 4 SE of the Fisher information of a t's
    log scale, 2 nu / (nu + 3) per draw (2 for the normal)."""
    from scipy import stats

    z = np.linspace(-8.0, 8.0, 33)
    for nu in (2.5, 4.0):
        for s in (0.7, 1.6):
            c = math.sqrt((nu - 2.0) / nu)
            assert np.allclose(ht.logpdf(z, nu, s), stats.t.logpdf(z, nu, scale=s * c), rtol=0, atol=1e-12)
    assert np.allclose(ht.logpdf(z, math.inf, 1.6), stats.norm.logpdf(z, scale=1.6), rtol=0, atol=1e-12)
    assert np.allclose(ht.normal_scores(1.6 * z, 4.0, 1.6), ht.normal_scores(z, 4.0))
    with pytest.raises(InputError):
        ht.logpdf(z, 3.0, 0.0)
    rng = np.random.default_rng(20261127)
    n = 3000
    for nu, s in ((3.0, 1.5), (5.0, 0.8), (math.inf, 1.2)):
        e = rng.standard_t(nu, n) * math.sqrt((nu - 2.0) / nu) if math.isfinite(nu) else rng.standard_normal(n)
        s_hat, ll = ht.profile_scale(s * e, nu)
        se = math.sqrt((nu + 3.0) / (2.0 * nu * n)) if math.isfinite(nu) else math.sqrt(1.0 / (2.0 * n))
        assert abs(math.log(s_hat / s)) < 4.0 * se, (nu, s, s_hat)
        assert ll == pytest.approx(float(np.sum(ht.logpdf(s * e, nu, s_hat))))
        assert ll >= float(np.sum(ht.logpdf(s * e, nu, s_hat * 1.01)))


def test_real_ferraris_poses_diagnosis():
    c = ferraris_campaign()
    d = diagnose(c, (), n_draws=400, seed=0)
    assert d.gap["significant"]   # hand-placed poses: chi2/dof in the thousands
    status = {x.effect: x for x in d.candidates}
    for e in ("angle_tempco", "scale_tempco", "bias_tempco", "hysteresis", "thermal_lag"):
        assert not status[e].testable
    # position_error closes the gap, but on 18 residuals of which the fit takes 12 its variance's
    # pattern over the poses is not told from a noise level the sd_* understate (the up axes keep
    # residuals as large as the others: LR p 0.18; noise_level.uniform_rival). Until 2026-11-28 it
    # was named, with the caveat that poses visited once cannot tell a random error from a systematic one
    v = d.verdict
    assert v["effect"] == "unexplained" and v["best_partial"] == "position_error" and v["gap_closed"], v
    assert v["ambiguous_with"][0].startswith("a white noise of the outputs above the declared level"), v
    assert v["uniform_rival"]["p_value"] > 0.05 and v["uniform_rival"]["variance_factor"] > 1000.0, v
    pe_sigma = status["position_error"].refit["new_parameters"]["position_error_sigma"]["value"]
    assert pe_sigma > 60.0   # hand placement: arc-minutes, not the bench's arcseconds


def _run_cli(*args, cwd):
    env = dict(os.environ, OMP_NUM_THREADS="1", XDG_CACHE_HOME=str(cwd / "xdg"))
    return subprocess.run([sys.executable, "-m", "triadcal", *args], cwd=cwd, env=env,
                          capture_output=True, text=True)


def test_cli_diagnose_writes_json_and_html(cli_reports, tmp_path):
    """The command end to end: the run of conftest.py's cli_reports (the validation campaign with the
    bias drift withheld, seed 5, five candidates, 200 draws: the page tests of
    tests/test_reports_render.py read the same run), and a refused model effect."""
    d = cli_reports["dir"]
    assert "verdict: bias_drift" in cli_reports["stdout"]["diagnosis"]
    doc = json.loads((d / "diagnosis.json").read_text())
    assert doc["verdict"]["effect"] == "bias_drift"
    page = (d / "diagnosis.html").read_text()
    assert page.count("data:image/png;base64,") >= 3 and "bias_drift" in page
    bad = _run_cli("diagnose", str(d / "diagnosis.csv"), "--model", "warp_drive", "--json", "x.json", cwd=tmp_path)
    assert bad.returncode == 1 and "unknown model effect" in bad.stderr


# -- slow: the validation of the issue is tests/test_diagnosis_validation.py ----------------------
# (test_validation_in_vocabulary_and_left_out: two magnitudes, the left-out mode, binomial bounds;
# it replaces the 20-seed in-vocabulary test that was here, at the same CI cost)


def test_a_noise_effect_never_absorbs_a_structured_gap(example):
    """The example campaign diagnosed with no thermal terms (--model none): position_error has
    the largest elpd (it widens the noise until the misfit looks like scatter), but slices keep
    structure after its refit, so it is not named; a thermal term shrinks the gap most but leaves
    it open, so it is the best partial answer of an 'unexplained' verdict (more is missing: an
    effect is named only when the gap after it is within the noise)."""
    d = diagnose(example, model=())
    pe = next(c for c in d.candidates if c.effect == "position_error")
    assert pe.refit and pe.refit["gap_after"]["significant_slices"] > 0
    assert d.verdict_effect == "unexplained"
    assert d.verdict["best_partial"] not in ("position_error", "heavy_tails", None)
    assert d.verdict.get("gap_closed") is False and "more is missing" in d.verdict["remaining"]


def test_a_name_that_leaves_the_slices_as_they_were_is_a_partial_answer():
    """The validation's heavy_tails at m = 1, seed 1017, with the noise effects left out: tilt_drift
    improves the fit (LR p 0.0016) and its chi2/dof is 0.97 after -- but it was 0.98 before, and the
    13 significant slices of the contaminated visits are all still there. It was named (with
    gap_closed false); a candidate that leaves two or more slices, or as many as before, has not
    explained where the model misses: 'unexplained', with it the best partial answer. One marginal
    slice left of many keeps the name (tests/test_cross_axis_effects.py: 2 of 10 campaigns)."""
    from triadcal.judgement.diagnosis_validation import run_case

    row = run_case("heavy_tails", 1017, left_out=True)
    assert row["left_out_verdict"] == "unexplained", row
    assert row["left_out_gap_closed"] is False and "13 slice(s) still significant" in row["left_out_reason"], row
    assert "tilt_drift" in row["left_out_reason"], row


def test_an_effect_outside_the_vocabulary_is_unexplained_not_noise(example):
    """Outputs changed with numpy, not the model's code: a quadratic temperature dependence of
    the y output, signed by the pose (40 ug at 70 degC), which no candidate models. The noise
    candidates would absorb it (before: heavy_tails named), but slices keep structure after
    their refit: the verdict is 'unexplained', with where it lies."""
    import copy

    c = copy.deepcopy(example)
    T = c.t.mean(axis=1)
    c.w[:, 1] += 40e-6 * ((T - 20.0) / 50.0) ** 2 * np.sign(np.cos(np.radians(c.axis1_deg)))
    d = diagnose(c)
    assert d.gap["significant"]
    assert d.verdict_effect == "unexplained"
    assert "structure is left after that refit" in d.verdict["reason"] and d.verdict["where"]
    assert all(w["p_adjusted"] < d.alpha for w in d.verdict["where"])
    # the generic families (generic.py) see the pattern before any refit (temperature: the u^2 g
    # terms; orientation: its mean over the setpoints, an offset per pose) and a family still finds
    # structure after each noise candidate's refit (after flicker's, whose covariance absorbs the
    # slow temperature pattern, the orientation families)
    assert d.gap["tests"]["generic:temperature"]["p_holm"] < d.alpha
    noise = [c for c in d.candidates if c.effect in ("position_error", "heavy_tails", "flicker_noise") and c.refit]
    assert noise and all(c.refit["gap_after"]["generic_structure"] for c in noise)


def test_a_quadratic_angle_tempco_made_with_numpy_is_named_and_recovered(example):
    """Ca_xy(T) = Ca_xy + 0.006"/degC^2 (t_x - 20)^2 added to the x output through the nominal
    gravity (eq. 1 to first order, written here with numpy, not the model's code): the diagnosis
    names angle_tempco2, the gap closes, and the refit recovers the coefficient within 3u."""
    import copy

    from triadcal.models.campaign import nominal_gravity

    c = copy.deepcopy(example)
    G = nominal_gravity(c.axis1_deg, c.axis2_deg)
    c.w[:, 0] += 0.006 * (c.t[:, 0] - 20.0) ** 2 * (np.pi / 648000.0) * G[:, 1]
    d = diagnose(c)
    assert d.verdict_effect == "angle_tempco2" and d.verdict.get("gap_closed") is True
    est = next(x for x in d.candidates if x.effect == "angle_tempco2").refit["new_parameters"]["Ca_xy_tempco2"]
    assert abs(est["value"] - 0.006) < 3 * est["u"] and est["unit"] == "arcsec/degC2"
