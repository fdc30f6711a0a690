"""Misread raw recordings and chamber cycles that an outside probe found accepted, answered with a
confident number, or ending in an internal error (exit 70); docs/raw.md ("What is refused, and
where", "The noise of each interval's mean").

Each input is made here from the repository's data: numpy-made recordings of a triad on its faces
(``test_raw_inputs.make_samples``), ``examples/data`` (mikoff's MPU-9150, tofupilot's chamber
cycle) and, where the other raw tests use it, imucal's annotated session of the shared real data.
"""

from __future__ import annotations

import hashlib
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_raw_inputs import FACES, RATE, STATIC, make_samples, twelve_poses, write_recording  # noqa: E402

from triadcal.cli import main as cli_main  # noqa: E402
from triadcal.errors import InputError  # noqa: E402
from triadcal.estimation.raw import fit_raw  # noqa: E402
from triadcal.estimation.result import CalibrationResult  # noqa: E402
from triadcal.io.raw import RawRecordingError, read_raw_csv  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "examples" / "data"
REAL = ROOT.parent / "shared" / "data" / "real"
if not REAL.exists():
    REAL = Path("/work/shared/data/real")
needs_real = pytest.mark.skipif(not REAL.exists(), reason="real recordings not available")
#: the numpy-made triad of make_samples: counts per g, per-axis gain and bias (counts); gravity 9.81
GAIN = 2048.0 * np.array([1.01, 0.99, 1.0])
BIAS = np.array([30.0, -20.0, 40.0])


def run_cli(capsys, *argv):
    rc = cli_main([*map(str, argv), "--quiet"])
    out = capsys.readouterr()
    return rc, out.err


def unwrap_free(w):
    """Signed 16-bit counts written as a logger that reads them unsigned would."""
    return np.where(w < 0, w + 65536, w)


# -- 1. two's-complement counts read as unsigned ------------------------------------------------
def test_counts_read_as_unsigned_are_refused_naming_the_interval(tmp_path):
    """A channel near zero g flips between 0.. and ..65535 inside a face: refused, with the interval,
    the channel and the conversion; before, the fit went on with means of mixed levels."""
    w, labels = make_samples(FACES)
    w = w - BIAS                   # a triad without bias: its axes at zero g straddle 0 (3 counts of noise)
    p = write_recording(tmp_path / "uwrap.csv", unwrap_free(w), labels)
    with pytest.raises(InputError) as e:
        fit_raw(str(p), RATE, labels="part")
    msg = str(e.value)
    assert "signed 16-bit (two's-complement) counts read as unsigned" in msg
    assert "uwrap.csv" in msg and re.search(r"in the interval [xyz]_[pa] \(samples \d+-\d+\) jumps between", msg)
    assert "subtract 65536" in msg


def test_unsigned_data_that_never_wraps_is_not_refused(tmp_path):
    """Offset-binary counts (+32768) are unsigned and never wrap: fitted as before."""
    w, labels = make_samples(FACES)
    p = write_recording(tmp_path / "offbin.csv", w + 32768, labels)
    assert fit_raw(str(p), RATE, labels="part").result.status == "ok"


@needs_real
def test_imucal_session_read_as_unsigned_is_refused_not_an_internal_error(tmp_path, capsys):
    """The probe's m_imu_uwrap.csv: exit 70 (LinAlgError in prior_sensitivity) before; exit 1 now."""
    lines = (REAL / "imucal_annotated_session.csv").read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:
        f = ln.split(",")
        for j in (2, 3, 4):
            v = float(f[j])
            f[j] = repr(v + 65536 if v < 0 else v)
        out.append(",".join(f))
    p = tmp_path / "m_imu_uwrap.csv"
    p.write_text("\n".join(out) + "\n")
    rc, err = run_cli(capsys, "fit-raw", p, "--rate", "102.4", "--labels", "part", "--json", tmp_path / "x.json")
    assert rc == 1, err
    assert "internal error" not in err and "counts read as unsigned" in err and "interval x_p" in err


