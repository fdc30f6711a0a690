"""The answer gate ``bias``: no accelerometer's zero-g offset is half a g.

An outside probe: a campaign in 16-bit offset-binary counts (``w = 32768 + 16384 a``) declared
``# output_unit = counts`` fitted with status ok and S = 1.999 +- 7e-6 g on every axis (the mid-scale
code read as an offset), K right, through `fit` and `batch`. Made here with the independent bench
(tests/independent_bench.py) and converted to counts by hand.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from independent_bench import default_truth, simulate_campaign  # noqa: E402
from triadcal.estimation.classical import fit_classical  # noqa: E402
from triadcal.estimation.gates import _gate_bias  # noqa: E402
from triadcal.estimation.joint import fit_joint  # noqa: E402
from triadcal.estimation.result import ParameterValue  # noqa: E402
from triadcal.io.bench_csv import read_bench_csv  # noqa: E402
from triadcal.models.effects import DEFAULT_EFFECTS  # noqa: E402


def _counts(text: str, mid: float) -> str:
    """The campaign's V columns as a 16-bit code at 16384 counts per V, plus ``mid``."""
    out, cols = [], None
    for line in text.splitlines():
        if line.startswith("# output_unit"):
            out.append("# output_unit = counts")
            continue
        if line.startswith("#"):
            out.append(line)
            continue
        f = line.split(",")
        if cols is None:
            cols = {n: i for i, n in enumerate(f)}
            out.append(line)
            continue
        for a in "xyz":
            f[cols[f"w_{a}"]] = repr(mid + 16384.0 * float(f[cols[f"w_{a}"]]))
            f[cols[f"sd_{a}"]] = repr(16384.0 * float(f[cols[f"sd_{a}"]]))
        out.append(",".join(f))
    return "\n".join(out) + "\n"


def _gate(result):
    return next(g for g in result.extra["gates"]["outcomes"] if g["gate"] == "bias")


def test_offset_binary_counts_are_refused_and_twos_complement_passes(tmp_path):
    truth = default_truth(np.random.default_rng(2))
    text, _ = simulate_campaign(np.random.default_rng(3), truth=truth, setpoints_C=(-20.0, 20.0, 60.0))
    for name, mid, ok in (("offset_binary", 32768.0, False), ("twos_complement", 0.0, True)):
        path = tmp_path / f"{name}.csv"
        path.write_text(_counts(text, mid), encoding="utf-8")
        c = read_bench_csv(path)
        for r in (fit_joint(c, DEFAULT_EFFECTS), fit_classical(c)):
            g = _gate(r)
            assert g["passed"] is ok, (name, r.method, g)
            if not ok:
                assert r.status == "unphysical_term" and "offset-binary" in g["reason"], (r.status, g["reason"])
                assert abs(r.parameters["S_x"].value - 2.0) < 0.03      # the mid-scale code, 32768/16384 x K (0.99-1.01)
            else:
                assert abs(r.parameters["S_x"].value - truth["S_x"]) < 1e-4


def test_the_bound_is_on_the_value_less_two_u():
    """Hand-derived edges: 0.49 g passes; 0.6 +- 0.06 g (0.6 - 0.12 = 0.48) passes, not known to be beyond;
    0.6 +- 0.01 g fails; -0.7 g fails; a bias in another unit, or without scale tempcos, is not judged."""
    def p(v, u, unit="g", tempco=True):
        out = {"S_x": ParameterValue(v, u, unit), "S_y": ParameterValue(0.0, 1e-6, unit),
               "S_z": ParameterValue(0.0, 1e-6, unit)}
        if tempco:
            out["K_x_tempco"] = ParameterValue(20.0, 1.0, "ppm/degC")
        return out
    assert _gate_bias(p(0.49, 1e-6)).passed is True
    assert _gate_bias(p(0.6, 0.06)).passed is True
    assert _gate_bias(p(0.6, 0.01)).passed is False
    assert _gate_bias(p(-0.7, 0.01)).passed is False
    assert _gate_bias(p(5.0, 0.01, unit="m/s2")).passed is None
    assert _gate_bias(p(2.0, 0.01, tempco=False)).passed is None      # one temperature: compensates exactly
