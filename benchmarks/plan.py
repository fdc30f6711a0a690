"""Chamber hours for equal U (issue 20, item 4): the example's 15-setpoint stepped plan against
the stepped plan `triadcal plan` chooses for the same U of the angles at the reference temperature
and of their tempcos, over the same range (-40..+70 degC) and chamber rate (1 degC/min).

For each noise scenario: the example plan's predicted U (worst of the six angles, worst of the six
angle tempcos) becomes the target; the planner searches for the cheapest plan meeting both; both
plans' hours and the ratio are printed, and the planned plan is simulated and fitted (SEEDS seeds)
to show the U it achieves.

    .venv/bin/python benchmarks/plan.py
"""
from __future__ import annotations

import datetime
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from triadcal.api import fit, simulate  # noqa: E402
from triadcal.io.lab import load_lab  # noqa: E402
from triadcal.planning import design, example_plan, predict, search  # noqa: E402

ANGLES = ("Ca_xy", "Ca_xz", "Ca_yx", "Ca_yz", "Ca_zx", "Ca_zy")
TEMPCOS = tuple(f"{a}_tempco" for a in ANGLES)
SEEDS = 5
SCENARIOS = {
    "example's noise (Q = 3e-9 V^2 s, no bench errors)": None,
    "plus the lab's random bench errors (5\" / 2\" per visit)": "[bench]\nsigma_position_arcsec = 5.0\n"
                                                               "sigma_wobble_arcsec = 2.0\n",
}


def worst(pred, names, which):
    return max(float(pred["U"][names.index(n)]) for n in which)


def main() -> None:
    print(f"benchmarks/plan.py, {datetime.date.today().isoformat()}, {platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}")
    rows = []
    tmp = Path(tempfile.mkdtemp())
    for label, lab_text in SCENARIOS.items():
        lab = None
        if lab_text:
            (tmp / "lab.toml").write_text(lab_text)
            lab = load_lab(tmp / "lab.toml")
        ex = example_plan()
        d = design(ex, lab=lab)
        p = predict(d, 3e-9)
        U_ca, U_tc = worst(p, d.names, ANGLES), worst(p, d.names, TEMPCOS)
        t0 = time.perf_counter()
        choice = search(f"Ca:U<={U_ca:.6g}arcsec, Ca_tempco:U<={U_tc:.6g}arcsec/degC", -40, 70, lab=lab)
        seconds = time.perf_counter() - t0
        plan = choice.plan
        dp = design(plan, lab=lab)
        pp = predict(dp, 3e-9)
        P_ca, P_tc = worst(pp, dp.names, ANGLES), worst(pp, dp.names, TEMPCOS)
        achieved_ca, achieved_tc = [], []
        sp = lab.sigma_position_arcsec if lab else 0.0
        sw = lab.sigma_wobble_arcsec if lab else 0.0
        for seed in range(SEEDS):
            _, c = simulate(None, schedule=plan.schedule(), plan=plan.visit_positions(), seed=seed,
                            sigma_position_arcsec=sp, sigma_wobble_arcsec=sw)
            r = fit(c, lab=lab)
            achieved_ca.append(max(2 * r.parameters[n].u for n in ANGLES))
            achieved_tc.append(max(2 * r.parameters[n].u for n in TEMPCOS))
        rows.append((label, ex, U_ca, U_tc, plan, P_ca, P_tc, float(np.mean(achieved_ca)),
                     float(np.mean(achieved_tc)), seconds, choice.searched))

    for (label, ex, U_ca, U_tc, plan, P_ca, P_tc, A_ca, A_tc, seconds, n) in rows:
        print(f"\n{label}")
        print("| plan | setpoints | positions x reps | tau | chamber hours | U(Ca) worst, arcsec "
              "| U(Ca_tempco) worst, arcsec/degC |")
        print("|---|---|---|---|---|---|---|")
        print(f"| example, 15-setpoint stepped | {len(ex.setpoints_C)} | 12 x 1 | 30 s | "
              f"{ex.chamber_hours():.1f} | {U_ca:.3f} | {U_tc:.4f} |")
        print(f"| planned stepped ({plan.name}) | {', '.join(f'{s:g}' for s in plan.setpoints_C)} | "
              f"{len(plan.positions)} x {plan.repetitions} | {plan.tau_s:g} s | {plan.chamber_hours():.1f} | "
              f"{P_ca:.3f} (fitted, {SEEDS} seeds: {A_ca:.3f}) | {P_tc:.4f} (fitted: {A_tc:.4f}) |")
        print(f"ratio of chamber hours, example / planned: {ex.chamber_hours() / plan.chamber_hours():.2f}x "
              f"(search: {n} plans in {seconds:.1f} s)")


if __name__ == "__main__":
    main()
