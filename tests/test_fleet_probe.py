"""An outside tester's defects of batch / history / export-compensation, each one fixed:
units never pooled in the fleet summary, a corrupt history database named and refused before any
fit, a default grid that says what is wrong, a C header safe for any serial, extrapolated rows and
notes in every table format, one unit and state in one input only, the history's columns."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess

import numpy as np
import pytest

from triadcal.cli import main
from triadcal.errors import InputError


# -- 1. the fleet summary never pools values of different units ---------------------------------

def _record(unit, k_x, k_unit, status="ok"):
    return {"unit": unit, "state": "initial", "input": f"{unit}.csv", "action": "fitted",
            "result": {"status": status, "fit": {"chi2_dof": 1.0, "n_obs": 540},
                       "parameters": {"K_x": {"value": k_x, "u": 1e-6 * k_x, "unit": k_unit},
                                      "Ca_xy": {"value": 10.0 + len(unit), "u": 0.3, "unit": "arcsec"}}}}


def test_fleet_summary_gives_each_unit_and_never_pools_units(tmp_path):
    from triadcal.fleet.summary import table, write_summary

    recs = [_record(f"SN-V{i}", 1.0 + 1e-4 * i, "g/V") for i in range(6)] + [_record("SN-C", 6.1e-5, "g/counts")]
    columns, rows, _ = table(recs)
    assert "K_x_unit" in columns and "Ca_xy_unit" in columns
    by = {r["unit"]: r for r in rows}
    # the unit in one spelling (a result written before 2026-11-30 says g/counts: models/units.py)
    assert by["SN-C"]["K_x_unit"] == "g/count" and by["SN-V0"]["K_x_unit"] == "g/V"
    # pooled, the one g/counts unit is a "5 sigma outlier" of the g/V ones: it is not one
    assert "K_x" not in by["SN-C"]["outliers"]
    files, _ = write_summary(recs, tmp_path)
    got = {r["unit"]: r for r in csv.DictReader(files["csv"].open(encoding="utf-8"))}
    assert got["SN-C"]["K_x_unit"] == "g/count" and got["SN-V3"]["K_x_unit"] == "g/V"
    page = files["html"].read_text(encoding="utf-8")
    assert "K_x (g/V)" in page and "K_x (g/count)" in page and "never pooled" in page
    # an outlier within one unit is still found
    recs[2]["result"]["parameters"]["K_x"]["value"] = 1.5
    _, rows, _ = table(recs)
    assert [r["unit"] for r in rows if "K_x" in r["outliers"]] == ["SN-V2"]


# -- 2. a corrupt history database: one line naming it, batch refuses before any fit -------------

def test_corrupt_history_database_is_named_and_refused_before_fitting(tmp_path, capsys):
    from triadcal.fleet.batch import batch

    bad = tmp_path / "bad.sqlite"
    bad.write_text("garbage\n", encoding="utf-8")
    assert main(["history", "SN-A", "--db", str(bad)]) == 1
    err = capsys.readouterr().err
    assert str(bad) in err and len(err.strip().splitlines()) == 1
    data = tmp_path / "d.csv"
    data.write_text("unit,state\nSN-A,initial\n", encoding="utf-8")
    out = tmp_path / "out"
    with pytest.raises(InputError, match="bad.sqlite"):
        batch([str(data)], out, history=bad, client=object())     # no cluster, no fit: refused first
    assert not out.exists()


# -- 3. the default grid of a result without a range, or of one temperature -----------------------

def test_default_grid_says_what_is_wrong():
    from triadcal.cli.export_compensation import default_grid

    with pytest.raises(InputError, match="no temperature range") as e:
        default_grid(None, "raw.json")
    assert "--grid '" not in str(e.value)
    with pytest.raises(InputError, match="one temperature") as e:
        default_grid((22.23, 22.36), "one.json")
    assert "single point" in str(e.value) and "--grid '" not in str(e.value)
    g = default_grid((-40.01, 80.02), "r.json")
    assert g[:3] == [-40.01, -40.0, -35.0] and g[-2:] == [80.0, 80.02] and len(g) == 27
    assert default_grid((21.0, 24.0), "r.json") == [21.0, 24.0]
    assert default_grid((-40.0, 80.0), "r.json") == [-40.0 + 5.0 * k for k in range(25)]


# -- 4 and 5. a C header safe for any serial; extrapolated rows and notes in every format -----------

def _table(serial):
    from triadcal.reports.compensation import CompensationTable

    n = 3
    z3, z6 = np.zeros((n, 3)), np.zeros((n, 6))
    return CompensationTable(
        unit=serial, output_unit="V", reference_temperature_C=20.0, temperature_range_C=(0.0, 30.0),
        grid_C=np.array([-40.0, 0.0, 30.0]), K=np.ones((n, 3)), S=z3.copy(), angles=z6.copy(),
        Ca_inv=np.stack([np.eye(3)] * n), u_K=z3 + 1e-6, u_S=z3 + 1e-6, u_angles=z6 + 0.3, interp_K=z3.copy(),
        interp_S=z3.copy(), interp_angles=z6.copy(),
        notes=["EXTRAPOLATED: grid points -40 degC lie outside the calibrated range 0.0..30.0 degC",
               "steady state: apply it to the temperature before the lookup"])


SERIAL = 'SN*/x"y /* ??/ \\'


def test_c_header_with_any_serial_compiles_and_marks_extrapolated_rows(tmp_path):
    t = _table(SERIAL)
    text = t.to_c_header()
    body = text[text.index("#ifndef"):]
    k_rows = body[body.index("triadcal_comp_K["):].splitlines()[1:4]
    assert "EXTRAPOLATED" in k_rows[0] and "EXTRAPOLATED" not in k_rows[1] + k_rows[2]
    assert "triadcal_comp_extrapolated[3] = {1, 0, 0}" in text
    assert "apply it to the temperature before the lookup" in text
    cc = shutil.which("gcc")
    if cc is None:
        pytest.skip("no gcc on this machine: the header is not compiled")
    (tmp_path / "comp.h").write_text(text, encoding="utf-8")
    (tmp_path / "t.c").write_text('#include "comp.h"\nint main(void){return (int)(triadcal_comp_K[0][0] < 0.5f)'
                                  ' + (int)triadcal_comp_extrapolated[1];}\n', encoding="utf-8")
    p = subprocess.run([cc, "-Wall", "-Wextra", "-Werror", "-o", str(tmp_path / "t"), str(tmp_path / "t.c")],
                       capture_output=True, text=True, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert subprocess.run([str(tmp_path / "t")]).returncode == 0


def test_csv_and_json_mark_extrapolated_rows_and_carry_the_notes():
    t = _table("SN-1")
    lines = t.to_csv().splitlines()
    notes = [ln for ln in lines if ln.startswith("# note")]
    assert any("before the lookup" in n for n in notes) and any("EXTRAPOLATED" in n for n in notes)
    rows = list(csv.DictReader([ln for ln in lines if not ln.startswith("#")]))
    assert [r["extrapolated"] for r in rows] == ["1", "0", "0"]
    d = json.loads(json.dumps(t.to_dict()))
    assert [r["extrapolated"] for r in d["rows"]] == [True, False, False]
    # a serial with a newline cannot end the CSV's comment line
    assert all(ln.startswith("#") or ln[:1] in "T-0123456789" for ln in _table("A\nB").to_csv().splitlines())


# -- 6. one unit and state in one input; one bad input said once ---------------------------------

def test_one_unit_and_state_in_two_inputs_is_refused_naming_both(tmp_path):
    from triadcal.fleet.batch import batch

    a, b = tmp_path / "a.csv", tmp_path / "a_again.csv"
    for f in (a, b):
        f.write_text("# date = 2026-01-01\nunit,state,setpoint_C\nSN-A,initial,20\nSN-A,,25\n", encoding="utf-8")
    with pytest.raises(InputError) as e:
        batch([str(a), str(b)], tmp_path / "out", client=object())
    assert "a.csv" in str(e.value) and "a_again.csv" in str(e.value) and "SN-A" in str(e.value)
    assert not (tmp_path / "out").exists()


def test_duplicated_manifest_entry_refused_and_a_bad_input_said_once(tmp_path):
    from triadcal.fleet.batch import FitOptions, fit_file_part
    from triadcal.fleet.manifest import read_manifest

    (tmp_path / "rec.csv").write_text("0,0,1\n", encoding="utf-8")
    entry = '[[recording]]\npath = "rec.csv"\nserial = "SN-R1"\nrate_hz = 100\nunit = "g"\nposes = "unknown"\n'
    man = tmp_path / "man.toml"
    man.write_text(entry + "\n" + entry, encoding="utf-8")
    with pytest.raises(InputError, match="recording 2.*SN-R1.*recording 1"):
        read_manifest(man)
    bad = tmp_path / "trunc.csv"
    bad.write_text("unit,state\nSN-A\n", encoding="utf-8")
    recs = [r for part in range(3) for r in fit_file_part(str(bad), str(tmp_path / "o"), part, 3, None, FitOptions())]
    assert len(recs) == 1 and recs[0]["action"] == "error"
    recs = [r for part in range(2) for r in fit_file_part(str(man), str(tmp_path / "o"), part, 2, None, FitOptions())]
    assert len(recs) == 1 and recs[0]["action"] == "error"


# -- 7. the history: each value with its own unit, columns apart -----------------------------------

def test_history_table_gives_each_value_its_unit_and_separates_columns():
    from triadcal.fleet.history import history_text

    def cal(i, v, u, unit):
        return {"id": i, "date": f"2026-0{i}-01", "state": "initial", "lab": "",
                "result": {"method": "joint", "status": "ok",
                           "parameters": {"K_x": {"value": v, "u": u, "unit": unit},
                                          "S_x": {"value": -0.00119937, "u": 7.6e-7, "unit": "g"}}}}

    text = history_text("SN-V", [cal(1, 1.0002087, 1.3e-6, "g/V"), cal(2, 6.1047897e-5, 8.0e-11, "g/counts")])
    row = next(ln for ln in text.splitlines() if ln.strip().startswith("K_x"))
    assert "g/V" in row and "g/counts" in row and row.index("g/V") < row.index("g/counts")
    cells = [c for c in row.split("  ") if c.strip()]
    assert len(cells) == 3, row                      # name and two cells, at least two spaces apart
    s_row = next(ln for ln in text.splitlines() if ln.strip().startswith("S_x"))
    assert len([c for c in s_row.split("  ") if c.strip()]) == 3, s_row


def test_history_says_when_calibrations_share_a_date():
    """An outside probe recorded five results without --date: all got today's date and the history
    compared them in the order they were added, with no word. A note now names the pairs with one
    date; distinct dates give none."""
    from triadcal.fleet.history import history_text

    def cal(i, date):
        return {"id": i, "date": date, "state": "initial", "lab": "",
                "result": {"method": "joint", "status": "ok",
                           "parameters": {"Ca_xy": {"value": 10.0 + i, "u": 0.5, "unit": "arcsec"}}}}

    text = history_text("SN-D", [cal(1, "2026-11-30"), cal(2, "2026-11-30"), cal(3, "2026-12-01")])
    assert "note: #1 and #2 have the same date" in text and "#2 and #3" not in text
    assert "the same date" not in history_text("SN-D", [cal(1, "2026-11-29"), cal(2, "2026-11-30")])
