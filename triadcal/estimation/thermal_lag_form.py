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
from scipy import optimize, stats

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
#: the search range of the bridge through a gap (min): a chamber's air settles in minutes, a housing
#: thermometer in tens of minutes; 9 grid points over it (a factor 2.6 apart): chi^2 is sharp in the
#: bridge (on an Euler-integrated stepped campaign 17.9, 1.07, 19.2 at 1, 5, 10 min)
BRIDGE_SEARCH_MIN = (0.1, 300.0)


#: an interval between consecutive visits longer than this many times their median spacing (and
#: than GAP_MIN_MIN) is a gap of the record: the thermometer's history through it is not measured
GAP_FACTOR, GAP_MIN_MIN = 10.0, 10.0


def gap_threshold_s(campaign: Campaign) -> float:
    """An interval between consecutive visits longer than this (s) is a gap of the record:
    ``GAP_FACTOR`` times the median spacing and at least ``GAP_MIN_MIN`` min."""
    t = np.sort(np.asarray(campaign.time_s, float))
    d = np.diff(t)
    med = float(np.median(d[d > 0])) if np.any(d > 0) else 0.0
    return max(GAP_FACTOR * med, 60.0 * GAP_MIN_MIN)


def record_gaps(campaign: Campaign) -> np.ndarray:
    """Lengths (min) of the gaps in the thermometer's record: intervals between consecutive visits
    longer than :func:`gap_threshold_s` (the soaks of a stepped campaign, whose temperatures no
    visit records)."""
    t = np.sort(np.asarray(campaign.time_s, float))
    d = np.diff(t)
    if len(d) == 0:
        return np.zeros(0)
    return d[d > gap_threshold_s(campaign)] / 60.0


def _gate_history(campaign: Campaign, tau_min: float, bridge_min: Optional[float] = None) -> GateOutcome:
    """The lag is estimated from the record: a record with gaps (unlogged soaks) leaves the element's
    state after each gap unknown, and the linear interpolation across it biases tau (stepped
    campaign, 2 h soaks: 20 min came out 6.9 +- 0.2 min with chi2/dof 0.99; docs/model.md). With
    the gaps bridged (``bridge_min``, a first-order approach profiled with the lags) the gate
    passes and says so: the bridge is then part of the model, judged by chi^2 and the other gates."""
    gaps = record_gaps(campaign)
    if len(gaps) == 0:
        return GateOutcome("history", True, "unidentifiable",
                           "the thermometer's record is continuous (no interval longer than "
                           f"{GAP_FACTOR:g}x the visits' spacing)", 0.0, "no gap")
    if bridge_min is not None:
        return GateOutcome("history", True, "unidentifiable",
                           f"the record's {len(gaps)} gap(s) of up to {gaps.max():.0f} min are bridged by a first-order "
                           f"approach of {bridge_min:.3g} min (profiled with the lags; docs/model.md)",
                           float(gaps.max()), "no gap, or gaps bridged")
    return GateOutcome("history", False, "unidentifiable",
                       f"thermal_lag = {tau_min:.4g} min is not determined: the thermometer's record has {len(gaps)} "
                       f"gap(s) of up to {gaps.max():.0f} min (soaks no visit records), through which the element's "
                       "history is unknown and the estimate biased; log the temperatures through the soaks, run a "
                       "ramp, bridge the gaps (--bridge-gaps: a first-order approach profiled with the lags), or use "
                       "the rate form (--effects thermal_lag) for a lag much shorter than the soak",
                       float(gaps.max()), "no gap in the record")


def with_element_temperature(campaign: Campaign, tau_min: float, location: str = "housing",
                             tau_housing_min: float = 0.0, bridge_min: Optional[float] = None) -> Campaign:
    """The campaign with each sensor's readings replaced by its element's temperature (the thermal
    terms of the joint model then follow the element); ``bridge_min``: the record's gaps filled by
    a first-order approach of that time constant (``element_temperature``'s ``bridge``)."""
    bridge = None if bridge_min is None else (60.0 * bridge_min, gap_threshold_s(campaign))
    Te = element_temperature(campaign.time_s, campaign.t, 60.0 * tau_min, location, 60.0 * tau_housing_min,
                             bridge=bridge)
    return replace(campaign, t=Te)


