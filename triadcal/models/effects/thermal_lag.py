"""Thermal lag: the sensing element lags the temperature sensor beside it.

A first-order lag with time constant ``tau``: ``T_elem = T_sensor - tau dT_sensor/dt``
(exact for the exponential approach to a setpoint). One time constant for the unit,
reported in minutes. The rate comes from the campaign (the readings of ``t_*`` against
``time_s`` within a setpoint).
"""

from __future__ import annotations

from ..parameters import ParameterSpec
from .base import Effect


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
