"""``triadcal budget``: the paper's error budgets, eq. 4 (bench test) and eq. 5-7 (thermal drift)."""

from __future__ import annotations

from pathlib import Path

from ._common import add_output_options, output


def register(sub) -> None:
    p = sub.add_parser(
        "budget", help="error budget of the orientation angles (the paper's eq. 4, or eq. 5-7 with --thermal)",
        description="Eq. 4: error of an orientation angle from the bench test (defaults: the paper's example, "
                    "11.52\"), with the standard deviation of the classical estimate per angle for comparison. "
                    "--thermal: eq. 5-7, thermal drift of the axes for a unit of the paper's Table 1 "
                    "(--accelerometer) or for all of them.")
    p.add_argument("--K", type=float, default=None, metavar="G_PER_V", help="scale factor K, g/V (default 1)")
    p.add_argument("--Q", type=float, default=None, metavar="V2S", help="white-noise intensity, V^2 s (default 3e-9)")
    p.add_argument("--tau", type=float, default=None, metavar="S", help="averaging time per position, s (default 30)")
    p.add_argument("--sigma1", type=float, default=None, metavar="ARCSEC",
                   help="bench positioning error, arcsec (default 5)")
    p.add_argument("--sigma2", type=float, default=None, metavar="ARCSEC", help="wobble of the axes, arcsec (default 2)")
    p.add_argument("--G", type=float, default=None, metavar="G", help="local gravity, g (default 1)")
    p.add_argument("--thermal", action="store_true", help="thermal drift budget, eq. 5-7")
    p.add_argument("--accelerometer", metavar="NAME",
                   help="unit of Table 1 (A-18, AK-15, BA-3, A-18T, AK-18, AAK-02, QA-3000); default: all")
    p.add_argument("--k-ca", type=float, default=None, metavar="ARCSEC_PER_C",
                   help="tempco of the reference plane for eq. 7 (default 1.5 quartz, 6 silicon)")
    p.add_argument("--dT", type=float, default=None, metavar="DEGC", help="temperature error, degC (default 0.2)")
    p.add_argument("--cte-body", type=float, default=None, metavar="PER_C",
                   help="CTE of the IMU body parts, 1/degC (default 22.9e-6, D-16)")
    p.add_argument("--cte-accelerometer", type=float, default=None, metavar="PER_C",
                   help="CTE of the accelerometer body, 1/degC (default 15e-6, steel)")
    p.add_argument("--T-max", type=float, default=None, metavar="DEGC", help="maximum temperature, degC (default 85)")
    p.add_argument("--T0", type=float, default=None, metavar="DEGC", help="normal temperature, degC (default 20)")
    p.add_argument("--json", metavar="OUT", help="write the budget tables (triadcal.budget v1)")
    add_output_options(p)
    p.set_defaults(func=run)


def _table(b) -> str:
    lines = [f"{b.quantity} ({b.equation})",
             f"  {'source':<72} {'u':>11} {'unit':<7} {'sensitivity':>14} {'contribution':>12}"]
    for c in b.components:
        sens = f"{c.sensitivity:.4g} {c.sensitivity_unit}" if c.sensitivity_unit != "1" else f"{c.sensitivity:.4g}"
        lines.append(f"  {c.source:<72} {c.u:>11.4g} {c.unit:<7} {sens:>14} "
                     f"{c.contribution:>10.2f} {b.unit}")
    lines.append(f"  {'total (' + b.combination + ')':<72} {'':>11} {'':<7} {'':>14} {b.total:>10.2f} {b.unit}")
    if "classical_sd_arcsec" in b.extra:
        sd = b.extra["classical_sd_arcsec"]
        lines.append("  standard deviation of the classical estimate, default 12-position plan: "
                     + ", ".join(f"{k} {v:.2f}" for k, v in sd.items()) + " arcsec")
    for n in b.notes:
        lines.append(f"  note: {n}")
    return "\n".join(lines)


#: the options of each budget and their defaults (the parser's are None): an option of the other budget given is refused
#: (an outside probe: `budget --dT 5` and `budget --thermal --K 5` printed the unchanged table, exit 0)
EQ4_OPTIONS = {"K": 1.0, "Q": 3e-9, "tau": 30.0, "sigma1": 5.0, "sigma2": 2.0, "G": 1.0}
THERMAL_OPTIONS = {"k_ca": None, "dT": 0.2, "cte_body": 22.9e-6, "cte_accelerometer": 15e-6, "T_max": 85.0,
                   "T0": 20.0}


def run(args) -> int:
    from ..errors import InputError
    from ..uncertainty.paper import budget

    own, other, why = ((THERMAL_OPTIONS, EQ4_OPTIONS, "eq. 4's (the bench test): not used by --thermal")
                       if args.thermal else (EQ4_OPTIONS, THERMAL_OPTIONS, "eq. 5-7's: add --thermal"))
    # given at all, whatever its value (the defaults are None: `--K 1 --thermal`, the default's value, was
    # accepted in silence by a check against the default -- an outside probe)
    given = ["--" + k.replace("_", "-") for k in other if getattr(args, k) is not None]
    if given:
        raise InputError(f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} {why}")
    for k, v in {**EQ4_OPTIONS, **THERMAL_OPTIONS}.items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    out = output(args)
    tables = budget(thermal=args.thermal, accelerometer_name=args.accelerometer, K_g_per_V=args.K, Q_V2s=args.Q,
                    tau_s=args.tau, sigma1_arcsec=args.sigma1, sigma2_arcsec=args.sigma2, G_g=args.G,
                    k_ca_arcsec_per_C=args.k_ca, dT_C=args.dT, cte_body_per_C=args.cte_body,
                    cte_accelerometer_per_C=args.cte_accelerometer, T_max_C=args.T_max, T0_C=args.T0)
    if args.thermal and args.accelerometer is None:
        out.say("thermal drift of the axes (eq. 5-7) for the units of Table 1")
        out.say(f"  {'unit':<9} {'material':<8} {'dCa_Ta':>8} {'dCa_Tn':>8} {'dCa_Tk':>8} {'dCa_T':>8}  arcsec")
        for b in tables:
            parts = {c.symbol: c.contribution for c in b.components}
            acc = b.extra["accelerometer"]
            out.say(f"  {acc['name']:<9} {acc['material']:<8} {parts['dCa_Ta']:>8.2f} {parts['dCa_Tn']:>8.2f} "
                  f"{parts['dCa_Tk']:>8.2f} {b.total:>8.2f}")
    else:
        out.say("\n\n".join(_table(b) for b in tables))
    if args.json:
        doc = {"format": "triadcal.budget", "version": 1, "tables": [b.to_dict() for b in tables]}
        from ..io.atomic import atomic_write_json

        atomic_write_json(Path(args.json), doc)
        out.say(f"budget written to {args.json}")
    return 0
