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


def identity_sha256(result: dict) -> str:
    """The identity of a recorded calibration (the table's ``sha256``): the SHA-256 of its content
    without its own checksum."""
    from ..estimation.result import CONTENT_HASH_KEY
    from ..io.atomic import json_safe

    # the identity of a calibration is its content without its own checksum: batch recorded a fit
    # as fitted (no content_sha256) and, on the rerun that skipped it, as read back from its file
    # (with it): two calibrations of one unchanged result, and an inconclusive compare between them
    # (an outside probe)
    body = json.dumps(json_safe({k: v for k, v in result.items() if k != CONTENT_HASH_KEY}), sort_keys=True,
                      allow_nan=False)
    return hashlib.sha256(body.encode("utf-8")).hexdigest()


class HistoryDB:
    """``with HistoryDB(path) as db: db.add(result_dict, lab=...)``; :meth:`calibrations`."""

    def __init__(self, path):
        self.path = Path(path)
        self.date_source = ""       # where the last add() took its date from (see add)
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

        text = json.dumps(json_safe(result), sort_keys=True, allow_nan=False)
        sha = identity_sha256(result)
        b = result.get("batch") or {}
        # the data's own date before the lab's and today's: a fit's result recorded with --add took today's
        # date where the data stated theirs, and the history put a 2024 calibration after a 2026 one
        given = (("--date", date), ("the result's batch.date", b.get("date")), ("the result's date", result.get("date")),
                 ("the result's data_date", result.get("data_date")),
                 ("the lab file's calibration_date", lab.calibration_date if lab is not None else ""))
        where, raw = next(((w, v) for w, v in given if v), ("today", _dt.datetime.now(_dt.timezone.utc).date().isoformat()))
        self.date_source = where        # "today": the caller says so (the history orders by this date)
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


def data_hashes(result) -> set:
    """The hashes naming the data a result was fitted to: its ``data_sha256`` and, for a bench CSV
    averaged from a raw recording, ``derived_from_sha256`` (the rule of compare's ``same_data``)."""
    if not isinstance(result, dict):
        return set()
    return {result.get(k) for k in ("data_sha256", "derived_from_sha256")
            if isinstance(result.get(k), str) and result.get(k)}


def _short(text: str, limit: int = 160) -> str:
    """The head of a message: up to its first ``: `` or `` -- `` after a dozen characters (the
    explanation after it is compare's, for a reader of one comparison), at most ``limit`` characters."""
    import re

    text = re.sub(r"^(before and after|#\d+ and #\d+): ", "", " ".join(str(text).split()))
    cut = len(text)
    for sep in (": ", " -- "):
        k = text.find(sep, 12)
        if 0 <= k < cut:
            cut = k
    text = text[:cut]
    return text if len(text) <= limit else text[:limit - 3].rstrip() + "..."


def inconclusive_reason(comparison) -> str:
    """Why compare's overall verdict is inconclusive, in a few words: the note of a verdict held back
    from pass (same data, same calibration, an angle missing, an unjudged parameter that moved, a
    correlation the budgets do not support), else the judged parameters that are not a pass against the
    joint test of the angles (significance only: an angle significant alone while the joint test is
    not)."""
    import math

    from ..judgement.compare import NOT_PASS_NOTE

    held = [n[len(NOT_PASS_NOTE):] for n in comparison.notes if isinstance(n, str) and n.startswith(NOT_PASS_NOTE)]
    if held:
        more = f" (and {len(held) - 1} more: see triadcal compare)" if len(held) > 1 else ""
        return _short(held[0]) + more
    open_ = sorted((p for p in comparison.parameters.values() if p.judged and p.verdict != "pass"),
                   key=lambda p: -abs(p.z) if math.isfinite(p.z) else 0.0)
    if not open_:
        return "no reason identified: see triadcal compare on the two results"
    shown = ", ".join(f"{p.name} {p.drift:+.3g} {p.unit} (z {p.z:.2f}, "
                      + ("significant alone" if p.verdict == "fail" else p.verdict) + ")" for p in open_[:3])
    if len(open_) > 3:
        shown += f" and {len(open_) - 3} more"
    j = comparison.joint
    if j is None:
        return shown + "; no joint test of the angles"
    if not j.significant:
        return (shown + f", but the joint test of the {j.dof} angles is not significant "
                f"(D2 {j.D2:.2f}, p {j.p_value:.2g})")
    return shown


