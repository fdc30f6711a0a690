"""Benchmark: the classical method's redundancy scatter (Paule-Mandel, ``bench_scatter``: the
setpoint blocks of one shape as one stacked SVD, the root by Brent's method) against the obvious
way (each block by ``numpy.linalg.lstsq``, the root by bisection to 1e-6, as it was written
before 2026-11-30), on the blocks of a standard campaign with known noise (sd_* columns, 5"
positioning errors: a scatter beyond the known noise to find). Prints both times, their ratio,
the largest relative difference of tau^2 (must be < 1e-5) and the time of one classical fit.

    python benchmarks/classical.py [--repeat 20]
"""

from __future__ import annotations

import argparse

import numpy as np
from raw import best_of          # benchmarks/raw.py's: the best of ``repeat`` wall times, and the last output

from triadcal.estimation import classical as C
from triadcal.estimation.classical import fit_classical
from triadcal.estimation.classical_redundancy import bench_scatter
from triadcal.models.simulate import preset_truth, simulate_campaign


def bisection_scatter(blocks):
    """The obvious way: every block by lstsq, tau^2 by bisection (relative 1e-6)."""
    def chi2(t2):
        out = 0.0
        for D, y, s2, _ in blocks:
            w = 1.0 / np.sqrt(s2 + t2)
            c, *_ = np.linalg.lstsq(D * w[:, None], y * w, rcond=None)
            out += float(np.sum((y * w - (D * w[:, None]) @ c) ** 2))
        return out

    dof = sum(len(y) - np.linalg.matrix_rank(D) for D, y, _, _ in blocks)
    if dof <= 0 or chi2(0.0) <= dof:
        return 0.0
    lo, hi = 0.0, max(float(np.median(np.concatenate([s2 for _, _, s2, _ in blocks]))), 1e-300)
    while chi2(hi) > dof:
        lo, hi = hi, hi * 4.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if chi2(mid) > dof else (lo, mid)
        if hi - lo <= 1e-6 * hi:
            break
    return hi


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args(argv)

    truth = preset_truth("ak18-quartz")
    campaign = simulate_campaign(truth, seed=1)
    captured = []
    original = C.worst_studentised_known
    C.worst_studentised_known = lambda design, dof, c: captured.append(design) or original(design, dof, c)
    try:
        t_fit, _ = best_of(lambda: fit_classical(campaign), args.repeat)
    finally:
        C.worst_studentised_known = original
    design = [blocks for blocks in captured[-1] if blocks]
    if not design:
        raise SystemExit("the campaign has no known noise per visit: nothing to benchmark")
    t_ours, ours = best_of(lambda: [bench_scatter(b)[0] for b in design], args.repeat)
    t_ref, ref = best_of(lambda: [bisection_scatter(b) for b in design], max(3, args.repeat // 4))
    diff = max(abs(a - b) / b if b > 0 else abs(a) for a, b in zip(ours, ref))
    print(f"campaign: {campaign.n_visits} visits, {len(design[0])} setpoint blocks per output, tau^2 per output "
          + ", ".join(f"{t:.3g}" for t in ours))
    print(f"Paule-Mandel scatter, 3 outputs: ours {1e3 * t_ours:.2f} ms, per-block lstsq + bisection "
          f"{1e3 * t_ref:.2f} ms, ratio {t_ref / t_ours:.1f}x; largest relative difference of tau^2 {diff:.1e}")
    print(f"one classical fit (known noise, redundancy gate included): {1e3 * t_fit:.1f} ms")
    if diff > 1e-5:
        raise SystemExit(f"tau^2 differs by {diff:.2e} (> 1e-5)")


if __name__ == "__main__":
    main()
