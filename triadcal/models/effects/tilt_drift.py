"""A bench tilt that changes during the campaign: the base settles, or its floor moves.

bench-csv.md's apparent gravity in the base frame ``(sin d cos b, sin d sin b, cos d)`` is
parametrised by its horizontal components ``tilt_x``, ``tilt_y`` (:mod:`.tilt`); here they
drift linearly with the time since the start of the campaign::

    tilt_x(t) = tilt_x + r_x t,   tilt_y(t) = tilt_y + r_y t     (r in arcsec/h)

(the z component renormalised). Needs ``bench_tilt`` (the drift of a tilt the model holds).
"""

from __future__ import annotations

from .. import ops
from ..parameters import ParameterSpec
from .base import Effect


class TiltDrift(Effect):
    name = "tilt_drift"
    description = "drift of the bench tilt during the campaign (rate of each horizontal component, arcsec/h)"

    def parameters(self):
        return (ParameterSpec("tilt_x_drift", "arcsec/h", 2.0, "rate of tilt_x", self.name),
                ParameterSpec("tilt_y_drift", "arcsec/h", 2.0, "rate of tilt_y", self.name))

    def gravity_base(self, p, cov, f):
        """``f -> (f_x + r_x t, f_y + r_y t, sqrt(1 - f_x'^2 - f_y'^2))`` (r internal: per second)."""
        tx = f[0] + p["tilt_x_drift"] * cov.time_s
        ty = f[1] + p["tilt_y_drift"] * cov.time_s
        return tx, ty, ops.sqrt(1.0 - tx * tx - ty * ty)
