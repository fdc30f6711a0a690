"""The diagnosis names a missing *form* of a thermal effect (issue 17 item 5): the play and
Prandtl-Ishlinskii hysteresis (``hysteresis_play``, ``hysteresis_pi``) and the lag over the
temperature history (``thermal_lag_history``) are refit-only candidates; the quadratic tempcos are
effects of the vocabulary. The data are made another way (tests/independent_bench.py: a backlash
state machine, Horner polynomials, Euler heat equations), never with the model's code.

Rules checked (docs/diagnosis.md, "Form candidates"): a form is named when its refit improves
(LR p < alpha, delta elpd less one per profiled parameter > 0) and it beats its simpler form by the
nested likelihood ratio at 99 % (play over the offset hysteresis: chi2(2); the history lag over
the rate form: chi2(1)).
"""

from __future__ import annotations

import json
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from independent_bench import (ANGLES, default_truth, simulate_campaign,  # noqa: E402
                               simulate_lag_campaign)

from triadcal.io.bench_csv import parse_bench_csv  # noqa: E402
from triadcal.judgement.diagnose import FORM_CANDIDATES, diagnose  # noqa: E402
from triadcal.models.effects import VOCABULARY  # noqa: E402

#: 10 degC steps up to 70, down to -40, back to 20: turns smaller than a play's 2r leave partial branches
SETPOINTS = (20, 30, 40, 50, 60, 70, 60, 50, 40, 30, 20, 10, 0, -10, -20, -30, -40, -30, -20, -10, 0, 10, 20)
MODEL = ("angle_tempco", "scale_tempco", "bias_tempco", "hysteresis")
LAG_MODEL = ("angle_tempco", "scale_tempco", "bias_tempco")
OPTS = dict(n_draws=100, seed=0, cross_group=False)


def hysteresis_campaign(seed: int, form: str = "play", half_width_C: float = 10.0, quadratic_xy: float = 0.0):
    """Angles' hysteresis of 5-10 arcsec (every angle, random sign) with the branch from the
    backlash state machine; ``quadratic_xy``: Ca_xy_tempco2 in arcsec/degC^2."""
    rng = np.random.default_rng(seed)
    t = default_truth(rng)
    for ab in ANGLES:
        t[f"Ca_{ab}_hysteresis"] = float(rng.uniform(5, 10)) * float(rng.choice([-1, 1]))
    if quadratic_xy:
        t["Ca_xy_tempco2"] = quadratic_xy
    txt, truth = simulate_campaign(rng, truth=t, setpoints_C=SETPOINTS,
                                   hysteresis={"form": form, "half_widths_C": [half_width_C]})
    return parse_bench_csv(txt), MODEL


def lag_campaign(seed: int, tau_min: float, program=None):
    """Ramp 20 -> -40 -> 70 -> 20 degC at 1 degC/min, the element lagging its housing thermometer by
    ``tau_min`` (Euler heat equations), angle tempcos of 0.5-1 arcsec/degC."""
    rng = np.random.default_rng(seed)
    t = default_truth(rng)
    for ab in ANGLES:
        t[f"Ca_{ab}_tempco"] = float(rng.uniform(0.5, 1.0)) * float(rng.choice([-1, 1]))
    txt, truth = simulate_lag_campaign(rng, truth=t, tau_element_min=tau_min, location="housing", program=program)
    return parse_bench_csv(txt), LAG_MODEL


def _cand(d, name):
    return next(c for c in d.candidates if c.effect == name)


