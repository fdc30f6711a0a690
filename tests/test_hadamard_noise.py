"""The capture's noise terms from the Hadamard variance (hardware/noise.py, models/noise_processes.py).

On a temperature ramp each recording window's outputs drift with the unit's temperature; the
drift is deterministic and the fit's model holds it, but it raises the Allan variance by
``D^2 tau^2 / 2`` at the longest tau, which the power-law fit took for a flicker floor and carried
into every visit's ``u_w``. The overlapping Hadamard variance does not see a linear drift. Proven
here against things made another way: the Hadamard factors of the flicker and random-walk terms
derived by hand (the sin^6 integral) and through the models' generalised covariance, and measured
with allantools' ``ohdev`` on this directory's independent 1/f generator (a sum of
Ornstein-Uhlenbeck processes, tests/test_visit_uncertainty.py) and a numpy random walk; the
windows of the drift tests are numpy white noise plus lines, not the emulator."""
from __future__ import annotations

import math

import allantools
import numpy as np
import pytest

from test_visit_uncertainty import ou_flicker
from triadcal.hardware.noise import allan_noise, fit_power_law
from triadcal.models.noise_processes import (HADAMARD_FLICKER, HADAMARD_RANDOM_WALK, _generalized_covariance,
                                             hadamard_variance_power_law)


def test_hadamard_factors_by_hand_and_by_the_generalised_covariance():
    # by hand: int_0^inf sin^6 x / x^3 dx = (3/2) ln 2 - (9/16) ln 3 (sin^6 = (10 - 15 cos 2x + 6 cos 4x
    # - cos 6x) / 32); Hadamard (8/3) h times it, Allan 2 ln 2 h: k_f = 2 - (3/4) log2 3
    k_f = (8.0 / 3.0) * (1.5 * math.log(2) - 9.0 / 16.0 * math.log(3)) / (2 * math.log(2))
    assert HADAMARD_FLICKER == pytest.approx(k_f, rel=1e-12) == pytest.approx(0.81128, abs=1e-5)
    # random walk: int sin^6 x / x^4 = pi/8, int sin^4 x / x^4 = pi/3: (8/3)(pi/8) / (2 pi/3) = 1/2
    assert HADAMARD_RANDOM_WALK == pytest.approx((8 / 3) * (math.pi / 8) / (2 * math.pi / 3), rel=1e-12)
    # the models' generalised covariance K(s) of the integrated output (each term reproduces its Allan
    # variance): (1/6) E[(ybar_3 - 2 ybar_2 + ybar_1)^2] = (1/6) sum c_m c_n K(s_m - s_n) / tau^2 with
    # c = (-1, 3, -3, 1) at s = 0, tau, 2 tau, 3 tau
    c = np.array([-1.0, 3.0, -3.0, 1.0])
    for tau in (0.5, 2.0, 30.0):
        s = np.arange(4) * tau
        for terms in ((2e-8, 0, 0), (0, 1e-8, 0), (0, 0, 3e-10), (2e-8, 1e-8, 3e-10)):
            K = _generalized_covariance(np.subtract.outer(s, s), *terms)
            h = float(c @ K @ c) / tau ** 2 / 6.0
            assert hadamard_variance_power_law(tau, *terms) == pytest.approx(h, rel=1e-9), (tau, terms)


def test_hadamard_factors_measured_by_allantools_on_independent_streams():
    """allantools' ohdev of the OU-sum 1/f stream (Allan floor B_f^2) and of a numpy random walk
    (E[(y(t+s) - y(t))^2] = R s) against the power law's Hadamard form; tolerance 3 standard errors
    of the mean over 6 records, plus 0.02 for the OU sum's known ripple (as the Allan test)."""
    rate, Bf2, R = 10.0, 1e-8, 1e-9
    taus = np.array([1.0, 10.0])
    fl, rw = [], []
    rng = np.random.default_rng(11)
    for _ in range(6):
        x = ou_flicker(2 ** 17, rate, Bf2, rng)
        fl.append(allantools.ohdev(x, rate=rate, data_type="freq", taus=taus)[1] ** 2
                  / hadamard_variance_power_law(taus, 0.0, Bf2))
        y = np.cumsum(rng.normal(0.0, math.sqrt(R / rate), 2 ** 17))
        rw.append(allantools.ohdev(y, rate=rate, data_type="freq", taus=taus)[1] ** 2
                  / hadamard_variance_power_law(taus, 0.0, 0.0, R))
    for name, v in (("flicker", np.array(fl)), ("random walk", np.array(rw))):
        mean, sem = v.mean(axis=0), v.std(axis=0, ddof=1) / math.sqrt(len(v))
        assert np.all(np.abs(mean - 1) < 3 * sem + 0.02), (name, mean, sem)
    # a line: no Hadamard variance at all, the Allan variance D^2 tau^2 / 2
    t = np.arange(4000) / rate
    D = 3e-6
    assert allantools.ohdev(D * t, rate=rate, data_type="freq", taus=taus)[1].max() < 1e-15
    np.testing.assert_allclose(allantools.oadev(D * t, rate=rate, data_type="freq", taus=taus)[1] ** 2,
                               D * D * taus ** 2 / 2, rtol=1e-6)


