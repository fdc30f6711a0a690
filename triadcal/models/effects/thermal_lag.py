"""Thermal lag: the sensing element lags the temperature sensor beside it.

A first-order lag with time constant ``tau``: ``T_elem = T_sensor - tau dT_sensor/dt``
(the rate form: first order in ``tau`` against the time scale of the temperature's changes,
exact for a steady ramp). One time constant for the unit, reported in minutes. The rate
comes from the campaign (the readings of ``t_*`` against ``time_s`` within a setpoint).

Where the thermometer sits (docs/model.md, "Thermal lag: where the thermometer sits"): the
rate form holds for a lag short against the campaign's transients. Over the whole measured
history, for any time constant, :func:`element_temperature` gives the element's temperature
from the thermometer's record for the two mechanisms of :data:`LOCATIONS`:

* ``housing`` -- the thermometer sits on the housing, the element lags it by one stage::

      dT_e/dt = (T_s - T_e) / tau                                 (thermal_lag = tau)

* ``air`` -- the thermometer measures the chamber air (the chamber's PV), the housing lags the
  air and the element lags the housing: two first-order stages in series::

      dT_h/dt = (T_s - T_h) / tau_h,   dT_e/dt = (T_h - T_e) / tau  (thermal_lag_housing = tau_h)

  (second order: the element's response to a step of the air starts with zero slope).

With the thermometer on the element itself there is no lag (leave the effect off).

**Gaps of the record.** A stepped campaign read only at its visits does not record the soaks. A
straight line across a gap says the thermometer moved evenly through it; after a setpoint step
it moves at once and settles. :func:`bridge_record` fills each gap (from the last reading
``T0`` before it to the first ``T1`` after it, ``D`` long) with a first-order approach that
starts with the gap::

    T(s) = T1 + (T0 - T1) (exp(-s / tau_b) - exp(-D / tau_b)) / (1 - exp(-D / tau_b)),  0 <= s <= D

which reaches ``T1`` at the gap's end; ``tau_b`` -> 0 is a step at the gap's start and
``tau_b`` -> inf the straight line (the chamber air behind a stepped setpoint: a first-order
response of the chamber's time constant; a housing thermometer is a slower, second-order one,
which one ``tau_b`` approximates).
:func:`triadcal.estimation.thermal_lag_form.fit_thermal_lag` estimates the time constants from
the record with the joint model, positive by construction (profiled in log tau).
"""

from __future__ import annotations

import numpy as np

from ..parameters import ParameterSpec
from ..thermal_history import first_order_lag, two_stage_lag
from .base import Effect

#: where the thermometer sits: on the housing (one stage to the element) or in the chamber air (two)
LOCATIONS = ("housing", "air")


def lagged(temperature, rate, tau):
    """``T - tau dT/dt``: temperature of an element lagging by a first-order time constant."""
    return temperature - tau * rate


def rate_form_time_constant(tau, tau_approach):
    """The time constant the rate form finds for an element lagging its thermometer by ``tau``
    (first order) while the thermometer approaches its final value exponentially with
    ``tau_approach`` (same unit): ``tau tau_a / (tau_a - tau)`` (``tau < tau_a``), and inversely
    ``tau = tau_r tau_a / (tau_a + tau_r)``.

    Derivation: with ``T(t) = T_inf + A exp(-t / tau_a)`` the lagging element settles (its own
    transient gone) to ``T_e - T_inf = (T - T_inf) tau_a / (tau_a - tau)``, and the rate form
    writes ``T - tau_r dT/dt = T_inf + (T - T_inf)(1 + tau_r / tau_a)``; equal when
    ``1 + tau_r / tau_a = tau_a / (tau_a - tau)``. The rate form is the first order in
    ``tau / tau_a``: a 7 min lag behind a thermometer settling with 20 min reads 10.8 min (an
    outside probe's stepped campaign: 10.5 +- 0.3 min, status ok)."""
    return tau * tau_approach / (tau_approach - tau)


