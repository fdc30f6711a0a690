"""The calibration history per serial number: an SQLite database (standard library) with one
table ``calibrations(id, serial, state, date, lab, equipment, result, sha256, added)``;
``equipment`` and ``result`` are JSON text, ``sha256`` that of the result's JSON text without its own
``content_sha256`` (unique: recording the same result twice is a no-op, whether or not the document
carries its checksum)."""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import sqlite3
from pathlib import Path
from typing import Optional

from ..errors import InputError

DEFAULT_DB = "triadcal-history.sqlite"
SCHEMA = """
CREATE TABLE IF NOT EXISTS calibrations (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    serial TEXT NOT NULL,
    state TEXT NOT NULL DEFAULT '',
    date TEXT NOT NULL,
    lab TEXT NOT NULL DEFAULT '',
    equipment TEXT NOT NULL DEFAULT '{}',
    result TEXT NOT NULL,
    sha256 TEXT NOT NULL UNIQUE,
    added TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS calibrations_serial ON calibrations (serial, date);
"""


def history_path(db: Optional[str] = None, lab=None) -> Path:
    """``db`` if given, else the lab file's ``[history] path`` (relative to the lab file's
    folder), else triadcal-history.sqlite in the current directory."""
    if db:
        return Path(db)
    if lab is not None and getattr(lab, "history_path", ""):
        p = Path(lab.history_path)
        if not p.is_absolute() and lab.source:
            p = Path(lab.source).parent / p
        return p
    return Path(DEFAULT_DB)


def equipment_of(lab) -> dict:
    if lab is None:
        return {}
    eq = {k: dict(v) for k, v in lab.equipment.items()}
    for section, name in (("bench", lab.bench), ("fixture", lab.fixture), ("chamber", lab.chamber),
                          ("thermometers", lab.thermometers), ("voltmeter", lab.voltmeter)):
        if name:
            eq.setdefault(section, {})["name"] = name
    return eq


