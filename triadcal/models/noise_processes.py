"""Power-law output noise: Allan and Hadamard variances, scatter of visit means, a flicker (1/f) generator.

Pure functions (no I/O) shared by the capture's noise estimate (:mod:`triadcal.hardware.noise`),
the emulator (:class:`triadcal.hardware.emulator_physics.UnitPhysics`) and the tests. The noise of a
raw output ``y(t)`` is the IEEE Std 952-1997 (Annex C) power-law model, one term per process:

* white noise of intensity ``Q`` (output unit^2 s; velocity random walk): one-sided PSD
  ``S_y(f) = 2 Q``, Allan variance ``Q / tau`` — the Q of the seed paper's eq. 4;
* flicker (1/f, bias instability): ``S_y(f) = h / f``, Allan variance the constant
  ``B_f^2 = 2 ln 2 h`` (IEEE 952: ``B_f = 0.664 B``, ``B`` the bias instability);
* random walk of the bias (rate random walk): ``y`` a Brownian motion with
  ``E[(y(t+s) - y(t))^2] = R s``, Allan variance ``R tau / 3``.

The fit needs the scatter of a visit's *mean* over its window ``tau`` about the model. For
white noise that is ``Q / tau = sd^2 / n``. With flicker or a random walk the means of
windows far apart in time differ more than adjacent ones: for two tau-means whose starts
are ``r tau`` apart (r >= 1) the mean squared difference is ``2 sigma_A^2(tau) B2(r)`` with
Barnes' bias function ``B2`` (NIST TN 1318, 1990): 1 for white noise,
``[(r+1)^2 ln(r+1) + (r-1)^2 ln(r-1) - 2 r^2 ln r] / (4 ln 2)`` for flicker (about
``(2 ln r + 3) / (4 ln 2)`` for large r: 6.7 at r = 2500, two visits 21 h apart with
tau = 30 s) and ``(3 r - 1) / 2`` for the random walk. :func:`visit_mean_variance` turns
these into the variance of each visit's mean about the campaign's own mean.
"""

from __future__ import annotations

import math

import numpy as np

LN2 = math.log(2.0)


def allan_variance_power_law(tau_s, Q, Bf2=0.0, R=0.0):
    """IEEE Std 952-1997 Annex C power-law Allan variance ``sigma^2(tau) = Q/tau + B_f^2 + R tau/3``.

    ``Q`` white-noise intensity (unit^2 s), ``Bf2`` the flicker floor ``(0.664 B)^2`` (unit^2),
    ``R`` the rate-random-walk intensity (unit^2 / s); ``tau_s`` in seconds (array or scalar)."""
    tau = np.asarray(tau_s, float)
    return Q / tau + Bf2 + R * tau / 3.0


#: the Hadamard variance of flicker noise against its Allan variance: ``2 - (3/4) log2 3``
#: (:func:`hadamard_variance_power_law`)
HADAMARD_FLICKER = 2.0 - 0.75 * math.log2(3.0)
#: the Hadamard variance of a random walk of the bias against its Allan variance
HADAMARD_RANDOM_WALK = 0.5


def hadamard_variance_power_law(tau_s, Q, Bf2=0.0, R=0.0):
    """The overlapping Hadamard variance ``(1/6) E[(ybar_3 - 2 ybar_2 + ybar_1)^2]`` (three adjacent
    tau-means) of the power-law terms of :func:`allan_variance_power_law`, in their parameters:
    ``Q/tau + k_f B_f^2 + k_R R tau/3``.

    From the spectral forms (Riley, NIST SP 1065, 2008, sec. 5.2.8): Allan
    ``2 int S(f) sin^4(pi f tau) / (pi f tau)^2 df``, Hadamard ``(8/3) int S(f) sin^6(pi f tau) /
    (pi f tau)^2 df``. White (``S = 2Q``): both ``Q/tau``. Flicker (``S = h/f``): Allan ``2 ln 2 h``,
    Hadamard ``(4 ln 2 - (3/2) ln 3) h`` (``int sin^6 x / x^3 dx = (3/2) ln 2 - (9/16) ln 3`` by
    ``sin^6 = (10 - 15 cos 2x + 6 cos 4x - cos 6x)/32``), so ``k_f = 2 - (3/4) log2 3 = 0.811``.
    Random walk (``S = h/f^2``): Allan ``(2 pi^2/3) h tau``, Hadamard ``(pi^2/3) h tau``, ``k_R = 1/2``.

    A linear drift of ``y`` does not enter it (the second difference of equal-length means of a
    line is zero), where the Allan variance grows by ``D^2 tau^2 / 2``: the outputs of a window on a
    temperature ramp drift with the unit's temperature, deterministically (the fit's model holds it)."""
    tau = np.asarray(tau_s, float)
    return Q / tau + HADAMARD_FLICKER * Bf2 + HADAMARD_RANDOM_WALK * R * tau / 3.0


