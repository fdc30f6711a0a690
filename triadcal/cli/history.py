"""``triadcal history``: the calibrations of a serial number over time (docs/fleet.md)."""

from __future__ import annotations

from ..errors import InputError
from ._common import add_output_options, output


def register(sub) -> None:
    p = sub.add_parser(
        "history", help="calibration history of a serial number: every calibration, drift, compare verdicts",
        description="Show every recorded calibration of a serial number (date, lab, method, status, each angle, "
                    "K and S with its u) and the compare verdict (significance only) between consecutive ones; "
                    "or record a result with --add. The history is an SQLite file: --db, else [history] path "
                    "of --lab, else triadcal-history.sqlite in the current directory.")
    p.add_argument("serial", nargs="?", metavar="SN", help="serial number to show")
    p.add_argument("--add", nargs="+", metavar="RESULT.json", help="record these results (a repeat is a no-op)")
    p.add_argument("--date", help="with --add: the calibration date (YYYY-MM-DD; default: the result's, else "
                                  "the lab file's [item] calibration_date, else today)")
    p.add_argument("--db", metavar="PATH", help="history database (SQLite)")
    p.add_argument("--lab", metavar="LAB.toml", help="lab file: [history] path, and the lab and equipment recorded "
                                                    "with --add")
    p.add_argument("--plot", metavar="FILE.png", help="draw each angle over time with its error bars")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    import datetime as dt

    from ..fleet.history import (HistoryDB, data_hashes, history_path, history_text, identity_sha256,
                                 plot_history, same_data_note)
    from ..io.atomic import read_json
    from ..io.lab import load_lab

    if not args.serial and not args.add:
        raise InputError("give a serial number to show, or --add RESULT.json")
    if args.date:
        try:
            dt.date.fromisoformat(args.date)
        except ValueError:
            raise InputError(f"--date {args.date!r} is not a date (YYYY-MM-DD)") from None
        from ..io.dates import future_problem

        late = future_problem(args.date, "a calibration")
        if late:
            raise InputError(f"--date {late}")
    lab = load_lab(args.lab) if args.lab else None
    path = history_path(args.db, lab)
    out = output(args)
    from ..estimation.result import CalibrationResult
    from ..estimation.result_checks import result_problems

    # every result is read and validated before the database is opened: a refusal left an empty
    # database behind (an outside probe)
    docs = []
    for f in args.add or ():
        d = read_json(f)
        r = CalibrationResult.from_dict(d, str(f))        # validated before it is recorded
        if r.content_mismatch:
            raise InputError(f"{f}: {r.content_mismatch}")
        if r.status == "ok":
            # status ok with a value, u or reference temperature the certificate and the compensation
            # table refuse (Ca_xy 1e140 arcsec, u = 0, 500 degC) was recorded as an ok calibration
            why = [w for w in result_problems(r) if w != r.content_mismatch]
            if why:
                raise InputError(f"{f}: refused: " + "; ".join(why))
        docs.append((f, d, r))
    existed = path.exists()
    try:
        with HistoryDB(path) as db:
            for f, d, r in docs:
                added = db.add(d, lab=lab, date=args.date, source=str(f))
                out.say(f"{f}: {'recorded' if added else 'already recorded (no change)'} in {path}")
                if added and db.date_source == "today":
                    out.say(f"{f}: note: no calibration date in the result (batch.date, date, data_date), no --date and "
                            "no lab file's calibration_date: recorded as today's; the history orders calibrations "
                            "and compares each with the one before it by this date, so an older result recorded now "
                            "stands after newer ones; give --date when recording an older result (a recorded "
                            "result keeps its date: adding it again is a no-op)")
                if added and data_hashes(d):
                    # an outside probe: the data of one campaign fitted again from a copy of its CSV were
                    # recorded as a second calibration, "inconclusive" against the first without a word
                    note = same_data_note(db.calibrations(str(d["unit"])), identity_sha256(d))
                    if note:
                        out.say(f"{f}: note: {note}")
                if r.content_unhashed:
                    out.say(f"{f}: note: the result holds no content_sha256 (another writer, or triadcal before "
                            "2026-11-30): nothing shows that its values are the fit's answer and not edited; the "
                            "history marks it")
            if not args.serial:
                return 0
            cals = db.calibrations(args.serial)
    except InputError:
        # a database this run created and left without a calibration (a refusal found while recording,
        # such as a data date after today) is not left behind; the file holds its schema, so its size
        # is no test of that
        if not existed and path.exists():
            import sqlite3

            con = sqlite3.connect(path)
            try:
                empty = con.execute("SELECT COUNT(*) FROM calibrations").fetchone()[0] == 0
            finally:
                con.close()
            if empty:
                path.unlink()
        raise
    if not cals:
        raise InputError(f"{path}: no calibration of {args.serial!r} recorded")
    out.say(history_text(args.serial, cals))
    if args.plot:
        plot_history(args.serial, cals, args.plot)
        out.say(f"plot written to {args.plot}")
    return 0
