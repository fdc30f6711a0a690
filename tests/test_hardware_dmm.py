"""The analog unit's voltmeter driver against pyvisa-sim (tests/data/dmm_34465a_sim.yaml).

The YAML lists each command verbatim; an unknown one puts -113 in the simulated error queue
(read by the driver's SYST:ERR? after configuring) and a query gets no answer. The bytes the
driver hands to the VISA library are recorded below the driver, at the backend's ``write``.
"""

from pathlib import Path

import numpy as np
import pytest
import pyvisa

from triadcal.errors import InputError
from triadcal.hardware.drivers.dmm import (AxisVoltmeters, DmmError, ScpiDmm, ScpiScanner, check_nplc,
                                           open_voltmeter, parse_readings)

YAML = Path(__file__).parent / "data" / "dmm_34465a_sim.yaml"
RES = {a: f"TCPIP0::192.168.0.{11 + i}::inst0::INSTR" for i, a in enumerate("xyz")}
FAST = "TCPIP0::192.168.0.14::inst0::INSTR"
SCANNER = "TCPIP0::192.168.0.20::inst0::INSTR"


class WireLog:
    """A pyvisa-sim ResourceManager whose backend writes are recorded per resource."""

    def __init__(self):
        self.rm = pyvisa.ResourceManager(f"{YAML}@sim")
        self.bytes: dict = {}
        lib = self.rm.visalib
        orig_write = lib.write

        def write(session, data):
            name = str(lib.sessions[session].parsed)          # the resource's canonical name
            self.bytes.setdefault(name, []).append(bytes(data))
            return orig_write(session, data)

        lib.write = write
        self.opened = []
        orig_open = self.rm.open_resource

        def open_resource(name, *a, **kw):
            self.opened.append(name)
            return orig_open(name, *a, **kw)

        self.rm.open_resource = open_resource

    def sent(self, resource: str) -> list:
        return [b for k, v in self.bytes.items() if k.lower() == resource.lower() for b in v]


def test_one_34465a_per_axis_exact_commands_and_statistics():
    wire = WireLog()
    cfg = {"driver": "scpi", "model": "34465A", "resources": RES, "range_V": 10, "nplc": 10}
    readout = open_voltmeter(cfg, rm=wire.rm)
    try:
        assert isinstance(readout, AxisVoltmeters)
        avg = readout.measure(5)
        # same count: SAMP:COUN is not sent again; the sim's dialogue answers READ? with the same five
        # readings every time: a stale answer, which the driver refuses (an outside probe's meter sent
        # the previous window again and it was recorded as the next position's)
        with pytest.raises(DmmError, match="the same 5 readings as the window before"):
            readout.measure(5)
    finally:
        readout.close()
    expected = [b"*IDN?\n", b"*CLS\n", b"CONF:VOLT:DC 10\n", b"VOLT:DC:NPLC 10\n", b"SYST:ERR?\n",
                b"SAMP:COUN 5\n", b"READ?\n", b"READ?\n"]
    for a in "xyz":                   # the stale answer stopped the second window at x's meter
        assert wire.sent(RES[a]) == (expected if a == "x" else expected[:-1]), a
        assert readout.meters[a].idn.startswith("Keysight Technologies,34465A,")
    x = np.array([10.052, 10.051, 10.053, 10.050, 10.054])
    assert avg.axes["x"].mean == pytest.approx(x.mean(), abs=1e-12)
    assert avg.axes["x"].sd == pytest.approx(np.sqrt(2.5e-6), rel=1e-9)        # sample SD (n - 1)
    assert avg.axes["y"].mean == pytest.approx(-0.25, abs=1e-12)
    assert avg.axes["z"].mean == pytest.approx(5e-3, abs=1e-15)
    row = avg.row()
    assert set(row) == {"w_x", "w_y", "w_z", "sd_x", "sd_y", "sd_z", "n_samples"} and row["n_samples"] == 5
    np.testing.assert_allclose(avg.w, [x.mean(), -0.25, 5e-3], atol=1e-12)


