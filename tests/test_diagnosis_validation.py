"""Tests of the validation of the diagnosis (triadcal validate-diagnosis): magnitudes and the
left-out mode (issue 18, item 4).

The quick tests check the structure (rows, confusion matrices, JSON, CLI) on one condition and
one seed. The slow tests are the CI's cut of the documented full run (docs/diagnosis.md,
"Validation"); their bounds are derived from binomial theory, not tuned (see their docstrings).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from triadcal.judgement.diagnosis_validation import (CONDITIONS, LEFT_OUT_GROUPS, MAGNITUDES, NONE, UNEXPLAINED,
                                                      condition_name, left_out_group, scenario, validate)
from triadcal.models.effects import NOISE_EFFECTS


def test_magnitude_scales_only_the_withheld_effect():
    """m = 0.5 halves every parameter of the withheld effect in the truth (tau for the lag, the
    tilt for bench_tilt), the sigmas for position_error, 1/nu for heavy_tails; nothing else."""
    for effect in ("hysteresis", "thermal_lag", "bench_tilt", "scale_nonlinearity"):
        t1, m1 = scenario(effect, magnitude=1.0)
        th, mh = scenario(effect, magnitude=0.5)
        assert m1 == mh and t1.effects == th.effects
        from triadcal.models.model import Model

        own = {s.name for s in Model(t1.effects).parameters if s.effect == effect}
        assert own
        for k, v in t1.parameters.items():
            assert th.parameters[k] == pytest.approx(0.5 * v if k in own else v), (effect, k)
    assert scenario("position_error", magnitude=0.5)[0].noise.sigma_position_arcsec == 2.5
    assert scenario("position_error", magnitude=0.5)[0].noise.sigma_wobble_arcsec == 1.0
    assert scenario("heavy_tails", magnitude=0.5)[0].noise.heavy_tails_dof == 6.0
    assert condition_name("hysteresis", 1.0) == "hysteresis" and condition_name("hysteresis", 0.5) == "hysteresis@0.5"
    assert MAGNITUDES == (1.0, 0.5)


def test_left_out_groups_hold_the_forms_and_orders_of_the_effect():
    assert left_out_group("hysteresis") == ("hysteresis", "hysteresis_play", "hysteresis_pi")
    assert left_out_group("thermal_lag") == ("thermal_lag", "thermal_lag_history")
    assert set(left_out_group("angle_tempco2")) == {"angle_tempco", "angle_tempco2", "angle_tempco3"}
    assert left_out_group("bench_tilt") == ("bench_tilt", "tilt_drift", "tilt_settling")
    assert left_out_group("tilt_drift") == ("tilt_drift", "tilt_settling")      # the two laws of one change
    assert left_out_group("tilt_settling") == ("tilt_settling", "tilt_drift")
    noise_group = {"position_error", "heavy_tails"}
    assert set(left_out_group("position_error")) == set(left_out_group("heavy_tails")) == noise_group
    assert left_out_group("scale_asymmetry") == ("scale_asymmetry",)     # separable by the oblique poses
    assert left_out_group("bias_drift") == ("bias_drift", "bias_warmup")  # a long warm-up is a rate
    assert all(e in left_out_group(e) for e in LEFT_OUT_GROUPS)
    # a verdict naming another form of the same effect is right in vocabulary; left out, every such
    # form is removed with the effect, or the left-out mode could be 'right' by naming it
    from triadcal.judgement.diagnosis_validation import SAME_EFFECT
    assert SAME_EFFECT["thermal_lag"] == ("thermal_lag", "thermal_lag_history")
    assert all(set(forms) <= set(left_out_group(e)) for e, forms in SAME_EFFECT.items())


@pytest.mark.slow   # 15 s; CI runs it with the slow tests (the quick suite's 10-minute budget)
def test_left_out_mode_rows_confusion_and_json(tmp_path):
    """One condition at half magnitude, one seed: the same campaign diagnosed twice (in vocabulary,
    left out); both verdicts in the row, both matrices in the result, the table and the JSON."""
    res = validate(seeds=1, effects=("bias_drift",), processes=1, magnitudes=(0.5,), left_out=True)
    (row,) = res.rows
    assert row["condition"] == "bias_drift@0.5" and row["magnitude"] == 0.5
    assert row["left_out"] == ["bias_drift", "bias_warmup"]        # the two laws of a bias in time
    assert row["left_out_verdict"] in res.labels and row["left_out_verdict"] not in row["left_out"]
    assert res.left_out_conditions == ("bias_drift@0.5",)
    M, L = res.confusion(), res.confusion(left_out=True)
    assert M.shape == L.shape == (1, len(res.labels)) and M.sum() == L.sum() == 1
    assert res.labels[-2:] == (UNEXPLAINED, NONE)
    s = res.summary["bias_drift@0.5"]
    assert s["unexplained_rate"] == float(row["left_out_verdict"] == UNEXPLAINED)
    assert s["left_out_verdicts"] == {row["left_out_verdict"]: 1}
    assert "left out" in res.table() and res.table().count("bias_drift") >= 2
    from triadcal.reports.diagnosis import write_validation

    paths = write_validation(res, tmp_path)
    doc = json.loads(open(paths["json"]).read())
    assert doc["left_out"] is True and doc["confusion_left_out"] == L.tolist()
    assert doc["left_out_groups"] == {"bias_drift@0.5": ["bias_drift", "bias_warmup"]} and doc["magnitudes"] == [0.5]
    assert "magnitude m" in doc["magnitude_definition"] and "left-out" in doc["design"]
    png = open(paths["plot"], "rb").read()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow  # 2026-11-29: the quick suite over its 10 minutes on CI (623 s); run in CI's slow phase
def test_noise_estimated_mode(tmp_path):
    """--noise-estimated: the campaign's declared noise removed before the diagnosis (validation's
    without_noise: no sd, n_samples, u_w, Q_V2s), the row says the noise was estimated, the JSON says
    the mode and follows its contract; the cubic scale tempco is still named (its wander rival asked
    with the level free: tests/test_correlated_noise.py), and flicker_noise is named (its floor
    estimated with the white level; the full run named it 20 of 20 at m = 1). With the noise
    declared: noise_known in the row."""
    from triadcal.judgement.diagnosis_validation import run_case, without_noise
    from triadcal.models.simulate import Schedule, simulate_campaign
    from triadcal.judgement.diagnosis_validation import VALIDATION_PLAN, VALIDATION_SOAK_S

    truth, _ = scenario("scale_tempco3")
    c = simulate_campaign(truth, plan=VALIDATION_PLAN, schedule=Schedule(soak_s=VALIDATION_SOAK_S), seed=1000)
    bare = without_noise(c)
    assert c.output_sigma() is not None and "Q_V2s" in c.metadata
    assert bare.output_sigma() is None and "Q_V2s" not in bare.metadata and np.array_equal(bare.w, c.w)
    res = validate(seeds=1, effects=("scale_tempco3", "flicker_noise"), processes=1, noise_estimated=True)
    row, fl = res.rows
    assert row["noise_known"] is False and row["verdict"] == "scale_tempco3", row
    # flicker_noise with the white level estimated together (was untestable without declared noise)
    assert fl["noise_known"] is False and fl["verdict"] == "flicker_noise", fl
    assert run_case("scale_tempco3", 1000)["noise_known"] is True
    from triadcal.reports.diagnosis import write_validation
    from test_results_contract import assert_valid, load

    paths = write_validation(res, tmp_path)
    doc = load(paths["json"])
    assert doc["noise_estimated"] is True and "estimated" in doc["noise_estimated_definition"]
    assert "noise estimated" in doc["design"]
    assert_valid(doc, "triadcal.diagnosis_validation")


@pytest.mark.slow   # 10-18 s; CI runs it with the slow tests (CI-29: the quick suite took 635 s of its 600)
def test_cli_magnitudes_and_left_out(tmp_path):
    """The command end to end on clean data alone with --left-out and a magnitude (the README's
    command as the doc harness reduces it): nothing is left out and the table says so (it was an
    internal error: max() of an empty sequence), the table, the plot and the JSON are written, the
    JSON follows its contract; a bad --magnitudes is refused naming the option. (The left-out rows of
    an effect: test_left_out_mode_rows_confusion_and_json.)"""
    out = subprocess.run([sys.executable, "-m", "triadcal", "validate-diagnosis", "--seeds", "1", "--effects",
                          "clean", "--magnitudes", "0.5", "--left-out", "--processes", "1",
                          "--out", "v", "--quiet"], cwd=tmp_path, capture_output=True, text=True,
                         env=dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "xdg")))
    assert out.returncode == 0, out.stderr
    doc = json.loads((tmp_path / "v" / "validation.json").read_text())
    assert doc["conditions"] == ["clean"] and doc["left_out_conditions"] == []
    assert doc["magnitudes"] == [0.5] and [r["magnitude"] for r in doc["rows"]] == [None]
    assert np.array(doc["confusion"]).sum() == 1 and doc["confusion_left_out"] == []
    table = (tmp_path / "v" / "confusion.txt").read_text()
    assert "nothing was left out" in table and "clean" in table
    png = (tmp_path / "v" / "confusion.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    from test_results_contract import assert_valid, load

    assert_valid(load(tmp_path / "v" / "validation.json"), "triadcal.diagnosis_validation")  # its contract
    bad = subprocess.run([sys.executable, "-m", "triadcal", "validate-diagnosis", "--magnitudes", "0,x",
                          "--out", "v"], cwd=tmp_path, capture_output=True, text=True)
    assert bad.returncode != 0 and "--magnitudes" in bad.stderr


# -- slow: the CI's cut of the full validation ------------------------------------------------
#: seeds per condition in CI: 1 clean + 23 effects (flicker_noise included) at the realistic magnitude,
#: each effect diagnosed twice (in vocabulary; left out, which redoes the slices after each refit):
#: 47 diagnoses a seed, about 108 s on 2 free cores (a seed of both magnitudes, 93 diagnoses, took
#: 214 s, seed 1000, 2026-11-25, with the flicker and quantisation candidates); 4 seeds ~7 min, below
#: the 20-seed in-vocabulary test they replace. The half magnitude is in the documented full run
#: (docs/diagnosis.md, "Validation"), not in CI.
CI_SEEDS = 4
#: magnitudes of the CI cut
CI_MAGNITUDES = (1.0,)
#: the issue's bar: the rate each condition must reach
BAR = 0.95
#: one-sided level of the binomial bounds
LEVEL = 0.01


def binomial_floor(n: int, rate: float = BAR, level: float = LEVEL) -> int:
    """Largest count k with P(X < k) <= level for X ~ Binomial(n, rate): a condition that meets
    the bar falls below k with probability <= level (n = 4: 2; n = 20: 16; n = 92: 82)."""
    k = int(stats.binom.ppf(level, n, rate))
    return k if stats.binom.cdf(k - 1, n, rate) <= level else k - 1


def _count(s: dict, rate_key: str) -> int:
    return round(s[rate_key] * s["n"])


@pytest.fixture(scope="module")
def ci_validation(tmp_path_factory):
    res = validate(seeds=CI_SEEDS, processes=2, magnitudes=CI_MAGNITUDES, left_out=True)
    from triadcal.reports.diagnosis import write_validation

    write_validation(res, tmp_path_factory.mktemp("validation"))
    print("\n" + res.table())
    return res


def _in_vocabulary_failures(res, magnitude: float) -> tuple[list, int, int]:
    """Conditions at ``magnitude`` below the per-condition floor (named), with a noise effect named
    on a mean effect's gap, or (at 1) chi2/dof after out of [0.8, 1.2]; and the pooled count."""
    s = res.summary
    k = binomial_floor(CI_SEEDS)
    conds = [c for c in res.conditions if c != "clean" and s[c]["magnitude"] == magnitude]
    assert len(conds) == len(CONDITIONS) - 1
    failures = []
    for c in conds:
        if _count(s[c], "correct_rate") < k:
            failures.append((c, "named", s[c]["correct_rate"]))
        if s[c]["noise_named_rate"]:
            failures.append((c, "a noise effect named on a mean effect's gap", s[c]["noise_named_rate"]))
        if magnitude == 1.0 and s[c]["chi2_dof_after_range"]:
            lo, hi = s[c]["chi2_dof_after_range"]
            if not (0.8 <= lo and hi <= 1.2):
                failures.append((c, "chi2/dof after", lo, hi))
    return failures, sum(_count(s[c], "correct_rate") for c in conds), sum(s[c]["n"] for c in conds)


