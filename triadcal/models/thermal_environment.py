"""Thermal environment of the unit: the chamber follows its setpoint, the unit follows the chamber.

Two first-order lags in series (time constants ``tau_c`` of the chamber, ``tau_u`` of the
unit), solved in closed form for a step of the setpoint. The simulator and the
instrument emulator both use it, so they heat and cool the unit identically.
"""

from __future__ import annotations

import numpy as np


def two_lag_step(x, setpoint, chamber0, unit0, tau_c, tau_u):
    """Chamber and unit temperatures and the unit's rate ``x`` seconds after a setpoint step.

    ``dc/dt = (sp - c)/tau_c``, ``du/dt = (c - u)/tau_u`` from ``c(0) = chamber0``,
    ``u(0) = unit0``; returns ``(chamber, unit, du/dt)`` (degC, degC, degC/s).
    """
    x = np.maximum(np.asarray(x, float), 0.0)
    if abs(tau_c - tau_u) < 1e-9 * tau_u:   # equal time constants: the limit of the formula
        tau_u = tau_u * (1 + 1e-6)
    A = chamber0 - setpoint
    B = A * tau_c / (tau_c - tau_u)
    ec, eu = np.exp(-x / tau_c), np.exp(-x / tau_u)
    chamber = setpoint + A * ec
    unit = setpoint + B * ec + (unit0 - setpoint - B) * eu
    return chamber, unit, (chamber - unit) / tau_u


def step_sequence(times, step_starts, setpoints, start_C, tau_c, tau_u):
    """Chamber, unit and unit rate at ``times`` for a sequence of setpoint steps.

    ``step_starts`` (increasing, s) are the times the chamber is commanded to ``setpoints``;
    before the first, chamber and unit rest at ``start_C``.
    """
    times = np.asarray(times, float)
    starts = np.asarray(step_starts, float)
    c0 = np.empty(len(starts))
    u0 = np.empty(len(starts))
    c, u, t_prev, sp_prev = start_C, start_C, 0.0, start_C
    for k, (t0, sp) in enumerate(zip(starts, setpoints)):
        c, u, _ = two_lag_step(t0 - t_prev, sp_prev, c, u, tau_c, tau_u)
        c0[k], u0[k] = c, u
        t_prev, sp_prev = t0, sp
    seg = np.searchsorted(starts, times, side="right") - 1
    chamber = np.full(times.shape, float(start_C))
    unit = np.full(times.shape, float(start_C))
    rate = np.zeros(times.shape)
    on = seg >= 0
    s = seg[on]
    sp = np.asarray(setpoints, float)[s]
    chamber[on], unit[on], rate[on] = two_lag_step(times[on] - starts[s], sp, c0[s], u0[s], tau_c, tau_u)
    return chamber, unit, rate


def sensor_temperatures(unit_C, self_heating_C, time_s=None, time_constant_s: float = 0.0):
    """Temperatures (n, 3) of the three accelerometers' own sensors: the unit's temperature
    plus each sensor's self-heating, reached after power-on as a first-order lag::

        T_i(t) = T_unit(t) + dT_i (1 - exp(-t / tau))        (tau = 0: dT_i at once)

    ``unit_C`` (n,), ``self_heating_C`` the three dT_i (degC), ``time_s`` (n,) since power-on.
    The simulator (steady self-heating) and the emulator (from power-on) both use it."""
    heat = np.asarray(self_heating_C, float)[None, :]
    if time_constant_s > 0 and time_s is not None:
        heat = heat * (1.0 - np.exp(-np.asarray(time_s, float) / time_constant_s))[:, None]
    return np.asarray(unit_C, float)[:, None] + heat


def two_lag_ramp(x, start, slope, chamber0, unit0, tau_c, tau_u):
    """Chamber and unit temperatures and the unit's rate ``x`` seconds into a linear ramp of the
    chamber's program ``r(x) = start + slope x`` (slope in degC/s; ``slope = 0`` is
    :func:`two_lag_step`).

    ``dc/dt = (r - c)/tau_c``, ``du/dt = (c - u)/tau_u`` from ``c(0) = chamber0``, ``u(0) = unit0``::

        c(x) = r(x) - s tau_c + A exp(-x/tau_c),                      A = c0 - r0 + s tau_c
        u(x) = r(x) - s (tau_c + tau_u) + B exp(-x/tau_c) + D exp(-x/tau_u),
               B = A tau_c / (tau_c - tau_u),   D = u0 - r0 + s (tau_c + tau_u) - B

    (substitute into ``du/dt = (c - u)/tau_u``: the ``exp(-x/tau_c)`` terms need
    ``-B/tau_c = (A - B)/tau_u``, which is B above). On a long ramp the unit trails the program by
    the steady-state error ``s (tau_c + tau_u)``. Returns ``(chamber, unit, du/dt)``.
    """
    x = np.maximum(np.asarray(x, float), 0.0)
    if abs(tau_c - tau_u) < 1e-9 * tau_u:
        tau_u = tau_u * (1 + 1e-6)
    A = chamber0 - start + slope * tau_c
    B = A * tau_c / (tau_c - tau_u)
    D = unit0 - start + slope * (tau_c + tau_u) - B
    ec, eu = np.exp(-x / tau_c), np.exp(-x / tau_u)
    r = start + slope * x
    chamber = r - slope * tau_c + A * ec
    unit = r - slope * (tau_c + tau_u) + B * ec + D * eu
    return chamber, unit, (chamber - unit) / tau_u


def ramp_sequence(times, knot_times, knot_values, tau_c, tau_u):
    """Chamber, unit and unit rate at ``times`` for a piecewise-linear chamber program through
    ``(knot_times, knot_values)`` (s, degC; the first knot at the program's start, where chamber
    and unit rest at ``knot_values[0]``; after the last knot the program holds its value).
    Exact: :func:`two_lag_ramp` on every segment, the state carried from knot to knot."""
    times = np.asarray(times, float)
    kt = np.asarray(knot_times, float)
    kv = np.asarray(knot_values, float)
    n = len(kt)
    slopes = np.zeros(n)
    if n > 1:
        dt = np.diff(kt)
        if np.any(dt < 0):
            raise ValueError("knot times must not decrease")
        slopes[:-1] = np.where(dt > 0, np.diff(kv) / np.where(dt > 0, dt, 1.0), 0.0)
    c0, u0 = np.empty(n), np.empty(n)
    c0[0] = u0[0] = kv[0]
    for k in range(1, n):
        c, u, _ = two_lag_ramp(kt[k] - kt[k - 1], kv[k - 1], slopes[k - 1], c0[k - 1], u0[k - 1], tau_c, tau_u)
        c0[k], u0[k] = float(c), float(u)
    seg = np.clip(np.searchsorted(kt, times, side="right") - 1, 0, n - 1)
    before = times < kt[0]
    chamber, unit, rate = two_lag_ramp(times - kt[seg], kv[seg], slopes[seg], c0[seg], u0[seg], tau_c, tau_u)
    chamber, unit, rate = (np.where(before, kv[0], chamber), np.where(before, kv[0], unit),
                           np.where(before, 0.0, rate))
    return chamber, unit, rate


def ramp_program(times, knot_times, knot_values):
    """The chamber's programmed temperature at ``times`` (linear between knots, held outside)."""
    return np.interp(np.asarray(times, float), knot_times, knot_values)
