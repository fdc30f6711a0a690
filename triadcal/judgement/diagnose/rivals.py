"""Does the named effect beat its rivals? An encompassing test (non-nested models).

A candidate that closes the gap is named only with "the evidence that it beats the runner-up"
(issue 18, item 1). Two models that are not nested -- the base model plus the candidate ``c``,
and the base model plus a rival ``t`` -- are compared by the encompassing (J-) test of
Davidson & MacKinnon (1981, Econometrica 49, 781-793): fit base + ``t``, then test whether the
columns of ``c`` still explain something (the score test of ``c`` at the base + ``t`` fit, χ²(k)
with known noise, F otherwise). ``c`` beats ``t`` when that test is significant at ``alpha``.
When it is not, ``t`` accounts for everything ``c`` does on this design: the data cannot tell
them apart, and naming ``c`` would be a coin toss between ``c`` and ``t`` (on the 28-pose sphere a
second-order nonlinearity ``K2 a^2`` and a scale asymmetry ``|a|`` differ by 0.1 g of ``|a|``
after the fitted span; at half the validation magnitude the data do not resolve that).

Rivals are (a) the other refitted mean candidates and (b) single smooth terms that no candidate
names, built from the generic families (``generic.py``): each term on one output, the same term
on every output, and the "diagonal" term (``|g_a|``, ``g_a^2``, ``u g_a`` ... on output ``a``).
(b) is what makes a left-out effect visible: when the true effect is not in the list, the
candidate that closes the gap in its place rarely beats the term that is the true effect's shape.
(b) holds the sign-dependent terms ``g_j sign(g_k)`` too (``generic.sign_terms``, rivals only): on
oblique poses at 30 and 45 degrees they are close to, or the same column as, a cross-coupling's
``g_j g_k``, and a sensitivity of x of 1 + 50 ppm sign(a_y) was named ``cross_coupling`` without them.
A rival with a column within the span of the base model and ``c`` (the same term written another
way: ``g_a^2`` for K2; ``g_x^3`` on every output for K3 holds K3's x column) is no rival and is
skipped: it explains the data by ``c`` itself; so is one within the base span. "The same term"
is judged on a reference design too (``reference_poses``: the same visits at 64 poses drawn
uniformly over the sphere): a rival within span(base, c) on the campaign but not on the reference
is another function that coincides with ``c`` at the campaign's poses -- an alias of the design,
not ``c`` itself -- and ``c`` beats it only by what it has beyond it (S = 0 on 0 dof when the alias
holds all of ``c``; the score test of the rest when it holds part: ``g_x sign(g_y)`` on output x is
one of cross_coupling's six columns on face-diagonal poses). On a tumble test whose poses put every axis
along or across gravity (g_a in {-1, 0, 1}) ``K2 g_a^2`` and the asymmetry ``|g_a|`` are the same
columns; naming either there is a coin toss (a 12-pose campaign with an asymmetry was named K2),
so the verdict is ``unexplained`` with both named as ambiguous.

Linearised at the base fit (the score tests' point): with ``Q`` an orthonormal basis of the base
Jacobian, ``T`` the rival's columns made orthogonal to it, ``r`` the standardised base residuals,
``r_t = r - P_T r`` (the residual after base + t), ``S = |P_{C orth [Q, T]} r_t|^2``.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from scipy import stats

from .candidates import _score_mean
from .fitting import _chi2_logsf
from .generic import _R

#: a rival's columns whose part outside span(base, c) is below this fraction of their norm
#: are ``c`` itself written another way (e.g. g_a^2 for K2: misalignment of milliradians
#: makes them differ by ~1e-3); a genuine alias such as |g_a| for K2 differs by ~0.2
SAME_TERM_FRACTION = 0.03
#: on the reference design a rival within span(base, c) on the campaign is "c written another way"
#: only when its part outside span(base, c) stays below this fraction; |g_a| against K2's g_a^2
#: over the sphere leaves ~0.2, the same term written another way ~1e-3
ALIAS_FRACTION = 0.1
#: poses of the reference design, (axis1_deg, axis2_deg): uniform over both bench axes, fixed seed
REFERENCE_POSES = np.random.default_rng(20261126).uniform(0.0, 360.0, size=(64, 2))


def reference_poses(n_visits: int) -> tuple:
    """(axis1_deg, axis2_deg) of ``n_visits`` visits cycling through ``REFERENCE_POSES``."""
    idx = np.arange(n_visits) % len(REFERENCE_POSES)
    return REFERENCE_POSES[idx, 0].copy(), REFERENCE_POSES[idx, 1].copy()


def _orth(Q: np.ndarray, T: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """Orthonormal columns spanning the part of ``T`` outside span(Q) (empty when none)."""
    norms = np.linalg.norm(T, axis=0)
    keep = norms > 1e-12
    if not keep.any():
        return np.zeros((T.shape[0], 0))
    T = T[:, keep] / norms[keep]
    Tp = T - Q @ (Q.T @ T)
    U, sv, _ = np.linalg.svd(Tp, full_matrices=False)
    rank = int(np.sum(sv > tol))
    return U[:, :rank]


def _fractions(Q: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Per column of ``T``: the fraction of its norm outside span(Q); inf for a zero column, which
    is no shape at all (neither within a span nor an alias of one)."""
    norms = np.linalg.norm(T, axis=0)
    out = np.full(T.shape[1], np.inf)
    keep = norms > 1e-12
    if keep.any():
        Tk = T[:, keep] / norms[keep]
        out[keep] = np.linalg.norm(Tk - Q @ (Q.T @ Tk), axis=0)
    return out


