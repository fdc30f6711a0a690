"""Run a bench campaign: chamber setpoints, stabilisation, bench positions, averaging.

:func:`capture` (behind ``triadcal capture``; :class:`CaptureSettings`, :class:`Stabilisation`,
:class:`CaptureReport`) records every accepted sample append-only, rewrites the bench CSV
``campaign.csv`` atomically after each visit, resumes from its completed rows, and writes
the Allan-deviation noise into its header. Derivation/design: docs/hardware.md (Campaign).
The checks of a visit's window are in visit_checks.py, the noise of the windows in noise.py;
the instruments' protocols and drivers are in protocols/ and drivers/.
"""

from __future__ import annotations

from ..errors import InputError

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Optional, Sequence

import numpy as np

from .. import __version__
from ..io.bench_csv import BenchCSVError, format_bench_csv, read_bench_csv
from ..models.campaign import Campaign
from ..models.simulate import Schedule
from .drivers.bench import Bench, BenchError
from .drivers.bench_template import BenchControllerError
from .drivers.chamber import Chamber
from .drivers.imu import ImuReadout, StreamThread
from .noise import NoiseEstimate, allan_noise, campaign_noise, _campaign_noise  # noqa: F401 - importable
from .protocols import Frame
from ..io.atomic import atomic_write_json, atomic_write_text, read_json
from ..io.formats import require_format
from .storage import TORN_MARK, EventLog, FolderLocked, RawStore, folder_lock, read_raw  # noqa: F401 - importable
from .runner import CaptureError, _max_temperature_rate, _Runner  # noqa: F401 - importable from here
from .visit_checks import (OVERFULL, VISIT_PROBLEMS, RepeatedEvents, bench_did_not_move,  # noqa: F401 - importable
                           bench_position_problem, thermal_departure, window_outlier)
from .session_checks import (UNIT_MISS_C, check_session_metadata, dated_metadata, setpoint_missed,  # noqa: F401 - importable
                             start_temperature, start_text, storage_error)

CSV_NAME = "campaign.csv"
STATE_NAME = "capture.json"
RAW_NAME = "raw/imu_samples.csv"
EVENTS_NAME = "raw/events.jsonl"
REPORT_NAME = "capture_report.json"


@dataclass
class Stabilisation:
    """When the unit counts as settled at a setpoint.

    The rate of change of each accelerometer temperature sensor is the least-squares
    slope of its readings over the last ``window_s`` seconds; the unit is stable once
    the largest of the three stays below ``rate_C_per_min`` for ``hold_s`` seconds
    without interruption. ``timeout_s`` (instrument time) stops the campaign with an
    error instead of waiting for ever.
    """

    rate_C_per_min: float = 0.01
    window_s: float = 120.0
    hold_s: float = 300.0
    timeout_s: float = 6 * 3600.0

    def describe(self) -> str:
        return (f"|dT/dt| of every accelerometer temperature (least-squares slope over {self.window_s:g} s) "
                f"< {self.rate_C_per_min:g} degC/min for {self.hold_s:g} s")


@dataclass
class CaptureSettings:
    """How each visit is made; times in instrument seconds."""

    tau_s: float = 30.0
    settle_s: float = 5.0
    stabilisation: Stabilisation = field(default_factory=Stabilisation)
    unit: str = "SN-UNKNOWN"
    bench_name: str = "two-axis bench"
    operator: str = ""
    #: the local gravity the operator stated (m/s^2); None: not stated, and the bench CSV then has no
    #: ``local_g_m_s2`` (a fit assumes standard gravity and says so; a certificate needs the value)
    local_g_m_s2: Optional[float] = None
    output_unit: str = "V"
    min_coverage: float = 0.9          # fraction of the expected samples a window must hold
    max_attempts: int = 3              # per visit, then give up
    move_timeout_s: float = 600.0
    silence_timeout_wall_s: float = 30.0   # no frame at all for this long (wall clock): stop


