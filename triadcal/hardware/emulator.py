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
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..models.effects.hysteresis import BRANCH, direction_after
from ..models.model import Covariates
from ..models.simulate import NoiseModel, Schedule, Truth, preset_truth
from ..models.thermal_environment import sensor_temperatures, two_lag_step
from ..models.units import ARCSEC, STANDARD_GRAVITY_M_S2
from .drivers.chamber import REG_PV, REG_SP, REG_STATUS
from .protocols import Frame, get_protocol
from .protocols.binary import crc16_modbus

#: bytes the emulator's garbage never contains, so that every damaged frame is counted
#: exactly once (the parsers cope with any bytes; this keeps the tests' accounting exact)
_SYNC_BYTES = {"nmea": set(b"$\r\n*"), "binary": {0xA5}, "vectornav": set(b"$\r\n*"), "xsens": {0xFA},
               "mip": {0x75}}
#: "silent": a vendor IMU whose output is off (not yet configured, or in config mode)
FATES = ("sent", "flipped", "dropped", "unattached", "disconnected", "overrun", "truncated", "silent")


@dataclass
class FaultPlan:
    """Faults to inject into the IMU stream; times in instrument seconds.

    Per frame: ``garbage_prob`` a burst of 1-16 random bytes before it, ``bitflip_prob`` one
    bit flipped inside it (a bad checksum), ``drop_prob`` not sent at all (its sequence
    number is used, so the receiver sees a gap). ``disconnects``: ``(at_s, for_s)`` pairs,
    the IMU line goes away and comes back on a new pty behind the same name.
    ``stalls``: ``(at_s, for_s)`` pairs, the IMU sends nothing (and uses no sequence numbers).
    ``bench_ignore_prob``: the bench drops a command line without a word (drawn from the
    bench's own random stream, so the IMU thread's draws do not change which lines);
    ``bench_ignore_lines``: 1-based numbers of the command lines the bench drops, always (a
    deterministic fault for tests).
    """

    garbage_prob: float = 0.0
    bitflip_prob: float = 0.0
    drop_prob: float = 0.0
    disconnects: Sequence[tuple] = ()
    stalls: Sequence[tuple] = ()
    bench_ignore_prob: float = 0.0
    bench_ignore_lines: Sequence[int] = ()

    @classmethod
    def all_faults(cls, start_s: float = 60.0) -> "FaultPlan":
        """A bit of everything, for demonstrations and tests."""
        return cls(garbage_prob=0.01, bitflip_prob=0.01, drop_prob=0.01,
                   disconnects=((start_s, 60.0),), stalls=((start_s + 240.0, 120.0),),
                   bench_ignore_prob=0.1)


@dataclass
class EmulatorTiming:
    """Timing of the emulated instruments, in instrument seconds (except ``time_scale``)."""

    time_scale: float = 60.0
    rate_hz: float = 10.0
    start_C: float = 20.0
    chamber_time_constant_s: float = 600.0
    unit_time_constant_s: float = 1200.0
    self_heating_C: tuple = (0.30, 0.35, 0.25)
    self_heating_time_constant_s: float = 300.0
    bench_rate_deg_s: float = 10.0
    bench_settle_s: float = 2.0

    @classmethod
    def from_schedule(cls, schedule: Schedule, **kw) -> "EmulatorTiming":
        """The simulator's thermal constants (same chamber and unit)."""
        return cls(start_C=schedule.start_C, chamber_time_constant_s=schedule.chamber_time_constant_s,
                   unit_time_constant_s=schedule.unit_time_constant_s,
                   self_heating_C=tuple(schedule.self_heating_C), **kw)


