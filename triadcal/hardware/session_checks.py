"""Checks of a capture session that are not the frame pump's (runner.py): a resume with the
header's settings unchanged, a full or read-only disk said as such, a setpoint the chamber did not
reach. Used by the stepped, ramp and voltmeter captures (docs/hardware.md, "Faults")."""

from __future__ import annotations

import errno
import math
from typing import Optional

import numpy as np

from .runner import CaptureError


#: metadata of a campaign's header that may change from one session to the next (they describe
#: the run, not the data: every other key describes the rows already captured)
SESSION_METADATA = ("generator", "date", "operator")


def check_session_metadata(state: dict, metadata: dict, out, header: Optional[dict] = None) -> None:
    """Record the header's metadata in the capture state at the first session; at a resume,
    refuse one that differs (but for :data:`SESSION_METADATA`), naming the key: the header is
    rewritten at every visit, so a resume with ``--local-g 9.78`` relabelled the visits captured
    at 9.80665 (K_x 2 700 ppm off, 300 U, status ok), and one with another IMU output unit would
    label volts as g (an outside probe). ``header``: the metadata of the campaign.csv already
    written, compared key by key too (a state written before this check holds no metadata)."""
    keep = {k: str(v) for k, v in metadata.items() if k not in SESSION_METADATA}
    before = state.get("metadata")

    def said(v):
        return "not stated" if v is None else repr(v)

    changed = []
    if before is not None:
        changed = [f"{k} = {said(before.get(k))} in the captured rows, now {said(keep.get(k))}"
                   for k in sorted(set(before) | set(keep)) if before.get(k) != keep.get(k)]
    elif header:
        changed = [f"{k} = {said(header.get(k))} in the captured rows, now {said(v)}" for k, v in sorted(keep.items())
                   if header.get(k) is None or str(header.get(k)) != v]
    if changed:
        raise CaptureError(f"{out} holds visits captured with other settings ({'; '.join(changed)}): the header "
                           "describes every row, so a resume must use the same ones (or choose another --out)")
    state["metadata"] = keep


def dated_metadata(metadata: dict, state: dict) -> dict:
    """``metadata`` with the ``date`` the data were taken (UTC, of the first session: the
    calibration date a certificate states) after its ``generator``."""
    import time

    rest = dict(metadata)
    first_start = state["sessions"][0]["started_wall"]
    return {"generator": rest.pop("generator"), "date": time.strftime("%Y-%m-%d", time.gmtime(first_start)), **rest}


#: errors of the disk, not of an instrument
STORAGE_ERRNOS = {errno.ENOSPC, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EDQUOT, errno.EIO}


def storage_error(exc: OSError, out_dir) -> None:
    """Raise :class:`CaptureError` for an ``OSError`` of the disk (full, file too large, read-only,
    no permission): a full disk ended in "internal error (a bug: please report it)" with no word
    that the visits on disk were kept (an outside probe). Every visit that counts was fsync'd
    before it counted, so the same command resumes once there is room."""
    if exc.errno in STORAGE_ERRNOS:
        raise CaptureError(f"cannot write into {out_dir}: {exc.strerror or exc} "
                           f"({exc.filename or 'a capture file'}); the visits done are on disk: free space or fix "
                           "the permission, then run the same command again to resume") from None


#: a chamber whose PV is this far (degC) from its setpoint once the unit is stable has not reached it
#: (a chamber controls to +-0.5 degC or better; its PV is its own sensor, next to the air it controls)
CHAMBER_MISS_C = 2.0
#: the unit's temperature sensors this far (degC) from the setpoint: beyond any self-heating or
#: gradient of a fixture in a working chamber (a few degC)
UNIT_MISS_C = 10.0
#: the chamber's PV and the unit's sensors this far apart (degC) once the unit is stable: more than a
#: unit's self-heating (a few degC); a PV that reads its setpoint while the air and the unit do not
#: (an outside probe: PV 30.0, unit 23.0, no word: neither was 2 degC from the setpoint's PV check or
#: 10 from the unit's)
PV_UNIT_APART_C = 5.0


def is_temperature_C(value: float) -> bool:
    """A chamber's PV that is a temperature: finite, between absolute zero and 300 degC (a Modbus
    controller's sensor break reads 0x8000, -3276.8 degC)."""
    return math.isfinite(value) and -273.15 <= value <= 300.0


