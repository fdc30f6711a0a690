"""``triadcal compare``: drift between calibrations, judged against both uncertainties.

Three forms (docs/compare.md):

* ``triadcal compare BEFORE.json AFTER.json [--posterior-before A.nc --posterior-after B.nc]
  [--lab LAB.toml | --shared-bench]``
* ``triadcal compare S0.json S1.json S2.json ... --sequence [--labels ...]``
* ``triadcal compare --published TABLE.csv --u-arcsec 12``
"""

from __future__ import annotations

from ..errors import InputError

import sys

from ._common import add_output_options, name_list, output


def register(sub) -> None:
    p = sub.add_parser(
        "compare", help="judge the drift of a unit between calibrations (shock, vibration) against uncertainty",
        description="Drift of every angle (and K, S, tempcos) between two calibrations of one unit, its "
                    "uncertainty from both calibrations, ISO 13528 En, a joint chi2 test of the six angles, "
                    "P(|drift| > tolerance) from posteriors, and a pass/fail/inconclusive verdict under the "
                    "rule printed with the result. Also a sequence of exposures, or a published drift table.")
    p.add_argument("results", nargs="*", metavar="RESULT.json",
                   help="calibration results (results-json v1): BEFORE AFTER, or a sequence with --sequence")
    p.add_argument("--sequence", action="store_true",
                   help="the results are a sequence (initial, after exposure 1, ...): compare step by step "
                        "and against the initial state")
    p.add_argument("--labels", help="comma-separated names of the states (sequence)")
    p.add_argument("--published", metavar="TABLE", help="judge a published drift table (CSV or JSON: exposure, "
                   "sensor, angle, drift_arcsec[, u_arcsec | u_drift_arcsec])")
    p.add_argument("--u-arcsec", type=float, metavar="U",
                   help="published mode: standard uncertainty (1 sigma) of each angle measurement, arcsec")
    p.add_argument("--posterior-before", metavar="A.nc", help="posterior (arviz netCDF) of BEFORE")
    p.add_argument("--posterior-after", metavar="B.nc", help="posterior (arviz netCDF) of AFTER")
    p.add_argument("--posteriors", help="sequence: comma-separated posterior files, one per result")
    p.add_argument("--tolerance", default="30arcsec",
                   help="tolerance on each angle's drift with its unit: arcsec, arcmin or deg "
                        "(default 30arcsec, the paper's limit); 'none' for significance only")
    p.add_argument("--param-tolerance", action="append", metavar="NAME=VALUE",
                   help="tolerance of one parameter in its own unit, e.g. K_x=2e-5 or Ca_xy=10 (arcsec; an angle "
                        "given one is judged against it instead of --tolerance) (repeatable); it then enters the "
                        "overall verdict; a finite number >= 0")
    p.add_argument("--correlation", default=None,
                   help="correlation coefficient rho between the two calibrations' errors (default: derived, "
                        "0 for fitted results and published tables; the reason is written in the output)")
    p.add_argument("--lab", metavar="LAB.toml",
                   help="lab file whose [compare] shared_equipment (e.g. [\"bench\", \"gravity\"]) names the "
                        "equipment shared by both calibrations: its systematic errors (the results' Type B budget "
                        "rows) are one error in both and partly cancel in the drift (default: nothing shared)")
    p.add_argument("--shared-bench", action="store_true",
                   help="both calibrations ran on the same bench with no adjustment between them: share the "
                        "[bench] and [gravity] systematic errors (shorthand for shared_equipment = "
                        "[\"bench\", \"gravity\"])")
    p.add_argument("--level", type=float, default=0.95, help="confidence level of the rule (default 0.95)")
    p.add_argument("--json", metavar="OUT", help="write the comparison (triadcal.comparison v1, or "
                   "triadcal.comparison_sequence v1 for a sequence or a table)")
    p.add_argument("--plot", metavar="OUT.png", help="write a PNG of the drifts with their uncertainty bands")
    p.add_argument("--exit-code", action="store_true",
                   help="exit 0 on pass, 4 on fail, 5 on inconclusive (overall)")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..judgement.compare import (compare, compare_sequence, judge_published, parse_tolerance,
                                      read_published_table)

    say = output(args).say
    try:
        tolerance = parse_tolerance(args.tolerance)
    except InputError as exc:
        raise InputError(f"--tolerance {args.tolerance}: {exc}") from None
    tolerances = _param_tolerances(args.param_tolerance)
    correlation = "auto" if args.correlation in (None, "auto") else _float(args.correlation, "--correlation")
    if correlation != "auto" and correlation < 0:
        from ..judgement.compare.pair import NEGATIVE_RHO_REASON

        raise InputError(f"--correlation {args.correlation}: {NEGATIVE_RHO_REASON}")
    shared = _shared_equipment(args)

    if args.published:
        if args.results:
            raise InputError("--published takes a table, not calibration results")
        if args.posterior_before or args.posterior_after or args.posteriors or args.sequence:
            raise InputError("--published judges drift values only: no posteriors, no --sequence")
        if args.lab or args.shared_bench:
            raise InputError("--lab and --shared-bench share the systematic errors of calibration results' "
                             "budgets; a published table has none")
        if tolerances:
            raise InputError("--param-tolerance applies to calibration results, not to a published table")
        rows = read_published_table(args.published)
        out = judge_published(rows, u_measurement_arcsec=args.u_arcsec, tolerance_arcsec=tolerance,
                              correlation=0.0 if correlation == "auto" else correlation, level=args.level)
        say(f"{args.published}: {len(rows)} published drifts, {len(out.labels)} exposures")
        say(out.table("step"))
        _print_footer(out.steps[0], say, joint=False)
        say(f"overall: {out.overall}")
    elif args.sequence:
        if len(args.results) < 2:
            raise InputError("--sequence needs at least two results (the initial state and one exposure)")
        if args.posterior_before or args.posterior_after:
            raise InputError("with --sequence give --posteriors A.nc,B.nc,... (one per result)")
        results = [_load_checked(f) for f in args.results]
        from ..judgement.compare.pair import check_data_order

        check_data_order(results, args.results)      # refused naming the files, not their labels
        labels = name_list(args.labels) if args.labels else [_stem(f) for f in args.results]
        posteriors = name_list(args.posteriors) if args.posteriors else None
        out = compare_sequence(results, labels, tolerance_arcsec=tolerance, tolerances=tolerances,
                               correlation=correlation, level=args.level, posteriors=posteriors,
                               shared_equipment=shared)
        say(f"{results[0].unit}: {len(results)} calibrations")
        say("step by step:")
        say(out.table("step"))
        say("against the initial state:")
        say(out.table("cumulative"))
        _print_footer(out.steps[0], say, joint=False)
        say(f"overall: {out.overall}")
    else:
        if len(args.results) != 2:
            raise InputError(f"give BEFORE.json and AFTER.json (got {len(args.results)} files); "
                             "for more use --sequence")
        if args.posteriors:
            raise InputError("--posteriors is for --sequence; use --posterior-before/--posterior-after")
        before, after = (_load_checked(f) for f in args.results)
        out = compare(before, after, tolerance_arcsec=tolerance, tolerances=tolerances,
                      posterior_before=args.posterior_before, posterior_after=args.posterior_after,
                      correlation=correlation, level=args.level, shared_equipment=shared,
                      label=f"{_stem(args.results[0])} -> {_stem(args.results[1])}", files=tuple(args.results))
        say(_comparison_text(out))
        _print_footer(out, say)
        say(f"overall: {out.overall}")
    if args.json:
        out.save(args.json)
        say(f"comparison written to {args.json}")
    if args.plot:
        from ..reports.drift import plot_drifts

        which = "cumulative" if args.sequence else "step"
        names = None
        if not args.sequence and not args.published:
            names = [n for n, p in out.parameters.items() if p.judged and p.unit == "arcsec"]
        plot_drifts(out, args.plot, which=which, names=names)
        say(f"plot written to {args.plot}")
    for note in getattr(out, "notes", []):
        print(f"note: {note}", file=sys.stderr)
    if args.sequence:
        # a comparison whose pass was held back says why (a same calibration, a missing angle)
        from ..judgement.compare import NOT_PASS_NOTE

        for c in out.steps + out.cumulative:
            for note in c.notes:
                if note.startswith(NOT_PASS_NOTE):
                    print(f"note: {c.label}: {note}", file=sys.stderr)
    if args.exit_code:
        return {"pass": 0, "fail": 4, "inconclusive": 5}[out.overall]
    return 0


