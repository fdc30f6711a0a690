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
import re
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


#: metadata keys that triadcal reads (``metadata.get`` / ``metadata[...]`` across the package):
#: a key that differs from one of them only by case, or is a close misspelling, is refused
#: rather than ignored (docs/bench-csv.md, "Three misreads refused")
KNOWN_METADATA = ("local_g_m_s2", "local_g_override", "output_unit", "Q_V2s", "power_on_s", "quantisation_lsb",
                  "u_w_method", "dTdt_method", "ramp", "date", "bench", "t_override")
#: metadata keys triadcal's own writers put in a file (simulate, capture and its noise estimate,
#: fit-raw, the lab file):
#: accepted as they are, however close to a known key they look (``input_unit``, ``temperature``)
WRITTEN_METADATA = ("generator", "seed", "ramp_setpoint", "ramp_labels", "raw_samples", "stabilisation",
                    "settle_s", "plan", "operator", "imu_protocol", "imu_temperature", "noise_method", "readout",
                    "samples_per_window", "unit_temperature", "source", "rate_hz", "input_unit", "temperature",
                    "emulator", "local_g_source",
                    *(f"Q_{a}_V2s" for a in "xyz"), *(f"bias_instability_{a}_V" for a in "xyz"))   # hardware/noise.py
#: difflib ratio at or above which a key is a misspelling of a known key
METADATA_CUTOFF = 0.8


def near_metadata_key(key: str) -> Optional[str]:
    """The known metadata key (:data:`KNOWN_METADATA`) that ``key`` is most likely a mistyped
    form of, or None: the same key in another case or with spaces or hyphens for underscores;
    a known key with up to 2 characters more (``output_units``); the start of a known key of
    at least 5 characters and 55 % of its length (``local_g`` for ``local_g_m_s2``); or a
    difflib ratio of at least :data:`METADATA_CUTOFF`. Exact known or written keys are None."""
    import difflib
    import re

    if key in KNOWN_METADATA or key in WRITTEN_METADATA:
        return None
    norm = re.sub(r"[\s\-]+", "_", key.lstrip("#").strip()).lower()
    lower = {k.lower(): k for k in KNOWN_METADATA}
    if not norm:
        return None
    if norm in lower:
        return lower[norm]
    if "gravity" in norm or norm.startswith("local_g"):
        return "local_g_m_s2"       # '# Local gravity = 9.8123' was ignored: standard gravity taken
    for low, k in lower.items():
        if norm.startswith(low) and len(norm) - len(low) <= 2:
            return k
        if low.startswith(norm) and len(norm) >= 5 and len(norm) >= 0.55 * len(low):
            return k
    close = difflib.get_close_matches(norm, list(lower), n=1, cutoff=METADATA_CUTOFF)
    return lower[close[0]] if close else None


#: the keys whose ':' form is refused (:func:`_check_comment_key`): those the fit reads as numbers,
#: flags or the output unit -- a value ignored there changes the answer
COLON_CHECKED = ("local_g_m_s2", "local_g_override", "output_unit", "Q_V2s", "power_on_s", "quantisation_lsb",
                 "t_override")


def _value_of_kind(key: str, value: str) -> bool:
    """Whether ``value`` is what ``key`` holds: a flag, a unit, or a number."""
    v = value.split()[0] if value.split() else ""
    if key.endswith("override"):
        return v.lower() in ("true", "false")
    if key == "output_unit":
        return v in ("V", "mV", "uV", "counts", "A", "mA", "uA", "g", "mg", "ug", "m/s2", "m/s^2")
    try:
        float(v)
    except ValueError:
        return False
    return True


def _check_comment_key(path, lineno, body):
    """Refuse a ``#`` line that was meant as metadata of a known key but will not be read as
    it: ``key: value`` instead of ``key = value``, or a key mistyped (case, spelling)."""
    if "=" in body:
        key = body.split("=", 1)[0].strip()
        if ":" in key:                                  # '# local_g_m_s2: 9.78 = measured'
            left = key.split(":", 1)[0].strip()
            known = left if left in KNOWN_METADATA else near_metadata_key(left)
            if known is not None:
                raise BenchCSVError(path, lineno, None,
                                    f"metadata line '# {body}' has ':' after the key '{left}', so its key would be "
                                    f"{key!r} and '{known}' ignored: a metadata line is '# {known} = value'")
        near = near_metadata_key(key)
        if near is not None:
            raise BenchCSVError(path, lineno, None,
                                f"metadata key {key!r} is not one triadcal reads: did you mean {near!r}? (a key "
                                f"close to a known one is refused rather than ignored; write '# {near} = "
                                f"{body.split('=', 1)[1].strip()}')")
        return
    if ":" in body:
        # prose is written 'Key: text' too ('# Power on: 08:00 local time', '# Date: see log book'):
        # a ':' line is refused only when its key is exactly one the model reads (any case, spaces for
        # underscores) and its value is of that key's kind -- a number, true/false, or an output unit
        left, value = (s.strip() for s in body.split(":", 1))
        norm = re.sub(r"[\s\-]+", "_", left).lower()
        known = next((k for k in COLON_CHECKED if k.lower() == norm), None)
        if known is not None and value and _value_of_kind(known, value):
            raise BenchCSVError(path, lineno, None,
                                f"metadata line '# {body}' uses ':' where the format has '=': it would be a "
                                f"comment and '{known}' ignored; write '# {known} = {value}'")


