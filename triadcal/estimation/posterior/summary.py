"""From draws to a result: posterior mean and SD, 95 % central and HDI intervals, flags of
prior-dominated and non-Gaussian parameters, the sampler block and the CalibrationResult.
"""

from __future__ import annotations

import math
from typing import Mapping, Optional, Sequence

import numpy as np
from scipy import stats

from ...models.kinematics import tilt_polar
from ...models.units import ARCSEC, DEG
from ..gates import DEFAULT_CONFIG, FitEvidence, GateConfig, GateOutcome, apply_gates
from ..joint import (
    noise_of,
    parameter_unit,
)
from ..priors import Prior
from ..result import Z95, CalibrationResult, ParameterValue
from .diagnostics import _arviz
from .run import PosteriorRun

#: posterior SD / prior SD above which a parameter is reported as prior-dominated
PRIOR_DOMINATED_RATIO = 0.5


#: an end of the 95 % central interval that differs from the least-squares one by more
#: than this fraction of the least-squares half-width flags the posterior as non-Gaussian
NON_GAUSSIAN_TOLERANCE = 0.15


LEVEL = 0.95


def _ls_notes(ls) -> list:
    """The least-squares fit's notes for the posterior's result; its gate lines say they are the
    least squares' (the posterior's own gates add theirs, with the posterior's numbers)."""
    return [f"least squares: {n}" if n.startswith("gate ") else n for n in ls.notes]


def posterior_summary(names: Sequence[str], units: Sequence[str], run: PosteriorRun, pri: Mapping[str, Prior],
                      ls_intervals: Mapping[str, tuple]):
    """Value (posterior mean), ``u`` (posterior SD), the 95 % central and HDI intervals beside the
    least-squares ones (``ls_intervals``: name -> (low, high)), and the flags of every parameter.
    Returns ``(params, intervals, non_gaussian, prior_dominated)``. Shared by the bench and the
    generic residual target."""
    az = _arviz()
    draws = run.flat()
    mean = draws.mean(axis=0)
    sd = draws.std(axis=0, ddof=1)
    lo, hi = np.quantile(draws, [(1 - LEVEL) / 2, (1 + LEVEL) / 2], axis=0)
    params, intervals = {}, {}
    non_gaussian, prior_dominated = [], []
    kept = run.draws()
    for i, n in enumerate(names):
        params[n] = ParameterValue(float(mean[i]), float(sd[i]), units[i])
        h = az.hdi(kept[:, :, i].ravel(), hdi_prob=LEVEL)
        iv = {"level": LEVEL, "low": float(lo[i]), "high": float(hi[i]),
              "hdi_low": float(h[0]), "hdi_high": float(h[1]), "ls_low": None, "ls_high": None}
        ratio = float(sd[i] / pri[n].sd)
        iv["prior_sd_ratio"] = ratio
        if n in ls_intervals:
            iv["ls_low"], iv["ls_high"] = (float(v) for v in ls_intervals[n])
            half = 0.5 * (iv["ls_high"] - iv["ls_low"])
            dev = max(abs(iv["low"] - iv["ls_low"]), abs(iv["high"] - iv["ls_high"]))
            differs = bool(half > 0 and dev > NON_GAUSSIAN_TOLERANCE * half) or not half > 0
            # why it differs: a posterior of Gaussian shape (its quantile interval within the tolerance of
            # mean +- z SD), no wider than the least squares, differs from them by the prior -- moved or
            # narrowed by it
            # (an outside probe: bias tempcos of +-950 ug/degC on a 2 degC campaign, pulled 2.2 SD toward
            # the default prior's 0, were called non-Gaussian and their posterior intervals, which held 10
            # of 21 truths, recommended over the least squares', which held 19)
            own = Z95 * float(sd[i])
            own_dev = max(abs(iv["low"] - (mean[i] - own)), abs(iv["high"] - (mean[i] + own)))
            # (not wider than the least squares: a prior only narrows; a wider posterior is the least squares'
            # too narrow an interval, a parameter it held fixed -- the heating-only campaign's hysteresis)
            pulled = (differs and half > 0 and own > 0 and own_dev <= NON_GAUSSIAN_TOLERANCE * own
                      and own <= (1.0 + NON_GAUSSIAN_TOLERANCE) * half)
            iv["ls_shift_in_u"] = (float((mean[i] - 0.5 * (iv["ls_low"] + iv["ls_high"])) / (half / Z95))
                                   if half > 0 else None)
            iv["prior_pulled"] = bool(pulled)
            iv["non_gaussian"] = bool(differs and not pulled)
            # the least-squares interval reaches beyond the prior's bound (a thermal lag of 0): the data do
            # not exclude the bound, which no central interval of the truncated posterior can hold
            iv["ls_beyond_bound"] = bool(iv["ls_low"] < pri[n].low or iv["ls_high"] > pri[n].high)
        else:
            iv["non_gaussian"] = True     # the least-squares fit could not determine it: no Gaussian interval
        iv["prior_dominated"] = ratio > PRIOR_DOMINATED_RATIO
        if iv["non_gaussian"]:
            non_gaussian.append(n)
        if iv["prior_dominated"]:
            prior_dominated.append(n)
        intervals[n] = iv
    return params, intervals, non_gaussian, prior_dominated


