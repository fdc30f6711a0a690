"""Scale asymmetry: a different scale factor for positive and negative input.

``K_+ = K (1 + e)``, ``K_- = K (1 - e)`` on the input side: ``a -> a + e |a|``
(IEEE Std 1293's asymmetry term), ``e`` in ppm.
"""

from __future__ import annotations

from .. import ops
from ..parameters import per_axis
from .base import Effect


def asymmetric(a, e):
    """``a (1 + e sign(a)) = a + e |a|``."""
    return a + e * ops.fabs(a)


class ScaleAsymmetry(Effect):
    name = "scale_asymmetry"
    description = "scale asymmetry between positive and negative input (ppm)"

    def parameters(self):
        return per_axis("K_{a}_asymmetry", "ppm", 50.0, "scale asymmetry of the {a} accelerometer", self.name)

    def transfer(self, p, cov, sensed):
        return tuple(asymmetric(sensed[i], p[f"K_{a}_asymmetry"]) for i, a in enumerate("xyz"))

    def inverse_transfer(self, p, cov, responded):
        """``a = m / (1 + e sign(m))``, exact (the sign of ``a`` is the sign of ``m`` for |e| < 1)."""
        return tuple(responded[i] / (1.0 + p[f"K_{a}_asymmetry"] * ops.sign(responded[i]))
                     for i, a in enumerate("xyz"))
