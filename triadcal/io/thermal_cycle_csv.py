"""The reader of a one-pose chamber cycle (``triadcal thermal-cycle``, docs/model.md "A real chamber
cycle"): named columns, every row and field checked, a time axis and temperatures no chamber cycle
has refused with the file, line and column."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..errors import InputError
from .raw import TIME_UNITS_S, RawRecordingError

#: the hottest temperature a chamber cycle of an IMU reaches, degC (chambers for IMUs end at +125 to +180)
MAX_TEMPERATURE_C = 200.0
#: a chamber moves the unit's temperature at a few degC/min (thermal-shock chambers at some tens):
#: a cycle whose temperature span would be crossed faster than this, on average, has a wrong time axis
MAX_SWEEP_C_MIN = 60.0
#: a one-pose chamber cycle lasting longer than this (s; 30 days) has a wrong time axis
MAX_CYCLE_S = 30 * 86400.0
# the time units of ``--time-unit`` in seconds: TIME_UNITS_S (io/raw.py, shared with its time-column check)


def read_cycle(path, columns: Sequence[str], time_column: str, time_unit: str, temperature_column: str,
               unit: str = "m/s2"):
    """``(t_s, T, y, lines)`` of a recording with named columns (comma, tab or semicolon separated: the
    header line that names every column decides). Every row must have the header's number of
    fields (a field added or lost shifts the columns after it: refused with the file, line and
    field count, as :func:`triadcal.io.raw.read_raw_csv` does); every field read must be a finite
    number, a bad one refused with the file, line and column; nothing is dropped. A time axis no
    chamber cycle has (:func:`check_time_axis`) and outputs no static pose gives
    (:func:`check_outputs`) are refused. ``lines``: each sample's line in the file."""
    import csv

    scale = TIME_UNITS_S
    if time_unit not in scale:
        raise InputError(f"--time-unit {time_unit!r}: choose one of {', '.join(scale)}")
    cols = list(columns)
    if not cols:
        raise InputError("give at least one output column")
    want = [time_column, temperature_column] + cols
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            lines = fh.read().splitlines()
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    header_at, index, sep, header = None, None, None, None
    for k, line in enumerate(lines[:200]):
        for d in (",", "\t", ";"):
            fields = [f.strip() for f in next(csv.reader([line], delimiter=d), [])]
            if all(c in fields for c in want):
                twice = [c for c in dict.fromkeys(want) if fields.count(c) > 1]
                if twice:
                    # the first of two columns of one name was read silently (an outside probe)
                    raise InputError(f"{path}:{k + 1}: the header names column {', '.join(repr(c) for c in twice)} "
                                     "more than once: which one holds the data is not known")
                header_at, index, sep, header = k, [fields.index(c) for c in want], d, fields
                break
        if header_at is not None:
            break
    if header_at is None:
        raise InputError(f"{path}: no header line names all of {', '.join(want)} in its first 200 lines")
    rows, row_lines = [], []
    for k, line in enumerate(lines[header_at + 1:], start=header_at + 2):
        if not line.strip():
            continue
        row_lines.append(k)
        fields = next(csv.reader([line], delimiter=sep))
        if len(fields) != len(header):
            # a field too many or too few shifts every column after it: the raw reader's rule
            raise RawRecordingError(str(path), k, header[len(fields)] if len(fields) < len(header) else None,
                                    f"{len(fields)} fields, the header has {len(header)} (a field added or lost "
                                    "shifts the columns after it; nothing is read from a row that does not match "
                                    "the header)")
        row = []
        for c, j in zip(want, index):
            try:
                v = float(fields[j])
            except (IndexError, ValueError):
                raise InputError(f"{path}:{k}: column '{c}': {fields[j] if j < len(fields) else 'missing'!r} "
                                 "is not a number") from None
            if not math.isfinite(v):
                raise InputError(f"{path}:{k}: column '{c}': {v} is not finite")
            row.append(v)
        rows.append(row)
    if len(rows) < 2:
        raise InputError(f"{path}: fewer than two samples")
    a = np.array(rows)
    t = (a[:, 0] - a[0, 0]) * scale[time_unit]
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise InputError(f"{path}:{header_at + k + 3}: column '{time_column}': the time does not increase")
    T = a[:, 1]
    if T.min() < -273.15 or T.max() > MAX_TEMPERATURE_C:
        # kelvin read as degC gave "254.4 .. 341.8 degC" and a verdict (an outside probe)
        k = int(np.argmax((T < -273.15) | (T > MAX_TEMPERATURE_C)))
        hint = " (kelvin? the column must be in degC)" if T.min() > 200.0 else ""
        raise InputError(f"{path}:{header_at + k + 2}: column '{temperature_column}': {T[k]:g} is not a chamber "
                         f"temperature in degC (-273.15 to {MAX_TEMPERATURE_C:g}){hint}")
    check_time_axis(path, a[:, 0], T, time_column, time_unit)
    check_outputs(path, cols, a[:, 2:], np.array(row_lines), unit)
    return t, T, a[:, 2:], np.array(row_lines)


