"""Thermal chamber driver: set and read the temperature.

:class:`Chamber` is the interface; :class:`ModbusChamber` talks Modbus RTU through
minimalmodbus (over pyserial), with the register map of docs/hardware.md:

=========  ======  ======================================  ==========
register   access  meaning                                 encoding
=========  ======  ======================================  ==========
100        read    chamber air temperature (process value) int16, 0.1 degC
300        r/w     temperature setpoint                    int16, 0.1 degC
301        read    status: bit 0 running                   uint16
=========  ======  ======================================  ==========
"""

from __future__ import annotations

from ...errors import TriadcalError

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
