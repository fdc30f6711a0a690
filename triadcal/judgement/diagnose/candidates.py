"""Which effect explains the gap: score tests of every candidate at the fitted point, refits of
the best, likelihood ratio, PSIS-LOO and cross-branch prediction; the noise candidates
(position_error, heavy_tails) by their own variance and kurtosis scores (docs/diagnosis.md,
"Which").
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy import optimize, stats

from ...models.campaign import Campaign
from ...models.effects import EFFECTS
from ...models.effects import heavy_tails as ht
from ...models.effects import position_error as pe
from ...models.model import Model
from ...estimation.joint import (
    JointProblem,
    identifiability_problems,
)
from .fitting import FitState, _chol, _fit


def _nominal_g(campaign):
    from ...models.campaign import nominal_gravity
    return nominal_gravity(campaign.axis1_deg, campaign.axis2_deg)


# ----------------------------------------------------------------------------------
# scores and refits
# ----------------------------------------------------------------------------------
def _effect_params(model_all: Model, effect: str) -> list[str]:
    return [s.name for s in model_all.parameters if s.effect == effect]


def _pe_sensitivity(full: JointProblem, campaign: Campaign, x_full, sigma) -> np.ndarray:
    """Added variance of each normalised residual per arcsec^2 of positioning error, (3n,)."""
    model = full.model
    p = model.to_internal(dict(zip(model.names, x_full)))
    v = pe.sensitivity_arcsec2(model, p, campaign.covariates(), campaign.gravity_g)
    return (v / sigma ** 2).reshape(-1)


def _score_mean(state: FitState, Jc: np.ndarray, Q: np.ndarray):
    """Score statistic and dof of new columns ``Jc`` (normalised) at the fitted point."""
    norms = np.linalg.norm(Jc, axis=0)
    keep = norms > 1e-12 * max(1.0, np.sqrt(state.r.size))
    if not keep.any():
        return None
    Jc = Jc[:, keep] / norms[keep]
    Jt = Jc - Q @ (Q.T @ Jc)
    U, sv, Vt = np.linalg.svd(Jt, full_matrices=False)
    rank = int(np.sum(sv > 1e-6 * max(sv[0], 1e-300))) if sv.size else 0
    if rank == 0:
        return None
    proj = U[:, :rank].T @ state.r
    S = float(proj @ proj)
    return S, rank


def _kurtosis_logp(z):
    z = np.asarray(z, float)
    if z.size < 20:
        return 0.0, 0.0
    stat, _ = stats.kurtosistest(z, alternative="greater")
    return float(stat), float(stats.norm.logsf(stat))


def _position_score(state: FitState, w: np.ndarray, h: np.ndarray, noise_known: bool):
    """One-sided score test of an added variance tau * w (w per normalised residual) at tau = 0."""
    r2 = state.r ** 2
    if noise_known:
        u = 0.5 * float(np.sum(w * (r2 - (1.0 - h))))
        info = 0.5 * float(np.sum(w * w))
    else:
        wc = w - np.mean(w)           # orthogonal to the estimated overall scale
        u = 0.5 * float(np.sum(wc * (r2 - (1.0 - h))))
        info = 0.5 * float(np.sum(wc * wc))
    if info <= 0:
        return None
    z = u / math.sqrt(info)
    return z, float(stats.norm.logsf(z))


def _loglik_pointwise(r, var_scale=None, nu=math.inf):
    """Pointwise log-likelihood of normalised residuals (up to a common constant)."""
    if var_scale is not None:
        return -0.5 * r * r / var_scale - 0.5 * np.log(var_scale) - 0.5 * np.log(2 * np.pi)
    return ht.logpdf(r, nu)


def _loo(state: FitState, n_draws: int, rng, var_scale=None, nu=math.inf):
    """PSIS-LOO elpd with Laplace draws from the LS covariance, linearised residuals.

    The left-out unit is a visit (its three outputs together): pointwise values per visit."""
    import arviz as az  # (its cache folder is the entry point's business: XDG_CACHE_HOME)

    p = len(state.names)
    L = _chol(state.cov)
    delta = rng.standard_normal((n_draws, p)) @ L.T
    # r is normalised by s; parameters in reporting units; J = dr/dx (normalised)
    rr = state.r[None, :] + delta @ state.J.T
    ll = _loglik_pointwise(rr, var_scale, nu) - (math.log(state.s) if state.s != 1.0 else 0.0)
    ll = ll.reshape(n_draws, -1, 3).sum(axis=2)
    idata = az.from_dict(posterior={"theta": delta[None, :, 0]}, log_likelihood={"obs": ll[None]})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = az.loo(idata, pointwise=True)
    pointwise = np.asarray(res.loo_i).reshape(-1)
    k = np.asarray(res.pareto_k).reshape(-1)
    return float(res.elpd_loo), float(res.se), pointwise, float(np.max(k))


def _loglik_total(state: FitState, var_scale=None, nu=math.inf) -> float:
    return float(np.sum(_loglik_pointwise(state.r, var_scale, nu))) - state.r.size * math.log(state.s)


def _fit_position_error(full, campaign, base: FitState, names, sigma, noise_known):
    """ML of the positioning-error variance (and of the noise scale when it is estimated),
    alternating with the mean refitted on the new weights (3 rounds)."""
    x = base.x_full
    tau, state, var_scale = 0.0, base, np.ones(base.r.size)
    for _ in range(3):
        w = _pe_sensitivity(full, campaign, x, sigma)     # added variance per arcsec^2, sigma units
        r2 = full.residuals(x) ** 2                       # raw, normalised by sigma only

        def nll(theta):
            log_s2, log_tau = (0.0, theta[0]) if noise_known else theta
            v = math.exp(log_s2) + math.exp(log_tau) * w
            return 0.5 * float(np.sum(r2 / v + np.log(v)))
        t0 = [math.log(max(tau, 1e-4))] if noise_known else [2 * math.log(base.s), math.log(max(tau, 1e-4))]
        res = optimize.minimize(nll, t0, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-6})
        log_s2, log_tau = (0.0, res.x[0]) if noise_known else res.x
        tau = math.exp(log_tau) if log_tau > -12 else 0.0
        var_scale = 1.0 + tau * w / math.exp(log_s2)        # variance relative to s^2
        state = _fit(full, names, x, noise_known, scale=np.sqrt(var_scale))
        x = state.x_full
    # keep the residuals normalised by the measurement noise only; var_scale carries the rest
    root = np.sqrt(var_scale)
    state.r, state.J = state.r * root, state.J * root[:, None]
    state.var_scale = var_scale
    state.extra_params = {"position_error_sigma": {"value": math.sqrt(tau), "unit": "arcsec"}}
    return state


def _fit_heavy_tails(base: FitState):
    """Student-t dof by profile likelihood with the least-squares mean (plug-in)."""
    grid = np.array([2.2, 2.5, 3.0, 3.5, 4.0, 5.0, 7.0, 10.0, 20.0, 50.0])
    ll = [float(np.sum(ht.logpdf(base.r, nu))) for nu in grid]
    nu = float(grid[int(np.argmax(ll))])
    state = FitState(base.names, base.x_full, base.r, base.J, base.cov, base.chi2, base.dof, base.s,
                     base.converged, nu=nu, extra_params={"heavy_tails_dof": {"value": nu, "unit": "1"}})
    return state


def _cross_group(campaign, noise, effects_names, names, T0, x_start_full, noise_known):
    """Fit on one branch, predict the other: log predictive density of the held-out branch
    (normalised units, Gaussian plug-in), summed over both directions. None if not possible."""
    br = campaign.branch
    if not ((br == -1).any() and (br == 1).any()):
        return None
    total = 0.0
    for train_b, test_b in ((-1.0, 1.0), (1.0, -1.0)):
        train = campaign.select(np.flatnonzero(br != test_b))
        test = campaign.select(np.flatnonzero(br == test_b))
        model = Model(tuple(EFFECTS), T0)
        ptr = JointProblem(train, model, noise.sigma[br != test_b])
        probs = identifiability_problems(train, Model(effects_names, T0))
        st = _fit(ptr, [n for n in names if n not in probs], x_start_full, noise_known)
        pte = JointProblem(test, model, noise.sigma[br == test_b])
        r = pte.residuals(st.x_full) / st.s
        total += float(np.sum(-0.5 * r * r))
    return total
