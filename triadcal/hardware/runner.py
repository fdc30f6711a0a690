"""The frame pump of a capture: every frame the IMU reader delivers is checked, de-duplicated,
put on one continuous clock and appended to the raw store (docs/hardware.md, "What a frame
must be").

A frame is refused (event ``invalid_frame``, counted in the report's ``invalid_frames``, never
stored, never averaged) when a value is not a finite number (a checksum covers the bytes, not
the physics: an outside probe's IMU sent NaN, inf and 9999 degC with valid checksums, the
capture wrote them into campaign.csv and the whole campaign could no longer be fitted or
resumed), an output beyond the bench CSV's range, or a temperature outside the bench CSV's
range (``t_*`` in [-273.15, 300] degC; NaN allowed only for an IMU that has no temperature).

The clock. The raw file's and the campaign's times are the instrument's clock made continuous:
``time_s + shift``, where ``shift`` changes only at a clock fault, each logged with its size:

- ``instrument_restart``: the sequence number and the clock both go back (the IMU rebooted);
- ``clock_step``: the sequence number goes on but the clock jumps by more than
  ``max(CLOCK_STEP_MIN_S, CLOCK_STEP_FRACTION x expected)`` from ``k x dt`` (k frames on, dt the
  median sample interval), or goes back; a +1e5 s jump had the capture wait for the
  bench until its move timeout, blaming the bench;
- ``sequence_reset``: the sequence number falls to less than half its last value while the
  clock goes on (a counter that wrapped at 2^32 or 2^16, or a firmware that restarted its
  counter): before, every later frame was counted as a duplicate and the capture waited for
  ever. A smaller step back is a duplicate (dropped, counted), as is a frame whose clock does
  not advance, except a *late frame*: a sequence number not yet admitted, at most
  :data:`LATE_WINDOW` behind, whose clock sits where that number belongs (``k x dt`` back within
  half a dt): two frames swapped on the way. It is not put into the record (the raw file is
  append-only, in time order; it stays counted in ``missing_frames``) but written with its values
  to the event log (event ``late_frame``) and counted in ``late_frames``: an outside probe's
  swapped frames lost the late one as a "duplicate".

Each of them increments ``clock_faults``: a visit whose settling or recording window holds one
is redone (a window across an IMU restart averaged two periods of the unit into one visit, 399
samples for 200, with exit 0).

A stall is not a clock step: an IMU that went quiet and resumed with its sequence number where it
stopped and its clock on by the time that passed (the emulator's ``stalls``) jumps forward as a
clock step does, but the host saw the silence. When the wall-clock silence before the frame
(:attr:`Frame.wall_s`), times the instrument seconds per wall second of the frames before it (1
for a real instrument, the emulator's time scale otherwise; over at least
:data:`RATE_SPAN_WALL_S`), covers at least :data:`STALL_COVER` of the jump, the jump is time that
passed: it is kept (event ``stall_gap``, no clock fault; a window across it lacks samples and is
redone by its coverage rule). An outside probe's 300 s stall was shifted away as a clock step,
the later rows' ``time_s`` 300 s early in campaign.csv and the raw file, exit 0.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from typing import Optional

import numpy as np

from ..errors import TriadcalError
from ..io.bench_csv import MAX_READING, RANGES
from .protocols import Frame

def _values(f: Frame) -> tuple:
    """A frame's readings, comparable (repr: a NaN equals itself)."""
    return (repr(tuple(f.w)), repr(tuple(f.t)))


#: a clock step is a jump this many seconds (at least) away from the expected k x dt
CLOCK_STEP_MIN_S = 1.0
#: ... and this fraction of the expected gap (a gap of missing frames grows with k)
CLOCK_STEP_FRACTION = 0.5
#: a restart: the clock goes back by more than this (s) while the sequence number does too
RESTART_BACK_S = 1.0
#: admitted frames remembered to tell a stale replay from a restart (2^18: 4.4 min at 1 kHz)
SEEN_FRAMES = 1 << 18
#: the clock's step is checked against the windows after this many frame intervals (check_clock_step)
CLOCK_CHECK_FRAMES = 16
#: ... and must leave the shortest window at least this many readings
MIN_WINDOW_READINGS = 4
#: a frame this many sequence numbers behind the latest, never admitted, is a late frame (docstring)
LATE_WINDOW = 64
T_LOW, T_HIGH = RANGES["t_x"][0], RANGES["t_x"][1]
#: a forward clock jump is a stall when the wall-clock silence before it, in instrument seconds,
#: covers at least this fraction of it (module docstring)
STALL_COVER = 0.5
#: the instrument seconds per wall second are measured over frames spanning at least this (wall s)
RATE_SPAN_WALL_S = 1.0
#: ... and, to tell a stall from a clock step, over at least this: a factor 2 suffices there
#: (STALL_COVER), and an outside probe's stall 0.4 wall s into a capture at x300 fell before the
#: first full second: shifted away as a clock step, every later time 120 s early, exit 0
STALL_RATE_SPAN_WALL_S = 0.2


