"""``triadcal validate-diagnosis``: does the diagnosis name the effect withheld from the fit?"""

from __future__ import annotations

from ..errors import InputError

import sys

from ._common import add_output_options


def register(sub) -> None:
    p = sub.add_parser(
        "validate-diagnosis", help="validate the diagnosis on simulated campaigns with a withheld effect",
        description="For each effect of the vocabulary (and clean data), simulate campaigns with it at a "
                    "realistic magnitude, fit the thermal-campaign model without it, diagnose, and count "
                    "how often the verdict names it. Writes the confusion matrix as a table "
                    "(confusion.txt), a plot (confusion.png) and every row (validation.json).")
    p.add_argument("--seeds", type=int, default=20, help="campaigns per effect (default 20)")
    p.add_argument("--effects", default=None,
                   help="comma-separated conditions (default: clean and every effect of the vocabulary)")
    p.add_argument("--preset", default="ak18-quartz", help="unit preset (default ak18-quartz)")
    p.add_argument("--processes", type=int, default=2, help="worker processes (default 2)")
    p.add_argument("--out", default="diagnosis-validation", metavar="DIR",
                   help="output folder (default ./diagnosis-validation)")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..judgement.diagnosis_validation import validate
    from ..reports.diagnosis import write_validation
    from ._common import name_list, output

    if args.seeds < 1:
        raise InputError("--seeds must be at least 1")

    out = output(args)

    def progress(row):
        if out.progress:
            print(f"{row['effect']:>20}, seed {row['seed']}: the diagnosis names {row['verdict']}", file=sys.stderr,
                  flush=True)

    res = validate(seeds=args.seeds, effects=name_list(args.effects) if args.effects else None,
                   processes=args.processes, preset=args.preset, progress=progress)
    paths = write_validation(res, args.out)
    out.say(res.table())
    fa = res.summary.get("clean", {}).get("false_alarm_rate")
    if fa is not None:
        out.say(f"false alarms on clean data: {fa:.0%}")
    out.say(f"{len(res.rows)} diagnoses in {res.seconds:.0f} s; the table is in {paths['table']}, the plot in "
            f"{paths['plot']} and every row in {paths['json']}")
    return 0
