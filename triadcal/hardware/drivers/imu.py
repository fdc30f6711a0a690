"""IMU readout driver: a stream of frames over a serial line, surviving disconnects.

:class:`ImuReadout` is the interface (open, read, close, stats); :class:`SerialImu`
implements it over pyserial with any wire protocol of ``protocols`` (the generic
``nmea`` / ``binary`` and the vendors' ``vectornav`` / ``xsens`` / ``mip``, which it
configures on every open); :class:`StreamThread` reads
any readout in the background into a queue so that the campaign runner can command
the bench and chamber without the stream overflowing.
"""

from __future__ import annotations

import dataclasses
import queue
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Optional

import serial

from ...errors import TriadcalError

from ..protocols import (VENDOR_PROTOCOLS, DeviceError, Frame, Link, ParserStats, get_protocol,
                         protocol_info)


class ImuPortError(TriadcalError, OSError):
    """The IMU's serial port cannot be opened."""


@dataclass
class LinkStats:
    """Events of the link (beyond the parser's counts)."""

    reconnects: int = 0
    disconnects: int = 0
    stalls: int = 0
    bytes_read: int = 0
    events: list = field(default_factory=list)   # (wall time, text)

    def note(self, text: str) -> None:
        self.events.append((time.time(), text))


class ImuReadout(ABC):
    """An IMU / accelerometer readout that delivers :class:`Frame` objects."""

    @abstractmethod
    def open(self) -> None: ...

    @abstractmethod
    def read(self) -> list[Frame]:
        """Frames received since the last call (possibly none); waits at most briefly.
        Must not raise on a lost link: reconnect and count it instead."""

    @abstractmethod
    def close(self) -> None: ...

    @property
    @abstractmethod
    def parser_stats(self) -> ParserStats: ...

    @property
    @abstractmethod
    def link_stats(self) -> LinkStats: ...