def _own_problems(result: dict, tag: str) -> list:
    """Why a recorded result cannot be compared with any other (read and checked as compare checks
    each side: status not ok, a value or u unusable, a failing answer gate), or []."""
    from ..estimation.result import CalibrationResult
    from ..estimation.result_checks import result_problems

    try:
        r = CalibrationResult.from_dict(result, tag)
    except InputError as exc:
        return [str(exc)]
    try:
        return list(result_problems(r))
    except InputError as exc:
        return [str(exc)]


def _refits(calibrations, usable) -> list:
    """For each calibration, the earlier one (0-based) whose data (:func:`data_hashes`) it was also
    fitted to: the first usable fit of those data (the calibration of those data), else the first fit of
    them; None for a calibration of data not recorded before it."""
    out = []
    for j, c in enumerate(calibrations):
        hashes = data_hashes(c["result"])
        same = [k for k in range(j) if hashes & data_hashes(calibrations[k]["result"])]
        out.append(next((k for k in same if usable[k]), same[0] if same else None))
    return out


def _refit_text(calibrations, j: int, first: int) -> str:
    sha = sorted(data_hashes(calibrations[j]["result"]) & data_hashes(calibrations[first]["result"]))[0]
    return (f"a refit of the data of #{first + 1} (data_sha256 {sha[:12]}...): its differences from #{first + 1} "
            "are the fits', not a drift of the unit, so it is not compared as a new calibration")


def same_data_note(calibrations, sha256: str) -> Optional[str]:
    """What the history makes of the calibration recorded as ``sha256`` (the identity :meth:`HistoryDB.add`
    gives it) when another calibration of the serial was fitted to the same data (:func:`data_hashes`):
    a refit of the data of an earlier one (listed, not compared as a new calibration), or the calibration
    of data that a later-listed result refits; None when no other calibration shares its data."""
    j = next((i for i, c in enumerate(calibrations) if c.get("sha256") == sha256), None)
    if j is None:
        return None
    hashes = data_hashes(calibrations[j]["result"])
    others = [k for k, c in enumerate(calibrations) if k != j and hashes & data_hashes(c["result"])]
    if not others:
        return None
    usable = [not _own_problems(c["result"], f"#{i}") for i, c in enumerate(calibrations, 1)]
    first = _refits(calibrations, usable)[j]

    def name(k):
        c = calibrations[k]
        src = c["result"].get("source")
        return f"#{k + 1} ({c['date']}{', from ' + str(src) if src else ''})"

    if first is not None and usable[first] and usable[j]:
        return (f"the same data as {name(first)}: recorded as #{j + 1}, " + _refit_text(calibrations, j, first)
                + "; `triadcal compare` shows the two fits' differences")
    return ("the same data (data_sha256) as " + ", ".join(name(k) for k in others) + f": recorded as #{j + 1}; the "
            "history compares one fit of those data as a calibration (the first that can be compared) and lists "
            "the others as refits")