def _comparison_text(c) -> str:
    from ..estimation.result import round_to_uncertainty

    lines = [f"{c.before.get('unit', '')}: {c.label}",
             f"  {'parameter':<20} {'drift':>12} {'u(d)':>10} {'En':>6} {'z':>7} {'P(>T)':>7}  verdict       unit"]
    for n, p in c.parameters.items():
        d, u = round_to_uncertainty(p.drift, p.u)
        pe = "" if p.p_exceeds is None else f"{p.p_exceeds:.3f}"
        verdict = p.verdict if p.judged else f"({p.verdict})"
        lines.append(f"  {n:<20} {d:>12} {u:>10} {p.En:>6.2f} {p.z:>7.2f} {pe:>7}  {verdict:<13} {p.unit}")
    if any(not p.judged for p in c.parameters.values()):
        lines.append("  (verdict): significance only, not in the overall verdict (no tolerance given; "
                     "see --param-tolerance)")
    for n, b in c.bench_check.items():
        lines.append(f"  bench check {n}: change {b['drift']:+.2f} +- {b['u']:.2f} {b['unit']}"
                     f"{' (significant: bench re-levelled?)' if b['significant'] else ''}")
    return "\n".join(lines)


def _print_footer(c, say=print, joint: bool = True) -> None:
    if joint and c.joint is not None:
        j = c.joint
        say(f"joint test of {j.dof} angles: D2 = {j.D2:.2f}, p = {j.p_value:.3g} "
              f"({'significant' if j.significant else 'not significant'} at {100 * j.level:g}%)")
    say(f"correlation between calibrations: {c.correlation.get('reason', '')}")
    sh = c.correlation.get("shared")
    if not isinstance(sh, dict):
        pass                                  # a published table: no budgets
    elif sh.get("equipment"):
        rows = ", ".join(f"{s['source']} ({s['key']}, u = {s['u']:g} {s['unit']})" for s in sh.get("sources", []))
        say(f"shared equipment: {', '.join(sh['equipment'])}; shared sources: {rows or 'none (nothing to share)'}")
    else:
        say("shared equipment: none (the calibrations' systematic errors are independent)")
    say(f"rule: {c.rule}")


