"""What ``triadcal history`` compares, and says, when a calibration in the row cannot be compared (an
outside probe, "probe W", 2026-12-02):

* #1 ok, #2 status model_mismatch, #3 ok with Ca_xy moved +40": "#1 -> #2" and "#2 -> #3" were both
  "not compared" and no verdict covered the move that ``compare #1 #3`` fails; the same with a result
  at another reference temperature in between. Each calibration is now compared with the most recent
  earlier one it can be compared with, the ones passed over named with why;
* an "inconclusive" verdict said nothing of why: it now gives compare's reason in short;
* the reference temperature of each calibration was not in the table (a refit at 25 degC beside
  calibrations at 20 degC looked like a drift): a row T_ref;
* the data of one campaign fitted again from a copy of its CSV were recorded as a second calibration,
  "inconclusive" against the first: recorded, marked a refit of the data of the first (data_sha256) and
  not compared as a new calibration (docs/fleet.md).

The campaigns are made by tests/independent_bench.py (no project model code), fitted with
``triadcal.api.fit``; results edited here are re-signed with ``content_sha256``.
"""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pytest

from independent_bench import default_truth, simulate_campaign
from triadcal.api import fit
from triadcal.cli import main
from triadcal.estimation.result import CONTENT_HASH_KEY, CalibrationResult, content_sha256
from triadcal.fleet.history import HistoryDB, comparisons, history_text, inconclusive_reason, verdicts
from triadcal.io.atomic import read_json
from triadcal.judgement.compare import compare

SERIAL = "SN-PW-0001"
DATES = {"a": "2025-01-10", "b": "2025-02-01", "c": "2025-03-01"}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Campaigns a, b (the unit unchanged) and c (Ca_xy moved +40 arcsec) of one unit, each fitted at
    20 degC and at 25 degC; and a's CSV copied to another folder, fitted at 20 degC."""
    tmp = tmp_path_factory.mktemp("probe_w")
    truth = default_truth(np.random.default_rng(11))
    moved = dict(truth, Ca_xy=truth["Ca_xy"] + 40.0)
    out = {"tmp": tmp}
    for name, seed, t in (("a", 1, truth), ("b", 2, truth), ("c", 3, moved)):
        text, _ = simulate_campaign(np.random.default_rng(seed), truth=t, setpoints_C=(-10, 20, 50), unit=SERIAL)
        csv = tmp / f"{name}.csv"
        csv.write_text(f"# date = {DATES[name]}\n" + text, encoding="utf-8")
        for T in (20, 25):
            r = fit(str(csv), method="joint", reference_temperature_C=float(T))
            assert r.status == "ok"
            r.save(tmp / f"{name}{T}.json")
            out[f"{name}{T}"] = tmp / f"{name}{T}.json"
        if name == "a":
            (tmp / "copy").mkdir()
            (tmp / "copy" / "a.csv").write_bytes(csv.read_bytes())
            fit(str(tmp / "copy" / "a.csv"), method="joint").save(tmp / "a20copy.json")
            out["a20copy"] = tmp / "a20copy.json"
    return out


def _edited(src, dst, **changes):
    """A copy of the result ``src`` with ``changes`` (keys; ``Ca_xy=`` a value shift in arcsec),
    re-signed."""
    d = read_json(src)
    for k, v in changes.items():
        if k in ("Ca_xy", "Ca_zy") and v is None:       # not determined by the data, as a fit says so
            del d["parameters"][k]
            d.setdefault("unidentifiable", {})[k] = "not determined by the data (a test's edit)"
        elif k == "Ca_xy":
            d["parameters"]["Ca_xy"]["value"] += v
        else:
            d[k] = v
    d.pop(CONTENT_HASH_KEY, None)
    d[CONTENT_HASH_KEY] = content_sha256(d)
    dst.write_text(json.dumps(d), encoding="utf-8")
    return dst


def _record(db, *files, capsys=None):
    for f in files:
        assert main(["history", "--add", str(f), "--db", str(db)]) == 0
    if capsys is not None:
        capsys.readouterr()
    assert main(["history", SERIAL, "--db", str(db)]) == 0
    with HistoryDB(db) as h:
        return h.calibrations(SERIAL)


def _compare_lines(text):
    return text.split("significance only):", 1)[1].split("\n\n", 1)[0].strip().splitlines()


def test_a_drift_behind_a_result_that_is_not_ok_is_compared_with_the_calibration_before_it(runs, capsys):
    bad = _edited(runs["b20"], runs["tmp"] / "b20_mismatch.json", status="model_mismatch")
    cals = _record(runs["tmp"] / "gap.sqlite", runs["a20"], bad, runs["c20"], capsys=None)
    text = capsys.readouterr().out
    assert [c["result"]["status"] for c in cals] == ["ok", "model_mismatch", "ok"]
    lines = [ln.strip() for ln in _compare_lines(text)]
    assert lines == ["#2: not compared: status is 'model_mismatch', not 'ok'",
                     "#1 -> #3: fail (#2 skipped: status is 'model_mismatch', not 'ok')"], text
    assert verdicts(cals) == ["not compared: status is 'model_mismatch', not 'ok'", "fail"]
    # the verdict is compare's on the two results
    a, c = (CalibrationResult.load(runs[k]) for k in ("a20", "c20"))
    assert compare(a, c, tolerance_arcsec=None).overall == "fail"


