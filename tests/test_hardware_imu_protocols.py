"""The documented IMU protocols (VectorNav ASCII, Xsens Xbus MTData2, MicroStrain MIP):
the vectors printed in the vendors' manuals (VN-100 UM001, Xsens MT0101P, MIP SDK),
checksums against independent implementations, property tests of the stream parsers, and
the driver configuring the emulator through real pseudo-terminals."""

import binascii
import functools
import math
import struct
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from triadcal.hardware.drivers.imu import SerialImu
from triadcal.hardware.emulator import Emulator, EmulatorTiming
from triadcal.hardware.protocols import G_CONVERSION_M_S2, DeviceError, Frame, mip, protocol_info, vectornav, xsens

G = 9.80665


# -- independent reference implementations (written from the public descriptions) ------
def ref_xor(body: bytes) -> int:
    return functools.reduce(lambda a, b: a ^ b, body, 0)


def ref_crc_xmodem(data: bytes) -> int:
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def ref_fletcher(data: bytes) -> bytes:
    a = sum(data) % 256
    b = sum((len(data) - i) * x for i, x in enumerate(data)) % 256    # b = sum of the running a's
    return bytes((a, b))


def vn_checksum_holds(sentence: bytes) -> bool:
    body, cs = sentence[1:sentence.rindex(b"*")], sentence[sentence.rindex(b"*") + 1:-2]
    if cs == b"XX":
        return True
    return int(cs, 16) == (ref_xor(body) if len(cs) == 2 else ref_crc_xmodem(body))


def xsens_checksum_holds(msg: bytes) -> bool:
    return msg[0] == 0xFA and sum(msg[1:]) % 256 == 0


def mip_checksum_holds(pkt: bytes) -> bool:
    return pkt[:2] == b"\x75\x65" and ref_fletcher(pkt[:-2]) == pkt[-2:] and len(pkt) == pkt[3] + 6


# -- verified vectors ------------------------------------------------------------------
VN_VECTORS = [
    (b"$VNRRG,11*73", ("RRG", ["11"])),
    (b"$VNWRG,06,0*6C", ("WRG", ["06", "0"])),
    (b"$VNYPR,+010.071,+000.278,-002.026*60", ("YPR", ["+010.071", "+000.278", "-002.026"])),
    (b"$VNERR,03*72", ("ERR", ["03"])),
    (b"$VNRRG,30,2,0,0,0,1,0,1*6E", ("RRG", ["30", "2", "0", "0", "0", "1", "0", "1"])),
    (b"$VNRRG,18,+00.013,+00.354,-09.801*65", ("RRG", ["18", "+00.013", "+00.354", "-09.801"])),
]


@pytest.mark.parametrize("text,reply", VN_VECTORS)
def test_vectornav_verified_vectors(text, reply):
    body, cs = text[1:-3], text[-2:]
    assert ref_xor(body) == int(cs, 16) == vectornav.xor_checksum(body)
    assert vectornav.sentence(body) == text + b"\r\n"
    p = vectornav.Parser()
    assert p.feed(text + b"\r\n") == []
    assert list(p.replies) == [reply]
    assert p.stats.corrupted == 0 and p.stats.garbage_bytes == 0
    if reply[0] == "ERR":
        assert p.errors == {3: 1}


def test_vectornav_command_encoders_match_the_manual():
    assert vectornav.read_register(11) == b"$VNRRG,11*73\r\n"
    assert vectornav.write_register(6, 0) == b"$VNWRG,06,0*6C\r\n"
    assert vectornav.error_reply(3) == b"$VNERR,03*72\r\n"
    assert vectornav.write_register(6, 0, checksum="none") == b"$VNWRG,06,0*XX\r\n"


def test_crc16_xmodem_is_binascii_crc_hqx_and_the_catalogue_value():
    assert ref_crc_xmodem(b"123456789") == 0x31C3 == binascii.crc_hqx(b"123456789", 0)   # CRC-16/XMODEM check
    rng = np.random.default_rng(0)
    for _ in range(50):
        data = bytes(rng.integers(0, 256, int(rng.integers(0, 80))).tolist())
        assert vectornav.crc16(data) == ref_crc_xmodem(data)


