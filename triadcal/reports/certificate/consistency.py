"""What a certificate checks of a result before it states anything: that the result agrees with
itself and with the data and dates given where the certificate would print it. A result re-signed
with a recomputed content_sha256 passes the reader's hash check; what it states must still hold
together (outside probes, 2026-12-01):

- every parameter's U at the coverage probability the certificate states (95.45 %, k = 2 for a
  normal distribution): a K_x re-signed at 68.27 %, k = 1, U = u, was printed under "U (95.45 %)"
  while section 7 recomputed k = 2 from its budget;
- the budget of every parameter the budget table shows when any parameter carries one, and in
  every budget a row of every systematic error the result propagated (the fit writes each row
  into every parameter's budget, 0 where the error does not reach it): K_x's budget deleted, or
  its local-gravity row deleted and u, U lowered to match, gave a certificate with a missing
  column or a smaller U and a blank gravity cell;
- the k, U and effective degrees of freedom section 7 recomputes from a budget equal to those
  the result states (section 4 prints the result's U);
- the temperature range against the data's visits (:func:`range_problem`) and the dates of
  calibration and issue (:func:`calibration_date`, :func:`check_issue_date`).

Each refusal is one line (:class:`~triadcal.estimation.result_checks.RefusedResult`) naming the
file and the JSON path.
"""

from __future__ import annotations

import datetime as _dt
import math
from typing import Optional

from ...errors import InputError
from ...estimation.result_checks import RefusedResult
from ...io.dates import FUTURE_SLACK_DAYS, iso_date
from ...models.sensor import AXES
from ...uncertainty.angles import ANGLES

#: the coverage probability of every U a certificate states: that of k = 2 for a normal
#: distribution (JCGM 100 G.1.3), as :class:`~triadcal.uncertainty.budget.Budget` computes it
CERTIFICATE_COVERAGE = math.erf(2.0 / math.sqrt(2.0))
#: a stated coverage probability within this of ``CERTIFICATE_COVERAGE`` is it (0.9545 written short)
COVERAGE_TOL = 5e-4
#: U, k and dof_eff recomputed from a budget against the result's (relative; the writer computes them
#: from the same rows, the Monte Carlo with the same seed)
RECOMPUTE_REL_TOL = 1e-3
#: the data's visit temperatures against a result's temperature_range_C (degC): the fit writes the
#: range of the temperatures it saw, the same numbers
RANGE_TOL_C = 0.005
#: the parameters whose budgets section 7 prints column by column (content.BUDGET_GROUPS)
BUDGET_TABLE_NAMES = tuple(f"K_{a}" for a in AXES) + tuple(f"S_{a}" for a in AXES) + tuple(ANGLES)


def _refuse(source: str, where: str, what: str) -> RefusedResult:
    return RefusedResult(f"{source}: refused: {where} {what}")


