"""The unit's own bias drift as a Type B row of the budget (lab file ``[item]
bias_drift_u_ug_per_h``; uncertainty/typeb.py, kind ``bias_drift``).

On a schedule that visits the temperatures in order a drift is inside the span of the biases and
their tempcos: no test of the residuals can see it (tests/test_drift_confounding.py). A lab that
knows its unit's stability states it, and the budget carries what such a drift moves each value
by, about the campaign's middle. Campaigns of tests/independent_bench.py (no project model code),
the drift made by its ``extra_bias`` hook, not by the model's ``bias_drift`` term the row is
computed with; the rows are checked against refits of drifted data and by coverage."""

import math

import numpy as np
import pytest
from scipy import stats

from independent_bench import default_truth, simulate_campaign
from triadcal.errors import InputError
from triadcal.estimation.joint import fit_joint
from triadcal.io.bench_csv import parse_bench_csv
from triadcal.io.lab import LabConfig, load_lab
from triadcal.models.effects import DEFAULT_EFFECTS
from triadcal.uncertainty.typeb import propagated_sources, systematic_sources

MONOTONE = (-40, -10, 20, 50, 80)


def _campaign(seed, drift_ug_h=(0.0, 0.0, 0.0), mid_s=0.0):
    truth = default_truth(np.random.default_rng(100 + seed))
    text, truth = simulate_campaign(
        np.random.default_rng(seed), truth=truth, setpoints_C=MONOTONE,
        extra_bias=lambda k, t, T, G, d: np.asarray(drift_ug_h) * 1e-6 * (t - mid_s) / 3600.0)
    return parse_bench_csv(text), truth


def _mid(seed=0) -> float:
    c, _ = _campaign(seed)
    return 0.5 * float(c.time_s.min() + c.time_s.max())


def _row(result, name, axis):
    return next(r for r in result.parameters[name].uncertainty["budget"]
                if r["key"] == "[item] bias_drift_u_ug_per_h" and r["source"].endswith(f"axis {axis}"))


def test_the_lab_file_states_the_units_drift_and_refuses_nonsense(tmp_path):
    p = tmp_path / "lab.toml"
    p.write_text('[item]\nbias_drift_u_ug_per_h = 0.2\ndistribution = "rectangular"\n')
    lab = load_lab(p)
    assert lab.bias_drift_u_ug_per_h == 0.2 and lab.distributions["item"] == "rectangular"
    src = [s for s in systematic_sources(lab, "V") if s.kind == "bias_drift"]
    assert [s.axis for s in src] == [0, 1, 2] and {s.unit for s in src} == {"ug/h"}
    assert all(s.u == 0.2 and s.distribution == "rectangular" and s.equipment == "item" for s in src)
    for bad, words in (("bias_drift_u_ug_per_h = -1", "non-negative"), ("bias_drift_u_ug_per_h = 2e4", "10 mg per hour")):
        p.write_text(f"[item]\n{bad}\n")
        with pytest.raises(InputError, match=words):
            load_lab(p)
    p.write_text('[compare]\nshared_equipment = ["item"]\n')     # a drift is new in every campaign
    with pytest.raises(InputError, match="shared_equipment"):
        load_lab(p)