def generic_rivals(per_output: dict, sigma_rows: np.ndarray, whiten) -> dict:
    """Rival column groups from the generic families' per-output terms.

    ``per_output``: ``{family: (F (n, k), labels [k], diag_axis [k] (int or None))}``;
    ``sigma_rows``: (n, 3) the residuals' divisor; ``whiten``: columns -> the standardised scale.
    Returns ``{label: (3n, m) array}``.
    """
    out = {}
    n = sigma_rows.shape[0]
    for fam, (F, labels, diag) in per_output.items():
        for i, lab in enumerate(labels):
            cols = []
            for a in range(3):
                B = np.zeros((n, 3))
                B[:, a] = F[:, i] / sigma_rows[:, a]
                cols.append(B.reshape(3 * n))
            for a, name in enumerate("xyz"):
                out[f"{lab} on {name}"] = cols[a][:, None]
            out[f"{lab} on x,y,z"] = np.column_stack(cols)
        # the diagonal terms: the term of axis a on output a (|g_a| = a scale asymmetry)
        kinds = {}
        for i, (lab, j) in enumerate(zip(labels, diag)):
            if j is not None:
                kinds.setdefault(lab.replace("xyz"[j], "a"), {})[j] = i
        for kind, idx in kinds.items():
            if len(idx) != 3:
                continue
            B = np.zeros((n, 3, 3))
            for a in range(3):
                B[:, a, a] = F[:, idx[a]] / sigma_rows[:, a]
            out[f"{kind} on output a"] = B.reshape(3 * n, 3)
    return {k: whiten(v) for k, v in out.items()}


