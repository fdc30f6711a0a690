"""A tempco the raw fit leaves out, on a recording whose temperature moves (``fit-raw
--temperature-column``).

fit-raw fits no thermal term: K, S and the angles are stated at the reference temperature T_ref, the
mean over the static intervals' samples. A bias tempco ``b_a`` (ug/degC) or a scale tempco ``k_a``
(ppm/degC) of output ``a`` (models/effects/thermal.py: ``S_a(T) = S_a + b_a (T - T_ref)``,
``K_a(T) = K_a (1 + k_a (T - T_ref))``, eq. 1 ``K_a W_a = Ca_a . G + S_a``) changes pose i's mean
output by::

    W'_ia = (K_a W_ia - S_a + S_a(T_i)) / K_a(T_i)

(the sensed acceleration ``K_a W_ia - S_a`` kept). When the poses' temperatures differ, the fit takes
that change into its values: on six faces S_a becomes the bias at the mean temperature of output a's
own +-1 g faces, and K_a moves by b_a (T(+1 g) - T(-1 g)) / 2 -- an outside probe: six faces on a
linear 20 -> 30 degC ramp, 100 ug/degC of bias tempco, status ok in 6 of 6 seeds with K 2.7-4.4 u and
S 2.1-5.8 u off (at the reference temperature the result stated), the same files without the ramp
within 2 u. Six faces have no redundancy to see it.

What each tempco does is measured, not assumed: the fit re-run on the pose means changed by a small
tempco of each kind on each output (+h and -h: the moves ``m = (theta(+h) - theta(-h)) / 2h`` per unit,
JCGM 100 5.1.3 by central difference) and what the residuals see of it: ``chi2(+h) + chi2(-h) -
2 chi2(0) = 2 h^2 |b_perp|^2``, so the tempco the fit measures to an SD of ``1 / |b_perp|`` (none when
the change lies in the model's span: no test can see it). The gate ``unseen_tempco`` (status
``unidentifiable``) fails when a tempco of twice that SD -- what would pass unseen -- moves a value of
K, S or the angles by more than 1 u. A tempco bound the user states (``--bias-tempco-bound``,
``--scale-tempco-bound``: a datasheet's, rectangular) replaces that test for its kind: its effect
enters each value's u as a Type B contribution ``|m| bound / sqrt(3)`` (JCGM 100 4.3.7), said in a
note and in ``extra.unseen_tempco``.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Callable, Optional

import numpy as np

from ...models.effects.thermal import linear_in_temperature
from ..gate_outcome import GateOutcome
from ..result import CalibrationResult

#: a tempco left unseen at this many SD of what the residuals measure of it is the gate's size
HIDDEN_SD = 2.0
#: the move of a value (in its u) that an unseen tempco may cause before the gate fails
MOVE_MAX_U = 1.0
#: the probe's largest change of a pose mean, g (small: the moves are linear in it)
PROBE_G = 1e-4
KINDS = {"bias": ("ug/degC", "S_{a}_tempco"), "scale": ("ppm/degC", "K_{a}_tempco")}


def changed_means(w: np.ndarray, K: np.ndarray, S: np.ndarray, dT: np.ndarray, axis: int, kind: str,
                  c: float) -> np.ndarray:
    """The pose means ``w`` (n, 3) with a tempco ``c`` of ``kind`` (bias: ug/degC, scale: ppm/degC) on
    output ``axis``; ``K`` (output unit -> g) and ``S`` (g) the fit's, ``dT`` the poses' T - T_ref."""
    w = np.array(w, float)
    sensed = K[axis] * w[:, axis] - S[axis]
    if kind == "bias":
        w[:, axis] = (sensed + linear_in_temperature(S[axis], c * 1e-6, dT)) / K[axis]
    else:
        w[:, axis] = (sensed + S[axis]) / (K[axis] * linear_in_temperature(1.0, c * 1e-6, dT))
    return w


def unseen_tempco(result: CalibrationResult, w: np.ndarray, pose_T: np.ndarray, T_ref: float,
                  refit: Callable, bounds: Optional[dict] = None) -> Optional[dict]:
    """The moves and visibility of each tempco (module docstring). ``refit(w)`` -> ``(result, chi2)``
    of the same fit on means ``w``; ``pose_T`` the poses' mean temperatures; ``bounds`` {"bias": ug/degC,
    "scale": ppm/degC} stated by the user (None: not stated). None without a temperature spread."""
    dT = np.asarray(pose_T, float) - T_ref
    span = float(np.max(np.abs(dT))) if dT.size else 0.0
    if not span > 0:
        return None
    K = np.array([result.parameters[f"K_{a}"].value for a in "xyz"])
    S = np.array([result.parameters[f"S_{a}"].value for a in "xyz"])
    names = [n for n in result.parameters if n.split("_")[0] in ("K", "S", "Ca")]
    u = {n: result.parameters[n].u for n in names}
    r0, chi0 = refit(np.asarray(w, float))
    sources = []
    for kind, (unit, pattern) in KINDS.items():
        # the probe: a change of PROBE_G at the poses furthest from T_ref (bias: ug/degC; scale: ppm of 1 g)
        h = PROBE_G * 1e6 / span
        for i, a in enumerate("xyz"):
            rp, chip = refit(changed_means(w, K, S, dT, i, kind, +h))
            rm, chim = refit(changed_means(w, K, S, dT, i, kind, -h))
            moves = {n: (rp.parameters[n].value - rm.parameters[n].value) / (2 * h) for n in names}
            seen2 = (chip + chim - 2 * chi0) / (2 * h * h)           # |b_perp|^2 per unit^2
            sd = 1.0 / math.sqrt(seen2) if seen2 > 1e-12 * (1.0 + abs(chi0)) / (h * h) else None
            moves_u = {n: abs(m) / u[n] for n, m in moves.items() if u[n] > 0 and math.isfinite(u[n])}
            worst = max(moves_u, key=moves_u.get)
            bound = (bounds or {}).get(kind)
            sources.append({"source": pattern.format(a=a), "kind": kind, "unit": unit, "sd": sd,
                            "hidden": None if sd is None else HIDDEN_SD * sd, "bound": bound,
                            "moves_per_unit": moves, "worst": worst, "worst_u_per_unit": moves_u[worst]})
    return {"span_C": span, "T_ref_C": T_ref, "pose_T_C": [float(t) for t in pose_T], "sources": sources,
            "equation": "W'_ia = (K_a W_ia - S_a + S_a(T_i)) / K_a(T_i); m = (theta(+h) - theta(-h)) / 2h"}


def apply_unseen_tempco(result: CalibrationResult, block: dict) -> Optional[GateOutcome]:
    """Widen the values' u by the stated bounds' Type B and judge the unstated (module docstring);
    the block goes to ``result.extra['unseen_tempco']``. Returns the gate's outcome."""
    stated = [s for s in block["sources"] if s["bound"] is not None]
    if stated:
        for n, p in list(result.parameters.items()):
            add = [s["moves_per_unit"][n] * s["bound"] / math.sqrt(3.0) for s in stated if n in s["moves_per_unit"]]
            if add:
                result.parameters[n] = replace(p, u=math.sqrt(p.u ** 2 + sum(c * c for c in add)))
        kinds = sorted({s["kind"] for s in stated})
        result.notes.append(
            "the poses' temperatures differ (" + f"{block['span_C']:.2g} degC from the reference {block['T_ref_C']:.2f} "
            "degC at most): the " + " and ".join(f"{k} tempco bound {next(s['bound'] for s in stated if s['kind'] == k):g} "
                                              f"{KINDS[k][0]}" for k in kinds)
            + " stated enter every value's u as a rectangular Type B contribution (|move per unit| x bound / sqrt 3; "
            "extra.unseen_tempco)")
    judged = [s for s in block["sources"] if s["bound"] is None]
    result.extra["unseen_tempco"] = block
    if not judged:
        return GateOutcome("unseen_tempco", True, "unidentifiable", "every tempco's bound is stated (Type B)", 0.0,
                           f"2-SD move <= {MOVE_MAX_U:g} u")

    def move(s):
        return math.inf if s["hidden"] is None else s["hidden"] * s["worst_u_per_unit"]

    worst = max(judged, key=move)
    m = move(worst)
    ok = m <= MOVE_MAX_U
    seen = ("which the recording cannot see (the change lies in the model's span: no redundancy tests it)"
            if worst["hidden"] is None else
            f"which the residuals would not see below {worst['hidden']:.3g} {worst['unit']} ({HIDDEN_SD:g} SD)")
    reason = (f"the poses' temperatures span {block['span_C']:.3g} degC about the reference {block['T_ref_C']:.2f} "
              f"degC and fit-raw fits no thermal term: a tempco {worst['source']} ({worst['unit']}), {seen}, "
              f"moves {worst['worst']} by {worst['worst_u_per_unit']:.3g} u per {worst['unit']}")
    if not ok:
        reason += (": the values are not those at the reference temperature to within their u; state the unit's "
                   "tempco bounds (--bias-tempco-bound UG_PER_DEGC, --scale-tempco-bound PPM_PER_DEGC, a datasheet's) "
                   "to carry them as Type B, or record at a steady temperature")
    return GateOutcome("unseen_tempco", ok, "unidentifiable", reason, m, f"2-SD move <= {MOVE_MAX_U:g} u")
