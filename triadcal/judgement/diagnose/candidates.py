"""Which effect explains the gap: score tests of every candidate at the fitted point, refits of
the best, likelihood ratio, PSIS-LOO and cross-branch prediction; the noise candidates
(position_error, heavy_tails) by their own variance and kurtosis scores (docs/diagnosis.md,
"Which").
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize, stats

from ...models.campaign import Campaign
from ...models.effects import EFFECTS, TEMPCO_EFFECTS
from ...models.effects import heavy_tails as ht
from ...models.effects import position_error as pe
from ...models.model import Model
from ...estimation.joint import (
    JointProblem,
    identifiability_problems,
)
from .fitting import FitState, _chol, _fit
from .psis import psis_loo


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


#: a candidate's column of which less than this fraction lies outside the fitted model's span is
#: not identifiable on the design: its parameter's u would be over 1000 times what it is alone, and
#: the direction tested is set by rounding, not by the physics (bench_nonorthogonality on a six-face
#: tumble: 1.6e-6, a score p of 4e-6 and a refit that cannot move, u = 2.8e5 arcsec; a testable
#: candidate of the validation's and the example's designs has 0.33 or more)
SPAN_FRACTION_MIN = 1e-3


def _score_mean(state: FitState, Jc: np.ndarray, Q: np.ndarray, min_fraction: float = 0.0):
    """Score statistic and dof of new columns ``Jc`` (normalised) at the fitted point. The columns
    are scaled to unit norm and projected off the span ``Q``; a direction counts towards the rank
    when its singular value is above 1e-6 of the largest and above ``min_fraction`` (the
    candidates pass :data:`SPAN_FRACTION_MIN`: a column almost in the model's span is not tested)."""
    norms = np.linalg.norm(Jc, axis=0)
    keep = norms > 1e-12 * max(1.0, np.sqrt(state.r.size))
    if not keep.any():
        return None
    Jc = Jc[:, keep] / norms[keep]
    Jt = Jc - Q @ (Q.T @ Jc)
    U, sv, Vt = np.linalg.svd(Jt, full_matrices=False)
    rank = int(np.sum(sv > max(1e-6 * max(sv[0], 1e-300), min_fraction))) if sv.size else 0
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
    """Pointwise log-likelihood of normalised residuals: normal (``nu = inf``) or Student-t, of
    variance ``var_scale`` (per residual) or 1."""
    return ht.logpdf(r, nu, 1.0 if var_scale is None else np.sqrt(var_scale))


def _loo(state: FitState, n_draws: int, rng, var_scale=None, nu=math.inf):
    """PSIS-LOO elpd with Laplace draws from the LS covariance, linearised residuals.

    The left-out unit is a visit (its three outputs together): pointwise values per visit."""
    p = len(state.names)
    L = _chol(state.cov)
    delta = rng.standard_normal((n_draws, p)) @ L.T
    # r is normalised by s; parameters in reporting units; J = dr/dx (normalised)
    rr = state.r[None, :] + delta @ state.J.T
    ll = _loglik_pointwise(rr, var_scale, nu) - (math.log(state.s) if state.s != 1.0 else 0.0)
    ll = ll.reshape(n_draws, -1, 3).sum(axis=2)
    elpd, se, pointwise, k = psis_loo(ll)       # arviz.loo's numbers, vectorised (psis.py)
    return elpd, se, pointwise, float(np.max(k))


def _loglik_total(state: FitState, var_scale=None, nu=math.inf) -> float:
    return float(np.sum(_loglik_pointwise(state.r, var_scale, nu))) - state.r.size * math.log(state.s)


def _fit_position_error(full, campaign, base: FitState, names, sigma, noise_known):
    """ML of the positioning-error variances -- the two bench axes' ``sigma_1^2`` and the wobble's
    ``sigma_2^2`` (eq. 4) -- and of the noise scale when it is estimated, with the full 3 x 3
    covariance of each visit's outputs, ``V_i = s^2 I + sigma_1^2 C1_i + sigma_2^2 C2_i`` (``C1``, ``C2``
    from :func:`~triadcal.estimation.whitening.bench_blocks`), alternating with the GLS refit of the mean (3 rounds).

    The state holds the whitened residuals as flicker's does (``r = L^-1 r_raw * diag(L)``,
    ``var_scale = diag(L)^2``), so that the Gaussian log-likelihood of ``r / sqrt(var_scale)`` with
    ``-log diag(L)`` is the exact one and the tests after the refit see standardised residuals. (A
    diagonal variance made those tests anti-conservative: one bench error moves a visit's outputs
    together; one common sigma for the three errors left a pattern in the scatter that the variance
    family found at the validation's 5"/2".)"""
    from ...estimation.joint import levenberg_marquardt
    from ...estimation.whitening import BlockWhitening, WhitenedProblem, bench_blocks
    from .fitting import _Subset, whitened_state

    sub = _Subset(full, names, base.x_full)
    x = base.x_full[sub.cols].copy()
    taus, log_s2, sol, whitening = np.array([1e-4, 1e-4]), 2 * math.log(base.s), None, None
    eye = np.eye(3)[None]
    for _ in range(3):
        p_int = full.model.to_internal(dict(zip(full.model.names, sub.embed(x))))
        C1 = bench_blocks(full.model, p_int, campaign, sigma, (1.0, 1.0, 0.0))
        C2 = bench_blocks(full.model, p_int, campaign, sigma, (0.0, 0.0, 1.0))
        r_raw = full.residuals(sub.embed(x)).reshape(-1, 3)

        def nll(theta):
            # log-variances held in [-30, 30] (the simplex's expansions may step far: exp overflows)
            theta = np.clip(theta, -30.0, 30.0)
            ls2, lt = (0.0, theta) if noise_known else (theta[0], theta[1:])
            t = np.exp(lt)
            V = math.exp(ls2) * eye + t[0] * C1 + t[1] * C2
            sign, logdet = np.linalg.slogdet(V)
            if not np.all(sign > 0):
                return math.inf
            try:
                q = np.einsum("na,na->n", r_raw, np.linalg.solve(V, r_raw[:, :, None])[:, :, 0])
            except np.linalg.LinAlgError:
                return math.inf
            val = 0.5 * float(np.sum(q + logdet))
            return val if math.isfinite(val) else math.inf
        t0 = np.log(np.maximum(taus, 1e-4))
        t0 = t0 if noise_known else np.concatenate([[log_s2], t0])
        res = optimize.minimize(nll, t0, method="Nelder-Mead",
                                options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 600})
        x_opt = np.clip(res.x, -30.0, 30.0)
        log_s2, lt = (0.0, x_opt) if noise_known else (x_opt[0], x_opt[1:])
        taus = np.where(lt > -12, np.exp(lt), 0.0)
        V = eye + (taus[0] * C1 + taus[1] * C2) / math.exp(log_s2)     # relative to s^2
        whitening = BlockWhitening(V)
        sol = levenberg_marquardt(WhitenedProblem(sub, whitening), x, max_iter=60)
        x = sol.x
    state = whitened_state(names, sub.embed(x), sol, whitening, noise_known)
    # the replicates' differences against the variance the positioning errors add (relative to s^2)
    from .generic import replicate_variance_test, repeat_pairs

    r_fin = full.residuals(sub.embed(x)).reshape(-1, 3) / math.exp(0.5 * log_s2)
    added = (taus[0] * C1 + taus[1] * C2) / math.exp(log_s2)
    keys = zip(np.round(campaign.axis1_deg, 6), np.round(campaign.axis2_deg, 6),
               np.round(np.asarray(campaign.setpoint_C, float), 6))
    rep = replicate_variance_test(r_fin, eye + added, added, *repeat_pairs(keys))
    if rep is not None:
        state.extra_tests["replicates"] = rep
    state.extra_params = {"position_error_sigma": {"value": math.sqrt(taus[0]), "unit": "arcsec"},
                          "position_error_wobble_sigma": {"value": math.sqrt(taus[1]), "unit": "arcsec"}}
    return state


