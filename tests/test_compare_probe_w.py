"""An outside probe's three findings on ``compare`` (probe W), each on data made another way:
hand-built results (numbers derived by hand below) and the independent simulator
(tests/independent_bench.py).

1. a negative ``--correlation`` widened u(d) silently and turned a real drift into "pass";
2. ``--shared-bench`` gave a confident "fail" while its own bench check said the bench moved;
3. BEFORE and AFTER swapped (data dates out of order) were compared, every drift's sign reversed.
"""

import math
import os
import sys

import numpy as np
import pytest

from triadcal.cli import main
from triadcal.errors import InputError
from triadcal.estimation.gates import FitEvidence, apply_gates
from triadcal.estimation.result import CalibrationResult, ParameterValue
from triadcal.judgement.compare import (ANGLES, ComparisonResult, compare, compare_sequence, judge_published,
                                        read_published_table)
from triadcal.models.model import Model

from test_compare_shared import _param  # noqa: E402 - an angle with a Type A row and the encoder zero's


def _result(xy=0.0, u=0.3, date=None, tilt_y=None, u_a=0.3, values=None):
    """Six angles ``values`` (default 0, Ca_xy = ``xy``) +- ``u`` (no budget), or, with ``tilt_y``, Ca_xy
    and tilt_y (and tilt_x = 0) carrying the encoder zero of axis 1 (u_s 5", sensitivity +1, Type A
    ``u_a``): the bench's zero goes one to one into both. ``date``: the data's date (``data_date``)."""
    vals = dict(zip(ANGLES, values or [0.0] * 6))
    params = {n: ParameterValue(vals[n], u, "arcsec") for n in ANGLES}
    params["Ca_xy"] = ParameterValue(xy, u, "arcsec")
    effects = ()
    if tilt_y is not None:
        effects = ("bench_tilt",)
        params["Ca_xy"] = _param(xy, u_a, c=1.0)
        params["tilt_y"] = _param(tilt_y, u_a, c=1.0)
        params["tilt_x"] = ParameterValue(0.0, u_a, "arcsec")
    r = CalibrationResult(unit="SN-W", method="joint", parameters=params, effects=effects)
    m = Model(r.effects)
    r.extra["fixed"] = {n: {"value": m.spec[n].nominal, "unit": m.spec[n].unit} for n in m.names if n not in params}
    if date:
        r.extra["data_date"] = date
    apply_gates(r, FitEvidence(converged=True))
    return r


# ---------------------------------------------------------------------------------------------------
# 1. a negative correlation
# Hand: u = 0.3" each side, Ca_xy moved 1.0". rho = 0: u(d) = 0.3 sqrt 2 = 0.424, z = 2.36 > 1.96: fail.
# rho = -0.9: u(d) = 0.3 sqrt(2 (1 + 0.9)) = 0.585, z = 1.71: "pass" -- a real drift read as none.

def test_negative_correlation_is_refused_naming_it():
    before, after = _result(0.0), _result(1.0)
    c = compare(before, after, tolerance_arcsec=None)
    assert c["Ca_xy"].u == pytest.approx(0.3 * math.sqrt(2))
    assert c["Ca_xy"].z == pytest.approx(1.0 / (0.3 * math.sqrt(2)))
    assert c["Ca_xy"].verdict == "fail"
    for rho in (-0.9, -0.3, -1e-6):
        with pytest.raises(InputError, match=rf"correlation = {rho:g}: a negative rho .* opposite signs"):
            compare(before, after, tolerance_arcsec=None, correlation=rho)
    # zero and positive stay as they were (a positive one beyond the budgets is held back: test_compare.py)
    assert compare(before, after, tolerance_arcsec=None, correlation=0.0)["Ca_xy"].verdict == "fail"
    # the published mode too: u(d) = u sqrt(2 (1 - rho)) would grow the same way
    rows = read_published_table(os.path.join(os.path.dirname(__file__), "..", "examples", "data", "table3.csv"))
    with pytest.raises(InputError, match=r"correlation = -0.5: a negative rho"):
        judge_published(rows, u_measurement_arcsec=12.0, correlation=-0.5)


