"""The measurement model: kinematics, eq. 1, every switchable effect, numpy vs CasADi,
and the calibration result that inverts the model (docs/model.md)."""

from __future__ import annotations

import json
import math

import casadi as ca
import numpy as np
import pytest

from triadcal.estimation.result import CalibrationResult, ParameterValue
from triadcal.models import kinematics, sensor
from triadcal.models.campaign import DEFAULT_PLAN, nominal_gravity, up_axis_label
from triadcal.models.effects import DEFAULT_EFFECTS, EFFECTS, NOISE_EFFECTS, get_effects
from triadcal.models.model import Covariates, Model
from triadcal.models.simulate import (PRESETS, NoiseModel, Schedule, Truth, preset_truth,
                                      simulate_campaign)
from triadcal.models.units import ARCSEC, STANDARD_GRAVITY_M_S2

ALL_EFFECTS = tuple(EFFECTS)

#: the table of bench-csv.md, typed in independently of DEFAULT_PLAN
SPEC_PLAN = {
    "P01": (0, 0, "+Y"), "P02": (180, 0, "+Y"), "P03": (0, 180, "-Y"), "P04": (180, 180, "-Y"),
    "P05": (90, 90, "+X"), "P06": (270, 270, "+X"), "P07": (270, 90, "-X"), "P08": (90, 270, "-X"),
    "P09": (180, 90, "+Z"), "P10": (0, 270, "+Z"), "P11": (0, 90, "-Z"), "P12": (180, 270, "-Z"),
}
UNIT_VECTOR = {"+X": (1, 0, 0), "-X": (-1, 0, 0), "+Y": (0, 1, 0), "-Y": (0, -1, 0),
               "+Z": (0, 0, 1), "-Z": (0, 0, -1)}


def Rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def Ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def Rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


M = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)


def R_from_kinematics(axis1, axis2, wobble=0.0):
    """R_base_from_imu, reconstructed column by column from gravity_in_imu (= R^T f)."""
    RT = np.column_stack([np.array(kinematics.gravity_in_imu(axis1, axis2, tuple(e), wobble), float)
                          for e in np.eye(3)])
    return RT.T


def covariates(axis1_deg, axis2_deg, temp=20.0, rate=0.0, branch=0.0, time_s=0.0):
    """Covariates of n visits; ``temp`` and ``rate`` scalar or a 3-tuple (per sensor)."""
    n = len(axis1_deg)

    def col(v):
        return np.broadcast_to(np.asarray(v, float), (n,)).copy()

    def triple(v):
        return tuple(col(x) for x in (v if isinstance(v, tuple) else (v, v, v)))

    return Covariates(axis1=np.radians(np.asarray(axis1_deg, float)),
                      axis2=np.radians(np.asarray(axis2_deg, float)),
                      temp=triple(temp), temp_rate=triple(rate), branch=col(branch), time_s=col(time_s))


def plan_angles():
    a1 = np.array([v[0] for v in SPEC_PLAN.values()], float)
    a2 = np.array([v[1] for v in SPEC_PLAN.values()], float)
    return a1, a2


def preset_values(model: Model, name: str = "a18-silicon") -> dict:
    return {n: PRESETS[name][n] for n in model.names}


def predict(model, values, cov, gravity_g=1.0) -> np.ndarray:
    return np.stack(model.predict(model.to_internal(values), cov, gravity_g), axis=1)


# -- kinematics --------------------------------------------------------------------------


def test_default_plan_is_the_table_of_bench_csv():
    assert list(DEFAULT_PLAN) == list(SPEC_PLAN)
    for label, (a1, a2, _) in SPEC_PLAN.items():
        assert DEFAULT_PLAN[label] == (a1, a2)


def test_default_plan_up_axes():
    a1, a2 = plan_angles()
    ups = [v[2] for v in SPEC_PLAN.values()]
    assert list(up_axis_label(a1, a2)) == ups
    g = nominal_gravity(a1, a2)
    np.testing.assert_allclose(g, np.array([UNIT_VECTOR[u] for u in ups], float), atol=1e-15)


