"""The lab's systematic errors as Type B (issue 16): sensitivities derived by hand, checked
against refits of data made another way (tests/independent_bench.py), the budget's k, the
Monte Carlo against a 10^6-draw reference, the results file and the certificate."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats

from independent_bench import simulate_campaign
from triadcal import api
from triadcal.errors import InputError
from triadcal.io.bench_csv import read_bench_csv
from triadcal.io.lab import LabConfig, load_lab
from triadcal.uncertainty.budget import Budget, BudgetComponent

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")


def _write(tmp_path, name, seed=3, **kw):
    text, truth = simulate_campaign(np.random.default_rng(seed), **kw)
    p = tmp_path / f"{name}.csv"
    p.write_text(text)
    return p, truth


def _c(result, name, source):
    row = next(r for r in result.parameters[name].uncertainty["budget"] if r["source"] == source)
    return row["sensitivity"]


@pytest.fixture(scope="module")
def lab_fit(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("typeb")
    path, truth = _write(tmp, "c")
    return api.fit(path, effects=EFFECTS, lab=LAB_OF_FIT), path, tmp


LAB_OF_FIT = LabConfig(sigma_position_arcsec=1.0, sigma_wobble_arcsec=0.5, encoder_zero_u_arcsec=5.0,
                       mounting_u_arcsec=10.0, local_g_u_ppm=10.0, temperature_uncertainty_C=0.2,
                       voltmeter_gain_u_ppm=20.0, voltmeter_offset_u_V=1e-5, source="test")


def test_sensitivities_are_those_derived_by_hand(lab_fit):
    """A fixture rotation r about IMU z turns G into G - r x G = (Gx + r Gy, Gy - r Gx, Gz):
    Ca_xy gains +r and Ca_yx -r (rows of Ca absorb it). An encoder zero e of axis 1:
    Rz(axis1 + e) M = Rz(axis1) M (M^T Rz(e) M), and M maps the IMU's y onto the platform's z,
    so it is a rotation of the unit about its own y: the pair Ca_xz -1, Ca_zx +1. One of
    axis 2: Rx(axis2 + e) = Rx(e) Rx(axis2) turns gravity in the base frame: tilt_y +1, the
    angles 0. A g larger by e reads as K smaller by e:
    dK/K = -1e-6 per ppm; so does a voltmeter gain; a voltmeter offset o adds K o to S.
    A thermometer reading low by d puts every quantity at T0 off by tempco * d."""
    r, _, _ = lab_fit
    assert _c(r, "Ca_xy", "fixture mounting, about z") == pytest.approx(1.0, abs=1e-3)
    assert _c(r, "Ca_yx", "fixture mounting, about z") == pytest.approx(-1.0, abs=1e-3)
    assert _c(r, "Ca_xz", "fixture mounting, about z") == 0.0
    assert _c(r, "Ca_xz", "encoder zero, axis 1") == pytest.approx(-1.0, abs=1e-3)
    assert _c(r, "Ca_zx", "encoder zero, axis 1") == pytest.approx(1.0, abs=1e-3)
    assert _c(r, "tilt_y", "encoder zero, axis 2") == pytest.approx(1.0, abs=1e-3)
    assert _c(r, "Ca_xy", "encoder zero, axis 2") == pytest.approx(0.0, abs=1e-3)
    for a in "xyz":
        K = r.parameters[f"K_{a}"].value
        assert _c(r, f"K_{a}", "local gravity") == pytest.approx(-K * 1e-6, rel=1e-3)
        assert _c(r, f"K_{a}", f"voltmeter gain, axis {a}") == pytest.approx(-K * 1e-6, rel=1e-3)
        assert _c(r, f"S_{a}", f"voltmeter offset, axis {a}") == pytest.approx(K, rel=1e-3)
    tempco = r.parameters["Ca_xy_tempco"].value
    assert _c(r, "Ca_xy", "thermometers") == pytest.approx(tempco, rel=1e-2)


def test_u_is_the_root_sum_of_squares_of_the_budget(lab_fit):
    r, _, _ = lab_fit
    for name in ("Ca_xy", "K_x", "S_z", "Ca_zx_tempco"):
        p = r.parameters[name]
        rows = p.uncertainty["budget"]
        assert rows[0]["type"] in ("A", "B") and any(x["type"] == "A" for x in rows)
        assert p.u == pytest.approx(math.sqrt(sum(x["contribution"] ** 2 for x in rows)), rel=1e-9)
        assert p.U == pytest.approx(2.0 * p.u, rel=1e-9)    # known noise: dof_eff infinite, k = 2
        assert p.uncertainty["dof_eff"] is None and p.uncertainty["coverage_probability"] == pytest.approx(0.9545, abs=1e-4)
    # the fixture's 10" dominate an angle: u close to 10", not the Type A ~0.5"
    assert 9.9 < r.parameters["Ca_xy"].u < 10.5


def test_linearised_sensitivity_matches_a_refit_of_data_made_another_way(tmp_path):
    """Two campaigns from the independent simulator, the same seed, one with a fixture rotation
    of 10" about y and an encoder zero of axis 1 of 5": the fitted angles move by c * delta."""
    base, _ = _write(tmp_path, "base", seed=7)
    moved, _ = _write(tmp_path, "moved", seed=7, fixture_arcsec=(0.0, 10.0, 0.0), encoder_zero_arcsec=(5.0, 0.0))
    lab = LabConfig(encoder_zero_u_arcsec=5.0, mounting_u_arcsec=10.0, source="t")
    r0, r1 = api.fit(base, effects=EFFECTS, lab=lab), api.fit(moved, effects=EFFECTS, lab=lab)
    for name in ("Ca_xz", "Ca_zx", "Ca_xy", "K_x", "S_y"):
        predicted = 10.0 * _c(r0, name, "fixture mounting, about y") + 5.0 * _c(r0, name, "encoder zero, axis 1")
        shift = r1.parameters[name].value - r0.parameters[name].value
        assert shift == pytest.approx(predicted, abs=0.02 * max(1.0, abs(predicted)) * r0.parameters[name].uncertainty["u_type_a"]
                                      + 1e-3 * abs(predicted)), name


def test_the_non_orthogonality_of_the_bench_is_measured_when_the_lab_declares_it(tmp_path):
    path, _ = _write(tmp_path, "n", seed=11, axes_nonorthogonality_arcsec=8.0)
    without = api.fit(path, effects=EFFECTS)
    assert without.status == "model_mismatch"            # it leaves its trace in the residuals
    r = api.fit(path, effects=EFFECTS, lab=LabConfig(axes_nonorthogonality_u_arcsec=5.0, source="t"))
    assert r.status == "ok" and "bench_nonorthogonality" in r.effects
    p = r.parameters["bench_nonorth"]
    assert abs(p.value - 8.0) < 4 * p.u and p.u < 1.0
    assert any("bench_nonorthogonality added" in n for n in r.notes)


def test_welch_satterthwaite_and_t_factor_by_hand():
    """u_A = 1 with 4 dof and u_B = 1 (infinite): u_c = sqrt 2, nu_eff = u_c^4 / (1/4) = 16,
    k = t_0.97725(16) = 2.167 (JCGM 100 G.4, table G.2: 2.17 for 16 dof at 95.45 %)."""
    b = Budget("x", [BudgetComponent("A", 1.0, 1.0, dof=4, type="A"), BudgetComponent("B", 1.0, 1.0)])
    assert b.dof_eff == pytest.approx(16.0)
    k = stats.t.ppf(0.5 + 0.9545 / 2, 16)
    assert b.effective_k == pytest.approx(k, rel=1e-3) and 2.16 < k < 2.18
    assert b.method == "GUM"


def test_monte_carlo_interval_within_5_percent_of_a_million_draw_reference():
    """A rectangular term of SD 3 with a normal of SD 1 (a fixture bound stated as a maker's
    +-a): JCGM 101's interval from MC_DRAWS draws against 10^6 draws; the rectangle's 95.45 %
    half-width alone would be 0.9545 * sqrt(3) * 3 = 4.96, k u_c = 6.32 overstates it."""
    b = Budget("Ca_xy", [BudgetComponent("fixture", 3.0, 3.0, distribution="rectangular"),
                         BudgetComponent("noise", 1.0, 1.0, type="A")])
    assert b.method == "Monte Carlo"
    ref = b.monte_carlo_U(draws=1_000_000, seed=12345)
    assert b.expanded_U == pytest.approx(ref, rel=0.05)
    assert ref < 2.0 * b.total
    # and a normal budget by Monte Carlo is k u_c with k = 2
    n = Budget("n", [BudgetComponent("a", 3.0, 3.0), BudgetComponent("b", 1.0, 1.0)])
    assert n.monte_carlo_U(draws=1_000_000, seed=1) == pytest.approx(2.0 * n.total, rel=0.01)


def test_arcsine_sd_is_the_stated_u():
    b = Budget("w", [BudgetComponent("wobble", 2.0, 2.0, distribution="arcsine")])
    # an arcsine of SD 2 has half-width 2 sqrt 2: its 95.45 % interval is 2 sqrt 2 sin(pi/2 * 0.9545)
    assert b.monte_carlo_U(draws=400_000, seed=3) == pytest.approx(2 * math.sqrt(2) * math.sin(math.pi / 2 * 0.9545),
                                                                     rel=0.01)


def test_results_file_round_trip_and_reader_validation(lab_fit, tmp_path):
    r, _, _ = lab_fit
    path = tmp_path / "r.json"
    r.save(path)
    from triadcal.estimation.result import CalibrationResult, ResultFormatError

    back = CalibrationResult.load(path)
    assert back.parameters["Ca_xy"].uncertainty["budget"] == r.parameters["Ca_xy"].uncertainty["budget"]
    assert back.parameters["Ca_xy"].U == pytest.approx(r.parameters["Ca_xy"].U)
    doc = json.loads(path.read_text())
    doc["parameters"]["Ca_xy"]["budget"][1]["contribution"] = -1.0
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(ResultFormatError, match=r"parameters\.Ca_xy\.budget\[1\]\.contribution"):
        CalibrationResult.load(bad)
    doc["parameters"]["Ca_xy"]["budget"][1]["contribution"] = 1.0
    doc["parameters"]["Ca_xy"]["U"] = "big"
    bad.write_text(json.dumps(doc))
    with pytest.raises(ResultFormatError, match=r"parameters\.Ca_xy\.U"):
        CalibrationResult.load(bad)


def test_results_file_with_budgets_follows_the_contract(lab_fit, tmp_path):
    from test_results_contract import assert_valid

    r, _, _ = lab_fit
    r.save(tmp_path / "r.json")
    assert_valid(json.loads((tmp_path / "r.json").read_text()), "triadcal.result")


def test_without_a_lab_the_result_says_type_a_only(lab_fit):
    _, path, _ = lab_fit
    r = api.fit(path, effects=EFFECTS)
    assert all(p.U is None and not p.uncertainty for p in r.parameters.values())
    assert any("Type A only" in n for n in r.notes)


def test_voltmeter_on_counts_is_refused(tmp_path):
    from triadcal.uncertainty.typeb import systematic_sources

    with pytest.raises(InputError, match="not volts"):
        systematic_sources(LabConfig(voltmeter_gain_u_ppm=10.0, source="lab.toml"), "count")


def test_lab_file_voltmeter_distribution_and_compare_sections(tmp_path):
    p = tmp_path / "lab.toml"
    p.write_text('[voltmeter]\ninstrument = "DMM"\ngain_u_ppm = 15\noffset_u_V = 2e-6\ndue = 2027-01-01\n'
                 '[fixture]\nmounting_u_arcsec = 3\ndistribution = "rectangular"\n'
                 '[compare]\nshared_equipment = ["bench"]\n')
    lab = load_lab(p)
    assert (lab.voltmeter_gain_u_ppm, lab.voltmeter_offset_u_V) == (15.0, 2e-6)
    assert lab.distributions == {"fixture": "rectangular"} and lab.shared_equipment == ("bench",)
    assert lab.equipment["voltmeter"]["due"] == "2027-01-01"
    p.write_text('[fixture]\nmounting_u_arcsec = 3\ndistribution = "triangular"\n')
    with pytest.raises(InputError, match=r"lab.toml: \[fixture\] distribution = 'triangular'"):
        load_lab(p)
    p.write_text('[compare]\nshared_equipment = ["chamber"]\n')
    with pytest.raises(InputError, match=r"\[compare\] shared_equipment"):
        load_lab(p)


def test_rectangular_fixture_gives_a_monte_carlo_U(tmp_path):
    path, _ = _write(tmp_path, "r", seed=5)
    lab = LabConfig(mounting_u_arcsec=10.0, distributions={"fixture": "rectangular"}, source="t")
    p = api.fit(path, effects=EFFECTS, lab=lab).parameters["Ca_xy"]
    assert p.uncertainty["U_method"] == "Monte Carlo"
    # a rectangle of SD 10 dominates: U near its own 95.45 % half-width sqrt(3) 10 0.9545 = 16.5, not 2 u = 20
    assert 16.0 < p.U < 17.5 and p.uncertainty["k"] < 1.8


def test_certificate_prints_each_parameters_budget(lab_fit, tmp_path):
    from triadcal.reports.certificate import build_certificate
    from triadcal.reports.certificate.html import render_html

    r, path, _ = lab_fit
    cert = build_certificate(r, lab=LAB_OF_FIT, campaign=read_bench_csv(path), plots=False, issue_date="2026-11-25")
    assert cert.issued, cert.reasons
    assert [b.quantity for b in cert.parameter_budgets["Orientation angles"]][:2] == ["Ca_xy", "Ca_xz"]
    assert len(cert.parameter_budgets["Scale factors"]) == 3 and len(cert.parameter_budgets["Biases"]) == 3
    html = render_html(cert)
    assert "data-budget='Orientation angles'" in html and "Effective degrees of freedom" in html
    row = next(x for x in cert.rows if x.name == "Ca_xy")
    assert float(row.U) == pytest.approx(r.parameters["Ca_xy"].U, rel=0.05)
    assert "Type B" in dict(cert.method)["Uncertainty"]
    # the angle budget over the range uses the angle's own rows, not sensitivity-1 rows
    src = {c.source for c in cert.budget.components}
    assert "fixture mounting, about z" in src and "fixture mounting" not in src


def test_sample_with_a_lab_combines_the_posterior_with_type_b(lab_fit):
    """The posterior's SD is the Type A row; u, U, the 95 % interval (draws plus the systematic
    errors drawn, JCGM 101) and the correlation carry the Type B rows; the flags compare
    like with like (no false non-Gaussian flag from a combined least-squares u)."""
    from triadcal.estimation.posterior import sample

    _, path, _ = lab_fit
    lab = LabConfig(sigma_position_arcsec=1.0, sigma_wobble_arcsec=0.5, mounting_u_arcsec=10.0, source="test")
    from triadcal.uncertainty.typeb import systematic_sources

    from triadcal.io.lab import bench_errors_of

    r = sample(path, EFFECTS, ess=300, bench_errors=bench_errors_of(lab), systematics=systematic_sources(lab))
    p = r.parameters["Ca_xy"]
    a = next(x for x in p.uncertainty["budget"] if x["type"] == "A")
    assert p.u == pytest.approx(math.hypot(a["contribution"], 10.0), rel=1e-3)
    iv = r.intervals["Ca_xy"]
    assert iv["type_a_high"] - iv["type_a_low"] < 4 * a["contribution"] * 1.2
    # the combined 95 % interval has the half-width of a normal of SD u (1.96 u) within MC error
    assert (iv["high"] - iv["low"]) / 2 == pytest.approx(1.96 * p.u, rel=0.05)
    assert not r.extra["flags"]["non_gaussian"]
    names = list(r.correlation_names)
    i, j = names.index("Ca_xy"), names.index("Ca_yx")
    assert r.correlation[i, j] < -0.9        # one fixture rotation about z moves both, opposite signs


def test_bench_errors_estimated_from_replicates(example):
    """A plan that visits every position twice per setpoint (360 visits, 180 pairs) with the
    paper's bench (sigma_1 = 5", sigma_2 = 2" per visit): the method-of-moments estimate of
    sigma_1 (wobble at 0.4 sigma_1, the paper's ratio) has a relative SD of about 3 % over seeds
    (10 seeds measured: mean 4.95", SD 0.14"), so each estimate lies within 12 % (4 SD) of 5"
    and the fit with it has chi2/dof near 1; the result says where the figures came from."""
    from triadcal.models.simulate import DEFAULT_PLAN

    plan = dict(DEFAULT_PLAN)
    plan.update({k + "r": v for k, v in DEFAULT_PLAN.items()})
    for seed in (0, 1):
        _, c = api.simulate(effects=("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis",
                                     "position_error"), seed=seed, plan=plan)
        r = api.fit(c, bench_errors_from_replicates=True)
        b = r.fit["bench_errors"]
        assert b["sigma_position_arcsec"] == pytest.approx(5.0, rel=0.12)
        assert "replicates of the plan (180 groups, 360 visits" in b["source"]
        assert r.status == "ok" and 0.85 < r.fit["chi2_dof"] < 1.15
    with pytest.raises(InputError, match="at least 5 are needed"):
        api.fit(example, bench_errors_from_replicates=True)


def test_the_labs_local_gravity_is_the_fits_when_the_data_state_none(tmp_path):
    """Data without a local_g line and a lab file that measured g = 9.8112 m/s^2 (+469 ppm on
    standard g, 464 ppm): the fit takes the lab's g, so K (g per volt) comes out 464 ppm higher
    than with standard g, the g the data were taken at; a file that states another g is refused
    naming both."""
    from triadcal.io.lab import with_lab_gravity

    text, _ = simulate_campaign(np.random.default_rng(4), true_g_m_s2=9.8112)
    text = "\n".join(ln for ln in text.splitlines() if not ln.startswith("# local_g_m_s2")) + "\n"
    p = tmp_path / "nog.csv"
    p.write_text(text)
    lab = LabConfig(local_g_m_s2=9.8112, local_g_u_ppm=10.0, source="lab.toml")
    plain = api.fit(p, effects=EFFECTS)
    with_g = api.fit(p, effects=EFFECTS, lab=lab)
    rel = with_g["K_x"].value / plain["K_x"].value - 1.0
    assert rel * 1e6 == pytest.approx((9.8112 / 9.80665 - 1.0) * 1e6, abs=0.5)
    c = read_bench_csv(p)
    c.metadata["local_g_m_s2"] = "9.80665"
    with pytest.raises(InputError, match="one of them is wrong"):
        with_lab_gravity(c, lab)


def test_a_certificate_under_another_lab_file_is_refused_in_both_directions(lab_fit):
    """An outside probe: a result fitted with a voltmeter got a certificate under a lab file without
    one (its budgets named equipment this lab does not have), and under one with a rectangular
    fixture, or sigma_1 = 60" for the fit's 1"; each is now refused, naming what differs."""
    import dataclasses

    from triadcal.reports.certificate import build_certificate

    r, path, _ = lab_fit
    assert build_certificate(r, lab=LAB_OF_FIT, plots=False, issue_date="2026-11-25").issued
    cases = {
        "without the voltmeter": (dataclasses.replace(LAB_OF_FIT, voltmeter_gain_u_ppm=None, voltmeter_offset_u_V=None),
                                  "does not declare (voltmeter gain, axis x"),
        "rectangular fixture": (dataclasses.replace(LAB_OF_FIT, distributions={"fixture": "rectangular"}),
                                "distribution rectangular in the lab file, normal in the result"),
        "another sigma_1": (dataclasses.replace(LAB_OF_FIT, sigma_position_arcsec=60.0),
                            "sigma_position_arcsec = 60 arcsec, but the result's u holds 1"),
    }
    for what, (lab, says) in cases.items():
        cert = build_certificate(r, lab=lab, plots=False, issue_date="2026-11-25")
        assert not cert.issued and any(says in x for x in cert.reasons), (what, cert.reasons)


def test_the_certificate_takes_a_local_g_within_3u_as_the_fit_does(lab_fit):
    """The fit accepts data whose g lies within 3 u of the lab's; the certificate refused beyond
    1 u, advising a refit that could not change it (an outside probe)."""
    import dataclasses

    from triadcal.reports.certificate import build_certificate

    r, _, _ = lab_fit
    g = r.extra["local_g_m_s2"]
    near = dataclasses.replace(LAB_OF_FIT, local_g_m_s2=g * (1 + 20e-6))          # 2 u
    assert not any("local gravity" in x for x in build_certificate(r, lab=near, plots=False,
                                                                   issue_date="2026-11-25").reasons)
    far = dataclasses.replace(LAB_OF_FIT, local_g_m_s2=g * (1 + 40e-6))           # 4 u
    assert any("local gravity" in x and "3 u" in x
               for x in build_certificate(r, lab=far, plots=False, issue_date="2026-11-25").reasons)