def _generalized_covariance(s, Q, Bf2, R):
    """Generalised covariance K(s) of the integrated output ``x(t) = int y`` for the three
    power-law processes (Matheron's intrinsic random functions): for any combination with
    ``sum c_m = sum c_m s_m = 0``, ``E[(sum c_m x(s_m))^2] = sum_mn c_m c_n K(s_m - s_n)``.

    white: ``K = -Q |s| / 2`` (x a Brownian motion); flicker: ``K = (k/2) s^2 ln|s|`` with
    ``k = B_f^2 / (2 ln 2)``; random walk: ``K = R |s|^3 / 12``. Each reproduces its Allan
    variance exactly (tests/test_visit_uncertainty.py checks the three against eq. above)."""
    a = np.abs(s)
    with np.errstate(divide="ignore", invalid="ignore"):
        slog = np.where(a > 0, a * a * np.log(np.where(a > 0, a, 1.0)), 0.0)
    return -0.5 * Q * a + 0.5 * (Bf2 / (2.0 * LN2)) * slog + R * a ** 3 / 12.0


def mean_difference_variance(t1_s, tau1_s, t2_s, tau2_s, Q, Bf2=0.0, R=0.0):
    """``E[(ybar_1 - ybar_2)^2]`` of the means of ``y`` over two windows (centres ``t1, t2``,
    lengths ``tau1, tau2``; arrays broadcast) under the power-law model.

    Each mean is ``(x(t + tau/2) - x(t - tau/2)) / tau``; the difference of two means is a
    combination of four values of ``x`` whose weights sum to zero and have zero first moment,
    so its variance follows from :func:`_generalized_covariance` for any windows, overlapping
    or not. For equal, non-overlapping windows it is ``2 sigma_A^2(tau) B2(r)`` (Barnes 1990):
    ``2 Q/tau`` for white noise, ``2 B_f^2`` for adjacent windows of flicker."""
    t1, w1, t2, w2 = np.broadcast_arrays(*(np.asarray(v, float) for v in (t1_s, tau1_s, t2_s, tau2_s)))
    pts = (t1 + w1 / 2, t1 - w1 / 2, t2 + w2 / 2, t2 - w2 / 2)
    cs = (1.0 / w1, -1.0 / w1, -1.0 / w2, 1.0 / w2)
    out = np.zeros(t1.shape)
    for pm, cm in zip(pts, cs):
        for pn, cn in zip(pts, cs):
            out = out + cm * cn * _generalized_covariance(pm - pn, Q, Bf2, R)
    return out


def visit_mean_variance(time_s, tau_s, Q, Bf2=0.0, R=0.0):
    """Variance of each visit's mean about the campaign's own mean (unit^2), per visit.

    With ``D_ij`` = :func:`mean_difference_variance` of visits i and j (centres ``time_s``,
    windows ``tau_s``) and ``N`` visits::

        u_i^2 = N/(N-1) * [ (1/N) sum_j D_ij  -  (1/(2 N^2)) sum_jk D_jk ]

    that is ``N/(N-1) E[(ybar_i - mean_j ybar_j)^2]``: the expected squared deviation of a
    visit's mean from the mean of all visits (the level a fit's bias absorbs), with the
    ``N/(N-1)`` of a sample variance, so that white noise gives exactly ``Q / tau`` (equal windows;
    with unequal ones ``(N-2)/(N-1) Q/tau_i + mean_j(Q/tau_j)/(N-1)``). For flicker
    it grows with the campaign's span as ``ln(span / tau)`` (Barnes' B2), which the Allan
    variance at tau alone (adjacent windows) does not see. One visit: ``sigma_A^2(tau)``."""
    t = np.asarray(time_s, float)
    tau = np.broadcast_to(np.asarray(tau_s, float), t.shape)
    n = len(t)
    if n < 2:
        return np.atleast_1d(allan_variance_power_law(tau, Q, Bf2, R)).astype(float)
    row = np.zeros(n)
    for i in range(n):                        # a row at a time: N^2 memory stays N
        d = mean_difference_variance(t[i], tau[i], t, tau, Q, Bf2, R)
        d[i] = 0.0
        row[i] = d.sum()
    total = row.sum()
    return n / (n - 1) * (row / n - total / (2.0 * n * n))


def flicker_noise(n: int, rate_hz: float, Bf2: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` samples at ``rate_hz`` of flicker (1/f) noise whose Allan variance is the floor ``Bf2``.

    Timmer & König (1995, A&A 300, 707) / Kasdin (1995, Proc. IEEE 83, 802): Gaussian Fourier
    coefficients with variance set by the one-sided PSD ``S(f) = h / f``, ``h = B_f^2 / (2 ln 2)``,
    transformed back with one inverse real FFT; the DC term is zero. With ``x = irfft(X)`` the
    bin ``f_k = k rate/n`` (0 < k < n/2) contributes ``4 s_k^2 / n^2`` to the variance, which must
    be ``S(f_k) rate / n``, so ``s_k^2 = S(f_k) rate n / 4`` (the Nyquist bin, real, gets twice
    that). The sequence is periodic with period ``n / rate``: it wraps without a jump, and has
    no power below ``rate / n``."""
    n = int(n)
    if n < 2 or Bf2 <= 0:
        return np.zeros(max(n, 0))
    h = Bf2 / (2.0 * LN2)
    f = np.fft.rfftfreq(n, d=1.0 / rate_hz)
    s2 = np.zeros(len(f))
    s2[1:] = h / f[1:] * rate_hz * n / 4.0
    X = (rng.normal(size=len(f)) + 1j * rng.normal(size=len(f))) * np.sqrt(s2)
    if n % 2 == 0:                             # the Nyquist coefficient is real
        X[-1] = rng.normal() * math.sqrt(2.0 * s2[-1])
    X[0] = 0.0
    return np.fft.irfft(X, n)