def test_pairs_differ_by_a_half_turn_about_the_vertical():
    """Within each up/down pair the positions differ by 180 deg about base e_z, so a
    horizontal tilt component changes sign (the cancellation of eq. 2-3)."""
    for p, q in (("P01", "P02"), ("P03", "P04"), ("P05", "P06"), ("P07", "P08"),
                 ("P09", "P10"), ("P11", "P12")):
        Rp = R_from_kinematics(*np.radians(DEFAULT_PLAN[p]))
        Rq = R_from_kinematics(*np.radians(DEFAULT_PLAN[q]))
        np.testing.assert_allclose(Rq @ Rp.T, Rz(math.pi), atol=1e-15)


def test_up_axis_label_is_empty_off_the_axes():
    assert list(up_axis_label([45.0], [45.0])) == [""]


@pytest.mark.parametrize("seed", range(5))
def test_R_base_from_imu_is_the_proper_rotation_of_the_spec(seed):
    rng = np.random.default_rng(seed)
    a1, a2 = rng.uniform(-2 * math.pi, 2 * math.pi, 2)
    wobble = rng.normal(0, 1e-3)
    R = R_from_kinematics(a1, a2)
    np.testing.assert_allclose(R, Rx(a2) @ Rz(a1) @ M, atol=1e-15)
    Rw = R_from_kinematics(a1, a2, wobble)
    np.testing.assert_allclose(Rw, Rx(a2) @ Ry(wobble) @ Rz(a1) @ M, atol=1e-15)
    for r in (R, Rw):
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-15)
        assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-14)


def test_mounting_at_zero_angles():
    """At zero angles IMU Y is along axis 1 (up), X along axis 2 (e_x), Z along -e_y."""
    R = R_from_kinematics(0.0, 0.0)
    np.testing.assert_array_equal(R, M)
    np.testing.assert_array_equal(R @ [0, 1, 0], [0, 0, 1])
    np.testing.assert_array_equal(R @ [1, 0, 0], [1, 0, 0])
    np.testing.assert_array_equal(R @ [0, 0, 1], [0, -1, 0])


@pytest.mark.parametrize("delta_arcsec, beta_deg", [(60.0, 30.0), (1.0, -179.0), (3600.0, 90.0),
                                                    (0.5, 0.0), (200.0, -45.0)])
def test_tilt_parametrisation_round_trips(delta_arcsec, beta_deg):
    d, b = delta_arcsec * ARCSEC, math.radians(beta_deg)
    tx, ty = math.sin(d) * math.cos(b), math.sin(d) * math.sin(b)
    f = kinematics.gravity_direction_base(tx, ty)
    np.testing.assert_allclose(f, (math.sin(d) * math.cos(b), math.sin(d) * math.sin(b), math.cos(d)),
                               rtol=0, atol=1e-16)
    assert math.fsum(c * c for c in f) == pytest.approx(1.0, abs=1e-15)
    d2, b2 = kinematics.tilt_polar(tx, ty)
    assert d2 == pytest.approx(d, rel=1e-9)
    assert b2 == pytest.approx(b, abs=1e-9)


def test_tilt_polar_at_zero_tilt():
    d, b = kinematics.tilt_polar(0.0, 0.0)
    assert d == 0.0 and math.isfinite(b)


# -- eq. 1 -------------------------------------------------------------------------------


def test_dcm_rows_are_unit_vectors_with_the_angles_off_the_diagonal():
    rng = np.random.default_rng(1)
    angles = dict(zip(sensor.ANGLE_NAMES, rng.normal(0, 900 * ARCSEC, 6)))
    Ca = np.array(sensor.dcm(angles), float)
    np.testing.assert_allclose(np.linalg.norm(Ca, axis=1), 1.0, atol=1e-15)
    for ab, v in angles.items():
        assert Ca["xyz".index(ab[0]), "xyz".index(ab[1])] == v
    assert (np.diag(Ca) > 0.9999).all()


def test_predict_is_eq_1():
    """K W = Ca G + S, with G = R^T f computed independently from the spec's matrices."""
    model = Model([])
    values = preset_values(model, "a18-silicon")
    a1, a2 = plan_angles()
    W = predict(model, values, covariates(a1, a2), gravity_g=1.0003)
    Ca = np.array(sensor.dcm({ab: values[f"Ca_{ab}"] * ARCSEC for ab in sensor.ANGLE_NAMES}))
    K = np.array([values[f"K_{a}"] for a in "xyz"])
    S = np.array([values[f"S_{a}"] for a in "xyz"])
    for i in range(len(a1)):
        G = 1.0003 * (Rx(math.radians(a2[i])) @ Rz(math.radians(a1[i])) @ M).T @ [0, 0, 1]
        np.testing.assert_allclose(K * W[i], Ca @ G + S, rtol=0, atol=1e-15)