def test_a_tilt_covariance_that_is_not_positive_definite_gives_a_proposal():
    """Why the probe reached a LinAlgError: the placement SD had run to the grid's 20 deg edge and the
    tilts' Laplace covariance (a pseudo-inverse of a Jacobian conditioned beyond 1e12) had a negative
    eigenvalue (-51 against 5e9); the Cholesky factor of the proposal failed. Now the factor falls back
    to the symmetric one with the eigenvalues raised."""
    from triadcal.estimation.raw.known import _proposal_factor

    rng = np.random.default_rng(0)
    V = np.linalg.qr(rng.standard_normal((12, 12)))[0]
    ev = np.geomspace(5e9, 1.0, 12)
    ev[-1] = -51.0
    C = (V * ev) @ V.T
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(C + 1e-12 * np.max(np.diag(C)) * np.eye(12))
    L = _proposal_factor(C)
    assert np.all(np.isfinite(L))
    LL = L @ L.T
    assert np.allclose(LL, (V * np.maximum(ev, 5e9 * 1e-12)) @ V.T, rtol=1e-6, atol=1e-3)
    np.linalg.solve(L, rng.standard_normal(12))            # invertible: the proposal density exists


# -- 2. a face of two samples ------------------------------------------------------------------
def _short_face(w, labels, face="x_p", keep=2, offset=(3.0, 0.0, 0.0)):
    """Keep ``keep`` samples of ``face`` (the rest labelled motion), one noise SD (3 counts) off the
    face's mean along x and one count apart on every axis: an own SD of 0.7 counts where the noise is
    3, as two samples have one time in five."""
    w, labels = w.copy(), labels.copy()
    idx = np.flatnonzero(labels == face)
    face_mean = w[idx].mean(axis=0)
    labels[idx[keep:]] = "move"
    w[idx[:keep]] = np.round(face_mean) + np.asarray(offset) + np.arange(keep)[:, None]
    return w, labels


def test_a_face_of_two_samples_has_an_honest_uncertainty(tmp_path, capsys):
    """Before: the two samples' own SD (0.7 counts here, small by chance in the probe too) was the
    noise of the face's mean, and K_x came out 4 u off with status ok. Now the interval's SD is floored by the
    pooled SD of all the intervals (fewer than 50 samples), and the note names the interval."""
    w, labels = _short_face(*make_samples(FACES))
    p = write_recording(tmp_path / "xp2.csv", w, labels)
    out = fit_raw(str(p), RATE, labels="part")
    r = out.result
    K_true = 1.0 / GAIN
    S_true = K_true * BIAS
    for i, a in enumerate("xyz"):
        assert abs(r[f"K_{a}"].value - K_true[i]) < 3 * r[f"K_{a}"].u, (a, r[f"K_{a}"])
        assert abs(r[f"S_{a}"].value - S_true[i]) < 3 * r[f"S_{a}"].u, (a, r[f"S_{a}"])
    k = out.averages.label.index("x_p")
    assert out.averages.n[k] == 2
    assert np.allclose(out.averages.sd[k], out.averages.sd_pooled)
    assert np.allclose(out.averages.sd_own[k], np.sqrt(0.5))
    assert np.all(out.averages.sd_pooled > 2.5) and np.all(out.averages.sd_pooled < 3.5)     # the noise is 3
    note = next(n for n in r.notes if "fewer than 50 samples" in n)
    assert "x_p" in note and "2 samples" in note and "pooled SD" in note


@needs_real
def test_imucal_face_of_two_samples_within_3u_of_the_full_session():
    """The probe's m_imu_xp2.csv: x_p cut to its first 2 samples gave K_x +9.7 u and S_x -11.3 u off the
    full session's values (docs/raw.md: K_x 4.8892e-4, S_x -0.002960) with status ok."""
    rec = read_raw_csv(REAL / "imucal_annotated_session.csv", 102.4, label_column="part")
    idx = np.flatnonzero(rec.labels == "x_p")
    rec.labels = rec.labels.astype(object)
    rec.labels[idx[2:]] = "move"
    rec.labels = rec.labels.astype(str)
    r = fit_raw(rec, labels="part").result
    assert abs(r["K_x"].value - 4.8892e-4) < 3 * r["K_x"].u, r["K_x"]
    assert abs(r["S_x"].value - -0.002960) < 3 * r["S_x"].u, r["S_x"]


