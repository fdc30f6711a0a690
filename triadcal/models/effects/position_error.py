"""Random bench positioning and wobble errors as an output variance (seed paper, eq. 4).

``var(W) = sigma_meas^2 + sigma_p^2 * sensitivity``: :func:`sensitivity_arcsec2` linearises
:meth:`~triadcal.models.model.Model.predict` in the per-visit bench errors (axis 1, axis 2,
wobble); :func:`output_variance` scales it; :func:`covariance_blocks` is the full 3 x 3
covariance of a visit's outputs (the diagnosis's refit uses it). A noise term, not a switchable mean effect.
Derivation/design: docs/model.md (Noise: positioning errors as an output variance).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..units import ARCSEC

name = "position_error"
unit = "arcsec"
description = ("random bench positioning and wobble errors per visit (r.m.s. angle, arcsec), "
               "an output variance from the kinematics' sensitivity (eq. 4's sigma_1, sigma_2)")
#: the paper's eq. 4 example: sigma_1 = 5", sigma_2 = 2"
TYPICAL_SIGMA_ARCSEC = 5.0

ERROR_TERMS = ("axis1_error", "axis2_error", "wobble")


def sensitivity_vectors(model, p, cov, gravity_g=1.0, step_arcsec: float = 10.0, which=None) -> np.ndarray:
    """``dW_a/de_k`` per visit: (n, 3 errors, 3 outputs), output unit per arcsec.

    The three per-visit bench errors ``e_k`` (axis 1, axis 2, wobble of axis 1) of
    ``ERROR_TERMS``, each derivative by a central difference of ``model.predict`` (``p``
    internal units, ``cov`` numpy covariates of n visits); ``which`` (3 booleans) leaves the
    others at 0 (not computed).
    """
    h = step_arcsec * ARCSEC
    n = len(np.atleast_1d(cov.axis1))
    out = np.zeros((n, len(ERROR_TERMS), 3))
    for k, term in enumerate(ERROR_TERMS):
        if which is not None and not which[k]:
            continue
        base = getattr(cov, term)
        plus = np.stack(model.predict(p, replace(cov, **{term: base + h}), gravity_g), axis=1)
        minus = np.stack(model.predict(p, replace(cov, **{term: base - h}), gravity_g), axis=1)
        out[:, k, :] = (plus - minus) / (2.0 * step_arcsec)
    return out


def sensitivity_arcsec2(model, p, cov, gravity_g=1.0, weights=(1.0, 1.0, 1.0),
                        step_arcsec: float = 10.0) -> np.ndarray:
    """Variance added to each output per arcsec^2 of positioning error, (output unit / arcsec)^2.

    ``sum_k w_k (dW/de_k)^2`` over the three per-visit bench errors (:func:`sensitivity_vectors`).
    ``weights`` are the relative variances of the three errors (1, 1, 1: one r.m.s.
    error for all; the paper's example 5", 5", 2" is ``(1, 1, 0.16)``). Shape (n, 3): the diagonal
    of :func:`covariance_blocks`.
    """
    w = np.asarray(weights, float)
    d = sensitivity_vectors(model, p, cov, gravity_g, step_arcsec, which=w != 0)
    return np.einsum("k,nka->na", w, d * d)


def covariance_blocks(model, p, cov, gravity_g=1.0, weights=(1.0, 1.0, 1.0),
                      step_arcsec: float = 10.0) -> np.ndarray:
    """Covariance of a visit's three outputs per arcsec^2 of positioning error, (n, 3, 3)::

        C_i = sum_k w_k d_ik d_ik^T,   d_ik = dW/de_k at visit i (:func:`sensitivity_vectors`)

    One bench error rotates gravity in the sensor frame and so moves the visit's outputs together:
    on an oblique pose (gravity shared by two or three axes) the off-diagonal terms are as large
    as the diagonal ones. Errors independent between visits (block-diagonal over visits).
    """
    w = np.asarray(weights, float)
    d = sensitivity_vectors(model, p, cov, gravity_g, step_arcsec, which=w != 0)
    return np.einsum("k,nka,nkb->nab", w, d, d)


def output_variance(model, p, cov, sigma_arcsec: float, gravity_g=1.0, weights=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Variance of each output (output unit^2) from positioning errors of r.m.s. ``sigma_arcsec``."""
    return sigma_arcsec ** 2 * sensitivity_arcsec2(model, p, cov, gravity_g, weights)


def bench_variance(model, p, cov, gravity_g, sigma_position_arcsec: float, sigma_wobble_arcsec: float) -> np.ndarray:
    """Variance of each mean output (output unit^2, shape (n, 3)) from a bench whose two axes
    each err by ``sigma_position_arcsec`` and whose axis 1 wobbles by ``sigma_wobble_arcsec``
    (r.m.s., independent per visit; eq. 4's sigma_1, sigma_2)::

        var_b(W) = sigma_1^2 [(dW/de_1)^2 + (dW/de_2)^2] + sigma_2^2 (dW/de_w)^2

    The diagonal of :func:`covariance_blocks`: on a pose with gravity along one sensing axis each
    error moves one output and the blocks are diagonal; on an oblique pose they are not, and the
    fit whitens with the full blocks (:func:`triadcal.estimation.whitening.bench_whitening`)."""
    s1, s2 = float(sigma_position_arcsec), float(sigma_wobble_arcsec)
    return sensitivity_arcsec2(model, p, cov, gravity_g, weights=(s1 * s1, s1 * s1, s2 * s2))
