"""The certificate as one self-contained HTML page (CSS inline, images as data URIs, nothing
fetched from a network).
"""

from __future__ import annotations

import math

import base64
import html as _html
from typing import Optional

from ... import __version__
from ...estimation.result import significant
from ...uncertainty.budget import Budget
from ..notation import display_unit
from .content import Certificate, values_temperature

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
table.drift td, table.drift th { font-size: 8pt; padding: 2px 3px; }
table.drift td:last-child { white-space: nowrap; }
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


PARAMETER_BUDGETS_TEXT = (
    "Each column is one parameter of section 4: the contribution |cᵢ|·u(xᵢ) of every source in the parameter's "
    "unit, cᵢ its sensitivity from the model (the least-squares estimate's response to the source; the results "
    "file gives cᵢ with its sign). Type A is the fit's own uncertainty (output noise, and the bench's random "
    "errors per visit when the lab states them); Type B are the lab's systematic errors from its lab file. "
    "A contribution of 0 means the source does not reach that parameter (e.g. a fixture rotation about z "
    "reaches Ca_xy and Ca_yx only).")


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
    # both from the unrounded u_c (U = 2 u_c), rounded half up: 15.25 -> 15.3 and 30.5 -> 31
    if abs(b.effective_k - b.coverage_factor) < 1e-9:
        u_label = f"Expanded uncertainty U = k·u_c (k = {b.coverage_factor:g})"
    else:
        u_label = (f"Expanded uncertainty U: {100 * b.coverage_probability:.2f} % coverage interval of the combined "
                   f"distribution (two-point parts exact; k = U/u_c = {b.effective_k:.3g})")
    totals = [("Combined standard uncertainty u_c (root sum of squares)", significant(b.total, 3)),
              (u_label, significant(b.expanded_U, 2))]
    return head, body, totals


def budget_matrix(budgets: list) -> tuple[list, list, list]:
    """The budgets of several parameters of one unit side by side (shared by HTML and PDF):
    a row per source (its standard uncertainty u(xᵢ), then each parameter's contribution
    |cᵢ|·u(xᵢ) in the parameter's unit), then u_c, ν_eff, k and U of each parameter."""
    unit = display_unit(budgets[0].unit)
    head = ["Source", "Type", "u(xᵢ)"] + [f"{b.quantity}" for b in budgets]
    sources = []
    for b in budgets:
        for c in b.components:
            if c.source not in [x.source for x in sources]:
                sources.append(c)
    body = []
    for src in sources:
        cells = []
        for b in budgets:
            c = next((x for x in b.components if x.source == src.source), None)
            cells.append("" if c is None or c.contribution is None else _g(c.contribution))
        ux = "" if src.type == "A" or src.u is None else f"{_g(src.u)} {display_unit(src.unit)}"
        dist = "" if src.distribution == "normal" else f", {src.distribution}"
        body.append([src.source, f"{src.type}{dist}", ux] + cells)
    dof = ["∞" if math.isinf(b.dof_eff) else f"{b.dof_eff:.0f}" for b in budgets]
    totals = [(f"Combined standard uncertainty u_c ({unit})", [significant(b.total, 3) for b in budgets]),
              ("Effective degrees of freedom ν_eff", dof),
              ("Coverage factor k (95.45 %)", [f"{b.effective_k:.3g}" + (" MC" if b.method == "Monte Carlo" else "")
                                               for b in budgets]),
              (f"Expanded uncertainty U ({unit})", [significant(b.expanded_U, 2) for b in budgets])]
    return head, body, totals


def results_intro(cert: Certificate) -> str:
    """The sentence above the results table (HTML and PDF)."""
    at = values_temperature(cert.result)
    if cert.parameter_budgets:
        return (f"Value and expanded uncertainty U (coverage probability 95.45 %) of every parameter at {at}. U comes "
                f"from each parameter's budget: the {cert.source_of_u} (Type A) and the lab's systematic errors "
                "(Type B), section 7.")
    return (f"Value and expanded uncertainty U (k = 2, coverage probability about 95 %) of every parameter at {at}. "
            f"U comes from the {cert.source_of_u}.")


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
    h.append(f"<p class='note'>{_e(results_intro(cert))}</p>")
    if cert.angle_statement:
        h.append(f"<p class='statement'><b>{_e(cert.angle_statement)}</b></p>")
    u_head = "U (95.45 %)" if cert.parameter_budgets else "U (k = 2)"
    h.append("<table class='results'><tr><th>Parameter</th><th>Meaning</th><th class='num'>Value</th>"
             f"<th class='num'>{u_head}</th><th>Unit</th></tr>")
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
                 f"Ca⁻¹ at {values_temperature(r)} (mid-line), rows and columns X, Y, Z; an off-diagonal "
                 "element is close to minus the corresponding angle in radians and carries its U:</p>")
        h.append("<table class='matrix'>" + "".join(
            "<tr>" + "".join(f"<td>{_matrix_str(x)}</td>" for x in row) + "</tr>" for row in cert.inverse_matrix)
            + "</table>")
    b = cert.budget
    h.append("<h2>7. Uncertainty budget</h2>")
    h.append(f"<p class='note'>Standard uncertainties of an {_e(b.quantity)}, sorted by size (seed paper eq. 4–7): "
             "the U that applies when the matrix is used at a temperature in the range (section 4 states the "
             "parameters at the reference temperature only).</p>")
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
    if cert.parameter_budgets:
        h.append("<h3>Budgets of the parameters at the reference temperature</h3>")
        h.append("<p class='note'>" + _e(PARAMETER_BUDGETS_TEXT) + "</p>")
        for group, budgets in cert.parameter_budgets.items():
            head, body, totals = budget_matrix(budgets)
            h.append(f"<table class='budget' data-budget='{_e(group)}'><tr><th colspan='{len(head)}'>{_e(group)}: "
                     f"contributions in {_e(display_unit(budgets[0].unit))}</th></tr><tr>"
                     + "".join(f"<th{' class=num' if i >= 2 else ''}>{_e(x)}</th>" for i, x in enumerate(head)) + "</tr>")
            for row in body:
                h.append("<tr>" + "".join(f"<td class='{'num' if i >= 2 else ''}'>{_e(x)}</td>"
                                          for i, x in enumerate(row)) + "</tr>")
            for label, values in totals:
                h.append(f"<tr class='total'><td colspan='3'>{_e(label)}</td>"
                         + "".join(f"<td class='num'>{_e(v)}</td>" for v in values) + "</tr>")
            h.append("</table>")
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
