"""Convergence diagnostics of an ensemble chain: integrated autocorrelation time (emcee),
split R-hat and bulk/tail ESS (arviz, walkers as chains; docs/posterior.md).
"""

from __future__ import annotations

import warnings
from typing import Optional, Sequence

import numpy as np

from .moves import _emcee


def _arviz():
    """arviz, imported on first use (it is slow to import). Where arviz keeps its cache is
    the entry point's choice (``XDG_CACHE_HOME``), never the library's."""
    import arviz as az
    return az


def integrated_time(chain: np.ndarray, c: float = 5.0) -> np.ndarray:
    """emcee's integrated autocorrelation time of a (steps, walkers, d) chain, vectorised.

    The estimator of ``emcee.autocorr.integrated_time`` (Goodman & Weare; Sokal's
    automatic window with ``c = 5``): the normalised autocorrelation of each walker (FFT),
    averaged over walkers, summed up to the first lag ``M >= c tau(M)``. One FFT over
    all walkers and parameters instead of a Python loop; same numbers.
    """
    emcee = _emcee()
    chain = np.asarray(chain, float)
    n, _, d = chain.shape
    nfft = 2 * emcee.autocorr.next_pow_two(n)
    # parameters in groups, so that a long chain does not need gigabytes of FFT buffers
    group = max(1, int(2e7 // (nfft * chain.shape[1])))
    out = np.empty(d)
    for k0 in range(0, d, group):
        x = chain[:, :, k0:k0 + group]
        x = x - x.mean(axis=0, keepdims=True)
        f = np.fft.rfft(x, n=nfft, axis=0)
        acf = np.fft.irfft(f * np.conj(f), n=nfft, axis=0)[:n]
        with np.errstate(invalid="ignore", divide="ignore"):
            acf = acf / acf[0:1]
        rho = np.nan_to_num(acf).mean(axis=1)              # (n, group)
        taus = 2.0 * np.cumsum(rho, axis=0) - 1.0
        for j in range(taus.shape[1]):
            out[k0 + j] = taus[emcee.autocorr.auto_window(taus[:, j], c), j]
    return out


def split_rhat_quick(chain: np.ndarray) -> np.ndarray:
    """Classic split R-hat (Gelman et al. BDA3, walkers as chains), vectorised: a cheap
    screen before arviz's rank-normalised R-hat."""
    n = chain.shape[0] // 2
    parts = np.concatenate([chain[:n], chain[-n:]], axis=1)       # (n, 2W, d)
    w = parts.var(axis=0, ddof=1).mean(axis=0)
    b = n * parts.mean(axis=0).var(axis=0, ddof=1)
    return np.sqrt(((n - 1) / n * w + b / n) / w)


def diagnostics(chain: np.ndarray, names: Sequence[str], tau: Optional[np.ndarray] = None) -> dict:
    """ESS (bulk, tail), rank-normalised split R-hat (walkers as chains, arviz) and emcee's
    integrated autocorrelation time of a (steps, walkers, d) chain."""
    az = _arviz()
    tau = integrated_time(chain) if tau is None else tau
    draws = np.swapaxes(chain, 0, 1)      # (chain=walker, draw, d)
    with warnings.catch_warnings():       # short runs: arviz warns of more chains than draws
        warnings.simplefilter("ignore", UserWarning)
        ds = az.convert_to_dataset({n: draws[:, :, i] for i, n in enumerate(names)})
        ess_b = az.ess(ds, method="bulk")
        ess_t = az.ess(ds, method="tail")
        rhat = az.rhat(ds)
    return {"tau": np.asarray(tau, float),
            "ess_bulk": np.array([float(ess_b[n]) for n in names]),
            "ess_tail": np.array([float(ess_t[n]) for n in names]),
            "rhat": np.array([float(rhat[n]) for n in names])}
