"""Emulated bench instruments besides the IMU: a Keysight 34465A-style DMM per axis
(:class:`Emulated34465A`, SCPI on a pty) and a bench controller that speaks a template profile
(:class:`TemplateBenchServer`). Both read the unit's physics of :mod:`triadcal.hardware.emulator`;
split from it (``emulator.py`` keeps the IMU stream, the chamber and the bench it drives).
"""

from __future__ import annotations

import math
import time
from typing import Optional

import numpy as np

from ..models.model import Covariates
from ..models.thermal_environment import sensor_temperatures

#: bytes the emulator's garbage never contains, so that every damaged frame is counted
#: exactly once (the parsers cope with any bytes; this keeps the tests' accounting exact)
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .emulator import UnitPhysics


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
        with ph.lock:
            _, unit, rate = ph._thermal(t)
            a1, a2 = ph._angles(t)
            e1, e2, wob = ph._errors
            branch = ph.branches(t, rate)
        tm = ph.timing
        sensor = sensor_temperatures(unit, tm.self_heating_C, t, tm.self_heating_time_constant_s)
        cov = Covariates(axis1=np.radians(a1), axis2=np.radians(a2),
                         temp=tuple(sensor[:, i] for i in range(3)), temp_rate=(rate, rate, rate),
                         branch=branch, time_s=t, axis1_error=e1, axis2_error=e2, wobble=wob)
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
