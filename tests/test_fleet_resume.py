"""What a rerun of ``batch`` reuses, and the dates and results ``history`` records (an outside probe
with its own numpy bench, 2026-12-01):

* a stored result edited by 50 arcsec with its checksum left stale, and one unit's result copied over
  another's of the same input file, were skipped as done ("7 ok"): the edited value, and the other
  unit's values under this unit's name, in the fleet summary and the history;
* ``# date`` in day-first form was stored as text and the history ordered by it: 20.03.2024 after
  12.02.2026, the oldest calibration compared as the latest; the plot skipped every point silently;
* ``fit --json`` then ``history --add`` recorded today's date where the data stated theirs;
* a result without its checksum, Ca_xy edited, recorded and compared ("fail") without a word.
"""

from __future__ import annotations

import json
import sqlite3

import pytest

from test_fleet import write_multi
from triadcal.errors import InputError
from triadcal.fleet.batch import FitOptions, fit_file_part
from triadcal.fleet.history import HistoryDB, history_text, plot_history
from triadcal.io.atomic import read_json
from triadcal.io.bench_csv import BenchCSVError, read_bench_csv


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("resume")
    src = write_multi(tmp / "two.csv", 2)
    out = tmp / "out"
    first = fit_file_part(str(src), str(out), 0, 1, None, FitOptions())
    assert [r["action"] for r in first] == ["fitted", "fitted"]
    return src, out, {r["unit"]: r["path"] for r in first}


def test_an_edited_stored_result_is_fitted_again_not_reused(fitted, tmp_path):
    src, out, paths = fitted
    p = paths["SN-0001"]
    d = read_json(p)
    true_value = d["parameters"]["Ca_xy"]["value"]
    d["parameters"]["Ca_xy"]["value"] += 50.0                     # content_sha256 left as it was: stale
    with open(p, "w", encoding="utf-8") as f:
        json.dump(d, f)
    again = {r["unit"]: r for r in fit_file_part(str(src), str(out), 0, 1, None, FitOptions())}
    assert again["SN-0001"]["action"] == "fitted" and again["SN-0002"]["action"] == "skipped"
    assert again["SN-0001"]["result"]["parameters"]["Ca_xy"]["value"] == pytest.approx(true_value, abs=1e-9)
    assert read_json(p)["parameters"]["Ca_xy"]["value"] == pytest.approx(true_value, abs=1e-9)


def test_another_units_result_in_this_units_file_is_fitted_again(fitted):
    src, out, paths = fitted
    with open(paths["SN-0002"], encoding="utf-8") as f:
        other = f.read()
    with open(paths["SN-0001"], "w", encoding="utf-8") as f:
        f.write(other)                                              # intact checksum, wrong unit
    again = {r["unit"]: r for r in fit_file_part(str(src), str(out), 0, 1, None, FitOptions())}
    assert again["SN-0001"]["action"] == "fitted" and again["SN-0001"]["result"]["unit"] == "SN-0001"
    assert read_json(paths["SN-0001"])["unit"] == "SN-0001"
    assert again["SN-0002"]["action"] == "skipped"


def test_a_date_that_is_not_iso_is_refused_naming_the_line(fitted, tmp_path):
    src, _, _ = fitted
    lines = src.read_text(encoding="utf-8").splitlines()
    bad = tmp_path / "dated.csv"
    bad.write_text("\n".join(["# date = 20.03.2024"] + lines) + "\n", encoding="utf-8")
    with pytest.raises(BenchCSVError, match=r"dated.csv:1: metadata 'date' = '20.03.2024' is not an ISO 8601 date"):
        read_bench_csv(bad)
    good = tmp_path / "iso.csv"
    good.write_text("\n".join(["# date = 2024-03-20"] + lines) + "\n", encoding="utf-8")
    assert read_bench_csv(good).metadata["date"] == "2024-03-20"


def test_history_add_takes_the_datas_date_and_marks_an_unhashed_result(tmp_path):
    """A fit of data dated 2024-06-05, saved and recorded with --add: the history holds 2024-06-05
    (not today). The same result with its checksum deleted and Ca_xy edited is recorded under
    another date, marked, and the note says its verdicts rest on values not known to be the fit's."""
    from triadcal.api import fit, simulate
    from triadcal.cli import main

    src = tmp_path / "c.csv"
    simulate(src, seed=3, unit="SN-DATE")
    src.write_text("# date = 2024-06-05\n" + src.read_text(encoding="utf-8"), encoding="utf-8")
    r = fit(read_bench_csv(src), method="joint")
    assert r.extra["data_date"] == "2024-06-05"
    r.save(tmp_path / "r.json")
    db = tmp_path / "h.sqlite"
    assert main(["history", "--add", str(tmp_path / "r.json"), "--db", str(db)]) == 0
    d = read_json(tmp_path / "r.json")
    d.pop("content_sha256")
    d["parameters"]["Ca_xy"]["value"] += 30.0
    d["data_date"] = "2026-03-01"
    (tmp_path / "edited.json").write_text(json.dumps(d), encoding="utf-8")
    assert main(["history", "--add", str(tmp_path / "edited.json"), "--db", str(db)]) == 0
    with HistoryDB(db) as h:
        cals = h.calibrations("SN-DATE")
    assert [c["date"] for c in cals] == ["2024-06-05", "2026-03-01"]
    text = history_text("SN-DATE", cals)
    assert "#2 2026-03-01" in text and "[not known to be the fit's answer]" in text.splitlines()[2]
    assert "note: #2 holds no content_sha256" in text
    assert "#1 2024-06-05" in text and "[not known" not in text.splitlines()[1]