def _fit_heavy_tails(base: FitState):
    """Student-t dof and scale by profile likelihood at the least-squares mean (plug-in): for each
    dof of the grid the scale's maximum (``heavy_tails.profile_scale``), the pair of the largest.
    The scale is free, the noise model's variance is not held: contamination also adds variance
    (models/effects/heavy_tails.py). ``var_scale`` carries the scale squared for every residual."""
    nu, scale, _ = ht.profile_dof(base.r)
    state = FitState(base.names, base.x_full, base.r, base.J, base.cov, base.chi2, base.dof, base.s,
                     base.converged, var_scale=np.full(base.r.shape, scale * scale), nu=nu,
                     extra_params={"heavy_tails_dof": {"value": nu, "unit": "1"},
                                   "heavy_tails_scale": {"value": scale, "unit": "1 (of the noise model's SD)"}})
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


# ----------------------------------------------------------------------------------
# form candidates: refit-only (issue 17 item 5; docs/diagnosis.md "Form candidates")
# ----------------------------------------------------------------------------------
#: candidates that are forms of a registered effect fitted in estimation/ (not effects of the
#: joint model): the play and Prandtl-Ishlinskii hysteresis (hysteresis_form.py) and the lag over
#: the temperature history (thermal_lag_form.py); and the settling of the tilt, an effect of the
#: model (models/effects/tilt_drift.py) refitted as a form of the linear drift it is nested over.
#: They have no score test at the fitted point (their nonlinear parameters r, start, tau are not
#: columns of the full Jacobian): each is refitted and ranked by its refit's likelihood gain with
#: its parameter count stated.
FORM_CANDIDATES = ("hysteresis_play", "hysteresis_pi", "thermal_lag_history", "quantisation",  # quantisation.py
                   "tilt_settling")
