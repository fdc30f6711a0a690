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
                    "how often the verdict names it. With --left-out each campaign is diagnosed a second "
                    "time with the effect (and the candidates that explain the same data) left out of the "
                    "candidates: the right verdict is then 'unexplained'. Writes the confusion matrices as a "
                    "table (confusion.txt), a plot (confusion.png) and every row (validation.json). Every row is also "
                    "appended to DIR/rows.jsonl as it finishes: a run stopped midway, started again with the same "
                    "settings into the same DIR, takes the rows it finds there and diagnoses only the rest (refused "
                    "when the settings or triadcal's code differ).")
    p.add_argument("--seeds", type=int, default=20, help="campaigns per effect (default 20)")
    p.add_argument("--effects", default=None,
                   help="comma-separated conditions (default: clean and every effect of the vocabulary)")
    p.add_argument("--magnitudes", default="1",
                   help="comma-separated magnitudes of the withheld effect, 1 = the preset's realistic one "
                        "(its parameters times m; position_error: the sigmas times m; heavy_tails: nu = 3/m). "
                        "Default 1; the full validation uses 1,0.5")
    p.add_argument("--left-out", action="store_true",
                   help="also diagnose each campaign with the effect and its group left out of the candidates "
                        "(right verdict: unexplained)")
    p.add_argument("--second-mechanisms", action="store_true",
                   help="the conditions are the effect families made by a second mechanism (hysteresis~2 ..., "
                        "written with numpy, not with the model's terms: docs/diagnosis.md \"Second mechanisms\"); "
                        "a verdict naming any effect of the family is right. --effects takes these names too")
    p.add_argument("--detectability", action="store_true",
                   help="instead of diagnosing: for each mean effect and magnitude, the noncentrality of its "
                        "signal on the validation's design (seed 1000, noise-free) and the power of the most "
                        "powerful test at alpha = 0.01 that knows the effect's exact shape (an upper bound on "
                        "any rule's detection rate) and of the effect's own score test at Holm's first step; "
                        "writes detectability.txt and detectability.json (docs/diagnosis.md, \"Detectability\")")
    p.add_argument("--noise-estimated", action="store_true",
                   help="remove each campaign's declared noise (sd_*, n_samples, u_w_*, Q_V2s) before the "
                        "diagnosis, as in a bench CSV without them: the white level is estimated from the "
                        "residuals (quantisation is then untestable; flicker_noise is tested with the "
                        "white level estimated together)")
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
    try:
        magnitudes = tuple(float(m) for m in name_list(args.magnitudes))
    except ValueError:
        raise InputError(f"--magnitudes takes comma-separated numbers, not {args.magnitudes!r}") from None
    if not magnitudes or not all(0 < m < float("inf") for m in magnitudes):
        raise InputError(f"--magnitudes must be positive numbers, not {args.magnitudes!r}")

    out = output(args)

    def progress(row):
        if out.progress:
            lo = row.get("left_out_verdict")
            print(f"{row['condition']:>24}, seed {row['seed']}: the diagnosis names {row['verdict']}"
                  + (f"; with it left out: {lo}" if lo is not None else ""), file=sys.stderr, flush=True)

    effects = name_list(args.effects) if args.effects else None
    if args.detectability:
        if args.noise_estimated:
            raise InputError("--detectability computes the noncentrality with the declared noise; "
                             "--noise-estimated does not apply to it")
        return _detectability(args, effects, magnitudes, out)
    if args.second_mechanisms and effects is None:
        from ..judgement.second_mechanisms import CONDITIONS

        effects = list(CONDITIONS)
    res = validate(seeds=args.seeds, effects=effects,
                   processes=args.processes, preset=args.preset, progress=progress, magnitudes=magnitudes,
                   left_out=args.left_out, noise_estimated=args.noise_estimated, journal_dir=args.out)
    paths = write_validation(res, args.out)
    out.say(res.table())
    fa = res.summary.get("clean", {}).get("false_alarm_rate")
    if fa is not None:
        out.say(f"false alarms on clean data: {fa:.0%}")
    if args.left_out:
        lo = [c for c in res.left_out_conditions if c in res.summary]
        wrong = {c: res.summary[c]["left_out_verdicts"] for c in lo if res.summary[c]["left_out_named_rate"] > 0}
        out.say(f"left out: 'unexplained' in {sum(res.confusion(left_out=True)[:, res.labels.index('unexplained')])}"
                f" of {int(res.confusion(left_out=True).sum())} diagnoses"
                f" ({sum(round(res.summary[c]['unexplained_rate_when_detected'] * res.summary[c]['left_out_detected_n']) for c in lo if res.summary[c]['left_out_detected_n'])}"
                f" of the {sum(res.summary[c]['left_out_detected_n'] for c in lo)} whose in-vocabulary diagnosis found the gap)"
                + ("; a candidate was named instead in " + "; ".join(f"{c}: {v}" for c, v in wrong.items())
                   if wrong else ""))
    if res.resumed:
        out.say(f"resumed: {res.resumed} of the {len(res.rows)} rows were taken from {args.out}/rows.jsonl, "
                "written by a stopped run of the same settings and code")
    out.say(f"{len(res.rows) - res.resumed} diagnoses in {res.seconds:.0f} s; the table is in {paths['table']}, the plot in "
            f"{paths['plot']} and every row in {paths['json']}")
    return 0


def _detectability(args, effects, magnitudes, out) -> int:
    from pathlib import Path

    from ..io.atomic import atomic_write_json, atomic_write_text
    from ..judgement.detectability import detectability_table, format_table
    from ..judgement.diagnosis_validation import CONDITIONS
    from ..models.effects import NOISE_EFFECTS

    if args.second_mechanisms:
        raise InputError("--detectability measures the effects of the vocabulary, not the second mechanisms")
    wanted = list(CONDITIONS) if effects is None else effects
    mean = [e for e in wanted if e != "clean" and e not in NOISE_EFFECTS]
    if not mean:
        raise InputError(f"--detectability needs a mean effect among the conditions, not only {', '.join(wanted)} "
                         "(clean data and the noise effects have no mean signal)")
    skipped = [e for e in wanted if e not in mean]
    if skipped:
        print(f"note: skipped, no mean signal: {', '.join(skipped)}", file=sys.stderr)
    rows = detectability_table(mean, magnitudes, preset=args.preset)
    folder = Path(args.out)
    folder.mkdir(parents=True, exist_ok=True)
    table = format_table(rows)
    atomic_write_text(folder / "detectability.txt", table + "\n")
    doc = {"format": "triadcal.detectability", "version": 1,
           "definition": "lambda_total: noncentrality (chi2 units) of the effect's signal after the fit; "
                         "power_bound: Phi(sqrt(lambda_total) - z_(1-alpha)), the most powerful level-alpha test "
                         "of the known signal; lambda_own, k_own: the effect's own score test; power_own: its "
                         "chance to pass alpha / n_gap_tests; closest_rival, lambda_rival, k_rival: the "
                         "encompassing test against the rival the effect beats least in the noise-free diagnosis; "
                         "power_rival: its power at alpha (the diagnosis names the effect only when it passes); "
                         "power_rival_bound: Phi(sqrt(lambda_rival) - z_(1-alpha))", "rows": rows}
    atomic_write_json(folder / "detectability.json", doc)
    out.say(table)
    out.say(f"written: {folder / 'detectability.txt'}, {folder / 'detectability.json'}")
    return 0
