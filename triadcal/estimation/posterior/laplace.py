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
    the priors' physical bounds (a least-squares value may sit beyond one); bounds are not
    active at the MAP of any sensible campaign, and a MAP beyond one is held at the bound's
    margin."""
    mu, sd, low, high = prior_arrays(priors, problem.names)
    margin = 1e-3 * sd
    x0 = np.clip(np.array(x_start, float), low + margin, high - margin)
    sol = levenberg_marquardt(_WithPriorRows(problem, mu, sd), x0, max_iter=max_iter)
    x = np.clip(sol.x, low + margin, high - margin)
    C = scaled_covariance(sol.J)
    return x, 0.5 * (C + C.T)


def _transformed_laplace(problem: ResidualProblem, y_start: np.ndarray):
    """MAP and Laplace covariance in the walkers' coordinates of a transformed target (the priors
    are rows of ``problem``): Levenberg-Marquardt, then ``(J^T J)^-1`` (column-scaled)."""
    sol = levenberg_marquardt(problem, np.asarray(y_start, float))
    C = scaled_covariance(sol.J)
    return sol.x, 0.5 * (C + C.T)
