"""Wire protocols of the IMU readout: one :class:`Frame` per sample.

Each protocol module provides ``encode(frame) -> bytes`` and a streaming ``Parser``
whose ``feed(data) -> list[Frame]`` takes bytes as they arrive (any chunking) and
counts what it had to throw away (:class:`ParserStats`).

Two generic formats of our own (``nmea`` $TCIMU, ``binary`` 0xA55A; outputs in V, one
temperature per axis) and three documented vendor protocols (``vectornav`` ASCII,
``xsens`` Xbus MTData2, ``mip`` MicroStrain; accelerations converted to g with the
conversion constant 9.80665 m/s^2 per g, one temperature copied to t_x, t_y, t_z).
:func:`protocol_info` says which, so that a capture can write it into its metadata.
The vendor modules also give ``configure(link, parser, rate_hz, ...)`` (what the driver
sends on open) and an ``Emulated`` instrument (what the emulator answers).
"""

from __future__ import annotations

from ...errors import InputError, TriadcalError

import time
from dataclasses import dataclass, field
from typing import Callable, Optional

from ...models.units import STANDARD_GRAVITY_M_S2

#: m/s^2 per g: the conversion constant of m/s^2 readings to g (standard gravity, 9.80665
#: exactly). Only a unit conversion: the local g of the bench stays ``local_g_m_s2`` of the
#: campaign, so a reading of 1 g here is 9.80665 m/s^2, not one local gravity.
G_CONVERSION_M_S2 = STANDARD_GRAVITY_M_S2


@dataclass(frozen=True)
class Frame:
    """One sample of the IMU readout.

    ``seq`` sequence number (uint32, +1 per sample), ``time_s`` the instrument's clock
    (s), ``w`` the X, Y, Z outputs (V), ``t`` the X, Y, Z accelerometer temperatures (degC).
    """

    seq: int
    time_s: float
    w: tuple
    t: tuple
    #: when the host read the frame's bytes (``time.monotonic()``, s), set by the driver's reader; NaN
    #: when unknown. Only the capture's clock rules use it (a stall against a clock step); not
    #: written, not compared.
    wall_s: float = field(default=float("nan"), compare=False, repr=False)


@dataclass
class ParserStats:
    """What a parser saw: good frames, corrupted frames (bad checksum or malformed,
    counted once per damaged frame), and bytes discarded outside any frame."""

    frames: int = 0
    corrupted: int = 0
    garbage_bytes: int = 0

    def as_dict(self) -> dict:
        return {"frames": self.frames, "corrupted": self.corrupted, "garbage_bytes": self.garbage_bytes}


PROTOCOLS = ("nmea", "binary", "vectornav", "xsens", "mip")
#: the documented vendor protocols (configured by the driver on open)
VENDOR_PROTOCOLS = ("vectornav", "xsens", "mip")

#: temperature conventions of Frame.t
TEMPERATURE_PER_AXIS = "per-axis"
TEMPERATURE_SINGLE = "single"     # one sensor, its reading copied to t_x, t_y, t_z
TEMPERATURE_NONE = "none"         # no instantaneous temperature: t_x, t_y, t_z are NaN


def get_protocol(name: str):
    """The protocol module for ``name`` (one of :data:`PROTOCOLS`)."""
    if name == "nmea":
        from . import nmea
        return nmea
    if name == "binary":
        from . import binary
        return binary
    if name == "vectornav":
        from . import vectornav
        return vectornav
    if name == "xsens":
        from . import xsens
        return xsens
    if name == "mip":
        from . import mip
        return mip
    raise InputError(f"unknown IMU protocol {name!r}; choose one of: {', '.join(PROTOCOLS)}")


def protocol_info(name: str) -> dict:
    """What a protocol's frames carry: ``output_unit`` of ``Frame.w`` ('V' or 'g'),
    ``temperature`` (:data:`TEMPERATURE_PER_AXIS`, :data:`TEMPERATURE_SINGLE` or
    :data:`TEMPERATURE_NONE`) and ``clock`` (where ``seq`` and ``time_s`` come from).
    Meant for a capture's metadata (``output_unit``, ``imu_temperature``) so that the CSV
    says when t_x, t_y, t_z are one sensor."""
    mod = get_protocol(name)
    return {"protocol": name,
            "output_unit": getattr(mod, "OUTPUT_UNIT", "V"),
            "temperature": getattr(mod, "TEMPERATURE", TEMPERATURE_PER_AXIS),
            "clock": getattr(mod, "CLOCK", "the instrument's sequence number and clock")}


class DeviceError(TriadcalError, RuntimeError):
    """An instrument refused a command or did not answer it; ``protocol``, ``code`` (the
    instrument's error code, None for no answer) and ``command`` name what happened."""

    def __init__(self, protocol: str, message: str, code=None, command: str = ""):
        super().__init__(message)
        self.protocol, self.code, self.command = protocol, code, command


class Link:
    """The two calls a configuration exchange needs: ``write(bytes)`` and ``read() -> bytes``
    (whatever arrived, waiting at most briefly). The driver adapts its serial port to it."""

    def __init__(self, write: Callable[[bytes], object], read: Callable[[], bytes]):
        self.write, self.read = write, read


def exchange(link: Link, parser, request: bytes, accept: Callable[[object], Optional[bool]],
             timeout_s: float, frames: list, protocol: str, what: str, tries: int = 3):
    """Send ``request`` and wait for the reply that ``accept(reply)`` recognises (True);
    ``accept`` raises :class:`DeviceError` for an error reply. Replies come from
    ``parser.replies`` (a deque the parser fills with what is not a frame); frames that
    arrive meanwhile are appended to ``frames``. Sent again up to ``tries`` times when
    nothing answers within ``timeout_s``; then :class:`DeviceError` with code None."""
    for _ in range(tries):
        parser.replies.clear()
        link.write(request)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            data = link.read()
            if data:
                frames.extend(parser.feed(data))
            while parser.replies:
                reply = parser.replies.popleft()
                if accept(reply):
                    return reply
    raise DeviceError(protocol, f"{protocol}: no answer to {what} ({request!r}) after {tries} tries of "
                                f"{timeout_s:g} s; check the port, baud rate and that the instrument is powered",
                      None, what)


__all__ = ["Frame", "ParserStats", "PROTOCOLS", "VENDOR_PROTOCOLS", "get_protocol", "protocol_info",
           "DeviceError", "Link", "exchange", "G_CONVERSION_M_S2", "TEMPERATURE_PER_AXIS",
           "TEMPERATURE_SINGLE", "TEMPERATURE_NONE", "field"]
