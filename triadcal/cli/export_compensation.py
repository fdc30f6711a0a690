"""``triadcal export-compensation``: per-temperature tables of K, S and Ca for a firmware."""

from __future__ import annotations

from ._common import add_output_options, output


def register(sub) -> None:
    p = sub.add_parser(
        "export-compensation", help="write per-temperature tables of K, S and Ca (Ca^-1) for a firmware",
        description="Evaluate a calibration result's thermal model on a temperature grid and write the tables a "
                    "firmware loads: K, S, the angles and Ca^-1 at each grid point, with the standard uncertainty "
                    "of each entry and the bound of linear interpolation to the next grid point (docs/compensation.md).")
    p.add_argument("result", help="calibration result (results-json v1, status ok)")
    p.add_argument("--format", choices=("json", "csv", "c-header"), default="json")
    p.add_argument("--grid", default=None, metavar="LO:HI:STEP",
                   help="temperature grid in degC, e.g. -40:85:5 (default: the calibrated range's two ends and the "
                        "multiples of 5 degC between them)")
    p.add_argument("-o", "--out", required=True, metavar="FILE", help="the table file to write")
    p.add_argument("--data", metavar="DATA.csv",
                   help="the bench CSV the result was fitted to: refuse the result (nothing written) when they are "
                        "not its data, its range reaches beyond their visits, or its values are not those they give "
                        "(one Gauss-Newton step moves one by more than 5 u: an edited result)")
    p.add_argument("--allow-extrapolation", action="store_true",
                   help="accept grid points outside the calibrated range (marked EXTRAPOLATED in the table)")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..estimation.result import CalibrationResult
    from ..reports.compensation import export_compensation

    grid = args.grid
    if grid is None:
        grid = default_grid(CalibrationResult.load(args.result).temperature_range_C, args.result,
                            args.allow_extrapolation)
    table = export_compensation(args.result, args.out, args.format, grid, args.allow_extrapolation, data=args.data)
    out = output(args)
    out.say(f"{table.unit}: {len(table.grid_C)} grid points {table.grid_C[0]:g}..{table.grid_C[-1]:g} degC "
            f"written to {args.out} ({args.format})")
    out.say(f"  largest u: K {table.u_K.max():.2g} {table.K_unit}, S {table.u_S.max():.2g} g, angles "
            f"{table.u_angles.max():.2g} arcsec; largest interpolation bound: K {table.interp_K.max():.2g}, "
            f"S {table.interp_S.max():.2g}, angles {table.interp_angles.max():.2g}")
    for n in table.notes:
        out.say(f"  note: {n}")
    return 0


def default_grid(rng, name, allow_extrapolation: bool = False) -> str:
    """The grid when --grid is not given: the calibrated range's two ends and the multiples of
    5 degC between them (:func:`grid_with_ends`). A result without a temperature range, or of one
    temperature, is refused with what is wrong, not with a grid the user never typed."""

    from ..errors import InputError

    if rng is None:
        raise InputError(f"{name}: the result has no temperature range (fitted without temperature data, e.g. by "
                         "fit-raw): a compensation table of T cannot be made from it; apply it with "
                         "CalibrationResult.apply, or calibrate over a temperature range")
    from ..estimation.joint import TEMPERATURE_SPAN_MIN_C

    lo, hi = float(rng[0]), float(rng[1])
    if not hi - lo >= TEMPERATURE_SPAN_MIN_C:     # as the fit says "one temperature" (estimation/joint.py)
        hint = ("give --grid LO:HI:STEP" if allow_extrapolation else "give --grid LO:HI:STEP with "
                "--allow-extrapolation") + f" (its points outside {lo:.2f}..{hi:.2f} degC are marked EXTRAPOLATED)"
        raise InputError(f"{name}: the result was calibrated at one temperature ({lo:.2f}..{hi:.2f} degC): a table of T would "
                         f"be a single point, and the thermal model is not valid away from it; {hint}")
    return grid_with_ends(lo, hi, 5.0)


def grid_with_ends(lo: float, hi: float, step: float) -> list:
    """``lo``, the multiples of ``step`` strictly inside (lo, hi), and ``hi``: the rows cover the
    whole calibrated range. With rows at the multiples only, a range of -39.8..70.4 degC got rows
    -35..70: the coldest setpoint had no row, and a firmware holding the end row below -35 degC
    was off by up to 288 ug against a u of 5 ug (an outside probe)."""
    import math

    inner = [step * k for k in range(math.floor(lo / step) + 1, math.ceil(hi / step))
             if lo + 1e-9 < step * k < hi - 1e-9]
    return [lo, *inner, hi]
