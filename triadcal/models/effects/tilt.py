"""Bench tilt: the bench's vertical axis is off the local vertical by delta toward beta.

bench-csv.md: the apparent gravity in the base frame is
``G (sin d cos b, sin d sin b, cos d)``; the paper's eq. 2-3 cancel it by pairing
positions a half turn apart, the joint model measures it.
"""

from __future__ import annotations

from ..kinematics import gravity_direction_base
from ..parameters import ParameterSpec
from .base import Effect


class BenchTilt(Effect):
    name = "bench_tilt"
    bench = True
    description = "tilt of the bench against the local vertical (delta, beta; fitted as its two horizontal components)"

    def parameters(self):
        return (
            ParameterSpec("tilt_x", "arcsec", 60.0, "tilt component toward base e_x: sin(delta) cos(beta)", self.name),
            ParameterSpec("tilt_y", "arcsec", 60.0, "tilt component toward base e_y: sin(delta) sin(beta)", self.name),
        )

    def gravity_base(self, p, cov, f):
        return gravity_direction_base(p["tilt_x"], p["tilt_y"])
