"""Continuous-ramp capture (``triadcal capture --ramp PLAN``): the chamber follows a ramp program
while the bench cycles through the positions, recording back to back, with no soak.

The program is a ramp plan of ``triadcal plan --ramp`` (:class:`~triadcal.planning.ramp.RampPlan`):
piecewise linear through ``program_C`` at ``rate_C_per_min``, holding ``hold_s`` at every interior
turning point. It runs on the campaign's side, not the controller's: every ``step_s`` seconds of
the program the capture writes the program's present value as the chamber's setpoint (rounded to
0.1 degC; the program's first move as soon as it shows in that resolution), so any chamber driver
that takes a setpoint runs a ramp (a Watlow F4 or an Espec has its own ramp programs, but each in
its own dialect; a moving setpoint is what all of them take), and the chamber's air follows it with
its own time constant.

Sequence: the first program temperature is written and the unit is left to settle there (the
stepped capture's criterion on the unit's own temperatures, :class:`~triadcal.hardware.capture.
Stabilisation`; a ramp program starts from rest), then the program starts and visits follow back
to back (:func:`triadcal.hardware.capture._visit`: move, in position, ``settle_s``, window of
``tau_s``) in the plan's position order, cycling, until the program's end; a visit started before
the end is completed while the chamber holds the last value.

Each visit is a bench CSV row: the window's means (``w``, ``t``, ``sd``, ``n_samples``), its
middle as ``time_s`` (campaign time), the position, and the two labels a ramp campaign carries
(as the simulator's :class:`~triadcal.models.simulate.RampSchedule`): ``setpoint_C`` the target of
the program's leg at the window's middle, ``direction`` the sign of the unit's rate over the window
(``heating`` on a rise: the ramp as the unit sees it; :func:`visit_rate_se`, :func:`window_rates`,
:func:`visit_direction`).
A window whose outputs are not those of a unit at rest (:func:`not_stationary`: the bench still
moving) or in which the unit's temperature turned (:func:`turned_within`: both hysteresis branches
in one visit) is recorded again at the same position. Extra columns: ``raw_visit`` (the samples of
the row in the raw store) and ``program_C`` (the program's value at the window's middle); and bench
CSV's optional ``dTdt_C_per_min``, the unit's rate over the window measured from the window's raw
readings (:func:`visit_rate`), which the fit takes as each visit's rate (``Campaign.temperature_rate``)
for the element's lag (``thermal_lag``) instead of central differences of the visit means.

Storage and resume are the stepped capture's (:mod:`triadcal.hardware.capture`): an exclusive
folder lock, every accepted sample appended to ``raw/imu_samples.csv`` (flushed every batch,
fsync'd before a visit counts), ``campaign.csv`` rewritten atomically after every visit, the
events in ``raw/events.jsonl`` (fsync'd each), the identity in ``capture.json`` (format
``triadcal.ramp_capture``, so neither kind of capture resumes the other's folder). Every setpoint
written is an event ``ramp_setpoint`` with its program time; a new run resumes the program where
the last one wrote it (the chamber has held that setpoint meanwhile, as a controller does when its
host goes away) and the visits at the next position of the cycle, without a new soak.

The plan file is read by :func:`triadcal.planning.ramp.read_ramp_plan` (every field checked, the
reader ``simulate --plan`` uses too); the visit itself, the storage and the noise are capture.py's.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from .. import __version__
from ..errors import InputError
from ..io.atomic import atomic_write_json, atomic_write_text, read_json
from ..io.bench_csv import BenchCSVError, format_bench_csv, read_bench_csv
from ..io.formats import require_format
from ..planning.ramp import RampPlan, read_ramp_plan  # noqa: F401 - read_ramp_plan: the capture's API
from .visit_checks import bench_did_not_move
from .capture import (CSV_NAME, EVENTS_NAME, RAW_NAME, STATE_NAME, CaptureError, CaptureReport,
                      CaptureSettings, VISIT_PROBLEMS, _campaign, campaign_noise, _Runner, _visit, check_session_metadata,
                      dated_metadata, finish_session, soak, imu_metadata, storage_error)
from .drivers.bench import Bench, BenchError
from .drivers.chamber import Chamber
from .drivers.imu import ImuReadout, StreamThread
from .noise import NoiseEstimate
from .storage import TORN_MARK, EventLog, FolderLocked, RawStore, folder_lock, read_events
from .ramp_labels import (DIRECTION_SPAN_S, DTDT_METHOD, _History, not_stationary, turned_within,  # noqa: F401
                          visit_direction, visit_rate, visit_rate_se, window_rates)

RAMP_STATE_FORMAT = "triadcal.ramp_capture"
#: program seconds between two setpoints written (a real chamber: 10 s is 0.17 degC at 1 degC/min)
DEFAULT_STEP_S = 10.0
#: the setpoint register's resolution (every driver takes tenths of a degree)
SETPOINT_RESOLUTION_C = 0.1


# -- the program ------------------------------------------------------------------------------

@dataclass
class RampProgram:
    """The chamber program of a ramp plan as a function of program time (s): its value (linear
    between knots, held after the end), the target of the current leg and the duration."""

    knot_s: np.ndarray
    knot_C: np.ndarray

    @classmethod
    def of(cls, plan: RampPlan) -> "RampProgram":
        kt, kv = plan.schedule().knots()
        return cls(np.asarray(kt, float), np.asarray(kv, float))

    @property
    def duration_s(self) -> float:
        return float(self.knot_s[-1])

    @property
    def rate_C_per_min(self) -> float:
        """The program's fastest rate (degC/min) over its legs."""
        dt = np.diff(self.knot_s)
        ok = dt > 0
        return float(np.max(np.abs(np.diff(self.knot_C)[ok] / dt[ok])) * 60.0) if ok.any() else 0.0

    def value(self, p: float) -> float:
        return float(np.interp(p, self.knot_s, self.knot_C))

    def target(self, p: float) -> float:
        """The temperature the leg running at program time ``p`` goes to (as the simulator labels a
        visit's ``setpoint_C``); a hold's target is its own temperature; after the end, the last."""
        seg = int(np.clip(np.searchsorted(self.knot_s, p, side="right"), 1, len(self.knot_s) - 1))
        return float(self.knot_C[seg])


