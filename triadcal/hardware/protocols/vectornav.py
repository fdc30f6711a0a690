"""VectorNav VN-100 / VN-200 ASCII protocol: $VNACC / $VNIMU output, $VNWRG / $VNRRG, $VNERR.

Sentence: ``$VN`` + type + ``,`` + fields + ``*`` + checksum + ``\\r\\n`` (VN-100 user manual
UM001). Checksum: 2 upper-case hex digits of the 8-bit XOR of every byte strictly between
``$`` and ``*``, or (register 30 set to CRC16) 4 upper-case hex digits of CRC-16/XMODEM
(``binascii.crc_hqx(body, 0)``); ``*XX`` means "no check" (accepted and counted in
``Parser.unchecked``).

Frames: ``$VNACC,ax,ay,az`` (m/s^2) and ``$VNIMU,mx,my,mz,ax,ay,az,gx,gy,gz,temp,pres``
(Gauss, m/s^2, rad/s, degC, kPa). ``Frame.w`` is the acceleration in g (m/s^2 divided by
the conversion constant 9.80665); the one temperature of VNIMU fills t_x, t_y, t_z (VNACC
has none: NaN). The ASCII outputs carry no counter or time stamp, so ``seq`` counts the
frames the parser accepted and ``time_s = seq / rate_hz``: a lost sentence is not seen as
a gap and shifts the clock by one period (the campaign only needs a monotonic clock).

Everything else with a good checksum (register replies, $VNERR, other output types) goes
to ``Parser.replies``; ``$VNERR,<code>`` is also counted in ``Parser.errors`` by code.
"""

from __future__ import annotations

import binascii
import math
from collections import Counter, deque
from typing import Optional

from . import (G_CONVERSION_M_S2, TEMPERATURE_SINGLE, DeviceError, Frame, Link, ParserStats, exchange)

OUTPUT_UNIT = "g"
TEMPERATURE = TEMPERATURE_SINGLE
CLOCK = "seq counts accepted sentences, time_s = seq / rate_hz (ASCII output has no counter)"

#: register 6 (async data output type) values
ASYNC_OFF, ASYNC_VNACC, ASYNC_VNYMR, ASYNC_VNIMU = 0, 11, 14, 19
OUTPUT_TYPES = {"off": ASYNC_OFF, "VNACC": ASYNC_VNACC, "VNYMR": ASYNC_VNYMR, "VNIMU": ASYNC_VNIMU}
#: register 7 (async data output frequency) accepted values, Hz
RATES_HZ = (1, 2, 4, 5, 10, 20, 25, 40, 50, 100, 200)
REG_OUTPUT_TYPE, REG_OUTPUT_RATE, REG_CHECKSUM = 6, 7, 30
#: error codes of $VNERR as listed in the VN-100 manual (UM001); only the existence of code
#: 03 is in a verified vector, the names are as we read them and may differ by firmware
ERROR_NAMES = {1: "hard fault", 2: "serial buffer overflow", 3: "invalid checksum", 4: "invalid command",
               5: "not enough parameters", 6: "too many parameters", 7: "invalid parameter",
               8: "invalid register", 9: "unauthorized access", 10: "watchdog reset",
               11: "output buffer overflow", 12: "insufficient baud rate", 255: "error buffer overflow"}

MAX_SENTENCE = 256
_HEXDIGITS = frozenset(b"0123456789ABCDEF")


def xor_checksum(body: bytes) -> int:
    """8-bit XOR of ``body`` (the bytes between '$' and '*')."""
    x = 0
    for b in body:
        x ^= b
    return x


def crc16(body: bytes) -> int:
    """CRC-16/XMODEM (poly 0x1021, init 0), as register 30 = 2 selects."""
    return binascii.crc_hqx(body, 0)


def sentence(body, checksum: str = "xor") -> bytes:
    """``$<body>*<checksum>\\r\\n``; ``checksum`` 'xor' (2 hex), 'crc' (4 hex) or 'none' (``XX``)."""
    body = body.encode("ascii") if isinstance(body, str) else bytes(body)
    if checksum == "xor":
        cs = b"%02X" % xor_checksum(body)
    elif checksum == "crc":
        cs = b"%04X" % crc16(body)
    elif checksum == "none":
        cs = b"XX"
    else:
        raise ValueError(f"checksum must be 'xor', 'crc' or 'none', not {checksum!r}")
    return b"$" + body + b"*" + cs + b"\r\n"


