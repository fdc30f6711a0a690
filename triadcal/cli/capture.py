"""``triadcal capture``: run (or resume) a bench campaign into a directory."""

from __future__ import annotations

from ..errors import InputError

import sys
import tempfile

from ._common import add_output_options, float_list, output
from .emulate import IMU_PROTOCOLS, add_emulator_options, build_emulator, fates_text


def register(sub) -> None:
    p = sub.add_parser(
        "capture", help="run a bench campaign on the instruments (or the emulator) into a directory",
        description="For each chamber setpoint: command the chamber, wait for the unit's temperatures to "
                    "settle, then for each bench position move, settle and record tau seconds. Raw samples "
                    "go to DIR/raw (append-only), position averages to DIR/campaign.csv (bench CSV v1) as "
                    "visits complete. Run the same command again to resume an interrupted campaign.")
    p.add_argument("--out", required=True, metavar="DIR", help="campaign directory")
    p.add_argument("--plan", default="default",
                   help="'default' (the 12-position plan), a CSV file position,axis1_deg,axis2_deg, or the stepped "
                        "plan file of 'triadcal plan' (PLAN.json: its setpoints, positions, repetitions and tau; the "
                        "effects it was made for go into the CSV as # planned_effects)")
    p.add_argument("--setpoints", help="chamber setpoints in degC, in order, e.g. 20,70,-40 (or --ramp, or a "
                                       "plan file's)")
    p.add_argument("--ramp", metavar="RAMP_PLAN.json",
                   help="continuous ramp instead of setpoints: the ramp plan of 'triadcal plan --ramp'; the chamber "
                        "follows its program while the bench cycles through its positions, recording back to back, "
                        "no soak (docs/hardware.md, 'Continuous ramp capture')")
    p.add_argument("--ramp-step-s", type=float, default=10.0, metavar="S",
                   help="with --ramp: write the program's value as the setpoint every S program seconds (default 10)")
    p.add_argument("--tau-s", type=float, default=None,
                   help="averaging time per position, s (default 30; with --ramp, the plan's)")
    p.add_argument("--settle-s", type=float, default=5.0, help="wait after in-position, s (default 5)")
    p.add_argument("--unit", default=None, help="serial number of the unit (default SN-UNKNOWN, or the emulator's)")
    p.add_argument("--operator", default="")
    p.add_argument("--local-g", type=float, default=None, metavar="M_S2",
                   help="local gravity, m/s^2, written to the bench CSV (without it the file states none: a fit "
                        "assumes standard gravity and says so, and a certificate needs the lab file's [gravity])")
    p.add_argument("--stab-rate", type=float, default=0.01, metavar="DEGC_PER_MIN",
                   help="stable when every |dT/dt| < this (default 0.01 degC/min)")
    p.add_argument("--stab-window-s", type=float, default=120.0, help="slope window, s (default 120)")
    p.add_argument("--stab-hold-s", type=float, default=300.0, help="... held for this long, s (default 300)")
    p.add_argument("--stab-timeout-s", type=float, default=6 * 3600.0, help="give up after, s (default 6 h)")
    p.add_argument("--config", help="TOML file with [imu], [bench], [chamber] ports (see docs/hardware.md)")
    p.add_argument("--instruments", metavar="INSTRUMENTS.toml",
                   help="TOML file choosing the drivers: [imu] driver = vectornav|xsens|mip|nmea|binary, "
                        "[chamber] driver = watlow-f4|watlow-f4t|espec|modbus, [bench] driver = template|scpi "
                        "(docs/hardware.md, examples/data/instruments.toml)")
    p.add_argument("--imu-port")
    p.add_argument("--imu-protocol", choices=IMU_PROTOCOLS)
    p.add_argument("--imu-rate-hz", type=float, help="IMU output rate a vendor IMU is configured to")
    p.add_argument("--bench-port")
    p.add_argument("--chamber-port")
    p.add_argument("--chamber-slave", type=int)
    p.add_argument("--emulate", action="store_true",
                   help="start the emulator in this process on a compressed clock and capture from it")
    add_output_options(p)
    add_emulator_options(p, prefix="emulate-")
    p.set_defaults(func=run)