#: level of the nested likelihood ratio a form must pass over its simpler form to be named
FORM_LEVEL = 0.99

#: names a verdict can give that are not terms of the mean but of the noise model: what each is
NOISE_MODEL_TERMS = {
    "position_error": "position_error: a variance component of the bench's random positioning errors",
    "heavy_tails": "heavy_tails: a Student-t likelihood",
    "flicker_noise": "flicker_noise: a 1/f covariance of the visit means",
    "quantisation": "quantisation: the output's LSB, a rounding of each sample",
}


#: the effects whose evidence is the difference between the heating and the cooling branches
HYSTERESIS_FAMILY = ("hysteresis", "hysteresis_play", "hysteresis_pi")


def turns(campaign: Campaign) -> int:
    """How many times the campaign's temperature path turns (heating to cooling or back), in the
    order of time (the visits' ``direction``; ``none`` does not count)."""
    d = [x for x in np.asarray(campaign.direction)[np.argsort(campaign.time_s, kind="stable")]
         if x in ("heating", "cooling")]
    return sum(1 for a, b in zip(d, d[1:]) if a != b)


def design_caveat(campaign: Campaign, effect: str):
    """What this campaign's design cannot tell from a named ``effect``, in words, or None.

    A hysteresis (any form) on a path that turns once is also a one-time change of the unit at
    the turn -- a unit that slips in its fixture at the top of the cycle gives the same two
    branches (tests/test_foreign_effects.py: a 30 arcsec slip at the turn was named
    ``hysteresis_play`` 5 times in 5; since the step rival, verdict.py, ``unexplained``), and so
    does a slow change in time: on one cycle each
    temperature is visited once a branch, so a drift of an angle or a creep of the unit in its
    fixture (15-20 arcsec over the campaign) is a function of temperature and branch too
    (``hysteresis_play`` 5 times in 5 each). A second turn tells them apart: a hysteresis comes
    back on the next heating, a slip or a drift does not.

    A positioning error on a campaign that visits every pose once is also a systematic error of
    each pose -- an encoder's error that depends on the angle gives one fixed offset a pose, which
    one visit cannot tell from a random one (the independent bench at one setpoint: a 12 arcsec
    once-per-revolution error of axis 1 is named ``position_error`` 3 times in 3; with the poses
    visited at nine setpoints it is ``unexplained``). A second visit of the poses tells them apart:
    a systematic error comes back, a random one does not."""
    if effect == "position_error":
        poses = {(round(float(a), 6), round(float(b), 6)) for a, b in zip(campaign.axis1_deg, campaign.axis2_deg)}
        if len(poses) < campaign.n_visits:
            return None
        return ("every pose is visited once: a systematic error of each pose (e.g. an encoder's error that "
                "depends on the angle) gives the same offsets as a random positioning error; a second visit "
                "of the poses tells them apart")
    if effect not in HYSTERESIS_FAMILY:
        return None
    n = turns(campaign)
    if n >= 2:
        return None
    return (f"the temperature path turns {n} time(s): a change of the unit in time -- once at the "
            "turn (e.g. a slip in its fixture) or slowly (a creep in the fixture, a drift of the axes) -- "
            "gives the same branches; a second turn (heat, cool, heat) tells a hysteresis from it")


