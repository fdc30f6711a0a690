"""``fit_raw``: read a recording, find its static intervals, average them, fit known or
unknown poses, and pass the result through the answer gates.
"""

from __future__ import annotations

from ...errors import InputError

import math
from dataclasses import dataclass, replace
from typing import Optional, Sequence, Union

import numpy as np

from ...io.raw import RawRecording, check_declared_unit, read_intervals, read_raw_csv
from ...models.campaign import Campaign
from ...models.units import STANDARD_GRAVITY_M_S2
from .motion import interval_turns, turning_gate
from .tempco import apply_unseen_tempco, unseen_tempco
from ..gates import (
    add_outcome,
    DEFAULT_CONFIG,
    FitEvidence,
    GateConfig,
    GateOutcome,
    apply_gates,
)
from ..joint import Solution
from ..result import CalibrationResult
from .detection import (
    POSE_LABELS,
    StaticDetection,
    StaticIntervalError,
    detect_static_intervals,
    intervals_from_labels,
    intervals_from_spec,
    pose_label_of,
    robust_noise_sd,
)
from .known import fit_known_poses
from .poses import PoseAverages, bench_campaign, pose_averages
from .sample import sample_known_poses, sample_unknown_poses
from .unknown import (
    fit_unknown_poses,
    nominal_scale,
    norm_residual_rms_m_s2,
    result_matrices,
)


# --------------------------------------------------------------------------------------
# the library function behind `triadcal fit-raw`
# --------------------------------------------------------------------------------------
@dataclass
class RawFit:
    """Everything ``fit-raw`` produced: the result, what the static step found, the averages,
    and (known poses) the bench campaign of the averages."""

    result: CalibrationResult
    detection: StaticDetection
    averages: PoseAverages
    recording: RawRecording
    campaign: Optional[Campaign] = None
    solution: Optional[Solution] = None
    posterior_run: Optional[object] = None     # PosteriorRun when sampled


def static_intervals_of(rec: RawRecording, *, labels: Optional[str] = None, intervals=None,
                        poses: str = "known", window_s: float = 1.0, threshold: float = 4.0,
                        min_duration_s: float = 2.0) -> StaticDetection:
    """The static intervals from the label column, an interval file, or the detector. In known-pose
    mode detected intervals are labelled by the up axis of their mean reading."""
    if labels is not None and intervals is not None:
        raise InputError("give either a label column or an interval file, not both")
    if labels is not None:
        if rec.labels is None:
            raise InputError(f"{rec.source}: the recording was read without its label column '{labels}'")
        det = intervals_from_labels(rec.labels, labels, POSE_LABELS if poses == "known" else None)
    elif intervals is not None:
        spec = read_intervals(intervals)
        det = intervals_from_spec(spec.start, spec.end, spec.labels, rec.n, spec.source,
                                  POSE_LABELS if poses == "known" else None)
    else:
        det = detect_static_intervals(rec.acc, rec.rate_hz, window_s=window_s, threshold=threshold,
                                      min_duration_s=min_duration_s)
    if labels is not None or intervals is not None:
        refuse_moving_intervals(rec, det, window_s, threshold)
    if poses == "known":
        for iv in det.intervals:
            if not iv.label:
                iv.label = pose_label_of(rec.acc[iv.start:iv.end].mean(axis=0))
    if not det.intervals:
        known = (f"; a face is named {', '.join(POSE_LABELS)} (imucal's: x_p = +X up, x_a = X down)"
                 if poses == "known" and det.ignored else "")
        raise StaticIntervalError(f"{rec.source}: no static intervals ({det.summary(rec.rate_hz)}){known}")
    return det


