"""Quantisation of a digital unit's output: the expected error of a visit mean.

A digital unit reports each sample rounded to its LSB ``q`` (mid-tread rounding,
``Q(y) = q round(y / q)``). A visit mean of N such samples of a signal ``x`` with Gaussian
sample noise of SD ``sigma`` has the expectation (Widrow & Kollar, *Quantization Noise*,
Cambridge University Press 2008, ch. 4-5: the characteristic-function series; the noise's
characteristic function multiplies the k-th Fourier mode of the sawtooth ``Q(x) - x`` by
``exp(-2 pi^2 k^2 sigma^2 / q^2)``):

    E[Q(x + n)] - x = sum_{k>=1} (q / (pi k)) (-1)^k exp(-2 pi^2 k^2 sigma^2 / q^2) sin(2 pi k x / q)

a periodic error in ``x`` of period ``q``: up to ``q/2`` (the sawtooth ``Q(x) - x``) when
sigma << q, damped to ``(q/pi) exp(-2 pi^2 sigma^2/q^2)`` when sigma is comparable to q, and
below 1e-8 q once sigma > 1.5 q. The sign and the form are checked against a brute-force numpy
average of rounded Gaussian samples in ``tests/test_quantisation.py``. The series is truncated
where its terms fall below ``1e-12 q`` (:func:`n_terms`). When that needs more than
:data:`LATTICE_ABOVE` terms (sigma below about q/5) the same expectation is evaluated exactly as the
sum over the codes, ``sum_m q m [Phi((q m + q/2 - x)/sigma) - Phi((q m - q/2 - x)/sigma)] - x``
(codes within 10 sigma), which then needs a few terms where the series needs hundreds.

Units: ``x``, ``q`` and ``sigma`` in the output unit of the campaign (V, counts, ...); one LSB
common to the three outputs (one converter), ``quantisation_lsb`` in the result.

**Why this is not an :class:`~.base.Effect` of ``EFFECTS``** (the brief's first option):

- it acts on the output itself, after eq. 1 (``W -> W + e(W)``), where the Effect interface has
  no hook (its last one, ``transfer``, acts on the acceleration before K and S);
- it needs the per-sample noise sigma of every visit and axis, which is not a covariate of the
  model (:class:`~triadcal.models.model.Covariates`), but a property of the data (``sd_*``) or of
  the simulator's noise (``Q`` and the sample rate);
- its one parameter has no least-squares column: the error is ``O(exp(-2 pi^2 sigma^2/q^2))``,
  so its derivative at ``q = 0`` vanishes (and the expression is 0/0 there in CasADi), and every
  effect of ``EFFECTS`` enters the diagnosis's full problem as columns of the Jacobian at 0.

So ``quantisation`` is a named term outside ``EFFECTS`` (:data:`NAME`), like the noise effects:
the simulator adds :func:`expected_error` to the visit means (``NoiseModel.quantisation_lsb``),
the joint fit applies it as an output map of the compiled problem
(:mod:`triadcal.estimation.quantisation_form`, ``fit --effects ...,quantisation``), the posterior
adds it to the outputs of its compiled log-likelihood with q and sigma held at the fit's values
(``sample --effects ...,quantisation``), and the diagnosis profiles q
(:mod:`triadcal.judgement.diagnose.quantisation`). The expression is written once,
:func:`error_expression`, on numpy arrays (:func:`expected_error`, :func:`expected_error_slope`) and
on CasADi symbols alike.
"""

from __future__ import annotations

import math

import numpy as np

NAME = "quantisation"
UNIT = "output unit"
description = ("quantisation of a digital output to an LSB q: the expected error of a visit mean, "
               "periodic in the output with period q, damped by the sample noise")
#: relative size of the last term kept: terms below TOL * q are dropped
TOL = 1e-12
#: most terms of the series evaluated (sigma < q / 1000)
MAX_TERMS = 1000


