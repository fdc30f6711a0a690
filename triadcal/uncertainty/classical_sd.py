"""The standard deviation of the classical angles (eq. 2-3) for a plan and the bench's noise
model: exact first-order propagation (:func:`classical_angle_sd`) and the default plan's closed
form (:func:`classical_angle_sd_default_plan`); eq. 4 relates to it (docs/classical.md, "How
this relates to the paper's eq. 4")."""

from __future__ import annotations

import math
from typing import Mapping, Optional

import numpy as np

from ..estimation.classical import pairing
from ..models.campaign import DEFAULT_PLAN, up_axis_label
from ..models.kinematics import gravity_in_imu
from ..models.sensor import ANGLE_NAMES, AXES
from ..models.units import ARCSEC


def gravity_derivatives(axis1_deg, axis2_deg) -> np.ndarray:
    """Derivatives of the IMU-frame gravity direction (level bench) with respect to the
    bench errors of the simulator: ``(n, 3, 3)`` = visit x IMU axis x (axis-1 error,
    axis-2 error, wobble), per radian. Exact derivatives of
    :func:`triadcal.models.kinematics.gravity_in_imu` (CasADi automatic differentiation)."""
    import casadi as ca

    e = ca.SX.sym("e", 3)
    a1 = ca.SX.sym("a1")
    a2 = ca.SX.sym("a2")
    g = ca.vertcat(*gravity_in_imu(a1 + e[0], a2 + e[1], (0.0, 0.0, 1.0), e[2]))
    f = ca.Function("dg", [a1, a2, e], [ca.jacobian(g, e)])
    out = [np.array(f(np.radians(x1), np.radians(x2), np.zeros(3)))
           for x1, x2 in zip(np.atleast_1d(axis1_deg), np.atleast_1d(axis2_deg))]
    return np.array(out)


def classical_angle_sd(plan: Optional[Mapping[str, tuple]] = None, *, Q_V2s: float, tau_s: float,
                       sigma_position_arcsec: float = 0.0, sigma_wobble_arcsec: float = 0.0,
                       K_g_per_V: float = 1.0, gravity_g: float = 1.0) -> dict:
    """Standard deviation (arcsec) of each classical angle estimate at one setpoint.

    The simulator's noise model (models/simulate.py): white output noise of variance
    ``Q / tau`` on every mean output, independent positioning errors ``sigma_1`` of each
    bench axis and a wobble ``sigma_2`` of axis 1 about base ``e_y`` at every visit. To
    first order (small angles; docs/classical.md)::

        Var(Ca_ab) = sum_i c_bi^2 [ K_a^2 Q / (G^2 tau) + sigma_1^2 (d1_ia^2 + d2_ia^2) + sigma_2^2 dw_ia^2 ]

    with ``c_bi`` the eq. 2-3 coefficients (+-1/4 for the default plan) and ``d*_ia`` the
    derivative of gravity component ``a`` with respect to each bench error at visit
    ``i``. For the default 12-position plan this is ``sqrt(n^2 + sigma_2^2)/2`` for Ca_xy
    and ``sqrt(n^2 + sigma_1^2)/2`` for the five others, ``n = K sqrt(Q/tau)/G`` in arcsec.
    """
    plan = dict(DEFAULT_PLAN if plan is None else plan)
    a1 = np.array([v[0] for v in plan.values()], float)
    a2 = np.array([v[1] for v in plan.values()], float)
    pair = pairing(up_axis_label(a1, a2), "plan")
    d = gravity_derivatives(a1, a2)                              # (n, 3, 3)
    noise_var = (K_g_per_V / gravity_g) ** 2 * Q_V2s / tau_s     # rad^2
    s1, s2 = sigma_position_arcsec * ARCSEC, sigma_wobble_arcsec * ARCSEC
    out = {}
    for ab in ANGLE_NAMES:
        a, b = AXES.index(ab[0]), AXES.index(ab[1])
        c2 = pair.difference[b] ** 2
        per_visit = noise_var + s1 ** 2 * (d[:, a, 0] ** 2 + d[:, a, 1] ** 2) + s2 ** 2 * d[:, a, 2] ** 2
        out[f"Ca_{ab}"] = float(math.sqrt(np.sum(c2 * per_visit)) / ARCSEC)
    return out


def classical_angle_sd_default_plan(*, Q_V2s: float, tau_s: float, sigma_position_arcsec: float = 0.0,
                                    sigma_wobble_arcsec: float = 0.0, K_g_per_V: float = 1.0,
                                    gravity_g: float = 1.0) -> dict:
    """Closed form of :func:`classical_angle_sd` for the default 12-position plan (arcsec).

    Only rotations about the third IMU axis ``c`` (neither ``a`` nor ``b``) move gravity
    along ``a`` while ``b`` is vertical. With Y vertical (P01-P04) axis 2 lies along X
    and the wobble axis along Z; with X or Z vertical axis 1 (Y) and axis 2 are both
    horizontal and the wobble axis is vertical. Hence Ca_xy sees the wobble, the five
    other angles one bench axis (sigma_1), each through four visits weighted 1/4.
    """
    n2 = (K_g_per_V / gravity_g) ** 2 * Q_V2s / tau_s / ARCSEC ** 2
    out = {}
    for ab in ANGLE_NAMES:
        s = sigma_wobble_arcsec if ab == "xy" else sigma_position_arcsec
        out[f"Ca_{ab}"] = 0.5 * math.sqrt(n2 + s * s)
    return out