#: after a visit, the chamber's PV lies within the values of the program lagged by any time constant
#: up to this (s; twice the emulator's chamber) ...
PROGRAM_LAG_MAX_S = 1200.0
PROGRAM_LAGS_S = tuple(float(x) for x in np.geomspace(30.0, PROGRAM_LAG_MAX_S, 12))
#: ... give or take this (degC)
PROGRAM_MISS_C = 2.0


def program_band(program, p0: float, p1: float) -> tuple:
    """``(lo, hi)`` degC: the values a chamber's air may have at some program time in ``[p0, p1]`` s
    when it follows ``program`` (a :class:`RampProgram`) with a first-order lag of any time constant
    up to :data:`PROGRAM_LAG_MAX_S` (``y' = (u - y) / tau``, :func:`models.thermal_history.first_order_lag`),
    give or take :data:`PROGRAM_MISS_C`. Every lag, not the two ends: after a turn a chamber of a
    middling lag lies outside both the program and the longest lag."""
    from ..models.thermal_history import first_order_lag

    p0, p1 = float(p0), float(max(p0, p1))
    grid = np.linspace(0.0, max(p1, 1e-9), max(2, int(math.ceil(p1 / 10.0)) + 1))   # even: first_order_lag's filter
    prog = np.array([program.value(x) for x in grid])
    near = (grid >= p0 - 10.0) | (np.arange(grid.size) == grid.size - 1)
    at = [float(program.value(p0)), float(program.value(p1))] + list(prog[near])
    for tau in PROGRAM_LAGS_S:
        at += list(np.asarray(first_order_lag(grid, prog, tau))[near])
    return min(at) - PROGRAM_MISS_C, max(at) + PROGRAM_MISS_C