def test_the_drift_row_is_what_a_refit_of_drifted_data_moves():
    """The row's sensitivity (the model's bias_drift term about the middle, linearised) against two
    least-squares fits of the same noise with and without a drift of +1 ug/h on x and -1 ug/h on y
    made by the independent simulator: the same move of S_a_tempco and S_a (to 1 %); a drift of one
    output does not reach another's parameters; the row's contribution is |c| u."""
    mid = _mid()
    clean, _ = _campaign(0, mid_s=mid)
    drifted, _ = _campaign(0, (1.0, -1.0, 0.0), mid_s=mid)
    lab = LabConfig(bias_drift_u_ug_per_h=0.5)
    with_row = fit_joint(clean, systematics=systematic_sources(lab, clean.output_unit))
    plain, moved = fit_joint(clean), fit_joint(drifted)
    assert with_row.status == plain.status == moved.status == "ok"
    for sign, a in ((1.0, "x"), (-1.0, "y")):
        for name in (f"S_{a}_tempco", f"K_{a}"):
            c = _row(with_row, name, a)["sensitivity"]
            seen = moved[name].value - plain[name].value
            assert c * sign == pytest.approx(seen, rel=0.01, abs=1e-3 * plain[name].u), (name, c, seen)
        row = _row(with_row, f"S_{a}_tempco", a)
        assert row["sensitivity_unit"] == "ug/degC/(ug/h)" and row["u"] == 0.5 and row["unit"] == "ug/h"
        assert row["contribution"] == pytest.approx(abs(row["sensitivity"]) * 0.5)
        # monotone in temperature: a drift of 1 ug/h moves the bias tempco by several u of the fit
        assert abs(row["sensitivity"]) > 3 * plain[f"S_{a}_tempco"].u
    assert _row(with_row, "S_x_tempco", "z")["sensitivity"] == 0.0
    u_a, u_c = plain["S_x_tempco"].u, with_row["S_x_tempco"].u
    c = _row(with_row, "S_x_tempco", "x")["sensitivity"]
    assert u_c == pytest.approx(math.hypot(u_a, 0.5 * c), rel=0.02)      # plus the lab's other rows: none
    note = next(n for n in with_row.notes if n.startswith("the schedule cannot show a bias drift"))
    assert "bias_drift_u_ug_per_h = 0.5" in note


def test_a_fitted_drift_has_no_row():
    """With ``bias_drift`` in the model the fit measures the drift: its u is the estimate's own, and
    the lab's row is left out (as a measured bench non-orthogonality's)."""
    src = systematic_sources(LabConfig(bias_drift_u_ug_per_h=0.5), "V")
    assert propagated_sources(src, ["S_x", "S_x_drift", "S_y_drift", "S_z_drift"]) == []
    assert [s.axis for s in propagated_sources(src, ["S_x", "S_y_drift"])] == [0, 2]
    c, _ = _campaign(1)
    r = fit_joint(c, effects=tuple(DEFAULT_EFFECTS) + ("bias_drift",), systematics=src)
    assert not any(e["key"] == "[item] bias_drift_u_ug_per_h" for e in r.fit.get("systematic_errors") or [])
    assert all("budget" not in p.uncertainty or not any("drift" in b["source"] for b in p.uncertainty["budget"])
               for p in r.parameters.values())


#: campaigns of the coverage test; each gives three bias tempcos
N_COVERAGE = 20


@pytest.mark.slow   # 40 fits, about 40 s
def test_a_stated_drift_makes_the_bias_tempcos_cover():
    """Units drifting at rates drawn uniformly in +-0.6 ug/h per output (a stability the lab states
    as u = 0.6/sqrt(3) ug/h, rectangular) on the monotone schedule: with the row the expanded
    intervals of S_a_tempco and S_a cover the truth at their 95 % level (60 of each; a floor of the
    binomial at 1 %); without it the same fits miss (a drift of 0.6 ug/h moves S_tempco about 3 u),
    fewer than 85 % covered."""
    mid = _mid()
    lab = LabConfig(bias_drift_u_ug_per_h=0.6 / math.sqrt(3.0), distributions={"item": "rectangular"})
    rng = np.random.default_rng(2026)
    hits_with, hits_without, hits_bias = 0, 0, 0
    for seed in range(N_COVERAGE):
        d = rng.uniform(-0.6, 0.6, 3)
        c, truth = _campaign(10 + seed, tuple(d), mid_s=mid)
        r = fit_joint(c, systematics=systematic_sources(lab, c.output_unit))
        plain = fit_joint(c)
        assert r.status == "ok", (seed, r.status)
        for a in "xyz":
            n = f"S_{a}_tempco"
            hits_with += abs(r[n].value - truth[n]) <= r.parameters[n].uncertainty["U"]
            hits_without += abs(plain[n].value - truth[n]) <= 2.0 * plain[n].u
            hits_bias += abs(r[f"S_{a}"].value - truth[f"S_{a}"]) <= r.parameters[f"S_{a}"].uncertainty["U"]
    n = 3 * N_COVERAGE
    print(f"covered with the row: S_tempco {hits_with}/{n}, S {hits_bias}/{n}; without it: S_tempco {hits_without}/{n}")
    floor = int(stats.binom.ppf(0.01, n, 0.95))
    assert hits_with >= floor and hits_bias >= floor, (hits_with, hits_bias, floor)
    assert hits_without < 0.85 * n, hits_without
