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


class ThermalLag(Effect):
    name = "thermal_lag"
    description = "first-order lag of the sensing elements behind their temperature sensors (min)"

    def parameters(self):
        return (ParameterSpec("thermal_lag", "min", 5.0,
                              "time constant of the sensing elements behind their sensors", self.name),)

    def temperature(self, p, cov, dT):
        return tuple(lagged(dT[i], cov.temp_rate[i], p["thermal_lag"]) for i in range(3))


def element_temperature(t_s, T, tau_s: float, location: str = "housing", tau_housing_s: float = 0.0):
    """Temperature of the sensing element from the thermometer's record ``T`` at times ``t_s``
    (s; any order, one column or ``(n, k)``): one first-order stage ``tau_s`` behind the record
    (``location="housing"``), or two stages, ``tau_housing_s`` then ``tau_s`` (``"air"``), each
    :mod:`triadcal.models.thermal_history`'s ramp-invariant lag, the element at rest with the
    record at the first sample. Times that repeat (several visits at one instant) keep the order
    of the input."""
    if location not in LOCATIONS:
        raise ValueError(f"unknown thermometer location {location!r}; choose one of {', '.join(LOCATIONS)}")
    t = np.asarray(t_s, float)
    X = np.asarray(T, float)
    order = np.argsort(t, kind="stable")
    ts = t[order]
    ts = ts + np.arange(len(ts)) * 1e-9 * (np.diff(ts, prepend=-np.inf) <= 0)   # strictly increasing
    cols = X[order].reshape(len(t), -1)
    out = np.empty_like(cols)
    for j in range(cols.shape[1]):
        out[:, j] = (first_order_lag(ts, cols[:, j], tau_s) if location == "housing" else
                     two_stage_lag(ts, cols[:, j], tau_housing_s, tau_s))
    res = np.empty_like(out)
    res[order] = out
    return res.reshape(X.shape)
