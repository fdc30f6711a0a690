"""Entry points: :func:`sample` (``triadcal sample``: the posterior of the joint model over a
campaign) and :func:`sample_target` (any :class:`ResidualTarget`, used by ``fit-raw --sample``).
"""

from __future__ import annotations

from ...errors import InputError

import math
import time
from dataclasses import replace
from typing import Callable, Mapping, Optional, Sequence, Union

import numpy as np

from ...models.campaign import Campaign
from ...models.effects import DEFAULT_EFFECTS
from ...models.effects.quantisation import NAME as NAME_QUANTISATION
from ..quantisation_form import positive_lsb
from ...models.model import Model
from ..gates import DEFAULT_CONFIG, GateConfig, config_of
from ..joint import (
    BenchErrors,
    JointProblem,
    with_bench_errors,
    fit_joint,
    noise_of,
)
from ..priors import Prior, autoscaled_priors, default_priors
from ..result import Z95, CalibrationResult
from .export import write_inference_data, write_target_inference_data
from .laplace import _transformed_laplace, laplace_approximation
from .moves import MOVES
from .options import check_sampler_options, walkers_for
from .run import MAX_SAVED_DRAWS, run_sampler
from .summary import (
    PRIOR_DOMINATED_RATIO,
    _flags_block,
    _result,
    intervals_to_use,
    recommendation_note,
    posterior_notes,
    posterior_summary,
    sampler_info,
)
from .targets import LogPosterior, ResidualLogPosterior, ResidualProblem, ResidualTarget


def _load(data) -> Campaign:
    if isinstance(data, Campaign):
        return data
    from ...io.bench_csv import read_bench_csv
    return read_bench_csv(data)


