"""The ``correlated`` generic family: residuals correlated in time that no candidate names.

The mean families of :mod:`.generic` see a smooth pattern of the mean; a noise that wanders --
1/f noise, a Gauss-Markov bias, a random walk -- has no smooth mean, and shows only as residuals
of visits close in time being alike. This family asks that, with no candidate's covariance: for
each correlation time ``tau`` of :data:`CORRELATION_FRACTIONS` (fractions of the campaign's span,
log-spaced from within a soak to the whole campaign) the Gauss-Markov kernel

    K_ij = exp(-|t_i - t_j| / tau) / (sigma_ia sigma_ja)     (per output a, block-diagonal)

(the covariance of a first-order Gauss-Markov process of any common variance, in the normalised
residuals' units; Gelb, *Applied Optimal Estimation*, 1974, table 3.1-1; a sum of them over
log-spaced ``tau`` is the classic approximation of 1/f noise, Keshner, Proc. IEEE 70, 212-218,
1982) gives the ratio

    rho = z' K z / z' z,

``z`` the standardised residuals (3n,), visit-major. ``rho`` does not depend on the residuals'
overall scale -- a noise level declared too small inflates the chi2, not this -- so the test is
the same with known and with estimated noise. Under the model ``z = P e``, ``e ~ N(0, I)``,
``P = I - Q Q'`` of rank ``nu``, and ``rho`` is independent of ``z' z`` (Pitman-Koopman), so its
first three moments are exact from ``t_k = tr((P K P)^k)`` (Durbin & Watson, Biometrika 37,
409-428, 1950; the cumulants of a Gaussian quadratic form are ``2^(k-1) (k-1)! t_k``):

    E rho^k = E (e' P K P e)^k / (nu (nu + 2) ... (nu + 2k - 2)).

The reference is Pearson's type III with those three moments (a shifted, scaled chi2: the ratio
of a kernel dominated by a few slow eigenvectors is skewed, where a normal reference would
reject far too often), one-sided: a covariance added to the noise makes ``rho`` large. Where
decisions are made (a three-moment p between :data:`REFINE_FAR` and :data:`REFINE_BELOW`) the
tail is recomputed from the exact spectrum of ``P K P`` on the residual space by the
Lugannani-Rice saddlepoint (:func:`_saddlepoint_logsf`), since three moments do not fix a tail
at 1e-4 well enough. The
family's p is Bonferroni's over the correlation times. The traces cost O(n^2 p) with ``K``
block-diagonal (``Q`` of rank p): ``tr((KP)^3) = tr K^3 - 3 tr(B'KB) + 3 tr(DC) - tr C^3`` with
``B = K Q``, ``C = Q'B``, ``D = B'B``.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from scipy import optimize, stats

#: correlation times of the family, as fractions of the campaign's span (first visit to last)
CORRELATION_FRACTIONS = (0.01, 0.1, 1.0)
#: the fewest visits the family is asked on (its three-moment reference is rough below)
CORRELATED_MIN_VISITS = 20


def _blocks_apply(K: list, X: np.ndarray) -> np.ndarray:
    """``A X`` for ``A`` block-diagonal over the outputs (rows visit-major: 3 i + a), blocks ``K[a]``."""
    n, m = K[0].shape[0], len(K)
    Xr = X.reshape(n, m, -1)
    out = np.empty_like(Xr)
    for a in range(m):
        out[:, a, :] = K[a] @ Xr[:, a, :]
    return out.reshape(X.shape)


def kernel_traces(K: list) -> tuple:
    """``(tr A, tr A^2, tr A^3)`` of ``A`` block-diagonal with the symmetric blocks ``K``: the
    kernel-only parts of :func:`ratio_test`'s traces (they depend on the campaign, not on the fit)."""
    return (sum(float(np.trace(k)) for k in K), sum(float(np.sum(k * k)) for k in K),
            sum(float(np.sum(k * (k @ k))) for k in K))


