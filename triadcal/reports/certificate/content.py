"""What a certificate states, independent of its rendering: identification, method, conditions,
parameters with U (k = 2, GUM 7.2.6 rounding), the thermal model, Ca^-1, the budget, plots.
"""

from __future__ import annotations

from ...models.units import STANDARD_GRAVITY_M_S2

import datetime as _dt
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from ... import __version__
from ...estimation.one_temperature import row_temperatures_C, rows_apart
from ...estimation.result import significant, CalibrationResult, round_to_uncertainty
from ...models.effects import EFFECTS
from ...models.model import Model
from ...models.sensor import AXES
from ...uncertainty.angles import ANGLES, uncertainty_budget
from ...uncertainty.budget import COVERAGE_FACTOR, Budget
from ...io.lab import LabConfig
from ...errors import InputError
from ..notation import display_text
from ...estimation.result_checks import RefusedResult
from .against_data import not_rederivable, typeb_problem, values_problem
from .consistency import calibration_date, check_certifiable, check_issue_date, range_problem
from .refusal import GAP_P_THRESHOLD, gravity_reasons, posterior_diagnostics, refusal_reasons

# =========================================================================================
# the certificate's content
# =========================================================================================
@dataclass
class ParameterRow:
    name: str
    description: str
    group: str
    value: str
    U: str
    unit: str


@dataclass
class Certificate:
    """Everything a certificate (or a refusal report) states, ready to render."""

    result: CalibrationResult
    issued: bool
    reasons: list
    number: Optional[str]
    issue_date: str
    lab: LabConfig
    rows: list = field(default_factory=list)
    source_of_u: str = ""
    identification: list = field(default_factory=list)   # (label, text)
    method: list = field(default_factory=list)
    conditions: list = field(default_factory=list)
    thermal_model: list = field(default_factory=list)    # lines of text
    inverse_matrix: Optional[np.ndarray] = None
    budget: Optional[Budget] = None
    plots: list = field(default_factory=list)
    skipped_plots: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    diagnostics: list = field(default_factory=list)       # (label, text)
    angle_statement: str = ""                             # the one angle uncertainty for using the matrix
    #: the budgets of the certified parameters at the reference temperature (angles, K, S),
    #: by group: {"Orientation angles": [Budget, ...], ...}; empty when the result has none
    parameter_budgets: dict = field(default_factory=dict)


#: budget components that are errors of the thermal model (the matrix used away from T0)
THERMAL_MODEL_SOURCES = ("hysteresis", "thermal coefficients", "thermal-model residual", "temperature measurement")


def values_temperature(result: CalibrationResult) -> str:
    """Where the values of ``result`` hold, for the certificate's sentences: "the reference temperature
    T0 °C", or, at one temperature with sensors apart (:func:`row_temperatures_C`), each accelerometer's
    own temperature (an outside probe: section 3 listed them while sections 4 and 6 and the console
    said "at the reference temperature 20.02 °C", X's row being 0.43 °C from it)."""
    if result.extra.get("reference_temperature_stated") is False:
        # a raw recording without a temperature column (fit-raw): its 20 degC is nominal, not measured
        return "the recording's temperature (not stated in the data)"
    rows_T = row_temperatures_C(result)
    if rows_apart(rows_T):
        return ("each accelerometer's own temperature (" + ", ".join(f"{a.upper()} {v:.2f}" for a, v in rows_T.items())
                + " °C, section 3)")
    return f"the reference temperature {result.reference_temperature_C:g} °C"


