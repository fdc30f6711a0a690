"""Generic structure tests: smooth mean terms that are no candidate of the vocabulary.

A candidate answers "which effect"; these answer only "is any smooth pattern of the mean left".
Each family is a set of columns added to every output ``a`` (visit ``i``, the normalised
residual's row ``3 i + a``, divided by the output's noise SD ``sigma_ia`` as the residuals are):

* ``temperature``: ``u, u^2, u^3`` times ``1, g_x, g_y, g_z``  (``u`` the visit's mean
  temperature reading scaled to [-1, 1] over the campaign; ``g`` the nominal gravity components
  in the sensor frame): a bias, scale or angle changing with temperature in any smooth way;
* ``time``: ``s, s^2`` times ``1, g_x, g_y, g_z`` (``s`` the campaign time scaled to [-1, 1]):
  drifts of bias, scale or angle;
* ``orientation_even``: ``g_j^2, |g_j|, g_j g_k`` (j < k): functions of the specific force even
  in its sign (K2, asymmetry, cross-coupling, and what lies between them);
* ``orientation_odd``: ``g_j |g_j|, g_j^3, g_j^2 g_k`` (j != k): odd ones (K3, g-dependent
  misalignment, an odd-quadratic nonlinearity);
* ``direction``: ``d`` times ``1, g_x, g_y, g_z`` (``d`` = +1 heating, -1 cooling, 0 none):
  any hysteresis-like offset of the branch.

The test of a family is the score test of the mean candidates (``candidates._score_mean``: the
residuals projected on the family's columns made orthogonal to the fitted model's span; ``S``
is chi2 with the projected rank as dof when the noise is known, the F form otherwise), so a
pattern the model already holds costs nothing. The families serve twice (docs/diagnosis.md,
"Generic structure"): in the gap's Holm family (a missing term no candidate names, e.g. a
cubic tempco left out of the list, is then detected: ``unexplained`` instead of ``none``), and
after a refit, on the residuals standardised by the refit's noise model (a noise candidate --
``position_error``, ``heavy_tails``, ``flicker_noise`` -- or a mean candidate is named only when
no family finds structure left: a candidate that absorbs the gap as noise, or a wrong term that
shrinks it below the chi2 test's power, leaves a pattern these columns see).
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from scipy import stats

from ...models.campaign import Campaign
from .candidates import _nominal_g, _score_mean
from .fitting import _chi2_logsf, _hat_q

FAMILIES = ("temperature", "time", "orientation_even", "orientation_odd", "direction")


def _scaled(x: np.ndarray) -> np.ndarray:
    lo, hi = float(np.min(x)), float(np.max(x))
    if hi - lo <= 0:
        return np.zeros_like(x, dtype=float)
    return (2.0 * x - (hi + lo)) / (hi - lo)


def generic_basis(campaign: Campaign, sigma: np.ndarray) -> dict:
    """The families' columns in normalised units: ``{family: (3n, k) array}`` (module docstring);
    ``sigma`` the outputs' noise SD (n, 3) or (3,), the residuals' divisor."""
    n = campaign.n_visits
    g = np.asarray(_nominal_g(campaign), float).reshape(n, 3)
    one_g = np.column_stack([np.ones(n), g])                      # 1, g_x, g_y, g_z
    u = _scaled(np.mean(np.asarray(campaign.t, float), axis=1))
    s = _scaled(np.asarray(campaign.time_s, float))
    d = np.array([{"heating": 1.0, "cooling": -1.0}.get(x, 0.0) for x in campaign.direction])
    per_output = {
        "temperature": np.column_stack([p[:, None] * one_g for p in (u, u ** 2, u ** 3)]),
        "time": np.column_stack([p[:, None] * one_g for p in (s, s ** 2)]),
        "orientation_even": np.column_stack([g ** 2, np.abs(g), g[:, [0]] * g[:, [1]], g[:, [0]] * g[:, [2]],
                                             g[:, [1]] * g[:, [2]]]),
        "orientation_odd": np.column_stack([g * np.abs(g), g ** 3] + [g[:, [j]] ** 2 * g[:, [k]] for j in range(3)
                                                                       for k in range(3) if j != k]),
        "direction": d[:, None] * one_g,
    }
    sig = np.broadcast_to(np.asarray(sigma, float), (n, 3))
    out = {}
    for fam, F in per_output.items():
        k = F.shape[1]
        B = np.zeros((n, 3, 3 * k))
        for a in range(3):
            B[:, a, a * k:(a + 1) * k] = F / sig[:, [a]]
        out[fam] = B.reshape(3 * n, 3 * k)
    return out


def generic_tests(basis: dict, r: np.ndarray, J: np.ndarray, noise_known: bool, dof: int,
                  Q: Optional[np.ndarray] = None) -> dict:
    """p-value of each family's score test at a fit with standardised residuals ``r`` (3n,) and
    Jacobian ``J`` (same scaling); ``{family: {"S", "k", "p_value"}}`` (families with no column
    outside the fit's span are left out). With the noise estimated, ``S / k`` against
    ``(r'r - S) / (dof - k)`` as F."""
    Q = _hat_q(J) if Q is None else Q
    out = {}
    for fam, B in basis.items():
        sc = _score_mean(_R(r), B, Q)
        if sc is None:
            continue
        S, k = sc
        if noise_known:
            logp = _chi2_logsf(S, k)
        else:
            rest = max(float(r @ r) - S, 1e-300)
            d2 = max(dof - k, 1)
            logp = float(stats.f.logsf((S / k) / (rest / d2), k, d2))
        out[fam] = {"S": float(S), "k": int(k), "p_value": float(math.exp(logp))}
    return out


class _R:
    """The residual holder ``_score_mean`` reads (``.r``)."""

    def __init__(self, r):
        self.r = np.asarray(r, float)
