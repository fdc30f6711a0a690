"""Continuous-ramp capture (issue 20, last part): `triadcal capture --ramp PLAN` against the emulator
through real pseudo-terminals: the chamber follows the program the capture writes as a moving
setpoint, the bench cycles through the positions with no soak, the result fits with thermal_lag;
a SIGKILL mid-ramp and a resume lose no sample; a bad plan file is refused naming file and field.

Independent checks: the unit's temperature the readings show is compared with an explicit Euler
integration of the chamber and unit lags driven by the setpoints the emulated chamber received
(tests/independent_bench.py, not the project's closed form), and the direction labels with the
sign of that integration's rate."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from scipy import stats

from independent_bench import euler_thermal_history
from triadcal.api import fit
from triadcal.cli import main
from triadcal.hardware.capture import (CSV_NAME, RAW_NAME, CaptureSettings, Stabilisation, load_port_config,
                                       open_instruments)
from triadcal.hardware.emulator import EmulatorTiming, emulate
from triadcal.hardware.ramp_capture import (RampProgram, capture_ramp, read_ramp_plan, turned_within, visit_direction,
                                            window_rates)
from triadcal.hardware.storage import read_events
from scatter_gates import assert_right_or_scatter
from test_hardware_capture import check_visits_against_raw  # the stepped capture's own check
from triadcal.io.bench_csv import read_bench_csv
from triadcal.models.campaign import DEFAULT_PLAN
from triadcal.planning.ramp import RampPlan

CLI = [sys.executable, "-m", "triadcal.cli"]
EFFECTS = ["bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis", "thermal_lag"]
ANGLES = ("Ca_xy", "Ca_xz", "Ca_yx", "Ca_yz", "Ca_zx", "Ca_zy")


def ramp_on(out, plan, imu, bench, chamber):
    """``capture_ramp`` of ``plan`` into ``out`` with the tests' settings on the emulator (tau 20 s,
    settle 3 s, the emulated unit, a 0.01 degC/min stabilisation over 120 s, set points every 30 s);
    bench and chamber closed after it, whatever it does."""
    try:
        return capture_ramp(out, plan=plan, imu=imu, bench=bench, chamber=chamber, step_s=30.0,
                            settings=CaptureSettings(tau_s=20.0, settle_s=3.0, unit="SN-EMU-0001",
                                                     stabilisation=Stabilisation(0.01, 120.0, 60.0, 3000.0)))
    finally:
        bench.close()
        chamber.close()


def _bound(n_z: int, alpha: float = 1e-3) -> float:
    """|z| that ``n_z`` standard normal z-scores all stay within with probability 1 - alpha
    (Bonferroni): the captures run on the wall clock, so which samples make a visit differs from run
    to run, and a fixed 3 or 3.5 on many z-scores fails a calibrated fit a few times in a hundred
    (CI of 2026-11-27: seed 14's angle or lag past 3.5 once; 24 reruns of seeds 11-22: every z
    within 3, the angles' SD 1.07)."""
    return float(stats.norm.isf(alpha / (2.0 * n_z)))


class _Staircase:
    """The setpoints the emulated chamber received, as the program of independent_bench's Euler
    integration (degC at instrument time t; held before the first and after the last)."""

    def __init__(self, log, start_C, duration_s):
        self.t = np.array([t for t, _ in log], float)
        self.v = np.array([v for _, v in log], float)
        self.start_C, self.duration_s = float(start_C), float(duration_s)

    def __call__(self, t):
        i = np.searchsorted(self.t, np.asarray(t, float), side="right") - 1
        return np.where(i >= 0, self.v[np.clip(i, 0, None)], self.start_C)


@pytest.mark.slow  # 2026-11-29: the quick suite over its 10 minutes on CI (623 s); run in CI's slow phase
def test_ramp_capture_through_the_emulator_fits_and_recovers_the_unit(tmp_path):
    # a short program on a faster chamber and unit than the simulator's (300 s, 600 s), so that
    # 80 min of program play in ~10 s at x500; the unit trails the program by s (tau_c + tau_u)
    plan_path = tmp_path / "ramp.json"
    RampPlan(program_C=(20.0, -10.0, 50.0, 20.0), rate_C_per_min=1.5, tau_s=20.0).save(plan_path)
    plan = read_ramp_plan(plan_path)
    timing = EmulatorTiming(time_scale=500.0, rate_hz=2.0, chamber_time_constant_s=300.0, unit_time_constant_s=600.0,
                            self_heating_time_constant_s=60.0)
    em = emulate(tmp_path / "emu", effects=EFFECTS, timing=timing, seed=5).start()
    received = []                                   # what the chamber got, on the emulator's clock
    set_sp = em.physics.set_setpoint
    em.physics.set_setpoint = lambda t, sp: (received.append((t, sp)), set_sp(t, sp))[1]
    out = tmp_path / "out"
    t_wall = time.monotonic()
    try:
        imu, bench, chamber = open_instruments(load_port_config(em.directory / "ports.toml"))
        settings = CaptureSettings(tau_s=20.0, settle_s=3.0, unit="SN-EMU-0001",
                                   stabilisation=Stabilisation(0.01, 120.0, 60.0, 3000.0))
        report = capture_ramp(out, plan=plan, imu=imu, bench=bench, chamber=chamber, settings=settings, step_s=30.0)
        bench.close()
        chamber.close()
    finally:
        em.stop()
    wall = time.monotonic() - t_wall
    c = read_bench_csv(out / CSV_NAME)
    check_visits_against_raw(out, c)
    labels = list(DEFAULT_PLAN)
    assert list(c.position) == [labels[i % 12] for i in range(c.n_visits)]     # cycling, no soak
    # how many visits fit in the program follows the wall clock (72-86 seen, fewer when the machine is
    # loaded): asserted only that the positions were cycled through at least once, not a speed
    assert c.n_visits == report.visits_done >= len(labels)
    assert np.all(np.diff(c.time_s) > 0)
    assert float(c.metadata["Q_V2s"]) == pytest.approx(3e-9, rel=0.2)
    assert c.metadata["ramp"].startswith("20:-10:50:20 degC at 1.5 degC/min")
    # a chamber that follows the program (air 5 min behind it) gives no chamber warning
    assert not [w for w in report.warnings if "chamber" in w], report.warnings

    # the program as written: every setpoint the log names reached the chamber, in order, each the
    # program's value at its program time (0.1 degC resolution), 30 s of program apart
    program = RampProgram.of(plan)
    events = read_events(out / "raw" / "events.jsonl")
    written = [e for e in events if e["kind"] == "ramp_setpoint"]
    changed = [e["setpoint_C"] for k, e in enumerate(written)
               if k == 0 or e["setpoint_C"] != written[k - 1]["setpoint_C"]]
    assert [sp for _, sp in received] == [20.0] + changed      # the soak's setpoint, then the program's
    for e in written:
        assert abs(e["setpoint_C"] - program.value(e["program_s"])) <= 0.05 + 1e-9     # the register's 0.1 degC
    p = np.array([e["program_s"] for e in written])
    # then every 30 s, the last at the end (when the first move goes out is the reader's timing at this
    # clock: test_the_program_writes_its_first_move_at_once checks the rule frame by frame)
    assert p[0] == 0.0 and np.all(np.diff(p)[1:-1] >= 30.0) and p[-1] == program.duration_s

    # the unit's temperature in the readings against an explicit Euler integration of the two lags
    # driven by the received setpoints (independent of models/thermal_environment)
    state = json.loads((out / "capture.json").read_text())
    from test_results_contract import assert_valid
    assert_valid(state, "triadcal.ramp_capture")                  # the state file keeps its contract
    offset = state["time_offset_s"]
    stairs = _Staircase(received, 20.0, float(c.time_s[-1] - offset + 60.0))
    t_e, air, unit, _ = euler_thermal_history(stairs, tau_chamber_min=5.0, tau_housing_min=10.0,
                                              tau_element_min=1.0, dt_s=0.25, start_C=20.0)
    mid = c.time_s - offset
    unit_mid = np.interp(mid, t_e, unit)
    readings = c.t - np.array(timing.self_heating_C)[None, :]
    dev = float(np.max(np.abs(readings - unit_mid[:, None])))
    assert dev < 0.02, dev           # seen 0.009 (0.09 before the emulator kept its recent setpoints)
    # direction labels: the sign of the unit's rate over the window, wherever it is clear
    rate = (np.interp(mid + 10.0, t_e, unit) - np.interp(mid - 10.0, t_e, unit)) / 20.0 * 60.0   # degC/min
    clear = np.abs(rate) > 0.1
    assert np.all((rate[clear] > 0) == (c.direction[clear] == "heating"))
    assert {"heating", "cooling"} == set(c.direction)
    # the measured rate each row carries (dTdt_C_per_min, the fit's dT/dt): the slope of the line through
    # the window's readings against the Euler unit's mean rate over the window (seen in 4 runs: rms
    # 0.008-0.010, largest 0.023-0.034 degC/min, the readings' noise; the central differences of the
    # visit means are off by 0.013-0.016 rms, up to 0.08 at the turns)
    assert c.dTdt_C_per_min is not None and c.metadata["dTdt_method"].startswith("slope of the least-squares line")
    err = c.dTdt_C_per_min - rate
    assert np.sqrt(np.mean(err ** 2)) < 0.015 and np.max(np.abs(err)) < 0.06, (np.sqrt(np.mean(err ** 2)),
                                                                                np.max(np.abs(err)))
    np.testing.assert_array_equal(c.temperature_rate(), np.repeat(c.dTdt_C_per_min[:, None] / 60.0, 3, axis=1))
    # the unit saw less than the program's range (it trails the turns by ~ s (tau_c + tau_u) = 22.5 degC)
    assert -10.0 < c.t.min() < 10.0 and 30.0 < c.t.max() < 50.0

    # the fit with thermal_lag recovers the emulated unit
    truth = em.truth
    r = fit(c, effects=EFFECTS)
    # every gate passes but perhaps one of the tests of the data's scatter, each of which refuses about
    # 0.001 of captures of a right model (tests/scatter_gates.py); its chi^2 must be inside the outer 1e-4
    # (two-sided: a fit that reads white noise as flicker is low) and the play's |z| inside 1e-5
    assert_right_or_scatter([r], max_refusals=1, label=(r.status, r.fit.get("chi2_dof"), r.notes[-2:]))
    assert abs(r.fit["thermal_play"]["z"]) < stats.norm.isf(5e-6), r.fit["thermal_play"]        # 4.42
    dof = r.fit["n_obs"] - r.fit["n_params"]
    lo, hi = stats.chi2.ppf(5e-5, dof) / dof, stats.chi2.isf(5e-5, dof) / dof     # 0.65-1.44 on 195 dof
    assert lo < r.fit["chi2_dof"] < hi, (r.fit["chi2_dof"], dof, lo, hi)
    z = {n: (r.parameters[n].value - v) / r.parameters[n].u for n, v in truth.parameters.items()}
    assert set(z) == set(truth.parameters)
    for n in (*ANGLES, "thermal_lag"):
        assert abs(z[n]) < _bound(7), (n, z[n])                     # 3.80
    assert max(abs(v) for v in z.values()) < _bound(len(z)), z      # 4.17 for the 33 parameters
    print(f"\nramp capture: {c.n_visits} visits in {wall:.1f} s wall, chi2/dof {r.fit['chi2_dof']:.3f}, "
          f"thermal_lag {r.parameters['thermal_lag'].value:.3f} +- {r.parameters['thermal_lag'].u:.3f} min, "
          f"largest |z| {max(abs(v) for v in z.values()):.2f}, angles {max(abs(z[n]) for n in ANGLES):.2f}; "
          f"readings against the Euler unit within {dev:.4f} degC")


def _capture_and_fit(tmp_path, seed):
    """The quick test's ramp (20 -> -10 -> 50 -> 20 degC at 1.5 degC/min, x500) captured and fitted."""
    RampPlan(program_C=(20.0, -10.0, 50.0, 20.0), rate_C_per_min=1.5, tau_s=20.0).save(tmp_path / "ramp.json")
    timing = EmulatorTiming(time_scale=500.0, rate_hz=2.0, chamber_time_constant_s=300.0, unit_time_constant_s=600.0,
                            self_heating_time_constant_s=60.0)
    em = emulate(tmp_path / "emu", effects=EFFECTS, timing=timing, seed=seed).start()
    try:
        imu, bench, chamber = open_instruments(load_port_config(em.directory / "ports.toml"))
        report = ramp_on(tmp_path / "out", read_ramp_plan(tmp_path / "ramp.json"), imu, bench, chamber)
        assert not [w for w in report.warnings if "chamber" in w], report.warnings   # it follows the program
    finally:
        em.stop()
    r = fit(read_bench_csv(tmp_path / "out" / CSV_NAME), effects=EFFECTS)
    return r, {n: (r.parameters[n].value - v) / r.parameters[n].u for n, v in em.truth.parameters.items()}


@pytest.mark.slow
def test_ramp_captures_over_seeds_recover_the_unit(tmp_path):
    """Six seeds (~80 s): every angle and thermal_lag within the Bonferroni bound of the 42 (4.22 u,
    _bound), the z-scores of all parameters pooled with SD in 0.6-1.5 (their u describes their
    scatter); every gate but the goodness of fit passes on each seed, and the goodness of fit is
    tested once on the six seeds together: sum chi^2 against chi^2 of the summed dof, two-sided at
    alpha = 0.001; so is the thermal play, sum z^2 against chi^2(6) at 0.001.

    Why not each seed's status: the gates that test the data's scatter (tests/scatter_gates.py) each
    refuse about 0.001 of captures of a right model, and asking thirty of them to accept random captures
    failed a CI now and then (CI73: seed 13's y at 1.66 on 75 dof, p 0.0003; 2026-12-02: seed 15's
    pooled 1.35 on 207 dof, p 0.0006; 2026-12-03: seed 15's thermal_play beyond 3.29, a z that over 49
    captures had SD 1.00, 1.05 on a loaded machine). They may refuse twice in all (three or more:
    2e-5 for a right model). The captures' scatter is the emulator's
    white noise: over 34 captures (30 on a machine loaded with 8 busy processes) the noise drawn in
    the recording windows, read back from the emulator, had z^2 1.004 +- 0.016 per visit mean against
    1.013 and 0.994 in the windows of as many frames just before and after (no selection of windows
    by their values), the data against the truth's model scattered as that noise alone (seed 21's z:
    1.64 from the noise, 1.71 with the model's), and the fits' chi^2/dof had SD 0.105 against 0.104
    expected, without the one capture whose white noise the power-law fit read as a flicker floor
    at 3 SE (its x at chi^2/dof 0.14; tests/test_hadamard_noise.py)."""
    zs, chi2, dof, play, results = [], [], [], [], []
    for seed in (11, 12, 13, 14, 15, 16):
        (tmp_path / str(seed)).mkdir()
        r, z = _capture_and_fit(tmp_path / str(seed), seed)
        results.append(r)
        assert_right_or_scatter([r], max_refusals=5, label=(seed, r.fit.get("chi2_dof"), r.notes[-3:]))
        play.append(r.fit["thermal_play"]["z"])
        assert all(abs(z[n]) < _bound(6 * 7) for n in (*ANGLES, "thermal_lag")), (
            seed, {n: z[n] for n in (*ANGLES, "thermal_lag")})
        zs.extend(z.values())
        dof.append(r.fit["n_obs"] - r.fit["n_params"])
        chi2.append(r.fit["chi2_dof"] * dof[-1])
    assert_right_or_scatter(results, max_refusals=2, label=[r.status for r in results])
    assert float(np.sum(np.square(play))) < stats.chi2.isf(1e-3, len(play)), play      # 22.5
    assert 0.6 < np.std(zs) < 1.5, np.std(zs)
    assert abs(np.mean(zs)) < 0.5
    total, n = float(np.sum(chi2)), float(np.sum(dof))
    p = float(stats.chi2.sf(total, n))
    assert 0.0005 < p < 0.9995, (total / n, n, p, [c / d for c, d in zip(chi2, dof)])
    print(f"\n6 seeds: z SD {np.std(zs):.2f}, mean {np.mean(zs):+.2f}, chi2/dof {total / n:.3f} on {n:.0f} dof "
          f"(p {p:.3f}), each {min(c / d for c, d in zip(chi2, dof)):.2f}-{max(c / d for c, d in zip(chi2, dof)):.2f}")


def test_sigkill_mid_ramp_then_resume_loses_no_sample(tmp_path):
    timing = EmulatorTiming(time_scale=240.0, rate_hz=5.0, chamber_time_constant_s=60.0, unit_time_constant_s=120.0,
                            self_heating_time_constant_s=30.0)
    em = emulate(tmp_path / "emu", effects=["bench_tilt", "thermal_lag"], timing=timing, seed=11,
                 keep_log=True).start()
    labels = ["P01", "P05", "P09", "P12"]
    plan_path = tmp_path / "ramp.json"
    RampPlan(program_C=(20.0, 10.0, 20.0), rate_C_per_min=2.0, tau_s=20.0,
             positions={k: DEFAULT_PLAN[k] for k in labels}).save(plan_path)
    out = tmp_path / "out"
    cmd = CLI + ["capture", "--config", str(em.directory / "ports.toml"), "--out", str(out), "--ramp", str(plan_path),
                 "--ramp-step-s", "10", "--settle-s", "2", "--stab-window-s", "60", "--stab-hold-s", "30",
                 "--unit", "SN-EMU-0001", "--no-progress"]
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        n_rows = 0
        while n_rows < 3:        # wait for events, not the clock: three visits written, then more samples
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
            if (out / CSV_NAME).exists():
                n_rows = read_bench_csv(out / CSV_NAME).n_visits
        size = (out / RAW_NAME).stat().st_size
        while (out / RAW_NAME).stat().st_size <= size:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.01)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        assert proc.returncode == -signal.SIGKILL
        killed_at = read_bench_csv(out / CSV_NAME).n_visits
        raw_before = (out / RAW_NAME).read_bytes()
        before = [e for e in read_events(out / "raw" / "events.jsonl") if e["kind"] == "ramp_setpoint"]
        r = subprocess.run(cmd, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
    finally:
        em.stop()
    c = read_bench_csv(out / CSV_NAME)
    assert killed_at < c.n_visits
    assert list(c.position) == [labels[i % 4] for i in range(c.n_visits)]     # the cycle goes on where it stopped
    assert np.all(np.diff(c.time_s) > 0)
    raw = check_visits_against_raw(out, c)
    tags = c.extra["raw_visit"]
    assert sum(t.split("-")[-1].startswith("1.") for t in tags) == killed_at
    assert all(t.split("-")[-1].startswith("2.") for t in tags[killed_at:])
    # append-only: the raw file of the killed run is a prefix of the final one
    assert (out / RAW_NAME).read_bytes()[:len(raw_before)] == raw_before
    # no sample lost: within each session, every frame the emulator put on the line intact is in the
    # raw store, as sent (the others of the span are frames the emulator could not write whole while
    # the line was full, counted by the reader as missing or corrupted, as in test_hardware_capture)
    log = {seq: (fate, fr) for seq, fate, fr in em.log}
    for s in (1, 2):
        seqs = raw["seq"][raw["session"] == s]
        assert len(seqs) and np.all(np.diff(seqs) > 0)
        lo, hi = int(seqs[0]), int(seqs[-1])
        fates = [log[q][0] for q in range(lo, hi + 1)]
        assert sum(f == "sent" for f in fates) == len(seqs), {f: fates.count(f) for f in set(fates)}
        assert set(fates) <= {"sent", "overrun", "truncated"}
        for k in range(0, len(seqs), 11):
            np.testing.assert_array_equal(raw["w"][raw["session"] == s][k], log[int(seqs[k])][1].w)
    # the program resumed where the killed run last wrote it, without a new soak, and ran to its end
    events = read_events(out / "raw" / "events.jsonl")
    second = next(i for i, e in enumerate(events) if e["kind"] == "session_start" and e["session"] == 2)
    resume = [e for e in events[second:] if e["kind"] == "ramp_resume"]
    assert len(resume) == 1 and resume[0]["program_s"] == max(e["program_s"] for e in before)
    assert not [e for e in events[second:] if e["kind"] in ("stable", "ramp_start")]
    assert [e for e in events if e["kind"] == "ramp_end"]
    visits = [e for e in events if e["kind"] == "visit"]
    assert visits[-1]["program_s"] >= 600.0 - 60.0
    assert set(c.direction) == {"heating", "cooling"}
    # the measured rate of the rows before the kill came back with them
    assert c.dTdt_C_per_min is not None and np.all(np.isfinite(c.dTdt_C_per_min))


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.pop("tau_s"), "field tau_s is missing"),
    (lambda d: d.update(rate_C_per_min=-1.0), "field rate_C_per_min: -1.0 out of range"),
    (lambda d: d.update(program_C=[20.0]), "field program_C: expected a list of at least two"),
    (lambda d: d["program_C"].__setitem__(1, "cold"), "field program_C[1]: expected a finite number"),
    (lambda d: d["positions"][1].update(axis1_deg="x"), "field positions[1].axis1_deg: expected a finite number"),
    (lambda d: d["positions"][2].pop("label"), "field positions[2].label is missing"),
    (lambda d: d.update(format="triadcal.plan"), "a stepped plan"),
    (lambda d: d.update(version=2), "ramp plan version 2 is not known"),
    (lambda d: d["positions"][3].update(label=d["positions"][0]["label"]), "field positions[3].label: 'P01' appears"),
])
def test_a_bad_ramp_plan_is_refused_naming_file_and_field(tmp_path, capsys, edit, message):
    path = tmp_path / "bad_ramp.json"
    d = RampPlan(program_C=(20.0, -10.0, 20.0)).to_dict()
    edit(d)
    path.write_text(json.dumps(d))
    assert main(["capture", "--ramp", str(path), "--out", str(tmp_path / "out"), "--emulate"]) == 1
    err = capsys.readouterr().err
    assert str(path) in err and message in err, err
    assert not (tmp_path / "out").exists()           # refused before anything started
    # simulate --plan reads it with the same checks (before: a label given twice lost a position)
    if "stepped" not in message:
        assert main(["simulate", "--plan", str(path), "--out", str(tmp_path / "sim.csv")]) == 1
        err = capsys.readouterr().err
        assert str(path) in err and message in err, err
        assert not (tmp_path / "sim.csv").exists()


