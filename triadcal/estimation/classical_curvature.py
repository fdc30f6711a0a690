"""What a curvature of a tempco does to the classical method's thermal lines (docs/classical.md, step 5):
the paper's correction is a straight line in temperature, and a quadratic term the lines' scatter cannot
show moves the value at the reference temperature and the tempco by a computable amount."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

#: a curvature within this many of its SDs (what the lines' scatter measures) is not seen
UNSEEN_SD = 2.0
#: ... and the note is given when it would move a value or a tempco by more than this many u
UNSEEN_MOVE_U = 1.0


def curvature_move(T: np.ndarray, var: np.ndarray, T_ref: float, cov: np.ndarray, birge: float) -> Optional[dict]:
    """A quadratic term ``c2 (T - T_ref)^2`` left out of a weighted line ``a + b (T - T_ref)``: the line
    takes up ``m = (X'WX)^-1 X'W (T - T_ref)^2`` per unit of c2 (``m[0]`` into the value at T_ref,
    ``m[1]`` into the slope); the rest, ``d = (T - T_ref)^2 - X m``, is what the scatter can show,
    which measures c2 with SD ``sqrt(birge / d'Wd)``. Returns ``unseen_value_u`` and
    ``unseen_tempco_u``: the moves of a curvature :data:`UNSEEN_SD` SDs in size, in the value's and the
    slope's u (``cov``, the line's Birge-scaled covariance), or None with fewer than three temperatures.

    An outside probe (its own simulator, 20 60 80 20 -20 -40 20 degC): curvatures of 0.0007
    arcsec/degC2, 0.005 ppm/degC2, 0.01 ug/degC2 moved the values at 20 degC by about 2.2 u (coverage
    0.47-0.63, 26 of 27 values beyond 3 u unnamed), status ok."""
    T = np.asarray(T, float)
    if len(np.unique(np.round(T, 6))) < 3 or cov.shape[0] < 2:
        return None
    X = np.column_stack([np.ones_like(T), T - T_ref])
    c = (T - T_ref) ** 2
    w = 1.0 / var if np.all(var > 0) else np.ones_like(T)
    m = np.linalg.solve(X.T @ (w[:, None] * X), X.T @ (w * c))
    d = c - X @ m
    seen = float(np.sum(w * d * d))
    if not seen > 0:
        return None
    sd = math.sqrt(max(birge, 1e-300) / seen)
    u_value, u_slope = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
    return {"value_move_per_c2": float(m[0]), "tempco_move_per_c2": float(m[1]), "c2_sd": sd,
            "unseen_value_u": UNSEEN_SD * sd * abs(float(m[0])) / u_value if u_value > 0 else None,
            "unseen_tempco_u": UNSEEN_SD * sd * abs(float(m[1])) / u_slope if u_slope > 0 else None}


def curvature_note(moves: dict, T_ref: float) -> Optional[str]:
    """The note of :func:`curvature_move`'s results (quantity -> dict) when a curvature within
    :data:`UNSEEN_SD` SDs moves a value or a tempco by more than :data:`UNSEEN_MOVE_U` u, or None."""
    big = {n: v for n, v in moves.items() if max(v["unseen_value_u"] or 0.0, v["unseen_tempco_u"] or 0.0) > UNSEEN_MOVE_U}
    if not big:
        return None
    top = sorted(big, key=lambda n: -(big[n]["unseen_value_u"] or 0.0))[:3]
    return ("the thermal lines are straight by the method: a curvature of a tempco too small for the lines' scatter "
            f"to show ({UNSEEN_SD:g} SD) would move the values at {T_ref:g} degC by up to "
            + ", ".join(f"{n} {big[n]['unseen_value_u']:.2g} u" for n in top)
            + (f" ({len(big) - len(top)} more in fit.curvature_sensitivity)" if len(big) > len(top) else "")
            + " and the tempcos by up to "
            + f"{max(v['unseen_tempco_u'] or 0.0 for v in big.values()):.2g} u; the values hold for linear tempcos. "
            "`triadcal fit --method joint --thermal-order auto` fits and tests the quadratic terms")
