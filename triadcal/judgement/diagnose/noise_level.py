"""A noise level the declared ``sd_*`` understate: the rival every noise effect must beat.

With known noise the diagnosis judges every test against the declared level. A white noise of the
outputs larger than the ``sd_*`` columns say -- a noise that correlates within a visit, a bench
that vibrates -- adds the same variance at every pose: it inflates the chi2 and every known-noise
score by one factor, and a noise effect that widens the noise (``position_error``, ``heavy_tails``:
:data:`LEVEL_MIMICS`) closes such a gap without being its cause. Here:

* :func:`uniform_rival` -- ``position_error`` against a common level: the pattern of its variance
  over the poses, by a likelihood ratio with the level free;
* :func:`noise_level_rival` -- the test each of :data:`LEVEL_MIMICS` must pass (``heavy_tails``: its
  kurtosis score, scale-free);
* :func:`uniform_ambiguity` -- the ``unexplained`` verdict when it does not;
* :func:`soak_level_rival`, :func:`soak_level_ambiguity` -- ``heavy_tails`` against a normal noise
  whose level changes soak by soak (a scale mixture: heavy-tailed only together), with either noise;
* :func:`score_with_level`, :func:`partial_without_level` -- a gap with no pattern (shape: the level
  alone): its best partial answer asked again with the level estimated;
* :func:`families_with_level` -- the generic families asked again with the level estimated (their F
  form), so that a level alone is not read as a pattern of the mean;
* :func:`gap_shape`, :func:`level_words` -- an unexplained gap's shape (moved here from generic.py,
  which re-exports them) and what a shape of the level alone adds to the reason.

docs/diagnosis.md, "Rivals" ("A positioning error against a noise level") and "Effects outside
every simulator" ("A noise level the sd_* columns understate").
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from scipy import optimize, stats

from ...models.effects import NOISE_EFFECTS


def uniform_rival(r: np.ndarray, w: np.ndarray, h: np.ndarray) -> Optional[dict]:
    """The encompassing test of ``position_error`` against a white noise of the outputs above the
    declared level, alike at every pose (known noise).

    A positioning error adds the variance ``tau w`` (``w`` the outputs' sensitivity per arcsec^2,
    :func:`_pe_sensitivity`: large where an axis lies across gravity, zero where it is along it);
    a noise the declared sd_* understate by a common factor adds the same to every residual. The
    known-noise score of :func:`_position_score` sees both. Here the two variance models of the
    normalised residuals are compared by their likelihood, the level free in both:

        H0: var r_i = (1 - h_i) c            H1: var r_i = (1 - h_i) (c0 + tau w_i),  c0, tau >= 0

    (``h`` the leverages; ``c`` is the chi2/dof at H0), ``LR = 2 (l1 - l0)`` with ``c0`` profiled
    in closed form for each ratio ``tau / c0`` (a log grid, then a bounded search), ``LR`` on the
    boundary ``tau = 0`` is 1/2 chi2_0 + 1/2 chi2_1 (Self & Liang, JASA 82, 605-610, 1987). A
    variance test of the squared residuals is as sensitive to their kurtosis as to a pattern, so
    ``LR`` is divided by ``mean(e^2) / 2``, ``e = q / c - 1`` the squared residuals' scatter at H0
    (2 for Gaussian residuals; Koenker, J. Econometrics 17, 107-112, 1981, studentises the
    Breusch-Pagan score so). The likelihood, not the score at ``tau = 0``: on a campaign whose
    poses are visited once a positioning error makes the variance of some residuals tens of times
    that of others, where the score's power stops near z = 2.5 (the independent bench at one
    setpoint, 10 or 20 arcsec: score p < 0.01 in 4 of 8, the likelihood in 5 of 8).
    ``variance_factor`` (c), ``LR`` (adjusted), ``kurtosis_ratio`` (mean(e^2) / 2), ``p_value``;
    None when ``w`` does not vary."""
    r, w, h = np.asarray(r, float), np.asarray(w, float), np.asarray(h, float)
    q = r * r / np.clip(1.0 - h, 1e-6, None)
    c = float(q.mean())
    if not (c > 0 and float(np.ptp(w)) > 0 and float(w.max()) > 0):
        return None
    ws = w / float(w.max())
    l0 = -0.5 * float(np.sum(np.log(c) + q / c))

    def profile(rho):
        g = 1.0 + rho * ws
        c0 = float(np.mean(q / g))
        return -0.5 * float(np.sum(np.log(c0 * g) + q / (c0 * g)))

    grid = np.logspace(-3.0, 8.0, 45)
    vals = [profile(x) for x in grid]
    k = int(np.argmax(vals))
    best = max(l0, vals[k])
    lo, hi = math.log10(grid[max(k - 1, 0)]), math.log10(grid[min(k + 1, grid.size - 1)])
    res = optimize.minimize_scalar(lambda lx: -profile(10.0 ** lx), bounds=(lo, hi), method="bounded")
    best = max(best, -float(res.fun))
    e = q / c - 1.0
    kr = float(np.mean(e * e)) / 2.0
    lr = max(2.0 * (best - l0), 0.0) / kr if kr > 0 else 0.0
    p = 0.5 * float(stats.chi2.sf(lr, 1)) if lr > 0 else 1.0
    return {"variance_factor": c, "LR": lr, "kurtosis_ratio": kr, "p_value": p}


#: the noise effects that widen the noise, so that a noise level the sd_* understate mimics them
LEVEL_MIMICS = ("position_error", "heavy_tails")


def noise_level_rival(c, r: np.ndarray, h: np.ndarray, pe_w: Optional[np.ndarray]) -> Optional[dict]:
    """The test a noise candidate ``c`` of :data:`LEVEL_MIMICS` must pass against a common noise
    level, at the base fit (residuals ``r``, leverages ``h``): ``position_error`` the pattern of its
    variance over the poses (:func:`uniform_rival`, ``pe_w`` its sensitivity); ``heavy_tails`` its
    own kurtosis score (scale-free: ``kurtosis_z``, ``p_value``) with the level ``variance_factor``.
    None when untestable."""
    if c.effect == "position_error":
        return uniform_rival(r, pe_w, h) if pe_w is not None else None
    return {"variance_factor": float(np.sum(r ** 2) / np.sum(np.clip(1.0 - h, 1e-6, None))),
            "kurtosis_z": float(math.copysign(math.sqrt(abs(c.score)), c.score)), "p_value": float(c.score_p)}


def score_with_level(c, chi2: float, dof: int) -> Optional[float]:
    """The p of mean candidate ``c``'s score with the noise level estimated from the residuals
    instead of the declared one: ``F = (S / k) / ((chi2 - S) / (dof - k))`` on ``(k, dof - k)``
    (the score test's F form, as with estimated noise). A level the sd_* understate inflates every
    known-noise score by the same factor; this is what the score says without it. None for a
    candidate with no score (a form, a noise effect) or no dof left."""
    if c.form is not None or not c.params or c.effect in NOISE_EFFECTS or c.k < 1 or dof - c.k < 1:
        return None
    rest = chi2 - c.score
    if not rest > 0:
        return 0.0
    return float(stats.f.sf((c.score / c.k) / (rest / (dof - c.k)), c.k, dof - c.k))


def partial_without_level(verdict: dict, cand_objs: list, base, h: np.ndarray, pe_w, alpha: float,
                          noise_known: bool) -> dict:
    """An ``unexplained`` verdict whose gap has no pattern (shape: the level alone) and stayed open:
    its best partial answer's score was judged against the declared noise level, which the gap says
    is too small. Asked again with the level estimated -- a mean term by :func:`score_with_level`,
    a noise effect of :data:`LEVEL_MIMICS` by :func:`noise_level_rival` -- and dropped (the verdict
    without ``best_partial``, saying why) when not significant at ``alpha``; else ``verdict``."""
    from .results import _p_is

    part = next((c for c in cand_objs if c.effect == verdict.get("best_partial")), None)
    if part is None or verdict.get("gap_closed") is not False:
        return verdict
    if part.effect in LEVEL_MIMICS and noise_known:
        u = noise_level_rival(part, base.r, h, pe_w)
        p, how = (u["p_value"], "its test against a common level") if u else (None, None)
    else:
        p, how = score_with_level(part, base.chi2, base.dof), "F form of its score"
    if p is None or p < alpha:
        return verdict
    return {"effect": "unexplained",
            "reason": (f"significant gap with no pattern: the best candidate, {part.effect} (score p "
                       f"{_p_is(part.score_p)} against the declared noise), is not significant with the noise "
                       f"level estimated from the residuals ({how}, p = {p:.3g} >= {alpha:g}), so it is no "
                       "partial answer"),
            "where": verdict["where"], "shape": verdict["shape"]}


def families_with_level(bases: dict, r: np.ndarray, J: np.ndarray, dof: int, Q: np.ndarray,
                        gap_tests: dict) -> dict:
    """The gap's generic families asked again with the noise level estimated from the residuals, when
    the declared one is rejected: each family's score in its F form, ``(S / k) / ((r'r - S) / (dof -
    k))`` (:func:`.generic.generic_tests` with the noise estimated), with the families already
    scale-free (``variance``: Koenker's studentised test; ``correlated``: a ratio of quadratic forms;
    the ``kurtosis``) as they were, Holm-adjusted together: ``{key: p_holm}`` with the gap's keys.

    A white noise the sd_* columns understate by a factor f inflates every known-noise statistic by
    f^2: at chi2/dof 2.3 a family of k = 8 columns has S ~ 18 under no pattern at all, p ~ 0.02, and
    among nine families one or more rejects after Holm (the independent bench, noise x 1.5: 4 of 4
    gaps were given a shape of orientation, scale or direction, and a best partial answer of a tempco
    or drift). The F form divides by the level the residuals show; a pattern of the mean keeps it
    (its columns take more than their share of the residual's sum of squares). ``bases`` holds the
    whitened family bases, ``gap_tests`` the gap's unadjusted p-values."""
    from .generic import generic_tests
    from .slices import _holm

    tests = {f"generic:{fam}": t["p_value"] for fam, t in generic_tests(bases, r, J, False, dof, Q).items()}
    for k in ("generic:variance", "generic:correlated", "kurtosis"):
        if k in gap_tests:
            tests[k] = gap_tests[k]
    keys = list(tests)
    return dict(zip(keys, (float(a) for a in _holm([tests[k] for k in keys])))) if keys else {}


#: draws of the Monte Carlo null of :func:`soak_level_rival` (fixed seed: p to 1 / (draws + 1))
SOAK_LEVEL_DRAWS = 4000


def soak_level_rival(r: np.ndarray, Q: np.ndarray, blocks: np.ndarray, seed: int = 0) -> Optional[dict]:
    """The test ``heavy_tails`` must pass against a Gaussian noise whose level changes soak by soak.

    Residuals from a noise whose SD is larger at one soak (a hot chamber, a vibrating compressor
    cycle) are a scale mixture of normals: heavy-tailed together, normal within each soak. So the
    residuals ``r`` (3n, normalised) are standardised by their own RMS within each setpoint block
    (``blocks``: per visit, ``Campaign.setpoint_blocks``; the three outputs of a soak together), and
    their kurtosis ``b2 = N sum z^4 / (sum z^2)^2`` is compared with its null: Gaussian white noise,
    projected off the fitted span (``Q``: its orthonormal basis, so the leverages are in the null)
    and standardised the same way, by Monte Carlo (:data:`SOAK_LEVEL_DRAWS` draws, seeded ``seed``;
    one-sided, ``p = (1 + #{b2* >= b2}) / (draws + 1)``; within a group of m the standardisation
    alone lowers E b2 to 3 m / (m + 2)). Tails heavy within the soaks keep b2 high; a level that only
    changes between soaks does not. ``b2``, ``b2_null_mean``, ``blocks``, ``level_ratio`` (the
    largest soak's mean square over the smallest's), ``p_value``; None with fewer than two blocks."""
    r = np.asarray(r, float)
    g = np.repeat(np.asarray(blocks, int), r.size // max(len(blocks), 1))
    m = int(g.max()) + 1 if g.size else 0
    if m < 2 or g.size != r.size:
        return None
    counts = np.bincount(g, minlength=m).astype(float)
    if np.any(counts < 4):
        return None

    def b2(X):                                     # X (N, k): the statistic of each column
        ms = np.zeros((m, X.shape[1]))
        np.add.at(ms, g, X * X)
        ms /= counts[:, None]
        Z2 = X * X / np.maximum(ms[g], 1e-300)
        return X.shape[0] * np.sum(Z2 * Z2, axis=0) / np.sum(Z2, axis=0) ** 2

    obs = float(b2(r[:, None])[0])
    rng = np.random.default_rng(seed)
    sims = []
    for _ in range(SOAK_LEVEL_DRAWS // 500):
        E = rng.standard_normal((r.size, 500))
        sims.append(b2(E - Q @ (Q.T @ E)))
    sims = np.concatenate(sims)
    ms = np.bincount(g, weights=r * r, minlength=m) / counts
    return {"b2": obs, "b2_null_mean": float(np.mean(sims)), "blocks": m,
            "level_ratio": float(ms.max() / max(ms.min(), 1e-300)),
            "p_value": float((1 + np.sum(sims >= obs)) / (sims.size + 1))}


def soak_level_ambiguity(u: dict, alpha: float) -> Optional[dict]:
    """The ``unexplained`` verdict's own fields when ``heavy_tails`` does not beat a noise whose level
    changes soak by soak (:func:`soak_level_rival`'s ``u`` not significant at ``alpha``), else None.
    The caller adds the evidence, the closed gap and where."""
    if u["p_value"] < alpha:
        return None
    lab = (f"a Gaussian noise whose level changes soak by soak (mean squares over {u['blocks']} soaks, the "
           f"largest {u['level_ratio']:.3g} times the smallest)")
    return {"effect": "unexplained", "best_partial": "heavy_tails", "ambiguous_with": [lab],
            "reason": (f"heavy_tails closes the gap but does not beat {lab}: standardised soak by soak the "
                       f"residuals' kurtosis is b2 = {u['b2']:.3g} against {u['b2_null_mean']:.3g} for normal "
                       f"noise, p = {u['p_value']:.3g} >= {alpha:g}; the data cannot tell heavy tails from a "
                       "scatter that grows at some soaks (docs/diagnosis.md \"Rivals\")")}


def uniform_ambiguity(effect: str, u: dict, alpha: float) -> Optional[dict]:
    """The ``unexplained`` verdict's own fields when the noise effect ``effect`` does not beat a
    uniform excess of white noise (``u``: :func:`uniform_rival`'s for ``position_error`` -- the
    pattern of its variance over the poses; for ``heavy_tails`` the kurtosis score of its tails,
    scale-free -- not significant at ``alpha`` once the common level is free), else None. The
    caller adds the evidence, the closed gap and where."""
    if u["p_value"] < alpha:
        return None
    lab = (f"a white noise of the outputs above the declared level, alike at every pose (variance "
           f"{u['variance_factor']:.3g} times the declared)")
    what = (f"the pattern of its variance over the poses gains LR = {u['LR']:.3g}" if effect == "position_error"
            else f"its tails are not heavier than a normal's: kurtosis score z = {u['kurtosis_z']:.3g}")
    cause = ("the bench's positioning errors" if effect == "position_error" else "heavy tails of the noise")
    return {"effect": "unexplained", "best_partial": effect, "ambiguous_with": [lab],
            "reason": (f"{effect} closes the gap but does not beat {lab}: with that level free, {what}, p = "
                       f"{u['p_value']:.3g} >= {alpha:g}; the data cannot tell {cause} from a noise the sd_* "
                       "columns understate (docs/diagnosis.md \"Rivals\")")}


#: the gap's own tests of the noise that give the shape when no generic family finds a pattern:
#: the chi2 against the declared noise (the level of the scatter) and the kurtosis (its tails)
LEVEL_TESTS = {"chi2": "level", "kurtosis": "tails"}


def gap_shape(gap_adj: dict, alpha: float, level_free: Optional[dict] = None) -> list:
    """An unexplained gap's shape (``verdict.shape``): the generic families among the gap's tests
    (``generic:<family>`` in ``gap_adj``, Holm-adjusted p) that reject at ``alpha``, most significant
    first -- where the misfit lies against temperature, time, orientation, direction or in the
    scatter when no single slice does. When none rejects, the gap's tests of the noise that do
    (:data:`LEVEL_TESTS`: ``level``, the chi2 against the declared noise; ``tails``, the kurtosis):
    a misfit with no pattern, e.g. a noise the sd_* columns understate.

    ``level_free`` (when the declared level was rejected: the families asked again with the level
    estimated, :func:`.noise_level.families_with_level`): a family that rejects only against the
    declared level is no pattern -- the level inflates every known-noise statistic alike -- so when
    none rejects there, the shape is the level (its entry has ``families_with_level_estimated``, the
    smallest such p_holm)."""
    def entry(k, fam):
        return {"family": fam, "p_holm": float(gap_adj[k]) if math.isfinite(gap_adj[k]) else None}

    sig = sorted((k for k, p in gap_adj.items() if k.startswith("generic:") and p < alpha), key=gap_adj.get)
    if sig and level_free is not None:
        fam_p = [p for k, p in level_free.items() if k.startswith("generic:")]
        if fam_p and min(fam_p) >= alpha:
            lev = [entry(k, LEVEL_TESTS[k]) for k in sorted((k for k in LEVEL_TESTS if gap_adj.get(k, 1.0) < alpha),
                                                            key=gap_adj.get)]
            for x in lev:
                if x["family"] == "level":
                    x["families_with_level_estimated"] = float(min(fam_p))
            return lev
    if sig:
        return [entry(k, k.split(":", 1)[1]) for k in sig]
    return [entry(k, LEVEL_TESTS[k]) for k in sorted((k for k in LEVEL_TESTS if gap_adj.get(k, 1.0) < alpha),
                                                     key=gap_adj.get)]


def level_words(chi2_dof: float, level_entry: Optional[dict] = None) -> str:
    """What an unexplained verdict whose shape is ``level`` alone (``level_entry``, its shape's entry)
    adds to its reason."""
    fl = (level_entry or {}).get("families_with_level_estimated")
    where = ("no generic family finds a pattern (against temperature, time, orientation, direction, in time "
             "or in the variance)" if fl is None else
             "no generic family finds a pattern with the noise level estimated from the residuals (their F form: "
             f"smallest p_holm {fl:.3g}; against the declared level some reject, as a level inflates them all)")
    return (f"; {where} and the tails are normal: the gap may be the level of the scatter alone, "
            f"chi2/dof {chi2_dof:.3g} against the declared noise, as a noise the sd_* columns understate makes "
            "it (the slices and the candidates' scores are judged against the declared noise too)")
