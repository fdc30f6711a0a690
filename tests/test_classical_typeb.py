"""The lab's systematic errors propagated into a classical result (estimation/classical_typeb.py).

Before, a classical result had Type A u only and its certificate was refused under a lab file
with systematic errors; its eq. 4-7 budget put the bench non-orthogonality and the axis-2 encoder
zero at sensitivity 1 into the angles, where the half-turn pairs cancel them (a hand derivation
gives 0). Checked here on data made another way (tests/independent_bench.py: scipy rotations, no
code of triadcal's model):

- each sensitivity of the result's budget equals the change of the classical estimate when the
  independent simulator puts that error into the data (same seed, same noise: the difference is
  the error's alone; the estimate is linear in it to 1e-4 at 20");
- the hand-derived values: a rotation about IMU y (the encoder zero of axis 1, the fixture about
  y) goes one to one into Ca_zx and Ca_xz with opposite signs; the axis-2 zero and the
  non-orthogonality into no angle; g one to one into K (ppm per ppm); a thermometer offset into
  each value at T0 by its tempco;
- coverage (slow): with every error drawn from the lab file's u, value +- U covers the truth
  0.95 +- 0.03 for the angles over 200 campaigns (the binomial SD of a 0.9545 rate over 200
  campaign-level errors is 0.015), and Type A alone covers < 0.6 (the control).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from independent_bench import simulate_campaign
from triadcal import api
from triadcal.io.lab import LabConfig

ANGLES = ("Ca_xy", "Ca_xz", "Ca_yx", "Ca_yz", "Ca_zx", "Ca_zy")
LAB = LabConfig(sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0, axes_nonorthogonality_u_arcsec=5.0,
                encoder_zero_u_arcsec=5.0, mounting_u_arcsec=10.0, local_g_u_ppm=10.0,
                temperature_uncertainty_C=0.2, source="test lab")


def _fit(tmp_path, name, lab=LAB, **errors):
    text, truth = simulate_campaign(np.random.default_rng(7), **errors)
    path = tmp_path / f"{name}.csv"
    path.write_text(text)
    return api.fit(path, method="classical", lab=lab), truth


def _c(result, name, source):
    rows = [r for r in result.parameters[name].uncertainty["budget"] if r["source"] == source]
    assert len(rows) == 1, (name, source)
    return rows[0]["sensitivity"]


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return _fit(tmp_path_factory.mktemp("ctb"), "base")


@pytest.mark.parametrize("source, errors, per", [
    ("encoder zero, axis 1", {"encoder_zero_arcsec": (20.0, 0.0)}, 20.0),
    ("encoder zero, axis 2", {"encoder_zero_arcsec": (0.0, 20.0)}, 20.0),
    ("bench axes non-orthogonality", {"axes_nonorthogonality_arcsec": 20.0}, 20.0),
    ("fixture mounting, about x", {"fixture_arcsec": (20.0, 0.0, 0.0)}, 20.0),
    ("fixture mounting, about y", {"fixture_arcsec": (0.0, 20.0, 0.0)}, 20.0),
    ("fixture mounting, about z", {"fixture_arcsec": (0.0, 0.0, 20.0)}, 20.0),
    ("local gravity", {"true_g_m_s2": 9.80665 * (1 + 20e-6)}, 20.0),
])
def test_each_sensitivity_is_what_the_error_does_to_the_classical_estimate(base, tmp_path, source, errors, per):
    r0, _ = base
    r1, _ = _fit(tmp_path, "shifted", **errors)
    for name in ANGLES + ("K_x", "K_y", "K_z", "S_x", "S_y", "S_z"):
        moved = (r1.parameters[name].value - r0.parameters[name].value) / per
        c = _c(r0, name, source)
        scale = 1.0 if name.startswith("Ca_") else abs(r0.parameters[name].value) * 1e-6 + 1e-9
        assert c == pytest.approx(moved, abs=2e-3 * scale), (name, c, moved)


def test_the_hand_derived_sensitivities(base):
    r, truth = base
    c = {s: {n: _c(r, n, s) for n in ANGLES} for s in ("encoder zero, axis 1", "encoder zero, axis 2",
                                                        "bench axes non-orthogonality", "fixture mounting, about y")}
    for s in ("encoder zero, axis 1", "fixture mounting, about y"):       # rotations about IMU y (axis 1)
        assert c[s]["Ca_zx"] == pytest.approx(1.0, abs=2e-3) and c[s]["Ca_xz"] == pytest.approx(-1.0, abs=2e-3)
        assert all(abs(c[s][n]) < 2e-3 for n in ANGLES if n not in ("Ca_zx", "Ca_xz")), c[s]
    for s in ("encoder zero, axis 2", "bench axes non-orthogonality"):   # cancelled by the half-turn pairs
        assert all(abs(v) < 2e-3 for v in c[s].values()), c[s]
    for a in "xyz":
        K = r.parameters[f"K_{a}"].value
        assert abs(_c(r, f"K_{a}", "local gravity")) / K == pytest.approx(1e-6, rel=2e-3)
    for n in ANGLES:       # a thermometer reading low by dT: each value at T0 is off by its tempco dT
        assert _c(r, n, "thermometers") == pytest.approx(r.parameters[f"{n}_tempco"].value, rel=0.02, abs=1e-3)


def test_u_is_the_root_sum_of_the_budget_and_U_is_stated(base):
    r, _ = base
    for name, p in r.parameters.items():
        rows = p.uncertainty["budget"]
        assert p.u == pytest.approx(math.sqrt(sum(row["contribution"] ** 2 for row in rows)), rel=1e-9), name
        assert p.U is not None and p.U >= 1.9 * p.u, name
    assert {s["key"] for s in r.fit["systematic_errors"]} >= {"[bench] encoder_zero_u_arcsec",
                                                              "[fixture] mounting_u_arcsec"}
    assert any("propagated into every parameter" in n for n in r.notes)


def test_a_classical_certificate_is_issued_with_the_propagated_budget(tmp_path):
    """Refused before under a lab file with systematic errors (Type A only); now issued, and the
    angle budget takes the worst angle's own rows (sensitivities of the estimate), not the
    sensitivity-1 rows that put the axis-2 zero and the non-orthogonality one to one into it."""
    from triadcal.io.lab import load_lab
    from triadcal.reports import certificate as C

    (tmp_path / "lab.toml").write_text(C.EXAMPLE_LAB_TOML)
    lab = load_lab(tmp_path / "lab.toml")
    text, _ = simulate_campaign(np.random.default_rng(7))
    (tmp_path / "x.csv").write_text(text)
    fitted = api.fit(tmp_path / "x.csv", method="classical", lab=lab)
    cert = C.build_certificate(fitted, lab=lab, issue_date="2026-11-29", plots=False)
    assert cert.issued, cert.reasons
    rows = {c.source: c for c in cert.budget.components}
    assert "encoder zeros" not in rows, list(rows)
    assert rows["encoder zero, axis 2"].contribution == 0.0 and rows["bench axes non-orthogonality"].contribution == 0.0
    # sigma_1 and sigma_2 are per-visit errors inside the residual-based u: not counted twice
    assert rows["bench positioning"].contribution == 0.0 and rows["wobble"].contribution == 0.0


@pytest.mark.slow
def test_value_plus_minus_U_covers_the_truth_of_a_classical_fit(tmp_path):
    rng = np.random.default_rng(20261129)
    n = 200
    covered, z, type_a = {"angles": [], "others": []}, {"angles": [], "others": []}, []
    ok = 0
    for i in range(n):
        text, truth = simulate_campaign(
            rng, sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0,
            encoder_zero_arcsec=tuple(rng.normal(0.0, 5.0, 2)), axes_nonorthogonality_arcsec=float(rng.normal(0.0, 5.0)),
            fixture_arcsec=tuple(rng.normal(0.0, 10.0, 3)), tilt_arcsec=tuple(rng.normal(0.0, 30.0, 2)),
            true_g_m_s2=9.80665 * (1.0 + 10e-6 * rng.normal()))
        path = tmp_path / f"c{i}.csv"
        path.write_text(text)
        r = api.fit(path, method="classical", lab=LabConfig(**{**LAB.__dict__, "temperature_uncertainty_C": None}))
        ok += r.status == "ok"
        for name, p in r.parameters.items():
            if name not in truth:
                continue
            fam = "angles" if name in ANGLES else "others"
            e = p.value - truth[name]
            covered[fam].append(abs(e) <= p.U)
            z[fam].append(e / p.u)
            if fam == "angles":
                type_a.append(abs(e) <= 2.0 * p.uncertainty["u_type_a"])
    lines = [f"{f}: n {len(covered[f])}, coverage {np.mean(covered[f]):.3f}, RMS(error/u) "
             f"{math.sqrt(np.mean(np.square(z[f]))):.3f}" for f in covered]
    lines.append(f"angles with Type A only: coverage {np.mean(type_a):.3f}; status ok {ok}/{n}")
    print("\n" + "\n".join(lines))
    assert 0.92 <= np.mean(covered["angles"]) <= 0.98, lines
    assert 0.85 <= math.sqrt(np.mean(np.square(z["angles"]))) <= 1.15, lines
    # K, S and the tempcos: the classical u from the pooled residuals holds bench errors the pairs
    # partly cancel, so they may be conservative, never overconfident
    assert np.mean(covered["others"]) >= 0.92 and math.sqrt(np.mean(np.square(z["others"]))) <= 1.15, lines
    assert np.mean(type_a) < 0.6, lines
    assert ok >= 0.95 * n


def test_one_setpoint_has_no_tempcos_and_still_gets_its_budget(tmp_path):
    """One setpoint: no line over temperature (chi2/dof per parameter None), no tempcos; the
    propagation crashed on the missing ratio (found by a probe of this change)."""
    text, _ = simulate_campaign(np.random.default_rng(3), setpoints_C=(20,))
    (tmp_path / "one.csv").write_text(text)
    r = api.fit(tmp_path / "one.csv", method="classical", lab=LAB)
    assert r.effects == () and not any(n.endswith("_tempco") for n in r.parameters)
    assert _c(r, "Ca_zx", "encoder zero, axis 1") == pytest.approx(1.0, abs=2e-3)
    assert all(p.U is not None for p in r.parameters.values())
    # no tempco carries a thermometer's offset into the values: no row of sensitivity 0, its u is
    # stated with the reference temperature instead
    assert not any(row["source"] == "thermometers" for row in r.parameters["K_x"].uncertainty["budget"])
    assert r.fit["reference_temperature_u_C"] == 0.2


def test_one_setpoint_values_are_the_units_at_its_true_temperature_stated_with_the_thermometers_u(tmp_path):
    """An outside probe: at one setpoint the thermometer row had sensitivity 0 and K was 3.2 U from the
    unit's K at the stated temperature (K tempco 150 ppm/degC, thermometers 0.5 degC off). The values
    are the unit's at its true temperature; the stated temperature is the thermometers' reading, and
    the certificate now says so with its u (the thermometers' 0.5 degC)."""
    from triadcal.io.lab import load_lab
    from triadcal.reports import certificate as C

    truth = {**{f"K_{a}": 1.0 for a in "xyz"}, **{f"S_{a}": 1e-3 for a in "xyz"},
             **{f"Ca_{ab}": 30.0 for ab in ("xy", "xz", "yx", "yz", "zx", "zy")},
             **{f"Ca_{ab}_tempco": 0.0 for ab in ("xy", "xz", "yx", "yz", "zx", "zy")},
             **{f"K_{a}_tempco": 150.0 for a in "xyz"}, **{f"S_{a}_tempco": 0.0 for a in "xyz"}}
    text, _ = simulate_campaign(np.random.default_rng(5), truth=truth, setpoints_C=(20,))
    lines = text.splitlines()
    head = next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#"))
    cols = lines[head].split(",")
    tcols = [cols.index(c) for c in ("t_x", "t_y", "t_z")]
    for i in range(head + 1, len(lines)):           # the thermometers read 1 degC high
        f = lines[i].split(",")
        for j in tcols:
            f[j] = repr(float(f[j]) + 1.0)
        lines[i] = ",".join(f)
    (tmp_path / "one.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "lab.toml").write_text(C.EXAMPLE_LAB_TOML.replace("u_C = 0.2", "u_C = 0.5"))
    lab = load_lab(tmp_path / "lab.toml")
    r = api.fit(tmp_path / "one.csv", method="classical", lab=lab)
    assert r.reference_temperature_C == pytest.approx(21.0, abs=0.05) and r.fit["reference_temperature_u_C"] == 0.5
    K = r.parameters["K_x"]
    assert abs(K.value - 1.0) <= K.U                        # the unit's K at its true 20 degC
    assert abs(K.value - (1.0 + 150e-6)) > K.U              # not its K at the 21 degC read
    cert = C.build_certificate(r, lab=lab, issue_date="2026-11-29", plots=False)
    assert cert.issued, cert.reasons
    assert "as the thermometers read it, u = 0.5 °C" in dict(cert.conditions)["Reference temperature"]


def test_the_certificate_says_why_k_is_not_2_without_a_hysteresis(tmp_path):
    """k = 2.01 from a finite nu_eff was explained as "the hysteresis being a two-point +-h" on a
    result with no hysteresis (an outside probe of this change)."""
    from triadcal.io.lab import load_lab
    from triadcal.reports import certificate as C

    (tmp_path / "lab.toml").write_text(C.EXAMPLE_LAB_TOML)
    lab = load_lab(tmp_path / "lab.toml")
    text, _ = simulate_campaign(np.random.default_rng(3), setpoints_C=(20,))
    (tmp_path / "one.csv").write_text(text)
    cert = C.build_certificate(api.fit(tmp_path / "one.csv", method="classical", lab=lab), lab=lab,
                               issue_date="2026-11-29", plots=False)
    assert cert.issued, cert.reasons
    assert "two-point" not in cert.angle_statement
    assert "effective degrees of freedom" in cert.angle_statement or "k = 2;" in cert.angle_statement


def test_a_joint_fit_at_one_temperature_states_the_thermometers_u_with_its_temperature_too(tmp_path):
    text, _ = simulate_campaign(np.random.default_rng(3), setpoints_C=(20,))
    (tmp_path / "one.csv").write_text(text)
    r = api.fit(tmp_path / "one.csv", effects=("bench_tilt",), lab=LAB)
    assert r.fit["reference_temperature_u_C"] == 0.2
    assert not any(row["source"] == "thermometers" for p in r.parameters.values()
                   for row in p.uncertainty.get("budget", []))
    assert any(row["source"] == "fixture mounting, about y" for row in r.parameters["Ca_zx"].uncertainty["budget"])


@pytest.mark.slow
def test_one_setpoint_angles_are_not_overconfident_with_the_labs_bench_errors(tmp_path):
    """An outside probe: at one setpoint the residual-based u of five angles was too small (RMS
    error/u 1.24-1.48, coverage 0.91 at sigma_1 = 5"): the residuals pool visits where a positioning
    error moves an output fully with visits where it does not move it. With the lab's sigma_1 and
    sigma_2 added through the classical estimate of the plan (conservative by the part the
    residuals hold): over 100 campaigns (600 angles, nearly independent: 3 binomial SDs of a 0.9545
    rate are 0.026) coverage >= 0.92 and RMS error/u <= 1.1 (3 SDs of an RMS over 600 are 0.09)."""
    lab = LabConfig(sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0, encoder_zero_u_arcsec=1.0,
                    mounting_u_arcsec=1.0, source="test lab")
    rng = np.random.default_rng(11)
    covered, z = [], []
    for i in range(100):
        text, truth = simulate_campaign(rng, setpoints_C=(20,), sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0,
                                        encoder_zero_arcsec=tuple(rng.normal(0, 1, 2)),
                                        fixture_arcsec=tuple(rng.normal(0, 1, 3)), tilt_arcsec=tuple(rng.normal(0, 30, 2)))
        path = tmp_path / f"o{i}.csv"
        path.write_text(text)
        r = api.fit(path, method="classical", lab=lab)
        assert r.status == "ok" and r.fit["bench_errors"]["in_u"]
        for n in ANGLES:
            e = r.parameters[n].value - truth[n]
            covered.append(abs(e) <= r.parameters[n].U)
            z.append(e / r.parameters[n].u)
    rms = math.sqrt(np.mean(np.square(z)))
    print(f"\none setpoint: coverage {np.mean(covered):.3f}, RMS error/u {rms:.3f}")
    assert np.mean(covered) >= 0.92 and rms <= 1.1, (np.mean(covered), rms)
