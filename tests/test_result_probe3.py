"""The readers and consumers of a result against an outside tester's mutated files (thirteenth
session): each case was read, compared or certified before; each test fails on the code before
its fix. Inputs are made here: the example campaign fitted once, then its JSON mutated."""

import copy
import json

import pytest

from triadcal.cli import main
from triadcal.errors import InputError
from triadcal.estimation.result import CalibrationResult
from triadcal.estimation.result_checks import result_problems
from triadcal.judgement.compare import compare


@pytest.fixture(scope="module")
def good(example):
    from triadcal.estimation.joint import fit_joint

    r = fit_joint(example)
    assert r.status == "ok"
    return r.to_dict()


def _load(d):
    return CalibrationResult.from_dict(json.loads(json.dumps(d)), "r.json")


def test_a_result_without_its_reference_temperature_is_refused(good):
    """It was read as 20 degC: a result fitted at 55 degC was compared as one at 20 (angle drifts
    of 14-29" from the tempcos alone) and certified with K_x of 55 degC printed as at 20."""
    d = copy.deepcopy(good)
    del d["reference_temperature_C"]
    with pytest.raises(InputError, match="reference_temperature_C.*missing"):
        _load(d)


@pytest.mark.parametrize("key", ["effects", "temperature_range_C", "intervals", "fit", "notes"])
def test_a_result_missing_a_key_every_fit_writes_is_refused(good, key):
    d = copy.deepcopy(good)
    del d[key]
    with pytest.raises(InputError, match=f"{key}.*missing"):
        _load(d)


def test_status_ok_needs_its_gates_and_no_failed_one(good):
    d = copy.deepcopy(good)
    del d["gates"]
    with pytest.raises(InputError, match="gates.*missing"):
        _load(d)
    assert _load({**d, "status": "model_mismatch"}).status == "model_mismatch"   # not ok: readable
    d = copy.deepcopy(good)
    gof = next(o for o in d["gates"]["outcomes"] if o["gate"] == "goodness_of_fit")
    gof["passed"] = False
    with pytest.raises(InputError, match="status.*goodness_of_fit.*failed"):
        _load(d)


def test_a_chi2_its_own_thresholds_reject_is_not_ok(good):
    d = copy.deepcopy(good)
    d["fit"]["chi2_dof"] = 1e6
    r = _load(d)                      # the file is well formed ...
    why = result_problems(r)          # ... but a consumer does not use it
    assert any("chi2_dof = 1e+06" in w for w in why), why
    assert not result_problems(_load(good))


def test_an_uncertainty_whose_square_overflows_is_refused(good, tmp_path):
    """u = 1e300: compare crashed (OverflowError, exit 70) and the certificate printed K_x as
    "0 +- 2000..." with 301 digits."""
    d = copy.deepcopy(good)
    d["parameters"]["K_x"]["u"] = 1e300
    with pytest.raises(InputError, match=r"parameters\.K_x\.u.*beyond"):
        _load(d)
    (tmp_path / "a.json").write_text(json.dumps(good))
    (tmp_path / "b.json").write_text(json.dumps(d))
    assert main(["compare", str(tmp_path / "a.json"), str(tmp_path / "b.json")]) not in (0, 70)
    assert main(["certificate", str(tmp_path / "b.json"), "--html", str(tmp_path / "c.html")]) not in (0, 70)
    assert not (tmp_path / "c.html").exists() or "issued" not in (tmp_path / "c.html").read_text()


