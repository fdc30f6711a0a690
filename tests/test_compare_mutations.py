"""`triadcal compare` against an outside tester's confident wrong answers: each test builds its
inputs here (small simulated campaigns fitted once per module, the example lab file) and
fails on the code before its fix (docs/compare.md)."""

import copy
import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from triadcal.errors import InputError
from triadcal.judgement.compare import (ANGLES, ComparisonResult, compare, compare_sequence, judge_published,
                                        parse_tolerance, read_published_table)

ROOT = Path(__file__).resolve().parents[1]
LAB = ROOT / "examples" / "data" / "lab.toml"
EFFECTS = ("bench_tilt",)


def _fit(seed, ca_xy=312.0, lab=None):
    from triadcal.api import fit, simulate
    from triadcal.models.simulate import Schedule

    _, campaign = simulate(effects=EFFECTS, schedule=Schedule(setpoints_C=(20.0,), soak_s=600.0), seed=seed,
                           parameters={"Ca_xy": ca_xy})
    r = fit(campaign, effects=EFFECTS, lab=lab)
    assert r.status == "ok"
    return r


@pytest.fixture(scope="module")
def fits():
    """Before (seed 1), the same unit again (seed 2), and after a 10" shift of Ca_xy (seed 3);
    the first two also fitted with the example lab file (Type B rows: encoder zeros, fixture...)."""
    os.environ.setdefault("XDG_CACHE_HOME", "/tmp/xdg")
    return {"before": _fit(1), "again": _fit(2), "moved": _fit(3, ca_xy=322.0),
            "before_lab": _fit(1, lab=LAB), "again_lab": _fit(2, lab=LAB)}


def _cli(*args):
    from triadcal.cli import main

    return main(["compare", *map(str, args)])


# -- 1. a per-parameter tolerance applies to an angle too ------------------------------------------
def test_param_tolerance_of_an_angle_is_applied_and_said(fits, tmp_path, capsys):
    c = compare(fits["before"], fits["moved"], tolerance_arcsec=30.0, tolerances={"Ca_xy": 1.0})
    p = c["Ca_xy"]
    assert p.drift == pytest.approx(10.0, abs=3.0) and abs(p.z) > 5
    assert p.tolerance == 1.0 and p.verdict == "fail" and c.overall == "fail"
    assert c["Ca_xz"].tolerance == 30.0                      # the other angles keep the angles' T
    assert any("Ca_xy (T = 1 arcsec)" in n for n in c.notes)
    assert "judged against it, not against the angles' T" in c.rule
    # through the CLI, with --exit-code
    fits["before"].save(tmp_path / "b.json")
    fits["moved"].save(tmp_path / "a.json")
    assert _cli(tmp_path / "b.json", tmp_path / "a.json", "--param-tolerance", "Ca_xy=1", "--exit-code",
                "--json", tmp_path / "c.json") == 4
    d = json.loads((tmp_path / "c.json").read_text())
    assert d["parameters"]["Ca_xy"]["tolerance"] == 1.0 and d["overall"] == "fail"


def test_a_tolerance_on_a_bench_parameter_says_it_is_the_benchs(fits):
    """An outside probe's ``--param-tolerance tilt_x=5`` was refused as "not in both results", though
    both results hold tilt_x: it is the bench's, reported in bench_check without a verdict."""
    from triadcal.errors import InputError

    assert "tilt_x" in fits["before"].parameters and "tilt_x" in fits["moved"].parameters
    with pytest.raises(InputError, match=r"tolerances given for \['tilt_x'\]: parameters of the bench"):
        compare(fits["before"], fits["moved"], tolerance_arcsec=30.0, tolerances={"tilt_x": 5.0})


# -- 2. a posterior is checked against its result ---------------------------------------------------
def _posterior(result, path, *, serial=None, created_by="triadcal sample", drop=(), add=(), shift=None, attrs=None):
    """A netCDF posterior of ``result``: N(value, u) draws of every parameter (4 x 500)."""
    import arviz as az

    rng = np.random.default_rng(0)
    post = {}
    for n, p in result.parameters.items():
        if n in drop:
            continue
        m = p.value + (shift or {}).get(n, 0.0)
        post[n] = m + p.u * rng.standard_normal((4, 500))
    for n in add:
        post[n] = rng.standard_normal((4, 500))
    idata = az.from_dict(posterior=post)
    for n in post:
        if n in result.parameters:
            idata.posterior[n].attrs["units"] = result[n].unit
    idata.posterior.attrs.update({"unit": serial or result.unit, "created_by": created_by, **(attrs or {})})
    idata.to_netcdf(str(path))
    return path