def comparisons(calibrations) -> list[dict]:
    """How each calibration (in the listed order, oldest first) was compared; one dict per calibration,
    ``index`` its number (1-based), and either

    * ``before`` (the number of the most recent earlier calibration it can be compared with), ``verdict``
      (compare's overall, significance only: tolerance_arcsec=None), ``reason`` (why, when inconclusive)
      and ``skipped`` (``[(number, why)]``, every calibration between the two, each with why it was
      not the one compared with), or
    * ``not_compared`` (why: the result itself cannot be compared, it is a refit of the data of an
      earlier calibration, or no earlier calibration can be compared with it), or neither (the
      first calibration that can be compared).

    ``refit_of``: the number of the earlier calibration whose data (data_sha256) it was fitted to, or
    None. A refit is not compared as a new calibration (its differences are the estimators', not a
    drift of the unit) but may be the earlier calibration of a later one (a refit at another reference
    temperature, as compare asks for)."""
    from ..estimation.result import CalibrationResult
    from ..judgement.compare import compare

    n = len(calibrations)
    own = [_own_problems(c["result"], f"#{i}") for i, c in enumerate(calibrations, 1)]
    usable = [not w for w in own]
    refit_of = _refits(calibrations, usable)
    out = []
    parsed: dict = {}

    def result(k):
        if k not in parsed:
            parsed[k] = CalibrationResult.from_dict(calibrations[k]["result"], f"#{k + 1}")
        return parsed[k]

    # root[k]: the first calibration whose data (data_sha256) calibration k was fitted to; firsts[root]:
    # the first usable fit of those data
    root = [next((m for m in range(k) if data_hashes(calibrations[k]["result"])
                  & data_hashes(calibrations[m]["result"])), k) for k in range(n)]
    firsts: dict = {}
    for k in range(n):
        if usable[k]:
            firsts.setdefault(root[k], k)
    for j in range(n):
        entry = {"index": j + 1, "before": None, "verdict": None, "reason": None, "skipped": [],
                 "not_compared": None, "refit_of": None}
        out.append(entry)
        first = refit_of[j]
        if first is not None:
            entry["refit_of"] = first + 1
        if not usable[j]:
            entry["not_compared"] = "; ".join(own[j])
            continue
        if first is not None and usable[first]:
            entry["not_compared"] = _refit_text(calibrations, j, first)
            continue
        # the earlier ones, most recent first; a refit stands where the data it refits stand (its own date
        # is when it was recorded), after the first usable fit of those data
        skipped, found = [], None
        for k in sorted(range(j), key=lambda k: (-root[k], k != firsts.get(root[k]), -k)):
            if not usable[k]:
                skipped.append((k + 1, _short(own[k][0])))
                continue
            try:
                cmp = compare(result(k), result(j), tolerance_arcsec=None, files=(f"#{k + 1}", f"#{j + 1}"))
            except InputError as exc:
                skipped.append((k + 1, _short(str(exc))))
                continue
            found = (k, cmp)
            break
        if found is None:
            if skipped:       # (none for the first calibration: nothing before it)
                entry["not_compared"] = "no earlier calibration can be compared with it (" + _grouped(skipped) + ")"
            continue
        k, cmp = found
        entry.update(before=k + 1, verdict=cmp.overall, skipped=sorted(skipped),
                     reason=inconclusive_reason(cmp) if cmp.overall == "inconclusive" else None)
    return out


def _grouped(skipped) -> str:
    """``[(2, why), (1, why)]`` as "#1, #2: why", one group per distinct why, oldest first."""
    groups: dict = {}
    for k, why in sorted(skipped):
        groups.setdefault(why, []).append(k)
    return "; ".join(", ".join(f"#{k}" for k in ks) + f": {why}" for why, ks in groups.items())


def verdicts(calibrations) -> list[str]:
    """For each calibration after the first, the ``compare`` overall verdict (significance only:
    tolerance_arcsec=None) against the most recent earlier calibration it can be compared with
    (:func:`comparisons`), or ``"not compared: why"``."""
    return [e["verdict"] if e["verdict"] else f"not compared: {e['not_compared'] or 'nothing earlier to compare with'}"
            for e in comparisons(calibrations)[1:]]


