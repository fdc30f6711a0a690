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
from typing import Optional

import minimalmodbus
import serial

try:
    import termios
    _TERMIOS_ERRORS: tuple = (termios.error,)
except ImportError:       # not POSIX
    _TERMIOS_ERRORS = ()

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


#: what a serial port raises when its device misbehaves or goes away: pyserial's exceptions, the
#: OS's, minimalmodbus's (IOErrors, ValueErrors) and, on POSIX, ``termios.error``, which is none of
#: them (a USB adapter unplugged mid-run fails the input flush before each transaction with
#: termios.error (5, 'Input/output error'); it ended a capture in "internal error", an outside probe)
PORT_ERRORS: tuple = (OSError, ValueError, serial.SerialException) + _TERMIOS_ERRORS


class ModbusRtuChamber(Chamber):
    """Common transport of the Modbus RTU chambers: minimalmodbus on a pyserial port (device path
    or URL), 8 data bits, parity and stop bits configurable, calls retried ``retries`` times, then
    :class:`ChamberError`; an exception answer of the controller is not retried."""

    name = "Modbus"

    def __init__(self, port: str, *, slave: int = 1, baudrate: int = 9600, parity: str = "N",
                 stopbits: float = 1, timeout_s: float = 0.5, retries: int = 3, loop: int = 1):
        if not 1 <= int(slave) <= 247:
            raise ValueError(f"Modbus slave address {slave}: expected 1..247")
        self.port = port
        self.slave = int(slave)
        self.retries = int(retries)
        self.loop = int(loop)
        ser = open_serial(port, baudrate=baudrate, parity=parity, stopbits=stopbits, timeout_s=timeout_s)
        self._inst = minimalmodbus.Instrument(ser, self.slave, mode=minimalmodbus.MODE_RTU)
        self._inst.clear_buffers_before_each_transaction = True

    def _call(self, what: str, fn, *args, **kw):
        last: Optional[BaseException] = None
        for _ in range(max(1, self.retries)):
            try:
                return fn(*args, **kw)
            except minimalmodbus.SlaveReportedException as exc:    # an answer: asking again changes nothing
                raise ChamberError(f"{self.name} chamber on {self.port} (slave {self.slave}): {what} refused by "
                                   f"the controller: {exc}") from None
            except PORT_ERRORS as exc:
                last = exc
                time.sleep(0.02)
        raise ChamberError(f"{self.name} chamber on {self.port} (slave {self.slave}): {what} failed "
                           f"after {self.retries} tries: {last}")

    def close(self) -> None:
        try:
            self._inst.serial.close()
        except Exception:   # noqa: BLE001 - closing a port that went away
            pass


class ModbusChamber(ModbusRtuChamber):
    """triadcal's own register map (module docstring): PV 100, set point 300, signed int16 tenths;
    19200 baud 8N1 and a 0.3 s timeout by default."""

    name = "Modbus"

    def __init__(self, port: str, *, baudrate: int = 19200, timeout_s: float = 0.3, **kw):
        super().__init__(port, baudrate=baudrate, timeout_s=timeout_s, **kw)

    def set_setpoint_C(self, value: float) -> None:
        self._call("write setpoint", self._inst.write_register, REG_SP, round(value, 1), 1, signed=True)
        back = self.setpoint_C()
        if abs(back - round(value, 1)) > 0.051:
            raise ChamberError(f"{self.name} chamber on {self.port} reads back setpoint {back} degC after "
                               f"writing {value}")

    def setpoint_C(self) -> float:
        return float(self._call("read setpoint", self._inst.read_register, REG_SP, 1, signed=True))

    def temperature_C(self) -> float:
        return float(self._call("read temperature", self._inst.read_register, REG_PV, 1, signed=True))


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
                             baudrate=int(cfg.get("baudrate", 19200)), **opt)
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
