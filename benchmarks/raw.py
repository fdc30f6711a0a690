"""Benchmark: the gravity-norm fit of ``fit-raw --poses unknown`` (CasADi exact Jacobian +
Levenberg-Marquardt) against a plain scipy.optimize.least_squares implementation of the
same cost (numpy residuals, finite-difference Jacobian), on the MPU-6050 recording of
tomisuarez2 (../shared/data/real), static intervals found by our detector.

Prints the best-of-N fit times (ours with and without building the CasADi function), the
time ratio, and the largest difference between the two optima in units of our standard
uncertainty.

    python benchmarks/raw.py [--repeat 20] [--data PATH]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from triadcal.estimation.raw import (NORM_NAMES, NormProblem, fit_unknown_poses, norm_start, pose_averages,
                                     static_intervals_of)
from triadcal.estimation.joint import levenberg_marquardt
from triadcal.io.raw import read_raw_csv
from triadcal.models.units import ARCSEC, STANDARD_GRAVITY_M_S2

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "tomisuarez2_example_data_calibration.csv"


def scipy_norm_residuals(x, w, g):
    """|A| - g with A = Ca^-1 (K W - S), Ca upper triangular (imu_tk's frame), plain numpy."""
    K, S = x[:3], x[3:6]
    xy, xz, yz = x[6:9] * ARCSEC
    Ca = np.array([[np.sqrt(1 - xy ** 2 - xz ** 2), xy, xz],
                   [0.0, np.sqrt(1 - yz ** 2), yz],
                   [0.0, 0.0, 1.0]])
    a = np.linalg.solve(Ca, (w * K - S).T).T
    return np.linalg.norm(a, axis=1) - g


def best_of(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--data", default=str(DATA))
    args = ap.parse_args(argv)

    rec = read_raw_csv(args.data, 100.0, unit="counts")
    det = static_intervals_of(rec, poses="unknown")
    avg = pose_averages(rec, det)
    g = 1.0   # local g = g_n, as tomisuarez2 assumes
    x0 = norm_start(avg.w, g)

    t_full, (result, _, _) = best_of(lambda: fit_unknown_poses(rec, avg, gravity_g=g, serial="mpu"), args.repeat)
    problem = NormProblem(avg.w, g)
    t_ours, sol = best_of(lambda: levenberg_marquardt(problem, x0), args.repeat)
    t_build, _ = best_of(lambda: NormProblem(avg.w, g), args.repeat)
    t_scipy, ls = best_of(lambda: least_squares(scipy_norm_residuals, x0, args=(avg.w, g), x_scale="jac",
                                                xtol=1e-12, ftol=1e-12, gtol=1e-12), args.repeat)
    u = np.array([result[n].u for n in NORM_NAMES])
    diff = np.max(np.abs(sol.x - ls.x) / u)
    rms = lambda r: float(np.sqrt(np.mean(r ** 2))) * STANDARD_GRAVITY_M_S2
    r_ours = sol.r * NormProblem.RESIDUAL_UNIT_G
    print(f"MPU-6050 recording: {rec.n} samples, {len(avg.w)} static intervals, {len(NORM_NAMES)} parameters")
    print(f"ours  (CasADi exact Jacobian, LM): solve {1e3 * t_ours:8.2f} ms  ({sol.iterations} iterations); "
          f"build {1e3 * t_build:.2f} ms; whole fit incl. uncertainties {1e3 * t_full:.2f} ms")
    print(f"scipy least_squares (TRF, 2-point FD Jacobian): {1e3 * t_scipy:8.2f} ms  ({ls.nfev} evaluations)")
    print(f"time ratio scipy / ours (solve): {t_scipy / t_ours:.2f}; scipy / ours (build + solve): "
          f"{t_scipy / (t_ours + t_build):.2f}")
    print(f"RMS |A| - g of the interval means: ours {rms(r_ours):.3g} m/s2, scipy {rms(ls.fun):.3g} m/s2; "
          f"largest difference of the optima: {diff:.2g} u")


if __name__ == "__main__":
    main()
