"""Calibration certificate of an accelerometer triad (ISO/IEC 17025 §7.8), as HTML and PDF.

:func:`build_certificate` gathers what a certificate states from a
:class:`~triadcal.estimation.result.CalibrationResult` (and, when given, the lab's
configuration, the campaign data, the posterior and a diagnosis): identification, method,
conditions, every parameter with its expanded uncertainty ``U = 2 u`` (k = 2, coverage
about 95 %; U rounded to two significant digits and the value to match, GUM 7.2.6),
the thermal model with its reference temperature and range, the inverse matrix
``Ca^-1`` a user applies to readings (``A_IMU = Ca^-1 (K W - S)``), an uncertainty
budget of the orientation angles (seed paper, eq. 4-7) and plots.
When a diagnostic failed (not converged, unidentifiable terms, a significant model-data
gap, a posterior that did not mix) no certificate is issued: the same renderers produce
a *refusal report* that says why (:func:`refusal_reasons`).

:func:`render_html` writes a self-contained page (CSS inline, images as base64 data
URIs, nothing fetched from a network); :func:`render_pdf` writes the PDF with reportlab.
:func:`certificate` is the library function behind ``triadcal certificate``.
"""

from __future__ import annotations

import base64
import datetime as _dt
import hashlib
import html as _html
import io
import json
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from .. import __version__
from ..estimation.gates import check_result_for_use, result_problems
from ..estimation.result import CalibrationResult, read_json, round_to_uncertainty
from ..io.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from ..io.formats import require_format
from ..models.effects import EFFECTS
from ..models.model import Model
from ..models.sensor import ANGLE_NAMES, AXES

#: coverage factor of the expanded uncertainty on the certificate
COVERAGE_FACTOR = 2.0
#: a model-data gap is significant below this p-value of chi^2 with known noise (as in the joint fit)
GAP_P_THRESHOLD = 1e-3
#: posterior diagnostics below which no certificate is issued (Vehtari et al. 2021)
RHAT_MAX = 1.01
ESS_MIN = 400.0

ANGLES = tuple(f"Ca_{ab}" for ab in ANGLE_NAMES)
DISPLAY_UNIT = {"degC": "°C", "ug": "µg", "arcsec/degC": "arcsec/°C", "ppm/degC": "ppm/°C",
                "ug/degC": "µg/°C", "ug/g2": "µg/g²", "ug/h": "µg/h"}


# =========================================================================================
# the lab's configuration
# =========================================================================================
@dataclass
class LabConfig:
    """The laboratory's fields for the certificate, read from a TOML file (:func:`load_lab`).

    Numbers the budget uses: ``sigma_position_arcsec`` and ``sigma_wobble_arcsec`` (the
    bench's positioning error and wobble, sigma_1 and sigma_2 of eq. 4) and
    ``temperature_uncertainty_C`` (Delta T of eq. 7).
    """

    name: str = "(laboratory not stated)"
    address: str = ""
    accreditation: str = ""
    certificate_prefix: str = "TC"
    place: str = ""
    signatory_name: str = ""
    signatory_title: str = ""
    customer_name: str = ""
    customer_address: str = ""
    item_description: str = "accelerometer triad"
    calibration_date: str = ""
    bench: str = ""
    sigma_position_arcsec: Optional[float] = None
    sigma_wobble_arcsec: Optional[float] = None
    chamber: str = ""
    temperature_uncertainty_C: Optional[float] = None
    traceability: str = ""
    source: Optional[str] = None


#: TOML section -> key -> (field, type)
LAB_SCHEMA = {
    "lab": {"name": ("name", str), "address": ("address", str), "accreditation": ("accreditation", str),
            "certificate_prefix": ("certificate_prefix", str), "place": ("place", str)},
    "signatory": {"name": ("signatory_name", str), "title": ("signatory_title", str)},
    "customer": {"name": ("customer_name", str), "address": ("customer_address", str)},
    "item": {"description": ("item_description", str), "calibration_date": ("calibration_date", str)},
    "bench": {"name": ("bench", str), "sigma_position_arcsec": ("sigma_position_arcsec", float),
              "sigma_wobble_arcsec": ("sigma_wobble_arcsec", float)},
    "chamber": {"name": ("chamber", str), "temperature_uncertainty_C": ("temperature_uncertainty_C", float)},
    "traceability": {"statement": ("traceability", str)},
}

EXAMPLE_LAB_TOML = """\
[lab]
name = "Inertial Sensors Calibration Laboratory"
address = "1 Metrology Road, Springfield"
accreditation = "Accredited to ISO/IEC 17025:2017, certificate No. 0000.01"
certificate_prefix = "ISCL"
place = "Springfield"

[signatory]
name = "A. N. Engineer"
title = "Head of the inertial laboratory"

[customer]
name = "Example Avionics Ltd"
address = "2 Customer Street, Springfield"

[item]
description = "accelerometer triad (IMU accelerometer block)"
calibration_date = "2026-11-20"

[bench]
name = "two-axis rate-and-position table, thermal chamber"
sigma_position_arcsec = 5.0     # sigma_1 of eq. 4
sigma_wobble_arcsec = 2.0       # sigma_2 of eq. 4

[chamber]
name = "thermal chamber -60..+100 degC"
temperature_uncertainty_C = 0.2 # Delta T of eq. 7

[traceability]
statement = "Angles traceable to the national standard of plane angle through the bench's calibration certificate; local gravity from the national gravimetric survey."
"""


def load_lab(path) -> LabConfig:
    """Read a lab configuration TOML (sections ``[lab] [signatory] [customer] [item] [bench]
    [chamber] [traceability]``, see ``EXAMPLE_LAB_TOML``). Unknown sections or keys and
    values of the wrong type are refused with the file, section and key named."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None
    lab = LabConfig(source=str(path))
    for section, table in data.items():
        if section not in LAB_SCHEMA:
            raise ValueError(f"{path}: unknown section [{section}]; known: {', '.join(LAB_SCHEMA)}")
        if not isinstance(table, dict):
            raise ValueError(f"{path}: {section} must be a [section] table")
        for key, value in table.items():
            if key not in LAB_SCHEMA[section]:
                raise ValueError(f"{path}: unknown key {key!r} in [{section}]; known: "
                                 f"{', '.join(LAB_SCHEMA[section])}")
            name, typ = LAB_SCHEMA[section][key]
            if typ is float:
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                        or value < 0:
                    raise ValueError(f"{path}: [{section}] {key} must be a non-negative number, got {value!r}")
                value = float(value)
            elif not isinstance(value, str):
                value = str(value)  # TOML dates etc. are written as they read
            setattr(lab, name, value)
    return lab


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


# =========================================================================================
# uncertainty budget (eq. 4-7)
# =========================================================================================
@dataclass
class BudgetComponent:
    """One row of a GUM budget of the orientation angles: the standard uncertainty ``u`` of an
    input (in ``unit``), its sensitivity coefficient ``c`` and its ``contribution`` ``|c| u``
    in the budget's unit (None when it could not be evaluated), with how it was obtained."""

    source: str
    contribution: Optional[float]
    u: Optional[float] = None
    unit: str = "arcsec"
    sensitivity: Optional[float] = 1.0
    sensitivity_unit: str = "1"
    basis: str = ""
    equation: str = ""


@dataclass
class Budget:
    quantity: str
    components: list
    unit: str = "arcsec"

    @property
    def evaluated(self) -> list:
        return [c for c in self.components if c.contribution is not None]

    @property
    def combined_u(self) -> float:
        """Root sum of squares of the contributions (independent components)."""
        return math.sqrt(sum(c.contribution ** 2 for c in self.evaluated))

    @property
    def expanded_U(self) -> float:
        return COVERAGE_FACTOR * self.combined_u

    def share(self, c: BudgetComponent) -> Optional[float]:
        """Fraction of the combined variance from ``c``."""
        total = sum(x.contribution ** 2 for x in self.evaluated)
        return None if c.contribution is None or total == 0 else c.contribution ** 2 / total


