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


class AngleTempco(Effect):
    name = "angle_tempco"
    description = "linear temperature coefficient of each orientation angle (arcsec/degC)"

    def parameters(self):
        return per_angle("Ca_{ab}_tempco", "arcsec/degC", 2.0,
                         "temperature coefficient of Ca_{ab}", self.name)

    def angles(self, p, cov, dT, angles):
        out = dict(angles)
        for ab in ANGLE_NAMES:
            out[ab] = linear_in_temperature(angles[ab], p[f"Ca_{ab}_tempco"], dT[AXES.index(ab[0])])
        return out


class ScaleTempco(Effect):
    name = "scale_tempco"
    description = "linear temperature coefficient of each scale factor (ppm/degC)"

    def parameters(self):
        return per_axis("K_{a}_tempco", "ppm/degC", 50.0, "temperature coefficient of K_{ax}", self.name)

    def scale(self, p, cov, dT, K):
        return tuple(K[i] * linear_in_temperature(1.0, p[f"K_{a}_tempco"], dT[i]) for i, a in enumerate(AXES))


class BiasTempco(Effect):
    name = "bias_tempco"
    description = "linear temperature coefficient of each bias (ug/degC)"

    def parameters(self):
        return per_axis("S_{a}_tempco", "ug/degC", 30.0, "temperature coefficient of S_{ax}", self.name)

    def bias(self, p, cov, dT, S):
        return tuple(linear_in_temperature(S[i], p[f"S_{a}_tempco"], dT[i]) for i, a in enumerate(AXES))
