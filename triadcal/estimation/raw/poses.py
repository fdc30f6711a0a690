"""Static intervals of a recording as pose averages (mean, its uncertainty from batch means) and
as a bench CSV campaign on the default plan's positions (docs/raw.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

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


def pose_averages(rec: RawRecording, detection: StaticDetection, batches: int = 10) -> PoseAverages:
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
