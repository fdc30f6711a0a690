"""``triadcal thermal-cycle``: which thermal form explains a one-pose chamber cycle."""

from __future__ import annotations

from ._common import add_output_options, name_list, output


def register(sub) -> None:
    p = sub.add_parser(
        "thermal-cycle", help="one static pose through a chamber cycle: which thermal form explains the output",
        description="Fit each thermal form (polynomials, constant-offset hysteresis, lag of the element behind its "
                    "sensor, alone, with a hysteresis or with a play, a thermometer behind the element, play hysteresis) to a one-pose recording through a temperature cycle and judge them on "
                    "held-out blocks of the cycle (blocked cross-validation); docs/model.md.")
    p.add_argument("data", help="recording with named columns (comma, tab or semicolon separated)")
    p.add_argument("--columns", required=True, help="output columns, e.g. imu.acc.x,imu.acc.y,imu.acc.z")
    p.add_argument("--time-column", required=True, metavar="NAME")
    p.add_argument("--time-unit", choices=("s", "ms", "us", "ns"), default="s")
    p.add_argument("--temperature-column", required=True, metavar="NAME", help="the unit's temperature, degC")
    p.add_argument("--unit", default="m/s2", help="unit of the outputs (written as given; default m/s2)")
    p.add_argument("--reference-temperature", type=float, default=20.0, metavar="DEGC",
                   help="temperature at which the branch gap (cooling minus heating) is stated, degC (default 20)")
    p.add_argument("--folds", type=int, default=6, help="contiguous blocks of the cross-validation (default 6)")
    p.add_argument("--json", metavar="OUT.json", help="write the analysis (format triadcal.thermal_cycle)")
    p.add_argument("--plot", metavar="OUT.png", help="draw each axis against temperature and its residuals")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..estimation.thermal_cycle import plot_cycle, thermal_cycle
    from ..io.atomic import atomic_write_json

    c = thermal_cycle(args.data, name_list(args.columns), time_column=args.time_column,
                      temperature_column=args.temperature_column, time_unit=args.time_unit, unit=args.unit,
                      reference_temperature_C=args.reference_temperature, folds=args.folds)
    out = output(args)
    lo, hi = c.temperature_range_C
    out.say(f"{c.source}: {c.n} samples over {c.duration_s / 60:.1f} min, {lo:.1f} .. {hi:.1f} degC")
    for a in c.axes:
        out.say(f"  {a.column}: held-out RMS per form ({c.unit}; noise floor {a.noise_floor:.2g}):")
        for f in sorted(a.forms, key=lambda f: f.cv_rms):
            par = "" if not f.parameter else " " + ", ".join(
                f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in f.parameter.items()
                if k != "at_grid_edge") + (
                " (at the edge of the search)" if f.parameter.get("at_grid_edge") else "")
            gap = "" if f.branch_gap is None else f", branch gap after {f.branch_gap:+.3g}"
            out.say(f"    {f.name:<22} {f.cv_rms:.4g}{par}{gap}")
    out.say(f"verdict: {c.verdict}")
    for n in c.notes:
        out.say(f"note: {n}")
    if args.json:
        atomic_write_json(args.json, c.to_dict())
    if args.plot:
        plot_cycle(c, args.plot)
    return 0
