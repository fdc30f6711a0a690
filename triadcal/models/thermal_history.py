"""Operators on a measured temperature history: the sensing element's first-order lag behind its
sensor, the element ahead of a thermometer that lags it, the play (backlash) operator of a hysteresis and the Prandtl-Ishlinskii sum of plays. Pure numpy functions of the sampled
history, used by the thermal-cycle analysis of real recordings (``triadcal thermal-cycle``) and
written once here (docs/model.md, "A real chamber cycle").
"""

from __future__ import annotations

import math

import numpy as np


def first_order_lag(t_s, T, tau_s: float, start=None) -> np.ndarray:
    """Temperature of an element that lags the measured ``T`` by a first-order time constant::

        dT_e/dt = (T - T_e) / tau

    solved exactly for ``T`` linear between samples (ramp-invariant discretisation): with
    ``s = (T1 - T0)/dt`` and ``a = exp(-dt/tau)``,
    ``T_e1 = T1 - s tau + (T_e0 - T0 + s tau) a``. ``start``: T_e at the first sample
    (default: equal to T, the element at rest with its sensor). ``tau_s = 0`` returns ``T``.
    """
    t = np.asarray(t_s, float)
    x = np.asarray(T, float)
    if tau_s <= 0:
        return x.copy()
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise ValueError("times must increase")
    prev = float(x[0]) if start is None else float(start)
    if len(dt) and np.ptp(dt) <= 1e-12 * dt[0]:
        # evenly sampled: the same recursion T_e1 = a T_e0 + b as a first-order IIR filter
        # (scipy.signal.lfilter, C speed), b = T1 - s tau + a (s tau - T0)
        a0 = math.exp(-float(dt[0]) / tau_s)
        stv = np.diff(x) / dt * tau_s
        b = x[1:] - stv + a0 * (stv - x[:-1])
        from scipy import signal      # here, not at the top: importing scipy.signal takes 1 s, and every
                                      # command imports this module (through models.effects)
        y = signal.lfilter([1.0], [1.0, -a0], b, zi=[a0 * prev])[0]
        return np.concatenate([[prev], y])
    a = np.exp(-dt / tau_s).tolist()
    st = (np.diff(x) / dt * tau_s).tolist()
    xs = x.tolist()
    out = [prev]
    for k in range(1, len(xs)):          # plain floats: the recursion is sequential
        prev = xs[k] - st[k - 1] + (prev - xs[k - 1] + st[k - 1]) * a[k - 1]
        out.append(prev)
    return np.array(out)


def centred_rate(t_s, T, window_s: float = 120.0) -> np.ndarray:
    """The rate of ``T`` (per second) about each sample: the difference of the samples that open and
    close the window of ``window_s`` centred on it, over their time apart (one-sided at the record's
    ends). For a sampled record with white noise sigma the rate's SD is about sigma sqrt 2 / window."""
    t, T = np.asarray(t_s, float), np.asarray(T, float)
    lo = np.searchsorted(t, t - window_s / 2)
    hi = np.minimum(np.searchsorted(t, t + window_s / 2, side="right") - 1, len(t) - 1)
    dt = np.maximum(t[hi] - t[lo], 1e-9)
    return (T[hi] - T[lo]) / dt


def centred_mean(t_s, T, window_s: float) -> np.ndarray:
    """The reading averaged over the window of ``window_s`` centred on each sample (a moving average
    in time, zero phase: no delay; shortened at the record's ends). Of a staircase reading (a
    thermometer of resolution q on a ramp of rate v) the mean over one step's duration q / v is the
    ramp itself; of a white reading noise sigma over m samples, sigma / sqrt m. Not a model of the
    unit: the reading's own noise taken out, against which a delay or a hysteresis must show
    (estimation/thermal_reading.py)."""
    t, T = np.asarray(t_s, float), np.asarray(T, float)
    c = np.concatenate([[0.0], np.cumsum(T)])
    lo = np.searchsorted(t, t - window_s / 2)
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    return (c[hi] - c[lo]) / np.maximum(hi - lo, 1)


def thermometer_lead(t_s, T, tau_s: float, window_s: float = 120.0) -> np.ndarray:
    """Temperature of an element that its thermometer lags by a first-order time constant ``tau``
    (the thermometer behind the element: a sensor on the housing's far side, a slow probe)::

        dT/dt = (T_e - T) / tau      =>      T_e = T + tau dT/dt

    the exact inverse of :func:`first_order_lag`, with ``dT/dt`` from :func:`centred_rate` over
    ``window_s`` (a reading lagging by tau changes on that time scale; the window's noise on
    ``T_e`` is about ``tau sigma sqrt 2 / window``). On a ramp of rate v the element is ``tau v``
    ahead of the reading: the mirror of a lagging element, with the other sign. ``tau_s = 0``
    returns ``T``."""
    T = np.asarray(T, float)
    if tau_s <= 0:
        return T.copy()
    return T + tau_s * centred_rate(t_s, T, window_s)


