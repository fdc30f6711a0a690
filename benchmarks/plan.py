"""Chamber hours for equal U (issue 20, item 4): the example's 15-setpoint stepped plan against
the stepped plan and the continuous-ramp plan `triadcal plan [--ramp]` chooses for the same U of the
angles at the reference temperature and of their tempcos, over the same range (-40..+70 degC) and
chamber rate (1 degC/min). The ramp's model and simulated unit include thermal_lag (the preset's 4 min).

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
from triadcal.models.effects import DEFAULT_EFFECTS  # noqa: E402
from triadcal.planning import design, example_plan, predict, search  # noqa: E402
from triadcal.models.simulate import RampSchedule, ramp_history  # noqa: E402
from triadcal.models.thermal_history import first_order_lag  # noqa: E402
from triadcal.planning.plan import POSITION_SETS  # noqa: E402
from triadcal.planning.ramp import RAMP_TAUS, RampPlan, ramp_effects, search_ramp  # noqa: E402

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
        # the planned ramp for the same targets (thermal_lag in the model and in the unit)
        eff = ramp_effects(DEFAULT_EFFECTS)
        t0 = time.perf_counter()
        rchoice = search_ramp(f"Ca:U<={U_ca:.6g}arcsec, Ca_tempco:U<={U_tc:.6g}arcsec/degC", -40, 70, lab=lab,
                              effects=eff)
        r_seconds = time.perf_counter() - t0
        rplan = rchoice.plan
        rp = rchoice.prediction
        rn = list(rp["names"])
        R_ca, R_tc = worst(rp, rn, ANGLES), worst(rp, rn, TEMPCOS)
        r_ca, r_tc = [], []
        for seed in range(SEEDS):
            _, c = simulate(None, effects=eff, schedule=rplan.schedule(), plan=rplan.visit_positions(), seed=seed,
                            sigma_position_arcsec=sp, sigma_wobble_arcsec=sw)
            r = fit(c, effects=eff, lab=lab)
            r_ca.append(max(2 * r.parameters[n].u for n in ANGLES))
            r_tc.append(max(2 * r.parameters[n].u for n in TEMPCOS))
        # what two legs (one heating, one cooling) reach at the same rate: the best over positions and tau
        two = []
        for prog in ((20.0, -40.0, 70.0), (20.0, 70.0, -40.0)):
            for npos in POSITION_SETS:
                for tau in RAMP_TAUS:
                    p2 = RampPlan(program_C=prog, positions=dict(POSITION_SETS[npos]), tau_s=tau)
                    d2 = design(p2, eff, lab)
                    q2 = predict(d2, 3e-9)
                    two.append((p2.chamber_hours(), worst(q2, list(d2.names), ANGLES),
                                worst(q2, list(d2.names), TEMPCOS)))
        ramp_row = (rplan, R_ca, R_tc, float(np.mean(r_ca)), float(np.mean(r_tc)), r_seconds, rchoice.searched,
                    (min(h for h, _, _ in two), max(h for h, _, _ in two), min(a for _, a, _ in two),
                     min(b for _, _, b in two)))
        rows.append((label, ex, U_ca, U_tc, plan, P_ca, P_tc, float(np.mean(achieved_ca)),
                     float(np.mean(achieved_tc)), seconds, choice.searched, ramp_row))

    for (label, ex, U_ca, U_tc, plan, P_ca, P_tc, A_ca, A_tc, seconds, n, ramp_row) in rows:
        print(f"\n{label}")
        print("| plan | setpoints | positions x reps | tau | chamber hours | U(Ca) worst, arcsec "
              "| U(Ca_tempco) worst, arcsec/degC |")
        print("|---|---|---|---|---|---|---|")
        print(f"| example, 15-setpoint stepped | {len(ex.setpoints_C)} | 12 x 1 | 30 s | "
              f"{ex.chamber_hours():.1f} | {U_ca:.3f} | {U_tc:.4f} |")
        print(f"| planned stepped ({plan.name}) | {', '.join(f'{s:g}' for s in plan.setpoints_C)} | "
              f"{len(plan.positions)} x {plan.repetitions} | {plan.tau_s:g} s | {plan.chamber_hours():.1f} | "
              f"{P_ca:.3f} (fitted, {SEEDS} seeds: {A_ca:.3f}) | {P_tc:.4f} (fitted: {A_tc:.4f}) |")
        rplan, R_ca, R_tc, RA_ca, RA_tc, r_seconds, r_n, two = ramp_row
        print(f"| planned ramp ({rplan.name}; {':'.join(f'{v:g}' for v in rplan.program_C)} degC) | none (ramp) | "
              f"{len(rplan.positions)}, {rplan.n_visits} visits | {rplan.tau_s:g} s | {rplan.chamber_hours():.2f} | "
              f"{R_ca:.3f} (fitted, {SEEDS} seeds: {RA_ca:.3f}) | {R_tc:.4f} (fitted: {RA_tc:.4f}) |")
        print(f"ratio of chamber hours, example / planned stepped: {ex.chamber_hours() / plan.chamber_hours():.2f}x "
              f"(search: {n} plans in {seconds:.1f} s)")
        print(f"ratio of chamber hours, example / planned ramp: {ex.chamber_hours() / rplan.chamber_hours():.2f}x "
              f"(search: {r_n} ramp plans in {r_seconds:.1f} s)")
        print(f"two-leg ramps at 1 degC/min ({two[0]:.2f}-{two[1]:.2f} h), best over positions and tau: "
              f"U(Ca) {two[2]:.3f} arcsec, U(Ca_tempco) {two[3]:.4f} arcsec/degC")
    # the model's lag form T - tau dT/dt against an exact first-order lag of the unit's temperature
    sched = RampSchedule(program_C=rows[0][11][0].program_C, rate_C_per_min=rows[0][11][0].rate_C_per_min)
    t = np.arange(0.0, sched.duration_s, 2.0)
    _, u, rate = ramp_history(sched, t)
    tau = 4.0 * 60.0
    print(f"\nmax |exact first-order lag - (T - tau dT/dt)| on {':'.join(f'{v:g}' for v in sched.program_C)} degC "
          f"at {sched.rate_C_per_min:g} degC/min, tau 4 min: {np.max(np.abs(first_order_lag(t, u, tau) - (u - tau * rate))):.2f} degC")


if __name__ == "__main__":
    main()
