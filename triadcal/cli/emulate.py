"""``triadcal emulate``: the IMU, bench and chamber on pseudo-terminals, until Ctrl-C."""

from __future__ import annotations

from ..errors import InputError

import sys
import time

from ..models.effects import DEFAULT_EFFECTS
from ..models.simulate import PRESETS
from ._common import add_output_options, name_list, output

#: the IMU wire protocols (triadcal.hardware.protocols.PROTOCOLS)
IMU_PROTOCOLS = ("nmea", "binary", "vectornav", "xsens", "mip")


def _windows(items):
    out = []
    for item in items or ():
        try:
            at, dur = (float(v) for v in item.split(":"))
        except ValueError:
            raise InputError(f"expected AT_S:FOR_S, got {item!r}") from None
        out.append((at, dur))
    return tuple(out)


def add_emulator_options(p, prefix: str = "") -> None:
    """Options shared with ``triadcal capture --emulate`` (``prefix`` 'emulate-' there)."""
    p.add_argument(f"--{prefix}preset", default="ak18-quartz", choices=sorted(PRESETS),
                   help="emulated unit (default ak18-quartz)")
    p.add_argument(f"--{prefix}effects", default=",".join(DEFAULT_EFFECTS),
                   help="effects present in the emulated unit ('none' for eq. 1 only)")
    p.add_argument(f"--{prefix}protocol", default="nmea", choices=IMU_PROTOCOLS,
                   help="IMU wire protocol (default nmea; vectornav, xsens, mip: the vendors' documented ones)")
    p.add_argument(f"--{prefix}bench-profile", default=None, metavar="PROFILE",
                   help="play the bench by a command-template profile (a TOML file or a shipped name: esp301) "
                        "instead of the SCPI-style bench")
    p.add_argument("--time-scale", type=float, default=60.0,
                   help="instrument seconds per wall second (default 60)")
    p.add_argument(f"--{prefix}rate-hz", type=float, default=10.0,
                   help="IMU samples per instrument second (default 10)")
    p.add_argument(f"--{prefix}Q", type=float, default=3e-9, help="white-noise intensity, V^2 s (default 3e-9)")
    p.add_argument(f"--{prefix}chamber-tau-s", type=float, default=600.0,
                   help="time constant of the chamber, s (default 600)")
    p.add_argument(f"--{prefix}unit-tau-s", type=float, default=1200.0,
                   help="time constant of the unit behind the chamber, s (default 1200)")
    p.add_argument(f"--{prefix}self-heating-tau-s", type=float, default=300.0,
                   help="time constant of the self-heating after power-on, s (default 300)")
    p.add_argument(f"--{prefix}faults", default="none", choices=("none", "all"),
                   help="'all': garbage bytes, flipped bits, dropped frames, a disconnect, a stall, "
                        "ignored bench commands")
    p.add_argument(f"--{prefix}disconnect", action="append", metavar="AT_S:FOR_S",
                   help="disconnect the IMU line at AT_S for FOR_S instrument seconds (repeatable)")
    p.add_argument(f"--{prefix}stall", action="append", metavar="AT_S:FOR_S",
                   help="stall the IMU at AT_S for FOR_S instrument seconds (repeatable)")
    p.add_argument(f"--{prefix}seed", type=int, default=0)


def build_emulator(args, directory, prefix: str = ""):
    from ..hardware.emulator import EmulatorTiming, FaultPlan, emulate

    g = lambda name: getattr(args, (prefix + name).replace("-", "_"))  # noqa: E731
    timing = EmulatorTiming(time_scale=args.time_scale, rate_hz=g("rate_hz"),
                            chamber_time_constant_s=g("chamber_tau_s"), unit_time_constant_s=g("unit_tau_s"),
                            self_heating_time_constant_s=g("self_heating_tau_s"))
    faults = FaultPlan.all_faults() if g("faults") == "all" else FaultPlan()
    if g("disconnect"):
        faults.disconnects = tuple(faults.disconnects) + _windows(g("disconnect"))
    if g("stall"):
        faults.stalls = tuple(faults.stalls) + _windows(g("stall"))
    return emulate(directory, preset=g("preset"), effects=name_list(g("effects")), Q_V2s=g("Q"),
                   protocol=g("protocol"), timing=timing, faults=faults, seed=g("seed"),
                   bench_profile=g("bench_profile"), dmm=bool(getattr(args, "dmm", False)))


def register(sub) -> None:
    p = sub.add_parser(
        "emulate", help="run the IMU, bench and chamber emulator on pseudo-terminals",
        description="Play the IMU readout, the two-axis bench (SCPI) and the thermal chamber (Modbus RTU) "
                    "on pseudo-terminals, with the model's physics on a compressed clock. Writes ports.toml "
                    "(a capture config) and truth.json in DIR. Runs until Ctrl-C or --duration.")
    p.add_argument("dir", help="directory for the port symlinks, ports.toml and truth.json")
    p.add_argument("--duration", type=float, default=None, help="stop after this many wall seconds")
    p.add_argument("--dmm", action="store_true",
                   help="an analog unit: one emulated Keysight 34465A per axis (SCPI on ptys dmm_x, dmm_y, dmm_z) "
                        "instead of the IMU; instruments.toml then has [dmm] with the ASRL/dev/pts/N::INSTR "
                        "resources for pyvisa-py")
    add_emulator_options(p)
    add_output_options(p)
    p.set_defaults(func=run)


def fates_text(fates: dict) -> str:
    """The emulator's frame counts in words: '1200 sent, 3 with a flipped bit, 2 dropped'."""
    words = {"sent": "sent", "flipped": "with a flipped bit", "dropped": "dropped",
             "unattached": "sent with no reader attached", "disconnected": "lost to a disconnection",
             "overrun": "overrun", "truncated": "truncated"}
    parts = [f"{n} {words.get(k, k)}" for k, n in fates.items() if n or k == "sent"]
    return ", ".join(parts) or "none"


def _summary_text(s: dict) -> str:
    return (f"{s['instrument_time_s']:.0f} instrument seconds emulated; frames: {fates_text(s['fates'])}; "
            f"{s['garbage_bytes_sent']} garbage bytes sent, {s['bench_commands_ignored']} bench commands ignored, "
            f"{s['modbus_requests']} Modbus requests received")


def run(args) -> int:
    out = output(args)
    em = build_emulator(args, args.dir)
    em.start()
    bench_kind = f"bench, profile {em.bench_profile_ref}" if em.bench_server is not None else "bench, SCPI"
    unit_kind = (f"{', '.join(em.ports[f'dmm_{a}'] for a in 'xyz')} (34465A voltmeters, SCPI)" if em.dmm
                 else f"{em.ports['imu']} (IMU, {em.protocol})")
    out.say(f"emulating on {unit_kind}, {em.ports['bench']} ({bench_kind}), "
          f"{em.ports['chamber']} (chamber, Modbus RTU slave 1); clock x{em.timing.time_scale:g}")
    out.say(f"the capture config is {em.directory / 'ports.toml'} (or --instruments "
            f"{em.directory / 'instruments.toml'}) and the truth {em.directory / 'truth.json'}")
    sys.stdout.flush()
    t0 = time.monotonic()
    try:
        while args.duration is None or time.monotonic() - t0 < args.duration:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        em.stop()
    out.say(f"stopped: {_summary_text(em.summary())}")
    return 0
