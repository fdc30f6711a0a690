"""The second mechanisms of the effect families (judgement/second_mechanisms.py), checked by hand
and against the bench geometry, and the diagnosis's verdicts on them (issue 18, items 3-4)."""

import numpy as np
import pytest

from triadcal.errors import InputError
from triadcal.judgement import second_mechanisms as sm


def test_play_branch_by_hand():
    """Half-width 8 degC, started in the middle: y_k = max(T - 8, min(T + 8, y_{k-1})), b = (T - y)/8.
    20 -> y 20, b 0; 30 -> y 22, b 1; 40 -> y 32, b 1; 30 -> y 32, b -0.25; 20 -> y 28, b -1;
    30 -> y 28, b 0.25."""
    b = sm.play_branch(np.array([20.0, 30.0, 40.0, 30.0, 20.0, 30.0]), 8.0)
    assert np.allclose(b, [0.0, 1.0, 1.0, -0.25, -1.0, 0.25])


def test_a_constant_tilt_moves_gravity_by_its_angle_at_every_pose():
    """bench_tilt~2 tilts gravity in the base frame by (52, 30) arcsec: a rotation, so at every
    pose the change of the (unit) gravity in the IMU frame has the norm 2 sin(theta / 2), theta =
    sqrt(52^2 + 30^2) arcsec, and gravity keeps unit norm."""
    from triadcal.judgement.diagnosis_validation import VALIDATION_PLAN
    from triadcal.models.simulate import Schedule, preset_truth, simulate_campaign

    c = simulate_campaign(preset_truth("ak18-quartz"), plan=VALIDATION_PLAN, schedule=Schedule(soak_s=1800.0),
                          seed=3)
    tx, ty = 52.0 * sm.ARCSEC, 30.0 * sm.ARCSEC
    n = c.n_visits
    G0 = sm._gravity(c)
    G1 = sm._gravity(c, sm._tilted(np.full(n, tx), np.full(n, ty)))
    theta = np.hypot(tx, ty)
    assert np.allclose(np.linalg.norm(G1, axis=1), 1.0, atol=1e-12)
    assert np.allclose(np.linalg.norm(G1 - G0, axis=1), 2 * np.sin(theta / 2), rtol=1e-6)


def test_the_sum_of_ou_processes_has_the_stated_variance():
    """Four independent stationary OU processes of SD s: the sum's variance is 4 s^2 (samples an
    hour apart over 20 000 h: the slowest, 37.5 h, gives ~530 independent stretches; chi2 band)."""
    rng = np.random.default_rng(5)
    t = np.arange(20000) * 3600.0
    x = sm._ou_sum(t, (0.3, 1.5, 7.5, 37.5), 2.0, rng)
    assert abs(np.var(x) / 16.0 - 1.0) < 0.2, np.var(x)


def test_the_exponential_tempco_laws_by_hand():
    """scale_tempco~2 and angle_tempco~2 (and bias_tempco~2) follow 2 c theta^2 (e^x - 1 - x),
    x = (T - 20) / theta, theta = 40 degC: c (T - 20)^2 near 20 degC (the preset's quadratic tempco,
    the first mechanism), 2 c 1600 (e - 2) = 2298.5 c at 60 degC. Checked on the campaigns: the
    scale's outputs are W / (1 + delta) of the clean campaign's (the same seed draws the same noise),
    per axis with its own sensor's temperature; the angles' change is c_ab law(T_mean) G_b on output
    a, nothing else."""
    from triadcal.judgement.diagnosis_validation import VALIDATION_PLAN, VALIDATION_SOAK_S, scenario
    from triadcal.models.simulate import Schedule, simulate_campaign

    theta = sm.EXP_THETA_C
    law = lambda T: 2.0 * theta ** 2 * (np.exp((T - 20.0) / theta) - 1.0 - (T - 20.0) / theta)  # noqa: E731
    assert law(60.0) == pytest.approx(2.0 * 1600.0 * (np.e - 2.0)) and law(20.0) == 0.0
    assert law(20.5) == pytest.approx(0.25, rel=0.01)
    truth, _ = scenario("clean")
    clean = simulate_campaign(truth, plan=VALIDATION_PLAN, schedule=Schedule(soak_s=VALIDATION_SOAK_S), seed=7)
    scale, _ = sm.second_campaign("scale_tempco", 7)
    delta = 1e-6 * np.array([0.05, -0.04, 0.06]) * law(np.asarray(clean.t, float))
    assert np.allclose(scale.w, clean.w / (1.0 + delta), rtol=0, atol=1e-15)
    angle, _ = sm.second_campaign("angle_tempco", 7)
    G = sm._gravity(clean)
    L = law(np.asarray(clean.t, float).mean(axis=1)) * sm.ARCSEC
    c2 = {"xy": 0.004, "xz": -0.003, "yx": 0.0035, "yz": -0.004, "zx": 0.003, "zy": 0.0025}
    K = np.array([truth.parameters[f"K_{a}"] for a in "xyz"])
    expect = np.column_stack([sum(c2[a + b] * L * G[:, "xyz".index(b)] for b in "xyz" if b != a) for a in "xyz"])
    assert np.allclose(angle.w - clean.w, expect / K, rtol=0, atol=1e-15)     # W = (Ca G + S) / K