def sample(data, effects: Sequence[str] = DEFAULT_EFFECTS, *, reference_temperature_C: float = 20.0,
           ess: float = 2000, rhat_max: float = 1.01, tau_factor: float = 50.0, max_steps: int = 20000,
           n_walkers: Optional[int] = None, seed: int = 0, priors: Optional[Mapping[str, Prior]] = None,
           moves: str = "de-snooker-laplace", progress: Union[bool, Callable, None] = None,
           json_path=None, posterior_path=None, max_saved_draws: int = MAX_SAVED_DRAWS,
           return_run: bool = False, least_squares: Optional[tuple] = None,
           gates: Optional[GateConfig] = None, bench_errors: Optional[BenchErrors] = None,
           systematics: Sequence = (), quantisation_lsb: Optional[float] = None):
    """Posterior of every parameter of the joint model (``triadcal sample``).

    ``data``: a bench CSV v1 path or a :class:`Campaign`. ``ess``: requested bulk and
    tail ESS of every parameter; ``max_steps``: the cap after which the result says
    ``status: not_converged``. ``progress``: True for a tqdm bar (stderr), or a callable
    ``f(steps, max_steps, check)`` called every 50 steps (``check`` is None between
    convergence checks, else the dict of the check). ``priors``: overrides
    of :func:`default_priors` by name. Writes results-json v1 to ``json_path`` and an
    arviz InferenceData netCDF to ``posterior_path`` when given. Returns the
    :class:`CalibrationResult` (method ``posterior``), or ``(result, run)`` with
    ``return_run``. ``least_squares``: the output of ``fit_joint(campaign, effects,
    return_problem=True)`` when the caller already has it (it is computed otherwise).
    ``gates``: the answer gates' thresholds (:class:`~triadcal.estimation.gates.GateConfig`).
    ``bench_errors``: the lab's random bench errors, variance components of the noise as in
    the joint fit (:func:`~triadcal.estimation.joint.with_bench_errors`). ``systematics``: the
    lab's systematic errors (:func:`triadcal.uncertainty.typeb.systematic_sources`),
    propagated through the least squares and combined with the posterior's SD in each ``u``.
    ``effects`` may name the noise effects (:mod:`triadcal.estimation.noise_effects`):
    ``position_error`` (the bench's random errors estimated from the residuals and held there, a
    plug-in variance component) and ``heavy_tails`` (the unit-variance Student-t likelihood, its
    dof held at the profile-likelihood value).
    ``effects`` may name ``quantisation`` (a digital output rounded to an LSB q, one for the three
    outputs, output unit; ``quantisation_lsb`` given implies it): the least-squares fit with the term
    (:func:`~triadcal.estimation.quantisation_form.fit_quantisation`, q given or profiled) runs first,
    then the posterior of the model's parameters with the outputs ``W + e(W; q, sigma)``
    (:func:`~triadcal.models.effects.quantisation.error_expression`), q and the per-sample sigma held
    at the fit's values (a plug-in, stated in the notes); ``fit.quantisation`` in the result.
    """
    gates = gates or DEFAULT_CONFIG
    if moves not in MOVES:
        raise InputError(f"unknown moves {moves!r}; choose one of {', '.join(MOVES)}")
    # the options first (docs/posterior.md, "Options and their ranges"): before anything is read or fitted
    check_sampler_options(ess=ess, max_steps=max_steps, seed=seed, rhat_max=rhat_max, tau_factor=tau_factor)
    campaign = _load(data)
    from ..joint import single_temperature_reference

    reference_temperature_C = single_temperature_reference(campaign, reference_temperature_C)[0]
    from ...uncertainty.typeb import effects_with_lab

    from ..noise_effects import resolve_noise_effects

    t_start = time.perf_counter()
    from ..form_names import held_form, resolve_form_names

    effects, h_form, lag_form = resolve_form_names(effects)
    form = None
    if h_form != "offset" or lag_form != "rate":
        if NAME_QUANTISATION in effects or quantisation_lsb is not None:
            raise InputError("sample: quantisation is sampled with the offset hysteresis and the rate-form lag (as in "
                             "fit), not with hysteresis_play, hysteresis_pi or thermal_lag_history")
        campaign, effects, *form = held_form(campaign, effects, h_form, lag_form,
                                             reference_temperature_C=reference_temperature_C, gates=gates,
                                             bench_errors=bench_errors, systematics=systematics)
    quantised = NAME_QUANTISATION in effects or quantisation_lsb is not None
    effects = [e for e in effects if e != NAME_QUANTISATION]
    if quantisation_lsb is not None:
        quantisation_lsb = positive_lsb(quantisation_lsb)
    if quantised and "flicker_noise" in effects:
        raise InputError("sample: quantisation and flicker_noise are not sampled together (the quantised output "
                         "model is not written for the whitened residuals); drop one of them")
    qmap = {}
    if quantised:
        from ..quantisation_form import noise_effects_map

        qmap = noise_effects_map(campaign, effects, quantisation_lsb)
    noise_fx = resolve_noise_effects(campaign, effects, bench_errors=bench_errors,
                                     reference_temperature_C=reference_temperature_C, gates=gates, **qmap)
    effects, bench_errors, nu = noise_fx["effects"], noise_fx["bench_errors"], noise_fx["nu"]
    nu = nu if noise_fx["loss"] == "student_t" else math.inf
    effects, added = effects_with_lab(effects, systematics)
    if noise_fx.get("whitening") is not None:      # flicker_noise: estimation/flicker_noise.py
        return _sample_flicker(campaign, effects, noise_fx, added, locals())
    walkers_for(n_walkers, len(Model(effects, reference_temperature_C).names))   # before the fits
    if least_squares is None and quantised:
        from ..quantisation_form import fit_quantisation

        least_squares = fit_quantisation(campaign, effects, quantisation_lsb,
                                         reference_temperature_C=reference_temperature_C, gates=gates,
                                         bench_errors=bench_errors, systematics=systematics, loss=noise_fx["loss"],
                                         nu=noise_fx["nu"])
    elif least_squares is None:
        least_squares = fit_joint(campaign, effects, reference_temperature_C=reference_temperature_C,
                                  return_problem=True, gates=gates, bench_errors=bench_errors,
                                  systematics=systematics, loss=noise_fx["loss"], nu=noise_fx["nu"],
                                  noise_per_output=True)
    ls, ls_problem, ls_sol = least_squares
    # a rate-form lag on a ramp: against the housing form, as `fit` judges it (lag_validity.ramp_form_check);
    # the least-squares gates carry over to the posterior
    from ..lag_validity import judge_ramp_form

    judge_ramp_form(campaign, ls, effects, dict(
        reference_temperature_C=reference_temperature_C, gates=gates, bench_errors=bench_errors,
        systematics=systematics, loss=noise_fx["loss"], nu=noise_fx["nu"]))
    # the bench's errors correlate the outputs of oblique poses: the fit was GLS (joint._bench_whitening)
    whitening = getattr(ls_problem, "whitening", None)
    model = Model(effects, reference_temperature_C)
    bound = config_of(ls).angle_bound_arcsec         # the bound the least-squares result was judged with
    pri, scaled = autoscaled_priors(default_priors(model, overrides=priors, angle_bound_arcsec=bound),
                                     {n: p.value for n, p in ls.parameters.items()}, user=priors or {},
                                     u={n: p.u for n, p in ls.parameters.items()})
    noise = with_bench_errors(campaign, model, noise_of(campaign), bench_errors)
    sigma = noise.sigma
    notes = ([added] if added else []) + noise_fx["notes"] + scaled
    if not noise.known:
        chi2_dof = ls.fit.get("chi2_dof")
        if not (chi2_dof and np.isfinite(chi2_dof)):
            raise InputError(f"{campaign.source or 'campaign'}: the noise of the outputs is not in the data "
                             "(no sd_* columns, no Q_V2s metadata) and cannot be estimated from the fit")
        q = ls.fit.get("Q_estimate_per_output")        # one level per output (joint.per_output_scale)
        per_output = isinstance(q, list) and len(q) == 3 and all(np.isfinite(v) and v > 0 for v in q)
        sigma = sigma * (np.sqrt(np.asarray(q, float))[None, :] if per_output else math.sqrt(chi2_dof))
        notes.append(f"output noise not in the data: held at its least-squares estimate ({noise.description}; "
                     + (f"variance per unit weight per output {', '.join(f'{v:.3g}' for v in q)}" if per_output
                        else f"variance per unit weight {chi2_dof:.3g}")
                     + ", the estimate itself, not a test of the model); the "
                     "posterior does not include the uncertainty of the noise level, and with the noise estimated "
                     "the model's fit cannot be tested by chi2: `triadcal diagnose` tests the residuals' structure")
    if math.isfinite(nu) and noise_fx.get("t_scale", 1.0) != 1.0:
        sigma = sigma * float(noise_fx["t_scale"])
        notes.append(f"heavy_tails: the Student-t's SD is {noise_fx['t_scale']:.3g} times the output noise's "
                     "(profile likelihood), held at that value (plug-in)")
    quantisation = _held_quantisation(campaign, ls) if quantised else None
    if quantisation is not None:
        from ..quantisation_form import output_map

        q, s_sample = quantisation
        notes.append(f"quantisation: the LSB q = {q:.6g} {campaign.output_unit} and the per-sample sigma "
                     + ", ".join(f"{v:.3g}" for v in np.broadcast_to(s_sample, (3,))) + f" {campaign.output_unit} "
                     "held at the least-squares fit's values (plug-in): the posterior is that of the model's "
                     "parameters given them, without their uncertainty")
    problem = JointProblem(campaign, model, sigma,
                           output_map=None if quantisation is None else output_map(*quantisation))
    if whitening is not None:
        from ..whitening import WhitenedProblem

        problem = WhitenedProblem(problem, whitening)
        notes.append("the bench's errors: the likelihood has the full 3 x 3 covariance of each visit's outputs "
                     "(oblique poses), as the least squares")
    ls_values = dict(zip(ls_problem.names, ls_sol.x))
    x_start = np.array([ls_values.get(n, pri[n].mean) for n in model.names])
    x_map, C = laplace_approximation(problem, pri, x_start)
    Lc = np.linalg.cholesky(C)
    W = walkers_for(n_walkers, len(model.names))
    target = LogPosterior(campaign, model, sigma, pri, x_map, Lc, block=W // 2, nu=nu, quantisation=quantisation,
                          whitening=whitening)
    run = run_sampler(target, W, ess=ess, rhat_max=rhat_max, tau_factor=tau_factor, max_steps=max_steps,
                      seed=seed, moves=moves, progress=progress, max_saved_draws=max_saved_draws)
    total_seconds = time.perf_counter() - t_start
    result = _result(campaign, model, problem, pri, ls, run, notes, total_seconds, ess, rhat_max, tau_factor, max_steps,
                     gates)
    result.extra.update(noise_fx["extra"])
    _attach_form(result, form)
    if quantisation is not None:
        result.fit["quantisation"] = dict(ls.fit["quantisation"], held_in_posterior=True,
                                          posterior="q and sigma_sample held at these values (plug-in)")
    if json_path is not None:
        result.save(json_path)
    if posterior_path is not None:
        write_inference_data(posterior_path, campaign, run, result)
    return (result, run) if return_run else result