def test_ramp_and_setpoints_exclude_each_other_and_the_folder_kinds_do_not_mix(tmp_path, capsys):
    from triadcal.hardware.capture import CaptureError, capture

    path = tmp_path / "ramp.json"
    RampPlan(program_C=(20.0, -10.0, 20.0)).save(path)
    assert main(["capture", "--ramp", str(path), "--setpoints", "20", "--out", str(tmp_path / "o")]) == 1
    assert "--setpoints (stepped), --plan PLAN.json" in capsys.readouterr().err
    assert main(["capture", "--ramp", str(path), "--tau-s", "60", "--out", str(tmp_path / "o")]) == 1
    assert "tau_s = 30" in capsys.readouterr().err
    # a ramp capture's folder is not a stepped capture's, and the other way round
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "capture.json").write_text(json.dumps(
        {"format": "triadcal.ramp_capture", "version": 1, "sessions": []}))
    with pytest.raises(CaptureError, match="not a capture state file"):
        capture(tmp_path / "r", plan={"P01": (0.0, 0.0)}, setpoints_C=[20.0], imu=None, bench=None, chamber=None,
                settings=CaptureSettings(unit="X"))
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "capture.json").write_text(json.dumps(
        {"format": "triadcal.capture", "version": 1, "sessions": []}))
    with pytest.raises(CaptureError, match="holds a stepped capture"):
        capture_ramp(tmp_path / "s", plan=read_ramp_plan(path), imu=None, bench=None, chamber=None)