class _RampRunner(_Runner):
    """The stepped capture's frame pump, which also runs the chamber program: while the program
    runs, each pump writes the program's value as the setpoint once ``step_s`` of program time
    has passed since the last write (and logs it as ``ramp_setpoint``, fsync'd: the resume point)."""

    def __init__(self, *args, chamber: Chamber, program: RampProgram, step_s: float, offset_of,
                 history: Optional[_History] = None, **kw):
        super().__init__(*args, **kw)
        self.history = history
        self.chamber, self.program, self.step_s = chamber, program, float(step_s)
        self.offset_of = offset_of
        self.running = False
        self.p0 = 0.0            # program time at instrument time t0
        self.t0 = 0.0
        self.last_p: Optional[float] = None      # program time of the last setpoint written
        self.last_sp: Optional[float] = None
        self.chamber_errors = 0
        self.refused: list = []                  # (program s, setpoint) of every write refused or missed
        self.off_program: list = []              # (program s, PV, program's value) of visits the PV was off
        self.writes = 0                          # setpoints written since the program (re)started
        self.last_window: Optional[list] = None    # the frames of the last recording window
        self.written: deque = deque(maxlen=4096)   # (program s when written, program s written) of each write

    def program_s(self, now: Optional[float] = None) -> float:
        now = self.now if now is None else now
        return self.p0 + (now - self.t0) if self.running else self.p0

    def start_program(self, p0: float) -> None:
        self.p0, self.t0, self.running, self.last_p = float(p0), float(self.now), True, None
        self.writes = 0
        self.write_setpoint()

    def setpoint_at(self, p: float) -> float:
        """The program's value at program time ``p`` in the setpoint's resolution."""
        return round(round(self.program.value(p) / SETPOINT_RESOLUTION_C) * SETPOINT_RESOLUTION_C, 1)

    def write_setpoint(self) -> None:
        p = min(self.program_s(), self.program.duration_s)
        sp = self.setpoint_at(p)
        try:
            if sp != self.last_sp:
                self.chamber.set_setpoint_C(sp)
        except OSError as exc:            # ChamberError, minimalmodbus and serial errors: try again next step
            self.chamber_errors += 1
            self.refused.append((p, sp))
            self.events.write("chamber_error", program_s=p, setpoint_C=sp, error=str(exc))
            if self.chamber_errors >= 20:
                raise CaptureError(f"the chamber refused or missed 20 setpoints of the ramp program in a row: {exc}; "
                                   "run the same command again to resume") from None
            self.last_p = p
            return
        self.last_p, self.last_sp, self.chamber_errors = p, sp, 0
        self.writes += 1
        self.written.append((min(self.program_s(self.present_s()), self.program.duration_s), p))
        self.events.write("ramp_setpoint", program_s=p, setpoint_C=sp, time_s=self.now + self.offset_of())

    def setpoint_lateness_s(self, p_now: float) -> float:
        """How far (program s) the set point the chamber held may have trailed the program over the
        last :data:`PROGRAM_LAG_MAX_S` x 3: the largest time from a write's program time to the next
        write (or to ``p_now``). One step normally; more when the host wrote late (a long visit, a
        loaded machine: at the emulator's x500, 0.9 s of wall held a set point for 426 s of program,
        the chamber 13 degC from the program's lagged values with nothing wrong with it)."""
        recent = [w for w in self.written if w[1] >= p_now - 3 * PROGRAM_LAG_MAX_S]
        if not recent:
            return 0.0
        gaps = [b[0] - a[1] for a, b in zip(recent, recent[1:])] + [p_now - recent[-1][1]]
        return max(0.0, *gaps)

    def observe(self, frames: list) -> None:
        if self.history is not None:
            self.history.add(frames)

    def check_chamber(self, index: int) -> None:
        """After a visit: the chamber's PV within the values an air lagging the program by any time
        constant up to :data:`PROGRAM_LAG_MAX_S` would have now, give or take :data:`PROGRAM_MISS_C`
        (a chamber's air follows its set point with a lag of minutes; the emulator's is 10 min). The
        ramp read the PV at its start soak only: a chamber that refused its set points, could not go
        below 17 degC or ran on a wrong word order went by with the rows labelled by the program,
        exit 0 (an outside probe). The visit stays (the fit uses the unit's measured temperatures);
        the event and the report say it."""
        p = min(self.program_s(), self.program.duration_s)
        want = float(self.program.value(p))
        try:
            pv = float(self.chamber.temperature_C())
        except OSError as exc:
            self.events.write("chamber_error", program_s=p, error=f"reading the PV: {exc}")
            self.off_program.append((p, None, want))
            return
        # the PV is the chamber's now, the program time that of the latest frame: the host's own work since
        # it (the visit's fsync on a loaded disk) and frames still queued put it behind; an emulator at x500
        # makes a second of it 500 s of program (a clean-clone CI: "off the program" on a healthy chamber)
        p_read = min(self.program_s(self.present_s()), self.program.duration_s)
        # and the chamber holds a set point until the next write: written late, it trails the program
        late = self.setpoint_lateness_s(p_read)
        lo, hi = program_band(self.program, max(0.0, p - late), max(p, p_read))
        if not (math.isfinite(pv) and lo <= pv <= hi):
            self.events.write("chamber_off_program", index=index, program_s=p, chamber_C=pv, program_C=want,
                              band_C=[lo, hi], setpoint_late_s=late)
            self.off_program.append((p, pv, want))

    def chamber_warnings(self) -> list:
        out = []
        if self.refused:
            p, sp = self.refused[0]
            out.append(f"the chamber refused or missed {len(self.refused)} set point writes of the ramp program "
                       f"(the first at program time {p:.0f} s, {sp:g} degC; events chamber_error): program_C and "
                       "setpoint_C of the visits after it are the program's, not what the chamber was told")
        if self.off_program:
            p, pv, want = self.off_program[0]
            seen = "could not be read" if pv is None else f"read {pv:.4g} degC"
            out.append(f"the chamber's PV was off the program after {len(self.off_program)} visit(s) (the first at "
                       f"program time {p:.0f} s: it {seen} where the program was at {want:.4g} degC, more than "
                       f"{PROGRAM_MISS_C:g} degC outside the program and its {PROGRAM_LAG_MAX_S / 60:g} min lag; events "
                       "chamber_off_program): "
                       "program_C and setpoint_C label the program, the unit's t_* what it measured")
        return out

    def pump(self, timeout: float = 0.02) -> int:
        n = super().pump(timeout)      # on the continuous clock: a restarted instrument does not rewind it
        if self.window is not None:
            self.last_window = self.window[2]
        if self.running and self.now is not None and (self.last_p is None or self.last_p < self.program.duration_s):
            p = self.program_s()
            due = self.last_p is None or p - self.last_p >= self.step_s
            if not due and self.writes == 1:
                # the program's first move goes out as soon as the setpoint's resolution shows it: the
                # chamber leaves the start temperature when the program does, not a step later
                due = self.setpoint_at(min(p, self.program.duration_s)) != self.last_sp
            if due:
                self.write_setpoint()
        return n


