"""Fleet scale (issue 21): --unit/--state, batch on a real dask LocalCluster, the fleet summary,
resume after a kill, the calibration history. docs/fleet.md."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from triadcal.api import fit, simulate
from triadcal.cli import main
from triadcal.fleet.batch import batch, result_path
from triadcal.fleet.history import HistoryDB, verdicts
from triadcal.fleet.summary import robust_outliers
from triadcal.io.atomic import json_text, read_json
from triadcal.io.bench_csv import read_bench_csv

TRIADCAL = str(Path(sys.executable).with_name("triadcal"))
PLANTED = "SN-0006"


def write_multi(path, n_units, planted=None, seed0=1, state=None):
    """A bench CSV holding ``n_units`` simulated units (seeds seed0, seed0 + 1, ...), written by
    simulating each to its own file and concatenating the data rows under the first header."""
    lines = []
    for i in range(n_units):
        unit = f"SN-{i + 1:04d}"
        one = Path(path).with_name(f".one-{i}.csv")
        simulate(one, unit=unit, seed=seed0 + i, parameters={"Ca_xy": 600.0} if unit == planted else None)
        text = one.read_text(encoding="utf-8").splitlines()
        one.unlink()
        if state is not None:
            text = [l.replace(",initial,", f",{state},") for l in text]
        if i == 0:
            lines += text
        else:
            lines += [l for l in text if not l.startswith("#")][1:]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return Path(path)


def comparable(d):
    """A result document without what differs from run to run (timings) or what batch adds (and the
    checksum of its content, which therefore differs too)."""
    d = json.loads(json.dumps(d))
    d.pop("batch", None)
    d.pop("content_sha256", None)
    for k in ("build_seconds", "solve_seconds"):
        d["fit"].pop(k, None)
    return json_text(d)


@pytest.fixture(scope="module")
def client():
    """A real small LocalCluster: 2 worker processes, one thread each."""
    from triadcal.fleet.batch import start_client

    c, cluster = start_client(None, workers=2, processes=True)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def fleet_csv(tmp_path_factory):
    return write_multi(tmp_path_factory.mktemp("fleet") / "fleet.csv", 6, planted=PLANTED)


# -- fit/sample --unit --state ---------------------------------------------------------------

def test_fit_refuses_a_multi_unit_file_naming_the_options(fleet_csv, tmp_path, capsys):
    assert main(["fit", str(fleet_csv), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "--unit" in err and "--state" in err and "SN-0001" in err


def test_fit_unknown_unit_or_state_lists_those_present(fleet_csv, capsys):
    assert main(["fit", str(fleet_csv), "--unit", "SN-9999", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "no unit 'SN-9999'" in err and "SN-0001, SN-0002" in err
    assert main(["sample", str(fleet_csv), "--unit", "SN-0001", "--state", "shock", "--quiet"]) == 1
    assert "no state 'shock'; its states are initial" in capsys.readouterr().err


def test_fit_unit_equals_api_fit_of_the_selection(fleet_csv, tmp_path):
    out = tmp_path / "r.json"
    assert main(["fit", str(fleet_csv), "--unit", "SN-0002", "--state", "initial", "--quiet",
                 "--json", str(out)]) == 0
    c = read_bench_csv(fleet_csv)
    ref = fit(c.select(c.unit == "SN-0002"))
    assert comparable(read_json(out)) == comparable(ref.to_dict())


# -- batch -------------------------------------------------------------------------------------

def test_batch_one_json_per_unit_bit_identical_resume_and_summary(fleet_csv, tmp_path, client):
    out = tmp_path / "out"
    tol = tmp_path / "tol.toml"
    tol.write_text('[tolerances]\nCa_xy = 450\n"*_hysteresis" = 3600\n', encoding="utf-8")
    rep = batch([str(fleet_csv)], out, client=client, tolerances=tol)
    units = [f"SN-{i:04d}" for i in range(1, 7)]
    files = sorted(p.name for p in (out / "results").glob("*.json"))
    assert files == [f"{u}__initial.json" for u in units]
    assert rep.n_fitted == 6 and rep.n_skipped == 0
    # the numbers of fitting one by one, to the bit
    c = read_bench_csv(fleet_csv)
    for u in units:
        d = read_json(result_path(out, u, "initial"))
        assert d["batch"]["input_sha256"] and d["unit"] == u
        assert comparable(d) == comparable(fit(c.select(c.unit == u)).to_dict()), u
    # the summary: CSV and Parquet, one row per unit, value and u of every parameter
    import csv

    import pyarrow.parquet as pq

    rows = list(csv.DictReader(open(out / "fleet.csv", encoding="utf-8")))
    assert [r["unit"] for r in rows] == units and all(r["status"] == "ok" for r in rows)
    t = pq.read_table(out / "fleet.parquet").to_pydict()
    assert t["unit"] == units
    d1 = read_json(result_path(out, "SN-0001", "initial"))
    for name in ("Ca_xy", "K_x", "S_z", "tilt_delta"):
        assert t[name][0] == d1["parameters"][name]["value"] and t[name + "_u"][0] == d1["parameters"][name]["u"]
        assert float(rows[0][name]) == d1["parameters"][name]["value"]
    assert t["chi2_dof"][0] == d1["fit"]["chi2_dof"]
    # the planted unit (Ca_xy = 600") is a fleet outlier and outside the tolerance; the others not on Ca_xy
    flagged = {r["unit"]: r for r in rows}
    assert "Ca_xy" in flagged[PLANTED]["outliers"].split(";")
    assert "Ca_xy" in flagged[PLANTED]["out_of_tolerance"].split(";")
    assert all("Ca_xy" not in flagged[u]["outliers"].split(";") for u in units if u != PLANTED)
    assert all(not flagged[u]["out_of_tolerance"] for u in units if u != PLANTED)
    page = (out / "fleet.html").read_text(encoding="utf-8")
    assert page.count("data:image/png;base64,") >= 30 and PLANTED in page and "<script" not in page
    # resumable, idempotent: a second batch fits nothing and leaves the files as they were
    before = {p: p.stat().st_mtime_ns for p in (out / "results").glob("*.json")}
    rep2 = batch([str(fleet_csv)], out, client=client, html=False)
    assert rep2.n_fitted == 0 and rep2.n_skipped == 6
    assert {p: p.stat().st_mtime_ns for p in (out / "results").glob("*.json")} == before
    # a result removed is refitted, alone
    result_path(out, "SN-0003", "initial").unlink()
    rep3 = batch([str(fleet_csv)], out, client=client, html=False)
    assert rep3.n_fitted == 1 and rep3.n_skipped == 5
    # a changed input file (other SHA-256) is refitted
    fleet2 = tmp_path / "fleet.csv"
    fleet2.write_text(fleet_csv.read_text(encoding="utf-8") + "\n", encoding="utf-8")
    rep4 = batch([str(tmp_path / "fleet*.csv")], out, client=client, html=False)
    assert rep4.n_fitted == 6


def test_batch_exit_code_says_a_unit_outside_tolerance(tmp_path, client):
    """Exit 4 when every pair is ok but one is outside a tolerance (it was 0: a check on the exit
    code passed the planted unit, Ca_xy = 600 arcsec against a limit of 450; an outside probe); 0
    without the tolerance; on the module's cluster (--scheduler)."""
    from triadcal.cli import main

    tol = tmp_path / "tol.toml"
    tol.write_text("[tolerances]\nCa_xy = 450\n", encoding="utf-8")
    two = write_multi(tmp_path / "two.csv", 2, planted="SN-0002")
    args = ["batch", str(two), "--out", str(tmp_path / "out"), "--scheduler", client.scheduler.address, "--quiet"]
    assert main(args + ["--tolerances", str(tol)]) == 4
    assert main(args) == 0                                  # the same results, skipped: no tolerance, a pass