def history_text(serial: str, calibrations) -> str:
    from ..estimation.result import round_to_uncertainty

    if not calibrations:
        return f"{serial}: no calibration recorded"
    from ..io.dates import iso_date

    lines = [f"{serial}: {len(calibrations)} calibration(s)"]
    unsure = []
    steps = comparisons(calibrations)
    for i, c in enumerate(calibrations, 1):
        r = c["result"]
        why = HistoryDB.unhashed_or_edited(None, r)
        if why:
            unsure.append((i, why))
        refit = steps[i - 1]["refit_of"]
        lines.append(f"  #{i} {c['date']}  state {c['state'] or '-'}  lab {c['lab'] or '-'}  method "
                     f"{r.get('method')}  status {r.get('status')}" + ("  [not known to be the fit's answer]" if why else "")
                     + (f"  [a fit of the data of #{refit}]" if refit else ""))
    names = shown_parameters(calibrations)
    # every cell is "value ± u unit" (a serial's calibrations may be in different units: g/V,
    # g/counts), and the columns are as wide as their widest cell, two spaces apart
    table = []
    # the reference temperature the values are at: a refit at 25 degC next to calibrations at 20 degC
    # showed its tempco shift as a drift (an outside probe)
    cells = []
    for c in calibrations:
        t = c["result"].get("reference_temperature_C")
        cells.append(f"{t:g} °C" if isinstance(t, (int, float)) and not isinstance(t, bool) else "-")
    table.append(("T_ref", cells))
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
    name_w = max([len("parameter")] + [len(n) for n, _ in table])
    lines += ["", "  " + "parameter".ljust(name_w) + "".join("  " + f"#{i}".rjust(w) for i, w in enumerate(widths, 1))]
    for n, cells in table:
        lines.append("  " + n.ljust(name_w) + "".join("  " + c.rjust(w) for c, w in zip(cells, widths)))
    if len(calibrations) > 1:
        # an outside probe: #1 ok, #2 status model_mismatch, #3 ok with Ca_xy moved 40": "#1 -> #2" and
        # "#2 -> #3" were both "not compared" and no verdict covered the move. Each calibration is now
        # compared with the most recent earlier one it can be, the ones passed over named with why
        lines += ["", "  compare (each with the most recent earlier calibration it can be compared with; "
                      "significance only):"]
        for e in steps:
            i = e["index"]
            if e["verdict"]:
                line = f"    #{e['before']} -> #{i}: {e['verdict']}" + (f": {e['reason']}" if e["reason"] else "")
                if e["skipped"]:
                    line += " (" + "; ".join(f"#{k} skipped: {why}" for k, why in e["skipped"]) + ")"
            elif e["not_compared"]:
                line = f"    #{i}: not compared: {e['not_compared']}"
                if e["refit_of"] and "refit" not in e["not_compared"]:
                    line += f" (a fit of the data of #{e['refit_of']})"
            else:
                continue          # the first calibration that can be compared: nothing before it
            lines.append(line)
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


def history_points(serial: str, calibrations, name: str) -> tuple:
    """The points of parameter ``name`` in the history plot: ``(x, value, u, label, shared)`` lists and
    whether some date holds several calibrations (then each is labelled ``#id state`` and they stand
    8 h apart in their recorded order: at one x a unit's states before and after a shock read as one
    point with a long error bar, an outside probe)."""
    xs, ys, us, labels = [], [], [], []
    on_day: dict = {}
    for c in calibrations:
        p = c["result"].get("parameters", {}).get(name)
        if p and p.get("value") is not None and p.get("u") is not None:
            try:
                day = _dt.date.fromisoformat(c["date"][:10])
            except ValueError:
                # skipped without a word, every point of a history with day-first dates was left out and
                # an empty figure written (an outside probe)
                raise InputError(f"{serial}: calibration #{c['id']} is dated {c['date']!r}, not an ISO 8601 "
                                 "date (YYYY-MM-DD): it cannot be placed on the time axis") from None
            # calibrations of one date (a unit's states before and after a shock) side by side, in their
            # recorded order, each labelled: at one x they read as one point with a long error bar
            j = on_day[day] = on_day.get(day, -1) + 1
            xs.append(_dt.datetime.combine(day, _dt.time()) + _dt.timedelta(hours=8 * j))
            ys.append(p["value"])
            us.append(p["u"])
            labels.append(f"#{c['id']}" + (f" {c['state']}" if c.get("state") else ""))
    return xs, ys, us, labels, any(v > 0 for v in on_day.values())


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
        xs, ys, us, labels, shared = history_points(serial, calibrations, n)
        ax.errorbar(xs, ys, yerr=us, fmt="o-", capsize=3)
        if shared:
            for x, y, lab in zip(xs, ys, labels):
                ax.annotate(lab, (x, y), fontsize=6, xytext=(3, 3), textcoords="offset points")
        ax.set_title(f"{n} (arcsec)", fontsize=9)
        ax.tick_params(labelsize=7)
        for lab in ax.get_xticklabels():
            lab.set_rotation(30)
    fig.suptitle(f"{serial}: angles over time (error bars: u, k = 1)")
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=90)