class CaptureError(TriadcalError, RuntimeError):
    """The campaign cannot go on (instrument silent, not stable in time, mismatched resume)."""


def frame_problem(f: Frame, temperature_required: bool = True) -> Optional[str]:
    """Why ``f`` cannot be a sample of the campaign, or None. See the module docstring."""
    if not (isinstance(f.time_s, (int, float)) and math.isfinite(f.time_s)):
        return f"time_s {f.time_s!r} is not a finite number"
    for a, v in zip("xyz", f.w):
        if not math.isfinite(v) or abs(v) > MAX_READING:
            return f"w_{a} {v!r} is not a finite number within +-{MAX_READING:g}"
    temps = list(f.t)
    if not temperature_required and all(math.isnan(v) for v in temps):
        return None
    for a, v in zip("xyz", temps):
        if not (math.isfinite(v) and T_LOW <= v <= T_HIGH):
            return f"t_{a} {v!r} degC is not a finite number within [{T_LOW:g}, {T_HIGH:g}] degC"
    return None


class _Runner:
    """Pumps frames from the reader into the raw store and the campaign's logic (module docstring)."""

    def __init__(self, stream, raw, events, session: int, settings, temperature_required: bool = True):
        self.stream, self.raw, self.events, self.session = stream, raw, events, session
        self.settings = settings
        self.temperature_required = temperature_required
        self.phase = "idle"
        self.visit_tag = ""
        self.window: Optional[tuple] = None       # (t0, t1, list) on the continuous clock
        self.last_seq: Optional[int] = None
        self.last_time: Optional[float] = None    # instrument clock of the latest frame
        self.shift = 0.0                          # continuous clock = instrument clock + shift
        self.now: Optional[float] = None          # continuous time of the latest frame
        self.accepted = self.duplicates = self.missing = self.invalid = 0
        self.clock_faults = 0
        self.temps: deque = deque()
        self.warnings: list = []                 # for the report (capture.setpoint_missed)
        self.visit_problem = "visit_incomplete"   # why the last window was refused (capture._visit)
        self.visit_detail = ""                    # ... with its numbers, for the error after the last attempt
        self._last_frame_wall = time.monotonic()
        self.dt_estimates: deque = deque(maxlen=256)
        self.last_wall = math.nan                 # Frame.wall_s of the latest admitted frame
        self._flow: deque = deque(maxlen=512)     # (wall_s, continuous time) of admitted frames
        self.stall_gaps = 0
        self.link_written = 0                     # the IMU link's events already in the event log
        self.stale = 0                            # exact replays of admitted frames, dropped
        self.late = 0                             # frames that came after later ones (event late_frame)
        self._clock_checked = False               # the clock's step against the windows (check_clock_step)
        self._recent_seqs: deque = deque(maxlen=LATE_WINDOW)   # sequence numbers of the latest admitted
        self._seen: dict = {}                     # hashes of (seq, time_s, w, t) of the latest admitted frames
        self._seen_order: deque = deque()
        self.conflicts = 0                        # a second copy of an admitted frame with other values
        self._recent_vals: dict = {}              # seq -> (time_s, w, t) of the latest admitted (conflicts)
        self._pending: Optional[Frame] = None     # a frame back in sequence and clock: a restart or a re-send

    def _silence(self) -> str:
        imu = getattr(self.stream, "readout", None)
        stats = getattr(imu, "parser_stats", None)
        got = (stats.garbage_bytes, stats.corrupted) if stats is not None else (0, 0)
        if got[0] or got[1]:
            return (f"no frame decoded from the IMU for {self.settings.silence_timeout_wall_s:g} s (wall clock), "
                    f"though bytes arrive ({got[0]} bytes outside any frame, {got[1]} corrupted frames so far): "
                    f"check --imu-protocol ({getattr(imu, 'protocol', '?')}) and the baud rate; run the same "
                    "command again to resume")
        return (f"no frame from the IMU for {self.settings.silence_timeout_wall_s:g} s (wall clock); check the "
                "cable and run the same command again to resume")

    def _dt(self) -> Optional[float]:
        return float(np.median(self.dt_estimates)) if self.dt_estimates else None

    def _clock_fault(self, kind: str, f: Frame, advance_s: float, **info) -> None:
        """Continue the continuous clock ``advance_s`` after the last frame at ``f``."""
        new_shift = self.last_time + self.shift + advance_s - f.time_s
        self.events.write(kind, seq=f.seq, time_s=f.time_s, last_seq=self.last_seq, last_time_s=self.last_time,
                          shift_s=new_shift - self.shift, **info)
        self.shift = new_shift
        self.clock_faults += 1

    def _admit(self, f: Frame) -> bool:
        """Sequence and clock rules of the module docstring; False for a duplicate."""
        if self.last_seq is None:
            return True
        dt = self._dt()
        if f.seq <= self.last_seq:
            if f.time_s < self.last_time - RESTART_BACK_S:
                self._clock_fault("instrument_restart", f, dt or 0.0)
            elif f.time_s > self.last_time and f.seq <= self.last_seq // 2:
                gap = f.time_s - self.last_time
                k = max(1, round(gap / dt)) if dt else 1
                self.missing += k - 1
                self._clock_fault("sequence_reset", f, gap)
            elif self._late(f, dt):
                self.late += 1
                self.events.write("late_frame", seq=f.seq, time_s=f.time_s, last_seq=self.last_seq,
                                  last_time_s=self.last_time, phase=self.phase, visit=self.visit_tag,
                                  w=[float(v) for v in f.w],
                                  t=[float(v) if math.isfinite(v) else None for v in f.t])
                return False
            else:
                prev = self._recent_vals.get(f.seq)
                if prev is not None and prev[0] == repr(f.time_s) and prev[1:3] != _values(f):
                    # the same sequence number and clock with other values: no copy can be trusted over the
                    # other (an outside probe's altered first copy of every 50th frame was kept, the genuine one
                    # dropped as a duplicate, each visit's mean biased by about 1 u, exit 0); the visit is redone
                    self.conflicts += 1
                    self.events.write("conflicting_frame", seq=f.seq, time_s=f.time_s, phase=self.phase,
                                      visit=self.visit_tag, kept_w=list(prev[3]), other_w=[float(v) for v in f.w],
                                      other_t=[float(v) if math.isfinite(v) else None for v in f.t])
                self.duplicates += 1
                return False
            return True
        k = f.seq - self.last_seq
        gap = f.time_s - self.last_time
        self.missing += k - 1
        expected = k * (dt or 0.0)
        if gap < 0.0 or (dt and abs(gap - expected) > max(CLOCK_STEP_MIN_S, CLOCK_STEP_FRACTION * expected)):
            stall = self._stall(f, gap - expected)
            if stall is not None:
                self.stall_gaps += 1
                self.events.write("stall_gap", seq=f.seq, time_s=f.time_s, last_seq=self.last_seq,
                                  last_time_s=self.last_time, jump_s=gap - expected, **stall)
            else:
                self._clock_fault("clock_step", f, expected, jump_s=gap - expected)
        elif k == 1:
            self.dt_estimates.append(gap)
        return True

    def check_clock_step(self) -> None:
        """Refuse a clock whose step between frames leaves the shortest window (the recording's
        ``tau_s``, the stabilisation's ``window_s``) fewer than :data:`MIN_WINDOW_READINGS` readings:
        no visit could be made and the soak could see no rate. An IMU whose time_s counted
        milliseconds ran the capture into the soak's timeout, "not stable after 3000 s ... last rate
        unknown" (a 10 Hz clock read as 0.01 Hz)."""
        dt = self._dt()
        stab = getattr(self.settings, "stabilisation", None)
        windows = [w for w in (getattr(self.settings, "tau_s", None), getattr(stab, "window_s", None)) if w]
        if not dt or not windows or dt * MIN_WINDOW_READINGS <= min(windows):
            return
        raise CaptureError(
            f"the IMU's clock advances {dt:g} s per frame by its time_s ({1.0 / dt:.3g} Hz): a window of "
            f"{min(windows):g} s (the recording's tau_s {getattr(self.settings, 'tau_s', 0):g} s, the stabilisation's "
            f"{getattr(stab, 'window_s', 0):g} s) would hold fewer than {MIN_WINDOW_READINGS} readings. The frames' "
            f"time_s must be seconds: a clock counting milliseconds runs 1000 times fast (it would be "
            f"{dt / 1000:g} s per frame, {1000.0 / dt:.3g} Hz); for a truly slow IMU lengthen --tau-s and "
            "--stab-window-s")

    def _late(self, f: Frame, dt: Optional[float]) -> bool:
        """Whether ``f`` (its sequence number not above the latest) is a late frame: never admitted,
        at most :data:`LATE_WINDOW` behind, its clock ``k x dt`` back within half a dt."""
        back = self.last_seq - f.seq
        if not dt or not 0 < back <= LATE_WINDOW or f.seq in self._recent_seqs:
            return False
        return abs((self.last_time - f.time_s) - back * dt) <= 0.5 * dt

    def _instrument_per_wall(self, min_span_s: float = RATE_SPAN_WALL_S) -> Optional[float]:
        """Instrument seconds per wall second over the admitted frames of the last ``min_span_s``
        (:data:`RATE_SPAN_WALL_S`) or more (None: too short a span, or no wall stamps)."""
        if len(self._flow) < 2:
            return None
        (w0, c0), (w1, c1) = self._flow[0], self._flow[-1]
        if not (w1 - w0 >= min_span_s) or c1 <= c0:
            return None
        return (c1 - c0) / (w1 - w0)

    def present_s(self) -> Optional[float]:
        """The continuous instrument time now, estimated: the latest admitted frame's plus the wall time
        since the reader stamped it times the instruments' measured rate (:meth:`_instrument_per_wall`;
        1 for hardware, the time scale for the emulator). The latest frame lags the present by the host's
        own work since it and the frames still queued. Without a measured rate: the latest frame's."""
        rate = self._instrument_per_wall()
        if self.now is None or rate is None or not math.isfinite(self.last_wall):
            return self.now
        return self.now + max(0.0, time.monotonic() - self.last_wall) * rate

    def _stall(self, f: Frame, jump_s: float) -> Optional[dict]:
        """The evidence that the forward jump ``jump_s`` of ``f``'s clock is a stall (time that passed
        while the host heard nothing), or None (module docstring)."""
        rate = self._instrument_per_wall(STALL_RATE_SPAN_WALL_S)
        silence = f.wall_s - self.last_wall
        if jump_s <= 0 or rate is None or not math.isfinite(silence) or silence * rate < STALL_COVER * jump_s:
            return None
        return {"silence_wall_s": silence, "instrument_s_per_wall_s": rate}

    def write_link_events(self) -> None:
        """The IMU link's events (lost, reopened, stalled: the driver's ``link_stats``) into the event log
        as they happen (each write synced), not at the session's end: an outside probe's capture killed
        after a reconnect kept no trace of it."""
        ls = getattr(getattr(self.stream, "readout", None), "link_stats", None)
        if ls is None:
            return
        while self.link_written < len(ls.events):
            t, text = ls.events[self.link_written]
            self.events.write("link", text=text, at_wall=t)
            self.link_written += 1

    def _replayed(self, f: Frame) -> bool:
        """Whether ``f`` repeats an admitted frame exactly (sequence number, clock and every value): a
        stale frame sent again, not a new reading. An outside probe's IMU re-sent one frame of 150 s
        before: it was taken as an instrument restart, every later time shifted by 150 s, the stale
        sample stored in the visit, 1499 frames counted missing. A restart's frames are new readings."""
        # a hash (one int, not four strings, per remembered frame); repr: a NaN equals itself
        key = hash((f.seq, repr(f.time_s), repr(tuple(f.w)), repr(tuple(f.t))))
        if key in self._seen:
            return True
        self._seen[key] = None
        self._seen_order.append(key)
        if len(self._seen_order) > SEEN_FRAMES:
            self._seen.pop(self._seen_order.popleft(), None)
        return False

    def _stale(self, f: Frame, why: str) -> None:
        """A frame from before that is not a new reading: counted, its values in the event log."""
        self.stale += 1
        self.duplicates += 1
        self.events.write("stale_frame", seq=f.seq, time_s=f.time_s, last_seq=self.last_seq, phase=self.phase,
                          visit=self.visit_tag, reason=why, w=[float(v) for v in f.w],
                          t=[float(v) if math.isfinite(v) else None for v in f.t])

    def flush_held(self) -> None:
        """At a session's end: a frame still held as a possible restart (:meth:`pump`) is told by no next
        frame; it is not put into the record, but written with its values to the event log
        (``held_frame``), so nothing read is lost."""
        f, self._pending = self._pending, None
        if f is not None:
            self.events.write("held_frame", seq=f.seq, time_s=f.time_s, last_seq=self.last_seq, phase=self.phase,
                              visit=self.visit_tag, w=[float(v) for v in f.w],
                              t=[float(v) if math.isfinite(v) else None for v in f.t],
                              reason="back in number and clock at the session's end: a restart or a frame sent "
                                     "again, no next frame to tell")

    def _take(self, f: Frame, accepted: list) -> None:
        """Admit ``f`` by the sequence and clock rules (:meth:`_admit`) and append it to ``accepted``."""
        if not self._admit(f):
            return
        self._replayed(f)
        self.last_seq, self.last_time = f.seq, f.time_s
        if len(self._recent_seqs) == self._recent_seqs.maxlen:
            self._recent_vals.pop(self._recent_seqs[0], None)
        self._recent_seqs.append(f.seq)
        self._recent_vals[f.seq] = (repr(f.time_s),) + _values(f) + (tuple(float(v) for v in f.w),)
        if math.isfinite(f.wall_s):
            self.last_wall = f.wall_s
            if not self._flow or f.wall_s - self._flow[-1][0] >= 0.05:   # thinned: 512 span >= 25 s
                self._flow.append((f.wall_s, f.time_s + self.shift))
        accepted.append(dataclasses.replace(f, time_s=f.time_s + self.shift) if self.shift else f)

    def pump(self, timeout: float = 0.02) -> int:
        self.write_link_events()
        batch = self.stream.get(timeout)
        if not batch:
            if time.monotonic() - self._last_frame_wall > self.settings.silence_timeout_wall_s:
                raise CaptureError(self._silence())
            return 0
        self._last_frame_wall = time.monotonic()
        accepted: list[Frame] = []
        for f in batch:
            why = frame_problem(f, self.temperature_required)
            if why is not None:
                self.invalid += 1
                self.events.write("invalid_frame", seq=f.seq, reason=why, phase=self.phase, visit=self.visit_tag)
                continue
            if self._pending is not None:
                cand, self._pending = self._pending, None
                if f.seq > self.last_seq and f.time_s > self.last_time - RESTART_BACK_S:
                    # the stream went on where it was: the frame back was sent again, not a restart (an
                    # outside probe's frame re-sent 3 s late, its first copy refused by its checksum: nine
                    # "restarts", the clock 28 s off by the end, 279 frames counted missing for 9)
                    self._stale(cand, "the next frame continues the stream: a frame sent again, not a restart")
                else:
                    self._take(cand, accepted)
            if self.last_seq is not None and f.seq < self.last_seq and f.time_s < self.last_time - RESTART_BACK_S:
                if self._replayed(f):                       # would pass for a restart: a stale frame sent again
                    self._stale(f, "an admitted frame sent again")
                else:                                       # a restart, or a frame sent again: the next tells
                    self._pending = f
                continue
            self._take(f, accepted)
        if not self._clock_checked and len(self.dt_estimates) >= CLOCK_CHECK_FRAMES:
            self._clock_checked = True
            self.check_clock_step()
        if not accepted:
            return 0
        self.accepted += len(accepted)
        self.now = accepted[-1].time_s
        self.observe(accepted)
        # split by phase: frames inside an open recording window are 'record'
        if self.window is not None:
            t0, t1, got = self.window
            rec = [f for f in accepted if t0 <= f.time_s < t1]
            before = [f for f in accepted if f.time_s < t0]
            after = [f for f in accepted if f.time_s >= t1]
            if before:
                self.raw.append(before, self.session, self.phase, self.visit_tag)
            if rec:
                self.raw.append(rec, self.session, "record", self.visit_tag)
                got.extend(rec)
            if after:
                self.raw.append(after, self.session, "idle", self.visit_tag)
        else:
            self.raw.append(accepted, self.session, self.phase, self.visit_tag)
        if self.phase == "soak":
            for f in accepted:
                self.temps.append((f.time_s, f.t))
        return len(accepted)

    def observe(self, frames: list) -> None:
        """Called with every batch of accepted frames (continuous clock); for subclasses."""

    def wait_first_frame(self) -> None:
        while self.now is None:
            self.pump(0.05)

    @property
    def rate_hz(self) -> Optional[float]:
        dt = self._dt()
        return None if dt is None else 1.0 / dt


def _max_temperature_rate(temps: deque, window_s: float, now: float) -> Optional[float]:
    """Largest |slope| (degC/s) of the three temperatures over the last window, or None
    while the window is not yet covered."""
    while temps and temps[0][0] < now - window_s:
        temps.popleft()
    if len(temps) < 3 or temps[-1][0] - temps[0][0] < 0.9 * window_s:
        return None
    t = np.array([x[0] for x in temps])
    T = np.array([x[1] for x in temps])
    tc = t - t.mean()
    slope = (tc @ (T - T.mean(axis=0))) / (tc @ tc)
    return float(np.max(np.abs(slope)))
