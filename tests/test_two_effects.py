"""Two effects at once, found one after the other (issue 18: "which unmodelled effect causes it, how
far the gap shrinks once it is added").

A real unit rarely lacks one term only. The diagnosis names one effect per verdict, and an effect
only when the gap after its refit is closed; with two effects missing the first verdict is
``unexplained``, its best partial answer the larger one and its ``remaining`` text "refit with X
and diagnose again". Following that advice (``diagnose --model ...,X``) must name the second, and
with both in the model the verdict must be ``none``. The campaigns are made by
``tests/independent_bench.py`` (scipy rotations, its own products and a backlash state machine,
not the model's terms): 24 poses (12 with gravity along a face diagonal), nine setpoints over
-40..80..-40 degC, a MEMS unit's magnitudes. Measured 2026-11-29 on seeds 1-4 of each pair: the
chain was right in 16 of 16 (docs/diagnosis.md, "Two effects at once").

A K2 is made as a bias proportional to the square of gravity on each axis (``extra_bias``), a
second mechanism too: the bench has no K2 term.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from independent_bench import OBLIQUE_POSITIONS, default_truth, simulate_campaign  # noqa: E402

from triadcal.errors import InputError  # noqa: E402
from triadcal.io.bench_csv import parse_bench_csv  # noqa: E402
from triadcal.judgement.diagnose import diagnose  # noqa: E402
from triadcal.judgement.diagnose.candidates import NOISE_MODEL_TERMS  # noqa: E402

BASE = ["angle_tempco", "scale_tempco", "bias_tempco"]
SETPOINTS = (-40, -10, 20, 50, 80, 50, 20, -10, -40)
KC = {"Kc_xy": 150.0, "Kc_xz": -100.0, "Kc_yx": 200.0, "Kc_yz": -120.0, "Kc_zx": 100.0, "Kc_zy": -180.0}
K3 = {"K3_x": 80.0, "K3_y": -60.0, "K3_z": 120.0}
GD = {"Ca_xy_g2": 15.0, "Ca_xz_g2": -10.0, "Ca_yx_g2": 12.0, "Ca_yz_g2": -15.0, "Ca_zx_g2": 10.0, "Ca_zy_g2": 8.0}
B2 = {"S_x_tempco2": 0.02, "S_y_tempco2": -0.015, "S_z_tempco2": 0.025}          # ug/degC^2: 72-90 ug at 80 degC
HY = {f"Ca_{ab}_hysteresis": v for ab, v in zip(("xy", "xz", "yx", "yz", "zx", "zy"), (8, -6, 7, -8, 6, 5))}
K2_UG = np.array([60.0, -50.0, 70.0])                                              # ug/g^2

#: pair -> (truth update, hysteresis, extra bias, the two effects in the order they are found)
PAIRS = {
    "cross_coupling+bias_tempco2": (dict(**KC, **B2), None, None, ("cross_coupling", "bias_tempco2")),
    "scale_cubic+hysteresis": (dict(**K3, **HY), {"form": "offset"}, None, ("hysteresis", "scale_cubic")),
    "cross_coupling+g_dependent_misalignment": (dict(**KC, **GD), None, None,
                                                ("cross_coupling", "g_dependent_misalignment")),
    "scale_nonlinearity+bias_tempco2": (dict(B2), None, lambda k, t, T, G, d: 1e-6 * K2_UG * G ** 2,
                                        ("bias_tempco2", "scale_nonlinearity")),
}


def _campaign(pair: str, seed: int):
    upd, hyst, extra_bias, _ = PAIRS[pair]
    return _make(upd, seed, hyst, extra_bias)


def _make(upd: dict, seed: int, hyst=None, extra_bias=None, encoder_error=None, **bench_errors):
    return parse_bench_csv(bench_text(upd, seed, hyst, extra_bias, encoder_error, **bench_errors))


def bench_text(upd: dict, seed: int, hyst=None, extra_bias=None, encoder_error=None, **bench_errors) -> str:
    """The bench CSV text of the independent bench's campaign with ``upd`` in its truth."""
    rng = np.random.default_rng(seed)
    truth = default_truth(rng)
    truth.update(upd)
    text, _ = simulate_campaign(rng, truth=truth, positions=OBLIQUE_POSITIONS, setpoints_C=SETPOINTS,
                                hysteresis=hyst, extra_bias=extra_bias, encoder_error=encoder_error, **bench_errors)
    return text


def chain(campaign, model=BASE, steps: int = 4):
    """Follow the verdicts' advice: add the named effect (or an ``unexplained`` verdict's best partial
    answer) to the model and diagnose again, until nothing is named. Returns the verdicts."""
    model, out = list(model), []
    for _ in range(steps):
        v = diagnose(campaign, model, n_draws=100, seed=1).verdict
        out.append(v)
        name = v.get("best_partial") if v.get("effect") == "unexplained" else v.get("effect")
        if not name or name in model or name in NOISE_MODEL_TERMS:          # a noise term ends it: fit with it
            break
        model += [e for e in (v.get("effects") or [name]) if e not in model]
    return out


