"""Benchmark: the joint fit (CasADi exact Jacobian + Levenberg-Marquardt) against
scipy.optimize.least_squares with a finite-difference Jacobian on the same residuals.

Standard campaign: 12 positions x 15 setpoints, default effects. Prints the warm fit
times, their ratio, the cold model-build time, and the largest difference between the
two optima in units of the standard uncertainty (must be < 0.01 u).

    python benchmarks/fit.py [--repeat 20]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.optimize import least_squares

from triadcal.estimation.joint import JointProblem, fit_joint, levenberg_marquardt, noise_of, start_values
from triadcal.models.model import Model
from triadcal.models.simulate import preset_truth, simulate_campaign


def best_of(fn, repeat):
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), float(np.median(times)), out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args(argv)

    truth = preset_truth("ak18-quartz")
    campaign = simulate_campaign(truth, seed=1)
    model = Model(truth.effects)
    sigma = noise_of(campaign).sigma

    t0 = time.perf_counter()
    problem = JointProblem(campaign, model, sigma)
    build = time.perf_counter() - t0
    start = start_values(campaign, model)
    x0 = np.array([start[n] for n in problem.names])

    ours_min, ours_med, sol = best_of(lambda: levenberg_marquardt(problem, x0), args.repeat)

    # the obvious alternative: the same residuals in plain numpy, finite-difference Jacobian
    cov = campaign.covariates()
    scales = model.scales()

    def residuals(x):
        p = dict(zip(model.names, x * scales))
        w = np.stack(model.predict(p, cov, campaign.gravity_g), axis=1)
        return ((campaign.w - w) / sigma).ravel()

    x_scale = np.array([model.spec[n].typical for n in model.names]) * 1e-3
    scipy_min, scipy_med, ls = best_of(
        lambda: least_squares(residuals, x0, method="lm", x_scale=x_scale, xtol=1e-12, ftol=1e-12, gtol=1e-12),
        max(3, args.repeat // 5))

    # the other CasADi route: IPOPT on 0.5 |r|^2 with exact derivatives (why we chose LM)
    import casadi as ca
    xs = ca.MX.sym("x", len(problem.names))
    w = problem._predict(xs, problem.cov_matrix, problem.gravity_g).T
    r = ca.vec((ca.DM(campaign.w) - w) / ca.DM(sigma))
    d = np.linalg.norm(sol.J, axis=0)   # column scaling, as LM does internally
    z = ca.MX.sym("z", len(problem.names))
    f = 0.5 * ca.sumsqr(ca.substitute(r, xs, z / d))
    solver = ca.nlpsol("ipopt", "ipopt", {"x": z, "f": f},
                       {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.tol": 1e-10})
    ip_min, _, ip = best_of(lambda: solver(x0=x0 * d), max(3, args.repeat // 5))
    x_ip = np.array(ip["x"]).ravel() / d

    result = fit_joint(campaign)
    u = np.array([result[n].u for n in problem.names])
    diff = np.max(np.abs(sol.x - ls.x) / u)
    cold_total = result.fit["build_seconds"]

    print(f"campaign: {campaign.n_visits} visits (12 positions x 15 setpoints), {len(problem.names)} parameters, "
          f"effects {','.join(truth.effects)}")
    print(f"model build (cold):             {build * 1e3:8.1f} ms   (target <= 500 ms)")
    print(f"joint fit, ours (warm):         {ours_min * 1e3:8.2f} ms   (median {ours_med * 1e3:.2f} ms, "
          f"{sol.iterations} iterations)")
    print(f"scipy least_squares, FD jac:    {scipy_min * 1e3:8.2f} ms   (median {scipy_med * 1e3:.2f} ms, "
          f"{ls.nfev} evaluations)")
    print(f"ratio scipy / ours:             {scipy_min / ours_min:8.1f} x   (target >= 5 x)")
    print(f"IPOPT via CasADi (warm):        {ip_min * 1e3:8.2f} ms   ({ip_min / ours_min:.1f} x ours; "
          f"largest difference {np.max(np.abs(x_ip - sol.x) / u):.1e} u)")
    print(f"largest |ours - scipy| / u:     {diff:8.2e}     (must be < 0.01)")
    print(f"build inside fit_joint:         {cold_total * 1e3:8.1f} ms")


if __name__ == "__main__":
    main()
