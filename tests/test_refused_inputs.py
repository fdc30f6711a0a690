"""Inputs an outside probe (fresh directory, its own mutations of real files) found accepted or
crashing, each refused now with a one-line error naming the file and field: a history of results
the certificate refuses, a date after today, a fit of one or two visits, budget options that
overflow, an empty output_unit, one output column in another unit (docs/bench-csv.md,
docs/fleet.md, docs/budget.md)."""

import copy
import json

import pytest

from test_bench_csv_misreads import example_table, refused
from triadcal import api
from triadcal.cli import main
from triadcal.io.bench_csv import read_bench_csv
from triadcal.estimation.result import CalibrationResult


@pytest.fixture(scope="module")
def joint():
    return json.loads(json.dumps(api.fit(None, method="joint").to_dict()))


def _save(tmp_path, doc, name):
    """Write ``doc`` with its content hash recomputed (as the probe re-signed its edits)."""
    r = CalibrationResult.from_dict(copy.deepcopy(doc), name)
    path = tmp_path / name
    r.save(path)
    return path


@pytest.mark.parametrize("edit, said", [
    (lambda d: d.__setitem__("reference_temperature_C", 500.0), "reference_temperature_C = 500.0"),
    (lambda d: d["parameters"]["Ca_xy"].__setitem__("value", 1e140), "gate angles fails")])
def test_history_refuses_an_ok_result_the_certificate_refuses_and_leaves_no_database(joint, tmp_path, capsys,
                                                                                      edit, said):
    bad = copy.deepcopy(joint)
    edit(bad)
    path = _save(tmp_path, bad, "bad.json")
    db = tmp_path / "h.sqlite"
    assert main(["history", "--add", str(path), "--db", str(db)]) == 1
    err = capsys.readouterr().err
    assert f"{path}: refused:" in err and said in err, err
    assert not db.exists()                               # an empty database was left behind


def test_dates_after_today_are_refused(joint, tmp_path, capsys):
    good = _save(tmp_path, joint, "good.json")
    db = tmp_path / "h.sqlite"
    assert main(["history", "--add", str(good), "--db", str(db), "--date", "2099-12-31"]) == 1
    assert "after today" in capsys.readouterr().err and not db.exists()
    later = copy.deepcopy(joint)
    later["data_date"] = "2099-01-01"
    path = _save(tmp_path, later, "later.json")
    assert main(["history", "--add", str(path), "--db", str(db)]) == 1
    err = capsys.readouterr().err
    assert f"{path}: the result's data_date: 2099-01-01 is after today" in err, err
    assert not db.exists()                 # refused while recording: the database it created is removed
    tab = example_table()
    tab.comments.append("# date = 2099-01-01")
    err = refused(tab.write(tmp_path / "future.csv"))
    assert err.line == len(tab.comments) and "after today" in str(err)


def test_an_empty_output_unit_is_refused(tmp_path):
    tab = example_table()
    i = next(i for i, c in enumerate(tab.comments) if c.startswith("# output_unit"))
    tab.comments[i] = "# output_unit ="
    err = refused(tab.write(tmp_path / "empty_unit.csv"))
    assert err.line == i + 1 and "'output_unit' is empty" in str(err)


def test_one_output_column_in_another_unit_is_refused(tmp_path):
    """w_x in mV in a file of V: the classical fit gave K_x = 0.001 g/V, status ok, a certificate."""
    tab = example_table()
    tab.map("w_x", lambda v: repr(float(v) * 1000.0))
    err = refused(tab.write(tmp_path / "mv.csv"))
    assert err.column == "w_x" and "a factor 1e+03 between the outputs" in str(err)


@pytest.mark.parametrize("plan, axes", [(("P01", "P02", "P03", "P04", "P05", "P06", "P07", "P08"), "z"),
                                        (("P01", "P02", "P03", "P04"), "x, y")])