def fit_thermal_lag(campaign: Campaign, effects: Sequence[str] = DEFAULT_EFFECTS, location: str = "housing", *,
                    bridge_gaps: bool = False, grid_points: int = 9, inner_iterations: int = 20,
                    location_assumed: bool = False, **fit_kwargs):
    """Joint fit with the element's thermal lag behind its thermometer estimated from the record.

    ``location``: ``"housing"`` (one stage, ``thermal_lag``) or ``"air"`` (the housing lags the air by
    ``thermal_lag_housing``, the element lags the housing by ``thermal_lag``; the two stages commute,
    so the data give the pair and the longer one is reported as the housing's). ``effects``: the
    rest of the joint model (``thermal_lag`` in it is ignored: the lag is this function's).
    ``bridge_gaps``: fill the record's gaps (:func:`record_gaps`) with a first-order approach
    (``models/effects/thermal_lag.bridge_record``) whose time constant is profiled with the lags
    over ``SEARCH_MIN`` (a step to nearly a straight line); kept in ``fit["thermal_lag"]["bridge"]``,
    not among the unit's parameters (it is the chamber's, not the unit's). Returns a
    :class:`~triadcal.estimation.result.CalibrationResult` with ``thermal_lag`` (and
    ``thermal_lag_housing``) in min, every other u including the time constants' uncertainty, and
    ``fit["thermal_lag"]`` (location, estimates, profile, search range). ``location_assumed``: the
    location was not stated by the caller but taken because the record leaves no choice (the
    bridged air form of :func:`fit_thermal_lag_history`): the result is then refused by the gate
    ``location`` (:func:`_gate_location`), since one stage behind a housing thermometer can fit such
    a record as well as two behind the air."""
    if location not in LOCATIONS:
        raise InputError(f"unknown thermometer location {location!r}; choose one of {', '.join(LOCATIONS)}")
    if bridge_gaps and location != "air":
        raise InputError("--bridge-gaps needs the thermometer in the chamber air (--thermal-lag-form air): the air "
                         "approaches a new setpoint as the chamber's first-order response, which the bridge is; a "
                         "housing lags the air and the chamber, two stages, which it is not (on a stepped campaign of "
                         "tests/independent_bench.py a housing's 20 min lag came out 20.52 +- 0.08 min with it)")
    effects = [e for e in effects if e != "thermal_lag"]
    lo, hi = math.log(SEARCH_MIN[0]), math.log(SEARCH_MIN[1])
    two = location == "air"
    bridged = bool(bridge_gaps) and len(record_gaps(campaign)) > 0
    thr = gap_threshold_s(campaign)

    blo, bhi = math.log(BRIDGE_SEARCH_MIN[0]), math.log(BRIDGE_SEARCH_MIN[1])

    def taus(theta):
        """(tau_element, tau_housing, tau_bridge or None) in min from the search coordinates (log min)."""
        theta = np.asarray(theta, float)
        th = np.exp(np.clip(theta, lo, hi))
        tb = float(np.exp(np.clip(theta[-1], blo, bhi))) if bridged else None
        if two:
            a, b = sorted(th[:2])
            return float(a), float(b), tb      # element: the shorter; housing: the longer
        return float(th[0]), 0.0, tb

    def element_of(te, th, tb):
        return element_temperature(campaign.time_s, campaign.t, 60.0 * te, location, 60.0 * th,
                                   bridge=None if tb is None else (60.0 * tb, thr))

    def element(theta):
        return element_of(*taus(theta))

    theta0 = np.array(([math.log(5.0), math.log(20.0)] if two else [math.log(5.0)])
                      + ([math.log(10.0)] if bridged else []))
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
        profile.append(taus(theta) + (float(s.cost),))
        return float(s.cost) if np.isfinite(s.cost) else 1e300

    # coarse grid in log tau, then a local refinement
    n_grid = grid_points if not two else max(grid_points - 2, 5)
    if two and bridged:
        n_grid = 5
    g = np.linspace(lo, hi, n_grid)
    pts = [[a, b] for i, a in enumerate(g) for b in g[i:]] if two else [[a] for a in g]
    if bridged:
        gb = np.linspace(blo, bhi, 9)
        pts = [p + [b] for p in pts for b in gb]
    pts = [np.array(p) for p in pts]
    vals = [chi2(p) for p in pts]
    step = g[1] - g[0]
    if len(pts[0]) > 1:
        # Nelder-Mead from the best grid point, and with the bridge from the next two too (the
        # bridge and the lags trade against each other: one start found a local minimum with the
        # bridge near a straight line, chi2/dof 1.27 against 0.96, on the air-lag validation campaign)
        starts = [pts[i] for i in np.argsort(vals)[:3 if bridged else 1]]
        best_res = None
        for best in starts:
            if two and abs(best[0] - best[1]) < step / 2:
                # the pair is symmetric (the stages commute): on the diagonal a simplex cannot tell
                # which way to split, so it starts split by half a grid step
                best = best.copy()
                best[:2] = best[:2] + np.array([-step / 2, step / 2])
            half = np.array([step / 2] * (len(best) - (1 if bridged else 0))
                            + ([(bhi - blo) / 16] if bridged else []))       # half a grid step each
            simplex = [best] + [best + half[k] * np.eye(len(best))[k] for k in range(len(best))]
            res = optimize.minimize(chi2, best, method="Nelder-Mead",
                                    options={"xatol": 1e-3, "fatol": 1e-4, "initial_simplex": simplex})
            if best_res is None or res.fun < best_res.fun:
                best_res = res
        theta_hat = best_res.x
    else:
        best = pts[int(np.argmin(vals))]
        a, b = max(best[0] - step, lo), min(best[0] + step, hi)
        res = optimize.minimize_scalar(lambda v: chi2(np.array([v])), bounds=(a, b), method="bounded",
                                       options={"xatol": 1e-5})
        theta_hat = np.array([res.x])
    te, th, tb = taus(theta_hat)

    result, problem, sol = fit_joint(with_element_temperature(campaign, te, location, th, tb), effects,
                                     return_problem=True, **fit_kwargs)
    # the time constants' columns of the Jacobian: central differences in log tau at the optimum
    names_tau = ["thermal_lag"] + (["thermal_lag_housing"] if two else [])
    values_tau = [te] + ([th] if two else [])
    if bridged:
        names_tau.append("thermal_lag_bridge")
        values_tau.append(tb)
    cols = []
    for k, v in enumerate(values_tau):
        h = 0.02
        rs = []
        for sgn in (1.0, -1.0):
            tt = list(values_tau)
            tt[k] = v * math.exp(sgn * h)
            problem.cov_matrix[2:5] = element_of(tt[0], tt[1] if two else 0.0, tt[-1] if bridged else None).T
            rs.append(problem.residuals(sol.x) * np.sqrt(sol.weights))
        cols.append((rs[0] - rs[1]) / (v * (math.exp(h) - math.exp(-h))))
    problem.cov_matrix[2:5] = element_of(te, th, tb).T
    sw = np.sqrt(sol.weights)
    J_cond = sol.J * sw[:, None]
    bridge_block = None
    if bridged:
        # the bridge at a limit of its range (a step, a straight line) moves nothing: its column is
        # then left out (it would only make the Jacobian singular) and its u is not given
        informative = float(np.linalg.norm(cols[-1]) * tb) > 1e-6 * max(float(np.linalg.norm(J_cond)), 1e-300)
        bridge_block = {"tau_min": tb, "u_min": None, "min_gap_min": thr / 60.0,
                        "gaps": int(len(record_gaps(campaign))),
                        "equation": "T(s) = T1 + (T0 - T1) (exp(-s/tau_b) - exp(-D/tau_b)) / (1 - exp(-D/tau_b))"}
        if not informative:
            names_tau, values_tau, cols = names_tau[:-1], values_tau[:-1], cols[:-1]
    J_full = np.column_stack([J_cond] + cols)
    # a play of the element's temperature (a hysteresis of every thermal term) against the lag
    play_sig = play_signature(problem, sol.x, campaign.time_s, problem.cov_matrix[2:5].T, sw)
    dropped = 1 if bridged and "thermal_lag_bridge" not in names_tau else 0     # profiled all the same
    dof = sol.r.size - J_full.shape[1] - dropped
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
        u = float(math.sqrt(max(cov_full[m + k, m + k], 0.0)))
        if n == "thermal_lag_bridge":
            bridge_block["u_min"] = u
            continue
        result.parameters[n] = ParameterValue(float(v), u, "min")
    # a parameter the data do not move (zero variance) correlates with nothing
    d = np.sqrt(np.clip(np.diag(cov_full), 0.0, None))
    dd = np.outer(d, d)
    corr = np.divide(cov_full, dd, out=np.zeros_like(cov_full), where=dd > 0)
    np.fill_diagonal(corr, 1.0)
    result.correlation_names = tuple(problem.names) + tuple(names_tau)
    result.correlation = corr
    result.effects = tuple(result.effects) + ("thermal_lag",)
    result.fit["n_params"] = J_full.shape[1] + dropped
    result.fit["chi2_dof"] = chi2_val / dof if dof > 0 else float("nan")
    prof = sorted(profile)
    result.fit["thermal_lag"] = {
        "form": "history", "location": location,
        "equation": ("dT_e/dt = (t_a - T_e)/tau" if not two else
                     "dT_h/dt = (t_a - T_h)/tau_h, dT_e/dt = (T_h - T_e)/tau"),
        "tau_min": te, "tau_housing_min": th if two else None, "search_min": list(SEARCH_MIN),
        "bridge": bridge_block,
        "profile": [{"tau_min": a, "tau_housing_min": (b if two else None),
                     **({"bridge_min": tb_} if bridged else {}), "cost": c} for a, b, tb_, c in prof],
        "evaluations": len(profile)}
    play = thermal_play_test(campaign, play_sig, sol.r * sw, J_full, list(problem.names) + list(names_tau),
                             np.sqrt(np.clip(np.diag(cov_full), 0.0, None)),
                             1.0 if noise_known else math.sqrt(chi2_val / max(dof, 1)))
    if play is not None:
        result.fit["thermal_play"] = play[0]
    # the gates again, with the time constants among the free parameters
    result.status = "ok"
    result.notes = [n for n in result.notes if not n.startswith("gate ")]
    ev = FitEvidence(converged=sol.converged, cost_start=None, cost_final=sol.cost, jacobian=J_full,
                     free_names=tuple(problem.names) + tuple(names_tau), chi2=chi2_val, dof=dof,
                     noise_known=noise_known,
                     extra=[_gate_history(campaign, te, tb)] + ([play[1]] if play is not None else [])
                     + ([_gate_location(names_tau, values_tau, cov_full, m)] if location_assumed else []))
    apply_gates(result, ev)
    note = one_rate_note(campaign, te, result.parameters["thermal_lag"].u, play[0] if play is not None else None)
    if note:
        result.notes.append(note)
    if bridged:
        result.notes.append(f"thermal_lag: the record's gaps bridged by a first-order approach of {tb:.3g} min"
                            + (f" +- {bridge_block['u_min']:.2g}" if bridge_block["u_min"] is not None else
                               " (at a limit of its range: a step or a straight line)")
                            + " profiled with the lags (fit.thermal_lag.bridge)")
    return result