def test_posterior_of_the_other_calibration_is_refused_naming_it(fits, tmp_path):
    b, a = fits["before"], fits["moved"]
    pb, pa = _posterior(b, tmp_path / "pb.nc"), _posterior(a, tmp_path / "pa.nc")
    ok = compare(b, a, posterior_before=pb, posterior_after=pa)     # the right ones: judged on the draws
    assert ok["Ca_xy"].basis == "posterior"
    for before_post, after_post in ((pa, pa), (pa, pb), (pb, pb)):  # swapped or repeated
        with pytest.raises(InputError, match=r"\.nc.*means disagree.*Ca_xy"):
            compare(b, a, posterior_before=before_post, posterior_after=after_post)
    # through the CLI: refused (exit 1), the file named
    b.save(tmp_path / "b.json")
    a.save(tmp_path / "a.json")
    assert _cli(tmp_path / "b.json", tmp_path / "a.json", "--posterior-before", pa, "--posterior-after", pa,
                "--exit-code") == 1


def test_posterior_of_another_unit_or_model_is_refused(fits, tmp_path):
    b, a = fits["before"], fits["again"]
    pa = _posterior(a, tmp_path / "pa.nc")
    other = _posterior(b, tmp_path / "serial.nc", serial="SN-OTHER-9")
    with pytest.raises(InputError, match=r"serial\.nc.*unit 'SN-OTHER-9'"):
        compare(b, a, posterior_before=other, posterior_after=pa)
    lacking = _posterior(b, tmp_path / "lacking.nc", drop=("K_x",))
    with pytest.raises(InputError, match=r"lacking\.nc.*parameter set.*lacks K_x"):
        compare(b, a, posterior_before=lacking, posterior_after=pa)
    extra = _posterior(b, tmp_path / "extra.nc", add=("Ca_xy_hysteresis",), created_by="another program")
    with pytest.raises(InputError, match=r"extra\.nc.*holds Ca_xy_hysteresis"):
        compare(b, a, posterior_before=extra, posterior_after=pa)


def test_posterior_fingerprint_is_the_certificates_check(fits, tmp_path):
    """A posterior result carries its sampler's worst R-hat; the file's stored verdict must match
    it (the check of triadcal.reports.certificate.refusal, reused)."""
    b = copy.deepcopy(fits["before"])
    b.method = "posterior"
    b.extra["sampler"] = {"rhat_max": 1.002}
    a = copy.deepcopy(fits["again"])
    a.method = "posterior"
    a.extra["sampler"] = {"rhat_max": 1.003}
    verdict = {"converged": 1, "rhat_worst": "Ca_xy", "ess_bulk_min": 2000.0, "ess_tail_min": 2000.0}
    pb = _posterior(b, tmp_path / "pb.nc", attrs={**verdict, "rhat_max": 1.002})
    pa = _posterior(a, tmp_path / "pa.nc", attrs={**verdict, "rhat_max": 1.003})
    compare(b, a, posterior_before=pb, posterior_after=pa)
    wrong = _posterior(b, tmp_path / "wrong.nc", attrs={**verdict, "rhat_max": 1.007})
    with pytest.raises(InputError, match=r"wrong\.nc.*not the one written with this result"):
        compare(b, a, posterior_before=wrong, posterior_after=pa)


# -- 3. a calibration compared with itself is not a pass --------------------------------------------
def test_same_calibration_is_never_a_pass_and_names_both_files(fits, tmp_path, capsys):
    fits["before"].save(tmp_path / "before.json")
    shutil.copy(tmp_path / "before.json", tmp_path / "copy.json")
    for other in ("before.json", "copy.json"):
        code = _cli(tmp_path / "before.json", tmp_path / other, "--exit-code", "--json", tmp_path / "c.json")
        err = capsys.readouterr().err
        assert code == 5, err
        assert "same calibration" in err and str(tmp_path / "before.json") in err and str(tmp_path / other) in err
        c = ComparisonResult.load(tmp_path / "c.json")          # loads: a held-back pass is allowed
        assert c.overall == "inconclusive"
    c = compare(fits["before"], copy.deepcopy(fits["before"]))
    assert c.overall != "pass" and "same calibration" in c.notes[0]
    assert compare(fits["before"], fits["again"]).overall == "pass"   # two calibrations: a pass


