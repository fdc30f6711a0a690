"""Generalised least squares on correlated output noise: whitened problems.

The fit machinery takes diagonal weights; a noise whose covariance is not diagonal is handled by
whitening the normalised residuals and the Jacobian with the Cholesky factor ``L`` of their
covariance ``V = L L^T`` (``r~ = L^-1 r``): least squares on the whitened problem is GLS on ``V``,
and ``(J~^T J~)^-1`` its covariance (Aitken 1935).

* :class:`WhitenedProblem` wraps a :class:`~triadcal.estimation.joint.JointProblem`;
* :class:`BlockWhitening` is ``L^-1`` for a covariance block-diagonal over visits with a 3 x 3 block
  per visit: the bench's random positioning and wobble errors (seed paper, eq. 4), which rotate
  gravity in the sensor frame and so move a visit's three outputs together
  (:func:`triadcal.models.effects.position_error.covariance_blocks`);
* :func:`bench_whitening` builds it for the lab's bench errors;
* :class:`~triadcal.estimation.flicker_noise.AxisWhitening` (1/f noise) is the other kind: full
  over visits, one output at a time.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

#: largest correlation between a visit's outputs still treated as none: on a plan whose poses put
#: gravity along one sensing axis each bench error moves one output, and the covariance is diagonal
#: but for the unit's misalignments (~1e-3 rad, a correlation of that order); the variances of a
#: fit that leaves out a correlation rho differ from the GLS ones at order rho^2 (1e-4 here), so the
#: fit keeps its diagonal weights below it
NEGLIGIBLE_CORRELATION = 0.01


class BlockWhitening:
    """``L_i^-1`` per visit of ``V_i = L_i L_i^T`` (3 x 3, normalised units), applied to vectors or
    matrices whose rows are visit-major (visit i, output a at row 3 i + a)."""

    def __init__(self, V: np.ndarray):
        self.V = np.asarray(V, float)
        self.L = np.linalg.cholesky(self.V)
        self.n = self.V.shape[0]

    def diag(self) -> np.ndarray:
        """``L_i,aa`` per visit and output (n, 3)."""
        return np.diagonal(self.L, axis1=1, axis2=2).copy()

    def apply(self, x: np.ndarray) -> np.ndarray:
        """``L^-1 x`` for ``x`` of shape (3n,) or (3n, p)."""
        x = np.asarray(x, float)
        shaped = x.reshape(self.n, 3, -1)
        return np.linalg.solve(self.L, shaped).reshape(x.shape)


class WhitenedProblem:
    """A :class:`~triadcal.estimation.joint.JointProblem` (or anything with ``residuals`` and
    ``residuals_and_jacobian``) whose normalised residuals and Jacobian are whitened by
    ``whitening`` (GLS); ``raw`` is the problem itself, every other attribute is its own."""

    def __init__(self, problem, whitening):
        self.raw = problem
        self.whitening = whitening

    def __getattr__(self, name):
        return getattr(self.raw, name)

    def residuals_and_jacobian(self, x):
        r, J = self.raw.residuals_and_jacobian(x)
        return self.whitening.apply(r), self.whitening.apply(J)

    def residuals(self, x):
        return self.whitening.apply(self.raw.residuals(x))


def bench_blocks(model, p, campaign, sigma, weights=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Covariance of each visit's three outputs from the bench's random errors, divided by
    ``sigma_a sigma_b`` (``sigma`` (n, 3) or broadcastable: the normalisation of the residuals),
    (n, 3, 3); ``weights``: the variances (arcsec^2) of the errors of axis 1, axis 2 and the wobble
    (:func:`~triadcal.models.effects.position_error.covariance_blocks`; ``p`` internal units)."""
    from ..models.effects.position_error import covariance_blocks

    C = covariance_blocks(model, p, campaign.covariates(), campaign.gravity_g, weights=weights)
    sig = np.broadcast_to(np.asarray(sigma, float), (C.shape[0], 3))
    return C / (sig[:, :, None] * sig[:, None, :])