def _metadata(lines, path):
    metadata: dict[str, str] = {}
    where: dict[str, int] = {}
    k = 0
    while k < len(lines) and (lines[k].startswith("#") or not lines[k].strip()):
        body = lines[k][1:].strip() if lines[k].startswith("#") else ""
        _check_comment_key(path, k + 1, body)
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
    if metadata.get("t_override", "false").lower() != "true":
        _check_temperature_unit(path, campaign)
    _check_directions(path, campaign)
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


#: degF check (docs/bench-csv.md, "Three misreads refused"), each t_* column on its own.
#: Setpoints spanning at least FAHRENHEIT_SPAN_C: the least-squares slope of t on setpoint_C in
#: FAHRENHEIT_SLOPE (degF: 1.8; degC: about 1, less with a thermal lag), the median |t - setpoint|
#: at least FAHRENHEIT_MIN_OFFSET_C, and the median |(t - 32)/1.8 - setpoint| at most
#: FAHRENHEIT_MAX_RESIDUAL_C or a quarter of the median |t - setpoint|, whichever is more.
FAHRENHEIT_SPAN_C = 10.0
FAHRENHEIT_SLOPE = (1.4, 2.2)
FAHRENHEIT_MIN_OFFSET_C = 5.0
FAHRENHEIT_MAX_RESIDUAL_C = 5.0
#: one setpoint (a span below FAHRENHEIT_SPAN_C): only the offset tells, so it must be larger
FAHRENHEIT_MIN_OFFSET_ONE_SETPOINT_C = 20.0
#: a ramp (setpoint_C the target of a leg, so t is far from it): at least FAHRENHEIT_HOT_SHARE of the
#: visits read FAHRENHEIT_HOT_C above the highest setpoint, t spans at least FAHRENHEIT_HOT_C and
#: 1.2 times the setpoints, and (t - 32)/1.8 lies within FAHRENHEIT_HOT_C / 2 of the setpoints' range
FAHRENHEIT_HOT_C = 20.0
FAHRENHEIT_HOT_SHARE = 0.2


def _fahrenheit(t, S):
    """Why the readings ``t`` of one column look like degF against the setpoints ``S``, or None."""
    d, u = t - S, (t - 32.0) / 1.8
    md, mf = float(np.median(np.abs(d))), float(np.median(np.abs(u - S)))
    span = float(np.ptp(S))
    close = mf <= max(FAHRENHEIT_MAX_RESIDUAL_C, 0.25 * md)
    why = (f"median |t - setpoint_C| over the {len(t)} visits {md:.3g} degC, while (t - 32)/1.8 is within "
           f"{mf:.2g} degC of the setpoint (median)")
    if span >= FAHRENHEIT_SPAN_C:
        b, a = np.polyfit(S, t, 1)
        if FAHRENHEIT_SLOPE[0] <= b <= FAHRENHEIT_SLOPE[1] and md >= FAHRENHEIT_MIN_OFFSET_C and close:
            return np.abs(d) >= 0.5 * md, why + f"; t = {a:.3g} + {b:.3g} setpoint_C (degF: 32 + 1.8 setpoint_C)"
    elif md >= FAHRENHEIT_MIN_OFFSET_ONE_SETPOINT_C and close:
        return np.abs(d) >= 0.5 * md, why
    lo, hi = float(np.min(S)), float(np.max(S))
    hot = t > hi + FAHRENHEIT_HOT_C
    inside = (u >= lo - FAHRENHEIT_HOT_C / 2) & (u <= hi + FAHRENHEIT_HOT_C / 2)
    if (hot.mean() >= FAHRENHEIT_HOT_SHARE and inside.all()
            and np.ptp(t) >= max(FAHRENHEIT_HOT_C, 1.2 * span)):
        return hot, (f"{100 * hot.mean():.0f} % of the visits read more than {FAHRENHEIT_HOT_C:g} degC above the "
                     f"highest setpoint, {hi:g} degC, while (t - 32)/1.8 lies within the setpoints' "
                     f"{lo:g} to {hi:g} degC")
    return None