def test_names_and_errors():
    assert sm.base_effect("hysteresis~2") == "hysteresis" and sm.is_second("hysteresis~2")
    assert set(sm.CONDITIONS) == {e + "~2" for e in sm.FAMILY}
    with pytest.raises(InputError, match="no second mechanism"):
        sm.base_effect("tilt_settling~2")
    with pytest.raises(InputError, match="no second mechanism"):
        sm.second_campaign("quantisation", 1)


def test_the_duffing_deflection_solves_its_equation():
    """x + beta x^3 = a to rounding; the series x = a - beta a^3 + 3 beta^2 a^5 - 12 beta^3 a^7 (the
    reversion of the cubic) to its next term; beta = 0 is the identity."""
    a = np.linspace(-1.0, 1.0, 41)
    for beta in (15e-6, -10e-6, 0.05):
        x = sm.duffing_deflection(a, beta)
        assert np.max(np.abs(x + beta * x ** 3 - a)) < 5e-16
        series = a - beta * a ** 3 + 3 * beta ** 2 * a ** 5 - 12 * beta ** 3 * a ** 7
        assert np.max(np.abs(x - series)) <= 60 * abs(beta) ** 4 + 5e-16
    assert np.array_equal(sm.duffing_deflection(a, 0.0), a)


def _clean(seed=7):
    from triadcal.judgement.diagnosis_validation import VALIDATION_PLAN, VALIDATION_SOAK_S, scenario
    from triadcal.models.simulate import Schedule, simulate_campaign

    truth, _ = scenario("clean")
    c = simulate_campaign(truth, plan=VALIDATION_PLAN, schedule=Schedule(soak_s=VALIDATION_SOAK_S), seed=seed)
    return c, truth, np.array([truth.parameters[f"K_{a}"] for a in "xyz"])