# -- the campaign -----------------------------------------------------------------------------

def _identity(plan: RampPlan, settings: CaptureSettings) -> dict:
    return {"program_C": [float(v) for v in plan.program_C], "rate_C_per_min": float(plan.rate_C_per_min),
            "hold_s": float(plan.hold_s),
            "positions": [[k, float(a), float(b)] for k, (a, b) in plan.positions.items()],   # in cycle order
            "tau_s": float(settings.tau_s), "unit": settings.unit}


def _open_ramp_session(out: Path, plan: RampPlan, settings: CaptureSettings, labels: list, metadata=None):
    """The ramp capture state of ``out`` (resume) or a new one, the rows already captured and a
    new session recorded: ``(state, rows, done_before, session)``. A folder holding a stepped
    capture or another ramp campaign is refused naming what differs."""
    state_path = out / STATE_NAME
    identity = _identity(plan, settings)
    if state_path.exists():
        try:
            state = read_json(state_path)
            if isinstance(state, dict) and state.get("format") == "triadcal.capture":
                raise CaptureError(f"{out} holds a stepped capture (format 'triadcal.capture'); a ramp capture "
                                   "cannot resume it: choose another --out")
            require_format(state, RAMP_STATE_FORMAT, 1, str(state_path), "a ramp capture state file",
                           "ramp capture state")
        except InputError as exc:
            raise CaptureError(str(exc)) from None
        for key, value in identity.items():
            if state.get(key) != value:
                raise CaptureError(f"{out} holds a ramp campaign with a different {key} ({state.get(key)!r}, "
                                   f"now {value!r}); resume with the same plan and settings or choose another --out")
    else:
        state = {"format": RAMP_STATE_FORMAT, "version": 1, **identity, "sessions": []}
    rows = _read_ramp_rows(out / CSV_NAME, labels)
    if metadata is not None:
        check_session_metadata(state, metadata, out, read_bench_csv(out / CSV_NAME).metadata if rows else None)
    done_before = len(rows)
    session = len(state["sessions"]) + 1
    state["sessions"].append({"session": session, "started_wall": time.time(), "visits_before": done_before})
    atomic_write_json(state_path, state)
    return state, rows, done_before, session