def posterior_notes(intervals: Mapping[str, dict], non_gaussian, prior_dominated, ls_names, run: PosteriorRun,
                    ess, rhat_max, tau_factor, max_steps, notes: Optional[list] = None) -> list:
    """The notes of the flags and of a run that did not converge (appended to ``notes``)."""
    notes = [] if notes is None else notes
    for n in prior_dominated:
        notes.append(f"{n}: prior-dominated (posterior SD / prior SD = {intervals[n]['prior_sd_ratio']:.2f} > "
                     f"{PRIOR_DOMINATED_RATIO}): the data do not measure it; its value is the prior's, not a measurement")
    for n in prior_pulled(intervals):
        if n in prior_dominated:
            continue
        iv = intervals[n]
        notes.append(f"{n}: the prior moved or narrowed the posterior (Gaussian in shape) away from the least squares: "
                     f"mean {iv['ls_shift_in_u']:+.2g} of the least-squares u from its value, SD "
                     f"{iv['prior_sd_ratio']:.2g} of the prior's; a prior-data conflict or a parameter the data "
                     "determine weakly")
    for n in non_gaussian:
        if n in prior_dominated:
            continue
        if n in ls_names:
            notes.append(f"{n}: the 95% posterior interval differs from the least-squares one by more than "
                         f"{NON_GAUSSIAN_TOLERANCE:.0%} of its half-width (a non-Gaussian posterior, or parameters "
                         "the least-squares fit held fixed)")
        else:
            notes.append(f"{n}: the least-squares fit could not determine it; only the posterior interval exists")
    if not run.converged:
        why = "; ".join(stop_rule_failures(run, ess, rhat_max, tau_factor))
        notes.insert(0, f"not converged within {max_steps} steps: the stop rule (chain >= {tau_factor:g} tau, "
                        f"ESS >= {ess:g}, R-hat < {rhat_max}) did not hold: {why}; do not use these intervals")
    return notes


def _worst(values, names, bad, pick) -> tuple:
    """``(value, name, how many fail)`` of the worst parameter by ``pick`` (np.nanargmin or
    np.nanargmax; a nan, a value that cannot be computed, is the worst) among those ``bad`` flags."""
    values = np.asarray(values, float)
    nan = np.flatnonzero(~np.isfinite(values))
    k = int(nan[0]) if nan.size else int(pick(values))
    return float(values[k]), names[k], int(np.sum(bad))


def _more(n: int) -> str:
    return f" and {n - 1} more" if n > 1 else ""


