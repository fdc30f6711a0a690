"""Heavy-tailed output noise: a Student-t likelihood of unit variance.

The simulator's ``heavy_tails`` noise (:class:`triadcal.models.simulate.NoiseModel`,
``heavy_tails_dof``) draws each averaged output error from a Student-t with ``nu``
degrees of freedom rescaled to the same standard deviation as the Gaussian noise. This
is its log density, for normalised residuals ``z = (W - W_model) / sigma``.

With a ``scale`` ``s`` it is a Student-t of variance ``s^2``: ``log p(z) = log t_nu(z / s) - log s``
with ``t_nu`` of unit variance (a location-scale Student-t, Lange, Little & Taylor 1989, "Robust
statistical modeling using the t distribution", JASA 84:881). The scale takes up what a unit variance
cannot: contamination, a mixture ``(1 - e) N(0, 1) + e N(0, k^2)``, has the variance
``1 + e (k^2 - 1)`` (2.2 for 5 % of 5-sigma errors) as well as heavy tails, so a unit-variance t leaves
chi2/dof near 1.4 after its refit where a free scale leaves 1.
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


def logpdf(z, nu: float, scale=1.0) -> np.ndarray:
    """Log density of a Student-t of ``nu`` dof and variance ``scale^2`` (module docstring) at
    normalised residuals ``z``; ``nu = inf`` gives the normal, ``scale`` may be an array like ``z``."""
    z = np.asarray(z, float)
    s = np.asarray(scale, float)
    if np.any(s <= 0):
        raise InputError("the Student-t's scale must be positive")
    z = z / s
    if not np.isfinite(nu):
        return -0.5 * z * z - 0.5 * np.log(2 * np.pi) - np.log(s)
    c = unit_variance_scale(nu)
    x = z / c
    return (special.gammaln((nu + 1) / 2) - special.gammaln(nu / 2) - 0.5 * np.log(nu * np.pi)
            - (nu + 1) / 2 * np.log1p(x * x / nu) - np.log(c) - np.log(s))


def profile_scale(z, nu: float) -> tuple[float, float]:
    """``(scale, log likelihood)``: the maximum-likelihood scale of :func:`logpdf` at ``nu`` for the
    residuals ``z`` (for ``nu = inf`` the RMS of ``z``, in closed form)."""
    from scipy import optimize

    z = np.asarray(z, float).reshape(-1)
    rms = float(np.sqrt(np.mean(z * z)))
    if rms <= 0:
        raise InputError("the residuals are all zero: no scale can be fitted")
    if not np.isfinite(nu):
        return rms, float(np.sum(logpdf(z, nu, rms)))
    res = optimize.minimize_scalar(lambda ls: -float(np.sum(logpdf(z, nu, np.exp(ls)))),
                                   bounds=(np.log(rms) - 5.0, np.log(rms) + 2.0), method="bounded",
                                   options={"xatol": 1e-7})
    return float(np.exp(res.x)), float(-res.fun)


#: Student-t dof tried by the profile likelihood of ``heavy_tails`` (the fit's and the diagnosis's)
NU_GRID = (2.2, 2.5, 3.0, 3.5, 4.0, 5.0, 7.0, 10.0, 20.0, 50.0)


def profile_dof(z, grid=NU_GRID) -> tuple[float, float, dict]:
    """``(nu, scale, {nu: log likelihood})``: the dof of ``grid`` with the largest likelihood, the
    scale profiled at each (:func:`profile_scale`); the first of equal maxima."""
    fits = {float(nu): profile_scale(z, float(nu)) for nu in grid}
    nu = max(fits, key=lambda k: fits[k][1])
    return nu, fits[nu][0], {k: f[1] for k, f in fits.items()}


def normal_scores(z, nu: float, scale=1.0) -> np.ndarray:
    """``Phi^-1(F_t(z / scale))``: residuals mapped through the Student-t CDF (``nu`` dof, variance
    ``scale^2``) to the standard normal (standard normal when the residuals follow that Student-t)."""
    from scipy import stats

    z = np.asarray(z, float) / np.asarray(scale, float)
    if not np.isfinite(nu):
        return z
    c = unit_variance_scale(nu)
    x = z / c
    # symmetric form keeps precision in both tails
    return np.sign(x) * stats.norm.isf(stats.t.sf(np.abs(x), nu))