def _values(values) -> str:
    return ",".join(v if isinstance(v, str) else (f"{v:d}" if isinstance(v, int) else f"{v:g}") for v in values)


def write_register(register: int, *values, checksum: str = "xor") -> bytes:
    """``$VNWRG,<id>,<values>`` (id two digits, as ``$VNWRG,06,0*6C``)."""
    return sentence(f"VNWRG,{register:02d}," + _values(values), checksum)


def read_register(register: int, checksum: str = "xor") -> bytes:
    """``$VNRRG,<id>`` (``$VNRRG,11*73``)."""
    return sentence(f"VNRRG,{register:02d}", checksum)


def error_reply(code: int, checksum: str = "xor") -> bytes:
    """``$VNERR,<code>`` (``$VNERR,03*72``)."""
    return sentence(f"VNERR,{code:02d}", checksum)


def _fmt_acc(frame: Frame) -> str:
    return ",".join(f"{a * G_CONVERSION_M_S2:+07.3f}" for a in frame.w)


def format_body(frame: Frame, kind: str = "VNIMU") -> bytes:
    """Body of a VNACC or VNIMU sentence for ``frame`` (w in g, sent in m/s^2). VNIMU's
    magnetometer, gyro and pressure are fixed values (only acceleration and temperature
    matter here); the decimals are ours (the parser takes any), not copied from a capture."""
    if kind == "VNACC":
        return f"VNACC,{_fmt_acc(frame)}".encode("ascii")
    if kind == "VNIMU":
        return (f"VNIMU,+0.2100,-0.0300,+0.4200,{_fmt_acc(frame)},+0.000000,+0.000000,+0.000000,"
                f"{frame.t[0]:+06.2f},+101.325").encode("ascii")
    raise ValueError(f"kind must be 'VNACC' or 'VNIMU', not {kind!r}")


def encode(frame: Frame, kind: str = "VNIMU", checksum: str = "xor") -> bytes:
    return sentence(format_body(frame, kind), checksum)


def quantise(frame: Frame, kind: str = "VNIMU") -> Frame:
    """The frame as a receiver decodes it, keeping ``seq`` and ``time_s`` (which the
    receiver counts itself)."""
    w, t = _decode(format_body(frame, kind).split(b","))
    return Frame(frame.seq, frame.time_s, w, t)


def _decode(parts):
    """(w in g, t) of a VNACC / VNIMU body split at commas; ValueError when malformed."""
    head = parts[0]
    if head == b"VNACC" and len(parts) == 4:
        acc = [float(v) for v in parts[1:4]]
        t = (math.nan,) * 3
    elif head == b"VNIMU" and len(parts) == 12:
        vals = [float(v) for v in parts[1:12]]
        acc = vals[3:6]
        t = (vals[9],) * 3
    else:
        raise ValueError("not a VNACC / VNIMU sentence")
    if not all(math.isfinite(a) for a in acc):
        raise ValueError("non-finite acceleration")
    return tuple(a / G_CONVERSION_M_S2 for a in acc), t


def _checksum_ok(body: bytes, cs: bytes) -> Optional[bool]:
    """True good, False bad, None 'XX' (no check)."""
    if cs == b"XX":
        return None
    if not cs or not set(cs) <= _HEXDIGITS:
        return False
    if len(cs) == 2:
        return int(cs, 16) == xor_checksum(body)
    if len(cs) == 4:
        return int(cs, 16) == crc16(body)
    return False


