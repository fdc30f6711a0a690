"""Where the normalised residuals disagree with the noise: offset, trend and excess-chi2 tests
per slice with exact null moments of the linearised fit, Holm-corrected, and a posterior
predictive p-value per slice (docs/diagnosis.md, "Where").
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ...models.campaign import Campaign
from ...models.sensor import AXES
from ...models.units import ARCSEC
from .candidates import _nominal_g
from .fitting import FitState, _chi2_logsf, _chol, _hat_q
from .results import SliceTest

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
             "angle_tempco2": ("up_x_setpoint", "setpoint", "time"),
             "scale_tempco2": ("up_x_setpoint", "setpoint", "time"),
             "bias_tempco2": ("setpoint", "up_x_setpoint", "time"),
             "angle_tempco3": ("up_x_setpoint", "setpoint", "time"),
             "scale_tempco3": ("up_x_setpoint", "setpoint", "time"),
             "bias_tempco3": ("setpoint", "up_x_setpoint", "time"),
             "hysteresis": ("up_x_direction", "direction"),
             "thermal_lag": ("since_change", "direction", "up_x_direction", "setpoint"),
             "bias_drift": ("time", "setpoint"),
             "bias_warmup": ("time", "since_change"), "scale_warmup": ("time", "up_x_setpoint"),
             "scale_nonlinearity": ("up",), "scale_asymmetry": ("up",),
             # third-order and cross-axis terms: offsets of the oblique poses (slice up=oblique)
             "scale_cubic": ("up",), "cross_coupling": ("up",), "g_dependent_misalignment": ("up",),
             "position_error": FAMILIES, "heavy_tails": ()}


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
