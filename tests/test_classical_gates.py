"""The classical method (eq. 2-3) behind the same answer gates as the joint fit, and its own
redundancy check. Mutations are made by hand from the built-in example; the redundancy
statistic's distribution is checked on readings generated here from eq. 1 directly (not by
triadcal's simulator), where theory says it is chi^2 with the plan's residual dof."""

import copy
import re

import numpy as np
import pytest
from scipy import stats

from triadcal.cli import main
from triadcal.estimation.classical import ClassicalPlanError, fit_classical
from triadcal.models.campaign import nominal_gravity


def _notes(r):
    return " | ".join(r.notes)


def test_example_is_ok_with_a_passing_redundancy_check(example):
    r = fit_classical(example)
    assert r.status == "ok", _notes(r)
    red = r.fit["redundancy"]
    assert red["passed"] is True and 0.7 < red["value"] < 1.3
    assert {o["gate"] for o in r.extra["gates"]["outcomes"]} >= {"finite", "scale", "angles", "redundancy"}


def test_swapped_columns_are_refused_with_a_hint(example):
    c = copy.deepcopy(example)
    c.w[:, [0, 1]] = c.w[:, [1, 0]]
    r = fit_classical(c)
    assert r.status == "angle_out_of_range", _notes(r)
    assert abs(r["Ca_xy"].value) > 1e5          # ~ 1 rad = 206264 arcsec: the gate, not the value, decides
    assert "follows gravity along y, not x" in _notes(r)


def test_an_inverted_output_gives_a_negative_scale_not_a_flipped_row(example):
    """Hand-derived: w_z -> -w_z makes W_z^b -> -W_z^b; with the sign of the diagonal
    element carried into K (eq. 1, cos > 0), K_z -> -K_z exactly while S_z = K_z m and the
    row of Ca are unchanged."""
    ref = fit_classical(example)
    c = copy.deepcopy(example)
    c.w[:, 2] *= -1
    r = fit_classical(c)
    assert r.status == "unphysical_scale", _notes(r)
    assert r["K_z"].value == pytest.approx(-ref["K_z"].value, rel=1e-12)
    assert r["S_z"].value == pytest.approx(ref["S_z"].value, rel=1e-9)
    for n in ("Ca_zx", "Ca_zy"):
        assert r[n].value == pytest.approx(ref[n].value, rel=1e-9)
    assert "w_z falls when its axis points up" in _notes(r)


@pytest.mark.parametrize("how", ["stuck", "constant", "nan"])
def test_stuck_or_constant_readings_are_refused_in_one_line(example, tmp_path, capsys, how):
    from triadcal.io.bench_csv import write_bench_csv

    c = copy.deepcopy(example)
    if how == "stuck":
        c.w[:, 1] = 0.25
    elif how == "constant":
        c.w[:] = 0.25
    else:
        c.w[3, 0] = np.nan
    if how != "nan":
        with pytest.raises(ClassicalPlanError, match="stuck channel"):
            fit_classical(c)
        path = tmp_path / "stuck.csv"
        write_bench_csv(c, path)
        code = main(["fit", str(path), "--method", "classical"])
        out, err = capsys.readouterr()
        assert code != 0 and "Traceback" not in out + err and "stuck channel" in err
        assert len(err.strip().splitlines()) == 1
    else:
        with pytest.raises(ClassicalPlanError, match="finite"):
            fit_classical(c)


def _eq1_campaign(example, rng, sigma):
    """Readings from eq. 1 (W = K^-1 (Ca g + S)) at the example's bench angles, plus Gaussian
    noise of the standard deviation the sd columns declare."""
    c = copy.deepcopy(example)
    g = nominal_gravity(c.axis1_deg, c.axis2_deg).reshape(-1, 3) * c.gravity_g
    a = 1e-3
    Ca = np.array([[1.0, a, -2 * a], [0.5 * a, 1.0, a], [-a, 1.5 * a, 1.0]])
    K, S = np.array([0.9, 1.1, 1.05]), np.array([1e-3, -2e-3, 5e-4])
    c.w = (g @ Ca.T + S) / K + rng.normal(0, sigma, size=g.shape)
    c.n_samples = np.full(len(g), 100)
    c.sd = np.full(g.shape, sigma * 10.0)      # sd of a sample; the mean's sd = sd / sqrt(100) = sigma
    return c


