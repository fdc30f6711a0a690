"""A chamber that misbehaves, played by an independent Modbus implementation (a pymodbus RTU server
on a pty) beside the emulator's bench, meters and IMU: a sensor break, a PV that never reaches the
setpoint, a PV register that cannot be read, a line that goes away, and the ``modbus`` driver's
port and serial options. Each was found by an outside probe with its own device simulator:

- the analog (voltmeter) capture wrote a sensor break's -3276.8 degC into every row, exit 0, a
  campaign neither fit nor a resume could take; and never compared the PV with the setpoint;
- the IMU capture skipped the chamber check silently when the PV could not be read;
- an unplugged chamber line ended in "internal error" (termios.error is not an OSError);
- the ``modbus`` driver opened its port with plain pyserial (no URL, "internal error" for a
  missing device) and ignored ``timeout_s``, ``parity`` and ``stopbits``.
"""

from __future__ import annotations

import asyncio
import json
import os
import struct
import subprocess
import sys
import threading
import tty

import pytest

pytest.importorskip("pymodbus", reason="the independent Modbus server")

from triadcal.hardware.capture import CSV_NAME, EVENTS_NAME, REPORT_NAME
from triadcal.hardware.drivers.chamber import ChamberError, open_chamber
from triadcal.hardware.emulator import EmulatorTiming, emulate
from triadcal.hardware.storage import read_events

CLI = [sys.executable, "-m", "triadcal.cli"]
FAST = ["--settle-s", "2", "--stab-window-s", "30", "--stab-hold-s", "30", "--no-progress"]


class FixedChamber:
    """A pymodbus RTU server (slave 1) on a pty with triadcal's / the F4's map: PV at register 100
    pinned to ``pv`` (signed tenths by struct, not by triadcal; None: no register 100, so reading
    it is Modbus exception 2), the set point at 300 kept as written."""

    def __init__(self, pv, stopbits: int = 1, baudrate: int = 9600):
        from pymodbus import FramerType
        from pymodbus.server import ModbusSerialServer
        from pymodbus.simulator import DataType, SimData, SimDevice

        self.master, slave = os.openpty()
        tty.setraw(slave)
        self._slave_fd = slave
        self.path = os.ttyname(slave)
        self.pv, self.sp = pv, 20.0
        # the server opens the other side: a second pty joined to this one by a copying thread
        # would add nothing; pymodbus serves on the master's twin, the driver opens `path`
        self.server_master, server_slave = os.openpty()
        tty.setraw(server_slave)
        self.server_path = os.ttyname(server_slave)
        self._server_slave_fd = server_slave
        self._stop = threading.Event()
        self._pump = threading.Thread(target=self._copy, daemon=True)
        self._pump.start()
        words = lambda v: struct.unpack(">H", struct.pack(">h", round(v * 10)))[0]   # noqa: E731
        blocks = [SimData(300, values=0, datatype=DataType.UINT16)]
        if pv is not None:
            blocks.insert(0, SimData(100, values=0, datatype=DataType.UINT16))

        async def action(fc, start, address, count, registers, values):
            if self.pv is not None and start <= 100 < start + len(registers):
                registers[100 - start] = words(self.pv)
            if start <= 300 < start + len(registers):
                if values is None:
                    registers[300 - start] = words(self.sp)
                elif address == 300:
                    self.sp = struct.unpack(">h", struct.pack(">H", values[0]))[0] / 10
            return None

        self.loop = asyncio.new_event_loop()
        ready, box = threading.Event(), {}

        def run():
            asyncio.set_event_loop(self.loop)

            async def main():
                server = box["server"] = ModbusSerialServer(
                    SimDevice(1, simdata=blocks, action=action), framer=FramerType.RTU, port=self.server_path,
                    baudrate=baudrate, stopbits=stopbits)
                await server.serve_forever(background=True)
                ready.set()
                await server.serving

            self.loop.run_until_complete(main())

        self._box = box
        self._t = threading.Thread(target=run, daemon=True)
        self._t.start()
        assert ready.wait(5), "pymodbus server did not start"

    def _copy(self):
        import select

        a, b = self.master, self.server_master
        while not self._stop.is_set():
            r, _, _ = select.select([a, b], [], [], 0.02)
            for fd in r:
                try:
                    data = os.read(fd, 4096)
                    os.write(b if fd == a else a, data)
                except OSError:
                    continue

    def unplug(self):
        """The line goes away: the driver's side of the pty loses its other end."""
        self._stop.set()
        self._pump.join(1)
        os.close(self.master)
        self.master = None

    def close(self):
        asyncio.run_coroutine_threadsafe(self._box["server"].shutdown(), self.loop).result(5)
        self._t.join(5)
        self._stop.set()
        self._pump.join(1)
        for fd in (self.master, self._slave_fd, self.server_master, self._server_slave_fd):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass


@pytest.fixture
def chamber_server(request):
    srv = FixedChamber(*request.param)
    try:
        yield srv
    finally:
        srv.close()


@pytest.mark.parametrize("chamber_server", [(-12.3, 2)], indirect=True)
def test_modbus_driver_passes_the_serial_options_and_reads_negative_tenths(chamber_server):
    ch = open_chamber({"driver": "modbus", "port": chamber_server.path, "baudrate": 9600, "stopbits": 2,
                       "parity": "N", "timeout_s": 0.7})
    try:
        ser = ch._inst.serial
        assert (ser.baudrate, ser.stopbits, ser.parity, ser.timeout) == (9600, 2, "N", 0.7)
        assert ch.temperature_C() == pytest.approx(-12.3, abs=1e-9)
        ch.set_setpoint_C(-40.5)
        assert chamber_server.sp == pytest.approx(-40.5) and ch.setpoint_C() == pytest.approx(-40.5)
    finally:
        ch.close()


def test_modbus_driver_refuses_a_port_it_cannot_open_by_name():
    for port in ("/dev/ttyUSB-triadcal-none", "socket://127.0.0.1:1"):
        with pytest.raises(ChamberError, match="cannot open the chamber's port"):
            open_chamber({"driver": "modbus", "port": port})


@pytest.mark.parametrize("driver", ["modbus", "watlow-f4"])
@pytest.mark.parametrize("chamber_server", [(21.5, 1)], indirect=True)
def test_a_line_that_goes_away_is_a_chamber_error_naming_the_port(chamber_server, driver):
    ch = open_chamber({"driver": driver, "port": chamber_server.path, "baudrate": 9600, "timeout_s": 0.2})
    try:
        assert ch.temperature_C() == pytest.approx(21.5)
        chamber_server.unplug()
        with pytest.raises(ChamberError, match=chamber_server.path):
            ch.temperature_C()
    finally:
        ch.close()


def _instruments(em, chamber_path: str) -> str:
    """The emulator's instruments file with its chamber replaced by the pymodbus server."""
    text = (em.directory / "instruments.toml").read_text()
    text = text.replace(f'port = "{em.directory / "chamber"}"', f'port = "{chamber_path}"\nbaud = 9600')
    out = em.directory / "instruments_fixed.toml"
    out.write_text(text)
    return str(out)


def _two_positions(tmp_path) -> str:
    """A plan of two positions: what these tests judge is the chamber, not the unit."""
    p = tmp_path / "plan.csv"
    p.write_text("position,axis1_deg,axis2_deg\nP01,0,0\nP02,90,0\n")
    return str(p)


def _dmm_capture(tmp_path, chamber_path, setpoints):
    timing = EmulatorTiming(time_scale=600.0, self_heating_time_constant_s=60.0)
    em = emulate(tmp_path / "emu", effects=["bench_tilt"], timing=timing, seed=5, dmm=True).start()
    out = tmp_path / "campaign"
    try:
        r = subprocess.run(CLI + ["capture", "--instruments", _instruments(em, chamber_path), "--setpoints",
                                  setpoints, "--tau-s", "30", "--out", str(out), "--unit", em.truth.unit,
                                  "--plan", _two_positions(tmp_path)] + FAST,
                           capture_output=True, text=True, timeout=180)
    finally:
        em.stop()
    return r, out


@pytest.mark.parametrize("chamber_server", [(-3276.8, 1)], indirect=True)
def test_the_analog_capture_records_no_sensor_break(tmp_path, chamber_server):
    """PV 0x8000 (-3276.8 degC) is the unit's temperature on this path: refused before a row."""
    r, out = _dmm_capture(tmp_path, chamber_server.path, "20")
    assert r.returncode == 1, r.stderr
    assert "not a temperature" in r.stderr and "-3276.8" in r.stderr and "Traceback" not in r.stderr
    assert not (out / CSV_NAME).exists()
    # the sensor is fixed: the same command resumes and records temperatures
    chamber_server.pv = 20.0
    r, out = _dmm_capture(tmp_path / "again", chamber_server.path, "20")
    assert r.returncode == 0, r.stderr
    assert "-3276.8" not in (out / CSV_NAME).read_text()