BUDGET_SOURCES = ("output noise", "bench positioning", "wobble", "tilt", "temperature measurement",
                  "thermal-model residual", "hysteresis")


def _sorted_budget(components) -> list:
    return sorted(components, key=lambda c: (c.contribution is None, -abs(c.contribution or 0.0)))


def _given_budget(given) -> Optional[list]:
    """Components written by an estimator into ``result.extra["budget"]``: a list of rows, or a
    :meth:`triadcal.estimation.budget.Budget.to_dict` (``components`` with ``standard_uncertainty``,
    ``sensitivity``, ``contribution``)."""
    rows = given.get("components") if isinstance(given, dict) else given
    if not isinstance(rows, list) or not rows:
        return None
    out = []
    for c in rows:
        contribution = c.get("contribution", c.get("u"))
        out.append(BudgetComponent(
            str(c["source"]), None if contribution is None else float(contribution),
            u=c.get("standard_uncertainty", c.get("u")), unit=str(c.get("unit", "arcsec")),
            sensitivity=c.get("sensitivity", 1.0), sensitivity_unit=str(c.get("sensitivity_unit", "1")),
            basis=str(c.get("basis", c.get("symbol", ""))), equation=str(c.get("equation", ""))))
    return out


def _bench_sd(plan, sigma_position: float, sigma_wobble: float) -> float:
    """Largest standard deviation (arcsec) of a single-setpoint classical angle from the bench
    errors alone (:func:`triadcal.estimation.classical.classical_angle_sd`, eq. 2-4)."""
    from ..estimation.classical import classical_angle_sd

    sd = classical_angle_sd(plan, Q_V2s=0.0, tau_s=1.0, sigma_position_arcsec=sigma_position,
                            sigma_wobble_arcsec=sigma_wobble)
    return max(sd.values())


def uncertainty_budget(result: CalibrationResult, lab: Optional[LabConfig] = None,
                       per_setpoint: Optional[list] = None, source_of_u: str = "", plan=None) -> Budget:
    """Budget of an orientation angle of the matrix as applied over the temperature range.

    Components are taken from ``result.extra["budget"]`` when the estimator wrote one;
    otherwise they are assembled from the result, the lab's bench figures and the
    per-setpoint estimates with :mod:`triadcal.estimation.budget` and
    :mod:`triadcal.estimation.classical` (seed paper, eq. 4-7):

    - output noise: the estimator's standard uncertainty of the angles (largest of six), under
      the name and basis the estimator gives in ``fit.angle_uncertainty`` when it gives one
      (``fit-raw``, known poses: "hand placement");
    - bench positioning and wobble: sigma_1, sigma_2 of eq. 4 through the classical estimate
      of one setpoint on ``plan`` (sensitivity 1/2 on the default plan); an upper bound for
      a joint fit, which averages them over the setpoints;
    - tilt: estimated with the calibration (its uncertainty is in the angles' u) or
      cancelled by the half-turn pairs of eq. 2-3;
    - temperature measurement: ``Delta T * k_ca`` of eq. 7 with the largest fitted tempco;
    - thermal-model residual: scatter of the per-setpoint estimates about the fitted
      thermal model beyond their own uncertainty (what a linear correction leaves, eq. 5);
    - hysteresis: the half-width ``h`` of the loop (largest of six; dCa_Ta of eq. 5): the
      matrix is stated on the mid-line, a reading on either branch is off by ``+-h``.
    """
    quantity = "orientation angle Ca_ab applied over the temperature range"
    given = _given_budget(result.extra.get("budget"))
    if given:
        return Budget(quantity, _sorted_budget(given), "arcsec")
    from ..estimation.budget import correction_error_arcsec

    P = result.parameters
    angles = [n for n in ANGLES if n in P]
    comps = []
    declared = result.fit.get("angle_uncertainty")
    if angles and declared:
        # the estimator says what sets its angles' u (fit-raw, known poses: the hand placement)
        worst = max(angles, key=lambda n: P[n].u)
        comps.append(BudgetComponent(declared["source"], P[worst].u, P[worst].u,
                                     basis=f"{declared['basis']} (largest: {worst})",
                                     equation=declared.get("equation", "")))
    elif angles:
        worst = max(angles, key=lambda n: P[n].u)
        comps.append(BudgetComponent("output noise", P[worst].u, P[worst].u, basis=(
            f"standard uncertainty of the angles from the {source_of_u or result.method} (largest: {worst}); "
            "Type A"), equation="eq. 4, 1st term"))
    else:
        comps.append(BudgetComponent("output noise", None, basis="the result has no orientation angles",
                                     equation="eq. 4"))
    s1 = lab.sigma_position_arcsec if lab is not None else None
    s2 = lab.sigma_wobble_arcsec if lab is not None else None
    upper = " (one setpoint; an upper bound for the joint fit)" if result.method != "classical" else ""
    for src, s, sym, key, args in (("bench positioning", s1, "σ1", "[bench] sigma_position_arcsec", (1.0, 0.0)),
                                   ("wobble", s2, "σ2", "[bench] sigma_wobble_arcsec", (0.0, 1.0))):
        if s is None:
            comps.append(BudgetComponent(src, None, basis=f"{sym} not stated (give {key} in the lab file)",
                                         equation="eq. 4"))
        else:
            c = _bench_sd(plan, *args)
            comps.append(BudgetComponent(src, c * s, s, sensitivity=c, basis=(
                f"{sym} = {s:g} arcsec (lab file) through the classical estimate of the plan{upper}"),
                equation="eq. 2-4"))
    if "bench_tilt" in result.effects:
        td = P.get("tilt_delta")
        txt = (f"estimated with the calibration (δ = {td.value:.1f} arcsec, u = {td.u:.2g} arcsec); "
               "its uncertainty is inside the angles' u") if td else "estimated with the calibration"
        comps.append(BudgetComponent("tilt", 0.0, td.u if td else None, sensitivity=0.0, basis=txt,
                                     equation="eq. 1"))
    elif result.method == "classical":
        comps.append(BudgetComponent("tilt", 0.0, sensitivity=0.0, basis="cancels in the half-turn pairs of the plan",
                                     equation="eq. 2-3"))
    else:
        comps.append(BudgetComponent("tilt", None, basis="bench tilt not modelled", equation=""))
    tempcos = [P[f"{n}_tempco"].value for n in angles if f"{n}_tempco" in P]
    if not tempcos:
        comps.append(BudgetComponent("temperature measurement", 0.0, basis="no thermal terms in the model",
                                     equation="eq. 7"))
    elif lab is None or lab.temperature_uncertainty_C is None:
        comps.append(BudgetComponent("temperature measurement", None, basis=(
            "ΔT not stated (give [chamber] temperature_uncertainty_C in the lab file)"), equation="eq. 7"))
    else:
        k = max(abs(t) for t in tempcos)
        dT = lab.temperature_uncertainty_C
        comps.append(BudgetComponent("temperature measurement", correction_error_arcsec(dT, k), dT, "°C",
                                     sensitivity=k, sensitivity_unit="arcsec/°C", basis=(
                                         "ΔT (lab file) times k_ca, the largest fitted tempco"), equation="eq. 7"))
    comps.append(_thermal_residual_component(result, per_setpoint))
    hyst = [abs(P[f"{n}_hysteresis"].value) for n in angles if f"{n}_hysteresis" in P]
    if hyst:
        comps.append(BudgetComponent("hysteresis", max(hyst), max(hyst), basis=(
            "largest half-width h of the loop; the matrix is stated on the mid-line, a reading on a branch "
            "is off by ±h (two-point distribution, sd h)"), equation="eq. 5, ΔCa_Ta"))
    else:
        comps.append(BudgetComponent("hysteresis", None, basis="not modelled (in the thermal-model residual)",
                                     equation="eq. 5, ΔCa_Ta"))
    return Budget(quantity, _sorted_budget(comps))