def test_a_result_at_another_reference_temperature_is_passed_over_with_its_reason(runs, capsys):
    cals = _record(runs["tmp"] / "tref.sqlite", runs["a20"], runs["b25"], runs["c20"])
    text = capsys.readouterr().out
    assert [c["result"]["reference_temperature_C"] for c in cals] == [20.0, 25.0, 20.0]
    lines = [ln.strip() for ln in _compare_lines(text)]
    assert lines[0].startswith("#2: not compared: no earlier calibration can be compared with it (#1: reference "
                               "temperatures differ (20 vs 25 degC)"), text
    assert lines[1] == "#1 -> #3: fail (#2 skipped: reference temperatures differ (25 vs 20 degC))", text
    assert len(lines) == 2
    # the table says at which temperature each calibration's values are
    row = next(ln for ln in text.splitlines() if ln.strip().startswith("T_ref"))
    assert row.split()[1:] == ["20", "°C", "25", "°C", "20", "°C"], row


def test_a_refit_at_another_temperature_is_no_new_calibration_but_the_earlier_one_at_that_temperature(runs, capsys):
    """a at 20 degC, a's data refitted at 25 degC (the refit compare asks for), c at 25 degC: the refit is
    not compared as a new calibration, and c is compared with it (a at 20 degC passed over, with why)."""
    cals = _record(runs["tmp"] / "refit25.sqlite", runs["a20"], runs["a25"], runs["c25"])
    text = capsys.readouterr().out
    assert [c["date"] for c in cals] == [DATES["a"], DATES["a"], DATES["c"]]
    lines = [ln.strip() for ln in _compare_lines(text)]
    assert lines[0].startswith("#2: not compared: a refit of the data of #1 (data_sha256 ")
    assert lines[1] == "#2 -> #3: fail (#1 skipped: reference temperatures differ (20 vs 25 degC))", text
    (head,) = [ln for ln in text.splitlines() if ln.startswith(f"  #2 {DATES['a']}")]
    assert head.endswith("[a fit of the data of #1]")


def test_inconclusive_gives_its_reason(runs, capsys):
    """An angle significant alone while the joint test of the six is not: compare's overall is
    inconclusive, and the history now says why."""
    a = read_json(runs["a20"])
    u = a["parameters"]["Ca_xy"]["u"]
    shift = 2.4 * math.sqrt(2.0) * u                  # z 2.4 on Ca_xy, the other angles unchanged
    other = _edited(runs["a20"], runs["tmp"] / "a20_moved.json", Ca_xy=shift, source="elsewhere.csv",
                    data_sha256=hashlib.sha256(b"another campaign").hexdigest(), data_date=DATES["b"])
    cals = _record(runs["tmp"] / "inc.sqlite", runs["a20"], other)
    text = capsys.readouterr().out
    (line,) = [ln.strip() for ln in _compare_lines(text)]
    assert line.startswith("#1 -> #2: inconclusive: Ca_xy +"), text
    assert "significant alone), but the joint test of the 6 angles is not significant" in line
    assert verdicts(cals) == ["inconclusive"]
    # a verdict held back from pass gives the note's head: an angle missing from one side
    gone = _edited(runs["a20"], runs["tmp"] / "a20_no_zy.json", Ca_zy=None, source="elsewhere.csv",
                   data_sha256=hashlib.sha256(b"a third campaign").hexdigest(), data_date=DATES["b"])
    before, after = CalibrationResult.load(runs["a20"]), CalibrationResult.load(gone)
    cmp = compare(before, after, tolerance_arcsec=None, files=("#1", "#2"))
    assert cmp.overall == "inconclusive"
    # (and the values of the other five are those of #1 to the digit: the same data, compare.guards.copied_data)
    assert inconclusive_reason(cmp) == "Ca_zy missing from #2 (and 1 more: see triadcal compare)"


