"""The angle budget of the matrix applied over the temperature range holds the fitted tempcos' own
uncertainty (uncertainty/angles.py, "thermal coefficients"). An outside probe of the certificate:
"U = 7.5 arcsec (u_c 3.77) within the calibrated range" while u(Ca_xz_tempco) = 0.033 arcsec/degC at
40 degC from T0 gives u 4.00 there (U 8.0). Hand-derived cases and a Monte Carlo of the line itself."""
from __future__ import annotations

import math

import numpy as np
import pytest

from triadcal.estimation.result import CalibrationResult, ParameterValue
from triadcal.uncertainty.angles import uncertainty_budget


def _result(u0, u1, rho, rng=(-20.0, 60.0), T0=20.0, extra_terms=None):
    P = {"Ca_xy": ParameterValue(10.0, u0, "arcsec"), "Ca_xy_tempco": ParameterValue(0.1, u1, "arcsec/degC")}
    names = ("Ca_xy", "Ca_xy_tempco")
    R = np.array([[1.0, rho], [rho, 1.0]])
    return CalibrationResult(unit="SN-1", method="joint", parameters=P, effects=("angle_tempco",),
                             reference_temperature_C=T0, temperature_range_C=rng, correlation_names=names,
                             correlation=R)


def _component(res):
    b = uncertainty_budget(res)
    return next(c for c in b.components if c.source == "thermal coefficients")


def test_the_tempcos_uncertainty_by_hand():
    """u0 3.77, u1 0.0334 arcsec/degC, uncorrelated, range -20..60 degC about 20: the component at the
    farther end in effect (|dT| 40 both ends) is 40 u1 = 1.336 arcsec, so u(T) = sqrt(3.77^2 + 1.336^2)
    = 4.00 (the probe's number)."""
    c = _component(_result(3.77, 0.0334, 0.0))
    assert c.contribution == pytest.approx(40 * 0.0334, rel=1e-12)
    assert math.hypot(3.77, c.contribution) == pytest.approx(4.00, abs=0.005)


def test_the_correlation_with_the_angle_counts_with_its_sign():
    """rho = +0.5, range 20..70 (dT = 0 or +50): increment 2 * 50 * rho u0 u1 + 50^2 u1^2; with rho =
    -0.5 the end T0 gives 0 and dT = 50 a smaller increment (the larger of the two ends is taken)."""
    u0, u1 = 2.0, 0.02
    for rho in (0.5, -0.5):
        c = _component(_result(u0, u1, rho, rng=(20.0, 70.0)))
        inc = 2 * 50 * rho * u0 * u1 + 2500 * u1 * u1
        assert c.contribution == pytest.approx(math.sqrt(max(inc, 0.0)), rel=1e-12)


def test_the_component_is_the_spread_of_the_fitted_line_by_monte_carlo():
    """Draw (Ca, c) from their normal with the stated covariance (JCGM 101): the SD of Ca + c dT at the
    range's end, squared, less u0^2, is the component squared, within 2 % (200 000 draws)."""
    u0, u1, rho, dT = 3.0, 0.05, -0.3, 45.0
    c = _component(_result(u0, u1, rho, rng=(20.0, 20.0 + dT)))
    C = np.array([[u0 * u0, rho * u0 * u1], [rho * u0 * u1, u1 * u1]])
    x = np.random.default_rng(11).multivariate_normal([0.0, 0.0], C, size=200_000)
    sd = float(np.std(x[:, 0] + dT * x[:, 1]))
    assert math.sqrt(max(sd * sd - u0 * u0, 0.0)) == pytest.approx(c.contribution, rel=0.02)


def test_no_tempco_no_component():
    P = {"Ca_xy": ParameterValue(10.0, 2.0, "arcsec")}
    res = CalibrationResult(unit="SN-1", method="joint", parameters=P, temperature_range_C=(-20.0, 60.0))
    assert all(c.source != "thermal coefficients" for c in uncertainty_budget(res).components)
