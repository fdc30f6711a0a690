"""``diagnose``: fit the model, find where it misses, name which effect explains it and how far
the gap shrinks when it is added.

One flow -- base fit, gap tests, scores, refits with their evidence -- whose steps share one base
fit's state (its residuals, Jacobian, hat matrix, noise, the generic bases and kernels, the locals
the inner functions ``evidence`` and ``mean_refit`` close over). Each test and rival lives in its own
module (generic, correlated, rivals, noise_level, series, slices, candidates); the verdict's rules
are in :mod:`.verdict`, which gets this flow's results as :class:`.verdict.VerdictInputs`.
"""

from __future__ import annotations

from ...errors import InputError

import math
from typing import Optional, Sequence

import numpy as np
from scipy import stats

from ...models.campaign import Campaign
from ...models.effects import DEFAULT_EFFECTS, EFFECTS, NOISE_EFFECTS, VOCABULARY
from ...models.effects import heavy_tails as ht
from ...models.model import Model
from ...models.sensor import ANGLE_NAMES, AXES
from ...estimation.joint import (
    JointProblem,
    identifiability_problems,
    noise_of,
    null_space_problems,
    start_values,
)
from ...estimation.noise_model import HOMOGENEITY_P, NoiseSource, bartlett_p, output_variances
from .candidates import (
    FORM_CANDIDATES,
    NOISE_MODEL_TERMS,
    _cross_group,
    _effect_params,
    _fit_heavy_tails,
    _fit_position_error,
    _hysteresis_forms,
    _kurtosis_logp,
    _loglik_total,
    _loo,
    _pe_sensitivity,
    _position_score,
    SPAN_FRACTION_MIN,
    _score_mean,
    _thermal_lag_history,
    _tilt_settling,
    form_gap_p,
)
from .fitting import FitState, _chi2_logsf, _fit, _hat_q
from .correlated import (CampaignKernels, correlated_test)
from .generic import (NOISE_RIVAL_TESTS, NOISE_SOAK_FAMILY, STEP_AFTER, families_after, generic_basis, generic_tests, soak_basis, variance_basis, variance_test)
from .results import ALPHA, Candidate, Diagnosis, _f
from .noise_level import families_with_level
from .slices import _family_tests, _holm, _slice_tests
from .time_constant import TIME_CONSTANT_OF, profiled_score, range_refusal
from .verdict import VerdictInputs, decide


def _top_by_score(cands, top: int) -> list:
    """The ``top`` scored candidates by score p (``flicker_noise`` aside: it takes no slot, a
    time-correlated misfit of the mean scores high on it too), the ones refitted anyway."""
    scored = [c for c in cands if c.testable and not c.refit_only and c.effect != "flicker_noise"]
    return sorted(scored, key=lambda c: c.score_logp)[:top]