#: the half-width (degC) of the play of the element's temperature whose signature is computed
PLAY_PROBE_C = 1.0


def play_of_visits(time_s, T, half_width_C: float) -> np.ndarray:
    """Each column of ``T`` (visits x sensors) through the play operator in the visits' time order
    (:func:`triadcal.models.thermal_history.play_operator`, started mid-band)."""
    from ..models.thermal_history import play_operator

    order = np.argsort(np.asarray(time_s, float), kind="stable")
    T = np.asarray(T, float)
    out = np.empty_like(T)
    for j in range(T.shape[1]):
        out[order, j] = play_operator(T[order, j], half_width_C)
    return out


def play_signature(problem, x, time_s, element_T, sw) -> np.ndarray:
    """The weighted residuals' change per degC at ``x`` when the element's temperatures
    ``element_T`` (visits x sensors) pass through a play of :data:`PLAY_PROBE_C` in time order: the
    problem's temperature rows moved by ``play(T_e) - T_e`` (the rate form's element is the row less
    tau dT/dt, the history form's the row itself), restored after."""
    base = problem.cov_matrix[2:5].copy()
    Te = np.asarray(element_T, float)
    delta = play_of_visits(time_s, Te, PLAY_PROBE_C) - Te
    r0 = problem.residuals(x)
    problem.cov_matrix[2:5] = base + delta.T
    try:
        r1 = problem.residuals(x)
    finally:
        problem.cov_matrix[2:5] = base
    return (r1 - r0) * np.asarray(sw, float) / PLAY_PROBE_C


