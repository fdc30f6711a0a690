"""Chamber drivers for documented controllers, through real pseudo-terminals.

* Watlow F4 / F4T (minimalmodbus) against an independent Modbus implementation: a pymodbus RTU
  server on one end of a pty pair whose PV follows the set point by a first-order lag updated
  in a thread; the bytes on the line are compared with the manual's frames, whose CRC is
  recomputed here by a bitwise CRC-16/MODBUS written from its definition.
* The same drivers against triadcal's own Watlow emulator (chamber_emulators.WatlowEmulator).
* Espec ASCII against chamber_emulators.EspecEmulator (address prefix, NA: errors, lag).
"""

import asyncio
import math
import os
import select
import struct
import threading
import time
import tty

import pytest

from triadcal.hardware.chamber_emulators import EspecEmulator, FirstOrderLag, WatlowEmulator
from triadcal.hardware.drivers.chamber import ChamberError, open_chamber
from triadcal.hardware.drivers.espec import EspecChamber, EspecCommandError
from triadcal.hardware.drivers.watlow import (WatlowF4, WatlowF4T, f4_register, float_to_words, read_holding_frame,
                                              rtu_frame, words_to_float, write_multiple_frame, write_single_frame)

READ_PV = bytes.fromhex("01 03 00 64 00 01 C5 D5")        # instruments.md, Watlow F4
WRITE_SP_25 = bytes.fromhex("01 06 01 2C 00 FA C9 BC")
MANUAL_READ_INPUTS = bytes.fromhex("01 02 00 01 00 02 A8 0B")
MANUAL_WRITE_7 = bytes.fromhex("01 06 00 07 2E E0 24 23")


def crc16_modbus_reference(data: bytes) -> int:
    """CRC-16/MODBUS bit by bit from its definition (reflected poly 0xA001, init 0xFFFF)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def crc_ok(frame: bytes) -> bool:
    return crc16_modbus_reference(frame[:-2]) == int.from_bytes(frame[-2:], "little")


# -- encoders against the manual --------------------------------------------------------
def test_reference_crc_and_encoders_give_the_manuals_frames():
    assert crc16_modbus_reference(b"123456789") == 0x4B37            # the catalogue's check value
    for frame in (READ_PV, WRITE_SP_25, MANUAL_READ_INPUTS, MANUAL_WRITE_7):
        assert crc_ok(frame), frame.hex(" ")
    assert read_holding_frame(1, 100) == READ_PV
    assert write_single_frame(1, 300, f4_register(25.0)) == WRITE_SP_25
    assert rtu_frame(1, 2, bytes.fromhex("0001 0002")) == MANUAL_READ_INPUTS
    assert write_single_frame(1, 7, 0x2EE0) == MANUAL_WRITE_7
    assert f4_register(-40.5) == struct.unpack(">H", struct.pack(">h", -405))[0]
    # F4T float: 25.0 = 0x41C80000, low word first -> 0000 41C8
    assert float_to_words(25.0) == (0x0000, 0x41C8)
    assert float_to_words(25.0, "high-first") == (0x41C8, 0x0000)
    assert words_to_float((0x0000, 0x41C8)) == 25.0
    assert write_multiple_frame(1, 2782, (0x0000, 0x41C8))[:11] == bytes.fromhex("01 10 0A DE 00 02 04 00 00 41 C8")
    with pytest.raises(ValueError):
        f4_register(4000.0)


# -- a pty pair: two ptys joined by a copying thread (what `socat pty pty` does) ---------
class PtyPair:
    def __init__(self):
        self.fds = [os.openpty(), os.openpty()]
        for _, slave in self.fds:
            tty.setraw(slave)
        self.paths = [os.ttyname(s) for _, s in self.fds]
        self.a_to_b = bytearray()            # bytes written on side A (the driver's side)
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self):
        ma, mb = self.fds[0][0], self.fds[1][0]
        while not self._stop.is_set():
            r, _, _ = select.select([ma, mb], [], [], 0.02)
            for fd in r:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue
                if fd == ma:
                    self.a_to_b += data
                os.write(mb if fd == ma else ma, data)

    def close(self):
        self._stop.set()
        self._t.join(1)
        for m, s in self.fds:
            os.close(m)
            os.close(s)


class ManualClock:
    """A clock the test advances (``advance``): the thermal models follow it, not the wall clock,
    so what a test reads does not depend on the machine's load."""

    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        self.t += dt


