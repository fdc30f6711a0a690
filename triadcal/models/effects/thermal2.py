"""Quadratic temperature coefficients of the angles, scale factors and biases.

Real units are not linear over −40…+85 °C (silicon MEMS above all): the second term of the
Taylor series about the reference temperature, ``value(T) = value(T0) + c1 (T − T0) +
c2 (T − T0)²``, added to the linear tempcos of :mod:`.thermal` (the same hooks, with
:func:`.thermal.quadratic_in_temperature`; docs/model.md, "Quadratic tempcos"). A quadratic
angle tempco of 0.004″/°C² moves an angle by 10″ at 50 °C from T0.
"""

from __future__ import annotations

from .thermal import AngleTempco, BiasTempco, ScaleTempco, quadratic_in_temperature


class AngleTempco2(AngleTempco):
    name = "angle_tempco2"
    description = "quadratic temperature coefficient of each orientation angle (arcsec/degC2)"
    term, suffix, unit, typical = staticmethod(quadratic_in_temperature), "tempco2", "arcsec/degC2", 0.004
    meaning = "quadratic temperature coefficient of Ca_{ab}"


class ScaleTempco2(ScaleTempco):
    name = "scale_tempco2"
    description = "quadratic temperature coefficient of each scale factor (ppm/degC2)"
    term, suffix, unit, typical = staticmethod(quadratic_in_temperature), "tempco2", "ppm/degC2", 0.05
    meaning = "quadratic temperature coefficient of K_{ax}"


class BiasTempco2(BiasTempco):
    name = "bias_tempco2"
    description = "quadratic temperature coefficient of each bias (ug/degC2)"
    term, suffix, unit, typical = staticmethod(quadratic_in_temperature), "tempco2", "ug/degC2", 0.05
    meaning = "quadratic temperature coefficient of S_{ax}"