@dataclass
class CaptureReport:
    """What a capture session did; also written to ``capture_report.json``."""

    out_dir: str
    csv_path: str
    session: int
    visits_total: int
    visits_done_before: int
    visits_done: int
    accepted_samples: int
    duplicate_frames: int
    missing_frames: int
    corrupted_frames: int
    garbage_bytes: int
    reconnects: int
    disconnects: int
    stalls: int
    redone_visits: int
    noise: Optional[dict] = None
    wall_seconds: float = 0.0
    invalid_frames: int = 0            # refused by runner.frame_problem (event invalid_frame)
    clock_faults: int = 0              # instrument restarts, clock steps, sequence resets (runner.py)
    late_frames: int = 0               # came after later ones: in the event log (late_frame), not the record
    conflicting_frames: int = 0        # a copy of an admitted frame with other values (conflicting_frame)
    warnings: list = field(default_factory=list)   # what the operator must know (setpoint not reached)

    def to_dict(self) -> dict:
        return asdict(self)


def plan_from_csv(path) -> dict:
    """A bench plan from a CSV file with columns ``position,axis1_deg,axis2_deg``."""
    import csv

    plan = {}
    with open(path, encoding="utf-8") as fh:
        rows = [r for r in csv.reader(line for line in fh if not line.startswith("#")) if r]
    if not rows or [h.strip() for h in rows[0]] != ["position", "axis1_deg", "axis2_deg"]:
        raise InputError(f"{path}: a plan file starts with the header 'position,axis1_deg,axis2_deg'")
    from ..io.numbers import NumberError, parse_number

    for k, r in enumerate(rows[1:], start=2):
        if len(r) != 3 or not r[0].strip():
            raise InputError(f"{path}:{k}: expected a label and two angles in degrees, got {r}")
        if r[0].strip() in plan:
            raise InputError(f"{path}:{k}: position {r[0].strip()!r} appears twice")
        try:
            plan[r[0].strip()] = tuple(parse_number(v, low=-360.0, high=360.0, what=name)
                                       for v, name in zip(r[1:], ("axis1_deg", "axis2_deg")))
        except NumberError as exc:
            raise InputError(f"{path}:{k}: {exc.problem}") from None
    if not plan:
        raise InputError(f"{path}: the plan has no positions")
    return plan


def _open_session(out, state_path, plan, setpoints_C, directions, labels, settings, metadata=None):
    """The capture state of the folder (resume) or a new one, the rows already captured, and a
    new session recorded (written atomically before anything moves): ``(state, rows,
    done_before, session)``. A folder that holds another campaign (plan, setpoints, tau, unit)
    or whose rows were captured with other header metadata (:func:`check_session_metadata`)
    is refused naming what differs."""
    identity = {"plan": {k: list(v) for k, v in plan.items()}, "setpoints_C": setpoints_C,
                "tau_s": settings.tau_s, "unit": settings.unit}
    if state_path.exists():
        try:
            state = read_json(state_path)
            require_format(state, "triadcal.capture", 1, str(state_path), "a capture state file", "capture state")
        except ValueError as exc:
            raise CaptureError(str(exc)) from None
        for key, value in identity.items():
            if state.get(key) != value:
                raise CaptureError(f"{out} holds a campaign with a different {key} ({state.get(key)!r}, "
                                   f"now {value!r}); resume with the same settings or choose another --out")
    else:
        state = {"format": "triadcal.capture", "version": 1, **identity, "sessions": []}
    rows = _read_rows(out / CSV_NAME, labels, setpoints_C, directions)
    if metadata is not None:
        check_session_metadata(state, metadata, out, read_bench_csv(out / CSV_NAME).metadata if rows else None)
    done_before = len(rows)
    session = len(state["sessions"]) + 1
    state["sessions"].append({"session": session, "started_wall": time.time(), "visits_before": done_before})
    atomic_write_json(state_path, state)
    return state, rows, done_before, session


def capture(out_dir, *, plan: Mapping[str, tuple], setpoints_C: Sequence[float],
            imu: ImuReadout, bench: Bench, chamber: Chamber,
            settings: Optional[CaptureSettings] = None,
            progress: Optional[Callable[[dict], None]] = None,
            extra_metadata: Optional[dict] = None) -> CaptureReport:
    """Run (or resume) a campaign into ``out_dir`` (``triadcal capture``); see the module docstring.

    ``progress`` is called with a dict (``event``: 'start', 'soak', 'move', 'record',
    'visit', 'done'; plus ``done``, ``total``, ``setpoint_C``, ``position``, ``chamber_C``).
    The folder is locked for the whole run (:func:`~triadcal.hardware.storage.folder_lock`):
    a second capture into it is refused at once, naming the holder.
    """
    try:
        with folder_lock(out_dir, "capture"):
            return _capture(out_dir, plan=plan, setpoints_C=setpoints_C, imu=imu, bench=bench, chamber=chamber,
                            settings=settings, progress=progress, extra_metadata=extra_metadata)
    except FolderLocked as exc:
        raise CaptureError(str(exc)) from None
    except OSError as exc:
        storage_error(exc, out_dir)
        raise