def _attach_form(result, form) -> None:
    """The held form's block (``fit.hysteresis`` or ``fit.thermal_lag``, ``held_in_posterior``) and
    note on the posterior's ``result``; when the form's own least-squares fit failed a gate (a time
    constant the data do not resolve, a form that did not converge) the posterior is not an answer
    either: its status becomes that one, with the gate's note."""
    if not form:
        return
    form_ls, key, held = form
    result.fit[key] = dict(form_ls.fit[key], held_in_posterior=True)
    result.notes.append(held + (" (plug-in): the posterior lacks the time constants' uncertainty, which the "
                                "least-squares u includes (fit.thermal_lag)" if key == "thermal_lag" else
                                " (plug-in): the posterior is that of the model's parameters given them "
                                "(fit.hysteresis)"))
    if form_ls.status != "ok" and result.status == "ok":
        result.status = form_ls.status
        result.notes.append(f"the least-squares fit of the form ({key}) has status {form_ls.status!r}: "
                            + "; ".join(n for n in form_ls.notes if n.startswith("gate ")))


def _held_quantisation(campaign, ls):
    """``(q, sigma_sample)`` of the least-squares fit with the quantisation term (its
    ``fit.quantisation`` block; sigma per visit and axis as the fit used it)."""
    from ..quantisation_form import sample_sigma_of

    block = ls.fit.get("quantisation")
    if not block:
        raise InputError("sample with quantisation: the least-squares fit given has no fit.quantisation block "
                         "(fit it with fit_quantisation, or let sample fit it)")
    q = float(block["lsb"])
    s, why = sample_sigma_of(campaign, q)
    if s is None:
        raise InputError(f"{campaign.source or 'campaign'}: {why}")
    return q, np.asarray(s, float)


