"""The model check of a fit whose noise is estimated from its own residuals (no ``sd_*``, no
``Q_V2s``): chi2 cannot test the model there (it defines the noise), but the residuals' structure
can. Smooth terms the model lacks -- of temperature, time, orientation (even and odd in g) and
direction, each on each output (the diagnosis's generic families, ``judgement/diagnose/generic.py``)
-- are score-tested at the fit, F against the residual variance, Holm over the families.

A family explains the residuals when its Holm-adjusted p < ``gof_p_min`` (0.001) **and** the noise
estimate with that structure in it is more than ``gof_ratio_max`` (1.2) times the estimate without
it (the goodness-of-fit gate's two-part rule: significant and material). Before, an outside
probe's campaign without noise columns and with a quadratic scale term K2 the model lacked was fitted
with status ok, S 6.6-10.6 u from the truth (the same data with the noise stated: chi2/dof 17.4,
model_mismatch)."""

from __future__ import annotations

from typing import Optional

import numpy as np


def structure_gap(campaign, sigma: np.ndarray, r: np.ndarray, J: np.ndarray, dof: int,
                  reference_temperature_C: float) -> Optional[dict]:
    """``{"p_value", "ratio", "family", "what"}`` of the strongest family (Holm-adjusted p), or None
    when no family has a column outside the fit's span. ``r``, ``J``: the fit's standardised
    residuals and Jacobian (least squares, no whitening)."""
    from ..judgement.diagnose.generic import generic_basis, generic_tests
    from ..judgement.diagnose.slices import _holm

    if dof < 2:
        return None
    tests = generic_tests(generic_basis(campaign, sigma, reference_temperature_C), r, J, False, dof)
    # a family needs residual degrees of freedom left beside it (F with dof - k >= 1): one that spans
    # every residual (six faces, dof 6, six terms) would "explain" them all (an outside probe: ratio
    # 1.5e291 on a clean six-face campaign)
    tests = {f: t for f, t in tests.items() if t["k"] < dof}
    if not tests:
        return None
    fams = list(tests)
    adj = dict(zip(fams, _holm([tests[f]["p_value"] for f in fams])))
    fam = min(fams, key=lambda f: (adj[f], -tests[f]["S"]))
    S, k = tests[fam]["S"], tests[fam]["k"]
    rr = float(r @ r)
    ratio = (rr / dof) / max((rr - S) / max(dof - k, 1), 1e-300)
    return {"p_value": float(adj[fam]), "ratio": float(ratio), "family": fam,
            "what": (f"structure of the residuals (the noise estimated from them, so chi2 cannot test the model): "
                     f"the strongest smooth family the model lacks, {fam} ({k} terms), F test Holm-adjusted over "
                     f"{len(fams)} families; ratio = the noise estimate with it over without it")}


#: the shift test's materiality: a family fails the answer when, added to the model, it moves a
#: parameter significantly (Holm over every family and parameter) and by more than this many of
#: its stated u beyond twice the shift's own SD
SHIFT_U_MAX = 1.0
#: the step sets are searched when the campaign has at most this many setpoint changes (a ramp's
#: visits each at their own setpoint would make hundreds of sets of little power each)
STEP_MAX_SETS = 50


def step_sets(campaign, sigma) -> list:
    """``[(label, B (3n, 12))]``: a step at each change of setpoint (the visits from then on) times
    ``1, g_x, g_y, g_z`` on each output -- a change at one moment, of a bias, a scale or an angle:
    a unit re-mounted in its fixture, a bench re-levelled, a shock. Normalised as the generic
    families are (divided by the outputs' noise SD)."""
    from ..judgement.diagnose.generic import _nominal_g

    n = campaign.n_visits
    t = np.asarray(campaign.time_s, float)
    order = np.argsort(t, kind="stable")
    sp = np.asarray(campaign.setpoint_C, float)[order]
    changes = [i for i in range(1, n) if sp[i] != sp[i - 1]]
    if not changes or len(changes) > STEP_MAX_SETS:
        return []
    g = np.asarray(_nominal_g(campaign), float).reshape(n, 3)
    one_g = np.column_stack([np.ones(n), g])
    sig = np.broadcast_to(np.asarray(sigma, float), (n, 3))
    out = []
    for i in changes:
        t0 = t[order[i]]
        H = (t >= t0).astype(float)[:, None] * one_g
        B = np.zeros((n, 3, 12))
        for a in range(3):
            B[:, a, 4 * a:4 * a + 4] = H / sig[:, [a]]
        out.append((f"step at {t0:.0f} s (setpoint {sp[i - 1]:g} -> {sp[i]:g} degC): 1, g on w_x/y/z",
                    B.reshape(3 * n, 12)))
    return out