class LagModel:
    """The test's own thermal model: PV follows SP, stepped by a thread every 10 ms on ``clock``."""

    def __init__(self, pv=23.0, tau_s=0.4, clock=time.monotonic):
        self.pv, self.sp, self.tau_s = pv, pv, tau_s
        self.clock = clock
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self):
        last = self.clock()
        while not self._stop.wait(0.01):
            now = self.clock()
            self.pv += (self.sp - self.pv) * (1 - math.exp(-(now - last) / self.tau_s))
            last = now

    def stop(self):
        self._stop.set()
        self._t.join(1)


def start_pymodbus(model: str, port: str, lag: LagModel, stopbits: int):
    """A pymodbus RTU server (slave 1) with the F4 or F4T holding registers; the datastore
    action maps the test's LagModel to and from the registers with struct (not triadcal)."""
    from pymodbus import FramerType
    from pymodbus.server import ModbusSerialServer
    from pymodbus.simulator import DataType, SimData, SimDevice

    received = bytearray()

    def trace(sending: bool, data: bytes) -> bytes:
        if not sending:
            received.extend(data)
        return data

    if model == "f4":
        blocks = [SimData(100, values=0, datatype=DataType.UINT16), SimData(300, values=0, datatype=DataType.UINT16)]

        async def action(fc, start, address, count, registers, values):
            registers[100 - start] = struct.unpack(">H", struct.pack(">h", round(lag.pv * 10)))[0]
            if values is None:
                registers[300 - start] = struct.unpack(">H", struct.pack(">h", round(lag.sp * 10)))[0]
            elif address == 300:
                lag.sp = struct.unpack(">h", struct.pack(">H", values[0]))[0] / 10
            return None
    else:
        def words(v):            # low word first
            hi, lo = struct.unpack(">HH", struct.pack(">f", v))
            return [lo, hi]

        blocks = [SimData(2782, values=0, datatype=DataType.UINT16, count=2),
                  SimData(2820, values=0, datatype=DataType.UINT16, count=2)]

        async def action(fc, start, address, count, registers, values):
            registers[2820 - start:2822 - start] = words(lag.pv)
            if values is None:
                registers[2782 - start:2784 - start] = words(lag.sp)
            elif address == 2782 and len(values) == 2:
                lo, hi = values
                lag.sp = struct.unpack(">f", struct.pack(">HH", hi, lo))[0]
            return None

    loop = asyncio.new_event_loop()
    ready = threading.Event()
    box = {}

    def run():
        asyncio.set_event_loop(loop)

        async def main():
            server = box["server"] = ModbusSerialServer(
                SimDevice(1, simdata=blocks, action=action), framer=FramerType.RTU, port=port,
                baudrate=9600, stopbits=stopbits, trace_packet=trace)   # needs a running loop
            await server.serve_forever(background=True)
            ready.set()
            await server.serving

        loop.run_until_complete(main())

    t = threading.Thread(target=run, daemon=True)
    t.start()
    assert ready.wait(5), "pymodbus server did not start"

    def stop():
        asyncio.run_coroutine_threadsafe(box["server"].shutdown(), loop).result(5)
        t.join(5)

    return received, stop


@pytest.fixture
def pymodbus_chamber(request):
    model, stopbits = request.param
    pair = PtyPair()
    lag = LagModel(clock=ManualClock())
    received, stop = start_pymodbus(model, pair.paths[1], lag, stopbits)
    try:
        yield model, stopbits, pair, lag, received
    finally:
        stop()
        lag.stop()
        pair.close()


def wait_until(fn, timeout_s=30.0):
    """Poll ``fn`` every 20 ms; the timeout only guards against a hang (the models follow a
    ManualClock that ``fn`` advances, so the number of polls needed does not depend on the load)."""
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if fn():
            return True
        time.sleep(0.02)
    return False