# -- quick ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow)])  # seed 1: slow (CI time)
def test_play_hysteresis_of_10_degC_is_named_not_blamed_on_noise(seed):
    c, model = hysteresis_campaign(seed, "play", 10.0)
    d = diagnose(c, model, **OPTS)
    assert d.gap["significant"]
    assert d.verdict_effect == "hysteresis_play", (d.verdict, d.ranked()[:4])
    play = _cand(d, "hysteresis_play")
    assert play.refit_only and play.k == 2      # r and the start (h in the model)
    # ranked by delta elpd: the PI (which contains the play) may rank level with it, never the noise
    noise_rank = min(_cand(d, e).rank for e in ("position_error", "heavy_tails"))
    assert play.rank < noise_rank
    form = play.refit["form"]
    assert form["beats_simpler"] and form["profiled"] == ["half_width_C", "start"]
    lo, hi = form["half_width_interval_C"]
    assert lo - 2.0 <= 10.0 <= hi + 2.0, form       # grid neighbours of the true half-width
    # how far it shrinks: reported as for every candidate, and the gap closes
    before, after = play.refit["gap_before"], play.refit["gap_after"]
    assert after["chi2_dof"] < 1.25 < before["chi2_dof"]
    assert after["residual_rms_ug"] < before["residual_rms_ug"]
    assert d.verdict.get("gap_closed") is True
    # one command away
    assert d.verdict["fit_options"].endswith("--hysteresis-form play")
    assert "--hysteresis-form play" in d.verdict["evidence"] and "refit-only" in d.verdict["evidence"]


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow)])  # seed 1: slow (CI time)
def test_play_hysteresis_of_30_degC_is_named(seed):
    c, model = hysteresis_campaign(seed, "play", 30.0)
    d = diagnose(c, model, **OPTS)
    assert d.verdict_effect == "hysteresis_play", (d.verdict, d.ranked()[:4])


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow)])  # seed 1: slow (CI time)
def test_quadratic_angle_tempco_is_named_angle_tempco2_not_a_form(seed):
    c, model = hysteresis_campaign(seed, "offset", quadratic_xy=0.004)
    d = diagnose(c, model, **OPTS)
    assert d.verdict_effect == "angle_tempco2", (d.verdict, d.ranked()[:4])
    assert not _cand(d, "hysteresis_play").refit["form"]["beats_simpler"]


def cubic_angle_campaign(seed: int):
    """The offset hysteresis campaign (5-10 arcsec) with a cubic angle tempco of the validation
    preset's magnitude on every angle (ak18-quartz: 1.2e-5 to 2e-5 arcsec/degC^3, about 3 arcsec at
    -40 degC), evaluated by Horner's rule in the independent bench, not by the model's term."""
    from triadcal.models.simulate import PRESETS

    rng = np.random.default_rng(seed)
    t = default_truth(rng)
    for ab in ANGLES:
        t[f"Ca_{ab}_hysteresis"] = float(rng.uniform(5, 10)) * float(rng.choice([-1, 1]))
        t[f"Ca_{ab}_tempco3"] = float(PRESETS["ak18-quartz"][f"Ca_{ab}_tempco3"])
    txt, truth = simulate_campaign(rng, truth=t, setpoints_C=SETPOINTS, hysteresis={"form": "offset"})
    return parse_bench_csv(txt), MODEL


#: the candidates with every order of the angle tempco left out (the validation's left-out group)
NO_ANGLE_TEMPCO = tuple(c for c in VOCABULARY + FORM_CANDIDATES
                        if c not in ("angle_tempco", "angle_tempco2", "angle_tempco3"))


def _cubic_verdicts(seed):
    c, model = cubic_angle_campaign(seed)
    d = diagnose(c, model, **OPTS)
    dl = diagnose(c, model, candidates=NO_ANGLE_TEMPCO, slices_after=True, **OPTS)
    return d.verdict_effect, dl.verdict_effect, dl.gap["tests"]["generic:temperature"]["p_holm"]


def test_a_cubic_angle_tempco_is_named_and_left_out_it_is_unexplained():
    """In vocabulary the cubic is named; with the angle tempcos left out the temperature family
    (a Taylor series about T0, generic.py) finds it: p_holm 1.6e-5 on this seed (0.009 with the
    family centred on the campaign's mid-range, a hair under alpha)."""
    named, left_out, p_holm = _cubic_verdicts(0)
    assert named == "angle_tempco3"
    assert left_out == "unexplained", p_holm
    assert p_holm < 1e-3