# ----------------------------------------------------------------------------------
# the diagnosis
# ----------------------------------------------------------------------------------
def diagnose(campaign: Campaign, model: Sequence[str] = DEFAULT_EFFECTS, *,
             candidates: Optional[Sequence[str]] = None, top: int = 3, alpha: float = ALPHA,
             n_draws: int = 400, reference_temperature_C: float = 20.0, cross_group: bool = True,
             slices_after: bool = True, seed: int = 0) -> Diagnosis:
    """Diagnose the gap between ``model`` (effect names) fitted to ``campaign`` and the data.

    ``candidates`` default to every effect of the vocabulary not in ``model``. ``top``
    candidates (by score) are refitted (``cross_group``: also fitted on one hysteresis branch
    and scored on the other; ``slices_after``: slice tests redone after each refit). Returns a :class:`Diagnosis` (``to_dict`` gives
    the results-json ``triadcal.diagnosis`` v1 document).
    """
    from ...estimation.form_names import held_form, resolve_form_names

    rng = np.random.default_rng(seed)
    asked = tuple(dict.fromkeys(model))
    resolved, h_form, lag_form = resolve_form_names(asked)
    model = tuple(resolved)
    likelihood = [m for m in model if m in NOISE_MODEL_TERMS]
    if likelihood:
        raise InputError(
            f"the diagnosed model holds terms of the mean; {', '.join(likelihood)} "
            f"{'is' if len(likelihood) == 1 else 'are'} part of the noise model ("
            + "; ".join(NOISE_MODEL_TERMS[m] for m in likelihood) + "), which the diagnosis's weighted least "
            "squares does not hold. A verdict that names one already says that after its refit no structure is left "
            "in any slice; to estimate with it, run triadcal fit --effects ... or triadcal sample --effects ... "
            "with the same names")
    unknown = [m for m in model if m not in EFFECTS]
    if unknown:
        raise InputError(f"unknown model effect(s) {unknown}; choose from {', '.join(EFFECTS)}, or the forms "
                         "hysteresis_play, hysteresis_pi, thermal_lag_history")
    if len(campaign.units) != 1 or len(set(campaign.state.tolist())) != 1:
        raise InputError("diagnose takes one unit in one mechanical state (select one with Campaign.select)")
    cands = [c for c in dict.fromkeys(candidates if candidates is not None else VOCABULARY + FORM_CANDIDATES)
             if c not in model and c not in asked]
    notes = []
    if h_form != "offset" or lag_form != "rate":
        # a form in the model (after a verdict named it): its nonlinear parameters profiled by the least
        # squares and held, the campaign carrying its branch or the element's temperature
        campaign, held_model, form_ls, _, held = held_form(campaign, list(model), h_form, lag_form,
                                                           reference_temperature_C=reference_temperature_C)
        model = tuple(held_model)
        notes.append(f"model: {held} (the form's least-squares status: {form_ls.status}); the gap and the "
                     "candidates are judged given them")
    bad = [c for c in cands if c not in VOCABULARY + FORM_CANDIDATES]
    if bad:
        raise InputError(f"unknown candidate effect(s) {bad}; the vocabulary is "
                         f"{', '.join(VOCABULARY + FORM_CANDIDATES)}")
    form_cands = [c for c in cands if c in FORM_CANDIDATES]
    cands = [c for c in cands if c not in FORM_CANDIDATES]
    T0 = reference_temperature_C
    noise = noise_of(campaign)
    sigma = noise.sigma
    model_all = Model(tuple(EFFECTS), T0)
    full = JointProblem(campaign, model_all, sigma)

    # -- the base fit -------------------------------------------------------------
    base_model = Model(model, T0)
    problems = identifiability_problems(campaign, base_model)
    start = start_values(campaign, model_all)
    x0 = np.array([start[n] for n in model_all.names])
    probe_x = x0.copy()
    for s in model_all.parameters:
        if s.effect != "core":
            probe_x[full.index[s.name]] = s.typical if s.effect in model else 0.0
    names0 = [n for n in base_model.names if n not in problems]
    _, Jp = full.residuals_and_jacobian(probe_x)
    # the null space of J is that of R in J = QR (same column norms and singular values): cheaper
    R0 = np.linalg.qr(Jp[:, [full.index[n] for n in names0]], mode="r")
    problems.update(null_space_problems(R0, names0))
    for k, v in problems.items():
        notes.append(f"{k} not estimated (held at 0): {v}")
    names = [n for n in base_model.names if n not in problems]
    base = _fit(full, names, x0, noise.known)
    if not noise.known:
        # one noise level per output, as `fit` has (estimation/noise_model.per_output_scale): with one
        # for the three, honest data whose X output is 8 times noisier than Y and Z were 'unexplained'
        # (a significant 'axis' slice) in 4 of 4 campaigns. Each level from the residuals left by the
        # base model plus every generic family (temperature, time, orientation, direction): a withheld
        # effect on one output must not pass for its noise (from the base residuals alone, a bias tempco
        # of the validation was 'unexplained' after its refit)
        # (columns normalised: the rank, and so the dof, must not depend on the output's unit). Only when
        # the outputs' levels differ (Bartlett p < 1e-3 over the three): data whose outputs share a level
        # keep the one scale, and every verdict of the validation with it
        A = np.column_stack([base.J] + [base.whitened(B) for B in generic_basis(campaign, sigma, T0).values()])
        norms = np.linalg.norm(A, axis=0)
        A = A[:, norms > 0] / norms[norms > 0]
        coef, *_ = np.linalg.lstsq(A, base.r, rcond=None)
        rank = int(np.linalg.matrix_rank(A))
        s2 = output_variances(base.r - A @ coef, rank)
        dof_a = len(base.r) / 3.0 - rank / 3.0
        if s2 is not None and bartlett_p(s2, np.full(3, dof_a)) < HOMOGENEITY_P:
            sigma = sigma * np.sqrt(s2 / np.mean(s2))[None, :]
            full.sigma = sigma
            noise = NoiseSource(sigma, False, noise.description + "; one scale per output (variances per unit "
                                "weight " + ", ".join(f"{a} {v:.3g}" for a, v in zip(AXES, s2)) + ")")
            base = _fit(full, names, x0, noise.known)
    Q = _hat_q(base.J)
    h = np.sum(Q * Q, axis=1)
    def unit_of(n):
        u = model_all.spec[n].unit
        return u.replace("/V", "/" + campaign.output_unit) if campaign.output_unit != "V" else u

    K = np.abs(np.array([base.x_full[full.index[f"K_{a}"]] for a in AXES]))
    to_ug = K * 1e6                                     # output unit -> ug
    sig_ug = sigma * to_ug[None, :]
    floor_ug = float(np.sqrt(np.mean(sig_ug ** 2))) * base.s     # with estimated noise: s * weights

    # -- which: score tests -----------------------------------------------------------
    _, Jfull = full.residuals_and_jacobian(base.x_full)
    Jfull = Jfull / base.s
    cand_objs = []
    pe_w = None                 # position_error's sensitivity (its rival, a uniform excess, needs it)
    for c in cands:
        if c == "position_error":
            w = pe_w = _pe_sensitivity(full, campaign, base.x_full, sigma)
            sc = _position_score(base, w, h, noise.known)
            if sc is None:
                cand_objs.append(Candidate(c, False, "no pose makes an output sensitive to positioning errors"))
            else:
                cand_objs.append(Candidate(c, True, k=1, score=sc[0] ** 2 * (1 if sc[0] > 0 else -1),
                                           score_logp=sc[1]))
            continue
        if c == "flicker_noise":
            from .flicker import flicker_candidate

            cand_objs.append(flicker_candidate(campaign, base, sigma, noise.known))
            continue
        if c == "heavy_tails":
            z = base.r / np.sqrt(np.clip(1.0 - h, 1e-6, None))
            if z.size < 20:
                cand_objs.append(Candidate(c, False, "fewer than 20 residuals: the tails cannot be tested"))
                continue
            stat, logp = _kurtosis_logp(z)
            cand_objs.append(Candidate(c, True, k=1, score=stat * abs(stat), score_logp=logp))
            continue
        pn = _effect_params(model_all, c)
        design = identifiability_problems(campaign, Model(model + (c,), T0))
        usable = [n for n in pn if n not in design]
        if not usable:
            cand_objs.append(Candidate(c, False, "invisible on this design: " + design[pn[0]]))
            continue
        if c in TIME_CONSTANT_OF:
            # its offsets' columns depend on its time constant: scored over a grid of it (time_constant.py)
            columns = []
            prof = profiled_score(full, campaign, base, Q, usable, TIME_CONSTANT_OF[c], noise.known,
                                  J_start=Jfull, columns_out=columns)
            if prof is not None:
                S, k, logp, profile = prof
                cand_objs.append(Candidate(c, True, k=k, score=S, score_logp=logp, params=usable,
                                           score_profile=profile, columns_by_tau=columns))
                continue
        sc = _score_mean(base, Jfull[:, [full.index[n] for n in usable]], Q, SPAN_FRACTION_MIN)
        if sc is None:
            why = ("its sensitivity is zero at the fitted point (thermal lag acts only through temperature "
                   "coefficients: add a tempco to the model to test it)" if c == "thermal_lag" else
                   "its sensitivity is zero or already in the fitted model's span on this design (less than "
                   f"{SPAN_FRACTION_MIN:g} of its columns outside it)")
            cand_objs.append(Candidate(c, False, why))
            continue
        S, k = sc
        if noise.known:
            logp = _chi2_logsf(S, k)
        else:
            logp = float(stats.f.logsf(S / k, k, max(base.dof - k, 1)))
        cand_objs.append(Candidate(c, True, k=k, score=S, score_logp=logp, params=usable))

    # -- form candidates (refit-only: no score test; docs/diagnosis.md "Form candidates") ----------
    hyst_forms = [c for c in form_cands if c.startswith("hysteresis_")]
    if hyst_forms:
        cand_objs += _hysteresis_forms(campaign, full, model, names, base, noise.known, T0, hyst_forms)
    if "thermal_lag_history" in form_cands:
        # a lag is indicated when the rate form is among the candidates refitted anyway (the top by
        # score, flicker aside, as below) at p < alpha: the bridged history costs hundreds of fits,
        # and a rate form far down the list (a tempco's gap scores on it too) does not call for it
        lag_indicated = any(c.effect == "thermal_lag" and c.score_logp < math.log(alpha)
                            for c in _top_by_score(cand_objs, top))
        cand_objs += _thermal_lag_history(campaign, full, model, names, base, noise.known, T0, lag_indicated)
    if "tilt_settling" in form_cands:
        # a settling is looked for when a change of the tilt in time is indicated: the linear drift among
        # the top candidates by score at p < alpha (the profile over the time constant costs eight fits)
        drift_indicated = any(c.effect == "tilt_drift" and c.score_logp < math.log(alpha)
                              for c in _top_by_score(cand_objs, top))
        cand_objs += _tilt_settling(campaign, full, model, names, base, noise.known, T0, drift_indicated)
    if "quantisation" in form_cands:
        from .quantisation import quantisation_candidates

        cand_objs += quantisation_candidates(campaign, full, model, names, base, noise.known)

    # -- gap -------------------------------------------------------------------------
    gap_tests = {}
    if noise.known and base.dof > 0:
        gap_tests["chi2"] = float(stats.chi2.sf(base.chi2, base.dof))
    z = base.r / np.sqrt(np.clip(1.0 - h, 1e-6, None))
    if z.size >= 20:
        gap_tests["kurtosis"] = float(math.exp(_kurtosis_logp(z)[1]))
    for c in cand_objs:
        if c.testable and c.effect != "heavy_tails" and not c.refit_only:
            gap_tests[f"score:{c.effect}"] = c.score_p
        elif c.testable and c.effect == "thermal_lag_history" and "thermal_lag" in model:
            # the model's own rate-form lag against the history form (the rule of fit's gate lag_form): no
            # score test stands for it, so without this a rate form the history form beat by LR 31 (an
            # element 2 min behind a housing 15 min behind the air, 2 degC/min, chi2/dof 1.15 on 180 dof)
            # was "no significant gap" while fit refused the same model (an outside probe)
            gap_tests["form:thermal_lag_history"] = form_gap_p(c, base.r.size, noise.known)
    # smooth mean terms that no candidate names (generic.py): a missing term outside the list
    gbasis = generic_basis(campaign, sigma, T0)
    # and a bench tilt free at each soak (generic.soak_basis): a base that moves between soaks
    tbasis = soak_basis(campaign, Jfull[:, [full.index["tilt_x"], full.index["tilt_y"]]] * base.s)
    if tbasis is not None:
        gbasis["tilt"] = tbasis
    generic0 = generic_tests({f: base.whitened(B) for f, B in gbasis.items()}, base.r, base.J, noise.known,
                             base.dof, Q)
    # and a scale free at each soak (generic.soak_basis): a scale that wanders in time. Among the gap's
    # tests only: after a refit, the candidate a wander passes for (a scale tempco) meets it as a rival
    # (correlated.SCALE_WANDER_MIMICS), and in the families left after every refit it diluted the
    # variance family's Holm correction after heavy_tails' refit (noise that grows at the hot soak,
    # seed 5 of tests/test_foreign_effects.py: heavy_tails named; docs/diagnosis.md "Generic structure")
    kbasis = soak_basis(campaign, Jfull[:, [full.index[f"K_{a}"] for a in AXES]] * base.s)
    scale0 = (generic_tests({"scale": base.whitened(kbasis)}, base.r, base.J, noise.known, base.dof, Q)
              if kbasis is not None else {})
    # and the misalignment free at each soak: asked after the noise effects' refits only (their
    # variance can take a wandering angle in: generic.NOISE_SOAK_FAMILY)
    angles_norm = Jfull[:, [full.index[f"Ca_{ab}"] for ab in ANGLE_NAMES]] * base.s
    abasis = soak_basis(campaign, angles_norm)
    for fam, t in (generic0 | scale0).items():
        gap_tests[f"generic:{fam}"] = t["p_value"]
    # a scatter that depends on the pose (positioning errors): Koenker's test of the variance
    vbasis = variance_basis(campaign)
    var0 = variance_test(base.r, h, vbasis)
    if var0 is not None:
        gap_tests["generic:variance"] = var0["p_value"]
    # residuals alike when close in time (a wandering noise: 1/f, Gauss-Markov) -- correlated.py
    ckern = CampaignKernels(campaign.time_s, sigma)     # built once: base, refits, wander rival
    corr0 = correlated_test(base.r, Q, campaign.time_s, sigma, cache=ckern)
    if corr0 is not None:
        gap_tests["generic:correlated"] = corr0["p_value"]
    keys = list(gap_tests)
    adj = _holm([gap_tests[k] for k in keys]) if keys else []
    gap_adj = dict(zip(keys, (float(a) for a in adj)))
    significant = bool(keys) and min(gap_adj.values()) < alpha
    # the declared level rejected: the families again with the level estimated (noise_level.py), so that
    # an unexplained gap's shape is not a pattern the level alone made
    level_free = None
    if noise.known and gap_adj.get("chi2", 1.0) < alpha:
        wb = {f: base.whitened(B) for f, B in gbasis.items()}
        if kbasis is not None:
            wb["scale"] = base.whitened(kbasis)
        level_free = families_with_level(wb, base.r, base.J, base.dof, Q, gap_tests)
    gap = {"chi2_dof": _f(base.chi2_dof) if noise.known else None, "chi2": base.chi2, "dof": base.dof,
           "p_value": _f(gap_tests.get("chi2")), "significant": significant,
           "tests": {k: {"p_value": _f(gap_tests[k]), "p_holm": _f(gap_adj[k])} for k in keys},
           "residual_rms_ug": float(np.sqrt(np.mean((base.r * base.s) ** 2 * sig_ug.reshape(-1) ** 2))),
           "noise_floor_ug": floor_ug,
           "testable": ("chi2 against its distribution with the known noise, tails, and candidate scores"
                        if noise.known else
                        "noise estimated from the residuals: the chi2 level is not testable (it defines the "
                        "noise); structure is: candidate scores (F form), tails, slice offsets/trends and "
                        "the variance pattern of positioning errors")}

    # -- where -------------------------------------------------------------------------
    slices = _slice_tests(campaign, base, to_ug, sigma, n_draws, rng)

    # -- refit the top candidates ------------------------------------------------------
    testable = sorted([c for c in cand_objs if c.testable], key=lambda c: c.score_logp)
    scored = [c for c in testable if not c.refit_only]
    # flicker_noise takes no --top slot (a time-correlated misfit of the mean, e.g. a thermal lag,
    # scores high on it too): refitted besides the top when its score is significant (flicker.py)
    to_refit = _top_by_score(scored, top)
    to_refit += [c for c in scored if c.effect == "flicker_noise" and c.score_p < alpha]
    # the rate-form lag is refitted whenever the history form is, so that the two can be compared
    if any(c.effect == "thermal_lag_history" for c in testable):
        to_refit += [c for c in scored if c.effect == "thermal_lag" and c not in to_refit]
    to_refit += [c for c in testable if c.refit_only]
    elpd0, se0, pw0, k0 = _loo(base, n_draws, rng)
    if k0 > 0.7:
        notes.append(f"base model: Pareto k up to {k0:.2f} > 0.7, the PSIS-LOO elpd is unreliable")
    base_ll = _loglik_total(base)
    base_u = base.u()
    base_val = base.value(full)
    cross0 = _cross_group(campaign, noise, model, names, T0, base.x_full, noise.known) if cross_group else None
    n_sig_before = sum(1 for s in slices if s.p_adjusted < alpha)

    def evidence(c, st, new_names, var_scale, nu, ll, lr_p, added):
        """The refit's evidence (likelihood, PSIS-LOO, the gap and the generic families after it, the
        parameter shifts) of candidate ``c`` refitted to ``st`` with ``added`` effects in the model."""
        form = c.form
        elpd, se, pw, kmax = _loo(st, n_draws, rng, var_scale=var_scale, nu=nu)
        diff = pw - pw0
        d_elpd, d_se = float(diff.sum()), float(math.sqrt(diff.size) * np.std(diff))
        if form is not None:
            # the Laplace draws hold the linear parameters only: the profiled ones (r, start, tau)
            # cost one elpd each (their AIC/2), so that a form is not favoured by its search
            d_elpd -= len(form["profiled"])
        # slice statistics after: residuals standardised by the fitted noise model (for a
        # Student-t, its normal scores Phi^-1(F_t(r)): Gaussian when the noise model holds)
        r_after = st.r / (np.sqrt(var_scale) if var_scale is not None else 1.0)
        J_after = st.J / (np.sqrt(var_scale)[:, None] if var_scale is not None else 1.0)
        Q_after = _hat_q(J_after)
        if math.isfinite(nu):
            r_after = ht.normal_scores(r_after, nu)
            # the slice tests are built for least-squares residuals, orthogonal to the fit's columns; the
            # Student-t fit's normal scores are not (it solves sum J psi(r) = 0), and a slice nearly in the
            # columns' span divides their part there by almost nothing: with per-visit sd_* (an S_y column
            # not quite constant) a probe's Student-t noise read as a whole-axis offset of z = -63 after the
            # heavy_tails refit, named 0 of 19 times. Projected orthogonal, three contaminated visits of the
            # independent bench read as significant cells instead (tests/test_foreign_effects.py). Both are
            # approximations of the t fit's residuals: a slice is left significant only by both (below)
        st_for_slices = FitState(st.names, st.x_full, r_after, J_after, st.cov, st.chi2, st.dof, st.s, st.converged)
        soak_angles = ({NOISE_SOAK_FAMILY: abasis} if c.effect in NOISE_EFFECTS and abasis is not None else {})
        gen = families_after(c.effect, {f: st.whitened(B) for f, B in (gbasis | soak_angles).items()}, r_after,
                             st_for_slices.J, Q_after, noise.known, st.dof, vbasis, campaign.time_s, sigma,
                             corr_kernels=ckern, pe_w=pe_w, replicates=st.extra_tests.get("replicates"),
                             # a step's columns are the angles' on the visits after it: with a whitening
                             # within each visit only (position_error's 3 x 3 blocks; flicker's GLS mixes them)
                             step_angles=(st.whitened(angles_norm) if c.effect in STEP_AFTER else None))
        # Holm over the families; the two noise effects' tests of each other are rival tests, each at
        # alpha on its own (generic.NOISE_RIVAL_TESTS)
        fams = [f for f in gen if f not in NOISE_RIVAL_TESTS]
        gen_holm = dict(zip(fams, _holm([gen[f]["p_value"] for f in fams]))) if fams else {}
        gen_holm.update({f: gen[f]["p_value"] for f in gen if f in NOISE_RIVAL_TESTS})
        n_sig_after = None
        if slices_after:
            sl_after = _slice_tests(campaign, st_for_slices, to_ug, sigma, 0, rng)
            sig = {(t.slice, t.family, t.axis, t.test) for t in sl_after if t.p_adjusted < alpha}
            if math.isfinite(nu) and sig:
                st_proj = FitState(st.names, st.x_full, r_after - Q_after @ (Q_after.T @ r_after), J_after, st.cov,
                                   st.chi2, st.dof, st.s, st.converged)
                sig &= {(t.slice, t.family, t.axis, t.test)
                        for t in _slice_tests(campaign, st_proj, to_ug, sigma, 0, rng) if t.p_adjusted < alpha}
            n_sig_after = len(sig)
        chi2_after = float(np.sum(r_after ** 2) * st.s ** 2)
        dof_after = (st.r.size - len(st.names) - (len(st.extra_params) if c.effect == "position_error" else
                                                  2 if c.effect == "heavy_tails" and noise.known else
                                                  1 if c.effect in NOISE_EFFECTS else 0)
                     - (len(form["profiled"]) if form is not None else 0))
        rms_after = float(np.sqrt(np.mean((st.r * st.s) ** 2 * sig_ug.reshape(-1) ** 2)))
        # parameter shifts in units of their uncertainty
        after_val = st.value(full)
        lag_after = ((form or {}).get("details") or {}).get("tau_min")
        if "thermal_lag" in names and "thermal_lag" not in after_val and lag_after is not None:
            # the history form (thermal_lag_history) replaces the rate form's parameter by its profiled time
            # constant (min, the same unit): a ramp fitted with thermal_lag crashed here (KeyError, an outside probe)
            after_val = {**after_val, "thermal_lag": float(lag_after)}
        shifts = {n: {"shift": after_val[n] - base_val[n], "u_before": base_u[n],
                      "in_u": (after_val[n] - base_val[n]) / base_u[n] if base_u[n] > 0 else None,
                      "unit": unit_of(n)}
                  for n in names if n in after_val}
        worst = max(shifts, key=lambda n: abs(shifts[n]["in_u"] or 0.0)) if shifts else None
        cross = None
        if cross_group and c.effect not in NOISE_EFFECTS and form is None:
            cg = _cross_group(campaign, noise, model + tuple(added), names + new_names, T0, base.x_full,
                              noise.known)
            cross = None if cg is None or cross0 is None else cg - cross0
        refit = {
            "delta_loglik": ll - base_ll, "lr_p_value": _f(lr_p), "dof_after": int(dof_after),
            "elpd_loo": elpd, "elpd_se": se, "delta_elpd": d_elpd, "delta_elpd_se": d_se,
            "pareto_k_max": kmax,
            "cross_branch_delta_lpd": _f(cross) if cross is not None else None,
            # with the noise estimated there is no chi2 level (the weights are relative: a tiny ratio that
            # means nothing); how far the gap shrank is then the ratio of chi2/dof after to before
            "gap_before": {"chi2_dof": _f(base.chi2_dof) if noise.known else None,
                           "residual_rms_ug": gap["residual_rms_ug"],
                           "noise_floor_ug": floor_ug, "elpd_loo": elpd0, "significant_slices": n_sig_before},
            "gap_after": {"chi2_dof": (_f(chi2_after / dof_after if dof_after > 0 else float("nan"))
                                       if noise.known else None),
                          # a noise model reweights the residuals: its chi2 is not the base's, no ratio
                          "chi2_dof_ratio": (None if c.effect in NOISE_EFFECTS else
                                             _f(chi2_after / dof_after / base.chi2_dof
                                                if dof_after > 0 and base.chi2_dof > 0 else float("nan"))),
                          "residual_rms_ug": rms_after, "noise_floor_ug": floor_ug, "elpd_loo": elpd,
                          "significant_slices": n_sig_after,
                          "generic": {f: {"S": _f(t["S"]), "k": t["k"], "p_value": _f(t["p_value"]),
                                          **({"p_full": _f(t["p_full"])} if "p_full" in t else {}),
                                          **({"z": _f(t["z"])} if "z" in t else {}),
                                          **({"tau_s": _f(t["tau_s"])} if "tau_s" in t else {}),
                                          "p_holm": _f(float(gen_holm[f]))} for f, t in gen.items()},
                          "generic_structure": [f for f in gen if gen_holm[f] < alpha]},
            "new_parameters": ({n: {"value": after_val.get(n, float(st.x_full[full.index[n]])),
                                    "u": float(math.sqrt(max(st.cov[st.names.index(n), st.names.index(n)], 0))),
                                    "unit": unit_of(n)} for n in new_names}
                               if new_names else {}) | (dict(st.extra_params) if (form or not new_names) else {}),
            "parameter_shifts": {n: {k: _f(v) if not isinstance(v, str) else v for k, v in s.items()}
                                 for n, s in shifts.items()},
            "largest_shift": ({"parameter": worst, "in_u": _f(shifts[worst]["in_u"])} if worst else None),
        }
        if form is not None:
            refit["form"] = {"refit_only": True, "n_parameters": int(c.k), "profiled": list(form["profiled"]),
                             "delta_elpd_penalty": len(form["profiled"]), "simpler_form": form["simpler"],
                             "chi2_simpler": _f(form["chi2_simpler"]), "chi2": _f(st.chi2),
                             "beats_simpler": bool(form["nested_passes"]), "criterion": form["criterion"],
                             "fit_options": form["fit_options"],
                             **{k: v for k, v in form["details"].items()}}
        if kmax > 0.7:
            notes.append(f"{c.effect}: Pareto k up to {kmax:.2f} > 0.7, the PSIS-LOO elpd is unreliable "
                         "(few visits or influential ones); rely on the likelihood ratio")
        return refit

    def mean_refit(new_names, x_start=None):
        """The base model with the mean parameters ``new_names`` added (from ``x_start``, default the
        base's point): (state, log-likelihood, LR p over the base: chi^2 with known noise, F with the
        noise estimated)."""
        st = _fit(full, names + list(new_names), base.x_full if x_start is None else x_start, noise.known)
        if noise.known:
            return st, _loglik_total(st), float(stats.chi2.sf(max(base.chi2 - st.chi2, 0.0), len(new_names)))
        ll = base_ll + 0.5 * st.r.size * math.log(base.chi2 / max(st.chi2, 1e-300))
        F = (base.chi2 - st.chi2) / len(new_names) / (st.chi2 / max(st.dof, 1))
        return st, ll, float(stats.f.sf(max(F, 0.0), len(new_names), max(st.dof, 1)))

    states = {}
    for c in to_refit:
        form = c.form
        if form is not None:
            st = form["state"]
            new_names, var_scale, nu = list(c.params), None, math.inf
            k_lr = max(c.k, 1)
            if noise.known:
                ll = _loglik_total(st)
                lr_p = float(stats.chi2.sf(max(base.chi2 - st.chi2, 0.0), k_lr))
            else:
                ll = base_ll + 0.5 * st.r.size * math.log(base.chi2 / max(st.chi2, 1e-300))
                F = (base.chi2 - st.chi2) / k_lr / (st.chi2 / max(st.dof - len(form["profiled"]), 1))
                lr_p = float(stats.f.sf(max(F, 0.0), k_lr, max(st.dof - len(form["profiled"]), 1)))
        elif c.effect in ("position_error", "flicker_noise"):
            if c.effect == "flicker_noise":
                from .flicker import fit_flicker

                st = fit_flicker(full, campaign, base, names, sigma, noise.known)
            else:
                st = _fit_position_error(full, campaign, base, names, sigma, noise.known)
            var_scale, nu, new_names = st.var_scale, math.inf, []
            ll = _loglik_total(st, var_scale=var_scale)
            lr = max(2 * (ll - base_ll), 0.0)
            # variances on the boundary (Self & Liang 1987): 1/2 chi2_0 + 1/2 chi2_1 for flicker's one;
            # 1/4 chi2_0 + 1/2 chi2_1 + 1/4 chi2_2 for position_error's two (bench axes, wobble)
            lr_p = (0.5 * float(stats.chi2.sf(lr, 1)) + 0.25 * float(stats.chi2.sf(lr, 2))
                    if c.effect == "position_error" else 0.5 * float(stats.chi2.sf(lr, 1)))
        elif c.effect == "heavy_tails":
            st = _fit_heavy_tails(base)
            var_scale, nu, new_names = st.var_scale, st.nu, []
            ll = _loglik_total(st, var_scale=var_scale, nu=nu)
            lr = max(2 * (ll - base_ll), 0.0)
            # nu on its boundary (inf) and, with the noise known, the scale free (1 under the null):
            # 1/2 chi2_1 + 1/2 chi2_2 (Self & Liang 1987); with the noise estimated the scale replaces it
            lr_p = (0.5 * float(stats.chi2.sf(lr, 1)) + 0.5 * float(stats.chi2.sf(lr, 2)) if noise.known
                    else 0.5 * float(stats.chi2.sf(lr, 1)))
        else:
            new_names = list(c.params)
            x_start = None
            if c.score_profile is not None:      # from the time constant its score was largest at
                x_start = base.x_full.copy()
                x_start[full.index[c.score_profile["parameter"]]] = c.score_profile["best"]
            st, ll, lr_p = mean_refit(new_names, x_start)
            var_scale, nu = None, math.inf
        c.refit = evidence(c, st, new_names, var_scale, nu, ll, lr_p, (c.effect,))
        refused = range_refusal(c)
        if refused:              # not a warm-up: the fit's answer gate would refuse it (time_constant.py)
            c.refit["time_constant_refused"] = refused
        states[c.effect] = st
    # -- rank ---------------------------------------------------------------------------
    refitted = sorted([c for c in testable if c.refit], key=lambda c: -c.refit["delta_elpd"])
    rest = [c for c in testable if not c.refit]
    order = refitted + rest + [c for c in cand_objs if not c.testable]
    for i, c in enumerate(order, 1):
        c.rank = i
    # -- verdict (verdict.py) ----------------------------------------------------------
    verdict = decide(VerdictInputs(campaign=campaign, model=model, noise=noise, alpha=alpha, seed=seed,
        base=base, full=full, Jfull=Jfull, Q=Q, T0=T0, sigma=sigma, significant=significant, gap_adj=gap_adj,
        level_free=level_free, refitted=refitted, cand_objs=cand_objs, states=states, generic0=generic0, corr0=corr0, slices=slices,
        n_sig_before=n_sig_before, ckern=ckern, h=h, pe_w=pe_w, mean_refit=mean_refit, evidence=evidence))
    if verdict.get("effect") == "unexplained" and not verdict.get("gap_closed"):
        # an outside probe: an element lagging its sensor by 30 min (chi2/dof 26) was 'unexplained' in 3 of 5
        # seeds: the rate-form lag's score (p 1e-146) ranked 7th behind thermal terms it correlates with, and
        # only the top 3 are refitted; --top 6 named thermal_lag_history with the gap closed. The verdict is
        # kept (refitting more would change what the validation measured); it names what was not tried
        left = [c for c in scored if not c.refit and c.score_p is not None and c.score_p < alpha]
        if left:
            rank = {c.effect: i for i, c in enumerate(sorted(scored, key=lambda c: c.score_logp), 1)}
            verdict["not_refitted"] = [{"effect": c.effect, "score_rank": rank[c.effect], "score_p": _f(c.score_p)}
                                       for c in left]
            verdict["reason"] += ("; candidates whose score is significant were not refitted (beyond --top "
                                  f"{top}): " + ", ".join(f"{c.effect} (score rank {rank[c.effect]}, p "
                                                         f"{c.score_p:.3g})" for c in left[:6])
                                  + f"; run again with --top {max(rank[c.effect] for c in left)} to refit them")
    if verdict.get("effect") is None and not significant and keys:
        # a none verdict says what it could not have seen (detection.py)
        from .detection import POWER, detection_limits, limits_text

        level = alpha / len(keys)
        blind = [c.effect for c in cand_objs if not c.testable]
        verdict["detection_limits"] = {
            "power": POWER, "level": level,
            "candidates": detection_limits(cand_objs, Jfull, full.index, Q, level, unit_of),
            "not_testable": blind}
        if verdict["detection_limits"]["candidates"]:
            verdict["reason"] += "; " + limits_text(verdict["detection_limits"]["candidates"], level)
        if blind:
            verdict["reason"] += "; not testable on this design (nothing said of them): " + ", ".join(blind)
    fit = {"chi2_dof": _f(base.chi2_dof) if noise.known else None, "n_obs": int(base.r.size), "n_params": len(names),
           "converged": base.converged, "parameters": {n: {"value": base_val[n], "u": base_u[n],
                                                           "unit": unit_of(n)} for n in names}}
    return Diagnosis(model=asked, noise_known=noise.known, noise=noise.description, gap=gap, slices=slices,
                     candidates=order, verdict=verdict, fit=fit, notes=notes, source=campaign.source, alpha=alpha,
                     residuals=base.r.reshape(-1, 3).copy(), families=_family_tests(campaign, base, Q))
