"""Diagnosis of the gap between a fitted model and the data: where, which effect, how far it shrinks.

Built on the joint fit (:mod:`triadcal.estimation.joint`): one CasADi problem of the
*full* model (every switchable effect of :data:`triadcal.models.effects.EFFECTS`) is
compiled per campaign; a model is a subset of its parameters, the others held at their
nominal value 0 (every effect is the identity at 0, so the subset problem *is* the
smaller model). That gives, at the fitted point, the exact sensitivity of the outputs
to every parameter of every candidate effect without a refit.

1. **Gap**: with known noise (``sd_*``/``n_samples`` or ``Q_V2s``) the sum of squared
   normalised residuals is tested against chi2(n_obs - n_par); the tails against the
   Gaussian by the Anscombe-Glynn kurtosis test on leverage-standardised residuals;
   and each candidate by its score test (below). The gap is significant when any of
   these rejects after Holm's correction at ``alpha`` (family-wise). With estimated
   noise the chi2 level is not testable (it *is* the noise estimate); the structure
   (score tests, slices, kurtosis, the variance pattern of positioning errors) is.
2. **Where**: normalised residuals sliced by output axis, up axis, setpoint,
   heating/cooling branch, time in the campaign and time since the setpoint block
   began; each slice x output tested for an offset, a trend in time and excess chi2
   with exact null moments of the linearised fit (hat matrix), Holm-corrected over all
   tests; a posterior predictive p-value per slice from Laplace draws of the LS
   covariance.
3. **Which**: every candidate scored by the Lagrange-multiplier (score) test at the
   fitted point with its parameters at 0: ``S = U' I^-1 U`` with ``U = J_c' r`` and
   ``I`` the information of the new parameters after projecting out the fitted ones,
   chi2(k) under the null (the chi2 reduction a linearised refit would give). Bilinear
   terms (thermal lag acts through the tempcos) are scored at the fitted tempcos;
   with no tempco in the model their sensitivity is 0 and they are reported as not
   testable. Noise effects: ``position_error`` by the score of an added variance
   ``sigma_p^2 * sensitivity`` (:mod:`triadcal.models.effects.position_error`),
   ``heavy_tails`` by the kurtosis test. The top candidates are refitted and compared by
   the likelihood-ratio (delta log-likelihood), PSIS-LOO elpd with its SE (arviz, on
   pointwise log-likelihoods of Laplace draws from the LS covariance, linearised
   residuals), and by prediction across branches (fit on heating, predict cooling and
   the reverse).
4. **How far it shrinks**: chi2/dof, residual RMS in ug against the noise floor,
   elpd, number of significant slices before and after, and how far every
   calibration parameter moves in units of its uncertainty.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
from scipy import optimize, stats

from ..models.campaign import Campaign
from ..models.effects import DEFAULT_EFFECTS, EFFECTS, NOISE_EFFECTS, VOCABULARY
from ..models.effects import heavy_tails as ht
from ..models.effects import position_error as pe
from ..models.model import Model
from ..models.sensor import AXES
from ..models.units import ARCSEC
from .joint import (JointProblem, identifiability_problems, levenberg_marquardt, noise_of,
                    null_space_problems, start_values)

FORMAT = "triadcal.diagnosis"
VERSION = 1
ALPHA = 0.01
#: slice families and the effects whose signature they show first (for validation)
FAMILIES = ("axis", "up", "setpoint", "direction", "time", "since_change", "up_x_direction", "up_x_setpoint")
#: where each effect's misfit should show first, from its physics (used by the validation):
#: tilt and K2/asymmetry are per-pose offsets; tempcos offsets per pose and setpoint (their
#: sign follows the pose) or per setpoint (bias); hysteresis per pose and branch; the lag a
#: temperature error signed by the branch and largest early in a setpoint block (through the
#: bias tempco it is an offset per setpoint); drift a trend in time; positioning errors
#: excess scatter anywhere; heavy tails nowhere in particular (empty: no family expected)
SIGNATURE = {"bench_tilt": ("up", "up_x_setpoint", "up_x_direction"),
             "angle_tempco": ("up_x_setpoint", "setpoint", "time"),
             "scale_tempco": ("up_x_setpoint", "setpoint", "time"),
             "bias_tempco": ("setpoint", "up_x_setpoint", "time"),
             "hysteresis": ("up_x_direction", "direction"),
             "thermal_lag": ("since_change", "direction", "up_x_direction", "setpoint"),
             "bias_drift": ("time", "setpoint"),
             "scale_nonlinearity": ("up",), "scale_asymmetry": ("up",),
             "position_error": FAMILIES, "heavy_tails": ()}


# ----------------------------------------------------------------------------------
# fitting a subset of the full model
# ----------------------------------------------------------------------------------
class _Subset:
    """The full problem restricted to ``names`` (others held at ``base``), with row scaling
    ``scale`` (normalised residuals divided by it, e.g. an added variance)."""

    def __init__(self, full: JointProblem, names: Sequence[str], base: np.ndarray, scale=None):
        self.full = full
        self.names = tuple(names)
        self.cols = np.array([full.index[n] for n in self.names], int)
        self.base = np.array(base, float)
        self.scale = None if scale is None else np.asarray(scale, float)

    def embed(self, x):
        z = self.base.copy()
        z[self.cols] = x
        return z

    def residuals_and_jacobian(self, x):
        r, J = self.full.residuals_and_jacobian(self.embed(x))
        J = J[:, self.cols]
        if self.scale is not None:
            r, J = r / self.scale, J / self.scale[:, None]
        return r, J


@dataclass
class FitState:
    """A least-squares fit of a subset of the full model at its optimum."""

    names: tuple
    x_full: np.ndarray           # full parameter vector, reporting units
    r: np.ndarray                # normalised residuals (3n,), divided by the noise scale s
    J: np.ndarray                # dr/dx of the fitted parameters (3n, p), same scaling
    cov: np.ndarray              # covariance of the fitted parameters, reporting units
    chi2: float                  # sum of squared normalised residuals (before the scale s)
    dof: int
    s: float                     # noise scale: 1 with known noise, sqrt(chi2/dof) otherwise
    converged: bool
    var_scale: Optional[np.ndarray] = None   # per-observation variance factor (position_error)
    nu: float = math.inf                     # Student-t dof (heavy_tails)
    extra_params: dict = field(default_factory=dict)

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    def u(self) -> dict:
        return {n: float(math.sqrt(max(self.cov[i, i], 0.0))) for i, n in enumerate(self.names)}

    def value(self, full: JointProblem) -> dict:
        return {n: float(self.x_full[full.index[n]]) for n in self.names}


def _fit(full: JointProblem, names, x_start: np.ndarray, noise_known: bool, scale=None) -> FitState:
    sub = _Subset(full, names, x_start, scale)
    sol = levenberg_marquardt(sub, x_start[sub.cols], max_iter=60)
    x_full = sub.embed(sol.x)
    r, J = sol.r, sol.J
    n_obs, p = r.size, len(names)
    dof = n_obs - p
    chi2 = float(r @ r)
    s = 1.0 if noise_known else math.sqrt(chi2 / max(dof, 1))
    cov = _lsq_cov(J) * s * s
    return FitState(tuple(names), x_full, r / s, J / s, cov, chi2, dof, s, sol.converged,
                    var_scale=None if scale is None else np.asarray(scale) ** 2)


def _lsq_cov(J):
    d = np.linalg.norm(J, axis=0)
    d[d == 0] = 1.0
    return np.linalg.pinv((J / d).T @ (J / d)) / np.outer(d, d)


def _chol(C):
    """A square root of a covariance (eigen-decomposition: tolerant of near-singular ones)."""
    w, V = np.linalg.eigh((C + C.T) / 2)
    return V * np.sqrt(np.clip(w, 0.0, None))


def _hat_q(J):
    """Orthonormal basis of the column space of J (the fit's hat matrix is Q Q')."""
    d = np.linalg.norm(J, axis=0)
    keep = d > 0
    Q, R = np.linalg.qr(J[:, keep] / d[keep])
    diag = np.abs(np.diag(R))
    return Q[:, diag > 1e-10 * max(diag.max(), 1e-300)]


def _chi2_logsf(S, k):
    """log P(chi2_k > S), with the Wilson-Hilferty normal form where scipy underflows."""
    v = float(stats.chi2.logsf(S, k))
    if math.isfinite(v):
        return v
    z = ((S / k) ** (1.0 / 3.0) - (1.0 - 2.0 / (9.0 * k))) / math.sqrt(2.0 / (9.0 * k))
    return float(stats.norm.logsf(z))


# ----------------------------------------------------------------------------------
# results
# ----------------------------------------------------------------------------------
@dataclass
class SliceTest:
    slice: str
    family: str
    axis: str
    test: str                # offset | trend | excess_chi2
    n: int
    statistic: float         # z for offset/trend, chi2 ratio for excess_chi2
    p_value: float
    p_adjusted: float = 1.0  # Holm
    log10_p: float = 0.0     # log10 of p_value without underflow (orders the extreme ones)
    size: float = 0.0
    unit: str = "ug"
    ppc_p: Optional[float] = None

    @property
    def standardised_size(self) -> float:
        """Size per observation in noise units: |mean| for an offset, the r.m.s. of the fitted
        line for a trend, sqrt(chi2/E[chi2] - 1) for excess scatter (all ~ delta for a
        misfit of delta sigma on every visit of the slice)."""
        if self.test == "excess_chi2":
            return math.sqrt(max(self.statistic - 1.0, 0.0))
        return abs(self.statistic) / math.sqrt(max(self.n, 1))

    def to_dict(self) -> dict:
        return {"slice": self.slice, "family": self.family, "axis": self.axis, "test": self.test,
                "n": self.n, "statistic": _f(self.statistic), "size": _f(self.size), "unit": self.unit,
                "size_sigma": _f(self.standardised_size),
                "p_value": _f(self.p_value), "log10_p": _f(self.log10_p), "p_holm": _f(self.p_adjusted),
                "ppc_p": _f(self.ppc_p)}


@dataclass
class Candidate:
    effect: str
    testable: bool
    reason: str = ""
    k: int = 0
    score: float = 0.0
    score_logp: float = 0.0          # natural log of the score test's p-value
    refit: Optional[dict] = None     # evidence of the refit (None when not refitted)
    rank: int = 0
    params: list = field(default_factory=list)   # its parameters the design can determine

    @property
    def score_p(self) -> float:
        return math.exp(self.score_logp)

    def to_dict(self) -> dict:
        d = {"effect": self.effect, "rank": self.rank, "testable": self.testable,
             "score": _f(self.score), "score_dof": self.k, "score_p_value": _f(self.score_p),
             "score_log10_p": _f(self.score_logp / math.log(10))}
        if self.reason:
            d["reason"] = self.reason
        if self.refit:
            d.update(self.refit)
        return d


@dataclass
class Diagnosis:
    model: tuple
    noise_known: bool
    noise: str
    gap: dict
    slices: list
    candidates: list
    verdict: dict
    fit: dict
    notes: list = field(default_factory=list)
    source: Optional[str] = None
    alpha: float = ALPHA
    #: families of slices ranked by how much of the misfit their offsets explain
    families: list = field(default_factory=list)
    #: normalised residuals of the base fit, (n_visits, 3); not part of the JSON
    residuals: Optional[np.ndarray] = None

    @property
    def where(self) -> list:
        """The disagreeing slices (Holm p < alpha), ranked by p-value."""
        return [s for s in self.slices if s.p_adjusted < self.alpha]

    @property
    def verdict_effect(self) -> Optional[str]:
        return self.verdict.get("effect")

    def ranked(self) -> list:
        return [c.effect for c in sorted(self.candidates, key=lambda c: c.rank) if c.testable]

    def to_dict(self) -> dict:
        return {
            "format": FORMAT, "version": VERSION, "model": list(self.model), "source": self.source,
            "noise": self.noise, "noise_known": self.noise_known, "alpha": self.alpha,
            "gap": self.gap,
            "where": [s.to_dict() for s in self.where],
            "where_families": self.families,
            "candidates": [c.to_dict() for c in sorted(self.candidates, key=lambda c: c.rank)],
            "verdict": self.verdict,
            "fit": self.fit,
            "slices": [s.to_dict() for s in self.slices],
            "notes": list(self.notes),
            "methods": METHODS_TEXT,
        }

    def save(self, path) -> None:
        from ..io.atomic import atomic_write_json

        atomic_write_json(path, self.to_dict())     # non-finite (e.g. a Pareto k) -> null, never a torn file


METHODS_TEXT = {
    "gap": "chi2 of the normalised residuals vs chi2(n_obs - n_par) with known noise; Anscombe-Glynn "
           "kurtosis test (one-sided) of leverage-standardised residuals; score test of every candidate; "
           "significant when any rejects after Holm's correction at alpha (family-wise)",
    "where": "slices x output axis, tests of offset (mean), trend (slope in time) and excess chi2 with exact "
             "null moments of the linearised fit (hat matrix; excess chi2 by Satterthwaite's scaled chi2); "
             "Holm's correction over all tests; posterior predictive p of the slice chi2 from Laplace draws",
    "which": "score (Lagrange multiplier) test at the fitted point with the new parameters at 0; the top "
             "candidates refitted: likelihood ratio, PSIS-LOO elpd (arviz.loo) from Laplace draws of the LS "
             "covariance with linearised residuals, prediction across heating/cooling branches; ranked by "
             "delta elpd among the refitted, then by score p-value",
}


def _f(v):
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


# ----------------------------------------------------------------------------------
# slices
# ----------------------------------------------------------------------------------
def _slices(campaign: Campaign, n_bins: int = 4):
    """(label, family, visit mask) of every slice of the campaign."""
    out = []
    up = campaign.up_axis()
    for lab in sorted(set(up.tolist())):
        out.append((f"up={lab or 'oblique'}", "up", up == lab))
    for sp in sorted(set(campaign.setpoint_C.tolist())):
        out.append((f"setpoint={sp:g}C", "setpoint", campaign.setpoint_C == sp))
    for d in ("heating", "cooling", "none"):
        m = campaign.direction == d
        if m.any() and not m.all():
            out.append((f"direction={d}", "direction", m))
    # crossed with the up axis (axis-aligned poses): where an angle or scale term shows as an
    # offset (its sign follows the pose, so it cancels in a one-way slice)
    aligned = sorted(set(up.tolist()) - {""})
    for fam, key, fmt in (("up_x_direction", campaign.direction, "{}"),
                          ("up_x_setpoint", campaign.setpoint_C, "{:g}C")):
        levels = sorted(set(key.tolist()))
        if len(levels) < 2 or len(aligned) < 2:
            continue
        for lab in aligned:
            for lev in levels:
                m = (up == lab) & (key == lev)
                if m.sum() >= 2:
                    out.append((f"up={lab}&{fam.split('_x_')[1]}={fmt.format(lev)}", fam, m))
    t_h = (campaign.time_s - campaign.time_s.min()) / 3600.0
    for lo, hi, m in _quantile_bins(t_h, n_bins):
        out.append((f"time={lo:.1f}-{hi:.1f}h", "time", m))
    blocks = campaign.setpoint_blocks
    since = np.zeros(campaign.n_visits)
    for b in np.unique(blocks):
        idx = np.flatnonzero(blocks == b)
        since[idx] = campaign.time_s[idx] - campaign.time_s[idx].min()
    if np.ptp(since) > 0:
        for lo, hi, m in _quantile_bins(since / 60.0, n_bins):
            out.append((f"since_change={lo:.0f}-{hi:.0f}min", "since_change", m))
    return out


def _quantile_bins(v, n_bins):
    if np.ptp(v) <= 0:
        return []
    edges = np.unique(np.quantile(v, np.linspace(0, 1, n_bins + 1)))
    bins = []
    for k in range(len(edges) - 1):
        lo, hi = edges[k], edges[k + 1]
        m = (v >= lo) & ((v < hi) if k < len(edges) - 2 else (v <= hi))
        if m.any():
            bins.append((lo, hi, m))
    return bins


def _holm(p):
    p = np.asarray(p, float)
    order = np.argsort(p)
    m = len(p)
    adj = np.empty(m)
    running = 0.0
    for k, i in enumerate(order):
        running = max(running, min(1.0, (m - k) * p[i]))
        adj[i] = running
    return adj


def _slice_tests(campaign, state: FitState, to_ug: np.ndarray, sigma: np.ndarray, n_draws: int,
                 rng) -> list[SliceTest]:
    """Offset, trend and excess chi2 of every slice x output axis (see module docstring)."""
    n = campaign.n_visits
    r = state.r
    Q = _hat_q(state.J)
    h = np.sum(Q * Q, axis=1)
    t_h = campaign.time_s / 3600.0
    gnom = np.abs(_nominal_g(campaign))
    tests = []
    chi2_args = []
    groups = []        # (index array) for the ppc of excess chi2
    # Laplace draws of the parameters, linearised residuals r + J delta (normalised)
    L = _chol(state.cov) if len(state.names) else None
    slices = [("axis", "axis", np.ones(n, bool))] + _slices(campaign)
    for label, family, mask in slices:
        vis = np.flatnonzero(mask)
        for i, a in enumerate(AXES):
            idx = vis * 3 + i
            m = len(idx)
            if m < 2:
                continue
            ra = r[idx]
            lab = a if family == "axis" else label
            horizontal = bool(np.all(gnom[vis, i] < 0.2))
            unit = "arcsec" if horizontal else "ug"
            conv = to_ug[i] * (1e-6 / ARCSEC if horizontal else 1.0)   # normalised -> unit, per sigma
            sig = float(np.sqrt(np.mean((sigma[vis, i] * state.s) ** 2)))
            Qs = Q[idx]
            # offset: a = 1 on the slice
            a_vec = np.ones(m)
            var = m - float(np.sum((Qs.T @ a_vec) ** 2))
            if var > 1e-9 * m:
                z = float(ra.sum() / math.sqrt(var))
                mean_out = float(np.mean(ra * sigma[vis, i] * state.s))
                tests.append(SliceTest(lab, family, a, "offset", m, z, math.nan,
                                       size=mean_out * to_ug[i] * (1e-6 / ARCSEC if horizontal else 1.0),
                                       unit=unit))
            # trend in time within the slice
            tt = t_h[vis] - t_h[vis].mean()
            if np.ptp(tt) > 0:
                var = float(tt @ tt - np.sum((Qs.T @ tt) ** 2))
                if var > 1e-9 * float(tt @ tt):
                    z = float(tt @ ra / math.sqrt(var))
                    slope = float(tt @ (ra * sigma[vis, i] * state.s) / (tt @ tt))   # output unit / h
                    tests.append(SliceTest(lab, family, a, "trend", m, z, math.nan,
                                           size=slope * to_ug[i], unit="ug/h"))
            # excess chi2: quadratic form of P_s (I - H), Satterthwaite
            mean = m - float(h[idx].sum())
            var2 = 2.0 * (m - 2.0 * float(h[idx].sum()) + float(np.sum((Qs.T @ Qs) ** 2)))
            if mean > 0.5 and var2 > 0:
                T = float(ra @ ra)
                g = var2 / (2 * mean)
                k = 2 * mean * mean / var2
                p = math.nan
                chi2_args.append((len(tests), T / g, k))
                excess = math.sqrt(max(T / mean - 1.0, 0.0)) * sig * to_ug[i]   # extra scatter
                tests.append(SliceTest(lab, family, a, "excess_chi2", m, T / mean, p,
                                       size=excess * (1e-6 / ARCSEC if horizontal else 1.0), unit=unit))
                groups.append((len(tests) - 1, idx))
    # p-values in one vectorised call per kind (normal for offset/trend, scaled chi2)
    zs = np.array([t.statistic if t.test != "excess_chi2" else 0.0 for t in tests])
    pz = 2.0 * stats.norm.sf(np.abs(zs))
    lz = (math.log(2.0) + stats.norm.logsf(np.abs(zs))) / math.log(10)
    for t, p, lp in zip(tests, pz, lz):
        if t.test != "excess_chi2":
            t.p_value, t.log10_p = float(p), float(lp)
    if chi2_args:
        ii, xx, kk = (np.array(v) for v in zip(*chi2_args))
        for i, p, x, k in zip(ii, stats.chi2.sf(xx, kk), xx, kk):
            tests[int(i)].p_value = float(p)
            tests[int(i)].log10_p = _chi2_logsf(float(x), float(k)) / math.log(10)
    adj = _holm([t.p_value for t in tests])
    for t, pa in zip(tests, adj):
        t.p_adjusted = float(pa)
    # posterior predictive check of each slice's chi2 from Laplace draws (linearised)
    if L is not None and n_draws > 0 and groups:
        delta = rng.standard_normal((n_draws, len(state.names))) @ L.T            # (S, p)
        rr = r[None, :] + delta @ state.J.T                                      # (S, N)
        for ti, idx in groups:
            d_obs = np.sum(rr[:, idx] ** 2, axis=1)
            d_rep = rng.chisquare(len(idx), n_draws)
            p = float(np.mean(d_rep >= d_obs))
            tests[ti].ppc_p = p
            # the offset / trend tests of the same slice share the ppc of its chi2
        ppc = {(t.slice, t.axis): t.ppc_p for t in tests if t.test == "excess_chi2"}
        for t in tests:
            if t.ppc_p is None:
                t.ppc_p = ppc.get((t.slice, t.axis))
    tests.sort(key=lambda t: (t.p_adjusted, t.log10_p))
    return tests


def _family_tests(campaign, state: FitState, Q) -> list[dict]:
    """Localisation by family: chi2 explained by the offsets of all slices x outputs of a
    family at once (after projecting out the fitted model), chi2(rank) under the null.
    Ranked by p-value: the family whose partition captures the misfit best comes first."""
    n = campaign.n_visits
    fams = {}
    for label, family, mask in _slices(campaign):
        fams.setdefault(family, []).append(mask)
    out = []
    for family, masks in fams.items():
        cols = []
        for m in masks:
            for i in range(3):
                a = np.zeros((n, 3))
                a[m, i] = 1.0
                cols.append(a.reshape(-1))
        A = np.array(cols).T
        A = A - Q @ (Q.T @ A)
        U, sv, _ = np.linalg.svd(A, full_matrices=False)
        rank = int(np.sum(sv > 1e-8 * max(sv[0], 1e-300))) if sv.size else 0
        if rank == 0:
            continue
        proj = U[:, :rank].T @ state.r
        stat = float(proj @ proj)
        logp = _chi2_logsf(stat, rank)
        out.append({"family": family, "slices": len(masks), "dof": rank, "chi2": stat,
                    "chi2_per_dof": stat / rank, "log10_p": logp / math.log(10)})
    out.sort(key=lambda d: d["log10_p"])
    return out


def _nominal_g(campaign):
    from ..models.campaign import nominal_gravity
    return nominal_gravity(campaign.axis1_deg, campaign.axis2_deg)


# ----------------------------------------------------------------------------------
# scores and refits
# ----------------------------------------------------------------------------------
def _effect_params(model_all: Model, effect: str) -> list[str]:
    return [s.name for s in model_all.parameters if s.effect == effect]


def _pe_sensitivity(full: JointProblem, campaign: Campaign, x_full, sigma) -> np.ndarray:
    """Added variance of each normalised residual per arcsec^2 of positioning error, (3n,)."""
    model = full.model
    p = model.to_internal(dict(zip(model.names, x_full)))
    v = pe.sensitivity_arcsec2(model, p, campaign.covariates(), campaign.gravity_g)
    return (v / sigma ** 2).reshape(-1)


def _score_mean(state: FitState, Jc: np.ndarray, Q: np.ndarray):
    """Score statistic and dof of new columns ``Jc`` (normalised) at the fitted point."""
    norms = np.linalg.norm(Jc, axis=0)
    keep = norms > 1e-12 * max(1.0, np.sqrt(state.r.size))
    if not keep.any():
        return None
    Jc = Jc[:, keep] / norms[keep]
    Jt = Jc - Q @ (Q.T @ Jc)
    U, sv, Vt = np.linalg.svd(Jt, full_matrices=False)
    rank = int(np.sum(sv > 1e-6 * max(sv[0], 1e-300))) if sv.size else 0
    if rank == 0:
        return None
    proj = U[:, :rank].T @ state.r
    S = float(proj @ proj)
    return S, rank


def _kurtosis_logp(z):
    z = np.asarray(z, float)
    if z.size < 20:
        return 0.0, 0.0
    stat, _ = stats.kurtosistest(z, alternative="greater")
    return float(stat), float(stats.norm.logsf(stat))


def _position_score(state: FitState, w: np.ndarray, h: np.ndarray, noise_known: bool):
    """One-sided score test of an added variance tau * w (w per normalised residual) at tau = 0."""
    r2 = state.r ** 2
    if noise_known:
        u = 0.5 * float(np.sum(w * (r2 - (1.0 - h))))
        info = 0.5 * float(np.sum(w * w))
    else:
        wc = w - np.mean(w)           # orthogonal to the estimated overall scale
        u = 0.5 * float(np.sum(wc * (r2 - (1.0 - h))))
        info = 0.5 * float(np.sum(wc * wc))
    if info <= 0:
        return None
    z = u / math.sqrt(info)
    return z, float(stats.norm.logsf(z))


def _loglik_pointwise(r, var_scale=None, nu=math.inf):
    """Pointwise log-likelihood of normalised residuals (up to a common constant)."""
    if var_scale is not None:
        return -0.5 * r * r / var_scale - 0.5 * np.log(var_scale) - 0.5 * np.log(2 * np.pi)
    return ht.logpdf(r, nu)


def _loo(state: FitState, n_draws: int, rng, var_scale=None, nu=math.inf):
    """PSIS-LOO elpd with Laplace draws from the LS covariance, linearised residuals.

    The left-out unit is a visit (its three outputs together): pointwise values per visit."""
    import arviz as az     # (its cache folder is the entry point's business: XDG_CACHE_HOME)

    p = len(state.names)
    L = _chol(state.cov)
    delta = rng.standard_normal((n_draws, p)) @ L.T
    # r is normalised by s; parameters in reporting units; J = dr/dx (normalised)
    rr = state.r[None, :] + delta @ state.J.T
    ll = _loglik_pointwise(rr, var_scale, nu) - (math.log(state.s) if state.s != 1.0 else 0.0)
    ll = ll.reshape(n_draws, -1, 3).sum(axis=2)
    idata = az.from_dict(posterior={"theta": delta[None, :, 0]}, log_likelihood={"obs": ll[None]})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = az.loo(idata, pointwise=True)
    pointwise = np.asarray(res.loo_i).reshape(-1)
    k = np.asarray(res.pareto_k).reshape(-1)
    return float(res.elpd_loo), float(res.se), pointwise, float(np.max(k))


def _loglik_total(state: FitState, var_scale=None, nu=math.inf) -> float:
    return float(np.sum(_loglik_pointwise(state.r, var_scale, nu))) - state.r.size * math.log(state.s)


def _fit_position_error(full, campaign, base: FitState, names, sigma, noise_known):
    """ML of the positioning-error variance (and of the noise scale when it is estimated),
    alternating with the mean refitted on the new weights (3 rounds)."""
    x = base.x_full
    tau, state, var_scale = 0.0, base, np.ones(base.r.size)
    for _ in range(3):
        w = _pe_sensitivity(full, campaign, x, sigma)     # added variance per arcsec^2, sigma units
        r2 = full.residuals(x) ** 2                       # raw, normalised by sigma only

        def nll(theta):
            log_s2, log_tau = (0.0, theta[0]) if noise_known else theta
            v = math.exp(log_s2) + math.exp(log_tau) * w
            return 0.5 * float(np.sum(r2 / v + np.log(v)))
        t0 = [math.log(max(tau, 1e-4))] if noise_known else [2 * math.log(base.s), math.log(max(tau, 1e-4))]
        res = optimize.minimize(nll, t0, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-6})
        log_s2, log_tau = (0.0, res.x[0]) if noise_known else res.x
        tau = math.exp(log_tau) if log_tau > -12 else 0.0
        var_scale = 1.0 + tau * w / math.exp(log_s2)        # variance relative to s^2
        state = _fit(full, names, x, noise_known, scale=np.sqrt(var_scale))
        x = state.x_full
    # keep the residuals normalised by the measurement noise only; var_scale carries the rest
    root = np.sqrt(var_scale)
    state.r, state.J = state.r * root, state.J * root[:, None]
    state.var_scale = var_scale
    state.extra_params = {"position_error_sigma": {"value": math.sqrt(tau), "unit": "arcsec"}}
    return state


def _fit_heavy_tails(base: FitState):
    """Student-t dof by profile likelihood with the least-squares mean (plug-in)."""
    grid = np.array([2.2, 2.5, 3.0, 3.5, 4.0, 5.0, 7.0, 10.0, 20.0, 50.0])
    ll = [float(np.sum(ht.logpdf(base.r, nu))) for nu in grid]
    nu = float(grid[int(np.argmax(ll))])
    state = FitState(base.names, base.x_full, base.r, base.J, base.cov, base.chi2, base.dof, base.s,
                     base.converged, nu=nu, extra_params={"heavy_tails_dof": {"value": nu, "unit": "1"}})
    return state


def _cross_group(campaign, noise, effects_names, names, T0, x_start_full, noise_known):
    """Fit on one branch, predict the other: log predictive density of the held-out branch
    (normalised units, Gaussian plug-in), summed over both directions. None if not possible."""
    br = campaign.branch
    if not ((br == -1).any() and (br == 1).any()):
        return None
    total = 0.0
    for train_b, test_b in ((-1.0, 1.0), (1.0, -1.0)):
        train = campaign.select(np.flatnonzero(br != test_b))
        test = campaign.select(np.flatnonzero(br == test_b))
        model = Model(tuple(EFFECTS), T0)
        ptr = JointProblem(train, model, noise.sigma[br != test_b])
        probs = identifiability_problems(train, Model(effects_names, T0))
        st = _fit(ptr, [n for n in names if n not in probs], x_start_full, noise_known)
        pte = JointProblem(test, model, noise.sigma[br == test_b])
        r = pte.residuals(st.x_full) / st.s
        total += float(np.sum(-0.5 * r * r))
    return total


# ----------------------------------------------------------------------------------
# the diagnosis
# ----------------------------------------------------------------------------------
def diagnose(campaign: Campaign, model: Sequence[str] = DEFAULT_EFFECTS, *,
             candidates: Optional[Sequence[str]] = None, top: int = 3, alpha: float = ALPHA,
             n_draws: int = 400, reference_temperature_C: float = 20.0, cross_group: bool = True,
             slices_after: bool = True, seed: int = 0) -> Diagnosis:
    """Diagnose the gap between ``model`` (effect names) fitted to ``campaign`` and the data.

    ``candidates`` default to every effect of the vocabulary not in ``model``. ``top``
    candidates (by score) are refitted (``cross_group``: also fitted on one hysteresis branch
    and scored on the other; ``slices_after``: slice tests redone after each refit). Returns a :class:`Diagnosis` (``to_dict`` gives
    the results-json ``triadcal.diagnosis`` v1 document).
    """
    rng = np.random.default_rng(seed)
    model = tuple(dict.fromkeys(model))
    unknown = [m for m in model if m not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown model effect(s) {unknown}; choose from {', '.join(EFFECTS)}")
    if len(campaign.units) != 1 or len(set(campaign.state.tolist())) != 1:
        raise ValueError("diagnose takes one unit in one mechanical state (select one with Campaign.select)")
    cands = [c for c in (candidates if candidates is not None else VOCABULARY) if c not in model]
    bad = [c for c in cands if c not in VOCABULARY]
    if bad:
        raise ValueError(f"unknown candidate effect(s) {bad}; the vocabulary is {', '.join(VOCABULARY)}")
    T0 = reference_temperature_C
    notes = []
    noise = noise_of(campaign)
    sigma = noise.sigma
    model_all = Model(tuple(EFFECTS), T0)
    full = JointProblem(campaign, model_all, sigma)

    # -- the base fit -------------------------------------------------------------
    base_model = Model(model, T0)
    problems = identifiability_problems(campaign, base_model)
    start = start_values(campaign, model_all)
    x0 = np.array([start[n] for n in model_all.names])
    probe_x = x0.copy()
    for s in model_all.parameters:
        if s.effect != "core":
            probe_x[full.index[s.name]] = s.typical if s.effect in model else 0.0
    names0 = [n for n in base_model.names if n not in problems]
    _, Jp = full.residuals_and_jacobian(probe_x)
    # the null space of J is that of R in J = QR (same column norms and singular values): cheaper
    R0 = np.linalg.qr(Jp[:, [full.index[n] for n in names0]], mode="r")
    problems.update(null_space_problems(R0, names0))
    for k, v in problems.items():
        notes.append(f"{k} not estimated (held at 0): {v}")
    names = [n for n in base_model.names if n not in problems]
    base = _fit(full, names, x0, noise.known)
    Q = _hat_q(base.J)
    h = np.sum(Q * Q, axis=1)
    def unit_of(n):
        u = model_all.spec[n].unit
        return u.replace("/V", "/" + campaign.output_unit) if campaign.output_unit != "V" else u

    K = np.abs(np.array([base.x_full[full.index[f"K_{a}"]] for a in AXES]))
    to_ug = K * 1e6                                     # output unit -> ug
    sig_ug = sigma * to_ug[None, :]
    floor_ug = float(np.sqrt(np.mean(sig_ug ** 2))) * base.s     # with estimated noise: s * weights

    # -- which: score tests -----------------------------------------------------------
    _, Jfull = full.residuals_and_jacobian(base.x_full)
    Jfull = Jfull / base.s
    cand_objs = []
    for c in cands:
        if c == "position_error":
            w = _pe_sensitivity(full, campaign, base.x_full, sigma)
            sc = _position_score(base, w, h, noise.known)
            if sc is None:
                cand_objs.append(Candidate(c, False, "no pose makes an output sensitive to positioning errors"))
            else:
                cand_objs.append(Candidate(c, True, k=1, score=sc[0] ** 2 * (1 if sc[0] > 0 else -1),
                                           score_logp=sc[1]))
            continue
        if c == "heavy_tails":
            z = base.r / np.sqrt(np.clip(1.0 - h, 1e-6, None))
            if z.size < 20:
                cand_objs.append(Candidate(c, False, "fewer than 20 residuals: the tails cannot be tested"))
                continue
            stat, logp = _kurtosis_logp(z)
            cand_objs.append(Candidate(c, True, k=1, score=stat * abs(stat), score_logp=logp))
            continue
        pn = _effect_params(model_all, c)
        design = identifiability_problems(campaign, Model(model + (c,), T0))
        usable = [n for n in pn if n not in design]
        if not usable:
            cand_objs.append(Candidate(c, False, "invisible on this design: " + design[pn[0]]))
            continue
        sc = _score_mean(base, Jfull[:, [full.index[n] for n in usable]], Q)
        if sc is None:
            why = ("its sensitivity is zero at the fitted point (thermal lag acts only through temperature "
                   "coefficients: add a tempco to the model to test it)" if c == "thermal_lag" else
                   "its sensitivity is zero or already in the fitted model's span on this design")
            cand_objs.append(Candidate(c, False, why))
            continue
        S, k = sc
        if noise.known:
            logp = _chi2_logsf(S, k)
        else:
            logp = float(stats.f.logsf(S / k, k, max(base.dof - k, 1)))
        cand_objs.append(Candidate(c, True, k=k, score=S, score_logp=logp, params=usable))

    # -- gap -------------------------------------------------------------------------
    gap_tests = {}
    if noise.known and base.dof > 0:
        gap_tests["chi2"] = float(stats.chi2.sf(base.chi2, base.dof))
    z = base.r / np.sqrt(np.clip(1.0 - h, 1e-6, None))
    if z.size >= 20:
        gap_tests["kurtosis"] = float(math.exp(_kurtosis_logp(z)[1]))
    for c in cand_objs:
        if c.testable and c.effect != "heavy_tails":
            gap_tests[f"score:{c.effect}"] = c.score_p
    keys = list(gap_tests)
    adj = _holm([gap_tests[k] for k in keys]) if keys else []
    gap_adj = dict(zip(keys, (float(a) for a in adj)))
    significant = bool(keys) and min(gap_adj.values()) < alpha
    gap = {"chi2_dof": _f(base.chi2_dof) if noise.known else None, "chi2": base.chi2, "dof": base.dof,
           "p_value": _f(gap_tests.get("chi2")), "significant": significant,
           "tests": {k: {"p_value": _f(gap_tests[k]), "p_holm": _f(gap_adj[k])} for k in keys},
           "residual_rms_ug": float(np.sqrt(np.mean((base.r * base.s) ** 2 * sig_ug.reshape(-1) ** 2))),
           "noise_floor_ug": floor_ug,
           "testable": ("chi2 against its distribution with the known noise, tails, and candidate scores"
                        if noise.known else
                        "noise estimated from the residuals: the chi2 level is not testable (it defines the "
                        "noise); structure is: candidate scores (F form), tails, slice offsets/trends and "
                        "the variance pattern of positioning errors")}

    # -- where -------------------------------------------------------------------------
    slices = _slice_tests(campaign, base, to_ug, sigma, n_draws, rng)

    # -- refit the top candidates ------------------------------------------------------
    testable = sorted([c for c in cand_objs if c.testable], key=lambda c: c.score_logp)
    elpd0, se0, pw0, k0 = _loo(base, n_draws, rng)
    if k0 > 0.7:
        notes.append(f"base model: Pareto k up to {k0:.2f} > 0.7, the PSIS-LOO elpd is unreliable")
    base_ll = _loglik_total(base)
    base_u = base.u()
    base_val = base.value(full)
    cross0 = _cross_group(campaign, noise, model, names, T0, base.x_full, noise.known) if cross_group else None
    n_sig_before = sum(1 for s in slices if s.p_adjusted < alpha)
    for c in testable[:top]:
        if c.effect == "position_error":
            st = _fit_position_error(full, campaign, base, names, sigma, noise.known)
            var_scale, nu, k_extra, new_names = st.var_scale, math.inf, 1, []
            ll = _loglik_total(st, var_scale=var_scale)
            lr_p = 0.5 * float(stats.chi2.sf(max(2 * (ll - base_ll), 0.0), 1))
        elif c.effect == "heavy_tails":
            st = _fit_heavy_tails(base)
            var_scale, nu, new_names = None, st.nu, []
            ll = _loglik_total(st, nu=nu)
            lr_p = 0.5 * float(stats.chi2.sf(max(2 * (ll - base_ll), 0.0), 1))
        else:
            new_names = list(c.params)
            st = _fit(full, names + new_names, base.x_full, noise.known)
            var_scale, nu = None, math.inf
            if noise.known:
                ll = _loglik_total(st)
                lr_p = float(stats.chi2.sf(max(base.chi2 - st.chi2, 0.0), len(new_names)))
            else:
                n_obs = st.r.size
                ll = base_ll + 0.5 * n_obs * math.log(base.chi2 / max(st.chi2, 1e-300))
                F = (base.chi2 - st.chi2) / len(new_names) / (st.chi2 / max(st.dof, 1))
                lr_p = float(stats.f.sf(max(F, 0.0), len(new_names), max(st.dof, 1)))
        elpd, se, pw, kmax = _loo(st, n_draws, rng, var_scale=var_scale, nu=nu)
        diff = pw - pw0
        d_elpd, d_se = float(diff.sum()), float(math.sqrt(diff.size) * np.std(diff))
        # slice statistics after: residuals standardised by the fitted noise model (for a
        # Student-t, its normal scores Phi^-1(F_t(r)): Gaussian when the noise model holds)
        r_after = st.r / (np.sqrt(var_scale) if var_scale is not None else 1.0)
        if math.isfinite(nu):
            r_after = ht.normal_scores(r_after, nu)
        st_for_slices = FitState(st.names, st.x_full, r_after, st.J / (np.sqrt(var_scale)[:, None]
                                 if var_scale is not None else 1.0), st.cov, st.chi2, st.dof, st.s, st.converged)
        n_sig_after = None
        if slices_after:
            sl_after = _slice_tests(campaign, st_for_slices, to_ug, sigma, 0, rng)
            n_sig_after = sum(1 for s in sl_after if s.p_adjusted < alpha)
        chi2_after = float(np.sum(r_after ** 2) * st.s ** 2)
        dof_after = st.r.size - len(st.names) - (1 if c.effect in NOISE_EFFECTS else 0)
        rms_after = float(np.sqrt(np.mean((st.r * st.s) ** 2 * sig_ug.reshape(-1) ** 2)))
        # parameter shifts in units of their uncertainty
        after_val = st.value(full)
        shifts = {n: {"shift": after_val[n] - base_val[n], "u_before": base_u[n],
                      "in_u": (after_val[n] - base_val[n]) / base_u[n] if base_u[n] > 0 else None,
                      "unit": unit_of(n)}
                  for n in names}
        worst = max(shifts, key=lambda n: abs(shifts[n]["in_u"] or 0.0)) if shifts else None
        cross = None
        if cross_group and c.effect not in NOISE_EFFECTS:
            cg = _cross_group(campaign, noise, model + (c.effect,), names + new_names, T0, base.x_full,
                              noise.known)
            cross = None if cg is None or cross0 is None else cg - cross0
        refit = {
            "delta_loglik": ll - base_ll, "lr_p_value": _f(lr_p),
            "elpd_loo": elpd, "elpd_se": se, "delta_elpd": d_elpd, "delta_elpd_se": d_se,
            "pareto_k_max": kmax,
            "cross_branch_delta_lpd": _f(cross) if cross is not None else None,
            "gap_before": {"chi2_dof": _f(base.chi2_dof), "residual_rms_ug": gap["residual_rms_ug"],
                           "noise_floor_ug": floor_ug, "elpd_loo": elpd0, "significant_slices": n_sig_before},
            "gap_after": {"chi2_dof": _f(chi2_after / dof_after if dof_after > 0 else float("nan")),
                          "residual_rms_ug": rms_after, "noise_floor_ug": floor_ug, "elpd_loo": elpd,
                          "significant_slices": n_sig_after},
            "new_parameters": ({n: {"value": after_val.get(n, float(st.x_full[full.index[n]])),
                                    "u": float(math.sqrt(max(st.cov[st.names.index(n), st.names.index(n)], 0))),
                                    "unit": unit_of(n)} for n in new_names}
                               if new_names else dict(st.extra_params)),
            "parameter_shifts": {n: {k: _f(v) if not isinstance(v, str) else v for k, v in s.items()}
                                 for n, s in shifts.items()},
            "largest_shift": ({"parameter": worst, "in_u": _f(shifts[worst]["in_u"])} if worst else None),
        }
        c.refit = refit
        if kmax > 0.7:
            notes.append(f"{c.effect}: Pareto k up to {kmax:.2f} > 0.7, the PSIS-LOO elpd is unreliable "
                         "(few visits or influential ones); rely on the likelihood ratio")
    # -- rank ---------------------------------------------------------------------------
    refitted = sorted([c for c in testable if c.refit], key=lambda c: -c.refit["delta_elpd"])
    rest = [c for c in testable if not c.refit]
    order = refitted + rest + [c for c in cand_objs if not c.testable]
    for i, c in enumerate(order, 1):
        c.rank = i
    # -- verdict ------------------------------------------------------------------------
    verdict = {"effect": None}
    if not significant:
        verdict["reason"] = f"no significant gap (smallest Holm-adjusted p = {min(gap_adj.values(), default=1.0):.3g} >= {alpha:g})"
    elif not refitted:
        verdict["reason"] = "significant gap, but no candidate effect is testable on this design"
    else:
        best = refitted[0]
        if best.refit["lr_p_value"] is not None and best.refit["lr_p_value"] < alpha and best.refit["delta_elpd"] > 0:
            verdict = {"effect": best.effect,
                       "evidence": f"score p = {best.score_p:.3g}, LR p = {best.refit['lr_p_value']:.3g}, "
                                   f"delta elpd = {best.refit['delta_elpd']:.1f} +- {best.refit['delta_elpd_se']:.1f}"}
            if len(refitted) > 1:
                second = refitted[1]
                verdict["runner_up"] = second.effect
                verdict["delta_elpd_to_runner_up"] = best.refit["delta_elpd"] - second.refit["delta_elpd"]
        else:
            verdict["reason"] = "significant gap that none of the candidate effects explains"
    fit = {"chi2_dof": _f(base.chi2_dof), "n_obs": int(base.r.size), "n_params": len(names),
           "converged": base.converged, "parameters": {n: {"value": base_val[n], "u": base_u[n],
                                                           "unit": unit_of(n)} for n in names}}
    return Diagnosis(model=model, noise_known=noise.known, noise=noise.description, gap=gap, slices=slices,
                     candidates=order, verdict=verdict, fit=fit, notes=notes, source=campaign.source, alpha=alpha,
                     residuals=base.r.reshape(-1, 3).copy(), families=_family_tests(campaign, base, Q))