def test_history_refuses_a_date_that_is_not_iso_and_the_plot_says_why_it_cannot_place_one(tmp_path):
    db = tmp_path / "h.sqlite"
    result = {"unit": "SN-X", "method": "joint", "status": "ok",
              "parameters": {"Ca_xy": {"value": 1.0, "u": 0.1, "unit": "arcsec"}}}
    with HistoryDB(db) as h:
        with pytest.raises(InputError, match=r"--date = '05.01.2025' is not an ISO 8601 date"):
            h.add(result, date="05.01.2025")
        assert h.add(result, date="2025-01-05")
        # a database written before the dates were checked
        h.con.execute("UPDATE calibrations SET date = '05.01.2025'")
        h.con.commit()
        cals = h.calibrations("SN-X")
    assert "is not an ISO 8601 date (YYYY-MM-DD), so the order" in history_text("SN-X", cals)
    with pytest.raises(InputError, match="cannot be placed on the time axis"):
        plot_history("SN-X", cals, tmp_path / "p.png")
    assert not (tmp_path / "p.png").exists()
    sqlite3.connect(db).close()


def test_the_outlier_rules_false_alarm_rate_is_measured_and_said():
    """An outside probe: on 7 normal units a unit 1.4 sigma from the mean was flagged a fleet outlier
    (the MAD of 7 values happened to be small); the documented "5 sigma" rule flags a unit of a
    normal fleet in 11 % of parameters at 5 units, 7.4 % at 7, 3.7 % at 10. The rate is measured
    for the fleet's size and said with every flag: here checked against robust_outliers itself, fleet
    by fleet (another seed; binomial 4 SE)."""
    import numpy as np

    from triadcal.fleet.summary import false_alarm_words, outlier_false_alarm, robust_outliers

    rng = np.random.default_rng(7)
    for n, probe in ((5, 0.11), (7, 0.074), (10, 0.037)):
        rate = outlier_false_alarm(n)
        direct = np.mean([robust_outliers(rng.standard_normal(n)).any() for _ in range(3000)])
        se = np.sqrt(rate * (1 - rate) / 3000)
        assert abs(direct - rate) < 4 * se + 1e-3, (n, direct, rate)
        assert abs(rate - probe) < 0.01, (n, rate, probe)
    assert "7.5 % of parameters" in false_alarm_words(7) or "7.4 % of parameters" in false_alarm_words(7)


def test_a_fleet_is_the_units_of_one_state():
    """An outside probe's batch: one unit calibrated in three states (initial, after_shock,
    after_vibration) with one truth, and two other units: the rule pooled the five unit/state pairs
    as five units, the three near-equal values set the median with a MAD of about 0, and the two
    other units were flagged on 24 and 23 of 24 parameters, "with 5 units". Hand-made records: the
    fleet is per state, the three-state unit is one unit of each state's fleet, and a state with
    fewer than 5 units flags nobody; six units of one state still flag the one 40 u off."""
    from triadcal.fleet.summary import fleet_words, table

    def rec(unit, state, value):
        return {"unit": unit, "state": state, "input": f"{unit}.csv", "action": "fitted",
                "result": {"status": "ok", "fit": {"chi2_dof": 1.0, "n_obs": 100},
                           "parameters": {"Ca_xy": {"value": value, "u": 1.0, "unit": "arcsec"}}}}

    records = [rec("SN-30", s, 10.0 + 0.01 * k) for k, s in enumerate(("initial", "after_shock", "after_vibration"))]
    records += [rec("SN-31", "initial", 30.0), rec("SN-32", "initial", -15.0)]
    _, rows, _ = table(records)
    assert all(r["outliers"] == "" for r in rows), [(r["unit"], r["state"], r["outliers"]) for r in rows]
    words = fleet_words(rows)
    assert "'initial': 3 unit(s) with status ok, too few for the rule" in words
    assert "'after_shock': 1 unit(s)" in words
    six = [rec(f"SN-{k}", "initial", v) for k, v in enumerate((0.3, -0.5, 0.1, 0.8, -0.2, 40.0))]
    _, rows, _ = table(six + records[1:3])
    flagged = {(r["unit"], r["state"]) for r in rows if r["outliers"]}
    assert flagged == {("SN-5", "initial")}, flagged
    assert "'initial': with 6 units a normal fleet" in fleet_words(rows)


def test_the_history_plot_sets_the_states_of_one_date_apart_and_names_them(tmp_path):
    """An outside probe's unit calibrated before and after a shock on one date: both points at one x,
    joined by a vertical line, no label: Ca_xy -39 and +20 arcsec read as one point with a long error
    bar. Calibrations of one date stand 8 h apart in their recorded order, each labelled #id state;
    a history of one calibration a date has no labels."""
    from triadcal.fleet.history import history_points

    def cal(i, date, state, v):
        return {"id": i, "date": date, "state": state,
                "result": {"parameters": {"Ca_xy": {"value": v, "u": 1.0, "unit": "arcsec"}}}}

    cals = [cal(1, "2025-02-10", "initial", -39.0), cal(2, "2025-02-10", "after_shock", 20.0),
            cal(3, "2025-06-01", "after_vibration", 21.0)]
    xs, ys, us, labels, shared = history_points("SN-002", cals, "Ca_xy")
    assert shared and labels == ["#1 initial", "#2 after_shock", "#3 after_vibration"] and ys == [-39.0, 20.0, 21.0]
    assert (xs[1] - xs[0]).total_seconds() == 8 * 3600 and xs[2] > xs[1]
    plot_history("SN-002", cals, tmp_path / "h.png")
    assert (tmp_path / "h.png").read_bytes()[:4] == b"\x89PNG"
    assert not history_points("SN-002", [cals[0], cals[2]], "Ca_xy")[4]