def encompassing(r: np.ndarray, Q: np.ndarray, C: np.ndarray, T: np.ndarray, noise_known: bool,
                 dof: int, same_elsewhere=None):
    """Score test of ``c`` (columns ``C``) at the base + rival fit (columns ``T``), linearised at the
    base fit (``Q``, ``r``: module docstring). Returns ``None`` when the rival is no rival (within
    the base span, or with a column within span(base, c) and -- when ``same_elsewhere`` is given --
    the same term on the reference design too: ``same_elsewhere(columns)`` True for the columns
    within span(base, c) but not within the base span alone), else ``(S, k, p)``. Against an alias
    of the design (within span(base, c) here, another function elsewhere) ``c`` is tested on what it
    has beyond the alias only: its directions outside span(base, t) by more than
    ``SAME_TERM_FRACTION``; an alias that holds all of ``c`` gives ``(0.0, 0, 1.0)``, one that holds
    part of it (``g_x sign(g_y)`` on output x against the six columns of ``cross_coupling``) the
    score test of the rest. A column within the base span (to ``SAME_TERM_FRACTION``) is the base's
    shape, no alias of ``c``."""
    QT = _orth(Q, T)
    if QT.shape[1] == 0:
        return None
    QC = np.column_stack([Q, _orth(Q, C)])
    within_c = _fractions(QC, T) < SAME_TERM_FRACTION
    alias = False
    if within_c.any():
        # columns within span(base, c) but not within the base span alone: c's own shape here
        mine = np.flatnonzero(within_c & (_fractions(Q, T) >= SAME_TERM_FRACTION))
        if same_elsewhere is None or mine.size == 0 or same_elsewhere(mine):
            return None
        alias = True
    rt = r - QT @ (QT.T @ r)
    Qbt = np.column_stack([Q, QT])
    # an alias of the design: c beats it only by what c has beyond it -- the directions of c's
    # columns outside span(base, t) by more than the same term written another way (none when the
    # alias holds all of c: S = 0 on 0 dof; K2 against |g_a| on output a on a tumble test)
    sc = _score_mean(_R(rt), C, Qbt, SAME_TERM_FRACTION if alias else 0.0)
    if sc is None:
        return 0.0, 0, 1.0
    S, k = sc
    if noise_known:
        logp = _chi2_logsf(S, k)
    else:
        d2 = max(dof - QT.shape[1] - k, 1)
        rest = max(float(rt @ rt) - S, 1e-300)
        logp = float(stats.f.logsf((S / k) / (rest / d2), k, d2))
    return float(S), int(k), float(math.exp(logp))


def rival_tests(r, Q, C, rivals: dict, noise_known: bool, dof: int, reference=None, never_same=()) -> list:
    """The encompassing test of ``c`` against every rival that is one: ``[(label, S, k, p)]``, the
    least beaten (largest p) first. The first of them that ``c`` beats is its closest rival: the
    verdict's evidence that it beats the runner-up (issue 18, item 1), and on a noise-free campaign
    its ``S`` is the noncentrality of that test (``detectability.py``).

    ``reference``: a callable giving ``(Q_ref, C_ref, rivals_ref)`` -- the base span, ``c``'s and
    the rivals' columns on the reference design (``reference_poses``), called at most once and
    only when a rival lies within span(base, c); None keeps every such rival skipped. ``never_same``:
    labels of rivals that are another function whatever the poses (a step of the angles in time is
    never a term of temperature or orientation written another way): within span(base, c) they are
    aliases of the design, never skipped."""
    out = []
    cache = {}

    def same_elsewhere_of(label):
        def same(columns):
            if "ref" not in cache:
                Qr, Cr, rivals_r = reference()
                cache["ref"] = (np.column_stack([Qr, _orth(Qr, Cr)]), rivals_r)
            QCr, rivals_r = cache["ref"]
            Tr = rivals_r.get(label)
            return Tr is None or bool(np.all(_fractions(QCr, Tr[:, columns]) < ALIAS_FRACTION))
        return same

    for label, T in rivals.items():
        same = ((lambda columns: False) if label in never_same else
                same_elsewhere_of(label) if reference is not None else None)
        res = encompassing(r, Q, C, T, noise_known, dof, same)
        if res is None:
            continue
        out.append((label, *res))
    # p underflows to 0 for rivals beaten by far: among equal p the smaller S is the closer
    return sorted(out, key=lambda x: (-x[3], x[1]))


