"""Open-world checks of the diagnosis on effects that are in no simulator of the project and in
no candidate: made by the independent bench (tests/independent_bench.py, scipy rotations, no
code of ``triadcal.models``), written to a real CSV file, read by the reader of ``triadcal
diagnose``.

Each effect is physical and outside the vocabulary, so the right answer is ``unexplained``
(with where it lies), never a name and never a noise effect:

* an encoder's once-per-revolution error on axis 1 (12 arcsec) and a twice-per-revolution error
  on axis 2 (10 arcsec): errors of the bench angles that depend on the angle, not a zero;
* a step of the y bias (40 ug at hour 20: a knock during the campaign), not a drift;
* a hysteresis of the z bias (offset form, +-20 ug by the direction of the last temperature
  change): the vocabulary's hysteresis is of the angles;
* the unit slipping 30 arcsec about IMU x in its fixture at hour 12, in the middle of the heating;
* the base tilting with the building's day (24 h period; 8 and 6 arcsec on its two components):
  a tilt the visits of one soak share, which the vocabulary's tilt (constant, a rate, a settling)
  does not follow, and which positioning errors (independent per visit) absorbed as noise before
  the ``tilt`` family (generic.soak_basis) was asked after every refit;
* a K2 that changes with temperature (0.5 ug/g^2/degC on every axis, 30 ug at 80 degC along an
  axis): the vocabulary's K2 is constant, and u g_a^2 is in no generic family;
* a fixture that rocks on its seat, rotated +-8 arcsec about IMU x by the side that is down (the
  sign of G_z): a misalignment that depends on the pose, neither K2 nor an asymmetry;
* a bias that is a sine in time: 25 ug on x with an 8 h period (a supply following the lab's day),
  20 ug on x, y, z (gains 1, 0.6, 0.8) with a 3 h period (a ground loop with the compressor's
  cycle): a 1/f covariance absorbs any pattern in time, so flicker_noise must beat the best sine in
  time to be named (an outside probe's: named, gap closed, chi2/dof up to 4.4 before);
* a thermometer that reads 0.5 degC high when heating and low when cooling (its own hysteresis, or
  a self-heating that follows the airflow): the unit follows its true temperature, the file's
  t_* do not (``test_a_thermometer_with_a_hysteresis_is_unexplained``).

And the noise effect that fits: three visits contaminated by 150 ug of random sign (a door
slammed) are ``heavy_tails``. When the three have one sign on one axis the Student-t can leave
one slice's offset behind; the verdict may then be ``unexplained``, but it must say that
heavy_tails would absorb it.

Noise 5e-4 V per sample, 3000 samples a visit: a visit's mean has an SD of 9 ug, so each effect is
4-5 SD of one visit at most (12 arcsec is 58 ug at 1 g across the axis).
"""

import json
import math
import re

import numpy as np
import pytest

from independent_bench import simulate_campaign
from triadcal.io.bench_csv import read_bench_csv
from triadcal.judgement.diagnose import diagnose
from triadcal.judgement.diagnose.candidates import HYSTERESIS_FAMILY
from triadcal.models.effects import NOISE_EFFECTS

#: one heating and one cooling leg: 9 soaks of 12 positions, 38 h
PATH_C = (-40, -10, 20, 50, 80, 50, 20, -10, -40)
UG = 1e-6
NOISE = ("position_error", "heavy_tails", "flicker_noise")
#: a visit mean's SD on the independent bench (noise 5e-4 V a sample, 3000 samples; g at K = 1 g/V)
SE_G = 5e-4 / math.sqrt(3000)
#: the last visit of PATH_C's schedule (s)
END_S = 7200.0 * 9 + 8000.0 * 8 + 50.0 * 11


def _bias(vector_ug):
    return lambda k, t, T, G, d: np.asarray(vector_ug(k, t, d), float) * UG