def _thermal_residual_component(result, per_setpoint) -> BudgetComponent:
    given = result.extra.get("thermal_residual_arcsec")
    if isinstance(given, (int, float)):
        return BudgetComponent("thermal-model residual", float(given), float(given), basis="from the result file",
                               equation="eq. 5")
    if not per_setpoint:
        return BudgetComponent("thermal-model residual", None, basis=(
            "needs per-setpoint estimates (--data DATA.csv and the classical estimator)"), equation="eq. 5")
    from .plots import BRANCH_VALUE, model_angles

    dev, var = [], []
    for r in per_setpoint:
        m = model_angles(result, np.array([r["temperature_C"]]), BRANCH_VALUE.get(r["direction"], 0.0))
        for ab in ANGLE_NAMES:
            if f"Ca_{ab}" in r:
                dev.append(r[f"Ca_{ab}"] - float(m[ab][0]))
                var.append(r.get(f"u_Ca_{ab}", 0.0) ** 2)
    if not dev:
        return BudgetComponent("thermal-model residual", None, basis="no per-setpoint angles", equation="eq. 5")
    rms2 = float(np.mean(np.square(dev)))
    u = math.sqrt(max(0.0, rms2 - float(np.mean(var))))
    return BudgetComponent("thermal-model residual", u, u, basis=(
        f"scatter of the {len(per_setpoint)} per-setpoint classical estimates about the model (rms "
        f"{math.sqrt(rms2):.2g} arcsec) less their own uncertainty (rms {math.sqrt(float(np.mean(var))):.2g})"),
        equation="eq. 5")


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


GROUPS = ("Scale factors", "Biases", "Orientation angles", "Thermal coefficients", "Hysteresis",
          "Other terms", "Bench (not a property of the unit)")


def _group(name: str) -> str:
    if name.startswith("tilt_"):
        return GROUPS[6]
    if name.endswith("_tempco"):
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


def display_unit(unit: str) -> str:
    return DISPLAY_UNIT.get(unit, unit)


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
        v, U = expanded(p.value, p.u)
        desc = spec[name].description if name in spec else extra_desc.get(name, "")
        rows.append(ParameterRow(name, desc, _group(name), v, U, p.unit))
    order = {g: i for i, g in enumerate(GROUPS)}
    return sorted(rows, key=lambda r: order[r.group])  # stable: keeps the file's order in a group


def certificate_number(result: CalibrationResult, prefix: str, issue_date: str) -> str:
    """``PREFIX-YYYYMMDD-XXXXXXXX``: the issue date and the first 8 hex digits of the SHA-256
    of the result's canonical JSON, so that different results never share a number and the
    same result issued the same day gets the same one (a lab with a register passes its own)."""
    blob = json.dumps(result.to_dict(), sort_keys=True, default=str).encode()
    h = hashlib.sha256(blob + issue_date.encode()).hexdigest()[:8].upper()
    return f"{prefix}-{issue_date.replace('-', '')}-{h}"


def build_certificate(result: CalibrationResult, *, lab: Optional[LabConfig] = None, campaign=None,
                      idata=None, diagnosis: Optional[dict] = None, number: Optional[str] = None,
                      issue_date: Optional[str] = None, result_path=None, plots: bool = True) -> Certificate:
    """Assemble a certificate (or a refusal report when :func:`refusal_reasons` finds any)."""
    lab = lab or LabConfig()
    issue_date = issue_date or _dt.date.today().isoformat()
    post_diag = posterior_diagnostics(idata, list(result.parameters)) if idata is not None else None
    reasons = refusal_reasons(result, posterior_diag=post_diag, diagnosis=diagnosis)
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
    # identification ---------------------------------------------------------------------
    cal_date = lab.calibration_date or (campaign.metadata.get("date", "") if campaign is not None else "")
    ident = [("Item", f"{lab.item_description}, serial number {result.unit}")]
    if lab.customer_name:
        ident.append(("Customer", lab.customer_name + (f", {lab.customer_address}" if lab.customer_address else "")))
    ident += [("Date of calibration", cal_date or "not stated"), ("Date of issue", issue_date)]
    if issued:
        ident.append(("Certificate number", cert.number))
    ident.append(("Software", f"triadcal {__version__}"))
    if result_path is not None:
        digest = hashlib.sha256(Path(result_path).read_bytes()).hexdigest()
        ident.append(("Result file", f"{Path(result_path).name} (SHA-256 {digest[:16]}…)"))
    cert.identification = ident
    # method -----------------------------------------------------------------------------------
    fit = result.fit
    method = []
    if campaign is not None:
        from ..models.campaign import up_axis_label

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
                   + "".join(f"; {e}: {EFFECTS[e].description}" if e in EFFECTS else f"; {e}"
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
    method.append(("Uncertainty", f"U = k·u with k = 2 (coverage probability about 95 %), u from the "
                   f"{source_of_u}; U rounded to two significant digits, the value to match"))
    cert.method = method
    # conditions ------------------------------------------------------------------------
    cond = []
    if result.temperature_range_C:
        lo, hi = result.temperature_range_C
        cond.append(("Temperature range (accelerometer sensors)", f"{lo:.1f} °C to {hi:.1f} °C"))
    cond.append(("Reference temperature", f"{result.reference_temperature_C:g} °C"))
    if campaign is not None:
        taus = sorted(set(np.round(campaign.tau_s, 6).tolist()))
        cond.append(("Averaging time per position", ", ".join(f"{t:g} s" for t in taus)))
    g = result.extra.get("local_g_m_s2") or (campaign.local_g_m_s2 if campaign is not None else None)
    if g:
        cond.append(("Local gravity", f"{float(g):.5f} m/s²"))
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
    T0 = result.reference_temperature_C
    tm = []
    if any(n.endswith("_tempco") for n in result.parameters) or "hysteresis" in result.effects:
        tm.append(f"Each term x of the table is given at the reference temperature T0 = {T0:g} °C; at a "
                  f"temperature T of the accelerometer's own sensor: x(T) = x + x_tempco · (T − T0)"
                  + (", and for the orientation angles ± Ca_ab_hysteresis on the cooling (+) and the "
                     "heating (−) branch; the matrix below is the mid-line" if "hysteresis" in result.effects else "")
                  + ".")
    if result.temperature_range_C:
        lo, hi = result.temperature_range_C
        tm.append(f"The thermal model applies from {lo:.1f} °C to {hi:.1f} °C (the range of the calibration); "
                  "it is not valid outside that range.")
    cert.thermal_model = tm
    try:
        cert.inverse_matrix = np.linalg.inv(result.matrix())
    except (KeyError, ValueError, np.linalg.LinAlgError):
        cert.inverse_matrix = None
    per_setpoint = None
    if campaign is not None:
        from .plots import per_setpoint_angles

        try:
            per_setpoint = per_setpoint_angles(campaign)
        except (ImportError, LookupError, ValueError):
            per_setpoint = None
    plan = None
    if campaign is not None:
        plan = dict(zip(campaign.position.tolist(), zip(campaign.axis1_deg.tolist(), campaign.axis2_deg.tolist())))
    cert.budget = uncertainty_budget(result, lab, per_setpoint, source_of_u, plan)
    if plots:
        from .plots import report_plots

        ps = report_plots(result, campaign, idata)
        cert.plots, cert.skipped_plots = ps.plots, ps.skipped
    return cert


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
                                 f"{post_diag['ess_bulk_min']:.0f} ({post_diag['ess_worst']})"))
    if diagnosis:
        gap = diagnosis.get("gap") or {}
        out.append(("Diagnosis", f"gap chi2/dof {gap.get('chi2_dof')}, significant: {gap.get('significant')}, "
                                 f"verdict: {(diagnosis.get('verdict') or {}).get('effect')}"))
    return out


