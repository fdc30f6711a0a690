"""Unit conversions used at every boundary (reporting unit <-> internal unit).

Internal units of the physics: angles in radians, scale factors in g per output
unit, biases and accelerations in g, temperatures in degC, times in seconds.
Reporting units follow docs/results-json.md.
"""

import math

ARCSEC = math.pi / (180.0 * 3600.0)   #: radians per arcsecond
DEG = math.pi / 180.0                 #: radians per degree
ARCMIN = 60.0 * ARCSEC
PPM = 1e-6
UG = 1e-6                             #: g per micro-g
STANDARD_GRAVITY_M_S2 = 9.80665       #: g_n, m/s^2 per g

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
