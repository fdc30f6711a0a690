"""Append-only raw storage: every accepted IMU sample, and an event log.

``imu_samples.csv`` gets one line per accepted frame, tagged with the capture session,
the phase of the campaign (``soak``, ``move``, ``settle``, ``record``, ``idle``) and the
visit it belongs to; nothing is ever rewritten. Lines are flushed to the OS at every
batch (so a killed process loses nothing) and fsync'd at least every
``sync_interval_s`` and always before a visit is declared complete (so a power cut
loses no sample of a completed visit). A torn last line (power cut mid-write) is
skipped by the reader, and the writer starts a fresh line after it.
"""

from __future__ import annotations

from ..errors import InputError, TriadcalError

import contextlib
import json
import os
import time
from pathlib import Path
from typing import Iterable, Optional

import numpy as np

from .protocols import Frame

RAW_COLUMNS = ("session", "seq", "time_s", "w_x", "w_y", "w_z", "t_x", "t_y", "t_z", "phase", "visit")


class RawStore:
    """Append-only CSV of accepted samples (see the module docstring)."""

    def __init__(self, path, sync_interval_s: float = 0.5):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.exists() or self.path.stat().st_size == 0
        torn = False
        if not new:
            with open(self.path, "rb") as fh:
                fh.seek(-1, os.SEEK_END)
                torn = fh.read(1) != b"\n"
        self._fh = open(self.path, "a", encoding="ascii", newline="")
        if new:
            self._fh.write(",".join(RAW_COLUMNS) + "\n")
        elif torn:
            self._fh.write("\n")
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


def read_raw(path) -> dict:
    """The raw samples as arrays by column (``w`` and ``t`` as (n, 3)); torn or malformed
    lines are skipped and counted in ``skipped_lines``."""
    cols = {c: [] for c in RAW_COLUMNS}
    skipped = 0
    with open(path, encoding="ascii", errors="replace") as fh:
        header = fh.readline().strip().split(",")
        if tuple(header) != RAW_COLUMNS:
            raise InputError(f"{path}: not a triadcal raw sample file (header {header})")
        for line in fh:
            parts = line.rstrip("\n").split(",")
            if not line.endswith("\n") or len(parts) != len(RAW_COLUMNS):
                skipped += 1
                continue
            try:
                vals = (int(parts[0]), int(parts[1])) + tuple(float(v) for v in parts[2:9])
            except ValueError:
                skipped += 1
                continue
            for c, v in zip(RAW_COLUMNS, vals + (parts[9], parts[10])):
                cols[c].append(v)
    out = {
        "session": np.array(cols["session"], int), "seq": np.array(cols["seq"], np.int64),
        "time_s": np.array(cols["time_s"], float),
        "w": np.array([cols["w_x"], cols["w_y"], cols["w_z"]], float).T.reshape(-1, 3),
        "t": np.array([cols["t_x"], cols["t_y"], cols["t_z"]], float).T.reshape(-1, 3),
        "phase": np.array(cols["phase"], dtype=object).astype(str),
        "visit": np.array(cols["visit"], dtype=object).astype(str),
        "skipped_lines": skipped,
    }
    return out


class EventLog:
    """Append-only JSON-lines log of what happened (commands, faults, reconnects)."""

    def __init__(self, path):
        self.path = Path(path)
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


def read_events(path) -> list[dict]:
    out = []
    if not Path(path).exists():
        return out
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            pass
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
