"""The three instruments on pseudo-terminals, driven by the model's physics.

:func:`emulate` / :class:`Emulator` (behind ``triadcal emulate``) play the IMU, bench and
chamber on ptys with stable symlinks and a ``ports.toml``; :class:`UnitPhysics` gives the
outputs from ``Model.predict``, :class:`EmulatorTiming` the clock, :class:`FaultPlan` the
injected faults. Derivation/design: docs/hardware.md (Emulator). Over 500 lines because the
three instruments share one clock, one physics and one fault plan; the physics itself is
models/ (Model.predict, the hysteresis branch map).
"""

from __future__ import annotations

import math
import os
import pty
import select
import threading
import time
import tty
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..models.simulate import NoiseModel, Truth, preset_truth
from .drivers.chamber import REG_PV, REG_SP, REG_STATUS
from .protocols import Frame, get_protocol
from .protocols.binary import crc16_modbus
from .emulator_physics import EmulatorTiming, UnitPhysics  # noqa: F401 (importable from here)
from .emulator_faults import FaultPlan  # noqa: F401 (importable from here)
from .emulated_instruments import Emulated34465A, TemplateBenchServer, _toml_str  # noqa: F401 (importable from here)

#: bytes the emulator's garbage never contains, so that every damaged frame is counted
#: exactly once (the parsers cope with any bytes; this keeps the tests' accounting exact)
_SYNC_BYTES = {"nmea": set(b"$\r\n*"), "binary": {0xA5}, "vectornav": set(b"$\r\n*"), "xsens": {0xFA},
               "mip": {0x75}}
#: "silent": a vendor IMU whose output is off (not yet configured, or in config mode)
FATES = ("sent", "flipped", "dropped", "unattached", "disconnected", "overrun", "truncated", "silent")


class _Pty:
    """A pseudo-terminal with a stable symlink to its slave; the emulator holds the master."""

    def __init__(self, link: Path):
        self.link = link
        self.master = -1
        self.open()

    def open(self) -> None:
        m, s = pty.openpty()
        tty.setraw(s)                       # no echo, no line editing, before anyone opens it
        name = os.ttyname(s)
        os.close(s)
        os.set_blocking(m, False)
        tmp = self.link.with_name(self.link.name + ".new")
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        os.symlink(name, tmp)
        os.replace(tmp, self.link)
        self.master = m
        self.name = name
        self._poll = select.poll()
        self._poll.register(m, select.POLLIN | select.POLLHUP)

    def close(self) -> None:
        """Hang up: the symlink first, then the master. A closed pty's number is free for the next
        pty anyone opens; a driver reconnecting through a link still naming it opened another test's
        pseudo-terminal (CI, 2026-12-01: a VectorNav driver's $VNWRG in a Modbus chamber test's line on
        the other xdist worker). Without the link a reconnect fails until :meth:`open` makes a new one."""
        if self.master >= 0:
            try:
                if os.readlink(self.link) == self.name:
                    self.link.unlink()
            except OSError:
                pass
            os.close(self.master)
            self.master = -1

    def attached(self) -> bool:
        """True while a reader holds the slave open (the master reports no hang-up)."""
        if self.master < 0:
            return False
        ev = self._poll.poll(0)
        return not any(e & select.POLLHUP for _, e in ev)

    def wait_readable(self, timeout_s: float) -> bool:
        ev = self._poll.poll(timeout_s * 1000)
        if any(e & select.POLLHUP for _, e in ev):
            time.sleep(timeout_s)
            return False
        return bool(ev)


