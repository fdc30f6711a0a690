"""The classical method's own check of its redundancy (docs/classical.md, "Redundancy gate"): the
positions beyond the five quantities per output and setpoint must agree with each other, one by one
(an outlier test on the studentised residuals of the per-setpoint linear models) and as a whole
(their scatter against a known noise).

The outlier test studentises each residual by the noise it has, which may differ from setpoint to
setpoint. With a known noise per visit (sd_* columns, Q) the models are weighted by the visit's
known variance plus the bench's own scatter, estimated per output (:func:`bench_scatter`,
Paule-Mandel), so one level holds in every block. Without it, the residuals are studentised by one
level pooled over the blocks, and where Bartlett's test says the blocks' levels differ a residual
must also stand out against its own block's level (:func:`worst_studentised`). An outside probe
gave honest data with the noise x exp((T - 20)/60) status ``inconsistent_redundancy`` 6 times in 20
(the hot block's residuals against one pooled level, Bonferroni p 0.0006), while the scatter against
the known noise was 0.95 of it."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..models.campaign import Campaign
from ..models.sensor import AXES
from .gates import DEFAULT_CONFIG, GateConfig, GateOutcome
from .noise_model import HOMOGENEITY_P, bartlett_p

#: a block with fewer residual degrees of freedom than this has no level of its own to studentise by
#: (the externally studentised residual has nu - 1 dof; below 3 its t distribution has no variance)
BLOCK_DOF_MIN = 3


def leverages(X: np.ndarray) -> np.ndarray:
    """The diagonal h_ii of the hat matrix of the least squares with design ``X`` (rank-revealing:
    columns the data cannot determine do not count)."""
    U_, sv, _ = np.linalg.svd(X, full_matrices=False)
    Ur = U_[:, sv > sv[0] * 1e-10] if len(sv) and sv[0] > 0 else U_[:, :0]
    return np.sum(Ur ** 2, axis=1)


def _pooled(parts, s_a: float, what: str) -> list:
    """``(p1, t, idx_i, how)`` of each residual of one output, internally studentised by the
    output's pooled level ``s_a``, normal: ``t = |e_i| / (s_a sqrt(1 - h_ii))``, ``p1 = 2 Phi(-t)``."""
    out = []
    for e, h, idx in parts:
        keep = h < 1 - 1e-9
        t = np.abs(e[keep]) / (s_a * np.sqrt(1 - h[keep]))
        out += [(float(p), float(x), int(i), what) for p, x, i in zip(2.0 * stats.norm.sf(t), t, idx[keep])]
    return out


def _own_block(parts, p_blocks: float) -> dict:
    """Per visit index: ``(p1, t, how)`` of the residual externally studentised by its own block's
    level (Cook & Weisberg 1982, eq. 2.2.9): ``r = e_i / (s_b sqrt(1 - h_ii))``, ``t = r sqrt((nu_b
    - 1) / (nu_b - r^2))`` ~ Student t with ``nu_b - 1`` dof; blocks of fewer than
    :data:`BLOCK_DOF_MIN` dof have no level of their own (absent)."""
    out = {}
    for e, h, idx in parts:
        keep = h < 1 - 1e-9
        nu_b = len(e) - int(round(float(np.sum(h))))
        s2_b = float(np.sum(e ** 2)) / nu_b if nu_b > 0 else 0.0
        if nu_b < BLOCK_DOF_MIN or s2_b <= 0:
            continue
        r2 = np.minimum(e[keep] ** 2 / (s2_b * (1 - h[keep])), nu_b * (1 - 1e-12))
        t = np.sqrt(r2 * (nu_b - 1) / (nu_b - r2))
        how = (f"also by its setpoint block's own noise level ({nu_b} dof), the blocks' levels differing "
               f"(Bartlett p = {p_blocks:.2g})")
        for p, x, i in zip(2.0 * stats.t.sf(t, nu_b - 1), t, idx[keep]):
            out[int(i)] = (float(p), float(x), how)
    return out