class Parser:
    """Streaming decoder of VectorNav sentences (see the module docstring).

    ``rate_hz`` sets the clock of the frames (``time_s = seq / rate_hz``);
    ``accept_unchecked`` accepts ``*XX`` sentences (counted in ``unchecked``);
    ``keep_raw`` keeps the bytes of every accepted frame in ``raw`` (for tests).
    """

    def __init__(self, rate_hz: float = 40.0, accept_unchecked: bool = True, keep_raw: bool = False):
        self.buf = b""
        self.stats = ParserStats()
        self.rate_hz = float(rate_hz)
        self.accept_unchecked = accept_unchecked
        self.keep_raw = keep_raw
        self.raw: list[bytes] = []
        self.replies: deque = deque(maxlen=256)   # (type, [fields as str]) of non-frame sentences
        self.errors: Counter = Counter()          # $VNERR codes seen
        self.unchecked = 0
        self.count = 0

    def feed(self, data: bytes) -> list[Frame]:
        buf = self.buf + bytes(data)
        out: list[Frame] = []
        stats = self.stats
        n = len(buf)
        start = buf.find(b"$")
        if start < 0:
            stats.garbage_bytes += n
            self.buf = b""
            return out
        stats.garbage_bytes += start
        while True:
            end = buf.find(b"\n", start)
            limit = end if end >= 0 else n
            nxt = buf.find(b"$", start + 1, limit)
            if nxt >= 0:                       # a new '$' before the line end: damaged sentence
                stats.corrupted += 1
                start = nxt
                continue
            if end < 0:
                if n - start > MAX_SENTENCE:   # no terminator in sight: damaged
                    stats.corrupted += 1
                    stats.garbage_bytes += n - start - 1
                    self.buf = b""
                    return out
                self.buf = buf[start:]
                return out
            self._sentence(buf[start:end + 1], out)
            start = end + 1
            nxt = buf.find(b"$", start)
            if nxt < 0:
                stats.garbage_bytes += n - start
                self.buf = b""
                return out
            stats.garbage_bytes += nxt - start
            start = nxt

    def _sentence(self, s: bytes, out: list) -> None:
        stats = self.stats
        star = s.rfind(b"*")
        if star < 0 or not s.endswith(b"\r\n"):
            stats.corrupted += 1
            return
        body, cs = s[1:star], s[star + 1:-2]
        ok = _checksum_ok(body, cs)
        if ok is False or (ok is None and not self.accept_unchecked):
            stats.corrupted += 1
            return
        parts = body.split(b",")
        head = parts[0]
        if len(head) != 5 or not head.startswith(b"VN"):
            stats.corrupted += 1
            return
        if head in (b"VNACC", b"VNIMU"):
            try:
                w, t = _decode(parts)
            except ValueError:
                stats.corrupted += 1
                return
            if ok is None:
                self.unchecked += 1
            f = Frame(self.count, self.count / self.rate_hz, w, t)
            self.count += 1
            stats.frames += 1
            if self.keep_raw:
                self.raw.append(s)
            out.append(f)
            return
        try:
            fields = [p.decode("ascii") for p in parts[1:]]
        except UnicodeDecodeError:
            stats.corrupted += 1
            return
        kind = head[2:].decode("ascii")
        if kind == "ERR":
            try:
                self.errors[int(fields[0])] += 1
            except (IndexError, ValueError):
                self.errors[-1] += 1
        self.replies.append((kind, fields))


# -- the driver's side: configuration on open ------------------------------------------
def error_text(code) -> str:
    try:
        c = int(code)
    except (TypeError, ValueError):
        return f"$VNERR {code}"
    return f"$VNERR,{c:02d} ({ERROR_NAMES.get(c, 'unknown code')})"


def _register_reply(register: int, what: str):
    def accept(reply):
        kind, fields = reply
        if kind == "ERR":
            code = fields[0] if fields else "?"
            raise DeviceError("vectornav", f"VectorNav refused {what}: {error_text(code)}", code, what)
        if kind in ("WRG", "RRG") and fields:
            try:
                return int(fields[0]) == register
            except ValueError:
                return False
        return False
    return accept


