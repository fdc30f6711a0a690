"""Answer gates: hand-derived cases for each gate, and the joint fit on mutated campaigns.

The mutations are made by hand from the built-in example (a column swapped, a sign flipped,
readings scaled while the unit says m/s^2, a campaign cut to 8 visits, averaging times of
10^12 s); the simulator is not involved, so the gates are not checked against the model's
own output only.
"""

import copy
import math

import numpy as np
import pytest

from triadcal.estimation.gates import (
    PRECEDENCE, STATUSES, FitEvidence, GateOutcome, RefusedResult, answer_gates, check_result_for_use,
    rank_deficiency, scale_band, status_of)
from triadcal.estimation.hints import orientation_hints
from triadcal.estimation.joint import fit_joint
from triadcal.estimation.result import CalibrationResult, ParameterValue
from triadcal.models.campaign import nominal_gravity


def params(K=1.0, angle=100.0, unit="g/V", u=0.1):
    p = {f"K_{a}": ParameterValue(K, 1e-6, unit) for a in "xyz"}
    p.update({f"S_{a}": ParameterValue(1e-3, 1e-6, "g") for a in "xyz"})
    p.update({f"Ca_{ab}": ParameterValue(angle, u, "arcsec") for ab in ("xy", "xz", "yx", "yz", "zx", "zy")})
    return p


def failed(outcomes):
    return {o.gate for o in outcomes if o.passed is False}


def test_every_status_is_documented():
    text = open("docs/statuses.md", encoding="utf-8").read()
    for s in STATUSES:
        assert f"`{s}`" in text, s


def test_a_good_answer_passes_every_gate():
    ev = FitEvidence(converged=True, cost_start=1e6, cost_final=500.0, n_obs=540, n_free=32,
                     residual_rms=1e-5, data_rms=0.5, chi2=500.0, dof=508, noise_known=True)
    out = answer_gates(params(), ev)
    assert status_of(out) == "ok" and not failed(out)


@pytest.mark.parametrize("mutate, gate, status", [
    (lambda p: p["K_z"].__setattr__("value", -1.0), "scale", "unphysical_scale"),
    (lambda p: p["K_z"].__setattr__("value", 0.0), "scale", "unphysical_scale"),
    (lambda p: p["Ca_xy"].__setattr__("value", 206264.8), "angles", "angle_out_of_range"),
    (lambda p: p["Ca_xy"].__setattr__("value", 1e7), "angles", "angle_out_of_range"),
    (lambda p: p["S_x"].__setattr__("value", math.nan), "finite", "non_finite"),
    (lambda p: p["S_x"].__setattr__("u", -1.0), "finite", "non_finite"),
    (lambda p: p["S_x"].__setattr__("u", math.inf), "finite", "non_finite"),
])
def test_result_gates_fail_with_their_status(mutate, gate, status):
    p = params()
    mutate(p)
    out = answer_gates(p, FitEvidence())
    assert gate in failed(out) and status_of(out) == status


def test_scale_band_follows_the_declared_unit():
    lo, hi, _ = scale_band("m/s2")
    assert lo < 1 / 9.80665 < hi and hi < 0.13          # a reading x1000 gives K ~ 1e-4: outside
    assert scale_band("g")[0] == pytest.approx(0.8) and scale_band("g")[1] == pytest.approx(1.2)
    assert scale_band("mV")[1] == pytest.approx(scale_band("V")[1] / 1000)
    assert scale_band("furlongs") is None
    # the same K in g/mV is 1000x too large as g/V
    out = answer_gates(params(K=30.0, unit="g/mV"), FitEvidence())
    assert "scale" in failed(out)
    assert "scale" not in failed(answer_gates(params(K=30.0, unit="g/V"), FitEvidence()))