@pytest.mark.slow
def test_validation_in_vocabulary(ci_validation):
    """CI cut of the documented full run: CI_SEEDS = 4 seeds (1000-1003) x (clean + every effect
    at the realistic magnitude), each campaign diagnosed in vocabulary and with its group left
    out (one run, shared by the two tests). This one: in vocabulary, as the 20-seed test it
    replaces.

    Bounds from binomial theory, not tuned: if a condition's true rate were the issue's bar
    (0.95), its count over n seeds is below ``binomial_floor(n)`` with probability <= 1 %
    (one-sided); per condition n = 4 (floor 2), pooled over the 23 effects (n = 92, floor 82).
    Named per condition and pooled; 'none' on clean data (floor 2 of 4); a noise effect never
    named on a mean effect's gap (zero); chi2/dof after the right effect's refit in [0.8, 1.2].
    """
    res = ci_validation
    assert set(res.summary) == set(res.conditions)
    assert _count(res.summary["clean"], "correct_rate") >= binomial_floor(CI_SEEDS), res.summary["clean"]
    failures, named, n = _in_vocabulary_failures(res, 1.0)
    assert named >= binomial_floor(n), (named, n)
    assert not failures, failures


@pytest.mark.slow
def test_validation_left_out_never_names_a_noise_effect_on_a_mean_gap(ci_validation):
    """Issue 18 item 1 in the left-out mode: with the effect's group left out of the candidates, a
    noise effect (position_error, heavy_tails, flicker_noise) is never named on a mean effect's gap
    (before the generic structure guard, generic.py: position_error for angle_tempco2 and
    cross_coupling, flicker_noise for bias_tempco3 and bias_drift at half magnitude, seed 1000)."""
    s = ci_validation.summary
    noise = [(c, s[c]["left_out_verdicts"]) for c in ci_validation.left_out_conditions
             if s[c]["effect"] not in NOISE_EFFECTS and s[c]["left_out_noise_rate"] > 0]
    assert not noise, noise