def _capture(out_dir, *, plan, setpoints_C, imu, bench, chamber, settings, progress, extra_metadata) -> CaptureReport:
    wall0 = time.monotonic()
    settings = settings or CaptureSettings()
    out = Path(out_dir)
    (out / "raw").mkdir(parents=True, exist_ok=True)
    plan = {str(k): (float(v[0]), float(v[1])) for k, v in plan.items()}
    setpoints_C = [float(s) for s in setpoints_C]
    if not plan or not setpoints_C:
        raise InputError("a campaign needs at least one bench position and one setpoint")
    # the first setpoint's branch from the side the unit starts on: the chamber's PV now (a new campaign)
    start_C, start = start_temperature(out / STATE_NAME, chamber, setpoints_C)
    directions = Schedule(setpoints_C=setpoints_C, start_C=start_C).directions()
    from .protocols import TEMPERATURE_NONE

    if getattr(imu, "temperature", None) == TEMPERATURE_NONE:
        # the stabilisation waits for the unit's own temperatures: with none it would wait forever
        raise CaptureError(f"the IMU ({getattr(imu, 'protocol', 'this protocol')}) gives no temperature, and the "
                           "capture waits for the unit's own temperatures to settle before each setpoint; use an "
                           "IMU output that carries one (VectorNav VNIMU, Xsens 0x0810) or an analog unit through "
                           "[dmm] (the chamber's PV)")
    commanded = getattr(bench, "commanded", None)     # a bench with soft limits checks the plan first
    if commanded is not None:
        for label, (a1, a2) in plan.items():
            try:
                commanded(a1, a2)
            except BenchError as exc:
                raise CaptureError(f"position {label} ({a1:g}, {a2:g}) of the plan: {exc}") from None
    labels = list(plan)
    total = len(labels) * len(setpoints_C)
    notify = progress or (lambda ev: None)

    metadata = {
        "generator": f"triadcal {__version__} capture",
        "bench": settings.bench_name,
        **({} if settings.local_g_m_s2 is None else {"local_g_m_s2": repr(settings.local_g_m_s2)}),
        "output_unit": settings.output_unit,
        **{k: v for k, v in imu_metadata(imu).items() if k != "output_unit" or settings.output_unit == "V"},
        "raw_samples": RAW_NAME,
        "stabilisation": settings.stabilisation.describe(),
        "settle_s": f"{settings.settle_s:g}",
        **({"operator": settings.operator} if settings.operator else {}),
        **({} if start is None else {"start_C": start_text(start)}),
        **(extra_metadata or {}),
    }

    # -- state: what the directory already holds --------------------------------------
    state_path = out / STATE_NAME
    state, rows, done_before, session = _open_session(out, state_path, plan, setpoints_C, directions, labels,
                                                      settings, metadata)
    if start is not None and "start_C" not in state:
        state["start_C"] = start
        atomic_write_json(state_path, state)
    metadata = dated_metadata(metadata, state)

    raw = RawStore(out / RAW_NAME)
    events = EventLog(out / EVENTS_NAME)
    if raw.torn_marked:          # the last session was killed mid-line: its torn line is marked, not read
        events.write("raw_torn_line", path=RAW_NAME, text="the raw file ended in a torn line (a killed session); "
                     f"marked {TORN_MARK!r} and skipped by the reader")
    events.write("session_start", session=session, visits_done=done_before, total=total,
                 stabilisation=settings.stabilisation.describe())
    imu.open()
    stream = StreamThread(imu)
    stream.start()
    run = _Runner(stream, raw, events, session, settings)
    redone = 0
    noise_est: Optional[NoiseEstimate] = None
    try:
        run.wait_first_frame()
        # campaign time = instrument time + offset; a restarted instrument clock is caught up
        offset = state.get("time_offset_s")
        last_end = max((r["time_s"] + r["tau_s"] / 2 for r in rows), default=0.0)
        if offset is None or run.now + offset < last_end:
            offset = last_end - run.now
            state["time_offset_s"] = offset
            atomic_write_json(state_path, state)
        notify({"event": "start", "done": done_before, "total": total})

        for k, (sp, direction) in enumerate(zip(setpoints_C, directions)):
            if (k + 1) * len(labels) <= len(rows):
                continue
            # -- chamber and stabilisation --
            stable_t = soak(run, chamber, events, settings, k, sp, f"s{k:03d}", f"setpoint {sp:g} degC", notify,
                            len(rows), total)
            chamber_lost = False

            for j, label in enumerate(labels):
                if k * len(labels) + j < len(rows):
                    continue
                a1, a2 = plan[label]
                for attempt in range(1, settings.max_attempts + 1):
                    tag = f"s{k:03d}-{label}-{session}.{attempt}"
                    row = _visit(run, bench, events, settings, tag, a1, a2, notify,
                                 {"done": len(rows), "total": total, "setpoint_C": sp, "position": label},
                                 stable_t=stable_t)
                    pv, chamber_lost = _chamber_at_visit(chamber, events, run, sp, label, chamber_lost)
                    if row is not None:
                        break
                    redone += 1
                else:
                    raise CaptureError(f"position {label} at setpoint {sp:g} degC: no clean window in "
                                       f"{settings.max_attempts} attempts, the last one "
                                       f"{VISIT_PROBLEMS[run.visit_problem]}"
                                       + (f": {run.visit_detail}" if run.visit_detail else "")
                                       + (f"; the chamber has not answered since position {chamber_lost}"
                                          if chamber_lost else "")
                                       + f" (events {run.visit_problem} in {EVENTS_NAME})")
                # a bench that reports each target but does not move: the output must follow gravity
                stuck = bench_did_not_move(rows[-1], row, a1, a2) if rows else None
                if stuck is not None:
                    prev = rows[-1]
                    events.write("bench_stuck", tag=tag, position=label, previous=prev["position"], text=stuck)
                    raise CaptureError(f"setpoint {sp:g} degC: position {label} ({a1:g}, {a2:g}) after position "
                                       f"{prev['position']} ({prev['axis1_deg']:g}, {prev['axis2_deg']:g}): {stuck}")
                raw.sync()   # every sample of the visit is on disk before the visit counts
                row.update(unit=settings.unit, setpoint_C=sp, direction=direction, position=label,
                           axis1_deg=a1, axis2_deg=a2, tau_s=settings.tau_s, raw_visit=tag)
                row["time_s"] = row.pop("mid_instrument_s") + offset
                rows.append(row)
                # the visit's event before its row (as the voltmeter path): a process killed between
                # the two leaves an event no row names and the visit is made again, never a row
                # without its event (the row first left one after a kill there, an outside probe)
                events.write("visit", index=len(rows), tag=tag, n_samples=row["n_samples"], chamber_C=pv)
                atomic_write_text(out / CSV_NAME, format_bench_csv(_campaign(rows, metadata)))
                notify({"event": "visit", "done": len(rows), "total": total, "setpoint_C": sp,
                        "position": label})
        run.phase, run.visit_tag = "idle", ""
        # -- noise from the recording windows of the visits the CSV points to --
        noise_est = campaign_noise(out / RAW_NAME, rows, run, metadata)
        atomic_write_text(out / CSV_NAME, format_bench_csv(_campaign(rows, metadata)))
        notify({"event": "done", "done": len(rows), "total": total})
    finally:
        stream.stop()
        try:                      # frames read but not yet pumped are stored too
            run.phase, run.visit_tag, run.window = "idle", "", None
            while run.pump(0.0):
                pass
        except (CaptureError, RuntimeError):
            pass
        run.flush_held()          # a frame held as a possible restart: its values into the event log
        raw.close()
        report = finish_session(out, imu, run, events, session, total, done_before, len(rows), redone, noise_est,
                                wall0)
    return report