def bench_whitening(model, p, campaign, sigma_data: np.ndarray, sigma_total: np.ndarray,
                    sigma_position_arcsec: float, sigma_wobble_arcsec: float) -> Optional[BlockWhitening]:
    """The whitening of the residuals normalised by ``sigma_total`` (the data's noise ``sigma_data``
    and the bench's variance, :func:`~triadcal.estimation.joint.with_bench_errors`) for the full
    covariance of each visit: ``V_i = D^-1 (diag(sigma_data^2) + C_i) D^-1`` with ``D = diag(sigma_total)``
    (unit diagonal). None when no visit's outputs correlate by more than :data:`NEGLIGIBLE_CORRELATION`
    (the diagonal weights are then the whole covariance)."""
    s1, s2 = float(sigma_position_arcsec), float(sigma_wobble_arcsec)
    if s1 == 0.0 and s2 == 0.0:
        return None
    C = bench_blocks(model, p, campaign, sigma_total, (s1 * s1, s1 * s1, s2 * s2))
    V = C + np.einsum("na,ab->nab", (np.asarray(sigma_data, float) / sigma_total) ** 2, np.eye(3))
    off = V - np.einsum("naa,ab->nab", V, np.eye(3))
    if float(np.max(np.abs(off))) <= NEGLIGIBLE_CORRELATION:
        return None
    return BlockWhitening(V)


def gls_posterior_target(campaign, effects, least_squares, whitening, priors=None,
                         reference_temperature_C: float = 20.0, name: str = "joint_gls", noise_scale: float = 1.0):
    """A :class:`~triadcal.estimation.posterior.targets.ResidualTarget` of the joint model whose
    residuals are whitened by ``whitening`` (one with ``casadi_apply``:
    :class:`~triadcal.estimation.flicker_noise.AxisWhitening`, ``flicker_noise``; the bench's blocks
    on oblique poses go into the compiled per-visit target instead, ``LogPosterior(whitening=...)``): the
    likelihood is the Gaussian of the full covariance, its variance components held at the values of
    the least-squares fit (a plug-in). ``least_squares``: the GLS fit ``(result, problem, solution)``
    of :func:`~triadcal.estimation.joint.fit_joint`. ``noise_scale``: the factor on the problem's
    sigma (with the noise estimated, the least squares' ``sqrt(chi2/dof)`` of the whitened residuals,
    held there: a plug-in, as ``sample`` holds the estimated white level without correlated noise)."""
    import casadi as ca

    from ..models.model import Model
    from .joint import parameter_unit, scaled_covariance
    from .posterior.targets import ResidualTarget
    from .gates import config_of
    from .priors import autoscaled_priors, default_priors

    ls, problem, sol = least_squares
    raw = getattr(problem, "raw", problem)
    model = Model(effects, reference_temperature_C)
    bound = config_of(ls).angle_bound_arcsec         # the bound the least-squares result was judged with
    pri, _ = autoscaled_priors(default_priors(model, overrides=priors, angle_bound_arcsec=bound),  # noted by the caller
                               {n: p.value for n, p in ls.parameters.items()}, user=priors or {},
                               u={n: p.u for n, p in ls.parameters.items()})
    names = tuple(raw.names)
    x = ca.MX.sym("x", len(names))
    w = raw._predict(x, ca.DM(raw.cov_matrix), raw.gravity_g)              # 3 x n
    r = (ca.DM(campaign.w.T) - w) / ca.DM(raw.sigma.T * noise_scale)
    f = ca.Function(f"{name}_whitened_residuals", [x], [whitening.casadi_apply(r)])   # visit-major, as the fit
    sigma = (raw.sigma * noise_scale * whitening.diag()).reshape(-1)        # one-step prediction SDs
    return ResidualTarget(
        name=name, residual=f, data=(), names=names,
        units=tuple(parameter_unit(model, nm, campaign.output_unit) for nm in names),
        priors={nm: pri[nm] for nm in names}, x_ls=np.asarray(sol.x, float),
        cov_ls=scaled_covariance(sol.J) * noise_scale ** 2,
        sigma=sigma, unit_serial=str(campaign.units[0]))

