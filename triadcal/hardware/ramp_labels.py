"""The labels of a ramp capture's visits, from the unit's temperature readings: the window's rates
(:func:`window_rates`, :func:`visit_rate_se`), its direction (:func:`visit_direction`), a turn
within it (:func:`turned_within`), a window that is not at rest (:func:`not_stationary`), and the
readings kept for them (:class:`_History`). Pure functions of the readings; split from
``ramp_capture.py`` (docs/hardware.md, "Continuous ramp capture")."""

from __future__ import annotations

import math
from collections import deque
from typing import Optional

import numpy as np


#: seconds of temperature readings before a window that its direction is judged on (with the window)
DIRECTION_SPAN_S = 150.0


def window_rates(history, t0: float, t1: float, span_s: float = DIRECTION_SPAN_S) -> dict:
    """Rates (degC/s) of the mean temperature reading over the window ``[t0, t1]``, each with its
    standard error, from a least-squares quadratic through the readings of ``[t0 - span_s, t1]``
    (``history``: (time_s, mean reading) pairs of every accepted frame, in any phase): ``mean``
    (the slope at the middle, which is the window's mean rate), ``start`` and ``end`` (at t0 and t1).
    Standard errors are infinite with fewer than 8 readings."""
    nothing = {"mean": 0.0, "mean_se": math.inf, "start": 0.0, "start_se": math.inf, "end": 0.0,
               "end_se": math.inf}
    if not len(history):
        return nothing
    h = np.asarray(history, float)
    h = h[(h[:, 0] >= t0 - span_s) & (h[:, 0] <= t1)]
    if len(h) < 8:
        return nothing
    x = h[:, 0] - 0.5 * (t0 + t1)
    X = np.stack([np.ones_like(x), x, x * x], axis=1)
    coef, *_ = np.linalg.lstsq(X, h[:, 1], rcond=None)
    res = h[:, 1] - X @ coef
    s2 = float(res @ res) / max(len(h) - 3, 1)
    try:
        cov = s2 * np.linalg.inv(X.T @ X)
    except np.linalg.LinAlgError:
        return nothing
    half = 0.5 * (t1 - t0)
    out = {"mean": float(coef[1]), "mean_se": float(math.sqrt(max(cov[1, 1], 0.0)))}
    for key, sign in (("start", -1.0), ("end", 1.0)):
        g = np.array([0.0, 1.0, 2.0 * sign * half])          # d/dx of (1, x, x^2) at the end
        out[key] = float(g @ coef)
        out[key + "_se"] = float(math.sqrt(max(g @ cov @ g, 0.0)))
    return out


def visit_rate(frames) -> float:
    """The rate (degC/s) of the unit's temperature over a visit's window that its row carries
    (bench CSV ``dTdt_C_per_min``, the fit's ``dT/dt`` for ``thermal_lag``): the slope of the
    least-squares line through the mean temperature reading of the window's frames (``f.time_s``,
    mean of ``f.t``); 0 with fewer than 2 frames.

    The visit's mean output holds the window's mean rate (the mean of ``T - tau dT/dt`` over the
    window is the mean reading minus ``tau`` times ``(T(t1) - T(t0)) / (t1 - t0)``), which the line's
    slope is, without bias, for any temperature that is quadratic over the window, whatever the
    chamber's and the unit's time constants. The direction's quadratic (:func:`window_rates`, with
    the 150 s before the window) is less noisy but not unbiased: on the tests' fast unit (300 s,
    600 s) its slope was 0.5 % steep and thermal_lag 0.6 SD short (docs/hardware.md)."""
    return visit_rate_se(frames)[0]


def visit_rate_se(frames) -> tuple[float, float]:
    """:func:`visit_rate` and its ordinary least-squares standard error (degC/s; infinite with fewer
    than 3 frames), from the line's residuals: with the window's curvature in them, an upper bound."""
    pts = np.array([(f.time_s, float(np.mean(f.t))) for f in frames or ()], float).reshape(-1, 2)
    if len(pts) < 2 or not np.ptp(pts[:, 0]) > 0:
        return 0.0, math.inf
    x = pts[:, 0] - pts[:, 0].mean()
    y = pts[:, 1] - pts[:, 1].mean()
    slope = float(x @ y / (x @ x))
    if len(pts) < 3:
        return slope, math.inf
    res = y - slope * x
    return slope, float(math.sqrt(float(res @ res) / (len(pts) - 2) / float(x @ x)))


#: how ``dTdt_C_per_min`` is measured (metadata ``dTdt_method`` of a ramp capture's campaign.csv)
DTDT_METHOD = ("slope of the least-squares line through the mean temperature reading of the window's samples "
               "(the window's mean rate), degC/min, the rate of all three t_*")


