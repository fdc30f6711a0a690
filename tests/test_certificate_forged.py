"""Forged-but-consistent results: a result JSON edited and re-signed with a recomputed content_sha256
(docs/results-json.md) passes the reader's hash check, and the certificate must still refuse what
contradicts itself, its data or its dates (reports/certificate/consistency.py, docs/certificate.md
"Refused outright"). Each case is an outside tester's probe of 2026-12-01, made here from a real fit:
a simulated campaign with a ``# date`` line, fitted with the example lab file (Type B budgets).
Also export-compensation's message for grid points just outside the range (enough digits)."""

from __future__ import annotations

import copy
import datetime as dt
import hashlib
import json
import math
import os
import re

import pytest

os.environ.setdefault("XDG_CACHE_HOME", "/tmp/xdg")

from triadcal import api  # noqa: E402
from triadcal.errors import InputError  # noqa: E402
from triadcal.estimation.result import CalibrationResult, content_sha256  # noqa: E402
from triadcal.io.bench_csv import read_bench_csv  # noqa: E402
from triadcal.models.effects import DEFAULT_EFFECTS  # noqa: E402
from triadcal.reports import certificate as C  # noqa: E402
from triadcal.reports.compensation import compensation_table  # noqa: E402

pytest.importorskip("reportlab")

DATA_DATE = "2026-11-20"
ISSUE = "2026-11-29"


# -- a real result and its re-signing ----------------------------------------------------------
def _clean(o):
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, list):
        return [_clean(v) for v in o]
    return o


