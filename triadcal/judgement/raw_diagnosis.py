"""Diagnosis of a raw recording after its fit (``triadcal fit-raw ... --diagnose OUT.json``).

Where, which and how far it shrinks, over the static intervals of the recording
(docs/diagnosis.md, "Diagnosing real recordings"):

- the data: each static interval's mean of the **calibrated** acceleration ``A_k`` (the fit's
  K, S, Ca applied to every sample) and its residual against gravity, ``r_k = |A_k| - g``
  (the gravity norm: free poses have no other reference, and for hand-placed poses the norm
  does not see the placement tilt); its noise floor ``sigma_k``, the standard error of the
  interval's mean of ``|A|`` from its own samples (the larger of SD/sqrt(n) and the SD of 10
  batch means / sqrt(10), as the goodness-of-fit gate of docs/raw.md);
- the base: what a refit of the calibration can still change and the norm can see, a
  symmetric correction matrix and a bias (9 parameters, :func:`terms.linear_correction`),
  fitted to the intervals by weighted Gauss-Newton; it is refitted in every fold, so the base
  is held to the same rule as the candidates;
- which: each candidate term of :mod:`triadcal.estimation.raw.terms` (and
  ``contaminated_interval``: drop the interval of largest robust z) added in turn and scored
  by **leave-one-interval-out cross-validation**: fitted without interval k, it predicts
  ``r_k``; the paired statistic over folds is ``d_k = z_base,k^2 - z_cand,k^2`` (held-out
  residuals in units of sigma_k);
- the rule: a candidate's held-out shrink is **significant** when mean(d) > 2 x its standard
  error sd(d)/sqrt(n); the gap is **significant** when the base fit's chi2 over the intervals
  has p < alpha (0.01) and chi2/dof > 1.2 (the goodness-of-fit gate's ratio); the verdict is
  ``null`` when the gap is not significant (the residual is at the noise floor), the
  significant candidate of the largest mean(d) when its full refit closes the gap (chi2 after
  no longer significant by the same rule), its **held-out** residual is at the floor
  (:func:`held_out_floor`: the held-out power sum z_k^2 against what a term that explains
  everything leaves there, sum 1/(1 - h_k) from its leverages, a scaled chi2; not at the floor
  when p < alpha and the ratio > 1.2, the gap's two-part rule) and it beats every rival held
  out, and ``unexplained`` otherwise (``best_partial``, ``gap_closed``, ``held_out_at_floor``);
  every verdict has a one-sentence ``reason``, one with a best candidate also ``evidence`` and
  ``size`` (its largest fitted correction with u: reported, not judged), a named term a
  ``caveat`` (the pattern beyond it the rule cannot see). The held-out test does not tell a
  candidate from an outside error whose norm pattern over the poses lies (nearly) in its span: a
  z error 500 ug cos(3 phi)(1 - a_z^2) leaves 11-14 ug RMS outside g_dependent_misalignment's span on
  40 free poses, against a 67 ug floor, and is named it (docs/diagnosis.md);
- the rivals (``terms.RIVALS``: a scale asymmetry ``e_i |a_i|``, K3 ``a_i^3``, an odd quadratic
  ``a_i |a_i|``, each on its own output): shapes outside the candidates, scored held out like
  them; the named candidate must predict the held-out intervals better than each by more than
  SHRINK_SE paired standard errors, else the verdict is ``unexplained`` with ``best_partial``,
  ``gap_closed: true`` and ``ambiguous_with``. On 40 free poses at 1 mg a sample K2 ``a_i^2``
  and an asymmetry ``|a_i|`` are not told apart: without the rivals an asymmetry of 800 or
  1500 ppm was named K2 in 11 of 12 recordings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from scipy import stats

from ..errors import InputError
from ..estimation.raw import terms as T
from ..models.sensor import calibrated_acceleration
from ..models.units import STANDARD_GRAVITY_M_S2
from .raw_verdict import (ALPHA, MIN_RIVAL_Z2, RATIO_MAX, SHRINK_SE, UG, _unseen, _verdict,  # noqa: F401 - the constants and
                          held_out_floor)                                     # held_out_floor: its API

FORMAT = "triadcal.diagnosis"
ROBUST_Z = 3.5           # an interval stands out when |modified z| of its residual exceeds this
CANDIDATES = ("scale_nonlinearity", "cross_coupling", "g_dependent_misalignment", "bias_tempco",
              "contaminated_interval")
#: rivals scored held out against a named candidate: the shapes of terms.RIVALS and a drifting bias
RIVAL_NAMES = tuple(T.RIVALS) + ("bias_drift",)


@dataclass
class IntervalData:
    """Calibrated interval means and their noise floor (g), with where and when."""

    A: np.ndarray            # (n, 3) mean calibrated acceleration, g
    sigma: np.ndarray        # (n,) standard error of the mean of |A|, g
    sd: np.ndarray           # (n,) SD of |A| over the samples, g
    n_samples: np.ndarray
    start: np.ndarray
    end: np.ndarray
    time_s: np.ndarray
    label: list
    gravity_g: float
    temperature_C: Optional[np.ndarray] = None
    #: what the rounding of readings on a grid added to ``sigma`` ("" when on no grid)
    rounding: str = ""


def interval_data(rawfit, temperature=None, batches: int = 10) -> IntervalData:
    """The static intervals of a :class:`~triadcal.estimation.raw.RawFit` with its calibration applied."""
    from ..estimation.raw.unknown import result_matrices

    rec, res = rawfit.recording, rawfit.result
    if temperature is not None:
        temperature = np.asarray(temperature, float).reshape(-1)
        if temperature.shape[0] != len(rec.acc):
            raise InputError(f"the temperature has {temperature.shape[0]} samples, the recording "
                             f"{rec.source or ''} {len(rec.acc)}: one temperature (degC) per sample is needed")
        if not np.all(np.isfinite(temperature)):
            bad = int(np.flatnonzero(~np.isfinite(temperature))[0])
            raise InputError(f"temperature sample {bad} is not a finite number ({temperature[bad]!r} degC)")
    K, S, Ca = result_matrices(res)
    local = res.fit.get("local_g_m_s2") or res.extra.get("local_g_m_s2") or STANDARD_GRAVITY_M_S2
    from ..estimation.raw.unknown import norm_mean_noise

    # every interval is used, as the fit uses them, with the fit's noise of its mean of |A|
    # (estimation/raw/unknown.norm_mean_noise: a short interval's SD floored by the pooled one, batch
    # means, the rounding of the readings); before, intervals under 2 samples were skipped unsaid and a
    # 2-sample interval's own SD, however small, weighted it
    avg = rawfit.averages
    sd, var = norm_mean_noise(rec, avg, K, S, Ca, batches=batches)
    bad = np.flatnonzero(~np.isfinite(sd))
    if bad.size:
        k = int(bad[0])
        raise InputError(f"{rec.source or 'the recording'}: the interval {avg.label[k] or avg.start[k]} has "
                         f"{int(avg.n[k])} sample(s) and no other interval gives the noise its mean needs")
    A = calibrated_acceleration(K, S, Ca, avg.w)
    sig = np.maximum(np.sqrt(var), 1e-12)
    s0, e0, n = np.asarray(avg.start), np.asarray(avg.end), np.asarray(avg.n)
    t, lab = (s0 + e0 - 1) / 2 / rec.rate_hz, [x or "" for x in avg.label]
    temp = [float(np.mean(temperature[a:b])) for a, b in zip(s0, e0)] if temperature is not None else None
    rounding = ""
    if avg.lsb is not None and np.any(avg.lsb > 0):
        rounding = (f": LSB {', '.join(f'{q:.4g}' for q in avg.lsb)}, rounding u of a mean "
                    f"{', '.join(f'{u:.3g}' for u in avg.rounding_u)} {rec.unit} (x, y, z)")
    return IntervalData(np.array(A), np.array(sig), np.array(sd), np.array(n), np.array(s0), np.array(e0),
                        np.array(t), lab, float(local) / STANDARD_GRAVITY_M_S2,
                        np.array(temp) if temperature is not None else None, rounding)


# --------------------------------------------------------------------------------------
# fits on the gravity norm
# --------------------------------------------------------------------------------------
def covariate(d: "IntervalData", name: str) -> Optional[np.ndarray]:
    """The centred covariate of a covariate term (``terms.COVARIATE_TERMS``), None when the
    recording has none (no temperature given)."""
    which = T.COVARIATE_TERMS[name][0]
    x = d.temperature_C if which == "temperature_C" else np.asarray(d.time_s, float) / 3600.0
    if x is None:
        return None
    x = np.asarray(x, float)
    return x - x.mean()


def _design(d: "IntervalData", term: Optional[str]) -> np.ndarray:
    A = d.A
    B = T.basis(T.linear_correction, A, len(T.BASE_NAMES))
    if term in T.COVARIATE_TERMS:
        x = covariate(d, term)
        B = np.concatenate([B, np.stack([T.per_output(x, e) for e in np.eye(3)], axis=-1)], axis=-1)
    elif term in T.TERMS:
        fn, names, _ = T.TERMS[term]
        B = np.concatenate([B, T.basis(fn, A, len(names))], axis=-1)
    elif term in T.RIVALS:
        fn, k = T.RIVALS[term]
        B = np.concatenate([B, T.basis(fn, A, k)], axis=-1)
    return B


def _residual(A, B, p, g):
    return np.linalg.norm(A + B @ p, axis=1) - g


def _gauss_newton(A, B, sigma, g, idx, iterations: int = 4):
    """Weighted least squares of ``|A + B p| - g`` over the intervals ``idx``; returns p, rank."""
    p = np.zeros(B.shape[-1])
    rank = 0
    for _ in range(iterations):
        Ap = A[idx] + B[idx] @ p
        nrm = np.linalg.norm(Ap, axis=1)
        J = np.einsum("ni,nip->np", Ap / nrm[:, None], B[idx]) / sigma[idx, None]
        r = (nrm - g) / sigma[idx]
        scale = np.linalg.norm(J, axis=0)
        scale[scale == 0] = 1.0
        dp, _, rank, _ = np.linalg.lstsq(J / scale, -r, rcond=1e-10)
        p = p + dp / scale
    return p, rank


def _modified_z(r: np.ndarray) -> np.ndarray:
    med = np.median(r)
    mad = np.median(np.abs(r - med))
    if mad <= 0:
        mad = np.mean(np.abs(r - med)) / 0.8 or 1.0
    return 0.6745 * (r - med) / mad


class _Model:
    """One candidate: fit on a subset of intervals, predict the others."""

    def __init__(self, d: IntervalData, name: Optional[str]):
        self.d, self.name = d, name
        self.B = _design(d, name)
        self.k = self.B.shape[-1] - len(T.BASE_NAMES)
        self.n_params = self.B.shape[-1]

    def fit(self, idx):
        """(p, rank, dropped interval or None) fitted on ``idx``."""
        d = self.d
        p, rank = _gauss_newton(d.A, self.B, d.sigma, d.gravity_g, idx)
        dropped = None
        if self.name == "contaminated_interval":
            z = _modified_z(_residual(d.A[idx], self.B[idx], p, d.gravity_g) / d.sigma[idx])
            dropped = int(idx[int(np.argmax(np.abs(z)))])
            keep = idx[idx != dropped]
            p, rank = _gauss_newton(d.A, self.B, d.sigma, d.gravity_g, keep)
        return p, rank, dropped

    def min_intervals(self) -> int:
        # every training fold keeps at least one residual dof
        return self.n_params + 2 + (1 if self.name == "contaminated_interval" else 0)


def _chi2(r, sigma, dof):
    chi2 = float(np.sum((r / sigma) ** 2))
    if dof < 1:
        return {"chi2": chi2, "dof": int(dof), "chi2_dof": None, "p_value": None, "significant": False}
    p = float(stats.chi2.sf(chi2, dof))
    return {"chi2": chi2, "dof": int(dof), "chi2_dof": chi2 / dof, "p_value": p,
            "significant": bool(p < ALPHA and chi2 / dof > RATIO_MAX)}


# --------------------------------------------------------------------------------------
# the diagnosis
# --------------------------------------------------------------------------------------
@dataclass
class RawDiagnosis:
    doc: dict
    data: IntervalData = field(repr=False, default=None)

    @property
    def verdict_term(self):
        return self.doc["verdict"]["term"]

    def candidate(self, name: str) -> dict:
        return next(c for c in self.doc["raw"]["candidates"] if c["term"] == name)

    def save(self, path) -> None:
        from ..io.atomic import atomic_write_json

        atomic_write_json(path, self.doc)


def diagnose_raw(rawfit, *, temperature=None, source: Optional[str] = None) -> RawDiagnosis:
    """Diagnose the fit of a raw recording (:func:`triadcal.estimation.raw.fit_raw`'s ``RawFit``);
    ``temperature`` (degC per sample) defaults to the recording's temperature column, if read."""
    if temperature is None:
        temperature = getattr(rawfit.recording, "temperature_C", None)
    return diagnose_intervals(interval_data(rawfit, temperature), source=source or rawfit.recording.source,
                              fit_status=rawfit.result.status, poses=("known" if rawfit.campaign is not None
                                                                      else "unknown"))


def diagnose_intervals(d: IntervalData, *, source=None, fit_status=None, poses=None) -> RawDiagnosis:
    n = len(d.sigma)
    g = d.gravity_g
    all_idx = np.arange(n)
    base = _Model(d, None)
    notes = []
    p0, rank0, _ = base.fit(all_idx) if n >= 1 else (np.zeros(base.n_params), 0, None)
    r0 = _residual(d.A, base.B, p0, g)
    dof0 = n - base.n_params
    gap = _chi2(r0, d.sigma, dof0)
    floor_ug = float(np.sqrt(np.mean(d.sigma ** 2))) * UG
    rms_ug = float(np.sqrt(np.mean(r0 ** 2))) * UG
    gap.update({"residual_rms_ug": rms_ug, "noise_floor_ug": floor_ug,
                "tests": {"chi2": {"p_value": gap["p_value"], "p_holm": gap["p_value"]}}})
    if dof0 < 1:
        gap["testable"] = (f"{n} intervals for the {base.n_params}-parameter norm correction: no residual "
                           f"degree of freedom, nothing can be held out")

    # where: every interval, and the up-axis slices
    z = r0 / d.sigma
    mz = _modified_z(r0) if n >= 3 else np.zeros(n)
    direction = d.A / np.linalg.norm(d.A, axis=1)[:, None]
    intervals = []
    for k in range(n):
        row = {"order": k + 1, "label": d.label[k], "start": int(d.start[k]), "end": int(d.end[k]),
               "time_s": float(d.time_s[k]), "n_samples": int(d.n_samples[k]),
               "gravity_direction": [round(float(v), 6) for v in direction[k]],
               "residual_ug": float(r0[k] * UG), "noise_floor_ug": float(d.sigma[k] * UG),
               "z": float(z[k]), "robust_z": float(mz[k]), "stands_out": bool(abs(mz[k]) > ROBUST_Z)}
        if d.temperature_C is not None:
            row["temperature_C"] = float(d.temperature_C[k])
        intervals.append(row)
    slices = _up_slices(direction, r0, d.sigma, dof0 >= 1)
    trends = _trends(d, z) if dof0 >= 1 else {}

    # which: leave-one-interval-out over the static intervals
    cands = []
    for name in CANDIDATES:
        cands.append(_score(d, name, base, r0, gap))
    tested = [c for c in cands if c["testable"]]
    sig = _parsimonious(sorted([c for c in tested if c["significant"]], key=lambda c: -c["held_out"]["mean_d"]))
    rivals = _rivals(d, base, r0, gap, sig[0]) if sig else []
    for c in cands + rivals:
        c.pop("_zc2", None)
    verdict = _verdict(gap, tested, sig, n, dof0, rms_ug, floor_ug, rivals)
    if verdict["effect"] is None and dof0 >= 1:
        from .raw_limits import detection_limits, limits_text

        verdict["detection_limits"] = detection_limits(d, base, p0, dof0)
        txt = limits_text(verdict["detection_limits"])
        if txt:
            verdict["reason"] += "; " + txt

    schema_cands = []
    for c in cands:
        e = {"effect": c["term"], "rank": len(schema_cands) + 1, "testable": c["testable"],
             "score": c.get("held_out", {}).get("z"), "reason": c.get("reason", "")}
        if c["testable"]:
            e["gap_before"] = {"chi2_dof": gap["chi2_dof"]}
            e["gap_after"] = {"chi2_dof": c["full_fit"]["chi2_dof"]}
            e["new_parameters"] = c["full_fit"]["new_parameters"]
        if not e["reason"]:
            del e["reason"]
        schema_cands.append(e)
    ranked = sorted(cands, key=lambda c: -(c.get("held_out", {}).get("mean_d", -math.inf) if c["testable"]
                                           else -math.inf))
    for i, c in enumerate(ranked):
        c["rank"] = i + 1
    doc = {
        "format": FORMAT, "version": 1, "model": [], "source": None if source is None else str(source),
        "noise": "the intervals' own scatter: standard error of each interval's mean of |A| (the larger of "
                 "SD/sqrt(n), times the correlation of its samples, and the SD of 10 batch means / sqrt(10)), with the "
                 "rounding of readings on a grid "
                 "(docs/raw.md, \"Readings on a grid\")" + d.rounding,
        "noise_known": True, "alpha": ALPHA,
        "gap": gap,
        "where": [s for s in slices if s["p_holm"] is not None and s["p_holm"] < ALPHA],
        "where_families": [],
        "candidates": schema_cands,
        "verdict": verdict,
        "fit": {"chi2_dof": gap["chi2_dof"], "n_obs": int(n), "n_params": int(base.n_params),
                "converged": True, "status": fit_status, "poses": poses,
                "correction": {nm: float(v) for nm, v in zip(T.BASE_NAMES, p0)}},
        "slices": slices,
        "notes": notes,
        "methods": METHODS,
        "raw": {"intervals": intervals, "candidates": sorted(cands, key=lambda c: c["rank"]),
                "standing_out": [row["order"] for row in intervals if row["stands_out"]],
                "trends": trends, "rule": RULE, "rivals": rivals},
    }
    if dof0 < 1:
        notes.append(gap["testable"])
    return RawDiagnosis(doc, d)


def _score(d: IntervalData, name: str, base: _Model, r0: np.ndarray, gap: dict) -> dict:
    n = len(d.sigma)
    if name in T.COVARIATE_TERMS and covariate(d, name) is None:
        return {"term": name, "n_parameters": 3, "testable": False, "significant": False,
                "reason": "no temperature of the intervals: give fit-raw --temperature-column COLUMN "
                          "(degC), or diagnose_raw(fit, temperature=per_sample_degC)"}
    m = _Model(d, name)
    out = {"term": name, "n_parameters": m.k if name != "contaminated_interval" else 0}
    if n < m.min_intervals():
        out.update({"testable": False, "significant": False,
                    "reason": f"{n} intervals: leave-one-out needs at least {m.min_intervals()} for "
                              f"{m.n_params} parameters{' and one dropped interval' if m.name == 'contaminated_interval' else ''}"})
        return out
    e_base, e_c = np.empty(n), np.empty(n)
    rank_short = 0
    for k in range(n):
        idx = np.delete(np.arange(n), k)
        pb, _, _ = base.fit(idx)
        pc, rank, _ = m.fit(idx)
        if rank < m.n_params:
            rank_short += 1
        e_base[k] = _residual(d.A[k:k + 1], base.B[k:k + 1], pb, d.gravity_g)[0]
        e_c[k] = _residual(d.A[k:k + 1], m.B[k:k + 1], pc, d.gravity_g)[0]
    zb, zc = e_base / d.sigma, e_c / d.sigma
    dd = zb ** 2 - zc ** 2
    mean_d = float(dd.mean())
    se_d = float(dd.std(ddof=1) / math.sqrt(n))
    rms_b, rms_c = float(np.sqrt(np.mean(e_base ** 2))) * UG, float(np.sqrt(np.mean(e_c ** 2))) * UG
    out["held_out"] = {
        "folds": n, "rms_base_ug": rms_b, "rms_ug": rms_c, "shrink_ug": rms_b - rms_c,
        "shrink_rel": (rms_b - rms_c) / rms_b if rms_b > 0 else None,
        "chi2_per_interval_base": float(np.mean(zb ** 2)), "chi2_per_interval": float(np.mean(zc ** 2)),
        "mean_d": mean_d, "se_d": se_d, "z": mean_d / se_d if se_d > 0 else None}
    out["significant"] = bool(mean_d > SHRINK_SE * se_d and mean_d > 0)
    out["_zc2"] = zc ** 2
    out["testable"] = rank_short == 0
    if rank_short:
        out["reason"] = f"rank-deficient in {rank_short} of {n} folds: the poses do not determine the term"
        out["significant"] = False
    # the full refit: how far the gap shrinks on all intervals, and the term's parameters
    p, _, dropped = m.fit(np.arange(n))
    r = _residual(d.A, m.B, p, d.gravity_g)
    keep = np.ones(n, bool)
    if dropped is not None:
        keep[dropped] = False
    after = _chi2(r[keep], d.sigma[keep], int(keep.sum()) - m.n_params)
    full = {"chi2_dof": after["chi2_dof"], "p_value": after["p_value"], "closes_gap": not after["significant"],
            "residual_rms_ug": float(np.sqrt(np.mean(r[keep] ** 2))) * UG, "new_parameters": {}}
    if after["dof"] >= 1:
        full["unseen"] = _unseen(d.sigma[keep], after["dof"])
    if name in T.TERMS or name in T.COVARIATE_TERMS:
        _, names, unit = T.TERMS[name] if name in T.TERMS else T.COVARIATE_TERMS[name]
        J = _jacobian(d, m.B, p)
        try:
            cov = np.linalg.inv(J.T @ J) * max(after["chi2_dof"] or 1.0, 1.0)
            u = np.sqrt(np.clip(np.diag(cov), 0, None))[len(T.BASE_NAMES):]
        except np.linalg.LinAlgError:
            u = np.full(m.k, np.nan)
        f = T.UNIT_FACTOR[unit]
        full["new_parameters"] = {nm: {"value": float(v * f), "u": (float(s * f) if np.isfinite(s) else None),
                                       "unit": unit} for nm, v, s in zip(names, p[len(T.BASE_NAMES):], u)}
    elif dropped is not None:
        full["dropped_interval"] = int(dropped) + 1
        full["dropped_residual_ug"] = float(r0[dropped] * UG)
    out["full_fit"] = full
    out["held_out"]["floor"] = held_out_floor(_jacobian(d, m.B, p)[keep], d.sigma[keep], (zc ** 2)[keep])
    return out


def _rivals(d: IntervalData, base, r0, gap, best: dict) -> list:
    """Each rival term (``terms.RIVALS``: shapes outside the candidate list) scored held out like a
    candidate, and compared with ``best`` fold by fold: ``best`` beats a rival when its held-out
    z^2 is smaller by more than SHRINK_SE paired standard errors and by MIN_RIVAL_Z2 per fold
    (``versus_best``). A rival it does
    not beat explains the held-out intervals as well: the data cannot tell them apart."""
    out = []
    for name in RIVAL_NAMES:
        if name == best["term"]:
            continue
        r = _score(d, name, base, r0, gap)
        r.pop("full_fit", None)
        if r["testable"]:
            diff = r["_zc2"] - best["_zc2"]           # > 0 where the rival predicts worse than best
            se = float(diff.std(ddof=1) / math.sqrt(len(diff)))
            r["versus_best"] = {"candidate": best["term"], "mean_diff": float(diff.mean()), "se": se,
                                "beaten": bool(float(diff.mean()) > max(SHRINK_SE * se, MIN_RIVAL_Z2))}
        out.append(r)
    return out


def _parsimonious(sig: list) -> list:
    """Among the significant candidates, the one with the fewest parameters whose held-out z^2 is not
    worse than the best's by more than SHRINK_SE standard errors (paired over folds) comes first:
    on a sphere of constant |g| a larger term can contain a smaller one (a_i^3 = a_i - a_i a_j^2 -
    a_i a_k^2: K2 lies in the span of the bias and the cross-coupling terms), so the larger never
    wins by chance."""
    if len(sig) < 2:
        return sig
    best = sig[0]
    ok = []
    for c in sig:
        diff = c["_zc2"] - best["_zc2"]          # > 0 where c predicts worse than the best
        se = float(diff.std(ddof=1) / math.sqrt(len(diff))) if len(diff) > 1 else 0.0
        if c is best or float(diff.mean()) <= SHRINK_SE * se:
            ok.append(c)
    chosen = min(ok, key=lambda c: (max(c["n_parameters"], 1), -c["held_out"]["mean_d"]))
    for c in ok:
        if c is not chosen:
            chosen.setdefault("indistinguishable_from", []).append(c["term"])
    return [chosen] + [c for c in sig if c is not chosen]


def _jacobian(d, B, p):
    Ap = d.A + B @ p
    nrm = np.linalg.norm(Ap, axis=1)
    return np.einsum("ni,nip->np", Ap / nrm[:, None], B) / d.sigma[:, None]


def _up_slices(direction, r, sigma, testable) -> list:
    """Offset of the norm residual per up axis (the dominant component of the gravity direction)."""
    out = []
    dom = np.argmax(np.abs(direction), axis=1)
    sign = np.sign(direction[np.arange(len(dom)), dom])
    for ax in range(3):
        for s in (1, -1):
            sel = (dom == ax) & (sign == s)
            m = int(sel.sum())
            if m == 0 or not testable:
                continue
            w = 1 / sigma[sel] ** 2
            mean = float(np.sum(w * r[sel]) / np.sum(w))
            zstat = mean * math.sqrt(float(np.sum(w)))
            p = float(2 * stats.norm.sf(abs(zstat)))
            out.append({"slice": f"up={'+' if s > 0 else '-'}{'XYZ'[ax]}", "family": "up", "axis": "xyz"[ax],
                        "test": "offset", "n": m, "statistic": zstat, "size": mean * UG, "unit": "ug",
                        "p_value": p, "log10_p": math.log10(max(p, 1e-300))})
    ps = [s["p_value"] for s in out]
    order = np.argsort(ps)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(ps) - rank) * ps[i]))
        out[i]["p_holm"] = running
    return sorted(out, key=lambda s: s["p_value"])