def stop_rule_failures(run: PosteriorRun, ess, rhat_max, tau_factor) -> list:
    """What broke the stop rule of a run that did not converge, with the numbers and the parameter:
    the verdict's own R-hat and bulk/tail ESS (on the saved draws, ``sampler.per_parameter``), the
    chain's length in autocorrelation times, then the cheap screens of the last look (ESS ~ W N / tau,
    classic split R-hat), which gate arviz's numbers (docs/posterior.md, Stop rule)."""
    diag = run.diagnostics
    names = list(run.names)
    out = []
    rhat = np.asarray(diag["rhat"], float)
    bad = ~(rhat < rhat_max)
    if bad.any():
        v, n, k = _worst(rhat, names, bad, np.nanargmax)
        out.append(f"R-hat {v:.4f} of {n}{_more(k)} >= {rhat_max:g}")
    for kind in ("bulk", "tail"):
        e = np.asarray(diag[f"ess_{kind}"], float)
        bad = ~(e >= ess)
        if bad.any():
            v, n, k = _worst(e, names, bad, np.nanargmin)
            out.append(f"smallest {kind} ESS {v:.0f} ({n}{_more(k)}) < {ess:g}")
    tau = np.asarray(diag["tau"], float)
    kept = int(run.kept_z.shape[0])           # saved draws per walker (tau is in the same draws)
    if not np.all(np.isfinite(tau)) or kept < tau_factor * np.nanmax(tau):
        v, n, _ = _worst(tau, names, ~np.isfinite(tau), np.nanargmax)
        unit = f"saved draws (every {run.thin}th step)" if run.thin > 1 else "steps"
        out.append(f"chain of {kept} {'saved draws' if run.thin > 1 else 'steps after the burn-in'} per walker "
                   f"< {tau_factor:g} tau = {tau_factor * v:.0f} (tau {v:.1f} {unit}, of {n})")
    if not out and run.checks:
        last = run.checks[-1]
        if not last["ess_estimate"] >= ess:
            out.append(f"the last look's ESS screen (walkers x steps / tau) {last['ess_estimate']:.0f} < {ess:g}")
        if not last["rhat_classic_max"] < rhat_max:
            out.append(f"the last look's classic split R-hat {last['rhat_classic_max']:.4f} >= {rhat_max:g}")
    if not out:
        out.append("the run stopped before its last look could confirm the rule")
    return out


def prior_pulled(intervals: Mapping[str, dict]) -> list:
    """The parameters whose Gaussian posterior the prior moved or narrowed away from the least squares
    (``posterior_summary``'s ``prior_pulled``)."""
    return [n for n, iv in intervals.items() if iv.get("prior_pulled")]


def beyond_bound(intervals: Mapping[str, dict]) -> list:
    """The non-Gaussian parameters whose least-squares interval reaches beyond their prior's bound."""
    return [n for n, iv in intervals.items() if iv.get("ls_beyond_bound") and iv.get("non_gaussian")]


def intervals_to_use(non_gaussian: Sequence[str], ls_names, prefer_least_squares: Optional[str] = None,
                     intervals: Optional[Mapping[str, dict]] = None) -> dict:
    """The one recommendation of a posterior result: which 95 % intervals to use, and why.

    ``prefer_least_squares``: the reason the least-squares intervals are the safer ones (the
    posterior holds a quantity fixed that the least squares integrate). The least squares' too
    where the prior moved or narrowed a Gaussian posterior away from them (``intervals``'
    ``prior_pulled``: a posterior interval then holds the unit's value only as far as the prior
    describes the unit, the least-squares one whatever the unit is), or where a parameter's
    least-squares interval reaches beyond its prior's bound (the data do not exclude the bound, a
    central posterior interval cannot hold it). Otherwise the posterior's, which hold whether or not
    it is Gaussian."""
    differ = [n for n in non_gaussian if n in ls_names]
    if prefer_least_squares:
        return {"use": "least_squares", "why": prefer_least_squares}
    ivs = intervals or {}
    pulled = [n for n in prior_pulled(ivs) if n in ls_names]
    bound = [n for n in beyond_bound(ivs) if n in ls_names]
    if pulled or bound:
        why = []
        if pulled:
            worst = max(pulled, key=lambda n: abs(ivs[n].get("ls_shift_in_u") or 0.0))
            why.append(f"the prior moves or narrows the posterior of {_listed(pulled)} away from the least squares "
                       f"(the mean of {worst} by {abs(ivs[worst]['ls_shift_in_u']):.2g} of its least-squares u): a "
                       "posterior interval holds the unit's value only as far as the prior describes the unit, the "
                       "least-squares one whatever it is")
        if bound:
            why.append(f"the least-squares interval of {_listed(bound)} reaches beyond the prior's bound: the data do "
                       "not exclude the bound, which a central posterior interval cannot hold")
        return {"use": "least_squares", "why": "; ".join(why)}
    # a non-Gaussian parameter the least squares held (not determined by the data alone) has no least-squares
    # interval to agree with: "agree within 15 %" was said of an outside probe's thermal_lag, prior-dominated,
    # its least-squares interval None
    alone = [n for n in non_gaussian if n not in ls_names]
    if differ or alone:
        why = []
        if differ:
            why.append(f"the posterior is not Gaussian for {', '.join(differ)}: its quantile intervals hold where the "
                       "least-squares ones do not")
        if alone:
            why.append(f"{_listed(alone)} {'has' if len(alone) == 1 else 'have'} no least-squares interval (the data "
                       "alone do not determine it) and a posterior that is not Gaussian: its interval holds only as "
                       "far as the prior describes the unit (flags.prior_dominated says whether the prior sets it)")
        return {"use": "posterior", "why": "; ".join(why)}
    return {"use": "posterior", "why": (f"the posterior and least-squares intervals agree within "
                                        f"{NON_GAUSSIAN_TOLERANCE:.0%} of their half-width; the posterior's are "
                                        "reported")}