FOREIGN = {
    "encoder_once_per_rev_axis1": dict(encoder_error=lambda a1, a2: (12.0 * np.sin(a1 + 0.5), 0.0 * a2)),
    "encoder_twice_per_rev_axis2": dict(encoder_error=lambda a1, a2: (0.0 * a1, 10.0 * np.sin(2.0 * a2 + 0.3))),
    "bias_step": dict(extra_bias=_bias(lambda k, t, d: (0.0, 40.0 if t > 20 * 3600.0 else 0.0, 0.0))),
    "bias_hysteresis": dict(extra_bias=_bias(lambda k, t, d: (0.0, 0.0, {"heating": -20.0,
                                                                          "cooling": 20.0}.get(d, 0.0)))),
    "fixture_slip": dict(fixture_change=lambda t: np.column_stack([30.0 * (t > 12 * 3600.0), 0 * t, 0 * t])),
    "diurnal_tilt": dict(tilt_change=lambda t: (8.0 * np.sin(2.0 * math.pi * t / 86400.0 + 0.7),
                                                6.0 * np.cos(2.0 * math.pi * t / 86400.0 + 0.2))),
    "k2_tempco": dict(extra_bias=lambda k, t, T, G, d: 0.5e-6 * (np.mean(T) - 20.0) * np.asarray(G) ** 2),
    "rocking_fixture": dict(extra_bias=lambda k, t, T, G, d: np.cross(
        np.array([np.sign(G[2]) * math.radians(8.0 / 3600.0), 0.0, 0.0]), np.asarray(G))),
    # periodic biases (a supply following the lab's day, a ground loop with a compressor's cycle):
    # flicker_noise absorbed them, gap closed, until the sine rival (rivals.periodic_rival)
    "bias_sine_8h": dict(extra_bias=_bias(lambda k, t, d: (25.0 * math.sin(2 * math.pi * t / (8 * 3600.0) + 0.4),
                                                          0.0, 0.0))),
    "ground_loop_3h": dict(extra_bias=_bias(lambda k, t, d: tuple(
        g * 20.0 * math.sin(2 * math.pi * t / (3 * 3600.0) + 1.1) for g in (1.0, 0.6, 0.8)))),
}
#: changes of the scale factors outside the vocabulary (its scale terms follow the temperature and
#: the specific force, not the time or the branch), near the detection limit: 40 and -30 ppm of x
#: and y over the campaign (an ageing scale), a 25 ppm step of y at hour 20 (a knock), and a
#: hysteresis of the z scale, +-15 ppm by the direction of the last temperature change (written as
#: a bias 15 ppm x G_z, G the gravity on the IMU axes)
FOREIGN_SCALE = {
    "scale_drift": dict(extra_scale=lambda k, t, T: np.array([40e-6, -30e-6, 0.0]) * t / END_S),
    "scale_step": dict(extra_scale=lambda k, t, T: np.array([0.0, 25e-6 if t > 20 * 3600.0 else 0.0, 0.0])),
    "scale_hysteresis": dict(extra_bias=lambda k, t, T, G, d: np.array(
        [0.0, 0.0, {"heating": 15e-6, "cooling": -15e-6}.get(d, 0.0) * G[2]])),
}
SPIKES = {17: (150.0, 0.0, 0.0), 50: (0.0, -150.0, 0.0), 91: (0.0, 0.0, 150.0)}
SPIKES_ONE_SIGN = {17: (150.0, 0.0, 0.0), 50: (150.0, 0.0, 0.0), 91: (150.0, 0.0, 0.0)}


def _diagnose(tmp_path, name, seed, **kw):
    text, _ = simulate_campaign(np.random.default_rng(seed), setpoints_C=PATH_C, tilt_arcsec=(40.0, -25.0), **kw)
    path = tmp_path / f"{name}_{seed}.csv"
    path.write_text(text, encoding="utf-8")
    return diagnose(read_bench_csv(path))


#: the periodic biases: a smooth law in time (a warm-up) may close their gap and still be unexplained
#: because it does not beat a wander of the bias (ambiguous_with; noise estimated, 8 h sine, seed 3)
PERIODIC = ("bias_sine_8h", "ground_loop_3h")


def _check_unexplained(d, name, seed):
    v = d.verdict
    assert d.gap["significant"], (name, seed)
    assert v["effect"] == "unexplained", (name, seed, v)
    # localised: by the slices, or by the shape against temperature, time, orientation, direction
    assert v["where"] or v["shape"], (name, seed, v)
    assert v.get("gap_closed") is not True or (name in PERIODIC and v.get("ambiguous_with")), (name, seed, v)
    assert v.get("best_partial") not in NOISE, (name, seed, v)


def _check_spikes(d, seed, one_sign):
    v = d.verdict
    if v["effect"] == "heavy_tails":
        # with estimated noise no chi2 can say the gap closed: gap_closed is absent then, never false
        assert v.get("gap_closed") is (True if d.noise_known else None), v
        return
    assert one_sign, (seed, v)           # random signs: heavy_tails every time
    assert v["effect"] == "unexplained" and "heavy_tails" in v["reason"].split("would absorb it as noise")[0], v


@pytest.mark.parametrize("name", sorted(FOREIGN))
def test_an_effect_outside_the_vocabulary_is_unexplained(tmp_path, name):
    _check_unexplained(_diagnose(tmp_path, name, 1, **FOREIGN[name]), name, 1)


@pytest.mark.parametrize("name", sorted(FOREIGN_SCALE))
def test_a_scale_change_outside_the_vocabulary_is_unexplained(tmp_path, name):
    """A scale that drifts with time, steps, or has a hysteresis of its own is no term of the
    vocabulary (scale_tempco* follow the temperature, scale_warmup the power-on): 'unexplained',
    never a tempco that shrinks the gap (seed 1 here; seeds 2-5 in the slow test below: 5 of 5 each,
    2026-11-28)."""
    _check_unexplained(_diagnose(tmp_path, name, 1, **FOREIGN_SCALE[name]), name, 1)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 3, 4, 5])
def test_scale_changes_outside_the_vocabulary_over_seeds(tmp_path, seed):
    for name, kw in FOREIGN_SCALE.items():
        _check_unexplained(_diagnose(tmp_path, name, seed, **kw), name, seed)


def test_a_tilt_that_follows_the_day_is_a_tilt_per_soak_not_positioning_errors(tmp_path):
    """Seed 1 of diurnal_tilt: positioning errors (independent per visit) absorbed it with the gap
    closed; the tilt free at each soak (generic.soak_basis) is what is left after their refit,
    and it is the gap's shape, first."""
    d = _diagnose(tmp_path, "diurnal_tilt", 1, **FOREIGN["diurnal_tilt"])
    _check_unexplained(d, "diurnal_tilt", 1)
    assert d.verdict["shape"][0]["family"] == "tilt", d.verdict["shape"]
    pe = next(c for c in d.candidates if c.effect == "position_error")
    assert "tilt" in pe.refit["gap_after"]["generic_structure"], pe.refit["gap_after"]


