"""``triadcal fit``: calibrate from a bench CSV v1 campaign (classical eq. 2-3, or joint)."""

from __future__ import annotations

from ..errors import InputError

import sys

from ..models.effects import DEFAULT_EFFECTS, EFFECTS, NOISE_EFFECTS
from ._common import add_output_options, name_list, output


def register(sub) -> None:
    p = sub.add_parser(
        "fit", help="calibrate a unit from a bench campaign (classical or joint least squares)",
        description="Calibrate from a bench CSV v1 campaign. --method classical: the paper's eq. 2 at "
                    "each setpoint and its linear thermal correction. --method joint: one CasADi "
                    "least-squares fit of every term over all positions and temperatures.")
    p.add_argument("data", nargs="?", help="bench CSV v1 file")
    p.add_argument("--example", action="store_true", help="use the built-in example campaign")
    p.add_argument("--unit", default=None, metavar="SN", help="serial number to fit when the file holds several")
    p.add_argument("--state", default=None, metavar="NAME",
                   help="mechanical state to fit when the file holds several")
    p.add_argument("--method", choices=("classical", "joint"), default="joint")
    p.add_argument("--effects", default=None,
                   help=f"effects of the joint model, from: {', '.join(EFFECTS)}, and the noise effects "
                        f"{', '.join(NOISE_EFFECTS)} (a variance component / the Student-t likelihood / 1/f noise: B_f by REML, the "
                        "mean by GLS), and quantisation "
                        "(a digital output rounded to an LSB q: the expected visit-mean error, q profiled or "
                        "--quantisation-lsb), and the diagnosis's forms hysteresis_play, hysteresis_pi (= "
                        "hysteresis with --hysteresis-form play / pi) and thermal_lag_history (= thermal_lag with "
                        "--thermal-lag-form history); default: the effects the data's plan was made for "
                        "(# planned_effects, written by simulate --plan and capture --ramp), else "
                        f"{','.join(DEFAULT_EFFECTS)} (the thermal-campaign model: bench tilt, linear "
                        "tempcos of angles, scale factors and biases, hysteresis of the angles)")
    p.add_argument("--reference-temperature", type=float, default=20.0, metavar="DEGC",
                   help="reference temperature of the thermal model, degC (default 20)")
    p.add_argument("--loss", choices=("l2", "huber", "student_t"), default="l2",
                   help="robust loss for the joint fit (default l2)")
    p.add_argument("--strict", action="store_true",
                   help="refuse when a parameter cannot be determined (default: hold it at 0 and say so)")
    p.add_argument("--angle-bound-arcsec", type=float, default=3600.0, metavar="ARCSEC",
                   help="largest orientation angle an answer may have before it is refused as "
                        "angle_out_of_range (default 3600 = 1 deg; raise only for a unit known to be that skewed)")
    p.add_argument("--lab", metavar="LAB.toml",
                   help="lab file: its [bench] positioning and wobble SDs (arcsec) enter the joint fit as "
                        "variance components, its systematic errors (encoder zeros, axes non-orthogonality, "
                        "fixture, g, thermometers, voltmeter) are propagated to every parameter as Type B, "
                        "with a budget, U and k per parameter (docs/lab.md; without it, u is Type A only)")
    p.add_argument("--json", metavar="OUT", help="write the result (results-json v1)")
    p.add_argument("--netcdf", metavar="OUT.nc", help="write residuals per visit and axis (joint)")
    p.add_argument("--bench-errors-from-replicates", action="store_true",
                   help="estimate the bench's random positioning and wobble errors from the plan's replicated "
                        "visits (one position visited twice or more at a setpoint) instead of the lab file's")
    p.add_argument("--thermal-order", choices=("1", "2", "3", "auto"), default="1",
                   help="order of the tempcos: 1 (linear, default), 2 (quadratic terms added), 3 (quadratic and "
                        "cubic terms added), auto (the order 1-3 the data support per family: likelihood ratio at "
                        "99 %%, cubic tested first); docs/model.md")
    p.add_argument("--hysteresis-form", choices=("offset", "play", "pi", "auto"), default="offset",
                   help="form of the angles' hysteresis: offset (the branches a constant offset apart, default), "
                        "play (a backlash of half-width r on the temperature history, r profiled), pi (a "
                        "Prandtl-Ishlinskii sum of two plays, widths and weight profiled), auto (chosen by "
                        "the data: nested likelihood ratios at 99 %%); docs/model.md")
    p.add_argument("--thermal-lag-form", choices=("rate", "housing", "air", "history"), default="rate",
                   help="with a ramp or a continuously logged record: the element's thermal lag estimated from "
                        "the temperature history, the thermometer on the housing (one stage, thermal_lag, min) or "
                        "in the chamber air (two stages, thermal_lag_housing and thermal_lag); history: the "
                        "location chosen by the data (the air kept when it beats the housing at 99 %%; a stepped "
                        "record with gaps refused until the location is stated), as --effects "
                        "...,thermal_lag_history; default rate: the "
                        "thermal_lag effect's T - tau dT/dt, for short lags only; docs/model.md")
    p.add_argument("--bridge-gaps", action="store_true",
                   help="with --thermal-lag-form housing or air on a stepped campaign read only at its visits: fill "
                        "each gap of the temperature record (a soak) with a first-order approach whose time constant "
                        "is profiled with the lags, instead of refusing the record (docs/model.md)")
    p.add_argument("--quantisation-lsb", type=float, default=None, metavar="Q",
                   help="the LSB q of a digital output in the file's output unit (one for the three outputs), fixed "
                        "instead of profiled; implies --effects ...,quantisation (docs/model.md, Quantisation)")
    p.add_argument("--hysteresis-width", type=float, default=None, metavar="DEGC",
                   help="the play's half-width r in degC (fixed instead of profiled)")
    p.add_argument("--joint-units", action="store_true",
                   help="fit every unit of a multi-unit file jointly, the bench's tilt (and non-orthogonality) "
                        "shared, each unit with its own parameters (docs/joint.md); one result per unit in --json-dir")
    p.add_argument("--json-dir", metavar="DIR", help="with --joint-units: write DIR/<unit>.json for every unit")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..api import example_path, fit
    from ..fleet.select import select_unit_state
    from ..io.bench_csv import read_bench_csv
    from ..reports.summary import summary_text

    if bool(args.data) == bool(args.example):
        raise InputError("give a bench CSV file or --example")
    out = output(args)
    if args.joint_units:
        return _joint_units(args, out)
    if args.json_dir:
        raise InputError("--json-dir goes with --joint-units (one result per unit); for one unit use --json")
    campaign = select_unit_state(read_bench_csv(args.data or example_path()), args.unit, args.state,
                                 source=args.data)
    result = fit(campaign, method=args.method, effects=None if args.effects is None else name_list(args.effects),
                 reference_temperature_C=args.reference_temperature, loss=args.loss,
                 strict=args.strict, json_path=args.json, netcdf_path=args.netcdf,
                 angle_bound_arcsec=args.angle_bound_arcsec, lab=args.lab,
                 hysteresis_form=args.hysteresis_form, hysteresis_half_width_C=args.hysteresis_width,
                 bench_errors_from_replicates=args.bench_errors_from_replicates, thermal_order=args.thermal_order,
                 thermal_lag_form=args.thermal_lag_form, quantisation_lsb=args.quantisation_lsb,
                 bridge_gaps=args.bridge_gaps)
    out.say(summary_text(result))
    if args.json:
        out.say(f"result written to {args.json}")
    if args.netcdf:
        out.say(f"residuals written to {args.netcdf}")
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    return 0 if result.status == "ok" else 3