def angle_uncertainty_statement(cert: "Certificate") -> str:
    """The one angle uncertainty a user of the matrix needs: U of an angle when Ca^-1 and the
    thermal model are applied at a temperature in the range (the budget's U, k = 2), what it
    contains, and how it relates to the U at the reference temperature in the results table.
    u_c and U are both from the unrounded budget (U = 2 u_c, each rounded half up)."""
    b = cert.budget
    if b is None or not b.evaluated:
        return ""
    angle_U = [float(r.U) for r in cert.rows if r.group == "Orientation angles" and _is_number(r.U)]
    thermal = [c for c in b.components if c.source in THERMAL_MODEL_SOURCES]
    parts = ", ".join(f"{c.source} {significant(c.contribution, 2)}" if c.contribution is not None
                      else f"{c.source} not evaluated" for c in thermal)
    two_point = any(c.distribution == "two-point" and c.contribution for c in b.components)
    if abs(b.effective_k - b.coverage_factor) < 1e-6:
        kind = "k = 2"
    elif two_point:
        kind = (f"coverage {100 * b.coverage_probability:.2f} %, k = U/u_c = {b.effective_k:.3g}, the hysteresis "
                "being a two-point ±h and not a normal distribution")
    else:
        # no two-point component: k above 2 comes from the finite degrees of freedom of a Type A part
        kind = (f"coverage {100 * b.coverage_probability:.2f} %, k = {b.effective_k:.3g} from the effective degrees "
                f"of freedom ν_eff = {b.dof_eff:.3g} (Welch–Satterthwaite)")
    own = (f" It contains the angles' own uncertainty at the reference temperature (U up to "
           f"{max(angle_U):g} {b.unit} in the results table, which applies only at "
           f"{values_temperature(cert.result)} on the mid-line)" if angle_U else " It contains")
    return (f"Using the matrix: when Ca⁻¹ and the thermal model are applied at a temperature within the "
            f"calibrated range, the uncertainty of each orientation angle is U = {significant(b.expanded_U, 2)} "
            f"{b.unit} ({kind}; u_c = {significant(b.total, 3)} {b.unit}).{own}, the bench's errors, and the "
            f"thermal model's error as its own components ({parts}; {b.unit}, standard uncertainties); "
            "section 7 lists them all.")


def _is_number(text) -> bool:
    try:
        float(text)
    except (TypeError, ValueError):
        return False
    return True


GROUPS = ("Scale factors", "Biases", "Orientation angles", "Thermal coefficients", "Hysteresis",
          "Other terms", "Bench (not a property of the unit)")


#: the groups whose budgets the certificate prints parameter by parameter
BUDGET_GROUPS = ("Orientation angles", "Scale factors", "Biases")


def _group(name: str) -> str:
    if name.startswith("tilt_") or name == "bench_nonorth":
        return GROUPS[6]
    if "_tempco" in name:  # every order: Ca_xy_tempco, K_x_tempco2, S_z_tempco3
        return GROUPS[3]
    if name.endswith("_hysteresis"):
        return GROUPS[4]
    if name in ANGLES:
        return GROUPS[2]
    if name in tuple(f"K_{a}" for a in AXES):
        return GROUPS[0]
    if name in tuple(f"S_{a}" for a in AXES):
        return GROUPS[1]
    return GROUPS[5]


def expanded(value: float, u: float) -> tuple[str, str]:
    """Value and U = k u (k = 2) as strings: U to two significant digits, the value to match."""
    return round_to_uncertainty(value, COVERAGE_FACTOR * u)


def parameter_rows(result: CalibrationResult) -> list:
    """One row per parameter of the result, grouped as on the certificate."""
    try:
        spec = Model([e for e in result.effects if e in EFFECTS], result.reference_temperature_C).spec
    except (ValueError, KeyError):
        spec = {}
    extra_desc = {"tilt_delta": "tilt of the bench against the local vertical (δ)",
                  "tilt_beta": "direction of the bench tilt (β)"}
    rows = []
    for name, p in result.parameters.items():
        # the parameter's own U (its budget: k from dof_eff, or a Monte Carlo) when it has one
        v, U = round_to_uncertainty(p.value, p.U) if p.U is not None else expanded(p.value, p.u)
        desc = display_text(spec[name].description if name in spec else extra_desc.get(name, ""))
        rows.append(ParameterRow(name, desc, _group(name), v, U, p.unit))
    order = {g: i for i, g in enumerate(GROUPS)}
    return sorted(rows, key=lambda r: order[r.group])  # stable: keeps the file's order in a group


def _tempco_terms(result: CalibrationResult, kind: str, symbol: str) -> list:
    """``symbol_tempco·dT``, ``symbol_tempco2·dT²``, ``symbol_tempco3·dT³`` for the orders of ``kind``'s
    tempcos (K, S, Ca) that the result has on any axis."""
    have = {n.split("_tempco", 1)[1] for n in result.parameters if n.startswith(kind + "_") and "_tempco" in n}
    return [f"{symbol}_tempco{o}·dT{power}" for o, power in (("", ""), ("2", "²"), ("3", "³")) if o in have]


