"""One notation for every report (terminal, HTML, PDF): parameter names as in the results
JSON (Ca_xy, K_x), units with their symbols (µg/°C, arcsec/°C) where a person reads them; the
JSON keeps its ASCII unit strings (docs/results-json.md)."""

from __future__ import annotations

import re

DISPLAY_UNIT = {"degC": "°C", "ug": "µg", "arcsec/degC": "arcsec/°C", "ppm/degC": "ppm/°C",
                "ug/degC": "µg/°C", "ug/g2": "µg/g²", "ug/h": "µg/h", "arcsec/degC2": "arcsec/°C²",
                "ppm/degC2": "ppm/°C²", "ug/degC2": "µg/°C²"}


def display_unit(unit: str) -> str:
    return DISPLAY_UNIT.get(unit, unit)


def display_text(text: str) -> str:
    """Units inside a sentence in the report's notation: (arcsec/degC) -> (arcsec/°C), ug -> µg."""
    text = re.sub(r"\bdegC2\b", "°C²", text)
    text = re.sub(r"\bdegC\b", "°C", text)
    return re.sub(r"\bug(?=/|\b)", "µg", text)
