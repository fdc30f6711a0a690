"""Drift reports: a comparison (``triadcal compare``) rendered as HTML and PDF, with its
decision rule.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html as _html
import io
from dataclasses import dataclass
from typing import Optional

from ... import __version__
from ...estimation.result import round_to_uncertainty
from ...io.atomic import read_json
from ...io.atomic import atomic_write_text
from ...io.formats import require_format
from ...uncertainty.budget import COVERAGE_FACTOR
from ..notation import display_unit
from .html import CSS, _e, _kv_table
from ...io.lab import LabConfig, load_lab
from .pdf import _fonts, _write_pdf

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
    significant: Optional[bool] = None     #: |d| > k2 u(d) (a change at the comparison's level)
    within: str = ""                       #: "yes", "no", "not shown" or "" (no tolerance)
    judged: bool = True                    #: part of the overall verdict
    before: str = ""
    after: str = ""

    @property
    def verdict_text(self) -> str:
        """The verdict as the report prints it: a parameter outside the overall verdict says so
        instead of a bare pass/fail."""
        if self.judged:
            return self.verdict
        return "not judged"


def _within(d: float, u: float, tolerance: Optional[float], level: float) -> str:
    """Within tolerance as the decision rule shows it: "yes" with the guard band
    (|d| + k1 u <= T), "no" when |d| > T, "not shown" in between; "" without a tolerance."""
    if tolerance is None:
        return ""
    from ...judgement.compare import coverage_factors

    k1 = coverage_factors(level)[0]
    if abs(d) + k1 * u <= tolerance:
        return "yes"
    return "no" if abs(d) > tolerance else "not shown"


def check_comparison(comparison: dict, source: str = "<dict>") -> None:
    require_format(comparison, COMPARISON_FORMAT, COMPARISON_VERSION, source, "a comparison", "comparison")
    from ...judgement.compare import ComparisonResult

    ComparisonResult.from_dict(comparison, source)      # every field it uses, validated


def drift_rows(comparison: dict) -> list:
    level = float(comparison.get("level", 0.95))
    rows = []
    for name, p in comparison.get("parameters", {}).items():
        d, u = float(p["drift"]), float(p["u"])
        U = float(p["U"]) if p.get("U") is not None else COVERAGE_FACTOR * u   # the comparison's own k if stated
        ds, Us = round_to_uncertainty(d, U)
        en = p.get("En")
        pe = p.get("p_exceeds")
        tol = None if p.get("tolerance") is None else float(p["tolerance"])
        before = after = ""
        if isinstance(p.get("before"), (int, float)) and isinstance(p.get("u_before"), (int, float)):
            before = round_to_uncertainty(float(p["before"]), COVERAGE_FACTOR * float(p["u_before"]))[0]
        if isinstance(p.get("after"), (int, float)) and isinstance(p.get("u_after"), (int, float)):
            after = round_to_uncertainty(float(p["after"]), COVERAGE_FACTOR * float(p["u_after"]))[0]
        rows.append(DriftRow(name, ds, Us, str(p.get("unit", "")), None if en is None else float(en),
                             None if pe is None else float(pe), str(p.get("verdict", "")), d, U, tol,
                             float(p.get("k", COVERAGE_FACTOR)),
                             significant=p.get("significant") if isinstance(p.get("significant"), bool) else None,
                             within=_within(d, u, tol, level), judged=p.get("judged", True) is not False,
                             before=before, after=after))
    return rows


def overall_statement(comparison: dict, rows: list) -> str:
    """The overall verdict with its rule in one sentence, and why a row that reads otherwise
    does not change it."""
    overall = str(comparison.get("overall", "")).upper()
    joint = comparison.get("joint") or {}
    bits = [f"Overall verdict: {overall}."]
    if joint:
        bits.append(f"The joint χ² test of the {len(joint.get('names', []))} angle drifts is "
                    f"{'significant' if joint.get('significant') else 'not significant'} at "
                    f"{float(joint.get('level', 0.95)):.0%} (D² = {float(joint.get('D2', float('nan'))):.4g}, "
                    f"{joint.get('dof', '?')} degrees of freedom).")
    judged = [r for r in rows if r.judged]
    failed = [r.name for r in judged if r.verdict == "fail"]
    undecided = [r.name for r in judged if r.verdict == "inconclusive"]
    if failed:
        bits.append(f"Judged parameters that fail: {', '.join(failed)}.")
    if undecided:
        bits.append(f"Judged parameters whose conformance is not shown: {', '.join(undecided)}.")
    if judged and not failed and not undecided:
        bits.append(f"Every judged parameter ({len(judged)}) passes.")
    from ...judgement.compare import NOT_PASS_NOTE

    held = [str(n)[len(NOT_PASS_NOTE):] for n in comparison.get("notes") or () if str(n).startswith(NOT_PASS_NOTE)]
    if overall != "PASS" and held:
        bits.append("The overall verdict is not pass: " + "; ".join(held) + ".")
    changed = [r.name for r in rows if not r.judged and r.significant]
    if changed:
        bits.append(f"{', '.join(changed)} changed significantly but {'have' if len(changed) > 1 else 'has'} no "
                    "tolerance, so the overall verdict does not judge "
                    f"{'them' if len(changed) > 1 else 'it'} (give one with --param-tolerance).")
    if overall == "FAIL" and not failed:
        bits.append("No single judged parameter fails: the verdict comes from the joint test.")
    return " ".join(bits)


_COMPARISON_KNOWN = {"format", "version", "rule", "parameters", "overall", "notes"}


def _g4(x) -> str:
    return f"{x:.4g}" if isinstance(x, (int, float)) else str(x)


def _p_text(p) -> str:
    if not isinstance(p, (int, float)):
        return "not computed"
    return f"= {p:.2g}" if p > 0 else "< 1e-300"


def _calibration_text(c: dict) -> str:
    return ", ".join(f"{k.replace('_', ' ')} {c[k]}" for k in ("unit", "method", "status", "source") if c.get(k))


def _drift_identification(comparison: dict, issue_date: str) -> list:
    """The comparison's identification as sentences (never a raw mapping)."""
    ident = [("Date of issue", issue_date), ("Software", f"triadcal {__version__}")]
    if comparison.get("label"):
        ident.append(("Comparison", str(comparison["label"])))
    for side in ("before", "after"):
        if isinstance(comparison.get(side), dict):
            ident.append((f"Calibration {side}", _calibration_text(comparison[side])))
    if comparison.get("level") is not None:
        ident.append(("Confidence level", f"{float(comparison['level']):.0%}"))
    tol = comparison.get("tolerance")
    if isinstance(tol, dict) and tol:
        ident.append(("Tolerances", "; ".join(
            f"{k.replace('_arcsec', '').replace('_', ' ')}: {_g4(v)}" + (" arcsec" if k.endswith("_arcsec") else "")
            for k, v in tol.items() if not isinstance(v, (dict, list)))))
    joint = comparison.get("joint")
    if isinstance(joint, dict) and joint:
        ident.append(("Joint test", f"χ² test of the drifts of {', '.join(joint.get('names', []))}: "
                                    f"D² = {_g4(joint.get('D2'))} with {joint.get('dof', '?')} degrees of freedom "
                                    f"(critical value {_g4(joint.get('critical'))}), p {_p_text(joint.get('p_value'))}, "
                                    f"{'significant' if joint.get('significant') else 'not significant'}"))
    corr = comparison.get("correlation")
    if isinstance(corr, dict) and corr:
        ident.append(("Correlation of the calibrations", str(corr.get("reason") or f"rho = {_g4(corr.get('rho'))}")))
    bench = comparison.get("bench_check")
    if isinstance(bench, dict) and bench:
        ident.append(("Bench check (not judged)", "; ".join(
            f"{n} changed by {float(b['drift']):+.2f} ± {float(b['u']):.2f} {b.get('unit', '')}"
            f" ({'significant' if b.get('significant') else 'not significant'})"
            for n, b in bench.items() if isinstance(b, dict) and "drift" in b and "u" in b)))
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
         f"<p class='verdict-{_e(overall)}'><b>{_e(overall_statement(comparison, rows))}</b></p>",
         "<h2>1. Identification</h2>" + _kv_table(_drift_identification(comparison, issue_date)),
         "<h2>2. Decision rule</h2>" + f"<p>{_e(comparison.get('rule', 'not stated'))}</p>",
         "<h2>3. Drift of each parameter</h2>",
         "<p class='note'>Drift = after − before; U is the expanded uncertainty of the drift (k = 2), from "
         "both calibrations and their correlation; E_n = |drift| / U_drift. <i>Significant change</i>: |drift| > "
         "k u(drift) at the comparison's level. <i>Within tolerance</i>: yes when |drift| + k1 u ≤ T (the guard "
         "band of the rule), no when |drift| > T, not shown in between. A parameter without a tolerance T is "
         "<i>not judged</i>: it is not part of the overall verdict, and its row says only whether it changed.</p>",
         "<table class='results drift'><tr><th>Parameter</th><th class='num'>Before</th><th class='num'>After</th>"
         "<th class='num'>Drift</th>"
         f"<th class='num'>U (k = {rows[0].k if rows else COVERAGE_FACTOR:g})</th>"
         "<th>Unit</th><th class='num'>E_n</th><th>Significant change</th><th class='num'>T</th>"
         "<th>Within tolerance</th><th class='num'>P(|d| &gt; T)</th><th>Verdict</th></tr>"]
    for r in rows:
        colour = ({"pass": "#1e8449", "fail": "#c0392b", "inconclusive": "#b9770e"}.get(r.verdict, "#111")
                  if r.judged else "#555")
        sig = "" if r.significant is None else ("yes" if r.significant else "no")
        h.append(f"<tr data-param='{_e(r.name)}'><td class='name'>{_e(r.name)}</td><td class='num'>{_e(r.before)}</td>"
                 f"<td class='num'>{_e(r.after)}</td><td class='num'>{_e(r.drift)}</td>"
                 f"<td class='num'>{_e(r.U)}</td><td class='unit'>{_e(display_unit(r.unit))}</td>"
                 f"<td class='num'>{'' if r.En is None else f'{r.En:.2f}'}</td><td>{sig}</td>"
                 f"<td class='num'>{'' if r.tolerance is None else f'{r.tolerance:g}'}</td><td>{_e(r.within)}</td>"
                 f"<td class='num'>{'' if r.p_exceeds is None else f'{r.p_exceeds:.4g}'}</td>"
                 f"<td style='color:{colour};font-weight:bold'>{_e(r.verdict_text)}</td></tr>")
    h.append("</table>")
    if comparison.get("notes"):
        h.append("<ul class='note'>" + "".join(f"<li>{_e(n)}</li>" for n in comparison["notes"]) + "</ul>")
    if plot and rows:
        from ..plots import drift_figure, figure_png

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
    rows = drift_rows(comparison)
    story = [Paragraph(_html.escape(lab.name), ParagraphStyle("lab", fontName=bold, fontSize=12, textColor=navy)),
             Spacer(1, 6), Paragraph("Drift report", h1),
             Paragraph(f"<b>{_html.escape(overall_statement(comparison, rows))}</b>", body),
             Paragraph("1. Identification", h2)]
    t = Table([[Paragraph(_html.escape(k), cell), Paragraph(_html.escape(v), cell)]
               for k, v in _drift_identification(comparison, issue_date)], colWidths=[0.32 * width, 0.68 * width])
    t.setStyle(TableStyle(grid))
    story += [t, Paragraph("2. Decision rule", h2), Paragraph(_html.escape(str(comparison.get("rule", "not stated"))), body),
              Paragraph("3. Drift of each parameter", h2),
              Paragraph("Drift = after − before; U is the expanded uncertainty of the drift (k = 2), from both "
                        "calibrations and their correlation; E_n = |drift| / U_drift. Significant change: |drift| > "
                        "k u(drift) at the comparison's level. Within tolerance: yes when |drift| + k1 u ≤ T (the guard "
                        "band of the rule), no when |drift| > T, not shown in between. A parameter without a "
                        "tolerance T is not judged: it is not part of the overall verdict, and its row says only "
                        "whether it changed.", body), Spacer(1, 3)]
    data = [["Parameter", "Before", "After", "Drift", f"U (k = {rows[0].k if rows else COVERAGE_FACTOR:g})", "Unit",
             "E_n", "Signif. change", "T", "Within tol.", "P(|d| > T)", "Verdict"]]
    data += [[r.name, r.before, r.after, r.drift, r.U, display_unit(r.unit), "" if r.En is None else f"{r.En:.2f}",
              "" if r.significant is None else ("yes" if r.significant else "no"),
              "" if r.tolerance is None else f"{r.tolerance:g}", r.within,
              "" if r.p_exceeds is None else f"{r.p_exceeds:.4g}",
              Paragraph(_html.escape(r.verdict_text), cell)] for r in rows]
    t = Table(data, colWidths=[w * width for w in (0.11, 0.11, 0.11, 0.09, 0.09, 0.07, 0.05, 0.07, 0.05, 0.06,
                                                    0.07, 0.11)], repeatRows=1)
    style = grid + [("BACKGROUND", (0, 0), (-1, 0), colors.HexColor("#eef1f6")), ("FONTNAME", (0, 0), (-1, 0), bold),
                    ("ALIGN", (1, 1), (4, -1), "RIGHT"), ("ALIGN", (6, 1), (6, -1), "RIGHT"),
                    ("ALIGN", (8, 1), (8, -1), "RIGHT"), ("ALIGN", (10, 1), (10, -1), "RIGHT"),
                    ("FONTNAME", (0, 1), (4, -1), mono), ("FONTSIZE", (0, 0), (-1, -1), 7),
                    ("LEFTPADDING", (0, 0), (-1, -1), 2), ("RIGHTPADDING", (0, 0), (-1, -1), 2)]
    for i, r in enumerate(rows, 1):
        c = {"pass": "#1e8449", "fail": "#c0392b", "inconclusive": "#b9770e"}.get(r.verdict) if r.judged else None
        if c:
            style.append(("TEXTCOLOR", (11, i), (11, i), colors.HexColor(c)))
    t.setStyle(TableStyle(style))
    story.append(t)
    for n in comparison.get("notes") or ():
        story.append(Paragraph(_html.escape("• " + str(n)), cell))
    if plot and rows:
        from PIL import Image as PILImage

        from ..plots import drift_figure, figure_png

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
