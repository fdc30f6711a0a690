"""The zero of the terms that change in time (``Campaign.time_origin_s``; docs/bench-csv.md,
"Reading decisions"): the ``power_on_s`` metadata line, else the start of the first visit's
window. Before it, ``time_s`` was used as read: a file stamped in Unix time (1.7e9 s) gave the
drift's bias of 1970 with status ok and a warm-up's exponential underflowed to nothing.

The campaigns are made by tests/independent_bench.py (numpy, its own clock starting at power-on);
the relations between the origins are derived by hand from the laws: a drift ``S + d t`` referred
to a zero ``t1`` later has the bias ``S + d t1``; a warm-up ``db exp(-t/tau)`` has ``db exp(-t1/tau)``.
"""

from __future__ import annotations

import numpy as np
import pytest

from independent_bench import simulate_campaign, simulate_lag_campaign
from triadcal.errors import InputError
from triadcal.estimation.joint import fit_joint
from triadcal.io.bench_csv import parse_bench_csv, read_bench_csv
from triadcal.models.model import Model

EPOCH_S = 1.7e9                      # 2023-11-14 in Unix time: a logger's clock
EFFECTS_T = ["angle_tempco", "scale_tempco", "bias_tempco"]
DRIFT_UG_PER_H = (4.0, -3.0, 2.0)


def _shift(text: str, dt: float, power_on: str | None) -> str:
    """The CSV ``text`` with every ``time_s`` moved by ``dt`` and its ``power_on_s`` line replaced by
    ``power_on`` (None: removed)."""
    out, col = [], None
    for line in text.splitlines():
        if line.startswith("#"):
            if line.startswith("# power_on_s"):
                if power_on is not None:
                    out.append(f"# power_on_s = {power_on}")
                continue
            out.append(line)
        elif col is None:
            col = line.split(",").index("time_s")
            out.append(line)
        else:
            f = line.split(",")
            f[col] = repr(float(f[col]) + dt)
            out.append(",".join(f))
    return "\n".join(out) + "\n"


def _drift_campaign():
    rng = np.random.default_rng(31)

    def drift(k, t, T, G, d):
        return np.array(DRIFT_UG_PER_H) * 1e-6 * (t / 3600.0)      # g, from power-on at t = 0
    return simulate_campaign(rng, extra_bias=drift)


def test_origin_from_the_file_and_from_the_first_visit():
    text, _ = _drift_campaign()
    c = parse_bench_csv(text)
    assert c.metadata["power_on_s"] == "0" and c.time_origin_s == 0.0
    bare = parse_bench_csv(_shift(text, 0.0, None))
    start = float(np.min(bare.time_s - bare.tau_s / 2.0))
    assert bare.time_origin_s == start > 7000.0                    # after the first 2 h soak
    assert np.allclose(bare.elapsed_s(), bare.time_s - start)
    # a part of a campaign keeps its whole's zero (a branch, a unit, a cross-validation fold)
    late = bare.select(bare.time_s > np.median(bare.time_s))
    assert late.time_origin_s == start
    assert np.allclose(late.covariate_matrix()[-1], late.time_s - start)


def test_a_drift_is_the_same_on_any_clock():
    text, truth = _drift_campaign()
    effects = EFFECTS_T + ["bias_drift"]
    ref = fit_joint(parse_bench_csv(text), effects)
    assert ref.status == "ok", ref.notes
    for a, d in zip("xyz", DRIFT_UG_PER_H):
        p = ref.parameters[f"S_{a}_drift"]
        assert abs(p.value - d) < 4 * p.u, (a, p, d)
    # the same file stamped in Unix time, its power-on line moved with it: the same fit
    unix = fit_joint(parse_bench_csv(_shift(text, EPOCH_S, repr(EPOCH_S))), effects)
    assert unix.status == "ok"
    for n, p in ref.parameters.items():
        q = unix.parameters[n]
        assert q.value == pytest.approx(p.value, rel=1e-6, abs=1e-6 * max(p.u, 1e-12)), n
        assert q.u == pytest.approx(p.u, rel=1e-4), n
    # without the power-on line the zero is the first visit's start t1: the bias is S + d t1
    # (hand-derived from S + d t), everything else unchanged. Before the origin, the Unix-time file
    # gave the bias of 1970, S - d * 1.7e9 s, with a u of d's u times 1.7e9 s
    bare = parse_bench_csv(_shift(text, EPOCH_S, None))
    t1_s = bare.time_origin_s - EPOCH_S
    assert t1_s > 7000.0
    r = fit_joint(bare, effects)
    assert r.status == "ok"
    spec = Model(tuple(effects)).spec
    for a in "xyz":
        S0, S1, d = ref.parameters[f"S_{a}"], r.parameters[f"S_{a}"], ref.parameters[f"S_{a}_drift"]
        expect = S0.value + d.value * spec[f"S_{a}_drift"].to_internal * t1_s / spec[f"S_{a}"].to_internal
        assert S1.value == pytest.approx(expect, rel=1e-6, abs=1e-3 * S0.u), (a, S0, S1, expect)
        assert S1.u < 1.5 * S0.u, (a, S0, S1)
    for n, p in ref.parameters.items():
        if not (n.startswith("S_") and len(n) == 3):
            assert r.parameters[n].value == pytest.approx(p.value, rel=1e-6, abs=1e-6 * max(p.u, 1e-12)), n


