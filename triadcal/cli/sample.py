"""``triadcal sample``: posterior of the joint model by MCMC, with diagnostics that gate it."""

from __future__ import annotations

from ..errors import InputError

import sys

from ..models.effects import DEFAULT_EFFECTS, EFFECTS, NOISE_EFFECTS
from ._common import add_output_options, name_list, output


def register(sub) -> None:
    p = sub.add_parser(
        "sample", help="posterior of every parameter of the joint model (emcee, arviz diagnostics)",
        description="Sample the posterior of the joint model of a bench CSV v1 campaign with documented, "
                    "weakly informative priors (stated in the JSON under 'priors'). Runs until the chain is "
                    ">= 50 autocorrelation times long and every parameter has the requested bulk and tail "
                    "ESS and R-hat < 1.01; otherwise the result says status: not_converged (exit code 3).")
    p.add_argument("data", nargs="?", help="bench CSV v1 file")
    p.add_argument("--example", action="store_true", help="use the built-in example campaign")
    p.add_argument("--unit", default=None, metavar="SN", help="serial number to sample when the file holds several")
    p.add_argument("--state", default=None, metavar="NAME",
                   help="mechanical state to sample when the file holds several")
    p.add_argument("--effects", default=None,
                   help=f"effects of the joint model, from: {', '.join(EFFECTS)}, the noise effects "
                        f"{', '.join(NOISE_EFFECTS)}, and quantisation (a digital output rounded to an LSB q: the "
                        "least-squares fit with the term first, q given or profiled, then the posterior with q and "
                        "the per-sample sigma held at the fit's values), and the diagnosis's forms hysteresis_play, "
                        "hysteresis_pi and thermal_lag_history (the form's nonlinear parameters profiled by the least "
                        "squares and held, as fit --effects with the same names); default: the effects the "
                        "data's plan was made for (# planned_effects), else "
                        f"{','.join(DEFAULT_EFFECTS)}")
    p.add_argument("--reference-temperature", type=float, default=20.0, metavar="DEGC",
                   help="reference temperature of the thermal model, degC (default 20)")
    p.add_argument("--quantisation-lsb", type=float, default=None, metavar="Q",
                   help="the LSB q of a digital output in the file's output unit (one for the three outputs), fixed "
                        "instead of profiled; implies --effects ...,quantisation (docs/model.md, Quantisation)")
    p.add_argument("--ess", type=float, default=2000,
                   help="bulk and tail ESS requested for every parameter, a finite number > 0 (default 2000)")
    p.add_argument("--max-steps", type=int, default=20000,
                   help="stop after this many steps even if not converged, at least 20 (the first look's "
                        "burn-in; default 20000)")
    p.add_argument("--walkers", type=int, default=None,
                   help="number of walkers, an even integer >= 2 x the free parameters (default 2 x parameters)")
    p.add_argument("--seed", type=int, default=0, help="random seed, an integer in 0..2**32-1 (default 0)")
    p.add_argument("--angle-bound-arcsec", type=float, default=3600.0, metavar="ARCSEC",
                   help="answer gate: largest orientation angle accepted as 'ok', arcsec (default 3600 = 1 deg)")
    p.add_argument("--lab", metavar="LAB.toml",
                   help="lab file: its [bench] positioning and wobble SDs (arcsec) enter the model as "
                        "variance components, its systematic errors (encoder zeros, axes non-orthogonality, "
                        "fixture, g, thermometers, voltmeter) are propagated to every parameter as Type B, "
                        "with a budget, U and k per parameter (docs/lab.md; without it, u is Type A only)")
    p.add_argument("--json", metavar="OUT", help="write the result (results-json v1, method posterior)")
    p.add_argument("--posterior", metavar="OUT.nc", help="write the arviz InferenceData (netCDF)")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..api import example_path
    from ..estimation.gates import GateConfig
    from ..estimation.posterior import sample
    from ..io.bench_csv import read_bench_csv
    from ..io.lab import bench_errors_of, load_lab
    from ..uncertainty.typeb import systematic_sources
    from ..reports.summary import summary_text

    if bool(args.data) == bool(args.example):
        raise InputError("give a bench CSV file or --example")
    from ..estimation.posterior.options import check_sampler_options

    # before anything is read (--walkers needs the model's number of parameters: sample() checks it)
    check_sampler_options(ess=args.ess, max_steps=args.max_steps, seed=args.seed)
    from ..fleet.select import select_unit_state

    data = str(example_path()) if args.example else args.data
    campaign = select_unit_state(read_bench_csv(data), args.unit, args.state, source=data)
    lab = load_lab(args.lab) if args.lab else None
    from ..io.lab import with_lab_gravity

    campaign = with_lab_gravity(campaign, lab)
    out = output(args)
    bar = out.bar(total=args.max_steps, desc="sampling", unit="step")
    progress = None
    if bar is not None:
        def progress(steps, max_steps, check):
            bar.update(steps - bar.n)
            if check is not None:
                bar.set_postfix(tau=f"{check['tau_max']:.1f}", ess=f"{check['ess_estimate']:.0f}",
                                rhat=f"{check.get('rhat_max', check['rhat_classic_max']):.3f}")
    try:
        from ..estimation.planned_effects import resolve

        effects, planned_note = resolve(None if args.effects is None else name_list(args.effects), campaign)
        result = sample(campaign, effects, reference_temperature_C=args.reference_temperature,
                        ess=args.ess, max_steps=args.max_steps, n_walkers=args.walkers, seed=args.seed,
                        progress=progress, json_path=None if planned_note else args.json,
                        posterior_path=args.posterior,
                        gates=GateConfig(angle_bound_arcsec=args.angle_bound_arcsec),
                        bench_errors=bench_errors_of(lab) if lab else None,
                        systematics=systematic_sources(lab, campaign.output_unit) if lab else (),
                        quantisation_lsb=args.quantisation_lsb)
    finally:
        if bar is not None:
            bar.close()
    if planned_note:
        result.notes.append(planned_note)
        if args.json:
            result.save(args.json)
    out.say(summary_text(result))
    s = result.extra["sampler"]
    out.say(f"  sampler: {s['walkers']} walkers x {s['steps']} steps ({s['moves']}), tau_max = {s['tau_max']:.1f}, "
            f"ESS bulk/tail >= {s['ess_bulk_min']:.0f}/{s['ess_tail_min']:.0f}, R-hat <= {s['rhat_max']:.4f}, "
            f"{s['total_seconds']:.1f} s")
    flags = result.extra["flags"]
    if flags["prior_dominated"]:
        out.say("  prior-dominated (not measured): " + ", ".join(flags["prior_dominated"]))
    if flags["non_gaussian"]:
        out.say("  posterior and least-squares intervals differ (non-Gaussian): " + ", ".join(flags["non_gaussian"]))
    if args.json:
        out.say(f"result written to {args.json}")
    if args.posterior:
        out.say(f"posterior written to {args.posterior}")
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    return 0 if result.status == "ok" else 3
