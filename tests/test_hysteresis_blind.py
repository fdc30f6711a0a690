"""A hysteresis of the angles the schedule cannot show (estimation/structure.py,
``hysteresis_confounding``; planning/plan.py, ``blind_to``).

An outside probe (its own numpy bench, 30 seeds): ``plan`` without ``hysteresis`` in ``--effects``
chose 20 (no branch) -> -40 (cooling) -> 85 degC (heating). There the branch of a visit is nearly
``-dT / 62.5 degC``, the angle tempco's own column: a unit with 6-15 arcsec of hysteresis fitted
without it passed every gate (status ok, chi2/dof 0.84) with every angle tempco 14-22 u off, and
nothing said so. Now the fit notes it with the shift per arcsec, and the planner does not choose
such a schedule.

Campaigns of tests/independent_bench.py (no project model code; its hysteresis is its own
``Ca_ab += h b``); the stated shift checked against two real fits, with and without the hysteresis.
"""

import numpy as np
import pytest

from independent_bench import default_truth, simulate_campaign
from triadcal.estimation.joint import fit_joint
from triadcal.estimation.structure import DRIFT_VISIBLE_MIN
from triadcal.io.bench_csv import parse_bench_csv
from triadcal.planning.search import search

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")
#: the probe's schedule: no temperature visited on both branches
ONE_PASS = (20, -40, 85)
#: the planner's schedule now: back through ambient on the way up
THROUGH_AMBIENT = (20, -40, 20, 85)
#: hysteresis of the angles, arcsec (the probe's unit)
H = {"xy": 12.0, "xz": -8.0, "yx": 15.0, "yz": 6.0, "zx": -10.0, "zy": 9.0}


def _fit(setpoints, hysteresis: bool, seed=0):
    truth = default_truth(np.random.default_rng(100 + seed))
    if hysteresis:
        truth.update({f"Ca_{ab}_hysteresis": h for ab, h in H.items()})
    text, truth = simulate_campaign(np.random.default_rng(seed), truth=truth, setpoints_C=setpoints,
                                    hysteresis={"form": "offset"} if hysteresis else None)
    return fit_joint(parse_bench_csv(text), effects=EFFECTS), truth


def test_a_schedule_blind_to_hysteresis_says_so_and_by_how_much_it_moves_the_tempcos():
    """On the probe's schedule the hysteresis passes every gate and moves the angle tempcos many u;
    the note says so before any hysteresis is there, and the stated move per arcsec times h is the
    difference of the two fits (same noise) within 3 %: the model is linear in the angles' offsets."""
    clean, _ = _fit(ONE_PASS, False)
    hyst, truth = _fit(ONE_PASS, True)
    assert clean.status == "ok" and hyst.status == "ok"            # no test of the residuals sees it
    conf = clean.fit["hysteresis_confounding"]
    note = next(n for n in clean.notes if n.startswith("the schedule cannot show a thermal hysteresis"))
    assert "4-60 arcsec" in note and "--effects ...,hysteresis" in note
    off = 0
    for ab, h in H.items():
        c = conf[ab]
        assert c["visible_fraction"] < DRIFT_VISIBLE_MIN
        name = f"Ca_{ab}_tempco"
        assert next(iter(c["moves_u_per_arcsec"])) == name
        predicted = h * c["moves_u_per_arcsec"][name] * clean[name].u
        seen = hyst[name].value - clean[name].value
        assert seen == pytest.approx(predicted, rel=0.03), (ab, seen, predicted)
        off += abs(hyst[name].value - truth[name]) > 2 * hyst[name].u
    assert off == 6                                                  # the wrong answer it warns of


def test_a_schedule_through_ambient_shows_the_hysteresis_and_has_no_note():
    """Back through 20 degC on the heating leg, 20 degC is visited with no branch and on the heating
    one: most of the hysteresis's signature is outside the model, no note, and the unit with the
    hysteresis is refused (the model misses it) instead of passing."""
    clean, _ = _fit(THROUGH_AMBIENT, False)
    conf = clean.fit["hysteresis_confounding"]
    assert all(c["visible_fraction"] > 0.2 for c in conf.values()), conf
    assert not any(n.startswith("the schedule cannot show a thermal hysteresis") for n in clean.notes)
    hyst, _ = _fit(THROUGH_AMBIENT, True)
    assert hyst.status == "model_mismatch", hyst.status


def test_a_model_with_the_hysteresis_has_nothing_to_say():
    truth = default_truth(np.random.default_rng(7))
    text, _ = simulate_campaign(np.random.default_rng(7), truth=truth, setpoints_C=(20, 70, -40, 20))
    r = fit_joint(parse_bench_csv(text), effects=EFFECTS + ("hysteresis",))
    assert "hysteresis_confounding" not in r.fit


def test_the_planner_without_hysteresis_does_not_choose_a_blind_schedule():
    """The probe's command: targets on Ca, Ca_tempco and K over -40:85 degC without hysteresis in the
    model. It chose 20, -40, 85 degC; now the cheapest schedule that shows a hysteresis: 20, -40,
    20, 85 (one soak more)."""
    choice = search("Ca:U<=5arcsec, Ca_tempco:U<=0.1arcsec/degC, K:U<=20ppm", -40.0, 85.0, effects=EFFECTS)
    sps = tuple(choice.plan.setpoints_C)
    assert sps == THROUGH_AMBIENT, sps
    dirs = choice.plan.directions()
    at_20 = {d for s, d in zip(sps, dirs) if s == 20}
    assert at_20 == {"none", "heating"}


def test_a_range_every_schedule_of_which_is_blind_is_refused_naming_the_effect():
    """Only the one-pass schedules: the planner refuses, naming the effect and the fraction."""
    from triadcal.errors import InputError

    with pytest.raises(InputError, match=r"blind to an effect the model leaves out \(hysteresis: [0-9.]+ %"):
        search("Ca:U<=5arcsec", -40.0, 85.0, effects=EFFECTS,
               sequences=[("one pass", (20.0, -40.0, 85.0))])
