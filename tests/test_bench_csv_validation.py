"""The bench CSV reader refuses what contradicts physics or itself, naming file, line and
column: ranges per column, metadata that does not parse, local g off Earth without an
override, kelvin temperatures, readings whose magnitude contradicts the declared unit.
Each file is the built-in example edited by hand (text, not the simulator)."""

import math

import pytest

from triadcal.api import example_path
from triadcal.cli import main
from triadcal.io.bench_csv import BenchCSVError, read_bench_csv

TEXT = example_path().read_text()
LINES = TEXT.splitlines()
N_META = sum(1 for ln in LINES if ln.startswith("#"))
HEADER = LINES[N_META].split(",")


def _write(tmp_path, lines, name="c.csv"):
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def _set(lines, row, col, value):
    """Data row ``row`` (0-based) gets ``value`` in column ``col``; returns its 1-based line."""
    k = N_META + 1 + row
    f = lines[k].split(",")
    f[HEADER.index(col)] = value
    lines[k] = ",".join(f)
    return k + 1


def _map_col(lines, col, fn):
    j = HEADER.index(col)
    for k in range(N_META + 1, len(lines)):
        f = lines[k].split(",")
        f[j] = fn(f[j])
        lines[k] = ",".join(f)


def _refused(path, *fragments):
    with pytest.raises(BenchCSVError) as e:
        read_bench_csv(path)
    msg = str(e.value)
    assert msg.startswith(str(path)), msg
    for f in fragments:
        assert f in msg, msg
    return e.value


@pytest.mark.parametrize("col, value, fragment", [
    ("axis1_deg", "400", "[-360, 360]"), ("axis2_deg", "-361", "[-360, 360]"),
    ("tau_s", "1e6", "(0, 86400]"), ("tau_s", "0", "(0, 86400]"),
    ("w_x", "1e300", "outside"), ("w_y", "inf", "not a finite number"), ("w_z", "nan", "not a finite number"),
    ("t_x", "-300", "[-273.15, 300]"), ("setpoint_C", "1e5", "outside"), ("sd_x", "-1e-3", "outside"),
    ("time_s", "1e300", "outside"), ("w_x", "0x10", "not a number"),
])
def test_each_column_has_a_range(tmp_path, col, value, fragment):
    lines = list(LINES)
    line = _set(lines, 17, col, value)
    e = _refused(_write(tmp_path, lines), f":{line}: column '{col}'", fragment)
    assert e.line == line and e.column == col


@pytest.mark.parametrize("key, value, fragment", [
    ("Q_V2s", "abc", "not a number"), ("Q_V2s", "-3e-9", "outside"), ("Q_V2s", "nan", "not a finite"),
    ("local_g_m_s2", "1.0", "local_g_override"), ("local_g_m_s2", "9.9", "9.76-9.84"),
])
def test_metadata_that_does_not_parse_or_is_off_earth_is_refused(tmp_path, key, value, fragment):
    lines = [f"# {key} = {value}" if ln.startswith(f"# {key}") else ln for ln in LINES]
    k = next(i for i, ln in enumerate(lines) if ln.startswith(f"# {key}"))
    e = _refused(_write(tmp_path, lines), f"{key}", fragment)
    assert e.line == k + 1


def test_an_explicit_override_accepts_another_local_g(tmp_path):
    lines = [("# local_g_m_s2 = 9.9" if ln.startswith("# local_g_m_s2") else ln) for ln in LINES]
    lines.insert(0, "# local_g_override = true")
    c = read_bench_csv(_write(tmp_path, lines))
    assert c.local_g_m_s2 == 9.9 and c.metadata["local_g_override"] == "true"
    lines[0] = "# local_g_override = yes please"
    _refused(_write(tmp_path, lines), "local_g_override", "true or false")


def test_a_repeated_metadata_key_is_refused(tmp_path):
    lines = ["# Q_V2s = 1e-9"] + list(LINES)
    _refused(_write(tmp_path, lines), "given twice")


def test_kelvin_temperatures_are_refused(tmp_path):
    lines = list(LINES)
    for col in ("t_x", "t_y", "t_z", "setpoint_C"):
        _map_col(lines, col, lambda v: repr(float(v) + 273.15))
    _refused(_write(tmp_path, lines), "look like kelvin", "median")


@pytest.mark.parametrize("unit, factor, ok", [
    ("V", 1.0, True), ("mV", 1000.0, True), ("g", 1.0, True), ("m/s2", 9.80665, True), ("mg", 1000.0, True),
    ("m/s2", 9806.65, False), ("g", 1000.0, False), ("mg", 1.0, False), ("V", 1e-6, False),
])
def test_declared_unit_against_the_readings_magnitude(tmp_path, unit, factor, ok):
    lines = [(f"# output_unit = {unit}" if ln.startswith("# output_unit") else ln) for ln in LINES]
    for col in ("w_x", "w_y", "w_z", "sd_x", "sd_y", "sd_z"):
        _map_col(lines, col, lambda v: repr(float(v) * factor))
    path = _write(tmp_path, lines)
    if ok:
        c = read_bench_csv(path)
        assert c.output_unit == unit
    else:
        _refused(path, f"contradict output_unit = {unit}", "median |w|")


def test_the_cli_refuses_in_one_line_with_the_place(tmp_path, capsys):
    lines = list(LINES)
    line = _set(lines, 3, "axis2_deg", "720")
    path = _write(tmp_path, lines)
    assert main(["fit", str(path)]) != 0
    out, err = capsys.readouterr()
    assert "Traceback" not in err and f"{path}:{line}: column 'axis2_deg'" in err
    assert len(err.strip().splitlines()) == 1


def test_the_mv_label_reaches_the_result(tmp_path):
    from triadcal.estimation.joint import fit_joint

    lines = [("# output_unit = mV" if ln.startswith("# output_unit") else ln) for ln in LINES]
    lines = [("# Q_V2s = 3e-03" if ln.startswith("# Q_V2s") else ln) for ln in lines]
    for col in ("w_x", "w_y", "w_z", "sd_x", "sd_y", "sd_z"):
        _map_col(lines, col, lambda v: repr(float(v) * 1000))
    r = fit_joint(read_bench_csv(_write(tmp_path, lines)))
    assert r.status == "ok" and r["K_x"].unit == "g/mV"
    assert math.isclose(r["K_x"].value, 1e-3, rel_tol=0.1)
