"""White-noise intensity Q and bias instability from raw samples (Allan deviation).

For white output noise of intensity Q (V^2 s) the Allan variance is
``sigma^2(tau) = Q / tau`` — the same Q as in eq. 4 of the seed paper, where the mean
over an averaging time tau has variance Q / tau. The overlapping Allan deviation
(allantools) of each stationary recording window (one per visit) is pooled over the
windows, weighted by the number of terms at each tau; Q is the weighted mean of
``sigma^2(tau) * tau`` over the shortest averaging times (m = 1, 2, 4 samples), where
white noise dominates; the bias instability is the floor of the deviation divided by
0.664 (IEEE Std 952), an upper bound when the curve is still falling at the longest tau.
"""

from __future__ import annotations

from ..errors import InputError

from dataclasses import dataclass, field
from typing import Sequence

import allantools
import numpy as np


@dataclass
class NoiseEstimate:
    """Q per axis (output unit^2 s), bias instability per axis (output unit), the pooled
    Allan deviation curve, and whether the floor was reached (else an upper bound)."""

    Q_V2s: tuple
    bias_instability_V: tuple
    floor_reached: tuple
    taus_s: np.ndarray
    adev: np.ndarray
    n_windows: int
    n_samples: int
    rate_hz: float
    details: dict = field(default_factory=dict)

    @property
    def Q_mean_V2s(self) -> float:
        return float(np.mean(self.Q_V2s))

    def metadata(self) -> dict:
        """``key = value`` lines for the bench CSV header."""
        md = {"Q_V2s": f"{self.Q_mean_V2s:.6g}"}
        for i, a in enumerate("xyz"):
            md[f"Q_{a}_V2s"] = f"{self.Q_V2s[i]:.6g}"
            md[f"bias_instability_{a}_V"] = (f"{self.bias_instability_V[i]:.6g}"
                                             + ("" if self.floor_reached[i] else " (upper bound)"))
        md["noise_method"] = (f"overlapping Allan deviation (allantools) over {self.n_windows} recording "
                              f"windows, {self.n_samples} samples at {self.rate_hz:.6g} Hz")
        return md


def allan_noise(windows: Sequence[np.ndarray], rate_hz: float) -> NoiseEstimate:
    """Pool the overlapping Allan deviation of stationary windows (each (n_i, 3), output unit)."""
    windows = [np.asarray(w, float) for w in windows if len(w) >= 8]
    if not windows:
        raise InputError("no recording window with at least 8 samples: cannot estimate the noise")
    shortest = min(len(w) for w in windows)
    ms = 2 ** np.arange(0, int(np.log2(max(shortest // 4, 1))) + 1)
    taus = ms / rate_hz
    avar = np.zeros((3, len(ms)))
    weight = np.zeros((3, len(ms)))
    for w in windows:
        for i in range(3):
            t_used, dev, _, ns = allantools.oadev(w[:, i], rate=rate_hz, data_type="freq", taus=taus)
            idx = np.searchsorted(taus, t_used)
            ok = (idx < len(taus))
            idx = idx[ok]
            avar[i, idx] += np.asarray(ns)[ok] * np.asarray(dev)[ok] ** 2
            weight[i, idx] += np.asarray(ns)[ok]
    good = weight.min(axis=0) > 0
    avar, weight, taus = avar[:, good] / weight[:, good], weight[:, good], taus[good]
    adev = np.sqrt(avar)
    short = taus <= 4.0 / rate_hz
    Q = tuple(float(np.sum(weight[i, short] * avar[i, short] * taus[short]) / np.sum(weight[i, short]))
              for i in range(3))
    k_min = np.argmin(adev, axis=1)
    bi = tuple(float(adev[i, k_min[i]] / 0.664) for i in range(3))
    floor = tuple(bool(k_min[i] < len(taus) - 1) for i in range(3))
    return NoiseEstimate(Q, bi, floor, taus, adev, len(windows), int(sum(len(w) for w in windows)),
                         float(rate_hz))