@pytest.mark.parametrize("pymodbus_chamber", [("f4", 2), ("f4t", 1)], indirect=True, ids=["F4-8N2", "F4T-8N1"])
def test_watlow_drivers_against_pymodbus_server(pymodbus_chamber):
    model, stopbits, pair, lag, received = pymodbus_chamber
    cls = WatlowF4 if model == "f4" else WatlowF4T
    chamber = cls(pair.paths[0], baudrate=9600, stopbits=stopbits, timeout_s=0.5)
    try:
        assert chamber._inst.serial.stopbits == stopbits and chamber._inst.serial.baudrate == 9600
        assert chamber.temperature_C() == pytest.approx(23.0, abs=0.05)
        chamber.set_setpoint_C(25.0)
        assert lag.sp == 25.0 and chamber.setpoint_C() == 25.0
        # PV follows the set point with the model's lag: rising, never beyond it, then there
        seen = [chamber.temperature_C()]
        assert wait_until(lambda: lag.clock.advance(0.05) or seen.append(chamber.temperature_C())
                          or seen[-1] >= 24.95)
        assert all(b >= a - 0.05 for a, b in zip(seen, seen[1:])) and max(seen) <= 25.0 + 1e-6
        assert seen[0] < 24.9                                   # it was read on the way, not jumped
        chamber.set_setpoint_C(-40.5)
        assert lag.sp == pytest.approx(-40.5, abs=1e-6) and chamber.setpoint_C() == pytest.approx(-40.5, abs=1e-6)
    finally:
        chamber.close()
    wire = bytes(pair.a_to_b)
    assert wire == bytes(received)                              # what the driver sent is what pymodbus got
    if model == "f4":
        assert READ_PV in wire and WRITE_SP_25 in wire          # the manual's frames, byte for byte
        assert wire.startswith(READ_PV)
        assert write_single_frame(1, 300, 0xFE6B) in wire       # -40.5 -> -405 = 0xFE6B
    else:
        write_25 = bytes.fromhex("01 10 0A DE 00 02 04 00 00 41 C8")       # 2782, two words: 0000 41C8
        frame = write_25 + crc16_modbus_reference(write_25).to_bytes(2, "little")
        assert frame in wire and frame == write_multiple_frame(1, 2782, float_to_words(25.0))
        read_pv = bytes.fromhex("01 03 0B 04 00 02")                        # 2820, two registers
        assert wire.startswith(read_pv + crc16_modbus_reference(read_pv).to_bytes(2, "little"))


def test_f4t_word_order_high_first_is_configurable():
    with WatlowEmulator(FirstOrderLag(23.0, tau_s=1.0), model="f4t", word_order="high-first") as em:
        c = WatlowF4T(em.port, word_order="high-first")
        try:
            c.set_setpoint_C(25.0)
            assert em.setpoint == 25.0
            assert any(f.startswith(bytes.fromhex("01 10 0A DE 00 02 04 41 C8 00 00")) for f in em.frames)
        finally:
            c.close()
        c = WatlowF4T(em.port, word_order="low-first", retries=1)   # the wrong order reads garbage
        try:
            assert c.setpoint_C() != pytest.approx(25.0)
        finally:
            c.close()
    # ... which the set point's read-back cannot see (it decodes its own words the same wrong way);
    # the PV, a temperature, names the order (an outside probe's ramp ran on garbage). A chamber at
    # rest at 23.0 degC: its float's low word is 0, so read swapped it is 2.4e-41 (a PV with other
    # low bits may read swapped as a plausible number: the check sees most, not all, of them)
    with WatlowEmulator(FirstOrderLag(23.0, tau_s=1.0), model="f4t", word_order="high-first") as em:
        c = WatlowF4T(em.port, word_order="low-first", retries=1)
        try:
            with pytest.raises(ChamberError, match=r"reads .* with word_order = 'low-first' and 23 degC with "
                                                   r"'high-first': set word_order = 'high-first'"):
                c.temperature_C()
        finally:
            c.close()


