"""What a ``none`` verdict could not have seen: the smallest effects this campaign would have shown.

A diagnosis that finds no significant gap says ``none``; on its own that reads as "the model is
complete", while it only says that nothing *large enough for this design and this noise* is
missing. So a ``none`` verdict carries ``detection_limits``: for each mean candidate the design can
test, the size of each of its parameters (the others at zero) at which the candidate's own score
test would reject with probability ``POWER`` at Holm's first level ``alpha / m`` (``m`` the gap's
tests): an effect at least that large would have made the gap significant that often by this one
test alone, whatever the other tests did, so the limit is conservative (the other tests only add
power).

For the linearised model the score statistic of a candidate with columns ``J_c`` (normalised by the
noise, as the residuals) is ``chi^2_k(lambda)`` with ``k`` its rank and the noncentrality
``lambda = |(I - Q Q^T) J_c theta|^2`` (``Q`` an orthonormal basis of the fitted model's columns:
what the base fit absorbs is not seen); with one parameter ``theta_j`` nonzero ``lambda = theta_j^2
|M_j|^2``, ``M = (I - Q Q^T) J_c``, so the limit is ``sqrt(lambda* / |M_j|^2)`` with ``lambda*`` the
noncentrality at which ``P(chi^2_k(lambda*) > chi^2_k^{-1}(1 - alpha / m)) = POWER`` (Cox & Hinkley
1974, ch. 9: the local power of the score test). With the noise estimated the test is an F test
with the base fit's dof in the denominator; the chi^2 form is its limit (the campaigns have hundreds
of dof) and the noise scale is the estimated one. The parameters are in their reporting units (the
Jacobian's columns are). Checked by simulation in tests/test_detection_limits.py.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np
from scipy import optimize, stats

from ...models.effects import NOISE_EFFECTS

#: the probability with which an effect at the limit is detected by its own score test
POWER = 0.95


def power_chi2(lam: float, k: int, level: float) -> float:
    """``P(chi2_k(lam) > chi2_k^{-1}(1 - level))``: the power of a chi2(k) test at ``level``."""
    crit = stats.chi2.isf(level, k)
    return float(stats.ncx2.sf(crit, k, max(lam, 1e-12)))


def lambda_needed(k: int, level: float, power: float = POWER) -> float:
    """The noncentrality at which a chi2(k) test at ``level`` has ``power``."""
    return lambda_beyond(k, float(stats.chi2.isf(level, k)), power)


def lambda_beyond(k: int, critical: float, power: float = POWER) -> float:
    """The noncentrality at which ``chi2_k(lambda)`` exceeds ``critical`` with probability ``power``
    (a test whose critical value is not a chi2 quantile alone: the raw diagnosis's gap needs p < alpha
    and chi2/dof above a ratio)."""
    def exceed(lam):
        return float(stats.ncx2.sf(critical, k, max(lam, 1e-12)))

    hi = 1.0
    while exceed(hi) < power:
        hi *= 2.0
    return float(optimize.brentq(lambda lam: exceed(lam) - power, 0.0, hi, xtol=1e-10))


def detection_limits(cand_objs: Sequence, Jfull: np.ndarray, index: dict, Q: np.ndarray, level: float,
                     unit_of: Callable[[str], str], power: float = POWER) -> list:
    """One entry per testable mean candidate with parameters: ``effect``, ``k`` (its score test's dof),
    ``parameters`` (name -> ``{"value", "unit"}``: the limit in reporting units, None where the design
    does not see the parameter apart from the model). ``Jfull``: the full Jacobian normalised as the
    residuals; ``index``: parameter name -> column; ``level``: Holm's first level ``alpha / m``."""
    out = []
    for c in cand_objs:
        if not c.testable or c.refit_only or not c.params or c.effect in NOISE_EFFECTS or c.k < 1:
            continue
        # a score profiled over a grid of time constants is tested at level / grid size (Bonferroni);
        # ``value`` is the limit at the start value's columns (Jfull's: a warm-up of 5 min), and
        # ``time_constant`` holds the limits at each time constant of the grid
        profile = getattr(c, "score_profile", None) or {}
        lam = lambda_needed(int(c.k), level / profile.get("grid_size", 1), power)
        limits = _limits(Jfull[:, [index[n] for n in c.params]], Q, lam)
        entry = {"effect": c.effect, "k": int(c.k),
                 "parameters": {n: {"value": v, "unit": unit_of(n)} for n, v in zip(c.params, limits)}}
        by_tau = getattr(c, "columns_by_tau", None)
        if by_tau:
            per_tau = [_limits(J, Q, lam) for _, J in by_tau]
            offsets = [n for n in c.params if n != profile.get("parameter")]     # the columns' order
            entry["time_constant"] = {
                "parameter": profile.get("parameter"), "unit": profile.get("unit", "min"),
                "grid": [float(t) for t, _ in by_tau],
                "limits": {n: [lim[j] for lim in per_tau] for j, n in enumerate(offsets)}}
        out.append(entry)
    return out


def _limits(Jc: np.ndarray, Q: np.ndarray, lam: float) -> list:
    """Each column's limit ``sqrt(lam / |M_j|^2)``, ``M = (I - Q Q^T) J_c``; None for a column with
    (almost) nothing outside the model's span (no finite limit)."""
    M = Jc - Q @ (Q.T @ Jc)
    m2 = np.sum(M * M, axis=0)
    scale = float(np.max(np.sum(Jc * Jc, axis=0), initial=0.0))
    return [float(math.sqrt(lam / v)) if v > 1e-12 * max(scale, 1e-300) else None for v in m2]


def limit_ranges(limits: Sequence[dict]) -> list:
    """``["scale_cubic 5.1-7.9 ug/g3", ...]``: each candidate's range of limits over its parameters
    (candidates without a finite limit left out)."""
    parts = []
    for e in limits:
        vals = [p["value"] for p in e["parameters"].values() if p["value"] is not None]
        tc = e.get("time_constant")
        if tc:       # over the grid of time constants too: "(tau 5-300 min)"
            vals += [v for vs in tc["limits"].values() for v in vs if v is not None]
        units = {p["unit"] for p in e["parameters"].values()}
        if not vals:
            continue
        lo, hi = min(vals), max(vals)
        rng = f"{lo:.2g}" if math.isclose(lo, hi, rel_tol=0.05) else f"{lo:.2g}-{hi:.2g}"
        over = f" (tau {min(tc['grid']):.2g}-{max(tc['grid']):.3g} {tc['unit']})" if tc else ""
        parts.append(f"{e['effect']} {rng} {'/'.join(sorted(units))}{over}")
    return parts


def limits_text(limits: Sequence[dict], level: float, power: float = POWER, most: int = 8) -> str:
    """``"... : scale_cubic 5.1-7.9 ug/g3, ..."``: :func:`limit_ranges` in a sentence."""
    parts = limit_ranges(limits)
    more = f", and {len(parts) - most} more (verdict.detection_limits)" if len(parts) > most else ""
    return (f"an effect this size or larger would have been found with probability {power:g} by its own "
            f"score test at Holm's first level {level:.2g}: " + ", ".join(parts[:most]) + more)