def _trends(d: IntervalData, z) -> dict:
    out = {}
    series = {"order": np.arange(len(z), dtype=float), "time_s": d.time_s}
    if d.temperature_C is not None:
        series["temperature_C"] = d.temperature_C
    for name, x in series.items():
        if len(z) < 4 or np.ptp(x) == 0:
            continue
        rho, p = stats.spearmanr(x, z)
        out[name] = {"spearman_rho": float(rho), "p_value": float(p)}
    return out


RULE = (f"leave-one-interval-out: each candidate (and the 9-parameter base correction) is fitted without interval "
        f"k and predicts its residual |A_k| - g; d_k = z_base,k^2 - z_cand,k^2 with z = held-out residual / the "
        f"interval's noise floor; a candidate is significant when mean(d) > {SHRINK_SE:g} x sd(d)/sqrt(n). Among the "
        f"significant, the one of fewest parameters whose held-out z^2 is within {SHRINK_SE:g} paired standard "
        f"errors of the best is preferred (on a sphere of constant |g| K2 lies in the span of the bias and the "
        f"cross-coupling terms). The gap "
        f"is significant when the base fit's chi2 over the intervals has p < {ALPHA} and chi2/dof > {RATIO_MAX}. "
        f"Verdict: null when the gap is not significant; the significant candidate of the largest mean(d) when "
        f"its refit on every interval leaves no significant gap, its held-out residual is at the floor (the "
        f"held-out power sum z_k^2 against its expectation for a term that explains everything, sum 1/(1 - h_k) "
        f"with h the leverages of its refit, as a scaled chi2 of the same mean and variance: not at the floor "
        f"when p < {ALPHA} and the ratio > {RATIO_MAX}) and its held-out z^2 beats that of every rival "
        f"outside the candidates ({', '.join(RIVAL_NAMES)}) by more than {SHRINK_SE:g} paired standard errors; "
        f"otherwise unexplained (best_partial; ambiguous_with: the rivals it does not beat). An interval stands out "
        f"when the modified z (0.6745 (r - median)/MAD) of its residual exceeds {ROBUST_Z:g}.")