def _problem_on(full: JointProblem, campaign: Campaign) -> JointProblem:
    """The compiled full problem with the covariates of ``campaign`` (same visits, another branch
    vector or temperature record): no recompilation."""
    import copy

    p = copy.copy(full)
    p.campaign = campaign
    p.cov_matrix = campaign.covariate_matrix()
    return p


def _nested(chi2_small: float, chi2_big: float, k: int, n_obs: int, noise_known: bool, what: str):
    """The larger form over the smaller at FORM_LEVEL (:func:`~triadcal.estimation.hysteresis_form.nested_criterion`)."""
    from ...estimation.hysteresis_form import nested_criterion

    return nested_criterion(chi2_small, chi2_big, k, n_obs, noise_known, what, level=FORM_LEVEL)


def form_gap_p(c, n_obs: int, noise_known: bool) -> float:
    """p-value of a refit-only form over the model's simpler form (``c.form``: ``chi2_simpler``, the
    form's state) for the gap's family: with known noise ``chi2_simpler - chi2`` against chi^2 with
    ``c.k`` dof (the equal-size rate and history forms of a lag are not nested: one-sided, the
    simpler form favoured), with the noise estimated the F form of the same drop."""
    drop = max(float(c.form["chi2_simpler"]) - float(c.form["state"].chi2), 0.0)
    k = max(int(c.k), 1)
    if noise_known:
        return float(stats.chi2.sf(drop, k))
    dof = max(n_obs - len(c.form["state"].names) - len(c.form["profiled"]), 1)
    return float(stats.f.sf(drop / k / max(float(c.form["state"].chi2) / dof, 1e-300), k, dof))


def _untestable(names, reason):
    from .results import Candidate
    return [Candidate(n, False, reason, refit_only=True) for n in names]


def _hysteresis_forms(campaign, full, model, names, base: FitState, noise_known: bool, T0: float, want):
    """Candidates ``hysteresis_play`` (and ``hysteresis_pi``): the branch of every visit from the
    temperature history through a play of half-width r (or a PI sum of two plays), r, the start
    state (and the PI's second width and weight) profiled by ``fit_hysteresis_form``, then the
    model refitted on that branch vector with the diagnosis's weights."""
    from ...errors import InputError, TriadcalError
    from ...estimation.hysteresis_form import fit_hysteresis_form, with_pi, with_play
    from .results import Candidate

    model = tuple(model)
    eff = model + (() if "hysteresis" in model else ("hysteresis",))
    hp = _effect_params(full.model, "hysteresis")
    if "hysteresis" in model:
        h_names = [n for n in hp if n in names]
    else:
        design = identifiability_problems(campaign, Model(eff, T0))
        h_names = [n for n in hp if n not in design]
        if not h_names:
            return _untestable(want, "invisible on this design: " + design[hp[0]])
    if not h_names:
        return _untestable(want, "the model's hysteresis is not estimated on this design")
    try:
        # refine=False: the play's r on the grid, as the validation of record ran it (the refinement of
        # fit --hysteresis-form, 2026-11-29, waits for a full rerun of validate-diagnosis here)
        block = fit_hysteresis_form(campaign, eff, form="pi" if "hysteresis_pi" in want else "play",
                                    reference_temperature_C=T0, refine=False, profile_only=True)
    except InputError as e:
        return _untestable(want, str(e))
    except (TriadcalError, ArithmeticError, ValueError, np.linalg.LinAlgError, RuntimeError) as e:  # never sink it
        return _untestable(want, f"the form's fit failed on these data ({type(e).__name__}: {e})")
    new_h = [n for n in h_names if n not in names]
    names_f = list(names) + new_h
    off = base if not new_h else _fit(full, names_f, base.x_full, noise_known)
    effects_opt = ",".join(e for e in EFFECTS if e in eff)
    out = []
    r, start = block["half_width_C"], block["start"]
    play = _fit(_problem_on(full, with_play(campaign, r, start)), names_f, off.x_full, noise_known)
    ok_play, crit_play = _nested(off.chi2, play.chi2, 2, play.r.size, noise_known,
                                 "chi2_offset - chi2_play")
    play.extra_params = {"hysteresis_half_width_C": {"value": float(r), "unit": "degC"}}
    c = Candidate("hysteresis_play", True, k=len(new_h) + 2, refit_only=True, params=new_h)
    c.form = {"state": play, "profiled": ["half_width_C", "start"], "simpler": "hysteresis (offset form)",
              "chi2_simpler": off.chi2, "nested_passes": ok_play, "criterion": crit_play,
              "details": {"half_width_C": r, "start": start,
                          "half_width_interval_C": block.get("half_width_interval_C"),
                          "at_grid_edge": block.get("at_grid_edge")},
              "fit_options": f"--effects {effects_opt} --hysteresis-form play"}
    if "hysteresis_play" in want:
        out.append(c)
    if "hysteresis_pi" in want:
        pi = _fit(_problem_on(full, with_pi(campaign, block["pi_half_widths_C"], block["pi_weights"],
                                            block["pi_start"])), names_f, off.x_full, noise_known)
        if ok_play:
            ok_pi, crit_pi = _nested(play.chi2, pi.chi2, 2, pi.r.size, noise_known, "chi2_play - chi2_pi")
        else:
            ok_pi, crit_pi = _nested(off.chi2, pi.chi2, 4, pi.r.size, noise_known, "chi2_offset - chi2_pi")
        pi.extra_params = {"hysteresis_pi_half_width_1_C": {"value": float(block["pi_half_widths_C"][0]), "unit": "degC"},
                           "hysteresis_pi_half_width_2_C": {"value": float(block["pi_half_widths_C"][1]), "unit": "degC"},
                           "hysteresis_pi_weight_2": {"value": float(block["pi_weights"][1]), "unit": "1"}}
        cp = Candidate("hysteresis_pi", True, k=len(new_h) + 4, refit_only=True, params=new_h)
        cp.form = {"state": pi, "profiled": ["half_width_1_C", "half_width_2_C", "weight", "start"],
                   "simpler": "hysteresis_play" if ok_play else "hysteresis (offset form)",
                   "chi2_simpler": play.chi2 if ok_play else off.chi2, "nested_passes": ok_pi,
                   "criterion": crit_pi,
                   "details": {"half_widths_C": block["pi_half_widths_C"], "weights": block["pi_weights"],
                               "start": block["pi_start"]},
                   "fit_options": f"--effects {effects_opt} --hysteresis-form pi"}
        out.append(cp)
    return out


