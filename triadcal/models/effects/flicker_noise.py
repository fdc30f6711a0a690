"""Flicker (1/f) noise of the outputs: the covariance it puts between the visit means of a campaign.

A noise term, not a switchable mean effect (like :mod:`.position_error`). The physics is
:mod:`triadcal.models.noise_processes` (IEEE Std 952-1997 Annex C power law; Barnes 1990,
NIST TN 1318): an output ``y(t)`` with a flicker component of one-sided PSD ``S_y(f) = h / f``
has the Allan-variance floor ``B_f^2 = 2 ln 2 h`` (output unit^2; ``B_f = 0.664 B``, ``B`` the
bias instability). Its visit means ``ybar_i`` (window of length ``tau_i`` centred on ``t_i``)
are correlated: means far apart in time differ more than adjacent ones.

**Equation.** Flicker has no finite variance (its power diverges at f -> 0), but every
difference of means has one: with the structure function

    D_ij = E[(ybar_i - ybar_j)^2] = B_f^2 d_ij

(:func:`triadcal.models.noise_processes.mean_difference_variance` with ``Q = R = 0``; for equal
windows ``r tau`` apart ``d_ij = 2 B2(r)``, Barnes' bias function), any contrast ``c`` with
``sum c_i = 0`` has ``Var(c' ybar) = -1/2 c' D c`` (the variogram identity of an intrinsic
random function, Matheron 1973). Every fit estimates a constant bias per output, which absorbs
the campaign's mean level, so what the data see is the deviation of each visit mean from the
campaign mean, ``e = P ybar`` with ``P = I - 1 1'/N``. Its covariance is well defined:

    Sigma_f = B_f^2 C,    C = -1/2 P d P                     (output unit^2, N x N)

``C`` is positive semi-definite with ``C 1 = 0``; its diagonal is ``(N-1)/N`` times
:func:`~triadcal.models.noise_processes.visit_mean_variance` per unit ``B_f^2``. The full
covariance of one output's visit means in a fit is ``diag(sigma_i^2) + B_f^2 C`` (white noise
plus flicker); the outputs' flicker is independent between axes (three accelerometers).
The bias a fit then reports is the campaign mean of the bias: the instability between
campaigns is not in its u (that is what ``compare`` measures).
"""

from __future__ import annotations

import numpy as np

from ..noise_processes import LN2, flicker_noise as _flicker_stream, mean_difference_variance

name = "flicker_noise"
unit = "output unit"
description = ("flicker (1/f) noise / bias instability of each output: correlated visit means, Allan floor "
               "B_f (output unit) per axis")
#: a realistic quartz-accelerometer floor: B_f = 2 ug (0.664 x a 3 ug bias instability), as a
#: fraction of g; multiply by the output's scale (V/g) for output units
TYPICAL_BF_G = 2e-6


def structure_matrix(time_s, tau_s) -> np.ndarray:
    """``d_ij = E[(ybar_i - ybar_j)^2] / B_f^2`` (dimensionless, N x N) of the visit means with
    centres ``time_s`` and windows ``tau_s`` (s; scalar or per visit), for pure flicker. The last
    few are kept (the diagnosis and the fit ask for one campaign's matrix several times)."""
    t = np.ascontiguousarray(np.asarray(time_s, float).reshape(-1))
    tau = np.ascontiguousarray(np.broadcast_to(np.asarray(tau_s, float), t.shape))
    key = (t.tobytes(), tau.tobytes())
    if key in _CACHE:
        return _CACHE[key].copy()
    d = mean_difference_variance(t[:, None], tau[:, None], t[None, :], tau[None, :], 0.0, 1.0, 0.0)
    np.fill_diagonal(d, 0.0)
    d = 0.5 * (d + d.T)
    if len(_CACHE) >= 4:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = d
    return d.copy()


_CACHE: dict = {}


def centred_covariance(time_s, tau_s, Bf2: float = 1.0) -> np.ndarray:
    """``Sigma_f = B_f^2 C``, ``C = -1/2 P d P``: covariance (output unit^2, N x N) of the
    deviations of the visit means from the campaign mean due to flicker of floor ``Bf2``
    (module docstring). Exact for any windows, overlapping or not."""
    d = structure_matrix(time_s, tau_s)
    n = d.shape[0]
    P = np.eye(n) - 1.0 / n
    C = -0.5 * P @ d @ P
    return Bf2 * 0.5 * (C + C.T)


def draw_visit_errors(time_s, tau_s, Bf2: float, rng: np.random.Generator, n_outputs: int = 3) -> np.ndarray:
    """Visit-mean errors (N, n_outputs) of independent flicker on each output, drawn from
    ``N(0, B_f^2 C)`` (their campaign mean is 0: the level is the bias's); zeros when ``Bf2 <= 0``."""
    t = np.asarray(time_s, float).reshape(-1)
    if Bf2 <= 0 or t.size < 2:
        return np.zeros((t.size, n_outputs))
    w, V = np.linalg.eigh(centred_covariance(t, tau_s, Bf2))
    root = V * np.sqrt(np.clip(w, 0.0, None))
    return root @ rng.standard_normal((t.size, n_outputs))


def stream(n: int, rate_hz: float, Bf2: float, rng: np.random.Generator) -> np.ndarray:
    """A sampled flicker stream of floor ``Bf2`` (the FFT generator of noise_processes)."""
    return _flicker_stream(n, rate_hz, Bf2, rng)


def psd_coefficient(Bf2: float) -> float:
    """``h = B_f^2 / (2 ln 2)`` of ``S_y(f) = h / f`` (output unit^2)."""
    return Bf2 / (2.0 * LN2)