def thermal_model_lines(result: CalibrationResult) -> list:
    """Section 5: how each K_a, S_a and Ca_ab of the table moves with temperature, written from the
    result's own terms (docs/model.md: linear, quadratic and cubic tempcos, K's as factors, the
    hysteresis branch and its form, the element's lag), with the unit factor a reader needs (K's
    coefficients in ppm are relative, S's in µg where S is in g), and the range where it holds.
    A reader applying only ``x + x_tempco·(T − T0)`` to a result with quadratic and cubic terms was
    off by 9″ in an angle and 3 000 ppm in K at the range's ends (an outside probe)."""
    T0 = result.reference_temperature_C
    hyst = "hysteresis" in result.effects and any(n.endswith("_hysteresis") for n in result.parameters)
    terms_K = _tempco_terms(result, "K", "K_a")
    terms_S = _tempco_terms(result, "S", "S_a")
    terms_Ca = _tempco_terms(result, "Ca", "Ca_ab")
    tm = []
    if terms_K or terms_S or terms_Ca or hyst:
        tm.append(f"Each term of the table is given at the reference temperature T0 = {T0:g} °C. At a temperature T "
                  "of the accelerometer's own sensor (dT = T − T0 in °C; K_a, S_a and the angles Ca_ab of row a "
                  "follow the sensor of accelerometer a), with the coefficients of the table in its units:")
        if terms_K:
            tm.append("K_a(T) = K_a · " + " · ".join(f"(1 + 10⁻⁶·{t})" for t in terms_K)
                      + (": the coefficients, in ppm, are relative and each is its own factor, so multiply the factors, "
                         "do not add the terms" if len(terms_K) > 1 else ": the coefficient, in ppm, is relative") + ";")
        if terms_S:
            tm.append("S_a(T) = S_a + 10⁻⁶·(" + " + ".join(terms_S)
                      + "): S_a in g, its coefficients in µg;")
        if terms_Ca or hyst:
            form = (result.fit.get("hysteresis") or {}).get("form", "offset") if hyst else None
            tm.append("Ca_ab(T) = Ca_ab" + "".join(f" + {t}" for t in terms_Ca)
                      + (" + Ca_ab_hysteresis·b" if hyst else "") + " (arcsec)"
                      + ("" if not hyst else
                         ", with b = +1 on the cooling branch and −1 on the heating branch" if form == "offset" else
                         ", with b the branch of a play of half-width "
                         f"{(result.fit.get('hysteresis') or {}).get('half_width_C', float('nan')):g} °C on the "
                         "temperature's history, between −1 (heating, saturated) and +1 (cooling, saturated)"
                         if form == "play" else
                         ", with b the branch of the fitted sum of plays on the temperature's history, between −1 "
                         "(heating, saturated) and +1 (cooling, saturated)")
                      + ("; the matrix below is the mid-line (b = 0)" if hyst else "") + ".")
        if "thermal_lag" in result.effects and "thermal_lag" in result.parameters:
            lag = result.fit.get("thermal_lag") or {}
            if lag.get("form") == "history":
                what = ("two first-order stages (the housing behind the chamber air by thermal_lag_housing, the "
                        "element behind the housing by thermal_lag)" if lag.get("location") == "air" else
                        "one first-order stage of time constant thermal_lag")
                tm.append(f"T is the sensing element's temperature, which follows the sensor's through {what}; at "
                          "a settled temperature it is the sensor's reading.")
            else:
                tm.append("T is the sensing element's temperature, T = T_sensor − thermal_lag · dT_sensor/dt (the "
                          "lag in minutes, the rate in °C/min); at a settled temperature it is the sensor's reading.")
    if result.temperature_range_C:
        lo, hi = result.temperature_range_C
        tm.append(f"The thermal model applies from {lo:.1f} °C to {hi:.1f} °C (the range of the calibration); "
                  "it is not valid outside that range.")
    return tm


def certificate_number(result: CalibrationResult, prefix: str, issue_date: str) -> str:
    """``PREFIX-YYYYMMDD-XXXXXXXX``: the issue date and the first 8 hex digits of the SHA-256
    of the result's canonical JSON, so that different results never share a number and the
    same result issued the same day gets the same one (a lab with a register passes its own)."""
    blob = json.dumps(result.to_dict(), sort_keys=True, default=str).encode()
    h = hashlib.sha256(blob + issue_date.encode()).hexdigest()[:8].upper()
    return f"{prefix}-{issue_date.replace('-', '')}-{h}"


