"""The classical method on a plan whose up/down groups are not half-turn pairs (six faces of a cube on
a two-axis bench): a bench tilt enters its angles and biases, so its redundant positions are tested
for one (``estimation.classical_tilt.tilt_leak_gate``, docs/classical.md "Tilt on other plans").
Before, a campaign on a bench tilted by 50 arcsec gave Ca_zx 91 u and S_x 88 u off with status ok
(an outside probe). The campaigns are made by tests/independent_bench.py; the level is checked on
tilt-free campaigns (the p-values of a valid test are uniform)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from independent_bench import POSITIONS, simulate_campaign
from triadcal.estimation.classical import fit_classical
from triadcal.estimation.joint import fit_joint
from triadcal.io.bench_csv import parse_bench_csv

SIX = {k: POSITIONS[k] for k in ("P01", "P03", "P05", "P07", "P09", "P11")}


def _six(seed, tilt):
    text, truth = simulate_campaign(np.random.default_rng(seed), positions=SIX, tilt_arcsec=tilt)
    return parse_bench_csv(text), truth


def test_a_tilted_bench_on_six_faces_is_refused_and_the_joint_fit_is_right():
    c, truth = _six(1, (50.0, -30.0))
    r = fit_classical(c)
    assert r.status == "model_mismatch"
    g = r.fit["tilt_leak"]
    assert g["passed"] is False and g["value"] < 1e-3 and "--method joint" in g["reason"]
    assert "not half-turn pairs" in g["reason"] and "factor up to 1" in g["reason"]
    # what the gate protects against: the classical angles carry the tilt
    worst = max(abs(r.parameters[f"Ca_{ab}"].value - truth[f"Ca_{ab}"]) / r.parameters[f"Ca_{ab}"].u
                for ab in ("xy", "xz", "yx", "yz", "zx", "zy"))
    assert worst > 10
    j = fit_joint(c, ["bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco"])
    assert j.status == "ok", j.notes
    for ab in ("xy", "xz", "yx", "yz", "zx", "zy"):
        p = j.parameters[f"Ca_{ab}"]
        assert abs(p.value - truth[f"Ca_{ab}"]) < 4 * p.u, (ab, p, truth[f"Ca_{ab}"])


@pytest.mark.parametrize("noise", ["residuals", "sd"])
def test_the_tilt_test_holds_its_level_on_a_level_bench(noise):
    """150 tilt-free six-face campaigns: the share of p < 0.1 within three binomial SDs of 0.1
    (with the noise from 5 residual dof the statistic is F, not chi2: the chi2 test rejected 37 %)."""
    n = 150
    p = np.array([fit_classical(_six(seed, (0.0, 0.0))[0], noise=noise).fit["tilt_leak"]["value"]
                  for seed in range(n)])
    k = int(np.sum(p < 0.1))
    assert abs(k - 0.1 * n) < 3 * math.sqrt(n * 0.1 * 0.9), k
    assert np.sum(p < 1e-3) <= 2


def test_the_default_plan_cancels_the_tilt_and_has_no_tilt_gate():
    text, _ = simulate_campaign(np.random.default_rng(3), tilt_arcsec=(50.0, -30.0))
    r = fit_classical(parse_bench_csv(text))
    assert r.status == "ok" and "tilt_leak" not in r.fit


# -- a large tilt on half-turn pairs: K and S divided by cos(tilt) ------------------------------------
@pytest.mark.parametrize("seed", range(4))
def test_a_large_tilt_is_estimated_and_k_and_s_are_multiplied_back(seed):
    """Eq. 2 divides K and S by cos(tilt) (the vertical gravity is g cos(tilt)): an outside probe's
    bench tilted 0.2-0.5 deg left K 20-35 ppm, up to 27 u, high with status ok. The tilt is now
    estimated at each setpoint from the redundant positions (inverse-covariance weighting of the
    three outputs' estimates) and K, S multiplied by its cosine: every K and S within 4 u, the
    tilt within 5" of the truth at each setpoint, and the correction (1 - cos) larger than 4 u(K)
    for at least one axis (without it the answer was wrong)."""
    tilt = tuple(np.random.default_rng(900 + seed).uniform(-1800, 1800, 2))
    text, truth = simulate_campaign(np.random.default_rng(seed), tilt_arcsec=tilt)
    r = fit_classical(parse_bench_csv(text))
    assert r.status == "ok"
    true_tilt = math.hypot(*tilt)
    for b in r.extra["per_setpoint"]:
        assert abs(b["tilt_arcsec"] - true_tilt) < 5.0, (b["setpoint_C"], b["tilt_arcsec"], true_tilt)
    factor = 1.0 - math.cos(math.radians(true_tilt / 3600.0))
    for a in "xyz":
        for q in ("K", "S"):
            p = r[f"{q}_{a}"]
            assert abs(p.value - truth[f"{q}_{a}"]) < 4 * p.u, (q, a, p, truth[f"{q}_{a}"])
    assert max(factor * abs(r[f"K_{a}"].value) / r[f"K_{a}"].u for a in "xyz") > 4 or true_tilt < 1500
    assert any("K and S were multiplied by cos(tilt)" in n for n in r.notes) == (true_tilt > 300)


def test_a_level_bench_changes_nothing():
    """No tilt: the estimated tilt is the noise's (a few arcsec at most) and K moves by < 1e-9."""
    text, truth = simulate_campaign(np.random.default_rng(3), tilt_arcsec=(0.0, 0.0))
    r = fit_classical(parse_bench_csv(text))
    assert r.status == "ok"
    assert all(b["tilt_arcsec"] < 5.0 for b in r.extra["per_setpoint"])
    assert not any("cos(tilt)" in n for n in r.notes)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_six_faces_at_one_setpoint_take_the_noise_from_the_sd_columns(seed):
    """Six faces at one setpoint leave 1 residual dof per accelerometer. An outside probe: the residual
    estimate was 0.016 of the declared noise on x, the angles' u 100 times too small, |z| up to 80 on a
    level bench and 448 with a 9 arcsec tilt that the tilt test, F(2, 1), could not see: status ok 10 of
    10. Now the noise is the sd columns' (classical.MIN_RESIDUAL_DOF), said in a note: level, every
    parameter within 4 u and ok; tilted by (8, -5) arcsec, refused by the tilt test (chi2)."""
    text, truth = simulate_campaign(np.random.default_rng(seed), positions=SIX, setpoints_C=(20,))
    r = fit_classical(parse_bench_csv(text))
    assert r.fit["noise_source"] == "sd" and any("fewer than 3" in n for n in r.notes), r.notes
    assert r.status == "ok", r.notes
    z = [abs(r.parameters[n].value - truth[n]) / r.parameters[n].u for n in r.parameters if n in truth]
    assert len(z) == 12 and max(z) < 4.0, z
    text, _ = simulate_campaign(np.random.default_rng(seed), positions=SIX, setpoints_C=(20,), tilt_arcsec=(8.0, -5.0))
    r = fit_classical(parse_bench_csv(text))
    assert r.status == "model_mismatch" and r.fit["tilt_leak"]["passed"] is False, r.fit["tilt_leak"]


def test_the_summary_states_u_from_residuals_on_their_dof():
    """The 12 positions at one setpoint: 6 residual dof per accelerometer, so the summary's U is
    t(6) u = 2.52 u (95.45 %), not 2 u (an outside probe: 87 % of 480 parameters within 2 u). Since
    2026-12-02 each parameter's budget holds its dof (its line's where the Birge ratio widened it)."""
    from triadcal.reports.summary import summary_text

    text, _ = simulate_campaign(np.random.default_rng(4), setpoints_C=(20,))
    r = fit_classical(parse_bench_csv(text))
    assert r.fit["noise_source"] == "residuals" and r.fit["residual_dof"] == [6, 6, 6]
    s = summary_text(r)
    assert all(p.uncertainty["k"] == pytest.approx(2.5174, abs=1e-3) for p in r.parameters.values())
    assert "  K_x " in s and " 2.52  g/V" in s and "k from Student's t on each parameter's dof" in s, s


def test_six_faces_at_five_setpoints_test_the_tilt_against_the_sd_columns_when_the_residuals_agree():
    """Six faces at five setpoints leave 5 residual dof per accelerometer; the tilt test on them, F(2, 5),
    passed a 9.4 arcsec tilt with the angles 10-17 u off in 5 of 10 campaigns (an outside probe). Where the
    residuals show no significant excess over the sd columns (no bench error to hold), the test is the
    chi2 against the sd columns: the tilt (8, -5) arcsec refused in 5 of 5; a level bench passed in 20
    of 20 (p uniform: about 0.1 % refused at the gates' 1e-3); a level bench with 5 arcsec positioning
    errors, whose residuals exceed the sd (tested on their own F), passed too."""
    for seed in range(1, 6):
        c, _ = _six(seed, (8.0, -5.0))
        r = fit_classical(c)
        assert r.status == "model_mismatch" and r.fit["tilt_leak"]["passed"] is False, (seed, r.fit["tilt_leak"])
    for seed in range(1, 21):
        c, _ = _six(100 + seed, (0.0, 0.0))
        assert fit_classical(c).fit["tilt_leak"]["passed"] is True, seed
    for seed in range(1, 4):
        text, _ = simulate_campaign(np.random.default_rng(200 + seed), positions=SIX, sigma_position_arcsec=5.0)
        r = fit_classical(parse_bench_csv(text))
        assert r.fit["tilt_leak"]["passed"] is True and "F(" in r.fit["tilt_leak"]["reason"], r.fit["tilt_leak"]