def test_a_warm_up_is_found_on_a_unix_clock():
    """A ramp from power-on (the warm-up written with numpy.exp from t = 0): stamped in Unix time
    with its power-on line, the same Δb and τ; without the line, Δb referred to the first visit,
    Δb exp(-t1/τ) (hand-derived; ``warmup.offset_at``)."""
    db = (2500.0, -1800.0, 3000.0)
    text, truth = simulate_lag_campaign(np.random.default_rng(21), tau_element_min=0.02, warmup=(db, 5.0))
    effects = EFFECTS_T + ["bias_warmup"]
    ref = fit_joint(parse_bench_csv(text), effects)
    assert ref.status == "ok", ref.notes
    unix = fit_joint(parse_bench_csv(_shift(text, EPOCH_S, repr(EPOCH_S))), effects)
    assert unix.status == "ok", unix.notes
    for n in ("S_x_warmup", "S_y_warmup", "S_z_warmup", "S_warmup_tau"):
        assert unix.parameters[n].value == pytest.approx(ref.parameters[n].value, rel=1e-5), n
        assert abs(ref.parameters[n].value - truth[n]) < 3 * ref.parameters[n].u, n
    bare = parse_bench_csv(_shift(text, EPOCH_S, None))
    t1_s = bare.time_origin_s - EPOCH_S
    r = fit_joint(bare, effects)
    assert r.status == "ok", r.notes
    tau_s = 60.0 * ref.parameters["S_warmup_tau"].value
    for a in "xyz":
        expect = ref.parameters[f"S_{a}_warmup"].value * np.exp(-t1_s / tau_s)
        assert r.parameters[f"S_{a}_warmup"].value == pytest.approx(expect, rel=1e-4), a


@pytest.mark.parametrize("value, what", [("abc", "not a number"), ("nan", "not a finite number"),
                                         ("1e11", "outside"), ("900000", "after the visit of line")])
def test_a_bad_power_on_line_is_refused(tmp_path, value, what):
    text, _ = _drift_campaign()
    p = tmp_path / "bad.csv"
    p.write_text(_shift(text, 0.0, value))
    line = next(i for i, s in enumerate(p.read_text().splitlines(), 1) if s.startswith("# power_on_s"))
    with pytest.raises(InputError) as e:
        read_bench_csv(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}:{line}:") and "power_on_s" in msg and what in msg, msg


def _as_unit(text: str, unit: str, dt: float) -> list:
    """The data rows of ``text`` with their ``unit`` set to ``unit`` and ``time_s`` moved by ``dt``."""
    rows = [ln for ln in text.splitlines() if ln and not ln.startswith("#")]
    head = rows[0].split(",")
    iu, it = head.index("unit"), head.index("time_s")
    out = []
    for ln in rows[1:]:
        f = ln.split(",")
        f[iu], f[it] = unit, repr(float(f[it]) + dt)
        out.append(",".join(f))
    return out


def test_a_unit_of_a_fleet_file_starts_at_its_own_first_visit():
    """Two units calibrated one after the other on one bench, 100 h apart, in one file without a
    power-on line: unit B selected (``--unit B``, ``batch``) has its own origin, the start of its
    first window, and its fit is the fit of B's file alone. With the file's origin B's drift bias
    was its bias 100 h before its calibration began, S + d (t1 - 100 h): u 2.8 mg against 0.22 mg."""
    from triadcal.fleet.select import select_unit_state
    a_text, _ = _drift_campaign()
    b_text, _ = simulate_campaign(np.random.default_rng(32), extra_bias=lambda k, t, T, G, d:
                                  np.array(DRIFT_UG_PER_H) * 1e-6 * (t / 3600.0))
    meta = [ln for ln in a_text.splitlines() if ln.startswith("#") and not ln.startswith("# power_on_s")]
    header = next(ln for ln in a_text.splitlines() if ln and not ln.startswith("#"))
    later = 100 * 3600.0
    fleet = parse_bench_csv("\n".join(meta + [header] + _as_unit(a_text, "A", 0.0)
                                      + _as_unit(b_text, "B", later)) + "\n")
    alone = parse_bench_csv("\n".join(meta + [header] + _as_unit(b_text, "B", later)) + "\n")
    b = select_unit_state(fleet, "B")
    assert b.time_origin_s == alone.time_origin_s > later > fleet.time_origin_s
    effects = EFFECTS_T + ["bias_drift"]
    r, ref = fit_joint(b, effects), fit_joint(alone, effects)
    assert r.status == ref.status == "ok", r.notes
    for n, p in ref.parameters.items():
        assert r.parameters[n].value == pytest.approx(p.value, rel=1e-9, abs=1e-9 * max(p.u, 1e-12)), n
    old = fit_joint(fleet.select(fleet.unit == "B"), effects)       # the file's origin, as before
    for a in "xyz":
        assert old.parameters[f"S_{a}"].u > 10 * ref.parameters[f"S_{a}"].u, a
    # a fold of B (cross-validation) stays on B's clock
    fold = b.select(b.time_s > np.median(b.time_s))
    assert fold.time_origin_s == b.time_origin_s
    # the file's power-on line is the lab's statement for every unit in it: kept
    stated = parse_bench_csv("\n".join(meta + ["# power_on_s = 0", header] + _as_unit(a_text, "A", 0.0)
                                       + _as_unit(b_text, "B", later)) + "\n")
    assert select_unit_state(stated, "B").time_origin_s == 0.0