def build_certificate(result: CalibrationResult, *, lab: Optional[LabConfig] = None, campaign=None,
                      idata=None, diagnosis: Optional[dict] = None, number: Optional[str] = None,
                      issue_date: Optional[str] = None, result_path=None, plots: bool = True,
                      allow_expired_equipment: bool = False) -> Certificate:
    """Assemble a certificate (or a refusal report when :func:`refusal_reasons` finds any).
    Equipment of the lab file whose calibration was due before the calibration date refuses
    the certificate, unless ``allow_expired_equipment``: then the expiry is printed on it."""
    lab = lab or LabConfig()
    source = str(result_path or f"result of {result.unit}")
    # what the result states must hold together before anything is printed: one coverage (95.45 %), a
    # budget with every propagated error's row for each parameter of the budget table, section 7's k and
    # U those of section 4 (consistency.py; outside probes with re-signed files)
    check_certifiable(result, source)
    sha = result.extra.get("data_sha256")
    same_data = campaign is not None and not (sha and campaign.data_sha256 != sha)
    if same_data:
        # the range the certificate states is the fit's: within the data's visit temperatures
        why = range_problem(result, campaign, source)
        if why:
            raise InputError(why)
        # the values it states are those its data give (against_data.py: one Gauss-Newton step, in u)
        why = values_problem(result, campaign, source) or typeb_problem(result, campaign, lab, source)
        if why:
            raise RefusedResult(why)
    # the date of calibration: the data's (when they are the result's), else the result's data_date, else the
    # lab file's; the date of issue on or after it and not after today
    data_date, cal_where = calibration_date(result, campaign if same_data else None, lab, source)
    given = issue_date is not None
    issue_date = issue_date or _dt.date.today().isoformat()
    check_issue_date(issue_date, given, data_date, cal_where)
    post_diag = posterior_diagnostics(idata, list(result.parameters), result) if idata is not None else None
    reasons = refusal_reasons(result, posterior_diag=post_diag, diagnosis=diagnosis)
    expired = lab.expired(data_date or issue_date)
    reasons += _missing_type_b(result, lab) + _lab_disagrees(result, lab) + gravity_reasons(result, lab)
    if campaign is not None and not same_data:
        # the data the certificate shows (plots, averaging times, date) must be those the result was fitted to
        reasons.append(f"the data given ({campaign.source or 'campaign'}) are not those the result was fitted to: their "
                       f"SHA-256 {campaign.data_sha256[:12]}... differs from the result's data_sha256 {sha[:12]}...")
    if expired and not allow_expired_equipment:
        reasons += [f"{e}; recalibrate it, or issue with --allow-expired-equipment, which prints the expiry on "
                    "the certificate" for e in expired]
    issued = not reasons
    if result.method == "posterior":
        source_of_u = "posterior (standard deviation of the draws)"
    elif result.method == "joint" and result.fit.get("estimator"):
        source_of_u = result.fit["estimator"]           # an estimator that says what it is
    elif result.method == "joint":
        source_of_u = "least squares (covariance of the joint fit)"
    else:
        source_of_u = f"{result.method} estimate (eq. 2-3 and its error propagation)"
    cert = Certificate(result=result, issued=issued, reasons=reasons,
                       number=(number or certificate_number(result, lab.certificate_prefix, issue_date)) if issued else None,
                       issue_date=issue_date, lab=lab, source_of_u=source_of_u, notes=list(result.notes))
    if same_data and not_rederivable(result):
        cert.notes.append(f"The values were not re-derived from the data given: the plain model on the data's "
                          f"covariates does not reproduce {not_rederivable(result)}.")
    # identification ---------------------------------------------------------------------
    if data_date:
        cal_date = f"{data_date} ({cal_where})"
    else:
        cal_date = ("not stated: neither the data nor the result carry a date (give --data with a captured "
                    "campaign, or [item] calibration_date in the lab file)")
    ident = [("Item", f"{lab.item_description}, serial number {result.unit}")]
    if lab.customer_name:
        ident.append(("Customer", lab.customer_name + (f", {lab.customer_address}" if lab.customer_address else "")))
    ident += [("Date of calibration", cal_date), ("Date of issue", issue_date)]
    if issued:
        ident.append(("Certificate number", cert.number))
    for section, e in lab.equipment.items():
        text = ", ".join(x for x in (e.get("instrument"), e.get("certificate") and f"certificate {e['certificate']}",
                                     e.get("due") and f"due {e['due']}") if x)
        ident.append((f"Equipment: {section}", text + ("" if not any(section in x for x in expired) else
                                                       " — EXPIRED before the calibration; issued with "
                                                       "--allow-expired-equipment")))
    ident.append(("Software", f"triadcal {__version__}"))
    if result_path is not None:
        digest = hashlib.sha256(Path(result_path).read_bytes()).hexdigest()
        ident.append(("Result file", f"{Path(result_path).name} (SHA-256 {digest[:16]}…)"))
    cert.identification = ident
    # method -----------------------------------------------------------------------------------
    fit = result.fit
    method = []
    if campaign is not None:
        from ...models.campaign import up_axis_label

        pos = dict(zip(campaign.position.tolist(), zip(campaign.axis1_deg.tolist(), campaign.axis2_deg.tolist())))
        ups = {p: up_axis_label([a1], [a2])[0] for p, (a1, a2) in pos.items()}
        method.append(("Plan", f"{len(pos)} bench positions: " + ", ".join(
            f"{p} ({ups[p] or 'oblique'})" for p in sorted(pos))))
        seq, prev = [], None
        order = np.argsort(campaign.time_s, kind="stable")
        for i in order:
            key = (float(campaign.setpoint_C[i]), str(campaign.direction[i]), int(campaign.cycle[i]))
            if key != prev:
                seq.append(f"{key[0]:g}" + {"heating": "↑", "cooling": "↓"}.get(key[1], ""))
                prev = key
        method.append(("Setpoints (°C, in order; ↑ heating, ↓ cooling)", ", ".join(seq)))
        method.append(("Visits", f"{campaign.n_visits}"))
    method.append(("Model terms", "eq. 1 (scale factors, biases, orientation angles)"
                   + "".join(f"; {e}: {display_text(EFFECTS[e].description)}" if e in EFFECTS else f"; {e}"
                             for e in result.effects)))
    est = {"joint": "joint least squares over all positions and temperatures (Levenberg-Marquardt, exact "
                    "Jacobians)", "posterior": "Bayesian posterior (MCMC)",
           "classical": "classical estimate per setpoint (eq. 2-3) with a linear thermal correction"}
    est_txt = est.get(result.method, result.method)
    if fit.get("loss"):
        est_txt += f"; loss {fit['loss']}"
    if fit.get("noise"):
        est_txt += f"; output noise: {fit['noise']}"
    method.append(("Estimator", est_txt))
    priors = result.extra.get("priors")
    if priors:
        ptxt = "; ".join(f"{k}: {v}" for k, v in priors.items()) if isinstance(priors, dict) else str(priors)
    else:
        ptxt = "none (least squares)" if result.method != "posterior" else "as stated in the result file"
    method.append(("Priors", ptxt))
    # a lab file with the bench's random errors only (sigma_1, sigma_2 in the weights) is not "no lab file"
    # (an outside probe's certificate said so of a fit whose u held them)
    type_a = ("Type A, with the bench's random errors (positioning, wobble) the lab file states in the fit's "
              "weights; it states none of the lab's systematic errors"
              if isinstance(result.fit.get("bench_errors"), dict) else
              "Type A only: no lab file with the lab's own errors")
    if result.holds_type_b():
        ks = {n: p.uncertainty.get("k") for n, p in result.parameters.items() if p.U is not None}
        odd = [f"{n} (k = {k:.3g})" for n, k in ks.items() if k is not None and abs(k - 2.0) > 0.005]
        method.append(("Uncertainty", (
            f"u_c of each parameter combines the {source_of_u} (Type A, with the bench's random errors when "
            "the lab states them) and the lab's systematic errors (Type B) through their sensitivities from the "
            "model (JCGM 100); U at a coverage probability of 95.45 %: U = k·u_c with k from the effective "
            "degrees of freedom (Welch–Satterthwaite), or the JCGM 101 Monte Carlo interval where a term is not "
            "normal; k = 2 for every parameter" + (f" except {', '.join(odd)}" if odd else "")
            + "; section 7 gives the budgets; U rounded to two significant digits, the value to match")))
    elif isinstance(result.fit.get("noise_dof"), (int, float)) and any(p.U is not None for p in result.parameters.values()):
        # the noise estimated from the residuals, no lab file: U = k u with k from Student's t on its dof
        ks = sorted({round(float(p.uncertainty["k"]), 3) for p in result.parameters.values()
                     if p.U is not None and p.uncertainty.get("k") is not None})
        method.append(("Uncertainty", f"U = k·u, u from the {source_of_u} ({type_a}), the output noise estimated from the residuals on {result.fit['noise_dof']:.3g} "
                       "degrees of freedom, so k from Student's t on them at a coverage probability of 95.45 % (k = "
                       + ", ".join(f"{k:g}" for k in ks) + "); U rounded to two significant digits, the value to match"))
    else:
        method.append(("Uncertainty", f"U = k·u with k = 2 (coverage probability about 95 %), u from the "
                       f"{source_of_u} ({type_a}); U rounded to two "
                       "significant digits, the value to match"))
    cert.method = method
    # conditions ------------------------------------------------------------------------
    cond = []
    if result.temperature_range_C:
        lo, hi = result.temperature_range_C
        cond.append(("Temperature range (accelerometer sensors)", f"{lo:.1f} °C to {hi:.1f} °C"))
    t_u = result.fit.get("reference_temperature_u_C")
    rows_T = row_temperatures_C(result)
    apart = bool(rows_apart(rows_T))
    cond.append(("Reference temperature", f"{result.reference_temperature_C:g} °C" + (
        f" (as the thermometers read it, u = {t_u:g} °C; one temperature: the values are the unit's at "
        + ("its sensors' temperatures, next row," if apart else "that temperature") + " and hold no tempco)"
        if isinstance(t_u, (int, float)) else (" (the sensors' mean; the values are at each sensor's own "
                                               "temperature, next row)" if apart else ""))))
    if apart:
        # one temperature, sensors apart: row a (K_a, S_a, Ca_ab) is at t_a, not at the sensors' mean
        def row(a):
            return ", ".join(n for n in result.parameters if n in (f"K_{a}", f"S_{a}") or n.startswith(f"Ca_{a}"))
        cond.append(("Temperature of each accelerometer's values", "; ".join(
            f"{a.upper()} ({row(a)}) {v:.2f} °C" for a, v in rows_T.items())
            + " — each accelerometer's own temperature sensor, which its row of the model is tied to; no "
            "temperature coefficient was determined to carry them to one temperature"))
    if campaign is not None:
        taus = sorted(set(np.round(campaign.tau_s, 6).tolist()))
        cond.append(("Averaging time per position", ", ".join(f"{t:g} s" for t in taus)))
    g = result.extra.get("local_g_m_s2") or (campaign.local_g_m_s2 if campaign is not None else None)
    if lab.local_g_m_s2 is not None:
        u_g = f", u = {lab.local_g_u_ppm:g} ppm" if lab.local_g_u_ppm is not None else ""
        cond.append(("Local gravity", f"{lab.local_g_m_s2:.5f} m/s² (measured, lab file{u_g})"
                     + ("" if g is None or abs(float(g) - lab.local_g_m_s2) < 5e-7 else
                        f"; the fit used {float(g):.5f} m/s² from the data")))
    elif g:
        standard = abs(float(g) - STANDARD_GRAVITY_M_S2) < 5e-7
        cond.append(("Local gravity", f"{float(g):.5f} m/s²" + (
            " (standard gravity, not measured: the data state no local value)" if standard else
            " (local value stated in the data)")))
    bench = lab.bench or (campaign.metadata.get("bench", "") if campaign is not None else "")
    if bench:
        cond.append(("Bench", bench))
    if lab.chamber:
        cond.append(("Thermal chamber", lab.chamber))
    if result.extra.get("output_unit"):
        cond.append(("Output unit of the accelerometers", str(result.extra["output_unit"])))
    cert.conditions = cond
    cert.diagnostics = _diagnostic_lines(result, post_diag, diagnosis)
    if not issued:
        return cert
    # results -----------------------------------------------------------------------------
    cert.rows = parameter_rows(result)
    tm = thermal_model_lines(result)
    cert.thermal_model = tm
    try:
        cert.inverse_matrix = np.linalg.inv(result.matrix())
    except (KeyError, ValueError, np.linalg.LinAlgError):
        cert.inverse_matrix = None
    per_setpoint = None
    if campaign is not None:
        from ..plots import per_setpoint_angles

        try:
            per_setpoint = per_setpoint_angles(campaign)
        except (ImportError, LookupError, ValueError):
            per_setpoint = None
    plan = None
    if campaign is not None:
        plan = dict(zip(campaign.position.tolist(), zip(campaign.axis1_deg.tolist(), campaign.axis2_deg.tolist())))
    cert.budget = uncertainty_budget(result, lab, per_setpoint, source_of_u, plan)
    from ...uncertainty.typeb import budget_of

    for row in cert.rows:
        if row.group in BUDGET_GROUPS:
            b = budget_of(row.name, result.parameters[row.name])
            if b is not None:
                cert.parameter_budgets.setdefault(row.group, []).append(b)
    cert.angle_statement = angle_uncertainty_statement(cert)
    if plots:
        from ..plots import report_plots

        ps = report_plots(result, campaign, idata)
        cert.plots, cert.skipped_plots = ps.plots, ps.skipped
    return cert


