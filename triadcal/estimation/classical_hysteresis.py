"""What a thermal hysteresis of the angles does to the classical method's thermal lines (docs/classical.md,
step 5): the lines' slopes move by a computable amount per arcsec of hysteresis when the setpoints'
branches lie along the temperatures, and the lines' scatter shows only part of it."""

from __future__ import annotations

from typing import Optional

import numpy as np

from ..models.units import ARCSEC

#: a hysteresis of the angles this large (arcsec, the low end of the seed paper's Table 1: 4-60) that moves
#: an angle's tempco by more than 1 u is said (:func:`hysteresis_tempco_move`) when the branches lie along
#: the temperatures: less than HYSTERESIS_VISIBLE_MAX of their weighted norm off the line (every setpoint
#: on both branches, 20 50 80 50 20 -10 -40 -10 20: 0.91, the scatter shows it and the Birge ratio widens
#: u, coverage 0.99 in the probe; 20 60 80 20 -20 -40 20: 0.60; 20 80 -40 20: 0.50)
HYSTERESIS_LOW_ARCSEC = 4.0
HYSTERESIS_VISIBLE_MAX = 0.8


def hysteresis_tempco_move(T: np.ndarray, var: np.ndarray, branch: np.ndarray, T_ref: float, u_slope: float) -> dict:
    """What a thermal hysteresis of an angle (``h b``, ``b`` the setpoint block's branch: +1 cooling, -1
    heating, 0 none) does to its thermal line: the line's slope moves by ``m`` per arcsec of h (weighted
    least squares of ``b`` on ``[1, T - T_ref]``, the line in rad), ``move_u_per_arcsec`` = m / ``u_slope``
    (the line's slope's u, Birge-scaled), and
    ``visible_fraction`` the weighted norm of ``b`` off the line over its norm (what the lines' scatter
    can show). On a round trip whose hot setpoints are reached by heating and cold ones by cooling, b is
    nearly a line in T: an outside probe's h = 3 arcsec moved the tempcos by -2.9 u on average (coverage
    0.09), status ok, the one-branch note absent (both branches were visited)."""
    X = np.column_stack([np.ones_like(T), T - T_ref])
    w = 1.0 / var if np.all(var > 0) else np.ones_like(T)
    A = X.T @ (w[:, None] * X)
    m = np.linalg.solve(A, X.T @ (w * branch)) * ARCSEC         # per arcsec of h (the line in rad)
    left = branch * ARCSEC - X @ m
    nb = float(np.sqrt(np.sum(w * branch * branch))) * ARCSEC
    return {"move_u_per_arcsec": float(m[1]) / u_slope if u_slope > 0 else None,
            "visible_fraction": float(np.sqrt(np.sum(w * left * left))) / nb if nb > 0 else None}


def hysteresis_tempco_note(hyst_moves: dict) -> Optional[str]:
    """The note of :func:`hysteresis_tempco_move`'s results (angle name -> dict) when :data:`HYSTERESIS_LOW_ARCSEC`
    moves a tempco by more than 1 u with less than :data:`HYSTERESIS_VISIBLE_MAX` visible, or None."""
    moved = {n: v for n, v in hyst_moves.items()
             if v["move_u_per_arcsec"] is not None and abs(v["move_u_per_arcsec"]) * HYSTERESIS_LOW_ARCSEC > 1.0
             and v["visible_fraction"] is not None and v["visible_fraction"] < HYSTERESIS_VISIBLE_MAX}
    if moved:
        worst = max(moved, key=lambda n: abs(moved[n]["move_u_per_arcsec"]))
        return (
            "the setpoints' branches lie along the temperatures (the hot ones reached by heating, the cold ones by "
            "cooling, or the like), so a thermal hysteresis of the angles tilts their lines: 1 arcsec of it moves "
            + ", ".join(f"{n}_tempco by {abs(v['move_u_per_arcsec']):.2g} u" for n, v in moved.items())
            + f" (the lines' scatter shows {100 * min(v['visible_fraction'] for v in moved.values()):.2g} % of it at "
            f"most, {worst} worst); units of this kind have 4-60 arcsec (the seed paper's Table 1). The tempcos "
            "hold for a unit without hysteresis; --method joint estimates h, and a plan that visits each "
            "temperature on both branches separates the two")
    return None