def test_goodness_of_fit_needs_significance_and_size():
    n = 10 ** 6
    # significant but immaterial (ratio 1.01 on a million observations): not a mismatch
    small = answer_gates(params(), FitEvidence(chi2=1.01 * n, dof=n, noise_known=True))
    assert "goodness_of_fit" not in failed(small)
    # a 1.4 ratio on 540 observations (play hysteresis in the thermal issue): a mismatch
    big = answer_gates(params(), FitEvidence(chi2=1.4 * 508, dof=508, noise_known=True))
    assert status_of(big) == "model_mismatch"
    # noise estimated from the residuals: not testable, skipped (never counted as passed)
    est = answer_gates(params(), FitEvidence(chi2=1e9, dof=508, noise_known=False))
    gof = next(o for o in est if o.gate == "goodness_of_fit")
    assert gof.passed is None and "not testable" in gof.reason


def test_identifiability_counts_and_rank():
    few = answer_gates(params(), FitEvidence(n_obs=3, n_free=14))
    assert status_of(few) == "unidentifiable"
    J = np.random.default_rng(0).normal(size=(30, 4))
    J[:, 3] = J[:, 0] + J[:, 1]                          # a combination with no effect
    k, involved = rank_deficiency(J, ["a", "b", "c", "d"], 1e-8)
    assert k == 1 and {"a", "b", "d"} <= set(involved) and "c" not in involved
    out = answer_gates(params(), FitEvidence(jacobian=J, free_names=["a", "b", "c", "d"]))
    assert status_of(out) == "unidentifiable"


def test_rank_of_a_tall_and_of_a_wide_jacobian():
    """Only the right singular vectors are formed: 100 000 visits x 40 parameters take 32 MB, where
    the observations x observations matrix of a full SVD took 80 GB (a 20 000-visit campaign died
    with MemoryError). Fewer rows than parameters: the missing directions count."""
    rng = np.random.default_rng(1)
    J = rng.normal(size=(100_000, 40))
    J[:, 39] = J[:, 2] - 2.0 * J[:, 7]
    names = [f"p{i}" for i in range(40)]
    k, involved = rank_deficiency(J, names, 1e-8)
    assert k == 1 and {"p2", "p7", "p39"} == set(involved)
    k, involved = rank_deficiency(rng.normal(size=(3, 5)), names[:5], 1e-8)
    assert k == 2 and set(involved) <= set(names[:5]) and involved


def test_degenerate_and_no_improvement():
    zero = answer_gates(params(), FitEvidence(residual_rms=0.0, data_rms=1.0))
    assert status_of(zero) == "degenerate"
    worse = answer_gates(params(), FitEvidence(cost_start=10.0, cost_final=11.0))
    assert status_of(worse) == "no_improvement"


def test_precedence_puts_the_most_basic_failure_first():
    outs = [GateOutcome("a", False, "model_mismatch", ""), GateOutcome("b", False, "not_converged", ""),
            GateOutcome("c", None, "non_finite", "skipped")]
    assert status_of(outs) == "not_converged"
    assert PRECEDENCE.index("non_finite") < PRECEDENCE.index("not_converged") < PRECEDENCE.index("model_mismatch")


def test_consumer_check_refuses_with_one_line():
    r = CalibrationResult(unit="SN", method="joint", parameters=params(angle=1e7))
    with pytest.raises(RefusedResult) as e:
        check_result_for_use(r, "r.json")
    assert str(e.value).startswith("r.json: refused:") and "Ca_xy" in str(e.value) and "\n" not in str(e.value)
    r = CalibrationResult(unit="SN", method="joint", parameters={}, status="ok")
    with pytest.raises(RefusedResult, match="no parameters"):
        check_result_for_use(r, "r.json")
    r = CalibrationResult(unit="SN", method="joint", parameters=params(), reference_temperature_C=math.nan)
    with pytest.raises(RefusedResult, match="reference_temperature_C"):
        check_result_for_use(r, "r.json")


# -- the joint fit on mutated copies of the example ------------------------------------------
def _gate_notes(r):
    return " | ".join(n for n in r.notes if n.startswith(("gate", "hint")))


def test_example_passes_and_records_every_gate(example):
    r = fit_joint(example)
    assert r.status == "ok"
    gates = {o["gate"]: o for o in r.extra["gates"]["outcomes"]}
    assert set(gates) >= {"finite", "converged", "residuals", "identifiable", "improved", "scale", "angles",
                          "goodness_of_fit"}
    assert all(o["passed"] for o in gates.values())
    assert r.to_dict()["gates"]["config"]["angle_bound_arcsec"] == 3600.0