def test_the_inclined_bearing_by_hand():
    """With w0 = 0 the inclined bearing is the bench's nominal kinematics (sm._gravity, from
    models.kinematics); with w0 it turns the unit about n = Ry(w0) z, Rot(n, t) = Ry(w0) Rz(t)
    Ry(w0)^T, which is the model's wobble Ry(w0) between the axes followed by the constant Ry(-w0)
    on the unit's side: in the IMU frame G = M^T Ry(w0) M G_model, M^T (q0, q1, q2) = (q0, q2, -q1).
    Gravity keeps unit norm."""
    from triadcal.models.kinematics import gravity_in_imu

    c, truth, _ = _clean()
    n = c.n_visits
    f = sm._tilted(np.full(n, truth.parameters["tilt_x"] * sm.ARCSEC),       # the preset's (52, 30) arcsec
                   np.full(n, truth.parameters["tilt_y"] * sm.ARCSEC))
    assert np.allclose(sm.inclined_bearing_gravity(c, f, 0.0), sm._gravity(c, f), rtol=0, atol=1e-15)
    w0 = 8.0 * sm.ARCSEC
    G = sm.inclined_bearing_gravity(c, f, w0)
    assert np.allclose(np.linalg.norm(G, axis=1), 1.0, rtol=0, atol=1e-14)
    a1, a2 = np.radians(np.asarray(c.axis1_deg, float)), np.radians(np.asarray(c.axis2_deg, float))
    Gm = np.column_stack(gravity_in_imu(a1, a2, f, w0))
    q = np.column_stack([Gm[:, 0], -Gm[:, 2], Gm[:, 1]])            # M G
    cw, sw = np.cos(w0), np.sin(w0)
    v = np.column_stack([cw * q[:, 0] + sw * q[:, 2], q[:, 1], -sw * q[:, 0] + cw * q[:, 2]])   # Ry(w0) q
    assert np.allclose(G, np.column_stack([v[:, 0], v[:, 2], -v[:, 1]]), rtol=0, atol=1e-15)
    bench, _ = sm.second_campaign("bench_nonorthogonality", 7)
    K = np.array([truth.parameters[f"K_{a}"] for a in "xyz"])
    assert np.max(np.abs(G - sm.inclined_bearing_gravity(c, f, 0.0))) > 30e-6          # 8 arcsec, about 39 ug
    assert np.allclose((bench.w - c.w) * K, G - sm.inclined_bearing_gravity(c, f, 0.0), rtol=0, atol=1e-15)


def test_the_static_nonlinearities_by_hand():
    """The five static mechanisms against the first mechanism's law on the same campaign (the same
    seed draws the same noise). The readout's laws act on the output W, bias included: exactly
    W + K2 K W^2, W (1 + e tanh(K W / 0.05)), x / K with x + beta x^3 = K W; within 0.13 ug of K2 a^2,
    e |a|, K3 a^3 (the bias, about 5 mg, times 2 K2 a, e, 3 K3 a^2; the crossover near 0). The
    pendulums and the bowed flexures within 1e-3 ug of the products Kc_ab a_a a_b (three of six)
    and m_ab a_a^2 a_b (second order in the angles: 1e-10 rad)."""
    c, truth, K = _clean()
    G = sm._gravity(c)
    W = np.asarray(c.w, float)
    ug = lambda x: (np.asarray(x.w, float) - W) * K * 1e6             # noqa: E731
    k2 = np.array([10.0, -8.0, 12.0])
    s, _ = sm.second_campaign("scale_nonlinearity", 7)
    assert np.allclose(s.w, W + 1e-6 * k2 * K * W * W, rtol=0, atol=1e-15)
    assert np.max(np.abs(ug(s) - k2 * G ** 2)) < 0.13
    e = np.array([20.0, -15.0, 25.0])
    s, _ = sm.second_campaign("scale_asymmetry", 7)
    assert np.allclose(s.w, W * (1 + 1e-6 * e * np.tanh(K * W / 0.05)), rtol=0, atol=1e-15)
    assert np.max(np.abs(ug(s) - e * np.abs(G))) < 0.13
    k3 = np.array([15.0, -10.0, 12.0])
    s, _ = sm.second_campaign("scale_cubic", 7)
    x = np.asarray(s.w, float) * K
    assert np.max(np.abs(x - 1e-6 * k3 * x ** 3 - K * W)) < 1e-15        # x + beta x^3 = a, beta = -K3
    assert np.max(np.abs(ug(s) - k3 * G ** 3)) < 0.13
    s, _ = sm.second_campaign("cross_coupling", 7)
    ref = np.column_stack([30.0 * G[:, 0] * G[:, 1], -15.0 * G[:, 1] * G[:, 2], 20.0 * G[:, 2] * G[:, 0]])
    assert np.max(np.abs(ref)) > 10 and np.max(np.abs(ug(s) - ref)) < 1e-3
    m = {"xy": 3.0, "xz": -2.0, "yx": 2.5, "yz": -3.0, "zx": 2.0, "zy": 1.5}
    s, _ = sm.second_campaign("g_dependent_misalignment", 7)
    ref = np.column_stack([sum(m[a + b] * sm.ARCSEC * 1e6 * G[:, i] ** 2 * G[:, j]
                               for j, b in enumerate("xyz") if b != a) for i, a in enumerate("xyz")])
    assert np.max(np.abs(ref)) > 5 and np.max(np.abs(ug(s) - ref)) < 1e-3
    half, _ = sm.second_campaign("cross_coupling", 7, magnitude=0.5)
    s, _ = sm.second_campaign("cross_coupling", 7)
    assert np.max(np.abs(ug(half) - ug(s) / 2)) < 1e-3              # linear in m but for cos(delta) - 1