def ratio_test(z: np.ndarray, Q: np.ndarray, K: list, traces: Optional[tuple] = None) -> Optional[dict]:
    """One-sided test of ``rho = z' A z / z' z`` for ``A`` block-diagonal over the outputs with the
    symmetric blocks ``K`` (n x n each), ``Q`` the orthonormal basis of the fit's Jacobian (module
    docstring: exact three moments, Pearson type III reference). ``traces``: :func:`kernel_traces`
    of ``K`` when already known. None when degenerate."""
    z = np.asarray(z, float)
    N = z.size
    nu = N - Q.shape[1]
    if nu < 3 or not float(z @ z) > 0:
        return None
    B = _blocks_apply(K, Q)
    C = Q.T @ B
    D = B.T @ B
    KB = _blocks_apply(K, B)
    trA, trA2, trA3 = traces if traces is not None else kernel_traces(K)
    t1 = trA - float(np.trace(C))
    t2 = trA2 - 2.0 * float(np.sum(B * B)) + float(np.sum(C * C))
    t3 = trA3 - 3.0 * float(np.sum(B * KB)) + 3.0 * float(np.sum(D * C)) - float(np.trace(C @ C @ C))
    m1 = t1 / nu
    m2 = (2.0 * t2 + t1 * t1) / (nu * (nu + 2.0))
    m3 = (8.0 * t3 + 6.0 * t1 * t2 + t1 ** 3) / (nu * (nu + 2.0) * (nu + 4.0))
    var = m2 - m1 * m1
    if not var > 0:
        return None
    mu3 = m3 - 3.0 * m1 * m2 + 2.0 * m1 ** 3
    skew = mu3 / var ** 1.5
    rho = float(z @ _blocks_apply(K, z[:, None])[:, 0]) / float(z @ z)
    zr = (rho - m1) / math.sqrt(var)
    if skew > 1e-3:
        h = 8.0 / (skew * skew)                       # chi2_h's skewness is sqrt(8 / h)
        x = h + zr * math.sqrt(2.0 * h)
        logp = float(stats.chi2.logsf(x, h)) if x > 0 else 0.0
    else:
        logp = float(stats.norm.logsf(zr))
    method = "pearson3"
    if math.log(REFINE_FAR) < logp < math.log(REFINE_BELOW):
        # the tail that decides: exact spectrum of P K P on the residual space, saddlepoint tail
        lam = _residual_spectrum(K, Q, B, C)
        exact = _saddlepoint_logsf(lam - rho)
        if exact is not None:
            logp, method = exact, "saddlepoint"
    return {"rho": rho, "z": zr, "skew": skew, "p_value": math.exp(logp), "logp": logp, "method": method}


#: between these three-moment p the tail is recomputed from the exact spectrum (the region where
#: decisions are made: Holm's thresholds over the gap's ~30 tests reach 0.01 / 30); far beyond it
#: the three-moment p stands (its order of magnitude decides nothing and the spectrum costs an
#: eigen-decomposition of the 3n x 3n residual space)
REFINE_BELOW = 0.05
REFINE_FAR = 1e-12