def _least_likely(candidates, n: int, campaign: Campaign, ai: int, best: tuple) -> tuple:
    """The better of ``best`` and the least likely of ``candidates`` ``(p1, t, i, how)`` of output ai."""
    for p1, t, i, how in candidates:
        if p1 < best[3] or (p1 == best[3] and t > best[0]):
            line = f", line {int(campaign.lines[i])}" if campaign.lines is not None else ""
            best = (t, n, f"w_{AXES[ai]} at position {campaign.position[i]}{line}" + (f", studentised {how}" if how else ""), p1)
    return best


def worst_studentised(resid, rss, dof, campaign: Campaign, what: str = "") -> tuple:
    """The residual of the per-setpoint models least likely under the noise: ``(t, n, where, p1)``.

    ``resid[a]`` holds ``(e, h, idx)`` per setpoint block of output a (residuals, leverages, visit
    indices). Each residual is internally studentised by the output's level pooled over the
    blocks, ``s_a^2 = RSS_a / dof_a``, normal (:func:`_pooled`). Where Bartlett's test over the
    blocks' levels rejects one level (p < HOMOGENEITY_P; with ``what`` empty, i.e. residuals not
    already weighted by a known noise), a residual counts by the larger of that p and its p
    externally studentised by its own block's level (:func:`_own_block`): a gross error stands out
    both ways, the residuals of an honestly noisier block only against the pooled level, and an
    outlier that itself makes its block look noisier still stands out against the pool. ``n``
    counts the residuals (Bonferroni), ``where`` names the output, position and line of the least
    likely one and says how it was studentised."""
    best = (0.0, 0, "", 1.0)
    n = sum(int(np.sum(h < 1 - 1e-9)) for parts in resid for _, h, _ in parts)
    for ai, parts in enumerate(resid):
        if dof[ai] <= 0 or rss[ai] <= 0:
            continue
        cands = _pooled(parts, math.sqrt(rss[ai] / dof[ai]), what)
        nu = [len(e) - int(round(float(np.sum(h)))) for e, h, _ in parts]
        tested = [(float(np.sum(e ** 2)) / v, v) for (e, _, _), v in zip(parts, nu) if v > 0 and np.any(e)]
        p_blocks = bartlett_p(*map(np.array, zip(*tested))) if len(tested) >= 2 and not what else 1.0
        if p_blocks < HOMOGENEITY_P:
            own = _own_block(parts, p_blocks)
            cands = [(max(p1, own[i][0]), t, i, own[i][2]) if i in own else (p1, t, i, how)
                     for p1, t, i, how in cands]
        best = _least_likely(cands, n, campaign, ai, best)
    return best


def _weighted_fit(groups, t2: float, n_blocks: int = 0) -> tuple:
    """``(chi2, per_block)`` of the per-setpoint models weighted by ``1 / (s2 + t2)``: ``groups``
    holds ``(D, y, s2, order)`` stacked over the blocks of one shape (``order``: their places in
    the caller's list). Each block's residual is its weighted outputs less their projection on the
    columns of its weighted design that ``numpy.linalg.lstsq`` keeps (singular values above ``eps
    max(n, p)`` of the largest); chi^2 sums them. With ``n_blocks``, ``per_block[i]`` is ``(e, h)``
    of block i, ``h`` the leverages of :func:`leverages` (its own rank rule)."""
    chi2, per_block = 0.0, [None] * n_blocks
    for D, y, s2, order in groups:
        w = 1.0 / np.sqrt(s2 + t2)
        Dw, yw = D * w[..., None], y * w
        U_, sv, _ = np.linalg.svd(Dw, full_matrices=False)
        keep = sv > sv[:, :1] * (np.finfo(float).eps * max(Dw.shape[1:]))
        e = yw - np.einsum("bnk,bk->bn", U_, np.einsum("bnk,bn->bk", U_, yw) * keep)
        chi2 += float(np.sum(e * e))
        if n_blocks:
            h = np.sum(U_ ** 2 * ((sv > sv[:, :1] * 1e-10) & (sv[:, :1] > 0))[:, None, :], axis=2)
            for k, i in enumerate(order):
                per_block[i] = (e[k], h[k])
    return chi2, per_block


