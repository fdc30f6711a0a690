"""Plots of drifts with their uncertainty bands (matplotlib, Agg canvas, written as PNG).

The plot follows the paper's Table 3: one column per exposure, one series per parameter;
each drift is drawn with its expanded uncertainty ``k2 u(d)`` (the two-sided coverage
factor of the comparison's level, the band the significance test uses), the tolerance
as a shaded band, and the verdict as the marker (filled red: fail, hollow: inconclusive,
filled: pass). No estimation here: it draws :mod:`triadcal.judgement.compare` results.
"""

from __future__ import annotations

from ..errors import InputError

from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..judgement.compare import ComparisonResult, SequenceComparison, coverage_factors

_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink",
           "tab:gray", "tab:olive", "tab:cyan")


def plot_drifts(comparison: Union[ComparisonResult, SequenceComparison], path, *, which: str = "step",
                names: Optional[Sequence[str]] = None, title: Optional[str] = None, dpi: int = 120) -> Path:
    """Write a PNG of drifts with uncertainty bands; returns the path.

    A :class:`ComparisonResult` is drawn as one column per parameter; a
    :class:`SequenceComparison` as one column per exposure (``which``: ``"step"`` or
    ``"cumulative"``), one series per parameter (default: the judged ones).
    """
    comps = [comparison] if isinstance(comparison, ComparisonResult) else comparison.comparisons(which)
    if not comps:
        raise InputError("nothing to plot: the sequence has no comparisons of kind " + repr(which))
    if names is None:
        names = [n for n, p in comps[0].parameters.items() if p.judged]
    if not names:
        raise InputError("no parameters to plot")
    units = {comps[0].parameters[n].unit for n in names if n in comps[0].parameters}
    if len(units) > 1:
        raise InputError(f"parameters in different units {sorted(units)}: plot them separately (names=...)")
    unit = units.pop() if units else ""
    k2, _ = coverage_factors(comps[0].level)

    fig = Figure(figsize=(max(6.0, 1.3 * (len(comps) if len(comps) > 1 else len(names)) + 2), 4.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    if len(comps) == 1:
        c = comps[0]
        x = np.arange(len(names))
        for i, n in enumerate(names):
            _point(ax, x[i], c.parameters[n], k2, _COLORS[0])
        ax.set_xticks(x, names, rotation=30, ha="right")
        ax.set_xlabel("parameter")
        tolerances = [c.parameters[n].tolerance for n in names]
    else:
        x = np.arange(len(comps))
        offsets = (np.arange(len(names)) - (len(names) - 1) / 2) * (0.7 / max(len(names), 1))
        tolerances = []
        for j, n in enumerate(names):
            color = _COLORS[j % len(_COLORS)]
            pts = [(x[i] + offsets[j], c.parameters[n]) for i, c in enumerate(comps) if n in c.parameters]
            if not pts:
                continue
            ax.plot([p[0] for p in pts], [p[1].drift for p in pts], color=color, lw=0.8, alpha=0.5)
            for xi, p in pts:
                _point(ax, xi, p, k2, color)
                tolerances.append(p.tolerance)
            ax.plot([], [], "o", color=color, label=n)
        ax.set_xticks(x, [c.label or f"#{i + 1}" for i, c in enumerate(comps)], rotation=20, ha="right")
        ax.set_xlabel("exposure" if which == "step" else "exposure (against the first state)")
    tol = [t for t in tolerances if t is not None]
    if tol and len(set(tol)) == 1:
        T = tol[0]
        ax.axhspan(-T, T, color="tab:green", alpha=0.08, lw=0)
        for s in (-T, T):
            ax.axhline(s, color="tab:green", lw=0.8, ls="--")
        ax.plot([], [], color="tab:green", ls="--", label=f"tolerance +-{T:g} {unit}")
    ax.axhline(0.0, color="black", lw=0.6)
    ax.plot([], [], "o", mfc="tab:red", mec="tab:red", label="fail")
    ax.plot([], [], "o", mfc="none", mec="black", label="inconclusive")
    ax.legend(fontsize=7, ncol=2, loc="best")
    ax.set_ylabel(f"drift, {unit}   (bars: +-{k2:.2f} u, {100 * comps[0].level:g}%)")
    ax.grid(alpha=0.3)
    ax.set_title(title or ("drift and uncertainty" if len(comps) == 1 else
                           f"drifts {'step by step' if which == 'step' else 'from the first state'}"),
                 fontsize=10)
    fig.tight_layout()
    path = Path(path)
    from ..io.atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    return path


def _point(ax, x, p, k2, color):
    face = {"fail": "tab:red", "inconclusive": "none", "pass": color}[p.verdict]
    edge = "tab:red" if p.verdict == "fail" else color
    ax.errorbar([x], [p.drift], yerr=[k2 * p.u], fmt="none", ecolor=color, elinewidth=1.2, capsize=3)
    ax.plot([x], [p.drift], "o", mfc=face, mec=edge, ms=6, mew=1.5)