def _scale_wander(seed: int, sd_ppm: float = 20.0, tau_h: float = 6.0):
    """``extra_scale`` of a Gauss-Markov wander of the x scale (scale-factor instability): SD
    ``sd_ppm``, correlation time ``tau_h``, the exact discretisation x_k = a x_(k-1) + sqrt(1 - a^2) w_k,
    a = exp(-dt / tau), written here with numpy (its own generator, seeded ``seed`` + 888)."""
    rng = np.random.default_rng(seed + 888)
    state = {"t": None, "x": rng.normal(0.0, sd_ppm)}

    def extra_scale(k, t, T):
        if state["t"] is not None:
            a = math.exp(-(t - state["t"]) / (tau_h * 3600.0))
            state["x"] = a * state["x"] + math.sqrt(1.0 - a * a) * rng.normal(0.0, sd_ppm)
        state["t"] = t
        return np.array([state["x"] * 1e-6, 0.0, 0.0])
    return extra_scale


@pytest.mark.parametrize("seed", [1, 2, 3, 6])
def test_a_scale_that_wanders_is_unexplained_and_shaped_scale(tmp_path, seed):
    """A scale of x that wanders in time (20 ppm, correlation time 6 h: foreign to every simulator
    here) is 'unexplained', and its shape holds the scale free at each soak (generic.soak_basis, the
    family ``scale``, among the gap's tests). Before, seed 2 was 'none' (the family finds it), and
    seeds 3 and 6 were named ``scale_tempco2`` and ``scale_tempco3`` with the gap closed: a realisation
    that follows a polynomial in temperature to the noise; a scale tempco must now beat a scale that
    wanders (correlated.SCALE_WANDER_MIMICS; seed 3: p 0.12 under its REML covariance). Seeds 1-20:
    named 3, 'none' 4 before; named 0, 'none' 1 now (docs/diagnosis.md, "A scale that wanders")."""
    d = _diagnose(tmp_path, "scale_wander", seed, extra_scale=_scale_wander(seed))
    v = d.verdict
    assert v["effect"] == "unexplained" and d.gap["significant"] and (v["where"] or v["shape"]), (seed, v)
    assert "scale" in [x["family"] for x in d.verdict["shape"]], d.verdict["shape"]
    if seed == 3:
        v = d.verdict
        assert v["best_partial"] == "scale_tempco2" and v["ambiguous_with"][0].startswith("a scale that wanders"), v
        assert v["wander_rival"]["quantity"] == "scale" and v["wander_rival"]["p_value"] > 0.05, v


@pytest.mark.parametrize("seed", [3, pytest.param(9, marks=pytest.mark.slow)])
def test_a_scale_that_wanders_with_the_noise_estimated_is_unexplained(tmp_path, seed):
    """The same wandering scale with the noise columns removed (the white level estimated): before,
    the wander rival was asked with known noise only, and seeds 3, 6, 9 and 15 of 1-20 were named a
    scale tempco with the gap closed. Now it is asked with the level free (REML with the level
    profiled out, the score an F test): named 0 of 20, these four 'unexplained' ambiguous with a
    scale that wanders (p 0.13, 0.11, 0.56, 0.31; docs/diagnosis.md "A scale that wanders")."""
    text, _ = simulate_campaign(np.random.default_rng(seed), setpoints_C=PATH_C, tilt_arcsec=(40.0, -25.0),
                                extra_scale=_scale_wander(seed))
    path = tmp_path / f"scale_wander_{seed}_estimated.csv"
    path.write_text(_without_noise_columns(text), encoding="utf-8")
    d = diagnose(read_bench_csv(path))
    v = d.verdict
    assert not d.noise_known and d.gap["significant"], d.gap
    assert v["effect"] == "unexplained" and v["gap_closed"] is True and (v["where"] or v["shape"]), v
    assert v["best_partial"].startswith("scale_tempco") and v["ambiguous_with"][0].startswith("a scale that wanders"), v
    w = v["wander_rival"]
    assert w["quantity"] == "scale" and w["p_value"] > 0.05 and len(w["F_dof"]) == 2, w
    assert "F test" in d.verdict["reason"], d.verdict["reason"]
    d.save(tmp_path / "d.json")                     # F_dof in the schema of docs/results-json.md
    from test_results_contract import errors
    assert errors(json.loads((tmp_path / "d.json").read_text())) == []
    # issue 18 item 6: no chi2 level with the noise estimated -- the summary and the report say so and
    # what it was estimated from, and how far each refit shrank the gap as a ratio to the base fit's
    # (the candidates' chi2/dof after were 1e-8-like ratios of relative weights before)
    from triadcal.reports.diagnosis import html_report, summary_text
    for c in d.candidates:
        if c.refit:
            a = c.refit["gap_after"]
            assert a["chi2_dof"] is None and c.refit["gap_before"]["chi2_dof"] is None, (c.effect, a)
            if c.effect in NOISE_EFFECTS:       # reweighted or whitened: no ratio to the base fit's
                assert a["chi2_dof_ratio"] is None, (c.effect, a)
                continue
            # nested at the optimum: chi2 does not rise, so the ratio is at most dof before / dof after
            bound = d.gap["dof"] / c.refit["dof_after"] * (1.0 + 1e-6)
            assert 0.0 < a["chi2_dof_ratio"] <= bound, (c.effect, a["chi2_dof_ratio"], bound)
    text = summary_text(d)
    assert "the noise was estimated from the residuals" in text and not re.search(r"chi2/dof after [0-9]", text), text
    assert "of the base fit's (noise estimated: no chi2 level)" in text and "not computed" not in text, text
    page = html_report(d)
    assert "the noise was estimated from the residuals" in page and "of the base fit&#x27;s (noise estimated" in page