def _readings(times, temps, rng, sd=0.006):
    return np.c_[times, temps + rng.normal(0.0, sd, times.size)]


def test_a_window_on_the_turn_at_the_program_start_is_a_turn():
    """The program's first window as a loaded run recorded it (by hand, 2026-11-25): the readings
    still rose with the electronics' self-heating (+0.005 degC/min at the window's start, 22 SE)
    while the chamber had begun to cool, and turned near the window's end (end rate -0.8 SE);
    labelled by its mean rate (heating), that window gave |z| 23 in the fit (chi2/dof 5.5). The
    rule of both rates 2 SE from 0 let it through. Made here with numpy: a parabola with its vertex
    10 s before the window's end, 2 Hz readings, sd 0.006 degC (three sensors' mean), 200 draws: a
    turn is seen whenever the end's noisy rate has the other sign (about 3/4 of the draws; the
    rest put 10 s of 120 on the other branch); a steady ramp never, a plateau about 0.3 %. 100 draws."""
    rng = np.random.default_rng(1)
    t = np.arange(500.0, 800.0, 0.5)
    vertex = 770.0
    curv = -0.0055 / 60.0 / (2 * (vertex - 650.0))          # +0.0055 degC/min at the window's start

    def rates(temps):
        return window_rates(_readings(t, temps, rng), 650.0, 780.0)

    turns = [rates(20.27 + curv * (t - vertex) ** 2) for _ in range(100)]
    assert all(r["start"] > 3 * r["start_se"] for r in turns)
    seen = sum(turned_within(r) for r in turns)
    # P(end rate estimated < 0) = Phi(E/SE) ~ 0.75 here; 55 is below the mean by 4.6 binomial SDs
    assert seen >= 55, seen
    assert not any(turned_within(rates(20.0 - (t - 500.0) / 60.0)) for _ in range(20))     # 1 degC/min
    fired = sum(turned_within(rates(np.full(t.size, 20.0))) for _ in range(100))
    assert fired <= 4          # expected ~0.3 % of 100; P(> 4) < 1e-3 for a binomial(100, 0.005)


