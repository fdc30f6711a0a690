"""Bench CSV v1: read and write the interchange format of ../shared/docs/bench-csv.md.

Every refusal names the file, the line and the column (:class:`BenchCSVError`);
nothing is silently dropped: columns the format does not define are kept as text in
``Campaign.extra`` and written back out.
"""

from __future__ import annotations

import csv
import io
import math
import os
from pathlib import Path
from typing import Optional, Union

import numpy as np

from ..models.campaign import DIRECTIONS, Campaign

REQUIRED = ("unit", "setpoint_C", "direction", "time_s", "position", "axis1_deg", "axis2_deg",
            "tau_s", "w_x", "w_y", "w_z", "t_x", "t_y", "t_z")
OPTIONAL = ("cycle", "sd_x", "sd_y", "sd_z", "n_samples", "state")
COLUMNS = REQUIRED + OPTIONAL
FLOATS = ("setpoint_C", "time_s", "axis1_deg", "axis2_deg", "tau_s",
          "w_x", "w_y", "w_z", "t_x", "t_y", "t_z", "sd_x", "sd_y", "sd_z")
#: metadata keys whose values must be numbers
NUMERIC_METADATA = ("local_g_m_s2",)


class BenchCSVError(ValueError):
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


def parse_bench_csv(text: str, path: str = "<string>") -> Campaign:
    """Parse bench CSV v1 text; ``path`` names the source in error messages."""
    lines = text.splitlines()
    metadata: dict[str, str] = {}
    k = 0
    while k < len(lines) and (lines[k].startswith("#") or not lines[k].strip()):
        body = lines[k][1:].strip() if lines[k].startswith("#") else ""
        if "=" in body:
            key, value = (s.strip() for s in body.split("=", 1))
            if key in NUMERIC_METADATA:
                v = to_float(value)
                if v is None or not math.isfinite(v) or v <= 0:
                    raise BenchCSVError(path, k + 1, None, f"metadata '{key}' must be a positive number, got {value!r}")
            metadata[key] = value
        k += 1
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
            raise BenchCSVError(path, header_line, r, "required column is missing from the header")
    for group in (("sd_x", "sd_y", "sd_z"),):
        present = [c for c in group if c in seen]
        if present and len(present) != len(group):
            missing = [c for c in group if c not in seen][0]
            raise BenchCSVError(path, header_line, missing, "sd_x, sd_y, sd_z come together")
    if ("n_samples" in seen) != ("sd_x" in seen):
        raise BenchCSVError(path, header_line, "n_samples" if "sd_x" in seen else "sd_x",
                            "sd_* and n_samples come together (their ratio is the uncertainty of the mean)")

    cols: dict[str, list] = {h: [] for h in header}
    line_numbers: list[int] = []
    keys: dict[tuple, int] = {}
    times: dict[tuple, int] = {}
    reader = csv.reader(lines[k + 1:])
    for offset, row in enumerate(reader):
        lineno = header_line + 1 + offset
        if not row or (len(row) == 1 and not row[0].strip()):
            continue  # a blank line carries no data
        if len(row) != len(header):
            col = header[len(row)] if len(row) < len(header) else None
            raise BenchCSVError(path, lineno, col,
                                f"{len(row)} fields, the header has {len(header)}"
                                + (" (this column and those after it have no field)" if col else ""))
        values = dict(zip(header, (v.strip() for v in row)))
        if all(values.get(c, "") == "" for c in ("w_x", "w_y", "w_z")):
            raise BenchCSVError(path, lineno, "w_x",
                                f"position {values.get('position', '?')!r} visited with no readings")
        for h, v in values.items():
            cols[h].append(check_field(path, lineno, h, v))
        key = tuple(values.get(c, "") for c in ("unit", "state", "cycle", "setpoint_C", "direction",
                                                 "position", "time_s"))
        key = key[:3] + (cols["setpoint_C"][-1], key[4], key[5], cols["time_s"][-1])
        if key in keys:
            raise BenchCSVError(path, lineno, "time_s",
                                f"duplicated row: position {values['position']!r} at the same time "
                                f"and setpoint as line {keys[key]}")
        keys[key] = lineno
        when = (values["unit"], values.get("state", ""), cols["time_s"][-1])
        if when in times:
            raise BenchCSVError(path, lineno, "time_s",
                                f"a second visit of unit {values['unit']!r} at the same time as line {times[when]} "
                                "(a unit is in one position at a time)")
        times[when] = lineno
        line_numbers.append(lineno)
    n = len(line_numbers)
    if n == 0:
        raise BenchCSVError(path, header_line, None, "no data rows after the header")

    def arr(name, dtype=float):
        return np.array(cols[name], dtype=dtype)

    opt_cycle = arr("cycle", int) if "cycle" in cols else np.zeros(n, int)
    state = np.array(cols["state"], dtype=object).astype(str) if "state" in cols else np.full(n, "initial")
    sd = np.stack([arr(c) for c in ("sd_x", "sd_y", "sd_z")], axis=1) if "sd_x" in cols else None
    return Campaign(
        unit=np.array(cols["unit"]).astype(str), setpoint_C=arr("setpoint_C"),
        direction=np.array(cols["direction"]).astype(str), time_s=arr("time_s"),
        position=np.array(cols["position"]).astype(str), axis1_deg=arr("axis1_deg"),
        axis2_deg=arr("axis2_deg"), tau_s=arr("tau_s"),
        w=np.stack([arr(c) for c in ("w_x", "w_y", "w_z")], axis=1),
        t=np.stack([arr(c) for c in ("t_x", "t_y", "t_z")], axis=1),
        cycle=opt_cycle, state=state, sd=sd,
        n_samples=arr("n_samples", int) if "n_samples" in cols else None,
        metadata=metadata, source=path, lines=np.array(line_numbers),
        extra={h: np.array(cols[h]).astype(str) for h in header if h not in COLUMNS})