# =========================================================================================
# HTML
# =========================================================================================
CSS = """
@page { size: A4; margin: 16mm 14mm; }
* { box-sizing: border-box; }
body { font-family: "DejaVu Sans", "Helvetica Neue", Arial, sans-serif; color: #111; background: #e8e8e8;
       margin: 0; font-size: 10.5pt; line-height: 1.4; }
main { max-width: 210mm; margin: 12px auto; background: #fff; padding: 14mm 14mm 10mm;
       box-shadow: 0 0 6px rgba(0,0,0,.25); }
header { display: flex; justify-content: space-between; align-items: flex-start;
         border-bottom: 2.5px solid #1f3a5f; padding-bottom: 8px; margin-bottom: 10px; }
header .lab { font-size: 13pt; font-weight: bold; color: #1f3a5f; }
header .small { font-size: 8.5pt; color: #444; }
header .no { text-align: right; }
header .no .num { font-family: "DejaVu Sans Mono", monospace; font-size: 11pt; font-weight: bold; }
h1 { font-size: 17pt; margin: 4px 0 2px; color: #1f3a5f; letter-spacing: .5px; }
h1.refused { color: #922b21; }
h2 { font-size: 11.5pt; color: #1f3a5f; border-bottom: 1px solid #b8c4d6; margin: 16px 0 6px; padding-bottom: 2px; }
h3 { font-size: 10pt; margin: 10px 0 4px; color: #333; }
table { border-collapse: collapse; width: 100%; margin: 4px 0 8px; }
th, td { border: 1px solid #c8ccd2; padding: 3px 6px; vertical-align: top; }
th { background: #eef1f6; text-align: left; font-size: 9pt; }
table.kv td:first-child { width: 34%; color: #333; background: #f7f8fa; }
td.num, th.num { text-align: right; font-family: "DejaVu Sans Mono", monospace; white-space: nowrap;
                 font-variant-numeric: tabular-nums; }
td.unit { white-space: nowrap; }
th.num { font-family: inherit; }
td.name { font-family: "DejaVu Sans Mono", monospace; white-space: nowrap; }
td.desc { font-size: 8.5pt; color: #333; }
tr.group td { background: #dfe6f0; font-weight: bold; font-size: 9pt; }
tr.total td { font-weight: bold; background: #f3f3f3; }
table.budget { table-layout: fixed; }
table.budget td, table.budget th { font-size: 8.8pt; }
table.budget td.num { white-space: normal; font-size: 9pt; }
table.drift td, table.drift th { font-size: 8.8pt; padding: 3px 4px; }
table.matrix { width: auto; }
table.matrix td { font-family: "DejaVu Sans Mono", monospace; text-align: right; padding: 3px 12px; }
.box { border: 1.5px solid #922b21; background: #fbeeee; padding: 8px 12px; margin: 8px 0; }
.note { font-size: 9pt; color: #333; }
figure { margin: 10px 0 14px; page-break-inside: avoid; }
figure img { width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { font-size: 8.5pt; color: #333; margin-top: 3px; }
.sign { display: flex; gap: 30px; margin-top: 18px; }
.sign div { flex: 1; border-top: 1px solid #555; padding-top: 3px; font-size: 9pt; }
footer { margin-top: 14px; border-top: 1px solid #aaa; padding-top: 4px; font-size: 8pt; color: #555; }
@media print { body { background: #fff; } main { box-shadow: none; margin: 0; max-width: none; padding: 0; } }
"""

STATEMENTS = (
    "The results relate only to the item calibrated, in the conditions stated.",
    "This certificate shall not be reproduced except in full without the written approval of the laboratory.",
)


def _e(x) -> str:
    return _html.escape(str(x))


def _kv_table(items) -> str:
    return "<table class='kv'>" + "".join(f"<tr><td>{_e(k)}</td><td>{_e(v)}</td></tr>" for k, v in items) + "</table>"


def _matrix_str(x: float) -> str:
    return f"{x:.9f}"


def _g(x: Optional[float], digits: int = 2) -> str:
    if x is None:
        return ""
    if x == 0:
        return "0"
    return f"{x:.{digits}g}"


def budget_table(b: Budget) -> tuple[list, list, list]:
    """Header, rows and totals of a budget as display strings (shared by HTML and PDF)."""
    head = ["Source", "Basis", "Eq.", "u(xᵢ)", "cᵢ", f"uᵢ ({b.unit})", "Share"]
    body = []
    for c in b.components:
        share = b.share(c)
        ux = "" if c.u is None else f"{_g(c.u)} {display_unit(c.unit)}"
        ci = "" if c.sensitivity is None or c.contribution is None else (
            _g(c.sensitivity, 3) + ("" if c.sensitivity_unit in ("1", "") else f" {display_unit(c.sensitivity_unit)}"))
        body.append([c.source, c.basis, c.equation, ux, ci,
                     "not evaluated" if c.contribution is None else _g(c.contribution),
                     "" if share is None else f"{100 * share:.0f} %"])
    totals = [("Combined standard uncertainty u_c (root sum of squares)", _g(b.combined_u)),
              ("Expanded uncertainty U = k·u_c (k = 2)", _g(b.expanded_U))]
    return head, body, totals


