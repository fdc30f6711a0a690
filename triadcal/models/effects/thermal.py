"""Linear temperature coefficients of the angles, scale factors and biases.

The paper's thermal correction (eq. 5-7 and its conclusion): a linear correction of
the orientation matrix against the accelerometers' temperature. Row ``a`` of Ca,
``K_a`` and ``S_a`` follow the temperature of accelerometer ``a``'s own sensor
(``t_a``), as deviation from the model's reference temperature.
"""

from __future__ import annotations

from ..parameters import per_angle, per_axis
from ..sensor import ANGLE_NAMES, AXES
from .base import Effect


def linear_in_temperature(value_ref, coefficient, dT):
    """``value(T) = value(T0) + coefficient * (T - T0)`` (the paper's linear thermal correction)."""
    return value_ref + coefficient * dT


def quadratic_in_temperature(value, coefficient2, dT):
    """``value + c2 (T - T0)^2``: the second-order term of the thermal dependence."""
    return value + coefficient2 * dT * dT


class AngleTempco(Effect):
    name = "angle_tempco"
    description = "linear temperature coefficient of each orientation angle (arcsec/degC)"
    #: the term's power of (T - T0), parameter suffix, unit, typical size and description
    term, suffix, unit, typical = staticmethod(linear_in_temperature), "tempco", "arcsec/degC", 2.0
    meaning = "temperature coefficient of Ca_{ab}"

    def parameters(self):
        return per_angle(f"Ca_{{ab}}_{self.suffix}", self.unit, self.typical, self.meaning, self.name)

    def angles(self, p, cov, dT, angles):
        out = dict(angles)
        for ab in ANGLE_NAMES:
            out[ab] = self.term(angles[ab], p[f"Ca_{ab}_{self.suffix}"], dT[AXES.index(ab[0])])
        return out


class ScaleTempco(Effect):
    name = "scale_tempco"
    description = "linear temperature coefficient of each scale factor (ppm/degC)"
    term, suffix, unit, typical = staticmethod(linear_in_temperature), "tempco", "ppm/degC", 50.0
    meaning = "temperature coefficient of K_{ax}"

    def parameters(self):
        return per_axis(f"K_{{a}}_{self.suffix}", self.unit, self.typical, self.meaning, self.name)

    def scale(self, p, cov, dT, K):
        return tuple(K[i] * self.term(1.0, p[f"K_{a}_{self.suffix}"], dT[i]) for i, a in enumerate(AXES))


class BiasTempco(Effect):
    name = "bias_tempco"
    description = "linear temperature coefficient of each bias (ug/degC)"
    term, suffix, unit, typical = staticmethod(linear_in_temperature), "tempco", "ug/degC", 30.0
    meaning = "temperature coefficient of S_{ax}"

    def parameters(self):
        return per_axis(f"S_{{a}}_{self.suffix}", self.unit, self.typical, self.meaning, self.name)

    def bias(self, p, cov, dT, S):
        return tuple(self.term(S[i], p[f"S_{a}_{self.suffix}"], dT[i]) for i, a in enumerate(AXES))