def _thermometer_hysteresis(text: str, delta_C: float) -> str:
    """The CSV with every t_* reading delta_C high on the heating branch and low on the cooling one."""
    lines = text.splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    cols = lines[head].split(",")
    di, ti = cols.index("direction"), [cols.index(c) for c in ("t_x", "t_y", "t_z")]
    out = lines[:head + 1]
    for line in lines[head + 1:]:
        f = line.split(",")
        sign = {"heating": 1.0, "cooling": -1.0}.get(f[di], 0.0)
        for i in ti:
            f[i] = f"{float(f[i]) + sign * delta_C:.4f}"
        out.append(",".join(f))
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("seed", [1, pytest.param(2, marks=pytest.mark.slow), pytest.param(3, marks=pytest.mark.slow)])
def test_a_thermometer_with_a_hysteresis_is_unexplained(tmp_path, seed):
    """The unit's tempcos (up to 20 ug/degC and 30 ppm/degC) meet a temperature misread by
    +-0.5 degC by the branch: offsets of bias and scale by the direction, which the vocabulary's
    hysteresis (of the angles) does not hold. 'unexplained', its shape led by the direction family
    (seeds 1-8 at 0.5 and 1 degC: 16 of 16, 2026-11-28)."""
    text, _ = simulate_campaign(np.random.default_rng(seed), setpoints_C=PATH_C, tilt_arcsec=(40.0, -25.0))
    path = tmp_path / f"thermometer_{seed}.csv"
    path.write_text(_thermometer_hysteresis(text, 0.5), encoding="utf-8")
    d = diagnose(read_bench_csv(path))
    _check_unexplained(d, "thermometer_hysteresis", seed)
    assert d.verdict["shape"][0]["family"] == "direction", d.verdict


def test_clean_campaign_of_the_independent_bench_has_no_gap(tmp_path):
    d = _diagnose(tmp_path, "clean", 1)
    assert d.verdict["effect"] is None and not d.gap["significant"], d.verdict


def test_contaminated_visits_are_heavy_tails(tmp_path):
    spikes = _bias(lambda k, t, d: SPIKES.get(k, (0.0, 0.0, 0.0)))
    _check_spikes(_diagnose(tmp_path, "spikes", 1, extra_bias=spikes), 1, one_sign=False)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 3, 4, 5])
def test_foreign_effects_over_seeds(tmp_path, seed):
    """Seeds 2-5 of every case above; the one-signed contamination too (heavy_tails named, or
    unexplained saying that heavy_tails would absorb it)."""
    for name, kw in FOREIGN.items():
        _check_unexplained(_diagnose(tmp_path, name, seed, **kw), name, seed)
    d = _diagnose(tmp_path, "clean", seed)
    assert d.verdict["effect"] is None, (seed, d.verdict)
    for one_sign, table in ((False, SPIKES), (True, SPIKES_ONE_SIGN)):
        spikes = _bias(lambda k, t, d, table=table: table.get(k, (0.0, 0.0, 0.0)))
        _check_spikes(_diagnose(tmp_path, f"spikes{int(one_sign)}", seed, extra_bias=spikes), seed, one_sign)


def test_the_foreign_effects_are_of_the_size_stated():
    """The docstring's sizes, by hand: 12 arcsec across a 1 g axis is 58 ug; a visit's mean has an
    SD of 5e-4 / sqrt(3000) V, 9.1 ug at K = 1 g/V."""
    assert math.isclose(math.radians(12.0 / 3600.0) * 1e6, 58.2, abs_tol=0.1)
    assert math.isclose(5e-4 / math.sqrt(3000) * 1e6, 9.13, abs_tol=0.01)


SLIP_AT_THE_TURN = dict(fixture_change=lambda t: np.column_stack([30.0 * (t > 20 * 3600.0), 0 * t, 0 * t]))


