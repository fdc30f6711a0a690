"""The thermal lag estimated from the measured temperature history, for either location of the
thermometer (docs/model.md, "Thermal lag: where the thermometer sits").

The joint model's ``thermal_lag`` effect uses the rate form ``T_e = T_s - tau dT_s/dt``, first
order in ``tau`` against the record's own time scale: a lag of 2 min behind a unit that settles
in 20 min is described, one of 90 min is not. Here the element's temperature is the record passed
through the lag itself (:func:`triadcal.models.effects.thermal_lag.element_temperature`: one
first-order stage behind a housing thermometer, two behind an air thermometer), and the time
constants are profiled: for each ``tau`` the joint model (without ``thermal_lag``) is fitted with
the thermal terms at the element's temperature, and ``tau`` minimises chi^2. The search runs over
``log tau`` within [0.05, 3000] min, so a time constant is positive by construction; the answer
gate (``time_constants``) then refuses one outside [0.5, 300] min (no lag in the data, or one no
campaign can measure), with the number.

The uncertainty of ``tau`` and its effect on every other parameter come from the Jacobian with the
``tau`` column added (central differences of the residuals at the optimum), ``(J^T J)^-1``; the
profile (chi^2 against tau) is kept in ``fit.thermal_lag``.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Optional, Sequence

import numpy as np
from scipy import optimize

from ..errors import InputError
from ..models.campaign import Campaign
from ..models.effects import DEFAULT_EFFECTS
from ..models.effects.thermal_lag import LOCATIONS, element_temperature
from .gates import FitEvidence, GateOutcome, apply_gates
from .joint import fit_joint, levenberg_marquardt, scaled_covariance
from .result import ParameterValue

#: the search range of every time constant (min): wider than the gate's [0.5, 300] min so that a
#: lag the data do not hold comes out below it and is refused, not pinned at the gate's edge
SEARCH_MIN = (0.05, 3000.0)


#: an interval between consecutive visits longer than this many times their median spacing (and
#: than GAP_MIN_MIN) is a gap of the record: the thermometer's history through it is not measured
GAP_FACTOR, GAP_MIN_MIN = 10.0, 10.0


def record_gaps(campaign: Campaign) -> np.ndarray:
    """Lengths (min) of the gaps in the thermometer's record: intervals between consecutive visits
    longer than ``GAP_FACTOR`` times the median spacing and than ``GAP_MIN_MIN`` min (the soaks of
    a stepped campaign, whose temperatures no visit records)."""
    t = np.sort(np.asarray(campaign.time_s, float))
    d = np.diff(t)
    if len(d) == 0:
        return np.zeros(0)
    med = float(np.median(d[d > 0])) if np.any(d > 0) else 0.0
    return d[(d > GAP_FACTOR * med) & (d > 60.0 * GAP_MIN_MIN)] / 60.0


def _gate_history(campaign: Campaign, tau_min: float) -> GateOutcome:
    """The lag is estimated from the record: a record with gaps (unlogged soaks) leaves the element's
    state after each gap unknown, and the linear interpolation across it biases tau (stepped
    campaign, 2 h soaks: 20 min came out 6.9 +- 0.2 min with chi2/dof 0.99; docs/model.md)."""
    gaps = record_gaps(campaign)
    if len(gaps) == 0:
        return GateOutcome("history", True, "unidentifiable",
                           "the thermometer's record is continuous (no interval longer than "
                           f"{GAP_FACTOR:g}x the visits' spacing)", 0.0, "no gap")
    return GateOutcome("history", False, "unidentifiable",
                       f"thermal_lag = {tau_min:.4g} min is not determined: the thermometer's record has {len(gaps)} "
                       f"gap(s) of up to {gaps.max():.0f} min (soaks no visit records), through which the element's "
                       "history is unknown and the estimate biased; log the temperatures through the soaks, run a "
                       "ramp, or use the rate form (--effects thermal_lag) for a lag much shorter than the soak",
                       float(gaps.max()), "no gap in the record")


def with_element_temperature(campaign: Campaign, tau_min: float, location: str = "housing",
                             tau_housing_min: float = 0.0) -> Campaign:
    """The campaign with each sensor's readings replaced by its element's temperature (the thermal
    terms of the joint model then follow the element)."""
    Te = element_temperature(campaign.time_s, campaign.t, 60.0 * tau_min, location, 60.0 * tau_housing_min)
    return replace(campaign, t=Te)


def fit_thermal_lag(campaign: Campaign, effects: Sequence[str] = DEFAULT_EFFECTS, location: str = "housing", *,
                    grid_points: int = 9, inner_iterations: int = 20, **fit_kwargs):
    """Joint fit with the element's thermal lag behind its thermometer estimated from the record.

    ``location``: ``"housing"`` (one stage, ``thermal_lag``) or ``"air"`` (the housing lags the air by
    ``thermal_lag_housing``, the element lags the housing by ``thermal_lag``; the two stages commute,
    so the data give the pair and the longer one is reported as the housing's). ``effects``: the
    rest of the joint model (``thermal_lag`` in it is ignored: the lag is this function's). Returns a
    :class:`~triadcal.estimation.result.CalibrationResult` with ``thermal_lag`` (and
    ``thermal_lag_housing``) in min, every other u including the time constants' uncertainty, and
    ``fit["thermal_lag"]`` (location, estimates, profile, search range)."""
    if location not in LOCATIONS:
        raise InputError(f"unknown thermometer location {location!r}; choose one of {', '.join(LOCATIONS)}")
    effects = [e for e in effects if e != "thermal_lag"]
    lo, hi = math.log(SEARCH_MIN[0]), math.log(SEARCH_MIN[1])
    two = location == "air"

    def taus(theta):
        """(tau_element, tau_housing) in min from the search coordinates (log min)."""
        if two:
            a, b = sorted(np.exp(np.clip(theta, lo, hi)))
            return float(a), float(b)          # element: the shorter; housing: the longer
        return float(math.exp(min(max(theta[0], lo), hi))), 0.0

    def element(theta):
        te, th = taus(theta)
        return element_temperature(campaign.time_s, campaign.t, 60.0 * te, location, 60.0 * th)

    theta0 = np.array([math.log(5.0), math.log(20.0)] if two else [math.log(5.0)])
    _, problem, sol0 = fit_joint(replace(campaign, t=element(theta0)), effects, return_problem=True, **fit_kwargs)
    loss, nu = fit_kwargs.get("loss", "l2"), fit_kwargs.get("nu", 4.0)
    state = {"x": sol0.x, "best": math.inf}
    profile = []

    def chi2(theta):
        problem.cov_matrix[2:5] = element(theta).T
        # warm start from the best point so far: the rest of the model is nearly linear, a few steps
        # converge (the LM stops early once its own test is met)
        s = levenberg_marquardt(problem, state["x"], loss=loss, nu=nu, max_iter=inner_iterations)
        if np.isfinite(s.cost) and s.cost < state["best"]:
            state["x"], state["best"] = s.x, float(s.cost)
        te, th = taus(theta)
        profile.append((te, th, float(s.cost)))
        return float(s.cost) if np.isfinite(s.cost) else 1e300

    # coarse grid in log tau, then a local refinement
    g = np.linspace(lo, hi, grid_points if not two else max(grid_points - 2, 5))
    if two:
        pts = [np.array([a, b]) for i, a in enumerate(g) for b in g[i:]]
    else:
        pts = [np.array([a]) for a in g]
    vals = [chi2(p) for p in pts]
    best = pts[int(np.argmin(vals))]
    step = g[1] - g[0]
    if two:
        # the pair is symmetric (the stages commute): on the diagonal a simplex cannot tell which way
        # to split, so it starts split by half a grid step
        if abs(best[0] - best[1]) < step / 2:
            best = best + np.array([-step / 2, step / 2])
        res = optimize.minimize(chi2, best, method="Nelder-Mead",
                                options={"xatol": 1e-3, "fatol": 1e-4, "initial_simplex":
                                         [best, best + [step / 2, 0], best + [0, step / 2]]})
        theta_hat = res.x
    else:
        a, b = max(best[0] - step, lo), min(best[0] + step, hi)
        res = optimize.minimize_scalar(lambda v: chi2(np.array([v])), bounds=(a, b), method="bounded",
                                       options={"xatol": 1e-5})
        theta_hat = np.array([res.x])
    te, th = taus(theta_hat)

    result, problem, sol = fit_joint(with_element_temperature(campaign, te, location, th), effects,
                                     return_problem=True, **fit_kwargs)
    # the time constants' columns of the Jacobian: central differences in log tau at the optimum
    names_tau = ["thermal_lag"] + (["thermal_lag_housing"] if two else [])
    values_tau = [te] + ([th] if two else [])
    cols = []
    for k, v in enumerate(values_tau):
        h = 0.02
        rs = []
        for sgn in (1.0, -1.0):
            tt = list(values_tau)
            tt[k] = v * math.exp(sgn * h)
            Te = element_temperature(campaign.time_s, campaign.t, 60.0 * tt[0], location,
                                     60.0 * (tt[1] if two else 0.0))
            problem.cov_matrix[2:5] = Te.T
            rs.append(problem.residuals(sol.x) * np.sqrt(sol.weights))
        cols.append((rs[0] - rs[1]) / (v * (math.exp(h) - math.exp(-h))))
    problem.cov_matrix[2:5] = element_temperature(campaign.time_s, campaign.t, 60.0 * te, location, 60.0 * th).T
    sw = np.sqrt(sol.weights)
    J_cond = sol.J * sw[:, None]
    J_full = np.column_stack([J_cond] + cols)
    dof = sol.r.size - J_full.shape[1]
    chi2_val = float(np.sum(sol.r ** 2))
    cov_cond = scaled_covariance(J_cond)
    cov_full = scaled_covariance(J_full)
    noise_known = bool(result.fit.get("noise_known", True))
    if not noise_known and dof > 0:
        factor = chi2_val / dof
        cov_cond, cov_full = cov_cond * factor, cov_full * factor
    # every parameter's u gains what the time constants' uncertainty adds to it
    for i, n in enumerate(problem.names):
        pv = result.parameters[n]
        extra_var = max(float(cov_full[i, i] - cov_cond[i, i]), 0.0)
        result.parameters[n] = replace(pv, u=math.sqrt(pv.u ** 2 + extra_var))
    m = len(problem.names)
    for k, (n, v) in enumerate(zip(names_tau, values_tau)):
        result.parameters[n] = ParameterValue(float(v), float(math.sqrt(max(cov_full[m + k, m + k], 0.0))), "min")
    d = np.sqrt(np.clip(np.diag(cov_full), 1e-300, None))
    result.correlation_names = tuple(problem.names) + tuple(names_tau)
    result.correlation = cov_full / np.outer(d, d)
    result.effects = tuple(result.effects) + ("thermal_lag",)
    result.fit["n_params"] = J_full.shape[1]
    result.fit["chi2_dof"] = chi2_val / dof if dof > 0 else float("nan")
    prof = sorted(profile)
    result.fit["thermal_lag"] = {
        "form": "history", "location": location,
        "equation": ("dT_e/dt = (t_a - T_e)/tau" if not two else
                     "dT_h/dt = (t_a - T_h)/tau_h, dT_e/dt = (T_h - T_e)/tau"),
        "tau_min": te, "tau_housing_min": th if two else None, "search_min": list(SEARCH_MIN),
        "profile": [{"tau_min": a, "tau_housing_min": (b if two else None), "cost": c} for a, b, c in prof],
        "evaluations": len(profile)}
    # the gates again, with the time constants among the free parameters
    result.status = "ok"
    result.notes = [n for n in result.notes if not n.startswith("gate ")]
    ev = FitEvidence(converged=sol.converged, cost_start=None, cost_final=sol.cost, jacobian=J_full,
                     free_names=tuple(problem.names) + tuple(names_tau), chi2=chi2_val, dof=dof,
                     noise_known=noise_known, extra=[_gate_history(campaign, te)])
    apply_gates(result, ev)
    return result


def profile_interval(result, level: float = 1.0) -> Optional[tuple]:
    """The range of ``thermal_lag`` (min) over which the profiled cost stays within ``level`` of its
    minimum (68 % for a known noise at level 1), from ``fit.thermal_lag.profile``; None without it."""
    block = result.fit.get("thermal_lag") if hasattr(result, "fit") else None
    if not block:
        return None
    pts = [(p["tau_min"], p["cost"]) for p in block["profile"]]
    cmin = min(c for _, c in pts)
    inside = [t for t, c in pts if c <= cmin + level]
    return (min(inside), max(inside)) if inside else None
