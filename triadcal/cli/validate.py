"""``triadcal validate``: simulation-based calibration of the least-squares and posterior intervals."""

from __future__ import annotations

from ..models.effects import DEFAULT_EFFECTS, EFFECTS
from ._common import add_output_options, name_list, output


def register(sub) -> None:
    p = sub.add_parser(
        "validate", help="simulation-based calibration: do the intervals cover? (rank histograms, coverage)",
        description="Draw N campaigns from the prior, simulate them, fit each by least squares and by the "
                    "posterior, and check that the ranks of the true values are uniform and that the 68% and "
                    "95% intervals cover at their nominal rates (Talts et al. 2018).")
    p.add_argument("--campaigns", type=int, default=200, help="number of simulated campaigns, >= 1 (default 200)")
    p.add_argument("--ranks", type=int, default=99,
                   help="posterior draws per campaign, L (ranks 0..L), 1..--ess (default 99)")
    p.add_argument("--effects", default=",".join(DEFAULT_EFFECTS),
                   help=f"effects of the model, from: {', '.join(EFFECTS)}; default: {','.join(DEFAULT_EFFECTS)}")
    p.add_argument("--processes", type=int, default=2, help="worker processes, >= 1 (1: in this process; default 2)")
    p.add_argument("--ess", type=float, default=400,
                   help="ESS each posterior run requests, a finite number > 0 (default 400)")
    p.add_argument("--seed", type=int, default=0, help="random seed, an integer in 0..2**32-1 (default 0)")
    p.add_argument("--json", metavar="OUT", help="write the summary (format triadcal.sbc v1)")
    p.add_argument("--plot", metavar="OUT.png", help="write the rank histograms")
    add_output_options(p)
    p.set_defaults(func=run)


def _num(x, fmt: str = ".3f") -> str:
    return "n/a" if x is None else format(x, fmt)


def run(args) -> int:
    import sys

    from ..api import validate
    from ..judgement.validation import LEVELS, METHODS, check_sbc_options

    check_sbc_options(args.campaigns, n_ranks=args.ranks, seed=args.seed, processes=args.processes, ess=args.ess)
    out = output(args)
    bar = out.bar(total=args.campaigns, desc="campaigns", unit="campaign")
    progress = None
    if bar is not None:
        def progress(done, total):
            bar.update(done - bar.n)
    try:
        result = validate(args.campaigns, name_list(args.effects), n_ranks=args.ranks, seed=args.seed,
                          processes=args.processes, ess=args.ess, json_path=args.json, plot_path=args.plot,
                          progress=progress)
    finally:
        if bar is not None:
            bar.close()
    s = result.summary()
    out.say(f"SBC: {s['n_campaigns']} campaigns of {s['n_ranks']} ranks each, "
            f"{len(s['parameters'])} parameters, {s['failed']} campaigns failed, {s['seconds']:.0f} s")
    for m in METHODS:
        d = s["methods"][m]
        line = (f"  {m:<14} ranks: min chi2 p = {_num(d['rank_min_p'], '.3g')} "
                f"({d['rank_n_below_alpha']} of {len(s['parameters'])} below {s['alpha']}, "
                f"{d['rank_expected_below_alpha']:.2f} expected)")
        for lv in LEVELS:
            key = f"{round(lv * 100)}"
            lo, hi = d[f"coverage_{key}_range"]
            line += (f"; {key}% coverage pooled {_num(d[f'coverage_{key}_pooled'])} "
                     f"(per parameter {_num(lo)}..{_num(hi)})")
        out.say(line)
    v = s["verdict"]
    # the exit code is the verdict's (docs/posterior.md, "The verdict"); what failed goes to stderr with its numbers
    for c in v["checks"]:
        if not c["passed"]:
            print(f"SBC check failed: {c['message']}", file=sys.stderr)
    weak = [c for c in v["checks"] if not c["conclusive"]]
    if v["passed"]:
        out.say(f"  verdict: no check failed ({len(v['checks'])} tests, each at family-wise {v['alpha']:g}"
                + (f"; {len(weak)} of them could not have failed with {s['n_campaigns']} campaigns)" if weak else ")"))
        if weak:
            print(f"note: with {s['n_campaigns']} campaigns {len(weak)} of the tests could not have failed (their "
                  f"smallest attainable p is above the threshold: " + ", ".join(
                      f"{c['test']} {c['method']}" + (f" {round(c['level'] * 100)}%" if c["level"] else "")
                      for c in weak[:4]) + (" ..." if len(weak) > 4 else "")
                  + f"); run at least {v['campaigns_needed']} campaigns for a verdict every test can refuse",
                  file=sys.stderr)
    if args.json:
        out.say(f"summary written to {args.json}")
    if args.plot:
        out.say(f"rank histograms written to {args.plot}")
    if v["passed"] and weak:
        # a verdict some of whose tests could not have failed is no pass (exit 3, as a failed one)
        print(f"SBC verdict inconclusive: {len(weak)} of {len(v['checks'])} tests could not have failed with "
              f"{s['n_campaigns']} campaigns; exit 3 (run at least {v['campaigns_needed']})", file=sys.stderr)
        return 3
    return 0 if v["passed"] else 3