class SerialImu(ImuReadout):
    """Frames over a serial port (pyserial), ``protocol`` one of ``protocols.PROTOCOLS``.

    The vendor protocols are configured on every open (a replugged instrument starts from
    its defaults): ``vectornav`` $VNWRG,06 (output type, ``output`` 'VNIMU' by default: it
    carries the temperature) and $VNWRG,07 (``rate_hz``), each confirmed by its echo;
    ``xsens`` GoToConfig, SetOutputConfiguration (acceleration at ``rate_hz``, temperature at
    ``temperature_hz``, SampleTimeFine, packet counter), GoToMeasurement, each acknowledged;
    ``mip`` a Ping answered by its ACK. A refusal ($VNERR, Xsens error 0x42, MIP NACK) raises
    :class:`~triadcal.hardware.protocols.DeviceError` naming the code; no answer raises it
    with ``code`` None at the first open and counts as a lost link on a reopen.
    ``options`` go to the protocol's ``configure`` (e.g. ``output``, ``temperature_hz``,
    ``timeout_s``); ``configure=False`` skips it. ``output_unit`` and ``temperature`` say
    what the frames carry (``protocols.protocol_info``).

    A read error (cable pulled, USB adapter gone) closes the port and reopens it as
    soon as it is back; no data for ``stall_timeout_s`` counts as a stall and the port is
    reopened (a stalled instrument often resumes on a fresh open).
    """

    def __init__(self, port: str, protocol: str = "nmea", baudrate: int = 921600,
                 stall_timeout_s: float = 1.0, poll_s: float = 0.02, rate_hz: Optional[float] = None,
                 configure: bool = True, **options):
        self.port, self.baudrate = port, baudrate
        self.protocol = protocol
        self._codec = get_protocol(protocol)
        self.vendor = protocol in VENDOR_PROTOCOLS
        if self.vendor:
            self.rate_hz = float(rate_hz) if rate_hz else 100.0 if protocol != "vectornav" else 40.0
            self._parser = self._codec.Parser(rate_hz=self.rate_hz)
        else:
            if options:
                raise TypeError(f"protocol {protocol!r} takes no options ({', '.join(options)})")
            self.rate_hz = rate_hz
            self._parser = self._codec.Parser()
        self.configure = configure and self.vendor
        self.options = options
        info = protocol_info(protocol)
        self.output_unit, self.temperature = info["output_unit"], info["temperature"]
        self._pending: list[Frame] = []
        self._link = LinkStats()
        self.stall_timeout_s = stall_timeout_s
        self.poll_s = poll_s
        self._ser: Optional[serial.Serial] = None
        self._last_data = time.monotonic()

    @property
    def parser_stats(self) -> ParserStats:
        return self._parser.stats

    @property
    def link_stats(self) -> LinkStats:
        return self._link

    def open(self) -> None:
        try:
            self._ser = serial.Serial(self.port, self.baudrate, timeout=self.poll_s)
        except (OSError, serial.SerialException, ValueError) as exc:
            # a missing IMU port was an internal error, exit 70 (an outside probe); the bench's and the
            # chamber's said "cannot open the ... port" (an OSError: a reopen during the run keeps trying)
            raise ImuPortError(f"cannot open the IMU's port {self.port}: {exc}") from None
        self._last_data = time.monotonic()
        if self.configure:
            try:
                self._pending.extend(self._configure(self._ser))
            except BaseException:
                self.close()
                raise

    def _configure(self, ser) -> list[Frame]:
        def read() -> bytes:
            data = ser.read(ser.in_waiting or 1)
            if data:
                self._link.bytes_read += len(data)
            return data

        def write(data: bytes) -> None:
            ser.write(data)
            ser.flush()

        frames = self._codec.configure(Link(write, read), self._parser, self.rate_hz, **self.options)
        self._link.note(f"configured {self.protocol} on {self.port}")
        return frames

    def close(self) -> None:
        if self._ser is not None:
            try:
                self._ser.close()
            except (OSError, serial.SerialException):
                pass
            self._ser = None

    def _reopen(self) -> None:
        self.close()
        try:
            self.open()
            self._link.reconnects += 1
            self._link.note(f"reopened {self.port}")
        except (OSError, serial.SerialException):
            time.sleep(self.poll_s)
        except DeviceError as exc:
            if exc.code is not None:       # the instrument refused: not a link problem
                raise
            self._link.note(f"no answer from {self.port} while configuring: {exc}")
            time.sleep(self.poll_s)

    def read(self) -> list[Frame]:
        if self._pending:
            out, self._pending = self._pending, []
            self._last_data = time.monotonic()
            return out
        if self._ser is None:
            self._reopen()
            if self._ser is None:
                return []
        ser = self._ser
        try:
            data = ser.read(ser.in_waiting or 1)
            if data:
                more = ser.in_waiting
                if more:
                    data += ser.read(more)
        except (OSError, serial.SerialException, TypeError) as exc:
            self._link.disconnects += 1
            self._link.note(f"lost {self.port}: {exc}")
            self.close()
            return []
        now = time.monotonic()
        if not data:
            if now - self._last_data > self.stall_timeout_s:
                self._link.stalls += 1
                self._link.note(f"no data from {self.port} for {self.stall_timeout_s:g} s: reopening")
                self._reopen()
            return []
        self._last_data = now
        self._link.bytes_read += len(data)
        # the arrival time of the bytes: the capture tells a stall (silence on the wall clock as long
        # as the instrument's clock jumped) from a clock step by it (hardware/runner.py)
        return [dataclasses.replace(f, wall_s=now) for f in self._parser.feed(data)]


class StreamThread(threading.Thread):
    """Reads an :class:`ImuReadout` in the background into ``frames`` (a queue of lists)."""

    def __init__(self, readout: ImuReadout):
        super().__init__(daemon=True, name="imu-reader")
        self.readout = readout
        self.frames: "queue.Queue[list[Frame]]" = queue.Queue()
        self._stop_event = threading.Event()
        self.error: Optional[BaseException] = None

    def run(self) -> None:
        try:
            while not self._stop_event.is_set():
                got = self.readout.read()
                if got:
                    self.frames.put(got)
        except BaseException as exc:   # surfaced to the campaign runner by get()
            self.error = exc

    def get(self, timeout: float) -> list[Frame]:
        """Frames available now, waiting up to ``timeout`` s for the first batch."""
        if self.error is not None:
            raise RuntimeError(f"IMU reader stopped: {self.error}") from self.error
        out: list[Frame] = []
        try:
            out.extend(self.frames.get(timeout=timeout))
            while True:
                out.extend(self.frames.get_nowait())
        except queue.Empty:
            pass
        return out

    def stop(self) -> None:
        self._stop_event.set()
        self.join(timeout=2.0)
        self.readout.close()
