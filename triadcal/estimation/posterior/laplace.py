"""Maximum a posteriori and its Laplace approximation, by the joint fit's Levenberg-Marquardt
on the data residuals with the prior residuals appended.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..joint import (
    JointProblem,
    levenberg_marquardt,
    scaled_covariance,
)
from ..priors import Prior, prior_arrays
from .targets import ResidualProblem


class _WithPriorRows:
    """``[r(x); (x - mu)/sd]`` and its Jacobian: the least-squares form of the log-posterior
    with Gaussian priors, for :func:`triadcal.estimation.joint.levenberg_marquardt`."""

    def __init__(self, problem, mu: np.ndarray, sd: np.ndarray):
        self.problem, self.mu, self.sd = problem, mu, sd

    def residuals_and_jacobian(self, x: np.ndarray):
        r, J = self.problem.residuals_and_jacobian(x)
        return np.concatenate([r, (x - self.mu) / self.sd]), np.vstack([J, np.diag(1.0 / self.sd)])


def laplace_approximation(problem: JointProblem, priors: Mapping[str, Prior], x_start: np.ndarray,
                          max_iter: int = 50):
    """MAP ``x`` and covariance ``(J^T J + diag(1/sd^2))^-1`` in reporting units, by the joint
    fit's Levenberg-Marquardt on ``[r(x); (x - mu)/sd]``. The start is moved strictly inside
    the priors' physical bounds (a least-squares value may sit beyond one); a MAP beyond one is
    held just inside it.

    "Just inside" is a thousandth of the posterior's SD (:data:`MARGIN_OF_POSTERIOR_SD`), never of
    the prior's: the prior's SD of an angle is 3000 arcsec, and a margin of 1e-3 of it (3 arcsec)
    moved the centre of a unit whose angle is 3599.3 +- 0.27 arcsec to 3597 -- the independence
    proposal then sat 8.6 posterior SDs off, the acceptance fell from 0.88 to 0.05 and the sampler
    did not converge in 6000 steps (an outside probe; SBC draws that near the bound made
    ``validate`` fail by chance)."""
    mu, sd, low, high = prior_arrays(priors, problem.names)
    inside = MARGIN_OF_PRIOR_SD * sd            # strictly inside, and nothing more
    x0 = np.clip(np.array(x_start, float), low + inside, high - inside)
    sol = levenberg_marquardt(_WithPriorRows(problem, mu, sd), x0, max_iter=max_iter)
    C = scaled_covariance(sol.J)
    post_sd = np.sqrt(np.clip(np.diag(C), 0.0, None))
    margin = np.maximum(MARGIN_OF_POSTERIOR_SD * post_sd, inside)
    x = np.clip(sol.x, low + margin, high - margin)
    return x, 0.5 * (C + C.T)


#: a MAP beyond a prior's bound is held this many posterior SDs inside it (laplace_approximation)
MARGIN_OF_POSTERIOR_SD = 1e-3
#: ... and at least this many prior SDs (a start strictly inside the bounds)
MARGIN_OF_PRIOR_SD = 1e-9


def _transformed_laplace(problem: ResidualProblem, y_start: np.ndarray):
    """MAP and Laplace covariance in the walkers' coordinates of a transformed target (the priors
    are rows of ``problem``): Levenberg-Marquardt, then ``(J^T J)^-1`` (column-scaled)."""
    sol = levenberg_marquardt(problem, np.asarray(y_start, float))
    C = scaled_covariance(sol.J)
    return sol.x, 0.5 * (C + C.T)