def test_a_slip_at_the_turn_of_one_cycle_is_a_step_in_time_not_a_hysteresis(tmp_path):
    """A slip at hour 20, when the path turns from heating to cooling: on one cycle it gives the
    two branches of a hysteresis. It was named ``hysteresis_play`` with the design's caveat (5 of 5,
    2026-11-28); since 2026-12-01 a hysteresis must beat a step of the angles in time wherever it
    falls (docs/diagnosis.md "Rivals"), and a slip is one: 'unexplained', the hysteresis the best
    partial answer, ambiguous with the step at the turn. A second heating tells them apart too: the
    slip stays, a hysteresis would come back."""
    from triadcal.judgement.diagnose.candidates import HYSTERESIS_FAMILY, turns
    from triadcal.reports.diagnosis import summary_text

    d = _diagnose(tmp_path, "slip_turn", 1, **SLIP_AT_THE_TURN)
    v = d.verdict
    assert v["effect"] == "unexplained" and v["best_partial"] in HYSTERESIS_FAMILY and v["gap_closed"] is True, v
    step = v["ambiguous_with"][0]
    assert step.startswith("a step of the six angles in time (at "), v
    assert 18.0 < float(step.split("(at ")[1].split(" h)")[0]) < 22.0, step      # at the turn, hour 20
    assert v["closest_rival"]["p_value"] >= 0.01 and "caveat" not in v
    line = next(x for x in summary_text(d).splitlines() if x.startswith("verdict:"))
    assert "unexplained" in line

    text, _ = simulate_campaign(np.random.default_rng(1), setpoints_C=PATH_C + (-10, 20, 50, 80),
                                tilt_arcsec=(40.0, -25.0), **SLIP_AT_THE_TURN)
    path = tmp_path / "slip_two_turns.csv"
    path.write_text(text, encoding="utf-8")
    c = read_bench_csv(path)
    assert turns(c) == 2
    d2 = diagnose(c)
    _check_unexplained(d2, "slip_two_turns", 1)
    assert "caveat" not in d2.verdict


def test_a_creep_on_one_cycle_is_a_hysteresis_with_the_designs_caveat_in_the_summary(tmp_path):
    """A creep of the unit in its fixture, linear over one cycle, is a function of temperature and
    branch there; a play fits its ramp better than a step (p 4e-10 against the best step, seed 1), so
    a hysteresis is named, with the caveat that a slow change gives the same branches, and the
    summary says it; a form candidate's verdict is not worded with a score test."""
    from triadcal.judgement.diagnose.candidates import HYSTERESIS_FAMILY
    from triadcal.reports.diagnosis import summary_text

    d = _diagnose(tmp_path, "creep", 1, **_slow_changes(END_S)["fixture_creep"])
    v = d.verdict
    assert v["effect"] in HYSTERESIS_FAMILY, v
    assert "turns 1 time(s)" in v["caveat"] and "second turn" in v["caveat"] and "slowly" in v["caveat"]
    assert v["closest_rival"]["rival"].startswith("a step of the six angles in time")
    line = next(x for x in summary_text(d).splitlines() if x.startswith("verdict:"))
    assert "caution: the temperature path turns 1 time(s)" in line
    assert "score p" not in line and "refit-only form candidate" in line


def test_an_encoder_error_on_poses_visited_once_is_a_positioning_error_with_a_caveat(tmp_path):
    """At one setpoint every pose is visited once: the once-per-revolution encoder error gives one
    fixed offset a pose, which no rule can tell from a random positioning error (the bench's poses
    are off either way). position_error is named, with the design's caveat, in the summary too;
    at nine setpoints the poses come back and the same error is 'unexplained' (above)."""
    from triadcal.reports.diagnosis import summary_text

    text, _ = simulate_campaign(np.random.default_rng(1), setpoints_C=(20,), tilt_arcsec=(40.0, -25.0),
                                **FOREIGN["encoder_once_per_rev_axis1"])
    path = tmp_path / "enc_one_setpoint.csv"
    path.write_text(text, encoding="utf-8")
    d = diagnose(read_bench_csv(path))
    assert d.verdict["effect"] == "position_error", d.verdict
    assert "every pose is visited once" in d.verdict["caveat"]
    line = next(x for x in summary_text(d).splitlines() if x.startswith("verdict:"))
    assert "caution: every pose is visited once" in line


#: slow changes of the unit in time: a creep of 20 arcsec about IMU x in its fixture and a drift of
#: 15 arcsec of the angle of x towards y, each linear over the campaign (``end_s`` its last visit)
def _slow_changes(end_s):
    return {
        "fixture_creep": dict(fixture_change=lambda t: np.column_stack([20.0 * t / end_s, 0 * t, 0 * t])),
        "angle_drift": dict(extra_bias=lambda k, t, T, G, d: np.array(
            [math.radians(15.0 / 3600.0) * t / end_s * G[1], 0.0, 0.0])),
    }


PATH_TWO_TURNS = PATH_C + (-10, 20, 50, 80)
END_TWO_TURNS_S = 7200.0 * 13 + 8000.0 * 12 + 50.0 * 11


def _slow_change_verdicts(tmp_path, seed):
    """One cycle: named a hysteresis, with the caveat that names a slow change, or 'unexplained' with a
    hysteresis the best partial answer when it does not beat a step of the angles in time (the angle's
    drift, seed 2: p 0.06); two: unexplained."""
    for name, kw in _slow_changes(END_S).items():
        v = _diagnose(tmp_path, name, seed, **kw).verdict
        if v["effect"] == "unexplained":
            assert v["best_partial"] in HYSTERESIS_FAMILY and v["gap_closed"] is True, (name, seed, v)
            assert v["ambiguous_with"][0].startswith("a step of the six angles in time"), (name, seed, v)
            assert v["closest_rival"]["p_value"] >= 0.01, (name, seed, v)
        else:
            assert v["effect"] in HYSTERESIS_FAMILY and "slowly" in v["caveat"], (name, seed, v)
    for name, kw in _slow_changes(END_TWO_TURNS_S).items():
        text, _ = simulate_campaign(np.random.default_rng(seed), setpoints_C=PATH_TWO_TURNS,
                                    tilt_arcsec=(40.0, -25.0), **kw)
        path = tmp_path / f"{name}_two_turns_{seed}.csv"
        path.write_text(text, encoding="utf-8")
        _check_unexplained(diagnose(read_bench_csv(path)), f"{name}_two_turns", seed)


