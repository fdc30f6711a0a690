"""Raw recordings: accelerometer samples at a stated rate, as CSV with named columns.

:func:`read_raw_csv` reads a recording (named columns, optional free header lines and
label column; the rate is always the user's, a disagreeing rate in the header is refused)
into a :class:`RawRecording`; :func:`read_intervals` reads an interval file (two-row or
two-column start/end CSV, imucal's session-list JSON). Derivation/design: docs/raw.md (Reading).
"""

from __future__ import annotations

from ..errors import InputError

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from .numbers import MAX_READING, NumberError, parse_number

#: accepted input units and the unit string of K (g per output unit) for each
INPUT_UNITS = {"m/s2": "g/(m/s2)", "g": "g/g", "counts": "g/count"}
DEFAULT_COLUMN_SETS = (("acc_x", "acc_y", "acc_z"), ("ax", "ay", "az"), ("x", "y", "z"))


class RawRecordingError(InputError):
    """Bad raw-recording input, located by file, line (1-based) and column where known."""

    def __init__(self, path: str, line: Optional[int], column: Optional[str], problem: str):
        self.path, self.line, self.column, self.problem = path, line, column, problem
        where = path + (f":{line}" if line else "") + (f": column '{column}'" if column else "")
        super().__init__(f"{where}: {problem}")


@dataclass
class RawRecording:
    """Accelerometer samples of one recording.

    ``acc`` (n, 3) in ``unit`` (``m/s2``, ``g`` or ``counts``), ``rate_hz`` as stated by the
    user, ``labels`` the label column (strings) when one was read, ``metadata`` the
    ``key,value`` header lines, ``first_line`` the file line of sample 0.
    """

    acc: np.ndarray
    rate_hz: float
    unit: str
    columns: tuple
    labels: Optional[np.ndarray] = None
    label_column: Optional[str] = None
    metadata: dict = field(default_factory=dict)
    source: str = "<memory>"
    first_line: int = 1
    #: the unit's temperature at each sample (degC), when a column of the file holds it
    temperature_C: Optional[np.ndarray] = None
    temperature_column: Optional[str] = None

    def __post_init__(self):
        self.acc = np.asarray(self.acc, float)
        if self.temperature_C is not None:
            self.temperature_C = np.asarray(self.temperature_C, float).reshape(-1)
            if len(self.temperature_C) != len(self.acc):
                raise InputError(f"{self.source}: {len(self.temperature_C)} temperatures for "
                                 f"{len(self.acc)} samples")
        if self.acc.ndim != 2 or self.acc.shape[1] != 3:
            raise InputError(f"{self.source}: samples must have shape (n, 3), got {self.acc.shape}")
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise InputError(f"{self.source}: the sample rate must be a positive number of Hz, got {self.rate_hz}")
        if self.unit not in INPUT_UNITS:
            raise InputError(f"{self.source}: unknown input unit {self.unit!r}; use one of {', '.join(INPUT_UNITS)}")

    @property
    def n(self) -> int:
        return len(self.acc)

    @property
    def time_s(self) -> np.ndarray:
        """Time of each sample since the first one, from the stated rate."""
        return np.arange(self.n) / self.rate_hz

    @property
    def scale_unit(self) -> str:
        """Unit of the scale factor K (eq. 1: K W = Ca G + S, g per output unit)."""
        return INPUT_UNITS[self.unit]


#: field separators a recording may use; the header line decides which
DELIMITERS = (",", "\t", ";")


