"""The results JSON contract (docs/results-json.md) against what the commands write.

The JSON Schemas embedded in docs/results-json.md (one per ``format``, after a marker line
``<!-- schema:FORMAT -->``) are extracted and every file the command line writes is validated
against the schema of its ``format``: ``fit`` (classical, joint), ``sample``, ``fit-raw``
(least squares, posterior, and a result whose status is not ok), ``compare`` (two results and a
sequence), ``diagnose``, ``simulate --truth``, ``budget``, ``validate``, ``validate-diagnosis``
and ``capture`` against the emulator. Mutated documents must fail, so the check can fail; and
the enumerations of the schemas must be those of the code (statuses, methods, units, effects).
"""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import numpy as np
import pytest

import jsonschema          # the test extra (pyproject.toml): a missing package is an error, not a skip
from referencing import Registry, Resource

from triadcal.api import example_path
from triadcal.cli import main

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "results-json.md"
MIKOFF = Path(__file__).parent / "data" / "real" / "mikoff_imu0.log"
_SCHEMA_BLOCK = re.compile(r"^<!-- schema:([a-z_.]+) -->\s*\n```json\n(.*?)\n```", re.S | re.M)


# -- the schemas of the doc ------------------------------------------------------------------
def doc_schemas() -> dict:
    text = DOC.read_text(encoding="utf-8")
    found = _SCHEMA_BLOCK.findall(text)
    schemas = {}
    for fmt, body in found:
        assert fmt not in schemas, f"two schemas for {fmt} in {DOC.name}"
        schemas[fmt] = json.loads(body)
    markers = re.findall(r"^<!-- schema:", text, re.M)
    assert len(markers) == len(found), "a schema marker not followed by a ```json block"
    return schemas


SCHEMAS = doc_schemas()


def _registry():
    return Registry().with_resources([(s["$id"], Resource.from_contents(s)) for s in SCHEMAS.values()])


REGISTRY = _registry()


def validator(fmt: str):
    cls = jsonschema.Draft202012Validator
    return cls(SCHEMAS[fmt], registry=REGISTRY)


def errors(doc) -> list:
    """Schema errors of ``doc`` against the schema of its own ``format`` (one line each)."""
    fmt = doc.get("format") if isinstance(doc, dict) else None
    if fmt not in SCHEMAS:
        return [f"no schema for format {fmt!r} in {DOC.name}"]
    return [f"{'/'.join(map(str, e.absolute_path)) or '<root>'}: {e.message[:200]}"
            for e in validator(fmt).iter_errors(doc)]


def assert_valid(doc, fmt: str):
    assert doc.get("format") == fmt
    errs = errors(doc)
    assert not errs, f"{fmt} written by the code does not follow {DOC.name}:\n" + "\n".join(errs[:20])


def _no_constant(name):
    raise ValueError(f"{name} is not JSON")


def load(path) -> dict:
    """Strict JSON: NaN and Infinity tokens are refused as the contract says."""
    return json.loads(Path(path).read_text(encoding="utf-8"), parse_constant=_no_constant)


def run(argv, expect=(0,)):
    code = main([str(a) for a in argv])
    assert code in expect, f"triadcal {' '.join(map(str, argv))} exited {code}"
    return code


# -- the schemas themselves ------------------------------------------------------------------
def test_every_schema_is_a_valid_draft_2020_12_schema():
    assert {"triadcal.result", "triadcal.comparison", "triadcal.diagnosis"} <= set(SCHEMAS)
    for fmt, s in SCHEMAS.items():
        jsonschema.Draft202012Validator.check_schema(s)
        assert s["$schema"] == "https://json-schema.org/draft/2020-12/schema", fmt
        assert s["properties"]["format"] == {"const": fmt}, fmt
        assert s["properties"]["version"] == {"const": 1}, fmt
        assert {"format", "version"} <= set(s["required"]), fmt


def test_every_format_the_code_writes_has_a_schema():
    written = set()
    for path in (ROOT / "triadcal").rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        written |= set(re.findall(r"[\"']format[\"']\s*:\s*[\"'](triadcal\.[a-z_]+)[\"']", text))
        written |= set(re.findall(r"^[A-Z_]*FORMAT\s*=\s*[\"'](triadcal\.[a-z_]+)[\"']", text, re.M))
    assert {"triadcal.result", "triadcal.comparison", "triadcal.diagnosis"} <= written
    assert written <= set(SCHEMAS), f"formats written without a schema in {DOC.name}: {written - set(SCHEMAS)}"