def test_redundancy_statistic_is_chi2_under_the_model(example):
    """Under eq. 1 with known Gaussian noise the redundancy chi^2 is chi^2(dof) exactly
    (weighted linear least squares): its p-values over 60 seeds are uniform (KS p > 0.001) and
    chi2/dof averages 1 within 4 standard errors (sd of chi2/dof is sqrt(2/dof))."""
    rng = np.random.default_rng(20261124)
    ratios, ps = [], []
    for _ in range(60):
        r = fit_classical(_eq1_campaign(example, rng, 2e-5), noise="sd")
        red = r.fit["redundancy"]
        dof, p = re.search(r"; (\d+) dof, p = ([0-9.e+-]+)", red["reason"]).groups()
        ratios.append(red["value"])
        ps.append(float(p))
    dof = int(dof)
    assert stats.kstest(ps, "uniform").pvalue > 1e-3
    assert abs(np.mean(ratios) - 1) < 4 * np.sqrt(2 / dof) / np.sqrt(len(ratios))


def test_a_mislabelled_position_fails_the_redundancy_check(example):
    """One visit whose readings belong to the opposite position (a mislabelled plan row):
    eq. 2 still forms every quantity, but the redundant positions disagree far beyond the noise."""
    rng = np.random.default_rng(7)
    c = _eq1_campaign(example, rng, 2e-5)
    c.w[0] = -c.w[0]
    r = fit_classical(c)
    # the redundancy gate fails, naming the position; the outlier also inflates the residual noise
    # so much that an angle is no longer determined, which (by precedence) may set the status
    assert r.status in ("inconsistent_redundancy", "unidentifiable"), _notes(r)
    assert r.fit["redundancy"]["passed"] is False and "position P" in r.fit["redundancy"]["reason"]


def test_scatter_is_tested_against_the_noise_the_uncertainties_assume(example):
    """Bench positioning errors (here: extra Gaussian scatter 3x the output noise, made by hand)
    inflate the scatter over the sd columns' noise by ~10. With u from the residuals (default)
    that is reported, not refused; with u from the sd columns (noise='sd') the u would be
    ~3x too small, so the gate refuses."""
    rng = np.random.default_rng(3)
    c = _eq1_campaign(example, rng, 2e-5)
    c.w = c.w + rng.normal(0, 6e-5, size=c.w.shape)
    r = fit_classical(c)
    assert r.status == "ok" and "informative only" in r.fit["redundancy"]["reason"]
    assert 7 < r.fit["redundancy"]["value"] < 13
    r = fit_classical(c, noise="sd")
    assert r.status == "inconsistent_redundancy", _notes(r)


def test_without_known_noise_only_the_outlier_test_runs(example):
    c = copy.deepcopy(example)
    c.sd, c.n_samples = None, None
    c.metadata.pop("Q_V2s", None)
    r = fit_classical(c)
    assert r.status == "ok"
    assert "scatter not testable" in r.fit["redundancy"]["reason"]


def _independent(tmp_path, name, **kw):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_bench import simulate_campaign
    from triadcal.io.bench_csv import read_bench_csv

    text, _ = simulate_campaign(np.random.default_rng(1), setpoints_C=(-40, -10, 20, 50, 80, 50, 20, -10, -40), **kw)
    path = tmp_path / f"{name}.csv"
    path.write_text(text, encoding="utf-8")
    return fit_classical(read_bench_csv(path))