#: directions of a family whose part outside the model's span is below this fraction of their norm
#: are left out of the shift: the model nearly absorbs them, and the shift they give is noise
#: (singular values of the projected unit columns; the spectrum has a gap between 1e-8 and 0.1)
SHIFT_SPAN_MIN = 0.02


def jacobian_qr(J: np.ndarray):
    """``(Q, R, d)``: the thin QR of ``J`` with its columns scaled to unit norm by ``d``, for
    :func:`hausman_shift` (computed once for all the column sets of a fit)."""
    d = np.linalg.norm(J, axis=0)
    d = np.where(d > 0, d, 1.0)
    Q, R = np.linalg.qr(J / d)
    return Q, R, d


def hausman_shift(J: np.ndarray, B: np.ndarray, r: np.ndarray, span_min: float = 0.0, qr=None,
                  score: bool = False):
    """``(shift, sd, rank)``: the linearised change of every parameter when the columns ``B`` are
    added to a least-squares fit with Jacobian ``J`` and residuals ``r`` at its optimum (``J'r = 0``;
    ``J``, ``B``, ``r`` normalised by the noise SD), and the SD of that change when ``B``'s true
    coefficients are 0 and the noise SD is 1 (Hausman 1978; the difference of the two fits'
    covariances, ``(J'J)^-1 J'B (B_perp'B_perp)^-1 B'J (J'J)^-1``, ``B_perp = (I - P_J) B``).

    The linearised residual of the larger fit is ``r + J dtheta + B g``; at its optimum
    ``g = -(B_perp'B_perp)^-1 B_perp'r`` and ``shift = dtheta = -(J'J)^-1 J'B g`` (invariant to the
    sign of ``B``): for a linear model exactly the difference of the two least-squares solutions. Directions of ``B``
    whose part outside ``J``'s span is at most ``span_min`` of their norm (columns scaled to unit
    norm) are left out; ``rank`` is the number kept (0: ``B`` lies in the span, shift and sd 0).
    ``qr``: :func:`jacobian_qr` of ``J``, when it is at hand. ``score``: also return ``|U'r|^2``
    (``U`` the kept directions of ``B_perp``, orthonormal and orthogonal to ``J``'s span), chi2 with
    ``rank`` dof when ``B``'s coefficients are 0 and the noise SD is 1; every parameter's
    ``|shift / sd|`` is at most its square root (Cauchy-Schwarz: the shift is ``M_i . U'r``, its SD
    ``|M_i|``), so it tests all the parameters' shifts of the set at once (Scheffe 1953)."""
    p = J.shape[1]
    Q, R, d = jacobian_qr(J) if qr is None else qr
    nb = np.linalg.norm(B, axis=0)
    keep = nb > 1e-12 * max(1.0, np.sqrt(r.size))
    nothing = (np.zeros(p), np.zeros(p), 0) + ((0.0,) if score else ())
    if not keep.any():
        return nothing
    B = B[:, keep] / nb[keep]
    U, sv, Vt = np.linalg.svd(B - Q @ (Q.T @ B), full_matrices=False)
    rk = int(np.sum(sv > max(span_min, 1e-10 * max(sv[0], 1e-300)))) if sv.size else 0
    if rk == 0:
        return nothing
    U, sv, Vt = U[:, :rk], sv[:rk], Vt[:rk]
    M = np.linalg.solve(R, Q.T @ B) @ (Vt.T / sv)       # (p, rk): the shift per unit of U'r
    Ur = U.T @ r
    out = (M @ Ur) / d, np.sqrt(np.sum(M * M, axis=1)) / d, rk
    return out + ((float(Ur @ Ur),) if score else ())


