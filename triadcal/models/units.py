"""Unit conversions used at every boundary (reporting unit <-> internal unit).

Internal units of the physics: angles in radians, scale factors in g per output
unit, biases and accelerations in g, temperatures in degC, times in seconds.
Reporting units follow docs/results-json.md.
"""

import math
from typing import Optional

ARCSEC = math.pi / (180.0 * 3600.0)   #: radians per arcsecond
DEG = math.pi / 180.0                 #: radians per degree
ARCMIN = 60.0 * ARCSEC
PPM = 1e-6
UG = 1e-6                             #: g per micro-g
STANDARD_GRAVITY_M_S2 = 9.80665       #: g_n, m/s^2 per g

#: output units a file may spell another way: the spelling a scale factor's unit uses
_OUTPUT_SPELLING = {"counts": "count", "lsb": "count", "LSB": "count", "m/s^2": "m/s2", "m s^-2": "m/s2"}


def scale_factor_unit(output_unit: str) -> str:
    """The unit of a scale factor K (g per output unit) for outputs in ``output_unit``: ``g/V``,
    ``g/mV``, ``g/count`` (for counts, LSB), ``g/(m/s2)`` (a compound unit in parentheses). One
    spelling everywhere, so that a fit of a raw recording and a fit of the bench CSV averaged from
    it carry the same unit (compare, fleet and history compare units as strings)."""
    u = _OUTPUT_SPELLING.get(str(output_unit).strip(), str(output_unit).strip())
    return f"g/({u})" if "/" in u else f"g/{u}"


def scale_output_unit(k_unit) -> Optional[str]:
    """The output unit of a scale factor's unit string: ``"g/V"`` -> ``"V"``, ``"g/(m/s2)"`` ->
    ``"m/s2"`` (a compound unit is written in parentheses, :func:`scale_factor_unit`; before the
    gates read it so, a fit-raw result in m/s2 had its K's band unchecked); None for another unit."""
    if not (isinstance(k_unit, str) and k_unit.strip().startswith("g/")):
        return None
    u = k_unit.strip()[2:]
    return u[1:-1] if u.startswith("(") and u.endswith(")") else u


def canonical_scale_unit(unit: str) -> str:
    """A scale factor's unit in :func:`scale_factor_unit`'s spelling: ``g/counts`` and ``g/count``,
    ``g/m/s2`` and ``g/(m/s2)`` are one unit (results written before 2026-11-30 spell them
    apart); any other unit unchanged."""
    out = scale_output_unit(unit)
    return str(unit).strip() if out is None else scale_factor_unit(out)


#: internal value = reporting value * TO_INTERNAL[unit]
TO_INTERNAL = {
    "arcsec": ARCSEC,
    "arcsec/degC": ARCSEC,
    "arcsec/degC2": ARCSEC,
    "arcsec/degC3": ARCSEC,
    "deg": DEG,
    "g": 1.0,
    "g/V": 1.0,
    "ppm": PPM,
    "ppm/degC": PPM,
    "ppm/degC2": PPM,
    "ppm/degC3": PPM,
    "ug": UG,
    "ug/degC": UG,
    "ug/degC2": UG,
    "ug/degC3": UG,
    "ug/g2": UG,
    "ug/g3": UG,
    "arcsec/g2": ARCSEC,
    "ug/h": UG / 3600.0,
    "arcsec/h": ARCSEC / 3600.0,
    "min": 60.0,
    "h": 3600.0,
    "1": 1.0,
}