def render_html(cert: Certificate) -> str:
    """The certificate (or refusal report) as one self-contained HTML page."""
    r, lab = cert.result, cert.lab
    title = (f"Calibration certificate {cert.number}" if cert.issued
             else f"No certificate issued: {r.unit}")
    h = ["<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
         f"<title>{_e(title)}</title><style>{CSS}</style></head><body><main>"]
    h.append("<header><div><div class='lab'>" + _e(lab.name) + "</div>"
             + "".join(f"<div class='small'>{_e(x)}</div>" for x in (lab.address, lab.accreditation) if x)
             + "</div><div class='no'>")
    if cert.issued:
        h.append(f"<div class='small'>Certificate number</div><div class='num'>{_e(cert.number)}</div>")
    h.append(f"<div class='small'>Date of issue {_e(cert.issue_date)}</div></div></header>")
    if cert.issued:
        h.append("<h1>Calibration certificate</h1>")
        h.append(f"<div class='note'>Accelerometer triad {_e(r.unit)}: scale factors, biases, orientation "
                 f"of the sensing axes and their thermal model.</div>")
    else:
        h.append("<h1 class='refused'>No certificate issued</h1>")
        h.append("<div class='box'><b>A calibration certificate cannot be issued for "
                 f"{_e(r.unit)}</b> because:<ul>" + "".join(f"<li>{_e(x)}</li>" for x in cert.reasons)
                 + "</ul>This report states why; it is not a calibration certificate and carries no "
                 "certificate number. Correct the cause and calibrate (or fit) again.</div>")
    h.append("<h2>1. Identification</h2>" + _kv_table(cert.identification))
    h.append("<h2>2. Method</h2>" + _kv_table(cert.method))
    h.append("<h2>3. Conditions</h2>" + _kv_table(cert.conditions))
    if not cert.issued:
        h.append("<h2>4. Diagnostics</h2>" + _kv_table(cert.diagnostics))
        if cert.notes:
            h.append("<h3>Notes of the estimator</h3><ul class='note'>"
                     + "".join(f"<li>{_e(n)}</li>" for n in cert.notes) + "</ul>")
        h.append(f"<footer>triadcal {_e(__version__)} · refusal report · {_e(r.unit)}</footer></main></body></html>")
        return "".join(h)
    h.append("<h2>4. Results</h2>")
    h.append(f"<p class='note'>Value and expanded uncertainty U (k = 2, coverage probability about 95 %) of "
             f"every parameter at the reference temperature {r.reference_temperature_C:g} °C. "
             f"U comes from the <b>{_e(cert.source_of_u)}</b>.</p>")
    h.append("<table class='results'><tr><th>Parameter</th><th>Meaning</th><th class='num'>Value</th>"
             "<th class='num'>U (k = 2)</th><th>Unit</th></tr>")
    group = None
    for row in cert.rows:
        if row.group != group:
            group = row.group
            h.append(f"<tr class='group'><td colspan='5'>{_e(group)}</td></tr>")
        h.append(f"<tr data-param='{_e(row.name)}'><td class='name'>{_e(row.name)}</td>"
                 f"<td class='desc'>{_e(row.description)}</td><td class='num'>{_e(row.value)}</td>"
                 f"<td class='num'>{_e(row.U)}</td><td class='unit'>{_e(display_unit(row.unit))}</td></tr>")
    h.append("</table>")
    h.append("<h2>5. Thermal model</h2>" + "".join(f"<p>{_e(t)}</p>" for t in cert.thermal_model))
    if cert.inverse_matrix is not None:
        h.append("<h2>6. Inverse matrix to apply to readings</h2>")
        h.append(f"<p>A_IMU = Ca⁻¹ · (K·W − S), with K and S of the table at the reading's temperature. "
                 f"Ca⁻¹ at {r.reference_temperature_C:g} °C (mid-line), rows and columns X, Y, Z; an off-diagonal "
                 "element is close to minus the corresponding angle in radians and carries its U:</p>")
        h.append("<table class='matrix'>" + "".join(
            "<tr>" + "".join(f"<td>{_matrix_str(x)}</td>" for x in row) + "</tr>" for row in cert.inverse_matrix)
            + "</table>")
    b = cert.budget
    h.append("<h2>7. Uncertainty budget</h2>")
    h.append(f"<p class='note'>Standard uncertainties of an {_e(b.quantity)}, sorted by size (seed paper eq. 4–7). "
             "This is the uncertainty a user should expect of the corrected axes anywhere in the range; "
             "the table of section 4 states the parameters at the reference temperature.</p>")
    head, body, totals = budget_table(b)
    h.append("<table class='budget'><colgroup>" + "".join(
        f"<col style='width:{w}%'>" for w in (14, 36, 9, 11, 12, 10, 8)) + "</colgroup><tr>" + "".join(
        f"<th{' class=num' if i >= 3 else ''}>{_e(x)}</th>" for i, x in enumerate(head)) + "</tr>")
    for row in body:
        h.append("<tr>" + "".join(
            f"<td class='{'num' if i >= 3 else ('desc' if i == 1 else '')}'>{_e(x)}</td>" for i, x in enumerate(row))
            + "</tr>")
    for label, value in totals:
        h.append(f"<tr class='total'><td colspan='5'>{_e(label)}</td><td class='num'>{_e(value)}</td><td></td></tr>")
    h.append("</table>")
    missing = [c.source for c in b.components if c.contribution is None]
    if missing:
        h.append(f"<p class='note'>Not evaluated (not in u_c): {_e(', '.join(missing))}.</p>")
    h.append("<h2>8. Diagnostics</h2>" + _kv_table(cert.diagnostics))
    if cert.notes:
        h.append("<ul class='note'>" + "".join(f"<li>{_e(n)}</li>" for n in cert.notes) + "</ul>")
    if cert.plots or cert.skipped_plots:
        h.append("<h2>9. Plots</h2>")
        for p in cert.plots:
            data = base64.b64encode(p.png).decode("ascii")
            h.append(f"<figure><img alt='{_e(p.title)}' src='data:image/png;base64,{data}'>"
                     f"<figcaption><b>{_e(p.title)}.</b> {_e(p.caption)}</figcaption></figure>")
        if cert.skipped_plots:
            h.append("<p class='note'>Not drawn: " + "; ".join(
                f"{_e(k)} ({_e(v)})" for k, v in cert.skipped_plots.items()) + ".</p>")
    h.append("<h2>10. Traceability and statements</h2>")
    if lab.traceability:
        h.append(f"<p>{_e(lab.traceability)}</p>")
    h.append("".join(f"<p class='note'>{_e(s)}</p>" for s in STATEMENTS))
    h.append("<div class='sign'><div>" + _e(lab.signatory_name or "Authorised signatory") + "<br>"
             + _e(lab.signatory_title) + "</div><div>Date and signature</div></div>")
    h.append(f"<footer>Certificate {_e(cert.number)} · {_e(lab.name)} · issued with triadcal "
             f"{_e(__version__)}</footer></main></body></html>")
    return "".join(h)


# =========================================================================================
# PDF (reportlab)
# =========================================================================================
_FONTS_READY = False


def _fonts() -> tuple[str, str, str]:
    """Register DejaVu Sans (shipped with matplotlib) so that ″ ± ° µ ⁻¹ σ δ render; fall back
    to Helvetica when the files are not there."""
    global _FONTS_READY
    from reportlab.pdfbase import pdfmetrics
    from reportlab.pdfbase.ttfonts import TTFont

    if _FONTS_READY:
        return "DejaVu", "DejaVu-Bold", "DejaVuMono"
    try:
        import matplotlib

        d = os.path.join(matplotlib.get_data_path(), "fonts", "ttf")
        pdfmetrics.registerFont(TTFont("DejaVu", os.path.join(d, "DejaVuSans.ttf")))
        pdfmetrics.registerFont(TTFont("DejaVu-Bold", os.path.join(d, "DejaVuSans-Bold.ttf")))
        pdfmetrics.registerFont(TTFont("DejaVuMono", os.path.join(d, "DejaVuSansMono.ttf")))
        from reportlab.lib.fonts import addMapping

        addMapping("DejaVu", 0, 0, "DejaVu")
        addMapping("DejaVu", 1, 0, "DejaVu-Bold")
        addMapping("DejaVu", 0, 1, "DejaVu")
        addMapping("DejaVu", 1, 1, "DejaVu-Bold")
        _FONTS_READY = True
        return "DejaVu", "DejaVu-Bold", "DejaVuMono"
    except (OSError, ImportError):
        return "Helvetica", "Helvetica-Bold", "Courier"


