"""Bench CSV v1: read and write the interchange format of docs/spec/bench-csv-v1.md.

Every refusal names the file, the line and the column (:class:`BenchCSVError`);
nothing is silently dropped: columns the format does not define are kept as text in
``Campaign.extra`` and written back out.
"""

from __future__ import annotations

from ..errors import InputError

import csv
import io
import math
import os
from pathlib import Path
from typing import Optional, Union

import numpy as np

from ..models.campaign import DIRECTIONS, Campaign
from .numbers import MAX_READING, NumberError, parse_number

REQUIRED = ("unit", "setpoint_C", "direction", "time_s", "position", "axis1_deg", "axis2_deg",
            "tau_s", "w_x", "w_y", "w_z", "t_x", "t_y", "t_z")
OPTIONAL = ("cycle", "sd_x", "sd_y", "sd_z", "n_samples", "state", "u_w_x", "u_w_y", "u_w_z",
            "dTdt_C_per_min")
#: per-visit standard uncertainty of the mean outputs (docs/bench-csv.md, "u_w_*")
U_W = ("u_w_x", "u_w_y", "u_w_z")
#: per-visit measured rate of the unit's temperature, degC/min (docs/bench-csv.md, "dTdt_C_per_min")
DTDT = "dTdt_C_per_min"
COLUMNS = REQUIRED + OPTIONAL
FLOATS = ("setpoint_C", "time_s", "axis1_deg", "axis2_deg", "tau_s",
          "w_x", "w_y", "w_z", "t_x", "t_y", "t_z", "sd_x", "sd_y", "sd_z", "u_w_x", "u_w_y", "u_w_z",
          "dTdt_C_per_min")


class BenchCSVError(InputError):
    """Bad bench CSV input, located by file, line (1-based) and column."""

    def __init__(self, path: str, line: int, column: Optional[str], problem: str):
        self.path, self.line, self.column, self.problem = path, line, column, problem
        where = f"{path}:{line}" + (f": column '{column}'" if column else "")
        super().__init__(f"{where}: {problem}")


def read_bench_csv(path: Union[str, os.PathLike]) -> Campaign:
    """Read a bench CSV v1 file into a :class:`~triadcal.models.campaign.Campaign`."""
    path = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")  # tolerate a BOM (spreadsheet export)
    except UnicodeDecodeError as exc:
        raise BenchCSVError(path, text_line_of_offset(Path(path).read_bytes(), exc.start), None,
                            "not UTF-8 text") from None
    return parse_bench_csv(text, path)


def text_line_of_offset(data: bytes, offset: int) -> int:
    return data[:offset].count(b"\n") + 1


#: accepted range of each numeric column (docs/bench-csv.md): (low, high, low_open)
RANGES = {
    "setpoint_C": (-273.15, 300.0, False), "t_x": (-273.15, 300.0, False), "t_y": (-273.15, 300.0, False),
    "t_z": (-273.15, 300.0, False),
    "axis1_deg": (-360.0, 360.0, False), "axis2_deg": (-360.0, 360.0, False),
    "tau_s": (0.0, 86400.0, True),
    "time_s": (-MAX_READING, MAX_READING, False),
    "w_x": (-MAX_READING, MAX_READING, False), "w_y": (-MAX_READING, MAX_READING, False),
    "w_z": (-MAX_READING, MAX_READING, False),
    "sd_x": (0.0, MAX_READING, False), "sd_y": (0.0, MAX_READING, False), "sd_z": (0.0, MAX_READING, False),
}
#: accepted range of the optional ``u_w_*`` columns: a standard uncertainty that weights the fit
#: is positive (0 would be an infinite weight); kept apart from RANGES, whose columns every
#: campaign file of the property tests holds
U_W_RANGE = (0.0, MAX_READING, True)
#: accepted range of the optional ``dTdt_C_per_min`` (degC/min): a ramp plan's rate is at most
#: 100 degC/min (planning/ramp.py), and no chamber changes a unit's temperature faster
DTDT_RANGE = (-100.0, 100.0, False)
#: the optional numeric columns, each with its range, kept apart from RANGES (see U_W_RANGE)
OPTIONAL_RANGES = {**{c: U_W_RANGE for c in U_W}, DTDT: DTDT_RANGE}


def column_range(name: str) -> tuple:
    """``(low, high, low_open)`` of a numeric column."""
    return OPTIONAL_RANGES[name] if name in OPTIONAL_RANGES else RANGES[name]


