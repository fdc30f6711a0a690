"""MicroStrain MIP protocol (3DM-GX5 family): packets, Fletcher checksum, scaled accel.

Packet: ``75 65 | descriptor set | payload length | fields | a b``; each field is
``[length incl. its 2 header bytes][descriptor][big-endian data]``; the checksum runs over
every byte from 0x75 to the end of the payload: ``a += byte; b += a`` (mod 256), ``a``
sent first (LORD-MicroStrain/mip_sdk ``mip_packet.c``).

Data set 0x80 (sensor data), field 0x04 scaled accelerometer vector: 3 × float32, in g
(so ``Frame.w`` needs no conversion). The set has no instantaneous temperature (0x14 is
min / max / mean since power-up), so t_x, t_y, t_z are NaN; ``seq`` counts the frames the
parser accepted and ``time_s = seq / rate_hz``. Other packets (command replies) go to
``Parser.replies`` as ``(descriptor set, [(field descriptor, data), ...])``.

Base command set 0x01: Ping (0x01) ``75 65 01 02 02 01 E0 C6``; the device answers with an
ACK/NACK field 0xF1 ``[echoed command descriptor][error code]`` (0 = ACK); the ACK layout is
from the MIP documentation as we read it, not from a verified vector.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from typing import Iterable

from . import TEMPERATURE_NONE, DeviceError, Frame, Link, ParserStats, exchange

OUTPUT_UNIT = "g"
TEMPERATURE = TEMPERATURE_NONE
CLOCK = "seq counts accepted packets, time_s = seq / rate_hz"

SYNC = b"\x75\x65"
SET_BASE, SET_SENSOR = 0x01, 0x80
CMD_PING = 0x01
FIELD_ACK = 0xF1
FIELD_SCALED_ACCEL = 0x04
#: NACK codes as we read the MIP documentation (not verified)
ERROR_NAMES = {0x01: "unknown command", 0x02: "invalid checksum", 0x03: "invalid parameter",
               0x04: "command failed", 0x05: "command timed out"}


def fletcher(data: bytes) -> bytes:
    """The two checksum bytes (a, b) of ``data``."""
    a = b = 0
    for byte in data:
        a = (a + byte) & 0xFF
        b = (b + a) & 0xFF
    return bytes((a, b))


def packet(descriptor_set: int, fields: Iterable[tuple]) -> bytes:
    """A MIP packet of ``(field descriptor, data)`` fields."""
    payload = b"".join(bytes((len(d) + 2, desc)) + bytes(d) for desc, d in fields)
    if len(payload) > 255:
        raise ValueError("a MIP payload holds at most 255 bytes")
    head = SYNC + bytes((descriptor_set, len(payload)))
    return head + payload + fletcher(head + payload)


def ping() -> bytes:
    """``75 65 01 02 02 01 E0 C6``."""
    return packet(SET_BASE, [(CMD_PING, b"")])


def ack(command_set: int, command: int, code: int = 0) -> bytes:
    """The reply to a command: field 0xF1 ``[command][code]`` in the command's set."""
    return packet(command_set, [(FIELD_ACK, bytes((command, code)))])


def encode(frame: Frame) -> bytes:
    """Data packet 0x80 with the scaled accelerometer vector (g) of ``frame``."""
    return packet(SET_SENSOR, [(FIELD_SCALED_ACCEL, struct.pack(">3f", *frame.w))])


def quantise(frame: Frame) -> Frame:
    """The frame as a receiver decodes it (float32, no temperature), keeping ``seq`` and
    ``time_s`` (which the receiver counts itself)."""
    w = struct.unpack(">3f", struct.pack(">3f", *frame.w))
    return Frame(frame.seq, frame.time_s, tuple(w), (math.nan,) * 3)


def fields_of(payload: bytes) -> list:
    """``[(descriptor, data)]``; ValueError when the field lengths do not fill the payload."""
    out, i, n = [], 0, len(payload)
    while i < n:
        ln = payload[i]
        if ln < 2 or i + ln > n:
            raise ValueError("bad MIP field length")
        out.append((payload[i + 1], bytes(payload[i + 2:i + ln])))
        i += ln
    return out


