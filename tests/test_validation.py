"""Simulation-based calibration: the machinery (quick) and the proof on 200 campaigns (slow)."""

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from triadcal.judgement.validation import LEVELS, METHODS, SBCResult, sbc
from triadcal.models.model import Model
from triadcal.reports.sbc import plot_rank_histograms


def _synthetic(ranks, n_ranks=99):
    N, P = ranks.shape
    names = tuple(f"p{k}" for k in range(P))
    cov = {m: {lv: np.ones((N, P)) for lv in LEVELS} for m in METHODS}
    return SBCResult(names=names, n_ranks=n_ranks, truths=np.zeros((N, P)),
                     ranks={m: ranks.astype(float) for m in METHODS}, covered=cov,
                     statuses=["ok"] * N, seconds=0.0)


def test_rank_statistics_detect_a_miscalibrated_posterior():
    rng = np.random.default_rng(0)
    uniform = rng.integers(0, 100, size=(400, 3))
    # over-confident posterior: truths fall in the tails of the draws -> U-shaped ranks
    u = rng.beta(0.5, 0.5, size=(400, 1))
    ushaped = np.floor(u * 100).clip(0, 99)
    r = _synthetic(np.hstack([uniform, ushaped]))
    p = r.rank_pvalues("posterior", bins=20)
    assert np.all(p[:3] > 0.001) and p[3] < 1e-6
    s = r.summary()
    assert s["methods"]["posterior"]["rank_uniform_bonferroni"] is False


@pytest.mark.slow          # 5-10 s: slow since the thirteenth session (the quick suite's 10 min)
def test_small_sbc_runs_and_plots(tmp_path):
    result = sbc(4, n_ranks=19, seed=3, processes=1, ess=300)
    P = len(Model().names)
    assert result.statuses == ["ok"] * 4
    for m in METHODS:
        r = result.ranks[m]
        assert r.shape == (4, P) and np.all((r >= 0) & (r <= 19))
        for lv in LEVELS:
            assert set(np.unique(result.covered[m][lv])) <= {0.0, 1.0}
    # the truths were drawn from the prior: K near 1 g/V, angles of the prior's size
    assert np.all(np.abs(result.truths[:, 0] - 1) < 0.6)
    path = tmp_path / "ranks.png"
    plot_rank_histograms(result, path)
    import matplotlib.image as mpimg

    img = mpimg.imread(path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and img.shape[0] > 500 and img.shape[1] > 1000
    assert img[..., :3].std() > 0.05                  # really drawn, not blank


@pytest.mark.slow   # 3 campaigns sampled through the CLI (~30 s in CI); the SBC machinery is quick above
def test_cli_validate_small(tmp_path):
    p = subprocess.run([sys.executable, "-m", "triadcal", "validate", "--campaigns", "3", "--ranks", "9",
                        "--processes", "1", "--ess", "300", "--json", "s.json", "--plot", "s.png", "--no-progress"],
                       cwd=tmp_path, capture_output=True, text=True)
    assert p.returncode in (0, 3), p.stderr
    assert "SBC: 3 campaigns" in p.stdout
    d = json.loads((tmp_path / "s.json").read_text())
    assert d["format"] == "triadcal.sbc" and d["n_campaigns"] == 3 and d["failed"] == 0
    assert set(d["methods"]) == set(METHODS)
    assert (tmp_path / "s.png").stat().st_size > 20_000


@pytest.mark.slow
def test_sbc_200_campaigns_ranks_uniform_and_intervals_cover():
    """SBC (Talts et al. 2018) on 200 campaigns drawn from the prior, default effects.

    Tolerances from theory: 32 parameters are 32 tests, so the family-wise checks use
    Bonferroni (alpha = 0.01 / 32); the pooled 95 % coverage (6400 indicators, correlated
    within a campaign, so its SD is between 0.27 % and 1.5 %) must lie in 0.95 +- 0.03; the
    per-parameter coverages (binomial SD 1.5 % with 200 campaigns, so +-0.03 is 2 SD and
    ~1.6 of 32 parameters fall outside it by chance) are tested with a binomial test.
    """
    result = sbc(200, n_ranks=99, seed=2024, processes=2)
    s = result.summary(alpha=0.01)
    P = len(result.names)
    assert s["failed"] == 0, [st for st in result.statuses if st != "ok"]
    for m in METHODS:
        d = s["methods"][m]
        assert d["rank_min_p"] > 0.01 / P, (m, d["rank_chi2_p"])
        assert abs(d["coverage_95_pooled"] - 0.95) < 0.03, m
        assert abs(d["coverage_68_pooled"] - 0.68) < 0.03, m
        assert d["coverage_95_binomial_min_p"] > 0.01 / P, (m, d["coverage_95"])
        assert d["coverage_68_binomial_min_p"] > 0.01 / P, (m, d["coverage_68"])
        # how many parameters leave 0.95 +- 0.03 by chance: Binomial(32, p_out), p_out ~ 0.05
        p_out = stats.binom.cdf(183, 200, 0.95) + stats.binom.sf(196, 200, 0.95)
        assert d["coverage_95_n_outside_0.03"] <= stats.binom.ppf(0.99, P, p_out), m