def test_batch_states_and_history(tmp_path, client):
    a = write_multi(tmp_path / "a.csv", 2, seed0=1)
    b = write_multi(tmp_path / "b.csv", 2, seed0=11, state="after-shock")
    db = tmp_path / "h.sqlite"
    rep = batch([str(tmp_path / "*.csv")], tmp_path / "out", client=client, history=db, html=False)
    assert rep.n_fitted == 4
    assert (tmp_path / "out" / "results" / "SN-0002__after-shock.json").exists()
    with HistoryDB(db) as h:
        cals = h.calibrations("SN-0001")
        assert sorted(c["state"] for c in cals) == ["after-shock", "initial"]
        assert h.add(cals[0]["result"]) is False          # the same result twice: a no-op
        assert len(h.calibrations("SN-0001")) == 2
        # the result as its file holds it (with content_sha256): the same calibration
        doc = json.loads((tmp_path / "out" / "results" / "SN-0001__initial.json").read_text())
        assert "content_sha256" in doc and h.add(doc) is False
    # a rerun skips every pair and records nothing twice (it recorded the files' documents again: two
    # calibrations of one unchanged result, an outside probe)
    rep2 = batch([str(tmp_path / "*.csv")], tmp_path / "out", client=client, history=db, html=False)
    assert rep2.n_skipped == 4 and rep2.n_fitted == 0
    with HistoryDB(db) as h:
        assert len(h.calibrations("SN-0001")) == 2 and len(h.calibrations("SN-0002")) == 2
    assert a.exists() and b.exists()