def refuse_moving_intervals(rec: RawRecording, det: StaticDetection, window_s: float, threshold: float) -> None:
    """Refuse a labelled or given interval whose samples' SD on an axis exceeds ``threshold`` times the
    recording's noise SD (the detector's own rule for rest, detection.robust_noise_sd): it holds motion.
    An outside probe's face labels reaching 1.5 s into the next move ended in NaN everywhere with status
    non_finite and a note blaming swapped columns (the placement evidence at its grid's edge); shorter
    reaches (0.4 s) were ok with each mean's u widened by the motion. The SD ratio of clean labels:
    1.0-1.2 (imucal's annotated session, simulated faces); labels 0.4-2 s into the moves: 4-220."""
    from .poses import refuse_clipped, refuse_wrapped

    refuse_wrapped(rec, det)        # the more specific reasons first: a wrapped or clipped channel moves too
    refuse_clipped(rec, det)
    window = max(3, int(round(window_s * rec.rate_hz)))
    sigma = robust_noise_sd(rec.acc, window)
    bad = []
    for k, iv in enumerate(det.intervals):
        if iv.n < 3:
            continue
        ratio = rec.acc[iv.start:iv.end].std(axis=0, ddof=1) / sigma
        a = int(np.argmax(ratio))
        if ratio[a] > threshold:
            bad.append(f"{iv.label or k + 1} (samples {iv.start}..{iv.end - 1}, {iv.start / rec.rate_hz:.2f}-"
                       f"{(iv.end - 1) / rec.rate_hz:.2f} s): SD of {rec.columns[a] if rec.columns else 'xyz'[a]} "
                       f"{ratio[a]:.3g} x the noise")
    if bad:
        raise StaticIntervalError(
            f"{rec.source}: {len(bad)} of the {det.method.split()[0]}' intervals move (an interval's SD beyond "
            f"{threshold:g} x the recording's noise SD, {', '.join(f'{s:.3g}' for s in sigma)} {rec.unit}, the "
            f"detector's rule for rest): {'; '.join(bad)}. Trim them to the still part, or leave the intervals to "
            "the detector (no --labels/--intervals); --static-threshold sets the ratio")


def samples_sha256(rec: RawRecording) -> str:
    """SHA-256 (64 lowercase hex digits) of the recording's accelerometer samples in order, as
    little-endian float64 bytes row by row: what was measured, not the file's name, format, rate,
    labels or the options of the fit, so two fits of one recording (known poses and ``--poses
    unknown``, another interval file, ``--sample``) carry the same hash and ``compare`` calls them
    two fits of one data set (``Campaign.data_sha256`` is the bench CSV's)."""
    import hashlib

    return hashlib.sha256(np.ascontiguousarray(np.asarray(rec.acc, dtype="<f8")).tobytes()).hexdigest()


#: the local g (m/s^2) taken when none is stated, and Earth's surface range it may be off by
ASSUMED_LOCAL_G_M_S2 = 9.81
EARTH_G_RANGE_M_S2 = (9.780, 9.832)


def assumed_g_note(result) -> str:
    """What an assumed local g can cost: K and S scale with g one to one (A = Ca^-1 (K W - S) is fitted
    to |A| = g), so a local g anywhere on Earth's surface moves them by up to the range's half-width
    over g, which their u (the data's) does not hold. An outside probe: a recording made at 9.78 m/s^2,
    fitted without --local-g, gave K 0.3 % (about 100 u) high with status ok."""
    lo, hi = EARTH_G_RANGE_M_S2
    rel = max(ASSUMED_LOCAL_G_M_S2 - lo, hi - ASSUMED_LOCAL_G_M_S2) / ASSUMED_LOCAL_G_M_S2
    k = result.parameters.get("K_x")
    times = (f", {rel * abs(k.value) / k.u:.3g} times K_x's u" if k is not None and k.u > 0 else "")
    return (f"local g not stated: {ASSUMED_LOCAL_G_M_S2:g} m/s2 assumed. K and S scale with it one to one: "
            f"anywhere on Earth's surface ({lo:g}-{hi:g} m/s2) that is up to {100 * rel:.2g} %{times}, which their "
            "u does not hold; give --local-g (the site's value) for K and S to be the unit's, and for a "
            "certificate (refused without it)")