#: the outputs' units whose size of g is known (per g); other units (V, counts) are read unchecked
G_IN_UNIT = {"m/s2": 9.80665, "m/s^2": 9.80665, "m/s²": 9.80665, "g": 1.0, "mg": 1e3, "ug": 1e6, "µg": 1e6}
#: a static pose's output along one axis is at most 1 g plus the bias; beyond this many g (its median)
#: the unit is not the one stated
MAX_STATIC_G = 1.5
#: the band of the norm of three columns' medians (g) that the three axes of one triad at rest read
TRIAD_NORM_G = (0.5, 1.5)
#: a sample this far from its output's range (in g) is not an acceleration of a unit at rest (an
#: outside probe's 1e30 read and named "linear", noise floor 1.7e28)
MAX_READING_G = 1000.0


def check_outputs(path, columns, y, row_lines, unit: str) -> None:
    """Refuse outputs no static pose gives: a column that reads one value on every row (a stuck or
    unconnected channel: an outside probe's was named ``linear``, "explained", noise floor 0); and,
    in a unit whose g is known (:data:`G_IN_UNIT`), a sample beyond :data:`MAX_READING_G` or a column
    whose median is beyond :data:`MAX_STATIC_G` (an output in m/s^2 read as g: |z| 9.8 "g", exit 0), or
    three columns whose medians' norm lies outside :data:`TRIAD_NORM_G` (a triad in g read as m/s^2)."""
    for i, c in enumerate(columns):
        v = y[:, i]
        if np.ptp(v) == 0:
            raise InputError(f"{path}: column '{c}' reads {v[0]:g} on every row: a stuck or unconnected channel "
                             "has no thermal form")
    g = G_IN_UNIT.get(unit)
    if g is None:
        return
    for i, c in enumerate(columns):
        v = y[:, i]
        far = np.flatnonzero(np.abs(v) > MAX_READING_G * g)
        if far.size:
            k = int(far[0])
            raise InputError(f"{path}:{int(row_lines[k])}: column '{c}': {v[k]:g} {unit} is {abs(v[k]) / g:.3g} g, not "
                             f"the reading of a unit at rest (beyond {MAX_READING_G:g} g)")
        med = float(np.median(np.abs(v)))
        if med > MAX_STATIC_G * g:
            others = [u for u in ("m/s2", "g", "mg") if 0.5 <= med / G_IN_UNIT[u] <= MAX_STATIC_G]
            raise InputError(f"{path}: column '{c}': its median |{med:.4g}| {unit} is {med / g:.3g} g, beyond the "
                             f"{MAX_STATIC_G:g} g an axis at rest reads: the output is not in {unit}"
                             + (f" (in {' or '.join(others)}? give --unit)" if others else " (give --unit)"))
    if len(columns) == 3:
        # three outputs of one triad at rest read 1 g together, whatever the pose (an outside probe's triad in
        # g under the default m/s2: a norm of 1.00 "m/s2", every value 9.8 times too small, exit 0)
        norm = float(np.linalg.norm(np.median(y[:, :3], axis=0)))
        if not TRIAD_NORM_G[0] * g <= norm <= TRIAD_NORM_G[1] * g:
            others = [u for u in ("m/s2", "g", "mg") if TRIAD_NORM_G[0] <= norm / G_IN_UNIT[u] <= TRIAD_NORM_G[1]]
            raise InputError(f"{path}: columns {', '.join(repr(c) for c in columns)}: the norm of their medians is "
                             f"{norm:.4g} {unit} = {norm / g:.3g} g, where the three axes of a triad at rest read 1 g "
                             f"together: the outputs are not in {unit}"
                             + (f" (in {' or '.join(others)}? give --unit)" if others else " (give --unit)")
                             + "; if they are not the three axes of one unit, judge them one at a time")