def test_batch_history_records_the_states_in_measured_order_with_their_checksums(tmp_path, client):
    """An outside probe: batch --history stored each result without its content_sha256 (every calibration
    then read 'not known to be the fit's answer'), and a unit's initial and after-shock states in
    alphabetical order, so that the history showed the shock's +60 arcsec backwards."""
    first = tmp_path / ".first.csv"
    second = tmp_path / ".second.csv"
    simulate(first, unit="SN-0001", seed=1)
    simulate(second, unit="SN-0001", seed=2, parameters={"Ca_xy": 600.0})
    a = first.read_text(encoding="utf-8").splitlines()
    b = [ln for ln in second.read_text(encoding="utf-8").splitlines() if not ln.startswith("#")]
    cols = b[0].split(",")
    it = cols.index("time_s")
    shifted = []
    for ln in b[1:]:
        f = ln.replace(",initial,", ",after-shock,").split(",")
        f[it] = repr(float(f[it]) + 1.0e6)             # measured after the first state
        shifted.append(",".join(f))
    (tmp_path / "unit.csv").write_text("\n".join(a + shifted) + "\n", encoding="utf-8")
    first.unlink()
    second.unlink()
    db = tmp_path / "h.sqlite"
    batch([str(tmp_path / "unit.csv")], tmp_path / "out", client=client, history=db, html=False)
    with HistoryDB(db) as h:
        cals = h.calibrations("SN-0001")
    assert [c["state"] for c in cals] == ["initial", "after-shock"]
    assert all("content_sha256" in c["result"] for c in cals)