def check_raw_options(local_g_m_s2: float, local_g_override: bool = False, *, window_s: float = 1.0,
                      threshold: float = 4.0, min_duration_s: float = 2.0) -> None:
    """The options of :func:`fit_raw` that the data cannot check, before anything is read (the library,
    ``triadcal fit-raw`` and ``batch`` manifests alike): a local g in m/s2 on Earth's surface (the bench
    reader's 9.76-9.84, ``LOCAL_G_RANGE_M_S2``) unless ``local_g_override`` (then still positive and at most
    100), and the static detector's window and threshold positive, its minimum duration not negative, all
    finite. Before, ``--local-g 1`` (g typed in g) gave K 9.81 times too small with status ok."""
    from ...io.bench_csv import LOCAL_G_MAX_M_S2, LOCAL_G_RANGE_M_S2

    g = local_g_m_s2
    if isinstance(g, bool) or not isinstance(g, (int, float)) or not (math.isfinite(g) and 0 < g <= LOCAL_G_MAX_M_S2):
        raise InputError(f"--local-g must be a positive number of m/s2, at most {LOCAL_G_MAX_M_S2:g}, got {g!r}")
    low, high = LOCAL_G_RANGE_M_S2
    if not local_g_override and not low <= g <= high:
        raise InputError(f"--local-g {g:g} m/s2 is outside {low}-{high} m/s2, the local gravity anywhere on "
                         "Earth's surface (it is in m/s2, not in g); if it is right (a centrifuge, another planet, a "
                         "deliberate test), add --local-g-override")
    for name, option, v, strict in (("window_s", "--static-window-s", window_s, True),
                                    ("threshold", "--static-threshold", threshold, True),
                                    ("min_duration_s", "--min-static-s", min_duration_s, False)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0 or (strict and v == 0):
            raise InputError(f"{option} must be a finite number {'>' if strict else '>='} 0 ({name}), got {v!r}")


def fit_raw(data, rate_hz: Optional[float] = None, *, columns: Optional[Sequence[str]] = None,
            unit: str = "counts", poses: str = "known", labels: Optional[str] = None, intervals=None,
            local_g_m_s2: Optional[float] = None, placement_sd_deg: Union[float, str] = "auto", misalignment_sd_deg: float = 1.0,
            counts_per_g: Optional[float] = None,
            serial: Optional[str] = None, window_s: float = 1.0, threshold: float = 4.0,
            min_duration_s: float = 2.0, json_path=None, bench_csv_path=None, sample: bool = False,
            posterior_path=None, priors=None, ess: float = 2000, seed: int = 0, max_steps: int = 20000,
            progress=None, n_walkers: Optional[int] = None, gates: GateConfig = DEFAULT_CONFIG,
            temperature_column: Optional[str] = None, local_g_override: bool = False,
            tempco_bounds: Optional[dict] = None) -> RawFit:
    """Calibrate from a raw recording (``triadcal fit-raw``).

    ``data`` is a CSV path (read with :func:`triadcal.io.raw.read_raw_csv` at the stated
    ``rate_hz``) or a :class:`RawRecording`. ``poses``: ``known`` (imucal's six faces) or
    ``unknown`` (free orientations, gravity norm). The result's ``fit`` block carries
    ``rms_norm_residual_m_s2`` (RMS of |A| - g over the static samples) before (nominal
    scaling) and after the calibration.

    ``sample``: the posterior through the bench's path (:mod:`triadcal.estimation.posterior`:
    same moves, stop rule, diagnostics, flags); the result is then the posterior's (method
    ``posterior``, the least-squares values under ``fit.least_squares``), ``posterior_path``
    receives the arviz InferenceData, ``priors`` overrides :func:`raw_priors` by name, ``ess``,
    ``seed``, ``max_steps``, ``progress`` as in :func:`triadcal.estimation.posterior.sample`.
    ``temperature_column``: a column of the file with the unit's temperature (degC), kept on the
    recording for the diagnosis (``diagnose_raw``) and for the gate ``unseen_tempco``
    (:mod:`.tempco`): where the poses' temperatures differ, what a bias or scale tempco the fit leaves
    out moves; ``tempco_bounds`` {"bias": ug/degC, "scale": ppm/degC}, a datasheet's bounds stated by the
    user, carry it into the u as Type B instead.
    ``local_g_override``: accept a local g outside Earth's surface range (:func:`check_raw_options`).
    ``local_g_m_s2`` None (not stated): :data:`ASSUMED_LOCAL_G_M_S2` is used, the result says so
    (``extra.local_g_stated`` false, a note with what it can cost K and S) and no certificate is issued.
    """
    if posterior_path is not None and not sample:
        raise InputError("a posterior file needs sampling (--sample)")
    if poses not in ("known", "unknown"):
        raise InputError(f"poses must be 'known' or 'unknown', got {poses!r}")
    local_g_stated = local_g_m_s2 is not None
    if not local_g_stated:
        local_g_m_s2 = ASSUMED_LOCAL_G_M_S2
    check_raw_options(local_g_m_s2, local_g_override, window_s=window_s, threshold=threshold,
                      min_duration_s=min_duration_s)
    if isinstance(data, RawRecording):
        rec = data
    else:
        if rate_hz is None:
            raise InputError("state the sample rate (--rate HZ): it cannot be guessed safely (imucal issue #25)")
        rec = read_raw_csv(data, rate_hz, columns, unit, labels, temperature_column)
    gravity_g = local_g_m_s2 / STANDARD_GRAVITY_M_S2
    serial = serial or (str(rec.source).rsplit("/", 1)[-1].rsplit(".", 1)[0])
    try:
        det = static_intervals_of(rec, labels=labels, intervals=intervals, poses=poses, window_s=window_s,
                                  threshold=threshold, min_duration_s=min_duration_s)
        avg = pose_averages(rec, det)
        check_declared_unit(rec, avg.w, local_g_m_s2)
        return _fit_raw_detected(rec, det, avg, poses=poses, gravity_g=gravity_g, serial=serial,
                                 local_g_m_s2=local_g_m_s2, placement_sd_deg=placement_sd_deg,
                                 misalignment_sd_deg=misalignment_sd_deg, counts_per_g=counts_per_g,
                                 json_path=json_path, bench_csv_path=bench_csv_path, sample=sample,
                                 posterior_path=posterior_path, priors=priors, ess=ess, seed=seed,
                                 max_steps=max_steps, progress=progress, n_walkers=n_walkers, gates=gates,
                                 local_g_stated=local_g_stated, tempco_bounds=tempco_bounds)
    except StaticIntervalError as exc:
        if str(rec.source) in str(exc):
            raise
        raise StaticIntervalError(f"{rec.source}: {exc}") from None


def _fit_raw_detected(rec, det, avg, *, poses, gravity_g, serial, local_g_m_s2, placement_sd_deg,
                      misalignment_sd_deg, counts_per_g, json_path, bench_csv_path, sample, posterior_path, priors,
                      ess, seed, max_steps, progress, n_walkers, gates, local_g_stated=True,
                      tempco_bounds=None) -> RawFit:
    campaign = None
    if poses == "known":
        result, problem, sol = fit_known_poses(avg, gravity_g=gravity_g, scale_unit=rec.scale_unit,
                                               serial=serial, placement_sd_deg=placement_sd_deg,
                                               misalignment_sd_deg=misalignment_sd_deg, gates=gates)
        campaign = bench_campaign(avg, rec, serial, local_g_m_s2 if local_g_stated else None)
    else:
        result, problem, sol = fit_unknown_poses(rec, avg, gravity_g=gravity_g, serial=serial, gates=gates)
    if poses == "known" and det.method == "detector":
        # an outside probe: acc_y,acc_x,acc_z or an inverted Y column on faces the detector named: status ok,
        # K_x the true K_y (52 u), S_y sign-flipped (317 u), nothing said (with --labels both are refused)
        result.notes.append("known poses named from the data (the detector: each face by the axis that reads "
                            "+-1 g): a swapped or inverted column names its faces accordingly and fits as well, so "
                            "it is not detected; the columns are taken as labelled (--labels, a face column "
                            "written while recording, checks them)")
    # a unit turning slowly through its holds: the detector's windows miss it, K takes it (motion.py)
    gate, note = turning_gate(result, interval_turns(rec.acc, avg.start, avg.end, rec.rate_hz), avg.label,
                              gates.gof_p_min)
    if gate is not None:
        add_outcome(result, gate)
    if note:
        result.notes.append(note)
    tempco = _unseen_tempco_block(result, rec, avg, poses, gravity_g, serial, misalignment_sd_deg, gates,
                                  tempco_bounds)
    run = None
    if sample:
        opts = dict(serial=serial, scale_unit=rec.scale_unit, priors=priors, posterior_path=posterior_path,
                    ess=ess, seed=seed, max_steps=max_steps, progress=progress, n_walkers=n_walkers)
        ls = result
        if poses == "known":
            result, run = sample_known_poses(result, problem, sol, avg.label, **opts)
        else:
            result, run = sample_unknown_poses(result, problem, sol, **opts)
        # the posterior is no better an answer than its least-squares fit: that fit's gates carry over
        result.extra.update({"output_unit": rec.unit, "local_g_m_s2": local_g_m_s2})
        ls_gate = GateOutcome("least_squares", ls.status in ("ok", "not_converged"),
                              ls.status if ls.status != "ok" else "model_mismatch",
                              f"the least-squares fit of the same model has status {ls.status!r}")
        apply_gates(result, FitEvidence(converged=run.converged, extra=[ls_gate]), config=gates)
    k0, how = nominal_scale(rec, det, gravity_g, counts_per_g)
    before = norm_residual_rms_m_s2(rec, det, np.full(3, k0), np.zeros(3), np.eye(3), gravity_g)
    after = norm_residual_rms_m_s2(rec, det, *result_matrices(result), gravity_g)
    result.fit.update({
        "rms_norm_residual_m_s2": {"before": before["samples"], "after": after["samples"]},
        "rms_norm_residual_of_means_m_s2": {"before": before["means"], "after": after["means"]},
        "before_scaling": how, "local_g_m_s2": local_g_m_s2})
    result.extra.update({"input_unit": rec.unit, "output_unit": rec.unit, "local_g_m_s2": local_g_m_s2,
                         "source": rec.source, "data_sha256": samples_sha256(rec), "rate_hz": rec.rate_hz,
                         "static_intervals": det.to_dict(rec.rate_hz)})
    for note in avg.notes:
        if note not in result.notes:
            result.notes.append(note)
    result.extra["local_g_stated"] = bool(local_g_stated)
    if not local_g_stated:
        result.notes.append(assumed_g_note(result))
    recording_temperature(result, rec, avg)
    if tempco is not None:
        add_outcome(result, apply_unseen_tempco(result, tempco))
    if json_path is not None:
        result.save(json_path)
    if bench_csv_path is not None:
        if campaign is None:
            raise InputError("--bench-csv needs known poses: free orientations have no bench angles")
        from ...io.bench_csv import write_bench_csv

        # the file's fit and this one are fits of one data set: compare must say so (Campaign.derived_from_sha256)
        write_bench_csv(replace(campaign, metadata={**campaign.metadata,
                                                    "raw_samples_sha256": samples_sha256(rec)}), bench_csv_path)
    return RawFit(result, det, avg, rec, campaign, sol, run)


#: a recording whose static intervals span more than this (degC) gets a note of what the span can cost
#: and the gate ``unseen_tempco``
TEMPERATURE_SPAN_NOTE_C = 1.0


def _unseen_tempco_block(result, rec, avg, poses, gravity_g, serial, misalignment_sd_deg, gates, bounds):
    """:func:`.tempco.unseen_tempco` of the least-squares ``result`` where the static intervals'
    temperatures span more than :data:`TEMPERATURE_SPAN_NOTE_C`; the refits hold the placement SD the
    fit chose (known poses) and weight the gravity norms by the noise of the means (free poses)."""
    if rec.temperature_C is None or result.status not in ("ok", "model_mismatch"):
        return None
    T = np.concatenate([rec.temperature_C[a:b] for a, b in zip(avg.start, avg.end)])
    if not float(np.max(T) - np.min(T)) > TEMPERATURE_SPAN_NOTE_C:
        return None
    pose_T = np.array([np.mean(rec.temperature_C[a:b]) for a, b in zip(avg.start, avg.end)])
    if poses == "known":
        sd = float(result.fit["placement_sd_deg"])

        def refit(w):
            r, _, s = fit_known_poses(replace(avg, w=w), gravity_g=gravity_g, scale_unit=rec.scale_unit,
                                      serial=serial, placement_sd_deg=sd, misalignment_sd_deg=misalignment_sd_deg,
                                      gates=gates)
            return r, float(s.r @ s.r)
    else:
        noise = float(result.fit["noise_variance_g2"])

        def refit(w):
            r, _, s = fit_unknown_poses(rec, replace(avg, w=w), gravity_g=gravity_g, serial=serial, gates=gates)
            return r, float(s.r @ s.r) / noise
    return unseen_tempco(result, avg.w, pose_T, float(np.mean(T)), refit, bounds)


def recording_temperature(result: CalibrationResult, rec: RawRecording, avg: PoseAverages) -> None:
    """The temperature the raw fit's values refer to. With a temperature column: the mean over the
    static intervals' samples is the reference temperature, their lowest and highest the range (an
    outside probe: a recording at 25-45 degC was reported, and certified, "at the reference temperature
    20 degC", S 6-10 u from the truth there); fit-raw fits no thermal terms, so a span of more than
    :data:`TEMPERATURE_SPAN_NOTE_C` gets a note. Without one the temperature is not known: the result
    keeps the nominal 20 degC that results must state, ``extra.reference_temperature_stated`` false,
    and the certificate says the values hold at the recording's temperature."""
    if rec.temperature_C is None:
        result.extra["reference_temperature_stated"] = False
        return
    T = np.concatenate([rec.temperature_C[a:b] for a, b in zip(avg.start, avg.end)])
    lo, hi, mean = float(np.min(T)), float(np.max(T)), float(np.mean(T))
    result.reference_temperature_C = round(mean, 2)
    result.temperature_range_C = (round(lo, 2), round(hi, 2))
    result.extra["reference_temperature_stated"] = True
    if hi - lo > TEMPERATURE_SPAN_NOTE_C:
        result.notes.append(
            f"the unit's temperature ({rec.temperature_column}) spans {lo:.1f} .. {hi:.1f} degC over the static "
            f"intervals: fit-raw fits no thermal terms, so K, S and the angles are those at about their mean "
            f"{mean:.1f} degC (the reference temperature); a bias tempco c moves S by c x {(hi - lo) / 2:.1f} degC "
            "at the ends, which the fit does not see (a bench campaign over setpoints with the thermal effects "
            "measures it)")
