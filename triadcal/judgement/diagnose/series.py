"""A series of one temperature coefficient: its orders refitted together (docs/diagnosis.md,
"A series of one temperature coefficient").

When the best refit of the diagnosis is one order of ``angle_tempco*``, ``scale_tempco*`` or
``bias_tempco*`` and leaves the gap open, a smooth law of temperature may need more than one power
of (T - T0): an exponential bias law has every order. The orders of that one quantity that the
model lacks are refitted together and named (as the order of largest Wald chi^2, with every order
in ``verdict.effects``) only when they beat the single order by the nested likelihood ratio, raise
the elpd, and close the gap. Never effects of different physics: a forward selection over the
vocabulary would turn a left-out effect into a two-term wrong name.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from scipy import stats

from ...models.effects import EFFECTS
from .results import Candidate, _f, _p_is


#: the orders of one temperature coefficient, a Taylor series in (T - T0) (models/effects/thermal*.py)
TEMPCO_SERIES = {q: (f"{q}_tempco", f"{q}_tempco2", f"{q}_tempco3") for q in ("angle", "scale", "bias")}


def series_members(effect: str, model, cand_objs) -> Optional[list]:
    """The orders of ``effect``'s temperature coefficient that ``model`` lacks and whose candidates
    are testable with parameters on this design, when ``effect`` is one of them and there are at
    least two; else None."""
    orders = next((o for o in TEMPCO_SERIES.values() if effect in o), None)
    if orders is None:
        return None
    usable = {c.effect for c in cand_objs if c.testable and c.params and not c.refit_only}
    members = [e for e in orders if e not in model and e in usable]
    return members if effect in members and len(members) >= 2 else None


def series_txt(c) -> str:
    """Why the series of ``c``'s temperature coefficient, when it was tried, is not the answer."""
    ser = (c.refit or {}).get("series")
    if not ser:
        return ""
    why = []
    if ser["gap_open_after"]:
        c2 = ser["gap_after"]["chi2_dof"]
        why.append("leaves it open too ({}; generic structure: {})".format(
            (f"the noise estimated, no chi2 level: chi2/dof {ser['gap_after'].get('chi2_dof_ratio') or float('nan'):.3g} "
             "of the base fit's") if c2 is None else f"chi2/dof after {c2:.3g}",
            ", ".join(ser["gap_after"]["generic_structure"]) or "none"))
    if not why:
        why.append(f"does not beat {c.effect} alone ({ser['over_single']['criterion']}) or the base model")
    return f"; the series {' + '.join(ser['effects'])} " + "; ".join(why)


def series_of(best, *, model, cand_objs, states: dict, full, noise_known: bool, alpha: float,
              mean_refit, evidence, acceptance):
    """The series of ``best``'s temperature coefficient (``TEMPCO_SERIES``): every order of
    its quantity that the model lacks and the design can determine, refitted together, when
    ``best`` is one of them and there is another. A candidate (not ranked) whose
    ``refit["series"]`` holds the evidence, also recorded on ``best``'s refit; None when there
    is no series. Named (``series["named"]``) when it improves on the base (LR p < alpha,
    delta elpd > 0), its added orders beat ``best`` alone (nested likelihood ratio at alpha,
    and a higher delta elpd) and the gap after it lies in the acceptance band; the effect
    named is the order with the largest Wald chi^2 in that refit (docs/diagnosis.md, "A
    series of one temperature coefficient").

    The diagnosis's state is passed in: ``model`` (the fitted effects), ``cand_objs`` (the
    candidates), ``states`` (the refitted candidates' fit states by effect; the series' is added),
    ``full`` (the joint problem of every parameter), ``noise_known``, ``alpha``, and its procedures
    ``mean_refit(new_names) -> (state, loglik, LR p)``, ``evidence(c, st, new_names, var_scale, nu,
    ll, lr_p, added) -> refit dict`` and ``acceptance(c) -> (gap open, slices left, what is left)``
    (run.py), so that a series is judged exactly as a single candidate is."""
    members = series_members(best.effect, model, cand_objs)
    if members is None:
        return None
    params = {c.effect: c.params for c in cand_objs if c.effect in members}
    new_names = list(dict.fromkeys(n for e in members for n in params[e]))
    st, ll, lr_p = mean_refit(new_names)
    st_best = states[best.effect]
    k_extra = len(new_names) - len(best.params)
    if noise_known:
        stat = st_best.chi2 - st.chi2
        p_more = float(stats.chi2.sf(max(stat, 0.0), k_extra))
        crit = f"chi2 falls by {stat:.4g} on {k_extra} dof, p {_p_is(p_more)}"
    else:
        F = (st_best.chi2 - st.chi2) / k_extra / (st.chi2 / max(st.dof, 1))
        p_more = float(stats.f.sf(max(F, 0.0), k_extra, max(st.dof, 1)))
        crit = f"F = {F:.4g} on ({k_extra}, {max(st.dof, 1)}) dof, p {_p_is(p_more)}"
    wald = {}
    for e in members:
        idx = [st.names.index(n) for n in params[e]]
        xv = np.array([st.x_full[full.index[n]] for n in params[e]])
        try:
            wald[e] = float(xv @ np.linalg.solve(st.cov[np.ix_(idx, idx)], xv))
        except np.linalg.LinAlgError:
            wald[e] = 0.0
    lead = max(members, key=lambda e: wald[e])
    sc = Candidate(lead, True, k=len(new_names), params=new_names)
    sc.refit = evidence(sc, st, new_names, None, math.inf, ll, lr_p, members)
    states[id(sc)] = st
    open_, n_left, left = acceptance(sc)
    named_ = bool(lr_p < alpha and sc.refit["delta_elpd"] > 0 and p_more < alpha
                  and sc.refit["delta_elpd"] > best.refit["delta_elpd"] and not open_)
    effects_opt = ",".join(e for e in EFFECTS if e in model + tuple(members))
    ser = {"effects": list(members), "n_parameters": len(new_names), "lead": lead,
           "wald_chi2": {e: _f(v) for e, v in wald.items()},
           "lr_p_value": _f(lr_p), "delta_elpd": sc.refit["delta_elpd"],
           "delta_elpd_se": sc.refit["delta_elpd_se"],
           "over_single": {"effect": best.effect, "p_value": _f(p_more), "criterion": crit},
           "gap_after": {k: sc.refit["gap_after"][k] for k in ("chi2_dof", "chi2_dof_ratio", "significant_slices",
                                                               "generic_structure")},
           "gap_open_after": bool(open_), "named": named_,
           "fit_options": f"--effects {effects_opt}"}
    ser["evidence"] = (f"the series {' + '.join(members)} ({len(new_names)} parameters) refitted together: "
                       f"LR p {_p_is(lr_p)}, delta elpd = {sc.refit['delta_elpd']:.1f} +- "
                       f"{sc.refit['delta_elpd_se']:.1f}; over {best.effect} alone ({best.refit['delta_elpd']:.1f}), "
                       f"which leaves the gap open: {crit}; the leading order {lead} (Wald chi2 "
                       f"{wald[lead]:.3g}); reproduce with: triadcal fit DATA.csv --effects {effects_opt}")
    sc.refit["series"] = ser
    best.refit["series"] = {k: v for k, v in ser.items() if k != "evidence"}
    return sc