def test_vectornav_frames_with_xor_crc_and_no_check():
    p = vectornav.Parser(rate_hz=40.0)
    acc = vectornav.sentence(b"VNACC,+00.013,+00.354,-09.801")
    imu = vectornav.sentence(b"VNIMU,+0.2100,-0.0300,+0.4200,+00.013,+00.354,-09.801,+0.0,+0.0,+0.0,+24.50,+101.325",
                             "crc")
    assert imu.endswith(b"*%04X\r\n" % ref_crc_xmodem(imu[1:imu.rindex(b"*")]))
    unchecked = b"$VNACC,+00.000,+00.000,+09.807*XX\r\n"
    out = p.feed(acc + imu + unchecked)
    assert len(out) == 3 and p.unchecked == 1 and p.stats.corrupted == 0
    np.testing.assert_allclose(out[0].w, np.array([0.013, 0.354, -9.801]) / G, rtol=0, atol=1e-15)
    assert all(math.isnan(t) for t in out[0].t)            # VNACC carries no temperature
    assert out[1].t == (24.5, 24.5, 24.5)                    # VNIMU's one temperature fills all three
    assert [f.seq for f in out] == [0, 1, 2] and [f.time_s for f in out] == [0.0, 0.025, 0.05]
    # a lower-case checksum (bit 5 flipped in a hex letter) is refused, as the NMEA parser does
    bad = acc.replace(acc[-4:-2], acc[-4:-2].lower())
    if bad != acc:
        p2 = vectornav.Parser()
        assert p2.feed(bad) == [] and p2.stats.corrupted == 1
    strict = vectornav.Parser(accept_unchecked=False)
    assert strict.feed(unchecked) == [] and strict.stats.corrupted == 1


def test_vnerr_is_counted_and_reported_not_a_frame():
    p = vectornav.Parser()
    out = p.feed(b"$VNERR,03*72\r\n" + vectornav.encode(Frame(0, 0.0, (0.0, 0.0, 1.0), (20.0,) * 3)))
    assert len(out) == 1 and p.errors[3] == 1 and p.stats.frames == 1
    assert ("ERR", ["03"]) in p.replies


XSENS_VECTORS = [
    (xsens.go_to_config, "FA FF 30 00 D1"),
    (xsens.go_to_measurement, "FA FF 10 00 F1"),
    (xsens.req_did, "FA FF 00 00 01"),
    (lambda: xsens.set_output_configuration([(0x4020, 100), (0x0810, 1), (0x1060, 0xFFFF)]),
     "FA FF C0 0C 40 20 00 64 08 10 00 01 10 60 FF FF EA"),
]


@pytest.mark.parametrize("make,hexbytes", XSENS_VECTORS)
def test_xsens_verified_messages(make, hexbytes):
    msg = make()
    assert msg == bytes.fromhex(hexbytes)
    assert xsens_checksum_holds(msg)
    p = xsens.Parser()
    assert p.feed(msg) == [] and list(p.replies) == [(msg[2], msg[4:-1])]


def test_xsens_extended_length_and_number_formats():
    long = xsens.message(0x99, bytes(range(256)) + bytes(44))
    assert long[3] == 0xFF and struct.unpack(">H", long[4:6])[0] == 300 and xsens_checksum_holds(long)
    p = xsens.Parser()
    assert p.feed(long) == [] and p.replies[0] == (0x99, long[6:-1])
    f = Frame(5, 12.3456, (0.5, -0.25, 1.0), (31.25,) * 3)
    for fmt, tol in ((0, 1e-7), (1, 2e-6 / G), (2, 1e-9), (3, 1e-15)):
        msg = xsens.mtdata2(f, fmt=fmt)
        (out,) = xsens.Parser().feed(msg)
        np.testing.assert_allclose(out.w, f.w, rtol=0, atol=tol)
        assert out.seq == 5 and out.time_s == pytest.approx(12.3456, abs=1e-9) and out.t == (31.25,) * 3
    # fp16.32 of a negative value: 4 bytes fraction then signed 16-bit integer (ethzasl / mip docs)
    assert xsens.encode_reals([-1.5], 2) == struct.pack(">Ih", 0x80000000, -2)
    assert xsens.decode_reals(struct.pack(">Ih", 0x80000000, -2), 2) == [-1.5]
    assert xsens.decode_reals(struct.pack(">i", -(1 << 19)), 1) == [-0.5]


