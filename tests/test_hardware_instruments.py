"""Issue 19, items 4 and 5: the bench by command template (drivers/bench_template.py, the
Newport ESP301 profile) against the emulator playing the same profile on a real pty, and the
instruments file of ``triadcal capture --instruments``, end to end."""

import subprocess
import sys
import time

import numpy as np
import pytest

from triadcal.errors import InputError
from triadcal.hardware.capture import CSV_NAME, load_instruments, open_bench
from triadcal.hardware.drivers.bench_template import (AxisSpec, BenchControllerError, BenchLimitError,
                                                      TemplateBench, angle_difference, load_profile, wrap_angle)
from triadcal.hardware.emulator import Emulator, EmulatorTiming, emulate
from triadcal.io.bench_csv import read_bench_csv

CLI = [sys.executable, "-m", "triadcal.cli"]
EXAMPLE = "examples/data/instruments.toml"


def start(tmp_path, profile, time_scale=20.0):
    timing = EmulatorTiming(time_scale=time_scale, self_heating_time_constant_s=0.0)
    return Emulator(tmp_path / "emu", timing=timing, bench_profile=profile).start()


def wait_in_position(bench, timeout_s=120.0):
    """Poll every 20 ms until the bench is in position; the timeout only guards against a hang (the
    move takes its emulated time, longer on a loaded machine; a busy loop, as before, took a core
    from the emulator it waited on, and a 10 s deadline made the test depend on the load)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if bench.in_position():
            return
        time.sleep(0.02)
    raise AssertionError("never in position")


# -- the ESP301 profile against the emulator on a pty ----------------------------------------
def test_esp301_moves_reads_settles_and_its_bytes_are_the_manuals(tmp_path):
    em = start(tmp_path, "esp301")
    try:
        bench = TemplateBench("esp301", em.ports["bench"])
        bench.move_to(90.0, 180.0)
        # the lines on the wire, as the ESP301 manual writes them (CR-terminated)
        assert bench.sent[:3] == ["1PA90.0000", "2PA180.0000", "TB?"]
        assert em.bench_server.commands[:3] == ["1PA90.0000", "2PA180.0000", "TB?"]
        wait_in_position(bench)
        assert bench.position() == pytest.approx((90.0, 180.0), abs=1e-5)
        for q in ("1MD?", "2MD?", "1TP?", "2TP?"):
            assert q in em.bench_server.commands
        # the settle rule: done and within tolerance for 3 consecutive polls
        bench.move_to(0.0, 0.0)
        time.sleep(20.0 / 10.0 / 20.0 * 10 + 0.3)          # 180 deg at 10 deg/s, clock x20, + settle
        assert [bench.in_position() for _ in range(4)] == [False, False, True, True]
        bench.close()
    finally:
        em.stop()


def test_soft_limits_refuse_before_sending_and_the_error_buffer_names_the_code(tmp_path):
    em = start(tmp_path, "esp301")
    try:
        bench = TemplateBench("esp301", em.ports["bench"])
        received = len(em.bench_server.commands)
        with pytest.raises(BenchLimitError, match=r"axis1 to 400 deg refused.*\[-5, 365\].*nothing was sent"):
            bench.move_to(400.0, 0.0)
        with pytest.raises(BenchLimitError, match="axis2"):
            bench.move_to(0.0, -10.0)
        time.sleep(0.1)
        assert bench.sent == [] and len(em.bench_server.commands) == received
        # a driver without those limits sends the move; the controller refuses it, the error
        # buffer says why and the driver raises naming the controller's code
        loose = TemplateBench(bench.profile.with_axes(min_deg=-1e9, max_deg=1e9), em.ports["bench"])
        with pytest.raises(BenchControllerError, match=r"controller error 106 \(POSITIVE SOFTWARE LIMIT") as err:
            loose.move_to(400.0, 0.0)
        assert err.value.code == "106"
        assert loose.sent == ["1PA400.0000", "2PA0.0000", "TB?"]
        # an unknown command: error 6 from the buffer
        loose._write("1XX")
        with pytest.raises(BenchControllerError) as err:
            loose.check_error()
        assert err.value.code == "6" and "COMMAND DOES NOT EXIST" in str(err.value)
        loose.check_error()                               # the buffer is empty again: no error
        loose.close()
        bench.close()
    finally:
        em.stop()


LAB_PROFILE = """
name = "lab table"
[transport]
write_terminator = "\\n"
read_terminator = "\\n"
timeout_s = 0.3
[[axes]]
name = "tilt"
id = "A"
scale = -2.0        # controller units per degree, counting the other way
offset = 10.0
wrap = "180"
min_deg = -180
max_deg = 180
[[axes]]
name = "spin"
id = "B"
scale = 4.0
offset = 0.0
wrap = "360"
[commands]
move = "MOV {axis} {value}"
position = "POS? {axis}"
done = "ST? {axis}"
error = "ERR?"
value_format = ".3f"
[responses]
position = 'P=([-+0-9.eE]+)'
done = 'S=(\\w+)'
done_value = "IDLE"
error = '^E(\\d+)\\s*(.*)$'
no_error = "0"
[settle]
tolerance_deg = 0.005
polls = 2
[emulator]
position_reply = "P={value:+.4f}"
done_reply = "S=IDLE"
moving_reply = "S=BUSY"
error_reply = "E{code} {message}"
no_error_message = "OK"
unknown_command = { code = "9", message = "unknown" }
"""


def test_a_lab_profile_scale_offset_and_wrap_both_ways(tmp_path):
    path = tmp_path / "lab.toml"
    path.write_text(LAB_PROFILE)
    em = start(tmp_path, path)
    try:
        bench = TemplateBench(path, em.ports["bench"])
        bench.move_to(270.0, -30.0)       # tilt wraps to -90 -> -2 * -90 + 10 = 190; spin -30 -> 330 -> 1320
        assert bench.sent[:2] == ["MOV A 190.000", "MOV B 1320.000"]
        assert bench.commanded(270.0, -30.0) == (-90.0, 330.0)
        wait_in_position(bench)
        a1, a2 = bench.position()
        assert a1 == pytest.approx(-90.0, abs=1e-4) and a2 == pytest.approx(330.0, abs=1e-4)
        assert "POS? A" in em.bench_server.commands and "ST? B" in em.bench_server.commands
        bench.close()
    finally:
        em.stop()
    # the reading's conversion and wrap on their own
    tilt = AxisSpec("tilt", "A", scale=-2.0, offset=10.0, wrap="180")
    assert tilt.to_degrees(-370.0) == pytest.approx(-170.0)          # 190 deg -> -170
    assert tilt.to_degrees(tilt.to_controller(179.0)) == pytest.approx(179.0)
    assert wrap_angle(-30.0, "360") == 330.0 and wrap_angle(540.0, "180") == -180.0 and wrap_angle(400, "none") == 400
    assert angle_difference(179.999, -179.999, "180") == pytest.approx(-0.002)
    assert angle_difference(179.999, -179.999, "none") == pytest.approx(359.998)


def test_profiles_are_checked(tmp_path):
    good = LAB_PROFILE
    for bad, match in ((good.replace("scale = 4.0", "scale = 4.0\nspeed = 3"), r"\[axes 2\] unknown key 'speed'"),
                       (good.replace('move = "MOV {axis} {value}"', 'move = "MOV {axis} {target}"'),
                        r"\[commands\] move .*unknown placeholder \{target\}"),
                       (good.replace("polls = 2", "polls = 2\nwait = 1"), r"\[settle\] unknown key 'wait'"),
                       (good.replace('wrap = "360"', 'wrap = "90"'), r"wrap '90'"),
                       (good.replace("position = 'P=([-+0-9.eE]+)'", "position = 'P=[0-9'"), "not a regular"),
                       (good.replace('position = "POS? {axis}"\n', ""), r"\[commands\] needs 'position'")):
        path = tmp_path / "p.toml"
        path.write_text(bad)
        with pytest.raises(InputError, match=match) as err:
            load_profile(path)
        assert str(path) in str(err.value)
    with pytest.raises(InputError, match="shipped profiles: esp301"):
        load_profile("no-such-bench")


# -- the instruments file -----------------------------------------------------------------
def test_the_example_instruments_file_and_refusals(tmp_path):
    cfg = load_instruments(EXAMPLE)
    assert cfg["imu"] == {"driver": "vectornav", "protocol": "vectornav", "port": "/dev/ttyUSB0",
                          "baudrate": 115200, "rate_hz": 40}
    assert cfg["chamber"] == {"driver": "watlow-f4", "port": "/dev/ttyUSB1", "baudrate": 9600, "slave": 1}
    assert cfg["bench"]["profile"] == "esp301" and cfg["bench"]["driver"] == "template"
    base = open(EXAMPLE).read()
    cases = (
        (base + '\n[robot]\nport = "x"\n', r"unknown section \[robot\]"),
        (base.replace("rate_hz = 40", "rate_hz = 40\nrate = 40"), r"\[imu\] unknown key 'rate'"),
        (base.replace('profile = "esp301"', 'profile = "esp301"\nprofle = "x"'), r"\[bench\] unknown key 'profle'"),
        (base.replace('driver = "watlow-f4" ', 'driver = "watlow-f5" '), r"\[chamber\] driver 'watlow-f5'"),
        (base.replace('driver = "vectornav"', 'driver = "sbg"'), r"\[imu\] driver 'sbg'"),
        (base.replace('port = "/dev/ttyUSB1"', ''), r"\[chamber\] needs 'port'"),
        (base.replace('profile = "esp301"', ''), r"\[bench\] driver = \"template\" needs 'profile'"),
    )
    for text, match in cases:
        path = tmp_path / "instruments.toml"
        path.write_text(text)
        with pytest.raises(InputError, match=match) as err:
            load_instruments(path)
        assert str(path) in str(err.value)
    # a profile path relative to the instruments file; any pyserial URL as a port
    (tmp_path / "lab.toml").write_text(LAB_PROFILE)
    path = tmp_path / "instruments.toml"
    path.write_text('[bench]\ndriver = "template"\nprofile = "lab.toml"\nport = "loop://"\n')
    cfg = load_instruments(path)
    assert cfg["bench"]["profile"] == str(tmp_path / "lab.toml")
    bench = open_bench(cfg["bench"])                     # loop:// echoes: the port opens by URL
    assert bench.profile.name == "lab table"
    bench.close()


def test_capture_through_an_instruments_file_end_to_end(tmp_path):
    """`triadcal capture --instruments` against emulated VectorNav + Watlow F4 (the emulator's
    Modbus chamber holds the F4's loop-1 registers: PV 100, set point 300, tenths, function 6)
    + the ESP301 profile: rate_hz reaches the IMU's configuration, the moves go out as 1PA/2PA,
    the CSV says g and that t_x = t_y = t_z is one sensor."""
    timing = EmulatorTiming(time_scale=120.0, rate_hz=20.0, self_heating_time_constant_s=0.0)
    em = emulate(tmp_path / "emu", effects=["bench_tilt"], protocol="vectornav", timing=timing, seed=5,
                 bench_profile="esp301").start()
    try:
        written = load_instruments(em.directory / "instruments.toml")
        assert written["bench"]["profile"] == "esp301" and written["imu"]["rate_hz"] == 20
        inst = tmp_path / "instruments.toml"
        inst.write_text(f'[imu]\ndriver = "vectornav"\nport = "{em.ports["imu"]}"\nbaud = 115200\nrate_hz = 20\n\n'
                        f'[chamber]\ndriver = "watlow-f4"\nport = "{em.ports["chamber"]}"\naddress = 1\n\n'
                        f'[bench]\ndriver = "template"\nprofile = "esp301"\nport = "{em.ports["bench"]}"\n')
        plan = tmp_path / "plan.csv"
        plan.write_text("position,axis1_deg,axis2_deg\nP01,0,0\nP05,90,90\n")
        out = tmp_path / "run"
        r = subprocess.run(CLI + ["capture", "--instruments", str(inst), "--setpoints", "20", "--out", str(out),
                                  "--plan", str(plan), "--tau-s", "20", "--settle-s", "2", "--stab-window-s", "30",
                                  "--stab-hold-s", "30", "--unit", "SN-EMU-0001", "--no-progress"],
                           capture_output=True, text=True, timeout=60)     # a hang fails, not a slow machine
    finally:
        em.stop()
    assert r.returncode == 0, r.stderr
    assert "VNWRG,07,20" in em.imu_device.commands                 # rate_hz from the file configured the IMU
    assert {"1PA0.0000", "2PA0.0000", "1PA90.0000", "2PA90.0000"} <= set(em.bench_server.commands)
    assert em.modbus_requests > 0
    c = read_bench_csv(out / CSV_NAME)
    assert list(c.position) == ["P01", "P05"]
    assert c.output_unit == "g" and c.metadata["imu_protocol"] == "vectornav"
    assert c.metadata["imu_temperature"].startswith("single")
    np.testing.assert_array_equal(c.t[:, 0], c.t[:, 1])
    np.testing.assert_array_equal(c.t[:, 0], c.t[:, 2])
    assert abs(c.w[0, 1] - 1.0) < 0.01 and abs(c.w[1, 0] - 1.0) < 0.01    # +Y up at P01, +X up at P05
    assert (c.n_samples >= 0.9 * 20 * 20).all()


def test_a_plan_outside_the_soft_limits_is_refused_before_the_campaign(tmp_path):
    em = start(tmp_path, "esp301")
    try:
        cfg = {"imu": {"port": em.ports["imu"]}, "chamber": {"port": em.ports["chamber"]},
               "bench": {"port": em.ports["bench"], "driver": "template", "profile": "esp301"}}
        inst = tmp_path / "i.toml"
        inst.write_text(f'[imu]\ndriver = "nmea"\nport = "{cfg["imu"]["port"]}"\n[chamber]\ndriver = "modbus"\n'
                        f'port = "{cfg["chamber"]["port"]}"\n[bench]\ndriver = "template"\nprofile = "esp301"\n'
                        f'port = "{cfg["bench"]["port"]}"\n')
        plan = tmp_path / "plan.csv"
        plan.write_text("position,axis1_deg,axis2_deg\nP01,0,0\nPX,-90,0\n")
        r = subprocess.run(CLI + ["capture", "--instruments", str(inst), "--setpoints", "20", "--out",
                                  str(tmp_path / "run"), "--plan", str(plan), "--no-progress"],
                           capture_output=True, text=True, timeout=60)
    finally:
        em.stop()
    assert r.returncode == 1
    assert "position PX (-90, 0)" in r.stderr and "soft limits [-5, 365]" in r.stderr
    assert not any(c.startswith(("1PA", "2PA")) for c in em.bench_server.commands)
    assert not (tmp_path / "run" / "capture.json").exists()


def test_an_imu_without_temperature_is_refused_before_anything_moves(tmp_path):
    """MIP's set 0x80 has no instantaneous temperature: the stabilisation could never pass, so the
    capture refuses at once instead of timing out."""
    from triadcal.hardware.capture import CaptureError, capture
    from triadcal.hardware.protocols import TEMPERATURE_NONE

    class NoTemperature:
        protocol, temperature = "mip", TEMPERATURE_NONE

    with pytest.raises(CaptureError, match="gives no temperature"):
        capture(tmp_path / "run", plan={"P01": (0.0, 0.0)}, setpoints_C=[20.0], imu=NoTemperature(),
                bench=object(), chamber=object())
    assert not (tmp_path / "run" / "capture.json").exists()


def test_the_scpi_bench_tolerance_comes_from_the_instruments_file(tmp_path):
    """The SCPI bench checks POS? against its target within a tolerance that could not be set from
    the instruments file (a bench whose encoders read 0.02 deg off could not be used); now
    [bench] tolerance_deg sets it, checked when the file is read."""
    path = tmp_path / "instruments.toml"
    path.write_text('[bench]\ndriver = "scpi"\nport = "loop://"\ntolerance_deg = 0.05\n')
    bench = open_bench(load_instruments(path)["bench"])
    assert bench.tolerance_deg == 0.05
    bench.close()
    path.write_text('[bench]\ndriver = "scpi"\nport = "loop://"\n')
    bench = open_bench(load_instruments(path)["bench"])
    assert bench.tolerance_deg == 0.01
    bench.close()
    for value, match in (("0", r"tolerance_deg = 0: must be a number of degrees in \(0, 1\]"),
                         ('"x"', r"tolerance_deg = 'x'"), ("2.0", r"tolerance_deg = 2.0")):
        path.write_text(f'[bench]\ndriver = "scpi"\nport = "loop://"\ntolerance_deg = {value}\n')
        with pytest.raises(InputError, match=match):
            load_instruments(path)
    (tmp_path / "lab.toml").write_text(LAB_PROFILE)
    path.write_text('[bench]\ndriver = "template"\nprofile = "lab.toml"\nport = "loop://"\ntolerance_deg = 0.05\n')
    with pytest.raises(InputError, match=r"profile's \[settle\] tolerance_deg"):
        load_instruments(path)