@pytest.mark.slow     # two command runs, each starting its own LocalCluster of processes: ~25 s
def test_killed_batch_loses_nothing_and_rerun_completes(tmp_path):
    data = write_multi(tmp_path / "many.csv", 30, seed0=100)
    out = tmp_path / "out"
    env = dict(os.environ, XDG_CACHE_HOME=os.environ.get("XDG_CACHE_HOME", str(tmp_path / "xdg")))
    p = subprocess.Popen([TRIADCAL, "batch", str(data), "--out", str(out), "--no-progress", "--quiet"],
                         env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        # wait for the event (the first result file), failing only if the batch exits first
        while not list((out / "results").glob("*.json")) if (out / "results").exists() else True:
            assert p.poll() is None, "the batch ended before any result was written"
            time.sleep(0.05)
    finally:
        os.killpg(p.pid, signal.SIGKILL)       # the batch, its cluster and workers (one process group)
        p.wait()
    written = {q.name: q.read_bytes() for q in (out / "results").glob("*.json")}
    assert 1 <= len(written)
    for text in written.values():
        json.loads(text)                        # whole files only
    r = subprocess.run([TRIADCAL, "batch", str(data), "--out", str(out), "--no-progress"], env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    n_done = len(written)
    assert f"{30 - n_done} fitted, {n_done} skipped" in r.stdout or \
        int(r.stdout.split(" fitted")[0].split()[-1]) <= 30 - n_done
    for name, text in written.items():         # nothing written before the kill was redone
        assert (out / "results" / name).read_bytes() == text
    assert len(list((out / "results").glob("*.json"))) == 30


# -- outlier rule and history ---------------------------------------------------------------------

def test_robust_outlier_rule():
    x = np.r_[np.random.default_rng(0).normal(40.0, 1.0, 50), 60.0]
    flags = robust_outliers(x)
    assert flags[-1] and not flags[:-1].any()
    assert not robust_outliers([1.0, 2.0, 100.0]).any()         # fewer than 5 units: no rule
    assert not robust_outliers([3.0] * 10).any()                # MAD 0: no rule
    # hand case: nine units at 0 +- 0.1 (MAD 0.1, 1.4826 MAD = 0.148) and one at 1.5, all with
    # u = 1: the old rule (5 x 0.148 = 0.74) flagged the tenth by its measurement noise (1.5 u);
    # floored at u, the threshold is 5 x 1 = 5
    x = np.r_[[-0.1, 0.1] * 4, 0.0, 1.5]
    assert robust_outliers(x)[-1]                                # without u: the fleet's spread only
    flags = robust_outliers(x, u=np.ones(10))
    assert not flags.any()
    assert robust_outliers(np.r_[x[:-1], 5.2], u=np.ones(10))[-1]  # 5.2 u off: flagged
    # a poorly measured unit (u = 10) 20 from the median: within 5 of its own u, not an outlier;
    # the same deviation with u = 1 is
    x2 = np.r_[np.random.default_rng(1).normal(0, 1, 20), 20.0]
    u2 = np.r_[np.ones(20), 10.0]
    assert not robust_outliers(x2, u=u2)[-1] and robust_outliers(x2, u=np.ones(21))[-1]
    assert robust_outliers([3.0] * 9 + [9.0], u=[1.0] * 10)[-1]      # MAD 0, u 1: 6 u off is flagged


def test_history_add_show_noop_verdict_plot(tmp_path, capsys):
    c1, c2 = tmp_path / "c1.csv", tmp_path / "c2.csv"
    simulate(c1, unit="SN-0042", seed=1)
    simulate(c2, unit="SN-0042", seed=2)
    r1, r2 = tmp_path / "r1.json", tmp_path / "r2.json"
    fit(str(c1), json_path=r1)
    fit(str(c2), json_path=r2)
    db = tmp_path / "h.sqlite"
    assert main(["history", "--add", str(r1), "--db", str(db), "--date", "2024-05-01"]) == 0
    assert main(["history", "--add", str(r2), "--db", str(db), "--date", "2025-05-01"]) == 0
    assert main(["history", "--add", str(r1), "--db", str(db)]) == 0          # twice: no-op
    assert "already recorded" in capsys.readouterr().out
    png = tmp_path / "h.png"
    assert main(["history", "SN-0042", "--db", str(db), "--plot", str(png)]) == 0
    text = capsys.readouterr().out
    assert "SN-0042: 2 calibration(s)" in text and "2024-05-01" in text and "2025-05-01" in text
    assert "Ca_xy" in text and "K_x" in text and "S_z" in text and "±" in text
    with HistoryDB(db) as h:
        cals = h.calibrations("SN-0042")
    v = verdicts(cals)
    assert len(v) == 1 and not v[0].startswith("not compared")
    assert f"#1 -> #2: {v[0]}" in text
    assert png.read_bytes()[:4] == b"\x89PNG"
    # the default database: [history] path of the lab file, relative to it
    lab = tmp_path / "lab.toml"
    lab.write_text('[history]\npath = "fromlab.sqlite"\n', encoding="utf-8")
    assert main(["history", "--add", str(r1), "--lab", str(lab), "--quiet"]) == 0
    assert (tmp_path / "fromlab.sqlite").exists()
    assert main(["history", "SN-NONE", "--db", str(db)]) == 1


def test_batch_on_a_running_scheduler_given_its_address(fleet_csv, tmp_path, client):
    """The --scheduler path: a Client of the address of a running scheduler (here the module's
    LocalCluster's), not a cluster of the batch's own; the same numbers as fitting one by one."""
    address = client.scheduler.address
    out = tmp_path / "remote"
    rep = batch([str(fleet_csv)], out, scheduler=address, html=False)
    assert rep.n_fitted == 6 and rep.n_errors == 0
    c = read_bench_csv(fleet_csv)
    ref = fit(c.select(c.unit == "SN-0003"))
    got = read_json(out / "results" / "SN-0003__initial.json")
    got.pop("batch", None)
    assert comparable(got) == comparable(ref.to_dict())
    assert client.status == "running"                 # the batch closed its own client, not the cluster


def test_a_rerun_with_other_settings_fits_again_instead_of_reusing(tmp_path):
    """An outside probe: a rerun of batch with --effects, --angle-bound-arcsec or --lab reused every
    result of the first run (same input SHA-256) and reported them ok, one without the lab's Type B,
    another without the angle gate's refusal. The task (no cluster needed) now refits when the
    settings differ, and reuses only the same input with the same settings."""
    from triadcal.fleet.batch import FitOptions, fit_file_part
    from triadcal.io.lab import LabConfig

    src = write_multi(tmp_path / "two.csv", 2)
    out = tmp_path / "out"
    first = fit_file_part(str(src), str(out), 0, 1, None, FitOptions())
    assert [r["action"] for r in first] == ["fitted", "fitted"]
    assert [r["action"] for r in fit_file_part(str(src), str(out), 0, 1, None, FitOptions())] == ["skipped"] * 2
    tight = fit_file_part(str(src), str(out), 0, 1, None, FitOptions(angle_bound_arcsec=20.0))
    assert [r["action"] for r in tight] == ["fitted", "fitted"]
    assert all(r["result"]["status"] == "angle_out_of_range" for r in tight), [r["result"]["status"] for r in tight]
    lab = LabConfig(encoder_zero_u_arcsec=5.0, mounting_u_arcsec=10.0, source="lab.toml")
    with_lab = fit_file_part(str(src), str(out), 0, 1, lab, FitOptions(angle_bound_arcsec=20.0))
    assert [r["action"] for r in with_lab] == ["fitted", "fitted"]
    assert all("budget" in r["result"]["parameters"]["Ca_xy"] for r in with_lab)


def test_an_input_refused_whole_is_counted_and_named_as_an_input(tmp_path, client, capsys):
    """An outside probe: a refused file was counted among the 'unit/state pairs', and the HTML's flagged
    table showed it as an empty unit and state with the word 'refused', no file, no reason."""
    simulate(tmp_path / "good.csv", unit="SN-0001", seed=1)
    simulate(tmp_path / "other.csv", unit="SN-0002", seed=2)
    text = (tmp_path / "other.csv").read_text(encoding="utf-8").splitlines()
    (tmp_path / "other.csv").unlink()
    (tmp_path / "cut.csv").write_text("\n".join(text[:40] + [text[40][:30]]) + "\n", encoding="utf-8")
    assert main(["batch", str(tmp_path / "good.csv"), str(tmp_path / "cut.csv"), "--out", str(tmp_path / "out"),
                 "--scheduler", client.scheduler.address, "--no-progress"]) != 0
    said = capsys.readouterr().out
    assert "1 unit/state pairs" in said and "1 input(s) refused whole" in said
    page = (tmp_path / "out" / "fleet.html").read_text(encoding="utf-8")
    assert "cut.csv" in page and "input(s) refused whole" in page


def test_relative_paths_reach_workers_whose_working_directory_differs(fleet_csv, tmp_path, client, monkeypatch):
    """The cluster's worker processes keep the directory they started in; the client moves elsewhere and
    names its input and --out relative to it (an outside probe's external scheduler: "results in
    outS2/results" printed, the results written under the worker's folder, the client's left empty)."""
    import shutil

    shutil.copy(fleet_csv, tmp_path / "fleet.csv")
    monkeypatch.chdir(tmp_path)
    rep = batch(["fleet.csv"], "out", client=client)
    assert rep.n_fitted == 6
    assert sorted(p.name for p in (tmp_path / "out" / "results").glob("*.json")) == [
        f"SN-{i:04d}__initial.json" for i in range(1, 7)]