#: local gravity accepted without ``# local_g_override = true`` (m/s^2): the range on Earth's
#: surface is 9.78 (equator) to 9.83 (poles), with a margin for altitude and anomalies
LOCAL_G_RANGE_M_S2 = (9.76, 9.84)
#: the largest local g accepted even with the override (m/s2)
LOCAL_G_MAX_M_S2 = 100.0
#: a temperature column whose median is at or above this (degC) is kelvin, not degC: no IMU
#: calibration runs at 200 degC, while 200 K is -73 degC
KELVIN_MEDIAN_C = 200.0
#: factor by which the median |w| may differ from 1 g in a physical output unit
UNIT_MAGNITUDE_FACTOR = 1.5


def _metadata(lines, path):
    from .bench_checks import check_comment_key

    metadata: dict[str, str] = {}
    where: dict[str, int] = {}
    k = 0
    while k < len(lines) and (lines[k].startswith("#") or not lines[k].strip()):
        body = lines[k][1:].strip() if lines[k].startswith("#") else ""
        check_comment_key(path, k + 1, body)
        if "=" in body:
            key, value = (s.strip() for s in body.split("=", 1))
            if key in where:
                raise BenchCSVError(path, k + 1, None, f"metadata '{key}' given twice (first on line {where[key]})")
            where[key] = k + 1
            metadata[key] = value
        k += 1
    for flag in ("local_g_override", "t_override"):
        if metadata.get(flag, "false").lower() not in ("true", "false"):
            raise BenchCSVError(path, where[flag], None,
                                f"metadata '{flag}' must be true or false, got {metadata[flag]!r}")
    if "date" in metadata:
        from .dates import ISO_HINT, iso_date

        if iso_date(metadata["date"]) is None:
            raise BenchCSVError(path, where["date"], None, f"metadata 'date' = {metadata['date']!r} is not {ISO_HINT}")
        from .dates import future_problem

        late = future_problem(iso_date(metadata["date"]), "the campaign")
        if late:
            raise BenchCSVError(path, where["date"], None, f"metadata 'date': {late}")
    if "output_unit" in metadata and not metadata["output_unit"].strip():
        # an outside probe's empty '# output_unit =' was fitted, status ok, K in 'g/'
        raise BenchCSVError(path, where["output_unit"], None, "metadata 'output_unit' is empty: name the unit of "
                                                              "w_x w_y w_z (V, mV, counts, g, m/s^2, ...)")
    override = metadata.get("local_g_override", "false").lower()
    for key, low, high, low_open in (("local_g_m_s2", 0.0, LOCAL_G_MAX_M_S2, True), ("Q_V2s", 0.0, MAX_READING, True),
                                     ("power_on_s", -MAX_READING, MAX_READING, False)):
        if key in metadata:
            try:
                v = parse_number(metadata[key], low=low, high=high, low_open=low_open, what=key)
            except NumberError as exc:
                raise BenchCSVError(path, where[key], None, f"metadata '{key}' = {metadata[key]!r}: {exc.problem}") from None
            if key == "local_g_m_s2" and override != "true" and not (
                    LOCAL_G_RANGE_M_S2[0] <= v <= LOCAL_G_RANGE_M_S2[1]):
                raise BenchCSVError(
                    path, where[key], None,
                    f"metadata 'local_g_m_s2' = {v:g} m/s^2 is outside {LOCAL_G_RANGE_M_S2[0]}-{LOCAL_G_RANGE_M_S2[1]} "
                    "m/s^2, the local gravity anywhere on Earth's surface; if it is right (a centrifuge, another "
                    "planet, a deliberate test), add the line '# local_g_override = true'")
    return metadata, where, k


def _float_column(path, name, strings, line_numbers):
    """One numeric column, converted at once; on a bad field the slow path names its line."""
    joined = "".join(strings)
    try:
        if "_" in joined or not joined.isascii():
            raise InputError("digit separators or non-ASCII digits")   # float() would read them
        v = np.array(strings, dtype=float)
    except ValueError:
        for s_, ln in zip(strings, line_numbers):
            check_field(path, int(ln), name, s_)
        raise AssertionError("unreachable: a field failed as a column but passed alone")  # pragma: no cover
    low, high, low_open = column_range(name)
    bad = ~np.isfinite(v) | (v > high) | ((v <= low) if low_open else (v < low))
    if bad.any():
        i = int(np.argmax(bad))
        check_field(path, int(line_numbers[i]), name, strings[i])
    return v