def n_terms(q: float, sigma) -> int:
    """Terms needed so that the dropped ones are below ``TOL q``: the smallest K with
    ``exp(-2 pi^2 K^2 s^2 / q^2) < TOL`` for the smallest ``s`` of ``sigma`` (the term is that
    over ``pi K``, so the bound holds), at most MAX_TERMS."""
    s = float(np.min(np.asarray(sigma, float)))
    if q <= 0:
        return 0
    a = 2.0 * math.pi ** 2 * (s / q) ** 2
    if a <= 0:
        return MAX_TERMS
    # exp(-a K^2) < TOL already bounds the term (the 1/(pi K) only helps): the smallest such K
    return int(min(MAX_TERMS, max(1, math.ceil(math.sqrt(-math.log(TOL) / a)))))


#: above this many series terms the expectation is summed over the codes instead (sigma < ~q/5)
LATTICE_ABOVE = 8


def form_of(q: float, sigma) -> tuple[str, int]:
    """How :func:`error_expression` evaluates the expectation at the LSB ``q`` for per-sample SDs
    ``sigma`` (numbers; all of them at once, as one expression serves every visit and output):
    ``("series", K)`` with the K terms of :func:`n_terms` for the smallest sigma, or, when that is
    more than :data:`LATTICE_ABOVE` (sigma below about q/5), ``("lattice", h)``: the codes within
    ``h = ceil(10 max(sigma) / q) + 1`` of the nearest one; ``("none", 0)`` when ``q <= 0``."""
    q = float(q)
    if q <= 0:
        return "none", 0
    K = n_terms(q, sigma)
    if K > LATTICE_ABOVE:
        return "lattice", int(math.ceil(10.0 * float(np.max(np.asarray(sigma, float))) / q)) + 1
    return "series", K


def error_expression(x, q, sigma, form: str, count: int, derivative: bool = False):
    """``E[Q(x + n)] - x`` (or its ``d/dx`` with ``derivative``), elementwise, on numpy arrays or on
    CasADi symbols alike: the one expression behind :func:`expected_error` (numpy) and the posterior's
    likelihood (``sample --effects ...,quantisation``, CasADi). ``x`` the output, ``q`` the LSB,
    ``sigma`` the per-sample SD (same shape as ``x`` or broadcastable; any of them may be symbolic);
    ``form, count`` from :func:`form_of` at the numeric q and sigma (the expression's structure must
    be fixed before it is built). With ``r = x - q floor(x/q + 1/2)`` (x about its nearest code: the
    phase stays exact for |x| >> q, and ``dr/dx = 1``):

    series (sigma >~ q/5), the characteristic-function series of the module docstring truncated at K::

        e = sum_{k=1..K} (q / (pi k)) (-1)^k exp(-2 pi^2 k^2 sigma^2 / q^2) sin(2 pi k r / q)
        de/dx = sum_{k=1..K} 2 (-1)^k exp(-2 pi^2 k^2 sigma^2 / q^2) cos(2 pi k r / q)

    lattice (sigma <~ q/5), the sum over the codes ``q j`` (relative to the nearest), ``|j| <= h``,
    ``Phi(b) - Phi(a) = (erf(b/sqrt 2) - erf(a/sqrt 2)) / 2``::

        e = sum_j q j [Phi((q j + q/2 - r)/sigma) - Phi((q j - q/2 - r)/sigma)] - r
        de/dx = sum_j q j [phi((q j - q/2 - r)/sigma) - phi((q j + q/2 - r)/sigma)] / sigma - 1

    (sigma = 0 is taken as 1e-300: the sawtooth ``q round(x/q) - x``)."""
    from ..ops import is_symbolic

    if is_symbolic(x, q, sigma):
        import casadi as ca

        floor, sin, cos, exp, erf = ca.floor, ca.sin, ca.cos, ca.exp, ca.erf
        s = ca.fmax(sigma, 1e-300)
    else:
        from scipy.special import erf

        floor, sin, cos, exp = np.floor, np.sin, np.cos, np.exp
        x = np.asarray(x, float)
        s = np.broadcast_to(np.asarray(sigma, float), x.shape)
        s = np.where(s > 0, s, 1e-300)
    if form == "none":
        return 0.0 * x
    r = x - q * floor(x / q + 0.5)
    out = 0.0
    if form == "series":
        # sin/cos(k theta) by the angle-addition recurrence and exp(c k^2) by products (one sin, one
        # cos and one exp per element, not K of each: the posterior evaluates this per walker and visit)
        theta = (2.0 * math.pi / q) * r
        s1, c1 = sin(theta), cos(theta)
        sk, ck = s1, c1
        E = exp(-2.0 * (math.pi * s / q) ** 2)
        E2 = E * E
        damp, ratio = E, E * E2                  # exp(c k^2) at k = 1; exp(c (2k + 1)) to the next
        for k in range(1, int(count) + 1):
            if k > 1:
                sk, ck = sk * c1 + ck * s1, ck * c1 - sk * s1
                damp, ratio = damp * ratio, ratio * E2
            sign = -1.0 if k % 2 else 1.0
            out = out + (2.0 * sign * damp * ck if derivative else (sign * q / (math.pi * k)) * damp * sk)
        return out
    if form != "lattice":
        raise ValueError(f"unknown form {form!r}: series, lattice or none")
    h = int(count)
    # the code boundaries b_m = (q m - r)/sigma at m = j -+ 1/2 are shared by neighbouring codes j
    b = [(q * (j + 0.5) - r) / s for j in range(-h - 1, h + 1)]           # b[i] is the upper one of j = i - h - 1
    if derivative:
        f = [exp(-0.5 * v * v) for v in b]
        for j in range(-h, h + 1):
            if j:
                out = out + (q * j) * (f[j + h] - f[j + h + 1]) / (math.sqrt(2.0 * math.pi) * s)
        return out - 1.0
    f = [erf(v / math.sqrt(2.0)) for v in b]
    for j in range(-h, h + 1):
        if j:                                    # the nearest code contributes q j = 0
            out = out + (0.5 * q * j) * (f[j + h + 1] - f[j + h])
    return out - r