def unbeaten_rivals(r, Q, C, rivals: dict, noise_known: bool, dof: int, alpha: float,
                    reference=None) -> list:
    """The rivals ``c`` does not beat (p >= ``alpha``) of :func:`rival_tests`, the least beaten first."""
    return [x for x in rival_tests(r, Q, C, rivals, noise_known, dof, reference) if x[3] >= alpha]


# ----------------------------------------------------------------------------------
# a step of the angles in time: the rival of a term that changes the angles once
# ----------------------------------------------------------------------------------
#: visits a step needs on each side (the six angles are estimated on each side of it)
STEP_MIN_SIDE = 6
#: eigenvalues of a step's Gram matrix (outside the base span) below this fraction of its largest
#: are no direction of the step (the base span holds them)
STEP_RANK_TOL = 1e-9


def angle_step_rival(r: np.ndarray, Q: np.ndarray, A: np.ndarray, time_s, min_side: int = STEP_MIN_SIDE):
    """The best single step in time of the columns ``A`` -- the six angles: a knock of the unit in its
    fixture, or a slip -- at the base fit: ``(T, t_break_s, S, k, m)`` (``m`` the breaks searched) or
    None when no break leaves ``min_side`` visits on each side.

    The angles after the break are ``Ca + d`` with ``d`` free: the rival's columns are ``A`` on the
    visits after the break (``T = A H``, ``H`` the visit's step), zero before. The break is chosen
    among the gaps between visits in time order as the one whose step explains most of the base
    residuals, ``S = |P_{T orth Q} r|^2`` -- the profile over the change point (Hinkley 1970,
    Biometrika 57, 1-17), made in one pass from suffix sums of each visit's ``Q_i^T A_i``,
    ``A_i^T A_i`` and ``A_i^T r_i`` (``Q`` orthonormal: ``T_orth^T T_orth = T^T T - (Q^T T)^T Q^T T``).
    The choice is the rival's best case: a term the diagnosis names must beat the step wherever the
    step falls (a play hysteresis of half-width 30-50 degC switches about once on the standard path
    and took in a knock of 8 arcsec; docs/diagnosis.md "Rivals")."""
    t = np.asarray(time_s, float)
    n = t.size
    if n < 2 * min_side or A.shape[0] != 3 * n:
        return None
    order = np.argsort(t, kind="stable")
    rows = (3 * order[:, None] + np.arange(3)).reshape(-1)
    As = A[rows].reshape(n, 3, -1)
    Qs = Q[rows].reshape(n, 3, -1)
    rs = r[rows].reshape(n, 3)
    # suffix sums over the visits in time order: index m holds the visits m..n-1
    PA = np.cumsum(np.einsum("iap,iaq->ipq", Qs, As)[::-1], axis=0)[::-1]
    AA = np.cumsum(np.einsum("iap,iaq->ipq", As, As)[::-1], axis=0)[::-1]
    Ar = np.cumsum(np.einsum("iaq,ia->iq", As, rs)[::-1], axis=0)[::-1]
    Qr = Q.T @ r
    ts = t[order]
    best, searched = None, 0
    for m in range(min_side, n - min_side + 1):
        if not ts[m] > ts[m - 1]:
            continue
        searched += 1
        G = AA[m] - PA[m].T @ PA[m]
        b = Ar[m] - PA[m].T @ Qr
        w, V = np.linalg.eigh(0.5 * (G + G.T))
        keep = w > STEP_RANK_TOL * max(float(w.max(initial=0.0)), 1e-300)
        if not keep.any():
            continue
        z = V[:, keep].T @ b
        S = float(np.sum(z * z / w[keep]))
        if best is None or S > best[0]:
            best = (S, m, int(keep.sum()))
    if best is None:
        return None
    S, m, k = best
    H = np.zeros(n)
    H[order[m:]] = 1.0
    T = A * np.repeat(H, 3)[:, None]
    return T, 0.5 * (float(ts[m - 1]) + float(ts[m])), S, k, searched