@pytest.mark.slow
def test_validation_left_out_is_unexplained(ci_validation):
    """The issue's bar for the left-out mode at the realistic magnitude (the CI cut), with the
    binomial floors: per condition 'unexplained' in at least 2 of 4 and pooled (23 conditions x 4)
    at least 82 of 92; no candidate named with the gap closed (a confident wrong answer). Measured
    2026-11-25 with the rivals' encompassing test, the 3 x 3 position_error and the variance family:
    91 of 92 (g_dependent_misalignment 'none' once), none confident wrong. (It was xfail before: K2
    and the asymmetry named each other, position_error was named flicker_noise.) At half the
    magnitude the bar is not met (docs/diagnosis.md, Validation): effects too small to detect give
    'none'."""
    s = ci_validation.summary
    conds = ci_validation.left_out_conditions
    k = binomial_floor(CI_SEEDS)
    confident = [(c, s[c]["left_out_verdicts"]) for c in conds if s[c]["left_out_confident_wrong_rate"] > 0]
    failures = [(c, s[c]["left_out_verdicts"]) for c in conds if _count(s[c], "unexplained_rate") < k]
    n_all = sum(s[c]["left_out_n"] for c in conds)
    unexplained = sum(_count(s[c], "unexplained_rate") for c in conds)
    assert not confident, confident
    assert unexplained >= binomial_floor(n_all), (unexplained, n_all)
    assert not failures, failures