#: where an analog unit's t_x, t_y, t_z come from (CSV metadata ``unit_temperature``)
def finish_session(out: Path, imu, run: "_Runner", events: EventLog, session: int, total: int, done_before: int,
                   done: int, redone: int, noise_est: Optional[NoiseEstimate], wall0: float) -> CaptureReport:
    """The session's counters as a :class:`CaptureReport`: the link's events and ``session_end``
    in the event log (which it closes), and the report file ``REPORT_NAME``."""
    ps, ls = imu.parser_stats, imu.link_stats
    report = CaptureReport(
        out_dir=str(out), csv_path=str(out / CSV_NAME), session=session, visits_total=total,
        visits_done_before=done_before, visits_done=done, accepted_samples=run.accepted,
        duplicate_frames=run.duplicates, missing_frames=run.missing, corrupted_frames=ps.corrupted,
        garbage_bytes=ps.garbage_bytes, reconnects=ls.reconnects, disconnects=ls.disconnects,
        stalls=ls.stalls, redone_visits=redone, invalid_frames=getattr(run, "invalid", 0),
        clock_faults=getattr(run, "clock_faults", 0), late_frames=getattr(run, "late", 0),
        conflicting_frames=getattr(run, "conflicts", 0),
        warnings=list(getattr(run, "warnings", [])),
        noise=None if noise_est is None else {
            "Q_V2s": list(noise_est.Q_V2s), "bias_instability_V": list(noise_est.bias_instability_V),
            "floor_reached": list(noise_est.floor_reached), "taus_s": noise_est.taus_s.tolist(),
            "adev_V": noise_est.adev.tolist()},
        wall_seconds=time.monotonic() - wall0)
    run.write_link_events()                  # the rest (most were written as they happened)
    events.write("session_end", **{k: v for k, v in report.to_dict().items() if k != "noise"})
    events.close()
    atomic_write_json(out / REPORT_NAME, report.to_dict())
    return report


