"""Log-posterior targets for emcee: the joint model over a campaign (:class:`LogPosterior`, all
walkers in one compiled CasADi call) and any residual function with Gaussian priors
(:class:`ResidualTarget`), optionally in sheared coordinates (:func:`conditional_shear`).
Derivations in docs/posterior.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Optional, Sequence

import casadi as ca
import numpy as np

from ...errors import InputError, UnknownName
from ...models.campaign import Campaign
from ...models.model import Covariates, Model
from ..joint import (
    COVARIATES,
)
from ..priors import Prior, prior_arrays
from ..result import Z95
from .compile import _compile


def _visit_functions(model: Model, nu: float = math.inf, quantisation: Optional[tuple] = None,
                     whitened: bool = False):
    """Per-visit pointwise ``-1/2 r^2`` (3 axes) of eq. 1, symbolic in the parameters
    (reporting units) and the visit's covariates, observation and inverse sigma; with a finite
    ``nu`` the unit-variance Student-t kernel ``-(nu+1)/2 log(1 + r^2 / ((nu-2)))`` instead
    (``heavy_tails``, :func:`triadcal.models.effects.heavy_tails.logpdf` without its constant).
    ``quantisation``: None, or the structure ``(form, count)`` of the expected quantisation error
    (:func:`triadcal.models.effects.quantisation.form_of`): the model outputs are then
    ``W + e(W; q, sigma_sample)`` (:func:`~triadcal.models.effects.quantisation.error_expression`),
    and the function takes two more inputs, the visit's per-sample SDs (3) and the LSB q.
    ``whitened``: the visit's normalised residuals are multiplied by ``L_i^-1`` (one more input, 9
    numbers, column-major), the inverse Cholesky factor of their 3 x 3 covariance (the bench's errors
    on oblique poses, :func:`triadcal.estimation.whitening.bench_whitening`)."""
    npar = len(model.names)
    x = ca.SX.sym("x", npar)
    c = ca.SX.sym("c", len(COVARIATES))
    g = ca.SX.sym("g")
    wo = ca.SX.sym("w_obs", 3)
    isg = ca.SX.sym("inv_sigma", 3)
    p = {s.name: x[i] * s.to_internal for i, s in enumerate(model.parameters)}
    cov = Covariates(axis1=c[0], axis2=c[1], temp=(c[2], c[3], c[4]), temp_rate=(c[5], c[6], c[7]),
                     branch=c[8], time_s=c[9])
    w = ca.vertcat(*model.predict(p, cov, g))
    inputs = [x, c, g, wo, isg]
    if quantisation is not None:
        from ...models.effects.quantisation import error_expression

        sq, q = ca.SX.sym("sigma_sample", 3), ca.SX.sym("q")
        w = w + error_expression(w, q, sq, *quantisation)
        inputs += [sq, q]
    r = (wo - w) * isg
    if whitened:
        lw = ca.SX.sym("whiten", 9)
        inputs.append(lw)
        r = ca.mtimes(ca.reshape(lw, 3, 3), r)
    if math.isfinite(nu):
        return ca.Function("visit_loglik", inputs, [-0.5 * (nu + 1.0) * ca.log1p(r * r / (nu - 2.0))])
    return ca.Function("visit_loglik", inputs, [-0.5 * r * r])


class LogPosterior:
    """``log p(z | data)`` up to a constant, in whitened coordinates ``x = x0 + L z``.

    ``__call__`` takes an (m, d) array of walkers and returns (m,) log-posteriors;
    :meth:`pointwise` gives the pointwise log-likelihood per visit and axis (with the
    Gaussian normalisation), for LOO.

    ``quantisation``: None, or ``(q, sigma_sample)``, the LSB of a digital output and the per-sample
    SDs (3,) or (n, 3), both held fixed: the model outputs are then ``W + e(W; q, sigma_sample)``, the
    expected visit-mean error of the rounding (:mod:`triadcal.models.effects.quantisation`).
    """

    def __init__(self, campaign: Campaign, model: Model, sigma: np.ndarray, priors: Mapping[str, Prior],
                 x0: np.ndarray, L: np.ndarray, block: int, nu: float = math.inf,
                 quantisation: Optional[tuple] = None, whitening=None):
        from ...models.effects.heavy_tails import logpdf

        self.model = model
        self.nu = float(nu)
        self.names = model.names
        self.d = len(self.names)
        self.n = campaign.n_visits
        self.block = int(block)
        self.x0 = np.asarray(x0, float)
        self.L = np.asarray(L, float)
        mu, sd, self.low, self.high = prior_arrays(priors, self.names)
        C = campaign.covariate_matrix()
        self.sigma = np.asarray(sigma, float)
        self.args = [ca.DM(self.x0), ca.DM(self.L), ca.DM(C), campaign.gravity_g, ca.DM(campaign.w.T),
                     ca.DM(1.0 / self.sigma.T), ca.DM(mu), ca.DM(1.0 / sd)]
        self.quantisation_form = None
        if quantisation is not None:
            from ...models.effects.quantisation import form_of

            q, s_sample = float(quantisation[0]), np.broadcast_to(np.asarray(quantisation[1], float), (self.n, 3))
            self.quantisation_form = form_of(q, s_sample)
            self.args += [ca.DM(np.ascontiguousarray(s_sample.T)), q]
        self.log_norm = float(logpdf(0.0, self.nu)) - np.log(self.sigma)    # (n, 3)
        self.whitened = whitening is not None
        if self.whitened:
            # per visit L_i^-1 (column-major, 9 x n); the density of the whitened residual of output a is
            # conditional on the visit's earlier outputs, its scale sigma_a L_i,aa
            Linv = np.linalg.inv(whitening.L)
            self.args += [ca.DM(np.ascontiguousarray(np.swapaxes(Linv, 1, 2).reshape(self.n, 9).T))]
            self.log_norm = self.log_norm - np.log(whitening.diag())
        self._key = (model.effect_names, model.reference_temperature_C, self.n, self.block, self.nu,
                     self.quantisation_form, self.whitened)
        self.f_lp, self.compiled = _compile(("lp",) + self._key, self._build_lp)
        self._f_pw = None
        self.evaluations = 0

    def _symbols(self):
        d, n, m = self.d, self.n, self.block
        Z = ca.MX.sym("z", d, m)
        syms = [ca.MX.sym("x0", d), ca.MX.sym("L", d, d), ca.MX.sym("cov", len(COVARIATES), n), ca.MX.sym("g"),
                ca.MX.sym("w_obs", 3, n), ca.MX.sym("inv_sigma", 3, n), ca.MX.sym("mu", d), ca.MX.sym("inv_sd", d)]
        # quantisation: the per-sample SDs (3 x n) and the LSB q, after the others
        extra = [ca.MX.sym("sigma_sample", 3, n), ca.MX.sym("q")] if self.quantisation_form is not None else []
        if self.whitened:
            extra.append(ca.MX.sym("whiten", 9, n))
        return Z, syms, extra

    def _build_lp(self) -> ca.Function:
        visit = _visit_functions(self.model, self.nu, self.quantisation_form, self.whitened)
        Z, (x0, L, C, g, W, IS, mu, isd), extra = self._symbols()
        xs = ca.MX.sym("x", self.d)
        ll = ca.sum2(ca.sum1(visit.map(self.n, "serial")(xs, C, g, W, IS, *extra)))
        lprior = -0.5 * ca.sumsqr((xs - mu) * isd)
        walker = ca.Function("walker_logpost", [xs, C, g, W, IS, mu, isd, *extra], [ll + lprior])
        X = ca.repmat(x0, 1, self.block) + ca.mtimes(L, Z)
        out = walker.map(self.block, "serial")(X, C, g, W, IS, mu, isd, *extra)
        return ca.Function("triadcal_logpost", [Z, x0, L, C, g, W, IS, mu, isd, *extra], [out])

    def _build_pw(self) -> ca.Function:
        visit = _visit_functions(self.model, self.nu, self.quantisation_form, self.whitened)
        Z, (x0, L, C, g, W, IS, mu, isd), extra = self._symbols()
        xs = ca.MX.sym("x", self.d)
        pw = ca.vec(visit.map(self.n, "serial")(xs, C, g, W, IS, *extra))    # visit-major: 3 per visit
        walker = ca.Function("walker_pointwise", [xs, C, g, W, IS, *extra], [pw])
        X = ca.repmat(x0, 1, self.block) + ca.mtimes(L, Z)
        out = walker.map(self.block, "serial")(X, C, g, W, IS, *extra)
        return ca.Function("triadcal_pointwise", [Z, x0, L, C, g, W, IS, mu, isd, *extra], [out])

    def to_x(self, z: np.ndarray) -> np.ndarray:
        """Whitened -> reporting units; ``z`` (..., d)."""
        return self.x0 + np.asarray(z) @ self.L.T

    def _blocks(self, f, z: np.ndarray, args: Optional[Sequence] = None) -> np.ndarray:
        """``f`` (mapped over ``block`` columns) on the rows of ``z`` in blocks, the last one
        padded; ``args`` after the block (default: the target's data)."""
        args = self.args if args is None else args
        z = np.atleast_2d(np.asarray(z, float))
        m = len(z)
        out = []
        for k in range(0, m, self.block):
            chunk = z[k:k + self.block]
            pad = self.block - len(chunk)
            if pad:
                chunk = np.vstack([chunk, np.repeat(chunk[-1:], pad, axis=0)])
            v = np.asarray(f(chunk.T, *args))
            out.append(v[:, :self.block - pad] if pad else v)
        return np.hstack(out)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        z = np.atleast_2d(z)
        self.evaluations += len(z)
        lp = self._blocks(self.f_lp, z)[0]
        x = self.to_x(z)
        inside = np.all((x > self.low) & (x < self.high), axis=1)
        lp = np.where(inside & np.isfinite(lp), lp, -np.inf)
        return lp

    def pointwise(self, z: np.ndarray) -> np.ndarray:
        """Pointwise log-likelihood ``log N(w_obs | w_model, sigma)`` (or the unit-variance
        Student-t of ``nu`` dof) per draw, visit and axis:
        shape (m, n, 3)."""
        if self._f_pw is None:
            self._f_pw, _ = _compile(("pw",) + self._key, self._build_pw)
        v = self._blocks(self._f_pw, z)              # (3 n, m)
        return v.T.reshape(-1, self.n, 3) + self.log_norm[None]


@dataclass
class ResidualTarget:
    """A posterior target defined by normalised residuals, for models other than the bench's eq. 1
    (e.g. the gravity-norm model of :mod:`triadcal.estimation.raw`).

    ``residual``: a CasADi function ``r = f(x, *data)`` of the parameter vector ``x`` (reporting
    units, order of ``names``) and numeric ``data`` arguments, giving the column of residuals
    divided by their standard deviations (``sigma``, in the observations' unit), so that the
    log-likelihood is ``-1/2 r^T r`` (Gaussian noise, known ``sigma``). ``priors``: a
    :class:`Prior` per name. ``x_ls``, ``cov_ls``: the least-squares optimum (start of the MAP
    search, then of the walkers through the Laplace approximation) and its covariance (the
    least-squares intervals, unless ``ls_intervals`` gives them, e.g. Student-t ones).
    ``obs_dim``/``obs_name``: names of the observation axis and of the log-likelihood variable in
    the InferenceData; ``observed``: optional ``{name: (dims, array, attrs)}`` for its
    ``observed_data`` group, with ``obs_coords``.

    ``transform`` (optional): a CasADi function ``x = T(y)`` from the coordinates the walkers
    move in to the parameters, with a constant Jacobian determinant (e.g. a shear
    ``x = (y_1 + m(y_2), y_2)``), and ``inverse`` its inverse. Priors, bounds, residuals and
    the reported draws are in ``x``; the MAP, the Laplace approximation, the whitening and the
    moves are in ``y``. A constant determinant leaves the density unchanged up to a constant,
    so the posterior is exact; a good ``T`` straightens a curved posterior (a "banana") that
    the Laplace proposal and the differential-evolution moves cannot follow.
    """

    name: str
    residual: ca.Function
    data: tuple
    names: tuple
    units: tuple
    priors: Mapping[str, Prior]
    x_ls: np.ndarray
    cov_ls: np.ndarray
    sigma: np.ndarray
    ls_intervals: Optional[Mapping[str, tuple]] = None
    obs_dim: str = "obs"
    obs_name: str = "r"
    observed: Optional[dict] = None
    obs_coords: Optional[dict] = None
    unit_serial: str = ""
    transform: Optional[ca.Function] = None
    inverse: Optional[ca.Function] = None

    def __post_init__(self):
        if (self.transform is None) != (self.inverse is None):
            raise InputError("a transform needs its inverse (and the inverse its transform)")
        self.names = tuple(self.names)
        self.units = tuple(self.units)
        self.x_ls = np.asarray(self.x_ls, float)
        self.cov_ls = np.asarray(self.cov_ls, float)
        self.sigma = np.asarray(self.sigma, float).reshape(-1)
        missing = [n for n in self.names if n not in self.priors]
        if missing:
            raise UnknownName(f"no prior for {', '.join(missing)}")
        if self.ls_intervals is None:
            z = Z95
            u = np.sqrt(np.maximum(np.diag(self.cov_ls), 0.0))
            self.ls_intervals = {n: (v - z * s, v + z * s) for n, v, s in zip(self.names, self.x_ls, u)}

    @property
    def n_obs(self) -> int:
        return len(self.sigma)


class ResidualProblem:
    """``residuals_and_jacobian`` of a :class:`ResidualTarget` (CasADi exact Jacobian), the
    interface :func:`laplace_approximation` uses. With a ``transform`` the variables are the
    walkers' coordinates ``y`` and the priors (Gaussian, on ``x = T(y)``) are residual rows
    ``(x - mean) / sd`` after the data's, so the MAP and Laplace approximation are in ``y``."""

    def __init__(self, target: ResidualTarget):
        self.names = target.names
        self.n_obs = target.n_obs
        data = [ca.DM(np.asarray(a, float)) if not np.isscalar(a) else a for a in target.data]
        v = ca.MX.sym("v", len(target.names))
        if target.transform is None:
            r = target.residual(v, *data)
        else:
            mu, sd, _, _ = prior_arrays(target.priors, target.names)
            x = target.transform(v)
            r = ca.vertcat(target.residual(x, *data), (x - ca.DM(mu)) / ca.DM(sd))
        self._f = ca.Function("residual_jac", [v], [r, ca.jacobian(r, v)])

    def residuals_and_jacobian(self, x: np.ndarray):
        r, J = self._f(np.asarray(x, float))
        return np.asarray(r).reshape(-1), np.asarray(J)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return self.residuals_and_jacobian(x)[0]


def conditional_shear(residual: ca.Function, data: Sequence, priors: Mapping[str, Prior], names: Sequence[str],
                      x_hat: np.ndarray, slow: Sequence[int], steps: int = 2):
    """A transform for :class:`ResidualTarget`: the shear ``x_fast = m(x_slow) + u``,
    ``x_slow = y_slow``, with ``m`` the conditional optimum of the other ("fast") parameters
    given the ``slow`` ones (indices). ``m`` is ``steps`` Gauss-Newton steps from ``x_hat`` on
    the data rows ``residual(x, *data)`` and the fast parameters' prior rows
    ``(x - mean) / sd``, each with its own exact Jacobian (CasADi, column-scaled at ``x_hat``).
    Returns ``(transform, inverse)``.

    Use: a posterior whose ridge is a curve along a few poorly determined parameters (the slow
    ones, e.g. prior-dominated nuisances), the others following them nonlinearly. In ``y`` the
    fast part is the residual about the ridge, nearly Gaussian and independent of the slow
    part, so the Laplace proposal and the DE moves work again. The Jacobian determinant of a
    shear is 1 whatever ``m`` is, so the density is unchanged and the posterior exact."""
    d = len(names)
    slow = [int(i) for i in slow]
    fast = [i for i in range(d) if i not in slow]
    mu, sd, _, _ = prior_arrays(priors, names)
    dat = [ca.DM(np.asarray(a, float)) if not np.isscalar(a) else a for a in data]
    xf, xs = ca.MX.sym("x_fast", len(fast)), ca.MX.sym("x_slow", len(slow))
    full = [None] * d
    for k, i in enumerate(fast):
        full[i] = xf[k]
    for k, i in enumerate(slow):
        full[i] = xs[k]
    x = ca.vertcat(*full)
    rows = ca.vertcat(residual(x, *dat), (xf - ca.DM(mu[fast])) / ca.DM(sd[fast]))
    rj = ca.Function("conditional_rows", [xf, xs], [rows, ca.jacobian(rows, xf)])
    _, J0 = rj(x_hat[fast], x_hat[slow])
    D = np.linalg.norm(np.asarray(J0), axis=0)
    D[D == 0] = 1.0
    Dm = ca.DM(D)
    m = ca.DM(x_hat[fast])
    for _ in range(steps):
        r, J = rj(m, xs)
        Js = J / ca.repmat(Dm.T, J.size1(), 1)
        m = m - ca.solve(ca.mtimes(Js.T, Js), ca.mtimes(Js.T, r)) / Dm
    m_of = ca.Function("conditional_optimum", [xs], [m])

    def assemble(y, sign):
        out = [None] * d
        mf = m_of(ca.vertcat(*[y[i] for i in slow]))
        for k, i in enumerate(fast):
            out[i] = y[i] + sign * mf[k]
        for i in slow:
            out[i] = y[i]
        return ca.vertcat(*out)

    y = ca.MX.sym("y", d)
    return (ca.Function("shear", [y], [assemble(y, 1.0)]), ca.Function("shear_inverse", [y], [assemble(y, -1.0)]))


class ResidualLogPosterior(LogPosterior):
    """``log p(z | data)`` of a :class:`ResidualTarget` in whitened coordinates ``x = x0 + L z``:
    ``-1/2 r^T r`` plus the Gaussian log-prior, mapped over a block of walkers and compiled like
    :class:`LogPosterior` (same ``__call__``, ``pointwise``, ``to_x``, bounds in numpy)."""

    def __init__(self, target: ResidualTarget, x0: np.ndarray, L: np.ndarray, block: int):
        import hashlib

        self.spec = target
        self.names = target.names
        self.units = target.units
        self.d = len(self.names)
        self.n = target.n_obs
        self.block = int(block)
        self.x0 = np.asarray(x0, float)
        self.L = np.asarray(L, float)
        mu, sd, self.low, self.high = prior_arrays(target.priors, self.names)
        self.sigma = target.sigma
        self._data = [ca.DM(np.asarray(a, float)) for a in target.data]
        self.args = [ca.DM(self.x0), ca.DM(self.L), *self._data, ca.DM(mu), ca.DM(1.0 / sd)]
        self.log_norm = -np.log(self.sigma * math.sqrt(2 * math.pi))    # (n,)
        code = hashlib.sha256((target.residual.serialize() + (target.transform.serialize() if target.transform
                                                                 is not None else "")).encode()).hexdigest()[:16]
        self._key = (target.name, code, tuple(a.shape for a in self._data), self.block)
        self.f_lp, self.compiled = _compile(("residual-lp",) + self._key, self._build_lp)
        self._f_pw = None
        self._f_x = None
        self.evaluations = 0

    def _symbols(self):
        Z = ca.MX.sym("z", self.d, self.block)
        data = [ca.MX.sym(f"data{i}", *a.shape) for i, a in enumerate(self._data)]
        return Z, ca.MX.sym("x0", self.d), ca.MX.sym("L", self.d, self.d), data, \
            ca.MX.sym("mu", self.d), ca.MX.sym("inv_sd", self.d)

    def _build(self, pointwise: bool) -> ca.Function:
        """Log-posterior (row 0) and, with a transform, the parameters ``x`` (rows 1..d) of a
        block of walkers; or the pointwise log-likelihood."""
        Z, x0, L, data, mu, isd = self._symbols()
        ys = ca.MX.sym("y", self.d)
        xs = ys if self.spec.transform is None else self.spec.transform(ys)
        r = self.spec.residual(xs, *data)
        out = -0.5 * r * r if pointwise else -0.5 * ca.sumsqr(r) - 0.5 * ca.sumsqr((xs - mu) * isd)
        if self.spec.transform is not None and not pointwise:
            out = ca.vertcat(out, xs)
        walker = ca.Function("walker", [ys, *data, mu, isd], [out])
        X = ca.repmat(x0, 1, self.block) + ca.mtimes(L, Z)
        res = walker.map(self.block, "serial")(X, *data, mu, isd)
        name = f"triadcal_{self.spec.name}_{'pointwise' if pointwise else 'logpost'}"
        return ca.Function(name, [Z, x0, L, *data, mu, isd], [res])

    def _build_lp(self) -> ca.Function:
        return self._build(False)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        if self.spec.transform is None:
            return super().__call__(z)
        z = np.atleast_2d(z)
        self.evaluations += len(z)
        out = self._blocks(self.f_lp, z)
        lp, x = out[0], out[1:].T
        inside = np.all((x > self.low) & (x < self.high), axis=1)
        return np.where(inside & np.isfinite(lp), lp, -np.inf)

    def to_x(self, z: np.ndarray) -> np.ndarray:
        """Whitened -> reporting units (through the transform, if any); ``z`` (..., d)."""
        y = self.x0 + np.asarray(z) @ self.L.T
        if self.spec.transform is None:
            return y
        if self._f_x is None:
            self._f_x = self.spec.transform.map(self.block, "serial")
        return self._blocks(self._f_x, y.reshape(-1, self.d), args=()).T.reshape(y.shape)

    def pointwise(self, z: np.ndarray) -> np.ndarray:
        """Pointwise log-likelihood ``log N(obs | model, sigma)`` per draw and observation: (m, n)."""
        if self._f_pw is None:
            self._f_pw, _ = _compile(("residual-pw",) + self._key, lambda: self._build(True))
        return self._blocks(self._f_pw, z).T + self.log_norm[None]
