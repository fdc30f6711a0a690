"""The hysteresis's form chosen by the data (issue 17, item 1): a play (backlash) hysteresis
added to simulated outputs by numpy in this test (its own relay loop on the setpoint path, not
the model's code), against the constant offset; and the offset's data, where the play must not
be chosen."""

from __future__ import annotations

import math

import numpy as np
import pytest

from triadcal import api
from triadcal.estimation.hysteresis_form import fit_hysteresis_form
from triadcal.models.effects.hysteresis import play_branch

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis")
ARCSEC = math.pi / 180 / 3600
H = {"xy": 12.0, "xz": -8.0, "yx": 15.0, "yz": 6.0, "zx": -10.0, "zy": 9.0}   # arcsec, the ak18 preset's


def _own_play(setpoints, r):
    """The test's own backlash on the sequence of setpoints the chamber walks through (the unit
    soaks at each, so the path between two is monotone): y trails a rise by r and leads a fall."""
    y, out = setpoints[0], []
    for x in setpoints:
        if x - y > r:
            y = x - r
        elif y - x > r:
            y = x + r
        out.append((y - x) / r)
    return np.array(out)


def _play_campaign(r, seed):
    """Simulated outputs without hysteresis, then h_ab * b * G_b / K_a added to W_a (first order of
    eq. 1 in an angle), b from the test's own play of the setpoint path."""
    truth, c = api.simulate(effects=EFFECTS[:-1], seed=seed)
    order = np.argsort(c.time_s, kind="stable")
    sp = c.setpoint_C[order]
    changes = np.flatnonzero(np.r_[True, np.diff(sp) != 0])
    b_sp = _own_play(sp[changes], r)
    b = np.empty(c.n_visits)
    b[order] = b_sp[np.searchsorted(changes, np.arange(len(sp)), side="right") - 1]
    a1, a2 = np.radians(c.axis1_deg), np.radians(c.axis2_deg)
    # nominal gravity of the 12 positions in the IMU frame, written out: Rx(a2)^T e_z = (0, sin a2,
    # cos a2); Rz(a1)^T turns it to (sin a1 sin a2, cos a1 sin a2, cos a2); M^T maps platform
    # (x, y, z) to IMU (x, z, -y): G = (sin a1 sin a2, cos a2, -cos a1 sin a2)
    G = np.stack([np.sin(a1) * np.sin(a2), np.cos(a2), -np.cos(a1) * np.sin(a2)], axis=1)
    w = c.w.copy()
    for i, a in enumerate("xyz"):
        K = truth.parameters[f"K_{a}"]
        for j, bb in enumerate("xyz"):
            if a != bb:
                w[:, i] += H[a + bb] * ARCSEC * b * G[:, j] / K
    from dataclasses import replace

    return truth, replace(c, w=w), b


def test_gravity_written_out_matches_the_kinematics():
    from triadcal.models.campaign import nominal_gravity

    a1 = np.array([0, 180, 0, 180, 90, 270, 270, 90, 180, 0, 0, 180.0])
    a2 = np.array([0, 0, 180, 180, 90, 270, 90, 270, 90, 270, 90, 270.0])
    r1, r2 = np.radians(a1), np.radians(a2)
    mine = np.stack([np.sin(r1) * np.sin(r2), np.cos(r2), -np.cos(r1) * np.sin(r2)], axis=1)
    assert np.allclose(mine, nominal_gravity(a1, a2), atol=1e-12)


@pytest.mark.parametrize("r, seed", [(10.0, 1), pytest.param(30.0, 2, marks=pytest.mark.slow)])
def test_a_play_hysteresis_is_chosen_with_its_width_and_the_angles_come_right(r, seed):
    truth, c, _ = _play_campaign(r, seed)
    off, *_ = fit_hysteresis_form(c, EFFECTS, "offset", return_problem=True)
    res, _, _, used = fit_hysteresis_form(c, EFFECTS, "auto")
    h = res.fit["hysteresis"]
    assert h["form"] == "play", h["criterion"]
    lo, hi = h["half_width_interval_C"]
    assert lo - 2.5 <= r <= hi + 2.5, (r, h["half_width_C"], h["half_width_interval_C"])
    assert res.status == "ok" and 0.8 < res.fit["chi2_dof"] < 1.25
    for ab, v in H.items():
        p = res.parameters[f"Ca_{ab}_hysteresis"]
        assert abs(p.value - v) < 3.5 * p.u, (ab, p.value, p.u)
        q = res.parameters[f"Ca_{ab}"]
        assert abs(q.value - truth.parameters[f"Ca_{ab}"]) < 3.5 * q.u
    # the offset form misses it: a larger chi^2
    assert off.fit["chi2_dof"] > res.fit["chi2_dof"] + 0.2