def _listed(names, most: int = 4) -> str:
    return ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most else "")


def recommendation_note(rec: dict) -> str:
    which = ("the least-squares (intervals' ls_low/ls_high, fit.least_squares)" if rec["use"] == "least_squares"
             else "the posterior")
    return f"intervals to use: {which} 95 % intervals, because {rec['why']}"


def sampler_info(run: PosteriorRun, names: Sequence[str], total_seconds, ess, rhat_max, tau_factor,
                 max_steps) -> dict:
    """The ``sampler`` block of a posterior result (moves, stop rule, diagnostics per parameter)."""
    diag = run.diagnostics
    return {
        "library": "emcee", "moves": run.moves, "walkers": int(run.chain_z.shape[1]),
        "steps": int(run.chain_z.shape[0]), "burn": int(run.burn), "acceptance": run.acceptance,
        "tau_max": float(diag["tau"].max()), "ess_bulk_min": float(diag["ess_bulk"].min()),
        "ess_tail_min": float(diag["ess_tail"].min()), "rhat_max": float(diag["rhat"].max()),
        # the last look's screen, part of the verdict: walkers as chains, not rank-normalised (an outside
        # probe: not_converged with every stored number passing, R-hat 1.006, the screen's 1.0107 unstored)
        "rhat_classic_max": float(run.checks[-1]["rhat_classic_max"]) if run.checks else None,
        "converged": bool(run.converged), "saved_draws": int(run.kept_z.shape[0] * run.kept_z.shape[1]),
        "thin": int(run.thin),
        "verdict": "computed once on the saved draws (the posterior file holds exactly these); consumers read it",
        "stop_rule": {"tau_factor": tau_factor, "ess": ess, "rhat_max": rhat_max, "max_steps": max_steps,
                      "chains": "walkers as chains (see docs/posterior.md)"},
        "compiled": bool(run.target.compiled), "sampling_seconds": run.seconds, "total_seconds": total_seconds,
        "per_parameter": {n: {"tau": float(diag["tau"][k]), "ess_bulk": float(diag["ess_bulk"][k]),
                              "ess_tail": float(diag["ess_tail"][k]), "rhat": float(diag["rhat"][k])}
                          for k, n in enumerate(names)},
    }


def _flags_block(non_gaussian, prior_dominated, intervals: Optional[Mapping[str, dict]] = None) -> dict:
    return {"non_gaussian": non_gaussian, "prior_dominated": prior_dominated,
            "prior_pulled": prior_pulled(intervals or {}),
            "criteria": {"non_gaussian": f"an end of the 95% central interval differs from the "
                                         f"least-squares interval by > {NON_GAUSSIAN_TOLERANCE} x its "
                                         "half-width, or no least-squares interval exists, and the posterior "
                                         "is not of Gaussian shape",
                         "prior_pulled": f"the posterior is of Gaussian shape (its 95% quantile interval within "
                                         f"{NON_GAUSSIAN_TOLERANCE} x its half-width of mean +- 1.96 SD) and differs "
                                         "from the least-squares interval as above: the prior moved or narrowed it",
                         "prior_dominated": f"posterior SD / prior SD > {PRIOR_DOMINATED_RATIO}"}}


def _add_type_b(params: dict, ls, notes: list) -> None:
    """The lab's systematic errors, propagated through the least squares (their budgets in
    ``ls``), combined with each posterior standard deviation: ``u`` becomes the combined
    standard uncertainty; the posterior's intervals stay Type A (said in the notes)."""
    from ...uncertainty.typeb import parameter_fields, with_type_a

    done = False
    for n, p in params.items():
        rows = ls.parameters[n].uncertainty.get("budget") if n in ls.parameters else None
        if rows and any(r.get("type") == "B" for r in rows):       # a Type A row alone: no lab file
            b = with_type_a(n, p.unit, p.u, None, "posterior standard deviation (output noise and the bench's "
                            "random errors)", rows)
            params[n] = ParameterValue(p.value, b.total, p.unit, parameter_fields(b))
            done = True
    if done:
        notes.append("u is the combined standard uncertainty: the posterior's SD with the lab's systematic errors "
                     "(Type B, linearised through the least squares); the 95 % intervals low/high include them (the "
                     "systematic errors drawn from their distributions and added to the draws), type_a_low/high and "
                     "the HDI are the posterior's own")