class UnitPhysics:
    """The unit on the bench in the chamber, as functions of instrument time (thread-safe)."""

    def __init__(self, truth: Truth, timing: EmulatorTiming, seed: int = 0, flicker_Bf_V: float = 0.0):
        """``flicker_Bf_V``: flicker (1/f, bias instability) output noise added in :meth:`sample`,
        given by its Allan-deviation floor B_f = 0.664 B (V; 0: white noise only)."""
        self.flicker_Bf_V = float(flicker_Bf_V)
        self._flicker: Optional[np.ndarray] = None
        if self.flicker_Bf_V > 0:
            # one periodic 1/f record (models/noise_processes.flicker_noise: it wraps without a jump)
            # of 2^20 samples at the timing's rate, indexed by instrument time in sample()
            from ..models.noise_processes import flicker_noise

            frng = np.random.default_rng([seed, 952])
            self._flicker = np.stack([flicker_noise(2 ** 20, timing.rate_hz, self.flicker_Bf_V ** 2, frng)
                                      for _ in range(3)], axis=1)
        self.truth = truth
        self.timing = timing
        self.model = truth.model()
        self.p = self.model.to_internal(truth.parameters)
        self.gravity_g = truth.local_g_m_s2 / STANDARD_GRAVITY_M_S2
        self.rng = np.random.default_rng(seed)
        self.lock = threading.Lock()
        T0 = timing.start_C
        # thermal segment: since t0, setpoint sp, chamber c0 and unit u0 at t0
        self._seg = (0.0, T0, T0, T0)
        # the recent segments, oldest first: a sample of a time before the last setpoint change
        # (the IMU thread computes its frames a tick after their times) takes the segment then in force
        self._segs: list = [self._seg]
        self.setpoint_C = T0
        self._last_sp: Optional[float] = None
        self.direction = "none"
        # from the first change of setpoint on, the hysteresis branch follows the unit's own
        # temperature (heating while it rises): see set_setpoint
        self._branch_follows_unit = False
        # bench: a move from (a0) at t0 to (a1) arriving at t_arrive, in position at t_ready
        self._move = (0.0, (0.0, 0.0), (0.0, 0.0), 0.0, 0.0)
        self._errors = self._draw_bench_errors()

    # -- thermal ----------------------------------------------------------------------
    def _thermal(self, t):
        """Chamber, unit (degC) and the unit's rate (degC/s) at instrument times ``t`` (increasing):
        the two first-order lags of models/thermal_environment, in closed form since the last
        setpoint, so a setpoint written every few seconds (a ramp program) is followed exactly.
        Once the branch follows the unit (:meth:`set_setpoint`), it is set here from the sign of
        the unit's rate at the latest of ``t`` (unchanged where the rate is 0)."""
        t = np.asarray(t, float)
        t0, sp, c0, u0 = self._seg
        if len(self._segs) > 1 and np.min(t, initial=t0) < t0:
            seg = np.array(self._segs)
            k = np.clip(np.searchsorted(seg[:, 0], t, side="right") - 1, 0, len(seg) - 1)
            t0, sp, c0, u0 = seg[k, 0], seg[k, 1], seg[k, 2], seg[k, 3]
        out = two_lag_step(t - t0, sp, c0, u0,
                           self.timing.chamber_time_constant_s, self.timing.unit_time_constant_s)
        if self._branch_follows_unit:
            rate = np.ravel(out[2])
            if len(rate) and rate[-1] != 0.0:
                self.direction = "heating" if rate[-1] > 0 else "cooling"
        return out

    def chamber_C(self, t: float) -> float:
        with self.lock:
            return float(self._thermal(t)[0])

    def set_setpoint(self, t: float, sp: float) -> None:
        """Command the chamber at instrument time ``t``. The hysteresis branch: ``none`` at the
        first setpoint (the unit has soaked at ambient, as :meth:`Schedule.directions`); at the
        first change, the direction of the change; from then on, the direction in which the unit's
        own temperature moves (heating while it rises, as :class:`RampSchedule` labels a visit),
        which on a stepped campaign is the direction of the last change once the unit has turned,
        and on a ramp program (a setpoint written every few seconds) trails the program's turns
        as the unit does."""
        with self.lock:
            c, u, _ = self._thermal(t)
            self._seg = (float(t), float(sp), float(c), float(u))
            self._segs = self._segs[-255:] + [self._seg]
            self.direction = direction_after(self.direction, self._last_sp, float(sp))
            if self._last_sp is not None and float(sp) != self._last_sp:
                self._branch_follows_unit = True
            self._last_sp = float(sp)
            self.setpoint_C = float(sp)

    # -- bench ------------------------------------------------------------------------
    def _draw_bench_errors(self):
        n = self.truth.noise
        return (self.rng.normal(0.0, n.sigma_position_arcsec * ARCSEC),
                self.rng.normal(0.0, n.sigma_position_arcsec * ARCSEC),
                self.rng.normal(0.0, n.sigma_wobble_arcsec * ARCSEC))

    def move(self, t: float, a1: float, a2: float) -> None:
        with self.lock:
            start = self._angles(t)
            start = (float(start[0]), float(start[1]))
            dist = max(abs(a1 - start[0]), abs(a2 - start[1]))
            arrive = t + dist / self.timing.bench_rate_deg_s
            self._move = (t, start, (float(a1), float(a2)), arrive, arrive + self.timing.bench_settle_s)
            self._errors = self._draw_bench_errors()

    def _angles(self, t):
        t0, a0, a1, arrive, _ = self._move
        frac = np.clip((np.asarray(t, float) - t0) / max(arrive - t0, 1e-12), 0.0, 1.0)
        return a0[0] + (a1[0] - a0[0]) * frac, a0[1] + (a1[1] - a0[1]) * frac

    def bench_state(self, t: float):
        """(present angles, target angles, in position) at instrument time ``t``."""
        with self.lock:
            a = self._angles(t)
            return (float(a[0]), float(a[1])), self._move[2], t >= self._move[4]

    # -- outputs ----------------------------------------------------------------------
    def sample(self, t: np.ndarray, rate_hz: Optional[float] = None):
        """Outputs (n, 3) in V and temperature readings (n, 3) in degC at times ``t``
        (white noise for samples at ``rate_hz``, by default the timing's rate)."""
        tm = self.timing
        t = np.asarray(t, float)
        n = len(t)
        with self.lock:
            _, unit, rate = self._thermal(t)
            a1, a2 = self._angles(t)
            e1, e2, wob = self._errors
            branch = BRANCH[self.direction]
        sensor = sensor_temperatures(unit, tm.self_heating_C, t, tm.self_heating_time_constant_s)
        cov = Covariates(axis1=np.radians(a1), axis2=np.radians(a2),
                         temp=tuple(sensor[:, i] for i in range(3)), temp_rate=(rate, rate, rate),
                         branch=np.full(n, branch), time_s=t, axis1_error=e1, axis2_error=e2, wobble=wob)
        w = np.stack(np.broadcast_arrays(*self.model.predict(self.p, cov, self.gravity_g)), axis=1)
        noise = self.truth.noise
        w = w + self.rng.normal(0.0, math.sqrt(noise.Q_V2s * (rate_hz or tm.rate_hz)), (n, 3))
        if self._flicker is not None:          # flicker: continuous across calls (indexed by time)
            k = np.floor(t * tm.rate_hz).astype(np.int64) % len(self._flicker)
            w = w + self._flicker[k]
        temps = sensor + self.rng.normal(0.0, noise.temp_noise_C, (n, 3))
        return w, temps


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
        self._poll = select.poll()
        self._poll.register(m, select.POLLIN | select.POLLHUP)

    def close(self) -> None:
        if self.master >= 0:
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
        self.directory = Path(directory)
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
            f'# written by triadcal emulate\n[imu]\nport = "{self.ports["imu"]}"\nprotocol = "{self.protocol}"\n'
            + (f'rate_hz = {self.timing.rate_hz:g}\n' if self.imu_device is not None else '') + '\n'
            f'[bench]\nport = "{self.ports["bench"]}"\n' + self._bench_driver_lines() + '\n'
            f'[chamber]\nport = "{self.ports["chamber"]}"\nslave = {self.chamber_slave}\n')
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
            self.physics.move(t, a1, a2)
            return None
        pos, target, ready = self.physics.bench_state(t)
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
        if not req or req[0] != self.chamber_slave:
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


