"""Small emulators of documented chamber controllers on pseudo-terminals.

* :class:`EspecEmulator` - the Espec P300 / SCP-220 ASCII protocol (``TEMP?``, ``TEMP, S25.0``,
  ``MON?``, ``MODE?``, ``MODE, CONSTANT``; ``\\r\\n``; optional RS-485 address prefix ``1,``;
  ``NA:<message>`` errors).
* :class:`WatlowEmulator` - a Modbus RTU slave with the Watlow F4 register map (PV 100, set
  point 300, signed int16 tenths; range 602/603) or the F4T's (set point 2782, current set
  point 2810, PV 2820, min/max 2774/2776; float32 over two words, low word first by default).

Both drive the same :class:`FirstOrderLag`: the air temperature follows the set point with
one time constant (closed form between set point changes), on a clock that runs
``time_scale`` times faster than the wall clock. Each emulator opens a pty with Python's own
``pty``/``os.openpty`` (no system package), answers on its master side in a thread, and
hands out the slave path as :attr:`port` (optionally behind a stable symlink ``link``), so a
driver opens it like a USB adapter. :meth:`config` gives the ``[chamber]`` section a capture
config file needs (``driver``, ``port``, ...; read by
:func:`triadcal.hardware.drivers.chamber.open_chamber`).
"""

from __future__ import annotations

import math
import os
import re
import select
import struct
import threading
import time
import tty
from pathlib import Path
from typing import Callable, Optional

from .drivers.watlow import (F4_PV, F4_SP, F4T_PV, F4T_SP, f4_register, f4_value, float_to_words, rtu_frame,
                             words_to_float)
from .protocols.binary import crc16_modbus


class FirstOrderLag:
    """Chamber air temperature: ``dT/dt = (target - T) / tau_s`` in emulated seconds
    (``time_scale`` emulated seconds per wall second), solved in closed form. Thread-safe."""

    def __init__(self, start_C: float = 23.0, tau_s: float = 60.0, time_scale: float = 1.0,
                 clock: Callable[[], float] = time.monotonic):
        if tau_s <= 0 or time_scale <= 0:
            raise ValueError("tau_s and time_scale must be > 0")
        self.tau_s = float(tau_s)
        self.time_scale = float(time_scale)
        self._clock = clock
        self._wall0 = clock()
        self._lock = threading.Lock()
        self._t0 = 0.0
        self._T0 = float(start_C)
        self._target = float(start_C)

    def now_s(self) -> float:
        return (self._clock() - self._wall0) * self.time_scale

    def _at(self, t: float) -> float:
        return self._target + (self._T0 - self._target) * math.exp(-(t - self._t0) / self.tau_s)

    def temperature_C(self) -> float:
        with self._lock:
            return self._at(self.now_s())

    @property
    def target_C(self) -> float:
        return self._target

    def set_target(self, value_C: float) -> None:
        with self._lock:
            t = self.now_s()
            self._T0 = self._at(t)
            self._t0 = t
            self._target = float(value_C)


