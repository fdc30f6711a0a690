"""When no certificate is issued: a result that fails an answer gate, parameters the data could
not determine, a significant model-data gap, a posterior that did not mix.
"""

from __future__ import annotations

import math
from typing import Optional

from ...estimation.gates import result_problems
from ...estimation.result import CalibrationResult

#: a model-data gap is significant below this p-value of chi^2 with known noise (as in the joint fit)
GAP_P_THRESHOLD = 1e-3


#: posterior diagnostics below which no certificate is issued (Vehtari et al. 2021)
RHAT_MAX = 1.01


ESS_MIN = 400.0


# =========================================================================================
# refusal
# =========================================================================================
def unidentified_parameters(result: CalibrationResult) -> dict:
    """Parameters the estimator could not determine (held at a nominal value), with the reason.

    From ``extra["unidentifiable"]`` when the estimator writes it, else from the joint
    fit's notes ("<name> not estimated, held at ...: <reason>").
    """
    structured = result.extra.get("unidentifiable")
    if isinstance(structured, dict):
        return {str(k): str(v) for k, v in structured.items()}
    out = {}
    for note in result.notes:
        head, sep, reason = str(note).partition(" not estimated, held at ")
        if sep and " " not in head:
            out[head] = reason.split(": ", 1)[-1]
    return out


def _arviz():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # arviz 0.2x announces its 1.0 refactor on import
        import arviz as az
    return az


def posterior_diagnostics(idata, names) -> dict:
    """Worst R-hat and bulk ESS over ``names`` present in the posterior (arviz)."""
    az = _arviz()

    names = [n for n in names if n in idata.posterior.data_vars]
    if not names:
        return {}
    sub = idata.posterior[names]
    rhat = az.rhat(sub)
    ess = az.ess(sub, method="bulk")
    r = {n: float(rhat[n].max()) for n in names}
    e = {n: float(ess[n].min()) for n in names}
    worst_r = max(r, key=lambda n: r[n] if math.isfinite(r[n]) else math.inf)
    worst_e = min(e, key=lambda n: e[n] if math.isfinite(e[n]) else -math.inf)
    return {"rhat_max": r[worst_r], "rhat_worst": worst_r, "ess_bulk_min": e[worst_e], "ess_worst": worst_e,
            "n_chains": int(idata.posterior.sizes.get("chain", 0)),
            "n_draws": int(idata.posterior.sizes.get("draw", 0))}


def refusal_reasons(result: CalibrationResult, *, posterior_diag: Optional[dict] = None,
                    diagnosis: Optional[dict] = None) -> list[str]:
    """Why no certificate can be issued for ``result`` (empty: it can be issued).

    Checked: the estimator's status, parameters it could not determine, a significant
    model-data gap (chi^2 with known noise, p < ``GAP_P_THRESHOLD``; or a diagnosis file
    whose ``gap.significant`` is true), missing or non-finite uncertainties, and the
    posterior's R-hat and bulk ESS (``RHAT_MAX``, ``ESS_MIN``) when a posterior is given.
    """
    reasons = []
    if result.status != "ok":
        reasons.append(f"the estimator reports status '{result.status}' (a certificate needs 'ok')"
                       + (": " + "; ".join(result.notes) if result.notes else ""))
    reasons += [f"the result fails an answer gate: {why}" for why in result_problems(result, need_ok=False)]
    unid = unidentified_parameters(result)
    if unid:
        reasons.append("the data could not determine " + "; ".join(f"{k} ({v})" for k, v in unid.items())
                       + " - refit without those terms (--effects) or with a campaign that determines them")
    p_gap = result.fit.get("gap_p_value")
    if isinstance(p_gap, (int, float)) and p_gap < GAP_P_THRESHOLD:
        reasons.append(f"significant gap between the model and the data: chi2/dof = "
                       f"{result.fit.get('chi2_dof', float('nan')):.3g} with known noise, p = {p_gap:.2g} "
                       f"< {GAP_P_THRESHOLD:g}; run `triadcal diagnose` and refit with the missing effect")
    if diagnosis:
        gap = diagnosis.get("gap") or {}
        if gap.get("significant"):
            eff = (diagnosis.get("verdict") or {}).get("effect")
            reasons.append(f"the diagnosis finds a significant model-data gap (chi2/dof = {gap.get('chi2_dof')})"
                           + (f", explained by the missing effect '{eff}'" if eff else ""))
    bad_u = [n for n, p in result.parameters.items() if not (math.isfinite(p.u) and p.u > 0)
             or not math.isfinite(p.value)]
    if bad_u:
        reasons.append(f"no finite value or uncertainty for {', '.join(bad_u)}")
    if posterior_diag:
        r, e = posterior_diag.get("rhat_max"), posterior_diag.get("ess_bulk_min")
        if r is not None and not r <= RHAT_MAX:
            reasons.append(f"the sampler did not converge: R-hat of {posterior_diag['rhat_worst']} is "
                           f"{r:.3f} > {RHAT_MAX} (run more or longer chains)")
        if e is not None and not e >= ESS_MIN:
            reasons.append(f"too few effective draws: bulk ESS of {posterior_diag['ess_worst']} is "
                           f"{e:.0f} < {ESS_MIN:.0f}")
    return reasons
