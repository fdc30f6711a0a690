"""A bias drift the schedule cannot show (triadcal/estimation/structure.py, ``drift_confounding``):
on a schedule monotone in temperature the drift is in the span of the biases and their tempcos,
the residuals hold none of it and every gate passes; the result says so, with the shift per ug/h.

Campaigns of tests/independent_bench.py (no project model code), the drift made by its
``extra_bias`` hook (not the model's ``bias_drift``); the shift per ug/h checked against two real
fits, with and without the drift."""

import numpy as np
import pytest

from independent_bench import default_truth, simulate_campaign
from triadcal.estimation.joint import fit_joint
from triadcal.estimation.structure import DRIFT_VISIBLE_MIN
from triadcal.io.bench_csv import parse_bench_csv
from triadcal.models.effects import DEFAULT_EFFECTS

MONOTONE = (-40, -10, 20, 50, 80)
ROUND_TRIP = (20, 50, 80, 50, 20, -10, -40, -10, 20)


def _fit(setpoints, drift_ug_h=0.0, seed=0, effects=DEFAULT_EFFECTS):
    truth = default_truth(np.random.default_rng(100 + seed))
    text, truth = simulate_campaign(
        np.random.default_rng(seed), truth=truth, setpoints_C=setpoints,
        extra_bias=lambda k, t, T, G, d: np.array([1.0, -1.0, 1.0]) * drift_ug_h * 1e-6 * t / 3600.0)
    return fit_joint(parse_bench_csv(text), effects=tuple(effects)), truth


def test_a_monotone_schedule_says_it_cannot_show_a_drift_and_by_how_much_it_moves_the_tempcos():
    """Five setpoints -40..80 degC in order: 0.8 % of a drift's signature is outside the model. A
    drift of 2 ug/h (+, -, + on x, y, z) leaves every gate passing (status ok) with each S_a_tempco
    about 10 u off; the note names it, and the stated shift per ug/h times 2 is the difference of
    the two fits (same noise) within 2 %: the model is linear in the biases."""
    clean, _ = _fit(MONOTONE)
    drifted, truth = _fit(MONOTONE, 2.0)
    assert clean.status == "ok" and drifted.status == "ok"        # no test of the residuals sees it
    conf = clean.fit["bias_drift_confounding"]
    note = next(n for n in clean.notes if n.startswith("the schedule cannot show a bias drift"))
    for sign, a in zip((1.0, -1.0, 1.0), "xyz"):
        c = conf[a]
        assert c["visible_fraction"] < DRIFT_VISIBLE_MIN
        name = f"S_{a}_tempco"
        assert next(iter(c["moves_u_per_ug_h"])) == name and name in note
        predicted = sign * 2.0 * c["moves_u_per_ug_h"][name] * clean[name].u
        seen = drifted[name].value - clean[name].value
        assert seen == pytest.approx(predicted, rel=0.02), (a, seen, predicted)
        assert abs(drifted[name].value - truth[name]) > 8 * drifted[name].u       # the wrong answer it warns of


def test_a_round_trip_shows_the_drift_and_has_no_note():
    """The same unit on a round trip 20 -> 80 -> -40 -> 20 degC: most of the drift's signature is
    outside the model (0.80), the drift's SD about 0.1 ug/h; no note."""
    r, _ = _fit(ROUND_TRIP)
    conf = r.fit["bias_drift_confounding"]
    assert all(conf[a]["visible_fraction"] > 0.5 for a in "xyz")
    assert all(0.05 < conf[a]["sd_ug_per_h"] < 0.2 for a in "xyz")
    assert not any(n.startswith("the schedule cannot show a bias drift") for n in r.notes)


def test_a_model_with_the_drift_has_nothing_to_say():
    r, _ = _fit(ROUND_TRIP, effects=tuple(DEFAULT_EFFECTS) + ("bias_drift",))
    assert "bias_drift_confounding" not in r.fit