# -- 3b. two fits of one data set are not two calibrations ------------------------------------------
def test_two_fits_of_the_same_data_are_never_judged(fits, tmp_path, capsys):
    """The joint and the classical fit of one campaign (or one fit with and without the lab file)
    differ by their estimators, not by a drift: compare said "pass" (a probe of the twelfth
    session). The data's SHA-256 (of the visits, not of the file) names the pair."""
    from triadcal.api import simulate
    from triadcal.estimation.classical import fit_classical
    from triadcal.io.bench_csv import read_bench_csv, write_bench_csv
    from triadcal.models.simulate import Schedule

    _, campaign = simulate(effects=EFFECTS, schedule=Schedule(setpoints_C=(20.0,), soak_s=600.0), seed=1)
    classical = fit_classical(campaign)
    assert classical.status == "ok"
    assert classical.extra["data_sha256"] == fits["before"].extra["data_sha256"]
    assert fits["again"].extra["data_sha256"] != fits["before"].extra["data_sha256"]
    for other in (classical, fits["before_lab"]):
        c = compare(fits["before"], other)
        assert c.overall == "inconclusive" and "two fits of the same data" in c.notes[0], c.notes
    # the hash is of the visits: the campaign written to a file and read back keeps it
    write_bench_csv(campaign, tmp_path / "c.csv")
    assert read_bench_csv(tmp_path / "c.csv").data_sha256 == campaign.data_sha256
    # through the CLI: exit 5 (inconclusive), and the saved comparison loads; a stored pass or fail
    # of such a pair is refused by the reader
    fits["before"].save(tmp_path / "joint.json")
    classical.save(tmp_path / "classical.json")
    code = _cli(tmp_path / "joint.json", tmp_path / "classical.json", "--exit-code", "--json", tmp_path / "c.json")
    err = capsys.readouterr().err
    assert code == 5 and "two fits of the same data" in err, err
    d = json.loads((tmp_path / "c.json").read_text())
    assert ComparisonResult.from_dict(d, "c.json").overall == "inconclusive"
    for forged in ("pass", "fail"):
        with pytest.raises(InputError, match="two fits of the same data"):
            ComparisonResult.from_dict({**d, "overall": forged}, "c.json")
    # a result with a malformed hash is refused by name
    bad = json.loads((tmp_path / "joint.json").read_text())
    bad["data_sha256"] = "xyz"
    from triadcal.estimation.result import CalibrationResult
    with pytest.raises(InputError, match="data_sha256"):
        CalibrationResult.from_dict(bad, "joint.json")
    # two calibrations (two data sets) are still judged
    assert compare(fits["before"], fits["again"]).overall == "pass"


# -- 4. an angle missing from one side ---------------------------------------------------------------
def test_missing_angle_keeps_the_overall_from_pass(fits):
    after = copy.deepcopy(fits["again"])
    del after.parameters["Ca_xy"]
    try:
        c = compare(fits["before"], after)
    except InputError as exc:                  # a refusal (e.g. by the result checks) is safe too
        assert "Ca_xy" in str(exc)
        return
    assert c.overall == "inconclusive"
    assert any(n.startswith("overall verdict not pass") and "Ca_xy missing from after" in n for n in c.notes)


# -- 5. the stored verdicts of a comparison are checked against its numbers ----------------------------
def test_comparison_verdict_contradicting_its_numbers_is_refused(fits, tmp_path):
    c = compare(fits["before"], fits["moved"], tolerance_arcsec=5.0)
    good = c.to_dict()
    assert good["parameters"]["Ca_xy"]["verdict"] == "fail" and good["overall"] == "fail"
    ComparisonResult.from_dict(good)
    bad = copy.deepcopy(good)
    bad["parameters"]["Ca_xy"]["verdict"] = "pass"
    bad["overall"] = "pass"
    with pytest.raises(InputError, match=r"parameters\.Ca_xy\.verdict 'pass' contradicts its numbers.*'fail'"):
        ComparisonResult.from_dict(bad, "bad.json")
    sig = copy.deepcopy(good)
    sig["parameters"]["Ca_xy"]["significant"] = False
    with pytest.raises(InputError, match=r"Ca_xy\.significant"):
        ComparisonResult.from_dict(sig)
    tol = copy.deepcopy(good)                  # a verdict made pass by a raised T: T is in the numbers
    tol["parameters"]["Ca_xy"]["tolerance"] = 100.0
    with pytest.raises(InputError, match=r"Ca_xy\.(verdict|p_exceeds)"):
        ComparisonResult.from_dict(tol)
    # the drift report (triadcal certificate COMPARISON.json) refuses it too, naming the file
    from triadcal.cli import main

    (tmp_path / "bad.json").write_text(json.dumps(bad))
    assert main(["certificate", str(tmp_path / "bad.json"), "--html", str(tmp_path / "d.html")]) == 1
    assert not (tmp_path / "d.html").exists()