def test_the_same_data_fitted_from_a_copied_csv_is_recorded_as_a_refit_and_not_compared(runs, capsys):
    a, copy = read_json(runs["a20"]), read_json(runs["a20copy"])
    assert a["source"] != copy["source"] and a["data_sha256"] == copy["data_sha256"]
    db = runs["tmp"] / "copy.sqlite"
    assert main(["history", "--add", str(runs["a20"]), "--db", str(db)]) == 0
    capsys.readouterr()
    assert main(["history", "--add", str(runs["a20copy"]), "--db", str(db)]) == 0
    said = capsys.readouterr().out.splitlines()
    assert said[0].endswith(f"recorded in {db}")
    assert said[1].startswith(f"{runs['a20copy']}: note: the same data as #1 ({DATES['a']}, from {a['source']}): "
                              "recorded as #2, a refit of the data of #1 (data_sha256 " + a["data_sha256"][:12])
    cals = _record(db, runs["c20"])
    text = capsys.readouterr().out
    lines = [ln.strip() for ln in _compare_lines(text)]
    assert lines[0].startswith("#2: not compared: a refit of the data of #1"), text
    assert lines[1] == "#1 -> #3: fail", text          # the calibration of a's data, not its refit
    assert "inconclusive" not in text
    assert [e["refit_of"] for e in comparisons(cals)] == [None, 1, None]


def test_a_fit_that_cannot_be_compared_leaves_the_data_to_the_next_fit_of_them(runs, capsys):
    """a's data: first a fit with status model_mismatch, then an ok one (the copied CSV): the ok fit
    is the calibration of those data and c is compared with it."""
    bad = _edited(runs["a20"], runs["tmp"] / "a20_mismatch.json", status="model_mismatch")
    cals = _record(runs["tmp"] / "first_bad.sqlite", bad, runs["a20copy"], runs["c20"])
    text = capsys.readouterr().out
    lines = [ln.strip() for ln in _compare_lines(text)]
    assert lines == ["#1: not compared: status is 'model_mismatch', not 'ok'",
                     "#2: not compared: no earlier calibration can be compared with it (#1: status is "
                     "'model_mismatch', not 'ok') (a fit of the data of #1)",
                     "#2 -> #3: fail"], text
    assert [e["verdict"] for e in comparisons(cals)] == [None, None, "fail"]


def test_history_text_of_minimal_records_still_reads(runs):
    """Records without a reference temperature (another writer) show '-' in T_ref, and results that
    cannot be read are not compared, with why."""
    cal = {"id": 1, "date": "2025-01-01", "state": "", "lab": "",
           "result": {"method": "joint", "status": "ok", "parameters": {"Ca_xy": {"value": 1.0, "u": 0.1,
                                                                                  "unit": "arcsec"}}}}
    text = history_text("SN-M", [cal, dict(cal, id=2, date="2025-02-01")])
    row = next(ln for ln in text.splitlines() if ln.strip().startswith("T_ref"))
    assert row.split()[1:] == ["-", "-"]
    assert "#2: not compared: " in text and "#1: not compared: " in text


def test_the_state_fitted_is_in_the_result_and_the_history(tmp_path):
    """An outside probe: `fit --state after` wrote no state into the result, and history listed "state -"
    for every calibration. The result now carries the state of the visits fitted (not the default
    'initial'), and history --add records it."""
    from triadcal.io.bench_csv import parse_bench_csv

    text, _ = simulate_campaign(np.random.default_rng(5))
    lines = text.splitlines()
    head = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    col = lines[head].split(",").index("state")
    body = []
    for ln in lines[head + 1:]:
        f = ln.split(",")
        f[col] = "after"
        body.append(",".join(f))
    camp = parse_bench_csv("\n".join(lines[:head + 1] + body) + "\n", "after.csv")
    res = fit(camp)
    assert res.extra.get("state") == "after"
    res.save(tmp_path / "after.json")
    assert main(["history", res.unit, "--db", str(tmp_path / "h.sqlite"), "--add", str(tmp_path / "after.json"),
                 "--quiet"]) == 0
    with HistoryDB(tmp_path / "h.sqlite") as db:
        assert [c["state"] for c in db.calibrations(res.unit)] == ["after"]
    # the default state is not said
    assert "state" not in fit(parse_bench_csv(text, "initial.csv")).extra


def test_an_undated_result_recorded_as_today_says_so(runs, tmp_path, capsys):
    """A result with no date of its own (batch.date, date, data_date), no --date and no lab file took
    today's date without a word, and the history orders (and compares) by it."""
    import datetime as dt

    d = read_json(runs["a20"])
    for k in ("date", "data_date"):
        d.pop(k, None)
    d.pop(CONTENT_HASH_KEY, None)
    d[CONTENT_HASH_KEY] = content_sha256(d)
    undated = tmp_path / "undated.json"
    undated.write_text(json.dumps(d), encoding="utf-8")
    db = tmp_path / "h.sqlite"
    assert main(["history", "--add", str(undated), "--db", str(db)]) == 0
    said = capsys.readouterr().out
    assert "no calibration date in the result" in said and "recorded as today's" in said
    with HistoryDB(db) as h:
        assert h.calibrations(SERIAL)[0]["date"] == dt.datetime.now(dt.timezone.utc).date().isoformat()
    # a dated one (the data's date) is recorded without the note
    assert main(["history", "--add", str(runs["b20"]), "--db", str(db)]) == 0
    assert "no calibration date" not in capsys.readouterr().out