def _read_ramp_rows(path: Path, labels: list) -> list:
    """Completed visits of an existing campaign.csv, checked against the cycle of positions."""
    if not path.exists():
        return []
    try:
        c = read_bench_csv(path)
    except BenchCSVError as exc:
        raise CaptureError(f"cannot resume: {exc}") from None
    if "raw_visit" not in c.extra or "program_C" not in c.extra or c.sd is None:
        raise CaptureError(f"cannot resume: {path} was not written by triadcal capture --ramp "
                           "(no raw_visit or program_C column)")
    rows = []
    for i in range(c.n_visits):
        want = labels[i % len(labels)]
        if c.position[i] != want:
            raise CaptureError(f"cannot resume: {path} line {c.lines[i]} holds {c.position[i]} where the cycle of "
                               f"positions has {want}")
        rows.append({"unit": c.unit[i], "setpoint_C": c.setpoint_C[i], "direction": c.direction[i],
                     "time_s": c.time_s[i], "position": c.position[i], "axis1_deg": c.axis1_deg[i],
                     "axis2_deg": c.axis2_deg[i], "tau_s": c.tau_s[i], "w": c.w[i], "t": c.t[i],
                     "sd": c.sd[i], "n_samples": int(c.n_samples[i]), "raw_visit": c.extra["raw_visit"][i],
                     "program_C": float(c.extra["program_C"][i]),
                     "dTdt_C_per_min": None if c.dTdt_C_per_min is None else float(c.dTdt_C_per_min[i])})
    return rows


def _ramp_campaign(rows: list, metadata: dict):
    c = _campaign(rows, metadata)
    c.extra["program_C"] = np.array([f"{r['program_C']:.3f}" for r in rows], dtype=object).astype(str)
    # the measured rate once every row has one (a folder begun by a capture without it keeps the
    # fit's central differences)
    if rows and all(r.get("dTdt_C_per_min") is not None for r in rows):
        c.dTdt_C_per_min = np.array([r["dTdt_C_per_min"] for r in rows], float)
        c.metadata["dTdt_method"] = DTDT_METHOD
    return c