def test_bench_tilt_rotates_the_gravity_vector():
    model = Model(["bench_tilt"])
    values = {"tilt_x": 60.0 * math.cos(0.5), "tilt_y": 60.0 * math.sin(0.5)}  # K = 1, S = 0, Ca = I
    a1, a2 = plan_angles()
    W = predict(model, values, covariates(a1, a2))
    f = np.array(kinematics.gravity_direction_base(values["tilt_x"] * ARCSEC, values["tilt_y"] * ARCSEC))
    for i in range(len(a1)):
        np.testing.assert_allclose(W[i], R_from_kinematics(math.radians(a1[i]), math.radians(a2[i])).T @ f,
                                   atol=1e-15)


# -- numpy and CasADi are one definition --------------------------------------------------


@pytest.fixture(scope="module")
def rich_covariates():
    """Covariates of a short simulated campaign: all branches, non-zero rates and times,
    different sensor temperatures, plus random bench errors and wobble."""
    truth = preset_truth("a18-silicon", ALL_EFFECTS, noise=NoiseModel(Q_V2s=0.0))
    sched = Schedule(setpoints_C=(20.0, 45.0, -10.0), soak_s=900.0)
    cov = simulate_campaign(truth, schedule=sched, seed=2).covariates()
    rng = np.random.default_rng(4)
    n = len(cov.axis1)
    cov.axis1_error, cov.axis2_error, cov.wobble = rng.normal(0, 5 * ARCSEC, (3, n))
    assert set(np.unique(cov.branch)) == {-1.0, 0.0, 1.0}
    assert all(np.any(r != 0) for r in cov.temp_rate)
    return cov


def casadi_predict(model: Model, values: dict, cov: Covariates, gravity_g: float) -> np.ndarray:
    """Model.predict on a CasADi SX parameter vector with the covariates as DM columns."""
    x = ca.SX.sym("x", len(model.names))
    p = {n: x[i] * s for i, (n, s) in enumerate(zip(model.names, model.scales()))}

    def dm(v):
        return ca.DM(np.asarray(v, float)) if np.ndim(v) else v

    cov_dm = Covariates(axis1=dm(cov.axis1), axis2=dm(cov.axis2), temp=tuple(dm(t) for t in cov.temp),
                        temp_rate=tuple(dm(r) for r in cov.temp_rate), branch=dm(cov.branch),
                        time_s=dm(cov.time_s), axis1_error=dm(cov.axis1_error),
                        axis2_error=dm(cov.axis2_error), wobble=dm(cov.wobble))
    out = model.predict(p, cov_dm, gravity_g)
    assert all(isinstance(o, ca.SX) for o in out)
    f = ca.Function("predict", [x], [ca.horzcat(*out)])
    return np.array(f(model.vector(values)))


@pytest.mark.parametrize("effects", [(), *((e,) for e in ALL_EFFECTS), ("thermal_lag", "angle_tempco"),
                                     ALL_EFFECTS],
                         ids=["core", *ALL_EFFECTS, "thermal_lag+angle_tempco", "all"])
def test_numpy_and_casadi_agree(rich_covariates, effects):
    model = Model(effects)
    values = preset_values(model, "a18-silicon")
    W_np = predict(model, values, rich_covariates, gravity_g=1.0008)
    W_ca = casadi_predict(model, values, rich_covariates, gravity_g=1.0008)
    assert W_ca.shape == W_np.shape == (len(rich_covariates.axis1), 3)
    np.testing.assert_allclose(W_ca, W_np, rtol=0, atol=1e-12)
    base = predict(Model([]), preset_values(Model([]), "a18-silicon"), rich_covariates, 1.0008)
    if effects == ("thermal_lag",):  # a lag only shifts the temperature of thermal terms: none here
        np.testing.assert_array_equal(W_np, base)
    elif effects:  # the effect is really switched on: its parameters matter
        assert np.max(np.abs(W_np - base)) > 1e-9


# -- each effect acts only where it should --------------------------------------------------