def render_pdf(cert: Certificate, path) -> None:
    """Write the certificate (or refusal report) as an A4 PDF with reportlab; every page
    carries the certificate number and "page n of m"."""
    from reportlab.lib import colors
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.styles import ParagraphStyle
    from reportlab.lib.units import mm
    from reportlab.platypus import Image, KeepTogether, Paragraph, Spacer, Table, TableStyle

    font, bold, mono = _fonts()
    r, lab = cert.result, cert.lab
    navy = colors.HexColor("#1f3a5f")
    st = {
        "body": ParagraphStyle("body", fontName=font, fontSize=9, leading=11.5),
        "small": ParagraphStyle("small", fontName=font, fontSize=7.8, leading=9.6, textColor=colors.HexColor("#333333")),
        "smallr": ParagraphStyle("smallr", fontName=font, fontSize=7.8, leading=9.6, alignment=2),
        "cell": ParagraphStyle("cell", fontName=font, fontSize=8, leading=9.8),
        "cellb": ParagraphStyle("cellb", fontName=bold, fontSize=8, leading=9.8),
        "h1": ParagraphStyle("h1", fontName=bold, fontSize=16, leading=20, textColor=navy, spaceAfter=2),
        "h1r": ParagraphStyle("h1r", fontName=bold, fontSize=16, leading=20, textColor=colors.HexColor("#922b21")),
        "h2": ParagraphStyle("h2", fontName=bold, fontSize=11, leading=14, textColor=navy, spaceBefore=9, spaceAfter=4),
        "lab": ParagraphStyle("lab", fontName=bold, fontSize=12, leading=15, textColor=navy),
        "right": ParagraphStyle("right", fontName=font, fontSize=8, leading=10, alignment=2),
        "num": ParagraphStyle("num", fontName=bold, fontSize=10.5, leading=13, alignment=2),
    }

    def P(text, style="body"):
        return Paragraph(_html.escape(str(text)), st[style])

    grid = [("GRID", (0, 0), (-1, -1), 0.4, colors.HexColor("#c8ccd2")),
            ("VALIGN", (0, 0), (-1, -1), "TOP"),
            ("TOPPADDING", (0, 0), (-1, -1), 2), ("BOTTOMPADDING", (0, 0), (-1, -1), 2)]
    width = A4[0] - 28 * mm

    def kv(items):
        t = Table([[P(k, "cell"), P(v, "cell")] for k, v in items], colWidths=[0.32 * width, 0.68 * width])
        t.setStyle(TableStyle(grid + [("BACKGROUND", (0, 0), (0, -1), colors.HexColor("#f3f5f8"))]))
        return t

    story = []
    right = ([P("Certificate number", "right"), Paragraph(_html.escape(cert.number), st["num"])] if cert.issued else []) \
        + [P(f"Date of issue {cert.issue_date}", "right")]
    left = [P(lab.name, "lab")] + [P(x, "small") for x in (lab.address, lab.accreditation) if x]
    head = Table([[left, right]], colWidths=[0.62 * width, 0.38 * width])
    head.setStyle(TableStyle([("VALIGN", (0, 0), (-1, -1), "TOP"), ("LINEBELOW", (0, 0), (-1, 0), 1.5, navy),
                              ("LEFTPADDING", (0, 0), (0, 0), 0), ("RIGHTPADDING", (-1, 0), (-1, 0), 0)]))
    story += [head, Spacer(1, 5)]
    if cert.issued:
        story.append(P("Calibration certificate", "h1"))
        story.append(P(f"Accelerometer triad {r.unit}: scale factors, biases, orientation of the sensing axes and "
                       "their thermal model."))
    else:
        story.append(P("No certificate issued", "h1r"))
        box = [P(f"A calibration certificate cannot be issued for {r.unit} because:", "cellb")]
        box += [P("• " + x, "cell") for x in cert.reasons]
        box.append(P("This report states why; it is not a calibration certificate and carries no certificate "
                     "number. Correct the cause and calibrate (or fit) again.", "cell"))
        t = Table([[box]], colWidths=[width])
        t.setStyle(TableStyle([("BOX", (0, 0), (-1, -1), 1.2, colors.HexColor("#922b21")),
                               ("BACKGROUND", (0, 0), (-1, -1), colors.HexColor("#fbeeee"))]))
        story.append(t)
    story += [P("1. Identification", "h2"), kv(cert.identification), P("2. Method", "h2"), kv(cert.method),
              P("3. Conditions", "h2"), kv(cert.conditions)]
    if not cert.issued:
        story += [P("4. Diagnostics", "h2"), kv(cert.diagnostics)]
        story += [P("• " + n, "small") for n in cert.notes]
    else:
        story.append(P("4. Results", "h2"))
        story.append(P(f"Value and expanded uncertainty U (k = 2, coverage probability about 95 %) of every "
                       f"parameter at the reference temperature {r.reference_temperature_C:g} °C. U comes from the "
                       f"{cert.source_of_u}."))
        story.append(Spacer(1, 3))
        rows = [[P("Parameter", "cellb"), P("Meaning", "cellb"), P("Value", "cellb"), P("U (k = 2)", "cellb"),
                 P("Unit", "cellb")]]
        style = list(grid) + [("BACKGROUND", (0, 0), (-1, 0), colors.HexColor("#eef1f6")),
                              ("ALIGN", (2, 1), (3, -1), "RIGHT"), ("FONTNAME", (0, 1), (0, -1), mono),
                              ("FONTNAME", (2, 1), (3, -1), mono), ("FONTSIZE", (0, 1), (-1, -1), 8)]
        group = None
        for row in cert.rows:
            if row.group != group:
                group = row.group
                rows.append([P(group, "cellb"), "", "", "", ""])
                i = len(rows) - 1
                style += [("SPAN", (0, i), (-1, i)), ("BACKGROUND", (0, i), (-1, i), colors.HexColor("#dfe6f0"))]
            # value, U and name as plain strings: one text run each, so the text extracts verbatim
            rows.append([row.name, P(row.description, "small"), row.value, row.U, display_unit(row.unit)])
        t = Table(rows, colWidths=[0.2 * width, 0.41 * width, 0.16 * width, 0.12 * width, 0.11 * width],
                  repeatRows=1)
        t.setStyle(TableStyle(style))
        story.append(t)
        story.append(P("5. Thermal model", "h2"))
        story += [P(x) for x in cert.thermal_model]
        if cert.inverse_matrix is not None:
            mt = Table([[_matrix_str(x) for x in row] for row in cert.inverse_matrix], hAlign="LEFT")
            mt.setStyle(TableStyle(grid + [("FONTNAME", (0, 0), (-1, -1), mono), ("FONTSIZE", (0, 0), (-1, -1), 9),
                                           ("ALIGN", (0, 0), (-1, -1), "RIGHT")]))
            story.append(KeepTogether([
                P("6. Inverse matrix to apply to readings", "h2"),
                P(f"A_IMU = Ca⁻¹ · (K·W − S), with K and S of the table at the reading's temperature. Ca⁻¹ at "
                  f"{r.reference_temperature_C:g} °C (mid-line), rows and columns X, Y, Z; an off-diagonal element is "
                  "close to minus the corresponding angle in radians and carries its U:"), Spacer(1, 3), mt]))
        b = cert.budget
        head, body, totals = budget_table(b)
        brow = [[P(x, "cellb") for x in head]]
        brow += [[P(row[0], "cell"), P(row[1], "small"), P(row[2], "small"), P(row[3], "smallr"),
                  P(row[4], "smallr")] + list(row[5:]) for row in body]
        n = len(brow)
        brow += [[P(label, "cellb"), "", "", "", "", value, ""] for label, value in totals]
        bt = Table(brow, colWidths=[0.14 * width, 0.35 * width, 0.09 * width, 0.11 * width, 0.13 * width,
                                    0.1 * width, 0.08 * width], repeatRows=1)
        bt.setStyle(TableStyle(grid + [("BACKGROUND", (0, 0), (-1, 0), colors.HexColor("#eef1f6")),
                                       ("ALIGN", (3, 1), (-1, -1), "RIGHT"), ("FONTSIZE", (0, 1), (-1, -1), 7.5),
                                       ("FONTNAME", (3, 1), (-1, -1), mono),
                                       ("SPAN", (0, n), (4, n)), ("SPAN", (0, n + 1), (4, n + 1)),
                                       ("BACKGROUND", (0, n), (-1, -1), colors.HexColor("#f3f3f3"))]))
        story += [P("7. Uncertainty budget", "h2"),
                  P(f"Standard uncertainties of an {b.quantity}, sorted by size (seed paper eq. 4–7). This is the "
                    "uncertainty a user should expect of the corrected axes anywhere in the range; the table of "
                    "section 4 states the parameters at the reference temperature."), Spacer(1, 3), bt]
        missing = [c.source for c in b.components if c.contribution is None]
        if missing:
            story.append(P(f"Not evaluated (not in u_c): {', '.join(missing)}.", "small"))
        story += [P("8. Diagnostics", "h2"), kv(cert.diagnostics)]
        story += [P("• " + n, "small") for n in cert.notes]
        if cert.plots or cert.skipped_plots:
            from PIL import Image as PILImage

            heading = [P("9. Plots", "h2")]
            for p in cert.plots:
                w_px, h_px = PILImage.open(io.BytesIO(p.png)).size
                w = 0.94 * width
                h = w * h_px / w_px
                if h > 190 * mm:
                    h, w = 190 * mm, 190 * mm * w_px / h_px
                story.append(KeepTogether(heading + [Image(io.BytesIO(p.png), width=w, height=h),
                                                     P(f"{p.title}. {p.caption}", "small"), Spacer(1, 6)]))
                heading = []
            if cert.skipped_plots:
                story += heading
                story.append(P("Not drawn: " + "; ".join(f"{k} ({v})" for k, v in cert.skipped_plots.items()) + ".",
                               "small"))
        sign = Table([[P((lab.signatory_name or "Authorised signatory") + (f", {lab.signatory_title}"
                                                                            if lab.signatory_title else ""), "cell"),
                       P("Date and signature", "cell")]], colWidths=[0.5 * width, 0.5 * width])
        sign.setStyle(TableStyle([("LINEABOVE", (0, 0), (0, 0), 0.8, colors.black),
                                  ("LINEABOVE", (1, 0), (1, 0), 0.8, colors.black)]))
        story.append(KeepTogether([P("10. Traceability and statements", "h2")]
                                  + ([P(lab.traceability)] if lab.traceability else [])
                                  + [P(s, "small") for s in STATEMENTS] + [Spacer(1, 22), sign]))

    footer = (f"Certificate {cert.number} · {lab.name}" if cert.issued
              else f"Refusal report (no certificate) · {r.unit}")

    _write_pdf(path, story, footer, font, title=("Calibration certificate " + cert.number) if cert.issued
               else f"No certificate issued: {r.unit}", author=lab.name)


