"""Wire protocols of the IMU readout: one :class:`Frame` per sample, two encodings.

Each protocol module provides ``encode(frame) -> bytes`` and a streaming ``Parser``
whose ``feed(data) -> list[Frame]`` takes bytes as they arrive (any chunking) and
counts what it had to throw away (:class:`ParserStats`).
"""

from __future__ import annotations

from ...errors import InputError

from dataclasses import dataclass, field


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


@dataclass
class ParserStats:
    """What a parser saw: good frames, corrupted frames (bad checksum or malformed,
    counted once per damaged frame), and bytes discarded outside any frame."""

    frames: int = 0
    corrupted: int = 0
    garbage_bytes: int = 0

    def as_dict(self) -> dict:
        return {"frames": self.frames, "corrupted": self.corrupted, "garbage_bytes": self.garbage_bytes}


PROTOCOLS = ("nmea", "binary")


def get_protocol(name: str):
    """The protocol module for ``name`` ('nmea' or 'binary')."""
    if name == "nmea":
        from . import nmea
        return nmea
    if name == "binary":
        from . import binary
        return binary
    raise InputError(f"unknown IMU protocol {name!r}; choose one of: {', '.join(PROTOCOLS)}")


__all__ = ["Frame", "ParserStats", "PROTOCOLS", "get_protocol", "field"]
