"""Consumers check what they read: `certificate` and `compare` refuse a result that is not an
answer, in one line naming the file and the field, never with a traceback; `compare` never
says pass when a side is not ok. Each case mutates a real result of the built-in example
(fitted once here by the joint fit) the way a hand-edited or corrupted file would be."""

import copy
import json
import math
import re
import sys
from pathlib import Path

import pytest

from triadcal.cli import main
from triadcal.judgement.compare import ComparisonResult, read_published_table
from triadcal.estimation.result import CalibrationResult, content_sha256


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    d = tmp_path_factory.mktemp("consumers")
    path = d / "good.json"
    assert main(["fit", "--example", "--json", str(path)]) == 0
    return json.loads(path.read_text())


def _signed(doc):
    """``doc`` with its checksum made anew (content_sha256): an edited document as a writer that signs
    what it writes would leave it, so that the consumers' own checks, not the checksum, must refuse it
    (test_an_edit_that_keeps_the_old_checksum_is_refused covers the checksum)."""
    d = copy.deepcopy(doc)
    if isinstance(d, dict) and "content_sha256" in d:
        d["content_sha256"] = content_sha256(d)
    return d


def _write(tmp_path, doc, name="r.json"):
    p = tmp_path / name
    p.write_text(json.dumps(_signed(doc)) if not isinstance(doc, str) else doc)
    return p


def _run(capsys, argv):
    code = main(argv)
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return code, out, err


def _mut(doc, fn):
    d = copy.deepcopy(doc)
    fn(d)
    return d


def _set_param(name, key, value):
    def f(d):
        d["parameters"][name][key] = value
    return f