def test_the_program_writes_its_first_move_at_once():
    """The program's pump, frame by frame (no clock, no thread): at 1.5 degC/min from 20 degC with a
    30 s step, the first move goes out at the first frame where the program's value shows a change
    of the setpoint's 0.1 degC (20 -> 19.9 at 2-6 s: 19.95 rounds to 19.9 or 20.0), then every 30 s."""
    from types import SimpleNamespace

    from triadcal.hardware.protocols import Frame
    from triadcal.hardware.ramp_capture import _RampRunner

    frames = [[Frame(k, 0.5 * k, (0.0, 0.0, 1.0), (20.0, 20.0, 20.0))] for k in range(400)]
    written, logged = [], []
    stream = SimpleNamespace(get=lambda timeout: frames.pop(0) if frames else [])
    raw = SimpleNamespace(append=lambda *a, **k: None)
    events = SimpleNamespace(write=lambda kind, **k: logged.append((kind, k)))
    chamber = SimpleNamespace(set_setpoint_C=written.append)
    program = RampProgram(np.array([0.0, 1200.0]), np.array([20.0, -10.0]))
    run = _RampRunner(stream, raw, events, 1, CaptureSettings(), chamber=chamber, program=program, step_s=30.0,
                      offset_of=lambda: 0.0)
    run.pump()
    run.start_program(0.0)
    while frames:
        run.pump()
    p = [k["program_s"] for kind, k in logged if kind == "ramp_setpoint"]
    assert written[:2] == [20.0, 19.9] and p[0] == 0.0
    assert 2.0 <= p[1] <= 6.0                   # the first frame whose value rounds to 19.9
    assert p[2] == pytest.approx(p[1] + 30.0)   # then the step rule
    assert written[2] == pytest.approx(20.0 - 1.5 * p[2] / 60.0, abs=0.05)


