"""Least-squares fits of a subset of the full model (every switchable effect compiled once per
campaign; a model is a subset of its parameters, the others held at 0), and the linear
algebra the tests share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import numpy as np
from scipy import special

from ...estimation.joint import (
    JointProblem,
    levenberg_marquardt,
    scaled_covariance,
)


# ----------------------------------------------------------------------------------
# fitting a subset of the full model
# ----------------------------------------------------------------------------------
class _Subset:
    """The full problem restricted to ``names`` (others held at ``base``), with row scaling
    ``scale`` (normalised residuals divided by it, e.g. an added variance)."""

    def __init__(self, full: JointProblem, names: Sequence[str], base: np.ndarray, scale=None):
        self.full = full
        self.names = tuple(names)
        self.cols = np.array([full.index[n] for n in self.names], int)
        self.base = np.array(base, float)
        self.scale = None if scale is None else np.asarray(scale, float)

    def embed(self, x):
        z = self.base.copy()
        z[self.cols] = x
        return z

    def residuals_and_jacobian(self, x):
        r, J = self.full.residuals_and_jacobian(self.embed(x))
        J = J[:, self.cols]
        if self.scale is not None:
            r, J = r / self.scale, J / self.scale[:, None]
        return r, J


@dataclass
class FitState:
    """A least-squares fit of a subset of the full model at its optimum."""

    names: tuple
    x_full: np.ndarray           # full parameter vector, reporting units
    r: np.ndarray                # normalised residuals (3n,), divided by the noise scale s
    J: np.ndarray                # dr/dx of the fitted parameters (3n, p), same scaling
    cov: np.ndarray              # covariance of the fitted parameters, reporting units
    chi2: float                  # sum of squared normalised residuals (before the scale s)
    dof: int
    s: float                     # noise scale: 1 with known noise, sqrt(chi2/dof) otherwise
    converged: bool
    var_scale: Optional[np.ndarray] = None   # per-observation variance factor (position_error)
    nu: float = math.inf                     # Student-t dof (heavy_tails)
    extra_params: dict = field(default_factory=dict)
    #: the noise model's whitening of columns in normalised units (``flicker_noise``: ``L^-1``);
    #: None: divided by ``sqrt(var_scale)`` when that is set, else as they are
    whiten: Optional[Callable] = None
    #: tests the refit makes of its own noise model where only it knows the covariance
    #: (``position_error``: ``replicates``, generic.replicate_variance_test)
    extra_tests: dict = field(default_factory=dict)

    def whitened(self, B: np.ndarray) -> np.ndarray:
        """Columns ``B`` (normalised units, rows as ``r``) on the scale of the standardised residuals
        the noise model makes of ``r`` (``r / sqrt(var_scale)``, or the GLS-whitened ones)."""
        B = B / self.s
        if self.whiten is not None:
            return self.whiten(B)
        if self.var_scale is not None:
            return B / np.sqrt(self.var_scale)[:, None]
        return B

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    def u(self) -> dict:
        return {n: float(math.sqrt(max(self.cov[i, i], 0.0))) for i, n in enumerate(self.names)}

    def value(self, full: JointProblem) -> dict:
        return {n: float(self.x_full[full.index[n]]) for n in self.names}


def _fit(full: JointProblem, names, x_start: np.ndarray, noise_known: bool, scale=None) -> FitState:
    sub = _Subset(full, names, x_start, scale)
    sol = levenberg_marquardt(sub, x_start[sub.cols], max_iter=60)
    x_full = sub.embed(sol.x)
    r, J = sol.r, sol.J
    n_obs, p = r.size, len(names)
    dof = n_obs - p
    chi2 = float(r @ r)
    s = 1.0 if noise_known else math.sqrt(chi2 / max(dof, 1))
    cov = scaled_covariance(J) * s * s
    return FitState(tuple(names), x_full, r / s, J / s, cov, chi2, dof, s, sol.converged,
                    var_scale=None if scale is None else np.asarray(scale) ** 2)


def whitened_state(names, x_full: np.ndarray, sol, whitening, noise_known: bool) -> FitState:
    """The :class:`FitState` of a GLS fit (``sol``: residuals and Jacobian whitened by
    ``whitening.apply``, whose factor's diagonal is ``whitening.diag()``): ``r = r_w diag(L)``,
    ``var_scale = diag(L)^2``, so that ``r / sqrt(var_scale)`` are the whitened residuals and the
    Gaussian log-likelihood of the sequential (Cholesky) decomposition is exact with ``-log diag(L)``."""
    rw, Jw = sol.r, sol.J
    chi2 = float(rw @ rw)
    dof = rw.size - len(names)
    s = 1.0 if noise_known else math.sqrt(chi2 / max(dof, 1))
    Ld = np.asarray(whitening.diag(), float).reshape(-1)
    return FitState(tuple(names), x_full, rw / s * Ld, Jw / s * Ld[:, None], scaled_covariance(Jw) * s * s, chi2, dof, s,
                    sol.converged, var_scale=Ld ** 2, whiten=whitening.apply)


def _chol(C):
    """A square root ``L`` of a covariance, ``L L^T = C``, that does not depend on the parameters'
    units: the Cholesky factor of the correlation matrix, scaled back by the standard deviations
    (an eigen-decomposition of the correlation matrix, negative eigenvalues clipped, where it is not
    positive definite). Taken on ``C`` itself, the factor lost its small variances: a file in counts
    (K of 6e-5 g/count, so var K of 1e-21 beside angles' arcsec^2) gave Laplace draws whose
    residuals blew up (Pareto k inf, delta elpd nan) where the same data in volts did not."""
    C = (np.asarray(C, float) + np.asarray(C, float).T) / 2
    d = np.sqrt(np.clip(np.diag(C), 0.0, None))
    d = np.where(d > 0, d, 1.0)
    R = C / np.outer(d, d)
    try:
        Lr = np.linalg.cholesky(R)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(R)
        Lr = V * np.sqrt(np.clip(w, 0.0, None))
    return d[:, None] * Lr


def _hat_q(J):
    """Orthonormal basis of the column space of J (the fit's hat matrix is Q Q')."""
    d = np.linalg.norm(J, axis=0)
    keep = d > 0
    Q, R = np.linalg.qr(J[:, keep] / d[keep])
    diag = np.abs(np.diag(R))
    return Q[:, diag > 1e-10 * max(diag.max(), 1e-300)]


def _chi2_logsf(S, k):
    """log P(chi2_k > S), with the Wilson-Hilferty normal form where the tail underflows.

    ``special.chdtrc`` is the function ``stats.chi2.sf`` evaluates (the same numbers), without the
    distribution object's argument handling: 2 us a call instead of 230 us, and the diagnosis asks
    it some 3 000 times a campaign."""
    v = float(special.chdtrc(k, S))
    if v > 0.0:
        return math.log(v)
    z = ((S / k) ** (1.0 / 3.0) - (1.0 - 2.0 / (9.0 * k))) / math.sqrt(2.0 / (9.0 * k))
    return float(special.log_ndtr(-z))