def _sample_flicker(campaign, effects, noise_fx, added, kw):
    """``sample`` with ``flicker_noise``: the posterior of the whitened (GLS) residuals, B_f held at
    its REML value (:func:`_sample_gls` with this fit's whitening; with the noise estimated the white
    level is held at the GLS estimate, ``noise_scale = sqrt(chi2/dof)``)."""
    ls = fit_joint(campaign, effects, reference_temperature_C=kw["reference_temperature_C"], return_problem=True,
                   gates=kw["gates"], bench_errors=noise_fx["bench_errors"], systematics=kw["systematics"],
                   whitening=noise_fx["whitening"])
    notes = ["flicker_noise: the likelihood has the full covariance of the visit means (residuals whitened per "
             "output), B_f held at its REML value (plug-in)"]
    scale = 1.0
    if not ls[0].fit.get("noise_known", True):
        chi2_dof = ls[0].fit.get("chi2_dof")
        if not (chi2_dof and np.isfinite(chi2_dof)):
            raise InputError(f"{campaign.source or 'campaign'}: the noise of the outputs is not in the data "
                             "and cannot be estimated from the fit (no degrees of freedom left)")
        scale = math.sqrt(chi2_dof)
        notes.append(f"output noise not in the data: the white level held at its estimate with B_f (REML, "
                     f"chi2/dof of the whitened residuals = {chi2_dof:.3g}); the posterior does not include the "
                     "uncertainty of the noise level")
    return _sample_gls(campaign, effects, ls, noise_fx["whitening"], noise_fx, added, kw, notes,
                       name="joint_flicker_gls", noise_scale=scale)