def test_a_plan_that_never_turns_an_axis_is_refused_for_that_not_for_its_unit(tmp_path, capsys, plan, axes):
    """An outside probe (its own simulator): a plan of P01-P08, z never up or down, was refused by the
    reader as "w_z spans 0.0025 V ... in another unit (mV in a file of V?)"; past it the joint fit stopped
    after one iteration (chi2/dof 2e5). The span check now leaves out outputs the poses do not turn through
    gravity, and the fit refuses naming the axis. Made with the independent bench (its own kinematics)."""
    import numpy as np

    from independent_bench import POSITIONS, simulate_campaign

    text, _ = simulate_campaign(np.random.default_rng(71), positions={k: POSITIONS[k] for k in plan})
    path = tmp_path / "plan.csv"
    path.write_text(text)
    camp = read_bench_csv(path)                        # the reader takes it: the units are right
    assert camp.n_visits == 5 * len(plan)
    assert main(["fit", str(path), "--method", "joint"]) == 1
    err = capsys.readouterr().err
    assert f"never turn the IMU's {axes.split(',')[0]}" in err and "cannot be told from" in err, err
    assert "another unit" not in err and "internal error" not in err, err
    # a column in another unit is still refused when every output is turned
    text, _ = simulate_campaign(np.random.default_rng(71))
    lines = text.splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.startswith("unit,") or ",w_x," in ln)
    col = lines[head].split(",").index("w_x")
    for i in range(head + 1, len(lines)):
        f = lines[i].split(",")
        f[col] = repr(float(f[col]) * 1000.0)
        lines[i] = ",".join(f)
    (tmp_path / "mv.csv").write_text("\n".join(lines) + "\n")
    err = refused(tmp_path / "mv.csv")
    assert err.column == "w_x"


@pytest.mark.parametrize("rows", [1, 2])
def test_a_joint_fit_of_one_or_two_visits_says_why(tmp_path, capsys, rows):
    tab = example_table()
    tab.rows = tab.rows[:rows]
    path = tab.write(tmp_path / f"rows{rows}.csv")
    assert main(["fit", str(path), "--method", "joint"]) == 1
    err = capsys.readouterr().err
    # one or two rows never turn the axes through gravity: refused for that, before the count of parameters
    assert "never turn the IMU's x" in err and "cannot be told from" in err and "internal error" not in err, err


@pytest.mark.parametrize("options, said", [
    (["--sigma1", "1e200"], "overflows"), (["--Q", "1e308"], "overflows"), (["--thermal", "--dT", "1e300"], "overflows"),
    (["--tau", "1e-300"], "beyond a full turn"), (["--thermal", "--T-max", "1e9"], "beyond a full turn")])
def test_budget_options_that_overflow_or_leave_the_circle_are_refused(capsys, options, said):
    assert main(["budget", *options]) == 1
    err = capsys.readouterr().err
    assert said in err and "internal error" not in err, err


@pytest.mark.parametrize("factor", [1e-6, 1e6])
def test_two_noise_statements_that_disagree_are_said(tmp_path, factor):
    """# Q_V2s 10^6 times too small or large beside honest sd_*: fitted without a word (the columns
    take precedence, docs/bench-csv.md); now a note says by how much (a visit's SD 1e-3 / 1e3 times)."""
    tab = example_table()
    i = next(i for i, c in enumerate(tab.comments) if c.startswith("# Q_V2s"))
    tab.comments[i] = f"# Q_V2s = {3e-9 * factor!r}"
    path = tab.write(tmp_path / "q.csv")
    for method in ("joint", "classical"):
        r = api.fit(path, method=method)
        said = [n for n in r.notes if n.startswith("the file states its noise twice")]
        assert said and f"gives a visit's SD {factor ** 0.5:.3g} times" in said[0], (method, r.notes)
    tab.comments[i] = "# Q_V2s = 3e-09"
    r = api.fit(tab.write(tmp_path / "same.csv"), method="joint")
    assert not [n for n in r.notes if "states its noise twice" in n]


def test_a_stated_q_weights_the_fit_where_the_sd_columns_cannot(tmp_path):
    """sd_x = 0 on every row with # Q_V2s stated: the noise was taken as unknown (estimated from the
    residuals); the file's Q weights the fit, and the noise description says why the columns were not used."""
    tab = example_table()
    tab.map("sd_x", lambda v: "0")
    r = api.fit(tab.write(tmp_path / "sd0.csv"), method="joint")
    assert r.fit["noise_known"] is True
    assert r.fit["noise"].startswith("white noise Q = 3e-09") and "sd_* columns not used" in r.fit["noise"]