def terms(model, values, cov):
    K, S, angles = model.terms(model.to_internal(values), cov)
    n = len(cov.axis1)
    full = lambda v: np.broadcast_to(np.asarray(v, float), (n,))  # noqa: E731
    return (np.stack([full(k) for k in K], 1), np.stack([full(s) for s in S], 1),
            {ab: full(v) for ab, v in angles.items()})


def test_hysteresis_branches_around_the_mid_line():
    model = Model(["hysteresis"])
    values = preset_values(model)
    n = 3
    cov = covariates([0.0] * n, [0.0] * n, branch=np.array([0.0, 1.0, -1.0]))
    _, _, ang = terms(model, values, cov)
    for ab in sensor.ANGLE_NAMES:
        mid, cool, heat = ang[ab]
        assert mid == values[f"Ca_{ab}"] * ARCSEC  # 'none' sits on the mid-line
        assert (cool - heat) / 2 == pytest.approx(values[f"Ca_{ab}_hysteresis"] * ARCSEC, rel=1e-12)
        assert (cool + heat) / 2 == pytest.approx(mid, rel=1e-12)


def test_hysteresis_changes_nothing_for_direction_none():
    a1, a2 = plan_angles()
    with_h, without = Model(["hysteresis"]), Model([])
    v = preset_values(with_h)
    for b, changed in ((0.0, False), (1.0, True), (-1.0, True)):
        cov = covariates(a1, a2, branch=b)
        d = predict(with_h, v, cov) - predict(without, preset_values(without), cov)
        assert (np.max(np.abs(d)) > 1e-6) == changed


def test_bias_drift_changes_nothing_at_time_zero():
    model = Model(["bias_drift"])
    v = preset_values(model)
    cov = covariates([0.0, 0.0], [0.0, 0.0], time_s=np.array([0.0, 7200.0]))
    _, S, _ = terms(model, v, cov)
    for i, a in enumerate("xyz"):
        assert S[0, i] == v[f"S_{a}"]
        assert S[1, i] == pytest.approx(v[f"S_{a}"] + v[f"S_{a}_drift"] * 1e-6 * 2.0, rel=1e-12)


def test_thermal_lag_changes_nothing_at_zero_rate():
    lag = Model(["thermal_lag", "angle_tempco", "scale_tempco", "bias_tempco"])
    nolag = Model(["angle_tempco", "scale_tempco", "bias_tempco"])
    v = preset_values(lag)
    T = (31.0, 32.0, 33.0)
    rate = 0.01  # degC/s, sensor warming
    tau_s = v["thermal_lag"] * 60.0
    K0, S0, A0 = terms(lag, v, covariates([0.0], [0.0], temp=T, rate=0.0))
    Kn, Sn, An = terms(nolag, preset_values(nolag), covariates([0.0], [0.0], temp=T))
    np.testing.assert_array_equal(K0, Kn)
    np.testing.assert_array_equal(S0, Sn)
    # with a rate the element sits at T - tau dT/dt: the same as a lag-free model there
    K1, S1, A1 = terms(lag, v, covariates([0.0], [0.0], temp=T, rate=rate))
    T_elem = tuple(t - tau_s * rate for t in T)
    K2, S2, A2 = terms(nolag, preset_values(nolag), covariates([0.0], [0.0], temp=T_elem))
    np.testing.assert_allclose(K1, K2, rtol=1e-15)
    np.testing.assert_allclose(S1, S2, rtol=1e-12)
    for ab in sensor.ANGLE_NAMES:
        assert A0[ab] == An[ab]
        assert A1[ab] == pytest.approx(A2[ab], rel=1e-12)
        assert A1[ab] != A0[ab]


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_thermal_terms_follow_their_own_sensor(axis):
    """Row a of Ca, K_a and S_a follow t_a only; at T0 = 20 degC they are the reference values."""
    model = Model(["angle_tempco", "scale_tempco", "bias_tempco"])
    v = preset_values(model)
    T = [20.0, 20.0, 20.0]
    K0, S0, A0 = terms(model, v, covariates([0.0], [0.0], temp=tuple(T)))
    for i, a in enumerate("xyz"):
        assert K0[0, i] == v[f"K_{a}"] and S0[0, i] == v[f"S_{a}"]
    T[axis] = 45.0
    K1, S1, A1 = terms(model, v, covariates([0.0], [0.0], temp=tuple(T)))
    for i, a in enumerate("xyz"):
        if i == axis:
            assert K1[0, i] == pytest.approx(v[f"K_{a}"] * (1 + v[f"K_{a}_tempco"] * 1e-6 * 25.0), rel=1e-14)
            assert S1[0, i] == pytest.approx(v[f"S_{a}"] + v[f"S_{a}_tempco"] * 1e-6 * 25.0, rel=1e-12)
        else:
            assert K1[0, i] == K0[0, i] and S1[0, i] == S0[0, i]
    for ab in sensor.ANGLE_NAMES:
        if ab[0] == "xyz"[axis]:
            assert A1[ab] - A0[ab] == pytest.approx(v[f"Ca_{ab}_tempco"] * ARCSEC * 25.0, rel=1e-9)
        else:
            assert A1[ab] == A0[ab]