def _missing_type_b(result: CalibrationResult, lab: LabConfig) -> list:
    """A result whose u is Type A only while the lab file declares systematic errors: its U would
    leave them out of every parameter (a classical result too: with --lab the classical fit
    propagates them, estimation/classical_typeb.py)."""
    if lab.source is None:
        return []
    from ...uncertainty.typeb import systematic_sources

    try:
        declared = systematic_sources(lab, str(result.extra.get("output_unit") or "V"))
    except InputError as exc:             # a voltmeter on counts: the fit refuses it, so does the certificate
        return [str(exc)]
    if not declared or result.holds_type_b():
        return []
    names = sorted({s.key for s in declared})
    if result.method == "classical":
        # a classical result fitted without --lab: Type A only; the results table would state U without
        # the lab's errors (an outside probe: Ca_zx 22.0 arcsec off with U 5.8, coverage 0.20-0.26 over 150
        # campaigns). With --lab the classical fit propagates them (estimation/classical_typeb.py)
        return [f"the lab file declares systematic errors ({', '.join(names)}), but the classical result's "
                "uncertainties are Type A only (it was fitted without them): fit again with --method classical "
                "--lab, which propagates them into every parameter's U"]
    return [f"the lab file declares systematic errors ({', '.join(names)}), but the result's uncertainties are "
            "Type A only (it was fitted without them): fit again with --lab so that every parameter's U includes "
            "them"]