def check_certifiable(result, source: str) -> None:
    """Refuse (one line naming ``source`` and the JSON path) a result whose stated uncertainties a
    certificate cannot print as they are: see the module. (A lab file declaring a systematic error
    that no budget holds is refusal.py's and content._lab_disagrees' reason: fitted with another lab file.)"""
    params = result.parameters
    # coverage: one, the certificate's ------------------------------------------------------------
    for n, p in params.items():
        unc = p.uncertainty or {}
        cp = unc.get("coverage_probability")
        if cp is None:
            if p.U is not None:
                raise _refuse(source, f"parameters.{n}.U", f"= {p.U:.6g} is stated without a coverage_probability: "
                              "a certificate states every U at 95.45 % (k = 2 for a normal distribution) and cannot "
                              "say what this one covers")
            continue
        if abs(float(cp) - CERTIFICATE_COVERAGE) > COVERAGE_TOL:
            others = sorted({f"{float(q.uncertainty['coverage_probability']):.4g}" for q in params.values()
                             if (q.uncertainty or {}).get("coverage_probability") is not None})
            raise _refuse(source, f"parameters.{n}.coverage_probability",
                          f"= {float(cp):.6g} (k = {float(unc.get('k', math.nan)):.4g}), but a certificate states every "
                          f"U at a coverage probability of 95.45 % (k = 2 for a normal distribution), in its results "
                          f"table, its method and its budgets" + (f"; the result's parameters state {', '.join(others)}"
                                                                  if len(others) > 1 else "")
                          + ": triadcal writes 95.45 %; fit again")
    # budgets: all or none of the table's parameters ----------------------------------------------
    with_budget = [n for n, p in params.items() if (p.uncertainty or {}).get("budget")]
    if with_budget:
        # (a parameter without a finite value or u: refusal.refusal_reasons says so in the report)
        lacking = [n for n in BUDGET_TABLE_NAMES if n in params and n not in with_budget
                   and math.isfinite(params[n].u) and math.isfinite(params[n].value)]
        if lacking:
            raise _refuse(source, f"parameters.{lacking[0]}.budget",
                          "is missing" + (f" (and that of {', '.join(lacking[1:])})" if len(lacking) > 1 else "")
                          + f", while {len(with_budget)} other parameters carry theirs (e.g. {with_budget[0]}): a fit "
                          "writes a budget for every parameter or for none, and the certificate's budget table shows "
                          "every scale factor, bias and angle; the file was edited: fit again")
    # every budget holds a row of every systematic error the result propagated ---------------------
    rows_of = {n: [r for r in params[n].uncertainty["budget"] if isinstance(r, dict)] for n in with_budget}
    declared = {}                                # source -> where it is declared
    for n, rows in rows_of.items():
        for r in rows:
            if r.get("type") == "B":
                declared.setdefault(str(r.get("source")), f"the budget of {n}")
    # ... and those the result's fit declares it propagated (fit.systematic_errors), when it holds Type B
    stated = result.fit.get("systematic_errors") if isinstance(result.fit, dict) else None
    if declared and isinstance(stated, list):
        for i, e in enumerate(stated):
            if isinstance(e, dict) and e.get("source") and str(e["source"]) not in declared:
                declared[str(e["source"])] = (f"fit.systematic_errors[{i}] ({e.get('key', '')} = "
                                              f"{e.get('u', '?')} {e.get('unit', '')})")
    for n, rows in rows_of.items():
        if not declared:
            break
        held = {str(r.get("source")) for r in rows if r.get("type") == "B"}
        missing = [s for s in declared if s not in held]
        if missing:
            s = missing[0]
            raise _refuse(source, f"parameters.{n}.budget",
                          f"holds no row of '{s}', which {declared[s]} declares" + (
                              f" (nor of {', '.join(repr(x) for x in missing[1:])})" if len(missing) > 1 else "")
                          + ": a fit writes a row of every systematic error it propagated into every parameter's "
                          "budget (contribution 0 where it does not reach it), so the U of this parameter leaves that "
                          "error out; the file was edited: fit again")
    # section 7 recomputes k, U and nu_eff from the budget: they must be the result's ----------------
    from ...uncertainty.typeb import budget_of

    for n in BUDGET_TABLE_NAMES:
        if n not in rows_of or params[n].U is None:
            continue
        p = params[n]
        b = budget_of(n, p)
        if b is None or b.total <= 0:
            continue
        U_b = b.expanded_U
        if abs(U_b - p.U) > RECOMPUTE_REL_TOL * max(abs(U_b), abs(p.U)):
            raise _refuse(source, f"parameters.{n}.U", f"= {p.U:.6g} (k = {p.U / p.u:.4g}), but its budget gives "
                          f"U = {U_b:.6g} (k = {b.effective_k:.4g}, {b.method}) at 95.45 %: the results table and the "
                          "budget table would state two different U; the file was edited: fit again")
        nu_b, nu = b.dof_eff, (p.uncertainty or {}).get("dof_eff")
        nu = math.inf if nu is None else float(nu)
        if not (math.isinf(nu_b) and math.isinf(nu)) and (
                math.isinf(nu_b) != math.isinf(nu) or abs(nu_b - nu) > RECOMPUTE_REL_TOL * max(nu_b, nu)):
            raise _refuse(source, f"parameters.{n}.dof_eff", f"= {'null (infinite)' if math.isinf(nu) else f'{nu:.4g}'}, "
                          f"but its budget's rows give {'infinite' if math.isinf(nu_b) else f'{nu_b:.4g}'} effective "
                          "degrees of freedom (Welch-Satterthwaite): the file was edited: fit again")