#: a sample further than this many robust SDs from the running median of its 9 neighbours is a glitch
GLITCH_SD = 20.0
#: more glitches than this fraction of the samples are not isolated: the recording is refused
GLITCH_FRACTION_MAX = 0.01


def glitches(y) -> np.ndarray:
    """Rows holding an isolated glitch: a sample of some column further than :data:`GLITCH_SD` robust
    SDs (1.4826 MAD) from the running median over 9 samples. A real chamber cycle's largest is 9
    (examples/data/tofupilot_imu_raw_data.csv); an outside probe's single sample raised by 0.5 m/s^2
    (1700 SDs) made a 4 min lag 3.77, one of 5 m/s^2 a line, "explained" with a branch gap of +540 ug."""
    from scipy.ndimage import median_filter

    bad = np.zeros(len(y), bool)
    for i in range(y.shape[1]):
        r = y[:, i] - median_filter(y[:, i], size=9, mode="nearest")
        sd = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        if sd > 0:
            bad |= np.abs(r) > GLITCH_SD * sd
    return np.flatnonzero(bad)


def _span(seconds: float) -> str:
    for limit, div, name in ((120.0, 1.0, "s"), (7200.0, 60.0, "min"), (172800.0, 3600.0, "h"),
                             (2 * 365.25 * 86400.0, 86400.0, "days")):
        if seconds < limit:
            return f"{seconds / div:.3g} {name}"
    return f"{seconds / (365.25 * 86400.0):.3g} years"


def check_time_axis(path, stamps, T, time_column: str, time_unit: str) -> None:
    """Refuse a time axis no chamber cycle has: with the stated ``--time-unit`` the temperature
    would cross its span faster than :data:`MAX_SWEEP_C_MIN` on average, or the cycle would last
    longer than :data:`MAX_CYCLE_S`. The message gives the duration, the implied sample rate and
    the time units that would make the cycle plausible. Before, timestamps in ms read as us (the
    cycle 1000 times too short) were refused as "the temperature only rises or only falls"."""
    stamps, T = np.asarray(stamps, float), np.asarray(T, float)
    span_s = float(stamps[-1] - stamps[0])
    dT = float(np.ptp(T))

    def plausible(unit):
        d = span_s * TIME_UNITS_S[unit]
        return d > 0 and d <= MAX_CYCLE_S and dT / (d / 60.0) <= MAX_SWEEP_C_MIN

    if plausible(time_unit):
        return
    d = span_s * TIME_UNITS_S[time_unit]
    rate_hz = (len(stamps) - 1) / d if d > 0 else float("inf")
    why = (f"the temperature would cross its {dT:.3g} degC span at {dT / (d / 60.0):.3g} degC/min on average, "
           f"faster than any chamber (more than {MAX_SWEEP_C_MIN:g} degC/min)" if d <= MAX_CYCLE_S else
           f"longer than any chamber cycle (more than {MAX_CYCLE_S / 86400.0:g} days)")
    others = [u for u in TIME_UNITS_S if u != time_unit and plausible(u)]
    hint = "; ".join(f"with --time-unit {u} it would last {_span(span_s * TIME_UNITS_S[u])}" for u in others)
    raise InputError(f"{path}: column '{time_column}': the time axis is implausible with --time-unit {time_unit}: "
                     f"{len(stamps)} samples over {_span(d)} ({rate_hz:.3g} samples per second), {why}. "
                     f"Check --time-unit" + (f" ({hint})" if hint else ""))