def test_angles_in_different_frames_are_not_compared(good):
    """fit-raw with known poses and with --poses unknown (Ca_yx = Ca_zx = Ca_zy = 0 by its frame's
    definition) of one recording: compare gave a drift of +513/-654/+426" and "fail"."""
    before = _load(good)
    after = copy.deepcopy(good)
    for n in ("Ca_yx", "Ca_zx", "Ca_zy"):
        unit = after["parameters"].pop(n)["unit"]
        after.setdefault("fixed", {})[n] = {"value": 0.0, "unit": unit}
    after["data_sha256"] = "1" * 64
    with pytest.raises(InputError, match="different frames"):
        compare(before, _load(after))
    # an angle the data could not determine is a missing angle (inconclusive), not a frame
    und = copy.deepcopy(good)
    und["data_sha256"] = "2" * 64
    und["fixed"] = {**(und.get("fixed") or {}), "Ca_yx": {"value": 0.0, "unit": und["parameters"].pop("Ca_yx")["unit"]}}
    und["unidentifiable"] = {**(und.get("unidentifiable") or {}), "Ca_yx": "not determined by the design"}
    try:
        c = compare(before, _load(und))
    except InputError as exc:
        assert "different frames" not in str(exc)
    else:
        assert c.overall != "pass"


def test_data_without_local_gravity_are_fitted_but_not_certified(tmp_path):
    """An outside tester's campaign made with g = 9.8100 m/s^2 and no local_g_m_s2 line: fitted at
    standard gravity with K_y 260 u off and status ok, nothing said, and certified. Now the result
    says the gravity was assumed (local_g_stated false, a note), and the certificate refuses it
    unless the data or the lab file state the local gravity."""
    from triadcal.api import example_path

    text = example_path().read_text()
    assert "# local_g_m_s2 = 9.80665\n" in text
    (tmp_path / "nog.csv").write_text(text.replace("# local_g_m_s2 = 9.80665\n", ""))
    assert main(["fit", str(tmp_path / "nog.csv"), "--json", str(tmp_path / "nog.json")]) == 0
    r = CalibrationResult.load(tmp_path / "nog.json")
    assert r.status == "ok" and r.extra["local_g_stated"] is False
    assert any("state no local gravity" in n for n in r.notes)
    code = main(["certificate", str(tmp_path / "nog.json"), "--html", str(tmp_path / "c.html")])
    assert code == 3 and "state no local gravity" in (tmp_path / "c.html").read_text()
    # the same data with their gravity stated are certified
    (tmp_path / "g.csv").write_text(text)
    assert main(["fit", str(tmp_path / "g.csv"), "--json", str(tmp_path / "g.json")]) == 0
    assert CalibrationResult.load(tmp_path / "g.json").extra["local_g_stated"] is True
    assert main(["certificate", str(tmp_path / "g.json"), "--html", str(tmp_path / "g.html")]) == 0
    # a capture writes the local gravity only when the operator states it (it wrote 9.80665 as if measured)
    from triadcal.hardware.capture import CaptureSettings
    assert CaptureSettings().local_g_m_s2 is None


def test_a_certificate_with_data_that_are_not_the_results_is_refused(tmp_path):
    """certificate --data with another campaign of the same unit was accepted: its plots and
    conditions would be of data the result was not fitted to."""
    from triadcal.api import example_path

    text = example_path().read_text()
    (tmp_path / "a.csv").write_text(text)
    assert main(["fit", str(tmp_path / "a.csv"), "--json", str(tmp_path / "a.json")]) == 0
    lines = text.splitlines(keepends=True)
    i = next(k for k, ln in enumerate(lines) if ln.startswith("unit,")) + 1
    cols = lines[i].split(",")
    cols[8] = repr(float(cols[8]) + 1e-7)            # w_x of the first visit: other data
    lines[i] = ",".join(cols)
    (tmp_path / "b.csv").write_text("".join(lines))
    code = main(["certificate", str(tmp_path / "a.json"), "--data", str(tmp_path / "b.csv"),
                 "--html", str(tmp_path / "c.html")])
    assert code == 3 and "not those the result was fitted to" in (tmp_path / "c.html").read_text()
    assert main(["certificate", str(tmp_path / "a.json"), "--data", str(tmp_path / "a.csv"),
                 "--html", str(tmp_path / "d.html")]) == 0
