"""What the errors of two calibrations share (correlation rho of the drift), and drifts from
posterior draws of both.
"""

from __future__ import annotations
from ...errors import InputError
import os
import numpy as np
from ...estimation.result import CalibrationResult


#: number of random before/after draw pairs used for posterior drifts
POSTERIOR_PAIRS = 50_000


#: Terms of our model and of the bench, and whether two campaigns of one unit on one bench
#: share their errors (docs/compare.md).
CORRELATION_TERMS = (
    {"term": "output noise (Q, sd_*)", "shared": False,
     "how": "independent between campaigns; each calibration's u holds it; adds in quadrature"},
    {"term": "random bench positioning and wobble per visit (sigma_1, sigma_2 of eq. 4)", "shared": False,
     "how": "drawn anew at every visit; independent between campaigns; adds in quadrature"},
    {"term": "bench_tilt (delta, beta)", "shared": True,
     "how": "the same bench levelling, but estimated in each joint fit (cancelled by pairing in eq. 2-3): "
            "its estimation error is campaign-specific and already in each result's covariance; its "
            "change is reported as a bench check, not judged"},
    {"term": "repeatable bench errors (encoder error at the commanded angles, axis non-orthogonality, "
             "wobble as a function of angle, fixture)", "shared": True,
     "how": "identical in both campaigns, so they cancel in the drift; the fit's u does not contain them, "
            "so nothing is subtracted (rho = 0); if a result's u includes such a budget term, state rho"},
    {"term": "temperature sensors and reference temperature (thermal terms)", "shared": True,
     "how": "a sensor offset shifts both calibrations alike and cancels; not in the fit's u"},
    {"term": "local gravity value (K)", "shared": True,
     "how": "scales K identically when both use the same value, cancels in the K drift; not in the fit's u"},
)


def derive_correlation(before: CalibrationResult, after: CalibrationResult) -> tuple[float, str]:
    """Default correlation ``rho`` between two calibrations' errors, with the reason."""
    methods = {before.method, after.method}
    if methods <= {"joint", "classical", "posterior"}:
        return 0.0, ("rho = 0: the uncertainties of fitted results come from each campaign's own random "
                     "errors (output noise, per-visit bench errors), which are independent between "
                     "campaigns; the bench's shared systematic errors cancel in the drift and are not in "
                     "these uncertainties, so there is nothing to subtract")
    return 0.0, f"rho = 0 assumed for methods {sorted(methods)}: no shared component is known"


def posterior_draws(source) -> dict:
    """Posterior draws by parameter name from an arviz InferenceData (object or netCDF path).

    The ``posterior`` group's variables are named like the parameters (``Ca_xy``), in the
    reporting unit; a ``unit``/``units`` attribute, when present, is kept for checking.
    Returns ``{name: (flat draws, unit or None)}``.
    """
    if isinstance(source, dict):
        return {k: (np.asarray(v, float).ravel(), None) for k, v in source.items()}
    if isinstance(source, (str, os.PathLike)):
        from ...io.netcdf import read_inference_data

        idata = read_inference_data(source)
    else:
        idata = source
    if not hasattr(idata, "posterior"):
        raise InputError(f"{source}: has no 'posterior' group (expected arviz InferenceData)")
    post = idata.posterior
    out = {}
    for name, var in post.data_vars.items():
        if set(var.dims) - {"chain", "draw"}:
            continue  # vector-valued variables are not parameters of results-json
        unit = var.attrs.get("unit", var.attrs.get("units"))
        out[str(name)] = (np.asarray(var.values, float).ravel(), unit)
    return out


def posterior_drift(draws_before: np.ndarray, draws_after: np.ndarray, seed: int = 0,
                    n_pairs: int = POSTERIOR_PAIRS) -> np.ndarray:
    """Draws of ``after - before`` for independent posteriors: random pairs (fixed seed)."""
    rng = np.random.default_rng(seed)
    i = rng.integers(0, len(draws_before), n_pairs)
    j = rng.integers(0, len(draws_after), n_pairs)
    return draws_after[j] - draws_before[i]
