"""``triadcal plan``: choose a stepped campaign for a target uncertainty and predict its U and hours."""

from __future__ import annotations

from ..errors import InputError
from ._common import add_output_options, name_list, output


def _range(text: str) -> tuple:
    try:
        lo, hi = (float(v) for v in text.split(":"))
    except ValueError:
        raise InputError(f"--range: {text!r}; write LOW:HIGH in degC, e.g. -40:85") from None
    from ..planning.search import checked_range

    checked_range(lo, hi)
    return lo, hi


def _hours(text: str) -> float:
    from ..planning.search import checked_hours_cap

    return checked_hours_cap(text)


def _rate(text: str, option: str = "--chamber-rate") -> float:
    t = text.strip().replace("°C", "degC").replace(" ", "")
    for suffix, f in (("degC/min", 1.0), ("degC/h", 1.0 / 60.0), ("K/min", 1.0)):
        if t.endswith(suffix):
            t = t[: -len(suffix)]
            break
    else:
        f = 1.0
    try:
        return float(t) * f
    except ValueError:
        raise InputError(f"{option}: {text!r}; write e.g. 1degC/min") from None


def register(sub) -> None:
    from ..models.effects import DEFAULT_EFFECTS

    p = sub.add_parser(
        "plan", help="plan a stepped campaign for target uncertainties (predicted U and chamber hours)",
        description="Search setpoints (heating and cooling sweeps), positions (12/18/24), dwell and repetitions "
                    "for the plan with the fewest chamber hours whose predicted U (Fisher information of the "
                    "model, the lab's bench and systematic errors included) meets every target (docs/plan.md).")
    p.add_argument("--target", required=True,
                   help='targets, e.g. "Ca:U<=5arcsec, Ca_tempco:U<=0.1arcsec/degC, K:U<=20ppm" '
                        "(families Ca, Ca_tempco, Ca_hysteresis, K, K_tempco, S, S_tempco, tilt, or one parameter)")
    p.add_argument("--lab", metavar="LAB.toml", help="lab file: bench errors and systematic errors (docs/lab.md)")
    p.add_argument("--range", required=True, metavar="LOW:HIGH", help="temperature range, degC (e.g. -40:85)")
    p.add_argument("--chamber-rate", default="1degC/min", help="chamber ramp rate (default 1degC/min)")
    p.add_argument("--positions", default="auto", choices=("auto", "12", "18", "24"),
                   help="position set (default auto: search 12, 18 and 24)")
    p.add_argument("--q", type=float, default=None, metavar="V2S",
                   help="white-noise intensity of the outputs, V^2 s (default 3e-9, the example campaign's Q_V2s)")
    p.add_argument("--effects", default=",".join(DEFAULT_EFFECTS), help="effects of the model to be fitted")
    p.add_argument("--preset", default="ak18-quartz", help="unit whose parameter values the Jacobian is taken at")
    p.add_argument("--max-hours", default="200", help="cap of chamber hours (default 200)")
    p.add_argument("--ramp", action="store_true",
                   help="plan a continuous ramp instead (no soak): program legs, rate (1, 1/2, 1/4 of --chamber-rate), "
                        "holds, positions and dwell; thermal_lag is added to the model (docs/plan.md)")
    p.add_argument("-o", "--output", required=True, metavar="PLAN", help="plan file to write (JSON, docs/plan.md)")
    p.add_argument("--json", metavar="PRED.json", help="write the prediction (U per parameter, hours, targets)")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..io.atomic import atomic_write_json
    from ..io.lab import load_lab
    from ..planning import DEFAULT_Q_V2S, prediction_document, search
    from ..planning.search import HELD_NEGLIGIBLE

    lo, hi = _range(args.range)
    hours_cap = _hours(args.max_hours)
    lab = load_lab(args.lab) if args.lab else None
    Q = DEFAULT_Q_V2S if args.q is None else args.q
    effects = name_list(args.effects)
    if getattr(args, "ramp", False):
        from ..planning.ramp import ramp_effects, search_ramp

        effects = ramp_effects(effects)
        choice = search_ramp(args.target, lo, hi, lab=lab, Q_V2s=Q, chamber_rate_C_per_min=_rate(args.chamber_rate),
                             positions=args.positions, effects=effects, preset=args.preset,
                             hours_cap=hours_cap)
    else:
        choice = search(args.target, lo, hi, lab=lab, Q_V2s=Q, chamber_rate_C_per_min=_rate(args.chamber_rate),
                        positions=args.positions, effects=effects, preset=args.preset, hours_cap=hours_cap)
    doc = prediction_document(choice, Q_V2s=Q, lab_source=args.lab, preset=args.preset, effects=effects)
    choice.plan.save(args.output, predicted={"chamber_hours": doc["chamber_hours"],
                                             "U": {n: v["U"] for n, v in doc["parameters"].items()},
                                             "criterion": doc["criterion"], "effects": list(effects)})
    if args.json:
        atomic_write_json(args.json, doc)
    plan = choice.plan
    out = output(args)
    if getattr(args, "ramp", False):
        out.say(f"plan: {plan.describe()}: {plan.chamber_hours():.1f} chamber hours "
                f"({doc['candidates_searched']} ramp plans evaluated)")
    else:
        out.say(f"plan: {plan.name}; {len(plan.setpoints_C)} setpoints "
                f"({', '.join(f'{s:g}' for s in plan.setpoints_C)} degC), {len(plan.positions)} positions x "
                f"{plan.repetitions}, tau {plan.tau_s:g} s: {plan.chamber_hours():.1f} chamber hours "
                f"({doc['candidates_searched']} plans searched)")
    left = doc["assumptions"].get("left_out_effects", {})
    for spec, t in doc["target"].items():
        verdict = "met" if t["met"] else "NOT met"
        if t["met"] and t.get("met_if_unit_has_no"):
            # met by the planned model's U only: a left-out effect at the preset's magnitude moves this target by more
            # than HELD_NEGLIGIBLE of it (never a bare "met" then; the moves in the notes below)
            verdict = f"met if the unit has no {', '.join(t['met_if_unit_has_no'])} (notes below)"
        out.say(f"  {spec}: predicted U {t['U_worst']:.3g} {t['unit']} ({t['worst_parameter']}) {verdict}")
    lag_targets = [spec for spec, t in doc["target"].items() if any(str(n).startswith("thermal_lag")
                                                                    for n in t.get("parameters", []))]
    if lag_targets:
        # the lag is seen only through the thermal terms it delays: its U depends on the unit's tempcos (an outside
        # probe's unit with K tempcos of 3-5 ppm/degC fitted U 0.070 min where 0.043 was predicted "met")
        from ..models.simulate import PRESETS

        pre = PRESETS.get(args.preset, {})
        k_tc = sorted(abs(float(pre.get(f"K_{a}_tempco", 0.0))) for a in "xyz")
        s_tc = sorted(abs(float(pre.get(f"S_{a}_tempco", 0.0))) for a in "xyz")
        out.say(f"  note: {', '.join(lag_targets)}: the lag is measured through the thermal terms it delays, so its U "
                f"was predicted at the {args.preset} preset's tempcos (K {k_tc[0]:g}-{k_tc[-1]:g} ppm/degC, S "
                f"{s_tc[0]:g}-{s_tc[-1]:g} ug/degC) and grows as they shrink: tempcos all n times smaller give about n "
                "times the U (plan with --preset of a unit like yours)")
    for h, v in doc["assumptions"].get("held_effects", {}).items():
        # a requested effect this plan holds (none of the plans that estimate it met the targets), said, not dropped
        worst = max(v["moves"].items(), key=lambda kv: abs(kv[1]["bias"]), default=None)
        moved = (f"; at {v['magnitude']:g} {v['unit']} it moves {worst[0]} by {worst[1]['bias']:+.2g} {worst[1]['unit']} at most, "
                 f"under {100 * HELD_NEGLIGIBLE:g} % of the target" if worst else "")
        out.say(f"  note: {h} ({v['effect']}) is not estimated by this plan, held at {v['held_at']:g} {v['unit']}: "
                f"{v['reason']}{moved}")
    for e, v in left.items():
        # an effect of the preset unit outside --effects that this plan's fit would absorb into the targets: said,
        # not refused (the preset is an example unit; the user's may not have it)
        vals = [p["value"] for p in v["preset_parameters"].values()]
        unit = next(iter(v["preset_parameters"].values()))["unit"] if vals else ""
        mags = sorted({abs(x) for x in vals})
        mag = (f"{mags[0]:g} to {mags[-1]:g} {unit}" if len(mags) > 1 else f"{vals[0]:g} {unit}")
        p, m = max(v["moves"].items(), key=lambda kv: kv[1]["fraction_of_target"])
        out.say(f"  note: {e} is not in --effects; at the {args.preset} preset's magnitude ({mag}) it would move {p} "
                f"by {m['bias']:+.3g} {m['unit']} on this plan ({100 * m['fraction_of_target']:.3g} % of {m['target']}; "
                f"all moves in the JSON's assumptions.left_out_effects): if your unit may have it, add it to --effects")
    out.say(f"wrote {args.output}" + (f" and {args.json}" if args.json else ""))
    return 0