def test_the_confusion_table_numbers_its_columns_so_no_two_read_alike():
    """Verdict names cut to 9 characters made angle_tempco, angle_tempco2 and angle_tempco3 all
    'angle_tem' (a newcomer could not tell the columns apart); the columns are now numbered with
    a legend naming each verdict in full."""
    from triadcal.judgement.diagnosis_validation import ValidationResult

    labels = ("angle_tempco", "angle_tempco2", "angle_tempco3", "unexplained", "none")
    rows = [{"condition": "angle_tempco2", "effect": "angle_tempco2", "verdict": "angle_tempco2"}] * 3 + \
           [{"condition": "angle_tempco2", "effect": "angle_tempco2", "verdict": "angle_tempco3"}]
    res = ValidationResult(rows=rows, conditions=("angle_tempco2",), labels=labels, seeds=4,
                           summary={"angle_tempco2": {"correct_rate": 0.75, "localised_rate": 1.0,
                                                      "chi2_dof_after_range": [0.9, 1.1]}})
    lines = res.table().splitlines()
    assert lines[0] == ("verdict columns: 1 angle_tempco, 2 angle_tempco2, 3 angle_tempco3, 4 unexplained, "
                        "5 none")
    head, row = lines[2].split(), lines[3].split()
    assert head[:5] == ["1", "2", "3", "4", "5"] and "angle_tem" not in lines[2]
    assert row[:6] == ["angle_tempco2", "0", "3", "1", "0", "0"]
