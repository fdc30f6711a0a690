"""The order of the tempcos chosen by the data (issue 17, item 2): a quadratic angle tempco added
to simulated outputs by numpy in the test (first order of eq. 1 in an angle), not by the
model's code; and linear data, where no quadratic term may be added beyond the test's size."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from triadcal import api

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis")
ARCSEC = math.pi / 180 / 3600


def _with_quadratic_angle(c2_arcsec_per_C2, seed):
    truth, c = api.simulate(effects=EFFECTS, seed=seed)
    a1, a2 = np.radians(c.axis1_deg), np.radians(c.axis2_deg)
    G = np.stack([np.sin(a1) * np.sin(a2), np.cos(a2), -np.cos(a1) * np.sin(a2)], axis=1)   # as in test_hysteresis_form
    dT = c.t[:, 0] - 20.0                       # row x of Ca follows the x sensor
    w = c.w.copy()
    w[:, 0] += c2_arcsec_per_C2 * dT ** 2 * ARCSEC * G[:, 1] / truth.parameters["K_x"]     # Ca_xy
    return truth, replace(c, w=w)


def test_a_quadratic_angle_tempco_is_added_and_recovered():
    """0.004 arcsec/degC^2, the issue's size: about 4 arcsec at the ends of -40..+70 degC."""
    truth, c = _with_quadratic_angle(0.004, seed=3)
    linear = api.fit(c)
    r = api.fit(c, thermal_order="auto")
    assert r.fit["thermal_order"]["added"] == ["angle_tempco2"], r.fit["thermal_order"]
    p = r.parameters["Ca_xy_tempco2"]
    assert abs(p.value - 0.004) < 3 * p.u
    assert abs(r["Ca_xy"].value - truth.parameters["Ca_xy"]) < 3 * r["Ca_xy"].u
    assert abs(linear["Ca_xy"].value - truth.parameters["Ca_xy"]) > 3 * linear["Ca_xy"].u   # the line is biased
    assert r.fit["chi2_dof"] < linear.fit["chi2_dof"]


def test_order_2_adds_every_family_and_1_keeps_the_model():
    _, c = api.simulate(effects=EFFECTS, seed=5)
    r2 = api.fit(c, thermal_order="2")
    assert {"angle_tempco2", "scale_tempco2", "bias_tempco2"} <= set(r2.effects)
    assert "thermal_order" not in api.fit(c).fit


@pytest.mark.slow
def test_linear_data_rarely_get_a_quadratic_term():
    """Each family's test is at 1 %: over 3 families a false addition in about 3 % of campaigns;
    over 20 campaigns more than 3 false additions has probability 0.003 (binomial)."""
    false = 0
    for seed in range(100, 120):
        _, c = api.simulate(effects=EFFECTS, seed=seed)
        false += bool(api.fit(c, thermal_order="auto").fit["thermal_order"]["added"])
    assert false <= 3


# -- cubic tempcos (issue 17, item 2) -----------------------------------------------------------
def _with_cubic_angle(c3_arcsec_per_C3, seed):
    truth, c = api.simulate(effects=EFFECTS, seed=seed)
    a1, a2 = np.radians(c.axis1_deg), np.radians(c.axis2_deg)
    G = np.stack([np.sin(a1) * np.sin(a2), np.cos(a2), -np.cos(a1) * np.sin(a2)], axis=1)
    dT = c.t[:, 0] - 20.0
    w = c.w.copy()
    w[:, 0] += c3_arcsec_per_C3 * dT ** 3 * ARCSEC * G[:, 1] / truth.parameters["K_x"]     # Ca_xy
    return truth, replace(c, w=w)


def test_a_cubic_angle_tempco_is_found_top_down_and_recovered():
    """1e-4 arcsec/degC^3 (about 12" at -40 and 70 degC from 20) with no quadratic part: the
    quadratic test alone would not see it, the top-down test adds the angles' order 3."""
    truth, c = _with_cubic_angle(1e-4, seed=3)
    r = api.fit(c, thermal_order="auto")
    block = r.fit["thermal_order"]
    assert block["orders"] == {"angle_tempco": 3, "scale_tempco": 1, "bias_tempco": 1}, block
    assert set(block["added"]) == {"angle_tempco2", "angle_tempco3"}
    p = r.parameters["Ca_xy_tempco3"]
    assert p.unit == "arcsec/degC3" and abs(p.value - 1e-4) < 3 * p.u
    assert abs(r.parameters["Ca_xy_tempco2"].value) < 3 * r.parameters["Ca_xy_tempco2"].u
    assert abs(r["Ca_xy"].value - truth.parameters["Ca_xy"]) < 3 * r["Ca_xy"].u


def test_order_3_adds_quadratic_and_cubic_terms_with_their_units():
    _, c = api.simulate(effects=EFFECTS, seed=5)
    r3 = api.fit(c, thermal_order="3")
    assert {"angle_tempco2", "scale_tempco2", "bias_tempco2", "angle_tempco3", "scale_tempco3",
            "bias_tempco3"} <= set(r3.effects)
    assert r3.parameters["K_x_tempco3"].unit == "ppm/degC3" and r3.parameters["S_x_tempco3"].unit == "ug/degC3"
    from triadcal.errors import InputError
    from triadcal.estimation.thermal_order import choose_thermal_order

    with pytest.raises(InputError, match="choose one of"):
        choose_thermal_order(c, EFFECTS, "4")