def read_raw_csv(path, rate_hz: float, columns: Optional[Sequence[str]] = None, unit: str = "counts",
                 label_column: Optional[str] = None, temperature_column: Optional[str] = None) -> RawRecording:
    """Read a raw recording (``triadcal fit-raw``).

    The header row is the first line that names all of ``columns`` (default: the first
    of ``acc_x,acc_y,acc_z`` / ``ax,ay,az`` / ``x,y,z`` found), separated by commas, tabs or
    semicolons (the header decides, the rows must follow it); lines before it are kept as
    metadata when they read ``key,value``. Every sample must be a finite number: a bad
    field is refused with its line and column, nothing is dropped. ``temperature_column``
    (degC, optional) is read with the same rules into ``temperature_C``.
    """
    path = str(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)                 # the header is within the first 200 lines
    except OSError as exc:
        raise RawRecordingError(path, None, None, f"cannot be read ({exc.strerror or exc})") from None
    bom = 3 if head.startswith(b"\xef\xbb\xbf") else 0
    lines = head[bom:].decode("utf-8", errors="replace").splitlines()
    if len(head) == 1 << 16:
        lines = lines[:-1]                          # the last line of the chunk may be cut
    wanted = [tuple(columns)] if columns else list(DEFAULT_COLUMN_SETS)
    header_at, header, cols, delim = None, None, None, ","
    for k, line in enumerate(lines[:200]):
        for sep in DELIMITERS:                      # the header line decides the separator
            fields = [f.strip() for f in next(csv.reader([line], delimiter=sep), [])]
            for cand in wanted:
                if all(c in fields for c in cand):
                    header_at, header, cols, delim = k, fields, tuple(cand), sep
                    break
            if header_at is not None:
                break
        if header_at is not None:
            break
    if header_at is None:
        raise RawRecordingError(path, None, None,
                                "no header line naming the columns " + " or ".join(",".join(c) for c in wanted)
                                + " in the first 200 lines (give --columns)")
    if label_column is not None and label_column not in header:
        raise RawRecordingError(path, header_at + 1, label_column,
                                f"label column not in the header (columns: {', '.join(header)})")
    if temperature_column is not None and temperature_column not in header:
        raise RawRecordingError(path, header_at + 1, temperature_column,
                                f"temperature column not in the header (columns: {', '.join(header)})")
    metadata = {}
    for line in lines[:header_at]:
        parts = [p.strip() for p in line.split(",")]
        if len(parts) >= 2 and parts[0]:
            metadata[parts[0]] = parts[1]
    file_rate = metadata.get("Fs") or metadata.get("rate_hz") or metadata.get("sample_rate_hz")
    if file_rate is not None:
        try:
            fr = float(file_rate)
        except ValueError:
            fr = None
        if fr is not None and abs(fr - rate_hz) > 1e-6 * rate_hz:
            raise RawRecordingError(path, None, None,
                                    f"the stated rate {rate_hz:g} Hz disagrees with the file's header ({fr:g} Hz); "
                                    "check which one is right (imucal issue #25)")
    offset = _line_start(path, header_at, bom)
    read = cols + ((temperature_column,) if temperature_column is not None else ())
    acc, labels = _read_samples_fast(path, offset, header_at, header, read, label_column, delim)
    temp = acc[:, 3] if temperature_column is not None else None
    return RawRecording(acc[:, :3], float(rate_hz), unit, cols, labels, label_column, metadata, path,
                        header_at + 2, temp, temperature_column)


def _line_start(path, k: int, bom: int) -> int:
    """Byte offset of line ``k`` (0-based) of the file (after a BOM)."""
    with open(path, "rb") as fh:
        fh.seek(bom)
        for _ in range(k):
            fh.readline()
        return fh.tell()


def _all_lines(path) -> list:
    try:
        return Path(path).read_text(encoding="utf-8-sig").splitlines()
    except UnicodeDecodeError as exc:
        raise RawRecordingError(path, None, None, f"not UTF-8 text (byte {exc.start})") from None


def _read_samples_fast(path, offset, header_at, header, cols, label_column, delim=","):
    """The samples with pyarrow's multi-threaded CSV reader (typed float64 columns, only the
    columns needed); any problem (a field that is not a number, a wrong field count, a value
    not finite or beyond :data:`~triadcal.io.numbers.MAX_READING`) sends the file through
    :func:`_read_samples_slow`, which names the line and the column."""
    import pyarrow as pa
    from pyarrow import csv as pacsv

    want = list(cols) + ([label_column] if label_column else [])
    slow = lambda: _read_samples_slow(path, _all_lines(path), header_at, header, cols, label_column,  # noqa: E731
                                      delim)
    cols_out = {c: [] for c in want}
    try:
        with open(path, "rb") as source:
            source.seek(offset)
            reader = pacsv.open_csv(
                source,
                read_options=pacsv.ReadOptions(use_threads=True, block_size=1 << 22),
                parse_options=pacsv.ParseOptions(delimiter=delim, newlines_in_values=False),
                convert_options=pacsv.ConvertOptions(
                    include_columns=want, column_types={c: pa.float64() for c in cols},
                    strings_can_be_null=False, quoted_strings_can_be_null=False),
                memory_pool=pa.system_memory_pool())   # freed buffers go back to the system at once
            # streamed batch by batch, each copied out as one (n, 3) block and released: peak
            # memory is the samples about twice, not the parser's buffers too
            for batch in reader:
                cols_out[cols[0]].append(np.column_stack([batch.column(c).to_numpy(zero_copy_only=False)
                                                          for c in cols]))
                if label_column:
                    cols_out[label_column].append(batch.column(label_column).to_pylist())
                del batch
    except (pa.ArrowInvalid, pa.ArrowKeyError, KeyError):
        return slow()
    blocks = cols_out[cols[0]]
    acc = np.empty((sum(len(b) for b in blocks), len(cols)))
    k = 0
    while blocks:
        b = blocks.pop(0)
        acc[k:k + len(b)] = b
        k += len(b)
    if not len(acc) or not np.all(np.isfinite(acc)) or np.max(np.abs(acc)) > MAX_READING:
        return slow()
    labels = None
    if label_column:
        labels = np.array([str(v).strip() for b in cols_out[label_column] for v in b])
    return acc, labels