def test_scanner_channel_list_and_sweep_order():
    wire = WireLog()
    # x on 102, y on 103, z on 101: the scanner sweeps 101, 102, 103 -> z, x, y
    scanner = open_voltmeter({"resource": SCANNER, "channels": {"x": 102, "y": 103, "z": 101}, "nplc": 1,
                              "model": "DAQ970A"}, rm=wire.rm)
    try:
        assert isinstance(scanner, ScpiScanner)
        avg = scanner.measure(4)
    finally:
        scanner.close()
    assert wire.sent(SCANNER) == [b"*IDN?\n", b"*CLS\n", b"CONF:VOLT:DC 10,(@101,102,103)\n",
                                  b"VOLT:DC:NPLC 1,(@101,102,103)\n", b"ROUT:SCAN (@101,102,103)\n",
                                  b"SYST:ERR?\n", b"TRIG:COUN 4\n", b"READ?\n"]
    assert avg.axes["z"].mean == pytest.approx(1e-3, abs=1e-12)
    assert avg.axes["x"].mean == pytest.approx(2.0, abs=1e-12)
    assert avg.axes["y"].mean == pytest.approx(-3.0, abs=1e-12)
    assert avg.n_samples == 4 and avg.axes["x"].sd == pytest.approx(np.std([2, 2.001, 1.999, 2], ddof=1))


@pytest.mark.parametrize("model, nplc", [("34465A", 0.5), ("34461A", 0.06), ("34461A", 1000), ("34465A", 0)])
def test_nplc_outside_the_models_set_is_refused_before_anything_is_sent(model, nplc):
    wire = WireLog()
    with pytest.raises(InputError, match=f"NPLC {nplc:g} is not available on the {model}"):
        ScpiDmm(RES["x"], model=model, nplc=nplc, rm=wire.rm).open()
    with pytest.raises(InputError):
        open_voltmeter({"resources": RES, "model": model, "nplc": nplc}, rm=wire.rm)
    assert wire.opened == [] and wire.bytes == {}


def test_nplc_sets_per_model():
    assert check_nplc("34465A", 0.06) == 0.06
    with pytest.raises(InputError, match="0.02, 0.2, 1, 10, 100"):
        check_nplc("34461A", 0.06)
    for n in (0.02, 0.2, 1, 10, 100):
        assert check_nplc("34461A", n) == n


def test_fast_nplc_on_the_34465a_and_an_overload_is_an_error():
    wire = WireLog()
    meter = ScpiDmm(FAST, model="34465A", range_V=1, nplc=0.06, rm=wire.rm).open()
    try:
        with pytest.raises(DmmError, match="overload"):
            meter.read(3)
    finally:
        meter.close()
    assert wire.sent(FAST)[2:4] == [b"CONF:VOLT:DC 1\n", b"VOLT:DC:NPLC 0.06\n"]


def test_a_command_the_meter_does_not_know_is_reported_from_its_error_queue():
    # the sim is strict: the 100 V range is not in its dialogue, so the driver's SYST:ERR? sees -113
    wire = WireLog()
    with pytest.raises(DmmError, match='-113,"Undefined header".*after configuring'):
        ScpiDmm(RES["x"], range_V=100, rm=wire.rm).open()
    assert wire.sent(RES["x"])[2] == b"CONF:VOLT:DC 100\n"


def test_wrong_model_and_readings_parsing():
    wire = WireLog()
    with pytest.raises(DmmError, match="not a 34461A"):
        ScpiDmm(RES["x"], model="34461A", nplc=10, rm=wire.rm).open()
    assert wire.sent(RES["x"]) == [b"*IDN?\n"]
    np.testing.assert_array_equal(parse_readings("+1.00520000E+01,-2.50000000E-01\n", 2), [10.052, -0.25])
    with pytest.raises(DmmError, match="3 readings, 2 expected"):
        parse_readings("+1E+00,+1E+00,+1E+00", 2)
    with pytest.raises(DmmError, match="not comma-separated numbers"):
        parse_readings("ERROR", 1)
    # a reading that is not a number, and one no 10 V range reads (a meter answering in mV: 530 "V")
    with pytest.raises(DmmError, match="not a finite number"):
        parse_readings("+1E+00,NAN", 2)
    with pytest.raises(DmmError, match="a reading of 530 V is beyond the 10 V range"):
        parse_readings("+5.3E+02,+1E+00", 2, full_scale_V=10.0)
    assert parse_readings("+1.19E+01,-1.19E+01", 2, full_scale_V=10.0)[0] == 11.9      # overrange: 120 %