class Emulated34465A:
    """A Keysight 34465A on one output of the emulated analog unit: the SCPI dialogue of
    drivers/dmm.py (``*IDN?``, ``*CLS``, ``CONF:VOLT:DC <range>``, ``VOLT:DC:NPLC <n>``,
    ``SYST:ERR?``, ``SAMP:COUN <n>``, ``READ?``; LF-terminated). Anything else puts
    ``-113,"Undefined header"`` in the error queue; a bad value ``-222,"Data out of range"``.

    ``READ?`` integrates ``n`` readings of ``nplc / mains_hz`` instrument seconds each from the
    moment it arrives, answers after that time (on the emulator's clock) and gives the unit's
    output (``Model.predict`` through :class:`UnitPhysics`, as the IMU outputs) plus white noise
    of the integration time (variance ``Q / (nplc / mains_hz)``); ``+9.9E+37`` beyond the range.
    ``windows`` keeps, per ``READ?``, (t0, t1, noiseless mean of the readings, mean of the
    readings): the truth a test compares a visit with."""

    NPLC = (0.02, 0.06, 0.2, 1.0, 10.0, 100.0)
    RANGES = (0.1, 1.0, 10.0, 100.0, 1000.0)

    def __init__(self, axis: str, index: int, physics: "UnitPhysics", now, time_scale: float,
                 mains_hz: float = 50.0, seed: int = 0):
        self.axis, self.index, self.physics, self.now = axis, index, physics, now
        self.time_scale, self.mains_hz = float(time_scale), float(mains_hz)
        self.rng = np.random.default_rng(seed)
        self.idn = f"Keysight Technologies,34465A,EMU000{index + 1},A.03.01-03.15-03.01-00.52-03-02"
        self.range_V, self.nplc, self.count = 10.0, 10.0, 1
        self.errors: list = []
        self.commands: list = []
        self.windows: list = []

    def outputs(self, t) -> np.ndarray:
        """The unit's noiseless output of this axis (V) at instrument times ``t``."""
        ph = self.physics
        t = np.asarray(t, float)
        n = len(t)
        with ph.lock:
            _, unit, rate = ph._thermal(t)
            a1, a2 = ph._angles(t)
            e1, e2, wob = ph._errors
            branch = BRANCH[ph.direction]
        tm = ph.timing
        sensor = sensor_temperatures(unit, tm.self_heating_C, t, tm.self_heating_time_constant_s)
        cov = Covariates(axis1=np.radians(a1), axis2=np.radians(a2),
                         temp=tuple(sensor[:, i] for i in range(3)), temp_rate=(rate, rate, rate),
                         branch=np.full(n, branch), time_s=t, axis1_error=e1, axis2_error=e2, wobble=wob)
        w = np.broadcast_arrays(*ph.model.predict(ph.p, cov, ph.gravity_g))[self.index]
        return np.asarray(w, float)

    def answer(self, cmd: str, stop=None) -> Optional[str]:
        self.commands.append(cmd)
        head, _, arg = cmd.partition(" ")
        head, arg = head.upper(), arg.strip()
        if head == "*IDN?":
            return self.idn
        if head == "*CLS":
            self.errors.clear()
            return None
        if head == "SYST:ERR?":
            return self.errors.pop(0) if self.errors else '+0,"No error"'
        try:
            if head == "CONF:VOLT:DC":
                if arg.upper() != "AUTO":
                    r = float(arg)
                    if not any(math.isclose(r, a) for a in self.RANGES):
                        raise ValueError
                    self.range_V = r
                return None
            if head == "VOLT:DC:NPLC":
                v = float(arg)
                if not any(math.isclose(v, a) for a in self.NPLC):
                    raise ValueError
                self.nplc = v
                return None
            if head == "SAMP:COUN":
                c = int(arg)
                if not 1 <= c <= 1_000_000:
                    raise ValueError
                self.count = c
                return None
        except ValueError:
            self.errors.append('-222,"Data out of range"')
            return None
        if head == "READ?":
            return self._read(stop)
        self.errors.append('-113,"Undefined header"')
        return None

    def _read(self, stop) -> str:
        dt = self.nplc / self.mains_hz                 # one reading's integration time
        t0 = self.now()
        times = t0 + (np.arange(self.count) + 0.5) * dt
        t1 = t0 + self.count * dt
        while self.now() < t1 and not (stop is not None and stop.is_set()):    # the meter integrates
            time.sleep(min(0.01, max(0.0, (t1 - self.now()) / self.time_scale)))
        true = self.outputs(times)
        q = self.physics.truth.noise.Q_V2s
        v = true + self.rng.normal(0.0, math.sqrt(q / dt), len(times))
        self.windows.append((t0, t1, float(true.mean()), float(v.mean())))
        v = np.where(np.abs(v) > 1.2 * self.range_V, 9.9e37, v)
        return ",".join(f"{x:+.9E}" for x in v)


