"""Calibration certificates (ISO/IEC 17025 §7.8) and drift reports, as HTML and PDF
(``triadcal certificate``); what each states and when none is issued: docs/certificate.md.

Modules: refusal (the rules that refuse a certificate), consistency (a result that contradicts
itself, its data or its dates, refused before anything is written), content (what a certificate
states), html and pdf (rendering), drift (drift reports of a comparison) and issue (the
entry point :func:`certificate`). The lab file is read by :mod:`triadcal.io.lab`, the
uncertainty budget is :mod:`triadcal.uncertainty`.
"""

from ...io.lab import EXAMPLE_LAB_TOML, LabConfig, load_lab  # noqa: F401
from ..notation import display_text, display_unit  # noqa: F401
from .content import (  # noqa: F401
    Certificate,
    ParameterRow,
    build_certificate,
    certificate_number,
    expanded,
    parameter_rows,
)
from .drift import DriftRow, check_comparison, drift_report, drift_rows, render_drift_html, render_drift_pdf  # noqa: F401
from .html import render_html  # noqa: F401
from .issue import certificate  # noqa: F401
from .pdf import render_pdf  # noqa: F401
from .refusal import posterior_diagnostics, refusal_reasons, unidentified_parameters  # noqa: F401
