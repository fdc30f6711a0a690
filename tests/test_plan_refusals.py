"""``triadcal plan``: refusals and requested effects (an outside tester's findings 2-4).

2. an effect in --effects that the chosen plan cannot estimate (K3 on the 12 axis-aligned poses) was
   dropped without a word and the K target printed "met" although K came out 7-21 ppm off;
3. --range beyond the plan file's own setpoint limits wrote a plan its reader refused;
4. --range=-40:1e9 was an internal error, a 0.01 degC range was blamed on --max-hours, --q 1e300
   gave an overflow and an absurd U.

The numbers checked are derived by hand, not taken from the planner: on a pose with gravity along
or across each sensing axis, ``a = +-1 g`` or 0, so ``a + K3 a^3 = a (1 + K3 * 1 g^2)``: the output
``(a + K3 a^3) / K`` is that of a scale factor ``K / (1 + K3)``, i.e. a K3 held at 0 moves the fitted
K by -K3 (in ppm for K3 in ug/g3): -15 ppm for the ak18-quartz preset's K3_x = 15 ug/g3.
"""
from __future__ import annotations

import json
import math

import pytest

from triadcal.cli import main
from triadcal.errors import InputError
from triadcal.planning import Plan, search
from triadcal.planning.plan import POSITION_SETS, design, held_sensitivity
from triadcal.planning.plan_fields import PLAN_TEMPERATURE_C
from triadcal.planning.search import Q_RANGE_V2S, checked_inputs, checked_range, prediction_document

CUBIC = ["bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis", "scale_cubic"]
FAST = dict(taus=(30.0, 120.0), repetitions=(1,))


# 2. a requested effect the plan cannot estimate --------------------------------------------------
def test_held_k3_moves_k_by_minus_one_ppm_per_ug_g3_on_axis_aligned_poses():
    d = design(Plan(setpoints_C=(20.0, -40.0, 85.0), positions=dict(POSITION_SETS[12])), CUBIC)
    assert {"K3_x", "K3_y", "K3_z"} <= set(d.problems)
    S = held_sensitivity(d, 3e-9, 30.0)
    names = list(d.names)
    for a in "xyz":
        # dK per ug/g3 of K3 (K in g/V): -K * 1e-6 (the hand derivation in the module docstring)
        rel_ppm = S[f"K3_{a}"][names.index(f"K_{a}")] / d.values[f"K_{a}"] * 1e6
        assert rel_ppm == pytest.approx(-1.0, rel=1e-3)
        # the other axes' scale factors do not take it up
        for b in "xyz".replace(a, ""):
            assert abs(S[f"K3_{a}"][names.index(f"K_{b}")] / d.values[f"K_{b}"] * 1e6) < 1e-3


def test_oblique_poses_estimate_k3():
    d = design(Plan(setpoints_C=(20.0, -40.0, 85.0), positions=dict(POSITION_SETS[18])), CUBIC)
    assert not {"K3_x", "K3_y", "K3_z"} & set(d.problems)


def test_plan_prefers_positions_that_estimate_every_requested_effect():
    # the probe's command chose the 12 positions (K3 held, K 7-21 ppm off against a "met" U of 5.8 ppm)
    choice = search("K:U<=8ppm", -40.0, 85.0, effects=CUBIC, **FAST)
    assert len(choice.plan.positions) in (18, 24)
    assert not {"K3_x", "K3_y", "K3_z"} & set(choice.problems)
    assert "K3_x" in choice.prediction["names"]
    assert not choice.held
    assert all(ok for ok, _, _ in choice.met.values())


def test_k_target_refused_when_no_plan_estimates_k3(tmp_path, capsys):
    with pytest.raises(InputError) as exc:
        search("K:U<=8ppm", -40.0, 85.0, effects=CUBIC, positions="12", **FAST)
    msg = str(exc.value)
    assert msg.startswith("--effects: scale_cubic")
    # the preset's K3 = 15 / -10 / 12 ug/g3 move K by -15 / +10 / -12 ppm (hand-derived), not "met"
    assert "moves K_x by -15 ppm" in msg and "moves K_y by +10 ppm" in msg and "moves K_z by -12 ppm" in msg
    assert "-1 ppm per ug/g3" in msg
    code = main(["plan", "--no-progress", "--target", "K:U<=8ppm", "--range", "-40:85", "--positions", "12",
                 "--effects", ",".join(CUBIC), "-o", str(tmp_path / "p.json")])
    out, err = capsys.readouterr()
    assert code == 1 and "--effects: scale_cubic" in err and " met" not in out
    assert not (tmp_path / "p.json").exists()


def test_ramp_refuses_likewise():
    from triadcal.planning.ramp import ramp_effects, search_ramp

    with pytest.raises(InputError, match=r"--effects: scale_cubic .*moves K_x by -15 ppm"):
        search_ramp("K:U<=8ppm", -40.0, 85.0, effects=ramp_effects(CUBIC), positions="12", taus=(30.0,),
                    rate_fractions=(1.0,), holds=(0.0,))