def capture_ramp(out_dir, *, plan: RampPlan, imu: ImuReadout, bench: Bench, chamber: Chamber,
                 settings: Optional[CaptureSettings] = None, step_s: float = DEFAULT_STEP_S,
                 progress: Optional[Callable[[dict], None]] = None,
                 extra_metadata: Optional[dict] = None) -> CaptureReport:
    """Run (or resume) the ramp ``plan`` into ``out_dir`` (``triadcal capture --ramp``); see the module
    docstring. ``settings.tau_s`` is the plan's dwell (set from the plan when the settings are not
    given); ``settings.stabilisation`` applies once, at the program's first temperature.
    ``progress`` is called as by :func:`triadcal.hardware.capture.capture` (events 'start', 'soak',
    'move', 'record', 'visit', 'done'; ``setpoint_C`` is the program's present value)."""
    settings = settings or CaptureSettings(tau_s=float(plan.tau_s))
    if not math.isclose(float(settings.tau_s), float(plan.tau_s)):
        raise InputError(f"the ramp plan's tau_s is {plan.tau_s:g} s; the capture's {settings.tau_s:g} s differs")
    if not step_s > 0:
        raise InputError(f"the ramp's setpoint step must be > 0 s, not {step_s!r}")
    try:
        with folder_lock(out_dir, "capture"):
            return _capture_ramp(Path(out_dir), plan, imu, bench, chamber, settings, float(step_s),
                                 progress, extra_metadata)
    except FolderLocked as exc:
        raise CaptureError(str(exc)) from None
    except OSError as exc:
        storage_error(exc, out_dir)
        raise


