"""Section 5 of the certificate (the thermal model) states the result's own model.

An outside probe fitted a campaign with quadratic and cubic tempcos (``--thermal-order 3``): the
certificate listed every coefficient but told the reader ``x(T) = x + x_tempco·(T − T0)``, which
at the range's ends was off by 9″ in Ca_xy and 2 980 ppm in K_x. Here the statement is evaluated
as a reader would, by code written in this test from the statement's text (not the model's), and
compared with :meth:`Model.terms` at rest, at temperatures over the range and on both branches.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("XDG_CACHE_HOME", "/tmp/xdg")

from triadcal.estimation.result import CalibrationResult, ParameterValue  # noqa: E402
from triadcal.models.model import Covariates, Model  # noqa: E402
from triadcal.models.sensor import ANGLE_NAMES, AXES  # noqa: E402
from triadcal.reports.certificate.content import parameter_rows, thermal_model_lines  # noqa: E402
from triadcal.reports.notation import display_unit  # noqa: E402

CUBIC = ("bench_tilt", "angle_tempco", "angle_tempco2", "angle_tempco3", "scale_tempco", "scale_tempco2",
         "scale_tempco3", "bias_tempco", "bias_tempco2", "bias_tempco3", "hysteresis")
LINEAR = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis")


def _result(effects, seed=3, fit=None) -> CalibrationResult:
    """A result by hand with every parameter of ``effects`` at a few times its typical size (the
    tempcos of a silicon unit bend over -40...70 degC)."""
    model = Model(effects)
    rng = np.random.default_rng(seed)
    params = {n: ParameterValue(model.spec[n].nominal + 3 * model.spec[n].typical * rng.normal(), 1e-3,
                                model.spec[n].unit) for n in model.names}
    return CalibrationResult(unit="SN-T", method="joint", parameters=params, status="ok", effects=effects,
                             temperature_range_C=(-39.7, 70.3), fit=dict(fit or {}))


def _as_stated(result: CalibrationResult, temps: dict, b: float) -> dict:
    """K_a, S_a (g) and Ca_ab (arcsec) by the statement's equations, read from its text:
    K_a (1 + 1e-6 k1 dT)(1 + 1e-6 k2 dT^2)(1 + 1e-6 k3 dT^3), S_a + 1e-6 (s1 dT + s2 dT^2 + s3 dT^3),
    Ca_ab + c1 dT + c2 dT^2 + c3 dT^3 + h b; dT of row a's sensor."""
    v = {n: p.value for n, p in result.parameters.items()}
    T0 = result.reference_temperature_C
    out = {}
    for a in AXES:
        dT = temps[a] - T0
        K = v[f"K_{a}"]
        for o, pw in (("", 1), ("2", 2), ("3", 3)):
            K *= 1 + 1e-6 * v.get(f"K_{a}_tempco{o}", 0.0) * dT ** pw
        out[f"K_{a}"] = K
        out[f"S_{a}"] = v[f"S_{a}"] + 1e-6 * sum(v.get(f"S_{a}_tempco{o}", 0.0) * dT ** pw
                                                 for o, pw in (("", 1), ("2", 2), ("3", 3)))
    for ab in ANGLE_NAMES:
        dT = temps[ab[0]] - T0
        out[f"Ca_{ab}"] = (v[f"Ca_{ab}"] + sum(v.get(f"Ca_{ab}_tempco{o}", 0.0) * dT ** pw
                                                for o, pw in (("", 1), ("2", 2), ("3", 3)))
                           + v.get(f"Ca_{ab}_hysteresis", 0.0) * b)
    return out


def _by_the_model(result: CalibrationResult, temps: dict, b: float) -> dict:
    model = Model(result.effects, result.reference_temperature_C)
    p = model.to_internal({n: q.value for n, q in result.parameters.items()})
    K, S, ang = model.terms(p, Covariates.at_rest(tuple(temps[a] for a in AXES), b))
    out = {f"K_{a}": float(K[i]) for i, a in enumerate(AXES)}
    out.update({f"S_{a}": float(S[i]) for i, a in enumerate(AXES)})
    out.update({f"Ca_{ab}": float(ang[ab]) / model.spec[f"Ca_{ab}"].to_internal for ab in ANGLE_NAMES})
    return out


