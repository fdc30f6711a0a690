"""The REML of the flicker floor in the eigenbasis of each component (SpectralREML) against the
Cholesky-in-time-order form (reml_pieces, _profiled_ll): the same log-likelihood, score,
information and traces, by algebra (both whiten with a square root of V^-1; they differ by an
orthogonal transformation of the rows). Checked on visits at irregular times, with one white
level per output (proportional components, one eigendecomposition) and with a level per visit
(three), at tau = 0 and at large tau; and the Fisher ascent lands where a direct maximisation of
the Cholesky form's likelihood does."""

import numpy as np
import pytest
from scipy import optimize

from triadcal.estimation import flicker_noise as fl
from triadcal.models.effects.flicker_noise import centred_covariance


def _problem(per_visit_sigma: bool, seed: int = 3, n: int = 60, p: int = 7):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0, 30 * 3600, n)) + np.arange(n) * 10.0
    C = centred_covariance(t, 10.0, 1.0)
    sigma = (rng.uniform(0.5, 2.0, (n, 3)) if per_visit_sigma else np.ones((n, 1)) * np.array([1.0, 1.7, 0.6]))
    G = [C / np.outer(sigma[:, a], sigma[:, a]) for a in range(3)]
    J = rng.normal(size=(3 * n, p))
    tau_true = np.array([0.5, 2.0, 0.1])
    noise = np.concatenate([np.linalg.cholesky(np.eye(n) + tau_true[a] * G[a] + 1e-12 * np.eye(n))
                            @ rng.normal(size=n) for a in range(3)]).reshape(3, n).T.reshape(-1)
    return t, G, J, noise


@pytest.mark.parametrize("per_visit_sigma", [False, True])
@pytest.mark.parametrize("tau", [np.zeros(3), np.array([0.3, 1.5, 40.0])])
@pytest.mark.parametrize("groups", [[[0, 1, 2]], [[0], [1], [2]], [[0, 2], [1]]])
def test_spectral_pieces_equal_the_cholesky_form(per_visit_sigma, tau, groups):
    t, G, J, r = _problem(per_visit_sigma)
    spec = fl.SpectralREML(G, r, J)
    ll0, U0, I0, tr0 = fl.reml_pieces(r, J, G, tau, t, groups, return_trace=True)
    ll1, U1, I1, tr1 = spec.pieces(tau, groups, return_trace=True)
    assert ll1 == pytest.approx(ll0, rel=1e-10, abs=1e-8)
    np.testing.assert_allclose(U1, U0, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(I1, I0, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(tr1, tr0, rtol=1e-9, atol=1e-8)
    pl0, s20 = fl._profiled_ll(r, J, G, tau, t)
    pl1, s21, rank = spec.profiled_ll(tau)
    assert pl1 == pytest.approx(pl0, rel=1e-10, abs=1e-8) and s21 == pytest.approx(s20, rel=1e-10)
    assert rank == J.shape[1]
    # the residuals scaled (the profiled score's r / sqrt(s2))
    _, Us, _ = spec.pieces(tau, groups, r_scale=0.5)
    np.testing.assert_allclose(Us, fl.reml_pieces(0.5 * r, J, G, tau, t, groups)[1], rtol=1e-9, atol=1e-8)


def test_proportional_components_share_one_decomposition():
    t, G, J, r = _problem(False)
    spec = fl.SpectralREML(G, r, J)
    np.testing.assert_allclose(spec.lam[1], spec.lam[0] / 1.7 ** 2, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("per_visit_sigma", [False, True])
def test_reml_tau_lands_at_the_cholesky_likelihoods_maximum(per_visit_sigma):
    """reml_tau (Fisher scoring on the spectral form) against Nelder-Mead on the Cholesky form's
    REML log-likelihood over log tau: the same maximum (to the simplex's tolerance)."""
    t, G, J, r = _problem(per_visit_sigma, n=80)
    groups = [[0], [1], [2]]
    tau, _, _, ll = fl.reml_tau(r, J, G, t, groups)

    def neg(lt):
        return -fl.reml_pieces(r, J, G, np.exp(lt), t, groups)[0]
    res = optimize.minimize(neg, np.log(np.maximum(tau, 1e-3)) + 0.3, method="Nelder-Mead",
                            options={"xatol": 1e-8, "fatol": 1e-10, "maxiter": 4000})
    assert ll >= -res.fun - 1e-6
    np.testing.assert_allclose(tau[tau > 1e-3], np.exp(res.x)[tau > 1e-3], rtol=2e-3)


def test_the_eigendecomposition_of_an_equal_matrix_is_reused_and_of_another_is_not():
    """SpectralREML's eigendecompositions (a diagnosis repeats them on one campaign's kernels):
    an equal matrix (a new array, every element equal) gets the stored result, read-only; a
    matrix one element apart is decomposed again; the values are numpy's."""
    _, G, _, _ = _problem(False, seed=11, n=40)
    A = 0.5 * (G[0] + G[0].T)
    w, V = fl._eigh_cached(A)
    w0, V0 = np.linalg.eigh(A)
    assert np.array_equal(w, w0) and np.array_equal(V, V0)
    w2, V2 = fl._eigh_cached(A.copy())
    assert w2 is w and V2 is V
    assert not V.flags.writeable and not w.flags.writeable
    with pytest.raises(ValueError):
        V[0, 0] = 1.0
    B = A.copy()
    B[3, 5] = B[5, 3] = A[3, 5] + 1e-9
    wb, Vb = fl._eigh_cached(B)
    assert wb is not w and np.array_equal(wb, np.linalg.eigh(B)[0])
