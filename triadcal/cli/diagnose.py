"""``triadcal diagnose``: where the model misses the data, which effect it lacks, how far adding it helps."""

from __future__ import annotations

from ..errors import InputError

import sys

from ..models.effects import DEFAULT_EFFECTS, EFFECTS, VOCABULARY
from ._common import add_output_options, name_list, output


def register(sub) -> None:
    p = sub.add_parser(
        "diagnose", help="diagnose the gap between a model and bench data (where, which effect, how much)",
        description="Fit the model, test the normalised residuals slice by slice (axis, up axis, setpoint, "
                    "heating/cooling, time, time since the setpoint began), score every effect the model "
                    "lacks, refit the best few and say how far the gap shrinks. Writes the diagnosis as "
                    "JSON (format triadcal.diagnosis v1) and optionally an HTML report.")
    p.add_argument("data", help="bench CSV v1 file")
    p.add_argument("--model", default=",".join(DEFAULT_EFFECTS),
                   help=f"effects of the fitted model, from: {', '.join(EFFECTS)}, or the forms hysteresis_play, "
                        "hysteresis_pi, thermal_lag_history (profiled by the least squares and held, so that a "
                        "model a verdict named can be diagnosed again); 'none' for eq. 1 only "
                        f"(default: {','.join(DEFAULT_EFFECTS)})")
    p.add_argument("--candidates", default=None,
                   help=f"effects to test (default: every effect of {', '.join(VOCABULARY)} not in the model, and "
                        "the refit-only forms hysteresis_play, hysteresis_pi, thermal_lag_history and quantisation: "
                        "a digital output's LSB q profiled, docs/diagnosis.md)")
    p.add_argument("--unit", default=None, help="serial number to diagnose when the file holds several")
    p.add_argument("--state", default=None, help="mechanical state to diagnose when the file holds several")
    p.add_argument("--top", type=int, default=3, help="number of candidates to refit (default 3)")
    p.add_argument("--alpha", type=float, default=0.01, help="family-wise significance level (default 0.01)")
    p.add_argument("--draws", type=int, default=400, help="Laplace draws for PSIS-LOO and the PPC (default 400)")
    p.add_argument("--reference-temperature", type=float, default=20.0, metavar="DEGC",
                   help="T0 of the fitted model's thermal terms, degC (default 20; as fit's)")
    p.add_argument("--seed", type=int, default=0, help="seed of the Laplace draws")
    p.add_argument("--json", metavar="OUT", required=True, help="write the diagnosis here (JSON)")
    p.add_argument("--html", metavar="REPORT", help="write an HTML report with plots here")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from ..judgement.diagnose import diagnose
    from ..io.bench_csv import read_bench_csv
    from ..reports.diagnosis import summary_text, write_html_report

    campaign = read_bench_csv(args.data)
    mask = np.ones(campaign.n_visits, bool)
    if args.unit:
        mask &= campaign.unit == args.unit
    if args.state:
        mask &= campaign.state == args.state
    if not mask.any():
        asked = " and ".join(x for x in (f"unit {args.unit}" if args.unit else "",
                                          f"state {args.state}" if args.state else "") if x)
        states = ", ".join(sorted(set(campaign.state.tolist())))
        raise InputError(f"{args.data} has no visit of {asked}; its units are {', '.join(campaign.units)} and "
                         f"its states {states}")
    campaign = campaign.select(np.flatnonzero(mask), own_origin=True)
    if len(campaign.units) > 1 or len(set(campaign.state.tolist())) > 1:
        raise InputError(f"{args.data} holds units {', '.join(campaign.units)} and states "
                         f"{', '.join(sorted(set(campaign.state.tolist())))}: choose one with --unit and --state")
    cands = name_list(args.candidates) if args.candidates else None
    d = diagnose(campaign, name_list(args.model), candidates=cands, top=args.top, alpha=args.alpha,
                 n_draws=args.draws, reference_temperature_C=args.reference_temperature, seed=args.seed)
    d.save(args.json)
    if args.html:
        write_html_report(d, args.html, campaign)
    out = output(args)
    out.say(summary_text(d))
    out.say(f"diagnosis written to {args.json}" + (f", report to {args.html}" if args.html else ""))
    for note in d.notes:
        print(f"note: {note}", file=sys.stderr)
    return 0