def test_a_rate_below_the_settled_rate_keeps_the_branch():
    """The first visit of a CI run's ramp (CI-15, the docs/hardware.md block): the readings crept up
    by 0.0028 degC/min (SE 0.0004, z = 7: the electronics' self-heating) while the program began
    to cool; labelled heating, that visit took the wrong hysteresis branch and the fit was refused
    (chi2/dof 5.76; 1.12 with the visit labelled cooling). Below the rate at which the capture counts
    the unit as settled (0.01 degC/min) a significant rate keeps the previous label."""
    at_rest = Stabilisation().rate_C_per_min / 60.0
    slope, se = 0.0028 / 60.0, 0.0004 / 60.0
    assert visit_direction(slope, se, "cooling", at_rest=at_rest) == "cooling"
    assert visit_direction(slope, se, "cooling") == "heating"                  # the rule of before
    assert visit_direction(-0.0208 / 60.0, 0.0003 / 60.0, "heating", at_rest=at_rest) == "cooling"
    assert visit_direction(0.5 / 60.0, 0.4 / 60.0, "cooling", at_rest=at_rest) == "cooling"   # within 3 SE


def test_a_turn_after_a_resume_is_labelled_by_the_windows_own_rate():
    """CI, 2026-11-30: after a SIGKILL and resume, a window whose own readings rose at 0.204 degC/min
    was labelled ``cooling`` and the reader refused the file its capture wrote (a ramp label against
    its row's rate by more than 0.2 degC/min). Made here with numpy, not the emulator: the test's
    program (20 -> 10 -> 20 degC at 2 degC/min), chamber air and unit as two first-order lags (60 s,
    120 s, explicit Euler), the capture killed at program time 200 s and the chamber holding that
    setpoint for 300 s before the program goes on; readings at 5 Hz, sd 0.006 degC; the history
    starts at the resume, as a new run's does. The quadratic through the 150 s before the window
    straddles the unit's turn and lags it: on its own it labelled ``cooling`` windows whose true rate
    was up to +0.2 degC/min (60 of 1 840 windows with |rate| > 0.05, seeds 0-19). With the window's
    own line deciding first, every label is the sign of the true rate."""
    from types import SimpleNamespace

    from triadcal.hardware.ramp_capture import visit_rate_se

    def program(t):              # program time stops for the 300 s the capture is down
        p = np.where(t < 200.0, t, np.where(t < 500.0, 200.0, t - 300.0))
        return np.interp(p, [0.0, 300.0, 600.0], [20.0, 10.0, 20.0])
    program.duration_s = 1500.0

    t, _, unit, _ = euler_thermal_history(program, tau_chamber_min=1.0, tau_housing_min=2.0, dt_s=0.1)
    true_rate = np.gradient(unit, t) * 60.0
    ts, us = t[::2], unit[::2]
    at_rest = Stabilisation().rate_C_per_min / 60.0
    n = wrong_old = wrong = 0
    for seed in range(20):
        y = us + np.random.default_rng(seed).normal(0.0, 0.006, ts.size)
        history = np.c_[ts, y][ts >= 500.0]
        previous = "cooling"
        for mid in np.arange(530.0, 1000.0, 5.0):
            w = (ts >= mid - 10.0) & (ts <= mid + 10.0)
            frames = [SimpleNamespace(time_s=a, t=(b, b, b)) for a, b in zip(ts[w], y[w])]
            r = window_rates(history, mid - 10.0, mid + 10.0)
            old = visit_direction(r["mean"], r["mean_se"], previous, at_rest=at_rest)
            new = visit_direction(r["mean"], r["mean_se"], previous, at_rest=at_rest, own=visit_rate_se(frames))
            rate = true_rate[(t >= mid - 10.0) & (t <= mid + 10.0)].mean()
            if abs(rate) > 0.05:
                want = "heating" if rate > 0 else "cooling"
                n, wrong_old, wrong = n + 1, wrong_old + (old != want), wrong + (new != want)
            previous = new
    assert n == 1840
    assert wrong_old >= 30, wrong_old          # the mechanism is there (60 seen)
    assert wrong == 0, wrong


