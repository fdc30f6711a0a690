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


def _thinned(run: PosteriorRun, max_saved_draws: int):
    """Kept draws thinned to at most ``max_saved_draws``: ``(idx, z, x, thin)``, ``z`` and ``x``
    (draw, chain, d) in whitened and reporting units."""
    kept_z = run.kept_z
    steps, W, _ = kept_z.shape
    thin = max(1, math.ceil(steps * W / max_saved_draws))
    idx = np.arange(steps - 1, -1, -thin)[::-1]
    z = kept_z[idx]                                   # (draw, chain, d)
    return idx, z, run.target.to_x(z), thin


def _posterior_variables(run: PosteriorRun, x: np.ndarray) -> dict:
    """One (chain, draw) variable per parameter, named as the parameter, with its unit."""
    return {name: (("chain", "draw"), x[:, :, i].T, {"units": unit})
            for i, (name, unit) in enumerate(zip(run.names, run.units))}


def _posterior_datasets(run: PosteriorRun, post: dict, idx: np.ndarray, attrs: dict):
    """The ``posterior`` and ``sample_stats`` (``lp``) groups, walkers as ``chain``."""
    import xarray as xr

    W = run.chain_z.shape[1]
    coords = {"chain": np.arange(W), "draw": np.arange(len(idx))}
    posterior = xr.Dataset(post, coords=coords, attrs=attrs)
    lp = run.log_prob[run.burn:][idx]
    sample_stats = xr.Dataset({"lp": (("chain", "draw"), lp.T)}, coords=coords)
    return posterior, sample_stats


def inference_data(campaign: Campaign, run: PosteriorRun, result: Optional[CalibrationResult] = None,
                   max_saved_draws: int = 4000):
    """arviz ``InferenceData``: posterior (parameters by name, reporting units; walkers as
    ``chain``), sample_stats (``lp``), observed_data and the pointwise log-likelihood
    (``w`` per ``visit`` and ``axis``, with ``position``, ``setpoint_C``, ``direction``
    coordinates), thinned to at most ``max_saved_draws`` draws."""
    az = _arviz()
    import xarray as xr

    idx, z, x, thin = _thinned(run, max_saved_draws)
    W, d = z.shape[1], z.shape[2]
    n = campaign.n_visits
    draws = np.arange(len(idx))
    chains = np.arange(W)
    post = _posterior_variables(run, x)
    if "tilt_x" in run.names and "tilt_y" in run.names:
        i, j = run.names.index("tilt_x"), run.names.index("tilt_y")
        delta, beta = tilt_polar(x[:, :, i].T * ARCSEC, x[:, :, j].T * ARCSEC)
        post["tilt_delta"] = (("chain", "draw"), np.asarray(delta) / ARCSEC, {"units": "arcsec"})
        post["tilt_beta"] = (("chain", "draw"), np.asarray(beta) / DEG, {"units": "deg"})
    attrs = {"inference_library": "emcee", "created_by": "triadcal sample", "moves": run.moves,
             "thinning": int(thin), "burn": int(run.burn), "chains": "emcee walkers"}
    if result is not None:
        attrs.update({"unit": result.unit, "status": result.status, "effects": ",".join(result.effects)})
    posterior, sample_stats = _posterior_datasets(run, post, idx, attrs)
    visit_coords = {"visit": np.arange(n), "axis": ["x", "y", "z"],
                    "position": ("visit", campaign.position.astype(str)),
                    "setpoint_C": ("visit", campaign.setpoint_C.astype(float), {"units": "degC"}),
                    "direction": ("visit", campaign.direction.astype(str))}
    observed = xr.Dataset({"w": (("visit", "axis"), campaign.w, {"units": campaign.output_unit})},
                          coords=visit_coords)
    pw = run.target.pointwise(z.reshape(-1, d)).reshape(len(idx), W, n, 3).transpose(1, 0, 2, 3)
    loglik = xr.Dataset({"w": (("chain", "draw", "visit", "axis"), pw)},
                        coords={"chain": chains, "draw": draws, **visit_coords})
    return az.InferenceData(posterior=posterior, sample_stats=sample_stats, observed_data=observed,
                            log_likelihood=loglik)


def write_inference_data(path, campaign: Campaign, run: PosteriorRun, result: Optional[CalibrationResult] = None,
                         max_saved_draws: int = 4000) -> None:
    idata = inference_data(campaign, run, result, max_saved_draws)
    from ...io.atomic import atomic_path

    with atomic_path(path) as tmp:
        idata.to_netcdf(str(tmp), engine="h5netcdf")


def target_inference_data(target: ResidualTarget, run: PosteriorRun, result: Optional[CalibrationResult] = None,
                          max_saved_draws: int = 4000):
    """arviz ``InferenceData`` of a :class:`ResidualTarget` run: posterior (by name, reporting
    units), sample_stats (``lp``), observed_data (when the target gives it) and the pointwise
    log-likelihood ``obs_name`` over ``(chain, draw, obs_dim)``."""
    az = _arviz()
    import xarray as xr

    idx, z, x, thin = _thinned(run, max_saved_draws)
    W, d = z.shape[1], z.shape[2]
    attrs = {"inference_library": "emcee", "created_by": f"triadcal ({target.name})", "moves": run.moves,
             "thinning": int(thin), "burn": int(run.burn), "chains": "emcee walkers"}
    if result is not None:
        attrs.update({"unit": result.unit, "status": result.status})
    posterior, sample_stats = _posterior_datasets(run, _posterior_variables(run, x), idx, attrs)
    n = target.n_obs
    coords = {target.obs_dim: np.arange(n), **(target.obs_coords or {})}
    groups = {"posterior": posterior, "sample_stats": sample_stats}
    if target.observed:
        groups["observed_data"] = xr.Dataset(target.observed, coords=coords)
    pw = run.target.pointwise(z.reshape(-1, d)).reshape(len(idx), W, n).transpose(1, 0, 2)
    loglik_coords = {"chain": np.arange(W), "draw": np.arange(len(idx)), target.obs_dim: np.arange(n)}
    groups["log_likelihood"] = xr.Dataset({target.obs_name: (("chain", "draw", target.obs_dim), pw)},
                                          coords=loglik_coords)
    return az.InferenceData(**groups)


def write_target_inference_data(path, target: ResidualTarget, run: PosteriorRun,
                                result: Optional[CalibrationResult] = None, max_saved_draws: int = 4000) -> None:
    idata = target_inference_data(target, run, result, max_saved_draws)
    from ...io.atomic import atomic_path

    with atomic_path(path) as tmp:
        idata.to_netcdf(str(tmp), engine="h5netcdf")
