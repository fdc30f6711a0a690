"""The ``flicker_noise`` effect in the fit: B_f^2 by REML, the mean by generalised least squares.

Model (:mod:`triadcal.models.effects.flicker_noise`): the visit means of output ``a`` have the
covariance ``V_a = diag(sigma_a^2) + B_a^2 C`` (``sigma`` the data's white noise, ``C`` the
covariance per unit ``B_f^2`` of the deviations of the visit means from the campaign mean; the
outputs independent). In the normalised residuals of the fit (divided by ``sigma``) it is
``I + tau_a G_a`` with ``G_a = C / (sigma_a sigma_a')`` and ``tau_a = B_a^2`` (output unit^2).

**Mean (GLS).** The fit machinery takes diagonal weights, so the residuals and the Jacobian of
each output are whitened with the Cholesky factor of ``I + tau_a G_a`` in time order
(:class:`AxisWhitening`; ``r~ = L^-1 r``: each whitened residual is the standardised one-step
prediction error of its visit given the earlier ones). Least squares on the whitened problem
is GLS on the full covariance, and ``(J~' J~)^-1`` its covariance.

**Variance (REML).** ``tau`` maximises the restricted likelihood (Patterson & Thompson 1971) of
the linearised problem, by Fisher scoring with the step halved until the REML log-likelihood
rises and ``tau`` projected on ``tau >= 0``: with ``P = V^-1 - V^-1 X (X' V^-1 X)^-1 X' V^-1``

    U_k = 1/2 (r' P G_k P r - tr(P G_k)),    I_kl = 1/2 tr(P G_k P G_l),

computed in the whitened space per output (``M_a = L_a^-1 G_a L_a^-T``, ``Q`` an orthonormal basis
of the whitened Jacobian: ``tr(P G_a) = tr(M_a) - tr(Q_a' M_a Q_a)``). It alternates with the GLS
refit of the mean (at most ``rounds``, until ``B_f`` moves by less than 0.1 %). ``u(tau)`` is
from the inverse expected information at the estimate (at ``tau = 0`` too: the boundary is not
treated specially; the diagnosis's LR uses the 1/2 chi2_0 + 1/2 chi2_1 mixture).

**Choice.** ``per_axis=True`` (the fit's default): one ``B_f`` per output (three accelerometers,
three floors); ``per_axis=False`` one common ``B_f`` (the diagnosis: one added variance, one score).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
from scipy import linalg

from ..errors import InputError
from ..models.effects.flicker_noise import centred_covariance
from .whitening import WhitenedProblem  # noqa: F401  (re-exported: written in whitening.py)


def normalised_components(campaign, sigma: np.ndarray) -> list:
    """``G_a = C / (sigma_a sigma_a')`` per output (three N x N), C per unit B_f^2."""
    C = centred_covariance(campaign.time_s, campaign.tau_s, 1.0)
    return [C / np.outer(sigma[:, a], sigma[:, a]) for a in range(sigma.shape[1])]


class AxisWhitening:
    """``L_a^-1`` per output of ``V_a = I + tau_a G_a`` (normalised units), applied in time order
    to vectors/matrices whose rows are visit-major (visit i, output a at row 3 i + a)."""

    def __init__(self, G: Sequence[np.ndarray], tau: Sequence[float], time_s):
        self.tau = np.asarray(tau, float)
        self.order = np.argsort(np.asarray(time_s, float), kind="stable")
        self.n = len(self.order)
        self.L = []
        for Ga, ta in zip(G, self.tau):
            V = np.eye(self.n) + ta * Ga[np.ix_(self.order, self.order)]
            self.L.append(np.linalg.cholesky(V))

    def diag(self) -> np.ndarray:
        """``L_a,ii`` per visit and output (n, 3): the one-step prediction SD in sigma units."""
        out = np.empty((self.n, len(self.L)))
        for a, L in enumerate(self.L):
            out[self.order, a] = np.diag(L)
        return out

    def apply(self, x: np.ndarray) -> np.ndarray:
        """``L^-1 x`` for ``x`` of shape (3n,) or (3n, p)."""
        x = np.asarray(x, float)
        k = len(self.L)
        shaped = x.reshape(self.n, k, -1)
        out = np.empty_like(shaped)
        for a, L in enumerate(self.L):
            out[self.order, a] = linalg.solve_triangular(L, shaped[self.order, a], lower=True)
        return out.reshape(x.shape)

    def logdet(self) -> float:
        return float(sum(2.0 * np.sum(np.log(np.diag(L))) for L in self.L))

    def casadi_apply(self, r):
        """``L^-1`` applied to CasADi residuals ``r`` (3 x n, the outputs by visit): the whitened
        residuals visit-major, as :meth:`apply` orders them."""
        import casadi as ca

        rows = []
        for a, L in enumerate(self.L):
            # L_a^-1 in time order, as a matrix on the visits' own order
            Linv = linalg.solve_triangular(L, np.eye(self.n), lower=True)
            full = np.empty((self.n, self.n))
            full[np.ix_(self.order, self.order)] = Linv
            rows.append(ca.mtimes(ca.DM(full), r[a, :].T).T)
        return ca.vec(ca.vertcat(*rows))


def _orthobasis(X):
    d = np.linalg.norm(X, axis=0)
    keep = d > 0
    Q, R = np.linalg.qr(X[:, keep] / d[keep])
    dg = np.abs(np.diag(R))
    ok = dg > 1e-10 * max(dg.max(), 1e-300)
    # log det(X' X) / 2 of the kept columns: R's diagonal and the column scales
    return Q[:, ok], float(np.sum(np.log(dg[ok])) + np.sum(np.log(d[keep][ok])))


def reml_pieces(r, J, G, tau, time_s, groups, return_trace: bool = False):
    """REML log-likelihood (up to a constant), score and expected information of the components
    ``groups`` (list of lists of outputs sharing one tau) at ``tau`` (per output, (3,)), for the
    linearised problem of normalised residuals ``r`` (3n,) and Jacobian ``J`` (3n, p)."""
    W = AxisWhitening(G, tau, time_s)
    rt, Xt = W.apply(r), W.apply(J)
    Q, logdetR = _orthobasis(Xt)
    e = rt - Q @ (Q.T @ rt)
    n, k = W.n, len(W.L)
    ll = -0.5 * (W.logdet() + 2.0 * logdetR + float(e @ e))
    Qa = [Q.reshape(n, k, -1)[:, a][W.order] for a in range(k)]      # rows in time order
    ea = [e.reshape(n, k)[:, a][W.order] for a in range(k)]
    M, QMQ, tr_pg, quad = [], [], [], []
    for a in range(k):
        L = W.L[a]
        Ga = G[a][np.ix_(W.order, W.order)]
        A = linalg.solve_triangular(L, Ga, lower=True)
        Ma = linalg.solve_triangular(L, A.T, lower=True)             # L^-1 G L^-T (symmetric)
        Ma = 0.5 * (Ma + Ma.T)
        M.append(Ma)
        QMQ.append(Qa[a].T @ Ma @ Qa[a])
        tr_pg.append(float(np.trace(Ma) - np.trace(QMQ[a])))
        quad.append(float(ea[a] @ Ma @ ea[a]))
    m = len(groups)
    U = np.array([0.5 * sum(quad[a] - tr_pg[a] for a in g) for g in groups])
    info = np.zeros((m, m))
    for i, gi in enumerate(groups):
        for j, gj in enumerate(groups):
            s = 0.0
            for a in gi:
                for b in gj:
                    if a == b:
                        Ma = M[a]
                        MQ = Ma @ Qa[a]
                        s += float(np.sum(Ma * Ma) - 2.0 * np.sum(MQ * MQ))
                    s += float(np.sum(QMQ[a] * QMQ[b].T))
            info[i, j] = 0.5 * s
    if return_trace:                      # tr(P G_k) per group: the null mean of r' P G_k P r
        return ll, U, info, np.array([sum(tr_pg[a] for a in g) for g in groups])
    return ll, U, info


#: the last few eigendecompositions of :class:`SpectralREML` (matrix -> eigenvalues, eigenvectors): a
#: diagnosis fits the flicker candidate and its REML time after time on one campaign, whose kernel
#: matrices G_a depend on the visits' times only (33 eigendecompositions of 420 x 420 in two
#: validation cases, 12 of them distinct)
_EIGH_CACHE: list = []
_EIGH_CACHE_SIZE = 6
_EIGH_LOCK = threading.Lock()


def _eigh_cached(A: np.ndarray):
    """``numpy.linalg.eigh(A)`` for a symmetric ``A``, the result of an equal matrix (every element)
    reused; the arrays returned are read-only."""
    A = np.ascontiguousarray(A, dtype=float)
    key = (A.shape, hash(A.tobytes()))
    with _EIGH_LOCK:
        for k, M, w, V in _EIGH_CACHE:
            if k == key and np.array_equal(M, A):
                return w, V
    w, V = np.linalg.eigh(A)
    M = A.copy()
    for a in (M, w, V):
        a.flags.writeable = False
    with _EIGH_LOCK:
        _EIGH_CACHE.insert(0, (key, M, w, V))
        del _EIGH_CACHE[_EIGH_CACHE_SIZE:]
    return w, V


class SpectralREML:
    """The REML pieces of :func:`reml_pieces` for many ``tau`` of one linearised problem, in the
    eigenbasis of each ``G_a = U_a diag(lambda_a) U_a'``.

    Whitening with ``(I + tau_a diag(lambda_a))^-1/2 U_a'`` instead of the Cholesky factor in time
    order is another square root of ``V_a^-1``: the two whitened problems differ by an orthogonal
    transformation of the rows, so the REML log-likelihood, ``log det(X~' X~)``, ``P``, the score and
    the information are the same numbers (tests/test_flicker_spectral.py: to 1e-9 against
    :func:`reml_pieces`). In this basis ``M_a = diag(lambda_a / (1 + tau_a lambda_a))``, and ``U_a' r``
    and ``U_a' J`` do not depend on ``tau``: one eigendecomposition per output (one for all when the
    ``G_a`` are proportional, one white level per output) replaces two n x n triangular solves per
    output and evaluation (n = 420 visits: 14 % of a diagnosis's time went to them, py-spy
    2026-11-30)."""

    def __init__(self, G: Sequence[np.ndarray], r, J):
        k = len(G)
        n = G[0].shape[0]
        self.k, self.n = k, n
        lam, U = [], []
        for a, Ga in enumerate(G):
            for b in range(a):                 # proportional to an earlier output's: its eigenvectors
                c = float(Ga[0, 0] / G[b][0, 0]) if G[b][0, 0] > 0 else math.nan
                if c > 0 and np.allclose(Ga, c * G[b], rtol=1e-12, atol=0.0):
                    lam.append(c * lam[b])
                    U.append(U[b])
                    break
            else:
                w, V = _eigh_cached(0.5 * (Ga + Ga.T))
                lam.append(np.clip(w, 0.0, None))   # a covariance: roundoff below 0 is 0
                U.append(V)
        self.lam = lam
        r = np.asarray(r, float).reshape(n, k)
        J = np.asarray(J, float).reshape(n, k, -1)
        self.r0 = [U[a].T @ r[:, a] for a in range(k)]
        self.X0 = [U[a].T @ J[:, a, :] for a in range(k)]

    def _whitened(self, tau, r_scale: float = 1.0):
        d = [1.0 + float(tau[a]) * self.lam[a] for a in range(self.k)]
        if any(np.any(da <= 0) for da in d):
            raise np.linalg.LinAlgError("I + tau G is not positive definite")
        h = [1.0 / np.sqrt(da) for da in d]
        rt = np.concatenate([self.r0[a] * h[a] for a in range(self.k)]) * r_scale
        Xt = np.vstack([self.X0[a] * h[a][:, None] for a in range(self.k)])
        logdet = float(sum(np.sum(np.log(da)) for da in d))
        return d, rt, Xt, logdet

    def pieces(self, tau, groups, return_trace: bool = False, r_scale: float = 1.0):
        """:func:`reml_pieces` at ``tau`` (per output), the residuals times ``r_scale``."""
        d, rt, Xt, logdet = self._whitened(tau, r_scale)
        Q, logdetR = _orthobasis(Xt)
        e = rt - Q @ (Q.T @ rt)
        n, k = self.n, self.k
        ll = -0.5 * (logdet + 2.0 * logdetR + float(e @ e))
        m = [self.lam[a] / d[a] for a in range(k)]                 # diagonal of M_a
        Qa = [Q[a * n:(a + 1) * n] for a in range(k)]
        ea = [e[a * n:(a + 1) * n] for a in range(k)]
        QMQ = [Qa[a].T @ (m[a][:, None] * Qa[a]) for a in range(k)]
        tr_pg = [float(np.sum(m[a]) - np.trace(QMQ[a])) for a in range(k)]
        quad = [float(np.sum(m[a] * ea[a] ** 2)) for a in range(k)]
        U = np.array([0.5 * sum(quad[a] - tr_pg[a] for a in g) for g in groups])
        info = np.zeros((len(groups), len(groups)))
        for i, gi in enumerate(groups):
            for j, gj in enumerate(groups):
                s_ = 0.0
                for a in gi:
                    for b in gj:
                        if a == b:
                            MQ = m[a][:, None] * Qa[a]
                            s_ += float(np.sum(m[a] ** 2) - 2.0 * np.sum(MQ * MQ))
                        s_ += float(np.sum(QMQ[a] * QMQ[b].T))
                info[i, j] = 0.5 * s_
        if return_trace:
            return ll, U, info, np.array([sum(tr_pg[a] for a in g) for g in groups])
        return ll, U, info

    def profiled_ll(self, tau):
        """:func:`_profiled_ll` at ``tau``: the REML log-likelihood with the white level profiled
        out, that level, and the rank of the whitened Jacobian."""
        _, rt, Xt, logdet = self._whitened(tau)
        Q, logdetR = _orthobasis(Xt)
        e = rt - Q @ (Q.T @ rt)
        nu = len(rt) - Q.shape[1]
        s2 = float(e @ e) / max(nu, 1)
        return -0.5 * (logdet + 2.0 * logdetR + nu * math.log(max(s2, 1e-300))), s2, Q.shape[1]


def _expander(groups, k: int):
    """The per-output vector (k,) of a value per group."""
    def expand(tg):
        out = np.zeros(k)
        for g, v in zip(groups, tg):
            out[list(g)] = v
        return out
    return expand


def _fisher_ascent(t, evaluate, max_iter: int):
    """Fisher scoring from ``t`` on ``t >= 0``: ``evaluate(t) -> (ll, U, info, extra)``; the step
    ``info^-1 U`` halved until ``ll`` rises; stops when ``t`` moves by < 1e-5 of itself or ``ll`` by
    < 1e-6. Returns ``(t, ll, U, info, extra)`` at the last point accepted."""
    ll, U, info, extra = evaluate(t)
    for _ in range(max_iter):
        try:
            step = np.linalg.solve(info, U)
        except np.linalg.LinAlgError:
            step = U / np.maximum(np.diag(info), 1e-300)
        moved = False
        for _h in range(30):
            t_new = np.maximum(t + step, 0.0)
            ll_new, U_new, info_new, extra_new = evaluate(t_new)
            if ll_new >= ll - 1e-10 * abs(ll):
                moved = True
                break
            step = step / 2.0
        if not moved:
            break
        # converged: tau moves by < 1e-5 of itself (B_f by 5e-6) or the likelihood by < 1e-6
        done = np.all(np.abs(t_new - t) <= 1e-5 * np.maximum(np.abs(t_new), 1e-300)) or abs(ll_new - ll) < 1e-6
        t, ll, U, info, extra = t_new, ll_new, U_new, info_new, extra_new
        if done:
            break
    return t, ll, U, info, extra


def reml_tau(r, J, G, time_s, groups, tau0=None, max_iter: int = 50):
    """``(tau per output (3,), u per group, info)`` maximising the REML likelihood (module docstring)."""
    expand = _expander(groups, len(G))
    t = np.zeros(len(groups)) if tau0 is None else np.array([tau0[g[0]] for g in groups], float)
    spec = SpectralREML(G, r, J)
    t, ll, _, info, _ = _fisher_ascent(t, lambda tg: spec.pieces(expand(tg), groups) + (None,), max_iter)
    try:
        cov = np.linalg.inv(info)
        u = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        u = np.full(len(groups), math.inf)
    return expand(t), u, info, ll


def _profiled_ll(r, J, G, tau, time_s):
    """REML log-likelihood with the white level profiled out, and that level: for
    ``V = s2 (I + sum_a tau_a G_a)``, ``s2 = e' e / (N - p)`` (``e`` the whitened residuals off the
    whitened Jacobian's span) and ``ll = -1/2 (log det(I + tau G) + log det(X~' X~) + (N - p) log s2)``
    up to a constant (Harville, JASA 72, 320-338, 1977, sec. 5: the scale profiled out of REML)."""
    W = AxisWhitening(G, tau, time_s)
    rt, Xt = W.apply(r), W.apply(J)
    Q, logdetR = _orthobasis(Xt)
    e = rt - Q @ (Q.T @ rt)
    nu = len(rt) - Q.shape[1]
    s2 = float(e @ e) / max(nu, 1)
    return -0.5 * (W.logdet() + 2.0 * logdetR + nu * math.log(max(s2, 1e-300))), s2


def reml_tau_profiled(r, J, G, time_s, groups, max_iter: int = 50):
    """``(tau per output (3,), s2)`` maximising the REML likelihood of ``V = s2 (I + sum tau_a G_a)``
    with the white level ``s2`` free (profiled out: :func:`_profiled_ll`): the variance components
    relative to a white noise that is estimated, not declared. Fisher scoring as :func:`reml_tau`
    (:func:`_fisher_ascent`) on the profiled likelihood, the score that of :func:`reml_pieces` at the
    residuals divided by the profiled ``sqrt(s2)`` (the profiled likelihood's derivative:
    ``1/2 (r' P G_k P r / s2 - tr(P G_k))``), ``tau >= 0``."""
    expand = _expander(groups, len(G))

    spec = SpectralREML(G, r, J)

    def evaluate(tg):
        ll, s2, _ = spec.profiled_ll(expand(tg))
        _, U, info = spec.pieces(expand(tg), groups, r_scale=1.0 / math.sqrt(max(s2, 1e-300)))
        return ll, U, info, s2

    t, _, _, _, s2 = _fisher_ascent(np.zeros(len(groups)), evaluate, max_iter)
    return expand(t), s2


def profiled_u(r, J, G, tau, s2: float, time_s, groups) -> np.ndarray:
    """u of ``b_k = s2 tau_k`` per group (the components in the residuals' own units: ``V = s2 I +
    sum b_k G_k``) from the inverse expected REML information of ``(s2, b)`` jointly, so that the
    white level's uncertainty is in it. With ``R`` the residual projector of the whitened problem
    (``I + tau G = L L'``), ``M_k = L^-1 G_k L^-T`` and ``L^-1 I L^-T = I - sum tau_k M_k``, the
    information ``1/2 tr(P V_i P V_j)`` (Harville 1977, eq. 4.6) is, times ``2 s2^2``,

        I_ss = nu - 2 tau't1 + tau'T2 tau,   I_sb = t1 - T2 tau,   I_bb = T2,

    ``nu = tr R``, ``t1_k = tr(R M_k)``, ``T2_kl = tr(R M_k R M_l)`` (:func:`reml_pieces`' trace and
    twice its information). ``inf`` where the information is singular."""
    expand = _expander(groups, len(G))
    tg = np.array([tau[g[0]] for g in groups], float)
    spec = SpectralREML(G, r, J)
    _, _, info, t1 = spec.pieces(expand(tg), groups, return_trace=True)
    nu = float(len(r) - spec.profiled_ll(expand(tg))[2])
    T2 = 2.0 * info
    m = len(groups)
    Im = np.empty((m + 1, m + 1))
    Im[0, 0] = nu - 2.0 * float(tg @ t1) + float(tg @ T2 @ tg)
    Im[0, 1:] = Im[1:, 0] = t1 - T2 @ tg
    Im[1:, 1:] = T2
    Im /= 2.0 * s2 * s2
    try:
        cov = np.linalg.inv(Im)
    except np.linalg.LinAlgError:
        return np.full(m, math.inf)
    return np.sqrt(np.clip(np.diag(cov)[1:], 0.0, None))


@dataclass
class FlickerEstimate:
    """B_f^2 per output (output unit^2) by REML with its u, and the whitening of the GLS fit."""

    Bf2: np.ndarray                 # (3,), output unit^2
    u_Bf2: np.ndarray               # (3,)
    per_axis: bool
    output_unit: str
    to_ug: np.ndarray               # output unit -> ug per axis (|K| 1e6)
    rounds: int
    whitening: Optional[AxisWhitening] = field(default=None, repr=False)
    #: the white level estimated with B_f^2 (no declared noise): profiled REML, :func:`reml_tau_profiled`
    white_estimated: bool = False

    @property
    def Bf(self) -> np.ndarray:
        return np.sqrt(np.clip(self.Bf2, 0.0, None))

    @property
    def u_Bf(self) -> np.ndarray:
        """Delta method ``u(tau) / (2 B_f)``; ``sqrt(u(tau))`` at ``B_f = 0``."""
        bf = self.Bf
        return np.where(bf > 0, self.u_Bf2 / (2.0 * np.where(bf > 0, bf, 1.0)), np.sqrt(self.u_Bf2))

    def to_dict(self) -> dict:
        from ..models.sensor import AXES

        axes = AXES if self.per_axis else ("common",)
        idx = range(3) if self.per_axis else (0,)
        return {"flicker_Bf": {a: {"value": float(self.Bf[i]), "u": float(self.u_Bf[i]), "unit": self.output_unit,
                                   "value_ug": float(self.Bf[i] * self.to_ug[i]),
                                   "u_ug": float(self.u_Bf[i] * self.to_ug[i])} for a, i in zip(axes, idx)},
                "flicker_Bf2": {a: {"value": float(self.Bf2[i]), "u": float(self.u_Bf2[i]),
                                    "unit": f"{self.output_unit}^2"} for a, i in zip(axes, idx)},
                "method": ("REML of the flicker floor B_f^2 (Allan-deviation floor of 1/f noise) "
                           + ("per output" if self.per_axis else "common to the outputs")
                           + (" with the white level estimated together (no declared output noise: the REML "
                              "likelihood of s^2 (I + tau G) with s^2 profiled out, Harville 1977; u of B_f^2 "
                              "from the joint information of s^2 and B_f^2)" if self.white_estimated else "")
                           + ", alternating with the GLS refit of the mean (residuals whitened per output with "
                             "the Cholesky factor of diag(sigma^2) + B_f^2 C in time order)"),
                "white_level_estimated": self.white_estimated,
                "rounds": self.rounds}


def flicker_from_residuals(campaign, effects: Sequence[str], *, per_axis: bool = True, rounds: int = 6,
                           reference_temperature_C: float = 20.0, **fit_kw):
    """REML of B_f^2 with the GLS refit of the joint fit of ``effects`` (module docstring).
    Returns ``(FlickerEstimate, result)``: ``result`` the GLS fit at the estimate."""
    from .joint import fit_joint, noise_of

    if fit_kw.get("loss", "l2") != "l2":
        raise InputError(f"flicker_noise is fitted by generalised least squares: it cannot be combined with "
                         f"--loss {fit_kw.get('loss')} or heavy_tails")
    noise = noise_of(campaign)
    if campaign.n_visits < 4:
        raise InputError("flicker_noise needs at least 4 visits at different times")
    G = None
    groups = [[0], [1], [2]] if per_axis else [[0, 1, 2]]
    tau = np.zeros(3)
    whitening, done, s2 = None, 0, 1.0
    u = np.zeros(len(groups))
    for done in range(1, rounds + 1):
        result, problem, sol = fit_joint(campaign, effects, reference_temperature_C=reference_temperature_C,
                                         return_problem=True, whitening=whitening, **fit_kw)
        # residuals and Jacobian normalised by sigma only (un-whiten: r = L r~)
        raw = getattr(problem, "raw", problem)
        if G is None:       # the fit's own sigma (with the bench's errors when they are given)
            G = normalised_components(campaign, raw.sigma)
        r_raw, J_raw = raw.residuals_and_jacobian(sol.x)
        if noise.known:
            new, u, _, _ = reml_tau(r_raw, J_raw, G, campaign.time_s, groups, tau0=tau)
        else:
            # the white level is estimated: V = s2 (I + tau G), s2 profiled out; B_f^2 = s2 tau
            new, s2 = reml_tau_profiled(r_raw, J_raw, G, campaign.time_s, groups)
            u = profiled_u(r_raw, J_raw, G, new, s2, campaign.time_s, groups)
        converged = np.all(np.abs(np.sqrt(new) - np.sqrt(tau)) <= 1e-3 * np.maximum(np.sqrt(new), 1e-300))
        tau = new
        whitening = AxisWhitening(G, tau, campaign.time_s)
        if converged and done > 1:
            break
    result, problem, sol = fit_joint(campaign, effects, reference_temperature_C=reference_temperature_C,
                                     return_problem=True, whitening=whitening, **fit_kw)
    K = np.array([abs(result.parameters[f"K_{a}"].value) if f"K_{a}" in result.parameters else 1.0
                  for a in "xyz"])
    u3 = np.array([u[0]] * 3) if not per_axis else np.asarray(u)
    est = FlickerEstimate(tau * s2, u3, per_axis, campaign.output_unit, K * 1e6, done, whitening,
                          white_estimated=not noise.known)
    return est, result