CASES = {
    # name: (mutation, text the one-line refusal must contain)
    "angle 1e7 arcsec": (_set_param("Ca_xy", "value", 1e7), "Ca_xy"),
    "empty parameters": (lambda d: d.__setitem__("parameters", {}), "no parameters"),
    "no status": (lambda d: d.pop("status"), "status is missing"),
    "NaN reference temperature": (lambda d: d.__setitem__("reference_temperature_C", None), "reference_temperature_C"),
    "negative K": (_set_param("K_x", "value", -1.0), "K_x"),
    "value null": (_set_param("K_y", "value", None), "K_y"),
    "u null": (_set_param("S_x", "u", None), "S_x"),
    "negative u": (_set_param("S_y", "u", -1.0), "S_y"),
    "value is a string": (_set_param("K_z", "value", "1.0"), "parameters.K_z.value"),
    "value is a bool": (_set_param("K_z", "value", True), "parameters.K_z.value"),
    "unknown unit": (_set_param("K_z", "unit", "furlong"), "parameters.K_z.unit"),
    "parameter not an object": (lambda d: d["parameters"].__setitem__("K_x", 1.0), "parameters.K_x"),
    "unknown version": (lambda d: d.__setitem__("version", 99), "version 99"),
    "unknown format": (lambda d: d.__setitem__("format", "x"), "not a calibration result"),
    "unknown status": (lambda d: d.__setitem__("status", "fine"), "'fine'"),
    "correlation not square": (lambda d: d["correlation"].__setitem__("matrix", [[1.0]]), "correlation.matrix"),
    "not converged": (lambda d: d.__setitem__("status", "not_converged"), "not_converged"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_certificate_refuses_in_one_line(tmp_path, capsys, good, case):
    mutate, needle = CASES[case]
    p = _write(tmp_path, _mut(good, mutate))
    code, out, err = _run(capsys, ["certificate", str(p), "--html", str(tmp_path / "c.html")])
    assert code != 0
    assert needle in err, err
    assert "certificate" not in out or "issued" not in out
    if case != "not converged":      # a status the estimator gave gets a refusal report; the rest no file
        assert str(p) in err
        assert not (tmp_path / "c.html").exists()
        assert len([ln for ln in err.splitlines() if ln.strip()]) == 1, err
    else:
        assert "No certificate issued" in (tmp_path / "c.html").read_text()


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("side", [0, 1])
def test_compare_never_passes_a_side_that_is_not_an_answer(tmp_path, capsys, good, case, side):
    mutate, needle = CASES[case]
    files = [_write(tmp_path, good, "a.json"), _write(tmp_path, good, "b.json")]
    files[side] = _write(tmp_path, _mut(good, mutate), "bad.json")
    code, out, err = _run(capsys, ["compare", str(files[0]), str(files[1]), "--json", str(tmp_path / "c.json")])
    assert code != 0
    assert "overall: pass" not in out
    assert "bad.json" in err and needle in err, err
    assert not (tmp_path / "c.json").exists()


def test_the_unmutated_result_certifies_and_compares(tmp_path, capsys, good):
    import copy
    second = copy.deepcopy(good)                 # a second calibration (the same one twice is never a pass)
    second["parameters"]["Ca_xy"]["value"] += 0.1
    second["data_sha256"] = "0" * 64             # ... of other data (two fits of one data are never judged)
    a, b = _write(tmp_path, good, "a.json"), _write(tmp_path, second, "b.json")
    code, out, err = _run(capsys, ["compare", str(a), str(b), "--json", str(tmp_path / "c.json")])
    assert code == 0 and "overall: pass" in out
    code, out, err = _run(capsys, ["compare", str(a), str(_write(tmp_path, good, "a2.json"))])
    assert "overall: pass" not in out and "inconclusive" in out
    code, out, err = _run(capsys, ["certificate", str(a), "--html", str(tmp_path / "c.html")])
    assert code == 0 and "issued" in out


def test_not_json_and_nan_tokens_are_refused_naming_the_line(tmp_path, capsys, good):
    text = json.dumps(good, indent=1).replace('"value": ' + json.dumps(good["parameters"]["K_x"]["value"]),
                                                '"value": NaN', 1)
    p = _write(tmp_path, text)
    code, out, err = _run(capsys, ["certificate", str(p), "--html", str(tmp_path / "c.html")])
    assert code != 0 and "NaN is not JSON" in err
    p = _write(tmp_path, json.dumps(good)[:-40])
    code, out, err = _run(capsys, ["compare", str(p), str(p)])
    assert code != 0 and f"{p}:1: not valid JSON" in err
    p = tmp_path / "bin.json"
    p.write_bytes(b"\xff\xfe{")
    code, out, err = _run(capsys, ["certificate", str(p), "--html", str(tmp_path / "c.html")])
    assert code != 0 and "not UTF-8" in err
    p = _write(tmp_path, "[" * 100000 + "]" * 100000)
    code, out, err = _run(capsys, ["certificate", str(p), "--html", str(tmp_path / "c.html")])
    assert code != 0 and str(p) in err


def test_null_means_not_finite_when_read_by_the_library(good):
    d = _mut(good, _set_param("K_x", "value", None))
    r = CalibrationResult.from_dict(_signed(d), "x.json")
    assert math.isnan(r["K_x"].value)


def test_summary_states_the_failing_gates_and_no_dash(good):
    from triadcal.reports.summary import summary_text

    d = _mut(good, lambda d: d.__setitem__("status", "model_mismatch"))
    d["gates"]["outcomes"][0].update(passed=False, status="model_mismatch", reason="chi2/dof = 9 with p = 1e-9")
    text = summary_text(CalibrationResult.from_dict(_signed(d)))
    assert "FAILED gate" in text and "chi2/dof = 9 with p = 1e-9" in text
    assert "chi2/dof = -" not in text


def test_comparison_files_are_validated(tmp_path, capsys, good):
    a, b = _write(tmp_path, good, "a.json"), _write(tmp_path, good, "b.json")
    assert main(["compare", str(a), str(b), "--json", str(tmp_path / "c.json")]) == 0
    capsys.readouterr()
    comp = json.loads((tmp_path / "c.json").read_text())
    ComparisonResult.from_dict(comp)                       # the real one reads
    name = next(iter(comp["parameters"]))
    for key, value, needle in [("u", None, f"parameters.{name}.u"), ("drift", "x", f"parameters.{name}.drift"),
                               ("u", -1.0, "outside"), ("verdict", "great", "verdict")]:
        bad = copy.deepcopy(comp)
        bad["parameters"][name][key] = value
        p = _write(tmp_path, bad, "bad_comp.json")
        with pytest.raises(ValueError, match=needle):
            ComparisonResult.load(p)
        code, out, err = _run(capsys, ["certificate", str(p), "--html", str(tmp_path / "d.html")])
        assert code != 0 and "bad_comp.json" in err, err
    bad = copy.deepcopy(comp)
    bad["overall"] = "pass"
    for p_ in bad["parameters"].values():
        if p_["judged"]:
            p_["verdict"] = "fail"
    with pytest.raises(ValueError, match="contradicts"):
        ComparisonResult.from_dict(bad, "x.json")


@pytest.mark.parametrize("row, needle", [
    ("e1,s,xy,1e300,2", "outside"), ("e1,s,xy,nan,2", "not a finite number"), ("e1,s,xy,3,-1", "outside"),
    ("e1,s,xy,abc,2", "not a number"), ("e1,s,xy,3,2,9", "more fields"), ("e1,s,qq,3,2", "unknown angle"),
])
def test_published_tables_are_validated(tmp_path, row, needle):
    p = tmp_path / "pub.csv"
    p.write_text("exposure,sensor,angle,drift_arcsec,u_arcsec\n" + row + "\n")
    with pytest.raises(ValueError, match=needle) as e:
        read_published_table(p)
    assert str(p) in str(e.value) and "row 1" in str(e.value)


def test_the_printed_coverage_is_the_interval_written(good):
    """With 1 residual dof the JSON's 95 % interval is value +- t(0.975, 1) u = 12.7 u: the
    terminal says so, instead of 'U = 2u'."""
    from triadcal.reports.summary import summary_text

    d = copy.deepcopy(good)
    d["intervals"] = {n: {"level": 0.95, "low": 0.0, "high": 1.0, "dof": 1} for n in d["parameters"]}
    text = summary_text(CalibrationResult.from_dict(_signed(d)))
    assert "U (k=12.7)" in text and "Student's t with 1 residual degrees of freedom" in text
    assert "U = 2u" not in text
    assert "U (k=2)" in summary_text(CalibrationResult.from_dict(good))


@pytest.mark.parametrize("field, value, message", [
    ("method", "guess", "'guess' is not one of classical, joint, posterior"),
    ("effects", ["bench_tilt", "warp_drive"], "'warp_drive' is not an effect of the model"),
])
def test_a_result_with_an_unknown_method_or_effect_is_refused(tmp_path, field, value, message):
    """Every reader validates what it reads: a method or effect this triadcal does not know is
    refused when the file is read, naming the field (not later, when the result is applied)."""
    from triadcal.api import fit
    from triadcal.estimation.result import CalibrationResult, ResultFormatError

    d = fit(None, method="classical").to_dict()
    d[field] = value
    with pytest.raises(ResultFormatError, match=message):
        CalibrationResult.from_dict(_signed(d), "r.json")


@pytest.mark.parametrize("change, message", [
    ({"version": 2}, "diagnosis version 2 is not known"),
    ({"gap": {"chi2_dof": 1.0}}, "gap.significant is missing"),
    ({"verdict": "hysteresis"}, "verdict is missing or not an object"),
])
def test_certificate_refuses_a_diagnosis_it_cannot_read(tmp_path, change, message):
    from triadcal.api import fit
    from triadcal.reports.certificate import certificate

    r = fit(None, method="joint")
    r.save(tmp_path / "r.json")
    diag = {"format": "triadcal.diagnosis", "version": 1, "gap": {"significant": False},
            "verdict": {"effect": None}, **change}
    (tmp_path / "d.json").write_text(json.dumps(diag))
    with pytest.raises(ValueError, match=message):
        certificate(tmp_path / "r.json", diagnosis=tmp_path / "d.json", html=tmp_path / "c.html")
    assert not (tmp_path / "c.html").exists()


def test_summary_with_the_noise_estimated_prints_no_ratio_but_the_level_and_its_source(tmp_path, capsys):
    """Issue 18 item 6: without sd_* / n_samples / Q_V2s the fit's chi2/dof is the scatter in the
    weights' units (3e-9 for volts: "chi2/dof = 0.000" was printed, with an excuse). The summary now
    prints no ratio and says the noise was estimated, from what, and its level: with the weights
    1/sqrt(tau_s), chi2/dof is the white-noise intensity Q. The example campaign says Q_V2s = 3e-9;
    with the line and the noise columns removed Q comes back within the chi2's spread on ~500 dof
    (3 SD: a factor 1 +- 0.19)."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_foreign_effects import _without_noise_columns
    from triadcal.api import example_path

    text = "\n".join(line for line in _without_noise_columns(Path(example_path()).read_text()).splitlines()
                     if not line.startswith("# Q_V2s")) + "\n"
    path = tmp_path / "no_noise.csv"
    path.write_text(text, encoding="utf-8")
    assert main(["fit", str(path)]) == 0
    out = capsys.readouterr().out
    assert "chi2/dof =" not in out and "chi2/dof: none, the noise was estimated from the residuals" in out, out
    # one level per output (joint.per_output_scale), each from ~1/3 of the dof: 3 SD a factor 1 +- 0.33
    qs = [float(v) for v in re.search(r"Q = ([0-9.e+-]+), ([0-9.e+-]+), ([0-9.e+-]+) V\^2 s", out).groups()]
    assert all(abs(q / 3e-9 - 1.0) < 0.33 for q in qs), qs


EDITS = {
    # an outside probe's hand edits, each a plausible result on its own, that no field check can see
    "reference temperature 20 -> 25": lambda d: d.__setitem__("reference_temperature_C", 25.0),
    "K_x x 1000": lambda d: d["parameters"]["K_x"].__setitem__("value", d["parameters"]["K_x"]["value"] * 1000),
    "u of Ca_xy 1e-12": _set_param("Ca_xy", "u", 1e-12),
    "correlation names reversed": lambda d: d["correlation"].__setitem__("names", d["correlation"]["names"][::-1]),
}


@pytest.mark.parametrize("case", sorted(EDITS))
def test_an_edit_that_keeps_the_old_checksum_is_refused(tmp_path, capsys, good, case):
    """A saved result carries content_sha256 of its own content; compare and export-compensation refuse
    a file edited after the fit, naming the file and the key, and the certificate is a refusal report
    that says so (before: the edited reference temperature was certified and exported, K_x 69 u off at
    the stated 25 degC)."""
    assert good["content_sha256"] == content_sha256(good)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(_mut(good, EDITS[case])))           # the old checksum kept
    assert CalibrationResult.load(bad).content_mismatch
    for argv in (["compare", str(_write(tmp_path, good, "a.json")), str(bad)],
                 ["export-compensation", str(bad), "-o", str(tmp_path / "t.json")],
                 ["history", "--add", str(bad), "--db", str(tmp_path / "h.sqlite")]):
        code, out, err = _run(capsys, argv)
        assert code != 0 and "bad.json" in err and "content_sha256 does not match" in err, (argv, err)
    code, out, err = _run(capsys, ["certificate", str(bad), "--html", str(tmp_path / "c.html")])
    page = (tmp_path / "c.html").read_text()
    assert code == 3 and "issued" not in out and "content_sha256 does not match" in page, (code, out, err)
    # the same edit in a document without the key (another writer) is read as it stands, by compare
    # and the others; the certificate refuses it (an outside probe: Ca_xy + 50 arcsec, key deleted, certified)
    d = _mut(good, EDITS[case])
    d.pop("content_sha256")
    assert CalibrationResult.from_dict(d, "unsigned.json").content_mismatch is None
    unsigned = _write(tmp_path, d, "unsigned.json")
    code, out, err = _run(capsys, ["certificate", str(unsigned), "--html", str(tmp_path / "u.html")])
    assert code == 3 and "holds no content_sha256" in (tmp_path / "u.html").read_text(), (code, out, err)


def test_an_edited_value_the_gates_reject_is_named_before_the_checksum(tmp_path, capsys, good):
    """The fields' own reasons come first: a negative K_x kept with the old checksum is refused naming
    K_x, the checksum after it; a status edited to not_converged gives the refusal report (exit 3)."""
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(_mut(good, _set_param("K_x", "value", -1.0))))
    code, out, err = _run(capsys, ["compare", str(_write(tmp_path, good, "a.json")), str(bad)])
    assert code != 0 and err.index("K_x") < err.index("content_sha256 does not match"), err
    bad.write_text(json.dumps(_mut(good, lambda d: d.__setitem__("status", "not_converged"))))
    code, out, err = _run(capsys, ["certificate", str(bad), "--html", str(tmp_path / "c.html")])
    assert code == 3 and "not_converged" in (tmp_path / "c.html").read_text()