def rate_form_play(result, campaign, problem, sol, sw, u, noise_scale: float):
    """The gate ``thermal_play`` and the one-rate note of a joint fit with the rate-form
    ``thermal_lag`` (the element at ``T - tau dT/dt``): as :func:`thermal_play_test` for the history
    forms. ``[]`` without the lag or with a non-finite Jacobian."""
    lag = result.parameters.get("thermal_lag")
    J = sol.J * np.asarray(sw, float)[:, None]
    if lag is None or not np.all(np.isfinite(J)) or not np.all(np.isfinite(u)):
        return []
    Te = np.asarray(campaign.t, float) - 60.0 * lag.value * campaign.temperature_rate()
    play = thermal_play_test(campaign, play_signature(problem, sol.x, campaign.time_s, Te, sw),
                             sol.r * np.asarray(sw, float), J, list(problem.names), np.asarray(u, float), noise_scale)
    note = one_rate_note(campaign, lag.value, lag.u, play[0] if play is not None else None)
    if note:
        result.notes.append(note)
    if play is None:
        return []
    result.fit["thermal_play"] = play[0]
    return [play[1]]


#: the play's score |z| beyond which the lag's fit misses a hysteresis of its thermal terms (two-sided 0.1 %)
PLAY_Z_MAX = float(stats.norm.isf(0.0005))