METHODS = {
    "gap": "chi2 of the interval residuals |A_k| - g after the base correction (symmetric matrix + bias, 9 "
           "parameters) against the intervals' own noise floor, chi2(n - 9)",
    "where": "per interval: residual, z, modified z; offset of the residual per up axis (Holm); Spearman "
             "correlation of z with the order, time and (when given) temperature",
    "which": RULE,
}


def summary_lines(diag: RawDiagnosis) -> list:
    """What ``fit-raw --diagnose`` prints: the gap, the candidates' held-out shrink, the verdict."""
    doc = diag.doc
    gap = doc["gap"]
    n = doc["fit"]["n_obs"]
    if gap["chi2_dof"] is None:
        # never "chi2/dof -": say why there is no ratio (issue 18, item 6)
        level = (f"no chi2: {n} intervals for the {doc['fit']['n_params']}-parameter norm correction leave no "
                 "residual degree of freedom")
    else:
        level = f"chi2/dof {gap['chi2_dof']:.3g}, {gap['dof']} dof"
    lines = [f"diagnosis over {n} static intervals: residual RMS {gap['residual_rms_ug']:.4g} ug after the fit, "
             f"noise floor {gap['noise_floor_ug']:.4g} ug ({level})"]
    out = doc["raw"]["standing_out"]
    if out:
        lines.append(f"  intervals standing out (|modified z| > {ROBUST_Z:g}): {', '.join(map(str, out))}")
    for c in doc["raw"]["candidates"]:
        if not c["testable"]:
            lines.append(f"  {c['term']:<26s} not testable: {c.get('reason', '')}")
            continue
        h = c["held_out"]
        zs = "-" if h["z"] is None else f"{h['z']:.2f}"
        lines.append(f"  {c['term']:<26s} held-out RMS {h['rms_base_ug']:.4g} -> {h['rms_ug']:.4g} ug "
                     f"(shrink {h['shrink_ug']:+.4g} ug, d/SE {zs}){'  significant' if c['significant'] else ''}")
    for r in doc["raw"].get("rivals", []):
        if not r["testable"]:
            continue
        h, vb = r["held_out"], r["versus_best"]
        lines.append(f"  rival {r['term']:<20s} held-out RMS {h['rms_base_ug']:.4g} -> {h['rms_ug']:.4g} ug; "
                     f"against {vb['candidate']}: z^2 worse by {vb['mean_diff']:.3g} +- {vb['se']:.3g} "
                     f"({'beaten' if vb['beaten'] else 'not beaten'})")
    v = doc["verdict"]
    lines.append(f"verdict: {v['term'] if v.get('term') else 'null'} ({v['reason']})")
    if v.get("evidence"):
        lines.append(f"  evidence: {v['evidence']}")
    if v.get("caveat"):
        lines.append(f"  caveat: {v['caveat']}")
    return lines