def _sample_gls(campaign, effects, ls, whitening, noise_fx, added, kw, gls_notes, name="joint_gls",
                noise_scale: float = 1.0):
    """The posterior of the residuals whitened as the least-squares fit ``ls`` whitened them
    (:func:`triadcal.estimation.whitening.gls_posterior_target`)."""
    from ..whitening import gls_posterior_target

    target = gls_posterior_target(campaign, effects, ls, whitening, kw["priors"], kw["reference_temperature_C"],
                                  name=name, noise_scale=noise_scale)
    notes = ([added] if added else []) + noise_fx["notes"] + list(gls_notes) + [
        f"prior of {n}: {p.reason}" for n, p in target.priors.items() if p.reason.startswith(("autoscaled", "widened"))]
    result, run = sample_target(target, ess=kw["ess"], rhat_max=kw["rhat_max"], tau_factor=kw["tau_factor"],
                                max_steps=kw["max_steps"], n_walkers=kw["n_walkers"], seed=kw["seed"],
                                moves=kw["moves"], progress=kw["progress"], posterior_path=kw["posterior_path"],
                                max_saved_draws=kw["max_saved_draws"], notes=notes)
    result.extra.update(noise_fx["extra"])
    _attach_form(result, kw.get("form"))
    if kw["json_path"] is not None:
        result.save(kw["json_path"])
    return (result, run) if kw["return_run"] else result