@pytest.mark.slow          # 13 s for its one quick case: all slow since the thirteenth session
@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("pair", PAIRS)
def test_two_effects_are_found_one_after_the_other(pair, seed):
    first, second = PAIRS[pair][3]
    v = chain(_campaign(pair, seed))
    assert len(v) == 3, v
    # the first verdict does not name one effect as if it closed the gap: the other is still missing
    assert v[0]["effect"] == "unexplained" and v[0]["best_partial"] == first, v[0]
    assert "diagnose again" in v[0].get("remaining", "") + v[0].get("reason", ""), v[0]
    assert v[1]["effect"] == second and v[1].get("gap_closed", True), v[1]
    assert v[2].get("effect") is None, v[2]


@pytest.mark.parametrize("name", sorted(NOISE_MODEL_TERMS))
def test_diagnose_model_refuses_a_term_of_the_noise_model_and_says_where_it_goes(name):
    """``diagnose --model ...,heavy_tails`` said "unknown model effect": the name is known, but the
    diagnosis's weighted least squares holds terms of the mean only. The refusal says what the term
    is and that ``fit`` and ``sample`` take it (before any fit: nothing is computed)."""
    c = _campaign("cross_coupling+bias_tempco2", 1)
    with pytest.raises(InputError) as e:
        diagnose(c, BASE + [name])
    msg = str(e.value)
    assert f"{name} is part of the noise model" in msg and "fit --effects" in msg and "unknown" not in msg


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_with_an_effect_outside_the_vocabulary_the_chain_never_closes(seed):
    """Cross-coupling plus an encoder error of axis 1 once per revolution (12 arcsec, in no simulator
    of the project and no candidate). The first verdict points at the cross-coupling; after it every
    verdict stays ``unexplained``: the best partial answers that follow (g-dependent misalignment,
    K3: shapes the encoder error shares on oblique poses) leave the gap open, and no verdict names an
    effect or says ``none`` (seeds 1-4 measured 2026-11-29: 4 of 4)."""
    c = _make(KC, seed, encoder_error=lambda a1, a2: (12.0 * np.sin(a1 + 0.3), np.zeros_like(a2)))
    v = chain(c, steps=5)
    assert v[0]["effect"] == "unexplained" and v[0]["best_partial"] == "cross_coupling", v[0]
    assert all(x["effect"] == "unexplained" for x in v), [x.get("effect") for x in v]


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("upd,first", [(KC, "cross_coupling"), (B2, "bias_tempco2")])
def test_a_mean_effect_with_random_positioning_errors(upd, first, seed):
    """A mean effect plus the bench's random positioning errors (5 arcsec per axis, wobble 2 arcsec,
    normal): the mean effect first (``unexplained``, its best partial answer), then, with it in the
    model, ``position_error`` with the gap closed, which ends the chain (a noise term is fitted with,
    not diagnosed with). Seeds 1-3 measured 2026-11-29: 2 of 3 each; seed 3 stays ``unexplained``
    after the mean effect, never naming a wrong effect."""
    v = chain(_make(upd, seed, sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0))
    assert v[0]["effect"] == "unexplained" and v[0]["best_partial"] == first, v[0]
    assert v[1]["effect"] == "position_error" and v[1].get("gap_closed", True), v[1]


@pytest.mark.slow
def test_an_open_gap_names_the_significant_candidates_it_did_not_refit():
    """An outside probe: a 30 min element lag was 'unexplained' at --top 3 (the rate form's score
    ranked below thermal terms it correlates with, so it was never refitted) and named, gap closed,
    at --top 6. The verdict is kept; it now lists what was significant and not refitted and which
    --top refits it. Here two effects, --top 1: the second is listed, and the --top it names refits
    every candidate listed."""
    c = _campaign("cross_coupling+bias_tempco2", 1)
    v = diagnose(c, BASE, n_draws=100, seed=1, top=1).verdict
    assert v["effect"] == "unexplained" and not v.get("gap_closed"), v
    listed = {x["effect"]: x for x in v["not_refitted"]}
    assert "bias_tempco2" in listed and all(x["score_p"] < 0.01 for x in listed.values())
    top = max(x["score_rank"] for x in listed.values())
    assert f"run again with --top {top} to refit them" in v["reason"]
    again = diagnose(c, BASE, n_draws=100, seed=1, top=top)
    refitted = {x.effect for x in again.candidates if x.refit}
    assert set(listed) <= refitted, (set(listed) - refitted)
    assert not again.verdict.get("not_refitted")