class HistoryDB:
    """``with HistoryDB(path) as db: db.add(result_dict, lab=...)``; :meth:`calibrations`."""

    def __init__(self, path):
        self.path = Path(path)
        if self.path.parent and not self.path.parent.exists():
            raise InputError(f"{self.path}: folder {self.path.parent} does not exist")
        if self.path.is_dir():
            raise InputError(f"{self.path}: is a folder, not a calibration history database (SQLite)")
        try:
            self.con = sqlite3.connect(self.path, timeout=30)
        except sqlite3.Error as exc:
            raise InputError(f"{self.path}: cannot open the calibration history database: {exc}") from None
        try:
            self.con.executescript(SCHEMA)
            cols = [r[1] for r in self.con.execute("PRAGMA table_info(calibrations)")]
        except sqlite3.DatabaseError as exc:
            self.con.close()
            raise InputError(f"{self.path}: not a usable calibration history database (SQLite): {exc}") from None
        need = ("id", "serial", "state", "date", "lab", "equipment", "result", "sha256", "added")
        if any(c not in cols for c in need):
            self.con.close()
            raise InputError(f"{self.path}: its table calibrations lacks {', '.join(c for c in need if c not in cols)}: "
                             "not a triadcal calibration history")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self.con.close()

    def add(self, result: dict, lab=None, date: Optional[str] = None, source: Optional[str] = None) -> bool:
        """Record a result (results-json document; ``source``, its file, names it in messages); False
        when it was already recorded."""
        from ..io.atomic import json_safe

        from ..estimation.result import CONTENT_HASH_KEY

        text = json.dumps(json_safe(result), sort_keys=True, allow_nan=False)
        # the identity of a calibration is its content without its own checksum: batch recorded a fit
        # as fitted (no content_sha256) and, on the rerun that skipped it, as read back from its file
        # (with it): two calibrations of one unchanged result, and an inconclusive compare between them
        # (an outside probe)
        body = json.dumps(json_safe({k: v for k, v in result.items() if k != CONTENT_HASH_KEY}), sort_keys=True,
                          allow_nan=False)
        sha = hashlib.sha256(body.encode("utf-8")).hexdigest()
        b = result.get("batch") or {}
        # the data's own date before the lab's and today's: a fit's result recorded with --add took today's
        # date where the data stated theirs, and the history put a 2024 calibration after a 2026 one
        given = (("--date", date), ("the result's batch.date", b.get("date")), ("the result's date", result.get("date")),
                 ("the result's data_date", result.get("data_date")),
                 ("the lab file's calibration_date", lab.calibration_date if lab is not None else ""))
        where, raw = next(((w, v) for w, v in given if v), ("today", _dt.datetime.now(_dt.timezone.utc).date().isoformat()))
        from ..io.dates import ISO_HINT, iso_date

        date = iso_date(raw)
        what = f"{source}: " if source else f"{self.path}: the calibration of {result.get('unit')!r}: "
        if date is None:
            raise InputError(f"{what}{where} = {raw!r} is not {ISO_HINT}")
        from ..io.dates import future_problem

        late = future_problem(date, "a calibration")
        if late:
            raise InputError(f"{what}{where}: {late}")
        lab_name = (lab.name if lab is not None else "") or b.get("lab", "")
        state = b.get("state") or result.get("state") or ""
        try:
            with self.con:
                cur = self._insert(result, state, date, lab_name, lab, text, sha)
        except sqlite3.DatabaseError as exc:
            raise InputError(f"{self.path}: cannot record in the calibration history database: {exc}") from None
        return cur.rowcount == 1

    def _insert(self, result, state, date, lab_name, lab, text, sha):
        return self.con.execute(
            "INSERT OR IGNORE INTO calibrations (serial, state, date, lab, equipment, result, sha256, added) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            (str(result["unit"]), state, str(date), lab_name, json.dumps(equipment_of(lab), sort_keys=True),
             text, sha, _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")))

    def unhashed_or_edited(self, result: dict) -> Optional[str]:      # (self unused: also called as a function)
        """Why a result recorded here is not known to be the fit's answer (no ``content_sha256``, or one
        that does not match), or None."""
        from ..estimation.result import CONTENT_HASH_KEY, content_sha256

        sha = result.get(CONTENT_HASH_KEY)
        if sha is None:
            return "holds no content_sha256 (another writer, or triadcal before 2026-11-30)"
        try:
            return None if content_sha256(result) == sha else "its content_sha256 does not match its content"
        except (TypeError, ValueError):
            return "its content cannot be hashed"

    def calibrations(self, serial: str) -> list[dict]:
        """Every recorded calibration of ``serial``, oldest first (by date, then by when recorded)."""
        try:
            rows = self.con.execute("SELECT id, serial, state, date, lab, equipment, result, sha256, added FROM "
                                    "calibrations WHERE serial = ? ORDER BY date, id", (serial,)).fetchall()
        except sqlite3.DatabaseError as exc:
            raise InputError(f"{self.path}: cannot read the calibration history database: {exc}") from None
        out = []
        for row in rows:
            out.append({"id": row[0], "serial": row[1], "state": row[2], "date": row[3], "lab": row[4],
                        "equipment": json.loads(row[5]), "result": json.loads(row[6]), "sha256": row[7],
                        "added": row[8]})
        return out

    def serials(self) -> list[str]:
        return [r[0] for r in self.con.execute("SELECT DISTINCT serial FROM calibrations ORDER BY serial")]


def shown_parameters(calibrations) -> list[str]:
    """Angles, K and S present in any of the calibrations, in a fixed order."""
    order = [f"Ca_{a}" for a in ("xy", "xz", "yx", "yz", "zx", "zy")] + [f"K_{a}" for a in "xyz"] + \
            [f"S_{a}" for a in "xyz"]
    return [n for n in order if any(n in c["result"].get("parameters", {}) for c in calibrations)]


def verdicts(calibrations) -> list[str]:
    """The ``compare`` overall verdict (significance only: tolerance_arcsec=None) of each
    calibration against the one before it, or why there is none."""
    from ..estimation.result import CalibrationResult
    from ..judgement.compare import compare

    out = []
    for a, b in zip(calibrations, calibrations[1:]):
        try:
            before = CalibrationResult.from_dict(a["result"], f"history #{a['id']}")
            after = CalibrationResult.from_dict(b["result"], f"history #{b['id']}")
            out.append(compare(before, after, tolerance_arcsec=None).overall)
        except InputError as exc:
            out.append(f"not compared: {exc}")
    return out


def history_text(serial: str, calibrations) -> str:
    from ..estimation.result import round_to_uncertainty

    if not calibrations:
        return f"{serial}: no calibration recorded"
    from ..io.dates import iso_date

    lines = [f"{serial}: {len(calibrations)} calibration(s)"]
    unsure = []
    for i, c in enumerate(calibrations, 1):
        r = c["result"]
        why = HistoryDB.unhashed_or_edited(None, r)
        if why:
            unsure.append((i, why))
        lines.append(f"  #{i} {c['date']}  state {c['state'] or '-'}  lab {c['lab'] or '-'}  method "
                     f"{r.get('method')}  status {r.get('status')}" + ("  [not known to be the fit's answer]" if why else ""))
    names = shown_parameters(calibrations)
    # every cell is "value ± u unit" (a serial's calibrations may be in different units: g/V,
    # g/counts), and the columns are as wide as their widest cell, two spaces apart
    table = []
    for n in names:
        cells = []
        for c in calibrations:
            p = c["result"].get("parameters", {}).get(n)
            if p is None or p.get("value") is None or p.get("u") is None:
                cells.append("-")
                continue
            v, u = round_to_uncertainty(p["value"], p["u"])
            cells.append(f"{v} ± {u} {p.get('unit', '')}".rstrip())
        table.append((n, cells))
    widths = [max([len(f"#{i}")] + [len(cells[i - 1]) for _, cells in table])
              for i in range(1, len(calibrations) + 1)]
    name_w = max([len("parameter")] + [len(n) for n in names])
    lines += ["", "  " + "parameter".ljust(name_w) + "".join("  " + f"#{i}".rjust(w) for i, w in enumerate(widths, 1))]
    for n, cells in table:
        lines.append("  " + n.ljust(name_w) + "".join("  " + c.rjust(w) for c, w in zip(cells, widths)))
    vs = verdicts(calibrations)
    if vs:
        lines += ["", "  compare (consecutive, significance only):"]
        for i, v in enumerate(vs, 1):
            lines.append(f"    #{i} -> #{i + 1}: {v}")
    # an outside probe: five results recorded without --date all got today's date and the history
    # compared them in the order they were added, not the order of the events, with no word
    # an outside probe: a result whose checksum had been deleted and Ca_xy edited by 30 arcsec was recorded and
    # compared ("fail") without a word, where compare notes such a file and the certificate refuses it
    if unsure:
        lines += ["", "  note: " + "; ".join(f"#{i} {why}" for i, why in unsure) + ": nothing shows that its values "
                  "are the fit's answer and not edited, and its verdicts rest on them"]
    odd = [f"#{i} ({c['date']})" for i, c in enumerate(calibrations, 1) if iso_date(c["date"]) != c["date"]]
    if odd:
        lines += ["", "  note: the date of " + ", ".join(odd) + " is not an ISO 8601 date (YYYY-MM-DD), so the order "
                  "above (by the date's text) need not be the order of the events (a database written before "
                  "2026-12-01, which recorded dates unchecked)"]
    same = [i for i in range(1, len(calibrations)) if calibrations[i]["date"] == calibrations[i - 1]["date"]]
    if same:
        lines += ["", "  note: " + ", ".join(f"#{i} and #{i + 1}" for i in same) + " have the same date, so they are "
                  "listed (and compared) in the order they were recorded, which need not be the order of the events; "
                  "record each with --date (or a result or lab file that states it)"]
    return "\n".join(lines)


def plot_history(serial: str, calibrations, path) -> None:
    """Each angle against the calibration date with its error bar (k = 1), one panel per angle."""
    from matplotlib.figure import Figure      # no pyplot: no backend, no global state

    from ..io.atomic import atomic_path

    angles = [n for n in shown_parameters(calibrations) if n.startswith("Ca_")]
    if not angles:
        raise InputError(f"{serial}: no angle recorded to plot")
    fig = Figure(figsize=(9, 5.5))
    for k, n in enumerate(angles):
        ax = fig.add_subplot(2, 3, k + 1)
        xs, ys, us = [], [], []
        for c in calibrations:
            p = c["result"].get("parameters", {}).get(n)
            if p and p.get("value") is not None and p.get("u") is not None:
                try:
                    xs.append(_dt.date.fromisoformat(c["date"][:10]))
                except ValueError:
                    # skipped without a word, every point of a history with day-first dates was left out and
                    # an empty figure written (an outside probe)
                    raise InputError(f"{serial}: calibration #{c['id']} is dated {c['date']!r}, not an ISO 8601 "
                                     "date (YYYY-MM-DD): it cannot be placed on the time axis") from None
                ys.append(p["value"])
                us.append(p["u"])
        ax.errorbar(xs, ys, yerr=us, fmt="o-", capsize=3)
        ax.set_title(f"{n} (arcsec)", fontsize=9)
        ax.tick_params(labelsize=7)
        for lab in ax.get_xticklabels():
            lab.set_rotation(30)
    fig.suptitle(f"{serial}: angles over time (error bars: u, k = 1)")
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=90)
