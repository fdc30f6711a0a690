"""The ``flicker_noise`` candidate (issue 18 item 2): 1/f noise that correlates the visit means.

(a) the covariance of the visit means' deviations from their campaign mean
(:func:`triadcal.models.effects.flicker_noise.centred_covariance`) by hand for two visits
(Barnes' B2) and against a brute-force Monte Carlo of the FFT generator of
:mod:`triadcal.models.noise_processes`, tolerance from the MC standard error;
(b) data made another way: visit means averaged from sample streams of a sum of
Ornstein-Uhlenbeck processes (``tests/test_visit_uncertainty.py``'s independent generator) on top
of the independent bench (``tests/independent_bench.py``): the diagnosis names flicker_noise and
the REML B_f is within its expanded uncertainty (k = 2) of the truth; (c) the same without
flicker: not named, B_f^2 consistent with 0; (d) a withheld quadratic bias tempco is not named
flicker_noise; (e) ``triadcal fit --effects ...,flicker_noise`` reports B_f; the simulator's
field is off by default (bit-identical campaigns) and on draws the stated covariance.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from independent_bench import simulate_campaign as independent_campaign  # noqa: E402
from test_visit_uncertainty import campaign_with_stream  # noqa: E402

from triadcal.estimation.flicker_noise import flicker_from_residuals  # noqa: E402
from triadcal.io.bench_csv import format_bench_csv, parse_bench_csv  # noqa: E402
from triadcal.judgement.diagnose import diagnose  # noqa: E402
from triadcal.models.effects import NOISE_EFFECTS  # noqa: E402
from triadcal.models.effects.flicker_noise import centred_covariance, draw_visit_errors  # noqa: E402
from triadcal.models.noise_processes import flicker_noise, visit_mean_variance  # noqa: E402

LN2 = math.log(2.0)
MODEL = ("angle_tempco", "scale_tempco", "bias_tempco")   # the independent bench's truth (no tilt)


def barnes_b2_flicker(r):
    f = (lambda x: x * x * math.log(x) if x > 0 else 0.0)
    return (f(r + 1) + f(abs(r - 1)) - 2 * f(r)) / (4 * LN2)


# -- (a) the covariance function ----------------------------------------------------------------
def test_two_visits_by_hand_and_diagonal_against_visit_mean_variance():
    # two equal windows r tau apart: e_1 = (ybar_1 - ybar_2)/2, Var = D/4 = 2 B_f^2 B2(r) / 4
    tau, Bf2 = 30.0, 4e-12
    for r in (1.0, 3.0, 100.0):
        C = centred_covariance([0.0, r * tau], tau, Bf2)
        expect = 2 * Bf2 * barnes_b2_flicker(r) / 4
        assert C == pytest.approx(np.array([[expect, -expect], [-expect, expect]]), rel=1e-9)
    # N visits: the diagonal is (N-1)/N times noise_processes.visit_mean_variance, rows sum to 0
    t = np.array([0.0, 50.0, 400.0, 7200.0, 7250.0, 30000.0])
    C = centred_covariance(t, 30.0, Bf2)
    n = len(t)
    assert np.diag(C) == pytest.approx((n - 1) / n * visit_mean_variance(t, 30.0, 0.0, Bf2), rel=1e-9)
    assert np.abs(C.sum(axis=1)).max() < 1e-9 * np.abs(C).max()
    assert np.linalg.eigvalsh(C).min() > -1e-9 * np.abs(C).max()


def test_covariance_against_monte_carlo_of_the_fft_generator():
    """Centred window means of the FFT flicker generator (1 Hz, 2^15 samples, its period 9 h: the
    missing power below 1/period moves these entries by < 0.5 %, below the MC SE of ~4 %)."""
    rate, n, m, reps = 1.0, 2 ** 15, 30, 1500
    starts = np.array([0, 30, 300, 330, 900, 1470])
    centres = (starts + (m - 1) / 2) / rate
    C = centred_covariance(centres, m / rate, 1.0)
    rng = np.random.default_rng(20261125)
    idx = starts[:, None] + np.arange(m)[None, :]
    prods = np.empty((reps, len(starts), len(starts)))
    for k in range(reps):
        y = flicker_noise(n, rate, 1.0, rng)
        e = y[idx].mean(axis=1)
        e = e - e.mean()
        prods[k] = np.outer(e, e)
    mc = prods.mean(axis=0)
    se = prods.std(axis=0, ddof=1) / math.sqrt(reps)
    z = (mc - C) / se
    # 21 distinct entries: 4 SE each (two-sided 6e-5, family < 0.2 %)
    assert np.abs(z).max() < 4.0, np.round(z, 2)


def test_simulator_flicker_off_is_bit_identical_and_on_adds_zero_mean_errors():
    from triadcal.models.simulate import NoiseModel, Schedule, preset_truth, simulate_campaign

    plan = {k: v for k, v in list(__import__("triadcal.models.campaign", fromlist=["DEFAULT_PLAN"])
                                  .DEFAULT_PLAN.items())[:4]}
    sched = Schedule(setpoints_C=(20.0, 40.0, 20.0), soak_s=600)
    base = simulate_campaign(preset_truth("ak18-quartz", ()), plan=plan, schedule=sched, seed=3)
    off = simulate_campaign(preset_truth("ak18-quartz", (), noise=NoiseModel(flicker_Bf=0.0)), plan=plan,
                            schedule=sched, seed=3)
    on = simulate_campaign(preset_truth("ak18-quartz", (), noise=NoiseModel(flicker_Bf=5e-6)), plan=plan,
                           schedule=sched, seed=3)
    assert np.array_equal(base.w, off.w) and np.array_equal(base.sd, off.sd) and np.array_equal(base.t, on.t)
    d = on.w - base.w                       # the flicker alone: the other draws are unchanged
    assert np.array_equal(base.sd, on.sd)
    assert np.abs(d.mean(axis=0)).max() < 1e-15                # its campaign mean is the bias's
    assert 0 < np.abs(d).max() < 10 * 5e-6 * math.sqrt(np.max(np.diag(centred_covariance(on.time_s, on.tau_s))))
    # the truth document omits the field when it is off (old truths unchanged)
    from triadcal.models.simulate import Truth

    assert "flicker_Bf" not in Truth().to_dict()["noise"]
    assert Truth(noise=NoiseModel(flicker_Bf=5e-6)).to_dict()["noise"]["flicker_Bf"] == 5e-6


def test_draws_have_the_stated_covariance():
    t = np.array([0.0, 40.0, 500.0, 5000.0, 5040.0])
    C = centred_covariance(t, 30.0, 1.0)
    e = draw_visit_errors(t, 30.0, 1.0, np.random.default_rng(7), n_outputs=40000)
    mc = e @ e.T / e.shape[1]
    se = np.sqrt((np.outer(np.diag(C), np.diag(C)) + C * C) / e.shape[1])
    assert np.abs((mc - C) / se).max() < 4.0


# -- (b)-(d) the diagnosis on data made another way ---------------------------------------------
BF = 3e-5          # V: about the white noise of one visit mean (5e-4 / sqrt(300) = 2.9e-5 V)


@pytest.mark.slow
def test_independent_flicker_scored_and_refitted_with_two_rivals():
    """Short form of the next test: the candidate with two mean rivals (no forms)."""
    c, _, _ = campaign_with_stream(11, BF)
    d = diagnose(c, MODEL, candidates=["flicker_noise", "bias_drift", "bias_tempco2"], n_draws=100,
                 cross_group=False)
    assert d.verdict["effect"] == "flicker_noise", d.verdict
    fl = next(x for x in d.candidates if x.effect == "flicker_noise")
    assert fl.score_p < 1e-6 and fl.refit["gap_after"]["significant_slices"] == 0
    bf = fl.refit["new_parameters"]["flicker_Bf"]
    assert bf["unit"] == "V" and abs(bf["value"] - BF) <= 2.0 * bf["u"]


@pytest.mark.slow
def test_independent_flicker_is_named_and_its_floor_recovered():
    c, _, _ = campaign_with_stream(11, BF)
    d = diagnose(c, MODEL, n_draws=200)
    assert d.verdict["effect"] == "flicker_noise", d.verdict
    fl = next(x for x in d.candidates if x.effect == "flicker_noise")
    assert fl.refit["gap_after"]["significant_slices"] == 0
    est, result = flicker_from_residuals(c, MODEL, per_axis=False)
    bf, u = float(est.Bf[0]), float(est.u_Bf[0])
    assert abs(bf - BF) <= 2.0 * u, (bf, u)            # expanded uncertainty, k = 2
    assert result.fit["chi2_dof"] == pytest.approx(1.0, abs=3 * math.sqrt(2 / result.fit["n_obs"]) + 0.05)


@pytest.mark.slow
def test_clean_independent_data_is_not_flicker_and_floor_is_consistent_with_zero():
    c, _, _ = campaign_with_stream(12, 0.0)
    d = diagnose(c, MODEL, n_draws=200)
    assert d.verdict["effect"] != "flicker_noise", d.verdict
    est, _ = flicker_from_residuals(c, MODEL, per_axis=False)
    assert est.Bf2[0] <= 2.0 * est.u_Bf2[0], (est.Bf2[0], est.u_Bf2[0])


@pytest.mark.slow
def test_withheld_quadratic_bias_tempco_is_not_named_flicker():
    rng = np.random.default_rng(5)
    from independent_bench import default_truth

    truth = default_truth(rng)
    truth["S_x_tempco2"] = 0.02            # ug/degC^2: 72 ug at 60 degC from 20, structured in temperature
    text, _ = independent_campaign(rng, truth=truth, n_samples=300)
    c = parse_bench_csv(text, "quadratic")
    d = diagnose(c, MODEL, n_draws=200)
    assert d.gap["significant"]
    assert d.verdict["effect"] != "flicker_noise", d.verdict


# -- (f) with the noise estimated (no sd_*, n_samples, u_w_*, Q_V2s) ----------------------------------
def test_independent_flicker_with_the_noise_estimated_is_named_and_its_floor_recovered():
    """The white level estimated together with the floor (REML with the level profiled out; the score
    the level-free ratio test): the independent 1/f stream of (b) with its noise columns removed is
    named flicker_noise with no slice left, its B_f within 2 u of the truth (u larger than with the
    noise declared: the level's uncertainty is in it), the same B_f as ``fit`` gives (one estimator);
    the clean stream is not named and its B_f^2 is within 2 u of 0."""
    from triadcal.judgement.diagnosis_validation import without_noise

    c, _, _ = campaign_with_stream(11, BF)
    est_c = without_noise(c)
    d = diagnose(est_c, MODEL, n_draws=100, cross_group=False)
    assert d.verdict["effect"] == "flicker_noise", d.verdict
    fl = next(x for x in d.candidates if x.effect == "flicker_noise")
    assert fl.testable and fl.score_p < 1e-6 and fl.refit["gap_after"]["significant_slices"] == 0
    bf = fl.refit["new_parameters"]["flicker_Bf"]
    assert bf["unit"] == "V" and abs(bf["value"] - BF) <= 2.0 * bf["u"], bf
    est, result = flicker_from_residuals(est_c, MODEL, per_axis=False)
    known, _ = flicker_from_residuals(c, MODEL, per_axis=False)
    assert est.white_estimated and not known.white_estimated
    assert float(est.u_Bf[0]) > float(known.u_Bf[0])
    assert float(est.Bf[0]) == pytest.approx(bf["value"], rel=0.02)
    assert result.fit["noise_known"] is False and result.fit["Q_estimate"] > 0
    clean = without_noise(campaign_with_stream(12, 0.0)[0])
    d0 = diagnose(clean, MODEL, n_draws=100, cross_group=False)
    assert d0.verdict["effect"] != "flicker_noise", d0.verdict
    est0, _ = flicker_from_residuals(clean, MODEL, per_axis=False)
    assert est0.Bf2[0] <= 2.0 * est0.u_Bf2[0], (est0.Bf2[0], est0.u_Bf2[0])


def test_the_level_free_flicker_score_does_not_depend_on_the_scale():
    """The estimated-noise score is a ratio r'Wr / r'r: the residuals scaled by 1000 (the outputs
    in mV instead of V, relative weights unchanged) give the same p to 1e-9 of its log."""
    import dataclasses

    from triadcal.judgement.diagnosis_validation import without_noise

    c = without_noise(campaign_with_stream(11, BF)[0])
    scaled = dataclasses.replace(c, w=c.w * 1000.0)
    ps = []
    for cc in (c, scaled):
        d = diagnose(cc, MODEL, candidates=["flicker_noise"], n_draws=50, cross_group=False)
        ps.append(next(x for x in d.candidates if x.effect == "flicker_noise").score_logp)
    assert ps[1] == pytest.approx(ps[0], rel=1e-9, abs=1e-9), ps


# -- (e) the command line ------------------------------------------------------------------------
def _cli_fit_flicker(tmp_path, capsys, c):
    """``triadcal fit`` of ``c`` (written as a bench CSV) with flicker_noise; its floors, each within
    3 u of the truth, and the result document."""
    from triadcal.cli import main

    path = tmp_path / "bench.csv"
    path.write_text(format_bench_csv(c), encoding="utf-8")
    out = tmp_path / "r.json"
    code = main(["fit", str(path), "--method", "joint", "--effects", ",".join(MODEL) + ",flicker_noise",
                 "--json", str(out)])
    assert code in (0, 3), capsys.readouterr()
    doc = json.loads(out.read_text())
    fl = doc["extra"]["flicker_noise"] if "extra" in doc else doc["flicker_noise"]
    for a in "xyz":
        v = fl["flicker_Bf"][a]
        assert v["unit"] == "V" and v["u"] > 0 and abs(v["value"] - BF) <= 3.0 * v["u"], v
    return fl, doc


def test_cli_fit_with_flicker_noise_reports_bf(tmp_path, capsys):
    from triadcal.cli import main

    assert "flicker_noise" in NOISE_EFFECTS
    fl, doc = _cli_fit_flicker(tmp_path, capsys, campaign_with_stream(13, BF)[0])
    assert fl["white_level_estimated"] is False
    assert any("flicker_noise" in n for n in doc["notes"])
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    assert "flicker_noise" in capsys.readouterr().out.replace("\n", " ")


def test_cli_fit_with_flicker_noise_and_no_declared_noise(tmp_path, capsys):
    """A bench CSV without sd_* / n_samples / Q_V2s: ``fit --effects ...,flicker_noise`` estimates the
    white level with the floors (it refused before: "the two cannot be told apart"), says so in the
    method, and the floors are within 3 u of the truth."""
    from triadcal.judgement.diagnosis_validation import without_noise

    c = without_noise(campaign_with_stream(13, BF)[0])
    text = format_bench_csv(c)
    assert "sd_x" not in text and "Q_V2s" not in text
    fl, _ = _cli_fit_flicker(tmp_path, capsys, c)
    assert fl["white_level_estimated"] is True and "profiled" in fl["method"]


@pytest.mark.slow
def test_sample_with_flicker_noise_and_the_noise_estimated_agrees_with_the_gls():
    """``sample`` with flicker_noise and no declared noise: the white level held at the GLS fit's
    estimate (a note says so); the posterior SDs agree with the GLS u within 20 % (ESS 400), as with
    the noise declared."""
    from triadcal.estimation.noise_effects import fit_with_noise_effects
    from triadcal.estimation.posterior.sample import sample
    from triadcal.judgement.diagnosis_validation import without_noise

    c = without_noise(campaign_with_stream(13, BF)[0])
    effects = list(MODEL) + ["flicker_noise"]
    post = sample(c, effects, ess=400, max_steps=6000, seed=1)
    gls = fit_with_noise_effects(c, effects)
    assert any("white level held at its estimate" in n for n in post.notes)
    for n in ("S_x", "K_y", "Ca_xy", "S_z_tempco"):
        assert post.parameters[n].u == pytest.approx(gls.parameters[n].u, rel=0.2)
        assert abs(post.parameters[n].value - gls.parameters[n].value) < 0.5 * gls.parameters[n].u


@pytest.mark.slow
def test_sample_with_flicker_noise_agrees_with_the_gls():
    """``sample --effects ...,flicker_noise``: the posterior of the whitened residuals; with a flat
    likelihood-dominated posterior its SDs agree with the GLS u (within 20 %: ESS 400)."""
    from triadcal.estimation.noise_effects import fit_with_noise_effects
    from triadcal.estimation.posterior.sample import sample

    c, _, _ = campaign_with_stream(13, BF)
    effects = list(MODEL) + ["flicker_noise"]
    post = sample(c, effects, ess=400, max_steps=6000, seed=1)
    gls = fit_with_noise_effects(c, effects)
    assert "flicker_noise" in post.extra and "flicker_noise" in gls.extra
    for n in ("S_x", "K_y", "Ca_xy", "S_z_tempco"):
        assert post.parameters[n].u == pytest.approx(gls.parameters[n].u, rel=0.2)
        assert abs(post.parameters[n].value - gls.parameters[n].value) < 0.5 * gls.parameters[n].u