#: the periodic rival's periods: from the campaign's span down to this many median visit spacings
#: (a shorter sine is not resolved by the visits) and at most this many periods (the scan's cost)
PERIODIC_MIN_SPACINGS = 4.0
PERIODIC_MAX_PERIODS = 400


def periodic_rival(r: np.ndarray, Q: np.ndarray, time_s, sigma_rows: np.ndarray, whiten) -> Optional[dict]:
    """The best sine in time of the three biases, a mean term no candidate names, as a rival of
    ``flicker_noise`` (verdict.mean_explains_better). A covariance in time (1/f) absorbs any
    pattern in time, a periodic bias too: an outside probe's 8 h and 3 h sines of 15-30 ug (a
    supply or ground loop following the lab's day, a compressor's cycle) were named flicker_noise
    with the gap closed, chi2/dof up to 4.4 before. For each period ``P`` of a grid (the span ``T``
    over ``j/2``, j = 2, 3, ...: the periodogram's frequencies oversampled twice, down to
    :data:`PERIODIC_MIN_SPACINGS` median visit spacings, at most :data:`PERIODIC_MAX_PERIODS`),
    the columns ``sin, cos(2 pi t / P)`` on each output (six, standardised as the residuals) and
    their score ``S`` at the base fit (``candidates._score_mean``: off the model's span ``Q``).
    Returns ``{"S", "k", "period_h", "n_periods", "pair"}`` of the largest S (None: too few visits),
    ``pair`` the best two periods (the first the best single one, the second found beside it:
    ``{"S", "k", "period_h": (P1, P2)}``); the caller charges each scanned period ``2 log(n_periods)``
    (Bonferroni over the grid, in AIC's units)."""
    t = np.asarray(time_s, float)
    n = t.size
    if n < 12:
        return None
    span = float(t.max() - t.min())
    steps = np.diff(np.sort(t))
    steps = steps[steps > 0]
    if span <= 0 or not steps.size:
        return None
    p_min = PERIODIC_MIN_SPACINGS * float(np.median(steps))
    periods = [span / (j / 2.0) for j in range(2, 2 * PERIODIC_MAX_PERIODS + 2)]
    periods = [P for P in periods if P >= p_min][:PERIODIC_MAX_PERIODS]
    if not periods:
        return None
    state = _R(r)

    def columns(P):
        ph = 2.0 * math.pi * (t - t.min()) / P
        B = np.zeros((n, 3, 6))
        for a in range(3):
            B[:, a, 2 * a] = np.sin(ph) / sigma_rows[:, a]
            B[:, a, 2 * a + 1] = np.cos(ph) / sigma_rows[:, a]
        return whiten(B.reshape(3 * n, 6))

    cols = [columns(P) for P in periods]
    best = None
    for i, C in enumerate(cols):
        sc = _score_mean(state, C, Q)
        if sc is not None and (best is None or sc[0] > best["S"]):
            best = {"S": float(sc[0]), "k": int(sc[1]), "period_h": periods[i] / 3600.0, "i": i}
    if best is None:
        return None
    # and the best second sine beside it (greedy): two periods (5 h and 13 h on x, y, z) were named
    # flicker_noise where no single sine fits (a second outside probe)
    pair = None
    for i, C in enumerate(cols):
        if i == best["i"]:
            continue
        sc = _score_mean(state, np.column_stack([cols[best["i"]], C]), Q)
        if sc is not None and (pair is None or sc[0] > pair["S"]):
            pair = {"S": float(sc[0]), "k": int(sc[1]), "period_h": (best["period_h"], periods[i] / 3600.0)}
    best.pop("i")
    best["n_periods"] = len(periods)
    best["pair"] = pair
    return best


def step_label(t_break_s: float) -> str:
    """The name of the angle-step rival in a verdict (``ambiguous_with``, ``closest_rival``)."""
    return f"a step of the six angles in time (at {t_break_s / 3600.0:.3g} h)"
