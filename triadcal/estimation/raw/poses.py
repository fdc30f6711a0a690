"""Static intervals of a recording as pose averages (mean, its uncertainty from batch means) and
as a bench CSV campaign on the default plan's positions (docs/raw.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...io.raw import RawRecording
from ...models.campaign import DEFAULT_PLAN, Campaign
from ...models.sensor import ANGLE_NAMES, AXES
from .detection import (
    StaticDetection,
    StaticIntervalError,
)

#: imucal pose label -> bench position of DEFAULT_PLAN with the same axis up
POSE_POSITIONS = {"y_p": "P01", "y_a": "P03", "x_p": "P05", "x_a": "P07", "z_p": "P09", "z_a": "P11"}


#: the angles the gravity-norm model can determine (imu_tk's upper-triangular frame)
NORM_ANGLES = ("xy", "xz", "yz")


UNIT_NAMES = tuple(f"K_{a}" for a in AXES) + tuple(f"S_{a}" for a in AXES) + tuple(f"Ca_{ab}" for ab in ANGLE_NAMES)


NORM_NAMES = tuple(f"K_{a}" for a in AXES) + tuple(f"S_{a}" for a in AXES) + tuple(f"Ca_{ab}" for ab in NORM_ANGLES)


# --------------------------------------------------------------------------------------
# position averages
# --------------------------------------------------------------------------------------
@dataclass
class PoseAverages:
    """Mean reading of each static interval and its standard uncertainty.

    ``se`` is the larger of the white-noise ``sd / sqrt(n)`` and a batch-means estimate
    (10 consecutive batches), so slowly correlated noise does not shrink it.
    """

    label: list
    start: np.ndarray
    end: np.ndarray
    w: np.ndarray
    sd: np.ndarray
    n: np.ndarray
    se: np.ndarray
    time_s: np.ndarray
    tau_s: np.ndarray


#: a static interval with at least this fraction of one channel's samples on the recording's extreme
#: value is a pile, examined as a clipped channel (:func:`clipped_intervals`)
PILE_FRACTION = 0.2


def clipped_intervals(rec: RawRecording, detection: StaticDetection) -> list:
    """``[(interval, axis, extreme, count, n, expected_fraction), ...]``: the static intervals in
    which a channel sits on the recording's largest or smallest value far more often than its noise
    allows: a channel clipped at full scale (its readings beyond the range collapse onto one value).

    A channel whose noise elsewhere has SD ``sigma`` (the median SD of its other static intervals)
    and whose readings come in steps ``q`` (the smallest difference of its distinct values: one
    count of a digital output, ~0 for floats) puts at most ``q / (sigma sqrt(2 pi))`` of its samples
    on one value (the peak of a normal density times the step; 1 when the noise is below a step).
    A pile of at least :data:`PILE_FRACTION` and three times that bound on the recording's extreme is
    clipping: an axis clipped at 2075 counts held 684 of its samples there, with sigma 8 counts
    (bound 5 %), and the fit said ok with K_x 19 u off (an outside probe)."""
    out = []
    ivs = [iv for iv in detection.intervals if iv.end - iv.start >= 2]
    if len(ivs) < 2:
        return out
    for a in range(rec.acc.shape[1]):
        col = rec.acc[:, a]
        values = np.unique(col)
        if len(values) < 2:
            continue
        q = float(np.min(np.diff(values)))
        sds = [float(np.std(col[iv.start:iv.end], ddof=1)) for iv in ivs]
        for ext in (float(values[-1]), float(values[0])):
            for k, iv in enumerate(ivs):
                x = col[iv.start:iv.end]
                count = int(np.count_nonzero(x == ext))
                if count < PILE_FRACTION * len(x):
                    continue
                others = [v for j, v in enumerate(sds) if j != k and v > 0]
                if not others:
                    continue
                bound = min(1.0, q / (float(np.median(others)) * math.sqrt(2.0 * math.pi)))
                if count > max(PILE_FRACTION, 3.0 * bound) * len(x):
                    out.append((iv, a, ext, count, len(x), bound))
    return out


def refuse_clipped(rec: RawRecording, detection: StaticDetection) -> None:
    """Refuse a recording with a clipped static interval (:func:`clipped_intervals`), naming it."""
    clipped = clipped_intervals(rec, detection)
    if not clipped:
        return
    parts = [f"{'xyz'[a] if a < 3 else a} in the interval {iv.label or '(unlabelled)'} (samples {iv.start}-{iv.end - 1}): "
             f"{count} of {n} samples on the recording's {'largest' if ext == float(np.max(rec.acc[:, a])) else 'smallest'}"
             f" value {ext:g} {rec.unit}, where its noise elsewhere puts at most {bound:.1%} on one value"
             for iv, a, ext, count, n, bound in clipped]
    raise InputError(f"{rec.source}: a channel is clipped at full scale: " + "; ".join(parts)
                     + ". The readings of that pose are not the unit's: redo it with a range that holds it, or "
                       "leave the interval out (--intervals)")


def pose_averages(rec: RawRecording, detection: StaticDetection, batches: int = 10) -> PoseAverages:
    refuse_clipped(rec, detection)
    w, sd, n, se, t, tau, lab, s0, e0 = [], [], [], [], [], [], [], [], []
    for iv in detection.intervals:
        x = rec.acc[iv.start:iv.end]
        if len(x) < 2:
            continue
        m = x.mean(axis=0)
        s = x.std(axis=0, ddof=1)
        white = s / math.sqrt(len(x))
        if len(x) >= 5 * batches:
            bm = np.array([b.mean(axis=0) for b in np.array_split(x, batches)])
            white = np.maximum(white, bm.std(axis=0, ddof=1) / math.sqrt(batches))
        w.append(m), sd.append(s), n.append(len(x)), se.append(white)
        t.append((iv.start + iv.end - 1) / 2 / rec.rate_hz), tau.append(len(x) / rec.rate_hz)
        lab.append(iv.label), s0.append(iv.start), e0.append(iv.end)
    if not w:
        raise StaticIntervalError(f"{rec.source}: no static interval with at least 2 samples")
    se = np.array(se)
    se = np.maximum(se, 1e-12 * np.maximum(np.abs(np.array(w)), 1.0))   # an exactly constant input
    return PoseAverages(lab, np.array(s0), np.array(e0), np.array(w), np.array(sd), np.array(n), se,
                        np.array(t), np.array(tau))


def bench_campaign(avg: PoseAverages, rec: RawRecording, serial: str, local_g_m_s2: float,
                   temperature_C: float = 20.0) -> Campaign:
    """The known-pose averages as bench CSV v1 visits (positions of DEFAULT_PLAN with the same
    axis up). There is no temperature channel: ``t_*`` hold ``temperature_C`` and the
    metadata says so."""
    pos = [POSE_POSITIONS[lab] for lab in avg.label]
    a1 = np.array([DEFAULT_PLAN[p][0] for p in pos])
    a2 = np.array([DEFAULT_PLAN[p][1] for p in pos])
    k = len(pos)
    meta = {"generator": "triadcal fit-raw (position averages of a raw recording)",
            "source": rec.source, "rate_hz": repr(rec.rate_hz), "output_unit": rec.unit,
            "input_unit": rec.unit, "local_g_m_s2": repr(float(local_g_m_s2)),
            "bench": "none: hand-placed poses (imucal labels " + ",".join(avg.label) + ")",
            "temperature": f"not measured; t_x t_y t_z hold a constant {temperature_C:g} degC placeholder"}
    return Campaign(
        unit=np.full(k, serial), setpoint_C=np.full(k, temperature_C), direction=np.full(k, "none"),
        time_s=avg.time_s.astype(float), position=np.array(pos), axis1_deg=a1, axis2_deg=a2,
        tau_s=avg.tau_s.astype(float), w=avg.w.copy(), t=np.full((k, 3), float(temperature_C)),
        cycle=np.zeros(k, int), state=np.full(k, "initial"), sd=avg.sd.copy(), n_samples=avg.n.astype(int),
        metadata=meta, source=rec.source)
