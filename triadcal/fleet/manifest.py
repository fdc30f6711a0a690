"""Raw recordings in a batch: a manifest (TOML) names each recording and how to read it, so
``triadcal batch`` fits them with ``fit-raw`` beside the bench campaigns (docs/fleet.md).

    [[recording]]
    path = "unit7.csv"            # relative to the manifest
    serial = "SN-0007"
    state = "initial"             # default "initial"
    rate_hz = 100.0
    unit = "m/s2"                 # m/s2 | g | mg | counts (the readings' unit)
    poses = "unknown"             # known | unknown
    columns = ["ax", "ay", "az"]  # optional
    labels = "part"               # optional: a label column naming the poses (known poses)
    local_g_m_s2 = 9.81           # optional

Every key is checked when the manifest is read; an unknown one is refused with the manifest,
the entry and the key named."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from ..errors import InputError

KEYS = {"path": str, "serial": str, "state": str, "rate_hz": float, "unit": str, "poses": str, "columns": list,
        "labels": str, "local_g_m_s2": float}
REQUIRED = ("path", "serial", "rate_hz", "unit", "poses")


@dataclass(frozen=True)
class RawEntry:
    path: Path
    serial: str
    state: str
    rate_hz: float
    unit: str
    poses: str
    columns: Optional[tuple] = None
    labels: Optional[str] = None
    local_g_m_s2: Optional[float] = None     # not stated: fit-raw assumes 9.81 and says so


def is_manifest(path) -> bool:
    return str(path).lower().endswith(".toml")


def read_manifest(path) -> list:
    """The entries of a manifest, validated (see the module)."""
    path = Path(path)
    from ..io.atomic import read_toml

    data = read_toml(path, "a manifest")
    unknown = [k for k in data if k != "recording"]
    if unknown or not isinstance(data.get("recording"), list) or not data["recording"]:
        raise InputError(f"{path}: a manifest holds [[recording]] entries only"
                         + (f"; unknown: {', '.join(unknown)}" if unknown else ""))
    out = []
    first: dict = {}
    for i, e in enumerate(data["recording"], start=1):
        where = f"{path}: recording {i}"
        bad = [k for k in e if k not in KEYS]
        if bad:
            raise InputError(f"{where}: unknown key {bad[0]!r}; known: {', '.join(KEYS)}")
        missing = [k for k in REQUIRED if k not in e]
        if missing:
            raise InputError(f"{where}: {', '.join(missing)} missing")
        for k, v in e.items():
            typ = KEYS[k]
            if typ is float and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0):
                raise InputError(f"{where}: {k} must be a positive number, got {v!r}")
            if typ is str and not isinstance(v, str):
                raise InputError(f"{where}: {k} must be a string, got {v!r}")
            if k in ("serial", "state", "path") and not v.strip():
                # serial = "" was fitted under the recording's file name (fit-raw's fallback), while the
                # summary listed unit '' (an outside probe); state = "" became a state of its own
                raise InputError(f"{where}: {k} is empty" + ("; leave it out for 'initial'" if k == "state" else ""))
            if typ is list and not (isinstance(v, list) and len(v) == 3 and all(isinstance(c, str) for c in v)):
                raise InputError(f"{where}: columns must be a list of three column names, got {v!r}")
        if "local_g_m_s2" in e:
            from ..io.bench_csv import LOCAL_G_RANGE_M_S2

            low, high = LOCAL_G_RANGE_M_S2
            if not low <= e["local_g_m_s2"] <= high:
                # fit-raw's refusal named its command-line options, which a manifest has none of
                raise InputError(f"{where}: local_g_m_s2 = {e['local_g_m_s2']:g} m/s2 is outside {low}-{high} m/s2, "
                                 "the local gravity anywhere on Earth's surface (it is in m/s2, not in g)")
        if e["unit"] not in ("m/s2", "g", "mg", "counts"):
            raise InputError(f"{where}: unit {e['unit']!r}; choose m/s2, g, mg or counts")
        if e["poses"] not in ("known", "unknown"):
            raise InputError(f"{where}: poses {e['poses']!r}; choose known or unknown")
        rec = (path.parent / e["path"]).resolve()
        if not rec.is_file():
            raise InputError(f"{where}: {e['path']}: no such file (paths are relative to the manifest)")
        from .batch import same_name_key

        # compared as batch compares them: no surrounding spaces, Unicode NFC (docs/fleet.md)
        key = (same_name_key(e["serial"]), same_name_key(e.get("state", "initial")))
        if key in first:
            raise InputError(f"{where}: serial {e['serial']} in state {e.get('state', 'initial')} is also recording {first[key]}: one result "
                             "file would hold one of them; give each serial and state once")
        first[key] = i
        out.append(RawEntry(rec, e["serial"], e.get("state", "initial"), float(e["rate_hz"]), e["unit"], e["poses"],
                            tuple(e["columns"]) if "columns" in e else None, e.get("labels"),
                            (float(e["local_g_m_s2"]) if "local_g_m_s2" in e else None)))
    return out