PAIRS = (("P01", "P03"), ("P05", "P07"), ("P09", "P11"))  # +Y/-Y, +X/-X, +Z/-Z, same axis1


@pytest.mark.parametrize("effect, parameter", [("scale_nonlinearity", "K2_{a}"),
                                               ("scale_asymmetry", "K_{a}_asymmetry")])
def test_even_transfer_terms_change_the_sum_not_the_difference(effect, parameter):
    """K2 a^2 and e |a| are even in a: they shift the up+down sum by 2 K2 a^2 (2 e |a|)
    and leave the up-down difference alone."""
    a1 = [DEFAULT_PLAN[p][0] for pair in PAIRS for p in pair]
    a2 = [DEFAULT_PLAN[p][1] for pair in PAIRS for p in pair]
    cov = covariates(a1, a2)
    with_e, without = Model([effect]), Model([])
    v = preset_values(with_e)
    W1, W0 = predict(with_e, v, cov), predict(without, preset_values(without), cov)
    K = np.array([v[f"K_{a}"] for a in "xyz"])
    S = np.array([v[f"S_{a}"] for a in "xyz"])
    coef = np.array([v[parameter.format(a=a)] for a in "xyz"]) * 1e-6
    for j in range(3):
        up, down = 2 * j, 2 * j + 1
        np.testing.assert_allclose(W1[up] - W1[down], W0[up] - W0[down], rtol=0, atol=1e-14)
        a = K * W0[up] - S  # sensed acceleration along each sensing axis, up position
        even = coef * (a * a if effect == "scale_nonlinearity" else np.abs(a))
        np.testing.assert_allclose((W1[up] + W1[down]) - (W0[up] + W0[down]), 2 * even / K,
                                   rtol=1e-6, atol=1e-15)
        assert np.max(np.abs(2 * even / K)) > 1e-6


def test_tilt_changes_nothing_when_level():
    a1, a2 = plan_angles()
    cov = covariates(a1, a2)
    tilt = Model(["bench_tilt"])
    v = preset_values(tilt) | {"tilt_x": 0.0, "tilt_y": 0.0}
    np.testing.assert_array_equal(predict(tilt, v, cov), predict(Model([]), preset_values(Model([])), cov))


# -- vocabulary and parameters ----------------------------------------------------------

ALLOWED_UNITS = {"arcsec", "arcsec/degC", "deg", "g", "g/V", "ppm", "ppm/degC", "ug", "ug/degC", "ug/g2",
                 "ug/h", "arcsec/h", "min", "h", "arcsec/degC2", "ppm/degC2", "ug/degC2", "arcsec/degC3", "ppm/degC3",
                 "ug/degC3", "ug/g3", "arcsec/g2"}


