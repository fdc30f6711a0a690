"""Rank histograms of a simulation-based calibration (Talts et al. 2018), matplotlib Agg.

One panel per parameter: the histogram of the ranks of the true values among the
posterior draws (and, as a step line, among draws of the least-squares Gaussian), with
the band that 99 % of the bins of a uniform histogram fall in (binomial quantiles).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy import stats

from .plots import styled


@styled
def rank_histogram_figure(result, bins=None):
    """A matplotlib figure of every parameter's rank histogram (``result``: SBCResult)."""
    from .plots import _mpl

    plt = _mpl()
    bins = bins or result.default_bins()
    names = list(result.names)
    P = len(names)
    ncol = 6
    nrow = math.ceil(P / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(2.6 * ncol, 1.9 * nrow), sharex=True, squeeze=False)
    edges = np.linspace(0, result.n_ranks + 1, bins + 1)
    N = result.n_campaigns
    lo, hi = stats.binom.ppf([0.005, 0.995], N, 1.0 / bins)
    p_post = result.rank_pvalues("posterior", bins)
    p_ls = result.rank_pvalues("least_squares", bins)
    for k, ax in enumerate(axes.flat):
        if k >= P:
            ax.axis("off")
            continue
        r = result.ranks["posterior"][:, k]
        ax.axhspan(lo, hi, color="0.88", zorder=0)
        ax.axhline(N / bins, color="0.5", lw=0.8, zorder=1)
        ax.hist(r[np.isfinite(r)], bins=edges, color="#2471a3", alpha=0.85, zorder=2)
        rl = result.ranks["least_squares"][:, k]
        if np.any(np.isfinite(rl)):
            c, _ = np.histogram(rl[np.isfinite(rl)], bins=edges)
            ax.step(edges, np.r_[c, c[-1]], where="post", color="#c0392b", lw=1.0, zorder=3)
        ax.set_title(f"{names[k]}\np={p_post[k]:.2g} (LS {p_ls[k]:.2g})", fontsize=7)
        ax.tick_params(labelsize=6)
    fig.suptitle(f"SBC rank histograms: {N} campaigns, {result.n_ranks} draws each "
                 f"(bars: posterior, red: least squares; grey: 99% band of a uniform bin)", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    return fig


def plot_rank_histograms(result, path, bins=None) -> None:
    """Render the rank histograms to a PNG file."""
    from ..io.atomic import atomic_path

    fig = rank_histogram_figure(result, bins)
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