def test_offset_data_keep_the_offset_form():
    truth, c = api.simulate(effects=EFFECTS, seed=4)
    res, _, _, used = fit_hysteresis_form(c, EFFECTS, "auto")
    assert res.fit["hysteresis"]["form"] == "offset", res.fit["hysteresis"]["criterion"]
    assert used is c


def test_play_branch_limits():
    T = np.array([20.0, 35, 55, 70, 55, 35, 20, 5, -10])
    b = play_branch(T, 5.0, "mid")
    assert b[1] == -1.0 and b[3] == -1.0 and b[4] == 1.0 and b[-1] == 1.0
    wide = play_branch(T, 60.0, "mid")     # from the middle a rise of r saturates; these rises and falls stay under r
    assert np.all(np.abs(wide[1:]) < 1.0) and np.any(wide > 0)
    with pytest.raises(ValueError):
        play_branch(T, 0.0)


# -- Prandtl-Ishlinskii (issue 17, item 1) ------------------------------------------------------
def _own_pi(setpoints, widths, weights):
    """The test's own PI branch: its own relay play of each width, weighted and normalised."""
    return sum(w * _own_play(setpoints, r) for r, w in zip(widths, weights)) / sum(weights)


def test_pi_branch_is_the_weighted_sum_of_plays():
    from triadcal.models.effects.hysteresis import pi_branch
    from triadcal.models.thermal_history import play_operator, prandtl_ishlinskii

    T = np.array([20.0, 35, 55, 70, 55, 35, 20, 5, -10, -25, -40, -25, -10, 5, 20])
    b = pi_branch(T, [3.0, 30.0], [0.25, 0.75])
    assert np.allclose(b, _own_pi(T, [3.0, 30.0], [0.25, 0.75]), atol=1e-12)
    assert np.all(np.abs(b) <= 1.0) and np.allclose(pi_branch(T, [10.0], [2.0]), play_branch(T, 10.0))
    # the PI operator: h b = sum_i p_i (F_ri[T] - T) with p_i = h w_i / (r_i sum w)
    h, r, w = 7.0, np.array([3.0, 30.0]), np.array([0.25, 0.75])
    p = h * w / (r * w.sum())
    assert np.allclose(h * b, prandtl_ishlinskii(T, r, p) - p.sum() * T, atol=1e-12)
    assert np.allclose(prandtl_ishlinskii(T, [5.0], [1.0]), play_operator(T, 5.0))
    with pytest.raises(ValueError):
        pi_branch(T, [3.0, 30.0], [-0.1, 1.1])
    with pytest.raises(ValueError):
        prandtl_ishlinskii(T, [3.0], [-1.0])


def _pi_campaign(widths, weights, seed):
    truth, c = api.simulate(effects=EFFECTS[:-1], seed=seed)
    order = np.argsort(c.time_s, kind="stable")
    sp = c.setpoint_C[order]
    changes = np.flatnonzero(np.r_[True, np.diff(sp) != 0])
    b_sp = _own_pi(sp[changes], widths, weights)
    b = np.empty(c.n_visits)
    b[order] = b_sp[np.searchsorted(changes, np.arange(len(sp)), side="right") - 1]
    a1, a2 = np.radians(c.axis1_deg), np.radians(c.axis2_deg)
    G = np.stack([np.sin(a1) * np.sin(a2), np.cos(a2), -np.cos(a1) * np.sin(a2)], axis=1)
    w = c.w.copy()
    for i, a in enumerate("xyz"):
        for j, bb in enumerate("xyz"):
            if a != bb:
                w[:, i] += 3 * H[a + bb] * ARCSEC * b * G[:, j] / truth.parameters[f"K_{a}"]
    from dataclasses import replace

    return truth, replace(c, w=w)


def test_a_pi_hysteresis_is_chosen_over_one_play_and_the_angles_come_right():
    """Plays of 3 and 30 degC, equal weights, h three times the AK-18 preset's (the A-18's size)."""
    truth, c = _pi_campaign([3.0, 30.0], [0.5, 0.5], seed=7)
    res, _, _, used = fit_hysteresis_form(c, EFFECTS, "auto")
    h = res.fit["hysteresis"]
    assert h["form"] == "pi", (h["criterion"], h["criterion_pi"])
    assert h["chi2_play"] - h["chi2_pi"] > 9.21 and h["chi2_offset"] > h["chi2_play"]
    assert 0.8 < res.fit["chi2_dof"] < 1.25
    for ab, v in H.items():
        p = res.parameters[f"Ca_{ab}_hysteresis"]
        assert abs(p.value - 3 * v) < 3.5 * p.u, (ab, p.value, p.u)
        q = res.parameters[f"Ca_{ab}"]
        assert abs(q.value - truth.parameters[f"Ca_{ab}"]) < 3.5 * q.u