class _LaggedRampChamber:
    """A chamber's air following the ramp 24 -> 0 degC at 2 degC/min (then held) with a first-order
    lag of 120 s, in closed form (y = 24 - r (t - tau (1 - exp(-t/tau))) on the ramp, then an
    exponential to 0): not the capture's own lag filter. Its clock is the wall clock x 500 from a
    given origin, as the emulator's is."""

    def __init__(self, wall0: float, p0: float, scale: float = 500.0, dead_at=None):
        self.wall0, self.p0, self.scale, self.dead_at = wall0, p0, scale, dead_at

    def temperature_C(self) -> float:
        if self.dead_at is not None:
            return self.dead_at
        t = self.p0 + (time.monotonic() - self.wall0) * self.scale
        tau, r, end = 120.0, 24.0 / 720.0, 720.0
        if t <= end:
            return 24.0 - r * (t - tau * (1.0 - np.exp(-t / tau)))
        y_end = 24.0 - r * (end - tau * (1.0 - np.exp(-end / tau)))
        return float(y_end * np.exp(-(t - end) / tau))


class _Events:
    def __init__(self):
        self.seen = []

    def write(self, kind, **kw):
        self.seen.append(kind)


def _runner_behind(chamber, wall: float):
    """A ramp runner whose latest frame (program time 600 s) the reader stamped at ``wall``
    (monotonic), the frames before it at 500 instrument s per wall s: the host busy since (a visit's
    fsync on a loaded 2-core machine)."""
    from collections import deque

    from triadcal.hardware.ramp_capture import _RampRunner

    program = RampProgram(np.array([0.0, 720.0]), np.array([24.0, 0.0]))
    run = _RampRunner(None, None, _Events(), 1, CaptureSettings(), chamber=chamber, program=program,
                      step_s=30.0, offset_of=lambda: 0.0)
    run.running, run.p0, run.t0, run.now, run.last_wall = True, 0.0, 0.0, 600.0, wall
    run._flow = deque([(wall - 1.0, 100.0), (wall, 600.0)])
    return run


