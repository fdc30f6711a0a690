"""Simulation-based calibration (Talts et al. 2018) of the least-squares and posterior intervals.

:func:`sbc` draws campaigns from the prior, simulates them, fits each by least squares and
by the posterior sampler, and returns an :class:`SBCResult` (ranks and coverage, with
``rank_pvalues``, ``coverage_pvalues``, ``pooled_coverage`` and ``summary``); behind
``triadcal validate``. Derivation/design: docs/posterior.md (Simulation-based calibration).
"""

from __future__ import annotations

from ..errors import InputError

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import numpy as np
from scipy import stats

from ..models.campaign import DEFAULT_PLAN
from ..models.effects import DEFAULT_EFFECTS
from ..models.model import Model
from ..models.simulate import NoiseModel, Schedule, Truth, simulate_campaign
from ..estimation.priors import default_priors, draw_parameters

#: compact thermal plan: soak at 20, heat to 60, cool to 20 and -20, heat back to 20
COMPACT_SETPOINTS_C = (20.0, 60.0, 20.0, -20.0, 20.0)
LEVELS = (0.68, 0.95)
METHODS = ("least_squares", "posterior")


def compact_schedule() -> Schedule:
    """12 positions x 5 setpoints with heating and cooling branches (hysteresis identifiable)."""
    return Schedule(setpoints_C=COMPACT_SETPOINTS_C)