def _lab_disagrees(result: CalibrationResult, lab: LabConfig) -> list:
    """The lab file given to the certificate is not the one the result was fitted with: a systematic
    error it declares that no parameter's budget holds, or holds with another u (a joint or posterior
    result whose U includes Type B), or a local g that differs from the fit's beyond the lab's own u
    (1 ppm when it states none; K is proportional to g). Before, a result fitted with a lab file
    without [gravity] and [voltmeter] got a certificate under one declaring both, U(K_x) 15 times
    too small, and one fitted with g = 9.80665 under a lab stating 9.81 (an outside probe)."""
    out = []
    if lab.source is None:
        return out
    rows = [row for p in result.parameters.values() for row in (p.uncertainty.get("budget") or [])
            if isinstance(row, dict)]
    if result.holds_type_b():
        from ...uncertainty.typeb import propagated_sources, systematic_sources

        try:
            declared = systematic_sources(lab, str(result.extra.get("output_unit") or "V"))
        except InputError:
            declared = []
        missing, changed = [], []
        expected = propagated_sources(declared, result.parameters)   # as the fit propagated them
        for src in expected:
            held = [row for row in rows if row.get("source") == src.source]
            if not held:
                missing.append(f"{src.source} ({src.key} = {src.u:g} {src.unit})")
            elif any(not math.isclose(float(row.get("u", math.nan)), src.u, rel_tol=1e-9) for row in held):
                changed.append(f"{src.source}: {src.key} = {src.u:g} {src.unit} in the lab file, "
                               f"{float(held[0].get('u', math.nan)):g} in the result")
            elif any(str(row.get("distribution", "normal")) != src.distribution for row in held):
                changed.append(f"{src.source}: distribution {src.distribution} in the lab file, "
                               f"{held[0].get('distribution', 'normal')} in the result")
        # the reverse: Type B rows of a source this lab file does not declare (fitted under another lab
        # file: its certificate named equipment this lab does not have; an outside probe)
        names = {s.source for s in expected}
        extra = sorted({str(row.get("source")) for row in rows if row.get("type") == "B"} - names)
        if extra:
            out.append(f"the result's budgets hold systematic errors this lab file does not declare ({', '.join(extra)}): "
                       "it was fitted with another lab file; fit again with this --lab")
        if missing:
            out.append(f"the lab file declares systematic errors the result's budgets do not hold ({'; '.join(missing)}): "
                       "it was fitted with another lab file; fit again with this --lab")
        if changed:
            out.append(f"the lab file states other uncertainties than the result was fitted with ({'; '.join(changed)}): "
                       "fit again with this --lab")
    be = result.fit.get("bench_errors") if isinstance(result.fit.get("bench_errors"), dict) else None
    if be and be.get("in_u") and str(be.get("source", "")).startswith("lab"):
        # sigma_1 and sigma_2 inside the result's u: those of the lab file it was fitted with
        for key, stated in (("sigma_position_arcsec", lab.sigma_position_arcsec),
                            ("sigma_wobble_arcsec", lab.sigma_wobble_arcsec)):
            used = be.get(key)
            if isinstance(used, (int, float)) and not math.isclose(float(used), float(stated or 0.0), rel_tol=1e-9,
                                                                    abs_tol=1e-12):
                out.append(f"the lab file's [bench] {key} = {float(stated or 0.0):g} arcsec, but the result's u holds "
                           f"{float(used):g}: it was fitted with another lab file; fit again with this --lab")
    g = result.extra.get("local_g_m_s2")
    if lab.local_g_m_s2 is not None and isinstance(g, (int, float)) and math.isfinite(g):
        # the fit's own rule (io.lab.with_lab_gravity): two values within 3 u of the lab's are one
        # measurement (1 ppm without a u); the certificate used 1 u and refused what the fit accepted
        tol_ppm = 3.0 * lab.local_g_u_ppm if lab.local_g_u_ppm else 1.0
        diff_ppm = abs(float(g) - lab.local_g_m_s2) / lab.local_g_m_s2 * 1e6
        if diff_ppm > tol_ppm:
            out.append(f"the lab file's local gravity {lab.local_g_m_s2:.5f} m/s² differs from the {float(g):.5f} m/s² "
                       f"the fit used by {diff_ppm:.3g} ppm (more than {tol_ppm:g} ppm: 3 u of the lab's g, or 1 ppm "
                       "without a u); K is proportional to g: fit again with the lab's g (--lab, or local_g_m_s2 in "
                       "the data)")
    return out