#: column names of a raw recording (fit-raw's defaults, io/raw.py): a hint when ``fit`` is given one
RAW_HEADER_NAMES = {"acc_x", "acc_y", "acc_z", "ax", "ay", "az", "x", "y", "z", "accel_x", "accel_y", "accel_z"}


def parse_bench_csv(text: str, path: str = "<string>") -> Campaign:
    """Parse bench CSV v1 text; ``path`` names the source in error messages.

    Every field is checked against its column's range (:data:`RANGES`), the metadata against
    theirs, and the file as a whole: temperatures that look like kelvin and readings whose
    magnitude contradicts the declared ``output_unit`` are refused (docs/bench-csv.md)."""
    lines = text.splitlines()
    metadata, meta_line, k = _metadata(lines, path)
    if k == len(lines):
        raise BenchCSVError(path, max(k, 1), None, "no header row: the file holds no bench data")
    header_line = k + 1
    header = next(csv.reader([lines[k]]))
    header = [h.strip() for h in header]
    seen = set()
    for h in header:
        if h in seen:
            raise BenchCSVError(path, header_line, h, "column appears twice in the header")
        seen.add(h)
        if not h:
            raise BenchCSVError(path, header_line, None, f"column {len(seen)} has an empty name")
    for r in REQUIRED:
        if r not in seen:
            raw = [h for h in header if h.lower() in RAW_HEADER_NAMES]
            hint = (f" (the header names {', '.join(raw)}: a raw recording of static poses? `triadcal fit-raw "
                    "FILE --rate HZ` calibrates one; `triadcal fit` reads a bench campaign, docs/bench-csv.md)"
                    if raw and "w_x" not in seen else "")
            other = next((f"{name} ({sep!r})" for sep, name in (("\t", "tabs"), (";", "semicolons"))
                          if len(header) == 1 and sep in header[0]), None)
            if other:
                # a tab- or semicolon-separated file read as one column: 'unit' was named missing
                hint = (f" (the header is one field separated by {other}: bench CSV v1 is comma-separated; "
                        "save it with commas)")
            raise BenchCSVError(path, header_line, r, "required column is missing from the header" + hint)
    for group in (("sd_x", "sd_y", "sd_z"), U_W):
        present = [c for c in group if c in seen]
        if present and len(present) != len(group):
            missing = [c for c in group if c not in seen][0]
            raise BenchCSVError(path, header_line, missing, f"{', '.join(group)} come together")
    if ("n_samples" in seen) != ("sd_x" in seen):
        raise BenchCSVError(path, header_line, "n_samples" if "sd_x" in seen else "sd_x",
                            "sd_* and n_samples come together (their ratio is the uncertainty of the mean)")

    raw: list = []
    line_numbers: list[int] = []
    width = len(header)
    for offset, row in enumerate(csv.reader(lines[k + 1:])):
        if not row or (len(row) == 1 and not row[0].strip()):
            continue  # a blank line carries no data
        if len(row) != width:
            lineno = header_line + 1 + offset
            col = header[len(row)] if len(row) < width else None
            raise BenchCSVError(path, lineno, col,
                                f"{len(row)} fields, the header has {width}"
                                + (" (this column and those after it have no field)" if col else ""))
        raw.append(row)
        line_numbers.append(header_line + 1 + offset)
    n = len(line_numbers)
    if n == 0:
        raise BenchCSVError(path, header_line, None, "no data rows after the header")
    lnum = np.array(line_numbers)
    strings = {h: [r[j].strip() for r in raw] for j, h in enumerate(header)}
    del raw
    for i in range(n):
        if strings["w_x"][i] == "" and strings["w_y"][i] == "" and strings["w_z"][i] == "":
            raise BenchCSVError(path, int(lnum[i]), "w_x",
                                f"position {strings['position'][i]!r} visited with no readings")
    _check_kelvin(path, strings, lnum)
    cols: dict = {}
    for h in header:
        if h in RANGES or h in OPTIONAL_RANGES:
            cols[h] = _float_column(path, h, strings[h], lnum)
        elif h in COLUMNS:
            cols[h] = [check_field(path, int(ln), h, v) for v, ln in zip(strings[h], lnum)]
        else:
            cols[h] = strings[h]
    _check_rows(path, strings, cols, lnum)

    def arr(name, dtype=float):
        return np.asarray(cols[name], dtype=dtype)

    opt_cycle = arr("cycle", int) if "cycle" in cols else np.zeros(n, int)
    state = np.array(cols["state"], dtype=object).astype(str) if "state" in cols else np.full(n, "initial")
    sd = np.stack([arr(c) for c in ("sd_x", "sd_y", "sd_z")], axis=1) if "sd_x" in cols else None
    u_w = np.stack([arr(c) for c in U_W], axis=1) if "u_w_x" in cols else None
    campaign = Campaign(
        unit=np.array(cols["unit"]).astype(str), setpoint_C=arr("setpoint_C"),
        direction=np.array(cols["direction"]).astype(str), time_s=arr("time_s"),
        position=np.array(cols["position"]).astype(str), axis1_deg=arr("axis1_deg"),
        axis2_deg=arr("axis2_deg"), tau_s=arr("tau_s"),
        w=np.stack([arr(c) for c in ("w_x", "w_y", "w_z")], axis=1),
        t=np.stack([arr(c) for c in ("t_x", "t_y", "t_z")], axis=1),
        cycle=opt_cycle, state=state, sd=sd,
        n_samples=arr("n_samples", int) if "n_samples" in cols else None,
        metadata=metadata, source=path, lines=lnum, u_w=u_w,
        dTdt_C_per_min=arr(DTDT) if DTDT in cols else None,
        extra={h: np.array(cols[h]).astype(str) for h in header if h not in COLUMNS})
    check_output_unit(campaign, meta_line.get("output_unit", header_line))
    if "power_on_s" in metadata:
        t_on, first = float(metadata["power_on_s"]), int(np.argmin(campaign.time_s))
        if t_on > campaign.time_s[first]:
            raise BenchCSVError(path, meta_line["power_on_s"], None,
                                f"metadata 'power_on_s' = {metadata['power_on_s']} s is after the visit of line "
                                f"{int(lnum[first])} (time_s {campaign.time_s[first]:g} s): a unit is read after it "
                                "is switched on; the time-dependent terms (drifts, warm-ups) count from power-on")
    from .bench_checks import (check_axis_spans, check_directions, check_fahrenheit_setpoints,
                               check_repeated_readings, check_stuck_thermometer, check_temperature_unit)

    if metadata.get("t_override", "false").lower() != "true":
        check_temperature_unit(path, campaign)
        check_fahrenheit_setpoints(path, campaign)
        check_stuck_thermometer(path, campaign)
    check_directions(path, campaign)
    check_repeated_readings(path, campaign)
    check_axis_spans(path, campaign)
    return campaign


