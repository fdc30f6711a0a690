"""Wire protocols, raw storage and the Allan noise estimate of the hardware layer."""

import numpy as np
import pytest

from triadcal.hardware.noise import allan_noise
from triadcal.hardware.protocols import Frame, binary, nmea
from triadcal.hardware.storage import RawStore, read_raw


def frames(n, seed=0):
    rng = np.random.default_rng(seed)
    return [Frame(k, 0.1 * k, tuple(rng.normal(0, 1, 3).tolist()), tuple((20 + rng.normal(0, 1, 3)).tolist()))
            for k in range(n)]


def test_crc_check_values():
    assert binary.crc16_ccitt(b"123456789") == 0x29B1     # CRC-16/CCITT-FALSE catalogue check
    assert binary.crc16_modbus(b"123456789") == 0x4B37    # CRC-16/MODBUS catalogue check


@pytest.mark.parametrize("codec", [nmea, binary])
def test_round_trip_in_any_chunking(codec):
    fs = frames(200)
    data = b"".join(codec.encode(f) for f in fs)
    rng = np.random.default_rng(1)
    p = codec.Parser()
    out, pos = [], 0
    while pos < len(data):
        step = int(rng.integers(1, 300))
        out += p.feed(data[pos:pos + step])
        pos += step
    assert out == [codec.quantise(f) for f in fs]
    assert p.stats.corrupted == 0 and p.stats.garbage_bytes == 0


@pytest.mark.parametrize("codec", [nmea, binary])
def test_every_single_bit_flip_is_caught_and_counted_once(codec):
    f0, f1, f2 = frames(3, seed=2)
    good0, bad, good2 = codec.encode(f0), bytearray(codec.encode(f1)), codec.encode(f2)
    caught = 0
    start = 1 if codec is nmea else 2                     # past the sync word
    end = len(bad) - (2 if codec is nmea else 0)          # before the NMEA line end
    for i in range(start, end):
        for bit in range(8):
            b = bytearray(bad)
            b[i] ^= 1 << bit
            if codec is nmea and b[i] in b"$\r\n*":
                continue
            p = codec.Parser()
            out = p.feed(good0 + bytes(b) + good2)
            assert out == [codec.quantise(f0), codec.quantise(f2)], (i, bit)
            assert p.stats.corrupted == 1, (i, bit)
            caught += 1
    assert caught > 8 * (end - start) * 0.9


@pytest.mark.parametrize("codec", [nmea, binary])
def test_random_garbage_never_loses_or_invents_a_frame(codec):
    rng = np.random.default_rng(3)
    fs = frames(300, seed=4)
    parts = []
    for f in fs:
        if rng.random() < 0.3:   # any bytes, sync bytes included
            parts.append(bytes(rng.integers(0, 256, int(rng.integers(1, 40))).tolist()))
        parts.append(codec.encode(f))
    p = codec.Parser()
    out = p.feed(b"".join(parts))
    assert [f.seq for f in out] == list(range(300))
    assert out == [codec.quantise(f) for f in fs]


def test_raw_store_is_append_only_and_survives_a_torn_line(tmp_path):
    path = tmp_path / "raw.csv"
    fs = frames(10)
    s = RawStore(path)
    s.append(fs[:5], 1, "record", "v1")
    s.close()
    with open(path, "a") as fh:                 # a power cut in the middle of a line
        fh.write("1,5,0.5,1.0,2")
    before = path.read_bytes()
    s = RawStore(path)
    s.append(fs[5:], 2, "record", "v2")
    s.close()
    assert path.read_bytes().startswith(before)
    raw = read_raw(path)
    assert raw["skipped_lines"] == 1
    assert raw["seq"].tolist() == list(range(10))
    assert raw["visit"].tolist() == ["v1"] * 5 + ["v2"] * 5
    np.testing.assert_array_equal(raw["w"], np.array([f.w for f in fs]))


def test_allan_Q_of_white_noise_within_its_standard_error():
    """Q from sigma^2(tau) tau at m = 1, 2, 4: for white noise the m = 1 term alone has a
    relative standard error sqrt(3/N) (mean of N squared first differences with correlation
    1/4 between neighbours); pooling m = 2, 4 does not make it worse, so 5 standard errors
    is a safe bound."""
    rng = np.random.default_rng(5)
    f, Q = 10.0, 3e-9
    windows = [rng.normal(0.0, np.sqrt(Q * f), (300, 3)) + rng.normal(0, 1, 3) for _ in range(12)]
    est = allan_noise(windows, f)
    n = 12 * 299
    for q in est.Q_V2s:
        assert abs(q / Q - 1) < 5 * np.sqrt(3 / n)
    assert not any(est.floor_reached)          # white noise only: no floor, an upper bound
    # sigma(tau) falls as tau^-1/2
    slope = np.polyfit(np.log(est.taus_s), np.log(est.adev[0]), 1)[0]
    assert abs(slope + 0.5) < 0.1
