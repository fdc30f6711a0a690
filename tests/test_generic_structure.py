"""The generic structure tests of the diagnosis (judgement/diagnose/generic.py).

The null distribution is checked on a hand-made linear-Gaussian problem (no simulator, no model
code: residuals of a least-squares fit of random noise on the example campaign's bias and scale
columns), where the score statistic of each family is exactly chi2 with the projected rank as
dof; the detection on outputs changed with numpy is in tests/test_diagnose.py
(test_an_effect_outside_the_vocabulary_is_unexplained_not_noise) and the guard it gives the
verdict in the left-out validation (tests/test_diagnosis_validation.py, docs/diagnosis.md).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from triadcal.judgement.diagnose.fitting import _hat_q
from triadcal.judgement.diagnose.generic import FAMILIES, generic_basis, generic_tests
from triadcal.judgement.diagnose.candidates import _nominal_g

N_DRAWS = 120


def _core_columns(campaign, sigma):
    """Bias and scale of each output (the part of eq. 1 linear in them), normalised units."""
    n = campaign.n_visits
    g = np.asarray(_nominal_g(campaign), float).reshape(n, 3)
    J = np.zeros((n, 3, 6))
    for a in range(3):
        J[:, a, 2 * a] = 1.0 / sigma[:, a]
        J[:, a, 2 * a + 1] = g[:, a] / sigma[:, a]
    return J.reshape(3 * n, 6)


def test_every_family_is_chi2_with_its_rank_under_the_linear_null(example):
    """Residuals of a linear least-squares fit of pure noise: S of each family ~ chi2(k) exactly.
    In the first draws S equals the independent formula r' B~ pinv(B~) r (B~ the family's columns
    minus their projection on the fit's span, by lstsq) and k its rank; over 120 draws the mean
    of S is k within 4 standard errors (sqrt(2k/120)) and the whole family's p-values (``p_full``)
    pass a Kolmogorov-Smirnov test of uniformity at 0.001; with estimated noise (the F form) too.
    The family's ``p_value`` (Bonferroni over the family and its blocks) rejects at 0.05 in at most
    5 % of the 600 family draws plus 3 binomial SD (Bonferroni is conservative)."""
    rng = np.random.default_rng(20261125)
    n = example.n_visits
    sigma = np.tile(rng.uniform(0.5, 2.0, size=3), (n, 1))      # unequal per-output noise
    basis = generic_basis(example, sigma)
    assert set(basis) == set(FAMILIES)
    J = _core_columns(example, sigma)
    Q = _hat_q(J)
    S = {f: [] for f in FAMILIES}
    p = {f: [] for f in FAMILIES}
    p_est = {f: [] for f in FAMILIES}
    p_comb = []
    k_of = {}
    dof = 3 * n - J.shape[1]
    for i in range(N_DRAWS):
        e = rng.standard_normal(3 * n)
        r = e - Q @ (Q.T @ e)
        if i < 3:
            for f, t in generic_tests(basis, r, J, True, dof, Q).items():
                Bt = basis[f] - J @ np.linalg.lstsq(J, basis[f], rcond=None)[0]
                coef = np.linalg.lstsq(Bt, r, rcond=1e-9)[0]
                assert np.isclose(t["S"], float(r @ (Bt @ coef)), rtol=1e-8), f
                assert t["k"] == np.linalg.matrix_rank(Bt, tol=1e-6 * np.linalg.norm(Bt, 2)), f
                assert np.isclose(t["p_full"], stats.chi2.sf(t["S"], t["k"]), rtol=1e-8), f
        for f, t in generic_tests(basis, r, J, True, dof, Q).items():
            S[f].append(t["S"])
            p[f].append(t["p_full"])
            p_comb.append(t["p_value"])
            k_of[f] = t["k"]
        s = np.sqrt(r @ r / dof)                                  # estimated noise: r / s, as the fits do
        for f, t in generic_tests(basis, r / s, J / s, False, dof, Q).items():
            p_est[f].append(t["p_full"])
    # the example campaign has one branch per setpoint block and no drift of its own: every family
    # keeps columns outside the bias/scale span
    assert set(k_of) == set(FAMILIES)
    for f in FAMILIES:
        k = k_of[f]
        assert abs(np.mean(S[f]) - k) < 4 * np.sqrt(2 * k / N_DRAWS), (f, k, np.mean(S[f]))
        assert stats.kstest(p[f], "uniform").pvalue > 1e-3, f
        assert stats.kstest(p_est[f], "uniform").pvalue > 1e-3, f
    rate = np.mean(np.array(p_comb) < 0.05)
    assert rate <= 0.05 + 3 * np.sqrt(0.05 * 0.95 / len(p_comb)), rate


def test_a_pattern_in_the_model_span_costs_nothing_and_one_outside_it_is_found(example):
    """A bias and scale error (in the fitted span) leaves S = 0 up to rounding; a cubic temperature
    dependence of the z bias, 3 noise SDs at the range's ends (no noise added), is found by the
    temperature family with p < 1e-6."""
    n = example.n_visits
    sigma = np.ones((n, 3))
    basis = generic_basis(example, sigma)
    J = _core_columns(example, sigma)
    Q = _hat_q(J)
    r_span = J @ np.arange(1.0, 7.0)
    r_span = r_span - Q @ (Q.T @ r_span)
    for t in generic_tests(basis, r_span, J, True, 3 * n - 6, Q).values():
        assert t["S"] < 1e-12
    T = example.t.mean(axis=1)
    u = (2 * T - (T.max() + T.min())) / (T.max() - T.min())
    bump = np.zeros((n, 3))
    bump[:, 2] = 3.0 * u ** 3
    r = bump.reshape(-1) - Q @ (Q.T @ bump.reshape(-1))
    out = generic_tests(basis, r, J, True, 3 * n - 6, Q)
    assert out["temperature"]["p_value"] < 1e-6


def _koenker_power(V, scale, alpha=0.01, draws=20000):
    """Koenker's N R^2 (generic.variance_test) against a noise SD ``scale`` (3n,) per residual, by
    the central limit of the projection: ``y = z^2`` has the mean ``scale^2`` and the variance
    ``2 scale^4``; its projection ``x`` on an orthonormal basis ``U`` of the basis' centred span
    (rank ``k``) is about normal with the mean ``U' y_c`` and the covariance ``U' diag(2 scale^4) U``,
    and N R^2 is about ``|x|^2`` over the variance of ``y`` (noise and signal). The probability that
    it passes the chi2_k quantile, from normal draws of ``x`` (a fixed seed). The skew of z^2 makes
    the test's real power higher than this (0.93, 0.88 and 0.93 measured over 2000 draws on the
    basis' rank 18 where this gives 0.88, 0.80 and 0.88): a conservative bound. Leverages
    neglected (6 of 540 here)."""
    B = V.reshape(-1, 3, V.shape[1])
    B = (B - B.mean(axis=0)).reshape(V.shape[0], -1)
    norms = np.linalg.norm(B, axis=0)
    keep = norms > 1e-9 * norms.max()
    U, sv, _ = np.linalg.svd(B[:, keep] / norms[keep], full_matrices=False)
    U = U[:, :int(np.sum(sv > 1e-8 * sv[0]))]
    y = (scale ** 2).reshape(-1, 3)
    y = (y - y.mean(axis=0)).reshape(-1)
    var_y = 2.0 * scale ** 4
    L = np.linalg.cholesky(U.T @ (U * var_y[:, None]))
    x = (U.T @ y)[:, None] + L @ np.random.default_rng(0).standard_normal((U.shape[1], draws))
    S = np.sum(x * x, axis=0) / (float(np.mean(var_y)) + float(np.mean(y * y)))
    return float(np.mean(S > stats.chi2.ppf(1.0 - alpha, U.shape[1])))


def test_the_variance_family_is_calibrated_under_normal_and_heavy_tailed_noise(example):
    """Koenker's test (generic.variance_test) on residuals of the linear fit of pure noise: the
    rejection rate at 0.01 over 400 draws stays within 4.5 binomial SD of 0.01 for normal noise and
    for a Student-t with 5 dof (its heavy tails must not read as a pose-dependent scatter). Three
    scatters (made with numpy, not the model's terms) are found at the same level at least as often
    as Koenker's noncentral power (_koenker_power) less 3 binomial SD of 400 draws:

    * of the form a positioning error gives: an output's SD x 1.6 on the poses where gravity is
      across it (1 - g_a^2 = 1: a rotation moves the outputs across gravity); on the basis' rank
      18 (6 pose, 6 temperature, 6 time columns on this campaign) the bound is 0.88;
    * a noise that grows with temperature: every output's SD x 2 at the hottest soak (12 of 180
      visits); the bound is 0.80. Without the temperature columns: 0 of 400;
    * a noise that grows with time: every output's SD from x1 at the first visit to x2 at the last,
      linearly; the bound is 0.88."""
    from triadcal.judgement.diagnose.generic import variance_basis, variance_test

    rng = np.random.default_rng(7)
    sigma = np.ones((example.n_visits, 3))
    J = _core_columns(example, sigma)
    Q = _hat_q(J)
    h = np.sum(Q * Q, axis=1)
    V = variance_basis(example)
    g = np.asarray(_nominal_g(example), float).reshape(-1, 3)
    T = example.t.mean(axis=1)
    time = np.asarray(example.time_s, float)

    def rate(draw):
        hits = 0
        for _ in range(400):
            e = draw()
            r = e - Q @ (Q.T @ e)
            hits += variance_test(r, h, V)["p_value"] < 0.01
        return hits / 400

    sd = np.sqrt(0.01 * 0.99 / 400)
    n3 = 3 * example.n_visits
    assert abs(rate(lambda: rng.standard_normal(n3)) - 0.01) <= 4.5 * sd
    assert abs(rate(lambda: stats.t.rvs(5, size=n3, random_state=rng)) - 0.01) <= 4.5 * sd
    for scale in ((1.0 + 0.6 * (1.0 - g ** 2)).reshape(-1),
                  np.repeat(np.where(T >= T.max() - 1.0, 2.0, 1.0), 3),
                  np.repeat(1.0 + (time - time.min()) / np.ptp(time), 3)):
        power = _koenker_power(V, scale)
        assert power > 0.7
        assert rate(lambda: rng.standard_normal(n3) * scale) >= power - 3.0 * np.sqrt(power * (1 - power) / 400)


def test_a_cubic_law_about_the_reference_temperature_lies_in_one_block(example):
    """The temperature family's powers are a Taylor series about the model's reference T0: a cubic
    angle law ``(T - T0)^3 g_x`` on output y (no noise; hand-made, not the model's term) lies in
    the span of the ``u^3``-on-another-output block, so that block's S equals the whole family's
    S (the residual's part outside the bias/scale span) on its 6 columns; centred on the
    campaign's mid-range (``T0=None``, as before) the same law is spread over the u, u^2 and u^3
    blocks and the u^3 block holds less of it (0.93 of it here). The family's span is the same
    either way."""
    from triadcal.judgement.diagnose.generic import _one_test, block_columns

    n = example.n_visits
    sigma = np.ones((n, 3))
    J = _core_columns(example, sigma)
    Q = _hat_q(J)
    T = example.t.mean(axis=1)
    T0 = 20.0
    assert abs(0.5 * (T.max() + T.min()) - T0) > 1.0       # the two centres differ on this campaign
    g = np.asarray(_nominal_g(example), float).reshape(n, 3)
    bump = np.zeros((n, 3))
    bump[:, 1] = ((T - T0) / np.max(np.abs(T - T0))) ** 3 * g[:, 0] * 4.0
    r = bump.reshape(-1) - Q @ (Q.T @ bump.reshape(-1))
    held = {}
    for centre in (T0, None):
        B = generic_basis(example, sigma, centre)["temperature"]
        per = B.shape[1] // 3
        S_full = generic_tests({"temperature": B}, r, J, True, 3 * n - 6, Q)["temperature"]["S"]
        cube_other = [cols for cols in block_columns("temperature", per)
                      if len(cols) == 6 and all(c % per in (9, 10, 11) for c in cols)]
        assert len(cube_other) == 1
        S_blk = _one_test(r, B[:, cube_other[0]], Q, True, 3 * n - 6)[0]
        held[centre] = (S_blk, S_full)
    S_blk, S_full = held[T0]
    assert S_full > 100.0
    assert np.isclose(S_blk, S_full, rtol=1e-9)
    assert np.isclose(held[None][1], S_full, rtol=1e-5)          # the same span (rounding of the SVD)
    assert held[None][0] < 0.95 * S_full                         # 0.927 on this campaign


def test_the_serial_test_by_hand():
    """generic.serial_test on numbers worked by hand. Three visits out of time order (times 20, 0,
    10 s): in time order they are visits 1, 2, 0, so the sum of adjacent products is, per output,
    z_1 z_2 + z_2 z_0: 0.5 * 2 + 2 * 1 = 3, -1 * 1 + 1 * 2 = 1, 2 * 1 + 1 * (-1) = 1; 5 in all, and
    z'z = 1 + 4 + 1 + 0.25 + 1 + 4 + 4 + 1 + 1 = 17.25, so rho = 5 / 17.25. With no fitted parameter
    (P = I, nu = 9) tr M = 0 and tr M^2 = tr A^2 = 6 x 1/4 + 6 x 1/4 = 3 (n - 1) / 2 = 3: the mean
    is 0 and the variance 2 x 3 / (9 x 11)."""
    from triadcal.judgement.diagnose.generic import serial_test

    z = np.array([[1.0, 2.0, -1.0],      # visit 0 (t = 20 s)
                  [0.5, -1.0, 2.0],      # visit 1 (t = 0 s)
                  [2.0, 1.0, 1.0]])      # visit 2 (t = 10 s)
    out = serial_test(z.reshape(-1), np.zeros((9, 0)), [20.0, 0.0, 10.0], min_visits=3)
    rho = 5.0 / 17.25
    zr = rho / np.sqrt(6.0 / 99.0)
    assert np.isclose(out["rho"], rho) and np.isclose(out["z"], zr)
    assert np.isclose(out["p_value"], 2.0 * stats.norm.sf(zr))
    assert out["k"] == 1 and np.isclose(out["S"], zr * zr)
    assert serial_test(np.ones(6), np.zeros((6, 0)), [0.0, 1.0], min_visits=2) is None   # 3 at the least
    assert serial_test(z.reshape(-1), np.zeros((9, 0)), [20.0, 0.0, 10.0]) is None     # SERIAL_MIN_VISITS


def test_the_serial_test_is_calibrated_and_finds_an_over_whitening(example):
    """The lag-one test of whitened residuals (generic.serial_test, run after a flicker_noise refit)
    on the linear fit of pure noise on the example's bias and scale columns: over 2000 draws the
    standardised statistic has mean 0 and variance 1 within 4 standard errors (its moments are
    exact), and the rejection rate at 0.01 is within 4.5 binomial SD of 0.01. Then the case it is
    for: white noise whitened by a 1/f covariance it does not have (``L^-1 e``, ``L`` the Cholesky
    factor of ``I + tau G``, ``G`` the flicker's covariance of the example's visits, ``tau`` ten
    times the white variance at the mean visit), refitted in the whitened space: adjacent visits are
    then anti-correlated, by ``tr(A Sigma) / tr(Sigma)`` = -0.28 on the example (``Sigma`` their
    covariance; -0.006 under the null, with an SD of 0.043: 6.4 SD): found in at least 390 of 400
    draws, each with a negative statistic. The scale of the whitened residuals does not enter: the
    same draws multiplied by 10 give the same statistic."""
    from triadcal.estimation.flicker_noise import AxisWhitening, normalised_components
    from triadcal.judgement.diagnose.generic import serial_test

    rng = np.random.default_rng(11)
    n = example.n_visits
    sigma = np.ones((n, 3))
    J = _core_columns(example, sigma)
    Q = _hat_q(J)
    zs, hits = [], 0
    for _ in range(2000):
        e = rng.standard_normal(3 * n)
        out = serial_test(e - Q @ (Q.T @ e), Q, example.time_s)
        zs.append(out["z"])
        hits += out["p_value"] < 0.01
    zs = np.array(zs)
    assert abs(zs.mean()) < 4.0 / np.sqrt(zs.size)
    assert abs(zs.var() - 1.0) < 4.0 * np.sqrt(2.0 / zs.size)
    assert abs(hits / 2000 - 0.01) <= 4.5 * np.sqrt(0.01 * 0.99 / 2000)

    G = normalised_components(example, sigma)
    W = AxisWhitening(G, [10.0 / float(np.mean(np.diag(G[0])))] * 3, example.time_s)
    Qw = _hat_q(W.apply(J))
    P = np.eye(3 * n) - Qw @ Qw.T
    Linv = W.apply(np.eye(3 * n))
    Sigma = P @ Linv @ Linv.T @ P
    order = np.argsort(example.time_s, kind="stable")
    A = np.zeros((3 * n, 3 * n))
    for a in range(3):
        rows = 3 * order + a
        A[rows[:-1], rows[1:]] = A[rows[1:], rows[:-1]] = 0.5
    assert -0.3 < float(np.trace(A @ Sigma) / np.trace(Sigma)) < -0.25
    hits, neg = 0, 0
    for _ in range(400):
        r = P @ (Linv @ rng.standard_normal(3 * n))
        out = serial_test(r, Qw, example.time_s)
        assert np.isclose(serial_test(10.0 * r, Qw, example.time_s)["z"], out["z"])
        hits += out["p_value"] < 0.01
        neg += out["z"] < 0
    assert hits >= 390 and neg == 400, (hits, neg)


def test_a_column_almost_in_the_span_is_not_scored_for_a_candidate():
    """candidates._score_mean by hand: a column equal to one of the span's plus 1e-6 of an
    orthogonal one has rank 1 for the generic families (any direction orthogonal to the span is a
    valid test) but 0 for a candidate (SPAN_FRACTION_MIN: its parameter could not move); with 0.1
    of it, both test it, and S is the squared projection of r on the orthogonal direction."""
    from types import SimpleNamespace

    from triadcal.judgement.diagnose.candidates import SPAN_FRACTION_MIN, _score_mean

    e = np.eye(6)
    Q = e[:, :2]
    r = np.array([0.0, 0.0, 3.0, 1.0, 0.0, 0.0])
    state = SimpleNamespace(r=r)
    tiny = (e[:, 0] + 1e-6 * e[:, 2])[:, None]
    assert _score_mean(state, tiny, Q) == (pytest.approx(9.0), 1)
    assert _score_mean(state, tiny, Q, SPAN_FRACTION_MIN) is None
    some = (e[:, 0] + 0.1 * e[:, 2])[:, None]
    assert _score_mean(state, some, Q, SPAN_FRACTION_MIN) == (pytest.approx(9.0), 1)


@pytest.mark.parametrize("c", [2, 3])
def test_a_soak_family_is_its_columns_split_by_soak(example, c):
    """generic.soak_basis by hand, for the tilt's two columns and the scales' three: c columns a
    setpoint block, column c k + j the j-th column on block k's rows and zero elsewhere, summing to
    the constant parameters' columns; None on one soak."""
    from triadcal.judgement.diagnose.generic import soak_basis

    rng = np.random.default_rng(3)
    n = example.n_visits
    Jc = rng.standard_normal((3 * n, c))
    B = soak_basis(example, Jc)
    blocks = example.setpoint_blocks
    m = int(blocks.max()) + 1
    assert m > 1 and B.shape == (3 * n, c * m)
    np.testing.assert_array_equal(B.reshape(3 * n, m, c).sum(axis=1), Jc)
    for k in range(m):
        rows = np.repeat(blocks == k, 3)
        np.testing.assert_array_equal(B[rows, c * k:c * k + c], Jc[rows])
        assert not B[~rows, c * k:c * k + c].any()
    one = blocks == blocks[0]
    assert soak_basis(example.select(one), Jc[np.repeat(one, 3)]) is None


def test_the_scale_family_is_tested_on_the_whole_and_on_each_axis(example):
    """The ``scale`` family's p: Bonferroni over the whole family and its three axes, each the score
    test by least squares written here (chi2 with the projected rank as dof)."""
    from triadcal.judgement.diagnose.generic import soak_basis

    rng = np.random.default_rng(5)
    n = example.n_visits
    JK = rng.standard_normal((3 * n, 3))
    B = soak_basis(example, JK)
    m = int(example.setpoint_blocks.max()) + 1
    # a fitted model that holds the constant scales; a scale of x off at the second soak
    J = np.column_stack([JK, rng.standard_normal((3 * n, 4))])
    e = rng.standard_normal(3 * n) + 0.8 * B[:, 3 * 1 + 0]
    Q = _hat_q(J)
    r = e - Q @ (Q.T @ e)

    def by_hand(cols):
        X = B[:, cols] - Q @ (Q.T @ B[:, cols])
        beta, *_ = np.linalg.lstsq(X, r, rcond=None)
        S = float(r @ (X @ beta))
        return S, stats.chi2.sf(S, np.linalg.matrix_rank(X))

    whole = by_hand(list(range(3 * m)))
    axes = [by_hand(list(range(a, 3 * m, 3))) for a in range(3)]
    t = generic_tests({"scale": B}, r, J, True, r.size - J.shape[1], Q)["scale"]
    assert t["k"] == 3 * (m - 1) and t["S"] == pytest.approx(whole[0], rel=1e-9)
    assert t["p_full"] == pytest.approx(whole[1], rel=1e-9)
    assert t["p_value"] == pytest.approx(min(1.0, 4 * min([whole[1]] + [p for _, p in axes])), rel=1e-9)
    assert axes[0][1] < min(axes[1][1], axes[2][1])       # the axis it was put on


def test_the_scale_family_keeps_its_size(example):
    """The ``scale`` family's p on residuals of the linear fit of pure noise (the example's design, its
    own scale columns split by soak), 1000 draws: rejections at 5 % within the binomial bound of a
    test of size at most 5 % (Bonferroni over the family and its axes is conservative)."""
    from triadcal.judgement.diagnose.generic import soak_basis

    rng = np.random.default_rng(11)
    n = example.n_visits
    JK = rng.standard_normal((3 * n, 3))
    J = np.column_stack([JK, rng.standard_normal((3 * n, 6))])
    B = soak_basis(example, JK)
    Q = _hat_q(J)
    hits = 0
    for _ in range(1000):
        e = rng.standard_normal(3 * n)
        r = e - Q @ (Q.T @ e)
        hits += generic_tests({"scale": B}, r, J, True, r.size - J.shape[1], Q)["scale"]["p_value"] < 0.05
    print("scale family, rejections at 5 %:", hits, "of 1000")
    assert hits <= stats.binom.ppf(0.999, 1000, 0.05), hits
    # and not a test that never rejects: the whole family alone rejects at 5 % / 4 under the null
    assert hits >= stats.binom.ppf(0.001, 1000, 0.05 / 4), hits


@pytest.mark.slow          # 5-10 s: slow since the thirteenth session (the quick suite's 10 min)
def test_the_tests_that_tell_positioning_errors_from_heavy_tails_are_calibrated(example):
    """generic.position_variance_test (asked after heavy_tails' refit) and generic.tails_test (after
    position_error's) on residuals of the linear fit of pure noise, 1000 draws each: the rejection
    rate at 0.01 within 4.5 binomial SD of 0.01 for normal noise, and for the position test also
    under a Student-t with 5 dof (Koenker's studentisation). Power, from theory:

    * the position test on a scatter of the positioning errors' form (every output's SD x 1.6 where
      gravity lies across it, w = 1 - g_a^2): its mean is ``mu = wc'E[y] / sqrt(wc'wc var y)``
      (``E y_i = s_i^2``, ``var y_i = 2 s_i^4`` for normal residuals), so it rejects at least as often
      as ``Phi(mu - z_0.99)`` less 3 binomial SD (the leverages make E y a little smaller: the bound
      is on the conservative side);
    * the tails test under a Student-t with 5 dof (excess kurtosis 6: D'Agostino's statistic near 9
      on these 540 residuals) rejects in at least 95 % of draws; under a uniform spread of the errors
      (lighter tails than a normal's, what uniform positioning errors make) at most at its level."""
    from triadcal.judgement.diagnose.generic import position_variance_test, tails_test

    rng = np.random.default_rng(11)
    sigma = np.ones((example.n_visits, 3))
    J = _core_columns(example, sigma)
    Q = _hat_q(J)
    h = np.sum(Q * Q, axis=1)
    g = np.asarray(_nominal_g(example), float).reshape(-1, 3)
    w = (1.0 - g ** 2).reshape(-1)
    n3 = 3 * example.n_visits
    N = 1000

    def rate(test, draw):
        hits = 0
        for _ in range(N):
            e = draw()
            r = e - Q @ (Q.T @ e)
            hits += test(r) < 0.01
        return hits / N

    pos = lambda r: position_variance_test(r, h, w)["p_value"]  # noqa: E731
    tails = lambda r: tails_test(r, h)["p_value"]  # noqa: E731
    sd = np.sqrt(0.01 * 0.99 / N)
    assert abs(rate(pos, lambda: rng.standard_normal(n3)) - 0.01) <= 4.5 * sd
    assert abs(rate(pos, lambda: stats.t.rvs(5, size=n3, random_state=rng)) - 0.01) <= 4.5 * sd
    assert abs(rate(tails, lambda: rng.standard_normal(n3)) - 0.01) <= 4.5 * sd

    s = 1.0 + 0.6 * w
    wc = w - w.mean()
    Ey = s ** 2
    vy = np.mean(2.0 * s ** 4) + np.var(Ey)
    mu = float(wc @ (Ey - Ey.mean())) / np.sqrt(float(wc @ wc) * vy)
    power = float(stats.norm.cdf(mu - stats.norm.isf(0.01)))
    assert power > 0.9
    assert rate(pos, lambda: rng.standard_normal(n3) * s) >= power - 3.0 * np.sqrt(power * (1 - power) / N)
    assert rate(tails, lambda: stats.t.rvs(5, size=n3, random_state=rng)) >= 0.95
    assert rate(tails, lambda: rng.uniform(-1.0, 1.0, n3)) <= 0.01 + 4.5 * sd
