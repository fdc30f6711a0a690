"""Benchmark: time to ESS >= 2000 for every parameter, ``triadcal sample`` against emcee's
default stretch move with a plain numpy log-probability (Model.predict in numpy).

Standard campaign: 12 positions x 15 setpoints, default effects
(``simulate_campaign(preset_truth("ak18-quartz"))``), 32 parameters, 64 walkers. Every
variant runs to the same stop rule (:func:`triadcal.estimation.posterior.run_sampler`):
after a burn-in of 5 tau, chain >= 50 tau (emcee's estimator), arviz bulk and tail ESS
>= 2000 and rank-normalised split R-hat < 1.01 for every parameter, walkers as chains.

Variants (same priors, same start: the Laplace approximation at the MAP):

- ``ours``: ``sample()`` end to end (joint LS fit, MAP, compiled CasADi log-posterior,
  DE + snooker + Laplace independence moves, diagnostics); the time includes everything
  but the imports (run ``--repeat`` times with different seeds; the first call in a
  process may include compiling the C code, which is then cached on disk);
- ``de-snooker`` and ``stretch-casadi``: the compiled log-posterior with the DE/snooker
  mixture alone and with the stretch move (separates the gain of the moves from that
  of the compiled log-probability);
- ``baseline``: emcee's default stretch move with a plain numpy log-probability, one
  ``Model.predict`` call per walker (what emcee does without ``vectorize``), capped at
  ``--baseline-max-seconds``; when the cap is hit the ratio printed is a lower bound.

    python benchmarks/sample.py [--repeat 3] [--baseline-max-seconds 1200] [--skip-slow]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

os.environ.setdefault("XDG_CACHE_HOME", os.path.join(tempfile.gettempdir(), "triadcal-xdg-cache"))

import numpy as np  # noqa: E402

from triadcal.estimation.joint import JointProblem, fit_joint, noise_of  # noqa: E402
from triadcal.estimation.posterior import (LogPosterior, _arviz, laplace_approximation, run_sampler,  # noqa: E402
                                           sample)
from triadcal.estimation.priors import default_priors, prior_arrays  # noqa: E402
from triadcal.models.model import Model  # noqa: E402
from triadcal.models.simulate import preset_truth, simulate_campaign  # noqa: E402


class NumpyLogPosterior:
    """The same posterior, written the plain way: numpy Model.predict, one walker at a time."""

    compiled = False

    def __init__(self, campaign, model, sigma, priors, x0, L):
        self.model, self.names, self.d = model, model.names, len(model.names)
        self.cov = campaign.covariates()
        self.g = campaign.gravity_g
        self.w = campaign.w
        self.sigma = sigma
        self.scales = model.scales()
        self.mu, self.sd, self.low, self.high = prior_arrays(priors, self.names)
        self.x0, self.L = x0, L

    def to_x(self, z):
        return self.x0 + np.asarray(z) @ self.L.T

    def one(self, x):
        if not np.all((x > self.low) & (x < self.high)):
            return -np.inf
        p = dict(zip(self.names, x * self.scales))
        w = np.stack(self.model.predict(p, self.cov, self.g), axis=1)
        r = (self.w - w) / self.sigma
        return -0.5 * float(np.sum(r * r)) - 0.5 * float(np.sum(((x - self.mu) / self.sd) ** 2))

    def __call__(self, z):
        return np.array([self.one(x) for x in self.to_x(np.atleast_2d(z))])


def report(label, seconds, run, note=""):
    g = run.diagnostics          # arviz and emcee's estimator on the kept chain at the end
    print(f"{label:<16} {seconds:8.2f} s  steps {run.chain_z.shape[0]:6d}  tau_max {g['tau'].max():7.1f}  "
          f"ESS bulk/tail {g['ess_bulk'].min():7.0f}/{g['ess_tail'].min():7.0f}  "
          f"R-hat {g['rhat'].max():.4f}  converged {run.converged}  "
          f"acceptance {run.acceptance:.2f} {note}", flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--baseline-max-seconds", type=float, default=1200.0)
    ap.add_argument("--variant-max-seconds", type=float, default=300.0)
    ap.add_argument("--skip-slow", action="store_true", help="only ours (no de-snooker/stretch/baseline runs)")
    args = ap.parse_args(argv)
    _arviz()                                   # imports are not part of the timing

    campaign = simulate_campaign(preset_truth("ak18-quartz"), seed=1)
    print(f"standard campaign: {campaign.n_visits} visits, default effects, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    ours = []
    for k in range(args.repeat):
        t0 = time.perf_counter()
        res, run = sample(campaign, seed=k, return_run=True)
        dt = time.perf_counter() - t0
        ours.append(dt)
        report(f"ours (seed {k})", dt, run, f"status {res.status}; sampling {run.seconds:.2f} s, "
                                           f"LS fit + MAP + build {dt - run.seconds:.2f} s")
    t_ours = float(np.median(ours))
    print(f"ours: median {t_ours:.2f} s, min {min(ours):.2f} s over {len(ours)} runs")
    if args.skip_slow:
        return

    # the same posterior and start for the other variants
    ls, prob, sol = fit_joint(campaign, return_problem=True)
    model = Model()
    pri = default_priors(model)
    sigma = noise_of(campaign).sigma
    problem = JointProblem(campaign, model, sigma)
    x_map, C = laplace_approximation(problem, pri, sol.x)
    L = np.linalg.cholesky(C)
    target = LogPosterior(campaign, model, sigma, pri, x_map, L, block=32)
    for label, moves in (("de-snooker", "de-snooker"), ("stretch-casadi", "stretch")):
        t0 = time.perf_counter()
        run = run_sampler(target, 64, seed=0, moves=moves, max_steps=10 ** 6, max_seconds=args.variant_max_seconds)
        dt = time.perf_counter() - t0
        report(label, dt, run, "" if run.converged else "(capped: time is a lower bound)")
        print(f"  -> ours is {dt / t_ours:.1f}x faster{'' if run.converged else ' (at least)'}", flush=True)

    base = NumpyLogPosterior(campaign, model, sigma, pri, x_map, L)
    t0 = time.perf_counter()
    base(np.zeros((64, 32)))
    per_call = (time.perf_counter() - t0) / 64
    print(f"numpy log-probability: {per_call * 1e3:.2f} ms per walker; compiled CasADi: "
          f"{_per_walker(target) * 1e3:.3f} ms per walker", flush=True)
    t0 = time.perf_counter()
    run = run_sampler(base, 64, seed=0, moves="stretch", max_steps=10 ** 6, max_seconds=args.baseline_max_seconds)
    dt = time.perf_counter() - t0
    report("baseline", dt, run, "" if run.converged else "(capped: time is a lower bound)")
    bound = "" if run.converged else " at least"
    print(f"RATIO: baseline {dt:.1f} s / ours {t_ours:.2f} s = {dt / t_ours:.0f}x{bound} "
          f"(target >= 15x, ours <= 5 s)")


def _per_walker(target):
    z = np.zeros((64, target.d))
    t0 = time.perf_counter()
    for _ in range(20):
        target(z)
    return (time.perf_counter() - t0) / 20 / 64


if __name__ == "__main__":
    main()