def _read_samples_slow(path, lines, header_at, header, cols, label_column, delim=","):
    """Line by line with one number parser (:func:`~triadcal.io.numbers.parse_number`): the
    first bad field is refused with its line and column."""
    idx = [header.index(c) for c in cols]
    li = header.index(label_column) if label_column else None
    acc, labels = [], []
    for k in range(header_at + 1, len(lines)):
        line = lines[k]
        if not line.strip():
            continue
        row = next(csv.reader([line], delimiter=delim))
        if len(row) != len(header):
            raise RawRecordingError(path, k + 1, header[len(row)] if len(row) < len(header) else None,
                                    f"{len(row)} fields, the header has {len(header)}")
        vals = []
        for c, i in zip(cols, idx):
            try:
                vals.append(parse_number(row[i], low=-MAX_READING, high=MAX_READING, what=c))
            except NumberError as exc:
                raise RawRecordingError(path, k + 1, c, exc.problem) from None
        acc.append(vals)
        if li is not None:
            labels.append(row[li].strip())
    if not acc:
        raise RawRecordingError(path, header_at + 1, None, "no samples after the header")
    return np.array(acc), (np.array(labels) if li is not None else None)


def check_declared_unit(rec: "RawRecording", w_means: np.ndarray, local_g_m_s2: float) -> None:
    """Refuse readings whose magnitude contradicts the declared unit: for ``g`` and ``m/s2`` the
    median norm of the static means must lie within a factor 1.5 of the local gravity in that
    unit (counts are the instrument's own; the answer gates check their K band)."""
    if rec.unit not in ("g", "m/s2") or not len(w_means):
        return
    expected = local_g_m_s2 / 9.80665 if rec.unit == "g" else local_g_m_s2
    med = float(np.median(np.linalg.norm(w_means, axis=1)))
    ratio = med / expected
    if not 1 / 1.5 <= ratio <= 1.5:
        raise RawRecordingError(rec.source, None, None,
                                f"the readings contradict --unit {rec.unit}: the median |a| of the static "
                                f"intervals is {med:.6g} {rec.unit}, gravity is {expected:.6g} {rec.unit} "
                                f"(ratio {ratio:.3g}); state the unit the readings are in (counts, g, m/s2)")


@dataclass
class IntervalSpec:
    """Sample ranges ``[start, end)`` (row indices of the samples), with labels where known."""

    start: np.ndarray
    end: np.ndarray
    labels: Optional[list] = None
    source: str = "<memory>"


def read_intervals(path) -> IntervalSpec:
    """Static intervals from a file: imucal's session-list JSON (labelled sample ranges), a
    two-row CSV of starts and ends (tomisuarez2), or a two-column ``start,end`` CSV."""
    path = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise RawRecordingError(path, None, None, f"not UTF-8 text (byte {exc.start})") from None
    if text.lstrip().startswith("{"):
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise RawRecordingError(path, exc.lineno, None, f"not valid JSON: {exc.msg}") from None
        labels, s, e = [], [], []
        for k, v in d.items():
            if not (isinstance(v, dict) and "start" in v and "end" in v):
                raise RawRecordingError(path, None, k, "each entry must be {\"start\": ..., \"end\": ...}")
            labels.append(k)
            for key, out in (("start", s), ("end", e)):
                try:
                    out.append(parse_number(v[key], low=0, high=MAX_READING, integer=True, what=key))
                except NumberError as exc:
                    raise RawRecordingError(path, None, f"{k}.{key}", exc.problem) from None
        return _checked(IntervalSpec(np.array(s), np.array(e), labels, path))
    rows = []
    for k, line in enumerate(text.splitlines()):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        try:
            rows.append([parse_number(f, low=0, high=MAX_READING, what="sample index") for f in fields])
        except NumberError as exc:
            if not rows and k == 0 and not any(c.isdigit() for c in line):
                continue  # a header row such as "start,end"
            raise RawRecordingError(path, k + 1, None, f"{exc.problem} in {line!r}") from None
    if len(rows) == 2 and len(rows[0]) == len(rows[1]) and len(rows[0]) != 2:
        s, e = np.array(rows[0]), np.array(rows[1])
    elif rows and all(len(r) == 2 for r in rows):
        arr = np.array(rows)
        if len(rows) == 2 and arr[0, 1] > arr[1, 0]:
            # ambiguous 2x2: two rows (starts; ends) as tomisuarez2 writes them
            s, e = arr[0], arr[1]
        else:
            s, e = arr[:, 0], arr[:, 1]
    else:
        raise RawRecordingError(path, None, None,
                                "expected two rows (starts; ends) or two columns (start,end) of sample indices")
    if np.any(s != np.round(s)) or np.any(e != np.round(e)):
        raise RawRecordingError(path, None, None, "interval limits must be whole sample indices")
    return _checked(IntervalSpec(s.astype(int), e.astype(int), None, path))


def _checked(spec: IntervalSpec) -> IntervalSpec:
    bad = np.flatnonzero(spec.end <= spec.start)
    if len(bad):
        raise RawRecordingError(spec.source, None, None,
                                f"interval {int(bad[0]) + 1} ends ({spec.end[bad[0]]}) before it starts ({spec.start[bad[0]]})")
    return spec
