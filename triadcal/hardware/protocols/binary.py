"""Binary frame of the IMU readout with CRC-16, and the CRC-16 of Modbus RTU.

54-byte little-endian frame (sync 0xA5 0x5A, type, length, seq, time, w_x w_y w_z,
t_x t_y t_z, CRC-16/CCITT-FALSE): :func:`encode`, :func:`quantise`, the streaming
:class:`Parser` (re-synchronises one byte after a failed sync word, counts each damaged
frame once), :func:`crc16_ccitt`, :func:`crc16_modbus`.
Frame layout and design: docs/hardware.md (Wire protocols: IMU, binary frame).
"""

from __future__ import annotations

import binascii
import struct

from . import Frame, ParserStats

SYNC = b"\xa5\x5a"
TYPE_IMU = 0x01
_PAYLOAD = struct.Struct("<Id3d3f")
PAYLOAD_LEN = _PAYLOAD.size          # 48
FRAME_LEN = 4 + PAYLOAD_LEN + 2      # 54
_HEADER = bytes((TYPE_IMU, PAYLOAD_LEN))
_CRC = struct.Struct("<H")


def crc16_ccitt(data: bytes, init: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection); check('123456789') = 0x29B1."""
    return binascii.crc_hqx(data, init)


def _modbus_table():
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xA001 if c & 1 else c >> 1
        table.append(c)
    return tuple(table)


_MODBUS_TABLE = _modbus_table()


def crc16_modbus(data: bytes) -> int:
    """CRC-16/MODBUS (poly 0x8005 reflected = 0xA001, init 0xFFFF); check('123456789') = 0x4B37.
    Sent low byte first at the end of every Modbus RTU frame."""
    crc = 0xFFFF
    for b in data:
        crc = (crc >> 8) ^ _MODBUS_TABLE[(crc ^ b) & 0xFF]
    return crc


def encode(frame: Frame) -> bytes:
    body = _HEADER + _PAYLOAD.pack(frame.seq & 0xFFFFFFFF, frame.time_s, *frame.w, *frame.t)
    return SYNC + body + _CRC.pack(crc16_ccitt(body))


def quantise(frame: Frame) -> Frame:
    """The frame as a receiver decodes it (temperatures rounded to float32)."""
    return _decode_payload(_PAYLOAD.pack(frame.seq & 0xFFFFFFFF, frame.time_s, *frame.w, *frame.t))


def _decode_payload(payload: bytes, offset: int = 0) -> Frame:
    v = _PAYLOAD.unpack_from(payload, offset)
    return Frame(v[0], v[1], (v[2], v[3], v[4]), (v[5], v[6], v[7]))


class Parser:
    """Streaming decoder of binary frames (see the module docstring)."""

    def __init__(self):
        self.buf = b""
        self.stats = ParserStats()
        self.in_sync = True   # last thing seen was a good frame (or nothing yet)
        self.base = 0         # stream offset of buf[0]
        self.expect = -1      # stream offset where a frame would follow the last damaged one

    def feed(self, data: bytes) -> list[Frame]:
        buf = self.buf + data
        out: list[Frame] = []
        stats = self.stats
        n = len(buf)
        pos = 0
        crc = binascii.crc_hqx
        while True:
            k = buf.find(SYNC, pos)
            if k < 0:
                keep = 1 if n and buf[-1] == 0xA5 else 0
                stats.garbage_bytes += max(n - pos - keep, 0)
                self.buf = buf[n - keep:]
                self.base += n - keep
                return out
            stats.garbage_bytes += k - pos
            if k + FRAME_LEN > n:
                self.buf = buf[k:]
                self.base += k
                return out
            body = buf[k + 2:k + FRAME_LEN - 2]
            if body[:2] == _HEADER and crc(body, 0xFFFF) == _CRC.unpack_from(buf, k + FRAME_LEN - 2)[0]:
                out.append(_decode_payload(body, 2))
                stats.frames += 1
                self.in_sync = True
                pos = k + FRAME_LEN
            else:
                if self.in_sync or body[:2] == _HEADER or self.base + k == self.expect:
                    stats.corrupted += 1
                    self.in_sync = False
                    self.expect = self.base + k + FRAME_LEN
                stats.garbage_bytes += 1
                pos = k + 1
