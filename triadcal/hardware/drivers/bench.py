"""Two-axis bench driver: move to (axis1, axis2), report position and in-position.

:class:`Bench` is the interface; :class:`ScpiBench` speaks the SCPI-style text
protocol of docs/hardware.md over pyserial (one command per line, queries end in '?',
answers are one line)::

    *IDN?            -> TRIADCAL,EMU-BENCH,<serial>,<version>
    POS <a1>,<a2>    (no answer) start a move to the angles in degrees
    POS:TARG?        -> <a1>,<a2>   the target the bench is moving to
    POS?             -> <a1>,<a2>   the present angles, degrees
    STAT?            -> 1 in position / 0 moving
    SYST:ERR?        -> <code>,"<text>"   0,"No error" when none

A controller with another line protocol needs no class: :mod:`.bench_template` drives it from a
TOML profile of command templates (``profiles/esp301.toml``, the Newport ESP301).
"""

from __future__ import annotations

from ...errors import TriadcalError

import time
from abc import ABC, abstractmethod

import serial


class BenchError(TriadcalError, OSError):
    """The bench did not do what it was told (no answer, wrong target, move timeout)."""


class Bench(ABC):
    @abstractmethod
    def move_to(self, axis1_deg: float, axis2_deg: float) -> None:
        """Start a move (returns at once; poll :meth:`in_position`)."""

    @abstractmethod
    def position(self) -> tuple[float, float]: ...

    @abstractmethod
    def in_position(self) -> bool: ...

    def close(self) -> None:
        pass


def _same_angle(a: float, b: float, tol: float = 1e-6) -> bool:
    return abs((a - b + 180.0) % 360.0 - 180.0) < tol


class ScpiBench(Bench):
    """The SCPI-style bench over a serial port; every query is retried ``retries`` times
    (a lost line or a busy controller), a move is confirmed by reading its target back."""

    def __init__(self, port: str, baudrate: int = 115200, timeout_s: float = 0.25, retries: int = 5):
        self.port = port
        self.retries = retries
        self._ser = serial.Serial(port, baudrate, timeout=timeout_s)

    def _query(self, command: str) -> str:
        last = None
        for _ in range(self.retries):
            try:
                self._ser.reset_input_buffer()
                self._ser.write((command + "\n").encode("ascii"))
                line = self._ser.readline()
                if line.endswith(b"\n"):
                    return line.decode("ascii").strip()
                last = "no answer"
            except (OSError, serial.SerialException) as exc:
                last = str(exc)
                self._reopen()
        raise BenchError(f"bench on {self.port}: no answer to {command!r} after {self.retries} tries ({last})")

    def _reopen(self) -> None:
        try:
            self._ser.close()
            time.sleep(0.05)
            self._ser.open()
        except (OSError, serial.SerialException):
            pass

    def identify(self) -> str:
        return self._query("*IDN?")

    def move_to(self, axis1_deg: float, axis2_deg: float) -> None:
        for _ in range(self.retries):
            self._ser.write(f"POS {axis1_deg:.6f},{axis2_deg:.6f}\n".encode("ascii"))
            a1, a2 = (float(v) for v in self._query("POS:TARG?").split(","))
            if _same_angle(a1, axis1_deg) and _same_angle(a2, axis2_deg):
                return
        raise BenchError(f"bench on {self.port} did not accept the move to ({axis1_deg}, {axis2_deg}); "
                         f"its target reads ({a1}, {a2})")

    def position(self) -> tuple[float, float]:
        a1, a2 = (float(v) for v in self._query("POS?").split(","))
        return a1, a2

    def in_position(self) -> bool:
        return self._query("STAT?") == "1"

    def close(self) -> None:
        self._ser.close()
