"""Xsens MTi Xbus protocol (document MT0101P): MTData2 output, configuration messages.

Message: ``FA | FF (bus id) | MID | LEN | DATA | CS``; LEN = 0xFF announces a 2-byte
big-endian length after it; CS makes the sum of every byte from the bus id through CS
≡ 0 (mod 256). Acknowledgement = MID + 1; error = MID 0x42 with an error code.

MTData2 (MID 0x36) is a sequence of ``[XDI u16][size u8][big-endian data]``; the low 2 bits
of the XDI give the number format (0 float32, 1 fp12.20, 2 fp16.32, 3 float64), bits 2-3
the coordinate frame. Used here: 0x4020 acceleration (m/s^2), 0x0810 temperature (degC),
0x1060 SampleTimeFine (u32, 10 kHz ticks), 0x1020 packet counter (u16).

``Frame.w`` is the acceleration in g (m/s^2 divided by the conversion constant 9.80665);
``seq`` is the packet counter unwrapped past 65535 (or, without one, the count of frames);
``time_s`` SampleTimeFine / 10 kHz unwrapped past 2^32 ticks (or ``seq / rate_hz``). The one
temperature fills t_x, t_y, t_z; it usually comes at a lower rate (1 Hz here by default:
the limit differs by model), so each frame carries the latest temperature received (NaN
before the first). A packet without acceleration gives no frame.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from typing import Iterable, Sequence

from . import (G_CONVERSION_M_S2, TEMPERATURE_SINGLE, DeviceError, Frame, Link, ParserStats, exchange)

OUTPUT_UNIT = "g"
TEMPERATURE = TEMPERATURE_SINGLE
CLOCK = "seq the packet counter (0x1020), time_s SampleTimeFine (0x1060) / 10 kHz, both unwrapped"

PREAMBLE, BID = 0xFA, 0xFF
SYNC = bytes((PREAMBLE, BID))
MID_REQ_DID, MID_GOTO_MEASUREMENT, MID_GOTO_CONFIG = 0x00, 0x10, 0x30
MID_SET_OUTPUT_CONFIGURATION, MID_MTDATA2, MID_ERROR = 0xC0, 0x36, 0x42
XDI_ACCELERATION, XDI_TEMPERATURE = 0x4020, 0x0810
XDI_PACKET_COUNTER, XDI_SAMPLE_TIME_FINE = 0x1020, 0x1060
#: frequency value meaning "with every packet" (as in the SetOutputConfiguration example)
EVERY_PACKET = 0xFFFF
#: longest DATA accepted (the extended length allows 65535; a claim beyond this is a false sync)
MAX_DATA = 2048
#: error codes as we read them in MT0101P (not verified against a device)
ERROR_NAMES = {0x03: "invalid period", 0x04: "invalid message", 0x1E: "timer overflow",
               0x20: "invalid baud rate", 0x21: "invalid parameter", 0x28: "device error"}
FORMATS = {0: "float32", 1: "fp12.20", 2: "fp16.32", 3: "float64"}
_FMT_SIZE = {0: 4, 1: 4, 2: 6, 3: 8}


def message(mid: int, data: bytes = b"") -> bytes:
    """One Xbus message with its checksum (extended length from 255 data bytes on)."""
    data = bytes(data)
    if len(data) < 0xFF:
        head = bytes((BID, mid, len(data)))
    else:
        head = bytes((BID, mid, 0xFF)) + struct.pack(">H", len(data))
    body = head + data
    return bytes((PREAMBLE,)) + body + bytes(((-sum(body)) & 0xFF,))


def go_to_config() -> bytes:
    """``FA FF 30 00 D1``."""
    return message(MID_GOTO_CONFIG)


def go_to_measurement() -> bytes:
    """``FA FF 10 00 F1``."""
    return message(MID_GOTO_MEASUREMENT)


def req_did() -> bytes:
    """``FA FF 00 00 01``."""
    return message(MID_REQ_DID)


def set_output_configuration(items: Iterable[tuple]) -> bytes:
    """SetOutputConfiguration: MID 0xC0 + N × (XDI u16, frequency u16)."""
    return message(MID_SET_OUTPUT_CONFIGURATION, b"".join(struct.pack(">HH", x, f) for x, f in items))


def output_configuration(rate_hz: float, temperature_hz: float = 1.0, fmt: int = 0) -> list:
    """The items the driver asks for: acceleration at ``rate_hz`` (format ``fmt``),
    temperature at ``temperature_hz``, SampleTimeFine and packet counter with every packet."""
    return [(XDI_PACKET_COUNTER, EVERY_PACKET), (XDI_SAMPLE_TIME_FINE, EVERY_PACKET),
            (XDI_ACCELERATION | fmt, int(round(rate_hz))), (XDI_TEMPERATURE, int(round(temperature_hz)))]


def encode_reals(values: Sequence[float], fmt: int) -> bytes:
    """Big-endian reals in the XDI number format ``fmt`` (0..3)."""
    if fmt == 0:
        return struct.pack(f">{len(values)}f", *values)
    if fmt == 3:
        return struct.pack(f">{len(values)}d", *values)
    out = b""
    for v in values:
        if fmt == 1:
            out += struct.pack(">i", int(round(v * (1 << 20))))
        else:
            raw = int(round(v * (1 << 32)))
            out += struct.pack(">Ih", raw & 0xFFFFFFFF, raw >> 32)
    return out


def decode_reals(data: bytes, fmt: int) -> list:
    size = _FMT_SIZE[fmt]
    if len(data) % size:
        raise ValueError(f"{len(data)} bytes are not a whole number of {FORMATS[fmt]}")
    if fmt == 0:
        return list(struct.unpack(f">{len(data) // 4}f", data))
    if fmt == 3:
        return list(struct.unpack(f">{len(data) // 8}d", data))
    out = []
    for i in range(0, len(data), size):
        if fmt == 1:
            out.append(int.from_bytes(data[i:i + 4], "big", signed=True) / (1 << 20))
        else:
            frac = int.from_bytes(data[i:i + 4], "big")
            whole = int.from_bytes(data[i + 4:i + 6], "big", signed=True)
            out.append(whole + frac / (1 << 32))
    return out


def item(xdi: int, payload: bytes) -> bytes:
    return struct.pack(">HB", xdi, len(payload)) + payload


def mtdata2(frame: Frame, *, temperature: bool = True, counter: bool = True, sample_time: bool = True,
            fmt: int = 0) -> bytes:
    """MTData2 message for ``frame``: packet counter = seq mod 65536, SampleTimeFine =
    round(time_s × 10 kHz) mod 2^32, acceleration (w in g, sent in m/s^2) and temperature t[0]."""
    data = b""
    if counter:
        data += item(XDI_PACKET_COUNTER, struct.pack(">H", frame.seq & 0xFFFF))
    if sample_time:
        data += item(XDI_SAMPLE_TIME_FINE, struct.pack(">I", int(round(frame.time_s * 1e4)) & 0xFFFFFFFF))
    data += item(XDI_ACCELERATION | fmt, encode_reals([a * G_CONVERSION_M_S2 for a in frame.w], fmt))
    if temperature:
        data += item(XDI_TEMPERATURE, struct.pack(">f", frame.t[0]))
    return message(MID_MTDATA2, data)


def encode(frame: Frame) -> bytes:
    return mtdata2(frame)


def quantise(frame: Frame, fmt: int = 0) -> Frame:
    """The frame as a receiver decodes it (float32 acceleration and temperature)."""
    acc = decode_reals(encode_reals([a * G_CONVERSION_M_S2 for a in frame.w], fmt), fmt)
    t = struct.unpack(">f", struct.pack(">f", frame.t[0]))[0]
    return Frame(frame.seq, round(frame.time_s * 1e4) / 1e4, tuple(a / G_CONVERSION_M_S2 for a in acc), (t,) * 3)


def parse_mtdata2(data: bytes) -> dict:
    """{XDI without format bits: (format, raw bytes)}; ValueError when the items do not
    fill the message exactly."""
    out = {}
    i, n = 0, len(data)
    while i < n:
        if i + 3 > n:
            raise ValueError("truncated MTData2 item header")
        xdi = (data[i] << 8) | data[i + 1]
        size = data[i + 2]
        if i + 3 + size > n:
            raise ValueError("truncated MTData2 item")
        out[xdi & 0xFFF0] = (xdi & 0x3, bytes(data[i + 3:i + 3 + size]))
        i += 3 + size
    return out


class Parser:
    """Streaming decoder of Xbus messages (see the module docstring).

    Re-synchronises one byte after a failed preamble; a damaged message is counted once
    (when it follows a good one or starts where the next would have started). Messages
    other than MTData2 go to ``replies`` as ``(mid, data)``; error messages (0x42) are also
    counted in ``errors``. ``keep_raw`` keeps the bytes of each accepted MTData2 in ``raw``.
    """

    def __init__(self, rate_hz: float = 100.0, keep_raw: bool = False):
        self.buf = b""
        self.stats = ParserStats()
        self.rate_hz = float(rate_hz)
        self.keep_raw = keep_raw
        self.raw: list[bytes] = []
        self.replies: deque = deque(maxlen=256)
        self.errors = 0
        self.temperature = math.nan
        self.count = 0
        self.in_sync = True
        self.base = 0
        self.expect = -1
        self._pc = None          # last packet counter, and the 65536s added
        self._pc_hi = 0
        self._stf = None
        self._stf_hi = 0

    def feed(self, data: bytes) -> list[Frame]:
        buf = self.buf + bytes(data)
        out: list[Frame] = []
        stats = self.stats
        n = len(buf)
        pos = 0
        while True:
            k = buf.find(SYNC, pos)
            if k < 0:
                keep = 1 if n > pos and buf[-1] == PREAMBLE else 0
                stats.garbage_bytes += max(n - pos - keep, 0)
                self.buf = buf[n - keep:]
                self.base += n - keep
                return out
            stats.garbage_bytes += k - pos
            if k + 4 > n:
                return self._wait(buf, k, out)
            mid, ln, hdr = buf[k + 2], buf[k + 3], 4
            if ln == 0xFF:
                if k + 6 > n:
                    return self._wait(buf, k, out)
                ln, hdr = (buf[k + 4] << 8) | buf[k + 5], 6
            total = hdr + ln + 1
            good = ln <= MAX_DATA
            if good and k + total > n:
                return self._wait(buf, k, out)
            if good and sum(buf[k + 1:k + total]) & 0xFF == 0:
                ok = self._message(mid, buf[k + hdr:k + hdr + ln], buf[k:k + total], out)
                if ok:
                    self.in_sync = True
                    pos = k + total
                    continue
                stats.corrupted += 1
                self.in_sync = False
                self.expect = self.base + k + total
                pos = k + total
                continue
            if self.in_sync or self.base + k == self.expect:
                stats.corrupted += 1
                self.in_sync = False
                self.expect = self.base + k + (total if good else 1)
            stats.garbage_bytes += 1
            pos = k + 1

    def _wait(self, buf, k, out):
        self.buf = buf[k:]
        self.base += k
        return out

    def _message(self, mid: int, data: bytes, raw: bytes, out: list) -> bool:
        if mid != MID_MTDATA2:
            if mid == MID_ERROR:
                self.errors += 1
            self.replies.append((mid, bytes(data)))
            return True
        try:
            items = parse_mtdata2(data)
            acc = None
            if XDI_TEMPERATURE in items:
                fmt, b = items[XDI_TEMPERATURE]
                (temp,) = decode_reals(b, fmt)
            else:
                temp = None
            if XDI_ACCELERATION in items:
                fmt, b = items[XDI_ACCELERATION]
                acc = decode_reals(b, fmt)
                if len(acc) != 3 or not all(math.isfinite(a) for a in acc):
                    raise ValueError("acceleration is not three finite numbers")
            pc = items.get(XDI_PACKET_COUNTER)
            if pc is not None and len(pc[1]) != 2:
                raise ValueError("packet counter is not 2 bytes")
            stf = items.get(XDI_SAMPLE_TIME_FINE)
            if stf is not None and len(stf[1]) != 4:
                raise ValueError("SampleTimeFine is not 4 bytes")
        except (ValueError, struct.error):
            return False
        if temp is not None:
            self.temperature = temp
        self.stats.frames += 1 if acc is not None else 0
        if acc is None:
            return True
        if pc is not None:
            v = int.from_bytes(pc[1], "big")
            if self._pc is not None and v < self._pc:
                self._pc_hi += 1 << 16
            self._pc = v
            seq = self._pc_hi + v
        else:
            seq = self.count
        if stf is not None:
            v = int.from_bytes(stf[1], "big")
            if self._stf is not None and v < self._stf:
                self._stf_hi += 1 << 32
            self._stf = v
            time_s = (self._stf_hi + v) / 1e4
        else:
            time_s = self.count / self.rate_hz
        self.count += 1
        if self.keep_raw:
            self.raw.append(bytes(raw))
        out.append(Frame(seq, time_s, tuple(a / G_CONVERSION_M_S2 for a in acc), (self.temperature,) * 3))
        return True


# -- the driver's side: configuration on open ------------------------------------------
def error_text(code) -> str:
    if code is None:
        return "an error without a code"
    return f"error 0x{code:02X} ({ERROR_NAMES.get(code, 'unknown code')})"


def _ack(mid: int, what: str):
    def accept(reply):
        rmid, data = reply
        if rmid == MID_ERROR:
            code = data[0] if data else None
            raise DeviceError("xsens", f"Xsens MTi refused {what}: {error_text(code)}", code, what)
        return rmid == mid + 1
    return accept


def configure(link: Link, parser: Parser, rate_hz: float, temperature_hz: float = 1.0, fmt: int = 0,
              timeout_s: float = 0.5) -> list[Frame]:
    """GoToConfig, SetOutputConfiguration (:func:`output_configuration`), GoToMeasurement,
    each waiting for its acknowledgement (MID + 1); an error message (MID 0x42) raises
    :class:`DeviceError` naming the code. Returns the frames that arrived meanwhile."""
    frames: list[Frame] = []
    items = output_configuration(rate_hz, temperature_hz, fmt)
    for mid, msg, what in ((MID_GOTO_CONFIG, go_to_config(), "GoToConfig"),
                           (MID_SET_OUTPUT_CONFIGURATION, set_output_configuration(items),
                            f"SetOutputConfiguration (acceleration {rate_hz:g} Hz, temperature {temperature_hz:g} Hz)"),
                           (MID_GOTO_MEASUREMENT, go_to_measurement(), "GoToMeasurement")):
        exchange(link, parser, msg, _ack(mid, what), timeout_s, frames, "xsens", what)
    parser.rate_hz = float(rate_hz)
    return frames


# -- the instrument's side: what the emulator answers ----------------------------------
class Emulated:
    """An MTi as the emulator plays it: starts in measurement mode sending counter,
    SampleTimeFine and acceleration at ``rate_hz``; GoToConfig stops the output,
    SetOutputConfiguration (config mode only) takes acceleration (any format), temperature,
    SampleTimeFine and packet counter at frequencies that divide the output rate (else
    error 0x21) and acknowledges with the configuration, GoToMeasurement starts the output.
    An unknown MID is answered with error 0x04 (codes as we read MT0101P)."""

    MAX_HZ = 400

    def __init__(self, rate_hz: float = 100.0):
        self.config_mode = False
        self.config = [(XDI_PACKET_COUNTER, EVERY_PACKET), (XDI_SAMPLE_TIME_FINE, EVERY_PACKET),
                       (XDI_ACCELERATION, int(rate_hz))]
        self.buf = b""
        self.parser = Parser()
        self.packets = 0
        self.commands = []

    @property
    def streaming(self) -> bool:
        return not self.config_mode and any(x & 0xFFF0 == XDI_ACCELERATION for x, _ in self.config)

    @property
    def rate_hz(self) -> float:
        return float(next(f for x, f in self.config if x & 0xFFF0 == XDI_ACCELERATION))

    def _fmt(self) -> int:
        return next(x & 3 for x, _ in self.config if x & 0xFFF0 == XDI_ACCELERATION)

    def _has(self, xdi) -> bool:
        return any(x & 0xFFF0 == xdi for x, _ in self.config)

    def encode(self, frame: Frame) -> bytes:
        temp_hz = next((f for x, f in self.config if x & 0xFFF0 == XDI_TEMPERATURE), 0)
        every = max(1, int(round(self.rate_hz / temp_hz))) if temp_hz and temp_hz != EVERY_PACKET else 1
        with_temp = bool(temp_hz) and self.packets % every == 0
        self.packets += 1
        return mtdata2(frame, temperature=with_temp, counter=self._has(XDI_PACKET_COUNTER),
                       sample_time=self._has(XDI_SAMPLE_TIME_FINE), fmt=self._fmt())

    def quantise(self, frame: Frame) -> Frame:
        return quantise(frame, self._fmt())

    def feed(self, data: bytes) -> bytes:
        self.parser.feed(data)
        out = []
        while self.parser.replies:
            mid, body = self.parser.replies.popleft()
            self.commands.append(mid)
            out.append(self._command(mid, body))
        return b"".join(out)

    def _command(self, mid: int, body: bytes) -> bytes:
        if mid == MID_GOTO_CONFIG:
            self.config_mode = True
            return message(mid + 1)
        if mid == MID_GOTO_MEASUREMENT:
            self.config_mode = False
            self.packets = 0
            return message(mid + 1)
        if mid == MID_REQ_DID:
            return message(mid + 1, struct.pack(">I", 0x03780000))
        if mid == MID_SET_OUTPUT_CONFIGURATION:
            if not self.config_mode or len(body) % 4:
                return message(MID_ERROR, bytes((0x04,)))
            items = [struct.unpack_from(">HH", body, i) for i in range(0, len(body), 4)]
            known = (XDI_ACCELERATION, XDI_TEMPERATURE, XDI_PACKET_COUNTER, XDI_SAMPLE_TIME_FINE)
            for x, f in items:
                if x & 0xFFF0 not in known or (f != EVERY_PACKET and (f <= 0 or f > self.MAX_HZ
                                                                      or self.MAX_HZ % f)):
                    return message(MID_ERROR, bytes((0x21,)))
            if not any(x & 0xFFF0 == XDI_ACCELERATION and f != EVERY_PACKET for x, f in items):
                return message(MID_ERROR, bytes((0x21,)))
            self.config = items
            return message(mid + 1, body)
        return message(MID_ERROR, bytes((0x04,)))