def configure(link: Link, parser: Parser, rate_hz: float, output: str = "VNIMU", timeout_s: float = 0.5,
              checksum: str = "xor") -> list[Frame]:
    """Set the asynchronous output: ``$VNWRG,06,<type>`` then ``$VNWRG,07,<rate>``, each
    confirmed by its echo; a ``$VNERR`` raises :class:`DeviceError` naming the code.
    Returns the frames that arrived meanwhile."""
    frames: list[Frame] = []
    rate = int(rate_hz) if float(rate_hz).is_integer() else rate_hz
    for reg, value, what in ((REG_OUTPUT_TYPE, OUTPUT_TYPES[output], f"output type {output}"),
                             (REG_OUTPUT_RATE, rate, f"output rate {rate} Hz")):
        exchange(link, parser, write_register(reg, value, checksum=checksum), _register_reply(reg, what),
                 timeout_s, frames, "vectornav", f"$VNWRG,{reg:02d} ({what})")
    parser.rate_hz = float(rate_hz)
    return frames


# -- the instrument's side: what the emulator answers ----------------------------------
class Emulated:
    """A VN-100 as the emulator plays it: registers 6 and 7 (read / write, echoed), its
    outputs and replies checked by ``checksum`` ('xor' or 'crc', as register 30 would set;
    register 30 itself, seven fields, is not emulated), $VNERR for a bad checksum (03), an
    unknown command (04), an unknown register (08) or a value out of range (07). Starts sending VNACC at ``rate_hz`` (a real unit ships with
    VNYMR at 40 Hz; the driver configures whatever it finds)."""

    def __init__(self, rate_hz: float = 40.0, checksum: str = "xor"):
        self.registers = {REG_OUTPUT_TYPE: ASYNC_VNACC, REG_OUTPUT_RATE: rate_hz}
        self.checksum = checksum
        self.buf = b""
        self.commands = []

    @property
    def streaming(self) -> bool:
        return self.registers[REG_OUTPUT_TYPE] in (ASYNC_VNACC, ASYNC_VNIMU)

    @property
    def rate_hz(self) -> float:
        return float(self.registers[REG_OUTPUT_RATE])

    def _cs(self) -> str:
        return self.checksum

    def encode(self, frame: Frame) -> bytes:
        kind = "VNACC" if self.registers[REG_OUTPUT_TYPE] == ASYNC_VNACC else "VNIMU"
        return encode(frame, kind, self._cs())

    def quantise(self, frame: Frame) -> Frame:
        return quantise(frame, "VNACC" if self.registers[REG_OUTPUT_TYPE] == ASYNC_VNACC else "VNIMU")

    def feed(self, data: bytes) -> bytes:
        """Replies to the complete commands in ``data`` (any chunking)."""
        self.buf += data
        out = []
        while b"\n" in self.buf:
            line, self.buf = self.buf.split(b"\n", 1)
            k = line.rfind(b"$")
            if k < 0:
                continue
            out.append(self._command(line[k:].rstrip(b"\r")))
        if len(self.buf) > MAX_SENTENCE:
            self.buf = b""
        return b"".join(out)

    def _command(self, s: bytes) -> bytes:
        star = s.rfind(b"*")
        if star < 0:
            return error_reply(3)
        body = s[1:star]
        if _checksum_ok(body, s[star + 1:]) is False:
            return error_reply(3)
        self.commands.append(body.decode("ascii", "replace"))
        parts = body.decode("ascii", "replace").split(",")
        if parts[0] not in ("VNWRG", "VNRRG") or len(parts) < 2:
            return error_reply(4)
        try:
            reg = int(parts[1])
        except ValueError:
            return error_reply(8)
        if reg not in self.registers:
            return error_reply(8)
        if parts[0] == "VNRRG":
            if len(parts) != 2:
                return error_reply(6)
            return sentence(f"VNRRG,{reg:02d},{_values([self.registers[reg]])}", self._cs())
        if len(parts) != 3:
            return error_reply(5 if len(parts) < 3 else 6)
        try:
            value = float(parts[2])
        except ValueError:
            return error_reply(7)
        if (reg == REG_OUTPUT_TYPE and value not in OUTPUT_TYPES.values()) or \
                (reg == REG_OUTPUT_RATE and value not in RATES_HZ):
            return error_reply(7)
        self.registers[reg] = int(value)
        return sentence(body, self._cs())     # a write is echoed