@pytest.mark.slow
def test_the_diagnosis_on_second_mechanisms_never_names_a_wrong_effect():
    """Seeds 1000-1001 of every second mechanism, both modes (the documented run has 20 seeds,
    docs/diagnosis.md "Second mechanisms"): in vocabulary the verdict names an effect of the family,
    or says `unexplained` / `none` -- never another effect; left out (the family removed from the
    candidates) nothing is named with the gap closed. The play hysteresis, the tilt made with numpy,
    the uniform positioning errors, the lag behind the air (its gaps bridged), the contamination
    (the Student-t's scale free) and five of the six static mechanisms (not the readout's K2, whose
    rival is the asymmetry: 14 of 20), named in 20 of 20 campaigns of that run, are named here."""
    from triadcal.judgement.diagnosis_validation import validate

    res = validate(seeds=2, effects=sm.CONDITIONS, processes=1, left_out=True)
    for r in res.rows:
        fam = sm.FAMILY[sm.base_effect(r["effect"])]
        assert r["verdict"] in fam + ("unexplained", "none"), r
        assert r["left_out_verdict"] in ("unexplained", "none") or r["left_out_gap_closed"] is False, r
        if r["effect"] in ("hysteresis~2", "bench_tilt~2", "position_error~2", "thermal_lag~2", "heavy_tails~2",
                           "scale_asymmetry~2", "scale_cubic~2", "cross_coupling~2", "g_dependent_misalignment~2",
                           "bench_nonorthogonality~2"):
            assert r["right"], r
    s = res.summary
    assert all(s[c]["left_out_confident_wrong_rate"] == 0 for c in sm.CONDITIONS)


@pytest.mark.slow   # 10-18 s; CI runs it with the slow tests (CI-29: the quick suite took 635 s of its 600)
def test_a_settling_bias_is_named_by_its_exponential_tested_at_the_fitted_time_constant():
    """bias_drift~2 seed 1005: the bias settles as r tau (1 - exp(-t/tau)), tau the campaign's 12.8 h.
    bias_warmup is that law; its rival test against the drift must take the warm-up's columns at the
    time constant its refit found, not at the 5 min the base fit starts from (verdict._columns_at_refit):
    with the old columns the test compared the drift with a warm-up over before the first visit, and
    the verdict was 'unexplained, ambiguous with bias_drift' (p 0.68 on seed 1001 of the last run).
    The fitted tau is the truth's within 3 u (581 +- 138 min against 770 min), and the exponential was
    named until 2026-11-29 (ninth session): a time constant of 581 min is one the fit's own answer gate
    refuses as a warm-up after power-on (time_constants, [0.5, 300] min), so the verdict now names the
    rate, in the family, and says why the exponential ranked above it is not named."""
    from triadcal.judgement.diagnose import diagnose

    campaign, model = sm.second_campaign("bias_drift", 1005)
    span_min = (float(campaign.time_s[-1]) - float(campaign.time_s[0])) / 60.0
    d = diagnose(campaign, model, n_draws=200, slices_after=False, top=2, seed=1005)
    v = d.verdict
    assert v["effect"] == "bias_drift" and v["effect"] in sm.FAMILY["bias_drift"], v
    assert "bias_warmup ranked above it" in v["evidence"] and "outside [0.5, 300] min" in v["evidence"], v
    tau = next(c.refit["new_parameters"]["S_warmup_tau"] for c in d.candidates if c.effect == "bias_warmup")
    assert tau["unit"] == "min" and abs(tau["value"] - span_min) < 3 * tau["u"], (tau, span_min)