def bench_scatter(blocks) -> tuple:
    """``(tau2, chi2, resid)`` of one output: the variance ``tau2`` (output unit^2) that the bench's own
    errors add to every visit's mean output beyond its known noise ``s2``, by Paule & Mandel (1982,
    J. Res. NBS 87, 377): the smallest ``tau2 >= 0`` at which the per-setpoint models weighted by
    ``1 / (s2 + tau2)`` leave ``chi2 = dof`` (0 when the known noise alone explains the scatter).
    ``blocks``: ``(D, y, s2, idx)`` per setpoint block (design, mean outputs, known variances,
    visits); ``resid``: ``(e, h, idx)`` per block of that weighted fit, for :func:`worst_studentised`.

    chi^2 falls monotonically with ``tau2``; its root is bracketed by quadrupling and found by
    Brent's method to 1e-7 of ``tau2``, the blocks of one shape solved as one stack
    (tests/test_classical_redundancy.py holds them to the block-by-block least squares)."""
    if not blocks:
        return 0.0, 0.0, []
    shapes: dict = {}
    for i, (D, y, s2, _) in enumerate(blocks):
        shapes.setdefault(np.shape(D), []).append((D, y, s2, i))
    groups = [tuple(np.stack(z) for z in zip(*g)) for g in shapes.values()]

    def fit(t2):
        chi2, per = _weighted_fit(groups, t2, len(blocks))
        return chi2, [(e, h, idx) for (e, h), (_, _, _, idx) in zip(per, blocks)]

    from .classical_structure import paule_mandel

    dof = sum(int(np.sum(D.shape[1] - np.linalg.matrix_rank(D))) for D, _, _, _ in groups)
    chi2, resid = fit(0.0)
    if dof <= 0 or chi2 <= dof:
        return 0.0, chi2, resid
    t2 = paule_mandel(lambda t: _weighted_fit(groups, t)[0], dof, np.concatenate([s2 for _, _, s2, _ in blocks]),
                     math.inf)[0]
    chi2, resid = fit(t2)
    return t2, chi2, resid


def worst_studentised_known(design, dof, campaign: Campaign) -> tuple:
    """:func:`worst_studentised` against a known noise per visit (sd_* columns, Q): the residuals of
    the per-setpoint models weighted by ``1 / (s2_i + tau2)``, the known variance of each visit plus
    the bench's own scatter (:func:`bench_scatter`, per output), their pooled level then one in every
    block whatever the noise of each visit. An outside probe: honest sd_* with the noise x exp((T -
    20)/60) refused 6 of 20 against one level pooled over blocks; on tests/independent_bench.py with
    the noise x exp((T - 20)/30), 61 of 300 refused before, none now (with 2 arcsec of bench scatter
    per visit: 21 of 100 before, 1 now); a visit mis-read by 30 sigma at 80 degC caught 20 of 20, as
    before. The price: the estimated scatter takes up part of a small error in a quiet block, so a 12
    sigma mis-read at -40 degC (1.7 times the noise at 20 degC) is caught 0 of 20 (2 before), and a 10
    sigma one at 20 degC 5 of 20 (1 before)."""
    resid, rss, taus = [], np.zeros(3), []
    for ai, blocks in enumerate(design):
        t2, chi2, r = bench_scatter(blocks) if blocks else (0.0, 0.0, [])
        resid.append(r)
        rss[ai] = chi2
        taus.append(math.sqrt(t2))
    what = ("against the known noise of each visit plus the bench's scatter (Paule-Mandel: "
            + ", ".join(f"w_{a} {t:.3g}" for a, t in zip(AXES, taus)) + " output units)")
    return worst_studentised(resid, rss, dof, campaign, what)