def _check_temperature_unit(path, c: Campaign) -> None:
    """Refuse t_* columns that read as degF against the setpoints (:func:`_fahrenheit`,
    docs/bench-csv.md, "Three misreads refused"); ``# t_override = true`` skips the check."""
    S = np.asarray(c.setpoint_C, float)
    for j, col in enumerate(("t_x", "t_y", "t_z")):
        t = np.asarray(c.t[:, j], float)
        found = _fahrenheit(t, S)
        if found is None:
            continue
        shows, why = found
        i = int(np.flatnonzero(shows)[0])           # the first visit, in file order, that shows it
        raise BenchCSVError(
            path, int(c.lines[i]) if c.lines is not None else i + 1, col,
            f"{col} = {t[i]:g} at setpoint_C {S[i]:g}: the temperatures look like degF, not degC ({why}); the "
            "t_* columns are degC: convert with (t - 32)/1.8. If they are degC readings (an oven-controlled "
            "unit far from the chamber's setpoint), add the line '# t_override = true'")


#: consecutive visits (of one unit, state and cycle, in time order) whose setpoints differ by at most
#: this (degC) are one block of the direction check
SETPOINT_SAME_C = 0.01
#: a block whose setpoint differs from the previous block's by less than this (degC) is not checked
SETPOINT_STEP_C = 1.0
#: a visit labelled with the previous block's direction against a setpoint change is the unit not yet
#: turned (a ramp as the unit sees it) only while its temperature has moved toward the new setpoint
#: by at most this fraction of the step since the previous block's last visit
CARRY_OVER_FRACTION = 0.25
#: in a ramp file, a direction opposed to the visit's temperature rate by more than this (degC/min) is refused
DIRECTION_RATE_C_PER_MIN = 0.2
#: ... or when more than half the labelled visits whose rate is at least this (degC/min) are against it
DIRECTION_RATE_NOISE_C_PER_MIN = 0.02
OPPOSITE = {"heating": "cooling", "cooling": "heating"}


#: the direction check refuses a stepped file when at least this many of its setpoint changes, and
#: more than half of those checked, contradict their heating/cooling labels
DIRECTION_MIN_AGAINST = 2


