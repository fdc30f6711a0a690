"""Raw recordings: accelerometer samples at a stated rate, as CSV with named columns.

:func:`read_raw_csv` reads a recording (named columns, optional free header lines and
label column; the rate is always the user's, a disagreeing rate in the header is refused)
into a :class:`RawRecording`; :func:`read_intervals` reads an interval file (two-row or
two-column start/end CSV, imucal's session-list JSON). Derivation/design: docs/raw.md (Reading).
"""

from __future__ import annotations

from ..errors import InputError
from .atomic import _DuplicateKey, _unique_keys

import csv
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..models.units import scale_factor_unit
from .numbers import MAX_READING, NumberError, parse_number

#: accepted input units and the unit string of K (g per output unit) for each
INPUT_UNITS = {u: scale_factor_unit(u) for u in ("m/s2", "g", "mg", "counts")}
#: input units fixed by physics: readings per g of standard gravity
PER_G = {"m/s2": 9.80665, "g": 1.0, "mg": 1000.0}
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
    if head[:2] in (b"\xff\xfe", b"\xfe\xff") or (len(head) > 64 and head.count(b"\x00") > len(head) // 4):
        # a UTF-16 file read as "no header line naming the columns" (an outside fuzz probe)
        raise RawRecordingError(path, None, None, "not UTF-8 text (UTF-16, or binary): save the recording as "
                                "UTF-8 (or ASCII) CSV")
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
    _check_unique_names(path, header_at + 1, header)
    if label_column is not None and label_column not in header:
        raise RawRecordingError(path, header_at + 1, label_column,
                                f"label column not in the header (columns: {', '.join(header)})")
    if temperature_column is not None and temperature_column not in header:
        raise RawRecordingError(path, header_at + 1, temperature_column,
                                f"temperature column not in the header (columns: {', '.join(header)})")
    metadata = {}
    for k, line in enumerate(lines[:header_at]):
        parts = _metadata_fields(line)
        if len(parts) >= 2 and parts[0]:
            metadata[parts[0]] = parts[1]
        fr = _file_rate(path, k + 1, line)
        if fr is not None and abs(fr - rate_hz) > 1e-6 * rate_hz:
            raise RawRecordingError(path, k + 1, None,
                                    f"the stated rate {rate_hz:g} Hz disagrees with the file's header ({fr:g} Hz); "
                                    "check which one is right (imucal issue #25)")
    offset = _line_start(path, header_at, bom)
    read = cols + ((temperature_column,) if temperature_column is not None else ())
    acc, labels = _read_samples_fast(path, offset, header_at, header, read, label_column, delim)
    temp = acc[:, 3] if temperature_column is not None else None
    if temp is not None:
        _check_temperature(path, header_at + 2, temperature_column, temp)
    _check_time_column(path, offset, header_at, header, delim, float(rate_hz), len(acc))
    return RawRecording(acc[:, :3], float(rate_hz), unit, cols, labels, label_column, metadata, path,
                        header_at + 2, temp, temperature_column)


def _check_unique_names(path, line: int, header: Sequence[str]) -> None:
    """Refuse a header that names a column twice: the reader would take the first and ignore the
    second without a word (``acc_x,acc_y,acc_z,acc_x``). Empty names (a trailing separator) are
    not names and may repeat."""
    first = {}
    for i, name in enumerate(header):
        if not name:
            continue
        if name in first:
            raise RawRecordingError(path, line, name,
                                    f"the header names this column twice (fields {first[name] + 1} and {i + 1}); "
                                    "which one holds the readings is ambiguous: rename or remove one")
        first[name] = i


def _metadata_fields(line: str) -> list:
    """A header line before the column names as ``key, value, ...``: split at the first of
    :data:`DELIMITERS` that the line holds (``Fs,100``, ``Fs<TAB>100``, ``Fs;100``)."""
    for sep in DELIMITERS:
        if sep in line:
            return [p.strip() for p in line.split(sep)]
    return [line.strip()]


#: header lines before the column names that state the sample rate (docs/raw.md, Reading): the
#: keys, matched whatever their case (``Fs``, ``fs``, ``FS``), with an optional unit in the key
#: (``Sample rate (Hz)``, ``rate_hz``) and an optional comment mark before it (``# Fs = 100 Hz``)
RATE_KEYS = ("Fs", "rate_hz", "sample_rate_hz", "sample rate", "sampling rate", "sampling frequency", "ODR",
             "output data rate")
_RATE_KEY = (r"(?:fs|odr|output[ _]data[ _]rate|(?:sample|sampling)[ _]?(?:rate|frequency|freq)"
             r"|rate(?=[ _]?(?:\(hz\)|\[hz\]|hz)))(?:[ _]?(?:\(hz\)|\[hz\]|hz))?")
_RATE_LINE = re.compile(r"^\s*(?:#+|//|%)?\s*(" + _RATE_KEY + r")\s*(?:[,;\t=:]|\s)(.*)$", re.IGNORECASE)
_RATE_VALUE = re.compile(r"^(.*?)\s*(k?hz)?$", re.IGNORECASE)


def _file_rate(path: str, line_number: int, line: str) -> Optional[float]:
    """The sample rate (Hz) a header line states, None when it states none. A rate line is one
    whose first field is a key of :data:`RATE_KEYS` in any case (``Fs``, ``fs``, ``ODR``,
    ``Sample rate (Hz)``), after an optional comment mark (``#``, ``//``, ``%``), separated by
    a comma, tab, semicolon, ``=``, ``:`` or blanks; its value is a number with an optional unit
    ``Hz`` or ``kHz`` (``Fs,100``, ``fs,100``, ``Fs,200 Hz``, ``Fs<TAB>200``, ``rate_hz = 0.2 kHz``,
    ``# Fs = 100 Hz``). A rate line whose value cannot be read is refused: a rate the reader
    ignored could not be checked against ``--rate`` (a lowercase ``fs,100`` was, before)."""
    m = _RATE_LINE.match(line)
    if m is None:
        return None
    key = m.group(1)
    text = re.sub(r"[,;\t]+", " ", m.group(2)).strip()
    v = _RATE_VALUE.match(text)
    number, unit = (v.group(1), v.group(2)) if v else (text, None)
    try:
        rate = parse_number(number, low=0.0, high=MAX_READING, low_open=True, what=key)
    except NumberError as exc:
        raise RawRecordingError(path, line_number, None,
                                f"the header line {line.strip()!r} states a sample rate that cannot be read "
                                f"({exc.problem}; expected e.g. '{key},100' or '{key},100 Hz'): correct or remove "
                                "the line, a rate in the file is checked against --rate") from None
    return rate * (1000.0 if unit and unit.lower() == "khz" else 1.0)


#: the hottest an IMU's own temperature gets in a raw recording, degC (commercial parts end at 85-125,
#: high-temperature ones at 150): a column beyond it is in another unit (tenths of a degC: an outside
#: probe's 15.5 +- 3.5 degC written as 120-190 was read as degC and its bias tempco came out 10 times
#: too small)
RAW_MAX_C = 150.0
#: a temperature column's name that states another unit than degC (any case): the unit it states
_NAME_UNITS = (("fahrenheit", "degF"), ("degf", "degF"), ("deg_f", "degF"), ("°f", "degF"), ("kelvin", "kelvin"),
               ("decic", "tenths of a degC"), ("dec_c", "tenths of a degC"), ("0.1c", "tenths of a degC"),
               ("0.01c", "hundredths of a degC"), ("centic", "hundredths of a degC"))
_NAME_SUFFIXES = (("_f", "degF"), ("(f)", "degF"), ("[f]", "degF"), ("_k", "kelvin"), ("(k)", "kelvin"),
                  ("[k]", "kelvin"), ("_dc", "tenths of a degC"), ("_cc", "hundredths of a degC"))


def temperature_unit_in_name(column: str) -> Optional[str]:
    """The unit other than degC a column's name states (``temp_F``, ``die_temp_degF``, ``T_kelvin``,
    ``temp_dC``), or None (``temp``, ``temp_C``, ``imu.temperature``)."""
    name = column.strip().lower().replace(" ", "")
    for key, unit in _NAME_UNITS:
        if key in name:
            return unit
    for suf, unit in _NAME_SUFFIXES:
        if name.endswith(suf):
            return unit
    return None


def _check_temperature(path: str, first_line: int, column: str, temp: np.ndarray) -> None:
    """The bench reader's rules for a temperature column (degC): a name that states another unit
    (:func:`temperature_unit_in_name`: an outside probe's ``temp_F`` was read as degC, its bias
    tempco 7 u off) is refused; a median at or above
    :data:`~triadcal.io.bench_csv.KELVIN_MEDIAN_C` is kelvin and refused as such, then every
    value must lie in the range of the bench's ``t_*`` columns and at most :data:`RAW_MAX_C`."""
    from .bench_csv import KELVIN_MEDIAN_C, column_range

    said = temperature_unit_in_name(column)
    if said is not None:
        raise RawRecordingError(path, first_line - 1, column,
                                f"the column's name says {said}: the temperature column is read in degC; convert it "
                                "(or name the column so it does not state another unit)")
    if not len(temp):
        return
    med = float(np.median(temp))
    if med >= KELVIN_MEDIAN_C:
        raise RawRecordingError(path, first_line, column,
                                f"temperatures look like kelvin (median {med:g}): the temperature column is degC "
                                f"(subtract 273.15; no IMU calibration runs at a median of {KELVIN_MEDIAN_C:g} degC)")
    low, high, _ = column_range("t_x")
    high = min(high, RAW_MAX_C)
    bad = np.flatnonzero((temp < low) | (temp > high))
    if len(bad):
        i = int(bad[0])
        hint = (" (no IMU runs that hot: tenths of a degC, or degF? the column is read in degC)"
                if temp[i] > RAW_MAX_C else "")
        raise RawRecordingError(path, first_line + i, column,
                                f"temperature {temp[i]:g} degC is outside {low:g} .. {high:g} degC{hint}")


#: seconds per unit of a time column (this reader's check; thermal-cycle's --time-unit)
TIME_UNITS_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: names of a time column (any case) that the reader checks against ``--rate``, with the unit of
#: their values (:data:`TIME_UNITS_S`); None: the unit is not in the name (every unit is tried)
TIME_COLUMNS = {"time_s": "s", "t_s": "s", "time_ms": "ms", "timestamp_ms": "ms", "t_ms": "ms", "time_us": "us",
                "timestamp_us": "us", "t_us": "us", "time_ns": "ns", "timestamp_ns": "ns", "time": None,
                "timestamp": None,
                # an outside probe's elapsed_ms and Arduino's millis()/micros() columns were not checked
                "timestamp_s": "s", "elapsed_s": "s", "elapsed_ms": "ms", "elapsed_us": "us", "millis": "ms",
                "micros": "us", "elapsed": None}
#: a time column whose mean step differs from 1/--rate (in the unit its name says, or in the closest of
#: s, ms, us, ns) by more than this fraction is refused
TIME_RATE_TOLERANCE = 0.05


def _check_time_column(path, offset: int, header_at: int, header, delim: str, rate_hz: float, n: int) -> None:
    """A time column of the recording (:data:`TIME_COLUMNS`), checked against the stated rate: the
    samples are placed at ``i / rate_hz`` (the time column is not used), so a column that says
    otherwise is refused, as a header line that states another rate is. Refused: a time that goes
    back (a wrapped counter, two recordings joined), and a mean step over the recording,
    ``(t_last - t_first) / (n - 1)``, more than :data:`TIME_RATE_TOLERANCE` from ``1/rate_hz`` in the
    column's unit (its name's, else the nearest of s, ms, us, ns): another rate, or dropped
    samples. An outside probe's ``time_s`` stepping 0.02 s was fitted with ``--rate 100`` as if at
    100 Hz, the intervals' durations twice too short, and a time going backwards was read
    silently. A column whose values are not all numbers (a date) is not read, and not checked."""
    names = {h.lower(): h for h in header if h}
    found = [(names[k], unit) for k, unit in TIME_COLUMNS.items() if k in names]
    if not found or n < 3:
        return
    column, unit = found[0]
    import pyarrow as pa
    from pyarrow import csv as pacsv

    try:
        with open(path, "rb") as source:
            source.seek(offset)
            table = pacsv.read_csv(source, parse_options=pacsv.ParseOptions(delimiter=delim),
                                   convert_options=pacsv.ConvertOptions(include_columns=[column],
                                                                        column_types={column: pa.float64()}))
    except (pa.ArrowInvalid, pa.ArrowKeyError, KeyError):
        return
    t = table.column(column).to_numpy(zero_copy_only=False)
    if len(t) != n or not np.all(np.isfinite(t)):
        return
    back = np.flatnonzero(np.diff(t) < 0)
    if len(back):
        i = int(back[0]) + 1
        raise RawRecordingError(path, header_at + 2 + i, column,
                                f"the time goes back from {t[i - 1]:.10g} to {t[i]:.10g} at sample {i}: a counter that "
                                "wrapped, or two recordings joined; the samples are taken at --rate in file order, so "
                                "split the file where the time restarts")
    step = (t[-1] - t[0]) / (n - 1)
    ratios = [(step * TIME_UNITS_S[name] * rate_hz, name) for name in ([unit] if unit else TIME_UNITS_S)]
    if any(abs(r - 1.0) <= TIME_RATE_TOLERANCE for r, _ in ratios):
        return
    implied = ", ".join(f"{rate_hz / r:.6g} Hz" + (f" if in {name}" if unit is None else "") if r > 0 else "no rate"
                        for r, name in ratios)
    raise RawRecordingError(path, header_at + 2, column,
                            f"the time column steps {step:.6g} a sample on average over {n} samples ({implied}), "
                            f"not the {rate_hz:g} Hz of --rate: the samples are placed at --rate, so give the "
                            "recording's rate (or, if samples were dropped, fill or split the gaps)")


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
    """Refuse readings whose magnitude contradicts the declared unit: for ``g``, ``mg`` and ``m/s2``
    the median norm of the static means must lie within a factor 1.5 of the local gravity in that
    unit (counts are the instrument's own; the answer gates check their K band)."""
    if rec.unit not in PER_G or not len(w_means):
        return
    expected = local_g_m_s2 / 9.80665 * PER_G[rec.unit]
    med = float(np.median(np.linalg.norm(w_means, axis=1)))
    ratio = med / expected
    if not 1 / 1.5 <= ratio <= 1.5:
        raise RawRecordingError(rec.source, None, None,
                                f"the readings contradict --unit {rec.unit}: the median |a| of the static "
                                f"intervals is {med:.6g} {rec.unit}, gravity is {expected:.6g} {rec.unit} "
                                f"(ratio {ratio:.3g}); state the unit the readings are in (counts, g, mg, m/s2)")


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
            d = json.loads(text, object_pairs_hook=_unique_keys)
        except _DuplicateKey as exc:
            raise RawRecordingError(path, None, exc.key, "entry given twice: a JSON reader keeps only the last one, "
                                    "so one of the two would be ignored") from None
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
                timed = [f for f in fields if _names_time(f)]
                if timed:        # an outside probe's start_s,end_s were read as sample indices without a word
                    raise RawRecordingError(path, 1, timed[0], f"the header {line.strip()!r} names a time; the "
                                            "limits are sample indices (0-based, end exclusive): multiply "
                                            "seconds by the rate") from None
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
    frac = [(i, key, v) for key, arr in (("start", s), ("end", e)) for i, v in enumerate(arr) if v != round(v)]
    if frac:
        i, key, v = min(frac, key=lambda t: (t[0], t[1] != "start"))
        raise RawRecordingError(path, None, f"interval {i + 1} {key}",
                                f"{v:g} is not a whole sample index ({len(frac)} limit(s) are not): the limits are "
                                "sample indices (0-based, end exclusive), not seconds; multiply seconds by the rate")
    return _checked(IntervalSpec(s.astype(int), e.astype(int), None, path))


def _names_time(field: str) -> bool:
    """Whether a column name of an interval file says a time (start_s, t_end, end_ms, seconds, time)."""
    f = field.strip().lower()
    return (f.endswith(("_s", "_sec", "_ms", "_us", "[s]", "(s)")) or f.startswith(("t_", "time"))
            or any(w in f for w in ("second", "time", "sec")))


def _checked(spec: IntervalSpec) -> IntervalSpec:
    """Each interval ends after it starts, and no two intervals share a sample: two faces pointed at
    the same range (or overlapping ranges) would average the same samples as two poses."""
    bad = np.flatnonzero(spec.end <= spec.start)
    if len(bad):
        raise RawRecordingError(spec.source, None, None,
                                f"interval {_entry(spec, int(bad[0]))} ends before it starts")
    order = np.argsort(spec.start, kind="stable")
    reach = -1                                 # the entry reaching furthest among those before
    for j in order:
        if reach >= 0 and spec.start[j] < spec.end[reach]:
            i, k = sorted((int(reach), int(j)))
            same = spec.start[i] == spec.start[k] and spec.end[i] == spec.end[k]
            lo, hi = max(spec.start[i], spec.start[k]), min(spec.end[i], spec.end[k])
            raise RawRecordingError(
                spec.source, None, None,
                f"intervals {_entry(spec, i)} and {_entry(spec, k)} "
                + ("cover the same samples" if same else f"overlap (samples {lo}..{hi})")
                + ": each static interval must have samples of its own (end is exclusive)")
        if reach < 0 or spec.end[j] > spec.end[reach]:
            reach = int(j)
    return spec


def _entry(spec: IntervalSpec, i: int) -> str:
    """One interval as the message names it: its label (JSON) or its position in the file."""
    name = f"'{spec.labels[i]}'" if spec.labels else f"{i + 1}"
    return f"{name} ({int(spec.start[i])}..{int(spec.end[i])})"
