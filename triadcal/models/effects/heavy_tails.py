"""Heavy-tailed output noise: a Student-t likelihood of unit variance.

The simulator's ``heavy_tails`` noise (:class:`triadcal.models.simulate.NoiseModel`,
``heavy_tails_dof``) draws each averaged output error from a Student-t with ``nu``
degrees of freedom rescaled to the same standard deviation as the Gaussian noise. This
is its log density, for normalised residuals ``z = (W - W_model) / sigma``.
"""

from __future__ import annotations

from ...errors import InputError

import numpy as np
from scipy import special

name = "heavy_tails"
unit = "1"
description = "Student-t output noise with nu degrees of freedom and the same variance (outliers)"
TYPICAL_DOF = 3.0


def unit_variance_scale(nu: float) -> float:
    """Scale of a Student-t with ``nu`` dof whose variance is 1: sqrt((nu - 2) / nu)."""
    if nu <= 2:
        raise InputError("a Student-t needs nu > 2 for a finite variance")
    return float(np.sqrt((nu - 2.0) / nu))


def logpdf(z, nu: float) -> np.ndarray:
    """Log density of a unit-variance Student-t (nu dof) at normalised residuals ``z``;
    ``nu = inf`` gives the standard normal."""
    z = np.asarray(z, float)
    if not np.isfinite(nu):
        return -0.5 * z * z - 0.5 * np.log(2 * np.pi)
    c = unit_variance_scale(nu)
    x = z / c
    return (special.gammaln((nu + 1) / 2) - special.gammaln(nu / 2) - 0.5 * np.log(nu * np.pi)
            - (nu + 1) / 2 * np.log1p(x * x / nu) - np.log(c))


def normal_scores(z, nu: float) -> np.ndarray:
    """``Phi^-1(F_t(z))``: residuals mapped through the unit-variance Student-t CDF to the
    standard normal (standard normal when the residuals follow that Student-t)."""
    from scipy import stats

    z = np.asarray(z, float)
    if not np.isfinite(nu):
        return z
    c = unit_variance_scale(nu)
    x = z / c
    # symmetric form keeps precision in both tails
    return np.sign(x) * stats.norm.isf(stats.t.sf(np.abs(x), nu))