def setpoint_missed(sp: float, unit_temps, chamber_C) -> Optional[str]:
    """Why a setpoint counts as not reached once the unit is stable, or None: the chamber's PV
    more than :data:`CHAMBER_MISS_C` from it, or not a temperature (a sensor break reads
    -3276.8 degC on a Modbus controller), or the unit's sensors more than :data:`UNIT_MISS_C` from
    it. The visits are still valid data (the fit uses the temperatures measured, not the
    setpoint), so the capture goes on and says so in its report's ``warnings`` and the event log:
    a chamber stuck at 70 degC through setpoints 20, 70, -40 went by with no word (an outside
    probe)."""
    out = []
    if chamber_C is not None:
        if not is_temperature_C(chamber_C):
            out.append(f"the chamber's PV reads {chamber_C!r} degC, not a temperature (a sensor break?)")
        elif abs(chamber_C - sp) > CHAMBER_MISS_C:
            out.append(f"the chamber's PV is {chamber_C:.2f} degC, {chamber_C - sp:+.2f} degC from the setpoint "
                       f"(more than {CHAMBER_MISS_C:g})")
    T = np.asarray(unit_temps, float).reshape(-1, 3) if len(unit_temps) else np.empty((0, 3))
    if len(T) and np.all(np.isfinite(T)):
        mean = float(T.mean())
        if abs(mean - sp) > UNIT_MISS_C:
            out.append(f"the unit's temperature is {mean:.2f} degC, {mean - sp:+.2f} degC from the setpoint "
                       f"(more than {UNIT_MISS_C:g})")
        if chamber_C is not None and is_temperature_C(chamber_C) and abs(chamber_C - mean) > PV_UNIT_APART_C:
            out.append(f"the chamber's PV reads {chamber_C:.2f} degC and the unit's sensors {mean:.2f} degC, "
                       f"{abs(chamber_C - mean):.2f} degC apart (more than {PV_UNIT_APART_C:g}, beyond a unit's "
                       "self-heating): a PV that does not measure the air the unit is in (one that reads its "
                       "setpoint?), or the unit's sensors off")
    return "; ".join(out) or None


#: the temperature a unit is assumed to have soaked at when the chamber's PV cannot be read at the start
#: (the simulator's and the emulator's ambient, ``Schedule.start_C``)
ASSUMED_START_C = 20.0
#: a chamber PV within this of the first setpoint at the start: no move to speak of, the unit's history
#: unknown, so the first setpoint is the hysteresis mid-line (``none``), as at the assumed ambient
START_SAME_C = 0.5


def start_temperature(state_path, chamber, setpoints_C) -> tuple[float, Optional[dict]]:
    """The temperature the unit starts from, whose side of the first setpoint gives that setpoint's
    hysteresis branch (:meth:`~triadcal.models.simulate.Schedule.directions`), and the record
    ``{"value", "source"}`` kept in the state file and the header's ``start_C`` (None for a campaign
    begun before it was recorded: resumed on the old rule, the assumed 20 degC).

    A new campaign reads the chamber's PV before the first setpoint is written: a chamber left at
    60 degC with a first setpoint of 30 takes the unit down to it, the cooling branch; the capture
    labelled it from an assumed 20 degC, heating (the session of 2026-12-01 left this open). Within
    ``START_SAME_C`` of the first setpoint the start is the setpoint itself (``none``); a PV that is
    not a temperature leaves ``ASSUMED_START_C``, said in the header. A resumed campaign takes the
    record of its state file, so its rows keep their labels."""
    from ..io.atomic import read_json

    try:
        prior = read_json(state_path) if state_path.exists() else None
    except ValueError:
        prior = None                   # the session's own reader says what is wrong with the file
    if isinstance(prior, dict) and prior.get("sessions"):
        start = prior.get("start_C")
        if not (isinstance(start, dict) and _number(start.get("value")) and is_temperature_C(start["value"])):
            return ASSUMED_START_C, None
        return float(start["value"]), {"value": float(start["value"]), "source": str(start.get("source", ""))}
    try:
        pv = chamber.temperature_C()
    except Exception as exc:           # noqa: BLE001 - any driver failure: the start is assumed, and said
        pv, why = None, f"{type(exc).__name__}: {exc}"
    else:
        why = f"it read {pv!r}"
    if not (_number(pv) and is_temperature_C(float(pv))):
        start = {"value": ASSUMED_START_C, "source": f"assumed: the chamber's PV was not a temperature ({why})"}
    else:
        pv = float(pv)
        value = float(setpoints_C[0]) if abs(pv - float(setpoints_C[0])) <= START_SAME_C else pv
        start = {"value": value, "source": f"the chamber's PV before the first setpoint, {pv:.2f} degC"
                 + (f", within {START_SAME_C:g} degC of it: the mid-line" if value != pv else "")}
    return start["value"], start


def _number(v) -> bool:
    return isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool)


def start_text(start: dict) -> str:
    """The header's ``start_C``: the value and where it comes from."""
    return f"{start['value']:.2f} ({start['source']})"