def thermal_play_test(campaign, signature, r_w, J, names, u, noise_scale: float):
    """``(block, gate)``: does the element's temperature run through a play (a hysteresis of every
    thermal term: the element's temperature stays until the reading has moved a band of 2 r, as
    ``thermal-cycle``'s play form), which a lag takes up? ``signature``: the weighted residuals' change
    per degC when the element's temperatures pass through a play of :data:`PLAY_PROBE_C` in time order
    (:func:`play_of_visits`); projected off the fit's Jacobian ``J`` (the lags' columns in it), its
    score on the weighted residuals ``r_w`` estimates the play, ``r = -b'r / |b|^2`` degC (linear about
    the probe's width) with SD ``noise_scale / |b|``, and ``z = r / SD`` (normal under a model without
    a play). The gate ``thermal_play`` (``model_mismatch``) fails beyond |z| > :data:`PLAY_Z_MAX`.

    An outside probe (its own simulator): ramps 20, -40, 70, 20 degC at 1 degC/min, the element 10
    min behind a housing thermometer, its temperature through a play of 1 degC: tau 11.5-11.75 +- 0.07
    min (22-25 u) and K_x's tempco 4-6 u off, status ok 9 of 10. The play's signature moves tau by 24 u
    per degC; the residuals measure it to 0.1 degC. None when the signature is 0 (no turn)."""
    from .structure import _confounding

    b = np.asarray(signature, float)
    conf = _confounding(J, names, u, b, noise_scale)
    if conf is None or conf["sd"] is None:
        return None
    perp = conf["perp"]
    nn = float(perp @ perp)
    r_hat = -float(perp @ np.asarray(r_w, float)) / nn
    sd = float(conf["sd"])
    z = r_hat / sd
    block = {"probe_half_width_C": PLAY_PROBE_C, "half_width_C": r_hat, "sd_C": sd, "z": z,
             "visible_fraction": conf["visible_fraction"], "moves_u_per_C": conf["moves_u"],
             "equation": "T_e -> play(T_e, r) in time order; r = -b'r/|b|^2 with b the signature off the model's span"}
    moves = ", ".join(f"{n} by {abs(m):.2g} u" for n, m in conf["moves_u"].items())
    ok = abs(z) <= PLAY_Z_MAX
    txt = (f"a play of the element's temperature (a hysteresis of the thermal terms) measured from the residuals: "
           f"r = {r_hat:+.3g} +- {sd:.2g} degC (z {z:+.2g}); 1 degC of it, left out, moves {moves}")
    if not ok:
        txt += (": the lag takes up a hysteresis of the thermal terms (or another effect of its shape at the turns), "
                "so tau and the tempcos are biased; `triadcal thermal-cycle` names the form on a one-pose record, "
                "`triadcal diagnose` on the campaign")
    return block, GateOutcome("thermal_play", ok, "model_mismatch", txt, abs(z), f"|z| <= {PLAY_Z_MAX:.3g}")