def _check_rows(path, strings, cols, lnum):
    """A unit is in one position at a time: no two rows of a unit (and state) at one time."""
    units, states = strings["unit"], strings.get("state", [""] * len(lnum))
    first: dict = {}
    for i, key in enumerate(zip(units, states, cols["time_s"].tolist())):
        j = first.setdefault(key, i)
        if j != i:
            same = all(strings[c][i] == strings[c][j] for c in ("position", "setpoint_C", "direction")
                       if c in strings)
            what = (f"duplicated row: position {strings['position'][i]!r} at the same time and setpoint as line "
                    f"{int(lnum[j])}" if same else
                    f"a second visit of unit {units[i]!r} at the same time as line {int(lnum[j])} "
                    "(a unit is in one position at a time)")
            raise BenchCSVError(path, int(lnum[i]), "time_s", what)


def _check_kelvin(path, strings, lnum):
    """Before the range checks, so that kelvin is named as such rather than as a range error."""
    try:
        T = np.array(strings["t_x"] + strings["t_y"] + strings["t_z"], dtype=float)
    except ValueError:
        return                                  # a field that is not a number: its own check names it
    T = T[np.isfinite(T)]
    if not len(T):
        return
    med = float(np.median(T))
    if med >= KELVIN_MEDIAN_C:
        raise BenchCSVError(path, int(lnum[0]), "t_x",
                            f"temperatures look like kelvin (median {med:g}): the t_* columns are degC "
                            f"(subtract 273.15; no IMU calibration runs at a median of {KELVIN_MEDIAN_C:g} degC)")