def _thermal_lag_history(campaign, full, model, names, base: FitState, noise_known: bool, T0: float,
                         lag_indicated: bool = False):
    """Candidate ``thermal_lag_history``: the thermal terms at the element's temperature, the record
    passed through one (thermometer on the housing) or two (in the air) first-order stages; the time
    constants profiled by ``fit_thermal_lag`` for each location, the model refitted at the element's
    temperature with the diagnosis's weights, and the location with the lower chi^2 kept (the air's
    two stages only when they beat the housing's one: ``thermal_lag_form.air_kept``, the likelihood
    ratio at 99 % with 1 dof, or the AIC with the noise estimated; the rule of ``fit
    --thermal-lag-form history``).

    A record with gaps (the soaks of a stepped campaign) is bridged (``fit_thermal_lag``'s
    ``bridge_gaps``: a first-order approach through each gap, its time constant profiled too) when
    a lag is indicated -- the rate form among the top candidates by score at p < alpha, or the rate
    form in the model -- and the candidate is untestable otherwise (the bridged search costs 300-700
    inner fits)."""
    from ...errors import InputError, TriadcalError
    from ...estimation.thermal_lag_form import (
        air_kept,
        fit_thermal_lag,
        housing_suffices,
        record_gaps,
        with_element_temperature,
    )
    from .results import Candidate

    name = "thermal_lag_history"
    model = tuple(model)
    design = identifiability_problems(campaign, Model(model + ("thermal_lag",), T0))
    if "thermal_lag" in design:
        return _untestable([name], "invisible on this design: " + design["thermal_lag"])
    if not any(e in model for e in TEMPCO_EFFECTS):       # a lag of the element acts through them
        return _untestable([name], "the lag acts only through temperature coefficients: add a tempco to the "
                                   "model to test it")
    gaps = record_gaps(campaign)
    bridge = bool(len(gaps))
    if bridge and not (lag_indicated or "thermal_lag" in model):
        return _untestable([name], f"the thermometer's record has {len(gaps)} gap(s) of up to {gaps.max():.0f} min "
                                   "(soaks no visit records) and the rate form is not a leading candidate: the "
                                   "history through the gaps is not bridged; the rate form (thermal_lag) is the "
                                   "candidate on this design")
    effects = tuple(e for e in model if e != "thermal_lag")
    names_h = [n for n in names if full.model.spec[n].effect != "thermal_lag"]
    x0 = base.x_full.copy()
    for n in _effect_params(full.model, "thermal_lag"):
        x0[full.index[n]] = 0.0
    fits = {}
    # with gaps only the air's form is bridged (fit_thermal_lag): a housing's history through a soak
    # is two stages, not the bridge's one
    for loc in ("air",) if bridge else ("housing", "air"):
        if loc == "air" and fits and housing_suffices(fits["housing"][0].chi2, fits["housing"][0].dof - 1,
                                                      noise_known):
            break           # one stage closes the gap: the air's second stage is not looked for
        try:
            res = fit_thermal_lag(campaign, effects, loc, bridge_gaps=bridge and loc == "air",
                                  reference_temperature_C=T0)
        except (TriadcalError, ArithmeticError, ValueError, np.linalg.LinAlgError, RuntimeError) as e:
            if not fits:
                return _untestable([name], str(e) if isinstance(e, InputError) else
                                   f"the form's fit failed on these data ({type(e).__name__}: {e})")
            continue
        blk = res.fit["thermal_lag"]
        te, th = float(blk["tau_min"]), float(blk["tau_housing_min"] or 0.0)
        tb = blk["bridge"]["tau_min"] if blk.get("bridge") else None
        st = _fit(_problem_on(full, with_element_temperature(campaign, te, loc, th, tb)), names_h, x0, noise_known)
        st.extra_params = {"thermal_lag_history_tau_min": {"value": te, "unit": "min"}}
        if loc == "air":
            st.extra_params["thermal_lag_history_tau_housing_min"] = {"value": th, "unit": "min"}
        if tb is not None:
            st.extra_params["thermal_lag_history_bridge_min"] = {"value": tb, "unit": "min"}
        fits[loc] = (st, te, th)
    loc = "housing" if "housing" in fits else "air"
    crit_loc = ""
    if "air" in fits and "housing" in fits:
        kept, crit_loc = air_kept(fits["housing"][0].chi2, fits["air"][0].chi2, fits["air"][0].r.size, noise_known)
        loc = "air" if kept else "housing"
    st, te, th = fits[loc]
    if "housing" in fits:
        why_loc = (f"thermometer location {loc}: chi2 housing {fits['housing'][0].chi2:.4g}"
                   + (f", air {fits['air'][0].chi2:.4g} (the air kept only when it beats the housing: {crit_loc})"
                      if "air" in fits else ""))
    else:
        why_loc = (f"thermometer location air, assumed: the record's gaps are bridged, which only the air's form "
                   f"is, and a record with gaps does not show where the thermometer sits (chi2 "
                   f"{fits['air'][0].chi2:.4g}; the lag is named, its split into stages is the air's)")
    n_tau = (2 if loc == "air" else 1) + (1 if bridge else 0)        # the bridge is profiled too
    tb = st.extra_params.get("thermal_lag_history_bridge_min", {}).get("value")
    rate_in_model = "thermal_lag" in model
    if rate_in_model:
        rate_state = base
    else:
        rate_names = [n for n in _effect_params(full.model, "thermal_lag")]
        rate_state = _fit(full, list(names) + rate_names, base.x_full, noise_known)
    # history over the rate form: they are not nested (both 1 time constant for the housing); the
    # history form is named only when it beats the rate form by the 99 % point of chi^2(1)
    ok, crit = _nested(rate_state.chi2, st.chi2, max(n_tau - 1, 1), st.r.size, noise_known,
                       "chi2_rate_form - chi2_history")
    c = Candidate(name, True, k=max(n_tau - (1 if rate_in_model else 0), 1), refit_only=True, params=[])
    c.form = {"state": st, "profiled": (["tau_min"] + (["tau_housing_min"] if loc == "air" else [])
                                        + (["bridge_min"] if bridge else [])),
              "simpler": "thermal_lag (rate form T - tau dT/dt)", "chi2_simpler": rate_state.chi2,
              "nested_passes": ok, "criterion": crit,
              "details": {"location": loc, "tau_min": te, "tau_housing_min": th if loc == "air" else None,
                          "bridge_min": tb, "location_choice": why_loc,
                          "chi2_by_location": {k: v[0].chi2 for k, v in fits.items()}},
              "fit_options": (f"--effects {','.join(e for e in EFFECTS if e in effects)} --thermal-lag-form {loc}"
                              + (" --bridge-gaps" if bridge else ""))}
    return [c]