def _check_directions(path, c: Campaign) -> None:
    """Refuse a ``direction`` that contradicts the file's own thermal history (docs/bench-csv.md,
    "Three misreads refused"), for each unit, state and cycle in time order.

    A ramp file (metadata ``ramp`` or the column ``dTdt_C_per_min``: ``simulate --ramp``,
    ``capture --ramp``) labels each visit with the sign of the unit's rate (docs/hardware.md):
    ``heating`` is refused where the reading falls faster than :data:`DIRECTION_RATE_C_PER_MIN`,
    ``cooling`` where it rises that fast. Any other file: after the first block of visits at one
    setpoint, ``heating`` needs a setpoint above the previous block's and ``cooling`` one below
    (``none`` is always accepted; a change below :data:`SETPOINT_STEP_C` is not checked), except at the start of a block, before any visit with the
    expected label, for visits that keep the previous block's last label while the unit's
    temperature has not moved toward the new setpoint by more than :data:`CARRY_OVER_FRACTION`
    of the step (a ramp labelled as the unit sees it, which turns after the program)."""
    n = c.n_visits
    if n < 2:
        return
    lines = c.lines if c.lines is not None else np.arange(1, n + 1)
    groups: dict = {}
    for i, key in enumerate(zip(c.unit.tolist(), c.state.tolist(), np.asarray(c.cycle).tolist())):
        groups.setdefault(key, []).append(i)
    ramp = "ramp" in c.metadata or c.dTdt_C_per_min is not None
    T = np.mean(np.asarray(c.t, float), axis=1)
    for idx in groups.values():
        idx = np.array(idx)[np.argsort(c.time_s[idx], kind="stable")]
        if len(idx) < 2:
            continue
        if ramp:
            rate = _group_rate(c, idx)
            sign = np.array([{"heating": 1.0, "cooling": -1.0}.get(d, 0.0) for d in c.direction[idx]])
            bad = np.flatnonzero(sign * rate < -DIRECTION_RATE_C_PER_MIN)
            moving = (sign != 0) & (np.abs(rate) >= DIRECTION_RATE_NOISE_C_PER_MIN)
            against = moving & (sign * rate < 0)
            most = ""
            if not len(bad) and moving.sum() >= 10 and against.sum() > 0.5 * moving.sum():
                bad = np.flatnonzero(against)       # a slow ramp: most labels against their rates
                most = (f"; {int(against.sum())} of the {int(moving.sum())} labelled visits moving faster than "
                        f"{DIRECTION_RATE_NOISE_C_PER_MIN:g} degC/min are against their rate")
            if len(bad):
                i, r = int(idx[bad[0]]), float(rate[bad[0]])
                src = ("dTdt_C_per_min" if c.dTdt_C_per_min is not None
                       else "central differences of the mean t_* within its block")
                raise BenchCSVError(
                    path, int(lines[i]), "direction",
                    f"direction '{c.direction[i]}', but the unit's temperature {'falls' if r < 0 else 'rises'} at "
                    f"{abs(r):.3g} degC/min during this visit ({src}{most}): in a ramp file the direction is the "
                    "sign of the unit's rate (heating on a rise, cooling on a fall); are heating and cooling swapped?")
            continue
        sp = np.asarray(c.setpoint_C, float)[idx]
        starts = [0] + [k for k in range(1, len(idx)) if abs(sp[k] - sp[k - 1]) > SETPOINT_SAME_C] + [len(idx)]
        checked, against = 0, []
        for b in range(1, len(starts) - 1):
            S, P, last = sp[starts[b]], sp[starts[b] - 1], int(idx[starts[b] - 1])
            if abs(S - P) < SETPOINT_STEP_C:
                continue                # too small a change to say (a setpoint written as measured)
            want, turned = ("heating" if S > P else "cooling"), False
            labels = {str(c.direction[i]) for i in idx[starts[b]:starts[b + 1]]}
            checked += bool(labels & {"heating", "cooling"})
            for i in idx[starts[b]:starts[b + 1]]:
                d = str(c.direction[i])
                turned = turned or d == want
                if d != OPPOSITE[want]:
                    continue
                moved = (T[i] - T[last]) * np.sign(S - P)
                if not turned and d == str(c.direction[last]) and moved <= CARRY_OVER_FRACTION * abs(S - P):
                    continue            # the unit has not turned yet: the previous block's direction goes on
                against.append((i, P, S, want, d, last))
                break
        # swapped labels contradict (nearly) every block; a unit taken beyond the next setpoint and back
        # without logging it (a preconditioning excursion) contradicts one or a few, rightly: refuse only
        # when at least MIN_AGAINST blocks and more than half of those checked contradict the sequence
        if len(against) >= DIRECTION_MIN_AGAINST and len(against) > 0.5 * checked:
            i, P, S, want, d, last = against[0]
            raise BenchCSVError(
                path, int(lines[i]), "direction",
                f"the setpoint went from {P:g} degC (line {int(lines[last])}) to {S:g} degC: that is {want}, "
                f"not {d} (direction says how the chamber arrived at this setpoint from the previous one), and "
                f"{len(against)} of the {checked} setpoint changes checked contradict their labels so; are heating "
                "and cooling swapped? (a unit taken past a setpoint without a logged visit contradicts only its "
                "own block; give such excursions visits, or their own cycle numbers)")


def _group_rate(c: Campaign, idx) -> np.ndarray:
    """Rate of the unit's temperature reading (degC/min) at the visits ``idx`` (one unit, state
    and cycle, in time order): ``dTdt_C_per_min`` when the file has it, else central differences
    of the mean of t_x, t_y, t_z within each run of visits of one setpoint and direction (one-sided
    at its ends, 0 for a run of one visit), so a soak between two setpoints is not a rate."""
    if c.dTdt_C_per_min is not None:
        return np.asarray(c.dTdt_C_per_min, float)[idx]
    T = np.mean(np.asarray(c.t, float)[idx], axis=1)
    time = np.asarray(c.time_s, float)[idx]
    key = list(zip(c.setpoint_C[idx].tolist(), c.direction[idx].tolist()))
    out = np.zeros(len(idx))
    start = 0
    for k in range(1, len(idx) + 1):
        if k == len(idx) or key[k] != key[start]:
            if k - start >= 2 and np.all(np.diff(time[start:k]) > 0):
                out[start:k] = np.gradient(T[start:k], time[start:k]) * 60.0
            start = k
    return out


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
                                f"implies K = {K:.4g} g/{unit}, outside the plausible {lo:g}-{hi:g} g/{unit}")


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