@dataclass
class SBCResult:
    """Ranks (0..n_ranks) and coverage indicators of every campaign and parameter."""

    names: tuple
    n_ranks: int
    truths: np.ndarray                 # (N, P), reporting units
    ranks: dict                        # method -> (N, P) float (nan where not available)
    covered: dict                      # method -> level -> (N, P) float 0/1 (nan where not available)
    statuses: list
    seconds: float
    settings: dict = field(default_factory=dict)

    @property
    def n_campaigns(self) -> int:
        return self.truths.shape[0]

    def default_bins(self) -> int:
        """20 bins, fewer for a small run (at least ~5 campaigns per bin expected)."""
        return int(max(2, min(20, self.n_campaigns // 5, self.n_ranks + 1)))

    def rank_pvalues(self, method: str, bins: Optional[int] = None) -> np.ndarray:
        """Chi-square p-value of each parameter's rank histogram (``bins`` equal bins of ranks)."""
        bins = bins or self.default_bins()
        r = self.ranks[method]
        out = np.full(len(self.names), np.nan)
        edges = np.linspace(0, self.n_ranks + 1, bins + 1)
        for k in range(len(self.names)):
            x = r[:, k][np.isfinite(r[:, k])]
            if len(x) < bins:
                continue
            counts, _ = np.histogram(x, bins=edges)
            out[k] = stats.chisquare(counts).pvalue
        return out

    def coverage(self, method: str, level: float) -> np.ndarray:
        """Fraction of campaigns whose interval covers the truth, per parameter."""
        return np.nanmean(self.covered[method][level], axis=0)

    def pooled_coverage(self, method: str, level: float) -> float:
        return float(np.nanmean(self.covered[method][level]))

    def coverage_pvalues(self, method: str, level: float) -> np.ndarray:
        """Two-sided binomial test of each parameter's coverage against the nominal level."""
        c = self.covered[method][level]
        out = np.full(len(self.names), np.nan)
        for k in range(len(self.names)):
            x = c[:, k][np.isfinite(c[:, k])]
            if len(x):
                out[k] = stats.binomtest(int(x.sum()), len(x), level).pvalue
        return out

    def summary(self, alpha: float = 0.01, bins: Optional[int] = None) -> dict:
        """The numbers a reader checks, per method (JSON-ready)."""
        P = len(self.names)
        bins = bins or self.default_bins()
        out = {"format": "triadcal.sbc", "version": 1, "n_campaigns": self.n_campaigns, "n_ranks": self.n_ranks,
               "parameters": list(self.names), "seconds": self.seconds, "settings": self.settings,
               "failed": sum(1 for s in self.statuses if s != "ok"), "alpha": alpha, "bins": bins,
               "methods": {}}
        for m in METHODS:
            p = self.rank_pvalues(m, bins)
            pmin = float(np.min(p)) if np.all(np.isfinite(p)) else float("nan")
            d = {"rank_chi2_p": dict(zip(self.names, map(_f, p))),
                 "rank_min_p": _f(pmin),
                 "rank_n_below_alpha": int(np.sum(p < alpha)), "rank_expected_below_alpha": alpha * P,
                 "rank_uniform_bonferroni": bool(pmin > alpha / P)}
            for level in LEVELS:
                cov = self.coverage(m, level)
                pv = self.coverage_pvalues(m, level)
                key = f"{round(level * 100)}"
                d[f"coverage_{key}"] = dict(zip(self.names, map(_f, cov)))
                d[f"coverage_{key}_pooled"] = self.pooled_coverage(m, level)
                d[f"coverage_{key}_range"] = [_f(np.nanmin(cov)), _f(np.nanmax(cov))]
                d[f"coverage_{key}_binomial_min_p"] = _f(np.nanmin(pv))
                d[f"coverage_{key}_n_outside_0.03"] = int(np.sum(np.abs(cov - level) > 0.03))
            out["methods"][m] = d
        return out


def _f(x) -> Optional[float]:
    x = float(x)
    return x if math.isfinite(x) else None


def _one_campaign(task) -> dict:
    """Everything SBC needs from campaign ``i`` (runs in a worker process)."""
    i, seed, effects, schedule, plan, n_ranks, ess, max_steps = task
    from ..estimation.joint import fit_joint
    from ..estimation.posterior import integrated_time, sample

    rng = np.random.default_rng([seed, i])
    model = Model(effects)
    priors = default_priors(model)
    truth_params = draw_parameters(priors, rng)
    truth = Truth(unit=f"SBC-{i:04d}", effects=tuple(effects), parameters=truth_params,
                  noise=NoiseModel(temp_noise_C=0.0))
    campaign = simulate_campaign(truth, plan=plan, schedule=schedule, seed=int(rng.integers(2 ** 31)))
    names = model.names
    theta = np.array([truth_params[n] for n in names])
    P = len(names)
    out = {"theta": theta, "ranks": {m: np.full(P, np.nan) for m in METHODS},
           "covered": {m: {lv: np.full(P, np.nan) for lv in LEVELS} for m in METHODS}, "status": "ok"}
    try:
        least_squares = fit_joint(campaign, effects, return_problem=True)
        ls = least_squares[0]
        for k, n in enumerate(names):
            if n in ls.parameters:
                v, u = ls.parameters[n].value, ls.parameters[n].u
                eps = rng.standard_normal(n_ranks)
                out["ranks"]["least_squares"][k] = np.sum(v + u * eps < theta[k])
                for lv in LEVELS:
                    z = stats.norm.ppf(0.5 + lv / 2)
                    out["covered"]["least_squares"][lv][k] = float(abs(theta[k] - v) <= z * u)
        res, run = sample(campaign, effects, ess=ess, max_steps=max_steps, seed=int(rng.integers(2 ** 31)),
                          return_run=True, least_squares=least_squares)
        out["status"] = res.status
        draws = run.draws()                                 # (steps, walkers, P)
        thin = max(1, int(math.ceil(np.max(integrated_time(run.kept_z)))))
        pool = draws[::-1][::thin].reshape(-1, P)           # thinned from the end, all walkers
        pick = pool[rng.choice(len(pool), size=n_ranks, replace=False)]
        out["ranks"]["posterior"] = np.sum(pick < theta[None, :], axis=0).astype(float)
        flat = draws.reshape(-1, P)
        for lv in LEVELS:
            lo, hi = np.quantile(flat, [0.5 - lv / 2, 0.5 + lv / 2], axis=0)
            out["covered"]["posterior"][lv] = ((theta >= lo) & (theta <= hi)).astype(float)
    except Exception as exc:  # recorded, never hidden: a failed campaign counts against the check
        out["status"] = f"error: {type(exc).__name__}: {exc}"
    return out


def sbc(n_campaigns: int = 200, effects: Sequence[str] = DEFAULT_EFFECTS, *, n_ranks: int = 99, seed: int = 0,
        processes: int = 2, schedule: Optional[Schedule] = None, plan=None, ess: float = 400,
        max_steps: int = 5000, progress: Optional[Callable[[int, int], None]] = None) -> SBCResult:
    """Run SBC on ``n_campaigns`` campaigns drawn from the prior.

    ``n_ranks`` (L) posterior draws per campaign give ranks 0..L; ``ess``: the ESS the
    posterior runs request (the stop rule's 50 tau and R-hat < 1.01 still apply; L draws
    need far less than the default 2000). ``processes`` worker processes (fork).
    ``progress(done, total)`` is called as campaigns finish.
    """
    if n_ranks < 1 or n_campaigns < 1:
        raise InputError("n_campaigns and n_ranks must be positive")
    effects = tuple(effects)
    schedule = schedule or compact_schedule()
    plan = dict(DEFAULT_PLAN if plan is None else plan)
    tasks = [(i, seed, effects, schedule, plan, n_ranks, ess, max_steps) for i in range(n_campaigns)]
    t0 = time.perf_counter()
    results = [None] * n_campaigns
    if processes > 1:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor, as_completed

        ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
        with ProcessPoolExecutor(max_workers=processes, mp_context=ctx) as pool:
            futures = {pool.submit(_one_campaign, t): t[0] for t in tasks}
            for done, fut in enumerate(as_completed(futures), 1):
                results[futures[fut]] = fut.result()
                if progress is not None:
                    progress(done, n_campaigns)
    else:
        for done, t in enumerate(tasks, 1):
            results[t[0]] = _one_campaign(t)
            if progress is not None:
                progress(done, n_campaigns)
    names = Model(effects).names
    return SBCResult(
        names=names, n_ranks=n_ranks, truths=np.array([r["theta"] for r in results]),
        ranks={m: np.array([r["ranks"][m] for r in results]) for m in METHODS},
        covered={m: {lv: np.array([r["covered"][m][lv] for r in results]) for lv in LEVELS} for m in METHODS},
        statuses=[r["status"] for r in results], seconds=time.perf_counter() - t0,
        settings={"effects": list(effects), "setpoints_C": list(schedule.setpoints_C), "positions": len(plan),
                  "ess": ess, "max_steps": max_steps, "seed": seed, "processes": processes,
                  "noise": "white output noise Q = 3e-9 V^2 s, no temperature-reading noise, no bench errors"})