def _capture_ramp(out, plan, imu, bench, chamber, settings, step_s, progress, extra_metadata) -> CaptureReport:
    from .protocols import TEMPERATURE_NONE

    wall0 = time.monotonic()
    (out / "raw").mkdir(parents=True, exist_ok=True)
    positions = {str(k): (float(v[0]), float(v[1])) for k, v in plan.positions.items()}
    labels = list(positions)
    program = RampProgram.of(plan)
    if getattr(imu, "temperature", None) == TEMPERATURE_NONE:
        raise CaptureError(f"the IMU ({getattr(imu, 'protocol', 'this protocol')}) gives no temperature: a ramp "
                           "capture labels each visit by the unit's temperatures and the fit takes their rate")
    commanded = getattr(bench, "commanded", None)
    if commanded is not None:
        for label, (a1, a2) in positions.items():
            try:
                commanded(a1, a2)
            except BenchError as exc:
                raise CaptureError(f"position {label} ({a1:g}, {a2:g}) of the plan: {exc}") from None
    total = int(plan.n_visits)          # the plan's count (20 s moves); the bench's own moves decide
    notify = progress or (lambda ev: None)

    ramp_text = (":".join(f"{v:g}" for v in plan.program_C) + f" degC at {plan.rate_C_per_min:g} degC/min, "
                 f"hold {plan.hold_s:g} s")
    metadata = {
        "generator": f"triadcal {__version__} capture --ramp",
        "bench": settings.bench_name,
        **({} if settings.local_g_m_s2 is None else {"local_g_m_s2": repr(settings.local_g_m_s2)}),
        "output_unit": settings.output_unit,
        **{k: v for k, v in imu_metadata(imu).items() if k != "output_unit" or settings.output_unit == "V"},
        "raw_samples": RAW_NAME,
        "ramp": ramp_text,
        "ramp_setpoint": (f"the program's value written as the chamber's setpoint every {step_s:g} s of the "
                          f"program ({SETPOINT_RESOLUTION_C:g} degC resolution); program_C is its value at the "
                          "window's middle"),
        "ramp_labels": ("setpoint_C: the target of the program's leg at the window's middle; direction: the sign "
                        "of the unit's rate over the window (a least-squares quadratic through the mean "
                        f"temperature reading over the window and the {DIRECTION_SPAN_S:g} s before), when 3 "
                        "standard errors from 0 and faster than the settled rate, else the previous visit's"),
        **({} if plan.effects is None else {"planned_effects": ",".join(plan.effects) or "none"}),
        "stabilisation": "at the program's first temperature only: " + settings.stabilisation.describe(),
        "settle_s": f"{settings.settle_s:g}",
        **({"plan": plan.name} if plan.name else {}),
        **({"operator": settings.operator} if settings.operator else {}),
        **(extra_metadata or {}),
    }
    state, rows, done_before, session = _open_ramp_session(out, plan, settings, labels, metadata)
    metadata = dated_metadata(metadata, state)
    state_path = out / STATE_NAME
    previous = [e for e in read_events(out / EVENTS_NAME) if e.get("kind") == "ramp_setpoint"]
    raw = RawStore(out / RAW_NAME)
    events = EventLog(out / EVENTS_NAME)
    if raw.torn_marked:          # the last session was killed mid-line: its torn line is marked, not read
        events.write("raw_torn_line", path=RAW_NAME, text="the raw file ended in a torn line (a killed session); "
                     f"marked {TORN_MARK!r} and skipped by the reader")
    events.write("session_start", session=session, visits_done=done_before, total=total, ramp=ramp_text,
                 stabilisation=settings.stabilisation.describe())
    imu.open()
    stream = StreamThread(imu)
    stream.start()
    offset_box = {"offset": float(state.get("time_offset_s", 0.0) or 0.0)}
    tee = _History()
    run = _RampRunner(stream, raw, events, session, settings, chamber=chamber, program=program, step_s=step_s,
                      offset_of=lambda: offset_box["offset"], history=tee)
    redone = 0
    noise_est: Optional[NoiseEstimate] = None
    try:
        run.wait_first_frame()
        offset = state.get("time_offset_s")
        last_end = max((r["time_s"] + r["tau_s"] / 2 for r in rows), default=0.0)
        if previous:
            last_end = max(last_end, max(float(e.get("time_s", 0.0)) for e in previous))
        if offset is None or run.now + offset < last_end:
            offset = last_end - run.now
            state["time_offset_s"] = offset
            atomic_write_json(state_path, state)
        offset_box["offset"] = offset
        notify({"event": "start", "done": done_before, "total": total})

        if previous:       # the program ran: go on from the last setpoint written, no new soak
            p_resume = max(float(e["program_s"]) for e in previous)
            events.write("ramp_resume", program_s=p_resume, setpoint_C=program.value(p_resume))
            run.start_program(p_resume)
        else:              # a ramp program starts from rest at its first temperature
            sp0 = float(program.knot_C[0])
            soak(run, chamber, events, settings, 0, sp0, "r-start", f"the ramp's first temperature {sp0:g} degC",
                 notify, len(rows), total)
            events.write("ramp_start", program_s=0.0, time_s=run.now + offset)
            run.start_program(0.0)

        while run.program_s() < program.duration_s:
            i = len(rows)
            label = labels[i % len(labels)]
            a1, a2 = positions[label]
            info = {"done": i, "total": max(total, i + 1), "setpoint_C": program.value(run.program_s()),
                    "position": label}
            for attempt in range(1, settings.max_attempts + 1):
                tag = f"r{i:04d}-{label}-{session}.{attempt}"
                run.last_window = None
                row = _visit(run, bench, events, settings, tag, a1, a2, notify, info)
                last_why = VISIT_PROBLEMS[run.visit_problem]
                if row is not None:
                    why = not_stationary(run.last_window or [], [r["sd"] for r in rows[-12:]])
                    if why is None:
                        mid = row["mid_instrument_s"]
                        rates = window_rates(tee.history, mid - settings.tau_s / 2, mid + settings.tau_s / 2)
                        if not turned_within(rates) or attempt == settings.max_attempts:
                            break
                        why = (f"the unit's temperature turned within the window (rate {rates['start'] * 60:+.3g} "
                               f"then {rates['end'] * 60:+.3g} degC/min): both hysteresis branches in one visit")
                    events.write("visit_redone", tag=tag, why=why)
                    last_why = why
                redone += 1
            else:
                raise CaptureError(f"visit {i + 1} ({label}) of the ramp: no clean window in {settings.max_attempts} "
                                   f"attempts, the last one {last_why} (see {EVENTS_NAME})")
            # a bench that reports each target but does not move (visit_checks.bench_did_not_move, as the
            # stepped capture): a temperature change between two visits moves w far less than a turn
            stuck = bench_did_not_move(rows[-1], row, a1, a2) if rows else None
            if stuck is not None:
                events.write("bench_stuck", tag=tag, position=label, previous=rows[-1]["position"], text=stuck)
                raise CaptureError(f"visit {i + 1} ({label}, {a1:g}, {a2:g}) of the ramp after {rows[-1]['position']} "
                                   f"({rows[-1]['axis1_deg']:g}, {rows[-1]['axis2_deg']:g}): {stuck}")
            raw.sync()       # every sample of the visit is on disk before the visit counts
            mid = row.pop("mid_instrument_s")
            p_mid = run.program_s(mid)
            rates = window_rates(tee.history, mid - settings.tau_s / 2, mid + settings.tau_s / 2)
            slope, se = rates["mean"], rates["mean_se"]
            dTdt, dTdt_se = visit_rate_se(run.last_window)
            first_leg = "heating" if program.knot_C[1] > program.knot_C[0] else "cooling"
            direction = visit_direction(slope, se, rows[-1]["direction"] if rows else first_leg,
                                        at_rest=settings.stabilisation.rate_C_per_min / 60.0, own=(dTdt, dTdt_se))
            row.update(unit=settings.unit, setpoint_C=program.target(p_mid), direction=direction, position=label,
                       axis1_deg=a1, axis2_deg=a2, tau_s=settings.tau_s, raw_visit=tag,
                       program_C=program.value(min(p_mid, program.duration_s)), dTdt_C_per_min=dTdt * 60.0)
            row["time_s"] = mid + offset
            rows.append(row)
            run.check_chamber(len(rows))
            # the event before the row, as capture.py (a kill between leaves an event no row names)
            events.write("visit", index=len(rows), tag=tag, n_samples=row["n_samples"], program_s=p_mid,
                         program_C=row["program_C"], slope_C_per_min=slope * 60.0,
                         slope_se_C_per_min=se * 60.0 if math.isfinite(se) else None, direction=direction,
                         dTdt_C_per_min=dTdt * 60.0)
            atomic_write_text(out / CSV_NAME, format_bench_csv(_ramp_campaign(rows, metadata)))
            notify({"event": "visit", "done": len(rows), "total": max(total, len(rows)),
                    "setpoint_C": row["program_C"], "position": label})
        if run.last_p is None or run.last_p < program.duration_s:
            run.write_setpoint()          # the program's last value: the chamber holds it
        run.running = False
        run.phase, run.visit_tag = "idle", ""
        events.write("ramp_end", program_s=program.duration_s, visits=len(rows))
        noise_est = campaign_noise(out / RAW_NAME, rows, run, metadata)
        if rows:
            atomic_write_text(out / CSV_NAME, format_bench_csv(_ramp_campaign(rows, metadata)))
        notify({"event": "done", "done": len(rows), "total": len(rows)})
    finally:
        stream.stop()
        try:                      # frames read but not yet pumped are stored too
            run.running = False
            run.phase, run.visit_tag, run.window = "idle", "", None
            while run.pump(0.0):
                pass
        except (CaptureError, RuntimeError):
            pass
        run.flush_held()          # a frame held as a possible restart: its values into the event log
        raw.close()
        run.warnings.extend(run.chamber_warnings())
        report = finish_session(out, imu, run, events, session, max(total, len(rows)), done_before, len(rows),
                                redone, noise_est, wall0)
    return report
