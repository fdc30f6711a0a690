"""Cubic temperature coefficients of the angles, scale factors and biases.

The third term of the Taylor series about the reference temperature T0, added to the linear
(:mod:`.thermal`) and quadratic (:mod:`.thermal2`) tempcos with the same hooks and each row's own
sensor temperature (docs/model.md, "Quadratic and cubic tempcos")::

    value(T) = value(T0) + c1 (T − T0) + c2 (T − T0)² + c3 (T − T0)³

A silicon MEMS unit over −40…+85 °C bends asymmetrically about 20 °C (the cold end flattens, the
hot end steepens, or the reverse): 2e-5″/°C³ moves an angle by 5.5″ at 65 °C from T0 and by
−4.3″ at −60 °C, which a quadratic cannot take up. ``K_a_tempco3`` (ppm/°C³) is a factor of K
like the lower orders; ``S_a_tempco3`` in µg/°C³.
"""

from __future__ import annotations

from .thermal import AngleTempco, BiasTempco, ScaleTempco


def cubic_in_temperature(value, coefficient3, dT):
    """``value + c3 (T - T0)^3``: the third-order term of the thermal dependence."""
    return value + coefficient3 * dT * dT * dT


class AngleTempco3(AngleTempco):
    name = "angle_tempco3"
    description = "cubic temperature coefficient of each orientation angle (arcsec/degC3)"
    term, suffix, unit, typical = staticmethod(cubic_in_temperature), "tempco3", "arcsec/degC3", 2e-5
    meaning = "cubic temperature coefficient of Ca_{ab}"


class ScaleTempco3(ScaleTempco):
    name = "scale_tempco3"
    description = "cubic temperature coefficient of each scale factor (ppm/degC3)"
    term, suffix, unit, typical = staticmethod(cubic_in_temperature), "tempco3", "ppm/degC3", 2e-4
    meaning = "cubic temperature coefficient of K_{ax}"


class BiasTempco3(BiasTempco):
    name = "bias_tempco3"
    description = "cubic temperature coefficient of each bias (ug/degC3)"
    term, suffix, unit, typical = staticmethod(cubic_in_temperature), "tempco3", "ug/degC3", 2e-4
    meaning = "cubic temperature coefficient of S_{ax}"
