"""The journal of validate-diagnosis (triadcal/judgement/validation_journal.py): rows appended as they
finish, read back only by a run of the same settings and code, every bad line an error naming the
file and line, a torn last line dropped and said; a stopped run resumed (a real kill, slow)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from triadcal.errors import InputError
from triadcal.hardware.storage import FolderLocked, folder_lock
from triadcal.judgement.diagnosis_validation import validate
from triadcal.reports.diagnosis import write_validation
from triadcal.judgement.validation_journal import FILENAME, Journal, code_fingerprint, job_key

SETTINGS = {"preset": "ak18-quartz", "n_draws": 200, "left_out": False, "noise_estimated": False}
ROW = {"condition": "clean", "seed": 1000, "magnitude": 1.0, "verdict": "none"}


def _journal(tmp_path, settings=SETTINGS, fingerprint="a" * 64):
    return Journal(tmp_path, settings, fingerprint)


def test_rows_read_back_as_written(tmp_path):
    j = _journal(tmp_path)
    row = dict(ROW, chi2=np.float64(1.25), n=np.int64(3), p=math.nan, lo=-math.inf)
    j.append("clean|1000|1.0", row)
    j.close()
    r = _journal(tmp_path).rows["clean|1000|1.0"]
    assert r["chi2"] == 1.25 and r["n"] == 3 and math.isnan(r["p"]) and r["lo"] == -math.inf
    assert type(r["n"]) is int
    # the key of a job tuple as validate() builds it: effect, seed, ..., magnitude at index 6
    assert job_key(("bias_drift", 1003, "ak18-quartz", 200, False, 2, 0.5, True, False)) == "bias_drift|1003|0.5"


def test_a_row_the_journal_cannot_write_is_refused_whole(tmp_path):
    j = _journal(tmp_path)
    with pytest.raises(TypeError, match="set"):
        j.append("clean|1000|1.0", dict(ROW, bad={1, 2}))
    j.close()
    lines = (tmp_path / FILENAME).read_text().splitlines()
    assert len(lines) == 1          # the header only: nothing half-written


def test_a_torn_last_line_is_dropped_and_said(tmp_path):
    j = _journal(tmp_path)
    j.append("clean|1000|1.0", ROW)
    j.close()
    with open(tmp_path / FILENAME, "a") as fh:
        fh.write('{"job": "clean|1001|1.0", "row": {"cond')        # killed in the middle of a write
    j = _journal(tmp_path)
    assert list(j.rows) == ["clean|1000|1.0"]
    assert len(j.notes) == 1 and "line 3" in j.notes[0] and "runs again" in j.notes[0]
    j.append("clean|1001|1.0", dict(ROW, seed=1001))
    j.close()
    assert set(_journal(tmp_path).rows) == {"clean|1000|1.0", "clean|1001|1.0"}


@pytest.mark.parametrize("field,settings,fingerprint", [
    ("settings.n_draws", dict(SETTINGS, n_draws=100), "a" * 64),
    ("settings.left_out", dict(SETTINGS, left_out=True), "a" * 64),
    ("code_sha256", SETTINGS, "b" * 64),
])
def test_rows_of_other_settings_or_code_are_refused(tmp_path, field, settings, fingerprint):
    _journal(tmp_path).close()
    with pytest.raises(InputError, match=rf"{FILENAME}: line 1: field {field}"):
        _journal(tmp_path, settings, fingerprint)


@pytest.mark.parametrize("bad,message", [
    ("{not json\n", "line 3: not JSON"),
    ('{"job": "clean|1001|1.0"}\n', "line 3: a row line holds the fields 'job'"),
    ('{"job": "clean|1001|1.0", "row": {"condition": "clean", "seed": 1001, "magnitude": 1.0}}\n',
     "line 3: field row.verdict is missing"),
    ('{"job": "clean|1000|1.0", "row": ' + json.dumps(ROW) + "}\n", "line 3: job clean|1000|1.0 is there twice"),
    (b"\xff\xfe\n", "line 3: not UTF-8"),
])
def test_every_bad_line_is_an_error_naming_file_and_line(tmp_path, bad, message):
    j = _journal(tmp_path)
    j.append("clean|1000|1.0", ROW)
    j.close()
    with open(tmp_path / FILENAME, "ab") as fh:
        fh.write(bad if isinstance(bad, bytes) else bad.encode())
    with pytest.raises(InputError, match=message):
        _journal(tmp_path)


def test_a_file_that_is_no_journal_is_not_taken(tmp_path):
    (tmp_path / FILENAME).write_text('{"format": "triadcal.diagnosis", "version": 1}\n')
    with pytest.raises(InputError, match="line 1: format 'triadcal.diagnosis' is not"):
        _journal(tmp_path)


def test_the_fingerprint_is_of_this_code():
    fp = code_fingerprint()
    assert len(fp) == 64 and fp == code_fingerprint()


def test_a_folder_in_use_is_refused_before_any_diagnosis(tmp_path):
    with folder_lock(tmp_path, "validate-diagnosis"):
        with pytest.raises(FolderLocked, match="in use by another validate-diagnosis"):
            validate(seeds=1, effects=["clean"], processes=1, journal_dir=tmp_path)
        assert not (tmp_path / FILENAME).exists()


@pytest.mark.slow
def test_a_killed_run_resumes_where_it_stopped(tmp_path):
    """A real kill -9 of the CLI after its first row: the second run takes the rows written before the
    kill, diagnoses the rest, and its table equals that of a run never stopped."""
    out = tmp_path / "v"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    cmd = [sys.executable, "-m", "triadcal", "validate-diagnosis", "--seeds", "3", "--effects", "clean",
           "--processes", "1", "--out", str(out), "--no-progress"]
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    journal = out / FILENAME
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and p.poll() is None:
        if journal.exists() and journal.read_text().count("\n") >= 2:      # header and one row
            break
        time.sleep(0.05)
    # killed after its first row, wherever it is then: a loaded machine's poll may come late, so the
    # number of rows written before the kill (1 to 3) is read, not assumed
    p.send_signal(signal.SIGKILL)
    p.wait()
    n_before = journal.read_text().count("\n") - 1
    assert 1 <= n_before <= 3, journal.read_text()
    done = subprocess.run(cmd[:-1], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert f"resumed: {n_before} of the 3 rows" in done.stdout
    assert f"{3 - n_before} diagnoses in" in done.stdout
    resumed = json.loads((out / "validation.json").read_text())["rows"]
    write_validation(validate(seeds=3, effects=["clean"], processes=1), tmp_path / "fresh")
    fresh = json.loads((tmp_path / "fresh" / "validation.json").read_text())["rows"]
    strip = lambda r: {k: v for k, v in r.items() if k not in ("seconds", "cpu_seconds")}  # noqa: E731
    assert [strip(r) for r in resumed] == [strip(r) for r in fresh]
