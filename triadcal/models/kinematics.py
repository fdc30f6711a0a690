"""Bench kinematics: the apparent gravity in the IMU frame for a bench position.

``R_base_from_imu = Rx(axis2) . Ry(wobble) . Rz(axis1) . M`` (frames of docs/spec/bench-csv-v1.md);
:func:`gravity_in_imu` returns G of eq. 1, :func:`gravity_direction_base` and
:func:`tilt_polar` handle the bench tilt. Elementwise on floats, numpy arrays or CasADi
symbols, so the simulator and the estimators share them. Derivation/design: docs/model.md (Frames).
"""

from __future__ import annotations

from . import ops

#: The fixed mounting matrix M (IMU frame -> platform frame at zero angles).
MOUNTING = ((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0))


def gravity_direction_base(tilt_x, tilt_y):
    """Unit vector of the apparent gravity (specific force at rest) in the base frame.

    bench-csv.md: ``G (sin d cos b, sin d sin b, cos d)`` for a bench tilted by d toward
    azimuth b (the paper's eq. 1 gravity vector with its tilt, in our frame). It is
    parametrised here by its horizontal components ``tilt_x = sin d cos b`` and
    ``tilt_y = sin d sin b`` (dimensionless), which stay identifiable at d = 0 where b
    is not; :func:`tilt_polar` converts back.
    """
    return tilt_x, tilt_y, ops.sqrt(1.0 - tilt_x * tilt_x - tilt_y * tilt_y)


def tilt_polar(tilt_x, tilt_y):
    """(delta, beta) in radians from the horizontal components of the gravity direction."""
    return ops.asin(ops.sqrt(tilt_x * tilt_x + tilt_y * tilt_y)), ops.atan2(tilt_y, tilt_x)


def gravity_in_imu(axis1, axis2, f_base, wobble=0.0):
    """Apparent gravity in the IMU frame: ``R_base_from_imu^T . f_base`` (bench-csv.md).

    ``axis1``, ``axis2`` and ``wobble`` in radians (actual angles, commanded plus any
    positioning error); ``f_base`` a 3-tuple (base frame), in any unit (g here).
    Returns the 3-tuple ``(G_x, G_y, G_z)`` of eq. 1.
    """
    fx, fy, fz = f_base
    c2, s2 = ops.cos(axis2), ops.sin(axis2)
    # u = Rx(axis2)^T f
    u0 = fx
    u1 = c2 * fy + s2 * fz
    u2 = -s2 * fy + c2 * fz
    # v = Ry(wobble)^T u
    cw, sw = ops.cos(wobble), ops.sin(wobble)
    v0 = cw * u0 - sw * u2
    v1 = u1
    v2 = sw * u0 + cw * u2
    # q = Rz(axis1)^T v
    c1, s1 = ops.cos(axis1), ops.sin(axis1)
    q0 = c1 * v0 + s1 * v1
    q1 = -s1 * v0 + c1 * v1
    q2 = v2
    # G = M^T q
    return q0, q2, -q1


def fixture_rotated(g_imu, rx, ry, rz):
    """Apparent gravity in the frame of a unit turned in its fixture by the small rotation
    ``(rx, ry, rz)`` (radians, about the IMU's x, y, z axes; rotation vector ``r``)::

        G' = R(r)^T G,   R(r) ~ I + [r]x   (first order; Rodrigues' formula)

    so ``G' = G - r x G``. A fixture rotation, an encoder zero of axis 1 (``Rz`` next to the
    unit in :func:`gravity_in_imu`) or any other constant rotation of the unit against the
    platform is the same for every visit of a campaign: it enters eq. 1 as ``Ca R^T`` and the
    fit cannot tell it from the unit's own angles (docs/lab.md, "The systematic errors").
    First order is exact enough: the rotations are tens of arcseconds (1e-4 rad), whose
    second-order terms (5e-9) are below any output noise. Elementwise on floats, numpy
    arrays or CasADi symbols."""
    gx, gy, gz = g_imu
    # r x G = (ry gz - rz gy, rz gx - rx gz, rx gy - ry gx)
    return (gx - (ry * gz - rz * gy), gy - (rz * gx - rx * gz), gz - (rx * gy - ry * gx))
