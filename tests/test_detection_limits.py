"""A ``none`` verdict's detection limits (judgement/diagnose/detection.py) against simulation.

The claim: an effect whose parameter is at its limit (the others at zero) makes the candidate's own
score test reject at Holm's first level with probability ``POWER`` (0.95); at half the limit with
``power_chi2(lambda* / 4)``. The campaigns are made by ``tests/independent_bench.py`` (its own
cross-coupling products, not the model's term): 24 poses, five setpoints. The limit is computed once
on a clean campaign (seed 0); the 40 campaigns at the limit and 40 at half of it have their own
units (``default_truth`` draws K, biases and angles per seed), so the test also says that the limit
does not hinge on the unit it was computed on. Bands: binomial, 3 SD (no tuning).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from independent_bench import OBLIQUE_POSITIONS, default_truth, simulate_campaign  # noqa: E402

from triadcal.io.bench_csv import parse_bench_csv  # noqa: E402
from triadcal.judgement.diagnose import diagnose  # noqa: E402
from triadcal.judgement.diagnose.detection import (POWER, lambda_needed, limits_text,  # noqa: E402
                                                   power_chi2)

BASE = ["angle_tempco", "scale_tempco", "bias_tempco"]
CANDS = ["cross_coupling", "scale_cubic", "bias_tempco2"]
SETPOINTS = (-40, -10, 20, 50, 80)


def _campaign(seed: int, kc_xy: float = 0.0):
    rng = np.random.default_rng(seed)
    truth = default_truth(rng)
    if kc_xy:
        truth["Kc_xy"] = kc_xy
    text, _ = simulate_campaign(rng, truth=truth, positions=OBLIQUE_POSITIONS, setpoints_C=SETPOINTS)
    return parse_bench_csv(text)


def _diagnose(c):
    return diagnose(c, BASE, candidates=CANDS, n_draws=20, top=1, slices_after=False, cross_group=False, seed=1)


def test_lambda_needed_by_hand():
    """k = 1 at level 0.05: the power of the two-sided z test, Phi(sqrt(lam) - 1.96) +
    Phi(-sqrt(lam) - 1.96) = 0.95 at sqrt(lam) = 1.96 + 1.645 = 3.605 (to 1e-4: the other tail is
    1e-12); power_chi2 at that lambda is 0.95; more dof need more."""
    lam = lambda_needed(1, 0.05)
    assert math.sqrt(lam) == pytest.approx(1.959964 + 1.644854, abs=1e-4)
    assert power_chi2(lam, 1, 0.05) == pytest.approx(0.95, abs=1e-9)
    assert lambda_needed(3, 0.05) > lam and lambda_needed(1, 0.001) > lam


def test_a_none_verdict_carries_its_limits(tmp_path):
    from triadcal.reports.diagnosis import summary_text, write_html_report

    c = _campaign(0)
    d = _diagnose(c)
    v = d.verdict
    assert v["effect"] is None
    lim = v["detection_limits"]
    assert lim["power"] == POWER and 0 < lim["level"] < d.alpha
    kc = next(e for e in lim["candidates"] if e["effect"] == "cross_coupling")
    assert set(kc["parameters"]) == {"Kc_xy", "Kc_xz", "Kc_yx", "Kc_yz", "Kc_zx", "Kc_zy"}
    assert all(p["unit"] == "ug/g2" and 1.0 < p["value"] < 100.0 for p in kc["parameters"].values())
    assert "would have been found with probability 0.95" in v["reason"]
    assert lim["not_testable"] == []            # every candidate is testable on 24 poses
    assert limits_text(lim["candidates"], lim["level"]).count("ug/g2") == 1
    assert "cross_coupling" in summary_text(d).split("verdict:", 1)[1]
    write_html_report(d, tmp_path / "d.html", c)
    page = (tmp_path / "d.html").read_text()
    assert "What this campaign could not have seen" in page and "<td>Kc_xy</td>" in page


@pytest.mark.slow
def test_the_limit_is_the_power_of_the_own_score_test():
    d0 = _diagnose(_campaign(0))
    lim = d0.verdict["detection_limits"]
    kc = next(e for e in lim["candidates"] if e["effect"] == "cross_coupling")
    limit, level, k = kc["parameters"]["Kc_xy"]["value"], lim["level"], kc["k"]
    n = 40
    for factor, expect in ((1.0, POWER), (0.5, power_chi2(lambda_needed(k, level) / 4, k, level))):
        hits = 0
        for s in range(n):
            d = _diagnose(_campaign(100 + s, factor * limit))
            own = next(c for c in d.candidates if c.effect == "cross_coupling")
            assert len(d.gap["tests"]) == round(d0.alpha / level)        # the same Holm family
            hits += own.score_p < level
        sd = math.sqrt(expect * (1 - expect) / n)
        assert abs(hits / n - expect) <= 3 * sd + 1.0 / n, (factor, hits, expect)


def test_a_none_verdict_on_six_faces_names_what_it_cannot_test():
    """On the 12 positions (every pose with one axis along gravity) K3 and the cross-coupling are
    invisible (a^3 = a, every product a_a a_b zero): a none verdict lists them as not testable and
    says nothing of their size."""
    rng = np.random.default_rng(5)
    text, _ = simulate_campaign(rng, setpoints_C=SETPOINTS)
    v = _diagnose(parse_bench_csv(text)).verdict
    assert v["effect"] is None
    lim = v["detection_limits"]
    assert {"cross_coupling", "scale_cubic"} <= set(lim["not_testable"])
    assert not {"cross_coupling", "scale_cubic"} & {e["effect"] for e in lim["candidates"]}
    assert "not testable on this design" in v["reason"]
