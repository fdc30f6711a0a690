"""Posterior draws as an arviz InferenceData (posterior, sample_stats, observed_data, pointwise
log-likelihood) and its netCDF file.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from ...models.campaign import Campaign
from ...models.kinematics import tilt_polar
from ...models.units import ARCSEC, DEG
from ..result import CalibrationResult
from .diagnostics import _arviz
from .run import PosteriorRun
from .targets import ResidualTarget


#: the pointwise log-likelihood (draws x observations) is saved for at most this many draws
MAX_LOGLIK_DRAWS = 4000


def _loglik_subset(run: PosteriorRun, max_loglik_draws: int) -> np.ndarray:
    """Indices into the saved draws (ending at the last) at which the pointwise log-likelihood
    is saved: every draw when they are at most ``max_loglik_draws`` (walkers x steps), else
    every k-th. Its ``draw`` coordinate holds these indices, so the two groups line up."""
    steps, W = run.kept_z.shape[:2]
    k = max(1, math.ceil(steps * W / max_loglik_draws))
    return np.arange(steps - 1, -1, -k)[::-1]


def verdict_attrs(run: PosteriorRun) -> dict:
    """The convergence verdict of the saved draws, as netCDF attributes of the posterior group
    (computed once by the sampler; consumers read it instead of recomputing it)."""
    diag = run.diagnostics
    names = list(run.names)
    ib, it, ir = (int(np.argmin(diag["ess_bulk"])), int(np.argmin(diag["ess_tail"])), int(np.argmax(diag["rhat"])))
    return {"converged": int(bool(run.converged)), "rhat_max": float(diag["rhat"][ir]), "rhat_worst": names[ir],
            "ess_bulk_min": float(diag["ess_bulk"][ib]), "ess_bulk_worst": names[ib],
            "ess_tail_min": float(diag["ess_tail"][it]), "ess_tail_worst": names[it],
            "stop_rule_ess": float(run.stop_rule.get("ess", math.nan)),
            "stop_rule_rhat_max": float(run.stop_rule.get("rhat_max", math.nan)),
            "rhat_classic_max": float(run.checks[-1]["rhat_classic_max"]) if run.checks else math.nan,
            "verdict": "computed once by the sampler on exactly these draws (walkers as chains), with the last "
                       "look's classic split R-hat (rhat_classic_max) part of it"}


def _posterior_variables(run: PosteriorRun, x: np.ndarray) -> dict:
    """One (chain, draw) variable per parameter, named as the parameter, with its unit."""
    return {name: (("chain", "draw"), x[:, :, i].T, {"units": unit})
            for i, (name, unit) in enumerate(zip(run.names, run.units))}


def _posterior_datasets(run: PosteriorRun, post: dict, attrs: dict):
    """The ``posterior`` and ``sample_stats`` (``lp``) groups of every saved draw, walkers as
    ``chain``."""
    import xarray as xr

    W = run.chain_z.shape[1]
    coords = {"chain": np.arange(W), "draw": np.arange(run.kept_z.shape[0])}
    posterior = xr.Dataset(post, coords=coords, attrs=attrs)
    lp = run.kept_log_prob
    sample_stats = xr.Dataset({"lp": (("chain", "draw"), lp.T)}, coords=coords)
    return posterior, sample_stats


def inference_data(campaign: Campaign, run: PosteriorRun, result: Optional[CalibrationResult] = None,
                   max_loglik_draws: int = MAX_LOGLIK_DRAWS):
    """arviz ``InferenceData``: posterior (every saved draw, parameters by name, reporting units;
    walkers as ``chain``; the convergence verdict in its attributes), sample_stats (``lp``),
    observed_data and the pointwise log-likelihood (``w`` per ``visit`` and ``axis``, with
    ``position``, ``setpoint_C``, ``direction`` coordinates) at most ``max_loglik_draws`` draws."""
    az = _arviz()
    import xarray as xr

    z = run.kept_z
    x = run.target.to_x(z)
    W, d = z.shape[1], z.shape[2]
    n = campaign.n_visits
    post = _posterior_variables(run, x)
    if "tilt_x" in run.names and "tilt_y" in run.names:
        i, j = run.names.index("tilt_x"), run.names.index("tilt_y")
        delta, beta = tilt_polar(x[:, :, i].T * ARCSEC, x[:, :, j].T * ARCSEC)
        post["tilt_delta"] = (("chain", "draw"), np.asarray(delta) / ARCSEC, {"units": "arcsec"})
        post["tilt_beta"] = (("chain", "draw"), np.asarray(beta) / DEG, {"units": "deg"})
    attrs = {"inference_library": "emcee", "created_by": "triadcal sample", "moves": run.moves,
             "thinning": int(run.thin), "burn": int(run.burn), "chains": "emcee walkers", **verdict_attrs(run)}
    if result is not None:
        attrs.update({"unit": result.unit, "status": result.status, "effects": ",".join(result.effects)})
    posterior, sample_stats = _posterior_datasets(run, post, attrs)
    visit_coords = {"visit": np.arange(n), "axis": ["x", "y", "z"],
                    "position": ("visit", campaign.position.astype(str)),
                    "setpoint_C": ("visit", campaign.setpoint_C.astype(float), {"units": "degC"}),
                    "direction": ("visit", campaign.direction.astype(str))}
    observed = xr.Dataset({"w": (("visit", "axis"), campaign.w, {"units": campaign.output_unit})},
                          coords=visit_coords)
    idx = _loglik_subset(run, max_loglik_draws)
    pw = run.target.pointwise(z[idx].reshape(-1, d)).reshape(len(idx), W, n, 3).transpose(1, 0, 2, 3)
    loglik = xr.Dataset({"w": (("chain", "draw", "visit", "axis"), pw)},
                        coords={"chain": np.arange(W), "draw": idx, **visit_coords})
    return az.InferenceData(posterior=posterior, sample_stats=sample_stats, observed_data=observed,
                            log_likelihood=loglik)


def write_inference_data(path, campaign: Campaign, run: PosteriorRun, result: Optional[CalibrationResult] = None,
                         max_loglik_draws: int = MAX_LOGLIK_DRAWS) -> None:
    idata = inference_data(campaign, run, result, max_loglik_draws)
    from ...io.atomic import atomic_path

    with atomic_path(path) as tmp:
        idata.to_netcdf(str(tmp), engine="h5netcdf")


def target_inference_data(target: ResidualTarget, run: PosteriorRun, result: Optional[CalibrationResult] = None,
                          max_loglik_draws: int = MAX_LOGLIK_DRAWS):
    """arviz ``InferenceData`` of a :class:`ResidualTarget` run: posterior (by name, reporting
    units), sample_stats (``lp``), observed_data (when the target gives it) and the pointwise
    log-likelihood ``obs_name`` over ``(chain, draw, obs_dim)``."""
    az = _arviz()
    import xarray as xr

    z = run.kept_z
    W, d = z.shape[1], z.shape[2]
    attrs = {"inference_library": "emcee", "created_by": f"triadcal ({target.name})", "moves": run.moves,
             "thinning": int(run.thin), "burn": int(run.burn), "chains": "emcee walkers", **verdict_attrs(run)}
    if result is not None:
        attrs.update({"unit": result.unit, "status": result.status})
    posterior, sample_stats = _posterior_datasets(run, _posterior_variables(run, run.target.to_x(z)), attrs)
    idx = _loglik_subset(run, max_loglik_draws)
    n = target.n_obs
    coords = {target.obs_dim: np.arange(n), **(target.obs_coords or {})}
    groups = {"posterior": posterior, "sample_stats": sample_stats}
    if target.observed:
        groups["observed_data"] = xr.Dataset(target.observed, coords=coords)
    pw = run.target.pointwise(z[idx].reshape(-1, d)).reshape(len(idx), W, n).transpose(1, 0, 2)
    loglik_coords = {"chain": np.arange(W), "draw": idx, target.obs_dim: np.arange(n)}
    groups["log_likelihood"] = xr.Dataset({target.obs_name: (("chain", "draw", target.obs_dim), pw)},
                                          coords=loglik_coords)
    return az.InferenceData(**groups)


def write_target_inference_data(path, target: ResidualTarget, run: PosteriorRun,
                                result: Optional[CalibrationResult] = None,
                                max_loglik_draws: int = MAX_LOGLIK_DRAWS) -> None:
    idata = target_inference_data(target, run, result, max_loglik_draws)
    from ...io.atomic import atomic_path

    with atomic_path(path) as tmp:
        idata.to_netcdf(str(tmp), engine="h5netcdf")