class ThermalLag(Effect):
    name = "thermal_lag"
    description = "first-order lag of the sensing elements behind their temperature sensors (min)"

    def parameters(self):
        return (ParameterSpec("thermal_lag", "min", 5.0,
                              "time constant of the sensing elements behind their sensors", self.name),)

    def temperature(self, p, cov, dT):
        return tuple(lagged(dT[i], cov.temp_rate[i], p["thermal_lag"]) for i in range(3))


def bridge_record(t_s, T, tau_bridge_s: float, min_gap_s: float):
    """``(times, values, kept)``: the record ``T`` ((n, k), at strictly increasing ``t_s``) with every
    interval longer than ``min_gap_s`` filled by the first-order approach of the module docstring
    (``tau_bridge_s``; points every ``tau_b / 4``, 8 to 200 per gap); ``kept`` the indices of the
    original samples in the result."""
    t = np.asarray(t_s, float)
    X = np.asarray(T, float).reshape(len(t), -1)
    if tau_bridge_s <= 0 or not np.isfinite(tau_bridge_s):
        raise ValueError("the bridge's time constant must be positive and finite")
    times, values, kept, count = [], [], [], 0
    for i in range(len(t)):
        kept.append(count)
        count += 1
        times.append(t[i:i + 1])
        values.append(X[i:i + 1])
        if i + 1 < len(t) and t[i + 1] - t[i] > min_gap_s:
            D = float(t[i + 1] - t[i])
            m = int(min(200, max(8, np.ceil(4.0 * D / tau_bridge_s))))
            s = np.linspace(0.0, D, m + 1)[1:-1]
            e = np.exp(-D / tau_bridge_s)
            f = (np.exp(-s / tau_bridge_s) - e) / (1.0 - e) if e < 1.0 - 1e-12 else 1.0 - s / D
            times.append(t[i] + s)
            values.append(X[i + 1] + (X[i] - X[i + 1]) * f[:, None])
            count += len(s)
    # the original samples sit one after another when no gap follows them: their indices grow by one
    return np.concatenate(times), np.concatenate(values), np.asarray(kept, int)


def element_temperature(t_s, T, tau_s: float, location: str = "housing", tau_housing_s: float = 0.0,
                        bridge=None):
    """Temperature of the sensing element from the thermometer's record ``T`` at times ``t_s``
    (s; any order, one column or ``(n, k)``): one first-order stage ``tau_s`` behind the record
    (``location="housing"``), or two stages, ``tau_housing_s`` then ``tau_s`` (``"air"``), each
    :mod:`triadcal.models.thermal_history`'s ramp-invariant lag, the element at rest with the
    record at the first sample. Times that repeat (several visits at one instant) keep the order
    of the input. ``bridge``: ``(tau_bridge_s, min_gap_s)`` fills the record's gaps first
    (:func:`bridge_record`); None: straight lines across them."""
    if location not in LOCATIONS:
        raise ValueError(f"unknown thermometer location {location!r}; choose one of {', '.join(LOCATIONS)}")
    t = np.asarray(t_s, float)
    X = np.asarray(T, float)
    order = np.argsort(t, kind="stable")
    ts = t[order]
    ts = ts + np.arange(len(ts)) * 1e-9 * (np.diff(ts, prepend=-np.inf) <= 0)   # strictly increasing
    cols = X[order].reshape(len(t), -1)
    kept = None
    if bridge is not None:
        ts, cols, kept = bridge_record(ts, cols, float(bridge[0]), float(bridge[1]))
    out = np.empty_like(cols)
    for j in range(cols.shape[1]):
        out[:, j] = (first_order_lag(ts, cols[:, j], tau_s) if location == "housing" else
                     two_stage_lag(ts, cols[:, j], tau_housing_s, tau_s))
    if kept is not None:
        out = out[kept]
    res = np.empty_like(out)
    res[order] = out
    return res.reshape(X.shape)