def _toml_str(text: str) -> str:
    return '"' + str(text).replace("\\", "\\\\").replace('"', '\\"') + '"'


_NUMBER = r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?"


class TemplateBenchServer:
    """The bench controller of a command-template profile (drivers/bench_template.py), as the
    emulator plays it: each command line is matched against the profile's templates (turned
    into regular expressions) and answered with the profile's ``[emulator]`` replies, so the
    driver and the emulator read one file. Several commands on a line are separated by ';'.

    Angles go through the axis's scale and offset (controller units on the line, bench degrees
    in the physics). A move outside an axis's ``min_deg``/``max_deg`` (the controller's own
    travel limits, here the profile's) is not made: the error buffer gets the profile's
    ``positive_limit`` / ``negative_limit`` code; an unknown command gets ``unknown_command``.
    ``commands`` keeps every line received."""

    def __init__(self, profile, physics: "UnitPhysics", now):
        import re

        self.profile, self.physics, self.now = profile, physics, now
        self.commands: list[str] = []
        self.errors: list[tuple[str, str]] = []
        self._target = [0.0, 0.0]
        ids = "|".join(re.escape(a.id) for a in profile.axes)
        self._patterns = []
        import string as _string

        for name, tpl in profile.commands.items():
            rx = ""
            for literal, fname, _, _ in _string.Formatter().parse(tpl):
                rx += re.escape(literal)
                if fname is not None:
                    rx += f"(?P<axis>{ids})" if fname == "axis" else f"(?P<value>{_NUMBER})"
            self._patterns.append((name, re.compile(rx + r"\Z", re.IGNORECASE)))
        em = profile.emulator
        self.position_reply = em.get("position_reply", "{value:.6f}")
        self.done_reply, self.moving_reply = em.get("done_reply", "1"), em.get("moving_reply", "0")
        self.error_reply = em.get("error_reply", "{code},{message}")
        self.no_error = (profile.responses.get("no_error", "0"), em.get("no_error_message", "no error"))
        self.ticks_per_s = float(em.get("ticks_per_s", 1.0))

    def _push(self, key: str, axis_id: str = "") -> None:
        spec = self.profile.emulator.get(key, {"code": "1", "message": key})
        self.errors.append((str(spec["code"]).format(axis=axis_id), str(spec.get("message", ""))))

    def answer(self, line: str) -> Optional[str]:
        replies = [r for r in (self._one(c.strip()) for c in line.split(";") if c.strip()) if r is not None]
        return ";".join(replies) if replies else None

    def _one(self, cmd: str) -> Optional[str]:
        from .drivers.bench_template import wrap_angle

        self.commands.append(cmd)
        t = self.now()
        for name, rx in self._patterns:
            m = rx.match(cmd)
            if m is None:
                continue
            axis_id = m.groupdict().get("axis")
            i = next((k for k, a in enumerate(self.profile.axes) if a.id == axis_id), 0)
            ax = self.profile.axes[i]
            if name == "move":
                deg = (float(m.group("value")) - ax.offset) / ax.scale
                d = wrap_angle(deg, ax.wrap)
                if d > ax.max_deg or d < ax.min_deg:
                    self._push("positive_limit" if d > ax.max_deg else "negative_limit", ax.id)
                    return None
                self._target[i] = deg
                self.physics.move(t, *self._target)
                return None
            if name in ("stop", "home"):
                # this axis only: stops where it is, or heads for the controller's zero; the
                # other axis keeps its own target (two HOME lines home both axes)
                pos, _, _ = self.physics.bench_state(t)
                self._target[i] = -ax.offset / ax.scale if name == "home" else pos[i]
                self.physics.move(t, *self._target)
                return None
            if name == "position":
                pos, _, _ = self.physics.bench_state(t)
                return self.position_reply.format(value=ax.to_controller(pos[i]))
            if name == "done":
                _, _, ready = self.physics.bench_state(t)
                return self.done_reply if ready else self.moving_reply
            if name == "error":
                code, message = self.errors.pop(0) if self.errors else self.no_error
                ticks = int(t * self.ticks_per_s) % 2**31
                return self.error_reply.format(code=code, timestamp=ticks, message=message)
        self._push("unknown_command")
        return None


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
