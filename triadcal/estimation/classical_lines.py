"""The paper's linear thermal correction of the classical method (a weighted straight line per quantity,
Birge-scaled) and the per-setpoint quantities in their reporting units. Moved here from classical.py
(2026-12-02, behaviour-neutral) when that module passed 600 lines; classical.py re-exports them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..models.units import ARCSEC, PPM, UG, scale_factor_unit


# --------------------------------------------------------------------------------------
# the thermal line
# --------------------------------------------------------------------------------------
@dataclass
class Line:
    """Weighted straight line ``y = a + b (T - T_ref)`` (or a weighted mean when ``slope`` is False)."""

    coef: np.ndarray    # (a,) or (a, b)
    cov: np.ndarray     # covariance after Birge scaling
    chi2: float
    dof: int
    birge: float        # factor applied to the covariance

    @property
    def chi2_dof(self) -> Optional[float]:
        return self.chi2 / self.dof if self.dof > 0 else None


def thermal_line(T: np.ndarray, y: np.ndarray, var: np.ndarray, T_ref: float, slope: bool) -> Line:
    """Weighted least squares of ``y`` against ``T - T_ref`` with weights ``1/var``.

    The covariance ``(X^T W X)^-1`` is multiplied by ``max(1, chi2/dof)`` (Birge ratio).
    When no variance is known (all zero), equal weights are used and the covariance is
    scaled by ``chi2/dof`` (the scatter alone).
    """
    X = np.column_stack([np.ones_like(T), T - T_ref]) if slope else np.ones((len(T), 1))
    known = bool(np.all(var > 0))
    wts = 1.0 / var if known else np.ones_like(y)
    A = X.T @ (wts[:, None] * X)
    cov = np.linalg.inv(A)
    coef = cov @ (X.T @ (wts * y))
    r = y - X @ coef
    chi2 = float(np.sum(wts * r * r))
    dof = len(y) - X.shape[1]
    if dof > 0:
        birge = max(1.0, chi2 / dof) if known else chi2 / dof
    else:
        birge = 1.0 if known else 0.0   # nothing to scale by: no uncertainty can be given
    return Line(coef, cov * birge, chi2, dof, birge)


def _line_p(line: Line, var: np.ndarray) -> Optional[float]:
    """P(chi2_dof > the line's chi2) under the per-setpoint uncertainties, or None when they are
    not known (an unweighted line) or the line has no residual dof."""
    from scipy import stats

    if line.dof <= 0 or not np.all(var > 0):
        return None
    return float(stats.chi2.sf(line.chi2, line.dof))



def _reporting(name: str, value: float, u: float, output_unit: str) -> dict:
    """One per-setpoint quantity in its reporting unit (arcsec for angles)."""
    if name.startswith("Ca_"):
        return {"value": float(value / ARCSEC), "u": float(u / ARCSEC), "unit": "arcsec"}
    if name.startswith("K_"):
        return {"value": float(value), "u": float(u), "unit": scale_factor_unit(output_unit)}
    return {"value": float(value), "u": float(u), "unit": "g"}


def _to_reporting(name: str, line: Line, slope: bool, output_unit: str):
    """Names, (value, u, unit) and covariance (reporting units) of a thermal line's result."""
    a = line.coef[0]
    if name.startswith("Ca_"):
        f = np.array([1 / ARCSEC, 1 / ARCSEC])
        units = ("arcsec", "arcsec/degC")
        Jm = np.diag(f[: len(line.coef)])
        coef = line.coef * f[: len(line.coef)]
    elif name.startswith("K_"):
        units = (scale_factor_unit(output_unit), "ppm/degC")
        if slope:
            b = line.coef[1]
            coef = np.array([a, b / a / PPM])
            Jm = np.array([[1.0, 0.0], [-b / a ** 2 / PPM, 1 / a / PPM]])
        else:
            coef, Jm = np.array([a]), np.eye(1)
    else:
        units = ("g", "ug/degC")
        f = np.array([1.0, 1.0 / UG])
        Jm = np.diag(f[: len(line.coef)])
        coef = line.coef * f[: len(line.coef)]
    cov = Jm @ line.cov @ Jm.T
    u = np.sqrt(np.diag(cov))
    names = [name, name + "_tempco"][: len(coef)]
    return names, list(zip(coef, u, units)), cov


def _block_diag(mats):
    n = sum(m.shape[0] for m in mats)
    out = np.zeros((n, n))
    k = 0
    for m in mats:
        s = m.shape[0]
        out[k:k + s, k:k + s] = m
        k += s
    return out
