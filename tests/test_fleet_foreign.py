"""An outside tester's four defects of ``batch``, each fixed, tested on inputs written here by hand
(the example campaign's rows, renamed and rescaled as text; links, folders and Unicode forms made
on the spot), not by the project's simulator:

1. a serial of 253 characters: "File name too long" in a worker took the whole batch down (exit 1,
   no summary, the healthy unit in none);
2. a glob's dangling symbolic link or folder named ``x.csv`` was dropped without a word (exit 0);
3. a file replaced while the batch ran: a result recorded one version's SHA-256 and the other's
   values, and the rerun reused it as done;
4. one serial in Unicode NFC and NFD was fitted as two units whose rows print identically.
"""

from __future__ import annotations

import hashlib
import json
import os
import unicodedata
from pathlib import Path

import pytest

from triadcal.api import fit
from triadcal.cli import main
from triadcal.errors import InputError
from triadcal.fleet import batch as fb
from triadcal.fleet.batch import (
    FitOptions,
    batch,
    check_unique_pairs,
    fit_file_part,
    result_path,
    safe_name,
)
from triadcal.io.atomic import read_json
from triadcal.io.bench_csv import parse_bench_csv

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN = (ROOT / "examples" / "data" / "campaign.csv").read_text(encoding="utf-8")
RECORDING = ROOT / "examples" / "data" / "mikoff_imu0.csv"


def bench_text(serial: str, scale: float = 1.0, header: bool = True) -> str:
    """The example campaign's rows as the unit ``serial``, its readings w_x, w_y, w_z times ``scale``
    (another unit: K divided by ``scale``), with or without the metadata and header lines."""
    lines = CAMPAIGN.splitlines()
    head = [ln for ln in lines if ln.startswith("#")]
    cols = next(ln for ln in lines if not ln.startswith("#")).split(",")
    iw = [cols.index(c) for c in ("w_x", "w_y", "w_z")]
    rows = []
    for ln in lines[len(head) + 1:]:
        f = ln.split(",")
        f[0] = serial
        for i in iw:
            f[i] = repr(float(f[i]) * scale)
        rows.append(",".join(f))
    return "\n".join((head + [",".join(cols)] if header else []) + rows) + "\n"


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


# -- 1. a serial too long for a file name; any failure is that pair's or file's error row -----------

LONG = "SN-" + "A" * 250


def test_safe_name_is_bounded_one_to_one_and_keeps_short_names():
    assert safe_name("SN-0003") == "SN-0003" and safe_name("x" * 100) == "x" * 100
    a, b = safe_name(LONG), safe_name(LONG[:-1] + "B")
    assert a != b and len(a) <= fb.MAX_NAME_CHARS and len(b) <= fb.MAX_NAME_CHARS and "~" in a
    name = result_path("out", LONG + "/é" * 50, "s" * 300).name
    assert len(name.encode("utf-8")) < 255 - 20          # room for the atomic save's temporary name


def test_a_long_serial_is_fitted_under_a_bounded_name_and_keeps_its_whole_serial(tmp_path):
    src = write(tmp_path / "long.csv", bench_text(LONG))
    recs = fit_file_part(str(src), str(tmp_path / "out"), 0, 1, None, FitOptions())
    assert [(r["unit"], r["action"]) for r in recs] == [(LONG, "fitted")]
    saved = read_json(recs[0]["path"])
    assert saved["unit"] == LONG and len(Path(recs[0]["path"]).name) < 120


