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

import math
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


#: how close to its target an axis must read to count as in position (degrees); the default of
#: both drivers (a template profile's ``[settle] tolerance_deg``, ``ScpiBench(tolerance_deg=)``)
DEFAULT_TOLERANCE_DEG = 0.01


def angle_difference(a: float, b: float, wrap: str = "360") -> float:
    """a - b, modulo 360 (in [-180, 180)) when the axis wraps (``wrap`` other than ``"none"``)."""
    d = a - b
    return (d + 180.0) % 360.0 - 180.0 if wrap != "none" else d


def within_tolerance(position, target, tolerance_deg: float, wraps=("360", "360")) -> bool:
    """Whether every axis of ``position`` reads within ``tolerance_deg`` of ``target`` (each
    difference taken as its axis wraps); a non-finite reading never is."""
    return all(abs(angle_difference(p, t, w)) <= tolerance_deg for p, t, w in zip(position, target, wraps))


def _same_angle(a: float, b: float, tol: float = 1e-6) -> bool:
    return abs(angle_difference(a, b)) < tol


def parse_angles(answer: str, command: str, where: str) -> tuple[float, float]:
    """The two angles of an ``<a1>,<a2>`` answer; :class:`BenchError` naming ``where``, the
    command and the answer when it is anything else (one number, three, text, nan, inf)."""
    parts = answer.split(",")
    if len(parts) != 2:
        raise BenchError(f"{where}: answer {answer!r} to {command!r} is not two angles '<a1>,<a2>' "
                         f"({len(parts)} field{'s' if len(parts) != 1 else ''})")
    try:
        a1, a2 = float(parts[0]), float(parts[1])
    except ValueError:
        raise BenchError(f"{where}: answer {answer!r} to {command!r} is not two numbers '<a1>,<a2>'") from None
    if not (math.isfinite(a1) and math.isfinite(a2)):
        raise BenchError(f"{where}: answer {answer!r} to {command!r} is not two finite angles")
    return a1, a2


class ScpiBench(Bench):
    """The SCPI-style bench over a serial port; every query is retried ``retries`` times
    (a lost line or a busy controller), a move is confirmed by reading its target back.
    ``in_position`` is true when ``STAT?`` says so and ``POS?`` reads both axes within
    ``tolerance_deg`` of the commanded target. An answer that is not what the protocol says
    raises :class:`BenchError` naming the command and the answer."""

    def __init__(self, port: str, baudrate: int = 115200, timeout_s: float = 0.25, retries: int = 5,
                 tolerance_deg: float = DEFAULT_TOLERANCE_DEG):
        self.port = port
        self.retries = max(1, int(retries))
        self.tolerance_deg = float(tolerance_deg)
        self.target: tuple | None = None          # the last move's commanded angles
        try:
            self._ser = serial.serial_for_url(port, baudrate=baudrate, timeout=timeout_s)   # a path or any pyserial URL
        except (serial.SerialException, ValueError) as exc:
            raise BenchError(f"cannot open the bench's port {port}: {exc}") from None

    def _query(self, command: str) -> str:
        last = None
        for _ in range(self.retries):
            try:
                self._ser.reset_input_buffer()
                self._ser.write((command + "\n").encode("ascii"))
                line = self._ser.readline()
                if line.endswith(b"\n"):
                    return line.decode("ascii", "replace").strip()
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
        where = f"bench on {self.port}"
        self.target = None
        for _ in range(self.retries):
            self._ser.write(f"POS {axis1_deg:.6f},{axis2_deg:.6f}\n".encode("ascii"))
            answer = self._query("POS:TARG?")
            try:
                a1, a2 = parse_angles(answer, "POS:TARG?", where)
            except BenchError as exc:     # a garbled line: send the move again
                why = str(exc).removeprefix(f"{where}: ")
                continue
            if _same_angle(a1, axis1_deg) and _same_angle(a2, axis2_deg):
                self.target = (float(axis1_deg), float(axis2_deg))
                return
            why = f"its target reads ({a1}, {a2})"
        raise BenchError(f"{where} did not accept the move to ({axis1_deg}, {axis2_deg}) in {self.retries} "
                         f"tries: {why}")

    def position(self) -> tuple[float, float]:
        return parse_angles(self._query("POS?"), "POS?", f"bench on {self.port}")

    def in_position(self) -> bool:
        status = self._query("STAT?")
        if status not in ("0", "1"):
            raise BenchError(f"bench on {self.port}: answer {status!r} to 'STAT?' is neither 1 (in position) "
                             "nor 0 (moving)")
        if status != "1":
            return False
        # the status alone is not enough: the axes must read the commanded target
        return self.target is None or within_tolerance(self.position(), self.target, self.tolerance_deg)

    def close(self) -> None:
        self._ser.close()
