"""Slow turning within a "static" interval of a raw recording: the bias it leaves in K.

The detector (detection.py) looks for motion as a moving SD over 1 s windows; a unit that turns
slowly and steadily through a hold (an outside probe: 0.3 deg/s through 20 s holds) raises no
window's SD above the threshold, and every hold is taken as static. A steady turn of ``theta``
(rad) about an axis perpendicular to gravity over the hold shortens the interval's mean vector by

    1 - |mean a| / g = 1 - sin(theta/2) / (theta/2) ~ theta^2 / 24,

the same fraction in every pose when the turning is alike: the gravity-norm fit (unknown poses)
and the six faces (known poses) put it into K with no residual. The probe's 6 deg turns shortened
the means by 460 ppm: K 15-50 u high, status ok, and `--diagnose` found nothing.

:func:`interval_turns` measures the turn of each interval from the trend of its mean vector's
direction: the interval in ``BATCHES`` consecutive batches, the batch means projected on the two
directions perpendicular to the interval's mean, each regressed on time (``BATCHES - 2`` dof, so
that slowly correlated noise and a bias wander widen the slope's SE rather than fake a turn).
:func:`turning_gate` refuses (``model_mismatch``) when the turns are significant (the largest
``|t|`` over the intervals' two slopes, Bonferroni over ``2 x intervals``, below the gates'
``gof_p_min``) and the mean shortening reaches ``SHIFT_MAX_U`` of the smallest relative u of K.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..gates import GateOutcome

BATCHES = 10
#: the mean shortening of the intervals' means, in the smallest relative u of K, above which the fit refuses
SHIFT_MAX_U = 0.5
#: ... and above which a note says it (significant turns below the refusal)
NOTE_MIN_U = 0.1


def interval_turns(acc: np.ndarray, starts, ends, rate_hz: float) -> list[dict]:
    """Per interval: ``{"theta_deg", "rate_deg_s", "shortening", "p"}`` (the turn over the interval,
    its rate, ``theta^2/24``, and the two-sided p of the larger perpendicular slope); None for an
    interval of fewer than ``5 * BATCHES`` samples (too short to show a trend)."""
    out = []
    for s, e in zip(starts, ends):
        x = np.asarray(acc[int(s):int(e)], float)
        if len(x) < 5 * BATCHES:
            out.append(None)
            continue
        m = x.mean(axis=0)
        g = float(np.linalg.norm(m))
        if not g > 0:
            out.append(None)
            continue
        u = m / g
        e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(u, e1)
        parts = np.array_split(np.arange(len(x)), BATCHES)
        t = np.array([p.mean() for p in parts]) / rate_hz
        bm = np.array([x[p].mean(axis=0) for p in parts])
        X = np.column_stack([np.ones(BATCHES), t - t.mean()])
        slopes, ts = [], []
        for d in (e1, e2):
            y = bm @ d
            c, *_ = np.linalg.lstsq(X, y, rcond=None)
            res = y - X @ c
            s2 = float(res @ res) / (BATCHES - 2)
            se = math.sqrt(s2 / float(np.sum((t - t.mean()) ** 2))) if s2 > 0 else 0.0
            slopes.append(c[1])
            ts.append(abs(c[1]) / se if se > 0 else (math.inf if c[1] != 0 else 0.0))
        span_s = (len(x) - 1) / rate_hz
        theta = math.hypot(*slopes) * span_s / g
        out.append({"theta_deg": math.degrees(theta), "rate_deg_s": math.degrees(theta) / span_s if span_s > 0 else 0.0,
                    "shortening": theta * theta / 24.0,
                    "p": float(2.0 * stats.t.sf(max(ts), BATCHES - 2))})
    return out


def turning_gate(result, turns: list, labels, alpha: float):
    """``(gate, note)`` of the intervals' turns against the fitted K (module docstring); ``(None, None)``
    when no interval could be measured or the result has no K with a u."""
    meas = [(k, d) for k, d in enumerate(turns) if d is not None]
    rel = [p.u / abs(p.value) for n, p in result.parameters.items()
           if n in ("K_x", "K_y", "K_z") and p.u and p.value and math.isfinite(p.u) and p.u > 0]
    if not meas or not rel:
        return None, None
    u_rel = min(rel)
    p_family = min(1.0, min(d["p"] for _, d in meas) * 2 * len(meas))
    mean_short = float(np.mean([d["shortening"] for _, d in meas]))
    shift_u = mean_short / u_rel
    worst = sorted(meas, key=lambda kd: -kd[1]["theta_deg"])[:3]
    named = "; ".join(f"{labels[k] or k + 1}: {d['theta_deg']:.2g} deg ({d['rate_deg_s']:.2g} deg/s, p = {d['p']:.2g})"
                      for k, d in worst)
    what = (f"the static intervals' mean vectors turn within them (largest: {named}; all {len(meas)}: p = "
            f"{p_family:.2g} with Bonferroni): a steady turn theta shortens a mean by theta^2/24, on average "
            f"{mean_short * 1e6:.3g} ppm here, {shift_u:.2g} of the smallest relative u of K ({u_rel * 1e6:.3g} ppm), "
            "which the fit puts into K")
    significant = p_family < alpha
    passed = not (significant and shift_u > SHIFT_MAX_U)
    reason = what if not passed else (f"mean shortening of the intervals' means by turning {mean_short * 1e6:.3g} ppm, "
                                      f"{shift_u:.2g} of the smallest relative u of K (p = {p_family:.2g})")
    if not passed:
        reason += (": the unit was moving through its holds slower than the detector's window sees (give "
                   "--static-window-s 5 or a lower --static-threshold, --intervals of the still parts, or hold the "
                   "unit still)")
    note = what if (passed and significant and shift_u > NOTE_MIN_U) else None
    gate = GateOutcome("static_intervals_still", passed, "model_mismatch", reason, shift_u,
                       f"turning shortens the means by <= {SHIFT_MAX_U:g} u of K, or no turn at p < {alpha:g}")
    return gate, note
