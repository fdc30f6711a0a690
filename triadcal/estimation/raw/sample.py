"""Posterior sampling of the raw models through the bench's sampler
(:func:`triadcal.estimation.posterior.sample_target`), in sheared coordinates that follow
the curved ridges of these designs (docs/raw.md, "Sampling").
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from ...errors import UnknownName
from ...models.units import ARCSEC
from ..joint import Solution, scaled_covariance
from ..result import Z95, CalibrationResult
from .known import KnownPoseProblem
from .poses import NORM_NAMES, UNIT_NAMES
from .unknown import NormProblem

# --------------------------------------------------------------------------------------
# posterior sampling through the bench's path (triadcal.estimation.posterior)
# --------------------------------------------------------------------------------------
#: priors of the raw models, ten times the spread of MEMS units (as the bench's are ten times
#: the spread of its units): K ~ N(k0, 0.1 k0) with k0 the isotropic scale of the recording
#: (10 x a 1 % scale-factor spread), S ~ N(0, 0.5 g) (10 x a 50 mg offset),
#: Ca ~ N(0, 5 deg) (10 x a 0.5 deg misalignment), |Ca| < 0.5 rad
RAW_PRIOR_K_REL = 0.1


RAW_PRIOR_S_G = 0.5


RAW_PRIOR_CA_ARCSEC = 5 * 3600.0


def raw_priors(names: Sequence[str], k0: float, scale_unit: str, placement_sd_arcsec: Optional[float] = None,
               overrides=None, misalignment_sd_arcsec: Optional[float] = None) -> dict:
    """The documented weakly informative priors of the raw models (reporting units); tilts (known
    poses) get the placement random effect's N(0, sigma_h^2), and there the angles get the
    known-pose model's misalignment prior N(0, sigma_a^2) (module docstring)."""
    from ..priors import HALF_RADIAN, Prior

    out = {}
    for n in names:
        if n.startswith("K_"):
            out[n] = Prior(n, scale_unit, float(k0), RAW_PRIOR_K_REL * float(k0), 0.0, np.inf,
                           "a scale factor is positive; 10 x a 1 % spread around the isotropic scale of the recording")
        elif n.startswith("S_"):
            out[n] = Prior(n, "g", 0.0, RAW_PRIOR_S_G, reason="10 x a 50 mg MEMS offset")
        elif n.startswith("Ca_"):
            b = HALF_RADIAN / ARCSEC
            if misalignment_sd_arcsec is None:
                out[n] = Prior(n, "arcsec", 0.0, RAW_PRIOR_CA_ARCSEC, -b, b,
                               "10 x a 0.5 deg MEMS misalignment; each row of Ca stays a unit vector")
            else:
                out[n] = Prior(n, "arcsec", 0.0, float(misalignment_sd_arcsec), -b, b,
                               "known poses: the misalignment prior of the least-squares fit "
                               "(--misalignment-sd-deg); the angles are confounded with the placement")
        elif n.startswith("tilt_"):
            out[n] = Prior(n, "arcsec", 0.0, float(placement_sd_arcsec),
                           reason="hand placement: the random effect's prior (--placement-sd-deg)")
        else:
            raise UnknownName(n)
    for k, v in (overrides or {}).items():
        if k not in out:
            raise UnknownName(f"prior for {k!r}: not a parameter of this model ({', '.join(names)})")
        out[k] = v
    return out


def widened_bias_priors(pri: dict, ls: CalibrationResult, user=None) -> tuple:
    """``(priors, notes)``: the biases' priors widened where the least-squares S contradicts
    ``N(0, 0.5 g)`` (:func:`~triadcal.estimation.priors.autoscaled_priors`: beyond 3 prior-predictive
    SDs, the SD set to the distance); a bias of an analog or offset-binary output far beyond a MEMS
    offset is the unit's, not a value for the prior to pull toward 0. The other raw priors are kept:
    K's is centred on the recording's own scale already, the angles' and tilts' are the models'."""
    from ..priors import autoscaled_priors

    s_names = [n for n in pri if n.startswith("S_") and n in ls.parameters]
    return autoscaled_priors(pri, {n: ls[n].value for n in s_names}, user=user or {},
                             u={n: ls[n].u for n in s_names})