def play_operator(x, half_width: float, start=None) -> np.ndarray:
    """The play (backlash) operator of half-width ``r`` (Krasnosel'skii & Pokrovskii; the
    elementary operator of a Prandtl-Ishlinskii hysteresis)::

        y_k = max(x_k - r, min(x_k + r, y_{k-1}))

    ``y`` follows ``x`` with a dead band of width 2r: on a rising ``x`` it trails by r, on a
    falling one it leads by r, so a quantity linear in ``y`` has a heating and a cooling branch
    2 r (times its slope) apart that join where the temperature turns. ``start``: the initial
    state ``y_0`` (default: ``x_0``, the middle of the band); ``r = 0`` returns ``x``. The
    constant-offset hysteresis of the joint model (``Ca_ab_hysteresis``) is its limit far from
    the turning points.
    """
    x = np.asarray(x, float)
    r = float(half_width)
    if r <= 0:
        return x.copy()
    xs = x.tolist()
    prev = xs[0] if start is None else min(max(float(start), xs[0] - r), xs[0] + r)
    out = []
    for v in xs:                          # plain floats: the recursion is sequential
        lo, hi = v - r, v + r
        prev = lo if prev < lo else (hi if prev > hi else prev)
        out.append(prev)
    return np.array(out)


def relay_branch(x, half_width: float) -> np.ndarray:
    """The branch of a hysteron (a relay with memory; Mayergoyz, *Mathematical Models of
    Hysteresis*, 1991, sec. 1.1) on ``x``: +1 after ``x`` has fallen by ``2r`` from a turn (the
    play :func:`play_operator` saturated above ``x``, ``y - x = r``), -1 after it has risen by
    ``2r`` (``y - x = -r``), the last value held in between, 0 before the first saturation::

        b_k = sign(y_k - x_k)  if |y_k - x_k| = r,   else b_{k-1};   b_0 = 0

    The joint model's branch of a visit (+1 cooling, -1 heating, held through a soak) on a
    continuous record. The ratio ``(y - x) / r`` itself is not a branch: inside the band it
    follows the noise of ``x`` (a thermometer of 0.01 degC SD against r = 0.1 moved it by 0.1).
    """
    x = np.asarray(x, float)
    r = float(half_width)
    if not r > 0:
        raise ValueError(f"relay_branch: half-width {r!r} must be positive")
    d = (play_operator(x, r) - x) / r
    sat = np.abs(d) >= 1.0 - 1e-9
    idx = np.where(sat, np.arange(len(x)), -1)
    last = np.maximum.accumulate(idx) if len(x) else idx
    return np.where(last >= 0, np.sign(d[np.maximum(last, 0)]), 0.0)


def prandtl_ishlinskii(x, half_widths, weights, start=None) -> np.ndarray:
    """The Prandtl-Ishlinskii operator: a weighted sum of plays (Brokate & Sprekels 1996, ch. 2;
    Kuhnen 2003)::

        y_k = sum_i w_i F_{r_i}[x]_k,        w_i >= 0

    with ``F_r`` the play of half-width ``r_i`` (:func:`play_operator`). Its loops are those of a
    Preisach model whose density lies on the lines alpha - beta = 2 r_i; with nonnegative weights
    every loop is traversed counterclockwise in (x, y) and the operator is rate independent,
    with the wiping-out memory of its plays. ``start``: one initial state ``y_0`` per play (a
    sequence), or one for all (each clipped to its play's band; default ``x_0``). Negative weights
    are refused (the loops would cross).
    """
    r = [float(v) for v in half_widths]
    w = [float(v) for v in weights]
    if len(r) != len(w) or not r:
        raise ValueError("a Prandtl-Ishlinskii operator needs as many weights as plays, and at least one")
    if any(v < 0 for v in w):
        raise ValueError("the weights of a Prandtl-Ishlinskii operator must be >= 0")
    starts = list(start) if isinstance(start, (list, tuple, np.ndarray)) else [start] * len(r)
    x = np.asarray(x, float)
    return sum(wi * play_operator(x, ri, s) for wi, ri, s in zip(w, r, starts))


def two_stage_lag(t_s, T, tau1_s: float, tau2_s: float, start=None) -> np.ndarray:
    """Temperature at the end of two first-order stages in series behind the measured ``T``
    (e.g. chamber air -> housing -> sensing element)::

        dT_1/dt = (T - T_1) / tau1,     dT_2/dt = (T_1 - T_2) / tau2

    :func:`first_order_lag` applied twice (each stage ramp-invariant between samples; exact for
    the first stage, accurate to O((dt/tau)^2) for the second, whose input is no longer linear
    between samples). The two stages commute (linear, time-invariant): the order of ``tau1``
    and ``tau2`` does not change the result, so data cannot tell which stage is which.
    ``start``: both stages at ``start`` (default: at rest with ``T``).
    """
    return first_order_lag(t_s, first_order_lag(t_s, T, tau1_s, start), tau2_s, start)