def test_the_enumerations_of_the_schemas_are_those_of_the_code():
    from triadcal.judgement.compare import VERDICTS
    from triadcal.judgement.diagnose import FAMILIES
    from triadcal.estimation.gates import STATUSES, DEFAULT_CONFIG
    from triadcal.estimation.result import METHODS
    from triadcal.models.effects import EFFECTS, VOCABULARY
    from triadcal.models.units import TO_INTERNAL

    d = SCHEMAS["triadcal.result"]["$defs"]
    assert d["status"]["enum"] == list(STATUSES)
    assert SCHEMAS["triadcal.result"]["properties"]["method"]["enum"] == list(METHODS)
    assert sorted(d["unit"]["anyOf"][0]["enum"]) == sorted(TO_INTERNAL)
    assert sorted(d["model_effect"]["enum"]) == sorted(EFFECTS)
    assert sorted(d["gates"]["properties"]["config"]["required"]) == sorted(DEFAULT_CONFIG.to_dict())
    dd = SCHEMAS["triadcal.diagnosis"]["$defs"]
    from triadcal.judgement.raw_diagnosis import CANDIDATES as RAW_CANDIDATES
    from triadcal.judgement.diagnose import FORM_CANDIDATES
    assert sorted(dd["effect"]["enum"]) == sorted(set(VOCABULARY) | set(RAW_CANDIDATES) | set(FORM_CANDIDATES))
    assert sorted(dd["slice"]["properties"]["family"]["enum"]) == sorted(set(FAMILIES) | {"axis"})
    assert SCHEMAS["triadcal.comparison"]["$defs"]["verdict"]["enum"] == list(VERDICTS)
    # the statuses the doc lists in prose are the schema's
    text = DOC.read_text(encoding="utf-8")
    for s in STATUSES:
        assert f"`{s}`" in text, s


# -- results written by the command line -----------------------------------------------------
@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("contract")


@pytest.fixture(scope="module")
def classical(work):
    run(["fit", "--example", "--method", "classical", "--json", work / "classical.json"])
    return work / "classical.json"


@pytest.fixture(scope="module")
def joint(work):
    run(["fit", "--example", "--method", "joint", "--json", work / "joint.json"])
    return work / "joint.json"


@pytest.fixture(scope="module")
def raw_csv(work):
    """The mikoff imu0 recording (MPU-9150) in its counts, as fit-raw reads it (tests/test_raw_gates.py)."""
    a = np.loadtxt(MIKOFF)[:, :3]
    path = work / "mikoff.csv"
    np.savetxt(path, np.round(a * 2048 / 9.81), delimiter=",", header="ax,ay,az", comments="", fmt="%d")
    return path


def _check_result(doc):
    assert_valid(doc, "triadcal.result")
    failed = [o for o in doc["gates"]["outcomes"] if o["passed"] is False]
    # status ok exactly when no gate failed (docs/statuses.md); otherwise a failing gate's status
    assert (doc["status"] == "ok") == (not failed), (doc["status"], failed)
    if failed:
        assert doc["status"] in {o["status"] for o in failed} | {"not_converged"}
    # K in g per output unit (the plural of a count is written singular: g/count)
    for name in ("K_x", "K_y", "K_z"):
        unit = doc["parameters"][name]["unit"]
        assert unit in (f"g/{doc['output_unit']}", f"g/{doc['output_unit'].rstrip('s')}"), (name, unit)


@pytest.mark.parametrize("which", ["classical", "joint"])
def test_fit_example_result_follows_the_contract(which, request):
    doc = load(request.getfixturevalue(which))
    _check_result(doc)
    assert doc["method"] == which and doc["status"] == "ok"
    assert {"Ca_xy", "K_x", "S_x", "Ca_xy_tempco"} <= set(doc["parameters"])


def test_fit_raw_result_follows_the_contract(raw_csv, work):
    out = work / "raw.json"
    run(["fit-raw", raw_csv, "--rate", "100", "--poses", "unknown", "--local-g", "9.81", "--json", out])
    doc = load(out)
    _check_result(doc)
    assert doc["parameters"]["K_x"]["unit"] == "g/count" and doc["temperature_range_C"] is None


