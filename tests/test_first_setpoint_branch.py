"""A first setpoint away from ambient is on a branch (Schedule.directions).

An outside probe: `plan --range 30:85` planned 30 -> 85 -> 30 degC from ambient 20 degC and labelled
the first 30 `none` (the hysteresis mid-line), though the unit reaches it by heating. On that
schedule the hysteresis is exactly identified (three temperatures, three labels), so nothing in the
residuals shows the error: a unit on the heating branch there fitted with status ok, chi2/dof
0.8-1.05, its angles 5-14 u off and its hysteresis twice the truth (coverage 0/120).

Made with the independent bench (tests/independent_bench.py): its backlash state machine walks
the path 20 -> 30 -> 85 -> 30 (the ambient block then dropped), so the physics at 30 is the heating
branch by its own rules, not by triadcal's labels.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from independent_bench import default_truth, simulate_campaign  # noqa: E402
from triadcal.estimation.joint import fit_joint  # noqa: E402
from triadcal.io.bench_csv import read_bench_csv  # noqa: E402
from triadcal.models.effects import DEFAULT_EFFECTS  # noqa: E402
from triadcal.models.simulate import Schedule  # noqa: E402

ANGLES = ("xy", "xz", "yx", "yz", "zx", "zy")


def test_the_labels_of_a_schedule_that_starts_away_from_ambient():
    """Hand-derived: from 20 degC, 30 is reached by heating and -40 by cooling; 20 is the mid-line."""
    assert Schedule(setpoints_C=(30.0, 85.0, 30.0), start_C=20.0).directions() == ["heating", "heating", "cooling"]
    assert Schedule(setpoints_C=(10.0, -40.0, 10.0), start_C=20.0).directions() == ["cooling", "cooling", "heating"]
    assert Schedule(setpoints_C=(20.0, 60.0, 20.0), start_C=20.0).directions() == ["none", "heating", "cooling"]


def _drop_first_block(text: str, n: int) -> str:
    lines = text.splitlines()
    head = [i for i, ln in enumerate(lines) if not ln.startswith("#")][0]
    return "\n".join(lines[:head + 1] + lines[head + 1 + n:]) + "\n"


def test_a_unit_reaching_its_first_setpoint_by_heating_is_fitted_on_that_branch(tmp_path):
    truth = default_truth(np.random.default_rng(7))
    truth.update({f"Ca_{ab}_hysteresis": 15.0 for ab in ANGLES})
    text, _ = simulate_campaign(np.random.default_rng(8), truth=truth, setpoints_C=(20.0, 30.0, 85.0, 30.0),
                                hysteresis={"form": "offset"})
    text = _drop_first_block(text, 12)                        # the ambient soak: not visited
    path = tmp_path / "c.csv"
    path.write_text(text, encoding="utf-8")
    c = read_bench_csv(path)
    blocks = list(dict.fromkeys(zip(c.setpoint_C, c.direction)))
    assert [d for _, d in blocks] == Schedule(setpoints_C=(30.0, 85.0, 30.0), start_C=20.0).directions()
    r = fit_joint(c, DEFAULT_EFFECTS)
    assert r.status == "ok", r.notes
    z = {ab: (r.parameters[f"Ca_{ab}"].value - truth[f"Ca_{ab}"]) / r.parameters[f"Ca_{ab}"].u for ab in ANGLES}
    zh = {ab: (r.parameters[f"Ca_{ab}_hysteresis"].value - 15.0) / r.parameters[f"Ca_{ab}_hysteresis"].u
          for ab in ANGLES}
    assert max(abs(v) for v in z.values()) < 4.0 and max(abs(v) for v in zh.values()) < 4.0, (z, zh)
    # the old label (`none` at the first 30) on the same data: the angles and h are wrong, status ok
    old = path.read_text().replace(",30.0,heating,", ",30.0,none,", 12) if ",30.0,heating," in text else None
    if old is None:       # the bench writes setpoints as integers
        old = "\n".join(ln.replace(",30,heating,", ",30,none,", 1) if i < 60 else ln
                        for i, ln in enumerate(text.splitlines())) + "\n"
    (tmp_path / "old.csv").write_text(old, encoding="utf-8")
    r_old = fit_joint(read_bench_csv(tmp_path / "old.csv"), DEFAULT_EFFECTS)
    z_old = max(abs(r_old.parameters[f"Ca_{ab}"].value - truth[f"Ca_{ab}"]) / r_old.parameters[f"Ca_{ab}"].u
                for ab in ANGLES)
    assert z_old > 5.0, z_old
