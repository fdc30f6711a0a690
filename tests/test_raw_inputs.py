"""fit-raw input validation: what an outside probe found accepted silently or ending in an
internal error (exit 70), each refused now with exit 1 and a line naming the file, line and
field, or the option (docs/raw.md, "What is refused, and where").

The recordings are made here with numpy (not with triadcal's simulator): a triad in counts
placed on its six faces (or twelve free poses), with linear moves between the poses.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from triadcal.cli import main as cli_main
from triadcal.io.bench_csv import read_bench_csv
from triadcal.io.raw import RawRecordingError, read_intervals, read_raw_csv

FACES = {"x_p": (1, 0, 0), "x_a": (-1, 0, 0), "y_p": (0, 1, 0), "y_a": (0, -1, 0),
         "z_p": (0, 0, 1), "z_a": (0, 0, -1)}
RATE = 100
STATIC = 600          # samples per pose (6 s)
MOVE = 100            # samples per move (1 s)


def make_samples(ups, *, seed=0, counts_per_g=2048.0, noise=3.0):
    """Samples (n, 3) in counts and their labels: each pose's gravity direction for STATIC samples,
    then a linear move of MOVE samples to the next; gravity 9.81 m/s^2."""
    rng = np.random.default_rng(seed)
    bias = np.array([30.0, -20.0, 40.0])
    gain = counts_per_g * np.array([1.01, 0.99, 1.0]) * 9.81 / 9.80665
    blocks, labels = [], []
    names = list(ups)
    for k, name in enumerate(names):
        u = np.asarray(ups[name], float)
        u = u / np.linalg.norm(u)
        blocks.append(np.tile(u, (STATIC, 1)))
        labels += [name] * STATIC
        if k + 1 < len(names):
            v = np.asarray(ups[names[k + 1]], float)
            v = v / np.linalg.norm(v)
            f = np.linspace(0, 1, MOVE)[:, None]
            blocks.append((1 - f) * u + f * v)
            labels += ["move"] * MOVE
    g = np.vstack(blocks)
    w = g * gain + bias + noise * rng.standard_normal(g.shape)
    return np.round(w), np.array(labels)


def write_recording(path, w, labels=None, *, header="acc_x,acc_y,acc_z", lines_before=(), extra=None):
    """A CSV recording: optional lines before the header, the accelerometer columns, then the
    label column ``part`` and any ``extra`` columns (name -> values)."""
    cols = [w[:, 0], w[:, 1], w[:, 2]]
    head = header
    if labels is not None:
        head += ",part"
    for name, values in (extra or {}).items():
        head += f",{name}"
    rows = []
    for i in range(len(w)):
        f = [f"{c[i]:.0f}" for c in cols]
        if labels is not None:
            f.append(labels[i])
        f += [f"{v[i]:.3f}" for v in (extra or {}).values()]
        rows.append(",".join(f))
    path.write_text("\n".join([*lines_before, head, *rows]) + "\n")
    return path


@pytest.fixture(scope="module")
def faces(tmp_path_factory):
    w, labels = make_samples(FACES)
    return write_recording(tmp_path_factory.mktemp("faces") / "faces.csv", w, labels)


def twelve_poses():
    ups = dict(FACES)
    for k, u in enumerate([(1, 1, 0), (-1, 0, 1), (0, -1, -1), (1, -1, 1), (-1, 1, -1), (1, 0, -1)]):
        ups[f"p{k}"] = u
    return ups


def run_cli(capsys, *argv):
    rc = cli_main(["fit-raw", *map(str, argv), "--quiet", "--no-progress"])
    return rc, capsys.readouterr().err


# -- 1. --local-g is in m/s2 and on Earth ---------------------------------------------------
@pytest.mark.parametrize("g", ["1", "9.0", "9.9", "0.5"])
def test_local_g_outside_earths_range_is_refused_naming_the_option(faces, tmp_path, capsys, g):
    out = tmp_path / "r.json"
    rc, err = run_cli(capsys, faces, "--rate", RATE, "--labels", "part", "--local-g", g, "--json", out)
    assert rc == 1, err
    assert "--local-g" in err and "9.76-9.84" in err and "--local-g-override" in err
    assert not out.exists()


def test_local_g_override_accepts_and_its_bench_csv_reads_back(faces, tmp_path, capsys):
    out, bench = tmp_path / "r.json", tmp_path / "b.csv"
    rc, err = run_cli(capsys, faces, "--rate", RATE, "--labels", "part", "--local-g", "9.0",
                      "--local-g-override", "--json", out, "--bench-csv", bench)
    assert rc in (0, 3), err
    assert "accepted with --local-g-override" in err
    assert json.loads(out.read_text())["local_g_m_s2"] == 9.0
    c = read_bench_csv(bench)                 # the bench reader refuses 9.0 without the override line
    assert c.metadata["local_g_override"] == "true" and float(c.metadata["local_g_m_s2"]) == 9.0
    # still bounded as the bench reader bounds it
    rc, err = run_cli(capsys, faces, "--rate", RATE, "--labels", "part", "--local-g", "150",
                      "--local-g-override", "--json", tmp_path / "r2.json")
    assert rc == 1 and "at most 100" in err


# -- 2. a column named twice ----------------------------------------------------------------
@pytest.mark.parametrize("header, twice", [("acc_x,acc_y,acc_z,acc_x", "acc_x"), ("acc_x,acc_x,acc_y,acc_z", "acc_x")])
def test_a_column_named_twice_is_refused(tmp_path, capsys, header, twice):
    w, labels = make_samples(FACES)
    extra_col = w[:, 0] * 0.9 + 50
    data = [w[:, 0], w[:, 1], w[:, 2]]
    data.insert(1 if header.startswith("acc_x,acc_x") else 3, extra_col)
    p = tmp_path / "dup.csv"
    p.write_text(header + "\n" + "\n".join(",".join(f"{c[i]:.1f}" for c in data) for i in range(len(w))) + "\n")
    with pytest.raises(RawRecordingError, match="twice") as e:
        read_raw_csv(p, RATE)
    assert e.value.line == 1 and e.value.column == twice and str(p) in str(e.value)
    rc, err = run_cli(capsys, p, "--rate", RATE, "--poses", "unknown", "--json", tmp_path / "r.json")
    assert rc == 1 and f"{p}:1: column '{twice}'" in err


def test_empty_names_may_repeat(tmp_path):
    """A trailing separator gives empty names: they are not columns anyone reads."""
    p = tmp_path / "trail.csv"
    p.write_text("acc_x,acc_y,acc_z,,\n" + "1,2,3,,\n" * 50)
    assert read_raw_csv(p, RATE).n == 50


# -- 3. intervals that share samples ----------------------------------------------------------
def _json(tmp_path, d, name="i.json"):
    p = tmp_path / name
    p.write_text(json.dumps(d))
    return p


def _face_ranges():
    return {lab: {"start": k * (STATIC + MOVE) + 30, "end": k * (STATIC + MOVE) + STATIC - 30}
            for k, lab in enumerate(FACES)}


def test_two_faces_on_the_same_samples_are_refused_naming_both(faces, tmp_path, capsys):
    d = _face_ranges()
    d["x_a"] = dict(d["x_p"])
    p = _json(tmp_path, d)
    with pytest.raises(RawRecordingError, match="cover the same samples") as e:
        read_intervals(p)
    assert "'x_p' (30..570)" in str(e.value) and "'x_a' (30..570)" in str(e.value) and str(p) in str(e.value)
    # the command: exit 1, not an internal error in the known-pose fit (exit 70)
    rc, err = run_cli(capsys, faces, "--rate", RATE, "--intervals", p, "--json", tmp_path / "r.json")
    assert rc == 1, err
    assert "internal error" not in err and "'x_a'" in err


def test_overlapping_intervals_are_refused_adjacent_ones_are_not(tmp_path):
    d = _face_ranges()
    d["y_p"] = {"start": d["x_a"]["end"] - 10, "end": d["y_p"]["end"]}
    with pytest.raises(RawRecordingError, match=r"'x_a' \(730..1270\) and 'y_p' \(1260..1970\) overlap "
                                                r"\(samples 1260..1270\)"):
        read_intervals(_json(tmp_path, d))
    # a CSV of start,end columns: entries named by their position
    p = tmp_path / "i.csv"
    p.write_text("start,end\n0,100\n500,600\n50,200\n")
    with pytest.raises(RawRecordingError, match=r"intervals 1 \(0..100\) and 3 \(50..200\) overlap"):
        read_intervals(p)
    # one interval inside another
    p.write_text("0,1000\n200,300\n2000,2100\n")
    with pytest.raises(RawRecordingError, match=r"intervals 1 \(0..1000\) and 2 \(200..300\) overlap"):
        read_intervals(p)
    p.write_text("0,100\n100,200\n200,300\n")           # end exclusive: adjacent intervals share no sample
    assert list(read_intervals(p).start) == [0, 100, 200]


def test_a_label_given_twice_in_a_session_list_is_refused(tmp_path):
    p = tmp_path / "i.json"
    p.write_text('{"x_p": {"start": 0, "end": 100}, "x_p": {"start": 200, "end": 300}}')
    with pytest.raises(RawRecordingError, match="given twice") as e:
        read_intervals(p)
    assert e.value.column == "x_p"


# -- 4. every numeric option ------------------------------------------------------------------
@pytest.mark.parametrize("option, value", [
    ("--static-window-s", "nan"), ("--static-window-s", "0"), ("--static-window-s", "-1"),
    ("--min-static-s", "nan"), ("--min-static-s", "-3"), ("--static-threshold", "nan"),
    ("--static-threshold", "-1"), ("--static-threshold", "0"), ("--angle-bound-arcsec", "nan"),
    ("--angle-bound-arcsec", "-1"), ("--counts-per-g", "0"), ("--counts-per-g", "nan"),
    ("--counts-per-g", "-2048"), ("--misalignment-sd-deg", "inf"), ("--placement-sd-deg", "nan"),
    ("--placement-sd-deg", "-1"), ("--rate", "nan"), ("--rate", "0"), ("--local-g", "nan"), ("--ess", "nan"),
    ("--max-steps", "0"), ("--seed", "-1")])
def test_a_numeric_option_that_is_not_finite_or_not_positive_is_refused(faces, tmp_path, capsys, option, value):
    out = tmp_path / "r.json"
    argv = [faces, "--rate", RATE, "--labels", "part", "--json", out, option, value]
    rc, err = run_cli(capsys, *argv)
    assert rc == 1, err
    assert f"{option} must be" in err and "internal error" not in err, err
    assert not out.exists()


def test_min_static_s_zero_is_no_minimum(faces, tmp_path, capsys):
    rc, err = run_cli(capsys, faces, "--rate", RATE, "--labels", "part", "--json", tmp_path / "r.json",
                      "--min-static-s", "0")
    assert rc in (0, 3), err


# -- 5. the sample rate in the header lines ----------------------------------------------------
@pytest.mark.parametrize("line", ["Fs,200 Hz", "Fs\t200", "Fs;200", "Fs,200,Hz", "Fs = 200", "rate_hz,0.2 kHz",
                                  "sample_rate_hz: 200hz"])
def test_a_rate_line_in_any_common_form_is_read_and_checked(tmp_path, line):
    w, _ = make_samples({"z_p": (0, 0, 1)})
    p = write_recording(tmp_path / "r.csv", w, lines_before=[line, "Logging Type,0"])
    with pytest.raises(RawRecordingError, match="disagrees with the file's header") as e:
        read_raw_csv(p, 100)
    assert e.value.line == 1 and "200 Hz" in str(e.value)
    assert read_raw_csv(p, 200).n == len(w)            # the same rate: read


def test_a_rate_line_that_cannot_be_read_is_refused_not_ignored(tmp_path):
    w, _ = make_samples({"z_p": (0, 0, 1)})
    p = write_recording(tmp_path / "r.csv", w, lines_before=["Logging Type,0", "Fs,fast"])
    with pytest.raises(RawRecordingError, match="cannot be read") as e:
        read_raw_csv(p, 100)
    assert e.value.line == 2
    # the plain form and other header lines as before
    p = write_recording(tmp_path / "r.csv", w, lines_before=["Fs,100", "Initialization time,36.5",
                                                            "Fsomething,3"])
    rec = read_raw_csv(p, 100)
    assert rec.metadata["Fs"] == "100" and rec.metadata["Fsomething"] == "3"


# -- 6. a temperature column in kelvin ----------------------------------------------------------
def test_a_temperature_column_in_kelvin_is_refused(tmp_path, capsys):
    w, _ = make_samples({"z_p": (0, 0, 1), "x_p": (1, 0, 0)})
    T = np.linspace(293.15, 323.15, len(w))
    p = write_recording(tmp_path / "k.csv", w, extra={"temp": T})
    with pytest.raises(RawRecordingError, match="kelvin") as e:
        read_raw_csv(p, RATE, temperature_column="temp")
    assert e.value.column == "temp"
    rc, err = run_cli(capsys, p, "--rate", RATE, "--poses", "unknown", "--temperature-column", "temp",
                      "--json", tmp_path / "r.json")
    assert rc == 1 and "kelvin" in err and "'temp'" in err
    # degC is read; a value beyond the bench's t_* range is refused with its line
    p = write_recording(tmp_path / "c.csv", w, extra={"temp": T - 273.15})
    assert np.allclose(read_raw_csv(p, RATE, temperature_column="temp").temperature_C, T - 273.15, atol=1e-3)
    T2 = T - 273.15
    T2[10] = -300.0
    p = write_recording(tmp_path / "c.csv", w, extra={"temp": T2})
    with pytest.raises(RawRecordingError, match="outside") as e:
        read_raw_csv(p, RATE, temperature_column="temp")
    assert e.value.line == 12


def test_the_temperature_column_sets_the_reference_temperature_and_range(tmp_path, capsys):
    """A recording at 25-38 degC with a temperature column: the values refer to the mean temperature of
    the static samples and the range is theirs, with a note of the span (an outside probe: reported and
    certified "at the reference temperature 20 degC", S 6-10 u from the truth there). Each hold is at
    one temperature here (the moves between them ramp), so the static mean is the holds' mean, by hand.
    Without the column the 20 degC is nominal and the certificate says the recording's temperature.
    With it, a tempco the fit leaves out moves the values by more than their u (the gate unseen_tempco,
    tests/test_raw_unseen_tempco.py): refused until the unit's tempco bounds are stated, then ok with
    every u widened by their Type B."""
    from triadcal.cli import main as cli

    ups = twelve_poses()
    w, labels = make_samples(ups, seed=3)
    hold_T = np.linspace(25.0, 38.0, len(ups))
    T = np.interp(np.arange(len(w)), [k * (STATIC + MOVE) + j for k in range(len(ups)) for j in (0, STATIC - 1)],
                  np.repeat(hold_T, 2))
    p = write_recording(tmp_path / "t.csv", w, extra={"temp_C": T})
    rc, err = run_cli(capsys, p, "--rate", RATE, "--poses", "unknown", "--local-g", "9.81", "--temperature-column",
                      "temp_C", "--json", tmp_path / "u.json")
    assert rc == 3 and "gate unseen_tempco failed (unidentifiable)" in err and "--scale-tempco-bound" in err, err
    u = json.loads((tmp_path / "u.json").read_text())
    assert u["status"] == "unidentifiable" and u["reference_temperature_C"] == pytest.approx(hold_T.mean(), abs=0.05)
    rc, err = run_cli(capsys, p, "--rate", RATE, "--poses", "unknown", "--local-g", "9.81", "--temperature-column",
                      "temp_C", "--bias-tempco-bound", "50", "--scale-tempco-bound", "20", "--json", tmp_path / "r.json")
    assert rc == 0, err
    r = json.loads((tmp_path / "r.json").read_text())
    assert r["status"] == "ok"
    assert all(r["parameters"][n]["u"] > u["parameters"][n]["u"] for n in ("K_x", "S_y", "Ca_xy"))
    assert r["reference_temperature_C"] == pytest.approx(hold_T.mean(), abs=0.05)        # 31.5
    assert r["temperature_range_C"] == pytest.approx([25.0, 38.0], abs=0.05)
    assert any("spans 25.0 .. 38.0 degC" in n and "fits no thermal terms" in n for n in r["notes"]), r["notes"]
    assert r["reference_temperature_stated"] is True
    assert cli(["certificate", str(tmp_path / "r.json"), "--html", str(tmp_path / "c.html")]) == 0
    assert "reference temperature 31.5 °C" in capsys.readouterr().out
    # without the column: nominal 20 degC, and the certificate does not claim it
    rc, err = run_cli(capsys, p, "--rate", RATE, "--poses", "unknown", "--local-g", "9.81", "--json", tmp_path / "n.json")
    assert rc == 0, err
    r = json.loads((tmp_path / "n.json").read_text())
    assert r["reference_temperature_C"] == 20.0 and r["temperature_range_C"] is None
    assert r["reference_temperature_stated"] is False
    assert cli(["certificate", str(tmp_path / "n.json"), "--html", str(tmp_path / "n.html")]) == 0
    out = capsys.readouterr().out
    assert "recording's temperature (not stated in the data)" in out and "20 °C" not in out


# -- 7. nothing written on a refusal --------------------------------------------------------------
def test_bench_csv_with_unknown_poses_writes_nothing(tmp_path, capsys):
    w, labels = make_samples(twelve_poses(), seed=2)
    p = write_recording(tmp_path / "free.csv", w, labels)
    out, bench = tmp_path / "r.json", tmp_path / "b.csv"
    rc, err = run_cli(capsys, p, "--rate", RATE, "--poses", "unknown", "--labels", "part", "--json", out,
                      "--bench-csv", bench)
    assert rc == 1 and "--bench-csv needs known poses" in err
    assert not out.exists() and not bench.exists()


def test_the_library_and_batch_check_the_options_too(faces):
    """The checks live in the library (``estimation.raw.fit.check_raw_options``), so ``fit_raw`` called
    from Python or from a ``batch`` manifest refuses what the command refuses."""
    from triadcal.errors import InputError
    from triadcal.estimation.raw import fit_raw
    with pytest.raises(InputError, match="--local-g 9 m/s2 is outside 9.76-9.84"):
        fit_raw(str(faces), RATE, labels="part", local_g_m_s2=9.0)
    with pytest.raises(InputError, match="--static-threshold must be a finite number > 0"):
        fit_raw(str(faces), RATE, labels="part", threshold=float("nan"))
    out = fit_raw(str(faces), RATE, labels="part", local_g_m_s2=9.0, local_g_override=True)
    assert out.result.parameters["K_x"].value > 0


def test_swapped_columns_are_refused_without_numpy_warnings(tmp_path):
    import warnings
    from triadcal.estimation.raw import fit_raw
    w, labels = make_samples(FACES)
    path = write_recording(tmp_path / "swapped.csv", w[:, [1, 0, 2]], labels)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        out = fit_raw(str(path), RATE, labels="part")
    assert out.result.status != "ok"


def test_fit_raw_without_unit_says_counts_and_what_the_readings_look_like(tmp_path, capsys):
    """A recording in m/s2 read with the default --unit counts got K in g/counts and no word."""
    from pathlib import Path

    from triadcal.cli import main

    data = Path(__file__).resolve().parents[1] / "examples" / "data" / "mikoff_imu0.csv"
    main(["fit-raw", str(data), "--rate", "100", "--poses", "unknown", "--json", str(tmp_path / "r.json"), "--quiet"])
    err = capsys.readouterr().err
    assert "--unit not given: the readings are taken as counts" in err and "looks like m/s2" in err, err
    main(["fit-raw", str(data), "--rate", "100", "--poses", "unknown", "--unit", "m/s2", "--json",
          str(tmp_path / "r2.json"), "--quiet"])
    assert "--unit not given" not in capsys.readouterr().err


def test_a_recording_in_mg_is_read_with_unit_mg(tmp_path, capsys):
    """Loggers often write mg; --unit had no mg, and the default (counts) gave K in g/counts. The
    real recording of examples/data (m/s2) rewritten in mg gives K 1000 times smaller in g/mg and
    the same angles; mg readings declared as g are refused (the magnitude check)."""
    from pathlib import Path

    from triadcal.cli import main

    src = Path(__file__).resolve().parents[1] / "examples" / "data" / "mikoff_imu0.csv"
    lines = src.read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#"))
    cols = lines[head].split(",")
    acc = [cols.index(c) for c in cols if c.strip() in ("acc_x", "acc_y", "acc_z", "ax", "ay", "az", "x", "y", "z")][:3]
    out = lines[:head + 1]
    for ln in lines[head + 1:]:
        f = ln.split(",")
        for j in acc:
            f[j] = repr(float(f[j]) * 1000.0 / 9.80665)
        out.append(",".join(f))
    mg = tmp_path / "mg.csv"
    mg.write_text("\n".join(out) + "\n")
    base = ["--rate", "100", "--poses", "unknown", "--quiet"]
    assert main(["fit-raw", str(src), "--unit", "m/s2", "--json", str(tmp_path / "a.json"), *base]) == 0
    assert main(["fit-raw", str(mg), "--json", str(tmp_path / "n.json"), *base]) == 0
    assert "looks like mg: give --unit mg" in capsys.readouterr().err
    assert main(["fit-raw", str(mg), "--unit", "mg", "--json", str(tmp_path / "b.json"), *base]) == 0
    a = json.loads((tmp_path / "a.json").read_text())["parameters"]
    b = json.loads((tmp_path / "b.json").read_text())["parameters"]
    assert b["K_x"]["unit"] == "g/mg"
    for ax in "xyz":           # K in g/(m/s2) = K in g/mg * 1000 / 9.80665
        assert b[f"K_{ax}"]["value"] * 1000.0 / 9.80665 == pytest.approx(a[f"K_{ax}"]["value"], rel=1e-6)
    for n in [k for k in a if k.startswith("Ca_") and "_" not in k[3:]]:
        assert b[n]["value"] == pytest.approx(a[n]["value"], abs=1e-3 + 1e-6 * abs(a[n]["value"]))
    assert main(["fit-raw", str(mg), "--unit", "g", "--json", str(tmp_path / "c.json"), *base]) == 1
    assert "the readings contradict --unit g" in capsys.readouterr().err


@pytest.mark.parametrize("text, match", [
    ("start,end\n0.50,7.50\n11.50,18.50\n", r"column 'interval 1 start': 0\.5 is not a whole sample index \(4 limit"),
    ("start_s,end_s\n1,7\n12,18\n", r":1: column 'start_s': the header 'start_s,end_s' names a time"),
])
def test_interval_files_in_seconds_are_refused_naming_the_entry(tmp_path, text, match):
    """An outside probe: limits in seconds were refused without a line or value ("interval limits must be
    whole sample indices"), and columns named start_s,end_s were read as sample indices without a word."""
    from triadcal.io.raw import RawRecordingError, read_intervals

    p = tmp_path / "iv.csv"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(RawRecordingError, match=match):
        read_intervals(p)