def _diagnostic_lines(result, post_diag, diagnosis) -> list:
    fit = result.fit
    out = [("Status", result.status), ("Method", result.method)]
    if fit.get("chi2_dof") is not None:
        out.append(("χ²/dof", f"{fit['chi2_dof']:.3f} ({fit.get('n_obs', '?')} observations, "
                              f"{fit.get('n_params', '?')} parameters)"))
    if fit.get("gap_p_value") is not None:
        out.append(("Model–data gap", f"p = {fit['gap_p_value']:.2g} (significant below {GAP_P_THRESHOLD:g})"))
    if post_diag:
        out.append(("Posterior", f"{post_diag['n_chains']} chains × {post_diag['n_draws']} draws; worst R-hat "
                                 f"{post_diag['rhat_max']:.4f} ({post_diag['rhat_worst']}), lowest bulk ESS "
                                 f"{post_diag['ess_bulk_min']:.0f} ({post_diag['ess_worst']}); "
                                 f"{'converged' if post_diag['converged'] else 'not converged'} "
                                 f"({post_diag['source']})"))
    if diagnosis:
        gap = diagnosis.get("gap") or {}
        out.append(("Diagnosis", f"gap chi2/dof {gap.get('chi2_dof')}, significant: {gap.get('significant')}, "
                                 f"verdict: {(diagnosis.get('verdict') or {}).get('effect')}"))
    return out
