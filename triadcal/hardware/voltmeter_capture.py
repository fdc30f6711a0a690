"""Capture of an analog unit read by a voltmeter (``[dmm]`` without ``[imu]``): the same plan walk,
soak and stabilisation as :func:`triadcal.hardware.capture.capture`, with the meters of
``drivers.dmm.open_voltmeter`` instead of an IMU stream, and temperatures from the chamber's
process value. Split from ``capture.py``.
"""

from __future__ import annotations

from ..errors import InputError

import time
from collections import deque
from pathlib import Path
from typing import Callable, Mapping, Optional, Sequence

import numpy as np

from .. import __version__
from ..io.bench_csv import format_bench_csv
from ..models.simulate import Schedule
from .drivers.bench import Bench, BenchError
from .drivers.bench_template import BenchControllerError
from .drivers.chamber import Chamber
from ..io.atomic import atomic_write_json, atomic_write_text
from .storage import EventLog, FolderLocked, folder_lock
from .capture import (CSV_NAME, EVENTS_NAME, REPORT_NAME, STATE_NAME, CaptureError, CaptureReport, CaptureSettings,
                      _campaign, _max_temperature_rate, _open_session, dated_metadata, setpoint_missed, storage_error)
from .session_checks import start_temperature, start_text


ANALOG_TEMPERATURE = ("chamber: the chamber's process value (air temperature), read before and after each "
                      "visit's window and averaged, copied to t_x, t_y and t_z; the analog unit has no "
                      "temperature output, so it lags and differs from the unit's own temperature")


def chamber_pv_C(chamber: Chamber, sp: float) -> float:
    """The chamber's process value, which this path records as the unit's temperature: a reading
    that is not a temperature (a Modbus controller's sensor break reads 0x8000, -3276.8 degC) is
    refused before anything is recorded. It was written to every row as t_x = t_y = t_z = -3276.8
    (exit 0), a campaign that neither fit nor the same command could then take (an outside probe)."""
    from .session_checks import is_temperature_C

    pv = chamber.temperature_C()
    if not is_temperature_C(pv):
        raise CaptureError(f"setpoint {sp:g} degC: the chamber's PV reads {pv!r} degC, not a temperature (a sensor "
                           "break?); this capture records the PV as the unit's temperature, so nothing is recorded "
                           "until it reads one (the visits done are kept: fix the sensor, then run the same command "
                           "again to resume)")
    return pv


def capture_voltmeter(out_dir, *, plan: Mapping[str, tuple], setpoints_C: Sequence[float], voltmeter,
                      bench: Bench, chamber: Chamber, settings: Optional[CaptureSettings] = None,
                      time_scale: float = 1.0, poll_s: float = 1.0,
                      progress: Optional[Callable[[dict], None]] = None,
                      extra_metadata: Optional[dict] = None) -> CaptureReport:
    """Run (or resume) a campaign of an analog unit read by a voltmeter
    (:class:`~triadcal.hardware.drivers.dmm.VoltmeterReadout`) into ``out_dir``.

    The same plan, state file, resume and bench CSV as :func:`capture`, but each visit's
    ``w``, ``sd`` and ``n_samples`` are the meter's statistics of one window of
    ``voltmeter.samples_for(tau_s)`` readings (``SAMP:COUN = round(tau_s * mains_hz / NPLC)``,
    at least 2), taken after the bench is in position and ``settle_s`` has passed. The
    temperatures are the chamber's PV (:data:`ANALOG_TEMPERATURE`), which is also what the
    stabilisation criterion watches, polled every ``poll_s``. Times are wall seconds times
    ``time_scale`` (1 for real instruments; the emulator's compressed clock otherwise). No raw
    per-reading store and no Allan noise: the CSV holds each window's sd and count.
    """
    try:
        with folder_lock(out_dir, "capture"):
            return _capture_voltmeter(out_dir, plan=plan, setpoints_C=setpoints_C, voltmeter=voltmeter,
                                      bench=bench, chamber=chamber, settings=settings or CaptureSettings(),
                                      time_scale=float(time_scale), poll_s=float(poll_s),
                                      progress=progress, extra_metadata=extra_metadata)
    except FolderLocked as exc:
        raise CaptureError(str(exc)) from None
    except OSError as exc:
        storage_error(exc, out_dir)
        raise


