"""Candidate extra terms of a raw calibration, as small functions of the calibrated acceleration.

Each term maps calibrated accelerations ``a`` (..., 3) in g and its parameters ``p`` to the
correction added to ``a`` (the term acts on the outputs, not on temperature); every term is
linear in its parameters and zero at ``p = 0``. ``triadcal.judgement.raw_diagnosis`` adds them
to a fit in turn and scores them on held-out static intervals (docs/diagnosis.md, "Diagnosing
real recordings").

- ``linear_correction``: the base of the diagnosis, what a refit of the calibration can still
  change and the gravity norm can see: a symmetric matrix ``D`` (3 scale and 3 shear terms;
  the antisymmetric part is a rotation, invisible to norms) and a bias ``b``: ``D a + b``.
- ``scale_nonlinearity`` (K2 of IEEE 1293): ``k2_i a_i^2`` on output ``i``, 1/g.
- ``cross_coupling`` (IEEE 1293's ``K_ij a_i a_j``, j != i): ``c_ij a_i a_j`` on output ``i``.
- ``g_dependent_misalignment``: the angle of sensing axis ``i`` toward ``j`` grows with the
  square of the gravity component along the axis, ``m_ij a_i^2`` (rad/g^2), so output ``i``
  gains ``m_ij a_i^2 a_j`` (even in ``a_i``: it does not change sign when the axis turns over,
  unlike a cross-coupling term).
- ``bias_tempco`` and ``bias_drift`` (``COVARIATE_TERMS``): ``p_i x`` on output ``i``, ``x`` the
  interval's temperature or time about their mean; a candidate when the temperature is given,
  and a rival of every candidate (a drifting bias), respectively.
- rivals (``RIVALS``, not candidates: a named candidate must beat them held out):
  ``scale_asymmetry`` ``e_i |a_i|``, ``scale_cubic`` ``K3_i a_i^3`` and ``odd_quadratic``
  ``q_i a_i |a_i|`` on output ``i``.
"""

from __future__ import annotations

import numpy as np

from ...models.effects.asymmetry import asymmetric
from ...models.effects.cross_axis import third_order

PAIRS = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))
_AX = "xyz"


def linear_correction(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``D a + b``; ``p = (d_xx, d_yy, d_zz, d_xy, d_xz, d_yz, b_x, b_y, b_z)``, D symmetric."""
    a = np.asarray(a, float)
    d = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]], float)
    return a @ d.T + np.asarray(p[6:9], float)


def scale_nonlinearity(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``k2_i a_i^2`` on each output; ``p = (K2_x, K2_y, K2_z)`` in 1/g."""
    a = np.asarray(a, float)
    return np.asarray(p, float) * a ** 2


def cross_coupling(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``c_ij a_i a_j`` on output ``i``; ``p`` in the order of :data:`PAIRS` (xy, xz, yx, yz, zx, zy), 1/g."""
    a = np.asarray(a, float)
    out = np.zeros_like(a)
    for k, (i, j) in enumerate(PAIRS):
        out[..., i] += p[k] * a[..., i] * a[..., j]
    return out


def g_dependent_misalignment(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Angle of axis ``i`` toward ``j`` equal to ``m_ij a_i^2``: ``m_ij a_i^2 a_j`` on output ``i``
    (``p`` in the order of :data:`PAIRS`, rad/g^2)."""
    a = np.asarray(a, float)
    out = np.zeros_like(a)
    for k, (i, j) in enumerate(PAIRS):
        out[..., i] += p[k] * a[..., i] ** 2 * a[..., j]
    return out


def scale_asymmetry(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``e_i |a_i|`` on each output (IEEE 1293's asymmetry, :func:`triadcal.models.effects.asymmetry.asymmetric`
    less ``a``); ``p = (e_x, e_y, e_z)``, dimensionless."""
    a = np.asarray(a, float)
    return asymmetric(a, np.asarray(p, float)) - a


def scale_cubic(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``K3_i a_i^3`` on each output (:func:`triadcal.models.effects.cross_axis.third_order` less ``a``);
    ``p = (K3_x, K3_y, K3_z)`` in 1/g^2."""
    a = np.asarray(a, float)
    return third_order(a, np.asarray(p, float)) - a


def odd_quadratic(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``q_i a_i |a_i|`` on each output: a second-order nonlinearity odd in the input (no model term
    of the vocabulary; a rival shape only, 1/g)."""
    a = np.asarray(a, float)
    return np.asarray(p, float) * a * np.abs(a)


#: name -> (function, parameter names, unit of the parameters)
TERMS = {
    "scale_nonlinearity": (scale_nonlinearity, tuple(f"K2_{c}" for c in _AX), "ug/g2"),
    "cross_coupling": (cross_coupling, tuple(f"Kc_{_AX[i]}{_AX[j]}" for i, j in PAIRS), "ug/g2"),
    "g_dependent_misalignment": (g_dependent_misalignment,
                                 tuple(f"Ca_{_AX[i]}{_AX[j]}_g2" for i, j in PAIRS), "arcsec/g2"),
}
def per_output(x: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``p_i x`` on each output ``i`` for a covariate ``x`` (n,) of the intervals: a bias linear in
    the temperature (``x = T - mean T``, degC) or in the time (``x = t - mean t``, h)."""
    return np.asarray(x, float)[:, None] * np.asarray(p, float)[None, :]


#: terms of a covariate of the intervals, not of the acceleration: name -> (covariate, parameter
#: names, unit); the covariate centred on its mean (the base's bias holds the mean)
COVARIATE_TERMS = {
    "bias_tempco": ("temperature_C", tuple(f"S_{c}_tempco" for c in _AX), "ug/degC"),
    "bias_drift": ("time_h", tuple(f"S_{c}_drift" for c in _AX), "ug/h"),
}

#: rivals of a named candidate (``raw_diagnosis``): terms outside the candidate list that a named
#: candidate must beat on held-out intervals; name -> (function, number of parameters)
RIVALS = {
    "scale_asymmetry": (scale_asymmetry, 3),
    "scale_cubic": (scale_cubic, 3),
    "odd_quadratic": (odd_quadratic, 3),
}
BASE_NAMES = ("D_xx", "D_yy", "D_zz", "D_xy", "D_xz", "D_yz", "b_x", "b_y", "b_z")

#: parameters of a term in g (or rad) -> the reporting unit of TERMS
UNIT_FACTOR = {"ug/g2": 1e6, "arcsec/g2": 180 / np.pi * 3600, "ug/degC": 1e6, "ug/h": 1e6}


def basis(term, a: np.ndarray, k: int) -> np.ndarray:
    """(n, 3, k): the correction of each of ``k`` unit parameters (every term is linear in ``p``)."""
    a = np.atleast_2d(np.asarray(a, float))
    return np.stack([term(a, np.eye(k)[j]) for j in range(k)], axis=-1)