def sample_unknown_poses(ls: CalibrationResult, problem: NormProblem, sol: Solution, *, serial: str,
                         scale_unit: str, priors=None, posterior_path=None, shear: bool = True, **sampler):
    """Posterior of the gravity-norm model (:func:`triadcal.estimation.posterior.sample_target`).

    Likelihood: ``|A_k| - g ~ N(0, s^2)`` per interval with ``s^2`` the variance the
    least-squares fit used (the residual variance, not below the noise of the interval means),
    held fixed. The least-squares intervals the flags compare with are the Gaussian ones
    (``value +- 1.96 u``, the same ``s``), so a ``non_gaussian`` flag is about the shape of
    the posterior, not the Student-t factor. Parameters whose least-squares SD exceeds half
    their prior SD (a nearly singular design: the MPU-6050's Ca_xy) are the slow coordinates of
    a :func:`~triadcal.estimation.posterior.conditional_shear` (``shear=False``: plain whitened
    coordinates, for comparison). Returns ``(CalibrationResult, PosteriorRun)``."""
    from ..posterior import (
        PRIOR_DOMINATED_RATIO,
        ResidualTarget,
        conditional_shear,
        sample_target,
    )

    f = ls.fit
    s2 = max(f["residual_variance_g2"] or 0.0, f["noise_variance_g2"])
    sigma = np.full(problem.n, math.sqrt(s2))
    k0 = float(np.mean(sol.x[:3]))
    names = NORM_NAMES
    units = tuple(ls[n].unit for n in names)
    cov = ls.covariance(list(names))
    pri = raw_priors(names, k0, scale_unit, overrides=priors)
    pri, widened = widened_bias_priors(pri, ls, priors)
    data = (problem.w.T, problem.gravity_g, 1.0 / sigma)
    # parameters the data determine no better than the prior: the walkers move along them and
    # the others follow through the conditional shear (the ridge of a nearly singular design)
    slow = [i for i, n in enumerate(names) if ls[n].u > PRIOR_DOMINATED_RATIO * pri[n].sd]
    transform = inverse = None
    if slow and shear:
        transform, inverse = conditional_shear(problem.residual_function(), data, pri, names, sol.x, slow)
    target = ResidualTarget(
        name="norm", residual=problem.residual_function(), data=data,
        names=names, units=units, priors=pri, x_ls=sol.x, transform=transform, inverse=inverse,
        cov_ls=cov, sigma=sigma, obs_dim="interval", obs_name="norm_residual",
        observed={"w": (("interval", "axis"), problem.w, {"units": scale_unit.split("/")[-1]})},
        obs_coords={"axis": ["x", "y", "z"]}, unit_serial=serial)
    notes = [f"noise of |A| - g held at the least-squares value (s = {math.sqrt(s2):.3g} g, "
             f"{f['variance_used']}); the posterior does not include its uncertainty"] + widened
    prefer = (f"the posterior holds the noise of |A| - g at its least-squares value, which {f['dof']} residual "
              f"degree{'s' if f['dof'] != 1 else ''} of freedom determine poorly; the least-squares intervals (Student's t) include that "
              "uncertainty" if 0 < f["dof"] < 10 else None)
    result, run = sample_target(target, posterior_path=posterior_path, notes=notes, prefer_least_squares=prefer,
                                **sampler)
    result.notes.extend(ls.notes)
    result.fit.update({"model": f["model"], "dof": f["dof"], "variance_used": f["variance_used"],
                       "sigma_g": math.sqrt(s2),
                       "least_squares": {"status": ls.status, "estimator": "gravity-norm least squares",
                                         "parameters": {n: ls[n].to_dict() for n in names},
                                         "intervals": ls.intervals}})
    result.extra["fixed"] = ls.extra.get("fixed", {})
    result.extra["sampler"]["coordinates"] = (
        "sheared: the walkers move along " + ", ".join(names[i] for i in slow) + "; the other parameters about "
        "their conditional optimum" if transform is not None else "whitened (Laplace approximation)")
    return result, run