@pytest.mark.slow   # 10-18 s; CI runs it with the slow tests (CI-29: the quick suite took 635 s of its 600)
def test_a_slow_change_of_the_unit_on_one_cycle_is_a_hysteresis_with_a_caveat_and_a_second_turn_tells(tmp_path):
    """A creep of the unit in its fixture or a drift of an angle, linear in time: on one heating and
    cooling each temperature is visited once a branch, so the change is a function of temperature
    and branch, and a hysteresis closes the gap (hysteresis_play 5 of 5 each, seeds 1-5, 2026-11-28; since
    the angle-step rival, 2026-12-01, the creep 5 of 5 and the drift 4 of 5, the fifth 'unexplained').
    No rule can tell them apart there, so the name carries the caveat, which says so; with a second
    heating the hysteresis would come back and the drift does not: 'unexplained' (3 of 3 each)."""
    _slow_change_verdicts(tmp_path, 1)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 3])
def test_slow_changes_of_the_unit_over_seeds(tmp_path, seed):
    _slow_change_verdicts(tmp_path, seed)


def test_turns_of_a_path_by_hand():
    from types import SimpleNamespace

    from triadcal.judgement.diagnose.candidates import design_caveat, turns

    def path(*directions):
        return SimpleNamespace(direction=np.array(directions), time_s=np.arange(len(directions), dtype=float))

    assert turns(path("none", "heating", "heating", "cooling", "cooling")) == 1
    assert turns(path("none", "heating", "cooling", "none", "heating")) == 2   # 'none' does not count
    assert turns(path("none", "none")) == 0
    # in the order of time, not of the rows
    shuffled = SimpleNamespace(direction=np.array(["cooling", "heating", "heating"]), time_s=np.array([3.0, 1.0, 2.0]))
    assert turns(shuffled) == 1
    assert design_caveat(path("none", "heating", "cooling"), "hysteresis") is not None
    assert design_caveat(path("none", "heating", "cooling", "heating"), "hysteresis_play") is None
    assert design_caveat(path("none", "heating", "cooling"), "bias_drift") is None
    # a positioning error: a caveat only when no pose is visited twice
    once = SimpleNamespace(axis1_deg=np.array([0.0, 90.0, 180.0]), axis2_deg=np.zeros(3), n_visits=3)
    again = SimpleNamespace(axis1_deg=np.array([0.0, 90.0, 0.0]), axis2_deg=np.zeros(3), n_visits=3)
    assert "visited once" in design_caveat(once, "position_error")
    assert design_caveat(again, "position_error") is None


def _without_noise_columns(text: str) -> str:
    """The CSV without ``sd_*`` and ``n_samples``: the diagnosis must estimate the noise."""
    lines = text.splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    drop = {i for i, c in enumerate(lines[head].split(",")) if c.startswith("sd_") or c == "n_samples"}
    return "\n".join(lines[:head] + [",".join(x for i, x in enumerate(line.split(",")) if i not in drop)
                                     for line in lines[head:]]) + "\n"


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_foreign_effects_with_the_noise_estimated(tmp_path, seed):
    """The same campaigns with the noise columns removed (the noise estimated from the residuals):
    every effect outside the vocabulary still 'unexplained' (the scale changes too), the clean
    campaign still 'none', the random-sign contamination still heavy_tails (measured 4 of 4 seeds
    each)."""
    cases = dict(FOREIGN, **FOREIGN_SCALE, clean={},
                 spikes=dict(extra_bias=_bias(lambda k, t, d: SPIKES.get(k, (0.0, 0.0, 0.0)))))
    for name, kw in cases.items():
        text, _ = simulate_campaign(np.random.default_rng(seed), setpoints_C=PATH_C, tilt_arcsec=(40.0, -25.0), **kw)
        path = tmp_path / f"{name}_{seed}_estimated.csv"
        path.write_text(_without_noise_columns(text), encoding="utf-8")
        d = diagnose(read_bench_csv(path))
        assert not d.noise_known, name
        if name == "clean":
            assert d.verdict["effect"] is None, (seed, d.verdict)
        elif name == "spikes":
            _check_spikes(d, seed, one_sign=False)
        else:
            _check_unexplained(d, name, seed)


#: a six-face tumble: one position of the 12 for each IMU axis up or down
SIX_FACES = ("P01", "P03", "P05", "P07", "P09", "P11")