def soak(run: "_Runner", chamber, events: EventLog, settings: CaptureSettings, index: int, sp: float, tag: str,
         what: str, notify, done: int, total: int) -> np.ndarray:
    """Set the chamber to ``sp`` degC and wait until the unit's temperatures meet the
    stabilisation rule (events ``setpoint`` and ``stable``); ``what`` names the step in the error
    raised when the rule's timeout passes first. Returns the unit's temperatures (mean of the
    rule's last window, per sensor) at the moment it was declared stable: each visit's window is
    held against them (:func:`thermal_departure`)."""
    chamber.set_setpoint_C(sp)
    events.write("setpoint", index=index, setpoint_C=sp)
    run.phase, run.visit_tag = "soak", tag
    run.temps.clear()
    crit = settings.stabilisation
    t_start, stable_since, last_note = run.now, None, 0.0
    while True:
        run.pump()
        rate = _max_temperature_rate(run.temps, crit.window_s, run.now)
        if rate is not None and rate * 60.0 < crit.rate_C_per_min:
            stable_since = run.now if stable_since is None else stable_since
            if run.now - stable_since >= crit.hold_s:
                break
        else:
            stable_since = None
        if run.now - t_start > crit.timeout_s:
            raise CaptureError(f"{what}: not stable after {crit.timeout_s:g} s ({crit.describe()}); last rate "
                               f"{'unknown' if rate is None else f'{rate * 60:.3g} degC/min'}")
        if time.monotonic() - last_note > 0.25:
            last_note = time.monotonic()
            notify({"event": "soak", "done": done, "total": total, "setpoint_C": sp,
                    "rate_C_per_min": None if rate is None else rate * 60.0,
                    "chamber_C": _safe(chamber.temperature_C)})
    stable_t = np.mean(np.array([T for _, T in run.temps], float), axis=0)
    events.write("stable", index=index, setpoint_C=sp, after_s=run.now - t_start,
                 t_C=[float(v) for v in stable_t])
    try:
        pv, unread = chamber.temperature_C(), None
    except OSError as exc:
        pv, unread = None, exc
    missed = setpoint_missed(sp, [T for _, T in run.temps], pv)
    if unread is not None:
        # an unreadable PV left only the unit's own 10 degC check, silently (an outside probe)
        missed = "; ".join(x for x in (f"the chamber's PV could not be read ({unread}): the setpoint is checked "
                                       f"on the unit's own sensors only (within {UNIT_MISS_C:g} degC)", missed) if x)
    if missed:
        events.write("setpoint_missed", index=index, setpoint_C=sp, text=missed)
        run.warnings.append(f"{what}: {missed}")
    return stable_t