def sample_known_poses(ls: CalibrationResult, problem: KnownPoseProblem, sol: Solution, labels: Sequence[str], *,
                       serial: str, scale_unit: str, priors=None, posterior_path=None, shear: bool = True,
                       **sampler):
    """Posterior of the known-pose model: the 12 unit parameters and the 12 placement tilts
    (prior N(0, sigma_h^2), the random effect), sampled jointly, so the tilts are integrated out
    exactly (no importance sampling); the angles' prior N(0, sigma_a^2) is the least-squares
    fit's. The walkers move in sheared coordinates
    (:func:`~triadcal.estimation.posterior.conditional_shear`): the tilts, and the unit
    parameters about their conditional optimum given the tilts; along the unresolved directions
    K and S move with the squares of the tilts, a curved ridge the shear straightens."""
    from ..posterior import ResidualTarget, conditional_shear, sample_target

    nu = len(UNIT_NAMES)
    tilt_names = tuple(f"tilt_{c}_{lab}" for lab in labels for c in "xy")
    names = UNIT_NAMES + tilt_names
    units = tuple(ls[n].unit for n in UNIT_NAMES) + ("arcsec",) * len(tilt_names)
    k0 = float(np.mean(sol.x[:3]))
    pri = raw_priors(names, k0, scale_unit, problem.sigma_h, overrides=priors,
                     misalignment_sd_arcsec=problem.sigma_a)
    pri, widened = widened_bias_priors(pri, ls, priors)
    cov_ls = scaled_covariance(sol.J)
    z = Z95
    ls_intervals = {n: (ls[n].value - z * ls[n].u, ls[n].value + z * ls[n].u) for n in UNIT_NAMES}
    data = (problem.w.T, 1.0 / problem.se.T, problem.cov_matrix, problem.gravity_g)
    transform = inverse = None
    if shear:
        transform, inverse = conditional_shear(problem.residual_function(), data, pri, names, sol.x,
                                               slow=range(nu, len(names)))
    target = ResidualTarget(
        name="known_poses", residual=problem.residual_function(), data=data,
        names=names, units=units, priors=pri, x_ls=sol.x, cov_ls=cov_ls, sigma=problem.se.reshape(-1),
        ls_intervals=ls_intervals, obs_dim="reading", obs_name="w",
        observed={"w": (("reading",), problem.w.reshape(-1), {"units": scale_unit.split("/")[-1]})},
        obs_coords={"pose": ("reading", np.repeat(np.asarray(labels, str), 3)),
                    "axis": ("reading", np.tile(["x", "y", "z"], problem.n))},
        unit_serial=serial, transform=transform, inverse=inverse)
    prefer = None
    if str(ls.fit.get("placement_sd_source", "")).startswith("integrated"):
        prefer = (f"the sampler holds the placement SD at the data's most probable value "
                  f"({problem.sigma_h / 3600.0:.2g} deg) while the least-squares result integrates it, so its "
                  "intervals are the slightly wider, safer ones")
    result, run = sample_target(target, posterior_path=posterior_path, prefer_least_squares=prefer, **sampler)
    tilts = {n: result.parameters.pop(n) for n in tilt_names}
    for n in tilt_names:
        result.intervals.pop(n, None)
    keep = [i for i, n in enumerate(names) if n in UNIT_NAMES]
    result.correlation = result.correlation[np.ix_(keep, keep)]
    result.correlation_names = UNIT_NAMES
    flags = result.extra["flags"]
    for key in ("non_gaussian", "prior_dominated", "prior_influenced", "prior_pulled"):
        flags[key] = [n for n in flags[key] if n in UNIT_NAMES]
    result.notes = [n for n in result.notes if not n.startswith("tilt_")] + widened + list(ls.notes)
    result.extra["sampler"]["coordinates"] = (
        "sheared: the walkers move along the placement tilts; the unit parameters about their conditional "
        "optimum given the tilts" if transform is not None else "whitened (Laplace approximation)")
    result.fit.update({"model": ls.fit["model"], "placement_sd_deg": ls.fit["placement_sd_deg"],
                       "placement_sd_source": ls.fit.get("placement_sd_source"),
                       "misalignment_sd_deg": ls.fit.get("misalignment_sd_deg"),
                       "n_nuisance": len(tilt_names),
                       "least_squares": {"status": ls.status, "estimator": ls.fit.get("estimator"),
                                         "parameters": {n: {"value": ls[n].value, "u": ls[n].u}
                                                        for n in UNIT_NAMES}}})
    result.extra["placement_tilts"] = [
        {"pose": lab, "tilt_x_deg": tilts[f"tilt_x_{lab}"].value / 3600.0,
         "tilt_y_deg": tilts[f"tilt_y_{lab}"].value / 3600.0,
         "u_deg": [tilts[f"tilt_x_{lab}"].u / 3600.0, tilts[f"tilt_y_{lab}"].u / 3600.0]} for lab in labels]
    return result, run
