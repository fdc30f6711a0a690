"""``triadcal simulate``: write a simulated campaign as bench CSV v1 and its truth as JSON."""

from __future__ import annotations

from ..models.effects import DEFAULT_EFFECTS, VOCABULARY
from ..models.simulate import PRESETS, STANDARD_SETPOINTS_C, RampSchedule, Schedule
from ._common import add_output_options, assignments, float_list, name_list, output


def register(sub) -> None:
    p = sub.add_parser(
        "simulate", help="simulate a bench campaign (bench CSV v1) with known truth",
        description="Simulate a multi-position thermal campaign with the model's physics. "
                    "Same seed, same file.")
    p.add_argument("-o", "--output", required=True, help="bench CSV v1 file to write")
    p.add_argument("--truth", help="write the true parameters and noise here (JSON)")
    p.add_argument("--preset", default="ak18-quartz",
                   help=f"one of {', '.join(sorted(PRESETS))}: unit drawn from the paper's Tables 1-2 (default: ak18-quartz)")
    p.add_argument("--effects", default=",".join(DEFAULT_EFFECTS),
                   help=f"comma-separated effects present in the unit, from: {', '.join(VOCABULARY)} "
                        f"(default: {','.join(DEFAULT_EFFECTS)}); 'none' for eq. 1 only")
    p.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="set a parameter in its reporting unit, e.g. --set Ca_xy=40 (repeatable)")
    p.add_argument("--setpoints", default=",".join(f"{s:g}" for s in STANDARD_SETPOINTS_C),
                   help="chamber setpoints in degC, in order (default: 15 setpoints, +70 and -40 degC)")
    p.add_argument("--soak-s", type=float, default=7200.0, help="soak time per setpoint, s (default 7200)")
    p.add_argument("--tau-s", type=float, default=30.0, help="averaging time per position, s (default 30)")
    p.add_argument("--Q", type=float, default=3e-9, help="white-noise intensity of the outputs, V^2 s (default 3e-9)")
    p.add_argument("--sigma-position-arcsec", type=float, default=None,
                   help="bench positioning error per axis, arcsec (sigma_1; default 0, or 5 with position_error)")
    p.add_argument("--sigma-wobble-arcsec", type=float, default=None,
                   help="wobble of axis 1, arcsec (sigma_2; default 0, or 2 with position_error)")
    p.add_argument("--heavy-tails-dof", type=float, default=None,
                   help="Student-t degrees of freedom of the output noise (default 3 with heavy_tails)")
    p.add_argument("--plan", metavar="PLAN",
                   help="simulate a plan of `triadcal plan` (its setpoints, soaks, positions, repetitions and tau; "
                        "replaces --setpoints, --soak-s and --tau-s; docs/plan.md)")
    p.add_argument("--ramp", metavar="T0:T1:...",
                   help="continuous ramp instead of setpoints: the chamber's piecewise-linear program in degC, e.g. "
                        "20:-40:85:20; the bench cycles through the positions back to back for the program's "
                        "duration (no soak; replaces --setpoints and --soak-s; docs/plan.md)")
    p.add_argument("--ramp-rate", default="1degC/min", help="rate of the ramp program (default 1degC/min)")
    p.add_argument("--ramp-hold-s", type=float, default=0.0,
                   help="hold at every interior turning point of the ramp program, s (default 0)")
    p.add_argument("--unit", default="SN-SIM-0001", help="serial number written in the file")
    p.add_argument("--seed", type=int, default=0)
    add_output_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..api import simulate

    effects = name_list(args.effects)
    positions, metadata = None, None
    if getattr(args, "plan", None):
        from ..planning.ramp import load_plan

        plan = load_plan(args.plan)
        schedule, positions = plan.schedule(), plan.visit_positions()
        if plan.effects is not None:      # the model the plan predicted U for: the fit's default effects
            metadata = {"planned_effects": ",".join(plan.effects) or "none"}
    elif getattr(args, "ramp", None):
        from ..errors import InputError
        from .plan import _rate

        try:
            program = tuple(float(v) for v in args.ramp.split(":"))
        except ValueError:
            raise InputError(f"--ramp: {args.ramp!r}; write the program's temperatures in degC, e.g. 20:-40:85:20") from None
        schedule = RampSchedule(program_C=program, rate_C_per_min=_rate(args.ramp_rate, "--ramp-rate"),
                                hold_s=args.ramp_hold_s, tau_s=args.tau_s)
        schedule.knots()                                  # refuses a bad program, rate or hold here
    else:
        schedule = Schedule(setpoints_C=tuple(float_list(args.setpoints)), soak_s=args.soak_s, tau_s=args.tau_s)
    truth, campaign = simulate(
        args.output, truth_path=args.truth, preset=args.preset, effects=effects,
        parameters=assignments(args.set), schedule=schedule, Q_V2s=args.Q,
        sigma_position_arcsec=args.sigma_position_arcsec, sigma_wobble_arcsec=args.sigma_wobble_arcsec,
        heavy_tails_dof=args.heavy_tails_dof, unit=args.unit, seed=args.seed, plan=positions, metadata=metadata)
    where = (f"on the ramp {':'.join(f'{v:g}' for v in schedule.program_C)} degC at {schedule.rate_C_per_min:g} "
             f"degC/min ({schedule.duration_s / 3600.0:.2f} chamber hours)" if isinstance(schedule, RampSchedule)
             else f"at {len(schedule.setpoints_C)} setpoints")
    output(args).say(f"wrote {args.output}: {campaign.n_visits} visits of {truth.unit} {where}, "
                     f"with effects {', '.join(effects) or 'none'}"
                     + (f"; the truth is in {args.truth}" if args.truth else ""))
    return 0
