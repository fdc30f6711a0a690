"""The checks of one visit's recording window (docs/hardware.md, "What a frame must be", "What a
visit must be"): a spike in the window (:func:`window_outlier`), a unit that left the state its
setpoint was declared stable in (:func:`thermal_departure`), a bench off its commanded position
after the window (:func:`bench_position_problem`) or that did not move at all
(:func:`bench_did_not_move`), and a bench's repeated errors logged once with a count
(:class:`RepeatedEvents`). Used by :func:`.capture._visit`; split from capture.py, which holds
the campaign's loop."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Optional

import numpy as np

from .drivers.bench import DEFAULT_TOLERANCE_DEG, Bench, BenchError, within_tolerance
from .drivers.bench_template import BenchControllerError
from .storage import EventLog

if TYPE_CHECKING:
    from .capture import Stabilisation


#: what each refusal of a window says (the events of :func:`_visit`)
VISIT_PROBLEMS = {"visit_incomplete": "had too few samples",
                  "visit_clock_fault": "held a restart or a step of the IMU's clock",
                  "visit_conflicting_frames": "held a frame the IMU sent twice with different values",
                  "visit_overfull": "held more samples than its length and the rate allow",
                  "visit_outlier": "held a sample far from the window's others (a spike)",
                  "visit_not_stable": "was not at the setpoint's stable temperature",
                  "visit_bench_moved": "ended with the bench off the commanded position",
                  "visit_bench_unread": "ended with the bench's position unreadable"}
#: a window holding more than this times the samples its length and the rate allow is not one
#: period of one stream (two streams interleaved, a clock running slow): the visit is redone
OVERFULL = 1.25


#: a sample of a soaked window's temperatures this far (degC) from the window's median, and beyond 10
#: noise SDs, is not the unit's temperature (a unit's thermal mass moves it by far less within a window)
TEMPERATURE_SPIKE_C = 1.0
#: ... and an output's sample this fraction of the triad's |w| from its median, when the output is
#: otherwise constant to the bit
QUIET_SPIKE_G = 0.01


def window_outlier(frames) -> Optional[str]:
    """Why a soaked window holds a sample that is not the unit's, or None: an output farther than 10
    noise SDs from the window's median (:func:`~triadcal.hardware.ramp_labels.not_stationary`'s rule,
    the noise from successive differences), or a temperature farther than 10 noise SDs and
    :data:`TEMPERATURE_SPIKE_C` from its median. An outside probe's IMU sent one frame of w_x = 1000 V
    (true 1.18) and one of t = 293.15 (kelvin, true 20) with valid checksums: the visit's w_x came out
    6.17 V and its t_x 21.37 degC, exit 0."""
    from .ramp_labels import not_stationary, strays

    if len(frames) < MIN_WINDOW_SAMPLES:
        return None
    why = not_stationary(frames, [])
    if why is not None:
        return why
    if len(frames) >= 4:
        # an output constant to the bit (no noise to measure against: a quiet quantised channel, an
        # emulated one): a sample off its median by more than QUIET_SPIKE_G of the triad's |w| (about
        # one g in the output's unit) is not the unit's; a quiet channel's flicker of one LSB is far below
        # it. The outside probe's noiseless IMU with one frame of w_x = 1000 V went through the noise
        # rule above, which has nothing to compare with
        w = np.array([f.w for f in frames], float)
        dev, noise = strays(w)
        scale = float(np.linalg.norm(np.median(w, axis=0)))
        for i, a in enumerate("xyz"):
            if noise[i] == 0 and dev[i] > QUIET_SPIKE_G * scale:
                return f"w_{a} strays {dev[i]:.3g} from the window's median, where its other samples do not move"
    t = np.array([f.t for f in frames], float)
    if len(t) < 4 or not np.all(np.isfinite(t)):
        return None
    # about the window's straight line in time, not its median: a ramp's window (capture --ramp, 1 degC/min
    # over 120 s) spans 2 degC, and its ends stood 1 degC from the median, "a spike" 3 times in a row (the
    # docs' ramp example failed now and then); a spike stays off the line as it stood off the median
    times = np.array([f.time_s for f in frames], float)
    if np.ptp(times) > 0:
        A = np.column_stack([np.ones_like(times), times - times.mean()])
        t = t - A @ np.linalg.lstsq(A, t, rcond=None)[0]
    dev, noise = strays(t)
    for i, a in enumerate("xyz"):
        if dev[i] > max(10.0 * noise[i], TEMPERATURE_SPIKE_C):
            return f"t_{a} strays {dev[i]:.3g} degC from the window's straight line in time"
    return None


#: -- the checks of a visit's window against the state the setpoint's soak declared stable --
#: (docs/hardware.md, "What a visit must be"). A window whose unit temperatures move faster than
#: VISIT_RATE_FACTOR times the stabilisation's rate criterion is not the stable state: the soak
#: ended with the rate below the criterion over ``window_s``, and a settled unit's rate only falls
#: after that; ten times the criterion (0.1 degC/min by default) is "well beyond" it yet far below
#: what a chamber that stopped does to a unit (an outside probe: 5 to 9 degC/min) ...
VISIT_RATE_FACTOR = 10.0
#: ... but the slope of a short window is noisy: never refused for a slope within VISIT_RATE_SE
#: standard errors of the window's own least-squares fit (the sensor's noise, measured), nor for one
#: that moves the temperature by less than VISIT_RATE_MIN_CHANGE_C over the window (a quantised
#: sensor of 0.0625 degC stepping once)
VISIT_RATE_SE = 5.0
VISIT_RATE_MIN_CHANGE_C = 0.1
#: a window whose mean unit temperature is farther than this (degC, any sensor) from the temperature
#: at which the soak declared the unit stable is not of that setpoint's state. A unit still settling at
#: the criterion's rate r with a time constant tau has about r tau left to drift: 0.6 degC at 0.01
#: degC/min and 60 min, 1 degC at 0.05 degC/min and 20 min (an outside probe's healthy campaign of 24
#: positions stopped at 0.5 degC, moving 0.016-0.020 degC/min); a chamber that stopped moves the
#: unit by degC per minute, which the rate rule above sees first
VISIT_DRIFT_C = 2.0
#: the rate rule and the spike rule need this many samples in the window: with 4 or 5 the slope's and
#: the successive differences' noise are too uncertain (an outside probe's clean 1 Hz windows of 4
#: samples were "20 noise SDs" and "-4.88 degC/min" off); the drift rule holds for any window
MIN_WINDOW_SAMPLES = 10

#: -- a bench that reports each target but did not move: two consecutive visits whose nominal gravity
#: directions in the IMU frame (models.campaign.nominal_gravity, the bench kinematics) are at least
#: STUCK_TURN_DEG apart must differ in their mean output: the unit vector of gravity changes by
#: 2 sin(5 deg) = 17 % or more, so the output by about 17 % of |w| (less by the share of a bias).
STUCK_TURN_DEG = 10.0
#: The outputs count as unchanged when |dw| is below STUCK_FRACTION of |w| (17 times below the
#: least change of a bias-free unit) *and* within the noise: STUCK_NOISE_SE standard errors of the
#: difference of the two means (at least STUCK_FLOOR of |w|, for a quantised or noiseless output).
#: A unit with a large bias (a 2.5 V offset, 0.1 V/g) moves less than 1 % of |w| but far more than its
#: noise, and is not refused.
STUCK_FRACTION = 0.01
STUCK_NOISE_SE = 4.0
STUCK_FLOOR = 1e-4
#: a position read after the window off the commanded one is read this many times more (the median decides)
POSITION_REREADS = 2
#: identical consecutive bench errors while polling a move: written once, then as one record with a
#: repeat count when they change or stop, and at least this often (wall seconds) while they go on
REPEAT_RECORD_WALL_S = 10.0


def thermal_departure(frames, stable_t, crit: Stabilisation) -> Optional[tuple]:
    """``(text, fields)`` when a window's unit temperatures are not the state ``stable_t`` the soak
    declared stable (a rate or a drift beyond the limits above), else None."""
    if stable_t is None or len(frames) < 2:
        return None
    stable_t = np.asarray(stable_t, float)
    t = np.array([f.time_s for f in frames], float)
    T = np.array([f.t for f in frames], float)
    if not (np.all(np.isfinite(T)) and np.all(np.isfinite(stable_t))):
        return None
    tc = t - t.mean()
    sxx = float(tc @ tc)
    span = float(t[-1] - t[0])
    if sxx <= 0.0 or span <= 0.0:
        return None
    slope = (tc @ (T - T.mean(axis=0))) / sxx                          # degC/s per sensor
    resid = T - T.mean(axis=0) - np.outer(tc, slope)
    se = np.sqrt(np.sum(resid ** 2, axis=0) / max(len(t) - 2, 1) / sxx)
    limit = np.maximum.reduce([np.full(3, VISIT_RATE_FACTOR * crit.rate_C_per_min / 60.0), VISIT_RATE_SE * se,
                               np.full(3, VISIT_RATE_MIN_CHANGE_C / span)])
    if len(frames) < MIN_WINDOW_SAMPLES:
        limit = np.full(3, np.inf)                # too few samples for a slope: the drift rule only
    drift = T.mean(axis=0) - stable_t
    badness = np.maximum(np.abs(slope) / limit, np.abs(drift) / VISIT_DRIFT_C)
    i = int(np.argmax(badness))
    if badness[i] <= 1.0:
        return None
    a = "xyz"[i]
    fields = {"sensor": f"t_{a}", "t_C": float(T[:, i].mean()), "stable_t_C": float(stable_t[i]),
              "drift_C": float(drift[i]), "drift_limit_C": VISIT_DRIFT_C, "rate_C_per_min": float(slope[i] * 60.0),
              "rate_limit_C_per_min": float(limit[i] * 60.0)}
    text = (f"t_{a} {T[:, i].mean():.2f} degC, {drift[i]:+.2f} degC from {stable_t[i]:.2f} at 'stable' "
            f"(limit {VISIT_DRIFT_C:g}), moving {slope[i] * 60.0:+.3g} degC/min in the window (limit "
            f"{limit[i] * 60.0:.3g}): the unit left the setpoint's stable state (has the chamber stopped?)")
    return text, fields


def bench_did_not_move(prev: dict, row: dict, a1: float, a2: float) -> Optional[str]:
    """Why the visit ``row`` at ``(a1, a2)`` cannot have been made where the bench said, after the
    visit ``prev``: the nominal gravity turned by :data:`STUCK_TURN_DEG` or more in the IMU frame and
    the mean output did not change (the thresholds above); None when it did, or need not."""
    from ..models.campaign import nominal_gravity

    g = nominal_gravity([prev["axis1_deg"], a1], [prev["axis2_deg"], a2])
    turn = float(np.degrees(np.arccos(np.clip(g[0] @ g[1], -1.0, 1.0))))
    if turn < STUCK_TURN_DEG:
        return None
    w0, w1 = np.asarray(prev["w"], float), np.asarray(row["w"], float)
    dw = float(np.linalg.norm(w1 - w0))
    scale = max(float(np.linalg.norm(w0)), float(np.linalg.norm(w1)))
    var = 0.0
    for r in (prev, row):
        sd = r.get("sd")
        if sd is not None and r.get("n_samples"):
            var += float(np.sum(np.square(np.asarray(sd, float)))) / float(r["n_samples"])
    se = float(np.sqrt(var)) if np.isfinite(var) else 0.0
    limit = min(STUCK_FRACTION * scale, max(STUCK_NOISE_SE * se, STUCK_FLOOR * scale))
    if dw >= limit:
        return None
    return (f"the bench did not move: the plan turns gravity by {turn:.1f} deg in the IMU frame, which "
            f"changes the output by about {200.0 * np.sin(np.radians(turn / 2)):.0f} % of |w|, but w changed by "
            f"{dw:.3g} ({100.0 * dw / scale:.3g} % of |w| = {scale:.4g}; limit {limit:.3g}: {STUCK_FRACTION:.0%} of "
            f"|w| and {STUCK_NOISE_SE:g} standard errors of the means). The bench reports a position it "
            "did not reach (a stuck axis, a slipping coupling), or the IMU's samples reach the host late (a "
            "stream that lags the bench by more than --settle-s shows the pose before the move: an outside "
            "probe's link delayed by 80 instrument s); the rows before this one are kept, check the last of them")


class RepeatedEvents:
    """Consecutive identical events of one kind: the first written at once, the repeats as one record
    ``repeats=n`` (n more since the last record) when the text changes, on :meth:`flush`, and every
    :data:`REPEAT_RECORD_WALL_S` while they go on; ``count`` and ``last`` for the error message. A
    bench answering an error to every poll wrote 5 956 identical lines (1.15 MB) in 60 s."""

    def __init__(self, events: EventLog, kind: str):
        self.events, self.kind = events, kind
        self.last: Optional[str] = None
        self.count = 0
        self.pending = 0
        self._written = 0.0

    def add(self, text: str) -> None:
        self.count += 1
        if text == self.last:
            self.pending += 1
            if time.monotonic() - self._written >= REPEAT_RECORD_WALL_S:
                self.flush()
            return
        self.flush()
        self.last = text
        self.events.write(self.kind, text=text)
        self._written = time.monotonic()

    def flush(self) -> None:
        if self.pending:
            self.events.write(self.kind, text=self.last, repeats=self.pending)
            self.pending = 0
        self._written = time.monotonic()


def bench_position_problem(bench: Bench, a1: float, a2: float) -> Optional[tuple]:
    """``(kind, text, fields)`` when the bench, asked after the recording window, is not within its
    in-position tolerance of the commanded position (or cannot say where it is), else None."""
    try:
        pos = bench.position()
    except BenchControllerError:
        raise
    except BenchError as exc:
        return "visit_bench_unread", f"POS? after the window: {exc}", {}
    profile = getattr(bench, "profile", None)
    tol = getattr(profile, "tolerance_deg", None) or getattr(bench, "tolerance_deg", None) or DEFAULT_TOLERANCE_DEG
    wraps = [ax.wrap for ax in profile.axes] if profile is not None else ("360", "360")
    target = getattr(bench, "target", None) or (a1, a2)
    if within_tolerance(pos, target, tol, wraps):
        return None
    # a reading that scatters (an outside probe's honest POS? with 0.005 deg of noise against a 0.01 deg
    # tolerance: "moved" 1 visit in 24): asked twice more, the median of the three decides
    reads = [pos]
    for _ in range(POSITION_REREADS):
        try:
            reads.append(bench.position())
        except BenchControllerError:
            raise
        except BenchError:
            break
    pos = tuple(float(np.median([r[i] for r in reads])) for i in range(2))
    if within_tolerance(pos, target, tol, wraps):
        return None
    off = [float((p - t + 180.0) % 360.0 - 180.0) if w != "none" else float(p - t) for p, t, w in zip(pos, target, wraps)]
    text = (f"the bench reads ({pos[0]:.4f}, {pos[1]:.4f}) after the window, {max(map(abs, off)):.3g} deg off the "
            f"commanded ({target[0]:g}, {target[1]:g}) (in-position tolerance {tol:g} deg): it moved during the visit")
    return "visit_bench_moved", text, {"position_deg": list(map(float, pos)), "target_deg": list(map(float, target)),
                                       "offset_deg": off, "tolerance_deg": float(tol)}