def to_float(s: str) -> Optional[float]:
    try:
        return float(s)
    except ValueError:
        return None


def check_field(path: str, line: int, column: str, value: str):
    """Validate and convert one field; raise :class:`BenchCSVError` naming it."""
    if column not in COLUMNS:
        return value
    if value == "":
        if column == "state":
            return "initial"
        if column == "cycle":
            return 0
        raise BenchCSVError(path, line, column, "empty field")
    if column in FLOATS:
        v = to_float(value)
        if v is None:
            raise BenchCSVError(path, line, column, f"not a number: {value!r}")
        if not math.isfinite(v):
            raise BenchCSVError(path, line, column, f"not a finite number: {value!r}")
        if column == "tau_s" and v <= 0:
            raise BenchCSVError(path, line, column, f"averaging time must be positive, got {value}")
        if column.startswith("sd_") and v < 0:
            raise BenchCSVError(path, line, column, f"a standard deviation cannot be negative, got {value}")
        return v
    if column in ("cycle", "n_samples"):
        try:
            v = int(value)
        except ValueError:
            raise BenchCSVError(path, line, column, f"not an integer: {value!r}") from None
        if column == "n_samples" and v < 1:
            raise BenchCSVError(path, line, column, f"must be at least 1, got {value}")
        if column == "cycle" and v < 0:
            raise BenchCSVError(path, line, column, f"must be 0 or more, got {value}")
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
    if col[:2] in ("w_", "t_") or col.startswith("sd_"):
        arr = {"w": c.w, "t": c.t, "sd": c.sd}[col.split("_")[0]]
        return repr(float(arr[i, xyz[col[-1]]]))
    v = getattr(c, col)[i]
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    return str(v)


def write_bench_csv(c: Campaign, path: Union[str, os.PathLike]) -> None:
    """Write a campaign as bench CSV v1 (atomically: a temporary file renamed into place)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8", newline="") as fh:
        fh.write(format_bench_csv(c))
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
