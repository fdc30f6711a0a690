"""The joint fit with the quantisation of a digital output (``fit --effects ...,quantisation``).

The expected visit-mean error of an output rounded to an LSB q
(:func:`triadcal.models.effects.quantisation.expected_error`) is added to the model's outputs
after eq. 1 (``JointProblem(output_map=...)``: ``W -> W + e(W; q, sigma)``, the Jacobian times
``1 + de/dW``). q is one LSB common to the three outputs, in the campaign's output unit; it is
given (``--quantisation-lsb``) or profiled over :func:`q_grid`.

The per-sample noise sigma comes from the data (:func:`sample_sigma_of`): from the ``sd_*`` of
each axis, the sigma whose variance of rounded samples at the visits' outputs
(:func:`~triadcal.models.effects.quantisation.rounded_variance`, exact; Sheppard's sigma^2 + q^2/12
only on average over x) matches the mean of sd^2 (the SD of rounded samples holds the rounding), else ``sqrt(Q_V2s f_s)`` with the sample rate ``f_s = n_samples / tau_s``; without
either it is unknown and the term cannot be evaluated.

**The profile of q is rough.** The error depends on ``W mod q``: an output of |W| >> q changes its
phase by a whole period when q changes by ``q^2 / |W|``, so the chi^2 over q has many narrow minima
and a log grid finds the true q only by luck when |W| >> q. The grid therefore holds the LSB the
data state (metadata ``quantisation_lsb``, output unit) or imply (visit means of N rounded samples
are multiples of q/N: :func:`~triadcal.models.effects.quantisation.resolution_lsb`); the log grid
covers the damped range, where it matters for outputs within a few q of 0.
"""

from __future__ import annotations

import copy
import math
from typing import Optional, Sequence

import numpy as np

from ..errors import InputError
from ..models.effects import quantisation as qz

#: the nested likelihood ratio a profiled q must pass over the model without it (chi^2, 1 dof)
LEVEL = 0.99
#: log grid of q in units of the smallest per-sample sigma
GRID_LOW, GRID_HIGH, GRID_POINTS = 0.5, 300.0, 40


def sample_sigma_of(campaign, q: float):
    """Per-sample noise SD before rounding, per axis (3,), output unit, and where it came from;
    ``(None, reason)`` when the data give none."""
    if campaign.sd is not None:
        sd = np.asarray(campaign.sd, float)
        if q <= 0:
            return np.sqrt(np.mean(sd ** 2, axis=0)), "pooled sd_* of each axis"
        return (qz.sigma_from_sample_sd(sd, campaign.w, q),
                "sd_* of each axis: the sigma whose variance of rounded samples at the visits' outputs "
                "matches their mean sd^2")
    Q = campaign.metadata.get("Q_V2s")
    if Q is not None and campaign.n_samples is not None:
        fs = float(np.median(np.asarray(campaign.n_samples, float) / np.asarray(campaign.tau_s, float)))
        s = math.sqrt(float(Q) * fs)
        return np.full(3, s), f"sqrt(Q_V2s f_s), f_s = n_samples/tau_s = {fs:g} Hz"
    return None, ("the per-sample noise is unknown (no sd_* columns, no Q_V2s with n_samples): the "
                  "quantisation error cannot be evaluated")


def stated_lsb(campaign) -> tuple[Optional[float], str]:
    """The LSB the campaign states (metadata ``quantisation_lsb``, output unit) or its visit means
    imply (:func:`resolution_lsb`); ``(None, '')`` when neither."""
    v = campaign.metadata.get("quantisation_lsb")
    if v is not None:
        try:
            q = float(v)
        except ValueError:
            raise InputError(f"{campaign.source or 'campaign'}: metadata quantisation_lsb = {v!r} is not a number")
        if q > 0 and math.isfinite(q):
            return q, "metadata quantisation_lsb"
    if campaign.n_samples is not None:
        q = qz.resolution_lsb(campaign.w, campaign.n_samples)
        if q is not None:
            return q, "resolution of the visit means (N w multiples of q)"
    return None, ""


def sheppard_sigma(campaign):
    """A cheap sigma(q) for ranking a profile: Sheppard's sigma^2 = mean(sd^2) - q^2/12 per axis (the
    rounding's variance on average over the output), at least (q/20)^2; None without ``sd_*``. The
    exact inversion (:func:`sample_sigma_of`) is for the refit."""
    if campaign.sd is None:
        return None
    v = np.mean(np.asarray(campaign.sd, float) ** 2, axis=0)
    return lambda q: np.sqrt(np.maximum(v - q * q / 12.0, (q / 20.0) ** 2))


def output_map(q: float, sigma):
    """The output map of ``JointProblem`` for an LSB ``q`` and per-sample SDs ``sigma`` (3,) or (n, 3)."""
    s = np.asarray(sigma, float)

    def f(w):
        return qz.expected_error(w, q, s), qz.expected_error_slope(w, q, s)
    return f