def test_a_candidate_in_the_models_span_on_a_six_face_tumble_is_not_tested(tmp_path):
    """On six faces the bench's non-orthogonality is the sensor's misalignment written again: its
    column lies within 1.6e-6 of the fitted model's span. It was scored (p 4e-6 on the scale drift's
    seed 2, a direction set by rounding) and refitted without moving (u 2.8e5 arcsec, delta elpd
    -2.3e7); it is now not testable, with the reason, and the verdict does not change."""
    from independent_bench import POSITIONS

    six = {p: POSITIONS[p] for p in SIX_FACES}
    d = _diagnose(tmp_path, "six_scale_drift", 2, positions=six, **FOREIGN_SCALE["scale_drift"])
    c = next(c for c in d.candidates if c.effect == "bench_nonorthogonality")
    assert not c.testable and "span on this design" in c.reason, (c.testable, c.reason)
    assert all(not x.refit or x.refit["delta_elpd"] > -1e3 for x in d.candidates)
    _check_unexplained(d, "six_scale_drift", 2)
    # no single slice is significant: the verdict says where the misfit lies by its shape
    # time first; on six poses the pose's heading (generic family since 2026-12-02) holds a part of a
    # pattern ordered in time too (one heading per face)
    shape = [x["family"] for x in d.verdict["shape"]]
    assert d.verdict["where"] == [] and shape[0] == "time" and set(shape) <= {"time", "heading"}, shape
    from triadcal.reports.diagnosis import summary_text

    line = next(x for x in summary_text(d).splitlines() if x.startswith("verdict:"))
    assert "where: no single slice; shape against time (p(Holm) = " in line, line


@pytest.mark.slow
def test_foreign_effects_on_a_six_face_tumble(tmp_path):
    """The same effects with 6 positions a soak (one per face, seeds 1-3): the once-per-revolution
    encoder error, the bias step, the bias hysteresis, the slip and the three scale changes
    (FOREIGN_SCALE) stay 'unexplained', clean stays
    'none'. The twice-per-revolution error of axis 2 is +-3 arcsec (15 ug) at those angles: no gap,
    and nothing named."""
    from independent_bench import POSITIONS
    from triadcal.models.campaign import nominal_gravity

    six = {p: POSITIONS[p] for p in SIX_FACES}
    g = nominal_gravity(np.array([a for a, _ in six.values()]), np.array([b for _, b in six.values()])).reshape(-1, 3)
    assert sorted(map(tuple, np.round(g).astype(int).tolist())) == sorted(
        tuple(s * e) for e in np.eye(3, dtype=int) for s in (1, -1))
    for seed in (1, 2, 3):
        for name, kw in dict(FOREIGN, **FOREIGN_SCALE, clean={}).items():
            d = _diagnose(tmp_path, f"six_{name}", seed, positions=six, **kw)
            if name in ("clean", "encoder_twice_per_rev_axis2"):
                assert d.verdict["effect"] is None, (name, seed, d.verdict)
            else:
                _check_unexplained(d, name, seed)



def _growing_noise(seed, kind):
    """A white scatter added to every visit's biases, drawn with its own generator: its SD grows
    linearly from 0 at the start of the campaign to 2 SE at its end (``time``: the SD from x1 to
    x sqrt(5)), or is 2 SE at the 80 degC soak only (``hot``: SD x sqrt(5) there, 12 of 108 visits)."""
    rng = np.random.default_rng(10_000 + seed)
    if kind == "time":
        return lambda k, t, T, G, d: rng.normal(0.0, 2.0 * SE_G * t / END_S, 3)
    return lambda k, t, T, G, d: rng.normal(0.0, 2.0 * SE_G, 3) if np.mean(T) > 70.0 else np.zeros(3)


def test_a_flicker_that_over_whitens_a_growing_scatter_is_not_named(tmp_path):
    """Seed 10 of the time-growing scatter: a 1/f floor absorbs it, and no generic family keeps
    structure after its refit, so flicker_noise was named. Its whitened residuals are not white:
    the flicker's covariance differences independent visits, so adjacent ones are anti-correlated
    (the serial family after the refit, generic.serial_test: z about -5), and the verdict is
    'unexplained' with flicker_noise among what would absorb it."""
    d = _diagnose(tmp_path, "grow_time", 10, extra_bias=_growing_noise(10, "time"))
    _check_unexplained(d, "grow_time", 10)
    fl = next(c for c in d.candidates if c.effect == "flicker_noise")
    after = fl.refit["gap_after"]
    assert after["generic_structure"] == ["serial"], after["generic_structure"]
    assert after["generic"]["serial"]["z"] < -4.0 and after["generic"]["serial"]["p_holm"] < 0.01
    assert "flicker_noise" in d.verdict["reason"].split("would absorb it as noise")[0]


def test_a_flicker_floor_is_not_named_where_nothing_is_correlated_in_time(tmp_path):
    """Seed 6 of the time-growing scatter: flicker_noise's refit leaves no family significant (the
    serial test's p_holm 0.07), and it was named. Its premise fails: the generic correlated family
    (no candidate's covariance) finds nothing correlated in time before the refit (p = 1: the
    residuals are independent, only their scatter grows), so its white part took up a scatter and
    the verdict is 'unexplained' (correlated.py; docs/diagnosis.md, flicker_noise's Rule)."""
    d = _diagnose(tmp_path, "grow_time", 6, extra_bias=_growing_noise(6, "time"))
    _check_unexplained(d, "grow_time", 6)
    assert d.gap["tests"]["generic:correlated"]["p_value"] > 0.5
    fl = next(c for c in d.candidates if c.effect == "flicker_noise")
    assert fl.refit["gap_after"]["correlation_absent"]["p_value"] > 0.5
    assert "flicker_noise" in d.verdict["reason"].split("would absorb it as noise")[0]


