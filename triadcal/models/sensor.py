"""The measurement equation of one accelerometer triad (seed paper, eq. 1).

    K_a W_a = sum_b Ca_ab G_b + S_a,    a, b in {x, y, z}

``Ca`` is the direction-cosine matrix of the sensing axes in the orthogonal IMU frame;
each row is a unit vector, its off-diagonal elements are the small orientation
angles (radians here, arcseconds in results).
"""

from __future__ import annotations

from . import ops

AXES = ("x", "y", "z")
#: the six off-diagonal elements, in the order of the result files
ANGLE_NAMES = ("xy", "xz", "yx", "yz", "zx", "zy")


def dcm_row(off1, off2):
    """Row of Ca from its two off-diagonal elements (eq. 1: each row is a unit vector).

    Returns ``(diagonal, off1, off2)`` with ``diagonal = sqrt(1 - off1^2 - off2^2)``.
    """
    return ops.sqrt(1.0 - off1 * off1 - off2 * off2), off1, off2


def dcm(angles):
    """The full Ca as a 3x3 nested tuple from a mapping ``{'xy': .., 'xz': .., ...}`` (eq. 1)."""
    rows = []
    for a in AXES:
        others = [b for b in AXES if b != a]
        d, o1, o2 = dcm_row(angles[a + others[0]], angles[a + others[1]])
        row = {a: d, others[0]: o1, others[1]: o2}
        rows.append(tuple(row[b] for b in AXES))
    return tuple(rows)


def sensed_acceleration(row, g_imu):
    """Projection of the apparent acceleration on one sensing axis: ``sum_b Ca_ab G_b`` (eq. 1)."""
    return row[0] * g_imu[0] + row[1] * g_imu[1] + row[2] * g_imu[2]


def output(sensed, scale, bias):
    """Output of one accelerometer, eq. 1 solved for W: ``W = (Ca.G + S) / K``."""
    return (sensed + bias) / scale


def calibrated_acceleration(K, S, Ca, w):
    """Apply a calibration to readings: ``A_IMU = Ca^-1 (K W - S)`` (paper, introduction).

    numpy: ``K``, ``S`` length-3, ``Ca`` 3x3, ``w`` (..., 3) readings; returns (..., 3) in g.
    CasADi (any argument symbolic): ``K``, ``S``, ``w`` 3-vectors, ``Ca`` a 3x3 matrix or
    nested rows (as :func:`dcm` returns); returns the 3-vector.
    """
    elements = [v for row in Ca for v in row] if isinstance(Ca, (tuple, list)) else [Ca]
    if ops.is_symbolic(K, S, w, *elements):
        import casadi as ca

        if isinstance(Ca, (tuple, list)):
            Ca = ca.vertcat(*[ca.horzcat(*row) for row in Ca])
        return ca.solve(Ca, K * w - S)
    import numpy as np

    a_sensor = np.asarray(w, float) * np.asarray(K, float) - np.asarray(S, float)
    # one Ca for every reading: one solve for all of them (a_sensor @ Ca^-T), not one per row
    flat = a_sensor.reshape(-1, 3)
    return np.linalg.solve(np.asarray(Ca, float), flat.T).T.reshape(a_sensor.shape)
