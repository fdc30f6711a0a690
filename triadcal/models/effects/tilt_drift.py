"""A bench tilt that changes during the campaign: the base settles, or its floor moves.

bench-csv.md's apparent gravity in the base frame ``(sin d cos b, sin d sin b, cos d)`` is
parametrised by its horizontal components ``tilt_x``, ``tilt_y`` (:mod:`.tilt`). Two laws of
their change with the time ``t`` since the start of the campaign (``time_s``; the z component
renormalised), both needing ``bench_tilt`` (the change of a tilt the model holds):

* ``tilt_drift`` -- a constant rate (a floor that creeps, a support that yields steadily)::

      tilt_x(t) = tilt_x + r_x t,   tilt_y(t) = tilt_y + r_y t           (r in arcsec/h)

* ``tilt_settling`` -- a first-order settling (a freshly mounted bench or fixture bedding in, a
  slab recovering from a load: the deflection of a viscoelastic support under a step load,
  ``d (1 - exp(-t / tau))``, the standard linear solid / Kelvin-Voigt creep law)::

      tilt_x(t) = tilt_x + d_x (1 - exp(-t / tau_s)),   likewise y     (d in arcsec, tau_s in h)

  ``tilt_x`` is the tilt at the start and ``tilt_x + d_x`` the settled one. The linear drift is
  its limit tau_s -> inf with d / tau_s = r: the two laws are nested (the diagnosis names the
  settling only when it beats the rate by the nested likelihood ratio, docs/diagnosis.md).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .. import ops
from ..parameters import ParameterSpec
from .base import Effect


def settled_fraction(t_s, tau_s):
    """``1 - exp(-max(t, 0) / |tau|)``: the share of the settling done at ``t`` (s; tau in s).
    Before the campaign's start the bench has not begun to settle (0)."""
    x = 0.5 * (t_s + ops.fabs(t_s)) / ops.fabs(tau_s)
    return 1.0 - (ca.exp(-x) if ops.is_symbolic(x) else np.exp(-x))


class TiltDrift(Effect):
    name = "tilt_drift"
    bench = True
    description = "drift of the bench tilt during the campaign (rate of each horizontal component, arcsec/h)"

    def parameters(self):
        return (ParameterSpec("tilt_x_drift", "arcsec/h", 2.0, "rate of tilt_x", self.name),
                ParameterSpec("tilt_y_drift", "arcsec/h", 2.0, "rate of tilt_y", self.name))

    def gravity_base(self, p, cov, f):
        """``f -> (f_x + r_x t, f_y + r_y t, sqrt(1 - f_x'^2 - f_y'^2))`` (r internal: per second)."""
        tx = f[0] + p["tilt_x_drift"] * cov.time_s
        ty = f[1] + p["tilt_y_drift"] * cov.time_s
        return tx, ty, ops.sqrt(1.0 - tx * tx - ty * ty)


class TiltSettling(Effect):
    name = "tilt_settling"
    bench = True
    description = ("settling of the bench tilt during the campaign, d (1 - exp(-t/tau_s)) on each horizontal "
                   "component (d in arcsec; one tau_s, h)")

    def parameters(self):
        return (ParameterSpec("tilt_x_settle", "arcsec", 10.0, "change of tilt_x when settled", self.name),
                ParameterSpec("tilt_y_settle", "arcsec", 10.0, "change of tilt_y when settled", self.name),
                ParameterSpec("tilt_settle_tau", "h", 3.0, "time constant of the settling", self.name,
                              nominal=3.0))

    def gravity_base(self, p, cov, f):
        """``f -> (f_x + d_x s, f_y + d_y s, sqrt(1 - ...))``, ``s = 1 - exp(-t/tau_s)`` (internal: rad, s)."""
        s = settled_fraction(cov.time_s, p["tilt_settle_tau"])
        tx = f[0] + p["tilt_x_settle"] * s
        ty = f[1] + p["tilt_y_settle"] * s
        return tx, ty, ops.sqrt(1.0 - tx * tx - ty * ty)
