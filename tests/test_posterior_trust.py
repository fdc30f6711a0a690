"""When the posterior's intervals are not the ones to trust, the result says so (docs/posterior.md,
"Which intervals to use"). An outside probe (its own numpy bench) found two regimes where `sample`
said "ok", recommended its posterior intervals and they missed:

* a prior-data conflict just under the widening threshold (bias tempcos of +-950 ug/degC on a
  20 -> 22 -> 20 degC campaign, 0.9 mg a visit): the Gaussian posterior pulled 2.2 SD toward the
  default prior's 0, flagged `non_gaussian`, recommended as "holding where the least-squares ones do
  not"; it held 10 of 21 truths, the least squares 19;
* the noise estimated from the residuals with few dof (six positions at two setpoints, 26
  parameters, 36 observations): one noise level per output on 3.3 dof each, the 95 % intervals
  (value +- 1.96 u, posterior and least squares alike) held 0.83 of the truths.

The campaigns are made by tests/independent_bench.py (scipy rotations, no code of the project's model)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from independent_bench import POSITIONS, default_truth, simulate_campaign
from triadcal.estimation.joint import fit_joint
from triadcal.estimation.posterior import sample
from triadcal.io.bench_csv import parse_bench_csv

EFFECTS = ["bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco"]
SIX = {k: POSITIONS[k] for k in ("P01", "P03", "P05", "P07", "P09", "P11")}      # +Y -Y +X -X +Z -Z


def _without_noise_columns(text: str) -> str:
    """The CSV with its sd_x, sd_y, sd_z, n_samples columns (the last four) removed: the noise unknown."""
    out = []
    for line in text.splitlines():
        out.append(line if line.startswith("#") else ",".join(line.split(",")[:-4]))
    return "\n".join(out) + "\n"


def few_dof_campaign(seed):
    rng = np.random.default_rng(seed)
    text, truth = simulate_campaign(rng, setpoints_C=(20, 50), positions=SIX, noise_sd=0.05,
                                    tilt_arcsec=(30.0, -20.0))
    return parse_bench_csv(_without_noise_columns(text), f"six-two-{seed}"), truth


def test_few_dof_pool_the_noise_and_expand_by_students_t():
    c, truth = few_dof_campaign(1)
    r = fit_joint(c, EFFECTS)
    assert r.status == "ok" and not r.fit["noise_known"]
    # 36 observations, 26 parameters: 10 dof, 3.3 an output -- too few to estimate three levels apart
    assert r.fit["noise_dof"] == 10 and "Q_estimate_per_output" not in r.fit
    for n, p in r.parameters.items():
        if n in truth:
            # JCGM 100 G.3: k from Student's t on the dof at the budget's coverage probability (95.45 %)
            k = float(stats.t.ppf(0.5 + p.uncertainty["coverage_probability"] / 2, 10))
            assert p.uncertainty["k"] == pytest.approx(k, rel=1e-6) and p.U == pytest.approx(k * p.u, rel=1e-6), n
            assert p.uncertainty["dof_eff"] == pytest.approx(10)
    k = float(stats.t.ppf(0.975, 10))          # the intervals' 95 %
    # the posterior holds the level at its estimate: the least-squares intervals (Student's t) are the ones
    post = sample(c, EFFECTS, ess=400, seed=1)
    assert post.extra["intervals_to_use"]["use"] == "least_squares"
    assert "10 residual degrees of freedom" in post.extra["intervals_to_use"]["why"]
    iv = post.intervals["K_x"]
    assert iv["ls_k"] == pytest.approx(k) and iv["ls_high"] - iv["ls_low"] == pytest.approx(2 * k * r["K_x"].u, rel=1e-6)


@pytest.mark.slow
def test_few_dof_intervals_cover():
    """value +- U (95.45 %) over 20 campaigns x the unit's parameters: before 0.83 (value +- 1.96 u, three
    noise levels on 3.3 dof each); one level on the 10 dof, value +- 1.96 u: 0.92; value +- U: 0.94. The 520 pairs are not independent (a campaign's parameters share its noise
    estimate); the bound 0.91 is 4 binomial SDs below 0.95 for independent pairs."""
    hit = tot = 0
    for seed in range(20):
        c, truth = few_dof_campaign(100 + seed)
        r = fit_joint(c, EFFECTS)
        assert r.status == "ok"
        for n, v in truth.items():
            if n in r.parameters:
                hit += abs(r[n].value - v) <= r[n].U
                tot += 1
    assert tot >= 500 and hit / tot >= 0.91, (hit, tot)


def test_a_prior_that_pulls_is_said_and_the_least_squares_intervals_recommended():
    rng = np.random.default_rng(7)
    truth = default_truth(rng)
    truth.update({"S_x_tempco": 950.0, "S_y_tempco": -950.0, "S_z_tempco": -950.0})
    text, truth = simulate_campaign(rng, truth=truth, setpoints_C=(20, 22, 20), noise_sd=0.05)
    c = parse_bench_csv(text, "conflict-7")
    post = sample(c, EFFECTS, ess=400, seed=1)
    assert post.status == "ok"
    flags = post.extra["flags"]
    pulled = [n for n in ("S_x_tempco", "S_y_tempco", "S_z_tempco") if n in flags["prior_pulled"]]
    # the prior pulled them: flagged as such, not as non-Gaussian (the posterior is a Gaussian's)
    assert pulled and not set(pulled) & set(flags["non_gaussian"])
    for n in pulled:
        iv = post.intervals[n]
        assert iv["prior_pulled"] and not iv["non_gaussian"]
        # toward the prior's 0: the posterior mean lies between 0 and the least squares' centre
        ls_c = 0.5 * (iv["ls_low"] + iv["ls_high"])
        assert abs(post[n].value) < abs(ls_c) and np.sign(post[n].value) == np.sign(ls_c)
        assert any(note.startswith(f"{n}: the prior moved or narrowed") for note in post.notes)
    rec = post.extra["intervals_to_use"]
    assert rec["use"] == "least_squares" and "the prior moves or narrows" in rec["why"]
