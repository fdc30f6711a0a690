"""IMU readout driver: a stream of frames over a serial line, surviving disconnects.

:class:`ImuReadout` is the interface (open, read, close, stats); :class:`SerialImu`
implements it over pyserial with either wire protocol; :class:`StreamThread` reads
any readout in the background into a queue so that the campaign runner can command
the bench and chamber without the stream overflowing.
"""

from __future__ import annotations

import queue
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Optional

import serial

from ..protocols import Frame, ParserStats, get_protocol


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
    """Frames over a serial port (pyserial), ``protocol`` 'nmea' or 'binary'.

    A read error (cable pulled, USB adapter gone) closes the port and reopens it as
    soon as it is back; no data for ``stall_timeout_s`` counts as a stall and the port is
    reopened (a stalled instrument often resumes on a fresh open).
    """

    def __init__(self, port: str, protocol: str = "nmea", baudrate: int = 921600,
                 stall_timeout_s: float = 1.0, poll_s: float = 0.02):
        self.port, self.baudrate = port, baudrate
        self.protocol = protocol
        self._parser = get_protocol(protocol).Parser()
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
        self._ser = serial.Serial(self.port, self.baudrate, timeout=self.poll_s)
        self._last_data = time.monotonic()

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

    def read(self) -> list[Frame]:
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
        return self._parser.feed(data)


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