def test_parameter_names_and_units_follow_results_json():
    model = Model(ALL_EFFECTS)
    assert model.names[:12] == ("K_x", "K_y", "K_z", "S_x", "S_y", "S_z", "Ca_xy", "Ca_xz", "Ca_yx",
                                "Ca_yz", "Ca_zx", "Ca_zy")
    assert len(set(model.names)) == len(model.names)
    for s in model.parameters:
        assert s.unit in ALLOWED_UNITS, s
    for ab in sensor.ANGLE_NAMES:
        assert model.spec[f"Ca_{ab}_tempco"].unit == "arcsec/degC"
        assert model.spec[f"Ca_{ab}_hysteresis"].unit == "arcsec"
    for a in "xyz":
        assert model.spec[f"K_{a}_tempco"].unit == "ppm/degC"
        assert model.spec[f"S_{a}_tempco"].unit == "ug/degC"
    assert set(EFFECTS) | set(NOISE_EFFECTS) == {
        "bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis", "scale_nonlinearity",
        "thermal_lag", "bias_drift", "scale_asymmetry", "position_error", "heavy_tails", "flicker_noise",
        "angle_tempco2", "scale_tempco2", "bias_tempco2", "bench_nonorthogonality", "tilt_drift", "tilt_settling",
        "angle_tempco3", "scale_tempco3", "bias_tempco3", "bias_warmup", "scale_warmup",
        "scale_cubic", "cross_coupling", "g_dependent_misalignment"}
    for ab in sensor.ANGLE_NAMES:
        assert model.spec[f"Ca_{ab}_tempco2"].unit == "arcsec/degC2"
    assert model.spec["bench_nonorth"].unit == "arcsec"


def test_effects_come_in_canonical_order_once():
    names = [e.name for e in get_effects(["hysteresis", "bench_tilt", "hysteresis"])]
    assert names == ["bench_tilt", "hysteresis"]
    assert Model(DEFAULT_EFFECTS[::-1]).effect_names == Model(DEFAULT_EFFECTS).effect_names


def test_unknown_effects_are_refused_by_name():
    with pytest.raises(ValueError, match="warp_drive"):
        get_effects(["bench_tilt", "warp_drive"])
    with pytest.raises(ValueError, match="noise options"):
        Model(["heavy_tails"])


def test_to_internal_refuses_unknown_and_fills_nominal():
    model = Model([])
    with pytest.raises(KeyError, match="Ca_xy_tempco"):
        model.to_internal({"Ca_xy_tempco": 1.0})
    p = model.to_internal({"Ca_xy": 3600.0})
    assert p["Ca_xy"] == pytest.approx(math.radians(1.0), rel=1e-15)
    assert p["K_x"] == 1.0 and p["S_y"] == 0.0
    np.testing.assert_allclose(model.vector({}) * model.scales(), [p0 if n != "Ca_xy" else 0.0
                                                                  for n, p0 in zip(model.names,
                                                                                   model.to_internal({}).values())])


def test_preset_truth_json_round_trip(tmp_path):
    truth = preset_truth("ak18-quartz", ALL_EFFECTS + ("heavy_tails",), noise=NoiseModel(heavy_tails_dof=4.0),
                         Ca_xy=40.0)
    assert truth.parameters["Ca_xy"] == 40.0
    truth.save(tmp_path / "truth.json")
    back = Truth.load(tmp_path / "truth.json")
    assert back == truth
    d = json.loads((tmp_path / "truth.json").read_text())
    d["version"] = 2
    with pytest.raises(ValueError, match="version"):
        Truth.from_dict(d)
    with pytest.raises(ValueError, match="not in the model"):
        preset_truth("ak18-quartz", ["bench_tilt"], K2_x=3.0)


# -- the calibration result inverts the model ----------------------------------------------


def truth_result(truth: Truth) -> CalibrationResult:
    model = truth.model()
    params = {n: ParameterValue(truth.parameters[n], 0.0, model.spec[n].unit) for n in model.names}
    return CalibrationResult(unit=truth.unit, method="joint", parameters=params, effects=truth.effects,
                             reference_temperature_C=truth.reference_temperature_C)


def noiseless(truth_effects, preset="a18-silicon", local_g=STANDARD_GRAVITY_M_S2, **overrides):
    truth = preset_truth(preset, truth_effects, noise=NoiseModel(Q_V2s=0.0, temp_noise_C=0.0), **overrides)
    truth.local_g_m_s2 = local_g
    sched = Schedule(setpoints_C=(20.0, 70.0, -40.0), soak_s=1800.0)
    return truth, simulate_campaign(truth, schedule=sched, seed=0)


@pytest.mark.parametrize("effects", [(), ("angle_tempco", "scale_tempco", "bias_tempco")],
                         ids=["core", "tempcos"])
def test_apply_recovers_nominal_gravity(effects):
    truth, c = noiseless(effects)
    assert np.ptp(c.t) > 50.0  # the tempcos are really exercised
    A = truth_result(truth).apply(c.w, c.t)
    np.testing.assert_allclose(A, nominal_gravity(c.axis1_deg, c.axis2_deg), rtol=0, atol=1e-9)