#: visits whose |dT/dt| (degC/min) exceeds this are on a ramp; ramps whose rates (75th over 25th
#: percentile over those visits) differ by less than ONE_RATE_SPREAD run at one rate
RAMP_RATE_MIN, ONE_RATE_SPREAD = 0.2, 1.5


def one_rate_note(campaign, tau_min: float, u_tau_min: float, play: Optional[dict]) -> Optional[str]:
    """The note of a lag fitted on ramps of one rate v (the campaign's measured rates): there the lag
    is the element's delay ``tau v`` behind the thermometer, and a play of half-width r of the
    element's temperature adds ``r / v`` to tau, a thermometer lagging the element takes its own lag
    off, and an offset of the biases between heating and cooling reads as a lag (an outside probe: +-2 ug
    at 0.5 degC/min read a 4 min lag as 4.24 +- 0.03, status ok); only the turns tell them apart
    (``play``: :func:`thermal_play_test`'s block, what the
    residuals measured of a play). None for a stepped campaign or ramps of several rates."""
    rate = getattr(campaign, "dTdt_C_per_min", None)
    if rate is None:
        return None
    r = np.abs(np.asarray(rate, float))
    r = r[r > RAMP_RATE_MIN]
    if len(r) < 8:
        return None
    lo, hi = (float(x) for x in np.percentile(r, [25, 75]))
    if not lo > 0 or hi / lo >= ONE_RATE_SPREAD:
        return None
    v = 0.5 * (lo + hi)
    seen = ("" if play is None else
            f"; the residuals measured r = {play['half_width_C']:+.2g} +- {play['sd_C']:.2g} degC (fit.thermal_play), "
            f"so tau holds to about {2 * play['sd_C'] / v:.2g} min ({2 * play['sd_C'] / v / u_tau_min:.2g} u) "
            "against a play below that")
    return (f"thermal_lag: the ramps run at {lo:.2g}-{hi:.2g} degC/min, one rate: tau = {tau_min:.4g} min is the "
            f"element's delay behind its thermometer there; a play of half-width r of the element's temperature "
            f"would add r/v ({1.0 / v:.2g} min per degC), a thermometer lagging the element would take its own lag "
            f"off, an offset of the biases between heating and cooling (a bias hysteresis, which the model does not "
            f"hold: its hysteresis is the angles') reads as a lag of that offset over v times the bias tempco, and "
            f"only the turns tell them apart{seen}; a ramp at another rate (half or twice) separates them")


def _gate_location(names_tau, values_tau, cov_full, m: int) -> GateOutcome:
    """Gate ``location`` of the air's form taken on a record with gaps without a stated location
    (``fit --thermal-lag-form history``): it always fails. The bridge is the air's form, but a record
    read only at its visits does not show where the thermometer sits, and one stage behind a
    thermometer on the housing fits it as well as two behind the air -- with a split that looks
    resolved: on the independent bench's stepped campaigns with the thermometer on the housing and
    the element 20 min behind it, the bridged air form gave 3.7 +- 0.7 and 15.9 +- 0.6 min (chi2/dof
    1.1), and 1.6 +- 0.9 and 18.3 +- 0.5 min on another. The numbers stay in the result; the
    answer needs the location stated (``--thermal-lag-form air --bridge-gaps``)."""
    stages = "; ".join(f"{n} = {v:.3g} +- {math.sqrt(max(cov_full[m + k, m + k], 0.0)):.2g} min"
                       for k, (n, v) in enumerate(zip(names_tau, values_tau)) if n != "thermal_lag_bridge")
    return GateOutcome("location", False, "unidentifiable",
                       "the record has gaps (soaks no visit records), so the data do not show where the "
                       f"thermometer sits: the air's two stages ({stages}) fit it, and so would one stage "
                       "behind a thermometer on the housing, with another split; state the location "
                       "(--thermal-lag-form air --bridge-gaps, the thermometer in the chamber air) or log the "
                       "record through the soaks")


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