@pytest.mark.parametrize("effects", [CUBIC, LINEAR])
def test_the_statement_is_the_model(effects):
    r = _result(effects)
    text = " ".join(thermal_model_lines(r))
    cubic = effects is CUBIC
    k_line = ("K_a(T) = K_a · (1 + 10⁻⁶·K_a_tempco·dT) · (1 + 10⁻⁶·K_a_tempco2·dT²) · (1 + 10⁻⁶·K_a_tempco3·dT³)"
              if cubic else "K_a(T) = K_a · (1 + 10⁻⁶·K_a_tempco·dT): the coefficient, in ppm, is relative")
    s_line = ("S_a(T) = S_a + 10⁻⁶·(S_a_tempco·dT + S_a_tempco2·dT² + S_a_tempco3·dT³)" if cubic
              else "S_a(T) = S_a + 10⁻⁶·(S_a_tempco·dT)")
    c_line = ("Ca_ab(T) = Ca_ab + Ca_ab_tempco·dT + Ca_ab_tempco2·dT² + Ca_ab_tempco3·dT³ + Ca_ab_hysteresis·b"
              if cubic else "Ca_ab(T) = Ca_ab + Ca_ab_tempco·dT + Ca_ab_hysteresis·b")
    for line in (k_line, s_line, c_line, "b = +1 on the cooling branch and −1 on the heating branch",
                 "T0 = 20 °C", "from -39.7 °C to 70.3 °C"):
        assert line in text, line
    assert ("tempco2" in text) == cubic
    worst = {"K": 0.0, "S": 0.0, "Ca": 0.0}
    rng = np.random.default_rng(7)
    for _ in range(20):
        temps = dict(zip(AXES, rng.uniform(-39.7, 70.3, 3)))
        for b in (-1.0, 0.0, 1.0):
            stated, model = _as_stated(r, temps, b), _by_the_model(r, temps, b)
            for n in stated:
                kind = n.split("_")[0]
                worst[kind] = max(worst[kind], abs(stated[n] - model[n]))
    # K ~ 1 and S ~ 1e-3 g to double precision; the angles in arcsec through rad and back
    assert worst["K"] < 1e-12 and worst["S"] < 1e-15 and worst["Ca"] < 1e-9, worst
    if cubic:
        # what the old statement (x + x_tempco dT only) misses here: far above every U
        r_lin = _result(effects)
        for n in list(r_lin.parameters):
            if n.endswith(("_tempco2", "_tempco3")):
                r_lin.parameters[n] = ParameterValue(0.0, 1e-3, r.parameters[n].unit)
        far = _by_the_model(r_lin, dict(zip(AXES, (70.3,) * 3)), 0.0)
        near = _by_the_model(r, dict(zip(AXES, (70.3,) * 3)), 0.0)
        assert max(abs(far[f"Ca_{ab}"] - near[f"Ca_{ab}"]) for ab in ANGLE_NAMES) > 1.0


def test_a_play_and_a_lag_are_stated_with_their_form():
    r = _result(LINEAR + ("thermal_lag",), fit={"hysteresis": {"form": "play", "half_width_C": 2.5},
                                                 "thermal_lag": {"form": "history", "location": "air"}})
    text = " ".join(thermal_model_lines(r))
    assert "b the branch of a play of half-width 2.5 °C" in text
    assert "two first-order stages" in text and "thermal_lag_housing" in text
    rate = " ".join(thermal_model_lines(_result(LINEAR + ("thermal_lag",))))
    assert "T = T_sensor − thermal_lag · dT_sensor/dt" in rate


def test_no_thermal_terms_no_equation():
    r = _result(("bench_tilt",))
    assert thermal_model_lines(r) == ["The thermal model applies from -39.7 °C to 70.3 °C (the range of the "
                                      "calibration); it is not valid outside that range."]


def test_every_order_of_tempco_is_a_thermal_coefficient_in_its_units():
    rows = {row.name: row for row in parameter_rows(_result(CUBIC))}
    for n in ("Ca_xy_tempco", "Ca_xy_tempco3", "K_z_tempco2", "S_y_tempco3"):
        assert rows[n].group == "Thermal coefficients", n
    assert display_unit(rows["Ca_xy_tempco3"].unit) == "arcsec/°C³"
    assert display_unit(rows["S_y_tempco3"].unit) == "µg/°C³"
    assert display_unit("ug/g3") == "µg/g³" and display_unit("arcsec/g2") == "arcsec/g²"