def test_fit_raw_result_that_is_not_ok_follows_the_contract(raw_csv, work):
    """A status other than ok is written with the same contract (exit code 3)."""
    out = work / "raw_bad.json"
    run(["fit-raw", raw_csv, "--rate", "100", "--poses", "unknown", "--local-g", "9.81",
         "--angle-bound-arcsec", "1", "--json", out], expect=(3,))
    doc = load(out)
    _check_result(doc)
    assert doc["status"] != "ok" and doc["gates"]["config"]["angle_bound_arcsec"] == 1.0


def test_fit_raw_posterior_follows_the_contract(raw_csv, work):
    out = work / "raw_post.json"
    run(["fit-raw", raw_csv, "--rate", "100", "--poses", "unknown", "--local-g", "9.81", "--sample",
         "--ess", "400", "--json", out])
    doc = load(out)
    _check_result(doc)
    assert doc["method"] == "posterior"


def test_sample_result_follows_the_contract(work):
    out = work / "posterior.json"
    run(["sample", "--example", "--ess", "400", "--seed", "1", "--no-progress", "--json", out])
    doc = load(out)
    _check_result(doc)
    assert doc["method"] == "posterior" and doc["intervals"]


# -- comparisons, diagnosis -------------------------------------------------------------------
def test_compare_of_two_results_follows_the_contract(classical, joint, work):
    out = work / "cmp.json"
    run(["compare", classical, joint, "--json", out])
    doc = load(out)
    assert_valid(doc, "triadcal.comparison")
    assert doc["overall"] in ("pass", "fail", "inconclusive") and "Ca_xy" in doc["parameters"]


def test_compare_sequence_and_published_table_follow_the_contract(classical, joint, work):
    out = work / "seq.json"
    run(["compare", classical, joint, classical, "--sequence", "--json", out])
    doc = load(out)
    assert_valid(doc, "triadcal.comparison_sequence")
    assert len(doc["steps"]) == 2 and len(doc["cumulative"]) == 2
    table = work / "published.csv"
    table.write_text("exposure,sensor,angle,drift_arcsec\nshock,A,xY,12.0\nshock,A,xZ,-3.0\n"
                     "vibration,A,xY,40.0\n", encoding="utf-8")
    out = work / "pub.json"
    run(["compare", "--published", table, "--u-arcsec", "12", "--json", out], expect=(0, 4, 5))
    doc = load(out)
    assert_valid(doc, "triadcal.comparison_sequence")
    assert doc["kind"] == "published" and doc["cumulative"] == []


@pytest.mark.parametrize("model", ["default", "none"])
def test_diagnose_follows_the_contract(model, work):
    out = work / f"diagnosis_{model}.json"
    argv = ["diagnose", example_path(), "--draws", "100", "--top", "2", "--json", out]
    if model == "none":
        argv[2:2] = ["--model", "none"]
    run(argv)
    doc = load(out)
    assert_valid(doc, "triadcal.diagnosis")
    if model == "none":          # eq. 1 alone on a thermal campaign: a gap, and an effect named
        assert doc["gap"]["significant"] and doc["verdict"]["effect"] is not None and doc["where"]
    else:                        # the campaign's own model: no significant gap, and what it could not see
        assert doc["verdict"]["effect"] is None and "reason" in doc["verdict"]
        lim = doc["verdict"]["detection_limits"]
        assert lim["candidates"] and 0 < lim["level"] < doc["alpha"]
        bad = json.loads(json.dumps(doc))
        bad["verdict"]["detection_limits"]["candidates"][0]["parameters"] = {"x": {"value": -1.0, "unit": "ug"}}
        assert any("detection_limits" in e for e in errors(bad)), errors(bad)


# -- the other formats -----------------------------------------------------------------------
def test_simulated_truth_follows_the_contract(work):
    run(["simulate", "-o", work / "sim.csv", "--truth", work / "truth.json"])
    assert_valid(load(work / "truth.json"), "triadcal.truth")


@pytest.mark.parametrize("extra", [[], ["--thermal"]])
def test_budget_follows_the_contract(extra, work):
    out = work / f"budget{len(extra)}.json"
    run(["budget", *extra, "--json", out])
    assert_valid(load(out), "triadcal.budget")


