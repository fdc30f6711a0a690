"""ASCII NMEA-style sentence of the IMU readout, with the NMEA 0183 XOR checksum.

One sentence per sample::

    $TCIMU,<seq>,<time_s>,<w_x>,<w_y>,<w_z>,<t_x>,<t_y>,<t_z>*HH\\r\\n

``seq`` decimal integer; ``time_s`` instrument clock, 4 decimals; ``w_*`` outputs in V,
9 decimals; ``t_*`` temperatures in degC, 4 decimals. ``HH`` is the XOR of every byte
between ``$`` and ``*`` (exclusive), two upper-case hex digits, as in NMEA 0183.
A sentence starts at ``$``; a ``$`` inside a damaged sentence starts a new one.
"""

from __future__ import annotations

from ...errors import InputError

import numpy as np

from . import Frame, ParserStats

TALKER = b"TCIMU"
N_FIELDS = 8
#: longest valid sentence; anything longer without a terminator is damaged
MAX_SENTENCE = 200
SYNC = b"$"
#: the checksum in upper-case hex only, as sent (a flipped case bit must not pass)
_HEX = {b"%02X" % v: v for v in range(256)}


def checksum(body: bytes) -> int:
    """XOR of the bytes of ``body`` (the text between '$' and '*')."""
    x = 0
    for b in body:
        x ^= b
    return x


def format_body(frame: Frame) -> bytes:
    w, t = frame.w, frame.t
    return (f"TCIMU,{frame.seq},{frame.time_s:.4f},{w[0]:.9f},{w[1]:.9f},{w[2]:.9f},"
            f"{t[0]:.4f},{t[1]:.4f},{t[2]:.4f}").encode("ascii")


def encode(frame: Frame) -> bytes:
    body = format_body(frame)
    return b"$" + body + b"*%02X\r\n" % checksum(body)


def quantise(frame: Frame) -> Frame:
    """The frame as a receiver decodes it (the sentence's decimal rounding)."""
    return decode_body(format_body(frame))


def decode_body(body: bytes) -> Frame:
    parts = body.split(b",")
    if len(parts) != N_FIELDS + 1 or parts[0] != TALKER:
        raise InputError("not a TCIMU sentence with 8 fields")
    return Frame(int(parts[1]), float(parts[2]), (float(parts[3]), float(parts[4]), float(parts[5])),
                 (float(parts[6]), float(parts[7]), float(parts[8])))


class Parser:
    """Streaming decoder: feed bytes in any chunks, get the frames whose checksum holds.

    The checksums of all sentences in a chunk come from one cumulative XOR over the
    buffer (numpy), so the cost per frame is a split and nine float conversions.
    """

    def __init__(self):
        self.buf = b""
        self.stats = ParserStats()

    def feed(self, data: bytes) -> list[Frame]:
        buf = self.buf + data
        out: list[Frame] = []
        stats = self.stats
        start = buf.find(b"$")
        if start < 0:
            stats.garbage_bytes += len(buf)
            self.buf = b""
            return out
        stats.garbage_bytes += start
        cx = None
        n = len(buf)
        while True:
            end = buf.find(b"\n", start)
            if end < 0:
                tail = buf[start:]
                if len(tail) > MAX_SENTENCE:       # no terminator in sight: damaged
                    stats.corrupted += 1
                    nxt = buf.find(b"$", start + 1)
                    if nxt < 0:
                        self.buf = b""
                        return out
                    start = nxt
                    continue
                self.buf = tail
                return out
            nxt = buf.find(b"$", start + 1, end)
            if nxt >= 0:                           # a new '$' before the end: damaged sentence
                stats.corrupted += 1
                start = nxt
                continue
            star = end - 4                         # ...*HH\r\n
            ok = False
            if star > start and buf[star] == 0x2A and buf[end - 1] == 0x0D:
                if cx is None:
                    cx = np.bitwise_xor.accumulate(np.frombuffer(buf, np.uint8))
                    cx = np.concatenate(([0], cx)).tolist()   # cx[i] = XOR of buf[:i]
                want = _HEX.get(buf[star + 1:star + 3])
                if want is not None and cx[star] ^ cx[start + 1] == want:
                    try:
                        out.append(decode_body(buf[start + 1:star]))
                        ok = True
                    except ValueError:
                        ok = False
            if ok:
                stats.frames += 1
            else:
                stats.corrupted += 1
            start = end + 1
            if start >= n:
                self.buf = b""
                return out
            nxt = buf.find(b"$", start)
            if nxt < 0:
                stats.garbage_bytes += n - start
                self.buf = b""
                return out
            stats.garbage_bytes += nxt - start
            start = nxt
