"""Residuals of a fit per visit and axis as netCDF (xarray, h5netcdf engine)."""

from __future__ import annotations

from ..errors import InputError

import numpy as np


def fit_dataset(campaign, problem, solution, result):
    """An ``xarray.Dataset`` of the fit: observed and modelled outputs, raw and normalised
    residuals per visit and axis, with the visit's conditions as coordinates."""
    import xarray as xr

    n = campaign.n_visits
    w_model = problem.predict(solution.x)
    ds = xr.Dataset(
        {
            "w_observed": (("visit", "axis"), campaign.w, {"units": campaign.output_unit}),
            "w_model": (("visit", "axis"), w_model, {"units": campaign.output_unit}),
            "residual": (("visit", "axis"), campaign.w - w_model, {"units": campaign.output_unit}),
            "residual_normalised": (("visit", "axis"), solution.r.reshape(n, 3),
                                    {"units": "1", "long_name": "(observed - model) / sigma"}),
            "sigma": (("visit", "axis"), problem.sigma, {"units": campaign.output_unit}),
            "temperature": (("visit", "axis"), campaign.t, {"units": "degC"}),
        },
        coords={
            "visit": np.arange(n), "axis": ["x", "y", "z"],
            "position": ("visit", campaign.position.astype(str)),
            "up_axis": ("visit", campaign.up_axis().astype(str)),
            "setpoint_C": ("visit", campaign.setpoint_C, {"units": "degC"}),
            "direction": ("visit", campaign.direction.astype(str)),
            "time_s": ("visit", campaign.time_s, {"units": "s"}),
        },
        attrs={"unit": result.unit, "method": result.method, "effects": ",".join(result.effects),
               "chi2_dof": float(result.fit.get("chi2_dof", np.nan)), "source": str(campaign.source)},
    )
    return ds


def write_fit_netcdf(path, campaign, problem, solution, result) -> None:
    from .atomic import atomic_path

    ds = fit_dataset(campaign, problem, solution, result)
    with atomic_path(path) as tmp:
        ds.to_netcdf(tmp, engine="h5netcdf")


def read_inference_data(path):
    """An arviz ``InferenceData`` from a netCDF file (a posterior written by ``sample`` or
    ``fit-raw --sample``), refused in one line naming the file when it is missing, is not
    such a file, or has no ``posterior`` group. The one reader of posterior files."""
    from pathlib import Path

    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such posterior file")
    import arviz as az

    try:
        idata = az.from_netcdf(str(path))
    except Exception as exc:  # noqa: BLE001 - h5py/netCDF raise many types; reported with the file
        raise InputError(f"{path}: not an arviz InferenceData netCDF file ({type(exc).__name__}: {exc})") from None
    if not hasattr(idata, "posterior"):
        raise InputError(f"{path}: has no 'posterior' group (expected arviz InferenceData)")
    return idata
