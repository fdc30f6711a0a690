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
