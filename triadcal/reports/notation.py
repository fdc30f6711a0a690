"""One notation for every report (terminal, HTML, PDF): parameter names as in the results
JSON (Ca_xy, K_x), units with their symbols (µg/°C, arcsec/°C³, µg/g²) where a person reads them;
the JSON keeps its ASCII unit strings (docs/results-json.md)."""

from __future__ import annotations

import re

_POWER = {"2": "²", "3": "³"}


def display_text(text: str) -> str:
    """Units inside a sentence in the report's notation: (arcsec/degC) -> (arcsec/°C), degC3 -> °C³,
    ug -> µg, ug/g2 -> µg/g²."""
    text = re.sub(r"\bdegC([23])\b", lambda m: "°C" + _POWER[m.group(1)], text)
    text = re.sub(r"\bdegC\b", "°C", text)
    text = re.sub(r"(?<=/)g([23])\b", lambda m: "g" + _POWER[m.group(1)], text)
    return re.sub(r"\bug(?=/|\b)", "µg", text)


def display_unit(unit: str) -> str:
    """A parameter's unit as a person reads it (every unit of the model's table, docs/model.md)."""
    return display_text(unit)