def test_swapped_columns_are_not_ok(example):
    c = copy.deepcopy(example)
    c.w[:, [0, 1]] = c.w[:, [1, 0]]
    r = fit_joint(c)
    assert r.status == "angle_out_of_range", _gate_notes(r)
    assert "follows gravity along y, not x" in _gate_notes(r)


def test_flipped_sign_is_not_ok(example):
    c = copy.deepcopy(example)
    c.w[:, 2] *= -1
    r = fit_joint(c)
    assert r.status != "ok"
    assert "w_z falls when its axis points up" in _gate_notes(r)


def test_readings_x1000_declared_as_m_s2_are_not_ok(example):
    c = copy.deepcopy(example)
    c.metadata["output_unit"] = "m/s2"
    c.w = c.w * 9806.65
    c.sd = c.sd * 9806.65
    r = fit_joint(c)
    assert r.status == "unphysical_scale" and r["K_x"].unit == "g/(m/s2)", _gate_notes(r)
    # the same readings /1000 (a real m/s^2 file) pass
    c.w, c.sd = c.w / 1000, c.sd / 1000
    assert fit_joint(c).status == "ok"


def test_scale_factor_is_labelled_with_the_output_unit(example):
    c = copy.deepcopy(example)
    c.metadata["output_unit"] = "mV"
    c.w, c.sd = c.w * 1000, c.sd * 1000
    r = fit_joint(c)
    assert r.status == "ok" and r["K_x"].unit == "g/mV"
    assert r["K_x"].value == pytest.approx(fit_joint(example)["K_x"].value / 1000, rel=1e-9)


def test_eight_visits_are_not_ok(example):
    """The first eight visits (P01-P08: z never up or down) are refused before a fit, naming the axis
    (2026-12-02; before, a result with a status other than ok)."""
    from triadcal.estimation.joint import IdentifiabilityError

    with pytest.raises(IdentifiabilityError, match=r"never turn the IMU's z .*K_z cannot be told from S_z"):
        fit_joint(example.select(np.arange(8)))


def test_tiny_sigma_from_a_huge_tau_is_a_mismatch(example):
    c = copy.deepcopy(example)
    c.sd, c.n_samples = None, None
    c.tau_s = np.full_like(c.tau_s, 1e12)
    r = fit_joint(c)
    assert r.status == "model_mismatch", _gate_notes(r)


def test_orientation_hints_on_hand_made_outputs():
    a1 = np.array([0, 180, 0, 180, 90, 90, 270, 270, 0, 90, 180, 270], float)
    a2 = np.array([0, 0, 180, 180, 90, 270, 90, 270, 90, 0, 90, 0], float)
    G = nominal_gravity(a1, a2)
    assert orientation_hints(G.copy(), G) == []
    w = G.copy()
    w[:, 2] *= -1
    assert orientation_hints(w, G) == ["output w_z falls when its axis points up (an inverted sign?)"]


def test_a_negative_thermal_time_constant_is_not_an_answer():
    """A time constant is >= 0: a thermal lag forced onto data whose sensors lag the element
    comes out negative, and that is refused (it was status ok), naming the number."""
    from triadcal.estimation.gates import result_gates
    from triadcal.estimation.result import ParameterValue

    base = {"K_x": ParameterValue(1.0, 1e-6, "g/V"), "K_y": ParameterValue(1.0, 1e-6, "g/V"),
            "K_z": ParameterValue(1.0, 1e-6, "g/V")}
    bad = [o for o in result_gates({**base, "thermal_lag": ParameterValue(-12.0, 2.0, "min")}, output_unit="V")
           if o.passed is False]
    assert [o.status for o in bad] == ["unphysical_term"] and "thermal_lag = -12 +- 2 min" in bad[0].reason
    ok = {o.gate: o for o in result_gates({**base, "thermal_lag": ParameterValue(-1.0, 2.0, "min")},
                                          output_unit="V")}
    assert ok["signs"].passed is True            # within 2u of zero: not known to be negative