def _progress_bar(out):
    """The progress callback of :func:`triadcal.hardware.capture.capture`: a bar of visits on stderr,
    or None (see :func:`triadcal.cli._common.output`)."""
    if not out.progress:
        return None
    state = {"bar": None}

    def progress(ev):
        if state["bar"] is None:
            state["bar"] = out.bar(total=ev["total"], initial=ev["done"], unit="visit")
        bar = state["bar"]
        bar.n = ev["done"]
        kind = ev["event"]
        if kind == "soak":
            rate = ev.get("rate_C_per_min")
            bar.set_postfix_str(f"{ev['setpoint_C']:g} degC: settling, dT/dt "
                                + ("--" if rate is None else f"{rate:.3f} degC/min")
                                + (f", chamber {ev['chamber_C']:.1f} degC" if ev.get("chamber_C") is not None
                                   else ""), refresh=True)
        elif kind in ("move", "record", "visit"):
            bar.set_postfix_str(f"{ev['setpoint_C']:g} degC {ev['position']} {kind}", refresh=True)
        elif kind == "done":
            bar.close()

    return progress


def run(args) -> int:
    from ..hardware.capture import (CaptureError, CaptureSettings, Stabilisation, capture, imu_metadata,
                                    load_instruments, load_port_config, open_instruments, plan_from_csv)
    from ..hardware.drivers.bench import BenchError
    from ..models.campaign import DEFAULT_PLAN

    out = output(args)
    extra = {}
    stepped = _stepped_plan(args)
    if stepped is not None:
        if stepped.effects is not None:        # the model the plan predicted U for: the fit's default effects
            extra["planned_effects"] = ",".join(stepped.effects) or "none"
    if (args.setpoints is None) == (args.ramp is None):
        raise InputError("give the chamber's program: --setpoints (stepped), --plan PLAN.json (a stepped plan of "
                         "'triadcal plan') or --ramp RAMP_PLAN.json (continuous)")
    ramp = None
    if args.ramp is not None:
        from ..hardware.ramp_capture import read_ramp_plan

        ramp = read_ramp_plan(args.ramp)
        if args.plan != "default":
            raise InputError(f"--ramp: the positions come from the ramp plan {args.ramp}; do not give --plan")
        if args.tau_s is not None and args.tau_s != ramp.tau_s:
            raise InputError(f"--tau-s {args.tau_s:g}: the ramp plan {args.ramp} says tau_s = {ramp.tau_s:g} s")
        args.tau_s = ramp.tau_s
    args.tau_s = 30.0 if args.tau_s is None else args.tau_s
    plan = (stepped.visit_positions() if stepped is not None else DEFAULT_PLAN if args.plan == "default"
            else plan_from_csv(args.plan))
    if args.config and args.instruments:
        raise InputError("give --config (a ports file) or --instruments (an instruments file), not both")
    if args.emulate:
        given = [opt for opt, v in (("--config", args.config), ("--instruments", args.instruments),
                                    ("--imu-port", args.imu_port), ("--imu-protocol", args.imu_protocol),
                                    ("--imu-rate-hz", args.imu_rate_hz), ("--bench-port", args.bench_port),
                                    ("--chamber-port", args.chamber_port), ("--chamber-slave", args.chamber_slave))
                 if v is not None]
        if given:
            # the emulator brings its own ports: these were silently ignored (a newcomer's probe)
            raise InputError(f"--emulate makes its own instruments and ports: {', '.join(given)} would be ignored "
                             "(the emulator's protocol is --emulate-protocol; drop --emulate for real instruments)")
    cfg = load_port_config(args.config) if args.config else load_instruments(args.instruments) \
        if args.instruments else {}
    # [dmm] without [imu]: an analog unit read by a voltmeter (hardware.voltmeter_capture.capture_voltmeter)
    dmm_cfg = dict(cfg["dmm"]) if "dmm" in cfg and "imu" not in cfg else None
    cfg = {k: dict(cfg.get(k, {})) for k in ("imu", "bench", "chamber")}
    for section, key, value in (("imu", "port", args.imu_port), ("imu", "protocol", args.imu_protocol),
                                ("imu", "rate_hz", args.imu_rate_hz),
                                ("bench", "port", args.bench_port), ("chamber", "port", args.chamber_port),
                                ("chamber", "slave", args.chamber_slave)):
        if value is not None:
            cfg[section][key] = value
    emulator = None
    unit = args.unit
    if args.emulate:
        emulator = build_emulator(args, tempfile.mkdtemp(prefix="triadcal-emulator-"), prefix="emulate-")
        emulator.start()
        cfg = load_port_config(emulator.directory / "ports.toml")
        unit = unit or emulator.truth.unit
        from pathlib import Path

        Path(args.out).mkdir(parents=True, exist_ok=True)
        truth_path = Path(args.out) / "emulator_truth.json"
        if truth_path.exists():
            # a resume with another emulated unit (--emulate-preset, --emulate-effects, --emulate-Q, ...) was
            # accepted, its truth written over the first's, and a fit of the two units' rows said ok with
            # tempcos of neither (an outside probe)
            from ..models.simulate import Truth

            try:
                before = Truth.load(truth_path).to_dict()
            except (OSError, ValueError, KeyError, TypeError, InputError) as exc:
                _stop_emulator(emulator)
                raise InputError(f"{truth_path}: cannot be read ({exc}): the emulated unit of the rows already "
                                 "captured is not known; choose another --out") from None
            now = emulator.truth.to_dict()
            if before != now:
                _stop_emulator(emulator)
                differs = sorted(k for k in set(before) | set(now) if before.get(k) != now.get(k))
                raise InputError(f"{args.out} holds visits of another emulated unit ({truth_path}: its "
                                 f"{', '.join(differs)} differ from this emulator's): a resume must emulate the same "
                                 "unit (the same --emulate-preset, --emulate-effects, noise and seed), or choose "
                                 "another --out")
        else:
            emulator.truth.save(truth_path)
        extra["emulator"] = f"triadcal emulate (clock x{args.time_scale:g}, {emulator.protocol}" + (
            f", bench profile {emulator.bench_profile_ref})" if emulator.bench_server is not None else ")")
    settings = CaptureSettings(
        tau_s=args.tau_s, settle_s=args.settle_s, unit=unit or "SN-UNKNOWN", operator=args.operator,
        local_g_m_s2=args.local_g,
        stabilisation=Stabilisation(args.stab_rate, args.stab_window_s, args.stab_hold_s, args.stab_timeout_s))
    if dmm_cfg is not None:
        if args.emulate or args.imu_port or args.imu_protocol or args.imu_rate_hz:
            raise InputError(f"{args.instruments}: [dmm] (an analog unit) takes no IMU options and no --emulate")
        if ramp is not None:
            raise InputError(f"{args.instruments}: --ramp needs an IMU with temperatures ([imu]); an analog unit "
                             "through [dmm] is captured at --setpoints")
        return _run_voltmeter(args, out, plan, cfg, dmm_cfg, settings, extra)
    try:
        imu, bench, chamber = open_instruments(cfg)
        settings.output_unit = imu_metadata(imu).get("output_unit", settings.output_unit)
        profile = getattr(bench, "profile", None)          # a bench by template names its controller
        if profile is not None:
            settings.bench_name = f"two-axis bench, {profile.name}"
        try:
            if ramp is not None:
                from ..hardware.ramp_capture import capture_ramp

                report = capture_ramp(args.out, plan=ramp, imu=imu, bench=bench, chamber=chamber, settings=settings,
                                      step_s=args.ramp_step_s, progress=_progress_bar(out), extra_metadata=extra)
            else:
                report = capture(args.out, plan=plan, setpoints_C=float_list(args.setpoints), imu=imu, bench=bench,
                                 chamber=chamber, settings=settings, progress=_progress_bar(out),
                                 extra_metadata=extra)
        except (CaptureError, BenchError) as exc:
            # the session's warnings first (a setpoint missed): they are in the report the session wrote,
            # but an outside probe's failed session showed only the error, 9 rows of a missed setpoint kept
            _print_report_warnings(args.out)
            raise InputError(str(exc)) from None      # one line, exit 1: the campaign cannot go on
        finally:
            bench.close()
            chamber.close()
    finally:
        if emulator is not None:
            _stop_emulator(emulator)
    r = report
    session_visits = r.visits_done - r.visits_done_before
    if ramp is not None:
        # a ramp's count is the plan's estimate (20 s moves); the bench's own moves decide how many fit
        out.say(f"wrote {r.csv_path}: {r.visits_done} visits through the ramp program (the plan estimated "
                f"{r.visits_total} with 20 s moves; the bench's own moves decide), {session_visits} of them in this "
                f"session (session {r.session}), in {r.wall_seconds:.1f} s")
    else:
        out.say(f"wrote {r.csv_path}: {r.visits_done} of {r.visits_total} visits done, {session_visits} of them in "
                f"this session (session {r.session}), in {r.wall_seconds:.1f} s")
    out.say(f"the readout: {r.accepted_samples} samples accepted; {r.corrupted_frames} corrupted, "
            f"{r.missing_frames} missing and {r.duplicate_frames} duplicated frames; {r.garbage_bytes} garbage "
            f"bytes; {r.reconnects} reconnections, {r.stalls} stalls and {r.redone_visits} visits redone")
    if r.invalid_frames or r.clock_faults or r.late_frames or r.conflicting_frames:
        out.say(f"the readout also had {r.invalid_frames} frames refused (values not finite or out of range), "
                f"{r.clock_faults} clock faults (restarts, clock steps, sequence resets), {r.late_frames} late "
                "frames (after later ones: their values are in the event log, not in the record) and "
                f"{r.conflicting_frames} conflicting frames (a copy with other values: the visits holding them "
                "redone); see raw/events.jsonl")
    for w in r.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if r.noise:
        q = r.noise["Q_V2s"]
        out.say(f"white-noise intensity from the Allan variance: Q = {q[0]:.3g}, {q[1]:.3g}, {q[2]:.3g} "
                f"{settings.output_unit}^2 s "
                "(x, y, z)")
    if emulator is not None:
        out.say(f"the emulator's frames: {fates_text(emulator.summary()['fates'])}")
    return 0


