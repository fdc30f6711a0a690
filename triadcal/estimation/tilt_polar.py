"""The bench tilt's polar form, derived from its two components: ``tilt_delta`` (the tilt's size,
arcsec) and ``tilt_beta`` (its direction, deg), :func:`triadcal.models.kinematics.tilt_polar`.
Their uncertainties by the delta method (GUM 5.1.2) from the covariance of ``tilt_x``, ``tilt_y``;
with the lab's systematic errors (a :class:`~triadcal.uncertainty.typeb.TypeB` of the fit), each
also gets its budget -- the Type A row from the fit's own covariance and one row per source with
sensitivity ``g . c_s`` (``g`` the gradient of the polar value, ``c_s`` the components'
sensitivities to source s, GUM 5.1.3) -- so U and k as every parameter of the result."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from ..models.kinematics import tilt_polar
from ..models.units import ARCSEC, DEG
from .result import ParameterValue


def tilt_polar_values(x: np.ndarray, cov: np.ndarray, index: dict, tb=None, cov_a: Optional[np.ndarray] = None,
                      dof_a: Optional[float] = None, type_a: str = "fit") -> dict:
    """``tilt_delta`` (arcsec) and ``tilt_beta`` (deg) with delta-method uncertainties from ``cov``
    (reporting units, the combined covariance); with ``tb`` (the fit's Type B sensitivities) and
    ``cov_a`` (its Type A covariance), their budgets too (``tilt_beta``'s only when the tilt is not
    0, where its direction is undefined)."""
    i, j = index["tilt_x"], index["tilt_y"]
    tx, ty = x[i] * ARCSEC, x[j] * ARCSEC
    delta, beta = tilt_polar(tx, ty)
    r = math.hypot(tx, ty)
    C = cov[np.ix_([i, j], [i, j])] * ARCSEC ** 2
    grads = {}
    if r > 0:
        gd = np.array([tx, ty]) / r / math.sqrt(max(1 - r * r, 1e-300))
        gb = np.array([-ty, tx]) / (r * r)
        ud = math.sqrt(gd @ C @ gd)
        ub = math.sqrt(gb @ C @ gb)
        # per arcsec of tilt_x, tilt_y: delta in arcsec, beta in deg
        grads = {"tilt_delta": (gd, "arcsec"), "tilt_beta": (gb * ARCSEC / DEG, "deg")}
    else:
        ud, ub = math.sqrt(np.trace(C) / 2), math.pi
    out = {"tilt_delta": ParameterValue(float(delta) / ARCSEC, ud / ARCSEC, "arcsec"),
           "tilt_beta": ParameterValue(float(beta) / DEG, min(ub, math.pi) / DEG, "deg")}
    if tb is None or cov_a is None or not grads or "tilt_x" not in tb.names or "tilt_y" not in tb.names:
        return out
    from ..uncertainty.typeb import TypeB, parameter_fields

    cols = [tb.names.index("tilt_x"), tb.names.index("tilt_y")]
    Ca = cov_a[np.ix_([i, j], [i, j])]
    names = tuple(grads)
    c = np.column_stack([tb.c[:, cols] @ grads[n][0] for n in names])
    derived = TypeB(list(tb.sources), names, c)
    for n in names:
        g, unit = grads[n]
        if n == "tilt_beta" and out[n].u >= 180.0 - 1e-9:
            continue                                   # a direction the data do not give
        u_a = math.sqrt(max(float(g @ Ca @ g), 0.0))
        out[n] = ParameterValue(out[n].value, out[n].u, unit,
                                parameter_fields(derived.budget(n, unit, u_a, dof_a, type_a)))
    return out