def check_output_unit(c: Campaign, line: int) -> None:
    """Refuse readings whose magnitude contradicts the declared ``output_unit``: for a
    physical acceleration unit the median |w| of the visits must lie within a factor
    :data:`UNIT_MAGNITUDE_FACTOR` of the local gravity in that unit; for an electrical or
    digital unit the implied K = g / median |w| must lie in the unit's plausible band
    (:data:`triadcal.estimation.gates.SCALE_BAND_G_PER_UNIT`)."""
    from ..estimation.gates import NOMINAL_SCALE_G_PER_UNIT, SCALE_BAND_G_PER_UNIT

    unit = c.output_unit.strip()
    med = float(np.median(np.linalg.norm(c.w, axis=1)))
    src = c.source or "<string>"
    if unit in NOMINAL_SCALE_G_PER_UNIT:
        expected = c.gravity_g / NOMINAL_SCALE_G_PER_UNIT[unit]
        ratio = med / expected if expected > 0 else math.inf
        if not 1 / UNIT_MAGNITUDE_FACTOR <= ratio <= UNIT_MAGNITUDE_FACTOR:
            raise BenchCSVError(src, line, None,
                                f"the readings contradict output_unit = {unit}: median |w| = {med:.6g} {unit}, "
                                f"while gravity is {expected:.6g} {unit} (ratio {ratio:.3g}); declare the unit the "
                                "readings are in")
    elif unit in SCALE_BAND_G_PER_UNIT:
        lo, hi = SCALE_BAND_G_PER_UNIT[unit]
        K = c.gravity_g / med if med > 0 else math.inf
        if not lo <= K <= hi:
            raise BenchCSVError(src, line, None,
                                f"the readings contradict output_unit = {unit}: median |w| = {med:.6g} {unit} "
                                f"implies K = {K:.6g} g/{unit}, {'below' if K < lo else 'above'} the plausible "
                                f"{lo:g}-{hi:g} g/{unit}")


def to_float(s: str) -> Optional[float]:
    try:
        return float(s)
    except ValueError:
        return None


def check_field(path: str, line: int, column: str, value: str):
    """Validate and convert one field; raise :class:`BenchCSVError` naming it and its range."""
    if column not in COLUMNS:
        return value
    if value == "":
        if column == "state":
            return "initial"
        if column == "cycle":
            return 0
        raise BenchCSVError(path, line, column, "empty field")
    if column in RANGES or column in OPTIONAL_RANGES:
        low, high, low_open = column_range(column)
        try:
            return parse_number(value, low=low, high=high, low_open=low_open, what=column)
        except NumberError as exc:
            raise BenchCSVError(path, line, column, exc.problem) from None
    if column in ("cycle", "n_samples"):
        try:
            v = int(value)
        except ValueError:
            raise BenchCSVError(path, line, column, f"not an integer: {value!r}") from None
        if column == "n_samples" and not 1 <= v <= MAX_READING:
            raise BenchCSVError(path, line, column, f"must be at least 1 (and at most {MAX_READING:g}), got {value}")
        if column == "cycle" and not 0 <= v <= MAX_READING:
            raise BenchCSVError(path, line, column, f"must be 0 or more (and at most {MAX_READING:g}), got {value}")
        return v
    if column == "direction" and value not in DIRECTIONS:
        raise BenchCSVError(path, line, column,
                            f"unknown direction {value!r} (expected one of: {', '.join(DIRECTIONS)})")
    return value


def format_bench_csv(c: Campaign) -> str:
    """Bench CSV v1 text of a campaign (floats written to round-trip exactly)."""
    buf = io.StringIO()
    for key, value in c.metadata.items():
        buf.write(f"# {key} = {value}\n")
    cols = list(REQUIRED) + ["cycle", "state"]
    if c.sd is not None and c.n_samples is not None:
        cols += ["sd_x", "sd_y", "sd_z", "n_samples"]
    if c.u_w is not None:
        cols += list(U_W)
    if c.dTdt_C_per_min is not None:
        cols.append(DTDT)
    cols += list(c.extra)
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(cols)
    for i in range(c.n_visits):
        writer.writerow([csv_value(c, col, i) for col in cols])
    return buf.getvalue()


def csv_value(c: Campaign, col: str, i: int) -> str:
    xyz = {"x": 0, "y": 1, "z": 2}
    if col in c.extra:
        return str(c.extra[col][i])
    if col in U_W:
        return repr(float(c.u_w[i, xyz[col[-1]]]))
    if col == DTDT:
        return repr(float(c.dTdt_C_per_min[i]))
    if col[:2] in ("w_", "t_") or col.startswith("sd_"):
        arr = {"w": c.w, "t": c.t, "sd": c.sd}[col.split("_")[0]]
        return repr(float(arr[i, xyz[col[-1]]]))
    v = getattr(c, col)[i]
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    return str(v)


def write_bench_csv(c: Campaign, path: Union[str, os.PathLike]) -> None:
    """Write a campaign as bench CSV v1 (atomically: a temporary file renamed into place)."""
    from .atomic import atomic_write_text

    atomic_write_text(path, format_bench_csv(c))