def turned_within(rates: dict) -> bool:
    """True when the unit's temperature turned during the window: its rates at the start and at the
    end have opposite signs and one of them is 3 standard errors from 0. Such a window holds both
    branches of the hysteresis, which one visit's label cannot describe.

    One significant rate is enough: at a turn one end of the window is still near the vertex, its
    rate within the noise (the program's start, where the readings still rise with the electronics'
    self-heating while the chamber has begun to cool, gave +22 SE then -0.8 SE: a window on both
    branches, labelled by its mean rate, |z| 23 in the fit). On a plateau both rates are noise and
    the rule fires with probability about 0.3 %, which costs one window again."""
    s, e = rates["start"], rates["end"]
    return bool(s * e < 0 and max(abs(s) / rates["start_se"], abs(e) / rates["end_se"]) > 3.0)


def visit_direction(slope: float, se: float, previous: str, at_rest: float = 0.0,
                    own: tuple[float, float] = (0.0, math.inf)) -> str:
    """``heating`` / ``cooling`` by the sign of the window's rate when it is 3 standard errors from
    0 and faster than ``at_rest`` (same unit as ``slope``: the rate below which the capture counts
    the unit as settled, ``Stabilisation.rate_C_per_min``); otherwise the previous visit's (at a
    ramp's start: its first leg's, the way the unit, at rest there, starts to move; at a turn: the
    branch the unit is on until its turn shows). A rate that is significant but below ``at_rest`` is
    no move of the element: at the program's start the readings still creep up by ~0.001 degC/min
    with the electronics' self-heating, many SE at 2 Hz, while the chamber is about to cool; labelled
    ``heating`` by it, the first visit of a CI run's ramp took the wrong branch (|z| 22 in the fit).

    ``own``: the window's own line (:func:`visit_rate_se`, the row's ``dTdt_C_per_min``), which
    decides first when it passes the same two tests. The quadratic through the 150 s before the
    window is less noisy but lags a turn: a CI run (2026-11-30, a unit with 60 s and 120 s time
    constants) labelled ``cooling`` a window whose own readings rose at 0.204 degC/min, and the
    reader refused the file its capture wrote (docs/bench-csv.md: a ramp label against its row's
    rate by more than 0.2 degC/min); a numpy turn of such a unit gives the quadratic -0.2 degC/min
    where the window's line gives +0.2 (tests/test_ramp_capture.py)."""
    for s, e in (own, (slope, se)):
        if abs(s) > 3.0 * e and abs(s) > at_rest:
            return "heating" if s > 0 else "cooling"
    return previous


def strays(x: np.ndarray) -> tuple:
    """``(dev, noise)`` per column of a window's samples ``x`` (n, k): the largest distance from the
    column's median, and the noise SD from successive differences (1.4826 MAD / sqrt 2, blind to a
    slow drift)."""
    d = np.diff(x, axis=0)
    noise = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / math.sqrt(2.0)
    return np.max(np.abs(x - np.median(x, axis=0)), axis=0), noise


def not_stationary(frames, previous_sd) -> Optional[str]:
    """Why a recording window's outputs are not those of a unit at rest (the bench still moving
    when the window began, a knock), or None. Per axis: a sample farther than 10 noise SDs from
    the window's median, the noise SD taken from successive differences (1.4826 MAD / sqrt 2,
    blind to the slow drift of a ramp); or an SD above 3 times the median SD of the recent visits
    (``previous_sd``, when there are 3 or more). A ramp's drift within a window (a few 1e-5 g) is
    far below either."""
    if len(frames) < 4:
        return None
    w = np.array([f.w for f in frames], float)
    dev, noise = strays(w)
    for i, a in enumerate("xyz"):
        if noise[i] > 0 and dev[i] > 10.0 * noise[i]:
            return f"w_{a} strays {dev[i] / noise[i]:.0f} noise SDs from the window's median"
    if len(previous_sd) >= 3:
        ref = np.median(np.asarray(previous_sd, float), axis=0)
        sd = w.std(axis=0, ddof=1)
        for i, a in enumerate("xyz"):
            if ref[i] > 0 and sd[i] > 3.0 * ref[i]:
                return f"sd of w_{a} {sd[i]:.3g} is {sd[i] / ref[i]:.1f} times the recent visits' median"
    return None


class _History:
    """``(time_s, mean reading)`` of every accepted frame (the runner's continuous clock, runner.py),
    for the directions: the last ``keep_s`` seconds. Fed by :meth:`_RampRunner.observe`."""

    def __init__(self, keep_s: float = 4 * DIRECTION_SPAN_S):
        self.keep_s = keep_s
        self.history: deque = deque()

    def add(self, frames) -> None:
        for f in frames:
            self.history.append((f.time_s, float(np.mean(f.t))))
        if frames:
            end = frames[-1].time_s
            while self.history and self.history[0][0] < end - self.keep_s:
                self.history.popleft()
