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
from .content import display_unit
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


def check_comparison(comparison: dict, source: str = "<dict>") -> None:
    require_format(comparison, COMPARISON_FORMAT, COMPARISON_VERSION, source, "a comparison", "comparison")
    from ...judgement.compare import ComparisonResult

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
