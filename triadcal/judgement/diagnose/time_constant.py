"""The score test of a candidate with a time constant (the warm-ups after power-on), profiled over it.

A warm-up ``db exp(-t/tau)`` (models/effects/warmup.py) is linear in its offsets ``db`` only once
``tau`` is given; at ``db = 0`` the data say nothing of ``tau`` (Davies 1977, 1987: a nuisance
parameter present only under the alternative). Scored at its start value alone (5 min), a warm-up
on a stepped campaign is over before the first visit that follows a 30 min soak, and one of
90 min, plain in the data (chi2/dof 18), scored below the drift and was never refitted: the
verdict was ``unexplained`` (docs/diagnosis.md, "A time constant profiled").

So the offsets' columns are scored at each time constant of a geometric grid (ratio
:data:`RATIO`, from the start value up to the answer gate's longest warm-up, 300 min, or
:data:`SPAN_FACTOR` times the campaign's elapsed span if that is shorter), the largest score kept,
and its p-value multiplied by the grid's size (Bonferroni: the level holds whatever the
correlation of the grid's scores; adjacent exponentials of ratio 2 have columns correlated
2 sqrt(2) / 3 = 0.94 over a half-line, so the grid loses little against the continuous maximum;
measured on the linear null, tests/test_warmup_profile.py). The refit starts from the best time
constant of the grid.

A refit the fit's answer gates would refuse is not a warm-up (``fit --effects bias_warmup`` would
say ``unphysical_term``) and is not named (:func:`range_refusal`): a time constant outside the
``time_constants`` gate's [0.5, 300] min (a warm-up of 10 h on a 13 h campaign is a drift, its
limit ``verdict.NESTED_LIMIT``, or a wander, not a power-on transient), or an offset at power-on
beyond the ``warmup_offsets`` gate's 50 mg / 1 % (a warm-up of 10 min fitted to an offset of the
first visits two hours after power-on: -34 g).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ...estimation.gates import TIME_CONSTANT_RANGE_MIN, _gate_time_constants, _gate_warmup_offsets
from .candidates import SPAN_FRACTION_MIN, _score_mean
from .fitting import _chi2_logsf

#: the candidates whose columns depend on a time constant, and its parameter
TIME_CONSTANT_OF = {"bias_warmup": "S_warmup_tau", "scale_warmup": "K_warmup_tau"}
#: ratio of the grid's neighbouring time constants
RATIO = 2.0
#: the grid reaches this many times the campaign's elapsed span, unless the gate's 300 min is shorter
#: (a warm-up that long is a drift over the campaign: the nested-laws rule names the drift)
SPAN_FACTOR = 2.0


def tau_grid(start_min: float, elapsed_s: np.ndarray) -> list:
    """The time constants scored (min): ``start * RATIO**k`` (start at least the gate's 0.5 min)
    below the top, then the top: the gate's longest time constant or ``SPAN_FACTOR`` times the
    largest elapsed time, the shorter (the start value alone when the top is not above it)."""
    start = max(abs(float(start_min)), TIME_CONSTANT_RANGE_MIN[0])     # a zero start would never double
    top = min(TIME_CONSTANT_RANGE_MIN[1], SPAN_FACTOR * float(np.max(elapsed_s, initial=0.0)) / 60.0)
    grid = [start]
    while grid[-1] * RATIO < top:
        grid.append(grid[-1] * RATIO)
    if top > grid[-1]:
        grid.append(top)
    return grid


def range_refusal(c):
    """The answer gates' refusal (``estimation.gates``: ``time_constants``, ``warmup_offsets``) of
    candidate ``c``'s refitted warm-up, in words, or None (no time constant, not refitted, or passed)."""
    if c.effect not in TIME_CONSTANT_OF:
        return None
    params = (c.refit or {}).get("new_parameters") or {}
    bad = [g.reason for g in (_gate_time_constants(params), _gate_warmup_offsets(params)) if g.passed is False]
    return "; ".join(bad) or None


def profiled_score(full, campaign, base, Q, params, tau_name: str, noise_known: bool, J_start=None,
                   columns_out: list | None = None):
    """``(S, k, logp, profile)`` of the offsets ``params`` (their tau excluded) scored at each time
    constant of :func:`tau_grid`, or None when no time constant gives a testable column. ``logp``
    is the largest score's log p-value plus log(grid size), at most 0; ``profile`` holds the grid,
    the score at each point (None: not testable there), the best time constant and the grid size.
    ``J_start``: the whitened Jacobian at ``base.x_full`` if the caller holds it (reused where the
    grid's time constant is the start value, not recomputed). ``columns_out``: a list to which each
    grid point's ``(tau, whitened offset columns)`` is appended (the detection limits per time
    constant, detection.py)."""
    offsets = [n for n in params if n != tau_name]
    if not offsets:
        return None
    grid = tau_grid(base.x_full[full.index[tau_name]], campaign.elapsed_s())
    cols = [full.index[n] for n in offsets]
    scores = []
    tau_start = base.x_full[full.index[tau_name]]
    for tau in grid:
        if J_start is not None and tau == tau_start:
            Jw = J_start
        else:
            x = base.x_full.copy()
            x[full.index[tau_name]] = tau
            Jw = full.residuals_and_jacobian(x)[1] / base.s
        scores.append(_score_mean(base, Jw[:, cols], Q, SPAN_FRACTION_MIN))
        if columns_out is not None:
            columns_out.append((float(tau), Jw[:, cols]))
    done = [(sc[0], sc[1], tau) for sc, tau in zip(scores, grid) if sc is not None]
    if not done:
        return None

    def logsf(S, k):
        if noise_known:
            return _chi2_logsf(S, k)
        return float(stats.f.logsf(S / k, k, max(base.dof - k, 1)))

    S, k, tau_best = min(done, key=lambda z: logsf(z[0], z[1]))
    logp = min(0.0, logsf(S, k) + math.log(len(grid)))
    profile = {"parameter": tau_name, "unit": "min", "grid": [float(t) for t in grid],
               "scores": [None if sc is None else float(sc[0]) for sc in scores],
               "best": float(tau_best), "grid_size": len(grid)}
    return S, k, logp, profile
