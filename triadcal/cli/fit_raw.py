"""``triadcal fit-raw``: calibrate from a raw recording of hand-placed static poses."""

from __future__ import annotations

import math
import sys

from ..errors import InputError
from ._common import add_output_options, name_list, output


def register(sub) -> None:
    p = sub.add_parser(
        "fit-raw", help="calibrate from a raw recording (hand-placed faces or free static poses)",
        description="Calibrate an accelerometer triad from a raw recording: finds (or reads) the static "
                    "intervals, then fits K, S and the angles with uncertainties. --poses known: imucal's six "
                    "faces (x_p = +X up, x_a = X down, ...) with a random placement tilt per pose; "
                    "--poses unknown: the gravity-norm model of Tedaldi et al. 2014 (imu_tk).")
    p.add_argument("data", help="raw recording (CSV with named columns; header lines before them are allowed)")
    p.add_argument("--rate", type=float, required=True, metavar="HZ",
                   help="sample rate in Hz (required: a wrong rate is the bug of imucal issue #25)")
    p.add_argument("--columns", default=None, help="accelerometer columns, e.g. acc_x,acc_y,acc_z "
                   "(default: the first of acc_x,acc_y,acc_z / ax,ay,az / x,y,z in the header)")
    p.add_argument("--unit", choices=("m/s2", "g", "mg", "counts"), default=None,
                   help="unit of the readings (default counts, said in a note with what the readings look like)")
    p.add_argument("--poses", choices=("known", "unknown"), default="known")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--labels", metavar="COLUMN", help="label column naming the poses (imucal's 'part')")
    src.add_argument("--intervals", metavar="FILE",
                     help="static intervals: imucal session-list JSON, or start/end sample indices (CSV)")
    p.add_argument("--local-g", type=float, default=None, metavar="M_S2",
                   help="local gravity, m/s2 (not given: 9.81 assumed, said in a note, no certificate); outside "
                        "9.76-9.84 (Earth's surface) refused unless --local-g-override")
    p.add_argument("--local-g-override", action="store_true",
                   help="accept a --local-g outside Earth's surface range (a centrifuge, another planet, a "
                        "deliberate test), as '# local_g_override = true' does in a bench CSV")
    p.add_argument("--placement-sd-deg", default="auto", metavar="DEG|auto",
                   help="SD of the hand-placement tilt per pose and component, deg (a stated prior), or 'auto' "
                        "(default): integrated over a log-uniform hyperprior on 0.02-20 deg, weighted by what the "
                        "data say (fit.placement_sd_from_data) (known poses)")
    p.add_argument("--misalignment-sd-deg", type=float, default=1.0,
                   help="prior SD of each misalignment angle Ca_*, deg (known poses; default 1, a cross-axis "
                        "sensitivity of 1.7 %%): the angles are confounded with the placement, and their spread "
                        "reaches K and S at second order (see fit.prior_sensitivity)")
    p.add_argument("--counts-per-g", type=float, default=None,
                   help="datasheet scale for the 'before' figure of count data (default: one isotropic scale)")
    p.add_argument("--serial", default=None, help="serial number for the result (default: the file name)")
    p.add_argument("--static-window-s", type=float, default=1.0, help="detector window, s (default 1)")
    p.add_argument("--static-threshold", type=float, default=4.0,
                   help="detector threshold, multiples of the robust noise SD (default 4)")
    p.add_argument("--min-static-s", type=float, default=2.0, help="shortest static interval kept, s (default 2)")
    p.add_argument("--sample", action="store_true",
                   help="posterior by MCMC through the bench's path (triadcal sample: same moves, stop rule, "
                        "diagnostics); the result is the posterior's, the least-squares values are in fit.least_squares")
    p.add_argument("--posterior", metavar="OUT.nc", help="with --sample: write the arviz InferenceData (netCDF)")
    p.add_argument("--ess", type=float, default=2000, help="with --sample: requested bulk and tail ESS (default 2000)")
    p.add_argument("--max-steps", type=int, default=20000,
                   help="with --sample: steps after which the result says not_converged (default 20000)")
    p.add_argument("--seed", type=int, default=0, help="with --sample: random seed (default 0)")
    p.add_argument("--angle-bound-arcsec", type=float, default=3600.0, metavar="ARCSEC",
                   help="answer gate: largest orientation angle accepted as 'ok', arcsec (default 3600 = 1 deg)")
    p.add_argument("--json", metavar="OUT", required=True, help="write the result (results-json v1)")
    p.add_argument("--bench-csv", metavar="OUT.csv", help="write the pose averages as bench CSV v1 (known poses)")
    p.add_argument("--temperature-column", metavar="COLUMN", default=None,
                   help="column with the unit's temperature in degC; with --diagnose the bias tempco is a "
                        "candidate (docs/diagnosis.md, \"Diagnosing real recordings\")")
    p.add_argument("--bias-tempco-bound", type=float, default=None, metavar="UG_PER_DEGC",
                   help="with --temperature-column: the largest bias tempco of the unit (ug/degC, a datasheet's): "
                        "what it moves, where the poses' temperatures differ, enters the u as Type B (else the "
                        "gate unseen_tempco judges it; docs/raw.md)")
    p.add_argument("--scale-tempco-bound", type=float, default=None, metavar="PPM_PER_DEGC",
                   help="with --temperature-column: the largest scale-factor tempco (ppm/degC), as "
                        "--bias-tempco-bound")
    p.add_argument("--diagnose", metavar="OUT.json",
                   help="after the fit, diagnose the static intervals (where the residual lies, which candidate "
                        "term shrinks it on held-out intervals) and write a triadcal.diagnosis JSON "
                        "(docs/diagnosis.md, 'Diagnosing real recordings')")
    add_output_options(p)
    p.set_defaults(func=run)


def _number(option: str, value, *, low: float = 0.0, low_open: bool = True, what: str = "") -> None:
    """Refuse an option value that is not finite or not above ``low`` (at or above when
    ``low_open`` is False), naming the option and the value."""
    if value is None:
        return
    ok = math.isfinite(value) and (value > low if low_open else value >= low)
    if not ok:
        bound = f"{'>' if low_open else '>='} {low:g}"
        raise InputError(f"{option} must be a finite number {bound}{' (' + what + ')' if what else ''}, "
                         f"got {value!r}")


def check_options(args) -> None:
    """Every numeric option of fit-raw, and the combinations that would be refused after a fit,
    before anything is read or written (docs/raw.md, "What is refused, and where")."""
    from ..estimation.raw.fit import ASSUMED_LOCAL_G_M_S2, check_raw_options

    _number("--rate", args.rate, what="Hz")
    check_raw_options(ASSUMED_LOCAL_G_M_S2 if args.local_g is None else args.local_g, args.local_g_override,
                      window_s=args.static_window_s, threshold=args.static_threshold,
                      min_duration_s=args.min_static_s)
    placement = str(args.placement_sd_deg).strip()
    if placement.lower() != "auto":
        try:
            value = float(placement)
        except ValueError:
            raise InputError(f"--placement-sd-deg must be 'auto' or a number of degrees, got {placement!r}") from None
        _number("--placement-sd-deg", value, what="deg")
    _number("--misalignment-sd-deg", args.misalignment_sd_deg, what="deg")
    _number("--counts-per-g", args.counts_per_g, what="counts per g")
    _number("--angle-bound-arcsec", args.angle_bound_arcsec, what="arcsec")
    _number("--ess", args.ess)
    _number("--max-steps", args.max_steps)
    _number("--seed", args.seed, low_open=False)
    if args.bench_csv and args.poses != "known":
        raise InputError("--bench-csv needs known poses (--poses known): free orientations have no bench angles")
    if args.posterior and not args.sample:
        raise InputError("--posterior needs sampling (--sample)")
    for option, value in (("--bias-tempco-bound", args.bias_tempco_bound),
                          ("--scale-tempco-bound", args.scale_tempco_bound)):
        _number(option, value, low_open=False, what="a tempco's largest magnitude")
        if value is not None and args.temperature_column is None:
            raise InputError(f"{option} needs the unit's temperature (--temperature-column): without it the "
                             "poses' temperatures are not known")


def run(args) -> int:
    from ..estimation.gates import GateConfig
    from ..estimation.raw import fit_raw
    from ..io.bench_csv import LOCAL_G_RANGE_M_S2
    from ..reports.summary import summary_text

    unit_given = args.unit is not None
    args.unit = args.unit or "counts"
    check_options(args)
    ui = output(args)
    bar = ui.bar(total=args.max_steps, desc="sampling", unit="step") if args.sample else None
    progress = None
    if bar is not None:
        def progress(steps, max_steps, check):
            bar.update(steps - bar.n)
    try:
        out = fit_raw(args.data, args.rate, columns=name_list(args.columns) if args.columns else None,
                      unit=args.unit, poses=args.poses, labels=args.labels, intervals=args.intervals,
                      temperature_column=args.temperature_column, local_g_override=args.local_g_override,
                      tempco_bounds={"bias": args.bias_tempco_bound, "scale": args.scale_tempco_bound},
                      local_g_m_s2=args.local_g, placement_sd_deg=args.placement_sd_deg,
                      misalignment_sd_deg=args.misalignment_sd_deg,
                      counts_per_g=args.counts_per_g, serial=args.serial, window_s=args.static_window_s,
                      threshold=args.static_threshold, min_duration_s=args.min_static_s,
                      json_path=args.json, bench_csv_path=None, sample=args.sample,
                      posterior_path=args.posterior, ess=args.ess, max_steps=args.max_steps, seed=args.seed,
                      progress=progress, gates=GateConfig(angle_bound_arcsec=args.angle_bound_arcsec))
    finally:
        if bar is not None:
            bar.close()
    r = out.result
    if args.bench_csv:
        _write_bench_csv(out.campaign, args)
    ui.say(out.detection.summary(out.recording.rate_hz))
    for iv in out.detection.intervals:
        ui.say(f"  samples {iv.start:>7d} .. {iv.end:<7d} {iv.n / out.recording.rate_hz:6.1f} s  {iv.label}")
    ui.say(summary_text(r))
    rms = r.fit["rms_norm_residual_m_s2"]
    rmsm = r.fit["rms_norm_residual_of_means_m_s2"]
    ui.say(f"RMS of |a| - g over the static samples: {rms['before']:.4g} m/s2 before "
           f"({r.fit['before_scaling']}), {rms['after']:.4g} m/s2 after; of the interval means: "
           f"{rmsm['before']:.4g} -> {rmsm['after']:.4g} m/s2")
    if args.sample:
        smp = r.extra["sampler"]
        ui.say(f"posterior: status {r.status} after {smp['steps']} steps of {smp['walkers']} walkers; "
               f"tau_max = {smp['tau_max']:.3g}, smallest ESS {min(smp['ess_bulk_min'], smp['ess_tail_min']):.0f}, "
               f"largest R-hat {smp['rhat_max']:.4f}")
    ui.say(f"result written to {args.json}")
    if args.posterior:
        ui.say(f"posterior draws written to {args.posterior} (arviz InferenceData)")
    if args.bench_csv:
        ui.say(f"position averages written to {args.bench_csv} (bench CSV v1)")
    if args.diagnose:
        from ..judgement.raw_diagnosis import diagnose_raw, summary_lines

        diag = diagnose_raw(out)
        diag.save(args.diagnose)
        for line in summary_lines(diag):
            ui.say(line)
        ui.say(f"diagnosis written to {args.diagnose}")
    low, high = LOCAL_G_RANGE_M_S2
    if args.local_g is not None and not low <= args.local_g <= high:
        print(f"note: --local-g {args.local_g:g} m/s2, outside Earth's {low}-{high} m/s2, accepted with "
              "--local-g-override", file=sys.stderr)
    if not unit_given:
        print(f"note: {unit_note(out)}", file=sys.stderr)
    for note in r.notes:
        print(f"note: {note}", file=sys.stderr)
    return 0 if r.status == "ok" else 3


def unit_note(out) -> str:
    """What --unit counts (the default, not given) means, and what the static readings look like:
    a recording in m/s2 read as counts got K in g/counts with status ok and no word (a newcomer's
    probe)."""
    import numpy as np

    iv = out.detection.intervals
    acc = out.recording.acc
    norms = [float(np.linalg.norm(acc[i.start:i.end].mean(axis=0))) for i in iv] if iv else []
    med = float(np.median(norms)) if norms else float("nan")
    looks = ("m/s2" if 9.0 < med < 10.6 else "g" if 0.9 < med < 1.1 else "mg" if 900 < med < 1100 else None)
    return (f"--unit not given: the readings are taken as counts (K in g/counts); the static readings' median "
            f"|a| is {med:.4g}" + (f", which looks like {looks}: give --unit {looks} if it is" if looks else ""))


def _write_bench_csv(campaign, args) -> None:
    """The pose averages as bench CSV v1; a --local-g outside Earth's range is written with the
    override line, so that `triadcal fit` reads back what fit-raw was told to accept."""
    from ..io.bench_csv import LOCAL_G_RANGE_M_S2, write_bench_csv

    if campaign is None:                                  # checked before the fit (check_options)
        raise InputError("--bench-csv needs known poses: free orientations have no bench angles")
    low, high = LOCAL_G_RANGE_M_S2
    if args.local_g is not None and not low <= args.local_g <= high:
        campaign.metadata["local_g_override"] = "true"
    write_bench_csv(campaign, args.bench_csv)