def test_a_pair_that_cannot_be_saved_is_its_error_row_and_the_batch_goes_on(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    write(data / "two.csv", bench_text("SN-OK") + bench_text("SN-BLOCKED", 1.001, header=False))
    out = tmp_path / "out"
    blocked = result_path(out, "SN-BLOCKED", "initial")
    blocked.mkdir(parents=True)                         # the result file cannot be written: a folder is there
    rep = batch([str(data / "*.csv")], out, workers=1, processes=False, html=False)
    by = {r["unit"]: r for r in rep.records}
    assert by["SN-OK"]["action"] == "fitted" and by["SN-OK"]["result"]["status"] == "ok"
    assert by["SN-BLOCKED"]["action"] == "error" and "SN-BLOCKED__initial.json" in by["SN-BLOCKED"]["error"]
    assert not rep.all_ok
    rows = (out / "fleet.csv").read_text(encoding="utf-8")
    assert "SN-OK" in rows and "SN-BLOCKED" in rows


def test_a_task_that_fails_is_its_files_error_row(tmp_path, monkeypatch):
    data = tmp_path / "data"
    data.mkdir()
    write(data / "a.csv", bench_text("SN-A"))
    write(data / "b.csv", bench_text("SN-B", 1.001))
    real = fb.fit_file_part

    def crashing(path, *args):
        if path.endswith("b.csv"):
            raise MemoryError("worker out of memory")
        return real(path, *args)

    monkeypatch.setattr(fb, "fit_file_part", crashing)
    rep = batch([str(data / "*.csv")], tmp_path / "out", workers=1, processes=False, html=False)
    errors = [r for r in rep.records if r["action"] == "error"]
    assert [r["unit"] for r in rep.records if r["action"] == "fitted"] == ["SN-A"]
    assert len(errors) == 1 and "b.csv" in errors[0]["error"] and "MemoryError" in errors[0]["error"]


# -- 2. a glob match that is not a readable file is an error row -----------------------------------

def test_a_dangling_link_and_a_folder_matched_by_a_glob_are_error_rows(tmp_path, capsys):
    data = tmp_path / "data"
    data.mkdir()
    gone = tmp_path / "offline_share" / "h03.csv"
    os.symlink(gone, data / "h03.csv")
    (data / "x.csv").mkdir()
    files, bad = fb.find_inputs([str(data / "*.csv")])
    assert files == [] and dict(bad) == {str(data / "h03.csv"): f"a dangling symbolic link: its target {gone} is not there",
                                         str(data / "x.csv"): "a directory, not a file"}
    # nothing to fit: no cluster is started, the rows are written, the exit status says "not all fitted"
    out = tmp_path / "out"
    assert main(["batch", str(data / "*.csv"), "--out", str(out), "--no-progress"]) == 3
    said = capsys.readouterr().out
    assert "h03.csv" in said and str(gone) in said and "x.csv" in said
    table = (out / "fleet.csv").read_text(encoding="utf-8")
    assert table.count(",error,refused,") == 2 and "dangling" in table and "directory" in table
    # named explicitly, it is refused before any fit, as before, with the reason
    with pytest.raises(InputError, match="no such file.*dangling.*offline_share"):
        fb.find_inputs([str(data / "h03.csv")])


def test_a_glob_with_good_and_bad_matches_fits_the_good_and_reports_the_bad(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    write(data / "h01.csv", bench_text("SN-H01"))
    os.symlink(tmp_path / "nowhere.csv", data / "h02.csv")
    rep = batch([str(data / "*.csv")], tmp_path / "out", workers=1, processes=False, html=False)
    assert sorted((r["input"].rsplit("/", 1)[-1], r["action"]) for r in rep.records) == [
        ("h01.csv", "fitted"), ("h02.csv", "error")]
    assert not rep.all_ok and rep.n_errors == 1


# -- 3. the SHA-256 recorded is that of the bytes fitted ------------------------------------------

def test_a_file_replaced_after_it_was_read_records_the_sha_of_what_was_fitted(tmp_path, monkeypatch):
    src = tmp_path / "unit.csv"
    a_text, b_text = bench_text("SN-FLIP"), bench_text("SN-FLIP", 1.002)
    write(src, a_text)
    sha = {t: hashlib.sha256(t.encode("utf-8")).hexdigest() for t in (a_text, b_text)}
    k_x = {t: fit(parse_bench_csv(t, str(src)), method="joint").parameters["K_x"].value for t in (a_text, b_text)}
    assert abs(k_x[a_text] / k_x[b_text] - 1.002) < 1e-4
    real = fb.read_input_bytes

    def read_then_replace(path):          # the file is replaced (atomic rename) right after it was read
        data = real(path)
        write(tmp_path / "unit.tmp", b_text)
        os.replace(tmp_path / "unit.tmp", src)
        return data

    monkeypatch.setattr(fb, "read_input_bytes", read_then_replace)
    out = tmp_path / "out"
    first = fit_file_part(str(src), str(out), 0, 1, None, FitOptions())
    monkeypatch.undo()
    doc = read_json(first[0]["path"])
    assert doc["batch"]["input_sha256"] == sha[a_text] and doc["parameters"]["K_x"]["value"] == k_x[a_text]
    # the rerun sees version B: another SHA-256, so it fits again and records B's with B's values
    again = fit_file_part(str(src), str(out), 0, 1, None, FitOptions())
    assert again[0]["action"] == "fitted"
    doc = read_json(again[0]["path"])
    assert doc["batch"]["input_sha256"] == sha[b_text] and doc["parameters"]["K_x"]["value"] == k_x[b_text]
    assert fit_file_part(str(src), str(out), 0, 1, None, FitOptions())[0]["action"] == "skipped"


def test_a_raw_recording_is_hashed_and_parsed_from_one_read_and_named_as_itself(tmp_path, monkeypatch):
    rec = tmp_path / "imu0.csv"
    rec.write_bytes(RECORDING.read_bytes())
    m = tmp_path / "raw.toml"
    m.write_text('[[recording]]\npath = "imu0.csv"\nserial = "MPU-0"\nrate_hz = 100.0\nunit = "m/s2"\n'
                 'poses = "unknown"\n', encoding="utf-8")
    a_sha = hashlib.sha256(RECORDING.read_bytes()).hexdigest()
    real = fb.read_input_bytes

    def read_then_break(path):
        data = real(path)
        Path(path).write_text("not a recording\n", encoding="utf-8")
        return data

    monkeypatch.setattr(fb, "read_input_bytes", read_then_break)
    got = fit_file_part(str(m), str(tmp_path / "out"), 0, 1, None, FitOptions())
    monkeypatch.undo()
    assert got[0]["action"] == "fitted" and got[0]["result"]["batch"]["input_sha256"] == a_sha
    assert got[0]["result"]["source"] == str(rec)
    from triadcal.estimation.raw import fit_raw

    alone = fit_raw(str(RECORDING), 100.0, unit="m/s2", poses="unknown", serial="MPU-0").result.to_dict()
    assert got[0]["result"]["parameters"] == alone["parameters"] and got[0]["result"]["data_sha256"] == alone["data_sha256"]
    # the file now holds no recording: refused naming it, never a temporary copy
    bad = fit_file_part(str(m), str(tmp_path / "out"), 0, 1, None, FitOptions())
    assert bad[0]["action"] == "error" and str(rec) in bad[0]["error"] and "triadcal-batch-" not in bad[0]["error"]


# -- 4. one serial in NFC and NFD is one serial -------------------------------------------------

NFC = unicodedata.normalize("NFC", "SN-É1")
NFD = unicodedata.normalize("NFD", "SN-É1")


def test_one_serial_in_nfc_and_nfd_in_two_files_is_refused_naming_both(tmp_path):
    assert NFC != NFD
    a = write(tmp_path / "nfc.csv", bench_text(NFC))
    b = write(tmp_path / "nfd.csv", bench_text(" " + NFD, 1.001))
    with pytest.raises(InputError) as e:
        batch([str(a), str(b)], tmp_path / "out", client=object())     # refused before any fit
    assert "nfc.csv" in str(e.value) and "nfd.csv" in str(e.value) and "NFD" in str(e.value)
    assert not (tmp_path / "out").exists()


def test_one_serial_in_two_forms_in_one_file_is_refused_not_fitted_twice(tmp_path):
    src = write(tmp_path / "both.csv", bench_text(NFC) + bench_text(NFD, 1.001, header=False))
    with pytest.raises(InputError, match="Unicode forms"):
        check_unique_pairs([src])
    recs = fit_file_part(str(src), str(tmp_path / "out"), 0, 1, None, FitOptions())
    assert len(recs) == 2 and all(r["action"] == "error" and "Unicode forms" in r["error"] for r in recs)
    assert not (tmp_path / "out" / "results").exists()


def test_a_manifest_with_one_serial_in_two_forms_is_refused(tmp_path):
    from triadcal.fleet.manifest import read_manifest

    (tmp_path / "r.csv").write_text("ax,ay,az\n0,0,1\n", encoding="utf-8")
    entry = '[[recording]]\npath = "r.csv"\nserial = "{}"\nrate_hz = 100\nunit = "g"\nposes = "unknown"\n'
    m = tmp_path / "m.toml"
    m.write_text(entry.format(NFC) + "\n" + entry.format(NFD), encoding="utf-8")
    with pytest.raises(InputError, match="recording 2.*recording 1"):
        read_manifest(m)
    assert json.dumps(NFD) != json.dumps(NFC)