def sample_target(target: ResidualTarget, *, ess: float = 2000, rhat_max: float = 1.01, tau_factor: float = 50.0,
                  max_steps: int = 20000, n_walkers: Optional[int] = None, seed: int = 0,
                  moves: str = "de-snooker-laplace", progress: Union[bool, Callable, None] = None,
                  posterior_path=None, max_saved_draws: int = MAX_SAVED_DRAWS, notes: Sequence[str] = (),
                  prefer_least_squares: Optional[str] = None):
    """Posterior of a :class:`ResidualTarget` through the bench's path: MAP and Laplace
    approximation from the least-squares optimum (:func:`laplace_approximation`), whitened
    coordinates, the same emcee moves and stop rule (:func:`run_sampler`), the same value,
    intervals and flags (:func:`posterior_summary`). Returns ``(CalibrationResult, PosteriorRun)``
    (method ``posterior``); writes the InferenceData to ``posterior_path`` when given.
    ``prefer_least_squares``: why the least-squares intervals are the ones to use (the posterior
    holds fixed something the least squares integrate); the result then recommends them."""
    if moves not in MOVES:
        raise InputError(f"unknown moves {moves!r}; choose one of {', '.join(MOVES)}")
    check_sampler_options(ess=ess, max_steps=max_steps, seed=seed, rhat_max=rhat_max, tau_factor=tau_factor)
    d = len(target.names)
    W = walkers_for(n_walkers, d)
    t_start = time.perf_counter()
    problem = ResidualProblem(target)
    if target.transform is None:
        x_map, C = laplace_approximation(problem, target.priors, target.x_ls)
    else:
        y_map, C = _transformed_laplace(problem, np.asarray(target.inverse(target.x_ls)).reshape(-1))
    # Cholesky of the column-scaled covariance (parameters differ by 10 orders of magnitude)
    D = np.sqrt(np.diag(C))
    Lc = np.linalg.cholesky(C / np.outer(D, D)) * D[:, None]
    lp = ResidualLogPosterior(target, x_map if target.transform is None else y_map, Lc, block=W // 2)
    if target.transform is not None:
        x_map = np.asarray(target.transform(y_map)).reshape(-1)
    run = run_sampler(lp, W, ess=ess, rhat_max=rhat_max, tau_factor=tau_factor, max_steps=max_steps,
                      seed=seed, moves=moves, progress=progress, max_saved_draws=max_saved_draws)
    total_seconds = time.perf_counter() - t_start
    names = list(target.names)
    params, intervals, non_gaussian, prior_dominated = posterior_summary(names, target.units, run, target.priors,
                                                                         target.ls_intervals)
    out_notes = posterior_notes(intervals, non_gaussian, prior_dominated, target.ls_intervals, run, ess, rhat_max,
                                tau_factor, max_steps, list(notes))
    # prior-influenced: the least-squares (data-only) uncertainty is comparable to the prior's,
    # so the prior, not the data, sets the posterior's width (weaker than prior-dominated)
    prior_influenced = []
    for n in names:
        if n in target.ls_intervals:
            lo_, hi_ = target.ls_intervals[n]
            ratio = float((hi_ - lo_) / (2 * Z95) / target.priors[n].sd)
            intervals[n]["ls_prior_sd_ratio"] = ratio
            if ratio > PRIOR_DOMINATED_RATIO and n not in prior_dominated:
                prior_influenced.append(n)
                out_notes.append(f"{n}: prior-influenced (least-squares SD / prior SD = {ratio:.2f} > "
                                 f"{PRIOR_DOMINATED_RATIO}): the data alone determine it poorly; the prior "
                                 f"narrows its interval (posterior SD / prior SD = {intervals[n]['prior_sd_ratio']:.2f})")
    rec = intervals_to_use(non_gaussian, target.ls_intervals, prefer_least_squares, intervals=intervals)
    out_notes.append(recommendation_note(rec))
    draws = run.flat()
    x_mean = draws.mean(axis=0)
    chi2 = float(np.sum(ResidualProblem(replace(target, transform=None, inverse=None)).residuals(x_mean) ** 2))
    n_obs = target.n_obs
    fit = {"chi2_dof": chi2 / (n_obs - d) if n_obs > d else None, "n_obs": n_obs, "n_params": d,
           "value": "posterior mean", "u": "posterior standard deviation",
           "map": dict(zip(names, map(float, x_map)))}
    result = CalibrationResult(
        unit=target.unit_serial, method="posterior", parameters=params,
        status="ok" if run.converged else "not_converged", intervals=intervals, fit=fit,
        correlation_names=tuple(names), correlation=np.corrcoef(draws, rowvar=False), notes=out_notes,
        extra={"priors": {n: target.priors[n].to_dict() for n in names},
               "flags": {**_flags_block(non_gaussian, prior_dominated, intervals), "prior_influenced": prior_influenced},
               "intervals_to_use": rec,
               "sampler": sampler_info(run, names, total_seconds, ess, rhat_max, tau_factor, max_steps)})
    result.extra["flags"]["criteria"]["prior_influenced"] = (f"least-squares SD / prior SD > {PRIOR_DOMINATED_RATIO} "
                                                             "(and not prior-dominated)")
    if posterior_path is not None:
        write_target_inference_data(posterior_path, target, run, result)
    return result, run