def test_the_chamber_check_takes_the_program_when_the_pv_was_read():
    """Flaky in a clean-clone CI: "the chamber's PV was off the program" on the emulator's healthy
    chamber. The PV is read now; the program time was the latest frame's. With the host 0.6 s
    behind at x500 the chamber is 300 s of program further: here at 0.9 degC (closed form) where the
    program at the frame's time is 4 degC and the old band's floor 2 degC (checked below). The check
    takes the program over the frame's time to the read's: no event. A dead chamber still is one."""
    from triadcal.hardware.ramp_capture import program_band

    program = RampProgram(np.array([0.0, 720.0]), np.array([24.0, 0.0]))
    lo_frame, _ = program_band(program, 600.0, 600.0)
    assert lo_frame == pytest.approx(2.0, abs=1e-6)          # the program's 4 degC, less 2 degC
    wall = time.monotonic() - 0.6
    healthy = _LaggedRampChamber(wall, 600.0)
    assert healthy.temperature_C() < lo_frame                 # the old rule would have called it off
    run = _runner_behind(healthy, wall)
    run.check_chamber(1)
    assert run.off_program == [] and run.events.seen == []

    for dead in (24.5, -8.0):      # held at its start, or far below the program's end
        run = _runner_behind(_LaggedRampChamber(wall, 600.0, dead_at=dead), wall)
        run.check_chamber(1)
        assert run.events.seen == ["chamber_off_program"], dead