#: the settling's time constants searched, as fractions of the campaign's span; the best is then
#: refined with the time constant free
SETTLING_GRID = (0.1, 0.2, 0.35, 0.6, 1.0, 2.0)


def _tilt_settling(campaign, full, model, names, base: FitState, noise_known: bool, T0: float,
                   drift_indicated: bool = False):
    """Candidate ``tilt_settling``: the tilt changing as ``d (1 - exp(-t/tau_s))``
    (models/effects/tilt_drift.py), a form of the linear drift (its limit tau_s -> inf). The time
    constant is profiled over ``SETTLING_GRID`` times the campaign's span (the offsets ``d`` fitted
    at each), then refined free from the best; named only when it beats the linear drift (refitted
    here, or the base when ``tilt_drift`` is in the model) by the nested likelihood ratio at 99 %
    (one parameter more). Untestable unless a drift is indicated (``tilt_drift`` among the top
    candidates by score at p < alpha, or in the model): the profile costs eight fits."""
    from .results import Candidate

    name = "tilt_settling"
    model = tuple(model)
    if "bench_tilt" not in model:
        return _untestable([name], "the settling of a tilt the model does not hold: add bench_tilt to the model")
    if not (drift_indicated or "tilt_drift" in model):
        return _untestable([name], "the tilt's drift is not a leading candidate: no change of the tilt in time to "
                                   "tell a settling from")
    sp = _effect_params(full.model, name)
    design = identifiability_problems(campaign, Model(model + (name,), T0))
    if any(n in design for n in sp):
        return _untestable([name], "invisible on this design: " + next(design[n] for n in sp if n in design))
    t = np.asarray(campaign.time_s, float)
    span_h = float(t.max() - t.min()) / 3600.0
    if not span_h > 0:
        return _untestable([name], "the campaign has no duration")
    d_names, tau = sp[:2], sp[2]
    if "tilt_drift" in model:
        simpler, simpler_txt, k_more = base, "the model's tilt_drift (a constant rate)", 3
    else:
        simpler = _fit(full, list(names) + _effect_params(full.model, "tilt_drift"), base.x_full, noise_known)
        simpler_txt, k_more = "tilt_drift (a constant rate)", 1
    profile = []
    for f in SETTLING_GRID:
        x = base.x_full.copy()
        x[full.index[tau]] = f * span_h
        st = _fit(full, list(names) + d_names, x, noise_known)
        profile.append((st.chi2, f * span_h, st))
    chi2_g, tau_g, st_g = min(profile, key=lambda z: z[0])
    st = _fit(full, list(names) + list(sp), st_g.x_full, noise_known)
    if not (math.isfinite(st.chi2) and st.chi2 <= chi2_g + 1e-6):     # the free refit lost its way: no answer
        return _untestable([name], f"the refit with the time constant free did not converge from the profile's best "
                                   f"({tau_g:.3g} h, chi2 {chi2_g:.6g})")
    tau_h = abs(float(st.x_full[full.index[tau]]))
    u_tau = float(math.sqrt(max(st.cov[st.names.index(tau), st.names.index(tau)], 0.0)))
    ok, crit = _nested(simpler.chi2, st.chi2, k_more, st.r.size, noise_known,
                       "chi2_drift - chi2_settling" if k_more == 1 else "chi2_base - chi2_settling")
    st.extra_params = {}
    c = Candidate(name, True, k=len(sp), refit_only=True, params=list(sp))
    effects_opt = ",".join(e for e in EFFECTS if e in model + (name,))
    c.form = {"state": st, "profiled": [], "simpler": simpler_txt, "chi2_simpler": simpler.chi2,
              "nested_passes": ok, "criterion": crit,
              "details": {"tau_h": tau_h, "tau_u_h": u_tau, "span_h": span_h,
                          "profile_tau_h": [float(z[1]) for z in profile],
                          "profile_chi2": [float(z[0]) for z in profile],
                          "at_grid_edge": bool(tau_g in (SETTLING_GRID[0] * span_h, SETTLING_GRID[-1] * span_h))},
              "fit_options": f"--effects {effects_opt}"}
    return [c]