# -- 3. an interval of one sample ---------------------------------------------------------------
def _intervals_csv(path, labels, extra=()):
    lab = np.asarray(labels)
    change = np.flatnonzero(lab[1:] != lab[:-1]) + 1
    starts, ends = np.r_[0, change], np.r_[change, len(lab)]
    rows = [(s + 20, e - 20) for s, e in zip(starts, ends) if lab[s] != "move"]
    rows += list(extra)
    path.write_text("start,end\n" + "".join(f"{s},{e}\n" for s, e in rows))
    return path, len(rows)


def test_a_one_sample_interval_is_used_and_named(tmp_path):
    """Before: the interval file gave 13 intervals, the report said 13, the fit used 12 without a word
    (intervals under 2 samples were skipped). Now it is used, with the pooled noise, and named."""
    w, labels = make_samples(twelve_poses())
    p = write_recording(tmp_path / "twelve.csv", w, labels)
    one_at = int(np.flatnonzero(labels == "p3")[-5])              # a sample of a static pose, not motion
    iv, n = _intervals_csv(tmp_path / "iv.csv", labels, extra=[(one_at, one_at + 1)])
    out = fit_raw(str(p), RATE, poses="unknown", intervals=str(iv))
    r = out.result
    assert r.extra["static_intervals"]["n_intervals"] == n == 13
    assert r.fit["n_obs"] == n and len(out.averages.n) == n
    note = next(x for x in r.notes if "fewer than 50 samples" in x)
    assert f"samples {one_at}..{one_at}, 1 sample)" in note


def test_the_diagnosis_uses_the_one_sample_interval_too(tmp_path):
    """raw_diagnosis.interval_data skipped intervals under 2 samples and weighted a short one by its
    own SD: it now takes every interval of the fit, a short one with the pooled SD as a floor."""
    from triadcal.judgement.raw_diagnosis import interval_data

    w, labels = make_samples(twelve_poses())
    p = write_recording(tmp_path / "twelve.csv", w, labels)
    last = np.flatnonzero(labels == "p3")[-19:]              # the end of a pose the intervals leave out (20 samples)
    iv, n = _intervals_csv(tmp_path / "iv.csv", labels,
                           extra=[(int(last[2]), int(last[2]) + 1), (int(last[10]), int(last[10]) + 2)])
    out = fit_raw(str(p), RATE, poses="unknown", intervals=str(iv))
    d = interval_data(out)
    assert len(d.n_samples) == n == 14 and sorted(d.n_samples)[:2] == [1, 2]
    long_sd = float(np.median(d.sd[d.n_samples >= 50]))
    assert np.all(d.sd[d.n_samples < 50] >= 0.5 * long_sd)            # not a 2-sample SD that happens to be tiny


def test_no_interval_of_two_samples_is_refused_with_the_reason(tmp_path):
    w, labels = make_samples(twelve_poses())
    p = write_recording(tmp_path / "twelve.csv", w, labels)
    iv = tmp_path / "ones.csv"
    starts = [int(np.flatnonzero(labels == k)[10]) for k in twelve_poses()]
    iv.write_text("start,end\n" + "".join(f"{s},{s + 1}\n" for s in starts))
    with pytest.raises(InputError, match="no static interval with at least 2 samples: the noise"):
        fit_raw(str(p), RATE, poses="unknown", intervals=str(iv))


# -- 4. thermal-cycle: a row with a field too many or too few; an implausible time axis ---------
def _cycle_lines():
    return (DATA / "tofupilot_imu_raw_data.csv").read_text().splitlines()


def _tc(p, unit="us"):
    from triadcal.io.thermal_cycle_csv import read_cycle

    return read_cycle(p, ["imu.acc.x", "imu.acc.y", "imu.acc.z"], "timestamp", unit, "imu.temperature")


@pytest.mark.parametrize("rows,change", [((4000,), "extra"), (tuple(range(0, 8400, 50)), "extra"),
                                         ((4000,), "missing")])