def test_a_thermal_line_the_values_do_not_follow_is_said_with_its_number(tmp_path, example):
    """The paper's straight line in temperature widens its u by the Birge ratio when the
    per-setpoint values scatter beyond their uncertainty; which lines that happened to, by how
    much and why is said in a note, not left in fit.chi2_dof_by_parameter. Made another way: the
    independent bench (no code of triadcal.models) with a 40 ug step of the y bias at hour 20 --
    only S_y's line is named, with its chi2/dof -- and with nothing added -- no note. The
    example's hysteresis of the angles names the six angles' lines, and nothing else."""
    step = _independent(tmp_path, "step", extra_bias=lambda k, t, T, G, d: np.array(
        [0.0, 40e-6 if t > 20 * 3600.0 else 0.0, 0.0]))
    note = [n for n in step.notes if "do not lie on a straight line" in n]
    assert len(note) == 1, _notes(step)
    listed = re.findall(r"(\w+_\w+) chi2/dof ([\d.e+]+)", note[0])
    assert [n for n, _ in listed] == ["S_y"], note
    assert float(listed[0][1]) == pytest.approx(step.fit["chi2_dof_by_parameter"]["S_y"], rel=1e-2)
    assert step.fit["chi2_dof_by_parameter"]["S_y"] > 10
    assert f"u widened x{np.sqrt(step.fit['chi2_dof_by_parameter']['S_y']):.3g}" in note[0]

    clean = _independent(tmp_path, "clean")
    assert not [n for n in clean.notes if "straight line" in n], _notes(clean)

    ex = fit_classical(example)
    note = [n for n in ex.notes if "do not lie on a straight line" in n]
    assert len(note) == 1
    assert {n for n, _ in re.findall(r"(\w+_\w+) chi2/dof ([\d.e+]+)", note[0])} == {
        f"Ca_{ab}" for ab in ("xy", "xz", "yx", "yz", "zx", "zy")}


def test_one_branch_only_says_the_hysteresis_is_unseen(tmp_path):
    """An outside probe: 20 degC (no history) then 60 degC (heating) with an angle hysteresis of
    2-6 arcsec gave the classical angle tempcos 3.9-6.4 u off, status ok, no word (the joint fit
    held h at 0 and said so for the angles only). Made with the independent bench: on a heating
    sweep the note says the hysteresis is not seen and what it moves; on both branches (the lines'
    scatter shows it) there is no such note; the joint fit's note names the tempcos as well."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_bench import default_truth, simulate_campaign
    from triadcal.estimation.joint import fit_joint
    from triadcal.io.bench_csv import read_bench_csv
    from triadcal.models.effects import DEFAULT_EFFECTS

    truth = default_truth(np.random.default_rng(3))
    truth.update({f"Ca_{ab}_hysteresis": 5.0 for ab in ("xy", "xz", "yx", "yz", "zx", "zy")})
    out = {}
    for name, sp in (("heating", (20.0, 60.0)), ("both", (20.0, 60.0, 20.0))):
        text, _ = simulate_campaign(np.random.default_rng(1), truth=truth, setpoints_C=sp,
                                    hysteresis={"form": "offset"})
        path = tmp_path / f"{name}.csv"
        path.write_text(text, encoding="utf-8")
        out[name] = read_bench_csv(path)
    note = [n for n in fit_classical(out["heating"]).notes if "hysteresis of the angles is not seen" in n]
    assert len(note) == 1 and "visited on heating only (and at steady temperatures)" in note[0], note
    assert "the tempcos up to h over the span" in note[0]
    assert not [n for n in fit_classical(out["both"]).notes if "is not seen" in n]
    joint = fit_joint(out["heating"], DEFAULT_EFFECTS)
    assert [n for n in joint.notes if n.startswith("Ca_xy_hysteresis not estimated") and "angle tempcos take up h" in n]


def test_branches_along_the_temperatures_say_what_a_hysteresis_moves(tmp_path):
    """An outside probe: a round trip 20 60 80 20 -20 -40 20 degC (hot setpoints reached by heating,
    cold ones by cooling, 20 on both), h = 3 arcsec on every angle: the classical angle tempcos came
    out -2.9 u on average (coverage 0.09), status ok, no word (both branches were visited, so the
    one-branch note did not apply). Made with the independent bench: the stated move per arcsec,
    times h, predicts each tempco's shift against the same campaign without hysteresis (within
    0.5 u + 25 %), and the note names them; every setpoint on both branches: no note (the lines'
    scatter shows the hysteresis)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_bench import default_truth, simulate_campaign
    from triadcal.io.bench_csv import read_bench_csv

    angles = ("xy", "xz", "yx", "yz", "zx", "zy")
    truth = default_truth(np.random.default_rng(3))
    fits = {}
    for name, sp, h in (("trip", (20.0, 60.0, 80.0, 20.0, -20.0, -40.0, 20.0), 3.0),
                        ("flat", (20.0, 60.0, 80.0, 20.0, -20.0, -40.0, 20.0), 0.0),
                        ("both", (20.0, 50.0, 80.0, 50.0, 20.0, -10.0, -40.0, -10.0, 20.0), 3.0)):
        t = dict(truth, **{f"Ca_{ab}_hysteresis": h for ab in angles})
        text, _ = simulate_campaign(np.random.default_rng(1), truth=t, setpoints_C=sp, hysteresis={"form": "offset"})
        path = tmp_path / f"{name}.csv"
        path.write_text(text, encoding="utf-8")
        fits[name] = fit_classical(read_bench_csv(path))
    trip, flat = fits["trip"], fits["flat"]
    sens = trip.fit["hysteresis_sensitivity"]
    for ab in angles:
        n = f"Ca_{ab}_tempco"
        moved = (trip[n].value - flat[n].value) / trip[n].u
        predicted = sens[f"Ca_{ab}"]["move_u_per_arcsec"] * 3.0
        assert abs(moved - predicted) < 0.5 + 0.25 * abs(predicted), (n, moved, predicted)
        assert abs(predicted) > 1.0
    note = [n for n in trip.notes if "a thermal hysteresis of the angles tilts their lines" in n]
    assert note and "Ca_xy_tempco by" in note[0] and "4-60 arcsec" in note[0], trip.notes
    assert not [n for n in fits["both"].notes if "tilts their lines" in n]


