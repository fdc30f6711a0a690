"""Append-only raw storage: every accepted IMU sample, and an event log.

``imu_samples.csv`` gets one line per accepted frame, tagged with the capture session,
the phase of the campaign (``soak``, ``move``, ``settle``, ``record``, ``idle``) and the
visit it belongs to; nothing is ever rewritten. Lines are flushed to the OS at every
batch (so a killed process loses nothing) and fsync'd at least every
``sync_interval_s`` and always before a visit is declared complete (so a power cut
loses no sample of a completed visit).

A torn line (a kill or a power cut in the middle of a write) can only be the last line of
the file. The readers tolerate it there and report it (``torn_lines``); any other line that
does not read is refused with :class:`~triadcal.errors.InputError` naming the file, the line
and the field. A writer that reopens a file ending in a torn line never overwrites it: it
ends it with a mark (``#torn`` in the raw samples, a ``torn_line`` record naming it in the
event log) and starts on a fresh line, so the readers know the torn line in the middle of a
resumed file for what it is, and never glue it onto the next line or read a torn prefix of
a sample (``0.12`` of ``0.1234``) as a sample.
"""

from __future__ import annotations

from ..errors import InputError, TriadcalError

import contextlib
import json
import math
import os
import time
from pathlib import Path
from typing import Iterable, Optional

import numpy as np

from .protocols import Frame

RAW_COLUMNS = ("session", "seq", "time_s", "w_x", "w_y", "w_z", "t_x", "t_y", "t_z", "phase", "visit")
#: the phases a raw sample line may carry (the capture's, see the module docstring)
RAW_PHASES = ("soak", "move", "settle", "record", "idle")
#: what :class:`RawStore` appends to a torn last line it finds on opening, before its own lines
TORN_MARK = "#torn"
_RAW_HEADER = ",".join(RAW_COLUMNS)


class RawStore:
    """Append-only CSV of accepted samples (see the module docstring)."""

    def __init__(self, path, sync_interval_s: float = 0.5):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.exists() or self.path.stat().st_size == 0
        torn = torn_header = False
        if not new:
            with open(self.path, "rb") as fh:
                torn_header = b"\n" not in fh.read(4096)      # killed while writing the header
                fh.seek(-1, os.SEEK_END)
                torn = fh.read(1) != b"\n"
        self._fh = open(self.path, "a", encoding="ascii", newline="")
        if new:
            self._fh.write(_RAW_HEADER + "\n")
        elif torn:
            # end the torn line with the mark (one write): the reader skips it and counts it, and
            # a kill in the middle of this write leaves a torn last line again, marked next time
            self._fh.write(TORN_MARK + "\n" + (_RAW_HEADER + "\n" if torn_header else ""))
        self.torn_marked = bool(torn)     # a torn last line found and marked (the capture logs it)
        self.sync_interval_s = sync_interval_s
        self._last_sync = time.monotonic()
        self.rows_written = 0
        self.sync()

    def append(self, frames: Iterable[Frame], session: int, phase: str, visit: str = "") -> None:
        lines = [f"{session},{f.seq},{f.time_s!r},{f.w[0]!r},{f.w[1]!r},{f.w[2]!r},"
                 f"{f.t[0]!r},{f.t[1]!r},{f.t[2]!r},{phase},{visit}\n" for f in frames]
        self._fh.write("".join(lines))
        self._fh.flush()
        self.rows_written += len(lines)
        if time.monotonic() - self._last_sync >= self.sync_interval_s:
            self.sync()

    def sync(self) -> None:
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self._last_sync = time.monotonic()

    def close(self) -> None:
        if not self._fh.closed:
            self.sync()
            self._fh.close()