def _combined_intervals(intervals: dict, params: dict, names, draws: np.ndarray) -> None:
    """With the lab's systematic errors in the budgets: ``low``/``high`` become the 95 % central
    interval of the posterior draws plus the systematic errors drawn from their distributions
    (JCGM 101); the posterior's own (Type A) interval stays as ``type_a_low``/``type_a_high``."""
    from ...uncertainty.typeb import with_type_b_draws

    if not any(params[n].U is not None for n in names):
        return
    comb = with_type_b_draws(draws, [params[n] for n in names])
    lo, hi = np.quantile(comb, [(1 - LEVEL) / 2, (1 + LEVEL) / 2], axis=0)
    for i, n in enumerate(names):
        iv = intervals.get(n)
        if iv is None or params[n].U is None:
            continue
        iv["type_a_low"], iv["type_a_high"] = iv["low"], iv["high"]
        iv["low"], iv["high"] = float(lo[i]), float(hi[i])
        iv["includes"] = "the posterior (Type A) and the lab's systematic errors (Type B), JCGM 101"


def _combined_correlation(cov_draws: np.ndarray, names, params: dict) -> np.ndarray:
    """Correlation of the draws' covariance plus the Type B part ``sum_s c_s c_s^T u_s^2`` (from
    the budget rows' signed sensitivities), so that ``u`` (combined) and the correlation
    describe one covariance."""
    from ...uncertainty.typeb import type_b_covariance

    cov = np.atleast_2d(cov_draws) + type_b_covariance([params[n] for n in names])
    s = np.sqrt(np.diag(cov))
    return cov / np.outer(s, s)


#: residual dof of an estimated noise level below which the least-squares intervals (Student's t) are the
#: ones to use: the posterior holds the level at its estimate, and its z-like intervals then hold the
#: truth less often than 0.94 (P(|t_30| < 1.96) = 0.941; 10 dof: 0.922, 3.3 dof: 0.86)
NOISE_DOF_FOR_POSTERIOR = 30


def _estimated_noise_intervals(ls, ua: Mapping[str, float], intervals: dict) -> Optional[str]:
    """With the noise estimated from the residuals (``ls.fit.noise_dof``): the least-squares intervals
    of ``intervals`` (``ls_low``/``ls_high``, Type A) widened to Student's t on those dof (``ls_k``), and
    below :data:`NOISE_DOF_FOR_POSTERIOR` the reason to use them, which the posterior (the level held
    at its estimate) has not. The flags were judged on the normal intervals (the posterior's own
    basis). None with the noise known."""
    nd = ls.fit.get("noise_dof")
    if not (isinstance(nd, (int, float)) and nd > 0):
        return None
    k = float(stats.t.ppf(0.5 + LEVEL / 2, nd))
    for n, iv in intervals.items():
        if n in ls.parameters and iv.get("ls_low") is not None:
            v = ls.parameters[n].value
            iv["ls_low"], iv["ls_high"], iv["ls_k"] = v - k * ua[n], v + k * ua[n], k
    if nd >= NOISE_DOF_FOR_POSTERIOR:
        return None
    return (f"the output noise is estimated from {nd:.3g} residual degrees of freedom, which the posterior holds at "
            f"its estimate; the least-squares intervals (Student's t, k = {k:.3g}) include the uncertainty of the "
            "level (ls_low/ls_high)")


