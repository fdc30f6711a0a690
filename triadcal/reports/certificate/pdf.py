"""The certificate as PDF (reportlab), with DejaVu fonts where available for µ, ° and ″.
"""

from __future__ import annotations

import html as _html
import io
import os

from ... import __version__
from ...io.atomic import atomic_path
from ..notation import display_unit
from .content import Certificate, values_temperature
from .html import PARAMETER_BUDGETS_TEXT, results_intro, STATEMENTS, _matrix_str, budget_matrix, budget_table

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
    from reportlab.platypus import (
        Image,
        KeepTogether,
        Paragraph,
        Spacer,
        Table,
        TableStyle,
    )

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
        "h3": ParagraphStyle("h3", fontName=bold, fontSize=9.5, leading=12, textColor=navy, spaceBefore=6, spaceAfter=3),
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
        story.append(P(results_intro(cert)))
        if cert.angle_statement:
            story.append(Paragraph(f"<b>{_html.escape(cert.angle_statement)}</b>", st["body"]))
        story.append(Spacer(1, 3))
        rows = [[P("Parameter", "cellb"), P("Meaning", "cellb"), P("Value", "cellb"), P("U (95.45 %)" if cert.parameter_budgets else "U (k = 2)", "cellb"),
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
                  f"{values_temperature(r)} (mid-line), rows and columns X, Y, Z; an off-diagonal element is "
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
                  P(f"Standard uncertainties of an {b.quantity}, sorted by size (seed paper eq. 4–7): the U that "
                    "applies when the matrix is used at a temperature in the range (section 4 states the parameters "
                    "at the reference temperature only)."), Spacer(1, 3), bt]
        missing = [c.source for c in b.components if c.contribution is None]
        if missing:
            story.append(P(f"Not evaluated (not in u_c): {', '.join(missing)}.", "small"))
        if cert.parameter_budgets:
            story += [P("Budgets of the parameters at the reference temperature", "h3"),
                      P(PARAMETER_BUDGETS_TEXT, "small")]
            for group, budgets in cert.parameter_budgets.items():
                head, body, totals = budget_matrix(budgets)
                ncol = len(head)
                rows = [[P(f"{group}: contributions in {display_unit(budgets[0].unit)}", "cellb")] + [""] * (ncol - 1),
                        [P(x, "cellb") for x in head]]
                rows += [[P(row[0], "cell"), P(row[1], "small"), P(row[2], "smallr")] + list(row[3:]) for row in body]
                n = len(rows)
                rows += [[P(label, "cellb"), "", ""] + list(values) for label, values in totals]
                first = 0.3 * width
                rest = (width - first - 0.16 * width) / (ncol - 3)
                t = Table(rows, colWidths=[first, 0.06 * width, 0.1 * width] + [rest] * (ncol - 3), repeatRows=2)
                t.setStyle(TableStyle(grid + [("SPAN", (0, 0), (-1, 0)),
                                              ("BACKGROUND", (0, 0), (-1, 1), colors.HexColor("#eef1f6")),
                                              ("ALIGN", (3, 2), (-1, -1), "RIGHT"),
                                              ("FONTSIZE", (0, 2), (-1, -1), 7.5),
                                              ("FONTNAME", (3, 2), (-1, -1), mono)]
                                      + [("SPAN", (0, k), (2, k)) for k in range(n, n + len(totals))]
                                      + [("BACKGROUND", (0, n), (-1, -1), colors.HexColor("#f3f3f3"))]))
                story += [Spacer(1, 4), t]
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
