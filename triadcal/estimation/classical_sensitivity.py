"""What the classical method's straight thermal lines take up of a term they leave out (docs/classical.md,
step 5): a thermal hysteresis of the angles (when the setpoints' branches lie along the temperatures)
and a curvature of a tempco. Each is a vector over the setpoint blocks; the weighted line takes up
its part in the line's span, which moves the value at T_ref and the slope by a computable amount, and
only the rest shows in the lines' scatter."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from ..models.units import ARCSEC


def _take_up(T: np.ndarray, var: np.ndarray, T_ref: float, v: np.ndarray) -> tuple:
    """``(m, left, w)``: the weighted line ``[1, T - T_ref]``'s take-up of ``v`` (``m[0]`` into the value,
    ``m[1]`` into the slope), the rest ``v - X m``, and the weights (``1/var``, or ones when no variance
    is known, as :func:`~triadcal.estimation.classical.thermal_line` weighs)."""
    T = np.asarray(T, float)
    X = np.column_stack([np.ones_like(T), T - T_ref])
    w = 1.0 / var if np.all(var > 0) else np.ones_like(T)
    m = np.linalg.solve(X.T @ (w[:, None] * X), X.T @ (w * v))
    return m, v - X @ m, w


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
    m, left, w = _take_up(T, var, T_ref, np.asarray(branch, float) * ARCSEC)   # per arcsec of h (rad)
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
    m, d, w = _take_up(T, var, T_ref, (T - T_ref) ** 2)
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


def curvature_test(T: np.ndarray, y: np.ndarray, var: np.ndarray, T_ref: float) -> Optional[dict]:
    """Lack-of-fit test of a weighted thermal line against the line plus ``c2 (T - T_ref)^2`` (the
    nested model's t test, e.g. Draper & Smith, *Applied Regression Analysis*, 3rd ed., sec. 6.1):
    ``c2 = d'W r / d'W d`` (``r`` the line's residuals, ``d`` the part of ``(T - T_ref)^2`` the line
    cannot take up, :func:`_take_up`), its variance ``s^2 / d'W d`` with ``s^2`` the scatter about
    the quadratic, ``(chi2_line - c2^2 d'W d) / (n - 3)``, floored at 1 when the variances are known
    (the Birge convention of :func:`~triadcal.estimation.classical.thermal_line`); ``t = c2 / sd`` on
    ``n - 3`` dof. A scatter without shape (a unit that changed, a hysteresis across the branches)
    widens ``s`` with ``c2``; a law of temperature that is not a line leaves ``s`` small and ``t`` large.
    Returns ``{"c2", "c2_sd", "t", "dof", "p", "value"}`` (``c2`` in y's unit per degC^2, ``value``
    the line's at ``T_ref``), or None with fewer
    than four temperatures."""
    from scipy import stats

    T, y = np.asarray(T, float), np.asarray(y, float)
    if len(np.unique(np.round(T, 6))) < 4:
        return None
    known = bool(np.all(np.asarray(var) > 0))
    _, d, w = _take_up(T, var, T_ref, (T - T_ref) ** 2)
    line, r, _ = _take_up(T, var, T_ref, y)
    dd = float(np.sum(w * d * d))
    if not dd > 0:
        return None
    c2 = float(np.sum(w * d * r)) / dd
    value = float(line[0])
    dof = len(T) - 3
    s2 = max(0.0, float(np.sum(w * r * r)) - c2 * c2 * dd) / dof
    if known:
        s2 = max(1.0, s2)
    if not s2 > 0:
        return {"c2": c2, "c2_sd": 0.0, "t": math.inf if c2 else 0.0, "dof": dof, "p": 0.0 if c2 else 1.0,
                "value": value}
    sd = math.sqrt(s2 / dd)
    t = c2 / sd
    return {"c2": c2, "c2_sd": sd, "t": float(t), "dof": dof, "p": float(2.0 * stats.t.sf(abs(t), dof)),
            "value": value}


def curvature_gate(tests: dict, p_family: float):
    """The gate ``thermal_curvature`` from :func:`curvature_test` per quantity: fails when the
    smallest p is below ``p_family`` / (number of quantities tested) (Bonferroni: the family of lines
    wrongly refused with probability ``p_family`` when every tempco is linear). An outside probe's unit
    with K2 0.1-0.2 ppm/degC^2 and S2 0.05-0.08 ug/degC^2 over -40..70 degC: the lines' chi2/dof up to
    3340, widened by the Birge ratio (x58), status ok; the values at 20 degC were 1.2-1.3 U from the
    truth (a line's value is biased by a curvature, which widening does not correct) and its
    compensation table 4 u off. None when no quantity could be tested."""
    from .gates import GateOutcome

    tests = {n: v for n, v in tests.items() if v is not None}
    if not tests:
        return None
    worst = min(tests, key=lambda n: tests[n]["p"])
    v = tests[worst]
    limit = p_family / len(tests)
    fails = v["p"] < limit
    if worst.startswith("Ca_"):
        scale, unit = 1.0 / ARCSEC, "arcsec"
    elif worst.startswith("K_") and v.get("value"):
        scale, unit = 1e6 / abs(v["value"]), "ppm"          # of K
    else:
        scale, unit = 1e6, "ug"
    reason = (f"the thermal line of {worst} is curved: c2 = {v['c2'] * scale:.3g} +- "
              f"{v['c2_sd'] * scale:.2g} {unit}/degC^2 (t = {v['t']:.3g} on {v['dof']} dof, p = {v['p']:.2g}"
              f" < {limit:.2g})"
              + ("; a straight line's value at the reference temperature and slope are biased by it, which the "
                 "Birge ratio's widening does not correct: fit with --method joint --thermal-order auto (on a "
                 "schedule that visits each temperature once, a unit that changed in steps during the campaign "
                 "looks the same: `triadcal diagnose` tells the two apart)"
                 if fails else "; no line of the " + str(len(tests)) + " is curved beyond it"))
    if not fails:
        reason = (f"no thermal line is curved beyond p {limit:.2g} (the most: {worst}, t = {v['t']:.3g} on "
                  f"{v['dof']} dof, p = {v['p']:.2g})")
    return GateOutcome("thermal_curvature", not fails, "model_mismatch", reason, float(abs(v["t"])),
                       f"p >= {limit:.2g} (0.001 / {len(tests)} lines)")
