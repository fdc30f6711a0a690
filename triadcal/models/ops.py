"""Elementwise maths that works on numpy arrays and on CasADi symbols alike.

The physics in :mod:`triadcal.models` is written once against these functions, so
the simulator (numpy) and the estimators (CasADi SX/MX graphs) evaluate the very
same expressions.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

_CASADI_TYPES = (ca.SX, ca.MX, ca.DM)


def is_symbolic(*xs) -> bool:
    """True when any argument is a CasADi value."""
    return any(isinstance(x, _CASADI_TYPES) for x in xs)


def sin(x):
    return ca.sin(x) if is_symbolic(x) else np.sin(x)


def cos(x):
    return ca.cos(x) if is_symbolic(x) else np.cos(x)


def sqrt(x):
    return ca.sqrt(x) if is_symbolic(x) else np.sqrt(x)


def fabs(x):
    return ca.fabs(x) if is_symbolic(x) else np.abs(x)


def sign(x):
    return ca.sign(x) if is_symbolic(x) else np.sign(x)


def asin(x):
    return ca.asin(x) if is_symbolic(x) else np.arcsin(x)


def atan2(y, x):
    return ca.atan2(y, x) if is_symbolic(y, x) else np.arctan2(y, x)