#: level of the likelihood ratio by which the air's second stage must lower chi^2 to be kept
#: (known noise), and the p-value of chi^2 above which the housing's one stage already fits
LOCATION_LEVEL = 0.99


def housing_suffices(chi2_housing: float, dof: int, noise_known: bool) -> bool:
    """With known noise, the housing's one stage already within the noise (chi^2 p >= 1 - level):
    the air's second stage is not looked for. With the noise estimated there is no such test."""
    return bool(noise_known and stats.chi2.sf(chi2_housing, max(dof, 1)) >= 1.0 - LOCATION_LEVEL)


def air_kept(chi2_housing: float, chi2_air: float, n_obs: int, noise_known: bool) -> tuple:
    """Whether the thermometer is taken to be in the air: the housing's form is the air's with the
    housing's stage at zero (nested, one time constant more), so the air is kept only when it beats
    the housing by the likelihood ratio at ``LOCATION_LEVEL`` (known noise: chi^2 with 1 dof) or by
    the AIC (noise estimated: scale-free, margin 0). Returns ``(kept, text)``
    (:func:`~triadcal.estimation.hysteresis_form.nested_criterion`). Used by ``fit`` with the
    history form and by the diagnosis's ``thermal_lag_history`` candidate."""
    from .hysteresis_form import nested_criterion

    return nested_criterion(chi2_housing, chi2_air, 1, n_obs, noise_known, "chi2_housing - chi2_air",
                            level=LOCATION_LEVEL, aic_margin=0.0)


def _chi2_of(result) -> tuple:
    """(chi^2, dof, n_obs) of a result of :func:`fit_thermal_lag`."""
    n = int(result.fit["n_obs"])
    dof = n - int(result.fit["n_params"])
    return float(result.fit["chi2_dof"]) * dof, dof, n


def fit_thermal_lag_history(campaign: Campaign, effects: Sequence[str] = DEFAULT_EFFECTS, **fit_kwargs):
    """The lag over the temperature history with the thermometer's location chosen by the data
    (``fit --thermal-lag-form history``, ``--effects ...,thermal_lag_history``): the rule of the
    diagnosis's candidate of that name. On a continuous record (a ramp, a logged soak) the housing's
    one stage, and the air's two only when the housing's is not within the noise
    (:func:`housing_suffices`) and the air beats it (:func:`air_kept`). A record with gaps (the soaks
    of a stepped campaign) does not show the location: it is fitted in the air's form with the gaps
    bridged (the only form the bridge is, see :func:`fit_thermal_lag`), and refused by the gate
    ``location`` until the location is stated. ``fit.thermal_lag.location_choice`` says why."""
    gaps = record_gaps(campaign)
    if len(gaps):
        res = fit_thermal_lag(campaign, effects, "air", bridge_gaps=True, location_assumed=True, **fit_kwargs)
        why = (f"the record has {len(gaps)} gap(s) of up to {gaps.max():.0f} min (soaks no visit records): "
               "the air's form, the only one the bridge is, taken without a choice: not an answer until the "
               "location is stated (gate location)")
    else:
        res = fit_thermal_lag(campaign, effects, "housing", **fit_kwargs)
        chi2_h, dof_h, n = _chi2_of(res)
        noise_known = bool(res.fit.get("noise_known", True))
        why = f"housing: chi2 {chi2_h:.4g}"
        if housing_suffices(chi2_h, dof_h, noise_known):
            why += " is within the noise; the air's second stage not looked for"
        else:
            air = fit_thermal_lag(campaign, effects, "air", **fit_kwargs)
            chi2_a = _chi2_of(air)[0]
            kept, crit = air_kept(chi2_h, chi2_a, n, noise_known)
            why += f", air: chi2 {chi2_a:.4g}; {crit}: " + ("the air kept" if kept else "the housing kept")
            if kept:
                res = air
    res.fit["thermal_lag"]["location_choice"] = why
    res.fit["thermal_lag"]["form_requested"] = "history (location chosen by the data)"
    res.notes.append(f"thermal_lag_history: thermometer location {res.fit['thermal_lag']['location']} ({why})")
    return res