def test_a_stuck_bench_stops_a_ramp_capture(tmp_path):
    """The stepped capture's stuck-bench rule in the ramp too (the helper that wrote it left the ramp
    out): the emulator's bench stops moving after its second move and reports each target; the ramp
    stops at the next visit naming both, with the visits before it kept. The two rows kept read back
    (a first leg's file, setpoint_C -10 while the unit is at 20: its degF check now holds t against the
    program_C column; against setpoint_C they "looked like degF", so such a ramp could not be resumed)."""
    from triadcal.hardware.capture import CaptureError
    from triadcal.hardware.emulator_faults import FaultPlan

    RampPlan(program_C=(20.0, -10.0, 50.0, 20.0), rate_C_per_min=1.5, tau_s=20.0).save(tmp_path / "ramp.json")
    timing = EmulatorTiming(time_scale=500.0, rate_hz=2.0, chamber_time_constant_s=300.0, unit_time_constant_s=600.0,
                            self_heating_time_constant_s=60.0)
    em = emulate(tmp_path / "emu", effects=["bench_tilt"], timing=timing, seed=5,
                 faults=FaultPlan(bench_stuck_after_moves=2)).start()
    try:
        imu, bench, chamber = open_instruments(load_port_config(em.directory / "ports.toml"))
        with pytest.raises(CaptureError, match=r"of the ramp after P02 .*the bench did not move"):
            ramp_on(tmp_path / "out", read_ramp_plan(tmp_path / "ramp.json"), imu, bench, chamber)
    finally:
        em.stop()
    c = read_bench_csv(tmp_path / "out" / CSV_NAME)
    assert list(c.position) == ["P01", "P02"]
    kinds = [e["kind"] for e in read_events(tmp_path / "out" / "raw" / "events.jsonl")]
    assert kinds.count("bench_stuck") == 1


def test_the_chamber_check_allows_for_set_points_written_late():
    """The same CI run under load, after the fix above: the host wrote no set point for 426 s of
    program (0.9 s of wall at x500) on the last leg of 20 -> -10 -> 50 -> 20 degC at 1.5 degC/min, so
    the chamber held 34.2 degC while the program went on to 23.6; at the next visit it read 35.2
    where the program's lag envelope ended at 34.9: "off the program" on a healthy chamber told late.
    Here the chamber is a lag of 300 s integrated by small exact steps of what it was told (every 30 s
    to 4100 s, then 4656 s on: 36.5 degC at 4701.5 s), not the capture's filter: within the band once the check allows for
    the writes' lateness (the old band, no lateness, refuses it); a chamber dead at 0 degC still not."""
    from triadcal.hardware.ramp_capture import program_band

    program = RampProgram(np.array([0.0, 1200.0, 3600.0, 4800.0]), np.array([20.0, -10.0, 50.0, 20.0]))
    writes = [float(p) for p in np.arange(0.0, 4101.0, 30.0)] + [4656.0, 4686.0]
    dt, tau, y = 0.5, 300.0, 20.0
    for t in np.arange(0.0, 4701.5, dt):
        told = program.value(writes[int(np.searchsorted(writes, t, side="right")) - 1])
        y = told + (y - told) * np.exp(-dt / tau)
    lo, hi = program_band(program, 4701.5, 4701.5)
    assert not lo <= y <= hi, (y, lo, hi)                        # the old band: off the program

    class Chamber:
        def __init__(self, pv):
            self.pv = pv

        def temperature_C(self):
            return self.pv

    for pv, off in ((y, False), (0.0, True)):
        wall = time.monotonic()
        run = _runner_behind(Chamber(pv), wall)
        run.program = program
        run.now = 4701.5
        run.written.extend((w, w) for w in writes)
        run.check_chamber(1)
        assert (run.events.seen == ["chamber_off_program"]) is off, (pv, run.events.seen)