def test_held_effect_that_moves_no_target_is_said(tmp_path, capsys):
    # K3 on axis-aligned poses moves the angles by < 0.01 arcsec: the Ca target may be met, but the held
    # effect is printed and in PRED.json, not dropped silently
    choice = search("Ca:U<=5arcsec", -40.0, 85.0, effects=CUBIC, positions="12", **FAST)
    assert set(choice.held) == {"K3_x", "K3_y", "K3_z"}
    for h, v in choice.held.items():
        assert v["effect"] == "scale_cubic" and v["held_at"] == 0.0
        assert all(abs(mv["bias"]) < 0.01 * 5.0 for mv in v["moves"])
    doc = prediction_document(choice, Q_V2s=3e-9, lab_source=None, preset="ak18-quartz", effects=CUBIC)
    assert set(doc["assumptions"]["held_effects"]) == {"K3_x", "K3_y", "K3_z"}
    assert doc["assumptions"]["held_effects"]["K3_x"]["magnitude"] == 15.0
    code = main(["plan", "--no-progress", "--target", "Ca:U<=5arcsec", "--range", "-40:85", "--positions", "12",
                 "--effects", ",".join(CUBIC), "-o", str(tmp_path / "p.json"), "--json", str(tmp_path / "q.json")])
    out = capsys.readouterr().out
    assert code == 0 and "note: K3_x (scale_cubic) is not estimated by this plan, held at 0 ug/g3" in out
    assert "K3_x" in json.loads((tmp_path / "q.json").read_text())["assumptions"]["held_effects"]


# 3. --range within the plan file's setpoint limits ------------------------------------------------
@pytest.mark.parametrize("rng", ["-40:250", "-250:-150", "-40:1e9", "-101:20", "20:200.5"])
def test_range_outside_plan_limits_is_refused(tmp_path, capsys, rng):
    code = main(["plan", "--no-progress", "--target", "Ca:U<=5arcsec", f"--range={rng}", "-o",
                 str(tmp_path / "p.json")])
    err = capsys.readouterr().err
    assert code == 1 and "--range" in err and "-100 to 200 degC" in err and "internal error" not in err
    assert not (tmp_path / "p.json").exists()


def test_range_limits_are_the_readers():
    lo, hi = PLAN_TEMPERATURE_C
    checked_range(lo, hi)                               # the reader's own ends are accepted
    for bad in ((lo - 0.5, hi), (lo, hi + 0.5)):
        with pytest.raises(InputError, match="--range"):
            checked_range(*bad)
    with pytest.raises(InputError, match="--range"):   # the ramp search shares the check
        from triadcal.planning.ramp import search_ramp
        search_ramp("Ca:U<=5arcsec", -40.0, 250.0)


# 4. degenerate ranges and noise -------------------------------------------------------------------
@pytest.mark.parametrize("extra", [[], ["--max-hours", "10000"]])
def test_range_narrower_than_setpoint_steps_names_the_range(tmp_path, capsys, extra):
    code = main(["plan", "--no-progress", "--target", "Ca_tempco:U<=0.1arcsec/degC", "--range", "20:20.01",
                 "-o", str(tmp_path / "p.json")] + extra)
    err = capsys.readouterr().err
    assert code == 1 and err.count("error: --range") == 1
    assert "--max-hours" not in err and "one temperature" in err and "angle_tempco" in err


@pytest.mark.parametrize("q", ["1e300", "1e-300", "nan", "inf", "0", "-3e-9", "2"])
def test_q_outside_physical_range_is_refused(tmp_path, capsys, q):
    code = main(["plan", "--no-progress", "--target", "Ca:U<=5arcsec", "--range", "-40:85", f"--q={q}",
                 "-o", str(tmp_path / "p.json")])
    out, err = capsys.readouterr()
    assert code == 1 and "error: --q" in err and "warning" not in err and "internal error" not in err
    assert not (tmp_path / "p.json").exists()


def test_q_bounds():
    lo, hi = Q_RANGE_V2S
    # sqrt(Q_max) = 1 V/sqrt(Hz): at K ~ 1 g/V the noise of a 1 s average equals gravity
    assert math.sqrt(hi) == 1.0
    assert lo < 3e-9 < hi                               # the example unit's noise lies inside
    for q in (lo, 3e-9, hi):
        checked_inputs(1.0, q, "auto")


@pytest.mark.parametrize("ramp", [[], ["--ramp"]])
def test_a_chamber_faster_than_the_plan_files_limit_is_refused(tmp_path, capsys, ramp):
    """An outside probe: --chamber-rate 1000degC/min planned 'met' in 5.8 h (1.0 h with --ramp), exit 0,
    and simulate --plan then refused the file (rate out of range, <= 100 degC/min)."""
    code = main(["plan", "--no-progress", "--target", "K:U<=20ppm", "--range", "-40:85", "--chamber-rate",
                 "1000degC/min", *ramp, "-o", str(tmp_path / "p.json")])
    err = capsys.readouterr().err
    assert code == 1 and "--chamber-rate 1000 degC/min" in err and "100 degC/min" in err
    assert not (tmp_path / "p.json").exists()