def positive_lsb(q) -> float:
    """``--quantisation-lsb`` as a float, or an InputError naming the option (fit, sample)."""
    try:
        v = float(q)
    except (TypeError, ValueError):
        raise InputError(f"--quantisation-lsb must be a positive number in the output unit, got {q!r}") from None
    if not (v > 0 and math.isfinite(v)):
        raise InputError(f"--quantisation-lsb must be a positive number in the output unit, got {q!r}")
    return v


def noise_effects_map(campaign, effects: Sequence[str], lsb: Optional[float]):
    """The output map the noise effects among ``effects`` are estimated with when the output is
    quantised (``{"output_map": ...}`` for ``resolve_noise_effects``; ``{}`` without noise effects).

    ``position_error``, ``heavy_tails`` and ``flicker_noise`` are estimated from the residuals of a
    fit of the mean; without the rounding term in that fit they absorb its misfit (a rounded campaign
    with ``position_error``: sigma_1 = 8591 arcsec and chi^2/dof 0.163 after, the rounding taken for
    bench scatter; with the term 0.30 +- 1.44 arcsec, chi^2/dof 1.05: tests/test_sample_quantisation.py).
    So they are estimated with the term, which needs q first: given (``--quantisation-lsb``), else
    refused (a profile of q with the noise effect re-estimated at every q is not written)."""
    from .noise_effects import split_effects

    noise = split_effects(effects)[1]
    if not noise:
        return {}
    if lsb is None:
        raise InputError(f"quantisation with {', '.join(noise)}: give --quantisation-lsb (the LSB in the output "
                         f"unit). The noise effect is estimated from the residuals of the fit with the rounding "
                         "term, which needs q; with q profiled it would absorb the rounding's misfit")
    lsb = positive_lsb(lsb)
    s, why = sample_sigma_of(campaign, lsb)
    if s is None:
        raise InputError(f"{campaign.source or 'campaign'}: {why}")
    return {"output_map": output_map(lsb, s)}


def q_grid(campaign, extra=()) -> np.ndarray:
    """q over GRID_LOW ... GRID_HIGH times the smallest per-sample SD (Sheppard's correction
    evaluated at q = 0), log-spaced, plus ``extra`` (the stated LSB)."""
    s, _ = sample_sigma_of(campaign, 0.0)
    if s is None:
        return np.array(sorted(extra), float)
    s0 = float(np.min(s[s > 0])) if np.any(s > 0) else 1.0
    g = np.geomspace(GRID_LOW * s0, GRID_HIGH * s0, GRID_POINTS)
    return np.unique(np.concatenate([g, np.asarray(list(extra), float)]))


def refine_q(problem, x_full: np.ndarray, cols: np.ndarray, campaign, grid, chi2, max_points: int = 2000):
    """The best q of a coarse profile refined between its grid neighbours: chi^2 varies with q on the
    scale ``q^2 / max|W|`` (the phase of the largest output), so the neighbours' interval is searched on
    a log grid of relative step ``q / (4 max|W|)`` (at most ``max_points``), sigma held at the coarse
    best's. Returns ``(q, chi2)``; the coarse best when the grid has fewer than 3 points."""
    i = int(np.argmin(chi2))
    if len(grid) < 3 or not np.isfinite(chi2[i]):
        return float(grid[i]), float(chi2[i])
    lo, hi = float(grid[max(i - 1, 0)]), float(grid[min(i + 1, len(grid) - 1)])
    wmax = float(np.max(np.abs(campaign.w)))
    step = max(float(grid[i]) / (4.0 * max(wmax, 1e-300)), 1e-9)
    n = int(min(max_points, max(3, math.ceil(math.log(hi / lo) / step))))
    fine = np.geomspace(lo, hi, n)
    s, _ = sample_sigma_of(campaign, float(grid[i]))
    c = profile_chi2(problem, x_full, cols, campaign, fine, sigma=s)
    j = int(np.argmin(c))
    if c[j] < chi2[i]:
        return float(fine[j]), float(c[j])
    return float(grid[i]), float(chi2[i])