def test_play_data_keep_the_play_and_the_profile_matches_the_exact_fit():
    from triadcal.estimation import hysteresis_form as hf
    from triadcal.estimation.joint import fit_joint

    _, c, _ = _play_campaign(10.0, 1)
    res, *_ = fit_hysteresis_form(c, EFFECTS, "auto")
    assert res.fit["hysteresis"]["form"] == "play", res.fit["hysteresis"]["criterion_pi"]
    # the one-step profile against the full nonlinear refit, at a few candidates
    off = fit_joint(c, EFFECTS, return_problem=True)
    prof = hf._Profile(c, off, EFFECTS)
    play, pi = hf._profiles(prof, (3.0, 10.0, 30.0), True)
    for p in play[::4]:
        exact = hf._chi2(fit_joint(hf.with_play(c, p["half_width_C"], p["start"]), EFFECTS, return_problem=True))
        assert abs(p["chi2"] - exact) < 0.05, (p, exact)
    for p in pi[::20]:
        exact = hf._chi2(fit_joint(hf.with_pi(c, p["half_widths_C"], p["weights"], p["start"]), EFFECTS,
                                   return_problem=True))
        assert abs(p["chi2"] - exact) < 0.05, (p, exact)


def test_pi_form_refusals():
    from triadcal.errors import InputError

    _, c = api.simulate(effects=EFFECTS, seed=4)
    with pytest.raises(InputError, match="pi form"):
        fit_hysteresis_form(c, EFFECTS, "pi", half_width_C=5.0)
    with pytest.raises(InputError, match="choose one of"):
        fit_hysteresis_form(c, EFFECTS, "preisach")


def test_a_play_between_the_grid_points_is_fitted_at_its_own_width_and_not_named_a_pi(tmp_path):
    """An outside probe: a play of r = 17 degC (between the grid's 15 and 20) was fitted at 15 with
    the interval "15..15", Ca_xy_hysteresis 5.6 u off with status ok, and --hysteresis-form auto
    named a PI of the two neighbouring grid plays. Data of tests/independent_bench.py (its own
    backlash on a path of turns smaller than 2r, so r shows)."""
    from independent_bench import simulate_campaign

    rng = np.random.default_rng(17)
    truth = {**{f"K_{a}": 1.0 for a in "xyz"}, **{f"S_{a}": 0.0 for a in "xyz"},
             **{f"Ca_{ab}": 40.0 for ab in H}, **{f"Ca_{ab}_tempco": 0.1 for ab in H},
             **{f"K_{a}_tempco": 10.0 for a in "xyz"}, **{f"S_{a}_tempco": 5.0 for a in "xyz"},
             **{f"Ca_{ab}_hysteresis": 3.0 * v for ab, v in H.items()}}
    text, truth = simulate_campaign(rng, truth=truth, setpoints_C=(20, 40, 60, 35, 10, 30, 55, 70, 40, 5, -15, 20),
                                    noise_sd=2e-4, hysteresis={"form": "play", "half_widths_C": [17.0], "start": "mid"})
    (tmp_path / "p.csv").write_text(text)
    res = api.fit(tmp_path / "p.csv", effects=EFFECTS, hysteresis_form="auto")
    h = res.fit["hysteresis"]
    assert h["form"] == "play", (h["form"], h.get("criterion_pi"))
    lo, hi = h["half_width_interval_C"]
    assert lo < hi and lo - (hi - lo) <= 17.0 <= hi + (hi - lo), (h["half_width_C"], lo, hi)
    for ab in H:
        p = res.parameters[f"Ca_{ab}_hysteresis"]
        assert abs(p.value - truth[f"Ca_{ab}_hysteresis"]) < 3.5 * p.u, (ab, p.value, p.u)


def test_a_heating_only_path_says_the_angles_are_the_heating_branchs(tmp_path):
    """An outside probe: on a heating-only path the hysteresis is held at 0 (it cannot be
    measured) and the angles are the heating branch's, 33 u from the mid-line, status ok; the note
    now says whose the angles are."""
    from independent_bench import simulate_campaign

    text, _ = simulate_campaign(np.random.default_rng(2), setpoints_C=(-20, 20, 60))
    (tmp_path / "h.csv").write_text(text)
    r = api.fit(tmp_path / "h.csv", effects=EFFECTS)
    assert any("the angles are then those of the heating branch, not the mid-line" in n for n in r.notes), r.notes