def test_apply_recovers_local_gravity_and_mean_temperature_input():
    truth, c = noiseless(("scale_tempco",), local_g=9.8123)
    A = truth_result(truth).apply(c.w, c.t)
    np.testing.assert_allclose(A, nominal_gravity(c.axis1_deg, c.axis2_deg) * 9.8123 / STANDARD_GRAVITY_M_S2,
                               rtol=0, atol=1e-9)
    # one temperature per reading (n,) is accepted and stands for all three sensors
    truth, c = noiseless(("angle_tempco", "scale_tempco", "bias_tempco"))
    r = truth_result(truth)
    T = c.t.mean(axis=1)
    np.testing.assert_array_equal(r.apply(c.w, T), r.apply(c.w, np.repeat(T[:, None], 3, axis=1)))
    assert np.max(np.abs(r.apply(c.w, T) - r.apply(c.w, c.t))) > 1e-7


def test_apply_uses_the_hysteresis_mid_line():
    """Visits with direction 'none' sit on the mid-line, where apply evaluates the angles."""
    truth, c = noiseless(("angle_tempco", "hysteresis"))
    A = truth_result(truth).apply(c.w, c.t)
    g = nominal_gravity(c.axis1_deg, c.axis2_deg)
    none = c.direction == "none"
    np.testing.assert_allclose(A[none], g[none], atol=1e-9)
    # on a branch the error is the hysteresis offset: up to ~max |h| in the cross axes
    h_max = max(abs(truth.parameters[f"Ca_{ab}_hysteresis"]) for ab in sensor.ANGLE_NAMES) * ARCSEC
    err = np.max(np.abs(A[~none] - g[~none]))
    assert 0.3 * h_max < err < 3 * h_max


def test_apply_inverts_the_transfer_to_first_order():
    truth, c = noiseless(("scale_nonlinearity", "scale_asymmetry"))
    A = truth_result(truth).apply(c.w, c.t)
    k2 = max(abs(truth.parameters[f"K2_{a}"]) for a in "xyz") * 1e-6
    e = max(abs(truth.parameters[f"K_{a}_asymmetry"]) for a in "xyz") * 1e-6
    # residual of a first-order inverse of a + k2 a^2 + e|a| at |a| <= 1: O((k2 + e)^2)
    tol = 3 * (k2 + e) ** 2
    np.testing.assert_allclose(A, nominal_gravity(c.axis1_deg, c.axis2_deg), rtol=0, atol=tol)


def test_apply_refuses_a_result_missing_its_parameters():
    truth, c = noiseless(("angle_tempco",))
    r = truth_result(truth)
    del r.parameters["Ca_zy_tempco"]
    with pytest.raises(ValueError, match="Ca_zy_tempco"):
        r.apply(c.w, c.t)


def test_result_matrix_is_Ca_at_the_reference_temperature():
    truth, _ = noiseless(())
    Ca = truth_result(truth).matrix()
    np.testing.assert_allclose(np.linalg.norm(Ca, axis=1), 1.0, atol=1e-15)
    assert Ca[0, 1] == pytest.approx(truth.parameters["Ca_xy"] * ARCSEC, rel=1e-15)


def test_result_json_round_trip(tmp_path):
    truth, _ = noiseless(("bench_tilt", "angle_tempco", "hysteresis"))
    r = truth_result(truth)
    r.temperature_range_C = (-40.0, 70.0)
    r.intervals = {"Ca_xy": {"level": 0.95, "low": -611.0, "high": -609.0}}
    r.fit = {"chi2_dof": 1.01, "n_obs": 540, "n_params": 35}
    r.correlation_names = ("Ca_xy", "Ca_xz")
    r.correlation = np.array([[1.0, 0.25], [0.25, 1.0]])
    r.notes = ["simulated"]
    r.extra = {"software": "triadcal test"}
    from triadcal.estimation.gates import FitEvidence, apply_gates
    apply_gates(r, FitEvidence(converged=True))        # status ok is read back only with its gates
    path = tmp_path / "result.json"
    r.save(path)
    d = json.loads(path.read_text())
    assert d["format"] == "triadcal.result" and d["version"] == 1
    assert d["parameters"]["Ca_xy_tempco"]["unit"] == "arcsec/degC"
    back = CalibrationResult.load(path)
    assert back.to_dict() == r.to_dict()
    assert back.parameters == r.parameters and back.effects == r.effects
    np.testing.assert_array_equal(back.correlation, r.correlation)
    assert back.covariance(["Ca_xy", "Ca_xz"])[0, 1] == 0.25 * r["Ca_xy"].u * r["Ca_xz"].u