def resign(doc: dict) -> dict:
    """content_sha256 as docs/results-json.md says: SHA-256 of the document without the key, canonical
    JSON (sorted keys, no spaces, ASCII, non-finite numbers as null)."""
    body = {k: v for k, v in doc.items() if k != "content_sha256"}
    text = json.dumps(_clean(body), sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    doc["content_sha256"] = hashlib.sha256(text.encode()).hexdigest()
    return doc


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("forged")
    api.simulate(d / "sim.csv", seed=12, unit="SN-FORGE-01")
    lines = (d / "sim.csv").read_text().splitlines(keepends=True)
    lines = [x for x in lines if not x.startswith("# date")]
    lines.insert(1, f"# date = {DATA_DATE}\n")              # the day the data were taken
    (d / "data.csv").write_text("".join(lines))
    (d / "lab.toml").write_text(C.EXAMPLE_LAB_TOML)
    result = api.fit(read_bench_csv(d / "data.csv"), effects=DEFAULT_EFFECTS, lab=d / "lab.toml")
    assert result.status == "ok", result.notes
    result.save(d / "result.json")
    doc = json.loads((d / "result.json").read_text())
    assert doc["data_date"] == DATA_DATE
    assert resign(copy.deepcopy(doc))["content_sha256"] == doc["content_sha256"] == content_sha256(doc)
    return d


def forged(fitted, name: str, edit) -> str:
    doc = json.loads((fitted / "result.json").read_text())
    edit(doc)
    path = fitted / f"{name}.json"
    path.write_text(json.dumps(resign(doc), indent=1))
    return str(path)


def issue(fitted, result, **kw):
    kw.setdefault("lab", fitted / "lab.toml")
    kw.setdefault("issue_date", ISSUE)
    return C.certificate(result, **kw)


def test_the_unedited_result_is_issued_with_and_without_data(fitted):
    cert = issue(fitted, fitted / "result.json", data=fitted / "data.csv")
    assert cert.issued, cert.reasons
    ident = dict(cert.identification)
    assert ident["Date of calibration"].startswith(f"{DATA_DATE} (from the data")
    # without --data the result's own data_date is the date of calibration (it said "not stated")
    cert = issue(fitted, fitted / "result.json")
    assert cert.issued, cert.reasons
    assert dict(cert.identification)["Date of calibration"] == f"{DATA_DATE} (the result's data_date)"


# -- finding 2: the temperature range against the data ----------------------------------------------
def test_a_range_wider_than_the_datas_visits_is_refused(fitted):
    path = forged(fitted, "wide", lambda d: d.__setitem__("temperature_range_C", [-60.0, 100.0]))
    t = read_bench_csv(fitted / "data.csv").t
    with pytest.raises(InputError) as e:
        issue(fitted, path, data=fitted / "data.csv", html=fitted / "wide.html")
    msg = str(e.value)
    assert "wide.json" in msg and "temperature_range_C = [-60.0000, 100.0000]" in msg, msg
    assert f"{t.min():.4f} .. {t.max():.4f} degC" in msg and "data.csv" in msg, msg
    assert not (fitted / "wide.html").exists()
    # one end only, by 0.1 degC
    path = forged(fitted, "wide_hi", lambda d: d["temperature_range_C"].__setitem__(1, float(t.max()) + 0.1))
    with pytest.raises(InputError, match="temperature_range_C"):
        issue(fitted, path, data=fitted / "data.csv")


# -- finding 3: one coverage, the certificate's ----------------------------------------------------
def test_a_parameter_at_another_coverage_is_refused(fitted):
    def cov68(d):
        p = d["parameters"]["K_x"]
        p["coverage_probability"], p["k"], p["U"] = 0.6827, 1.0, p["u"]     # k = 1 is the GUM k at 68.27 %
    path = forged(fitted, "cov68", cov68)
    CalibrationResult.load(path)                                              # the reader accepts it
    with pytest.raises(InputError) as e:
        issue(fitted, path, data=fitted / "data.csv")
    msg = str(e.value)
    assert "parameters.K_x.coverage_probability = 0.6827" in msg and "95.45 %" in msg, msg


def test_a_stated_U_that_its_budget_does_not_give_is_refused(fitted):
    """dof_eff 3 with k = t(3) = 3.307 and U = k u passes the reader, but the budget's rows (all of
    infinite dof) give k = 2: section 4 would print 3.3 u and section 7 recompute 2 u."""
    from scipy import stats

    def dof3(d):
        p = d["parameters"]["K_x"]
        p["dof_eff"] = 3.0
        p["k"] = float(stats.t.ppf((1 + p["coverage_probability"]) / 2, 3.0))
        p["U"] = p["k"] * p["u"]
    path = forged(fitted, "dof3", dof3)
    CalibrationResult.load(path)
    with pytest.raises(InputError) as e:
        issue(fitted, path)
    assert "parameters.K_x.U" in str(e.value) and "its budget gives" in str(e.value), str(e.value)


# -- finding 4: dates -----------------------------------------------------------------------------------
def test_an_issue_date_before_the_calibration_or_after_today_is_refused(fitted):
    with pytest.raises(InputError) as e:
        issue(fitted, fitted / "result.json", data=fitted / "data.csv", issue_date="2026-11-01")
    msg = str(e.value)
    assert "--date 2026-11-01" in msg and f"before the date of calibration {DATA_DATE}" in msg, msg
    # without --data, from the result's data_date
    with pytest.raises(InputError, match=f"before the date of calibration {DATA_DATE} \\(the result's data_date\\)"):
        issue(fitted, fitted / "result.json", issue_date="2026-11-19")
    later = (dt.datetime.now(dt.timezone.utc).date() + dt.timedelta(days=30)).isoformat()
    with pytest.raises(InputError) as e:
        issue(fitted, fitted / "result.json", data=fitted / "data.csv", issue_date=later)
    msg = str(e.value)
    assert f"--date {later}" in msg and "after today" in msg and DATA_DATE in msg, msg
    # on the day of calibration: issued
    assert issue(fitted, fitted / "result.json", issue_date=DATA_DATE).issued


def test_a_data_date_edited_into_the_future_is_refused(fitted):
    path = forged(fitted, "future", lambda d: d.__setitem__("data_date", "2099-01-01"))
    with pytest.raises(InputError, match="data_date = 2099-01-01 is not the date of its data"):
        issue(fitted, path, data=fitted / "data.csv")
    with pytest.raises(InputError, match="before the date of calibration 2099-01-01.*after today"):
        issue(fitted, path)


# -- finding 5: budgets ----------------------------------------------------------------------------------
def test_a_parameter_without_its_budget_is_refused(fitted):
    path = forged(fitted, "nobudget", lambda d: d["parameters"]["K_x"].pop("budget"))
    with pytest.raises(InputError, match=r"nobudget\.json: refused: parameters\.K_x\.budget is missing"):
        issue(fitted, path, data=fitted / "data.csv")

    def strip(d):
        p = d["parameters"]["S_y"]
        for k in ("budget", "U", "k", "coverage_probability", "dof_eff", "U_method", "u_type_a"):
            p.pop(k, None)
    path = forged(fitted, "nobudget_all", strip)
    with pytest.raises(InputError, match=r"parameters\.S_y\.budget is missing"):
        issue(fitted, path)


def test_a_budget_without_the_gravity_row_is_refused(fitted):
    def drop(d):
        p = d["parameters"]["K_x"]
        p["budget"] = [b for b in p["budget"] if b["source"] != "local gravity"]
        p["u"] = math.sqrt(sum(b["contribution"] ** 2 for b in p["budget"]))      # u, U lowered to match
        p["U"] = p["k"] * p["u"]
    path = forged(fitted, "nogravity", drop)
    CalibrationResult.load(path)
    with pytest.raises(InputError) as e:
        issue(fitted, path, data=fitted / "data.csv")
    msg = str(e.value)
    assert "parameters.K_x.budget holds no row of 'local gravity'" in msg, msg


# -- finding 6: export-compensation's message -----------------------------------------------------------
def test_grid_points_just_outside_the_range_are_printed_beyond_it(fitted):
    result = CalibrationResult.load(fitted / "result.json")
    lo, hi = result.temperature_range_C
    with pytest.raises(InputError) as e:
        compensation_table(result, [lo - 0.004, 20.0, hi + 0.003])
    msg = str(e.value)
    m = re.search(r"grid points (\S+), (\S+) degC lie outside the calibrated range (\S+)\.\.(\S+) degC", msg)
    assert m, msg
    p_lo, p_hi, r_lo, r_hi = map(float, m.groups())
    assert p_lo < r_lo and p_hi > r_hi, msg