def _chamber_at_visit(chamber, events: EventLog, run: "_Runner", sp: float, label: str, lost):
    """The chamber's PV after a visit's window (one register read), None when it does not answer:
    said once a setpoint (event ``chamber_unread``, a warning of the run; ``chamber_answers`` when
    it comes back). An outside probe's chamber stopped answering after the first visit and its
    heater went off: no request was made after 'stable', nothing said. Returns ``(pv, lost)``,
    ``lost`` the position at which it stopped answering (or False)."""
    try:
        pv = chamber.temperature_C()
    except OSError as exc:
        if not lost:
            lost = label
            events.write("chamber_unread", setpoint_C=sp, position=label, text=str(exc))
            run.warnings.append(f"setpoint {sp:g} degC: the chamber stopped answering at position {label} "
                                f"({exc}); its visits are checked on the unit's own temperatures only")
        return None, lost
    if lost:
        events.write("chamber_answers", setpoint_C=sp, position=label, chamber_C=pv)
    return pv, False


def _safe(fn):
    try:
        return fn()
    except OSError:
        return None


def _visit(run: _Runner, bench: Bench, events: EventLog, settings: CaptureSettings, tag: str,
           a1: float, a2: float, notify, info: dict, stable_t=None) -> Optional[dict]:
    """Move, settle, record one window; the row's values, or None when the window is refused
    (``run.visit_problem`` and ``run.visit_detail`` say why): too few samples, a clock fault, a
    bench off its position after the window, a unit not at ``stable_t`` (the soak's stable
    temperatures; None: not checked, a ramp), a spike."""
    run.phase, run.visit_tag = "move", tag
    run.visit_detail = ""
    notify({"event": "move", **info})
    faults, conflicts = run.clock_faults, getattr(run, "conflicts", 0)
    bench.move_to(a1, a2)
    t_move = run.now
    errors = RepeatedEvents(events, "bench_error")
    try:
        while True:
            run.pump()
            try:
                ready = bench.in_position()
            except BenchControllerError:   # the controller's own error: polling again will not help
                raise
            except BenchError as exc:      # keep polling until the move timeout
                errors.add(str(exc))
                ready = False
            if ready:
                break
            if run.now - t_move > settings.move_timeout_s:
                raise BenchError(f"bench did not reach ({a1}, {a2}) in {settings.move_timeout_s:g} s"
                                 + (f"; it answered an error {errors.count} times while polling, the last: "
                                    f"{errors.last}" if errors.count else ""))
    finally:
        errors.flush()
    # in position: the settling time starts now, the instrument's present (runner.present_s), or at the
    # first frame read after this moment if that is later. The first frame read may be older than the
    # move's end: frames still queued, a host behind its reader (a loaded machine: at the emulator's x500
    # 0.2 s of wall is 100 s of instrument time, and a ramp's window began before the bench had moved,
    # "the bench did not move" on a bench that had)
    present = run.present_s()
    run.phase = "settle"
    t_ready = None
    while t_ready is None:
        before = run.last_seq
        run.pump()
        if run.last_seq != before:
            t_ready = run.now
    window_start = max(t_ready, present if present is not None else t_ready) + settings.settle_s
    got: list[Frame] = []
    run.window = (window_start, window_start + settings.tau_s, got)
    notify({"event": "record", **info})
    while run.now < window_start + settings.tau_s:
        run.pump()
    run.window = None
    run.phase = "idle"
    rate = run.rate_hz or 1.0
    expected = settings.tau_s * rate
    # where the bench is after the window (asked once before the settle only, an outside probe's bench
    # crept 0.055 deg in a window with every row at the commanded angle); first, as it explains the rest
    moved = bench_position_problem(bench, a1, a2)
    if moved is not None:
        kind, text, fields = moved
        events.write(kind, tag=tag, text=text, **fields)
        run.visit_problem, run.visit_detail = kind, text
        return None
    if run.clock_faults != faults:
        # a restart or clock step during the move, settling or window: the window's frames may
        # come from two periods of the unit (runner.py); redo the visit
        events.write("visit_clock_fault", tag=tag, n_samples=len(got), expected=expected)
        run.visit_problem = "visit_clock_fault"
        return None
    if getattr(run, "conflicts", 0) != conflicts:
        # two copies of a frame with other values (runner.py): which the window holds is not known; redo it
        events.write("visit_conflicting_frames", tag=tag, n_conflicts=run.conflicts - conflicts)
        run.visit_problem = "visit_conflicting_frames"
        return None
    if len(got) < max(2, settings.min_coverage * expected):
        events.write("visit_incomplete", tag=tag, n_samples=len(got), expected=expected)
        run.visit_problem = "visit_incomplete"
        return None
    if len(got) > OVERFULL * expected + 2:
        events.write("visit_overfull", tag=tag, n_samples=len(got), expected=expected)
        run.visit_problem = "visit_overfull"
        return None
    departed = thermal_departure(got, stable_t, settings.stabilisation)
    if departed is not None:
        text, fields = departed
        events.write("visit_not_stable", tag=tag, text=text, **fields)
        run.visit_problem, run.visit_detail = "visit_not_stable", text
        return None
    why = window_outlier(got)
    if why is not None:
        events.write("visit_outlier", tag=tag, reason=why, n_samples=len(got))
        run.visit_problem, run.visit_detail = "visit_outlier", why
        return None
    w = np.array([f.w for f in got])
    t = np.array([f.t for f in got])
    return {"w": w.mean(axis=0), "t": t.mean(axis=0), "sd": w.std(axis=0, ddof=1), "n_samples": len(got),
            "mid_instrument_s": window_start + settings.tau_s / 2}