@pytest.mark.slow
def test_cubic_angle_tempco_over_12_seeds():
    """Seeds 0-11: named in vocabulary in at least 11 and left out ``unexplained`` in at least 9
    (measured 12 and 11; the one left-out miss is ``none``, p_holm 0.07: the family's power). A
    true rate of 95 % falls to 9 or fewer of 12 with probability 0.2 %; a candidate other than the
    cubic is never named."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    with ProcessPoolExecutor(max_workers=2) as ex:
        rows = list(ex.map(_cubic_verdicts, range(12)))
    named = [r[0] for r in rows]
    left = [r[1] for r in rows]
    assert named.count("angle_tempco3") >= 11, rows
    assert left.count("unexplained") >= 9, rows
    assert set(named) <= {"angle_tempco3", None} and set(left) <= {"unexplained", None}, rows


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow)])  # seed 1: slow (CI time)
def test_clean_data_with_the_offset_hysteresis_stay_none(seed, tmp_path):
    c, model = hysteresis_campaign(seed, "offset")
    d = diagnose(c, model, **OPTS)
    assert d.verdict_effect is None and not d.gap["significant"]
    # the forms are candidates (refit-only), in the JSON vocabulary, with their evidence
    d.save(tmp_path / "d.json")
    doc = json.loads((tmp_path / "d.json").read_text())
    from test_results_contract import errors      # the schema of docs/results-json.md
    assert errors(doc) == []
    cands = {x["effect"]: x for x in doc["candidates"]}
    for cand in doc["candidates"]:
        assert cand["effect"] in VOCABULARY + FORM_CANDIDATES
    for name in ("hysteresis_play", "hysteresis_pi"):
        x = cands[name]
        assert x["refit_only"] and x["score"] is None and x["score_p_value"] is None
        assert x["gap_after"]["chi2_dof"] is not None and x["form"]["fit_options"]
    # a stepped record with soaks: the history lag is not testable, said so
    assert not cands["thermal_lag_history"]["testable"] and "gap" in cands["thermal_lag_history"]["reason"]


@pytest.mark.parametrize("tau", [20.0, pytest.param(60.0, marks=pytest.mark.slow)])
def test_lag_behind_the_housing_on_a_ramp_is_named_thermal_lag_history(tau):
    c, model = lag_campaign(3, tau)
    d = diagnose(c, model, **OPTS)
    assert d.verdict_effect == "thermal_lag_history", (d.verdict, d.ranked()[:4])
    form = _cand(d, "thermal_lag_history").refit["form"]
    assert form["location"] == "housing" and form["beats_simpler"]     # over the rate form
    assert abs(form["tau_min"] - tau) < 0.1 * tau
    assert d.verdict["fit_options"].endswith("--thermal-lag-form housing")
    assert "location housing" in d.verdict["evidence"]


@pytest.mark.slow  # 2026-11-29: the quick suite over its 10 minutes on CI (623 s); run in CI's slow phase
def test_lag_behind_the_air_on_a_stepped_campaign_is_named_with_the_gaps_bridged():
    """A stepped campaign read only at its visits (30 min soaks), the thermometer in the air, the
    housing 20 min and the element 4 min behind it, the chamber 5 min behind its program (Euler heat
    equations): the record's gaps are bridged (the air form), and the history form closes the gap
    that the rate form leaves; its refit is one command away (`--bridge-gaps`)."""
    from independent_bench import StepProgram

    rng = np.random.default_rng(61)
    t = default_truth(rng)
    for ab in ANGLES:
        t[f"Ca_{ab}_tempco"] = float(rng.uniform(0.5, 1.0)) * float(rng.choice([-1, 1]))
    txt, _ = simulate_lag_campaign(rng, truth=t, tau_element_min=4.0, location="air", tau_housing_min=20.0,
                                   tau_chamber_min=5.0, program=StepProgram(soak_min=30.0))
    d = diagnose(parse_bench_csv(txt), LAG_MODEL, **OPTS)
    assert d.verdict_effect == "thermal_lag_history", (d.verdict, d.ranked()[:4])
    form = _cand(d, "thermal_lag_history").refit["form"]
    assert form["location"] == "air" and form["beats_simpler"] and form["bridge_min"] is not None
    assert "bridge_min" in form["profiled"] and d.verdict["fit_options"].endswith("--bridge-gaps")
    assert d.verdict["gap_closed"]


def test_a_short_lag_the_rate_form_explains_is_named_thermal_lag():
    """tau = 1 min: the rate form T - tau dT/dt is as good as the history (chi2 lower by < 6.63), so
    the simpler rate form is named, though the history ranks first by delta elpd."""
    c, model = lag_campaign(3, 1.0)
    d = diagnose(c, model, **OPTS)
    assert d.verdict_effect == "thermal_lag", (d.verdict, d.ranked()[:4])
    assert not _cand(d, "thermal_lag_history").refit["form"]["beats_simpler"]


def test_the_models_rate_form_lag_against_the_history_enters_the_gap():
    """The rate-form ``thermal_lag`` in the model, a ramp with the rates measured per visit: the
    history form has no score test, so its likelihood ratio over the model's rate form did not enter
    the gap's family. An outside probe (element 2 min behind a housing 15 min behind the air, 2
    degC/min): the history form beat the rate form by chi^2 31 (LR p 2e-8), and the verdict was "no
    significant gap" (chi2/dof 1.15 on 180 dof) while ``fit`` refused the same model by its gate
    ``lag_form``. Now the drop is one test of the gap (``gap.tests["form:thermal_lag_history"]``,
    chi^2(1), one-sided). Independent bench (Euler), housing 20 min, 1 degC/min: the element 4 min
    behind the housing is named (Holm p 2e-12 .. 2e-27, seeds 1-4); the element at the rate form
    itself (H - tau dH/dt, 2 and 4 min) stays none, the history form no better (p = 1, seeds 1-4).
    At 2 min behind the housing the drop is p 0.001-1 (seeds 1-4): below the family's level, none
    (the fit's gate, which asks whether the two forms' answers differ, refuses those)."""
    model = LAG_MODEL + ("thermal_lag",)
    for rate_form, seed in ((False, 1), (False, 2), (True, 1), (True, 2)):
        txt, _ = simulate_lag_campaign(np.random.default_rng(seed), tau_element_min=4.0, location="housing",
                                       tau_housing_min=20.0, measured_rate=True, element_rate_form=rate_form)
        d = diagnose(parse_bench_csv(txt, f"ramp_{seed}.csv"), model, **OPTS)
        test = d.gap["tests"]["form:thermal_lag_history"]
        if rate_form:
            assert d.verdict_effect is None and test["p_value"] > 0.5, (seed, d.verdict, test)
        else:
            assert d.gap["significant"] and test["p_holm"] < 1e-6, (seed, test)
            assert d.verdict_effect == "thermal_lag_history", (seed, d.verdict)
            assert d.verdict["fit_options"].endswith("--thermal-lag-form housing")


def test_form_candidates_can_be_chosen_and_unknown_ones_are_refused():
    c, model = hysteresis_campaign(0, "play", 10.0)
    d = diagnose(c, model, candidates=("hysteresis_play", "position_error"), **OPTS)
    assert [x.effect for x in d.candidates] and {x.effect for x in d.candidates} == {"hysteresis_play",
                                                                                      "position_error"}
    assert d.verdict_effect == "hysteresis_play"
    from triadcal.errors import InputError
    with pytest.raises(InputError, match="unknown candidate"):
        diagnose(c, model, candidates=("hysteresis_backlash",), **OPTS)


# -- slow: confusion counts -----------------------------------------------------------------------
CASES = {
    "play_10C": lambda s: hysteresis_campaign(s, "play", 10.0),
    "play_30C": lambda s: hysteresis_campaign(s, "play", 30.0),
    "angle_tempco2": lambda s: hysteresis_campaign(s, "offset", quadratic_xy=0.004),
    "lag_housing_20_60min": lambda s: lag_campaign(s, 20.0 + 40.0 * (s % 20) / 19.0),
    "clean_offset": lambda s: hysteresis_campaign(s, "offset"),
}
EXPECTED = {"play_10C": "hysteresis_play", "play_30C": "hysteresis_play", "angle_tempco2": "angle_tempco2",
            "lag_housing_20_60min": "thermal_lag_history", "clean_offset": None}


def _one(args):
    case, seed = args
    c, model = CASES[case](seed)
    return case, seed, diagnose(c, model, **OPTS).verdict_effect


@pytest.mark.slow
def test_confusion_of_the_form_candidates():
    n = 20
    jobs = [(case, 100 + s) for case in CASES for s in range(n)]
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    with ProcessPoolExecutor(max_workers=2) as ex:
        rows = list(ex.map(_one, jobs))
    counts = {}
    for case, _, v in rows:
        counts.setdefault(case, {}).setdefault(str(v), 0)
        counts[case][str(v)] += 1
    print("\n" + "\n".join(f"{case}: {counts[case]}" for case in CASES))
    for case, want in EXPECTED.items():
        right = counts[case].get(str(want), 0)
        assert right >= 0.95 * n, (case, counts[case])
    for case in ("play_10C", "play_30C"):
        assert not {"position_error", "heavy_tails"} & set(counts[case]), counts[case]


def test_a_runner_up_ahead_in_elpd_is_said_why_it_was_not_named():
    """An outside probe: a thermal_lag_history runner-up (no structure left, not beating the rate form by
    its nested test) was said to be "a noise effect" that "keeps structure after its refit"."""
    from types import SimpleNamespace

    from triadcal.reports.diagnosis import _why_not_named

    form = SimpleNamespace(effect="thermal_lag_history", refit={
        "lr_p_value": 1e-30, "form": {"beats_simpler": False, "simpler_form": "thermal_lag (rate form)",
                                      "criterion": "chi2_rate_form - chi2_history = 4.6 against 9.21"}})
    noise = SimpleNamespace(effect="heavy_tails", refit={"lr_p_value": 1e-30})
    weak = SimpleNamespace(effect="bias_drift", refit={"lr_p_value": 0.2})
    d = SimpleNamespace(candidates=[form, noise, weak], alpha=0.01)
    assert "beats its simpler form" in _why_not_named(d, "thermal_lag_history")
    assert "noise effect" not in _why_not_named(d, "thermal_lag_history")
    assert "noise effect" in _why_not_named(d, "heavy_tails")
    assert "not significant" in _why_not_named(d, "bias_drift")


def test_isolated_slices_after_a_noise_refit_do_not_point_outside_the_vocabulary():
    """Probe Z: Student-t noise with the sd_* columns right kept 2-3 single cells after the heavy_tails
    refit and was told a term outside the vocabulary was "the likelier cause"."""
    from types import SimpleNamespace

    from triadcal.judgement.diagnose.verdict import _absorbed_conclusion

    def cand(slices, generic=()):
        return SimpleNamespace(refit={"gap_after": {"significant_slices": slices, "generic_structure": list(generic)}})

    assert "not told apart" in _absorbed_conclusion([cand(2)])
    assert "likelier cause" in _absorbed_conclusion([cand(2, ["temperature"])])
    assert "likelier cause" in _absorbed_conclusion([cand(7)])


def test_a_noise_candidate_far_ahead_of_the_best_partial_is_the_lead():
    """Probe Z: three 15-sigma visits on random axes; heavy_tails 259 elpd ahead of angle_tempco3 with one
    slice left, and the reason said only "refit with angle_tempco3 and diagnose again"."""
    from types import SimpleNamespace

    from triadcal.judgement.diagnose.verdict import _far_ahead_txt

    best = SimpleNamespace(effect="angle_tempco3", refit={"delta_elpd": 1.3, "delta_elpd_se": 20.4})
    ht = SimpleNamespace(effect="heavy_tails", refit={"delta_elpd": 260.7, "delta_elpd_se": 50.0,
                                                      "gap_after": {"significant_slices": 1, "generic_structure": []}})
    assert "heavy_tails is 259 elpd ahead of angle_tempco3" in _far_ahead_txt([ht], best)
    close = SimpleNamespace(effect="heavy_tails", refit={"delta_elpd": 40.0, "delta_elpd_se": 30.0,
                                                         "gap_after": {"significant_slices": 1, "generic_structure": []}})
    assert _far_ahead_txt([close], best) == ""
    smooth = SimpleNamespace(effect="flicker_noise", refit={"delta_elpd": 300.0, "delta_elpd_se": 10.0,
                                                            "gap_after": {"significant_slices": 1,
                                                                          "generic_structure": ["temperature"]}})
    assert _far_ahead_txt([smooth], best) == ""