def test_a_curvature_the_lines_cannot_show_is_said_with_its_move(tmp_path):
    """An outside probe: curvatures of 0.0007 arcsec/degC2 (angles), 0.005 ppm/degC2 (K), 0.01
    ug/degC2 (S) on a round trip 20 60 80 20 -20 -40 20 degC moved the values at 20 degC by about 2.2 u
    (coverage 0.47-0.63; 26 of 27 values beyond 3 u unnamed), status ok. Made with the independent
    bench (Horner's polynomial): the stated move per unit of curvature predicts the shift of Ca_xy
    against the same campaign without it (within 10 %), and the note says how far a curvature the
    lines cannot show would move the values."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_bench import default_truth, simulate_campaign
    from triadcal.io.bench_csv import read_bench_csv

    truth = default_truth(np.random.default_rng(5))
    sp = (20.0, 60.0, 80.0, 20.0, -20.0, -40.0, 20.0)
    fits = {}
    for name, c2 in (("bent", 0.0007), ("straight", 0.0)):
        text, _ = simulate_campaign(np.random.default_rng(2), truth=dict(truth, Ca_xy_tempco2=c2), setpoints_C=sp)
        path = tmp_path / f"{name}.csv"
        path.write_text(text, encoding="utf-8")
        fits[name] = fit_classical(read_bench_csv(path))
    bent, straight = fits["bent"], fits["straight"]
    curv = straight.fit["curvature_sensitivity"]["Ca_xy"]
    moved = bent["Ca_xy"].value - straight["Ca_xy"].value                     # arcsec
    assert moved == pytest.approx(curv["value_move_per_c2"] * 0.0007, rel=0.1), (moved, curv)
    assert moved / straight["Ca_xy"].u > 1.5                                  # the probe's few u
    assert curv["unseen_value_u"] > 1.0
    note = [n for n in straight.notes if n.startswith("the thermal lines are straight by the method")]
    assert note and "would move the values at 20 degC by up to" in note[0], straight.notes