def _series(x, q: float, sigma, derivative: bool):
    x = np.asarray(x, float)
    s = np.broadcast_to(np.asarray(sigma, float), x.shape)
    if q <= 0 or x.size == 0:
        return np.zeros_like(x)
    form, count = form_of(q, s)
    return np.asarray(error_expression(x, q, s, form, count, derivative), float).reshape(x.shape)


def expected_error(x, q: float, sigma):
    """``E[Q(x + n)] - x`` for mid-tread rounding to ``q`` of ``x`` plus N(0, sigma^2) noise
    (the equation of the module docstring; arrays broadcast, output unit)."""
    return _series(x, float(q), sigma, derivative=False)


def expected_error_slope(x, q: float, sigma):
    """``d/dx`` of :func:`expected_error` (dimensionless): ``sum 2 (-1)^k exp(...) cos(2 pi k x/q)``."""
    return _series(x, float(q), sigma, derivative=True)


def rounded_variance(x, q: float, sigma):
    """Variance of one rounded sample ``Q(x + n)``, n ~ N(0, sigma^2), by the sum over the codes
    ``q m`` with probabilities ``Phi((q m + q/2 - x)/sigma) - Phi((q m - q/2 - x)/sigma)`` (exact up to
    codes beyond 10 sigma; output unit squared). Sheppard's ``sigma^2 + q^2/12`` is its mean over x
    when sigma is comparable to q; at a given x it differs by a term periodic in x."""
    from scipy.special import ndtr

    x = np.asarray(x, float)
    s = np.broadcast_to(np.asarray(sigma, float), x.shape).reshape(-1, 1)
    if q <= 0:
        return np.broadcast_to(s.reshape(x.shape) ** 2, x.shape).copy()
    xf = x.reshape(-1, 1)
    half = int(math.ceil(10.0 * float(np.max(s)) / q)) + 1
    base = np.round(xf / q)
    m = base + np.arange(-half, half + 1)[None, :]                 # codes around each x
    ss = np.where(s > 0, s, 1e-300)
    p = ndtr((q * m + q / 2 - xf) / ss) - ndtr((q * m - q / 2 - xf) / ss)
    d = q * (m - base)                                              # codes relative to the nearest: precision
    mean = np.sum(p * d, axis=1, keepdims=True)
    return (np.sum(p * (d - mean) ** 2, axis=1)).reshape(x.shape)