def _write_pdf(path, story, footer: str, font: str, title: str, author: str) -> None:
    """Build an A4 document whose every page carries ``footer`` and "page n of m"."""
    from reportlab.lib import colors
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.units import mm
    from reportlab.pdfgen import canvas as rl_canvas
    from reportlab.platypus import SimpleDocTemplate

    class NumberedCanvas(rl_canvas.Canvas):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self._pages = []

        def showPage(self):
            self._pages.append(dict(self.__dict__))
            self._startPage()

        def save(self):
            total = len(self._pages)
            for state in self._pages:
                self.__dict__.update(state)
                self.setFont(font, 7.5)
                self.setFillColor(colors.HexColor("#555555"))
                self.drawString(14 * mm, 9 * mm, footer)
                self.drawRightString(A4[0] - 14 * mm, 9 * mm, f"page {self._pageNumber} of {total}")
                super().showPage()
            super().save()

    with atomic_path(path) as tmp:
        _build_pdf(SimpleDocTemplate, tmp, story, NumberedCanvas, A4, mm, title, author)


def _build_pdf(SimpleDocTemplate, path, story, NumberedCanvas, A4, mm, title, author) -> None:
    doc = SimpleDocTemplate(str(path), pagesize=A4, leftMargin=14 * mm, rightMargin=14 * mm, topMargin=13 * mm,
                            bottomMargin=16 * mm, title=title, author=author, creator=f"triadcal {__version__}")
    doc.build(story, canvasmaker=NumberedCanvas)


# =========================================================================================
# drift report: a comparison of two calibrations (results-json "triadcal.comparison")
# =========================================================================================
COMPARISON_FORMAT = "triadcal.comparison"
COMPARISON_VERSION = 1


@dataclass
class DriftRow:
    """One compared parameter: drift (after - before) and its U = 2u rounded as on a certificate."""

    name: str
    drift: str
    U: str
    unit: str
    En: Optional[float]
    p_exceeds: Optional[float]
    verdict: str
    drift_value: float
    U_value: float
    tolerance: Optional[float] = None
    k: float = COVERAGE_FACTOR


def check_comparison(comparison: dict, source: str = "<dict>") -> None:
    require_format(comparison, COMPARISON_FORMAT, COMPARISON_VERSION, source, "a comparison", "comparison")
    from ..estimation.compare import ComparisonResult

    ComparisonResult.from_dict(comparison, source)      # every field it uses, validated


def drift_rows(comparison: dict) -> list:
    rows = []
    for name, p in comparison.get("parameters", {}).items():
        d, u = float(p["drift"]), float(p["u"])
        U = float(p["U"]) if p.get("U") is not None else COVERAGE_FACTOR * u   # the comparison's own k if stated
        ds, Us = round_to_uncertainty(d, U)
        en = p.get("En")
        pe = p.get("p_exceeds")
        rows.append(DriftRow(name, ds, Us, str(p.get("unit", "")), None if en is None else float(en),
                             None if pe is None else float(pe), str(p.get("verdict", "")), d, U,
                             None if p.get("tolerance") is None else float(p["tolerance"]),
                             float(p.get("k", COVERAGE_FACTOR))))
    return rows


_COMPARISON_KNOWN = {"format", "version", "rule", "parameters", "overall", "notes"}


def _drift_identification(comparison: dict, issue_date: str) -> list:
    ident = [("Date of issue", issue_date), ("Software", f"triadcal {__version__}")]
    for k, v in comparison.items():
        if k in _COMPARISON_KNOWN:
            continue
        if isinstance(v, dict):
            v = ", ".join(f"{a}: {b:.4g}" if isinstance(b, float) else f"{a}: {b}" for a, b in v.items()
                          if not isinstance(b, (dict, list)))
        elif isinstance(v, list):
            v = ", ".join(str(x) for x in v)
        ident.append((k.replace("_", " "), str(v)))
    return ident


def render_drift_html(comparison: dict, *, lab: Optional[LabConfig] = None, issue_date: Optional[str] = None,
                      plot: bool = True) -> str:
    """A self-contained HTML drift report of a comparison (results-json ``triadcal.comparison``)."""
    check_comparison(comparison)
    lab = lab or LabConfig()
    issue_date = issue_date or _dt.date.today().isoformat()
    rows = drift_rows(comparison)
    overall = str(comparison.get("overall", ""))
    h = ["<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
         f"<title>Drift report: {_e(overall)}</title><style>{CSS}</style></head><body><main>",
         "<header><div><div class='lab'>" + _e(lab.name) + "</div>"
         + "".join(f"<div class='small'>{_e(x)}</div>" for x in (lab.address, lab.accreditation) if x)
         + f"</div><div class='no'><div class='small'>Date of issue {_e(issue_date)}</div></div></header>",
         "<h1>Drift report</h1>",
         f"<p>Overall verdict: <b class='verdict-{_e(overall)}'>{_e(overall.upper())}</b></p>",
         "<h2>1. Identification</h2>" + _kv_table(_drift_identification(comparison, issue_date)),
         "<h2>2. Decision rule</h2>" + f"<p>{_e(comparison.get('rule', 'not stated'))}</p>",
         "<h2>3. Drift of each parameter</h2>",
         "<p class='note'>Drift = after − before; U is the expanded uncertainty of the drift (k = 2), from "
         "both calibrations and their correlation; E_n = |drift| / U_drift.</p>",
         "<table class='results drift'><tr><th>Parameter</th><th class='num'>Drift</th>"
         f"<th class='num'>U (k = {rows[0].k if rows else COVERAGE_FACTOR:g})</th>"
         "<th>Unit</th><th class='num'>Tolerance</th><th class='num'>E_n</th><th class='num'>P(|drift| &gt; T)</th>"
         "<th>Verdict</th></tr>"]
    for r in rows:
        colour = {"pass": "#1e8449", "fail": "#c0392b", "inconclusive": "#b9770e"}.get(r.verdict, "#111")
        h.append(f"<tr data-param='{_e(r.name)}'><td class='name'>{_e(r.name)}</td><td class='num'>{_e(r.drift)}</td>"
                 f"<td class='num'>{_e(r.U)}</td><td class='unit'>{_e(display_unit(r.unit))}</td>"
                 f"<td class='num'>{'' if r.tolerance is None else f'{r.tolerance:g}'}</td>"
                 f"<td class='num'>{'' if r.En is None else f'{r.En:.2f}'}</td>"
                 f"<td class='num'>{'' if r.p_exceeds is None else f'{r.p_exceeds:.4g}'}</td>"
                 f"<td style='color:{colour};font-weight:bold'>{_e(r.verdict)}</td></tr>")
    h.append("</table>")
    if comparison.get("notes"):
        h.append("<ul class='note'>" + "".join(f"<li>{_e(n)}</li>" for n in comparison["notes"]) + "</ul>")
    if plot and rows:
        from .plots import drift_figure, figure_png

        data = base64.b64encode(figure_png(drift_figure(rows))).decode("ascii")
        h.append(f"<figure><img alt='drift' src='data:image/png;base64,{data}'><figcaption>Drift of each "
                 "parameter with U (k = 2), coloured by the verdict.</figcaption></figure>")
    h.append(f"<footer>Drift report · {_e(lab.name)} · triadcal {_e(__version__)}</footer></main></body></html>")
    return "".join(h)


