"""The vectorised PSIS-LOO of the diagnosis (triadcal.judgement.diagnose.psis) gives arviz.loo's
numbers: on Gaussian, heavy-tailed, scaled, tied and cubed log-likelihoods, for 50 to 1000 draws,
the elpd, its SE, the pointwise values and the Pareto k agree to 1e-9 (float summation order only).
arviz is the independent reference (its own per-observation loop)."""

import warnings
import zlib

import numpy as np
import pytest

from triadcal.judgement.diagnose.psis import psis_log_weights, psis_loo


def _arviz_loo(ll):
    import arviz as az

    rng = np.random.default_rng(0)
    idata = az.from_dict(posterior={"t": rng.normal(size=(1, ll.shape[0]))}, log_likelihood={"obs": ll[None]})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return az.loo(idata, pointwise=True)


def _finite(k):
    k = np.asarray(k, float)
    return np.where(np.isinf(k), 0.0, k)


@pytest.mark.parametrize("kind", ["normal", "student2", "scaled", "ties", "cubed"])
@pytest.mark.parametrize("S", [50, 200, 1000])
def test_psis_loo_equals_arviz(kind, S):
    rng = np.random.default_rng([zlib.crc32(kind.encode()), S])      # fixed seeds (str hash is salted)
    n = 60
    ll = {"normal": lambda: rng.normal(size=(S, n)),
          "student2": lambda: -0.5 * rng.standard_t(2, size=(S, n)) ** 2,
          "scaled": lambda: rng.normal(size=(S, n)) * rng.exponential(5, size=n),
          "ties": lambda: np.round(rng.normal(size=(S, n)), 1),
          "cubed": lambda: -20 * rng.exponential(size=(S, n)) ** 3}[kind]()
    ref = _arviz_loo(ll)
    elpd, se, loo_i, k = psis_loo(ll)
    assert elpd == pytest.approx(float(ref.elpd_loo), rel=1e-12, abs=1e-9)
    assert se == pytest.approx(float(ref.se), rel=1e-9, abs=1e-9)
    np.testing.assert_allclose(loo_i, np.asarray(ref.loo_i), rtol=0, atol=1e-9)
    np.testing.assert_allclose(_finite(k), _finite(ref.pareto_k), rtol=0, atol=1e-9)
    assert np.array_equal(np.isinf(k), np.isinf(np.asarray(ref.pareto_k)))


def test_hand_case_weights_normalise_and_a_flat_row_is_uniform():
    """Equal ratios (a visit no draw moves): every weight 1/S, k of a degenerate tail not finite
    or <= 0.5 (no smoothing needed); every row's weights sum to 1."""
    S = 200
    lr = np.vstack([np.zeros(S), np.random.default_rng(1).normal(size=S)])
    lw, k = psis_log_weights(lr)
    np.testing.assert_allclose(np.exp(lw).sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(lw[0], -np.log(S), atol=1e-12)
    assert k[1] < 0.7