def _raw_values(parts: list) -> tuple:
    """The values of one raw sample line split at commas; ValueError(field, reason) when not."""
    try:
        vals = (int(parts[0]), int(parts[1])) + tuple(float(v) for v in parts[2:9]) + (parts[9], parts[10])
    except (ValueError, IndexError):
        vals = None
    # a temperature may be nan (an IMU output without one); nothing else may be non-finite
    if (vals is not None and len(parts) == len(RAW_COLUMNS) and parts[9] in RAW_PHASES
            and all(map(math.isfinite, vals[2:6])) and all(math.isfinite(v) or math.isnan(v) for v in vals[6:9])):
        return vals
    # not a sample: say which field
    if len(parts) != len(RAW_COLUMNS):
        raise ValueError("line", f"has {len(parts)} fields where a sample has {len(RAW_COLUMNS)} "
                                 f"({_RAW_HEADER})")
    for name, text in zip(RAW_COLUMNS[:2], parts[:2]):
        try:
            int(text)
        except ValueError:
            raise ValueError(name, f"{text!r} is not an integer") from None
    for name, text in zip(RAW_COLUMNS[2:9], parts[2:9]):
        try:
            v = float(text)
        except ValueError:
            raise ValueError(name, f"{text!r} is not a number") from None
        if not math.isfinite(v) and not (name.startswith("t_") and math.isnan(v)):
            raise ValueError(name, f"{text!r} is not a finite number")
    raise ValueError("phase", f"{parts[9]!r} is not one of {', '.join(RAW_PHASES)}")


def _starts_a_later_session(line: bytes, session) -> bool:
    """Whether ``line`` is a sample of a session after ``session`` (of the last sample read)."""
    if session is None:
        return False
    try:
        return _raw_values(line.rstrip(b"\n").decode("ascii", "replace").split(","))[0] > session
    except ValueError:
        return False


def read_raw(path) -> dict:
    """The raw samples as arrays by column (``w`` and ``t`` as (n, 3)).

    Torn lines (see the module docstring) are skipped and reported: ``torn_lines`` lists their
    line numbers (1 = the header), ``skipped_lines`` counts them. A torn line is the last line
    when it has no newline or does not read, any line ended with the writer's ``#torn`` mark,
    or a line that does not read followed by the first sample of a later session (the end of a
    killed session, ended by a writer of before the mark). Any other line that does not read
    raises :class:`InputError` naming the file, the line and the field."""
    cols = {c: [] for c in RAW_COLUMNS}
    torn: list[int] = []
    mark = TORN_MARK.encode("ascii")
    try:
        fh = open(path, "rb")
    except OSError as exc:
        raise InputError(f"{path}: cannot read the raw samples: {exc.strerror or exc}") from None
    with fh:
        n = 1
        first = fh.readline().decode("ascii", "replace")
        while first.endswith(TORN_MARK + "\n"):
            torn.append(n)           # a header torn at creation, ended by the writer that reopened it
            n += 1
            first = fh.readline().decode("ascii", "replace")
        if first and not first.endswith("\n") and _RAW_HEADER.startswith(first):
            torn.append(n)           # killed while writing the header: no samples yet
            first = _RAW_HEADER + "\n"
        if first.rstrip("\n") != _RAW_HEADER:
            raise InputError(f"{path} line {n}: not a triadcal raw sample file (header {first.rstrip()!r}, "
                             f"expected {_RAW_HEADER!r})")
        line = fh.readline()
        session = None               # of the last sample read
        while line:
            n += 1
            following = fh.readline()
            ended = line.endswith(b"\n")
            body = line[:-1] if ended else line
            if body.endswith(mark) or (not following and not ended):
                torn.append(n)
            else:
                try:
                    vals = _raw_values(body.decode("ascii", "replace").split(","))
                except ValueError as exc:
                    if following and not _starts_a_later_session(following, session):
                        field, why = exc.args
                        raise InputError(f"{path} line {n}: " + (why if field == "line" else f"{field} {why}")) \
                            from None
                    # the last line of a writer killed mid-line; or the last line of a session,
                    # ended by a resumed writer of before the mark (a bare newline)
                    torn.append(n)
                else:
                    for c, v in zip(RAW_COLUMNS, vals):
                        cols[c].append(v)
                    session = vals[0]
            line = following
    out = {
        "session": np.array(cols["session"], int), "seq": np.array(cols["seq"], np.int64),
        "time_s": np.array(cols["time_s"], float),
        "w": np.array([cols["w_x"], cols["w_y"], cols["w_z"]], float).T.reshape(-1, 3),
        "t": np.array([cols["t_x"], cols["t_y"], cols["t_z"]], float).T.reshape(-1, 3),
        "phase": np.array(cols["phase"], dtype=object).astype(str),
        "visit": np.array(cols["visit"], dtype=object).astype(str),
        "skipped_lines": len(torn),
        "torn_lines": torn,
    }
    return out