def _drifting_windows(rng, n_windows, n, rate, sd, drift, flicker_Bf2=0.0):
    """White noise of SD ``sd`` per sample (+ OU 1/f of Allan floor ``flicker_Bf2``) plus a line of
    slope +-[0.5, 1] ``drift`` (unit/s) in each window, three outputs."""
    t = np.arange(n) / rate
    out = []
    for _ in range(n_windows):
        w = rng.normal(0.0, sd, (n, 3)) + np.outer(t, rng.choice([-1, 1], 3) * rng.uniform(0.5, 1.0, 3) * drift)
        if flicker_Bf2:
            w += np.stack([ou_flicker(n, rate, flicker_Bf2, rng) for _ in range(3)], axis=1)
        out.append(w)
    return out


def test_a_drift_within_each_window_is_not_taken_for_a_flicker_floor():
    """60 windows of 120 samples at 2 Hz (a 60 s visit on a ramp), white noise Q = 5e-9, each window a
    line that raises the pooled Allan variance at the longest tau (8 s) by about half: the Allan
    curve (pooled here with allantools directly) rises there as a flicker floor would, and the same
    power-law fit on it keeps a non-white term; the Hadamard fit keeps the white term alone, Q
    within 4 standard errors of the truth, u_w = sqrt(Q/tau) within 8 %."""
    rate, sd = 2.0, 1e-4
    Q = sd * sd / rate
    # a slope of +-[0.5, 1] D (mean square 7/12 D^2) with D^2 tau^2 / 2 = Q / tau at tau = 8 s: + 58 % there
    drift = math.sqrt(2 * Q / 8.0 ** 3)
    taus = np.array([0.5, 1.0, 2.0, 4.0, 8.0])
    edf = 60 * np.array([allantools.edf_greenhall(alpha=0, d=2, m=int(m), N=120, overlapping=True, modified=False)
                         for m in taus * rate])
    for seed in range(3):
        wins = _drifting_windows(np.random.default_rng(seed), 60, 120, rate, sd, drift)
        est = allan_noise(wins, rate)
        for i in range(3):
            avar = np.mean([allantools.oadev(w[:, i], rate=rate, data_type="freq", taus=taus)[1] ** 2 for w in wins],
                           axis=0)
            assert avar[-1] * 8.0 / Q > 1.3, avar * taus / Q                 # the drift shows in the Allan curve
            allan_terms, _ = fit_power_law(taus, avar, edf, variance="allan")
            assert allan_terms[1] > 0 or allan_terms[2] > 0, allan_terms      # and an Allan fit keeps a term
            q, bf2, r = est.power_law[i]
            assert bf2 == 0.0 and r == 0.0, (seed, i, est.power_law[i])
            assert abs(q / Q - 1) < 4 * est.power_law_se[i][0] / Q, (seed, i, q / Q)
        u = est.visit_uncertainty(np.arange(60) * 100.0, np.full(60, 60.0))
        np.testing.assert_allclose(u, math.sqrt(Q / 60.0), rtol=0.08)


def test_a_flicker_floor_under_a_drift_is_still_found():
    """The same with the OU 1/f of Allan floor B_f = 1e-4 V under white noise of Q = 2.5e-8 (the
    flicker dominates from a few seconds on) and a drift: B_f^2 within 3 of its standard errors
    (and 35 %) of the truth."""
    rate, sd, Bf2 = 10.0, 5e-4, 1e-8
    drift = 2e-5                                 # V/s: a line of 6e-3 V over a 300-sample window
    for seed in range(2):
        wins = _drifting_windows(np.random.default_rng(100 + seed), 60, 300, rate, sd, drift, flicker_Bf2=Bf2)
        est = allan_noise(wins, rate)
        for i in range(3):
            q, bf2, r = est.power_law[i]
            se = est.power_law_se[i][1]
            assert bf2 > 0 and abs(bf2 - Bf2) < max(3 * se, 0.0) and abs(bf2 / Bf2 - 1) < 0.35, (seed, i, bf2, se)