def _capture_voltmeter(out_dir, *, plan, setpoints_C, voltmeter, bench, chamber, settings, time_scale, poll_s,
                       progress, extra_metadata) -> CaptureReport:
    from .drivers.dmm import DmmError

    wall0 = time.monotonic()
    out = Path(out_dir)
    (out / "raw").mkdir(parents=True, exist_ok=True)
    plan = {str(k): (float(v[0]), float(v[1])) for k, v in plan.items()}
    setpoints_C = [float(s) for s in setpoints_C]
    if not plan or not setpoints_C:
        raise InputError("a campaign needs at least one bench position and one setpoint")
    if not time_scale > 0:
        raise InputError(f"time_scale {time_scale!r}: must be positive")
    # the first setpoint's branch from the side the unit starts on: the chamber's PV now (a new campaign)
    start_C, start = start_temperature(out / STATE_NAME, chamber, setpoints_C)
    directions = Schedule(setpoints_C=setpoints_C, start_C=start_C).directions()
    commanded = getattr(bench, "commanded", None)
    if commanded is not None:
        for label, (a1, a2) in plan.items():
            try:
                commanded(a1, a2)
            except BenchError as exc:
                raise CaptureError(f"position {label} ({a1:g}, {a2:g}) of the plan: {exc}") from None
    labels = list(plan)
    total = len(labels) * len(setpoints_C)
    notify = progress or (lambda ev: None)
    n_per_window = voltmeter.samples_for(settings.tau_s)

    def clock() -> float:                          # instrument seconds
        return time.monotonic() * time_scale

    def pause(instrument_s: float) -> None:
        time.sleep(max(0.0, instrument_s) / time_scale)

    crit = settings.stabilisation
    stab_text = crit.describe().replace("every accelerometer temperature", "the chamber's PV")
    metadata = {
        "generator": f"triadcal {__version__} capture",
        "bench": settings.bench_name,
        **({} if settings.local_g_m_s2 is None else {"local_g_m_s2": repr(settings.local_g_m_s2)}),
        "output_unit": "V",
        "readout": f"voltmeter: {voltmeter.describe()}",
        "samples_per_window": f"{n_per_window} (SAMP:COUN = round(tau_s * mains_hz / NPLC), at least 2)",
        "unit_temperature": ANALOG_TEMPERATURE,
        "stabilisation": stab_text,
        "settle_s": f"{settings.settle_s:g}",
        **({"operator": settings.operator} if settings.operator else {}),
        **({} if start is None else {"start_C": start_text(start)}),
        **(extra_metadata or {}),
    }
    state_path = out / STATE_NAME
    state, rows, done_before, session = _open_session(out, state_path, plan, setpoints_C, directions, labels,
                                                      settings, metadata)
    if start is not None and "start_C" not in state:
        state["start_C"] = start
        atomic_write_json(state_path, state)
    metadata = dated_metadata(metadata, state)
    events = EventLog(out / EVENTS_NAME)
    events.write("session_start", session=session, visits_done=done_before, total=total,
                 stabilisation=stab_text, voltmeter=voltmeter.describe(), samples_per_window=n_per_window)
    last_end = max((r["time_s"] + r["tau_s"] / 2 for r in rows), default=0.0)
    c0 = clock()

    def campaign_time() -> float:
        return clock() - c0 + last_end

    redone = 0
    warnings: list = []
    try:
        notify({"event": "start", "done": done_before, "total": total})
        for k, (sp, direction) in enumerate(zip(setpoints_C, directions)):
            if (k + 1) * len(labels) <= len(rows):
                continue
            chamber.set_setpoint_C(sp)
            events.write("setpoint", index=k, setpoint_C=sp)
            temps: deque = deque()
            t_start = clock()
            stable_since = None
            while True:
                now = clock()
                pv = chamber_pv_C(chamber, sp)
                temps.append((now, (pv, pv, pv)))
                rate = _max_temperature_rate(temps, crit.window_s, now)
                if rate is not None and rate * 60.0 < crit.rate_C_per_min:
                    stable_since = now if stable_since is None else stable_since
                    if now - stable_since >= crit.hold_s:
                        break
                else:
                    stable_since = None
                if now - t_start > crit.timeout_s:
                    raise CaptureError(f"setpoint {sp:g} degC: not stable after {crit.timeout_s:g} s "
                                       f"({stab_text}); last rate "
                                       f"{'unknown' if rate is None else f'{rate * 60:.3g} degC/min'}")
                notify({"event": "soak", "done": len(rows), "total": total, "setpoint_C": sp,
                        "rate_C_per_min": None if rate is None else rate * 60.0, "chamber_C": pv})
                pause(poll_s)
            events.write("stable", index=k, setpoint_C=sp, after_s=clock() - t_start)
            # the chamber's PV is the only temperature here: it is checked against the setpoint, as the
            # IMU path checks it (a chamber stuck at 20 degC through a -15 degC setpoint went by with no
            # word, an outside probe)
            missed = setpoint_missed(sp, [], pv)
            if missed:
                events.write("setpoint_missed", index=k, setpoint_C=sp, text=missed)
                warnings.append(f"setpoint {sp:g} degC: {missed}")
            for j, label in enumerate(labels):
                if k * len(labels) + j < len(rows):
                    continue
                a1, a2 = plan[label]
                info = {"done": len(rows), "total": total, "setpoint_C": sp, "position": label}
                for attempt in range(1, settings.max_attempts + 1):
                    tag = f"s{k:03d}-{label}-{session}.{attempt}"
                    notify({"event": "move", **info})
                    bench.move_to(a1, a2)
                    t_move = clock()
                    while True:
                        try:
                            ready = bench.in_position()
                        except BenchControllerError:
                            raise
                        except BenchError as exc:
                            events.write("bench_error", text=str(exc))
                            ready = False
                        if ready:
                            break
                        if clock() - t_move > settings.move_timeout_s:
                            raise BenchError(f"bench did not reach ({a1}, {a2}) in {settings.move_timeout_s:g} s")
                        pause(poll_s)
                    pause(settings.settle_s)
                    notify({"event": "record", **info})
                    T0, t0 = chamber_pv_C(chamber, sp), campaign_time()
                    try:
                        avg = voltmeter.measure(n_per_window)
                    except DmmError as exc:
                        events.write("visit_incomplete", tag=tag, error=str(exc))
                        redone += 1
                        continue
                    T1, t1 = chamber_pv_C(chamber, sp), campaign_time()
                    break
                else:
                    raise CaptureError(f"position {label} at {sp:g} degC: the voltmeter failed "
                                       f"{settings.max_attempts} times (see {EVENTS_NAME})")
                T = 0.5 * (T0 + T1)
                # the event log is this path's raw record: the visit is on disk (fsync'd) before the
                # CSV row makes it count, as the IMU path syncs its samples first; a process killed
                # in between leaves an event that no row names, and the visit is made again
                events.write("visit", index=len(rows) + 1, tag=tag, n_samples=avg.n_samples,
                             w=avg.w.tolist(), sd=avg.sd.tolist(), chamber_C=[T0, T1])
                rows.append({"unit": settings.unit, "setpoint_C": sp, "direction": direction, "time_s": 0.5 * (t0 + t1),
                             "position": label, "axis1_deg": a1, "axis2_deg": a2, "tau_s": settings.tau_s,
                             "w": avg.w, "t": np.array([T, T, T]), "sd": avg.sd, "n_samples": avg.n_samples,
                             "raw_visit": tag})
                atomic_write_text(out / CSV_NAME, format_bench_csv(_campaign(rows, metadata)))
                notify({"event": "visit", "done": len(rows), "total": total, "setpoint_C": sp,
                        "position": label})
        notify({"event": "done", "done": len(rows), "total": total})
    finally:
        report = CaptureReport(
            out_dir=str(out), csv_path=str(out / CSV_NAME), session=session, visits_total=total,
            visits_done_before=done_before, visits_done=len(rows),
            accepted_samples=sum(int(r["n_samples"]) for r in rows[done_before:]),
            duplicate_frames=0, missing_frames=0, corrupted_frames=0, garbage_bytes=0, reconnects=0,
            disconnects=0, stalls=0, redone_visits=redone, noise=None, wall_seconds=time.monotonic() - wall0,
            warnings=warnings)
        events.write("session_end", **{k: v for k, v in report.to_dict().items() if k != "noise"})
        events.close()
        atomic_write_json(out / REPORT_NAME, report.to_dict())
    return report