# -- 6. infinite, NaN and negative tolerances ----------------------------------------------------------
def test_non_finite_or_negative_tolerances_are_refused(fits, tmp_path, capsys):
    for text in ("1e400arcsec", "1e400deg", "-1arcsec"):
        with pytest.raises(InputError):
            parse_tolerance(text)
    assert parse_tolerance("none") is None and parse_tolerance("0.5arcmin") == 30.0
    for value in (math.inf, math.nan, -1.0):
        with pytest.raises(InputError, match="K_x"):
            compare(fits["before"], fits["moved"], tolerances={"K_x": value})
    with pytest.raises(InputError):
        compare(fits["before"], fits["moved"], tolerance_arcsec=math.inf)
    fits["before"].save(tmp_path / "b.json")
    fits["moved"].save(tmp_path / "a.json")
    # K_x=1_0 was read by float() as 10 g/V (every K drift passed); 1e-400 underflowed to a tolerance of 0
    for args in (("--tolerance", "1e400arcsec"), ("--param-tolerance", "K_x=inf"),
                 ("--param-tolerance", "K_x=nan"), ("--param-tolerance", "K_x=-1"),
                 ("--param-tolerance", "K_x=1_0"), ("--param-tolerance", "Ca_xy=1e-400")):
        assert _cli(tmp_path / "b.json", tmp_path / "a.json", *args) == 1
        err = capsys.readouterr().err
        assert args[0] in err and args[1] in err


# -- 7. docs and behaviour agree: shareable equipment, the overall rule, the published table ------------
def test_chamber_is_not_shareable_in_the_api_as_in_the_lab_file_and_the_docs(fits):
    with pytest.raises(InputError, match="thermometers"):
        compare(fits["before_lab"], fits["again_lab"], shared_equipment=("chamber",))
    docs = (ROOT / "docs" / "compare.md").read_text(encoding="utf-8")
    names = docs.split("the names are lab-file sections", 1)[1].split(")", 1)[0]
    assert "`bench`" in names and "`thermometers`" in names and "`chamber`" not in names


def test_a_parameter_failing_its_tolerance_fails_the_overall_alone_as_documented(fits):
    after = copy.deepcopy(fits["again"])
    after.parameters["K_x"].value += 20 * after["K_x"].u          # K_x moved; the angles did not
    c = compare(fits["before"], after, tolerance_arcsec=30.0, tolerances={"K_x": 5 * after["K_x"].u})
    assert c["K_x"].verdict == "fail" and not c.joint.significant
    assert not [n for n in ANGLES if c[n].verdict == "fail"]
    assert c.overall == "fail"
    docs = " ".join((ROOT / "docs" / "compare.md").read_text(encoding="utf-8").split())
    assert "a parameter given `--param-tolerance` that fails makes the overall verdict fail on its own" in docs


def test_published_table_refuses_two_uncertainties_and_string_numbers(tmp_path):
    csv = tmp_path / "t.csv"
    csv.write_text("exposure,sensor,angle,drift_arcsec,u_arcsec,u_drift_arcsec\ns1,accel,xy,10,12,5\n")
    with pytest.raises(InputError, match="both u_arcsec.*u_drift_arcsec"):
        read_published_table(csv)
    js = tmp_path / "t.json"
    js.write_text(json.dumps({"drifts": [{"exposure": "s1", "angle": "xy", "drift_arcsec": "50", "u_arcsec": 12}]}))
    with pytest.raises(InputError, match="drift_arcsec.*not a JSON number"):
        read_published_table(js)
    js.write_text(json.dumps({"drifts": [{"exposure": "s1", "angle": "xy", "drift_arcsec": 50, "u_arcsec": 12}]}))
    seq = judge_published(read_published_table(js))
    assert seq.steps[0]["Ca_xy"].verdict == "fail"


# -- 8. the bench check with shared equipment ------------------------------------------------------------
def test_bench_check_subtracts_the_shared_encoder_zero(fits):
    b, a = fits["before_lab"], fits["again_lab"]
    ua_b, ua_a = b["tilt_y"].uncertainty["u_type_a"], a["tilt_y"].uncertainty["u_type_a"]
    assert b["tilt_y"].u > 1.3 * ua_b                     # the encoder zero is in its u
    ind = compare(b, a)
    sh = compare(b, a, shared_equipment=("bench", "gravity"))
    assert ind.bench_check["tilt_y"]["u"] == pytest.approx(math.hypot(b["tilt_y"].u, a["tilt_y"].u))
    # shared: the encoder zero of axis 2 (sensitivity 1 both times) cancels, the Type A parts remain
    assert sh.bench_check["tilt_y"]["u"] == pytest.approx(math.hypot(ua_b, ua_a), rel=0.02)
    assert sh.bench_check["tilt_y"]["u"] < 0.8 * ind.bench_check["tilt_y"]["u"]