def _residual_spectrum(K: list, Q: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """The ``nu`` eigenvalues of ``P A P`` on the residual space ``range(P)`` (``A`` block-diagonal
    with blocks ``K``, ``B = A Q``, ``C = Q' A Q``): ``P A P - g Q Q'`` with ``g`` beyond the
    spectrum puts the ``p`` directions of ``Q`` at ``-g``, where they are dropped."""
    n, m = K[0].shape[0], len(K)
    N = n * m
    A = np.zeros((N, N))
    for a in range(m):
        idx = np.arange(a, N, m)
        A[np.ix_(idx, idx)] = K[a]
    QC = Q @ C
    M = A - Q @ B.T - B @ Q.T + QC @ Q.T
    g = 10.0 * (1.0 + max(float(np.abs(k).sum(axis=1).max()) for k in K))     # beyond |A| (Gershgorin)
    lam = np.linalg.eigvalsh(0.5 * (M + M.T) - g * (Q @ Q.T))
    return lam[Q.shape[1]:]


def _saddlepoint_logsf(w: np.ndarray) -> Optional[float]:
    """log P(sum_i w_i chi2_1 > 0) by the Lugannani-Rice saddlepoint approximation of a Gaussian
    quadratic form (Kuonen, Biometrika 86, 929-935, 1999): ``K(s) = -1/2 sum ln(1 - 2 s w_i)``,
    ``K'(s_hat) = 0``, ``w_hat = sign(s_hat) sqrt(-2 K(s_hat))``, ``u_hat = s_hat sqrt(K''(s_hat))``,
    ``P = 1 - Phi(w_hat) + phi(w_hat) (1/u_hat - 1/w_hat)``. None near the centre (``|w_hat|``
    small, where the three-moment form is already good)."""
    w = np.asarray(w, float)
    w = w[np.abs(w) > 1e-14 * max(float(np.max(np.abs(w), initial=0.0)), 1e-300)]
    if w.size == 0:
        return None
    if not (w > 0).any():
        return -math.inf                      # rho at the top of its range
    if not (w < 0).any():
        return 0.0
    lo, hi = 1.0 / (2.0 * w.min()), 1.0 / (2.0 * w.max())
    def k1(s):
        return float(np.sum(w / (1.0 - 2.0 * s * w)))
    eps = 1e-12
    a, b = lo + eps * abs(lo), hi - eps * abs(hi)
    if not (k1(a) < 0 < k1(b)):
        return None
    s = optimize.brentq(k1, a, b, xtol=1e-14 * max(abs(lo), abs(hi)), maxiter=500)
    one = 1.0 - 2.0 * s * w
    K0 = -0.5 * float(np.sum(np.log(one)))
    K2 = float(np.sum(2.0 * w * w / (one * one)))
    if not (-2.0 * K0 > 0) or abs(s) * math.sqrt(K2) < 1e-3:
        return None
    wh = math.copysign(math.sqrt(-2.0 * K0), s)
    uh = s * math.sqrt(K2)
    if abs(wh) < 0.1:
        return None
    if wh > 0:
        # log of sf(wh) + pdf(wh)(1/uh - 1/wh), both small: factor out pdf for stability
        val = stats.norm.sf(wh) + stats.norm.pdf(wh) * (1.0 / uh - 1.0 / wh)
        if val > 0:
            return float(math.log(val))
        mills = math.exp(float(stats.norm.logsf(wh) - stats.norm.logpdf(wh)))
        inner = mills + 1.0 / uh - 1.0 / wh
        return float(stats.norm.logpdf(wh)) + math.log(inner) if inner > 0 else None
    val = stats.norm.sf(wh) + stats.norm.pdf(wh) * (1.0 / uh - 1.0 / wh)
    return float(math.log(min(max(val, 1e-300), 1.0)))


def kernels(time_s, sigma: np.ndarray, tau_s: float) -> list:
    """The Gauss-Markov kernel of correlation time ``tau_s`` per output in normalised units
    (``exp(-|t_i - t_j| / tau) / (sigma_ia sigma_ja)``)."""
    t = np.asarray(time_s, float)
    E = np.exp(-np.abs(t[:, None] - t[None, :]) / tau_s)
    return [E / np.outer(sigma[:, a], sigma[:, a]) for a in range(sigma.shape[1])]


class CampaignKernels:
    """The family's kernels of one campaign (visit times ``time_s``, noise ``sigma`` (n, 3)), one per
    correlation time ``fractions x span``, each with its :func:`kernel_traces`: they depend on the
    campaign only, so a diagnosis builds them once and asks them of the base fit, after every refit
    and in :func:`wander_rival`. Built lazily, per correlation time."""

    def __init__(self, time_s, sigma: np.ndarray, fractions=CORRELATION_FRACTIONS):
        self.time_s = np.asarray(time_s, float)
        self.sigma = np.asarray(sigma, float)
        self.fractions = tuple(fractions)
        self.span = float(np.ptp(self.time_s)) if self.time_s.size else 0.0
        self._blocks: dict = {}
        self._traces: dict = {}

    def tau_s(self, i: int) -> float:
        return self.fractions[i] * self.span

    def blocks(self, i: int) -> list:
        """:func:`kernels` at the ``i``-th correlation time."""
        if i not in self._blocks:
            self._blocks[i] = kernels(self.time_s, self.sigma, self.tau_s(i))
        return self._blocks[i]

    def traces(self, i: int) -> tuple:
        """:func:`kernel_traces` of :meth:`blocks` ``(i)``."""
        if i not in self._traces:
            self._traces[i] = kernel_traces(self.blocks(i))
        return self._traces[i]


def correlated_test(z: np.ndarray, Q: np.ndarray, time_s, sigma: np.ndarray,
                    fractions=CORRELATION_FRACTIONS, min_visits: int = CORRELATED_MIN_VISITS,
                    cache: Optional[CampaignKernels] = None) -> Optional[dict]:
    """The ``correlated`` family (module docstring): the most significant correlation time, its
    ``rho`` and ``z``, and Bonferroni's p over :data:`CORRELATION_FRACTIONS`; None below
    ``min_visits`` visits or when the campaign has one time. ``cache``: the campaign's
    :class:`CampaignKernels` (of these ``time_s``, ``sigma`` and ``fractions``) when already built."""
    ck = cache if cache is not None else CampaignKernels(time_s, sigma, fractions)
    if ck.time_s.size < max(min_visits, 3) or not ck.span > 0:
        return None
    best = None
    for i in range(len(ck.fractions)):
        res = ratio_test(z, Q, ck.blocks(i), ck.traces(i))
        if res is not None and (best is None or res["logp"] < best["logp"]):
            best = dict(res, tau_s=ck.tau_s(i))
    if best is None:
        return None
    p = min(1.0, len(ck.fractions) * best["p_value"])
    return {"S": best["z"] * abs(best["z"]), "k": 1, "p_value": p, "p_best": best["p_value"], "z": best["z"],
            "rho": best["rho"], "tau_s": best["tau_s"]}


#: mean candidates that a bias wandering in time can mimic: functions of the time alone, on the bias
WANDER_MIMICS = ("bias_drift", "bias_warmup")
#: mean candidates that a scale factor wandering in time can mimic: functions of the temperature on
#: the scale, which on a stepped campaign is one value a soak, as a wander's is near enough (a
#: Gauss-Markov scale of 20 ppm, 6 h, on the independent bench: a scale tempco named with the gap
#: closed in 3 of 20 seeds before this rival; docs/diagnosis.md "A scale that wanders")
SCALE_WANDER_MIMICS = ("scale_tempco", "scale_tempco2", "scale_tempco3")


def wander_rival(r: np.ndarray, J: np.ndarray, Jc: np.ndarray, time_s, sigma: np.ndarray,
                 fractions=CORRELATION_FRACTIONS, cache: Optional[CampaignKernels] = None,
                 along: Optional[np.ndarray] = None, groups=((0, 1, 2),),
                 noise_known: bool = True) -> Optional[dict]:
    """The encompassing test of a mean candidate against a bias (or, with ``along``, a scale factor)
    that wanders.

    For each correlation time ``tau`` of ``fractions`` (of the campaign's span), the variance
    ``v`` of a Gauss-Markov bias with the kernel of :func:`kernels` is estimated by REML on the
    base model (``r``, ``J``: its normalised residuals and Jacobian; the white level held at 1:
    :func:`triadcal.estimation.flicker_noise.reml_tau`), and the candidate's columns ``Jc`` are
    scored by GLS under ``V = I + v K`` (the residuals and the columns whitened, projected off the
    base's span): ``S ~ chi2_k`` when the wander alone made the data. A drift of the bias that is a
    drift stays significant whatever the wander is allowed to be; one that the wander explains as
    well is not told from it by these data. Returns the least significant of the ``tau``:
    ``tau_s``, ``variance`` (normalised units; the largest of ``groups``'), ``S``, ``k``, ``p_value``;
    None when degenerate. ``cache``: as in :func:`correlated_test`.

    ``along`` (n, 3), when given, makes it a wander of what multiplies it on each output: the kernel
    of output a becomes ``D_a K_a D_a`` with ``D_a = diag(along[:, a])`` -- with the nominal gravity on
    the sensor axes, a scale factor that wanders (:data:`SCALE_WANDER_MIMICS`); ``groups``: the outputs
    that share one variance (the bias's: all three; a scale's: one each, the three elements' scale
    factors being unrelated).

    ``noise_known=False`` (no ``sd_*``: the white level estimated): the covariance is
    ``s2 (I + v K)`` with ``s2`` free, REML with the level profiled out
    (:func:`triadcal.estimation.flicker_noise.reml_tau_profiled`), and the score is the GLS F test
    ``F = (S / k) / s2_1`` on ``(k, nu - k)`` dof, ``s2_1`` the whitened residual variance with the
    candidate added (``S`` then in units of that level). With the level held at the declared one a
    wander would have to explain every excess of scatter; freed, it is asked only to explain the
    correlation in time."""
    from ...estimation.flicker_noise import AxisWhitening, reml_tau, reml_tau_profiled

    ck = cache if cache is not None else CampaignKernels(time_s, sigma, fractions)
    t = ck.time_s
    k = Jc.shape[1]
    if not ck.span > 0 or k == 0:
        return None
    worst = None
    for i in range(len(ck.fractions)):
        G = ck.blocks(i)
        if along is not None:
            G = [along[:, [a]] * Ga * along[:, a][None, :] for a, Ga in enumerate(G)]
        if noise_known:
            v, _, _, _ = reml_tau(r, J, G, t, [list(g) for g in groups])
        else:
            v, _ = reml_tau_profiled(r, J, G, t, [list(g) for g in groups])
        W = AxisWhitening(G, v, t)
        rw, Jw, Jcw = W.apply(r), W.apply(J), W.apply(Jc)
        Q, _ = np.linalg.qr(Jw)
        Jp = Jcw - Q @ (Q.T @ Jcw)
        e0 = rw - Q @ (Q.T @ rw)
        U = Jp.T @ e0
        S = float(U @ np.linalg.lstsq(Jp.T @ Jp, U, rcond=None)[0])
        if noise_known:
            p = float(stats.chi2.sf(S, k))
        else:
            nu1 = len(rw) - Q.shape[1] - k
            if nu1 < 1:
                return None
            s2_1 = (float(e0 @ e0) - S) / nu1
            if not s2_1 > 0:
                return None
            S = S / s2_1                        # the reduction in units of the white level
            p = float(stats.f.sf(S / k, k, nu1))
        if worst is None or p > worst["p_value"]:
            worst = {"tau_s": ck.tau_s(i), "variance": float(np.max(v)), "S": S, "k": int(k), "p_value": p}
            if not noise_known:
                worst["F_dof"] = [int(k), int(nu1)]
    return worst


def wander_ambiguity(effect: str, w: dict, alpha: float, quantity: str = "bias") -> Optional[dict]:
    """The ``unexplained`` verdict's own fields when the mean candidate ``effect`` does not beat a
    ``quantity`` (bias or scale) that wanders (:func:`wander_rival`'s ``w``: its score under the
    wander's REML covariance is not below ``alpha`` at every correlation time), else None. The caller
    adds the evidence, the closed gap and where."""
    if w["p_value"] < alpha:
        return None
    lab = f"a {quantity} that wanders in time (Gauss-Markov, correlation time {w['tau_s'] / 3600.0:.3g} h)"
    change = "a change of the bias in time" if quantity == "bias" else f"a change of the {quantity} with temperature"
    return {"effect": "unexplained", "best_partial": effect, "ambiguous_with": [lab],
            "reason": (f"{effect} closes the gap but does not beat {lab}: under that noise's "
                       f"REML covariance its score is S = {w['S']:.3g} on {w['k']} dof"
                       + (f" (F test on {w['F_dof'][0]} and {w['F_dof'][1]} dof, the white level "
                          "estimated)" if "F_dof" in w else "") + ", p = "
                       f"{w['p_value']:.3g} >= {alpha:g}; the data cannot tell {change} "
                       "from a wander (docs/diagnosis.md \"Rivals\")")}