def test_the_model_and_the_independent_polynomial_agree_on_cubic_terms():
    """The cubic effects against a polynomial written out here (K a factor, S in ug)."""
    from triadcal.models.effects.thermal3 import AngleTempco3, BiasTempco3, ScaleTempco3
    from triadcal.models.units import PPM, UG

    dT = (np.array([-60.0, 0.0, 65.0]),) * 3
    ang = AngleTempco3().angles({f"Ca_{ab}_tempco3": 2e-5 * ARCSEC for ab in ("xy", "xz", "yx", "yz", "zx", "zy")},
                                None, dT, {ab: 0.0 for ab in ("xy", "xz", "yx", "yz", "zx", "zy")})
    assert np.allclose(ang["xy"] / ARCSEC, 2e-5 * np.array([-216000.0, 0.0, 274625.0]))
    K = ScaleTempco3().scale({f"K_{a}_tempco3": 2e-4 * PPM for a in "xyz"}, None, dT, (1.0, 1.0, 1.0))
    assert np.allclose(K[0], 1 + 2e-10 * dT[0] ** 3)
    S = BiasTempco3().bias({f"S_{a}_tempco3": 2e-4 * UG for a in "xyz"}, None, dT, (0.0, 0.0, 0.0))
    assert np.allclose(S[2], 2e-10 * dT[0] ** 3)


def test_compensation_bound_of_a_cubic_tempco_by_hand():
    """q(T) = c3 (T - T0)^3: q'' = 6 c3 (T - T0), linear in T, so the bound on [T_i, T_i+1] is
    D^2 * 6 |c3| max(|T_i - T0|, |T_i+1 - T0|) / 8; the true largest error lies between half of it
    and it."""
    from triadcal.estimation.result import CalibrationResult, ParameterValue
    from triadcal.reports.compensation import compensation_table

    c3 = 2e-5
    params = {n: ParameterValue(v, 1e-6, u) for n, v, u in [
        ("K_x", 1.0, "g/V"), ("K_y", 1.0, "g/V"), ("K_z", 1.0, "g/V"), ("S_x", 0.0, "g"), ("S_y", 0.0, "g"),
        ("S_z", 0.0, "g")] + [(f"Ca_{ab}", 0.0, "arcsec") for ab in ("xy", "xz", "yx", "yz", "zx", "zy")]
        + [(f"Ca_{ab}_tempco", 0.0, "arcsec/degC") for ab in ("xy", "xz", "yx", "yz", "zx", "zy")]
        + [(f"Ca_{ab}_tempco3", c3 if ab == "xy" else 0.0, "arcsec/degC3") for ab in ("xy", "xz", "yx", "yz", "zx", "zy")]}
    names = list(params)
    res = CalibrationResult(unit="SN-C3", method="joint", parameters=params,
                            effects=("angle_tempco", "angle_tempco3"), reference_temperature_C=20.0,
                            temperature_range_C=(-40.0, 85.0), fit={"chi2_dof": 1.0},
                            correlation_names=tuple(names), correlation=np.eye(len(names)))
    res.status = "ok"
    grid = np.arange(-40.0, 85.1, 5.0)
    table = compensation_table(res, grid)
    D = 5.0
    want = D ** 2 * 6 * c3 * np.maximum(np.abs(grid[:-1] - 20), np.abs(grid[1:] - 20)) / 8
    assert table.interp_angles[:-1, 0] == pytest.approx(want, rel=1e-6, abs=1e-12)
    assert table.interp_angles[-1, 0] == 0.0 and np.all(table.interp_angles[:, 1:] == 0.0)
    for i in range(len(grid) - 1):               # the true error of the chord, finely sampled
        t = np.linspace(grid[i], grid[i + 1], 201)
        q = c3 * (t - 20) ** 3
        err = np.max(np.abs(q - np.interp(t, grid[i:i + 2], q[[0, -1]])))
        assert want[i] / 2 - 1e-12 <= err <= want[i] + 1e-12
    assert table.interp_angles[24, 0] == pytest.approx(0.024375, rel=1e-6)     # [80, 85]: 25 * 6 * 2e-5 * 65 / 8


def test_the_command_takes_order_3_and_the_pi_form(tmp_path):
    import json

    from triadcal.cli import main

    out = tmp_path / "r.json"
    assert main(["fit", "--example", "--thermal-order", "3", "--hysteresis-form", "pi", "--json", str(out)]) in (0, 3)
    doc = json.loads(out.read_text(encoding="utf-8"))
    assert doc["parameters"]["Ca_xy_tempco3"]["unit"] == "arcsec/degC3"
    assert doc["fit"]["hysteresis"]["form"] == "pi" and len(doc["fit"]["hysteresis"]["pi_weights"]) == 2