@pytest.mark.slow
@pytest.mark.parametrize("noise_estimated", [False, True])
def test_noise_that_grows_with_time_or_temperature_is_not_a_noise_effect(tmp_path, noise_estimated):
    """Noise whose SD follows the time or the temperature is structure, not a noise effect of the
    vocabulary (none of them has a variance that changes over the campaign): Koenker's variance test
    looks at s, s^2 of the time and u, u^2 of the temperature (generic.variance_basis), and after a
    flicker_noise refit the serial test asks whether its whitened residuals are white
    (generic.serial_test), and flicker_noise is named only where the generic correlated family finds
    the residuals correlated in time before its refit (correlated.py); heavy_tails must beat a normal
    noise whose level changes soak by soak (noise_level.soak_level_rival). Over seeds 1-32 no noise
    effect is named, for the time or the temperature (before the soak-level rival: heavy_tails once
    for the temperature, seed 16, tests/test_soak_level_rival.py; before the correlation premise
    flicker_noise twice for the time). Asserted on seeds 1-16: none; before the premise 2 of 16 for
    the time, without the serial test 3, without the time columns 11.

    With the noise columns removed (``noise_estimated``, the white level estimated from the
    residuals) the same 32 campaigns: no noise effect named; 26 'unexplained' (the variance family,
    Koenker's test, is free of the level) and 6 'none', all of the time (seeds 3, 6, 7, 9, 10, 13:
    a scatter that grows from nothing is then measured against a level that includes it, and no
    test sees a gap; measured 2026-11-28)."""
    named = {"time": [], "hot": []}
    for kind in named:
        for seed in range(1, 17):
            if noise_estimated:
                text, _ = simulate_campaign(np.random.default_rng(seed), setpoints_C=PATH_C,
                                            tilt_arcsec=(40.0, -25.0), extra_bias=_growing_noise(seed, kind))
                path = tmp_path / f"grow_{kind}_{seed}_estimated.csv"
                path.write_text(_without_noise_columns(text), encoding="utf-8")
                d = diagnose(read_bench_csv(path))
                assert not d.noise_known
            else:
                d = _diagnose(tmp_path, f"grow_{kind}", seed, extra_bias=_growing_noise(seed, kind))
            if d.verdict["effect"] in NOISE:
                named[kind].append((seed, d.verdict["effect"]))
            else:
                assert d.verdict["effect"] in ("unexplained", None), (kind, seed, d.verdict)
    assert not named["time"] and not named["hot"], named


def test_a_field_fixed_in_the_room_is_unexplained_not_cross_coupling(monkeypatch):
    """A bias that follows the pose's rotation about the vertical -- a field fixed in the room acting on
    the sensor, C R^T b with b horizontal -- is no function of gravity, so no candidate and none of the
    five first mean families holds it. An outside probe's (tests/data/foreign/README.md) was named
    ``cross_coupling`` with the gap "closed" on seeds 2 and 5 of 6 (6.2 ug, visit noise 10 ug). The
    family ``heading`` (the base's horizontal directions in the sensor frame) is asked of the gap and
    after every refit: both are unexplained, the structure left after the best refit in that family.
    Without it (the family removed here) they are cross_coupling again: the test can fail. The same on
    the independent bench's own field (tests/independent_bench.py ``room_field``, 10 ug along x)."""
    from pathlib import Path

    import triadcal.judgement.diagnose.generic as generic
    from independent_bench import OBLIQUE_POSITIONS
    from triadcal.io.bench_csv import parse_bench_csv

    data = Path(__file__).parent / "data" / "foreign"
    for seed in (2, 5):
        c = read_bench_csv(data / f"room_field_probe_s{seed}.csv")
        d = diagnose(c)
        assert d.verdict_effect == "unexplained", (seed, d.verdict)
        assert d.gap["tests"]["generic:heading"]["p_holm"] < 1e-6
        best = next(x for x in d.candidates if x.effect == d.verdict.get("best_partial"))
        assert "heading" in best.refit["gap_after"]["generic_structure"], best.refit["gap_after"]
    C = np.diag([1.0, -0.6, 0.3]) * 1e-6
    C[2, 0] = 0.5e-6
    text, _ = simulate_campaign(np.random.default_rng(1), setpoints_C=PATH_C, tilt_arcsec=(40.0, -25.0),
                                positions=OBLIQUE_POSITIONS, room_field=(C, (10.0, 3.0, 0.0)))
    d = diagnose(parse_bench_csv(text, "room_field.csv"))
    assert d.verdict_effect == "unexplained" and d.gap["tests"]["generic:heading"]["p_holm"] < 1e-6, d.verdict
    orig = generic.per_output_terms
    monkeypatch.setattr(generic, "per_output_terms",
                        lambda c, T0=None: {k: v for k, v in orig(c, T0).items() if k != "heading"})
    d = diagnose(read_bench_csv(data / "room_field_probe_s2.csv"))
    assert d.verdict_effect == "cross_coupling", d.verdict