def redundancy_gate(chi2: np.ndarray, dof: np.ndarray, noise_known: bool, noise_what: str,
                    config: GateConfig = DEFAULT_CONFIG, noise_source: str = "sd",
                    worst: tuple = (0.0, 0, "", 1.0)) -> GateOutcome:
    """The classical method's own check of its redundancy: the positions beyond the five
    quantities per output and setpoint (eq. 2-3 use the up/down differences and the balanced
    mean; the per-setpoint linear model of :func:`.classical.residual_design` leaves ``dof`` residual
    degrees of freedom) must agree.

    Two tests, both reported, and the gate fails (status ``inconsistent_redundancy``) on either:

    - *an outlier*: the studentised residual least likely under the noise
      (:func:`worst_studentised`, ``worst`` is ``(t, n, where, p1)``), Bonferroni p-value
      ``min(1, n p1)`` < ``gof_p_min`` (one mislabelled or mis-read position).
    - *the scatter against the known noise* (``chi2`` per output, chi^2 with ``sum(dof)``
      dof under the model), when the uncertainties come from that noise (``noise_source``
      "sd"): significant (p < ``gof_p_min``) and material (chi2/dof > ``gof_ratio_max``), as the
      goodness-of-fit gate. With the default ``noise_source`` "residuals" the scatter itself
      sets the uncertainties, bench positioning errors included, so its ratio to the output
      noise is reported (how much the bench adds) but does not fail the gate.
    """
    n = int(np.sum(dof))
    if n <= 0:
        return GateOutcome("redundancy", None, "inconsistent_redundancy",
                           "not testable: the plan has no redundant positions (no residual degrees of freedom)")
    t, n_res, where, p1 = worst
    p_out = min(1.0, max(n_res, 1) * p1) if n_res else 1.0
    out_fails = p_out < config.gof_p_min
    parts = [f"largest studentised residual {t:.3g} ({where}; Bonferroni p = {p_out:.2g} over {n_res})"]
    scatter_fails = False
    ratio = None
    if noise_known:
        total = float(np.sum(chi2))
        p = float(stats.chi2.sf(total, n))
        ratio = total / n
        per = ", ".join(f"w_{a}: {c / max(d, 1):.3g}" for a, c, d in zip(AXES, chi2, dof))
        scatter_fails = noise_source == "sd" and p < config.gof_p_min and ratio > config.gof_ratio_max
        parts.append(f"scatter chi2/dof = {ratio:.4g} against the known noise ({noise_what}; {n} dof, p = {p:.2g}; "
                     f"{per})" + ("" if noise_source == "sd" else
                                  ": informative only, the uncertainties come from the residuals themselves"))
    else:
        parts.append("scatter not testable against a known noise (no sd_* columns or Q_V2s)")
    reason = "; ".join(parts)
    if out_fails:
        reason += (f"; p < {config.gof_p_min:g}: one position disagrees with the others (a mislabelled position, "
                   "a mis-read visit, or a swapped or inverted column; or a noise with heavier tails than the "
                   "normal, whose outliers a test of normal residuals flags: `triadcal diagnose` tells them apart, "
                   "and `fit --method joint --loss student_t` is made for them)")
    if scatter_fails:
        reason += (f"; p < {config.gof_p_min:g} and ratio > {config.gof_ratio_max:g}: the positions scatter beyond "
                   "the noise the uncertainties assume")
    return GateOutcome("redundancy", not (out_fails or scatter_fails), "inconsistent_redundancy", reason,
                       ratio if ratio is not None else t,
                       f"Bonferroni p >= {config.gof_p_min:g}" + (
                           f"; chi2/dof <= {config.gof_ratio_max:g} or p >= {config.gof_p_min:g}"
                           if noise_source == "sd" else ""))