class Emulator:
    """IMU readout, SCPI bench and Modbus chamber on pseudo-terminals under ``directory``.

    Use as a context manager or call :meth:`start` / :meth:`stop`. ``ports`` maps
    'imu', 'bench', 'chamber' to the symlinks; :meth:`now_s` is the instrument clock.
    ``bench_profile`` (a profile name or path, or a ``BenchProfile``) plays the bench by that
    command-template profile (:class:`TemplateBenchServer`) instead of the SCPI-style one.
    """

    def __init__(self, directory, truth: Optional[Truth] = None, protocol: str = "nmea",
                 timing: Optional[EmulatorTiming] = None, faults: Optional[FaultPlan] = None,
                 seed: int = 0, keep_log: bool = False, chamber_slave: int = 1, bench_profile=None,
                 dmm: bool = False, dmm_mains_hz: float = 50.0):
        # absolute: the ports.toml it writes is read from anywhere (an outside probe's `emulate EMU` wrote
        # port = "EMU/imu", and `capture --config /abs/EMU/ports.toml` run elsewhere could not open it)
        self.directory = Path(os.path.abspath(directory))
        self.directory.mkdir(parents=True, exist_ok=True)
        self.truth = truth or preset_truth()
        self.protocol = protocol
        self.codec = get_protocol(protocol)
        # a vendor IMU answers configuration commands and may have its output off
        # (protocols/<name>.py, class Emulated); the generic formats just stream
        self.imu_device = (self.codec.Emulated(rate_hz=(timing or EmulatorTiming()).rate_hz)
                           if hasattr(self.codec, "Emulated") else None)
        self.timing = timing or EmulatorTiming()
        self.faults = faults or FaultPlan()
        self.physics = UnitPhysics(self.truth, self.timing, seed)
        self.physics.creep_deg_s = float(self.faults.bench_creep_deg_s)
        self.bench_moves = 0                      # POS commands to a new target (the faults count them)
        self._last_target: Optional[tuple] = None
        self._stuck_target: Optional[tuple] = None
        self.chamber_dead = False
        self.rng = np.random.default_rng(seed + 1)
        self.bench_seed = seed + 2
        self.keep_log = keep_log
        self.chamber_slave = chamber_slave
        # a bench by command template (drivers/bench_template.py): the same profile the driver
        # loads; None: the SCPI-style bench
        self.bench_profile_ref = None if bench_profile is None else str(bench_profile)
        self.bench_server = None
        if bench_profile is not None:
            from .drivers.bench_template import BenchProfile, load_profile

            prof = bench_profile if isinstance(bench_profile, BenchProfile) else load_profile(bench_profile)
            if isinstance(bench_profile, BenchProfile):
                self.bench_profile_ref = prof.source
            self.bench_server = TemplateBenchServer(prof, self.physics, self.now_s)
        self.log: list[tuple[int, str, Frame]] = []
        self.fates = {f: 0 for f in FATES}
        self.garbage_bytes_sent = 0
        self.bench_ignored = 0
        self.modbus_requests = 0
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._mono0 = None
        self.ports = {k: str(self.directory / k) for k in ("imu", "bench", "chamber")}
        # an analog unit read by one emulated 34465A per axis (Emulated34465A) instead of an IMU
        self.dmm = bool(dmm)
        self.dmm_mains_hz = float(dmm_mains_hz)
        self.dmm_meters: dict = {}
        if self.dmm:
            for i, a in enumerate("xyz"):
                self.ports[f"dmm_{a}"] = str(self.directory / f"dmm_{a}")
                self.dmm_meters[a] = Emulated34465A(a, i, self.physics, self.now_s, self.timing.time_scale,
                                                    mains_hz=self.dmm_mains_hz, seed=seed + 10 + i)

    # -- clock -------------------------------------------------------------------------
    def now_s(self) -> float:
        """Instrument time, s since start."""
        return (time.monotonic() - self._mono0) * self.timing.time_scale

    def wall_s(self, instrument_s: float) -> float:
        return instrument_s / self.timing.time_scale

    # -- lifecycle ---------------------------------------------------------------------
    def start(self) -> "Emulator":
        self._ptys = {k: _Pty(Path(v)) for k, v in self.ports.items()}
        self._mono0 = time.monotonic()
        if self.dmm:
            self.write_instruments()       # the voltmeters' resources name the ptys' /dev/pts/N
        runners = [("bench", self._run_bench), ("chamber", self._run_chamber)]
        if self.dmm:     # the analog unit: voltmeters, no IMU stream
            runners += [(f"dmm_{a}", (lambda a=a: self._run_dmm(a))) for a in self.dmm_meters]
        else:
            runners.insert(0, ("imu", self._run_imu))
        for name, target in runners:
            th = threading.Thread(target=target, daemon=True, name=f"emulator-{name}")
            th.start()
            self._threads.append(th)
        return self

    def stop(self) -> None:
        self._stop.set()
        for th in self._threads:
            th.join(timeout=2.0)
        for p in self._ptys.values():
            p.close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def write_config(self, path=None) -> Path:
        """A capture config file (TOML) naming the emulator's ports."""
        from ..io.atomic import atomic_write_text

        path = Path(path) if path else self.directory / "ports.toml"
        self.write_instruments()          # first: a reader waits for ports.toml, then may read both
        atomic_write_text(
            path,
            f'# written by triadcal emulate\n[imu]\nport = {_toml_str(self.ports["imu"])}\nprotocol = "{self.protocol}"\n'
            + (f'rate_hz = {self.timing.rate_hz:g}\n' if self.imu_device is not None else '') + '\n'
            f'[bench]\nport = {_toml_str(self.ports["bench"])}\n' + self._bench_driver_lines() + '\n'
            f'[chamber]\nport = {_toml_str(self.ports["chamber"])}\nslave = {self.chamber_slave}\n')
        return path

    def _bench_driver_lines(self) -> str:
        if self.bench_server is None:
            return ""
        return f'driver = "template"\nprofile = {_toml_str(self.bench_profile_ref)}\n'

    def write_instruments(self, path=None) -> Path:
        """An instruments file (``triadcal capture --instruments``) naming the emulator's ports:
        the IMU's protocol as its driver, the bench (``template`` with the profile, or ``scpi``)
        and the chamber (triadcal's own Modbus map, ``modbus``)."""
        from ..io.atomic import atomic_write_text

        path = Path(path) if path else self.directory / "instruments.toml"
        if self.dmm:
            # pyvisa-py opens a serial line as ASRL<device path>::INSTR; the pty's own /dev/pts/N
            res = ", ".join(f'{a} = {_toml_str("ASRL" + os.path.realpath(self.ports[f"dmm_{a}"]) + "::INSTR")}'
                            for a in self.dmm_meters)
            imu = (f'[dmm]\ndriver = "scpi"\nmodel = "34465A"\nresources = {{ {res} }}\nrange_V = 10\n'
                   f'nplc = 10\nmains_hz = {self.dmm_mains_hz:g}\n'
                   f'time_scale = {self.timing.time_scale:g}   # the emulator\'s compressed clock; 1 for a real meter\n')
        else:
            imu = None
        imu = imu or (f'[imu]\ndriver = "{self.protocol}"\nport = {_toml_str(self.ports["imu"])}\n'
               f'rate_hz = {self.timing.rate_hz:g}\n')
        bench = (f'[bench]\ndriver = "template"\nprofile = {_toml_str(self.bench_profile_ref)}\n'
                 if self.bench_server is not None else '[bench]\ndriver = "scpi"\n')
        bench += f'port = {_toml_str(self.ports["bench"])}\n'
        chamber = (f'[chamber]\ndriver = "modbus"\nport = {_toml_str(self.ports["chamber"])}\n'
                   f'address = {self.chamber_slave}\n')
        atomic_write_text(path, "# written by triadcal emulate (triadcal capture --instruments)\n"
                          + imu + "\n" + bench + "\n" + chamber)
        return path

    def summary(self) -> dict:
        return {"fates": dict(self.fates), "garbage_bytes_sent": self.garbage_bytes_sent,
                "bench_commands_ignored": self.bench_ignored, "modbus_requests": self.modbus_requests,
                "instrument_time_s": self.now_s()}

    # -- IMU stream ----------------------------------------------------------------------
    def _in_window(self, windows, t):
        return any(a <= t < a + d for a, d in windows)

    def _run_imu(self) -> None:
        port = self._ptys["imu"]
        f = self.timing.rate_hz
        dev = self.imu_device
        encode = dev.encode if dev is not None else self.codec.encode
        quantise = dev.quantise if dev is not None else self.codec.quantise
        k_next = 0                # index of the next frame time k / f
        seq = 0
        attached_at = None        # wall time the reader was seen attached
        state = "up"              # up / draining / down
        state_until = 0.0
        done_disconnects = set()
        forbidden = _SYNC_BYTES[self.protocol]
        fl = self.faults
        tick = 0.005
        while not self._stop.is_set():
            time.sleep(tick)
            now_i = self.now_s()
            wall = time.monotonic()
            # disconnect / reconnect of the line
            if state == "up":
                for i, (a, d) in enumerate(fl.disconnects):
                    if i not in done_disconnects and now_i >= a:
                        done_disconnects.add(i)
                        state, state_until = "draining", wall + 0.1   # let the reader drain the line
                        reconnect_at = a + d
            elif state == "draining" and wall >= state_until:
                port.close()
                state = "down"
            elif state == "down" and now_i >= reconnect_at:
                port.open()
                state, attached_at = "up", None
            if dev is not None:
                self._imu_commands(port, state)
                if dev.rate_hz != f:           # output rate changed by a command
                    f = dev.rate_hz
                    k_next = int(math.floor(now_i * f)) + 1
            k_end = int(math.floor(now_i * f)) + 1
            if k_end <= k_next:
                continue
            times = np.arange(k_next, k_end) / f
            k_next = k_end
            stalled = np.array([self._in_window(fl.stalls, t) for t in times]) if fl.stalls else None
            if stalled is not None:
                times = times[~stalled]
            if not len(times):
                continue
            w, temps = self.physics.sample(times, f)
            if state == "up" and port.attached():
                if attached_at is None:
                    attached_at = wall
                can_write = wall - attached_at >= 0.05
            else:
                attached_at = None
                can_write = False
            chunks, fates, frames = [], [], []
            for j in range(len(times)):
                fr = Frame(seq, float(times[j]), tuple(w[j].tolist()), tuple(temps[j].tolist()))
                seq += 1
                if can_write and dev is not None and not dev.streaming:
                    fates.append("silent")
                    chunks.append(b"")
                    frames.append(fr)
                    continue
                if not can_write:
                    fates.append("unattached" if state == "up" else "disconnected")
                    chunks.append(b"")
                    frames.append(fr)
                    continue
                if fl.drop_prob and self.rng.random() < fl.drop_prob:
                    fates.append("dropped")
                    chunks.append(b"")
                    frames.append(fr)
                    continue
                data = encode(fr)
                fate = "sent"
                if fl.bitflip_prob and self.rng.random() < fl.bitflip_prob:
                    data = self._flip(data, forbidden)
                    fate = "flipped"
                if fl.garbage_prob and self.rng.random() < fl.garbage_prob:
                    g = bytes(b for b in self.rng.integers(0, 256, int(self.rng.integers(1, 17))).tolist()
                              if b not in forbidden)
                    self.garbage_bytes_sent += len(g)
                    data = g + data
                chunks.append(data)
                fates.append(fate)
                frames.append(fr)
            blob = b"".join(chunks)
            written = 0
            if blob:
                try:
                    written = os.write(port.master, blob)
                except (BlockingIOError, OSError):
                    written = 0
            pos = 0
            for data, fate, fr in zip(chunks, fates, frames):
                if data:
                    if pos + len(data) <= written:
                        pass
                    elif pos < written:
                        fate = "truncated"
                    else:
                        fate = "overrun"
                    pos += len(data)
                self.fates[fate] += 1
                if self.keep_log:
                    self.log.append((fr.seq, fate, quantise(fr)))

    def _imu_commands(self, port, state) -> None:
        """Commands to a vendor IMU (configuration) read from the line and answered."""
        if state != "up" or port.master < 0:
            return
        try:
            data = os.read(port.master, 4096)
        except (BlockingIOError, OSError):
            return
        if data:
            reply = self.imu_device.feed(data)
            if reply:
                try:
                    os.write(port.master, reply)
                except OSError:
                    pass

    def _flip(self, data: bytes, forbidden) -> bytes:
        """One bit flipped inside the frame (past its sync word), never creating a sync byte."""
        b = bytearray(data)
        text = self.protocol in ("nmea", "vectornav")
        lo = 1 if text else 2
        hi = len(b) - (2 if text else 0)
        while True:
            i = int(self.rng.integers(lo, hi))
            v = b[i] ^ (1 << int(self.rng.integers(0, 8)))
            if v not in forbidden:
                b[i] = v
                return bytes(b)

    # -- bench (SCPI-style text) -----------------------------------------------------
    def _run_bench(self) -> None:
        port = self._ptys["bench"]
        buf = b""
        n_lines = 0
        rng = np.random.default_rng(self.bench_seed)     # the bench thread's own stream
        ignore = set(self.faults.bench_ignore_lines)
        server = self.bench_server
        term_in = server.profile.write_terminator.encode("ascii") if server else b"\n"
        term_out = server.profile.read_terminator if server else "\n"
        while not self._stop.is_set():
            if not port.wait_readable(0.02):
                continue
            try:
                buf += os.read(port.master, 4096)
            except (BlockingIOError, OSError):
                continue
            while term_in in buf:
                line, buf = buf.split(term_in, 1)
                n_lines += 1
                if n_lines in ignore or (self.faults.bench_ignore_prob and
                                         rng.random() < self.faults.bench_ignore_prob):
                    self.bench_ignored += 1
                    continue
                text = line.decode("ascii", "replace").strip()
                reply = server.answer(text) if server else self._bench_command(text)
                if reply is not None:
                    try:
                        os.write(port.master, (reply + term_out).encode("ascii"))
                    except OSError:
                        pass

    def _bench_command(self, cmd: str) -> Optional[str]:
        t = self.now_s()
        head, _, arg = cmd.partition(" ")
        head = head.upper()
        if head == "*IDN?":
            return "TRIADCAL,EMU-BENCH,0,1.0"
        if head == "POS":
            try:
                a1, a2 = (float(v) for v in arg.split(","))
            except ValueError:
                self._bench_error = '-102,"Syntax error"'
                return None
            if (a1, a2) != self._last_target:     # a visit redone at its position is no new move: the
                self.bench_moves += 1             # faults counted on moves do not shift with the redos
                self._last_target = (a1, a2)      # a loaded machine makes (an incomplete window)
            f = self.faults
            if f.chamber_dies_after_moves and self.bench_moves > f.chamber_dies_after_moves and not self.chamber_dead:
                self.chamber_dead = True          # no answer from now on, the heater off
                self.physics.set_setpoint(t, self.timing.start_C)
            if f.bench_stuck_after_moves and self.bench_moves > f.bench_stuck_after_moves:
                self._stuck_target = (a1, a2)     # does not move; reports the target, in position
                return None
            self.physics.move(t, a1, a2)
            return None
        # a creeping bench reports its target exactly when first asked in position, then creeps
        pos, target, ready = self.physics.bench_state(t, start_creep=head == "POS?")
        if self._stuck_target is not None:
            pos = target = self._stuck_target
            ready = True
        if (head == "STAT?" and self.faults.bench_stat_error_after_moves
                and self.bench_moves > self.faults.bench_stat_error_after_moves):
            return '-113,"Undefined header"'
        if head == "POS?":
            return f"{pos[0]:.6f},{pos[1]:.6f}"
        if head == "POS:TARG?":
            return f"{target[0]:.6f},{target[1]:.6f}"
        if head == "STAT?":
            return "1" if ready else "0"
        if head == "SYST:ERR?":
            err, self._bench_error = getattr(self, "_bench_error", None) or '0,"No error"', None
            return err
        self._bench_error = '-113,"Undefined header"'
        return None

    # -- voltmeters (34465A SCPI, one per axis) ---------------------------------------
    def _run_dmm(self, axis: str) -> None:
        port = self._ptys[f"dmm_{axis}"]
        meter = self.dmm_meters[axis]
        buf = b""
        while not self._stop.is_set():
            if not port.wait_readable(0.02):
                continue
            try:
                buf += os.read(port.master, 4096)
            except (BlockingIOError, OSError):
                continue
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                reply = meter.answer(line.decode("ascii", "replace").strip(), self._stop)
                if reply is not None:
                    try:
                        os.write(port.master, (reply + "\n").encode("ascii"))
                    except OSError:
                        pass

    # -- chamber (Modbus RTU slave) ----------------------------------------------------
    def _run_chamber(self) -> None:
        port = self._ptys["chamber"]
        buf = b""
        while not self._stop.is_set():
            if not port.wait_readable(0.01):
                buf = b""          # 3.5 character times of silence end a Modbus frame
                continue
            try:
                buf += os.read(port.master, 4096)
            except (BlockingIOError, OSError):
                continue
            req = self._modbus_frame(buf)
            if req is None:
                continue
            buf = b""
            reply = self._modbus_reply(req)
            if reply is not None:
                try:
                    os.write(port.master, reply + crc16_modbus(reply).to_bytes(2, "little"))
                except OSError:
                    pass

    @staticmethod
    def _modbus_frame(buf: bytes) -> Optional[bytes]:
        if len(buf) < 8:
            return None
        fc = buf[1]
        n = 9 + buf[6] if fc == 16 and len(buf) >= 7 else 8
        if len(buf) < n:
            return None
        frame = buf[:n]
        if crc16_modbus(frame[:-2]) != int.from_bytes(frame[-2:], "little"):
            return b""
        return frame[:-2]

    def _modbus_reply(self, req: bytes) -> Optional[bytes]:
        if not req or req[0] != self.chamber_slave or self.chamber_dead:
            return None                       # damaged, or for another slave: stay silent
        self.modbus_requests += 1
        fc = req[1]
        addr = int.from_bytes(req[2:4], "big")
        t = self.now_s()

        def to_reg(v):
            return int(round(v * 10)) & 0xFFFF

        if fc in (3, 4):
            count = int.from_bytes(req[4:6], "big")
            regs = []
            for a in range(addr, addr + count):
                if a == REG_PV:
                    regs.append(to_reg(self.physics.chamber_C(t)))
                elif a == REG_SP:
                    regs.append(to_reg(self.physics.setpoint_C))
                elif a == REG_STATUS:
                    regs.append(1)
                else:
                    return bytes((req[0], fc | 0x80, 2))
            return bytes((req[0], fc, 2 * count)) + b"".join(r.to_bytes(2, "big") for r in regs)
        if fc in (6, 16):
            if addr != REG_SP:
                return bytes((req[0], fc | 0x80, 2))
            raw = req[4:6] if fc == 6 else req[7:9]
            value = int.from_bytes(raw, "big", signed=True) / 10.0
            self.physics.set_setpoint(t, value)
            return req[:6]
        return bytes((req[0], fc | 0x80, 1))


