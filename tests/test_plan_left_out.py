"""The preset's effects that --effects leaves out (docs/plan.md, "An effect of the preset that
--effects leaves out"): an outside tester planned `plan --preset a18-silicon` with the default
(linear) effects, was told "Ca:U<=5arcsec met", and a campaign on that plan was refused by the fit
(model_mismatch, chi2/dof ~6.4, 10 of 10 seeds): the preset's quadratic angle tempcos
(0.0025-0.004 arcsec/degC^2) lie outside the fitted model. The planner now computes what each
left-out effect moves the targets by on the chosen plan and says so (a note, never a bare "met";
not a refusal).

Hand derivation (axis-aligned poses): a quadratic tempco c2 adds c2 (T - 20)^2 to its angle; the
linear model fits a line a + b (T - 20) to it over the visits, so the angle moves by the line's
intercept a and its tempco by the slope b:

- setpoints 20 -> -40 -> 85 degC (dT = 0, -60, 65; each visited by the same 12 positions, equal
  weights): mean dT 5/3, slope = sum((dT - m)(dT^2 - m2)) / sum((dT - m)^2) = 45583.3 / 7816.67
  = 5.8316 c2, intercept = 7825/3 c2 - 5.8316 c2 * 5/3 = 2598.6 c2 (10.39 arcsec for c2 = 0.004);
- setpoints -40 -> 85 degC only: the line through (a, c2 a^2), (b, c2 b^2) has intercept
  -c2 a b = 3900 c2 (15.6 arcsec for c2 = 0.004) and slope c2 (a + b) = 5 c2.

The visits' temperatures carry the sensors' self-heating (~0.3 degC) and the soak's tail: the
intercepts change by < 0.5 % (checked against the hand numbers), the slopes by 2 c2 delta (~10 %),
so the slopes are checked against an independent numpy line fit at the visits' own temperatures.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from triadcal.cli import main
from triadcal.models.simulate import PRESETS, preset_truth, simulate_campaign
from triadcal.planning.plan import Plan, design, left_out_signatures
from triadcal.planning.search import HELD_NEGLIGIBLE, left_out_moves, parse_targets

C2 = PRESETS["a18-silicon"]["Ca_xy_tempco2"]          # 0.004 arcsec/degC^2


def _moves(setpoints, effects=("angle_tempco",), preset="a18-silicon", target="Ca:U<=5arcsec,Ca_tempco:U<=0.1arcsec/degC"):
    plan = Plan(setpoints_C=setpoints)
    d = design(plan, effects, None, preset)
    sigs = left_out_signatures(plan, effects, None, preset)
    targets = parse_targets(target, d.names)
    mv = left_out_moves(d, targets, {"angle_tempco2": sigs["angle_tempco2"]}, 3e-9, 30.0)["angle_tempco2"]
    return plan, {m["parameter"]: m["bias"] for m in mv["moves"]}, mv


def _x_temperatures(plan, effects=("angle_tempco",)):
    c = simulate_campaign(preset_truth("a18-silicon", effects), plan.visit_positions(), plan.schedule())
    return np.asarray(c.covariates().temp)[0]          # the x sensor's temperature per visit


def test_three_setpoints_hand_derived():
    assert C2 == pytest.approx(0.004)
    plan, moves, mv = _moves((20.0, -40.0, 85.0))
    # hand: intercept 2598.6 c2 at the setpoints' nominal temperatures
    assert moves["Ca_xy"] == pytest.approx(2598.6 * C2, rel=5e-3)
    dT = np.array([0.0, -60.0, 65.0])
    a, b = np.linalg.lstsq(np.c_[np.ones(3), dT], C2 * dT ** 2, rcond=None)[0]
    assert a == pytest.approx(2598.6 * C2, rel=1e-4) and b == pytest.approx(5.8316 * C2, rel=1e-4)
    # independent: a line fitted to c2 (T - 20)^2 at the visits' own temperatures
    T = _x_temperatures(plan) - 20.0
    a, b = np.linalg.lstsq(np.c_[np.ones_like(T), T], C2 * T ** 2, rcond=None)[0]
    assert moves["Ca_xy"] == pytest.approx(a, rel=2e-3)
    assert moves["Ca_xy_tempco"] == pytest.approx(b, rel=1e-2)
    # the sign follows c2: Ca_xz's is negative (-0.003)
    assert PRESETS["a18-silicon"]["Ca_xz_tempco2"] < 0 and moves["Ca_xz"] < 0
    assert mv["significant"]


def test_two_setpoints_hand_derived():
    plan, moves, _ = _moves((-40.0, 85.0))
    # hand: the line through the two points: intercept -c2 a b = 3900 c2 (15.6 arcsec)
    assert moves["Ca_xy"] == pytest.approx(3900.0 * C2, rel=5e-3)
    T = _x_temperatures(plan) - 20.0
    a, b = np.linalg.lstsq(np.c_[np.ones_like(T), T], C2 * T ** 2, rcond=None)[0]
    assert moves["Ca_xy"] == pytest.approx(a, rel=2e-3)
    assert moves["Ca_xy_tempco"] == pytest.approx(b, rel=1e-2)


def test_effect_in_the_model_is_not_left_out():
    sigs = left_out_signatures(Plan(setpoints_C=(20.0, -40.0, 85.0)), ("angle_tempco", "angle_tempco2"), None,
                               "a18-silicon")
    assert "angle_tempco2" not in sigs and "angle_tempco3" in sigs
    # bench effects are the lab's, never reported as the unit's
    assert not {"bench_tilt", "tilt_drift", "tilt_settling", "bench_nonorthogonality"} & set(sigs)


def _run(tmp_path, capsys, target, *extra):
    out_plan, pred = tmp_path / "plan.json", tmp_path / "pred.json"
    code = main(["plan", "--no-progress", "--preset", "a18-silicon", "--target", target, "--range", "-40:85",
                 "-o", str(out_plan), "--json", str(pred), *extra])
    out, err = capsys.readouterr()
    return code, out, json.loads(pred.read_text())


def test_cli_says_left_out_quadratic_tempco(tmp_path, capsys):
    code, out, doc = _run(tmp_path, capsys, "Ca:U<=5arcsec")
    assert code == 0                                      # a note, not a refusal
    line = next(ln for ln in out.splitlines() if ln.strip().startswith("Ca:U<=5arcsec:"))
    assert "met if the unit has no angle_tempco2" in line and "NOT met" not in line
    assert not line.rstrip().endswith(" met")
    note = next(ln for ln in out.splitlines() if "note: angle_tempco2" in ln)
    assert "a18-silicon" in note and "0.0025 to 0.004 arcsec/degC2" in note and "add it to --effects" in note
    assert "Ca_yz by +2.18 arcsec" in note
    left = doc["assumptions"]["left_out_effects"]
    assert "angle_tempco2" in left
    assert left["angle_tempco2"]["preset_parameters"]["Ca_xy_tempco2"]["value"] == pytest.approx(0.004)
    worst = max(m["fraction_of_target"] for m in left["angle_tempco2"]["moves"].values())
    assert worst > HELD_NEGLIGIBLE
    assert "angle_tempco2" in doc["target"]["Ca:U<=5arcsec"]["met_if_unit_has_no"]
    assert doc["target"]["Ca:U<=5arcsec"]["met"] is True
    # the move printed is the one in PRED.json, the plan's own (not a refusal of the plan)
    mv = left["angle_tempco2"]["moves"]
    p = max(mv, key=lambda k: abs(mv[k]["bias"]))
    assert f"move {p} by {mv[p]['bias']:+.3g} arcsec" in note


def test_cli_no_note_when_the_effect_is_modelled(tmp_path, capsys):
    eff = "bench_tilt,angle_tempco,angle_tempco2,scale_tempco,bias_tempco,hysteresis"
    code, out, doc = _run(tmp_path, capsys, "Ca:U<=5arcsec", "--effects", eff)
    assert code == 0
    assert "note: angle_tempco2" not in out
    assert "angle_tempco2" not in doc["assumptions"]["left_out_effects"]


def test_cli_bare_met_when_every_move_is_negligible(tmp_path, capsys):
    # the largest move (angle_tempco2, ~2.2 arcsec) is under 1 % of a 1000 arcsec target
    code, out, doc = _run(tmp_path, capsys, "Ca:U<=1000arcsec")
    assert code == 0
    line = next(ln for ln in out.splitlines() if ln.strip().startswith("Ca:U<=1000arcsec:"))
    assert line.rstrip().endswith(" met")
    assert "note: angle_tempco2" not in out
    assert doc["assumptions"]["left_out_effects"] == {}
    assert "angle_tempco2" in doc["assumptions"]["left_out_negligible"]
    assert "met_if_unit_has_no" not in doc["target"]["Ca:U<=1000arcsec"]