def _result(campaign, model, problem, pri, ls, run: PosteriorRun, notes, total_seconds, ess, rhat_max, tau_factor,
            max_steps, gates: GateConfig = DEFAULT_CONFIG) -> CalibrationResult:
    names = list(model.names)
    z = Z95
    # the posterior's draws are the Type A part: compare them with the least squares' own (Type A) u
    ua = {n: p.uncertainty.get("u_type_a", p.u) for n, p in ls.parameters.items()}
    ls_intervals = {n: (p.value - z * ua[n], p.value + z * ua[n]) for n, p in ls.parameters.items()}
    params, intervals, non_gaussian, prior_dominated = posterior_summary(
        names, [parameter_unit(model, n, campaign.output_unit) for n in names], run, pri, ls_intervals)
    prefer = _estimated_noise_intervals(ls, ua, intervals)
    draws = run.flat()
    if "tilt_x" in names and "tilt_y" in names:
        i, j = names.index("tilt_x"), names.index("tilt_y")
        delta, beta = tilt_polar(draws[:, i] * ARCSEC, draws[:, j] * ARCSEC)
        delta = np.asarray(delta) / ARCSEC
        beta_mean = math.atan2(np.mean(np.sin(beta)), np.mean(np.cos(beta)))
        dev = np.angle(np.exp(1j * (np.asarray(beta) - beta_mean)))
        params["tilt_delta"] = ParameterValue(float(delta.mean()), float(delta.std(ddof=1)), "arcsec")
        params["tilt_beta"] = ParameterValue(beta_mean / DEG, float(dev.std(ddof=1)) / DEG, "deg")
    _add_type_b(params, ls, notes)
    _combined_intervals(intervals, params, names, draws)
    posterior_notes(intervals, non_gaussian, prior_dominated, ls.parameters, run, ess, rhat_max, tau_factor,
                    max_steps, notes)
    rec = intervals_to_use(non_gaussian, ls.parameters, prefer, intervals=intervals)
    notes.append(recommendation_note(rec))
    corr = _combined_correlation(np.cov(draws, rowvar=False), names, params)
    x_mean = draws.mean(axis=0)
    chi2 = float(np.sum(problem.residuals(x_mean) ** 2))
    n_obs = 3 * campaign.n_visits
    T = campaign.t
    # the parameters the data determine: the least-squares fit's free ones. The others (held there as not
    # identifiable, sampled here from their priors) take no degree of freedom from the data: counted,
    # an outside probe's 12 poses at one temperature (36 observations, 14 determined, 18 tempcos and
    # hysteresis from their priors) had chi2/dof 4.99 on 4 dof, "model_mismatch", where the fit had 0.91 on
    # 22, ok -- 5 of 7 such campaigns refused for a reason that was not so
    n_det = int(ls.fit.get("n_params") or len(names))
    n_det = len(names) if not 0 < n_det <= len(names) else n_det
    fit = {"chi2_dof": chi2 / (n_obs - n_det) if n_obs > n_det else None, "n_obs": n_obs,
           "n_params": len(names), "n_params_determined": n_det,
           "value": "posterior mean", "u": "posterior standard deviation",
           "least_squares": {"status": ls.status, "chi2_dof": ls.fit.get("chi2_dof")},
           "bench_errors": ls.fit.get("bench_errors")}
    result = CalibrationResult(
        unit=ls.unit, method="posterior", parameters=params, effects=tuple(model.effect_names),
        reference_temperature_C=model.reference_temperature_C,
        temperature_range_C=(float(T.min()), float(T.max())), intervals=intervals, fit=fit,
        correlation_names=tuple(names), correlation=corr, notes=notes + _ls_notes(ls),
        extra={"priors": {n: p.to_dict() for n, p in pri.items()},
               "flags": _flags_block(non_gaussian, prior_dominated, intervals), "intervals_to_use": rec,
               "sampler": sampler_info(run, names, total_seconds, ess, rhat_max, tau_factor, max_steps),
               "output_unit": campaign.output_unit,
               "local_g_m_s2": campaign.local_g_m_s2, **campaign.provenance()})
    # the least-squares answer's own gates (fit, rank, physics) carry over: a posterior of a
    # model that does not fit the data is no better an answer than its least-squares fit
    ls_failed = [f"{o['gate']}: {o['reason']}" for o in (ls.extra.get("gates") or {}).get("outcomes", [])
                 if o.get("passed") is False]
    ls_gate = GateOutcome("least_squares", ls.status in ("ok", "not_converged"),
                          ls.status if ls.status != "ok" else "model_mismatch",
                          f"the least-squares fit under the same model has status {ls.status!r}"
                          + (f" (its failed gates: {'; '.join(ls_failed)})" if ls_failed and ls.status != "ok" else ""))
    noise_known = noise_of(campaign).known
    apply_gates(result, FitEvidence(converged=run.converged, n_obs=n_obs, n_free=n_det, chi2=chi2,
                                    dof=n_obs - n_det, noise_known=noise_known, extra=[ls_gate]),
                config=gates)
    return result
