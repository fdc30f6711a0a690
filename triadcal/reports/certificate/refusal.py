"""When no certificate is issued: a result that fails an answer gate, parameters the data could
not determine, a significant model-data gap, a posterior that did not mix.
"""

from __future__ import annotations

import math
from typing import Optional

from ...models.effects import TEMPCO_EFFECTS

from ...estimation.result_checks import result_problems
from ...estimation.result import CalibrationResult

#: a model-data gap is significant below this p-value of chi^2 with known noise (as in the joint fit)
GAP_P_THRESHOLD = 1e-3


#: the rule for a posterior file that carries no verdict and whose result states no stop rule
#: (another program's draws): rank-normalised R-hat < 1.01 and bulk and tail ESS >= 400
#: (Vehtari et al. 2021, Bayesian Analysis 16(2))
DEFAULT_STOP_RULE = {"rhat_max": 1.01, "ess": 400.0}


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


def posterior_diagnostics(idata, names, result: Optional[CalibrationResult] = None) -> dict:
    """The posterior file's convergence verdict. ``triadcal sample`` computes it once, on exactly
    the draws it saves, and stores it in the posterior group's attributes: it is read here, not
    recomputed. A file without it (another program's) is judged once by the sampler's own
    function (:func:`triadcal.estimation.posterior.diagnostics`) under the stop rule of
    ``result`` (or, without one, ``DEFAULT_STOP_RULE``)."""
    post = idata.posterior
    base = {"n_chains": int(post.sizes.get("chain", 0)), "n_draws": int(post.sizes.get("draw", 0))}
    a = post.attrs
    if all(k in a for k in ("converged", "rhat_max", "rhat_worst", "ess_bulk_min", "ess_tail_min")):
        return {**base, "source": "stored by the sampler with the draws", "converged": bool(a["converged"]),
                "rhat_max": float(a["rhat_max"]), "rhat_worst": str(a["rhat_worst"]),
                "ess_bulk_min": float(a["ess_bulk_min"]), "ess_worst": str(a.get("ess_bulk_worst", "")),
                "ess_tail_min": float(a["ess_tail_min"]),
                "stop_rule": {"rhat_max": float(a.get("stop_rule_rhat_max", DEFAULT_STOP_RULE["rhat_max"])),
                              "ess": float(a.get("stop_rule_ess", DEFAULT_STOP_RULE["ess"]))}}
    names = [n for n in names if n in post.data_vars]
    if not names:
        return {}
    import numpy as np

    from ...estimation.posterior.diagnostics import diagnostics

    chain = np.stack([np.asarray(post[n].values, float).T for n in names], axis=-1)   # (draw, chain, d)
    diag = diagnostics(chain, names)
    stored = ((result.extra.get("sampler") or {}).get("stop_rule") if result is not None else None) or {}
    rule = {"rhat_max": float(stored.get("rhat_max", DEFAULT_STOP_RULE["rhat_max"])),
            "ess": float(stored.get("ess", DEFAULT_STOP_RULE["ess"]))}
    ir, ib, it = int(np.argmax(diag["rhat"])), int(np.argmin(diag["ess_bulk"])), int(np.argmin(diag["ess_tail"]))
    converged = bool(diag["rhat"][ir] < rule["rhat_max"]
                     and min(diag["ess_bulk"][ib], diag["ess_tail"][it]) >= rule["ess"])
    return {**base, "source": "computed from the draws (the file carries no verdict)", "converged": converged,
            "rhat_max": float(diag["rhat"][ir]), "rhat_worst": names[ir], "ess_bulk_min": float(diag["ess_bulk"][ib]),
            "ess_worst": names[ib], "ess_tail_min": float(diag["ess_tail"][it]), "stop_rule": rule}


#: a reference temperature this far (degC) outside the calibrated range is an extrapolation, not a calibration
REFERENCE_OUTSIDE_C = 1.0