def _joint_units(args, out) -> int:
    """``fit --joint-units``: every unit of the file (one state) with the bench terms shared."""
    from pathlib import Path

    from ..api import example_path
    from ..estimation.gates import GateConfig
    from ..estimation.multi import fit_joint_units
    from ..io.bench_csv import read_bench_csv
    from ..io.lab import bench_errors_of, load_lab
    from ..reports.summary import summary_text
    from ..uncertainty.typeb import systematic_sources

    if args.method != "joint" or args.unit or args.json or args.netcdf:
        raise InputError("--joint-units fits every unit with the joint method: no --unit, --json or --netcdf "
                         "(give --json-dir DIR)")
    ignored = [flag for flag, given in (
        ("--loss", args.loss != "l2"), ("--strict", args.strict), ("--thermal-order", args.thermal_order != "1"),
        ("--hysteresis-form", args.hysteresis_form != "offset"), ("--hysteresis-width", args.hysteresis_width is not None),
        ("--thermal-lag-form", args.thermal_lag_form != "rate"), ("--bridge-gaps", args.bridge_gaps),
        ("--quantisation-lsb", args.quantisation_lsb is not None),
        ("--bench-errors-from-replicates", args.bench_errors_from_replicates)) if given]
    from ..estimation.form_names import FORM_NAMES

    unit_effects = name_list(args.effects) if args.effects is not None else list(DEFAULT_EFFECTS)
    ignored += [e for e in unit_effects if e in FORM_NAMES or e in NOISE_EFFECTS or e == "quantisation"]
    if ignored:
        raise InputError(f"--joint-units fits the effects of the joint model with least squares, not {', '.join(ignored)} "
                         "(they would be ignored); fit each unit with --unit for those")
    campaign = read_bench_csv(args.data or example_path())
    if args.state is not None:
        states = sorted(set(campaign.state.tolist()))
        if args.state not in states:
            raise InputError(f"{args.data}: no state {args.state!r}; its states are {', '.join(states)}")
        campaign = campaign.select(campaign.state == args.state, own_origin=True)
    lab = load_lab(args.lab) if args.lab else None
    results = fit_joint_units(campaign, unit_effects, reference_temperature_C=args.reference_temperature,
                              bench_errors=bench_errors_of(lab) if lab else None,
                              systematics=systematic_sources(lab, campaign.output_unit) if lab else (),
                              gates=GateConfig(angle_bound_arcsec=args.angle_bound_arcsec))
    for unit, r in results.items():
        out.say(summary_text(r))
        if args.json_dir:
            from ..fleet.batch import safe_name

            path = Path(args.json_dir) / f"{safe_name(unit)}.json"
            path.parent.mkdir(parents=True, exist_ok=True)
            r.save(path)
            out.say(f"result written to {path}")
    return 0 if all(r.status == "ok" for r in results.values()) else 3