def _campaign(rows: list, metadata: dict) -> Campaign:
    n = len(rows)

    def col(name, dtype=float):
        return np.array([r[name] for r in rows], dtype=dtype)

    return Campaign(
        unit=col("unit", object).astype(str), setpoint_C=col("setpoint_C"),
        direction=col("direction", object).astype(str), time_s=col("time_s"),
        position=col("position", object).astype(str), axis1_deg=col("axis1_deg"),
        axis2_deg=col("axis2_deg"), tau_s=col("tau_s"),
        w=np.array([r["w"] for r in rows], float).reshape(n, 3),
        t=np.array([r["t"] for r in rows], float).reshape(n, 3),
        cycle=np.zeros(n, int), state=np.full(n, "initial"),
        sd=np.array([r["sd"] for r in rows], float).reshape(n, 3), n_samples=col("n_samples", int),
        # u_w_* once every row has one (written by _campaign_noise at the end of the campaign)
        u_w=(np.array([r["u_w"] for r in rows], float).reshape(n, 3)
             if rows and all(r.get("u_w") is not None for r in rows) else None),
        metadata=dict(metadata), extra={"raw_visit": col("raw_visit", object).astype(str)})


def _read_rows(path: Path, labels: list, setpoints: list, directions: list) -> list[dict]:
    """Completed visits from an existing campaign.csv, checked against the campaign's order."""
    if not path.exists():
        return []
    try:
        c = read_bench_csv(path)
    except BenchCSVError as exc:
        raise CaptureError(f"cannot resume: {exc}") from None
    if "raw_visit" not in c.extra or c.sd is None:
        raise CaptureError(f"cannot resume: {path} was not written by triadcal capture (no raw_visit column)")
    rows = []
    for i in range(c.n_visits):
        k, j = divmod(i, len(labels))
        if k >= len(setpoints) or c.position[i] != labels[j] or c.setpoint_C[i] != setpoints[k]:
            raise CaptureError(f"cannot resume: {path} line {c.lines[i]} holds {c.position[i]} at "
                               f"{c.setpoint_C[i]:g} degC where the plan has "
                               f"{labels[j] if k < len(setpoints) else 'nothing'}")
        rows.append({"unit": c.unit[i], "setpoint_C": c.setpoint_C[i], "direction": c.direction[i],
                     "time_s": c.time_s[i], "position": c.position[i], "axis1_deg": c.axis1_deg[i],
                     "axis2_deg": c.axis2_deg[i], "tau_s": c.tau_s[i], "w": c.w[i], "t": c.t[i],
                     "sd": c.sd[i], "n_samples": int(c.n_samples[i]), "raw_visit": c.extra["raw_visit"][i],
                     "u_w": None if c.u_w is None else c.u_w[i]})
    return rows


# opening the instruments from a file (split out; the names stay importable from here)
from .instrument_config import (BENCH_DRIVERS, IMU_DRIVERS, IMU_OPTIONS, INSTRUMENT_KEYS,  # noqa: E402,F401
                                imu_metadata, load_instruments, load_port_config, open_bench, open_instruments)
