"""Second-order scale nonlinearity K2 (IEEE Std 1293 model equation).

``K W = a + K2 a^2 + S`` with ``a`` the acceleration along the sensing axis in g and
``K2`` in ug/g^2.
"""

from __future__ import annotations

from ..parameters import per_axis
from .base import Effect


def second_order(a, k2):
    """``a + K2 a^2`` (IEEE 1293, K2 term)."""
    return a + k2 * a * a


class ScaleNonlinearity(Effect):
    name = "scale_nonlinearity"
    description = "second-order scale nonlinearity K2 (ug/g^2)"

    def parameters(self):
        return per_axis("K2_{a}", "ug/g2", 20.0, "second-order nonlinearity of the {a} accelerometer", self.name)

    def transfer(self, p, cov, sensed):
        return tuple(second_order(sensed[i], p[f"K2_{a}"]) for i, a in enumerate("xyz"))

    def inverse_transfer(self, p, cov, responded):
        """``a = m - K2 m^2`` to first order in K2 (the error is 2 K2^2 m^3: 1e-9 g for K2 = 20 ug/g^2)."""
        return tuple(responded[i] - p[f"K2_{a}"] * responded[i] * responded[i] for i, a in enumerate("xyz"))
