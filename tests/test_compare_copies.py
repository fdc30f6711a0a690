"""compare on two fits of the same data whose files differ in bytes, and on results whose data_date
is no date (an outside probe: a campaign's CSV with its rows reversed, its numbers rewritten to 15
significant digits or its times moved to Unix time got a new data_sha256 each, and compare said
"overall pass", exit 0, largest |z| 2e-10; '10.02.2026', '2026-02-30' and '2099-01-01' as data_date
were accepted, the malformed ones dropped, which turned the date-order check off).

The campaign is the independent bench's (tests/independent_bench.py); the re-export is done here on
its text."""
from __future__ import annotations

import json

import numpy as np
import pytest

from independent_bench import simulate_campaign
from triadcal.api import fit
from triadcal.cli import main
from triadcal.io.bench_csv import parse_bench_csv


def _reversed_rows(text: str) -> str:
    lines = text.splitlines()
    head = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if ln and not ln.startswith("#")]
    return "\n".join(head + body[:1] + body[1:][::-1]) + "\n"


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    d = tmp_path_factory.mktemp("copies")
    text, _ = simulate_campaign(np.random.default_rng(5), setpoints_C=(20.0,))
    a, b = parse_bench_csv(text), parse_bench_csv(_reversed_rows(text))
    fa, fb = fit(a, effects=["bench_tilt"]), fit(b, effects=["bench_tilt"])
    assert fa.extra["data_sha256"] != fb.extra["data_sha256"]           # the hash does not see the copy
    fa.save(d / "a.json")
    fb.save(d / "b.json")
    return d


def test_a_reexported_copy_is_not_a_pass(pair, capsys):
    code = main(["compare", str(pair / "a.json"), str(pair / "b.json"), "--tolerance", "none", "--exit-code",
                 "--json", str(pair / "c.json")])
    out = capsys.readouterr().out
    c = json.loads((pair / "c.json").read_text())
    assert c["overall"] == "inconclusive" and code != 0, (c["overall"], code)
    assert any("fits of the same data" in n and "re-exported" in n for n in c["notes"]), c["notes"]
    assert "overall: inconclusive" in out


def test_two_calibrations_are_still_compared(tmp_path, capsys):
    """Two campaigns of one unit (independent noise): no copy note, a verdict."""
    truth = None
    paths = []
    for seed in (6, 7):
        text, t = simulate_campaign(np.random.default_rng(seed), setpoints_C=(20.0,), truth=truth)
        truth = truth or t
        fit(parse_bench_csv(text), effects=["bench_tilt"]).save(tmp_path / f"{seed}.json")
        paths.append(str(tmp_path / f"{seed}.json"))
    main(["compare", *paths, "--json", str(tmp_path / "c.json")])
    c = json.loads((tmp_path / "c.json").read_text())
    assert not any("fits of the same data" in n for n in c["notes"]), c["notes"]
    assert c["overall"] in ("pass", "fail", "inconclusive")


@pytest.mark.parametrize("date,says", [("10.02.2026", "is not an ISO 8601 date"),
                                       ("2026-02-30", "is not an ISO 8601 date"),
                                       ("2099-01-01", "cannot have happened yet")])
def test_a_data_date_that_is_no_date_is_refused(pair, tmp_path, capsys, date, says):
    doc = json.loads((pair / "a.json").read_text())
    doc["data_date"] = date
    doc.pop("content_sha256", None)
    (tmp_path / "d.json").write_text(json.dumps(doc))
    assert main(["compare", str(tmp_path / "d.json"), str(pair / "b.json")]) == 1
    err = capsys.readouterr().err
    assert "d.json: data_date" in err and says in err, err


# -- a drift that is a rigid rotation of the triad (judgement/compare/rotation.py) -----------------------------

def test_the_rotation_of_a_hand_made_drift_is_recovered():
    """d = A w exactly (w = (2, -3, 5) arcsec, unit covariance): w back, nothing left, supported."""
    from triadcal.judgement.compare.rotation import ROTATION_ROWS, rigid_rotation, rotation_note

    names = list(ROTATION_ROWS)
    w = np.array([2.0, -3.0, 5.0])
    d = np.array([ROTATION_ROWS[n] for n in names], float) @ w
    rot = rigid_rotation(d, np.eye(6) * 0.01, names)
    np.testing.assert_allclose(rot["w_arcsec"], w, atol=1e-12)
    assert rot["chi2_rest"] < 1e-20 and rot["p_rotation"] < 1e-10
    assert "rigid rotation" in rotation_note(rot, 0.95, bench_in_u=False)
    # one angle alone (Ca_xy +5 arcsec) is no rotation
    single = np.zeros(6)
    single[names.index("Ca_xy")] = 5.0
    assert rotation_note(rigid_rotation(single, np.eye(6) * 0.01, names), 0.95, False) is None


