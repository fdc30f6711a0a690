"""Quadratic temperature coefficients of the angles, scale factors and biases.

Real units are not linear over −40…+85 °C (silicon MEMS above all): the second term of the
Taylor series about the reference temperature, ``value(T) = value(T0) + c1 (T − T0) +
c2 (T − T0)²``, added to the linear tempcos of :mod:`.thermal` (docs/model.md, "Quadratic
tempcos"). A quadratic angle tempco of 0.004″/°C² moves an angle by 10″ at 50 °C from T0.
"""

from __future__ import annotations

from ..parameters import per_angle, per_axis
from ..sensor import ANGLE_NAMES, AXES
from .base import Effect


def quadratic_in_temperature(value, coefficient2, dT):
    """``value + c2 (T − T0)²``: the second-order term of the thermal dependence."""
    return value + coefficient2 * dT * dT


class AngleTempco2(Effect):
    name = "angle_tempco2"
    description = "quadratic temperature coefficient of each orientation angle (arcsec/degC2)"

    def parameters(self):
        return per_angle("Ca_{ab}_tempco2", "arcsec/degC2", 0.004,
                         "quadratic temperature coefficient of Ca_{ab}", self.name)

    def angles(self, p, cov, dT, angles):
        out = dict(angles)
        for ab in ANGLE_NAMES:
            out[ab] = quadratic_in_temperature(angles[ab], p[f"Ca_{ab}_tempco2"], dT[AXES.index(ab[0])])
        return out


class ScaleTempco2(Effect):
    name = "scale_tempco2"
    description = "quadratic temperature coefficient of each scale factor (ppm/degC2)"

    def parameters(self):
        return per_axis("K_{a}_tempco2", "ppm/degC2", 0.05, "quadratic temperature coefficient of K_{ax}",
                        self.name)

    def scale(self, p, cov, dT, K):
        return tuple(K[i] * quadratic_in_temperature(1.0, p[f"K_{a}_tempco2"], dT[i]) for i, a in enumerate(AXES))


class BiasTempco2(Effect):
    name = "bias_tempco2"
    description = "quadratic temperature coefficient of each bias (ug/degC2)"

    def parameters(self):
        return per_axis("S_{a}_tempco2", "ug/degC2", 0.05, "quadratic temperature coefficient of S_{ax}",
                        self.name)

    def bias(self, p, cov, dT, S):
        return tuple(quadratic_in_temperature(S[i], p[f"S_{a}_tempco2"], dT[i]) for i, a in enumerate(AXES))