def test_sequence_names_its_states(fits):
    seq = compare_sequence([fits["before"], fits["before"]], ["s0", "s1"])
    assert seq.steps[0].overall == "inconclusive" and "s0 and s1 are the same calibration" in seq.steps[0].notes[0]
    assert all(a in seq.steps[0].parameters for a in ANGLES)


# -- an edited u of 0, and what the reason says of a remount ------------------------------------------
def test_a_u_of_zero_is_refused_and_the_reason_names_a_remount(fits, tmp_path, capsys):
    """An outside probe edited one angle's u to 0 in a result: compare took it and said pass (the
    drift judged against nothing). No estimate from measured data has u = 0: refused, naming the
    parameter. And without lab files the correlation's reason said the bench's systematic errors
    cancel in the drift, while a remounted unit (fixture seating N(0, 10")) failed 10 of 10: it now
    names the seating as in the drift and in no u."""
    c = compare(fits["before"], fits["again"])
    assert "seating of the unit in its fixture" in c.correlation["reason"] and "--lab" in c.correlation["reason"]
    edited = copy.deepcopy(fits["again"])
    edited.parameters["Ca_xy"] = edited.parameters["Ca_xy"].__class__(edited["Ca_xy"].value, 0.0, "arcsec")
    with pytest.raises(InputError, match=r"Ca_xy: u = 0"):
        compare(fits["before"], edited)
    fits["before"].save(tmp_path / "b.json")
    edited.save(tmp_path / "a.json")
    assert _cli(tmp_path / "b.json", tmp_path / "a.json") != 0
    assert "Ca_xy: u = 0" in capsys.readouterr().err
    # a u below the value's floating-point resolution is no estimate either (an outside probe: 1e-30
    # arcsec, the hash recomputed, was compared and tabulated as u = 0)
    edited.parameters["Ca_xy"] = edited.parameters["Ca_xy"].__class__(edited["Ca_xy"].value, 1e-30, "arcsec")
    with pytest.raises(InputError, match=r"Ca_xy: u = 0 or below the value's floating-point resolution"):
        compare(fits["before"], edited)


def test_two_results_of_one_source_without_hashes_are_noted(fits):
    """data_sha256 removed from both: the pair cannot be known as one data set; same source names
    get a note (the verdict stays the rule's: the source is a name, not the data)."""
    a, b = copy.deepcopy(fits["before"]), copy.deepcopy(fits["again"])
    for r in (a, b):
        r.extra.pop("data_sha256", None)
        r.extra["source"] = "campaign.csv"
    c = compare(a, b)
    assert any("name the same source (campaign.csv) and do not both carry data_sha256" in n for n in c.notes)
    b.extra["source"] = "other.csv"
    assert not any("name the same source" in n for n in compare(a, b).notes)


def test_a_result_without_its_checksum_and_another_local_g_are_said(fits, tmp_path):
    """An outside probe: with content_sha256 deleted, a Ca_xy edited by +20 arcsec was compared without a
    word; a unit calibrated at 9.80665 and at 9.78 m/s^2 had a K drift of 0 (z 0.5), yet the note said the
    K drift "contains" the difference of the local g's (each fit scales K to its own stated g)."""
    from triadcal.estimation.result import CalibrationResult

    d = fits["moved"].to_dict()
    d.pop("content_sha256", None)
    d["parameters"]["Ca_xy"]["value"] += 20.0
    edited = CalibrationResult.from_dict(d)
    c = compare(fits["before"], edited, files=("b.json", "a.json"))
    assert any(n.startswith("a.json holds no content_sha256") for n in c.notes), c.notes
    other_g = copy.deepcopy(fits["again"])
    other_g.extra["local_g_m_s2"] = 9.78
    c = compare(fits["before"], other_g)
    note = next(n for n in c.notes if n.startswith("local gravity differs"))
    assert "each fit scaled K to its own stated g" in note and "contains" not in note


def test_a_number_that_underflows_is_refused_and_zero_is_not():
    from triadcal.io.numbers import NumberError, parse_number

    for text in ("1e-400", "-2.5E-330", "0.0001e-320"):
        with pytest.raises(NumberError, match="underflows to 0"):
            parse_number(text)
    for text in ("0", "0.000", "-0e5", "0E-400"):
        assert parse_number(text) == 0.0
    assert parse_number("5e-324") == 5e-324          # the smallest subnormal is a number