@pytest.mark.parametrize("model", ["f4", "f4t"])
def test_watlow_emulator_with_minimalmodbus_driver_lag_and_errors(model):
    clock = ManualClock()
    lag = FirstOrderLag(20.0, tau_s=30.0, time_scale=150.0, clock=clock)   # tau 0.2 s of the test's clock
    with WatlowEmulator(lag, model=model, range_C=(-70.0, 180.0)) as em:
        chamber = open_chamber(em.config())
        try:
            assert isinstance(chamber, WatlowF4 if model == "f4" else WatlowF4T)
            chamber.set_setpoint_C(60.0)
            first = chamber.temperature_C()
            assert 20.0 <= first < 59.0
            assert wait_until(lambda: clock.advance(0.05) or chamber.temperature_C() > 59.9)
            with pytest.raises(ChamberError, match="refused by the controller"):
                chamber.set_setpoint_C(250.0)                # outside 602/603 (2774/2776): exception 3
            assert chamber.setpoint_C() == pytest.approx(60.0)
        finally:
            chamber.close()
        if model == "f4":
            assert em.frames[0] == write_single_frame(1, 300, 600)
            assert READ_PV in em.frames
    with pytest.raises(ChamberError, match="failed after"):     # nobody there: a clear error, not a hang
        with WatlowEmulator(model=model, slave=2) as em:
            c = open_chamber({**em.config(), "slave": 1, "timeout_s": 0.1})
            try:
                c.temperature_C()
            finally:
                c.close()


# -- Espec ASCII -------------------------------------------------------------------------
@pytest.mark.parametrize("address", [None, 1])
def test_espec_driver_against_emulator(address):
    clock = ManualClock()
    lag = FirstOrderLag(23.0, tau_s=30.0, time_scale=100.0, clock=clock)
    with EspecEmulator(lag, address=address, upper_C=100.0, lower_C=-50.0, mode="STANDBY") as em:
        chamber = open_chamber(em.config())
        assert isinstance(chamber, EspecChamber)
        try:
            assert chamber.frame("TEMP?") == (b"1,TEMP?\r\n" if address else b"TEMP?\r\n")
            assert chamber.temperature_C() == 23.0 and chamber.mode() == "STANDBY"
            chamber.set_setpoint_C(25.0)
            assert chamber.mode() == "CONSTANT"             # started, so the set point takes effect
            assert chamber.setpoint_C() == 25.0 and chamber.limits_C() == (100.0, -50.0)
            assert wait_until(lambda: clock.advance(0.05) or chamber.temperature_C() >= 24.9)
            mon = chamber.monitor()
            assert mon["mode"] == "CONSTANT" and mon["alarms"] == 0 and mon["humidity_pct"] is None
            with pytest.raises(EspecCommandError) as err:
                chamber.set_setpoint_C(120.0)
            assert err.value.command == "TEMP, S120.0" and err.value.message == "DATA OUT OF RANGE"
            assert "'TEMP, S120.0'" in str(err.value) and "NA:DATA OUT OF RANGE" in str(err.value)
            with pytest.raises(EspecCommandError, match="NA:CMD ERR"):
                chamber.query("HUMI, S50")
        finally:
            chamber.close()
        prefix = "1," if address else ""
        assert f"{prefix}TEMP, S25.0" in em.commands and f"{prefix}MODE, CONSTANT" in em.commands
        raw = bytes(em.received)
        assert (prefix + "TEMP, S25.0\r\n").encode() in raw and b"\r\n\r\n" not in raw


def test_espec_wrong_address_is_silence_and_a_clear_error():
    with EspecEmulator(address=2) as em:
        chamber = EspecChamber(em.port, address=1, timeout_s=0.2, retries=2)
        try:
            with pytest.raises(ChamberError, match="'TEMP\\?' failed after 2 tries: no answer"):
                chamber.temperature_C()
        finally:
            chamber.close()
    assert em.requests == 0


def test_espec_emulator_parses_a_manual_style_mon_answer():
    with EspecEmulator(humidity=100.0) as em:
        chamber = EspecChamber(em.port)
        try:
            mon = chamber.monitor()
        finally:
            chamber.close()
    assert mon == {"temperature_C": 23.0, "humidity_pct": 100.0, "mode": "CONSTANT", "alarms": 0}


def test_capture_chamber_slave_reaches_an_espec_chamber():
    """`capture --chamber-slave N` sets `slave`, which the Espec driver (it reads `address`)
    ignored silently; both spellings now give the RS-485 address."""
    from triadcal.hardware.drivers.chamber import open_chamber

    for cfg in ({"driver": "espec", "port": "loop://", "slave": 3}, {"driver": "espec", "port": "loop://", "address": 3}):
        c = open_chamber(cfg)
        try:
            assert c.address == 3
        finally:
            c.close()