class Parser:
    """Streaming decoder of MIP packets: resynchronises one byte after a failed sync,
    counts a damaged packet once (when it follows a good one or starts where the next
    would have started); ``keep_raw`` keeps the bytes of each accepted data packet."""

    def __init__(self, rate_hz: float = 100.0, keep_raw: bool = False):
        self.buf = b""
        self.stats = ParserStats()
        self.rate_hz = float(rate_hz)
        self.keep_raw = keep_raw
        self.raw: list[bytes] = []
        self.replies: deque = deque(maxlen=256)
        self.count = 0
        self.in_sync = True
        self.base = 0
        self.expect = -1

    def feed(self, data: bytes) -> list[Frame]:
        buf = self.buf + bytes(data)
        out: list[Frame] = []
        stats = self.stats
        n = len(buf)
        pos = 0
        while True:
            k = buf.find(SYNC, pos)
            if k < 0:
                keep = 1 if n > pos and buf[-1] == SYNC[0] else 0
                stats.garbage_bytes += max(n - pos - keep, 0)
                self.buf = buf[n - keep:]
                self.base += n - keep
                return out
            stats.garbage_bytes += k - pos
            if k + 4 > n:
                return self._wait(buf, k, out)
            total = 4 + buf[k + 3] + 2
            if k + total > n:
                return self._wait(buf, k, out)
            if fletcher(buf[k:k + total - 2]) == buf[k + total - 2:k + total] and \
                    self._packet(buf[k + 2], buf[k + 4:k + total - 2], buf[k:k + total], out):
                self.in_sync = True
                pos = k + total
                continue
            if self.in_sync or self.base + k == self.expect:
                stats.corrupted += 1
                self.in_sync = False
                self.expect = self.base + k + total
            stats.garbage_bytes += 1
            pos = k + 1

    def _wait(self, buf, k, out):
        self.buf = buf[k:]
        self.base += k
        return out

    def _packet(self, dset: int, payload: bytes, raw: bytes, out: list) -> bool:
        try:
            fields = fields_of(payload)
        except ValueError:
            return False
        if dset != SET_SENSOR:
            self.replies.append((dset, fields))
            return True
        acc = None
        for desc, d in fields:
            if desc == FIELD_SCALED_ACCEL:
                if len(d) != 12:
                    return False
                acc = struct.unpack(">3f", d)
                if not all(math.isfinite(a) for a in acc):
                    return False
        if acc is None:
            return True          # a data packet without the accelerometer: nothing to deliver
        f = Frame(self.count, self.count / self.rate_hz, tuple(acc), (math.nan,) * 3)
        self.count += 1
        self.stats.frames += 1
        if self.keep_raw:
            self.raw.append(bytes(raw))
        out.append(f)
        return True


# -- the driver's side: the documented minimum on open ---------------------------------
def error_text(code) -> str:
    return f"NACK 0x{code:02X} ({ERROR_NAMES.get(code, 'unknown code')})"


def _ack_of(command_set: int, command: int, what: str):
    def accept(reply):
        dset, fields = reply
        if dset != command_set:
            return False
        for desc, d in fields:
            if desc == FIELD_ACK and len(d) >= 2 and d[0] == command:
                if d[1] != 0:
                    raise DeviceError("mip", f"MicroStrain MIP refused {what}: {error_text(d[1])}", d[1], what)
                return True
        return False
    return accept


def configure(link: Link, parser: Parser, rate_hz: float, timeout_s: float = 0.5) -> list[Frame]:
    """The documented minimum: a Ping answered by its ACK (the device is there and speaks
    MIP). The stream's content and rate stay as the device is set up (3DM-GX5 message format
    commands are not sent: their layouts are not among the verified facts); ``rate_hz`` only
    sets the parser's clock. Returns the frames that arrived meanwhile."""
    frames: list[Frame] = []
    exchange(link, parser, ping(), _ack_of(SET_BASE, CMD_PING, "Ping"), timeout_s, frames, "mip", "Ping")
    parser.rate_hz = float(rate_hz)
    return frames


# -- the instrument's side: what the emulator answers ----------------------------------
class Emulated:
    """A 3DM-GX5 as the emulator plays it: streams scaled accel at ``rate_hz`` from the
    start, ACKs a Ping, NACKs (0x01) any other command of the base set."""

    def __init__(self, rate_hz: float = 100.0):
        self.rate_hz = float(rate_hz)
        self.streaming = True
        self.parser = Parser()
        self.commands = []

    encode = staticmethod(encode)
    quantise = staticmethod(quantise)

    def feed(self, data: bytes) -> bytes:
        self.parser.feed(data)
        out = []
        while self.parser.replies:
            dset, fields = self.parser.replies.popleft()
            for desc, _ in fields:
                self.commands.append((dset, desc))
                ok = dset == SET_BASE and desc == CMD_PING
                out.append(ack(dset, desc, 0 if ok else 0x01))
        return b"".join(out)
