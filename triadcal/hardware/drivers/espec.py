"""Espec chamber controllers (P300, SCP-220, EHS series) over their ASCII protocol.

One command per line, ``\\r\\n`` both ways; on RS-485 each command carries the controller's
address (``1,TEMP?``), the answer does not. Public facts: the P300 / EHS manuals;
ChamberConnectLibrary ``p300.py``, ``especinteract.py`` (MIT).

==================  =============================================  =======================
command             answer                                         used for
==================  =============================================  =======================
``TEMP?``           ``PV,SP,upper,lower`` (degC)                    temperature, set point
``TEMP, S25.0``     ``OK: TEMP, S25.0``                             set point
``MON?``            ``temp,humidity,mode,alarms``                   :meth:`monitor`
``MODE?``           ``OFF`` / ``STANDBY`` / ``CONSTANT`` / ``RUN``  :meth:`mode`
``MODE, CONSTANT``  ``OK: ...``                                     start constant control
any refused         ``NA:<message>`` (e.g. ``NA:DATA OUT OF RANGE``) :class:`EspecCommandError`
==================  =============================================  =======================
"""

from __future__ import annotations

import time
from typing import Optional

import serial

from .chamber import Chamber, ChamberError, open_serial

#: the controllers' error texts (ChamberConnectLibrary's list; the wording differs by generation)
NA_MESSAGES = {
    "CMD ERR": "unrecognised command",
    "ADDR ERR": "bad address",
    "PARA ERR": "parameter missing or unrecognisable",
    "DATA OUT OF RANGE": "value outside the valid range",
    "PROTECT ON": "data protection enabled on the controller's panel",
    "CONT NOT READY-1": "the chamber does not support this (humidity / PTCON)",
    "CONT NOT READY-3": "command not supported by this controller",
    "INVALID REQ": "unsupported function",
    "CHB NOT READY": "could not act on the command",
}
MODES = ("OFF", "STANDBY", "CONSTANT", "RUN")


class EspecCommandError(ChamberError):
    """The controller answered ``NA:<message>`` to a command."""

    def __init__(self, port: str, command: str, message: str):
        self.command = command
        self.message = message
        hint = NA_MESSAGES.get(message)
        super().__init__(f"Espec chamber on {port} refused {command!r}: NA:{message}"
                         + (f" ({hint})" if hint else ""))


class EspecChamber(Chamber):
    """An Espec controller on a serial port (device path or pyserial URL), 9600 8N1 by
    default. ``address``: the RS-485 address prefixed to every command (None on RS-232).
    ``start_constant``: after writing a set point, a controller found in ``OFF`` or
    ``STANDBY`` is put in ``CONSTANT`` (constant-temperature control) so that the set point
    takes effect. A silent controller is asked again ``retries`` times; an ``NA:`` answer is
    raised at once."""

    def __init__(self, port: str, *, baudrate: int = 9600, address: Optional[int] = None, parity: str = "N",
                 stopbits: float = 1, timeout_s: float = 1.0, retries: int = 2, start_constant: bool = True):
        if address is not None and not 0 < int(address) < 100:
            raise ValueError(f"Espec RS-485 address {address}: expected 1..99")
        self.port = port
        self.address = None if address is None else int(address)
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.start_constant = start_constant
        self._ser = open_serial(port, baudrate=baudrate, parity=parity, stopbits=stopbits, timeout_s=timeout_s)

    # -- transport ----------------------------------------------------------------------
    def frame(self, command: str) -> bytes:
        """The bytes sent for ``command`` (address prefix, CR LF)."""
        prefix = f"{self.address}," if self.address is not None else ""
        return (prefix + command + "\r\n").encode("ascii")

    def query(self, command: str) -> str:
        """Send one command, return its answer without the terminator; ``NA:`` raises
        :class:`EspecCommandError`, silence :class:`ChamberError`."""
        last = "no answer"
        for _ in range(max(1, self.retries)):
            try:
                self._ser.reset_input_buffer()
                self._ser.write(self.frame(command))
                self._ser.flush()
                line = self._read_line()
            except (serial.SerialException, OSError) as exc:
                last = str(exc)
                time.sleep(0.05)
                continue
            if line is None:
                last = f"no answer within {self.timeout_s:g} s"
                continue
            if line.startswith("NA:"):
                raise EspecCommandError(self.port, command, line[3:].strip())
            return line
        raise ChamberError(f"Espec chamber on {self.port}: {command!r} failed after {self.retries} tries: {last}")

    def _read_line(self) -> Optional[str]:
        deadline = time.monotonic() + self.timeout_s
        buf = b""
        while not buf.endswith(b"\r\n"):
            if time.monotonic() > deadline:
                return None
            chunk = self._ser.read_until(b"\r\n")
            if not chunk:
                return None
            buf += chunk
        return buf[:-2].decode("ascii", "replace").strip()

    # -- readings ------------------------------------------------------------------------
    def _temp(self) -> tuple:
        text = self.query("TEMP?")
        try:
            pv, sp, upper, lower = (float(v) for v in text.split(",")[:4])
        except ValueError:
            raise ChamberError(f"Espec chamber on {self.port}: TEMP? answered {text!r}, "
                               "expected PV,SP,upper,lower") from None
        return pv, sp, upper, lower

    def temperature_C(self) -> float:
        return self._temp()[0]

    def setpoint_C(self) -> float:
        return self._temp()[1]

    def limits_C(self) -> tuple:
        """(upper, lower) alarm limits: a set point must lie between them."""
        return self._temp()[2:]

    def mode(self) -> str:
        text = self.query("MODE?").strip().upper()
        return text

    def monitor(self) -> dict:
        """``MON?``: temperature, humidity (None on a temperature-only chamber), mode, alarms."""
        text = self.query("MON?")
        parts = [p.strip() for p in text.split(",")]
        if len(parts) < 3:
            raise ChamberError(f"Espec chamber on {self.port}: MON? answered {text!r}")
        try:
            temp = float(parts[0])
            hum = float(parts[1]) if len(parts) >= 4 and parts[1] else None
            alarms = int(parts[-1])
        except ValueError:
            raise ChamberError(f"Espec chamber on {self.port}: MON? answered {text!r}") from None
        return {"temperature_C": temp, "humidity_pct": hum, "mode": parts[-2].upper(), "alarms": alarms}

    # -- control -------------------------------------------------------------------------
    def set_setpoint_C(self, value: float) -> None:
        target = round(float(value), 1)
        command = f"TEMP, S{target:.1f}"
        answer = self.query(command)
        if not answer.startswith("OK"):
            raise ChamberError(f"Espec chamber on {self.port}: {command!r} answered {answer!r}, expected OK:...")
        back = self.setpoint_C()
        if abs(back - target) > 0.051:
            raise ChamberError(f"Espec chamber on {self.port} reads back set point {back} degC after writing {target}")
        if self.start_constant and self.mode() in ("OFF", "STANDBY"):
            answer = self.query("MODE, CONSTANT")
            if not answer.startswith("OK"):
                raise ChamberError(f"Espec chamber on {self.port}: 'MODE, CONSTANT' answered {answer!r}")

    def close(self) -> None:
        try:
            self._ser.close()
        except Exception:   # noqa: BLE001
            pass
