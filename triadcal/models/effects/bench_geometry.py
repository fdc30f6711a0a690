"""Non-orthogonality of the bench's two axes: the angle between axis 2 and axis 1 is off 90°.

In the bench's kinematics (bench-csv.md, :func:`triadcal.models.kinematics.gravity_in_imu`)
``R_base_from_imu = Rx(axis2) . Ry(w) . Rz(axis1) . M``, the rotation ``Ry(w)`` between the two
axes is the wobble of axis 1; a constant part ``w0`` of it is the non-orthogonality of the axes
(an error of the bench, stated in its calibration certificate). A rotation about the platform's
x axis at that place would commute with ``Rx(axis2)`` and is an encoder zero of axis 2, one
about z is an encoder zero of axis 1: ``Ry`` is the one rotation between the axes that is
neither. Unlike those (which the fit cannot tell from the bench tilt and from the unit's own
angles), ``w0`` turns with axis 2 and leaves its trace in the residuals of a plan with several
axis-2 angles: the fit measures it (docs/lab.md, docs/model.md).
"""

from __future__ import annotations

from ..parameters import ParameterSpec
from .base import Effect


class BenchNonorthogonality(Effect):
    name = "bench_nonorthogonality"
    bench = True
    description = ("non-orthogonality of the bench's two axes: a constant rotation about the platform's y axis "
                   "between axis 2 and axis 1 (arcsec)")

    def parameters(self):
        return (ParameterSpec("bench_nonorth", "arcsec", 10.0,
                              "angle between the bench's axes minus 90 deg (rotation Ry between axis 2 and axis 1)",
                              self.name),)

    def wobble(self, p, cov, wobble):
        """``w = w_visit + w0`` (rad)."""
        return wobble + p["bench_nonorth"]