def _fits_of(tmp_path, tag, seed, truth=None, **kw):
    text, t = simulate_campaign(np.random.default_rng(seed), setpoints_C=(20.0,), truth=truth, **kw)
    fit(parse_bench_csv(text), effects=["bench_tilt"]).save(tmp_path / f"{tag}.json")
    return t


@pytest.mark.parametrize("seed", [21, 22])
def test_a_bench_re_zeroed_between_calibrations_is_not_the_unit_failing(tmp_path, seed):
    """The independent bench's axis 1 zero moved by 15 arcsec, the unit unchanged: the drift is a turn
    about y (Ca_xz -15, Ca_zx +15); without a lab file the data cannot tell the bench from the unit,
    so not fail but inconclusive, naming the turn."""
    truth = _fits_of(tmp_path, "b", seed)
    _fits_of(tmp_path, "a", seed + 100, truth=truth, encoder_zero_arcsec=(15.0, 0.0))
    main(["compare", str(tmp_path / "b.json"), str(tmp_path / "a.json"), "--tolerance", "none", "--json",
          str(tmp_path / "c.json")])
    c = json.loads((tmp_path / "c.json").read_text())
    assert c["overall"] == "inconclusive", c["overall"]
    note = next(n for n in c["notes"] if "rigid rotation" in n)
    assert "axis 1 re-zeroed" in note and "--lab" in note
    y = float(note.split(" y ")[1].split(" +- ")[0])
    assert abs(y - 15.0) < 3.0, note


def test_a_single_angle_that_moved_still_fails(tmp_path):
    truth = _fits_of(tmp_path, "b", 31)
    moved = dict(truth, Ca_xy=truth["Ca_xy"] + 8.0)
    _fits_of(tmp_path, "a", 131, truth=moved)
    main(["compare", str(tmp_path / "b.json"), str(tmp_path / "a.json"), "--tolerance", "none", "--json",
          str(tmp_path / "c.json")])
    c = json.loads((tmp_path / "c.json").read_text())
    assert c["overall"] == "fail" and not any("rigid rotation" in n for n in c["notes"]), (c["overall"], c["notes"])


# -- a drift that is the tempcos times one temperature error (judgement/compare/thermometer.py) ---------------

def _range_fit(seed, truth=None, dT=0.0):
    from dataclasses import replace

    text, t = simulate_campaign(np.random.default_rng(seed), truth=truth, setpoints_C=(-10.0, 20.0, 50.0))
    c = parse_bench_csv(text)
    if dT:
        c = replace(c, t=c.t + dT)                     # the thermometers read dT high
    return fit(c), t


def test_a_thermometer_read_differently_is_not_the_unit_failing(tmp_path):
    """The independent bench's unit twice over -10..50 degC, unchanged; the after campaign's thermometers
    0.5 degC high: every value with a tempco moves by -c x 0.5. Fitted back: delta within 0.1 degC of
    0.5, and the fail held back as inconclusive; the same pair without the offset gets no such note."""
    rb, truth = _range_fit(41)
    ra, _ = _range_fit(141, truth=truth, dT=0.5)
    rc, _ = _range_fit(241, truth=truth)
    assert rb.status == ra.status == rc.status == "ok"
    for r, name in ((rb, "b"), (ra, "a"), (rc, "c")):
        r.save(tmp_path / f"{name}.json")
    main(["compare", str(tmp_path / "b.json"), str(tmp_path / "a.json"), "--tolerance", "none", "--json",
          str(tmp_path / "ba.json")])
    c = json.loads((tmp_path / "ba.json").read_text())
    note = next(n for n in c["notes"] if "one temperature error" in n)
    delta = float(note.split("thermometers read ")[1].split(" +- ")[0])
    assert abs(delta - 0.5) < 0.1 and c["overall"] == "inconclusive", (delta, c["overall"])
    main(["compare", str(tmp_path / "b.json"), str(tmp_path / "c.json"), "--tolerance", "none", "--json",
          str(tmp_path / "bc.json")])
    c = json.loads((tmp_path / "bc.json").read_text())
    assert not any("one temperature error" in n for n in c["notes"]), c["notes"]