@pytest.mark.parametrize("chamber_server", [(20.0, 1)], indirect=True)
def test_the_analog_capture_says_when_the_chamber_misses_its_setpoint(tmp_path, chamber_server):
    r, out = _dmm_capture(tmp_path, chamber_server.path, "20,-15")
    assert r.returncode == 0, r.stderr
    report = json.loads((out / REPORT_NAME).read_text())
    (w,) = report["warnings"]
    assert "setpoint -15 degC" in w and "PV is 20.00 degC, +35.00" in w
    missed = [e for e in read_events(out / EVENTS_NAME) if e["kind"] == "setpoint_missed"]
    assert [e["setpoint_C"] for e in missed] == [-15.0]
    assert chamber_server.sp == -15.0                       # the set point was written: the PV stayed


@pytest.mark.parametrize("chamber_server", [(None, 1)], indirect=True)
def test_the_imu_capture_says_when_the_pv_cannot_be_read(tmp_path, chamber_server):
    """Register 100 answers Modbus exception 2: the capture goes on on the unit's own sensors and
    says the chamber went unchecked."""
    # the emulator's unit stays at its start temperature (its chamber is not the one set): within
    # 10 degC of the set point; the IMU paced as in test_instruments_end_to_end.py
    timing = EmulatorTiming(time_scale=120.0, rate_hz=20.0, self_heating_time_constant_s=0.0)
    em = emulate(tmp_path / "emu", effects=["bench_tilt"], timing=timing, seed=3).start()
    out = tmp_path / "campaign"
    fast = list(FAST)
    fast[fast.index("--settle-s") + 1] = "10"
    try:
        r = subprocess.run(CLI + ["capture", "--instruments", _instruments(em, chamber_server.path), "--setpoints",
                                  "20", "--tau-s", "20", "--out", str(out), "--unit", em.truth.unit,
                                  "--plan", _two_positions(tmp_path)] + fast,
                           capture_output=True, text=True, timeout=300)
    finally:
        em.stop()
    assert r.returncode == 0, r.stderr
    report = json.loads((out / REPORT_NAME).read_text())
    assert any("PV could not be read" in w and "unit's own sensors only" in w for w in report["warnings"])


@pytest.mark.parametrize("chamber_server", [(24.5, 1)], indirect=True)
def test_a_ramp_whose_chamber_does_not_follow_the_program_says_so(tmp_path, chamber_server):
    """An outside probe: the ramp read the chamber's PV at its start soak only; a chamber that
    refused its set points (it held 24.5 degC while the program went 28 -> 10) left rows labelled by
    the program and no warning, exit 0. Here the chamber is a pymodbus server whose PV stays at
    24.5 degC whatever it is told: the ramp says, after its visits, that the PV was off the program."""
    from test_ramp_capture import ramp_on
    from triadcal.hardware.capture import load_port_config, open_instruments
    from triadcal.planning.ramp import RampPlan

    plan = RampPlan(program_C=(24.0, 0.0), rate_C_per_min=2.0, tau_s=20.0,
                    positions={"P01": (0.0, 0.0), "P02": (90.0, 0.0)})
    timing = EmulatorTiming(time_scale=500.0, rate_hz=2.0, self_heating_time_constant_s=0.0)
    em = emulate(tmp_path / "emu", effects=["bench_tilt"], timing=timing, seed=3).start()
    try:
        imu, bench, _ = open_instruments(load_port_config(em.directory / "ports.toml"))
        chamber = open_chamber({"driver": "modbus", "port": chamber_server.path, "baudrate": 9600})
        report = ramp_on(tmp_path / "out", plan, imu, bench, chamber)
    finally:
        em.stop()
    assert chamber_server.sp == 0.0                                  # the program was written to the end
    off = [w for w in report.warnings if "off the program" in w]
    assert off and "read 24.5 degC" in off[0], report.warnings
    kinds = [e["kind"] for e in read_events(tmp_path / "out" / "raw" / "events.jsonl")]
    assert "chamber_off_program" in kinds