class _PtyEmulator:
    """One pty, a thread answering on its master side; subclasses implement ``_feed``."""

    driver = ""

    def __init__(self, thermal: Optional[FirstOrderLag] = None, link: Optional[str] = None):
        self.thermal = thermal or FirstOrderLag()
        self.link = Path(link) if link else None
        self.requests = 0
        self.received = bytearray()      # everything the driver sent, for tests
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._master = self._slave = -1
        self._path = ""

    @property
    def port(self) -> str:
        return str(self.link) if self.link else self._path

    def start(self):
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)        # no echo, no CR/LF translation before the driver opens it
        self._path = os.ttyname(self._slave)
        if self.link:
            tmp = self.link.with_name(self.link.name + ".tmp")
            tmp.unlink(missing_ok=True)
            os.symlink(self._path, tmp)
            os.replace(tmp, self.link)
        self._thread = threading.Thread(target=self._run, name=f"{type(self).__name__}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread:
            self._thread.join(2.0)
        if self.link and self._path:
            # the link first: the freed pty number is the next pty anyone opens (emulator._Pty.close)
            try:
                if os.readlink(self.link) == self._path:
                    self.link.unlink()
            except OSError:
                pass
        for fd in (self._master, self._slave):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = -1

    def __enter__(self):
        return self.start() if self._thread is None else self

    def __exit__(self, *exc):
        self.stop()

    def _run(self) -> None:
        while not self._stop.is_set():
            r, _, _ = select.select([self._master], [], [], 0.01)
            if not r:
                self._idle()
                continue
            try:
                data = os.read(self._master, 4096)
            except OSError:
                time.sleep(0.01)
                continue
            self.received += data
            for reply in self._feed(data):
                try:
                    os.write(self._master, reply)
                except OSError:
                    pass

    def _feed(self, data: bytes) -> list:
        raise NotImplementedError

    def _idle(self) -> None:
        pass

    def config(self) -> dict:
        return {"driver": self.driver, "port": self.port}


# -- Espec ASCII -------------------------------------------------------------------------
class EspecEmulator(_PtyEmulator):
    """An Espec P300 / SCP-220 on a pty. ``address`` set: answers only ``<address>,CMD``
    (an RS-485 bus: anything else is for another controller, silence); ``None``: RS-232,
    takes the command with or without a prefix. ``upper_C`` / ``lower_C`` are the alarm
    limits a set point must lie within (else ``NA:DATA OUT OF RANGE``). ``humidity`` None:
    a temperature-only chamber (empty humidity field in ``MON?``)."""

    driver = "espec"

    def __init__(self, thermal: Optional[FirstOrderLag] = None, *, address: Optional[int] = None,
                 upper_C: float = 150.0, lower_C: float = -70.0, humidity: Optional[float] = None,
                 mode: str = "CONSTANT", ambient_C: Optional[float] = None, link: Optional[str] = None):
        super().__init__(thermal, link)
        self.address = address
        self.upper_C = float(upper_C)
        self.lower_C = float(lower_C)
        self.humidity = humidity
        self.setpoint = self.thermal.target_C
        self.ambient_C = self.thermal.target_C if ambient_C is None else float(ambient_C)
        self.mode = mode
        self.commands: list = []      # every command line received, without the terminator
        self._buf = b""
        if mode not in ("CONSTANT", "RUN"):
            self.thermal.set_target(self.ambient_C)

    def config(self) -> dict:
        c = super().config()
        if self.address is not None:
            c["address"] = self.address
        return c

    def _feed(self, data: bytes) -> list:
        self._buf += data
        out = []
        while b"\n" in self._buf:
            line, self._buf = self._buf.split(b"\n", 1)
            text = line.rstrip(b"\r").decode("ascii", "replace").strip()
            self.commands.append(text)
            reply = self._answer(text)
            if reply is not None:
                out.append(reply.encode("ascii") + b"\r\n")
        return out

    def _answer(self, text: str) -> Optional[str]:
        m = re.match(r"^(\d+),(.*)$", text)
        if m:
            if self.address is not None and int(m.group(1)) != self.address:
                return None
            text = m.group(2).strip()
        elif self.address is not None:
            return None
        self.requests += 1
        cmd = text.upper()
        if cmd == "TEMP?":
            return f"{self.thermal.temperature_C():.1f},{self.setpoint:.1f},{self.upper_C:.1f},{self.lower_C:.1f}"
        if cmd == "MON?":
            hum = "" if self.humidity is None else f"{self.humidity:.0f}"
            return f"{self.thermal.temperature_C():.1f},{hum},{self.mode},0"
        if cmd == "MODE?":
            return self.mode
        m = re.match(r"^MODE,\s*(OFF|STANDBY|CONSTANT|RUN)$", cmd)
        if m:
            self.mode = m.group(1)
            self.thermal.set_target(self.setpoint if self.mode in ("CONSTANT", "RUN") else self.ambient_C)
            return f"OK: {text}"
        m = re.match(r"^TEMP,\s*(.*)$", cmd)
        if m:
            fields = {}
            for tok in m.group(1).replace(",", " ").split():
                if tok[:1] not in ("S", "H", "L") or tok[:1] in fields:
                    return "NA:PARA ERR"
                try:
                    fields[tok[:1]] = float(tok[1:])
                except ValueError:
                    return "NA:PARA ERR"
            if not fields:
                return "NA:PARA ERR"
            upper, lower = fields.get("H", self.upper_C), fields.get("L", self.lower_C)
            sp = fields.get("S", self.setpoint)
            if not lower < upper or not lower <= sp <= upper:
                return "NA:DATA OUT OF RANGE"
            self.upper_C, self.lower_C, self.setpoint = upper, lower, sp
            if self.mode in ("CONSTANT", "RUN"):
                self.thermal.set_target(sp)
            return f"OK: {text}"
        return "NA:CMD ERR"


# -- Watlow Modbus RTU -------------------------------------------------------------------
class WatlowEmulator(_PtyEmulator):
    """A Watlow F4 (``model="f4"``) or F4T (``"f4t"``) Modbus RTU slave on a pty, loop 1.
    Functions 3, 6 and 16; exceptions 1 (function), 2 (address), 3 (value: a set point
    outside the range); a frame with a bad CRC or for another slave gets no answer."""

    def __init__(self, thermal: Optional[FirstOrderLag] = None, *, model: str = "f4", slave: int = 1,
                 word_order: str = "low-first", range_C: tuple = (-70.0, 180.0), link: Optional[str] = None):
        if model not in ("f4", "f4t"):
            raise ValueError(f"Watlow model {model!r}: expected 'f4' or 'f4t'")
        super().__init__(thermal, link)
        self.model = model
        self.driver = "watlow-" + model
        self.slave = int(slave)
        self.word_order = word_order
        self.range_C = (float(range_C[0]), float(range_C[1]))
        self.setpoint = self.thermal.target_C
        self.frames: list = []        # every valid request frame, CRC included
        self._buf = b""

    def config(self) -> dict:
        c = super().config()
        c["slave"] = self.slave
        if self.model == "f4t":
            c["word_order"] = self.word_order
        return c

    # the register map: address -> (read function, or None), writable set
    def _read(self, reg: int) -> Optional[int]:
        T = self.thermal.temperature_C()
        if self.model == "f4":
            table = {F4_PV[1]: f4_register(T), F4_SP[1]: f4_register(self.setpoint), 200: 0,
                     602: f4_register(self.range_C[0]), 603: f4_register(self.range_C[1])}
            return table.get(reg)
        floats = {F4T_SP: self.setpoint, 2810: self.thermal.target_C, F4T_PV: T,
                  2774: self.range_C[0], 2776: self.range_C[1]}
        for base, v in floats.items():
            if reg in (base, base + 1):
                return float_to_words(v, self.word_order)[reg - base]
        return None

    def _writable(self, reg: int) -> bool:
        return reg == F4_SP[1] if self.model == "f4" else reg in (F4T_SP, F4T_SP + 1)

    def _write(self, addr: int, words) -> bool:
        """Store consecutive words from ``addr``; False when the value is refused (exception 3)."""
        if self.model == "f4":
            v = f4_value(words[-1])
        else:
            cur = list(float_to_words(self.setpoint, self.word_order))
            for i, w in enumerate(words):
                cur[addr - F4T_SP + i] = w
            v = words_to_float(cur, self.word_order)
        if math.isnan(v) or not self.range_C[0] <= v <= self.range_C[1]:
            return False
        self.setpoint = v
        self.thermal.set_target(v)
        return True

    def _feed(self, data: bytes) -> list:
        self._buf += data
        out = []
        while len(self._buf) >= 8:
            fc = self._buf[1]
            n = 9 + self._buf[6] if fc == 16 else 8
            if len(self._buf) < n:
                break
            frame, self._buf = self._buf[:n], self._buf[n:]
            if crc16_modbus(frame[:-2]) != int.from_bytes(frame[-2:], "little"):
                self._buf = b""              # resynchronise on the next silence
                break
            self.frames.append(bytes(frame))
            reply = self._reply(frame[:-2])
            if reply is not None:
                out.append(reply)
        return out

    def _idle(self) -> None:
        self._buf = b""                       # 3.5 character times of silence end a frame

    def _exception(self, fc: int, code: int) -> bytes:
        return rtu_frame(self.slave, fc | 0x80, bytes([code]))

    def _reply(self, req: bytes) -> Optional[bytes]:
        if req[0] != self.slave:
            return None
        self.requests += 1
        fc = req[1]
        addr, arg = struct.unpack(">HH", req[2:6])
        if fc == 3:
            if not 1 <= arg <= 125:
                return self._exception(fc, 3)
            words = [self._read(a) for a in range(addr, addr + arg)]
            if any(w is None for w in words):
                return self._exception(fc, 2)
            return rtu_frame(self.slave, 3, bytes([2 * arg]) + b"".join(struct.pack(">H", w) for w in words))
        if fc == 6:
            if not self._writable(addr):
                return self._exception(fc, 2)
            if not self._write(addr, [arg]):
                return self._exception(fc, 3)
            return rtu_frame(self.slave, 6, req[2:6])
        if fc == 16:
            nbytes = req[6]
            if nbytes != 2 * arg or not all(self._writable(a) for a in range(addr, addr + arg)):
                return self._exception(fc, 2)
            words = struct.unpack(f">{arg}H", req[7:7 + nbytes])
            if not self._write(addr, list(words)):
                return self._exception(fc, 3)
            return rtu_frame(self.slave, 16, req[2:6])
        return self._exception(fc, 1)