def reference_outside_range(result: CalibrationResult) -> Optional[str]:
    """Why the values, stated at the model's reference temperature, are no calibration: that temperature
    lies more than :data:`REFERENCE_OUTSIDE_C` outside the calibrated range, where the thermal terms
    extrapolate (or None). An outside probe fitted --reference-temperature 100 on data of -20..60 degC:
    the certificate stated every value "at the reference temperature 100 degC" and, in section 5, that
    the model is not valid outside -19.8..60.3 degC."""
    rng, tref = result.temperature_range_C, result.reference_temperature_C
    if not rng or tref is None or not any(e in result.effects for e in TEMPCO_EFFECTS):
        return None
    lo, hi = float(rng[0]), float(rng[1])
    if lo - REFERENCE_OUTSIDE_C <= float(tref) <= hi + REFERENCE_OUTSIDE_C:
        return None
    return (f"the values are stated at the reference temperature {float(tref):g} degC, outside the calibrated range "
            f"{lo:.2f}..{hi:.2f} degC: there the thermal terms extrapolate, which is no calibration; fit again with "
            "--reference-temperature inside the range")


def refusal_reasons(result: CalibrationResult, *, posterior_diag: Optional[dict] = None,
                    diagnosis: Optional[dict] = None, unhashed: bool = True) -> list[str]:
    """Why no certificate can be issued for ``result`` (empty: it can be issued).

    Checked: the estimator's status, parameters it could not determine, a significant
    model-data gap (chi^2 with known noise, p < ``GAP_P_THRESHOLD``; or a diagnosis file
    whose ``gap.significant`` is true), missing or non-finite uncertainties, and the
    posterior's convergence verdict (:func:`posterior_diagnostics`) when a posterior is given.
    ``unhashed=False``: a result without ``content_sha256`` is not a reason (export-compensation
    writes such a result's table with a note).
    """
    reasons = []
    if result.status != "ok":
        # the failed gates say why (each its own reason below); without them, the notes do
        failed = [o.get("reason") for o in (result.extra.get("gates") or {}).get("outcomes") or []
                  if isinstance(o, dict) and o.get("passed") is False and o.get("reason")]
        reasons.append(f"the estimator reports status '{result.status}' (a certificate needs 'ok')"
                       + (": " + "; ".join(failed) if failed else
                          (": " + "; ".join(result.notes) if result.notes else "")))
    reasons += [why if why == result.content_mismatch else f"the result fails an answer gate: {why}"
                for why in result_problems(result, need_ok=False)]
    if result.content_unhashed and unhashed:
        # an outside probe: with its content_sha256 deleted, a result whose Ca_xy was edited by +50 arcsec
        # was certified (compare and history still read such files, as the contract says)
        reasons.append("the result file holds no content_sha256 (written by another tool, or by triadcal before "
                       "2026-11-30), so nothing shows that its values are the fit's answer: a certificate is issued "
                       "only for a result as triadcal saved it; fit the data again with this version")
    if result.extra.get("local_g_stated") is False:
        # fit-raw without --local-g: K and S rest on an assumed 9.81 m/s^2, up to 0.3 % off on Earth's
        # surface, which their u does not hold (an outside probe: K 100 u high with status ok)
        # (a bench CSV without # local_g_m_s2 too: there standard gravity; the reason named fit-raw's 9.81 for it)
        g = result.extra.get("local_g_m_s2")
        g_txt = f"{float(g):.7g} m/s2" if isinstance(g, (int, float)) and math.isfinite(g) else "a standard value"
        reasons.append(f"the data state no local gravity ({g_txt} assumed): K and S scale with it one to one, "
                       "up to 0.3 % anywhere on Earth's surface, which their uncertainties do not hold; state the "
                       "site's value and fit again (fit-raw --local-g; a bench CSV's # local_g_m_s2, or the lab "
                       "file's [gravity] local_g_m_s2 with u_ppm)")
    unid = unidentified_parameters(result)
    if unid:
        reasons.append("the data could not determine " + "; ".join(f"{k} ({v})" for k, v in unid.items())
                       + " - refit without those terms (--effects) or with a campaign that determines them")
    outside = reference_outside_range(result)
    if outside:
        reasons.append(outside)
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
    if posterior_diag and not posterior_diag.get("converged", True):
        rule = posterior_diag["stop_rule"]
        reasons.append(
            f"the posterior has not converged on its saved draws ({posterior_diag['source']}): worst R-hat "
            f"{posterior_diag['rhat_max']:.4f} ({posterior_diag['rhat_worst']}) against < {rule['rhat_max']:g}, "
            f"lowest bulk/tail ESS {posterior_diag['ess_bulk_min']:.0f}/{posterior_diag['ess_tail_min']:.0f} "
            f"against >= {rule['ess']:.0f}; run `triadcal sample` again with a larger --max-steps "
            f"(or a larger --ess, e.g. --ess {2 * rule['ess']:.0f}, for longer chains)")
    if posterior_diag and result.method == "posterior" and posterior_diag["source"].startswith("stored"):
        mine = (result.extra.get("sampler") or {}).get("rhat_max")
        if isinstance(mine, (int, float)) and not math.isclose(mine, posterior_diag["rhat_max"], rel_tol=1e-9):
            reasons.append(f"the posterior file is not the one written with this result (its worst R-hat is "
                           f"{posterior_diag['rhat_max']:.6f}, the result's {mine:.6f}); give the netCDF that "
                           "`triadcal sample` wrote together with this JSON")
    return reasons