def render_drift_pdf(comparison: dict, path, *, lab: Optional[LabConfig] = None,
                     issue_date: Optional[str] = None, plot: bool = True) -> None:
    """The drift report as an A4 PDF (reportlab)."""
    from reportlab.lib import colors
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.styles import ParagraphStyle
    from reportlab.lib.units import mm
    from reportlab.platypus import Image, Paragraph, Spacer, Table, TableStyle

    check_comparison(comparison)
    lab = lab or LabConfig()
    issue_date = issue_date or _dt.date.today().isoformat()
    font, bold, mono = _fonts()
    navy = colors.HexColor("#1f3a5f")
    body = ParagraphStyle("b", fontName=font, fontSize=9, leading=11.5)
    cell = ParagraphStyle("c", fontName=font, fontSize=8, leading=9.8)
    h1 = ParagraphStyle("h1", fontName=bold, fontSize=16, leading=20, textColor=navy)
    h2 = ParagraphStyle("h2", fontName=bold, fontSize=11, leading=14, textColor=navy, spaceBefore=9, spaceAfter=4)
    width = A4[0] - 28 * mm
    grid = [("GRID", (0, 0), (-1, -1), 0.4, colors.HexColor("#c8ccd2")), ("VALIGN", (0, 0), (-1, -1), "TOP"),
            ("FONTNAME", (0, 0), (-1, -1), font), ("FONTSIZE", (0, 0), (-1, -1), 8)]
    overall = str(comparison.get("overall", ""))
    story = [Paragraph(_html.escape(lab.name), ParagraphStyle("lab", fontName=bold, fontSize=12, textColor=navy)),
             Spacer(1, 6), Paragraph("Drift report", h1),
             Paragraph(f"Overall verdict: <b>{_html.escape(overall.upper())}</b>", body),
             Paragraph("1. Identification", h2)]
    t = Table([[Paragraph(_html.escape(k), cell), Paragraph(_html.escape(v), cell)]
               for k, v in _drift_identification(comparison, issue_date)], colWidths=[0.32 * width, 0.68 * width])
    t.setStyle(TableStyle(grid))
    story += [t, Paragraph("2. Decision rule", h2), Paragraph(_html.escape(str(comparison.get("rule", "not stated"))), body),
              Paragraph("3. Drift of each parameter", h2),
              Paragraph("Drift = after − before; U is the expanded uncertainty of the drift (k = 2), from both "
                        "calibrations and their correlation; E_n = |drift| / U_drift.", body), Spacer(1, 3)]
    rows = drift_rows(comparison)
    data = [["Parameter", "Drift", f"U (k = {rows[0].k if rows else COVERAGE_FACTOR:g})", "Unit", "Tolerance", "E_n", "P(|d| > T)", "Verdict"]]
    data += [[r.name, r.drift, r.U, display_unit(r.unit), "" if r.tolerance is None else f"{r.tolerance:g}",
              "" if r.En is None else f"{r.En:.2f}",
              "" if r.p_exceeds is None else f"{r.p_exceeds:.4g}", r.verdict] for r in rows]
    t = Table(data, colWidths=[0.19 * width, 0.13 * width, 0.12 * width, 0.11 * width, 0.1 * width, 0.09 * width,
                               0.12 * width, 0.14 * width], repeatRows=1)
    style = grid + [("BACKGROUND", (0, 0), (-1, 0), colors.HexColor("#eef1f6")), ("FONTNAME", (0, 0), (-1, 0), bold),
                    ("ALIGN", (1, 1), (2, -1), "RIGHT"), ("ALIGN", (4, 1), (6, -1), "RIGHT"),
                    ("FONTNAME", (0, 1), (2, -1), mono)]
    for i, r in enumerate(rows, 1):
        c = {"pass": "#1e8449", "fail": "#c0392b", "inconclusive": "#b9770e"}.get(r.verdict)
        if c:
            style.append(("TEXTCOLOR", (7, i), (7, i), colors.HexColor(c)))
    t.setStyle(TableStyle(style))
    story.append(t)
    for n in comparison.get("notes") or ():
        story.append(Paragraph(_html.escape("• " + str(n)), cell))
    if plot and rows:
        from PIL import Image as PILImage

        from .plots import drift_figure, figure_png

        png = figure_png(drift_figure(rows))
        w_px, h_px = PILImage.open(io.BytesIO(png)).size
        w = 0.9 * width
        h = min(w * h_px / w_px, 200 * mm)
        story += [Spacer(1, 8), Image(io.BytesIO(png), width=h * w_px / h_px, height=h)]
    _write_pdf(path, story, f"Drift report · {lab.name}", font, title=f"Drift report: {overall}", author=lab.name)


def drift_report(comparison, *, lab=None, html=None, pdf=None, issue_date: Optional[str] = None) -> dict:
    """Write the drift report of a comparison (path or dict) as HTML and/or PDF; returns the comparison."""
    source = "<dict>"
    if not isinstance(comparison, dict):
        source = str(comparison)
        comparison = read_json(comparison)
    check_comparison(comparison, source)
    if lab is not None and not isinstance(lab, LabConfig):
        lab = load_lab(lab)
    if html is not None:
        atomic_write_text(html, render_drift_html(comparison, lab=lab, issue_date=issue_date))
    if pdf is not None:
        render_drift_pdf(comparison, pdf, lab=lab, issue_date=issue_date)
    return comparison


# =========================================================================================
# the library function behind `triadcal certificate`
# =========================================================================================
def certificate(result, *, posterior=None, lab=None, data=None, diagnosis=None, html=None, pdf=None,
                plots_dir=None, number: Optional[str] = None, issue_date: Optional[str] = None) -> Certificate:
    """Issue a certificate (``triadcal certificate``) or, when a diagnostic failed, a refusal report.

    ``result``: a results-json path or a CalibrationResult; ``posterior``: netCDF path or
    InferenceData; ``lab``: TOML path or LabConfig; ``data``: bench CSV path or Campaign;
    ``diagnosis``: a diagnosis JSON path or dict. Writes ``html``, ``pdf`` and the plots as
    PNG in ``plots_dir`` when given; returns the :class:`Certificate` (``issued`` says which).
    """
    result_path = None
    if not isinstance(result, CalibrationResult):
        result_path = result
        result = CalibrationResult.load(result)
    # a result that is not a calibration at all (no parameters, values or u not finite, K <= 0
    # or outside its unit's band, an angle beyond the gate, no reference temperature) is
    # refused outright, one line, before any file is written; a result whose estimator said
    # "not ok" gets the refusal report below
    check_result_for_use(result, str(result_path or f"result of {result.unit}"), need_ok=False)
    if lab is not None and not isinstance(lab, LabConfig):
        lab = load_lab(lab)
    if posterior is not None and not hasattr(posterior, "posterior"):
        from ..io.netcdf import read_inference_data

        posterior = read_inference_data(posterior)
    if data is not None and not hasattr(data, "n_visits"):
        from ..io.bench_csv import read_bench_csv

        data = read_bench_csv(data)
    if data is not None and data.units != [result.unit]:
        raise ValueError(f"the campaign data is of unit(s) {data.units}, the result of {result.unit!r}")
    if diagnosis is not None and not isinstance(diagnosis, dict):
        source = str(diagnosis)
        diagnosis = read_json(diagnosis)
        if not isinstance(diagnosis, dict) or diagnosis.get("format") != "triadcal.diagnosis":
            raise ValueError(f"{source}: not a diagnosis (format "
                             f"{diagnosis.get('format') if isinstance(diagnosis, dict) else None!r}, "
                             "expected 'triadcal.diagnosis')")
    cert = build_certificate(result, lab=lab, campaign=data, idata=posterior, diagnosis=diagnosis, number=number,
                             issue_date=issue_date, result_path=result_path)
    if html is not None:
        atomic_write_text(html, render_html(cert))
    if pdf is not None:
        render_pdf(cert, pdf)
    if plots_dir is not None and cert.plots:
        Path(plots_dir).mkdir(parents=True, exist_ok=True)
        for p in cert.plots:
            atomic_write_bytes(Path(plots_dir) / f"{p.name}.png", p.png)
    return cert