def profile_chi2(problem, x_full: np.ndarray, cols: np.ndarray, campaign, grid, sigma=None) -> np.ndarray:
    """chi^2 after one Gauss-Newton step from ``x_full`` (the model without the term, its fitted
    columns ``cols``) at every q of ``grid``: the model is linear enough in the other parameters
    for the ranking; the chosen q is refitted in full. ``sigma``: the per-sample SDs (3,), a function
    of q giving them, or None for :func:`sample_sigma_of` at each q."""
    p0 = copy.copy(problem)
    p0.output_map = None
    r0, J0 = p0.residuals_and_jacobian(x_full)
    J0 = J0[:, cols]
    norm = np.linalg.norm(J0, axis=0)
    J0 = J0[:, norm > 0] / norm[norm > 0]          # unit columns: the normal equations stay conditioned
    sig = problem.sigma.reshape(-1)
    w0 = (campaign.w.reshape(-1) - r0 * sig)
    out = np.full(len(grid), np.inf)
    for i, q in enumerate(grid):
        s = sigma(q) if callable(sigma) else (sigma if sigma is not None else sample_sigma_of(campaign, q)[0])
        if s is None:
            continue
        sb = np.broadcast_to(np.asarray(s, float), campaign.w.shape).reshape(-1)
        e = qz.expected_error(w0, q, sb)
        de = qz.expected_error_slope(w0, q, sb)
        r = r0 - e / sig
        J = J0 * (1.0 + de)[:, None]
        try:      # normal equations (p x p): far cheaper than an SVD of the (3n x p) Jacobian per q
            step = np.linalg.solve(J.T @ J, -(J.T @ r))
        except np.linalg.LinAlgError:
            step, *_ = np.linalg.lstsq(J, -r, rcond=None)
        rr = r + J @ step
        out[i] = float(rr @ rr)
    return out


def criterion(chi2_without: float, chi2_with: float, n_obs: int, noise_known: bool, k: int = 1):
    """Nested likelihood ratio at LEVEL with ``k`` counted parameters (q), or AIC lower by 10 with
    the noise estimated; ``(passes, text)``."""
    from .hysteresis_form import nested_criterion

    return nested_criterion(chi2_without, chi2_with, k, n_obs, noise_known, "chi2_without - chi2_with",
                            level=LEVEL, aic_margin=10.0)


def fit_quantisation(campaign, effects: Sequence[str], lsb: Optional[float] = None, **kwargs):
    """The joint fit with the quantisation term: ``lsb`` (output unit) given, or profiled over
    :func:`q_grid` (with the stated LSB). Returns ``(result, problem, solution)`` like
    ``fit_joint(return_problem=True)``; ``result.fit['quantisation']`` holds q with its unit, the
    per-sample sigma and its source, the chi^2 without and with the term, the nested criterion and
    the profile. The answer gates apply to the fit with the term as to any fit."""
    from .joint import fit_joint

    kwargs = dict(kwargs, return_problem=True)
    base, problem0, sol0 = fit_joint(campaign, effects, **kwargs)
    chi2_0 = float(np.sum(sol0.r ** 2))
    q_stated, why_stated = stated_lsb(campaign)
    s0, s_source = sample_sigma_of(campaign, 0.0)
    if s0 is None:
        raise InputError(f"{campaign.source or 'campaign'}: {s_source}")
    profile = None
    if lsb is not None:
        q, how = positive_lsb(lsb), "given"
    else:
        grid = q_grid(campaign, [q_stated] if q_stated else [])
        x_full = np.array(sol0.x, float)
        cols = np.arange(len(problem0.names))
        chi2 = profile_chi2(problem0, x_full, cols, campaign, grid)
        q, _ = refine_q(problem0, x_full, cols, campaign, grid, chi2)
        how = "profiled" + (f" (grid with the stated LSB {q_stated:.6g}: {why_stated})" if q_stated else "")
        profile = {"q": [float(v) for v in grid], "chi2_one_step": [float(v) for v in chi2]}
    s, _ = sample_sigma_of(campaign, q)
    result, problem, sol = fit_joint(campaign, effects, output_map=output_map(q, s), **kwargs)
    chi2_q = float(np.sum(sol.r ** 2))
    ok, crit = criterion(chi2_0, chi2_q, sol.r.size, bool(result.fit.get("noise_known")))
    unit = campaign.output_unit
    block = {"lsb": q, "unit": unit, "common_to_axes": True, "how": how,
             "sigma_sample": [float(v) for v in np.broadcast_to(s, (3,))], "sigma_sample_unit": unit,
             "sigma_source": s_source, "stated_lsb": q_stated, "stated_lsb_source": why_stated or None,
             "chi2_without": chi2_0, "chi2_with": chi2_q, "beats_without": ok, "criterion": crit,
             "n_parameters_counted": 1,
             "equation": "E[Q(x+n)] - x = sum_k (q/(pi k)) (-1)^k exp(-2 pi^2 k^2 sigma^2/q^2) sin(2 pi k x/q)",
             "profile": profile}
    result.fit["quantisation"] = block
    result.notes.append(f"quantisation: LSB q = {q:.6g} {unit} ({how}), per-sample sigma "
                        + ", ".join(f"{v:.3g}" for v in block["sigma_sample"]) + f" {unit} ({s_source}); "
                        + crit + ("" if ok else " -- the term does not improve the fit significantly"))
    return result, problem, sol