def emulate(directory, *, preset: str = "ak18-quartz", effects: Optional[Sequence[str]] = None,
            Q_V2s: float = 3e-9, sigma_position_arcsec: float = 0.0, sigma_wobble_arcsec: float = 0.0,
            unit: str = "SN-EMU-0001", protocol: str = "nmea", timing: Optional[EmulatorTiming] = None,
            faults: Optional[FaultPlan] = None, seed: int = 0, keep_log: bool = False,
            bench_profile=None, dmm: bool = False) -> Emulator:
    """An :class:`Emulator` of a preset unit (``triadcal emulate``), not yet started; its
    truth is saved as ``truth.json``, the capture config as ``ports.toml`` and the instruments
    file as ``instruments.toml`` in ``directory``. ``bench_profile`` (a shipped profile's name
    such as ``"esp301"`` or a TOML path) plays the bench by that command-template profile
    instead of the SCPI-style one. ``dmm``: an analog unit read by one emulated 34465A per
    axis (:class:`Emulated34465A`) in place of the IMU; ``instruments.toml`` then has ``[dmm]``
    and is rewritten by :meth:`Emulator.start` with the ptys' device paths."""
    from ..models.effects import DEFAULT_EFFECTS

    noise = NoiseModel(Q_V2s=Q_V2s, sigma_position_arcsec=sigma_position_arcsec,
                       sigma_wobble_arcsec=sigma_wobble_arcsec,
                       sample_rate_hz=(timing or EmulatorTiming()).rate_hz)
    truth = preset_truth(preset, DEFAULT_EFFECTS if effects is None else effects, noise=noise, unit=unit)
    em = Emulator(directory, truth=truth, protocol=protocol, timing=timing, faults=faults, seed=seed,
                  keep_log=keep_log, bench_profile=bench_profile, dmm=dmm)
    truth.save(em.directory / "truth.json")
    em.write_config()
    return em