def _stop_emulator(emulator) -> None:
    """Stop the emulator and remove its folder (pty links, ports, a copy of the truth already saved in
    --out): every run left it in the temporary directory, 112 after a day of tests, and a resume refused
    for another emulated unit still did."""
    import shutil

    emulator.stop()
    shutil.rmtree(emulator.directory, ignore_errors=True)


def _stepped_plan(args):
    """The stepped plan file of ``triadcal plan`` given as ``--plan PLAN.json`` (None for 'default' or a
    position CSV): its setpoints and tau become ``args.setpoints`` and ``args.tau_s``; a value given
    besides that differs from the plan's is refused (the data would not follow the plan whose predicted U
    and effects they carry), as is a ramp plan (``--ramp``)."""
    from pathlib import Path

    if args.plan == "default" or Path(args.plan).suffix.lower() != ".json":
        return None
    from ..planning.plan import Plan
    from ..planning.ramp import load_plan

    plan = load_plan(args.plan)
    if not isinstance(plan, Plan):
        raise InputError(f"{args.plan}: a ramp plan; run it with --ramp {args.plan} (--plan takes a stepped plan "
                         "of 'triadcal plan' or a position CSV)")
    if args.ramp is not None:
        raise InputError(f"--ramp: the positions come from the ramp plan {args.ramp}; do not give --plan")
    setpoints = ",".join(f"{float(sp):g}" for sp in plan.setpoints_C)
    if args.setpoints is not None and float_list(args.setpoints) != [float(sp) for sp in plan.setpoints_C]:
        raise InputError(f"--setpoints {args.setpoints}: the plan {args.plan} visits {setpoints} degC; drop "
                         "--setpoints (or make another plan)")
    if args.tau_s is not None and args.tau_s != plan.tau_s:
        raise InputError(f"--tau-s {args.tau_s:g}: the plan {args.plan} says tau_s = {plan.tau_s:g} s; drop --tau-s")
    args.setpoints, args.tau_s = setpoints, float(plan.tau_s)
    return plan