def _shared_equipment(args) -> tuple:
    """The equipment shared by the calibrations: ``[compare] shared_equipment`` of ``--lab``
    and, with ``--shared-bench``, bench and gravity."""
    shared = []
    if args.lab:
        from ..io.lab import load_lab

        shared += list(load_lab(args.lab).shared_equipment)
    if args.shared_bench:
        from ..uncertainty.typeb import BENCH_EQUIPMENT

        shared += list(BENCH_EQUIPMENT)
    return tuple(dict.fromkeys(shared))


def _load_checked(path: str):
    """A result file, validated and refused (one line naming the file) unless it is an answer."""
    from ..estimation.result_checks import check_result_for_use
    from ..estimation.result import CalibrationResult

    result = CalibrationResult.load(path)
    check_result_for_use(result, path)
    return result


def _stem(path: str) -> str:
    from pathlib import Path

    return Path(path).stem


def _param_tolerances(items) -> dict:
    """``['K_x=2e-5', 'Ca_xy=10']`` -> ``{'K_x': 2e-05, 'Ca_xy': 10.0}``; each a finite number >= 0,
    refused naming the option and the value otherwise."""
    from ..judgement.compare import check_tolerance

    out = {}
    for item in items or ():
        if "=" not in item:
            raise InputError(f"--param-tolerance {item}: expected NAME=VALUE, e.g. K_x=2e-5")
        k, v = (x.strip() for x in item.split("=", 1))
        if not k:
            raise InputError(f"--param-tolerance {item}: no parameter name")
        from ..io.numbers import NumberError, parse_number

        try:
            value = parse_number(v, what=f"the tolerance of {k}")
        except NumberError as exc:
            # float() took '1_0' as 10 (an outside probe: every K drift passed a tolerance of 10 g/V)
            raise InputError(f"--param-tolerance {item}: {exc.problem} (a number in the parameter's own unit; "
                             "leave the parameter out for significance only)") from None
        if k in out:
            raise InputError(f"--param-tolerance {item}: {k} is given twice")
        try:
            out[k] = check_tolerance(value, f"the tolerance of {k}")
        except InputError as exc:
            raise InputError(f"--param-tolerance {item}: {exc}") from None
    return out


def _float(text: str, what: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise InputError(f"{what}: expected a number or 'auto', got {text!r}") from None