def test_thermal_cycle_refuses_a_row_whose_field_count_differs(tmp_path, rows, change):
    """A stray field after gyro.x shifted the accelerometer and temperature columns of that row (the
    temperature read 0 from imu.status): one such row was read silently, one in 50 changed the verdict."""
    lines = _cycle_lines()
    for i in rows:
        f = lines[i + 1].split("\t")
        if change == "extra":
            f.insert(2, "0.0")
        else:
            del f[7]
        lines[i + 1] = "\t".join(f)
    p = tmp_path / "cycle.csv"
    p.write_text("\n".join(lines) + "\n")
    first = rows[0] + 2                       # file line: the header is line 1, row i is line i + 2
    n = 10 if change == "extra" else 8
    with pytest.raises(RawRecordingError, match=rf"cycle.csv:{first}: .*{n} fields, the header has 9") as e:
        _tc(p)
    assert e.value.line == first


def test_thermal_cycle_says_the_time_axis_is_implausible(tmp_path, capsys):
    """Timestamps in ms declared as us: a 71 min cycle read as 4.2 s. Before, refused as "the
    temperature only rises or only falls"; now the time axis is named, with the unit that fits."""
    lines = _cycle_lines()
    out = [lines[0]]
    for ln in lines[1:]:
        f = ln.split("\t")
        f[0] = str(int(f[0]) // 1000)
        out.append("\t".join(f))
    p = tmp_path / "ts_ms.csv"
    p.write_text("\n".join(out) + "\n")
    with pytest.raises(InputError, match="the time axis is implausible with --time-unit us") as e:
        _tc(p, "us")
    msg = str(e.value)
    assert "only rises" not in msg and "degC/min" in msg and "with --time-unit ms it would last 70.7 min" in msg
    t, T, y, _ = _tc(p, "ms")                                       # the right unit: read
    assert t[-1] == pytest.approx(4241, abs=5)
    # seconds given for microseconds: 134 years
    with pytest.raises(InputError, match=r"longer than any chamber cycle .*with --time-unit us it would last 70.7 min"):
        _tc(DATA / "tofupilot_imu_raw_data.csv", "s")
    rc, err = run_cli(capsys, "thermal-cycle", p, "--columns", "imu.acc.x", "--time-column", "timestamp",
                      "--time-unit", "us", "--temperature-column", "imu.temperature")
    assert rc == 1 and "time axis is implausible" in err


# -- 5. data_sha256 of fit-raw results ------------------------------------------------------------
def test_fit_raw_results_carry_the_samples_sha256(tmp_path, capsys):
    """Bench fits carry data_sha256 so that compare calls two fits of one data set inconclusive;
    fit-raw's did not. Now: the SHA-256 of the samples, the same whatever the options."""
    from triadcal.judgement.compare.pair import same_data

    w, labels = make_samples(twelve_poses())
    p = write_recording(tmp_path / "twelve.csv", w, labels)
    want = hashlib.sha256(np.ascontiguousarray(w, dtype="<f8").tobytes()).hexdigest()
    known = fit_raw(str(p), RATE, labels="part").result
    unknown = fit_raw(str(p), RATE, poses="unknown", labels="part").result
    detected = fit_raw(str(p), RATE, poses="unknown").result
    assert known.extra["data_sha256"] == unknown.extra["data_sha256"] == detected.extra["data_sha256"] == want
    assert re.fullmatch(r"[0-9a-f]{64}", want)
    assert same_data(known, unknown) == want
    # written to and read from the JSON, top level like `source`
    rc, err = run_cli(capsys, "fit-raw", p, "--rate", RATE, "--labels", "part", "--poses", "unknown",
                      "--json", tmp_path / "u.json")
    d = json.loads((tmp_path / "u.json").read_text())
    assert d["data_sha256"] == want and "source" in d
    assert CalibrationResult.load(tmp_path / "u.json").extra["data_sha256"] == want
    # one sample changed: another data set
    w2 = w.copy()
    w2[100, 0] += 1
    p2 = write_recording(tmp_path / "twelve2.csv", w2, labels)
    assert fit_raw(str(p2), RATE, poses="unknown", labels="part").result.extra["data_sha256"] != want


def test_the_fit_of_the_bench_csv_fit_raw_wrote_is_the_same_data(tmp_path, capsys):
    """fit-raw --bench-csv averages the recording into a bench CSV; a `fit` of that file hashed the
    averages (another data_sha256), so compare judged it and the recording's fit-raw as two
    calibrations ("pass"). The file now carries the recording's hash, the fit's result
    derived_from_sha256, and compare says inconclusive whichever side each is on; the saved
    comparison with a stored "pass" is refused by its reader."""
    from triadcal.judgement.compare.pair import compare, same_data
    from triadcal.io.bench_csv import read_bench_csv
    from triadcal.api import fit

    w, labels = make_samples(twelve_poses())
    p = write_recording(tmp_path / "twelve.csv", w, labels)
    want = hashlib.sha256(np.ascontiguousarray(w, dtype="<f8").tobytes()).hexdigest()
    raw = fit_raw(str(p), RATE, labels="part", bench_csv_path=tmp_path / "avg.csv").result
    campaign = read_bench_csv(tmp_path / "avg.csv")
    assert campaign.metadata["raw_samples_sha256"] == want and campaign.derived_from_sha256 == want
    # no --local-g: the file states none either (it wrote the assumed 9.81 as the site's), and its fit says so
    assert raw.extra["local_g_stated"] is False and not campaign.local_g_stated
    bench = fit(campaign)
    assert any(n.startswith("the data state no local gravity") for n in bench.notes)
    assert bench.extra["data_sha256"] != want and bench.extra["derived_from_sha256"] == want
    assert same_data(raw, bench) == want and same_data(bench, raw) == want
    raw.save(tmp_path / "raw.json")
    bench.save(tmp_path / "bench.json")
    loaded = CalibrationResult.load(tmp_path / "bench.json")
    assert loaded.extra["derived_from_sha256"] == want
    for a, b in ((raw, loaded), (loaded, raw)):
        c = compare(a, b)
        assert c.overall == "inconclusive" and "two fits of the same data" in c.notes[0], c.notes
    rc, err = run_cli(capsys, "compare", tmp_path / "raw.json", tmp_path / "bench.json", "--json", tmp_path / "c.json")
    d = json.loads((tmp_path / "c.json").read_text())
    assert d["overall"] == "inconclusive" and d["after"]["derived_from_sha256"] == want
    from triadcal.judgement.compare.results import ComparisonResult
    d["overall"] = "pass"
    (tmp_path / "c2.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match="two fits of the same data"):
        ComparisonResult.load(tmp_path / "c2.json")
    # a mangled hash in a result is refused by the reader, naming the field
    bad = json.loads((tmp_path / "bench.json").read_text())
    bad["derived_from_sha256"] = "abc"
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(InputError, match="derived_from_sha256"):
        CalibrationResult.load(tmp_path / "bad.json")


def test_the_sampled_result_carries_the_same_sha256(tmp_path):
    w, labels = make_samples(twelve_poses())
    p = write_recording(tmp_path / "twelve.csv", w, labels)
    ls = fit_raw(str(p), RATE, poses="unknown", labels="part").result
    sampled = fit_raw(str(p), RATE, poses="unknown", labels="part", sample=True, max_steps=300, ess=200).result
    assert sampled.method == "posterior" and sampled.extra["data_sha256"] == ls.extra["data_sha256"]


# -- 6. a rate line in any case -------------------------------------------------------------------
@pytest.mark.parametrize("line", ["fs,100", "FS,100", "# Fs = 100 Hz", "Sample rate (Hz),100", "ODR,100",
                                  "sampling_rate;100", "// fs: 100 Hz"])
def test_a_rate_line_is_read_whatever_its_case(tmp_path, line):
    """A lowercase ``fs,100`` was ignored and a recording at 100 Hz fitted at any --rate."""
    src = (DATA / "mikoff_imu0.csv").read_text().splitlines()
    p = tmp_path / "fs.csv"
    p.write_text("\n".join([line, *src[:2000]]) + "\n")
    with pytest.raises(RawRecordingError, match=r"the stated rate 50 Hz disagrees with the file's header \(100 Hz\)") as e:
        read_raw_csv(p, 50)
    assert e.value.line == 1
    assert read_raw_csv(p, 100).n == 1999


def test_lines_that_only_look_like_a_rate_are_metadata(tmp_path):
    src = (DATA / "mikoff_imu0.csv").read_text().splitlines()
    p = tmp_path / "meta.csv"
    p.write_text("\n".join(["fsomething,3", "frequency,5", "baud rate,115200", *src[:100]]) + "\n")
    rec = read_raw_csv(p, 50)
    assert rec.metadata["fsomething"] == "3" and rec.metadata["baud rate"] == "115200"
    p.write_text("\n".join(["fs,fast", *src[:100]]) + "\n")
    with pytest.raises(RawRecordingError, match="states a sample rate that cannot be read"):
        read_raw_csv(p, 50)


# -- 6. a time column against --rate; free poses cannot check the columns' labels ------------------
@pytest.mark.parametrize("name,scale,step,ok", [
    ("time_s", 1.0, 1.0, True), ("time_s", 1.0, 2.0, False),            # the probe's: 50 Hz read at 100
    ("timestamp", 1e6, 1.0, True),                                       # us, as tofupilot's timestamp
    ("time", 1e3, 1.0, True), ("Time_MS", 1e3, 1.0, True), ("time_ms", 1.0, 1.0, False),
    ("time_s", 1.0, 1.03, True), ("time_s", 1.0, 1.07, False),           # 5 %: dropped samples or a rate
    # an outside probe's elapsed_ms and Arduino's millis()/micros() were not checked
    ("millis", 1e3, 1.0, True), ("millis", 1e3, 2.0, False), ("elapsed_ms", 1e3, 2.0, False),
    ("micros", 1e6, 1.0, True), ("micros", 1e6, 2.0, False)])
def test_a_time_column_is_checked_against_the_rate(tmp_path, name, scale, step, ok):
    w, labels = make_samples(twelve_poses())
    t = 1000.0 + np.arange(len(w)) * step * scale / RATE
    p = write_recording(tmp_path / "timed.csv", w, labels, extra={name: t})
    if ok:
        assert read_raw_csv(p, RATE).n == len(w)
        return
    with pytest.raises(RawRecordingError, match=r"the time column steps .* Hz.*\), not the 100 Hz of --rate") as e:
        read_raw_csv(p, RATE)
    assert e.value.column == name and e.value.line == 2


def test_a_time_that_goes_back_is_refused_with_its_line(tmp_path):
    w, labels = make_samples(twelve_poses())
    t = np.arange(len(w)) / RATE
    t[5000:] -= t[5000]                                                  # two recordings joined
    p = write_recording(tmp_path / "joined.csv", w, labels, extra={"time_s": t})
    with pytest.raises(RawRecordingError, match="the time goes back .* at sample 5000: a counter that wrapped") as e:
        read_raw_csv(p, RATE)
    assert e.value.line == 2 + 5000 and e.value.column == "time_s"


def test_the_real_chamber_run_reads_at_its_rate_and_not_at_another():
    """tofupilot's run: a ``timestamp`` in us, about 505 403 a row (1.9786 Hz)."""
    p = DATA / "tofupilot_imu_raw_data.csv"
    cols = ["imu.acc.x", "imu.acc.y", "imu.acc.z"]
    assert read_raw_csv(p, 1.9786, cols, unit="m/s2").n == 8400
    with pytest.raises(RawRecordingError, match="1.97862 Hz if in us"):
        read_raw_csv(p, 100.0, cols, unit="m/s2")


def test_free_poses_say_the_columns_are_taken_as_labelled(tmp_path):
    """An outside probe: x and y swapped, free poses: ok with K_x the true K_y (389 u off). The
    norms cannot tell; the result says so."""
    w, labels = make_samples(twelve_poses())
    p = write_recording(tmp_path / "free.csv", w[:, [1, 0, 2]])
    r = fit_raw(str(p), RATE, poses="unknown").result
    assert [n for n in r.notes if "a swapped or inverted column fits as well and is not detected" in n]


def test_six_faces_say_that_the_bias_holds_k2(tmp_path):
    """An outside probe: six hand-placed faces of a unit with K2 = 3 mg/g^2 on each axis gave status
    ok with every S 3 mg (30 u) off and no word. Made here with numpy (tilts of 0.3 deg): S is the
    bias plus K2, to within its u, as the result's note now says; far from the bias alone."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    k2, gain, bias = 3e-3, 2048.0 * 9.81 / 9.80665, np.array([30.0, -20.0, 40.0])
    blocks, labels = [], []
    for name, up in FACES.items():
        g = Rotation.from_rotvec(np.r_[np.radians(0.3) * rng.standard_normal(2), 0.0]).apply(np.asarray(up, float))
        blocks.append(np.tile(g + k2 * g ** 2, (STATIC, 1)))
        labels += [name] * STATIC
    w = np.round(np.vstack(blocks) * gain + bias + 3.0 * rng.standard_normal((6 * STATIC, 3)))
    p = write_recording(tmp_path / "k2.csv", w, np.array(labels))
    r = fit_raw(str(p), RATE, labels="part", local_g_m_s2=9.81).result
    assert r.status == "ok"
    for i, a in enumerate("xyz"):
        S = r.parameters[f"S_{a}"]
        assert abs(S.value - (bias[i] / gain + k2)) < 3 * S.u, (a, S.value, bias[i] / gain + k2, S.u)
        assert abs(S.value - bias[i] / gain) > 10 * S.u
    assert [n for n in r.notes if n.startswith("six faces:") and "K2_a adds to it in full" in n
            and "6 intervals leave no redundancy" in n and "a wander slower than an interval (bias instability" in n]


def test_samples_written_twice_are_named_in_the_refusal(tmp_path):
    """An outside probe wrote every row twice: refused as "no static intervals" with a noise SD at the
    quantisation floor and nothing about the repeats; now the refusal names them."""
    w, labels = make_samples(twelve_poses())
    p = write_recording(tmp_path / "twice.csv", np.repeat(w, 2, axis=0))
    with pytest.raises(InputError, match="50 % of the samples repeat the one before on all three channels"):
        fit_raw(str(p), 2 * RATE, poses="unknown")


def test_one_huge_reading_does_not_blind_the_static_detection(tmp_path):
    """An outside probe: one reading of 1e9 (inside the parser's 1e10 limit) in mikoff's imu0
    recording put 1e18 into moving_sd's running sum of squares; its differences lost every digit and
    the fit said "found 4 static intervals". The moving SD against the exact one of every window
    (numpy's sliding windows), and the recording's fit with and without the spike."""
    from numpy.lib.stride_tricks import sliding_window_view

    from triadcal.estimation.raw.detection import moving_sd

    rng = np.random.default_rng(4)
    x = np.repeat([0.0, 9.81, -9.81, 3.0], 2500)[:, None] + rng.normal(0, 0.02, (10000, 1))
    x[5001, 0] = 1e9
    w = 101
    sd = moving_sd(x, w)[w // 2:w // 2 + len(x) - w + 1, 0]
    exact = sliding_window_view(x[:, 0], w).std(axis=1, ddof=1)
    clean = np.ones(len(exact), bool)
    clean[5001 - w + 1:5002] = False                       # the windows holding the spike
    np.testing.assert_allclose(sd[clean], exact[clean], rtol=1e-6)      # clean: 1e-8; the clipped spike's 4e6 in the sums
    assert np.all(sd[~clean] > 1e3 * 0.02)                  # still far from static (>= 100 ranges / sqrt(w))
    src = ROOT / "examples" / "data" / "mikoff_imu0.csv"
    lines = src.read_text().splitlines()
    lines[5001] = "1e9," + ",".join(lines[5001].split(",")[1:])
    spiked = tmp_path / "spike.csv"
    spiked.write_text("\n".join(lines) + "\n")
    a = fit_raw(str(src), 100.0, unit="m/s2", poses="unknown").result
    b = fit_raw(str(spiked), 100.0, unit="m/s2", poses="unknown").result
    assert len(b.extra["static_intervals"]) >= len(a.extra["static_intervals"]) - 1
    for name in ("K_x", "K_y", "K_z", "S_x", "S_y", "S_z"):
        assert abs(b.parameters[name].value - a.parameters[name].value) < 0.5 * a.parameters[name].u, name


def _free_poses_k2(k2_per_g, *, seed=7, n_poses=30, noise_counts=2.0):
    """Free poses made here with numpy (directions uniform on the sphere, 4 s each, a move between):
    the readings ``(g + k2 g^2) gain + bias`` in counts, rounded, with white noise."""
    rng = np.random.default_rng(seed)
    gain, bias = 2048.0 * 9.81 / 9.80665, np.array([30.0, -20.0, 40.0])
    ups = rng.standard_normal((n_poses, 3))
    ups /= np.linalg.norm(ups, axis=1, keepdims=True)
    blocks = []
    for k, g in enumerate(ups):
        blocks.append(np.tile(g + k2_per_g * g ** 2, (400, 1)))
        nxt = ups[(k + 1) % n_poses]
        blocks.append(np.linspace(g, nxt, 100) * 1.3)          # a move: |a| off g, not static
    w = np.vstack(blocks) * gain + bias
    return np.round(w + noise_counts * np.random.default_rng(seed + 1).standard_normal(w.shape))


def test_free_poses_say_what_a_nonlinearity_below_detection_would_move(tmp_path):
    """An outside probe: 30-40 free poses of a unit with K2 = 200 ug/g2 on each axis (or a 300 ppm
    scale asymmetry): status ok with every S 4-9 u off (the norm takes 0.6 K2 into the bias), the
    diagnosis null in half the runs, nothing said. The fit now states the move of a K2 the residuals
    cannot show (fit.nonlinearity_sensitivity), and the stated move per ug/g2 predicts the shift
    that a K2 made here (numpy, same noise) gives, within 15 %."""
    k2 = 200e-6
    fits = {}
    for name, k in (("lin", 0.0), ("k2", k2)):
        p = write_recording(tmp_path / f"{name}.csv", _free_poses_k2(k))
        fits[name] = fit_raw(str(p), RATE, poses="unknown", local_g_m_s2=9.81).result
    lin, bent = fits["lin"], fits["k2"]
    sens = lin.fit["nonlinearity_sensitivity"]["scale_nonlinearity"]
    for a in "xyz":
        moved = (bent[f"S_{a}"].value - lin[f"S_{a}"].value) / lin[f"S_{a}"].u
        # the three outputs' K2 at once: the sum of each one's stated move
        predicted = sum(sens["moves_u"][b][f"S_{a}"] for b in "xyz") * k2 * 1e6
        assert moved == pytest.approx(predicted, rel=0.15), (a, moved, predicted)
        assert moved > 2                                      # the shift the probe found: several u
        assert sens["unseen_u"][f"S_{a}"] > 1
    note = [n for n in lin.notes if n.startswith("the gravity-norm model is linear in the readings")]
    assert note and "a K2 within 2 SD of 0" in note[0] and "S_x by up to" in note[0], lin.notes
    assert lin.status == "ok"


@pytest.mark.parametrize("name, values, said", [
    ("temp_F", lambda T: 32 + 1.8 * T, "degF"), ("T_kelvin", lambda T: T + 273.15, "kelvin"),
    ("temp_dC", lambda T: 10 * T, "tenths of a degC"), ("temp", lambda T: 10 * T, "no IMU runs that hot")])
def test_a_temperature_column_in_another_unit_is_refused(tmp_path, name, values, said):
    """An outside probe: a temperature column in tenths of a degC (15.5 +- 3.5 degC written as
    120-190) and one named temp_F were read as degC, the diagnosed bias tempco 10 times and 1.7
    times too small. A name that states another unit is refused, and a value no IMU reaches."""
    w, labels = make_samples(twelve_poses())
    T = 15.5 + 3.5 * np.sin(np.linspace(0, 6, len(w)))
    p = write_recording(tmp_path / "t.csv", w, extra={name: np.round(values(T), 2)})
    with pytest.raises(RawRecordingError) as e:
        read_raw_csv(str(p), RATE, temperature_column=name)
    assert said in str(e.value) and name in str(e.value)
    ok = write_recording(tmp_path / "ok.csv", w, extra={"temp_C": np.round(T, 2)})
    assert read_raw_csv(str(ok), RATE, temperature_column="temp_C").temperature_C is not None