def _run_voltmeter(args, out, plan, cfg, dmm_cfg, settings, extra=None) -> int:
    """``--instruments`` with ``[dmm]`` and no ``[imu]``: an analog unit, voltages from the meter(s),
    temperatures from the chamber's PV (hardware.voltmeter_capture.capture_voltmeter)."""
    from ..hardware.capture import CaptureError, open_bench
    from ..hardware.voltmeter_capture import capture_voltmeter
    from ..hardware.drivers.bench import BenchError
    from ..hardware.drivers.chamber import open_chamber
    from ..hardware.drivers.dmm import DmmError, open_voltmeter

    missing = [s for s in ("bench", "chamber") if not cfg[s].get("port")]
    if missing:
        raise InputError(f"{args.instruments}: no port given for: {', '.join(missing)}")
    time_scale = float(dmm_cfg.pop("time_scale", 1.0))
    settings.output_unit = "V"
    try:
        voltmeter = open_voltmeter(dmm_cfg)
    except DmmError as exc:
        raise InputError(str(exc)) from None
    try:
        bench = open_bench(cfg["bench"])
        try:
            c = dict(cfg["chamber"])
            if "driver" not in c:
                c.setdefault("baudrate", 19200)
            chamber = open_chamber(c)
        except BaseException:
            bench.close()
            raise
        profile = getattr(bench, "profile", None)
        if profile is not None:
            settings.bench_name = f"two-axis bench, {profile.name}"
        try:
            report = capture_voltmeter(args.out, plan=plan, setpoints_C=float_list(args.setpoints),
                                       voltmeter=voltmeter, bench=bench, chamber=chamber, settings=settings,
                                       time_scale=time_scale, progress=_progress_bar(out),
                                       extra_metadata=extra or None)
        except (CaptureError, BenchError, DmmError) as exc:
            raise InputError(str(exc)) from None
        finally:
            bench.close()
            chamber.close()
    finally:
        voltmeter.close()
    r = report
    out.say(f"wrote {r.csv_path}: {r.visits_done} of {r.visits_total} visits done, "
            f"{r.visits_done - r.visits_done_before} of them in this session (session {r.session}), "
            f"in {r.wall_seconds:.1f} s")
    out.say(f"the voltmeter: {r.accepted_samples} readings in this session, {r.redone_visits} visits redone; "
            "temperatures are the chamber's PV")
    return 0


def _print_report_warnings(out_dir) -> None:
    """The warnings of the session's report (``capture_report.json``, written when the session ended,
    failed or not) on stderr."""
    import json
    from pathlib import Path

    from ..hardware.capture import REPORT_NAME

    try:
        warnings = json.loads((Path(out_dir) / REPORT_NAME).read_text(encoding="utf-8")).get("warnings") or []
    except (OSError, ValueError, AttributeError):
        return
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