def gravity_reasons(result: CalibrationResult, lab) -> list:
    """Why the local gravity under K keeps a certificate back, given the lab file ``lab``: the data state
    none (:func:`_unstated_gravity`), or the budgets hold the lab's errors but not the g's
    (:func:`_gravity_without_u`). (Data that state none and a fit-raw that assumed one: refusal_reasons.)"""
    return _unstated_gravity(result, lab) + _gravity_without_u(result)


def _unstated_gravity(result: CalibrationResult, lab) -> list:
    """A result whose data stated no local gravity (``local_g_stated`` false: the fit assumed standard
    gravity), certified without a lab file that states it. K and S are in g of the gravity assumed,
    and a site's is 9.78-9.83 m/s^2: 9.81 where 9.80665 was assumed put K 260 u off with status ok
    (an outside probe); the certificate would state that K to 1 ppm."""
    stated = result.extra.get("local_g_stated")
    if (lab.local_g_m_s2 is not None or stated is False            # (refusal.refusal_reasons says it then)
            or result.extra.get("local_g_m_s2") is not None):
        return []
    return ["the data state no local gravity: the fit took standard gravity (9.80665 m/s^2), and K and S are in g of "
            "it where a site's is 9.78-9.83 m/s^2 (up to 0.3 % in K); state the measured value in the data "
            "(# local_g_m_s2 = ..., capture --local-g) and fit again, or in the lab file ([gravity] local_g_m_s2)"]


def _gravity_without_u(result: CalibrationResult) -> list:
    """A result whose budgets hold the lab's systematic errors but no row of the local gravity: the g of
    the fit, stated in the data without a u (bench CSV v1 has no key for one), was taken as exact, and
    K takes it one to one. An outside probe: a site value uncertain by 20 ppm, a lab file of bench and
    fixture errors without ``[gravity]``: value +- U held K in 75 of 150 and the certificate was issued
    ("Local gravity 9.81120 m/s2 (local value stated in the data)"). A Type-A-only result says it leaves
    every systematic error out (section 2), and is not refused here."""
    if not result.holds_type_b() or result.extra.get("local_g_stated") is False:   # no g at all: _unstated_gravity
        return []
    if any(r.get("key") == "[gravity] u_ppm" or r.get("equipment") == "gravity" for r in result.budget_rows()):
        return []
    g = result.extra.get("local_g_m_s2")
    return ["the budgets hold the lab's systematic errors but not the local gravity's: the fit took g"
            + (f" = {float(g):.7g} m/s^2" if isinstance(g, (int, float)) else "")
            + " as exact (the data state no u for it), and K takes it one to one; state it in the lab file "
            "([gravity] local_g_m_s2, u_ppm) and fit again with --lab"]