def test_cli_refuses_a_negative_correlation_in_one_line(tmp_path, capsys):
    _result(0.0).save(tmp_path / "b.json")
    _result(1.0).save(tmp_path / "a.json")
    base = ["compare", str(tmp_path / "b.json"), str(tmp_path / "a.json"), "--tolerance", "none", "--exit-code"]
    # z 2.36: Ca_xy fails, the joint test (D2 5.6 on 6 dof) does not: inconclusive; at -0.9 it was "pass", exit 0
    assert main(base + ["--quiet"]) == 5
    capsys.readouterr()
    assert main(base + ["--correlation", "-0.9"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--correlation -0.9: a negative rho" in err[0], err
    assert main(["compare", "--published", os.path.join(os.path.dirname(__file__), "..", "examples", "data",
                                                        "table3.csv"),
                 "--u-arcsec", "12", "--correlation", "-0.5"]) == 1
    assert "--correlation -0.5: a negative rho" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------------
# 2. --shared-bench against the bench check
# Hand: the unit did not move; the bench's encoder zero of axis 1 was re-zeroed by +3" between the
# campaigns, so Ca_xy and tilt_y (sensitivity +1 each) read 3" more after. Type A 0.3" each side, the
# encoder row u_s = 5".
#   shared:      u(d) = sqrt(0.3^2 + 0.3^2) = 0.424 (the 5" cancel), Ca_xy z = 3/0.424 = 7.07: "fail";
#                tilt_y's change 3 +- 0.424 (z 7.07): significant, the bench moved.
#   independent: u(d) = sqrt(2 (0.09 + 25)) = 7.08, z = 0.42: pass.
# The check contradicts the sharing: the verdict is held back (inconclusive), naming tilt_y and its number.

def test_shared_bench_held_back_when_the_bench_check_says_it_moved(tmp_path):
    before, after = _result(100.0, tilt_y=10.0), _result(103.0, tilt_y=13.0)
    ind = compare(before, after, tolerance_arcsec=None)
    assert ind["Ca_xy"].u == pytest.approx(math.sqrt(2 * 25.09)) and ind["Ca_xy"].verdict == "pass"
    assert ind.overall == "pass"

    s = compare(before, after, tolerance_arcsec=None, shared_equipment=("bench", "gravity"))
    assert s["Ca_xy"].u == pytest.approx(0.3 * math.sqrt(2))                 # still reported as shared
    assert s.bench_check["tilt_y"]["significant"]
    assert s.bench_check["tilt_y"]["u"] == pytest.approx(0.3 * math.sqrt(2))
    assert s["Ca_xy"].verdict == "inconclusive" and s["Ca_xy"].held_back
    assert s.overall == "inconclusive"
    said = s.notes[0]
    assert said.startswith("overall verdict not pass: held back: the bench check contradicts the shared [bench]")
    assert "tilt_y changed +3 +- 0.42 arcsec (z 7.07)" in said, said
    assert "shared the verdict is fail, with its errors independent it is pass" in said
    assert "Ca_xy (fail -> pass)" in said
    # it reads back (a held-back verdict is inconclusive, nothing else)
    s.save(tmp_path / "s.json")
    back = ComparisonResult.load(tmp_path / "s.json")
    assert back.overall == "inconclusive" and back["Ca_xy"].verdict == "inconclusive"

    # the bench did not move (the same zero both times): the check is quiet and the shared fail stands
    still = compare(_result(100.0, tilt_y=10.0), _result(103.0, tilt_y=10.0), tolerance_arcsec=None,
                    shared_equipment=("bench",))
    assert not still.bench_check["tilt_y"]["significant"]
    assert still["Ca_xy"].verdict == "fail" and still.overall == "fail"
    assert not [n for n in still.notes if "bench check" in n]


def test_shared_bench_end_to_end_with_the_bench_rezeroed():
    """The independent simulator: one unchanged unit, the bench's encoder zeros (3", 3") before and
    (-4", -3") after; both fitted with a lab file (encoder_zero_u_arcsec 5). The zero of axis 1 goes
    one to one into Ca_xz, Ca_zx and the tilt: with --shared-bench the angles' drifts are 7" against
    u(d) under 1" (a confident "fail" before the fix); the tilt check fires, so the verdict is held back."""
    sys.path.insert(0, os.path.dirname(__file__))
    from independent_bench import simulate_campaign
    from triadcal import api
    from triadcal.io.lab import LabConfig

    import tempfile

    lab = LabConfig(encoder_zero_u_arcsec=5.0, source="t")
    rng = np.random.default_rng(11)
    fits, truth = [], None
    with tempfile.TemporaryDirectory() as tmp:
        for name, zero in (("before", (3.0, 3.0)), ("after", (-4.0, -3.0))):
            text, truth = simulate_campaign(rng, truth=truth, setpoints_C=(20,), encoder_zero_arcsec=zero)
            path = os.path.join(tmp, f"{name}.csv")
            with open(path, "w") as f:
                f.write(text)
            fits.append(api.fit(path, effects=("bench_tilt",), lab=lab))
    rb, ra = fits
    assert rb.status == "ok" and ra.status == "ok"
    sh = compare(rb, ra, tolerance_arcsec=None, shared_equipment=("bench", "gravity"))
    ind = compare(rb, ra, tolerance_arcsec=None)
    print("shared:", sh.overall, sh.joint.D2, sh.bench_check, "independent:", ind.overall, ind.joint.D2)
    assert any(v["significant"] for v in sh.bench_check.values())
    assert sh.overall != "fail" and ind.overall != "fail"
    assert sh.notes[0].startswith("overall verdict not pass: held back: the bench check contradicts the shared")


# ---------------------------------------------------------------------------------------------------
# 3. BEFORE and AFTER out of the order of their data

def test_reversed_order_is_refused_naming_both_files_and_dates(tmp_path, capsys):
    early, late = _result(0.0, date="2026-01-10"), _result(1.0, date="2026-03-01")
    assert compare(early, late, tolerance_arcsec=None)["Ca_xy"].drift == pytest.approx(1.0)
    with pytest.raises(InputError, match=r"^a\.json \(data_date 2026-03-01\) is given before b\.json "
                                         r"\(data_date 2026-01-10\)"):
        compare(late, early, tolerance_arcsec=None, files=("a.json", "b.json"))
    # equal dates, or a date on one side only: compared
    compare(_result(0.0, date="2026-03-01"), late, tolerance_arcsec=None)
    compare(late, _result(0.0), tolerance_arcsec=None)
    # a sequence: any two states out of order (here the first and the last)
    mid = _result(0.5, date="2026-02-01")
    compare_sequence([early, mid, late], tolerance_arcsec=None)
    with pytest.raises(InputError, match=r"s0 \(data_date 2026-03-01\) is given before s2 \(data_date 2026-01-10\)"):
        compare_sequence([late, _result(0.2), early], ["s0", "s1", "s2"], tolerance_arcsec=None)

    # the CLI: one line naming both files
    early.save(tmp_path / "before.json")
    late.save(tmp_path / "after.json")
    b, a = str(tmp_path / "before.json"), str(tmp_path / "after.json")
    assert main(["compare", a, b, "--tolerance", "none"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{a} (data_date 2026-03-01) is given before {b} (data_date 2026-01-10)" in err[0], err
    assert main(["compare", a, b, "--sequence", "--tolerance", "none"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{a} (data_date 2026-03-01) is given before {b}" in err[0], err
    assert main(["compare", b, a, "--tolerance", "none", "--quiet"]) == 0