@pytest.mark.parametrize("change, match", [({"format": "triadcal.comparison"}, "not a calibration result"),
                                           ({"format": None}, "not a calibration result"),
                                           ({"version": 2}, "version 2"),
                                           ({"version": "1"}, "version")])
def test_result_refuses_unknown_format_or_version(tmp_path, change, match):
    truth, _ = noiseless(())
    d = truth_result(truth).to_dict() | change
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=match) as info:
        CalibrationResult.load(path)
    assert str(path) in str(info.value)


def test_result_refuses_unknown_unit_and_broken_json(tmp_path):
    truth, _ = noiseless(())
    d = truth_result(truth).to_dict()
    d["parameters"]["Ca_xy"]["unit"] = "furlongs"
    with pytest.raises(ValueError, match="furlongs"):
        CalibrationResult.from_dict(d)
    path = tmp_path / "broken.json"
    path.write_text('{"format": "triadcal.result",\n "version": 1,,}')
    with pytest.raises(ValueError, match=f"{path}:2"):
        CalibrationResult.load(path)


def test_branch_rule_and_sensor_temperatures_by_hand():
    """The two pieces of thermal physics the simulator and the emulator share (models/)."""
    import numpy as np

    from triadcal.models.effects.hysteresis import direction_after
    from triadcal.models.simulate import Schedule
    from triadcal.models.thermal_environment import sensor_temperatures

    assert direction_after("none", None, 20.0) == "none"
    assert direction_after("none", 20.0, 35.0) == "heating"
    assert direction_after("heating", 35.0, 35.0) == "heating"
    assert direction_after("heating", 35.0, -40.0) == "cooling"
    assert Schedule(setpoints_C=(20.0, 20.0, 70.0, 70.0, -40.0)).directions() == \
        ["none", "none", "heating", "heating", "cooling"]
    T = sensor_temperatures(np.array([20.0, 25.0]), (0.3, 0.35, 0.25))
    assert np.allclose(T, [[20.3, 20.35, 20.25], [25.3, 25.35, 25.25]])
    # from power-on: dT (1 - exp(-t/tau)); at t = tau, 63.2 % of the self-heating
    T = sensor_temperatures(np.array([20.0, 20.0]), (1.0, 2.0, 0.0), np.array([0.0, 300.0]), 300.0)
    assert np.allclose(T[0], 20.0) and np.allclose(T[1], [20.0 + (1 - np.exp(-1)), 20.0 + 2 * (1 - np.exp(-1)), 20.0])


def test_quadratic_tempcos_by_hand():
    """value(T) = value(T0) + c2 (T - T0)^2 for the angles, the scale factors and the biases."""
    import numpy as np

    from triadcal.models.effects.thermal2 import AngleTempco2, BiasTempco2, ScaleTempco2
    from triadcal.models.units import ARCSEC, PPM, UG

    dT = (10.0, -20.0, 30.0)
    p = {f"Ca_{ab}_tempco2": 0.004 * ARCSEC for ab in ("xy", "xz", "yx", "yz", "zx", "zy")}
    angles = AngleTempco2().angles(p, None, dT, {ab: 0.0 for ab in ("xy", "xz", "yx", "yz", "zx", "zy")})
    assert np.isclose(angles["xy"] / ARCSEC, 0.4) and np.isclose(angles["yz"] / ARCSEC, 1.6)
    assert np.isclose(angles["zx"] / ARCSEC, 3.6)
    K = ScaleTempco2().scale({f"K_{a}_tempco2": 0.05 * PPM for a in "xyz"}, None, dT, (1.0, 2.0, 1.0))
    assert np.allclose(K, (1.0 + 5e-6, 2.0 * (1.0 + 2e-5), 1.0 + 4.5e-5))
    S = BiasTempco2().bias({f"S_{a}_tempco2": 0.05 * UG for a in "xyz"}, None, dT, (0.0, 0.0, 0.0))
    assert np.allclose(np.array(S) / UG, (5.0, 20.0, 45.0))