def test_xsens_counter_and_sample_time_unwrap_and_temperature_is_held():
    p = xsens.Parser()
    msgs = [xsens.mtdata2(Frame(65534 + k, (2 ** 32 - 2 + k) / 1e4, (0.0, 0.0, 1.0), (20.0 + k,) * 3),
                          temperature=(k == 0)) for k in range(4)]
    out = p.feed(b"".join(msgs))
    assert [f.seq for f in out] == [65534, 65535, 65536, 65537]
    assert np.all(np.diff([f.time_s for f in out]) == pytest.approx(1e-4))
    assert [f.t[0] for f in out] == [20.0] * 4                # held from the packet that had it
    assert all(math.isnan(t) for t in xsens.Parser().feed(msgs[1])[0].t)   # none yet: NaN


def test_mip_verified_vectors():
    assert mip.ping() == bytes.fromhex("75 65 01 02 02 01 E0 C6")
    accel = bytes.fromhex("75 65 80 0E 0E 04 3F800000 40000000 C0400000 79 ED")
    assert mip.encode(Frame(0, 0.0, (1.0, 2.0, -3.0), (0.0,) * 3)) == accel
    for pkt in (mip.ping(), accel):
        assert ref_fletcher(pkt[:-2]) == pkt[-2:] == mip.fletcher(pkt[:-2])
    p = mip.Parser(rate_hz=50.0)
    (f,) = p.feed(accel)
    assert f.w == (1.0, 2.0, -3.0) and f.seq == 0 and all(math.isnan(t) for t in f.t)
    assert p.feed(mip.ping()) == [] and p.replies[0] == (0x01, [(0x01, b"")])


def test_units_and_temperature_conventions():
    assert G_CONVERSION_M_S2 == 9.80665
    assert protocol_info("vectornav")["output_unit"] == protocol_info("xsens")["output_unit"] == "g"
    assert protocol_info("mip")["temperature"] == "none"
    assert protocol_info("xsens")["temperature"] == "single"
    assert protocol_info("nmea") == {**protocol_info("nmea"), "output_unit": "V", "temperature": "per-axis"}


# -- property tests ----------------------------------------------------------------------
CODECS = {
    # the temperature field has two decimals: half its LSB (0.005 degC) plus float slack, since
    # 0.875 is written "0.88" and 0.88 - 0.875 = 0.0050000000000000044 in binary (a flake under -p randomly)
    "vectornav": (vectornav, lambda f: vectornav.encode(f, "VNIMU"), vn_checksum_holds, 5e-4 / G, 0.005 + 1e-9),
    "vectornav-crc": (vectornav, lambda f: vectornav.encode(f, "VNACC", "crc"), vn_checksum_holds, 5e-4 / G, None),
    "xsens": (xsens, xsens.encode, xsens_checksum_holds, 1e-6, 1e-3),
    "mip": (mip, mip.encode, mip_checksum_holds, 1e-6, None),
}
accel = st.floats(-15.0, 15.0, allow_nan=False)
frames_st = st.lists(st.tuples(accel, accel, accel, st.floats(-60.0, 120.0)), min_size=1, max_size=12)


def to_frames(vals):
    return [Frame(k, 0.01 * k, (a, b, c), (t, t, t)) for k, (a, b, c, t) in enumerate(vals)]


def split(data: bytes, cuts):
    cuts = sorted({c % (len(data) + 1) for c in cuts})
    pieces, last = [], 0
    for c in cuts + [len(data)]:
        pieces.append(data[last:c])
        last = c
    return pieces


def check_decoded(out, fs, w_tol, t_tol):
    assert len(out) == len(fs)
    for got, want in zip(out, fs):
        np.testing.assert_allclose(got.w, want.w, rtol=0, atol=w_tol)
        if t_tol is not None:
            np.testing.assert_allclose(got.t, want.t, rtol=0, atol=t_tol)


@pytest.mark.parametrize("name", list(CODECS))
@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(vals=frames_st, cuts=st.lists(st.integers(0, 10_000), max_size=20))
def test_encode_parse_round_trip_in_any_chunking(name, vals, cuts):
    codec, enc, _, w_tol, t_tol = CODECS[name]
    fs = to_frames(vals)
    p = codec.Parser()
    out = []
    for piece in split(b"".join(enc(f) for f in fs), cuts):
        out += p.feed(piece)
    check_decoded(out, fs, w_tol, t_tol)
    assert p.stats.corrupted == 0 and p.stats.garbage_bytes == 0 and p.stats.frames == len(fs)


@pytest.mark.parametrize("name", list(CODECS))
@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(vals=frames_st, garbage=st.lists(st.binary(max_size=40), min_size=13, max_size=13),
       cuts=st.lists(st.integers(0, 10_000), max_size=20))
