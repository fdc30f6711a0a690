"""The journal of a diagnosis validation: every finished row, appended as it comes, so that a run
stopped (killed, timed out, the machine down) resumes where it stopped.

``validate-diagnosis`` runs for up to an hour (1 920 diagnoses for the validation of record). Its
rows are written to ``OUT/rows.jsonl`` one by one -- a JSON line each, flushed and fsync'd -- after
a header line that holds the run's settings and a fingerprint of the code that made the rows
(:func:`code_fingerprint`: the package's source and the versions of numpy, scipy and casadi). A
second run into the same folder with the same settings and the same code takes the rows it finds
and runs only the others; with other settings or other code it is refused, naming the field that
differs (rows of two codes in one table would be a table of neither).

The reader validates what it reads: a line that is not JSON, a row without its job's fields, a
row of a job twice -- each an error naming the file and the line; only a last line without its
newline (a kill in the middle of the write) is dropped and cut off, and said so: that job runs
again.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Optional

from ..errors import InputError

FORMAT = "triadcal.diagnosis-validation.rows"
VERSION = 1
FILENAME = "rows.jsonl"


def code_fingerprint() -> str:
    """sha256 over the package's Python source (sorted relative paths and contents) and the versions
    of numpy, scipy and casadi: the code that makes a row."""
    import casadi
    import numpy
    import scipy

    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        h.update(p.relative_to(root).as_posix().encode() + b"\0")
        h.update(p.read_bytes() + b"\0")
    for mod in (numpy, scipy, casadi):
        h.update(f"{mod.__name__} {mod.__version__}\0".encode())
    return h.hexdigest()


def job_key(job: tuple) -> str:
    """A job's key in the journal: condition effect, seed and magnitude (the settings shared by all
    jobs are in the header)."""
    effect, seed, magnitude = job[0], int(job[1]), float(job[6])
    return f"{effect}|{seed}|{magnitude!r}"


def _plain(obj):
    """numpy scalars as Python numbers for the JSON line; anything else unknown is an error (a row is
    never written half)."""
    if hasattr(obj, "item") and callable(obj.item):
        return obj.item()
    raise TypeError(f"a validation row holds a {type(obj).__name__}, which the journal cannot write")


class Journal:
    """``OUT/rows.jsonl`` of a validation run with ``settings`` (module docstring). ``rows`` holds
    the rows read back, by :func:`job_key`; ``notes`` what the reader had to say (a torn last line)."""

    def __init__(self, folder, settings: dict, fingerprint: Optional[str] = None):
        self.path = Path(folder) / FILENAME
        self.header = {"format": FORMAT, "version": VERSION, "settings": dict(settings),
                       "code_sha256": fingerprint or code_fingerprint()}
        self.rows: dict = {}
        self.notes: list = []
        if self.path.exists() and self.path.stat().st_size > 0:
            self._read()
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(self.path, "w", encoding="utf-8") as fh:
                fh.write(json.dumps(self.header) + "\n")
                fh.flush()
                os.fsync(fh.fileno())
        self._fh = open(self.path, "a", encoding="utf-8")

    def _read(self) -> None:
        data = self.path.read_bytes()
        end = data.rfind(b"\n") + 1
        if end < len(data):
            # a kill in the middle of a write: the last line has no newline; cut it off, that job reruns
            n_line = data.count(b"\n") + 1
            self.notes.append(f"{self.path}: line {n_line} was cut off in the middle of its write "
                              f"({len(data) - end} bytes, no newline): dropped, that diagnosis runs again")
            with open(self.path, "r+b") as fh:
                fh.truncate(end)
                fh.flush()
                os.fsync(fh.fileno())
            data = data[:end]
        try:
            lines = data.decode("utf-8").splitlines()
        except UnicodeDecodeError as e:
            n_line = data[:e.start].count(b"\n") + 1
            raise InputError(f"{self.path}: line {n_line}: not UTF-8 text (byte {e.start})") from None
        if not lines:
            raise InputError(f"{self.path}: line 1: empty; a validation journal starts with its header")
        head = self._json(lines[0], 1)
        if not isinstance(head, dict) or head.get("format") != FORMAT:
            raise InputError(f"{self.path}: line 1: format {head.get('format') if isinstance(head, dict) else head!r}"
                             f" is not {FORMAT}: not a validation journal; choose another --out")
        if head.get("version") != VERSION:
            raise InputError(f"{self.path}: line 1: version {head.get('version')!r}, this triadcal reads {VERSION}")
        for field in ("settings", "code_sha256"):
            mine, theirs = self.header[field], head.get(field)
            if field == "settings":
                diff = sorted(k for k in set(mine) | set(theirs or {}) if (theirs or {}).get(k) != mine.get(k))
                if diff:
                    k = diff[0]
                    raise InputError(f"{self.path}: line 1: field settings.{k} is {(theirs or {}).get(k)!r} there and "
                                     f"{mine.get(k)!r} in this run: its rows are of another validation; remove the "
                                     "file or choose another --out")
            elif theirs != mine:
                raise InputError(f"{self.path}: line 1: field code_sha256 differs: its rows were made by other code "
                                 "(triadcal's source or numpy/scipy/casadi changed since); a table must be of one "
                                 "code -- remove the file or choose another --out")
        for i, line in enumerate(lines[1:], 2):
            rec = self._json(line, i)
            if not isinstance(rec, dict) or not isinstance(rec.get("job"), str) or not isinstance(rec.get("row"), dict):
                raise InputError(f"{self.path}: line {i}: a row line holds the fields 'job' (text) and 'row' "
                                 "(an object)")
            row = rec["row"]
            for f in ("condition", "seed", "magnitude", "verdict"):
                if f not in row:
                    raise InputError(f"{self.path}: line {i}: field row.{f} is missing")
            if rec["job"] in self.rows:
                raise InputError(f"{self.path}: line {i}: job {rec['job']} is there twice")
            self.rows[rec["job"]] = row

    def _json(self, line: str, i: int):
        try:
            return json.loads(line)          # NaN and Infinity, as json.dumps writes them, read back
        except json.JSONDecodeError as e:
            raise InputError(f"{self.path}: line {i}: not JSON ({e})") from None

    def append(self, key: str, row: dict) -> None:
        """Write one finished row (flushed and fsync'd before returning)."""
        self._fh.write(json.dumps({"job": key, "row": row}, default=_plain) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self.rows[key] = row

    def close(self) -> None:
        self._fh.close()


__all__ = ["FILENAME", "FORMAT", "Journal", "code_fingerprint", "job_key"]