def test_sbc_summary_follows_the_contract(work):
    out = work / "sbc.json"
    # 3 campaigns cannot make a conclusive verdict: exit 3 (the summary is written all the same)
    run(["validate", "--campaigns", "3", "--ranks", "9", "--effects", "none", "--ess", "100",
         "--processes", "1", "--no-progress", "--json", out], expect=(3,))
    assert_valid(load(out), "triadcal.sbc")


# the contract of validate-diagnosis's validation.json: tests/test_diagnosis_validation.py
# (test_cli_magnitudes_and_left_out, the CLI run with two conditions and --left-out)


def test_capture_state_and_emulator_truth_follow_the_contract(emulated_capture):
    # the conftest's `triadcal capture --emulate` run (shared with test_hardware_capture.py)
    assert_valid(load(emulated_capture / "capture.json"), "triadcal.capture")
    assert_valid(load(emulated_capture / "emulator_truth.json"), "triadcal.truth")


# -- the check can fail ------------------------------------------------------------------------
def _mutations():
    def drop(key):
        def f(d):
            del d[key]
        return f

    def setter(path, value):
        def f(d):
            *head, last = path
            for k in head:
                d = d[k]
            d[last] = value
        return f

    return {
        "missing status": drop("status"),
        "u is a string": setter(("parameters", "K_x", "u"), "1e-6"),
        "unknown status": setter(("status",), "great"),
        "negative u": setter(("parameters", "Ca_xy", "u"), -1.0),
        "unknown unit": setter(("parameters", "Ca_xy", "unit"), "furlong"),
        "unknown method": setter(("method",), "guess"),
        "version 2": setter(("version",), 2),
        "value is a string": setter(("parameters", "S_x", "value"), "0.001"),
        "passed is a string": setter(("gates", "outcomes", 0, "passed"), "yes"),
        "gate status ok": setter(("gates", "outcomes", 0, "status"), "ok"),
        "missing parameters": drop("parameters"),
        "unknown effect": setter(("effects",), ["warp_drive"]),
    }


MUTATIONS = _mutations()
#: mutations the reader (CalibrationResult.from_dict) refuses by itself; the others are refused
#: by the gates of a consumer (negative u) or only by the schema (see docs/results-json.md)
READER_REFUSES = {"missing status", "u is a string", "unknown status", "unknown unit", "version 2",
                  "value is a string", "missing parameters"}


@pytest.mark.parametrize("name", sorted(MUTATIONS))
def test_a_mutated_result_fails_the_schema(name, joint):
    from triadcal.estimation.result import CalibrationResult

    doc = load(joint)
    assert not errors(doc)
    bad = copy.deepcopy(doc)
    MUTATIONS[name](bad)
    assert errors(bad), f"the schema accepts a result with {name}"
    if name in READER_REFUSES:
        with pytest.raises(ValueError):
            CalibrationResult.from_dict(bad, "mutated.json")


def test_a_mutated_comparison_and_diagnosis_fail_the_schema(classical, joint, work):
    from triadcal.judgement.compare import ComparisonResult

    out = work / "cmp_m.json"
    run(["compare", classical, joint, "--json", out])
    doc = load(out)
    for mutate in (lambda d: d["parameters"]["Ca_xy"].__setitem__("verdict", "maybe"),
                   lambda d: d["parameters"]["Ca_xy"].__setitem__("u", "3.2"),
                   lambda d: d["parameters"]["Ca_xy"].__setitem__("u", -3.2),
                   lambda d: d.__setitem__("overall", "ok"),
                   lambda d: d.pop("rule")):
        bad = copy.deepcopy(doc)
        mutate(bad)
        assert errors(bad)
        with pytest.raises(ValueError):
            ComparisonResult.from_dict(bad, "mutated.json")
    diag = {"format": "triadcal.diagnosis", "version": 1, "model": [], "noise": "", "noise_known": True,
            "alpha": 0.01, "gap": {"chi2_dof": 1.0, "significant": False}, "where": [], "candidates": [],
            "verdict": {"effect": None}, "fit": {"chi2_dof": 1.0, "n_obs": 6, "n_params": 1}, "slices": [],
            "notes": []}
    assert not errors(diag)
    for path, value in ((("verdict", "effect"), "gremlins"), (("gap", "significant"), "yes"),
                        (("model",), ["warp_drive"])):
        bad = copy.deepcopy(diag)
        d = bad
        for k in path[:-1]:
            d = d[k]
        d[path[-1]] = value
        assert errors(bad), path