def test_arbitrary_garbage_between_frames_loses_and_invents_nothing(name, vals, garbage, cuts):
    codec, enc, holds, w_tol, t_tol = CODECS[name]
    fs = to_frames(vals)
    # garbage may hold a sync word and a length: the parser then waits for the bytes it
    # announces (at most 261 for MIP, 2055 for Xsens) before it gives up on it, so the
    # stream goes on with more frames (as a live one does) and they all arrive
    n_tail = 0 if name.startswith("vectornav") else 2100 // len(enc(fs[0])) + 1
    tail_frames = to_frames([(0.5, 0.5, 0.5, 25.0)] * n_tail)
    data = b"".join(g + enc(f) for g, f in zip(garbage, fs)) + garbage[-1] + b"".join(enc(f) for f in tail_frames)
    p = codec.Parser(keep_raw=True)
    out = []
    for piece in split(data, cuts):
        out += p.feed(piece)                      # never raises
    assert all(holds(raw) for raw in p.raw)       # nothing accepted without its checksum
    assert len(out) == len(fs) + len(tail_frames)
    check_decoded(out[:len(fs)], fs, w_tol, t_tol)          # garbage with sync bytes costs no frame


@pytest.mark.parametrize("name", ["vectornav", "xsens", "mip"])
@settings(max_examples=150, deadline=None, derandomize=True)
@given(data=st.binary(max_size=600), cuts=st.lists(st.integers(0, 10_000), max_size=10))
def test_random_bytes_never_raise_and_never_yield_an_unchecked_frame(name, data, cuts):
    codec, _, holds, _, _ = CODECS[name]
    prefix = {"vectornav": b"$VNACC,", "xsens": b"\xfa\xff\x36", "mip": b"\x75\x65\x80"}[name]
    p = codec.Parser(keep_raw=True)
    out = []
    for piece in split(prefix + data, cuts):
        out += p.feed(piece)
    assert len(out) == len(p.raw) == p.stats.frames
    assert all(holds(raw) for raw in p.raw)


@pytest.mark.parametrize("name", ["vectornav", "xsens", "mip"])
def test_every_single_bit_flip_is_caught(name):
    codec, enc, _, _, _ = CODECS[name]
    f0, f1, f2 = to_frames([(0.1, 0.2, 9.0, 20.0), (-1.0, 0.5, 3.0, 21.0), (2.0, -2.0, 1.0, 22.0)])
    good0, bad, good2 = enc(f0), enc(f1), enc(f2)
    n_tail = 0 if name == "vectornav" else 260 // len(good2) + 1
    tail = good2 * n_tail
    text = name == "vectornav"
    lo, hi = (1, len(bad) - 2) if text else (2, len(bad))
    caught = 0
    for i in range(lo, hi):
        for bit in range(8):
            b = bytearray(bad)
            b[i] ^= 1 << bit
            if text and b[i] in b"$\r\n*":
                continue
            p = codec.Parser()
            # a flipped length byte makes the parser wait for the bytes it announces: the
            # stream goes on (more frames), and then nothing is lost
            out = p.feed(good0 + bytes(b) + good2 + tail)
            assert len(out) == 2 + n_tail and p.stats.corrupted == 1, (i, bit, p.stats)
            np.testing.assert_allclose(out[0].w, f0.w, atol=1e-3)
            np.testing.assert_allclose(out[1].w, f2.w, atol=1e-3)
            caught += 1
    assert caught > 0.9 * 8 * (hi - lo)


# -- the driver against the emulator, through real pseudo-terminals ------------------------
def start_emulator(tmp_path, protocol, rate_hz=10.0):
    timing = EmulatorTiming(time_scale=5.0, rate_hz=rate_hz, self_heating_time_constant_s=0.0)
    return Emulator(tmp_path / "emu", protocol=protocol, timing=timing, keep_log=True).start()


def read_for(imu, seconds, at_least=5, hang_s=60.0):
    """Read for ``seconds``, and on until ``at_least`` frames have come: how many frames a fixed
    wall time brings depends on the machine's load, so the count asserted is waited for; ``hang_s``
    only guards against a hang."""
    out, t0 = [], time.monotonic()
    while True:
        out += imu.read()
        waited = time.monotonic() - t0
        if (waited >= seconds and len(out) >= at_least) or waited >= hang_s:
            return out