def sigma_from_sample_sd(sd, x, q: float):
    """The per-sample SD before rounding from the SDs of the rounded samples of several visits at
    their visit means ``x`` (arrays (n,) for one output, or (n, k) for k outputs at once, giving k
    values): the sigma whose :func:`rounded_variance` at the signals (``x - e(x)`` solved by
    fixed-point steps: the mean is pulled toward the nearest code) averaged over the visits equals
    the mean of ``sd^2`` (bisection to 1e-4; 0 when even sigma = 0 leaves more than that mean;
    Sheppard's ``sd^2 - q^2/12`` where sd^2 > 1.5 q^2, the two then agreeing to 3e-9 q^2). At most
    ~200 visits are used (every k-th: the mean variance, not each visit's)."""
    x = np.asarray(x, float)
    one = x.ndim == 1
    x = x.reshape(x.shape[0], -1)
    step = max(1, x.shape[0] // 200)
    x = x[::step]
    sd2 = np.mean(np.asarray(sd, float).reshape(-1, x.shape[1])[::step] ** 2, axis=0)
    out = np.sqrt(np.clip(sd2 - q * q / 12.0, 0.0, None)) if q > 0 else np.sqrt(sd2)
    todo = (sd2 <= 1.5 * q * q) if q > 0 else np.zeros(sd2.shape, bool)
    if np.any(todo):
        xs, target = x[:, todo], sd2[todo]

        def f(sig):
            xt = xs
            for _ in range(3):
                xt = xs - expected_error(xt, q, sig[None, :])
            return np.mean(rounded_variance(xt, q, sig[None, :]), axis=0) - target

        lo, hi = np.zeros(target.shape), np.sqrt(target) + q
        zero = f(lo) >= 0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            below = f(mid) < 0
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
            if np.all(hi - lo < 1e-4 * hi):
                break
        out[todo] = np.where(zero, 0.0, 0.5 * (lo + hi))
    return float(out[0]) if one else out


def phase_rms_error(q: float, sigma):
    """RMS over the signal's phase of the expected error of a mean of rounded samples, :func:`expected_error`
    averaged (squared) over ``x`` uniform on one LSB: by Parseval on the series of the module docstring,

        u_q = (q / (pi sqrt 2)) sqrt( sum_{k>=1} exp(-4 pi^2 k^2 sigma^2 / q^2) / k^2 )

    ``q / sqrt(12)`` at ``sigma = 0`` (sum 1/k^2 = pi^2/6: the resolution of a digital indication,
    JCGM 100:2008 F.2.2.1, a rectangular distribution of half-width q/2), damped by the noise: 0.04 q at
    sigma = 0.3 q, below 1e-8 q once sigma > q. It is the standard uncertainty that rounding leaves
    in a long mean whose signal sits anywhere between two codes (static poses, many LSB apart): the
    error is fixed for that signal and averages away only over poses, never over more samples.
    ``sigma`` (per-sample SD before rounding) may be an array; output unit, 0 for ``q <= 0``. The
    series is summed to :data:`MAX_TERMS` terms, the rest bounded by ``exp(-a K^2) / (K + 1/2)``."""
    s = np.asarray(sigma, float)
    if q <= 0:
        return np.zeros_like(s) if s.ndim else 0.0
    a = 4.0 * math.pi ** 2 * (np.clip(s, 0.0, None) / q) ** 2
    k = np.arange(1, MAX_TERMS + 1, dtype=float)
    terms = np.exp(-np.multiply.outer(a, k * k)) / (k * k)
    # the terms beyond MAX_TERMS: at most exp(-a K^2) sum_{k>K} 1/k^2, about exp(-a K^2) / (K + 1/2)
    tail = np.exp(-a * MAX_TERMS ** 2) / (MAX_TERMS + 0.5)
    out = q / (math.pi * math.sqrt(2.0)) * np.sqrt(np.sum(terms, axis=-1) + tail)
    return float(out) if np.ndim(out) == 0 else out


def sigma_from_phase_averaged_variance(v, q: float):
    """The per-sample SD ``sigma`` before rounding from ``v``, the variance of rounded samples about their
    means pooled over many signals whose phase on the LSB is uniform (static poses many LSB apart): the
    root of

        v = sigma^2 + q^2/12 - u_q(sigma)^2

    (``E[(Q(x+n) - x)^2] = sigma^2 + q^2/12`` over a uniform phase, the rounding error then uniform and
    independent of the noise; less the phase-averaged square of the mean's error, :func:`phase_rms_error`).
    The right side rises from 0 at ``sigma = 0`` (every signal one code) monotonically (its derivative
    ``2 sigma - 2 u_q u_q'`` with ``u_q' < 0``), so the root is unique: bisection to 1e-10 of ``sqrt(v) + q``.
    It stays defined where :func:`sigma_from_sample_sd` is not (sigma << q: a constant interval's mean does
    not say where between two codes its signal lies, so the variance at each visit's own phase says nothing
    of sigma). 0 for ``v <= 0``; Sheppard's ``sqrt(v - q^2/12)`` for ``q <= 0`` or ``v > 1.5 q^2``."""
    v = float(v)
    if not math.isfinite(v):
        return float("nan")
    if v <= 0:
        return 0.0
    if q <= 0:
        return math.sqrt(v)
    if v > 1.5 * q * q:
        return math.sqrt(v - q * q / 12.0)
    lo, hi = 0.0, math.sqrt(v) + q
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if mid * mid + q * q / 12.0 - float(phase_rms_error(q, mid)) ** 2 < v:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-10 * (math.sqrt(v) + q):
            break
    return 0.5 * (lo + hi)


def sample_sigma(sd, q: float):
    """Per-sample SD of the noise before rounding from the SD of rounded samples: Sheppard's
    correction ``sigma^2 = sd^2 - q^2/12`` (exact up to terms of the order of the error above),
    clipped at 0 (sigma << q: the samples are all one code)."""
    sd = np.asarray(sd, float)
    return np.sqrt(np.clip(sd * sd - q * q / 12.0, 0.0, None))


def resolution_lsb(values, n_samples=None, n_differences: int = 30):
    """The LSB implied by the data's own resolution, or None: visit means of N samples rounded to
    q are multiples of q/N, so ``N w`` are multiples of q. q is found as the approximate greatest
    common divisor of the ``n_differences`` smallest gaps between the sorted ``N |w|`` (small
    multiples of q, so Euclid on floats stays accurate; remainders below 1e-9 of the largest value
    count as 0), refined by least squares over every value, and accepted only when every
    ``N w / q`` is within 1e-6 of an integer and q is above 1e-9 of the largest |N w| (not the
    float resolution of the file)."""
    v = np.asarray(values, float)
    if n_samples is not None:
        v = v * np.asarray(n_samples, float).reshape(-1, *([1] * (v.ndim - 1)))
    v = np.sort(np.abs(v[np.isfinite(v)].ravel()))
    if v.size < 3 or v[-1] <= 0:
        return None
    big = float(v[-1])
    tol = 1e-9 * big
    d = np.diff(v)
    d = np.sort(d[d > tol])[:n_differences]
    if d.size < 2:
        return None

    def gcd(a, b):
        for _ in range(200):
            if b <= tol:
                return a
            a, b = b, math.fmod(a, b)
        return None

    g = float(d[0])
    for i, val in enumerate(d[1:], 2):
        g = gcd(max(g, val), min(g, val))
        if g is None or g <= tol:
            return None
        m = np.round(d[:i] / g)
        g = float(np.sum(d[:i] * m) / np.sum(m * m))
    for _ in range(2):
        m = np.round(v / g)
        g = float(np.sum(v * m) / np.sum(m * m))
    if np.max(np.abs(v / g - np.round(v / g))) > 1e-6:
        return None
    return g
