"""Thermal chamber driver: set and read the temperature.

:class:`Chamber` is the interface; :class:`ModbusChamber` talks Modbus RTU through
minimalmodbus (over pyserial), with triadcal's own register map (docs/hardware.md). The
documented controllers have their own modules: :mod:`.watlow` (Watlow F4, F4T) and
:mod:`.espec` (Espec P300 / SCP-220 ASCII); :func:`open_chamber` picks one from a config
section, and :func:`open_serial` opens any pyserial URL or device path. Stabilisation is
not the chamber's job: the capture runner waits on the unit's own temperatures
(capture.Stabilisation).

The register map of :class:`ModbusChamber`:

=========  ======  ======================================  ==========
register   access  meaning                                 encoding
=========  ======  ======================================  ==========
100        read    chamber air temperature (process value) int16, 0.1 degC
300        r/w     temperature setpoint                    int16, 0.1 degC
301        read    status: bit 0 running                   uint16
=========  ======  ======================================  ==========
"""

from __future__ import annotations

from ...errors import InputError, TriadcalError

import time
from abc import ABC, abstractmethod

import minimalmodbus
import serial

REG_PV = 100
REG_SP = 300
REG_STATUS = 301


class ChamberError(TriadcalError, OSError):
    """The chamber did not answer or refused a setpoint."""


class Chamber(ABC):
    @abstractmethod
    def set_setpoint_C(self, value: float) -> None: ...

    @abstractmethod
    def setpoint_C(self) -> float: ...

    @abstractmethod
    def temperature_C(self) -> float: ...

    def close(self) -> None:
        pass


class ModbusChamber(Chamber):
    """A Modbus RTU chamber controller (minimalmodbus); calls are retried ``retries`` times."""

    def __init__(self, port: str, slave: int = 1, baudrate: int = 19200, timeout_s: float = 0.3,
                 retries: int = 3):
        self.port = port
        self.retries = retries
        self._inst = minimalmodbus.Instrument(port, slave, mode=minimalmodbus.MODE_RTU)
        self._inst.serial.baudrate = baudrate
        self._inst.serial.timeout = timeout_s
        self._inst.clear_buffers_before_each_transaction = True

    def _call(self, what: str, fn, *args, **kw):
        last = None
        for _ in range(self.retries):
            try:
                return fn(*args, **kw)
            except (IOError, ValueError, serial.SerialException) as exc:   # minimalmodbus errors are IOErrors
                last = exc
                time.sleep(0.02)
        raise ChamberError(f"chamber on {self.port}: {what} failed after {self.retries} tries: {last}")

    def set_setpoint_C(self, value: float) -> None:
        self._call("write setpoint", self._inst.write_register, REG_SP, round(value, 1), 1, signed=True)
        back = self.setpoint_C()
        if abs(back - round(value, 1)) > 0.051:
            raise ChamberError(f"chamber on {self.port} reads back setpoint {back} degC after writing {value}")

    def setpoint_C(self) -> float:
        return float(self._call("read setpoint", self._inst.read_register, REG_SP, 1, signed=True))

    def temperature_C(self) -> float:
        return float(self._call("read temperature", self._inst.read_register, REG_PV, 1, signed=True))

    def close(self) -> None:
        self._inst.serial.close()


def open_serial(port: str, *, baudrate: int, bytesize: int = 8, parity: str = "N", stopbits: float = 1,
                timeout_s: float = 0.5) -> serial.SerialBase:
    """An open pyserial port from a device path (``/dev/ttyUSB0``, ``COM3``) or any pyserial
    URL (``rfc2217://host:port``, ``socket://host:port``, ``loop://``, ``spy://...``)."""
    if parity not in ("N", "E", "O"):
        raise ValueError(f"parity must be N, E or O, not {parity!r}")
    if stopbits not in (1, 1.5, 2):
        raise ValueError(f"stop bits must be 1, 1.5 or 2, not {stopbits!r}")
    try:
        return serial.serial_for_url(port, baudrate=int(baudrate), bytesize=int(bytesize), parity=parity,
                                     stopbits=stopbits, timeout=timeout_s)
    except (serial.SerialException, ValueError) as exc:
        raise ChamberError(f"cannot open the chamber's port {port}: {exc}") from None


#: the ``driver`` names of a ``[chamber]`` config section
CHAMBER_DRIVERS = ("modbus", "watlow-f4", "watlow-f4t", "espec")


def open_chamber(cfg) -> Chamber:
    """A chamber driver from a config mapping: ``driver`` (one of :data:`CHAMBER_DRIVERS`,
    default ``modbus``: triadcal's own map), ``port`` (device path or pyserial URL), and the
    driver's options: ``baudrate``, ``slave`` / ``address``, ``stopbits``, ``parity``, ``loop``,
    ``word_order`` (F4T: ``low-first`` | ``high-first``), ``timeout_s``."""
    driver = str(cfg.get("driver", "modbus")).lower()
    if not cfg.get("port"):
        raise InputError("[chamber] needs a 'port' (a device path or a pyserial URL)")
    port = cfg["port"]
    opt = {k: cfg[k] for k in ("stopbits", "parity", "timeout_s") if k in cfg}
    if driver == "modbus":
        return ModbusChamber(port, slave=int(cfg.get("slave", cfg.get("address", 1))),
                             baudrate=int(cfg.get("baudrate", 19200)))
    if driver in ("watlow-f4", "watlow-f4t"):
        from .watlow import WatlowF4, WatlowF4T

        kw = dict(slave=int(cfg.get("slave", cfg.get("address", 1))), baudrate=int(cfg.get("baudrate", 9600)),
                  loop=int(cfg.get("loop", 1)), **opt)
        if driver == "watlow-f4t":
            return WatlowF4T(port, word_order=str(cfg.get("word_order", "low-first")), **kw)
        return WatlowF4(port, **kw)
    if driver == "espec":
        from .espec import EspecChamber

        # the RS-485 address: `address` of an instruments file, or `slave` (capture --chamber-slave,
        # which set `slave` only and was silently ignored here)
        address = cfg.get("address", cfg.get("slave"))
        return EspecChamber(port, baudrate=int(cfg.get("baudrate", 9600)),
                            address=None if address in (None, "", 0) else int(address), **opt)
    raise InputError(f"[chamber] driver {driver!r}: expected one of {', '.join(CHAMBER_DRIVERS)}")
