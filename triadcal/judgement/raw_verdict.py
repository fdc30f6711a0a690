"""The verdict of a raw diagnosis (``raw_diagnosis``): its rule's constants, the held-out floor test
of a named verdict, the size of a candidate and what a named verdict cannot see (docs/diagnosis.md,
"Held out at the floor")."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from scipy import stats

ALPHA = 0.01
RATIO_MAX = 1.2          # chi2/dof above which a significant gap is also material (gates' gof_ratio_max)
SHRINK_SE = 2.0          # a held-out shrink counts when mean(d) > SHRINK_SE x SE(d)
#: a candidate beats a rival only when its held-out z^2 is also smaller by this much per fold on average: a
#: difference of 0.01 is a log-likelihood of 0.005 per interval, no evidence. Two terms that are one
#: column (a temperature that is a ramp in time: bias_tempco and bias_drift) differ fold by fold only by
#: the rounding of the file (1e-7 with temperatures written to 1e-4 degC), with an SE smaller still, and
#: the winner was drawn by that rounding: bias_tempco named over bias_drift in 1 of 30 recordings of a
#: drift, "2.51 paired SE" (an outside probe)
MIN_RIVAL_Z2 = 0.01
UG = 1e6
UNSEEN_POWER = 0.95      # a named term's caveat: the pattern beyond it that the gap's rule detects with this power


def _unseen(sigma: np.ndarray, dof: int, power: float = UNSEEN_POWER) -> dict:
    """How large a pattern outside a refitted term can be and still pass the gap's own rule after the
    refit (chi2 with p < ALPHA and chi2/dof > RATIO_MAX) with probability 1 - ``power``: the
    noncentrality ``lambda*`` at which chi2_dof exceeds the critical value with ``power``
    (``detection.lambda_beyond``, as the null verdict's detection limits), spread evenly over the
    intervals: ``sum_k r^2 / sigma_k^2 = lambda*``, ``r = sqrt(lambda* / sum_k sigma_k^-2)``."""
    from .diagnose.detection import lambda_beyond

    crit = max(float(stats.chi2.isf(ALPHA, dof)), RATIO_MAX * dof)
    lam = lambda_beyond(int(dof), crit, power)
    return {"rms_ug": float(math.sqrt(lam / float(np.sum(sigma ** -2.0)))) * UG, "noncentrality": lam,
            "dof": int(dof), "power": power}


def held_out_floor(J: np.ndarray, d_sig: np.ndarray, zc2: np.ndarray) -> dict:
    """Is the candidate's held-out residual at the noise floor? The test of the named verdict.

    If the term explained everything and the floors were right, the normalised residuals of its fit on
    all intervals would be ``e = (I - H) eps`` (``eps`` iid N(0, 1), ``H`` the hat matrix of the weighted
    Jacobian at the fit, linearised) and leave-one-out's held-out ones ``e_k / (1 - h_k)``: each is
    wider than the floor by the uncertainty of the parameters fitted without it, so the held-out mean
    square of a right term is ``mean 1/(1 - h_k)``, not 1 (15 parameters on 40 intervals: about 1.65;
    a held-out RMS of 1.3 x the floor is what the right term leaves there). The held-out power
    ``Q = sum_k z_k^2`` over the kept intervals is then the quadratic form ``eps' M eps`` with
    ``M = (I - H) D^-2 (I - H)``, ``D = diag(1 - h)``: a sum of chi2_1 weighted by M's eigenvalues,
    taken as ``c chi2_nu`` with the same mean and variance (Satterthwaite: ``c = sum l^2 / sum l``,
    ``nu = (sum l)^2 / sum l^2``). Not at the floor when ``p < ALPHA`` **and** ``Q / E[Q] > RATIO_MAX``
    (the gap's own two-part rule). ``contaminated_interval`` is tested over the intervals it keeps:
    it claims the dropped one is not predicted. ``J``: the weighted Jacobian of the refit over the
    intervals tested, ``d_sig`` their floors, ``zc2`` their held-out z^2."""
    U, sv, _ = np.linalg.svd(J, full_matrices=False)
    U = U[:, sv > 1e-10 * (sv[0] if len(sv) else 1.0)]
    H = U @ U.T
    h = np.clip(np.diag(H), 0.0, 1.0 - 1e-9)
    IH = np.eye(len(h)) - H
    M = IH @ np.diag(1.0 / (1.0 - h) ** 2) @ IH
    lam = np.linalg.eigvalsh((M + M.T) / 2)
    lam = lam[lam > 1e-12 * max(float(lam.max(initial=0.0)), 1e-300)]
    q = float(np.sum(zc2))
    expected = float(lam.sum())
    nk = len(zc2)
    if expected <= 0:
        return {"mean_square": q / max(nk, 1), "expected": None, "ratio": None, "dof": None, "p_value": None,
                "intervals": nk, "rms_ug": float(np.sqrt(np.mean(zc2 * d_sig ** 2))) * UG,
                "expected_rms_ug": None, "at_floor": True}
    c = float(np.sum(lam ** 2)) / expected
    nu = expected ** 2 / float(np.sum(lam ** 2))
    pval = float(stats.chi2.sf(q / c, nu))
    ratio = q / expected
    return {"mean_square": q / nk, "expected": expected / nk, "ratio": ratio, "dof": nu, "scale": c,
            "p_value": pval, "intervals": nk,
            "rms_ug": float(np.sqrt(np.mean(zc2 * d_sig ** 2))) * UG,
            "expected_rms_ug": float(np.sqrt(np.mean(d_sig ** 2 / (1.0 - h)))) * UG,
            "at_floor": not (pval < ALPHA and ratio > RATIO_MAX)}


def _size(c: dict) -> Optional[dict]:
    """The fitted size of a candidate (reported, not judged: no physical bound is assumed): its largest
    correction with u and how many of its parameters lie beyond 2 u; for ``contaminated_interval`` the
    dropped interval and its residual."""
    ff = c["full_fit"]
    pars = ff.get("new_parameters") or {}
    if pars:
        name = max(pars, key=lambda k: abs(pars[k]["value"]))
        q = pars[name]
        beyond = sum(1 for v in pars.values() if v["u"] is not None and abs(v["value"]) > 2 * v["u"])
        out = {"parameter": name, "value": q["value"], "u": q["u"], "unit": q["unit"],
               "beyond_2u": beyond, "of": len(pars)}
        u = "" if q["u"] is None else f" +- {q['u']:.3g}"
        out["text"] = (f"fitted size: its largest correction {name} = {q['value']:.4g}{u} {q['unit']} ({beyond} of "
                       f"{len(pars)} parameters beyond 2 u; a correction, the sensor's term has the opposite sign)")
        return out
    if ff.get("dropped_interval") is not None:
        return {"interval": ff["dropped_interval"], "residual_ug": ff["dropped_residual_ug"],
                "text": f"dropped interval {ff['dropped_interval']} (residual {ff['dropped_residual_ug']:.4g} ug)"}
    return None


def _held_out_text(best: dict) -> str:
    ho, fl = best["held_out"], best["held_out"]["floor"]
    if fl.get("expected") is None:
        return "held-out floor test undefined (no residual degree of freedom in the fit)"
    kept = "" if fl["intervals"] == ho["folds"] else f" over the {fl['intervals']} intervals it keeps"
    return (f"held out{kept}, its residual's power in units of each interval's floor is {fl['ratio']:.3g} x what a "
            f"term that explains everything leaves there (the floor widened by its parameters' uncertainty, fitted "
            f"without the interval), p = {fl['p_value']:.3g} (scaled chi2 on {fl['dof']:.3g} dof; RMS "
            f"{fl['rms_ug']:.3g} ug against {fl['expected_rms_ug']:.3g} ug expected)")


def _verdict(gap, tested, sig, n, dof0, rms_ug, floor_ug, rivals=()) -> dict:
    """Every verdict has a one-sentence ``reason``; one with a best candidate also ``evidence`` (its
    held-out numbers), ``size`` and ``held_out_at_floor``."""
    if dof0 < 1:
        return {"effect": None, "term": None, "reason": gap["testable"]}
    if not gap["significant"]:
        return {"effect": None, "term": None,
                "reason": f"the residual is at the noise floor: RMS {rms_ug:.3g} ug over {n} intervals against "
                          f"their own scatter {floor_ug:.3g} ug (chi2/dof {gap['chi2_dof']:.3g}, p = "
                          f"{gap['p_value']:.3g}; significant only when p < {ALPHA} and chi2/dof > {RATIO_MAX})"}
    what = (f"residual RMS {rms_ug:.3g} ug against the floor {floor_ug:.3g} ug (chi2/dof {gap['chi2_dof']:.3g}, "
            f"p = {gap['p_value']:.3g})")
    if not tested:
        return {"effect": "unexplained", "term": "unexplained",
                "reason": f"significant gap, {what}, and no candidate can be tested on {n} intervals"}
    if not sig:
        return {"effect": "unexplained", "term": "unexplained",
                "reason": f"significant gap, {what}; no candidate shrinks the held-out residual by more than "
                          f"{SHRINK_SE:g} standard errors"}
    best = sig[0]
    ho, ff, fl = best["held_out"], best["full_fit"], best["held_out"]["floor"]
    size = _size(best)
    ev = (f"held-out RMS {ho['rms_base_ug']:.3g} -> {ho['rms_ug']:.3g} ug (shrink {ho['shrink_ug']:.3g} ug), "
          f"mean d = {ho['mean_d']:.3g} +- {ho['se_d']:.3g} over {ho['folds']} folds; chi2/dof after its refit "
          f"{ff['chi2_dof']:.3g} (p = {ff['p_value']:.3g}); {_held_out_text(best)}"
          + (f"; {size['text']}" if size else ""))
    partial = {"effect": "unexplained", "term": "unexplained", "best_partial": best["term"], "evidence": ev,
               "held_out_at_floor": bool(fl["at_floor"])}
    if size:
        partial["size"] = {k: v for k, v in size.items() if k != "text"}
    if not ff["closes_gap"]:
        return {**partial, "gap_closed": False,
                "reason": f"significant gap, {what}; the best candidate, {best['term']}, shrinks the held-out "
                          f"residual ({ho['rms_base_ug']:.3g} -> {ho['rms_ug']:.3g} ug) but leaves chi2/dof "
                          f"{ff['chi2_dof']:.3g} (p = {ff['p_value']:.3g}) after its refit: no candidate closes it"}
    if not fl["at_floor"]:
        return {**partial, "gap_closed": False,
                "reason": f"significant gap, {what}; the best candidate, {best['term']}, closes it on the intervals "
                          f"it is fitted to (chi2/dof {ff['chi2_dof']:.3g}) but not on held-out ones: their residual "
                          f"power is {fl['ratio']:.3g} x what a term that explains everything leaves there (p = "
                          f"{fl['p_value']:.3g}; RMS {ho['rms_base_ug']:.3g} -> {fl['rms_ug']:.3g} ug against "
                          f"{fl['expected_rms_ug']:.3g} ug expected): a partial shrink, not the answer"}
    lost = [r for r in rivals if r["testable"] and not r["versus_best"]["beaten"]]
    if lost:
        txt = "; ".join(f"{r['term']} (held-out z^2 worse by {r['versus_best']['mean_diff']:.3g} +- "
                        f"{r['versus_best']['se']:.3g})" for r in lost)
        return {**partial, "ambiguous_with": [r["term"] for r in lost][:4], "gap_closed": True,
                "reason": (f"significant gap, {what}; {best['term']} closes it, held out too, but does not beat "
                           f"{len(lost)} rival(s) outside the candidates on held-out intervals by "
                           f"{SHRINK_SE:g} paired standard errors (and {MIN_RIVAL_Z2:g} in z^2 per fold): {txt}; "
                           f"the data cannot tell "
                           f"{best['term']} from them")}
    v = {"effect": best["term"], "term": best["term"], "gap_closed": True, "held_out_at_floor": True, "evidence": ev,
         "reason": (f"{best['term']} closes the significant gap ({what}): its held-out residual is at the floor "
                    f"(power {fl['ratio']:.3g} x what a term that explains everything leaves there, p = "
                    f"{fl['p_value']:.3g}; RMS {ho['rms_base_ug']:.3g} -> {fl['rms_ug']:.3g} ug against "
                    f"{fl['expected_rms_ug']:.3g} ug expected) and it beats every rival outside the candidates held "
                    f"out by {SHRINK_SE:g} paired standard errors")}
    if size:
        v["size"] = partial["size"]
    beaten = [r for r in rivals if r["testable"]]
    if beaten:
        # the evidence that it beats the runner-up: the rival it beats by the fewest paired SE
        close = min(beaten, key=lambda r: r["versus_best"]["mean_diff"] / max(r["versus_best"]["se"], 1e-300))
        vb = close["versus_best"]
        v["evidence"] += (f"; beats its closest rival, {close['term']}, held out: z^2 worse by {vb['mean_diff']:.3g} "
                          f"+- {vb['se']:.3g} there ({vb['mean_diff'] / max(vb['se'], 1e-300):.3g} paired SE, "
                          f"{SHRINK_SE:g} and at least {MIN_RIVAL_Z2:g} needed)")
    if best.get("indistinguishable_from"):
        v["evidence"] += ("; held out, not better than " + ", ".join(best["indistinguishable_from"])
                          + " by 2 SE, which has more parameters")
    if size and "parameter" in size:
        unseen = best["full_fit"].get("unseen")
        within = (f" by less than about {unseen['rms_ug']:.3g} ug RMS over the intervals (the size at which the "
                  f"gap's rule, after its refit, detects a pattern with probability {unseen['power']:g})"
                  if unseen else "")
        v["caveat"] = (f"the gravity norm sees {best['term']} only through its pattern over these {n} intervals "
                       f"outside the 9-parameter correction: an error outside the candidates and rivals whose "
                       f"pattern there differs from it{within} is named {best['term']} too; its fitted size is "
                       f"reported, not judged")
    if len(sig) > 1:
        v["runner_up_term"] = v["runner_up"] = sig[1]["term"]
    return v