@pytest.mark.parametrize("protocol,options", [("vectornav", {}), ("xsens", {"temperature_hz": 5}), ("mip", {})])
def test_driver_configures_the_emulator_and_reads_it_through_a_pty(tmp_path, protocol, options):
    em = start_emulator(tmp_path, protocol)
    try:
        imu = SerialImu(em.ports["imu"], protocol=protocol, baudrate=115200, rate_hz=10.0, **options)
        imu.open()
        got = read_for(imu, 1.5)
        imu.close()
    finally:
        em.stop()
    dev = em.imu_device
    if protocol == "vectornav":
        assert dev.commands[:2] == ["VNWRG,06,19", "VNWRG,07,10"]
        assert dev.registers[6] == 19 and dev.registers[7] == 10
    elif protocol == "xsens":
        assert dev.commands[:3] == [0x30, 0xC0, 0x10] and not dev.config_mode
        assert (0x0810, 5) in dev.config and (0x4020, 10) in dev.config
    else:
        assert dev.commands[0] == (0x01, 0x01)                     # the Ping
    assert len(got) >= 5 and imu.parser_stats.corrupted == 0
    assert imu.output_unit == "g"
    # what arrived is what the emulator sent (in order, nothing lost), after the protocol's rounding
    sent = [fr for _, fate, fr in em.log if fate == "sent"]
    assert len(sent) - 3 <= len(got) <= len(sent)        # at most the last few not read before closing
    for f, want in zip(got, sent):
        assert f.w == want.w
        if protocol == "vectornav":
            assert f.t == want.t or all(math.isnan(t) for t in f.t + want.t)   # VNACC before, VNIMU after
        elif protocol == "xsens":    # temperature at 5 Hz, held in between; counter and clock the device's
            assert abs(f.t[0] - want.t[0]) < 0.1 and f.t[0] == f.t[1] == f.t[2]
            assert f.seq == want.seq and f.time_s == pytest.approx(want.time_s, abs=1e-9)
        else:
            assert all(math.isnan(t) for t in f.t)
    seqs = [f.seq for f in got]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)


@pytest.mark.parametrize("protocol,code", [("vectornav", "07"), ("xsens", 0x21)])
def test_a_refused_configuration_names_the_device_error(tmp_path, protocol, code):
    em = start_emulator(tmp_path, protocol)
    try:
        imu = SerialImu(em.ports["imu"], protocol=protocol, rate_hz=3.0)   # 3 Hz: not a rate they take
        with pytest.raises(DeviceError) as err:
            imu.open()
    finally:
        em.stop()
    assert err.value.code == code
    text = str(err.value)
    assert ("$VNERR,07" in text) if protocol == "vectornav" else ("0x21" in text)


def test_no_answer_is_a_clear_error(tmp_path):
    em = start_emulator(tmp_path, "nmea")          # a $TCIMU stream never answers a Ping
    try:
        imu = SerialImu(em.ports["imu"], protocol="mip", rate_hz=10.0, timeout_s=0.2)
        with pytest.raises(DeviceError) as err:
            imu.open()
    finally:
        em.stop()
    assert err.value.code is None and "no answer to Ping" in str(err.value)


def test_a_campaign_through_the_vectornav_driver_survives_faults_and_a_reconfiguring_reopen(tmp_path):
    """capture() through SerialImu('vectornav') against the emulator with garbage, flipped
    bits and a disconnect: the driver configures the new line again after the reconnect, every
    visit completes, the CSV says g, and t_x = t_y = t_z (one sensor)."""
    from triadcal.hardware.capture import CSV_NAME, CaptureSettings, Stabilisation, capture, load_port_config, \
        open_instruments
    from triadcal.hardware.emulator import FaultPlan, emulate
    from triadcal.io.bench_csv import read_bench_csv
    from triadcal.models.campaign import DEFAULT_PLAN

    faults = FaultPlan(garbage_prob=0.02, bitflip_prob=0.02, disconnects=((40.0, 30.0),))   # during the soak
    timing = EmulatorTiming(time_scale=120.0, rate_hz=10.0, self_heating_time_constant_s=0.0)
    em = emulate(tmp_path / "emu", effects=["bench_tilt"], protocol="vectornav", timing=timing, faults=faults,
                 seed=7, keep_log=True).start()
    try:
        cfg = load_port_config(em.directory / "ports.toml")
        assert cfg["imu"]["rate_hz"] == 10
        _, bench, chamber = open_instruments(cfg)
        imu = SerialImu(cfg["imu"]["port"], protocol="vectornav", rate_hz=cfg["imu"]["rate_hz"])
        plan = {k: DEFAULT_PLAN[k] for k in ("P01", "P05")}
        settings = CaptureSettings(tau_s=30.0, settle_s=2.0, unit="SN-EMU-0001", output_unit=imu.output_unit,
                                   stabilisation=Stabilisation(rate_C_per_min=0.01, window_s=30.0, hold_s=30.0,
                                                               timeout_s=3000.0))
        report = capture(tmp_path / "out", plan=plan, setpoints_C=[20.0], imu=imu, bench=bench, chamber=chamber,
                         settings=settings)
        bench.close()
        chamber.close()
    finally:
        em.stop()
    assert report.visits_done == 2 and report.disconnects >= 1 and report.corrupted_frames > 0
    configured = [text for _, text in imu.link_stats.events if text.startswith("configured vectornav")]
    assert len(configured) >= 2                              # on open, and again after the reconnect
    assert em.imu_device.commands.count("VNWRG,06,19") >= 2
    c = read_bench_csv(tmp_path / "out" / CSV_NAME)
    assert c.output_unit == "g"
    np.testing.assert_array_equal(c.t[:, 0], c.t[:, 1])
    np.testing.assert_array_equal(c.t[:, 0], c.t[:, 2])
    assert abs(c.w[0, 1] - 1.0) < 0.01 and abs(c.w[1, 0] - 1.0) < 0.01   # +Y up at P01, +X up at P05