class EventLog:
    """Append-only JSON-lines log of what happened (commands, faults, reconnects)."""

    def __init__(self, path):
        self.path = Path(path)
        # a log reopened by a resumed capture is read first: a line that is no record anywhere but
        # a torn one is refused now, naming the line, not after this session appended to it
        # (read_events would refuse the whole log at the next resume or report)
        read_events(self.path)
        torn = self._torn_tail()
        self._fh = open(self.path, "a", encoding="utf-8")
        if torn is not None:
            # a kill in the middle of a write left a last line without its newline: end it there,
            # so this session's records start on lines of their own, and say so
            self._fh.write("\n")
            self.write("torn_line", line=torn[0], n_bytes=torn[1])

    def _torn_tail(self):
        """(line number, bytes) of a last line that has no newline, or None."""
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return None
        if not data or data.endswith(b"\n"):
            return None
        return data.count(b"\n") + 1, len(data) - (data.rfind(b"\n") + 1)

    def write(self, kind: str, **fields) -> None:
        rec = {"wall_time": time.time(), "kind": kind, **fields}
        self._fh.write(json.dumps(rec, default=float) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._fh.close()


class EventRecords(list):
    """The records of an event log (a list of dicts); ``torn_lines`` the line numbers of its
    torn lines (see the module docstring), skipped."""

    torn_lines: list


def _event_record(raw: bytes):
    """The record of one event-log line, or the reason it is not one."""
    try:
        rec = json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        return None, f"not UTF-8 text ({exc.reason} at byte {exc.start})"
    except json.JSONDecodeError as exc:
        return None, f"not a JSON record ({exc.msg} at column {exc.colno})"
    if not isinstance(rec, dict):
        return None, f"not a JSON object but {type(rec).__name__} {raw[:40].decode('utf-8', 'replace')!r}"
    if not isinstance(rec.get("kind"), str):
        return None, f"field 'kind' is {'missing' if 'kind' not in rec else repr(rec['kind'])}, not a string"
    return rec, None


def read_events(path) -> EventRecords:
    """The event log's records in order (none when the file does not exist).

    A torn line (see the module docstring) is skipped and its line number listed in the
    result's ``torn_lines``: the last line when it does not read, or a line the writer marked
    by the ``torn_line`` record right after it when it reopened the log. Any other line that is
    not a JSON object with a ``kind`` raises :class:`InputError` naming the file and the line."""
    out = EventRecords()
    out.torn_lines = []
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return out
    except OSError as exc:
        raise InputError(f"{path}: cannot read the event log: {exc.strerror or exc}") from None
    lines = data.split(b"\n")
    if lines[-1] == b"":
        lines.pop()                  # the newline of the last line
    parsed = [_event_record(raw) for raw in lines]
    for i, (rec, why) in enumerate(parsed):
        n = i + 1
        if rec is not None:
            out.append(rec)
            continue
        nxt = parsed[i + 1][0] if i + 1 < len(parsed) else None
        if i == len(parsed) - 1 or (nxt is not None and nxt["kind"] == "torn_line" and nxt.get("line") == n):
            out.torn_lines.append(n)
            continue
        raise InputError(f"{path} line {n}: {why}")
    return out


def optional_float(v) -> Optional[float]:
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


class FolderLocked(TriadcalError, RuntimeError):
    """Another process holds the folder's lock (the message names it)."""


@contextlib.contextmanager
def folder_lock(folder, what: str = "capture"):
    """An exclusive lock on ``folder`` for the time of the block: ``fcntl.flock`` on
    ``folder/.lock``, which records the holder (pid, host, start time). A second holder is
    refused at once with :class:`FolderLocked` naming the first; the kernel releases the lock
    when its process ends, however it ends, so a lock file left by a dead process does not
    block (its recorded holder is simply overwritten)."""
    import fcntl
    import socket

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / ".lock"
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 4096, 0).decode("utf-8", "replace").strip() or "an unknown process"
            raise FolderLocked(f"{folder} is in use by another {what}: {holder}; wait for it to finish or "
                               "choose another folder") from None
        stamp = time.strftime("%Y-%m-%dT%H:%M:%S%z")
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{what} pid {os.getpid()} on host {socket.gethostname()} since {stamp}\n".encode(), 0)
        os.fsync(fd)
        try:
            yield path
        finally:
            os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)