def range_problem(result, campaign, source: str) -> Optional[str]:
    """Why the result's ``temperature_range_C`` is not the range its data saw, or None: the fit writes
    the lowest and highest sensor temperature of the visits it fitted (a subset of the file with
    ``--state``: a narrower range), so a range reaching beyond the data's visit temperatures by more
    than ``RANGE_TOL_C`` is not the fit's (an outside probe: [-60, 100] re-signed over visits at
    -39.76..70.37 degC was certified as "the thermal model applies from -60 to 100 °C")."""
    rng = result.temperature_range_C
    if not rng or campaign is None:
        return None
    import numpy as np

    t = np.asarray(campaign.t, float)
    t = t[np.isfinite(t)]
    if t.size == 0:
        return None
    lo, hi = float(t.min()), float(t.max())
    if rng[0] < lo - RANGE_TOL_C or rng[1] > hi + RANGE_TOL_C:
        return (f"{source}: refused: temperature_range_C = [{rng[0]:.4f}, {rng[1]:.4f}] degC reaches beyond the "
                f"temperatures of the data's visits ({campaign.source or 'the campaign'}: {lo:.4f} .. {hi:.4f} degC, "
                "t_x, t_y, t_z): the fit writes the range of the temperatures it saw, and the thermal model is not "
                "valid beyond them; the file was edited: fit again")
    return None


def calibration_date(result, campaign, lab, source: str = "result") -> tuple[str, str]:
    """The date of calibration and where it comes from: the data's ``# date`` (with ``--data``), else the
    result's ``data_date`` (written by the fit from the same line), else the lab file's
    ``[item] calibration_date``; ("", "") when none states one. A result whose ``data_date`` is not its
    data's date is refused (its data given, their SHA-256 the result's)."""
    data_day = campaign.metadata.get("date", "") if campaign is not None else ""
    stored = result.extra.get("data_date")
    if data_day:
        iso = iso_date(data_day)
        if stored and iso and str(stored) != iso:
            where = campaign.source or "the campaign"
            raise _refuse(source, "data_date", f"= {stored} is not the date of its data ({where}: # date {data_day}), "
                          "whose SHA-256 is the result's data_sha256: the fit writes the data's date; the file was "
                          "edited: fit again")
        return str(data_day), f"from the data{f' {campaign.source}' if campaign.source else ''}"
    if stored:
        return str(stored), "the result's data_date"
    if lab is not None and lab.calibration_date:
        return str(lab.calibration_date), "lab file"
    return "", ""


def check_issue_date(issue_date: str, given: bool, cal_date: str, cal_where: str) -> None:
    """Refuse an issue date before the date of calibration, or after today (the machine's clock, UTC,
    with io.dates' slack of ``FUTURE_SLACK_DAYS`` for time zones): --date 2026-11-01 gave a certificate
    dated 19 days before its data were taken, --date 2099-01-01 one 73 years ahead (an outside probe)."""
    what = f"--date {issue_date} (the date of issue)" if given else f"the date of issue {issue_date} (today; no --date)"
    try:
        day = _dt.date.fromisoformat(str(issue_date))
    except ValueError:
        raise InputError(f"--date: expected YYYY-MM-DD, got {issue_date!r}") from None
    today = _dt.datetime.now(_dt.timezone.utc).date()
    if (day - today).days > FUTURE_SLACK_DAYS:
        raise InputError(f"{what} is after today ({today.isoformat()}): a certificate is dated the day it is "
                         "issued" + (f" (the date of calibration is {cal_date}, {cal_where})" if cal_date else ""))
    iso = iso_date(cal_date) if cal_date else None
    if iso and day < _dt.date.fromisoformat(iso):
        late = _dt.date.fromisoformat(iso) > today + _dt.timedelta(days=FUTURE_SLACK_DAYS)
        raise InputError(f"{what} is before the date of calibration {iso} ({cal_where}): a certificate is issued on "
                         "or after the calibration" + (f"; and {iso} is after today ({today.isoformat()}): a "
                                                      "calibration cannot have happened yet" if late else ""))
