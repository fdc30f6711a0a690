"""Benchmark: posterior sampling of ``fit-raw --sample`` in sheared coordinates (ours) against
the same emcee sampler, moves and stop rule in the plain whitened coordinates of the Laplace
approximation (the bench's path, the obvious alternative), on

* a simulated hand-placed six-face recording (known poses, 12 unit parameters + 12 placement
  tilts: K and S follow the squares of the unresolved tilts, a curved ridge), and
* the MPU-6050 recording of tomisuarez2 (unknown poses, 10 intervals for 9 parameters: a
  ridge along the prior-dominated Ca_xy).

Prints, for each, the seconds to the stop rule (ESS >= --ess for every parameter, chain >= 50
tau, R-hat < 1.01) or to --max-steps, the final tau and acceptance, and the time ratio. When
the plain run hits --max-steps without converging its time is a lower bound and so is the
ratio (printed with ">").

    python benchmarks/raw_sample.py [--ess 2000] [--max-steps 20000]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from triadcal.estimation.raw import (fit_known_poses, fit_unknown_poses, pose_averages, sample_known_poses,
                                     sample_unknown_poses, static_intervals_of)
from triadcal.io.raw import read_raw_csv
from triadcal.models.units import STANDARD_GRAVITY_M_S2

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "real" / "tomisuarez2_example_data_calibration.csv"


def timed(fn):
    t0 = time.perf_counter()
    result, run = fn()
    return time.perf_counter() - t0, result, run


def report(label, plain, ours):
    (tp, rp, runp), (to, ro, runo) = plain, ours
    for name, t, r, run in (("plain whitened", tp, rp, runp), ("sheared (ours)", to, ro, runo)):
        c = run.checks[-1]
        print(f"  {name:15s}: {r.status:13s} {t:7.1f} s  {c['steps']:6d} steps  tau {c['tau_max']:7.1f}  "
              f"acceptance {run.acceptance:.2f}")
    bound = ">" if rp.status != "ok" else ""
    print(f"  time ratio plain / ours: {bound}{tp / to:.1f}" + (" (plain did not converge: a lower bound)"
                                                                   if bound else ""))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--ess", type=float, default=2000)
    ap.add_argument("--max-steps", type=int, default=20000)
    args = ap.parse_args(argv)
    opts = dict(ess=args.ess, max_steps=args.max_steps, seed=0)

    sys.path.insert(0, str(ROOT / "tests"))
    from test_raw import FACES, LOCAL_G, random_unit, simulate_recording

    truth = random_unit(np.random.default_rng(3))
    rec, _ = simulate_recording(truth, FACES, seed=3, static_s=4.0)
    avg = pose_averages(rec, static_intervals_of(rec, labels="part"))
    ls, problem, sol = fit_known_poses(avg, gravity_g=LOCAL_G / STANDARD_GRAVITY_M_S2, scale_unit=rec.scale_unit,
                                       serial="sim")
    kw = dict(serial="sim", scale_unit=rec.scale_unit, **opts)
    print("known poses, simulated six-face recording (24 parameters):")
    report("known", timed(lambda: sample_known_poses(ls, problem, sol, avg.label, shear=False, **kw)),
           timed(lambda: sample_known_poses(ls, problem, sol, avg.label, shear=True, **kw)))

    if DATA.exists():
        rec = read_raw_csv(DATA, 100.0)
        avg = pose_averages(rec, static_intervals_of(rec, poses="unknown"))
        ls, problem, sol = fit_unknown_poses(rec, avg, gravity_g=1.0, serial="mpu")
        kw = dict(serial="mpu", scale_unit=rec.scale_unit, **opts)
        print("unknown poses, MPU-6050 recording (9 parameters, 10 intervals):")
        report("mpu", timed(lambda: sample_unknown_poses(ls, problem, sol, shear=False, **kw)),
               timed(lambda: sample_unknown_poses(ls, problem, sol, shear=True, **kw)))
    else:
        print(f"(MPU-6050 recording not found at {DATA}: skipped)")


if __name__ == "__main__":
    main()