def shift_rows(campaign, sigma: np.ndarray, r: np.ndarray, J: np.ndarray, dof: int,
               reference_temperature_C: float, u: np.ndarray, names, noise_known: bool,
               noise_scale: float = 1.0) -> list:
    """Every (set of columns, parameter) pair of :func:`structure_shift`: ``{"family", "parameter",
    "k", "z", "p_raw", "p_set", "set", "shift_u", "sd_u", "lower_u"}`` (``z`` the signed shift over its
    SD; ``p_set`` the set's own p of all its shifts at once, :func:`hausman_shift`'s ``score``, chi2 with
    ``k`` dof with a known noise, ``k F(k, dof - k)`` otherwise; ``set`` the set's index)."""
    from scipy import special

    from ..judgement.diagnose.generic import SUB_BLOCKS, block_columns, generic_basis, per_output_terms

    basis = generic_basis(campaign, sigma, reference_temperature_C)
    labels = {f: v[1] for f, v in per_output_terms(campaign, reference_temperature_C).items()}
    sets = []
    for fam, Bf in basis.items():
        per = Bf.shape[1] // 3
        # the family, and its sub-blocks (a term mostly absorbed by one parameter shows in its block,
        # with a smaller SD than in the whole family's, as in the families' own tests)
        sets.append((fam, Bf))
        for cols in (block_columns(fam, per) if fam in SUB_BLOCKS else []):
            terms = sorted({labels[fam][c % per] for c in cols})
            outs = sorted({"xyz"[c // per] for c in cols})
            sets.append((f"{fam}: {', '.join(terms)} on w_{'/'.join(outs)}", Bf[:, cols]))
    sets += step_sets(campaign, sigma)
    u = np.asarray(u, float)
    qr = jacobian_qr(J)
    rows = []
    for j, (what, B) in enumerate(sets):
        shift, sd, rk, chi2 = hausman_shift(J, B, r, SHIFT_SPAN_MIN, qr, score=True)
        if rk == 0 or rk >= dof:
            continue
        sd = noise_scale * sd
        chi2 = chi2 / noise_scale ** 2
        # scipy.stats' chi2.sf and f.sf are these special functions behind argument checks that
        # cost 0.35 ms a call (41 calls a fit): the same numbers
        p_set = float(special.chdtrc(rk, chi2) if noise_known else special.fdtrc(rk, max(dof - rk, 1), chi2 / rk))
        use = (u > 0) & (sd > 1e-3 * u)                       # a shift of SD < 0.001 u: never material
        z = np.where(use, shift / np.where(use, sd, 1.0), 0.0)
        p = 2.0 * (special.ndtr(-np.abs(z)) if noise_known else special.stdtr(max(dof - rk, 1), -np.abs(z)))
        for i in np.flatnonzero(use):
            rows.append({"family": what, "parameter": str(names[i]), "k": rk, "z": float(z[i]),
                         "p_raw": float(p[i]), "p_set": p_set, "set": j, "shift_u": float(shift[i] / u[i]),
                         "sd_u": float(sd[i] / u[i]), "lower_u": float((abs(shift[i]) - 2.0 * sd[i]) / u[i])})
    return rows


def structure_shift(campaign, sigma: np.ndarray, r: np.ndarray, J: np.ndarray, dof: int,
                    reference_temperature_C: float, u: np.ndarray, names, noise_known: bool,
                    noise_scale: float = 1.0, p_min: float = 1e-3):
    """Whether a structure the fit's residuals hold biases the answer: Hausman's test (Hausman
    1978, the difference of two estimators, efficient under the model and consistent beyond it),
    per parameter. For each generic family of :func:`structure_gap`, each of its sub-blocks
    (``generic.block_columns``: e.g. the ``u^2`` terms on the angles' outputs), and a step at each
    change of setpoint (:func:`step_sets`) -- columns ``B`` -- the linearised
    shift of every free parameter when ``B`` is added to the model,
    ``d = (J'J)^-1 J'B (B_perp'B_perp)^-1 B_perp'r`` (:func:`hausman_shift`; ``B_perp``: ``B`` made
    orthogonal to the model's span), and its SD when the model holds,
    ``s = sqrt(diag[(J'J)^-1 J'B (B_perp'B_perp)^-1 B'J (J'J)^-1])`` times ``noise_scale`` (1 with a
    known noise; the estimated noise SD otherwise). Under the model ``d ~ N(0, s^2)`` exactly (the
    residuals' part outside the span is the noise's), so ``z = d / s`` is tested (normal with a
    known noise, Student t with the fit's dof otherwise), Holm over every set of columns and parameter;
    and each set for all its parameters at once (``|U'r|^2``, chi2 with the set's rank, bounds every
    ``z^2`` of the set; :func:`hausman_shift`), Holm over the sets. A pair is significant when either
    adjusted p is below ``p_min`` (a false refusal of a right model at most ``2 p_min``). The set's
    test was added on 2026-11-30 (an outside probe): a bias drift of 0.3 ug/h on all three outputs of
    a 32 h campaign moved S_x_tempco by 4.05 u (SD 0.86 u) with status ok, its pair's z 4.7 but Holm
    p 0.0025 over 1 037 pairs, whose shifts within a set are one vector ``U'r`` counted many times;
    the set's chi2 with 3 dof was 45.

    A pair fails the answer when it is significant at ``p_min`` **and** material,
    ``|d| > SHIFT_U_MAX u + 2 s``: the parameter moves by more than its stated ``u`` with 97.5 %
    one-sided confidence. Returns ``None`` when no family has columns outside the model's span,
    else ``{"passed", "family", "parameter", "p_value", "k", "shift_u", "sd_u", "lower_u", "n_tests",
    "what"}`` of the most significant failing pair, or of the most significant one when none fails.

    Why a per-parameter test: the chi2 gate and the families' own score tests spread a term that
    is mostly absorbed by a parameter over many dof. A quadratic angle tempco (0.001 "/K^2, five
    setpoints -40..80 degC) fitted with the linear model left Ca_xy 5.4 u off with chi2/dof 1.16
    (passed) and the temperature family at Holm p 0.11; the shift of Ca_xy, 5 SD, is what the
    missing term does to the answer."""
    from ..judgement.diagnose.slices import _holm

    if dof < 2:
        return None
    try:
        rows = shift_rows(campaign, sigma, r, J, dof, reference_temperature_C, u, names, noise_known, noise_scale)
    except np.linalg.LinAlgError:       # a Jacobian with a null column: the identifiable gate refuses the fit
        return None
    if not rows:
        return None
    # two Holm families, each at p_min: the (set, parameter) pairs, and the sets, each tested for all
    # its parameters' shifts at once (a drift on all three outputs: per pair z 4.7, Holm p 0.0025
    # over 1 037 pairs; as a set of 3 columns chi2 45)
    set_p = {row["set"]: row["p_set"] for row in rows}
    set_adj = dict(zip(set_p, _holm(list(set_p.values()))))
    for row, p in zip(rows, _holm([row["p_raw"] for row in rows])):
        row["p_value"] = float(min(p, set_adj[row["set"]]))
        row["fails"] = row["p_value"] < p_min and row["lower_u"] > SHIFT_U_MAX
    failing = [row for row in rows if row["fails"]]
    # the pair reported: the most significant failing one (a wrong family can also move a parameter,
    # by more but less surely), else the most significant of all
    row = max(failing or rows, key=lambda x: abs(x["z"]))
    out = {k: row[k] for k in ("family", "parameter", "p_value", "k", "shift_u", "sd_u", "lower_u")}
    out["passed"] = not failing
    out["n_tests"] = len(rows)
    out["what"] = (f"adding the residuals' {row['family']} structure ({row['k']} terms outside the model's span) "
                   f"moves {row['parameter']} by {row['shift_u']:+.2f} u (SD of that shift {row['sd_u']:.2f} u; "
                   f"Holm-adjusted p = {row['p_value']:.2g}, the smaller of the pair's over {len(rows)} "
                   f"family-parameter pairs and its set's over {len(set_p)} sets)")
    return out


def structure_outcome(row: Optional[dict], why_not: str = ""):
    """The answer gate ``structure`` (status ``model_mismatch``) of :func:`structure_shift`'s row."""
    from .gates import GateOutcome

    threshold = (f"Holm p >= 1e-3 (of the pair and of its set), or |shift| <= {SHIFT_U_MAX:g} u + 2 SD of the "
                 "shift")
    if row is None:
        return GateOutcome("structure", None, "model_mismatch",
                           why_not or "not testable: no smooth family has terms outside the model's span")
    txt = row["what"]
    if not row["passed"]:
        txt += (f": more than {SHIFT_U_MAX:g} u beyond twice its SD, so the model misses an effect that biases "
                "the answer although the noise test may pass; run `triadcal diagnose` and refit with the "
                "missing effect")
    return GateOutcome("structure", row["passed"], "model_mismatch", txt, row["lower_u"], threshold)


#: a bias drift whose signature has less than this fraction of its norm outside the model's span is
#: one the residuals cannot show (a schedule monotone in temperature: 0.008; a round trip: 0.76-0.80)
DRIFT_VISIBLE_MIN = 0.05


def drift_confounding(campaign, J: np.ndarray, names, u: np.ndarray, noise_scale: float = 1.0) -> Optional[dict]:
    """What a bias drift the model leaves out does to the answer, per output ``a``: the drift
    ``S_a(t) = S_a + d (t - t_mid)`` (``t_mid`` the campaign's middle; d in ug/h; the model's
    ``bias_drift`` with another origin: a model without it holds one bias for the campaign, for a
    drifting unit its bias near the middle, so S_a's move is from there, not from the start),
    whose residual signature is ``b = (t - t_mid) dr/dS_a``.
    Left out, the least-squares fit absorbs its part in the model's span: every parameter moves by
    ``(J'J)^-1 J'b`` per ug/h (``moves_u_per_ug_h``, in each parameter's u, the three largest);
    the rest shows in the residuals: ``visible_fraction`` = |(I - P_J) b| / |b|, and the drift the
    residuals measure with SD ``sd_ug_per_h`` = noise SD / |(I - P_J) b| (infinite when invisible).

    A schedule monotone in temperature puts the drift in the span of the biases and their tempcos
    (visible fraction 0.008 on five setpoints -40..80 degC): 2 ug/h moved S_tempco 10 u and S 18 u
    with chi2/dof 0.87-1.24 and status ok (tests/independent_bench.py). None when the model has
    ``bias_drift`` or the campaign's clock does not move."""
    names = list(names)
    if any(n.endswith("_drift") and n.startswith("S_") for n in names):
        return None
    t = np.asarray(campaign.time_s, float)
    if not np.ptp(t) > 0:
        return None
    t_h = np.repeat((t - 0.5 * (t.min() + t.max())) / 3600.0, 3)
    out = {}
    for a in "xyz":
        if f"S_{a}" not in names:
            continue
        c = _confounding(J, names, u, t_h * J[:, names.index(f"S_{a}")] * 1e-6, noise_scale)  # S in g: 1 ug/h
        if c is not None:
            out[a] = {"visible_fraction": c["visible_fraction"], "sd_ug_per_h": c["sd"],
                      "moves_u_per_ug_h": c["moves_u"]}
    return out or None


def _confounding(J: np.ndarray, names, u: np.ndarray, b: np.ndarray, noise_scale: float) -> Optional[dict]:
    """A left-out term's signature ``b`` (per unit of the term) against the model's span ``J``:
    ``visible_fraction``, the SD of the term the residuals measure (None when invisible), the three
    largest moves of the parameters (in their u) per unit of the term, and ``perp``, the signature off
    the span (what a score test of the term projects the residuals on; not for the JSON)."""
    nb = float(np.linalg.norm(b))
    if not nb > 0:
        return None
    moves, *_ = np.linalg.lstsq(J, b, rcond=None)
    perp = b - J @ moves
    left = float(np.linalg.norm(perp))
    moves_u = {n: float(m / s) for n, m, s in zip(names, moves, u) if s > 0 and np.isfinite(s)}
    top = sorted(moves_u, key=lambda n: -abs(moves_u[n]))[:3]
    return {"visible_fraction": left / nb, "sd": float(noise_scale / left) if left > 1e-12 * nb else None,
            "moves_u": {n: moves_u[n] for n in top}, "perp": perp}


def hysteresis_confounding(campaign, J: np.ndarray, names, u: np.ndarray, noise_scale: float = 1.0) -> Optional[dict]:
    """What a thermal hysteresis of the angles the model leaves out does to the answer, per angle
    ``ab``: the model's ``hysteresis`` term (``Ca_ab + h b``, ``b`` the visit's branch: +1 cooling, -1
    heating, 0 none; models/effects/hysteresis.py), whose residual signature per arcsec is
    ``b dr/dCa_ab``. As :func:`drift_confounding`: ``visible_fraction``, ``sd_arcsec`` (the hysteresis
    the residuals measure) and ``moves_u_per_arcsec`` (the three largest moves, in each parameter's u).

    A schedule that visits no temperature on both branches -- 20 degC (no branch), -40 (cooling), 85
    (heating) -- makes ``b`` nearly ``-dT / 62.5 degC``, the angle tempco's own column: an outside
    probe's unit with hysteresis of 6-15 arcsec was fitted without it with status ok, chi2/dof 0.84,
    and every angle tempco 14-22 u off (``Ca_yx_tempco`` 0.247 for 0.5 arcsec/degC). None when the
    model has the hysteresis or no visit has a branch."""
    from ..models.sensor import ANGLE_NAMES

    names = list(names)
    if any(n.endswith("_hysteresis") for n in names):
        return None
    br = np.asarray(campaign.branch, float)
    if not np.any(br != 0):
        return None
    rows = np.repeat(br, 3)
    out = {}
    for ab in ANGLE_NAMES:
        if f"Ca_{ab}" not in names:
            continue
        c = _confounding(J, names, u, rows * J[:, names.index(f"Ca_{ab}")], noise_scale)
        if c is not None:
            out[ab] = {"visible_fraction": c["visible_fraction"], "sd_arcsec": c["sd"],
                       "moves_u_per_arcsec": c["moves_u"]}
    return out or None


#: the hysteresis of the orientation angles of this class of units: the seed paper's Table 1 (arcsec)
HYSTERESIS_TYPICAL_ARCSEC = (4.0, 60.0)


def _blind(conf: dict, moves_key: str, shown: Optional[int] = None, more: str = ""):
    """``(blind, moves, worst)`` of a confounding dict: the entries below ``DRIFT_VISIBLE_MIN`` visible,
    their largest moves in words (each entry's first, and the others of 0.1 u or more; the first
    ``shown`` of them, then how many more and where), the smallest visible fraction."""
    blind = {k: c for k, c in conf.items() if c["visible_fraction"] < DRIFT_VISIBLE_MIN}
    if not blind:
        return blind, "", None
    moves = [f"{n} by {abs(m):.2g} u" for c in blind.values()
             for k, (n, m) in enumerate(c[moves_key].items()) if k == 0 or abs(m) >= 0.1]
    text = ", ".join(moves[:shown]) + (f" (and {len(moves) - shown} more: {more})"
                                        if shown is not None and len(moves) > shown else "")
    return blind, text, min(c["visible_fraction"] for c in blind.values())


def hysteresis_note(conf: dict) -> Optional[str]:
    """The result's note when a hysteresis of some angle is invisible (:func:`hysteresis_confounding`)."""
    blind, moves, worst = _blind(conf, "moves_u_per_arcsec", shown=3, more="fit.hysteresis_confounding")
    if not blind:
        return None
    lo, hi = HYSTERESIS_TYPICAL_ARCSEC
    return (f"the schedule cannot show a thermal hysteresis of the angle(s) {', '.join('Ca_' + ab for ab in blind)}: "
            f"{100 * worst:.1g} % of a hysteresis's signature is outside the model (no temperature is visited on "
            "both the heating and the cooling branch), so no test of the residuals sees one, and 1 arcsec of "
            f"hysteresis would move {moves}; units of this kind have {lo:g}-{hi:g} arcsec (the seed paper's Table 1). "
            "The values hold for a unit without hysteresis; a schedule that visits a temperature on both branches "
            "tells the two apart (docs/plan.md), and `--effects ...,hysteresis` fits it")


def drift_note(conf: dict, stated_u: Optional[float] = None) -> Optional[str]:
    """The result's note when a bias drift is invisible on some output (:func:`drift_confounding`);
    ``stated_u``: the unit's drift u the lab states (``[item] bias_drift_u_ug_per_h``), propagated
    into the budget (uncertainty/typeb.py), which the note then says instead of assuming no drift."""
    blind, moves, worst = _blind(conf, "moves_u_per_ug_h")
    if not blind:
        return None
    return (f"the schedule cannot show a bias drift in time on output(s) {', '.join(blind)}: "
            f"{100 * worst:.1g} % of a drift's signature is outside the model (the temperatures visited in time "
            f"order), so no test of the residuals sees one, and a drift of 1 ug/h would move {moves}. "
            + ("The values hold for a unit whose bias does not drift during the campaign" if stated_u is None else
               f"The budget holds the drift the lab states for the unit ([item] bias_drift_u_ug_per_h = {stated_u:g} "
               "ug/h, a Type B row about the campaign's middle); a unit drifting more is not covered")
            + "; a schedule that returns to its first temperature tells the two apart (docs/plan.md), and "
            "`--effects ...,bias_drift` fits both")


def residual_checks(result, campaign, noise, sol, dof: int, chi2_dof: float, reference_temperature_C: float,
                    u: np.ndarray, names, plain: bool, p_min: float = 1e-3):
    """The joint fit's checks of its residuals and model form: ``(structure, gates)``. ``structure``:
    :func:`structure_gap` with the noise estimated (the goodness of fit's evidence, also
    ``result.fit["structure"]``), else None; ``gates``: the ``structure`` gate
    (:func:`structure_shift`, its evidence in ``result.fit["structure_shift"]``) and, with the rate-form
    ``thermal_lag`` in the result, the ``lag_form`` gate (:mod:`.lag_validity`), and the
    ``correlated_residuals`` gate at ``p_min`` (:mod:`.serial_correlation`). ``plain``: least
    squares without a robust loss or whitening, the fits these tests are made for."""
    structure = None
    finite = plain and bool(np.all(np.isfinite(sol.J)))
    if finite and not noise.known:
        structure = structure_gap(campaign, noise.sigma, sol.r, sol.J, dof, reference_temperature_C)
        if structure is not None:
            result.fit["structure"] = structure
    if finite and np.all(np.isfinite(u)):
        shift = structure_shift(campaign, noise.sigma, sol.r, sol.J, dof, reference_temperature_C, u, names,
                                noise.known, 1.0 if noise.known else float(np.sqrt(max(chi2_dof, 0.0))))
        if shift is not None:
            result.fit["structure_shift"] = dict(shift)
        gates = [structure_outcome(shift)]
        from .serial_correlation import correlated_residuals_gate

        corr = correlated_residuals_gate(campaign, noise.sigma, sol.r, sol.J, p_min, result)
        if corr is not None:
            gates.append(corr)
        conf = drift_confounding(campaign, sol.J, names, u, 1.0 if noise.known else float(np.sqrt(max(chi2_dof, 0.0))))
        if conf is not None:
            result.fit["bias_drift_confounding"] = conf
            stated = next((e["u"] for e in result.fit.get("systematic_errors") or []
                           if e.get("key") == "[item] bias_drift_u_ug_per_h"), None)
            note = drift_note(conf, stated)
            if note:
                result.notes.append(note)
        hyst = hysteresis_confounding(campaign, sol.J, names, u,
                                      1.0 if noise.known else float(np.sqrt(max(chi2_dof, 0.0))))
        if hyst is not None:
            result.fit["hysteresis_confounding"] = hyst
            note = hysteresis_note(hyst)
            if note:
                result.notes.append(note)
    else:
        gates = [structure_outcome(None, "not testable: a robust loss or a whitened (1/f) fit")]
    if "thermal_lag" in result.parameters:    # the rate form (the history forms leave the effect out of the model)
        from .lag_validity import rate_form_check

        lag = result.parameters["thermal_lag"]
        gates.append(rate_form_check(campaign, lag.value, lag.u))
    return structure, gates


def one_branch_hysteresis_hint(result, problems: dict, campaign) -> list:
    """The hint of a ``model_mismatch`` fit that held the hysteresis at 0 on one branch with visits of no
    branch (``joint``'s identifiability: h would take in anything localised at the first soak): a unit
    with a hysteresis misfits through those visits, which the model puts on the mid-line. An outside
    probe: 20 degC (no branch) then heating to 70 degC, a 10" hysteresis and the model that made it:
    refused 9 times in 10 with only "the model misses something". ``[]`` otherwise."""
    if not (result.status == "model_mismatch" and any(k.endswith("_hysteresis") for k in problems)
            and 0.0 in set(np.sign(campaign.branch).tolist())):
        return []
    return ["hint: the hysteresis was held at 0 (one branch, see above); a unit with a hysteresis then misfits "
            "through its visits of no branch, which the model puts on the mid-line between the branches: a cooling "
            "branch measures the hysteresis, or fit without the visits of no branch"]