@pytest.mark.parametrize("name", ["vectornav", "xsens", "mip"])
def test_configuration_finds_its_replies_inside_a_running_stream(name):
    """configure() against the emulated instrument over an in-memory link that keeps sending
    frames (before, between and after the replies, cut at odd places): every reply is found,
    no frame is lost, none is counted as damaged."""
    from triadcal.hardware.protocols import Link

    codec = {"vectornav": vectornav, "xsens": xsens, "mip": mip}[name]
    dev = codec.Emulated(rate_hz=10.0)
    fs = iter(to_frames([(0.01 * k, 0.0, 1.0, 20.0) for k in range(1000)]))
    pending = bytearray()

    def write(data):
        pending.extend(dev.encode(next(fs)) + dev.feed(data) + dev.encode(next(fs)))

    def read():
        pending.extend(dev.encode(next(fs)) if dev.streaming else b"")
        chunk = bytes(pending[:7])
        del pending[:7]
        return chunk

    p = codec.Parser(rate_hz=10.0)
    got = codec.configure(Link(write, read), p, 10.0)
    got += p.feed(bytes(pending))
    assert p.stats.corrupted == 0 and p.stats.garbage_bytes == 0 and len(got) > 3
    first = round(got[0].w[0], 2)
    np.testing.assert_allclose([f.w[0] for f in got], first + 0.01 * np.arange(len(got)), rtol=0, atol=1e-4)


def test_an_imu_port_that_cannot_be_opened_is_named_not_an_internal_error():
    """An outside probe's capture with --imu-port /dev/ttyNOPE ended in "internal error: SerialException
    ... (a bug: please report it)", exit 70, where a missing bench or chamber port is named. The IMU's
    is named too (a TriadcalError: exit 1), and a reopen during a run still keeps trying (an OSError)."""
    from triadcal.errors import TriadcalError
    from triadcal.hardware.drivers.imu import ImuPortError, SerialImu

    imu = SerialImu("/dev/ttyUSB-triadcal-none", protocol="nmea")
    with pytest.raises(ImuPortError, match="cannot open the IMU's port /dev/ttyUSB-triadcal-none") as info:
        imu.open()
    assert isinstance(info.value, TriadcalError) and isinstance(info.value, OSError)
    imu._reopen()                                  # the run's reconnect loop: no exception, no port
    assert imu._ser is None


def test_the_emulators_ports_file_names_absolute_ports(tmp_path, monkeypatch):
    """An outside probe ran `triadcal emulate EMU` and then `capture --config /abs/EMU/ports.toml` from
    another directory: "cannot open the bench's port EMU/bench" (the ports were written relative to the
    emulator's working directory). They are absolute now, and TOML strings whatever the path holds."""
    import tomllib

    monkeypatch.chdir(tmp_path)
    e = Emulator("EMU dir \"quoted\"")
    cfg = tomllib.loads(e.write_config().read_text())
    for k in ("imu", "bench", "chamber"):
        assert cfg[k]["port"] == str(tmp_path / "EMU dir \"quoted\"" / k), cfg
