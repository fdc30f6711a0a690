"""Simulation-based calibration (Talts et al. 2018) of the least-squares and posterior intervals.

:func:`sbc` draws campaigns from the prior, simulates them, fits each by least squares and
by the posterior sampler, and returns an :class:`SBCResult` (ranks and coverage, with
``rank_pvalues``, ``coverage_pvalues``, ``pooled_coverage`` and ``summary``); behind
``triadcal validate``. Derivation/design: docs/posterior.md (Simulation-based calibration).
"""

from __future__ import annotations

from ..errors import InputError

import math
import numbers
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
#: family-wise level of each test of the verdict (Bonferroni over the parameters within a test)
ALPHA = 0.01
#: the fixed band of the 95 % coverage, justified for the docs' design of 200 campaigns and more
BAND = 0.03
DESIGN_CAMPAIGNS = 200


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
    reasons: list = field(default_factory=list)   # why each campaign that is not ok is not ("" when ok)

    @property
    def n_campaigns(self) -> int:
        return self.truths.shape[0]

    def default_bins(self) -> int:
        """20 bins, fewer for a small run (at least ~5 campaigns per bin expected)."""
        return _bins(self.n_campaigns, self.n_ranks)

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
        c = self.covered[method][level]
        n = np.sum(np.isfinite(c), axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > 0, np.nansum(c, axis=0) / np.maximum(n, 1), np.nan)

    def pooled_coverage(self, method: str, level: float) -> float:
        c = self.covered[method][level]
        return float(np.nanmean(c)) if np.any(np.isfinite(c)) else float("nan")

    def campaign_coverage(self, method: str, level: float) -> np.ndarray:
        """Each campaign's fraction of covered parameters (campaigns without any indicator left out)."""
        c = self.covered[method][level]
        ok = np.any(np.isfinite(c), axis=1)
        return np.nanmean(c[ok], axis=1) if ok.any() else np.zeros(0)

    def pooled_pvalue(self, method: str, level: float) -> float:
        """Two-sided p-value of the pooled coverage, valid at any number of campaigns and whatever the
        correlation of the parameters' indicators within a campaign (:func:`pooled_coverage_pvalue`)."""
        return pooled_coverage_pvalue(self.campaign_coverage(method, level), level)

    def coverage_pvalues(self, method: str, level: float) -> np.ndarray:
        """Two-sided binomial test of each parameter's coverage against the nominal level."""
        c = self.covered[method][level]
        out = np.full(len(self.names), np.nan)
        for k in range(len(self.names)):
            x = c[:, k][np.isfinite(c[:, k])]
            if len(x):
                out[k] = stats.binomtest(int(x.sum()), len(x), level).pvalue
        return out

    def failed_campaigns(self) -> list:
        """Every campaign whose status is not ok: its index, status and the reason."""
        reasons = list(self.reasons) + [""] * (len(self.statuses) - len(self.reasons))
        return [{"campaign": i, "status": st, "reason": reasons[i] or st}
                for i, st in enumerate(self.statuses) if st != "ok"]

    def verdict(self, alpha: float = ALPHA, bins: Optional[int] = None) -> dict:
        """The checks behind ``triadcal validate``'s exit code (docs/posterior.md, "The verdict"):
        no campaign failed; per method, the rank histograms uniform (chi-square, Bonferroni over the
        parameters); each parameter's 68 % and 95 % coverage by a two-sided exact binomial test
        (Bonferroni); the pooled 68 % and 95 % coverage by :func:`pooled_coverage_pvalue` (valid for
        any correlation within a campaign); and, from 200 campaigns (the docs' design), the pooled
        95 % coverage in 0.95 +- 0.03 and at most the 99 % quantile of Binomial(P, p_out) parameters
        outside 0.95 +- 0.03. Returns ``{"passed", "conclusive", "campaigns_needed", "checks"}``; each
        check has ``passed``, ``conclusive`` (could it have failed with this many campaigns?) and
        a ``message`` with its numbers."""
        return _verdict(self, alpha, bins or self.default_bins())

    def summary(self, alpha: float = ALPHA, bins: Optional[int] = None) -> dict:
        """The numbers a reader checks, per method (JSON-ready)."""
        P = len(self.names)
        bins = bins or self.default_bins()
        out = {"format": "triadcal.sbc", "version": 1, "n_campaigns": self.n_campaigns, "n_ranks": self.n_ranks,
               "parameters": list(self.names), "seconds": self.seconds, "settings": self.settings,
               "failed": sum(1 for s in self.statuses if s != "ok"), "alpha": alpha, "bins": bins,
               "failed_campaigns": self.failed_campaigns(), "methods": {}}
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
                d[f"coverage_{key}_pooled"] = _f(self.pooled_coverage(m, level))
                d[f"coverage_{key}_pooled_p"] = _f(self.pooled_pvalue(m, level))
                d[f"coverage_{key}_range"] = [_f(_nan(np.nanmin, cov)), _f(_nan(np.nanmax, cov))]
                d[f"coverage_{key}_binomial_min_p"] = _f(_nan(np.nanmin, pv))
                d[f"coverage_{key}_n_outside_0.03"] = _n_outside(cov, level)
            out["methods"][m] = d
        out["verdict"] = self.verdict(alpha, bins)
        return out


def _f(x) -> Optional[float]:
    x = float(x)
    return x if math.isfinite(x) else None


def _nan(fn, x) -> float:
    """``fn`` (np.nanmin, np.nanmax) of ``x``, nan when nothing in it is finite (no warning)."""
    x = np.asarray(x, float)
    return float(fn(x)) if np.any(np.isfinite(x)) else float("nan")


def _bins(n_campaigns: int, n_ranks: int) -> int:
    """20 bins of the rank histogram, fewer for a small run (at least ~5 campaigns per bin expected)."""
    return int(max(2, min(20, n_campaigns // 5, n_ranks + 1)))


def _stop_loss_bound(t: float, n: int, p: float) -> float:
    """An upper bound of ``P(S >= t)`` for ``S`` a sum of ``n`` independent variables in [0, 1] of
    mean ``p``. Each is smaller in the convex order than a Bernoulli(p) (a convex f on [0, 1] lies
    below its chord), so ``S`` is smaller than ``B ~ Binomial(n, p)`` (independent sums keep the order),
    and ``P(S >= t) <= E(S - a)+ / (t - a) <= E(B - a)+ / (t - a)`` for every ``a < t``; the ratio is
    monotone between integers, so its minimum is at an integer ``a`` in ``0 .. ceil(t) - 1``."""
    if not t > n * p:
        return 1.0
    k = np.arange(n + 1)
    pmf = stats.binom.pmf(k, n, p)
    # E(B - a)+ = sum_{k > a} k pmf - a sum_{k > a} pmf, for a = 0 .. n - 1
    mass = np.cumsum(pmf[::-1])[::-1]              # mass[j] = P(B >= j)
    first = np.cumsum((k * pmf)[::-1])[::-1]       # first[j] = E(B; B >= j)
    a = np.arange(0, min(int(math.ceil(t)), n + 1))
    a = a[(a < t) & (a < n)]
    if a.size == 0:
        return 1.0
    excess = first[a + 1] - a * mass[a + 1]
    return float(min(1.0, np.min(excess / (t - a))))


def pooled_coverage_pvalue(campaign_coverage, level: float) -> float:
    """Two-sided p-value of the pooled coverage against ``level``, from each campaign's fraction of
    covered parameters ``c_i`` (independent across campaigns, in [0, 1], of mean ``level`` when the
    intervals are calibrated, however the parameters' indicators correlate within a campaign):
    twice the smaller of the stop-loss bounds of the two tails (:func:`_stop_loss_bound`), at most 1.
    Exact in the sense of a bound, at any number of campaigns; at full correlation it is within a
    small factor of the binomial test on the campaigns."""
    c = np.asarray(campaign_coverage, float)
    c = c[np.isfinite(c)]
    n = len(c)
    if n == 0:
        return float("nan")
    s = float(np.sum(c))
    upper = _stop_loss_bound(s, n, level)
    lower = _stop_loss_bound(n - s, n, 1.0 - level)
    return float(min(1.0, 2.0 * min(upper, lower)))


def _binomial_min_p(n: int, level: float) -> float:
    """The smallest two-sided exact binomial p-value ``n`` indicators can give (all covered or none)."""
    if n < 1:
        return 1.0
    return float(min(stats.binomtest(0, n, level).pvalue, stats.binomtest(n, n, level).pvalue))


def _chi2_min_p(n: int, bins: int) -> float:
    """The smallest chi-square p-value ``n`` ranks in ``bins`` equal bins can give (all in one bin)."""
    if n < bins or bins < 2:
        return 1.0
    return float(stats.chi2.sf(n * (bins - 1), bins - 1))


def _outside(coverage, level: float) -> np.ndarray:
    """Coverages more than :data:`BAND` from ``level`` (0.92 and 0.98 of 200 are on the band, inside:
    the comparison allows for the rounding of ``0.95 - 0.92``)."""
    return np.abs(np.asarray(coverage, float) - level) > BAND + 1e-9


def _n_outside(coverage, level: float) -> int:
    return int(np.sum(_outside(coverage, level)))


def _outside_probability(n: int, level: float) -> float:
    """P(|X/n - level| > BAND) for X ~ Binomial(n, level), with the comparison the summary counts with
    (at n = 200: 0.033, the docs' Binomial(32, 0.033))."""
    k = np.arange(n + 1)
    return float(np.sum(stats.binom.pmf(k[_outside(k / n, level)], n, level)))


def campaigns_needed(n_parameters: int, n_ranks: int = 99, alpha: float = ALPHA) -> int:
    """The fewest campaigns with which every check of :meth:`SBCResult.verdict` could fail."""
    for n in range(1, 100_000):
        if _chi2_min_p(n, _bins(n, n_ranks)) >= alpha / n_parameters:
            continue
        if any(_binomial_min_p(n, lv) >= alpha / n_parameters for lv in LEVELS):
            continue
        if any(pooled_coverage_pvalue(np.full(n, 0.0), lv) >= alpha for lv in LEVELS):
            continue
        return n
    return 100_000


def _check(test, method, level, passed, conclusive, message, **numbers) -> dict:
    return {"test": test, "method": method, "level": level, "passed": bool(passed), "conclusive": bool(conclusive),
            "message": message, **{k: _f(v) if isinstance(v, float) else v for k, v in numbers.items()}}


def _verdict(r: "SBCResult", alpha: float, bins: int) -> dict:
    P = len(r.names)
    N = r.n_campaigns
    a_each = alpha / P
    checks = []
    failed = r.failed_campaigns()
    msg = (f"{len(failed)} of {N} campaigns failed: " + "; ".join(f"campaign {f['campaign']}: {f['status']}"
                                                                  + (f" ({f['reason']})" if f['reason'] != f['status']
                                                                     else "") for f in failed[:3])
           + (f"; and {len(failed) - 3} more (failed_campaigns in the JSON)" if len(failed) > 3 else "")
           if failed else f"0 of {N} campaigns failed")
    checks.append(_check("campaigns", None, None, not failed, True, msg, failed=len(failed)))
    for m in METHODS:
        p = r.rank_pvalues(m, bins)
        n_ranked = np.sum(np.isfinite(r.ranks[m]), axis=0)
        if not np.all(np.isfinite(p)):
            k = int(np.flatnonzero(~np.isfinite(p))[0])
            checks.append(_check("ranks", m, None, False, False,
                                 f"{m} ranks: the chi-square test of {r.names[k]} cannot be computed: "
                                 f"{int(n_ranked[k])} campaign(s) with a rank, fewer than the {bins} bins of the "
                                 f"histogram (run at least {campaigns_needed(P, r.n_ranks, alpha)} campaigns)",
                                 min_p=None, threshold=a_each))
        else:
            k = int(np.argmin(p))
            pmin_attainable = max(_chi2_min_p(int(n), bins) for n in n_ranked)
            ok = p[k] > a_each
            checks.append(_check("ranks", m, None, ok, pmin_attainable < a_each,
                                 f"{m} ranks: min chi-square p {p[k]:.3g} ({r.names[k]}) "
                                 f"{'>' if ok else '<='} {alpha:g}/{P} = {a_each:.3g}",
                                 min_p=float(p[k]), parameter=r.names[k], threshold=a_each,
                                 smallest_attainable_p=pmin_attainable))
        for lv in LEVELS:
            key = f"{round(lv * 100)}%"
            c = r.covered[m][lv]
            n_k = np.sum(np.isfinite(c), axis=0).astype(int)
            hits = np.nansum(c, axis=0)
            pv = r.coverage_pvalues(m, lv)
            if not np.any(np.isfinite(pv)):
                checks.append(_check("coverage_binomial", m, lv, False, False,
                                     f"{m} {key} coverage: no campaign gave an interval", min_p=None,
                                     threshold=a_each))
            else:
                missing = [r.names[k] for k in range(P) if n_k[k] == 0]
                k = int(np.nanargmin(pv))
                ok = pv[k] > a_each and not missing
                attainable = max(_binomial_min_p(int(n), lv) for n in n_k)
                text = (f"{m} {key} coverage of {r.names[k]} {hits[k] / n_k[k]:.3f} ({int(hits[k])} of {n_k[k]}): "
                        f"two-sided binomial p {pv[k]:.3g} {'>' if pv[k] > a_each else '<='} {alpha:g}/{P} = "
                        f"{a_each:.3g}")
                if missing:
                    text += f"; no interval at all for {', '.join(missing)}"
                checks.append(_check("coverage_binomial", m, lv, ok, attainable < a_each, text,
                                     min_p=float(pv[k]), parameter=r.names[k], threshold=a_each,
                                     smallest_attainable_p=attainable))
            cc = r.campaign_coverage(m, lv)
            pp = pooled_coverage_pvalue(cc, lv)
            if not np.isfinite(pp):
                checks.append(_check("coverage_pooled", m, lv, False, False,
                                     f"{m} {key} pooled coverage: no campaign gave an interval", p=None,
                                     threshold=alpha))
            else:
                attainable = min(pooled_coverage_pvalue(np.zeros(len(cc)), lv),
                                 pooled_coverage_pvalue(np.ones(len(cc)), lv))
                ok = pp > alpha
                checks.append(_check("coverage_pooled", m, lv, ok, attainable < alpha,
                                     f"{m} {key} pooled coverage {np.mean(cc):.3f} over {len(cc)} campaigns: p "
                                     f"{pp:.3g} {'>' if ok else '<='} {alpha:g} (a bound valid for any correlation "
                                     "within a campaign)", pooled=float(np.mean(cc)), p=pp, threshold=alpha,
                                     smallest_attainable_p=attainable))
            if lv == 0.95 and N >= DESIGN_CAMPAIGNS:
                pooled = r.pooled_coverage(m, lv)
                ok = abs(pooled - lv) <= BAND
                checks.append(_check("coverage_pooled_band", m, lv, ok, True,
                                     f"{m} {key} pooled coverage {pooled:.3f} {'within' if ok else 'outside'} "
                                     f"{lv} +- {BAND} (from {DESIGN_CAMPAIGNS} campaigns)", pooled=pooled,
                                     band=BAND))
                cov = r.coverage(m, lv)
                n_out = _n_outside(cov, lv)
                limit = int(stats.binom.ppf(0.99, P, _outside_probability(N, lv)))
                ok = n_out <= limit
                checks.append(_check("coverage_outside_band", m, lv, ok, True,
                                     f"{m} {key} coverage: {n_out} of {P} parameters outside {lv} +- {BAND} "
                                     f"{'<=' if ok else '>'} {limit} (99 % quantile of Binomial({P}, "
                                     f"{_outside_probability(N, lv):.3f}))", n_outside=n_out, limit=limit))
    passed = all(c["passed"] for c in checks)
    conclusive = all(c["conclusive"] for c in checks)
    return {"passed": passed, "conclusive": conclusive, "alpha": alpha,
            "campaigns_needed": campaigns_needed(P, r.n_ranks, alpha), "checks": checks}


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
           "covered": {m: {lv: np.full(P, np.nan) for lv in LEVELS} for m in METHODS}, "status": "ok",
           "reason": ""}
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
        if res.status != "ok":
            out["reason"] = "; ".join(n for n in res.notes if n.startswith(("not converged", "gate "))) or (
                f"the posterior's status is {res.status!r}")
        draws = run.draws()                                 # (steps, walkers, P)
        thin = max(1, int(math.ceil(np.max(integrated_time(run.kept_z)))))
        pool = draws[::-1][::thin].reshape(-1, P)           # thinned from the end, all walkers
        if len(pool) < n_ranks:
            raise InputError(f"only {len(pool)} posterior draws after thinning by tau = {thin} steps, fewer than "
                             f"the {n_ranks} ranks (--ranks); give a larger --ess or fewer --ranks")
        pick = pool[rng.choice(len(pool), size=n_ranks, replace=False)]
        out["ranks"]["posterior"] = np.sum(pick < theta[None, :], axis=0).astype(float)
        flat = draws.reshape(-1, P)
        for lv in LEVELS:
            lo, hi = np.quantile(flat, [0.5 - lv / 2, 0.5 + lv / 2], axis=0)
            out["covered"]["posterior"][lv] = ((theta >= lo) & (theta <= hi)).astype(float)
    except Exception as exc:  # recorded, never hidden: a failed campaign counts against the check
        out["status"] = "error"
        out["reason"] = f"{type(exc).__name__}: {exc}"
    return out


def _count(option: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
        raise InputError(f"{option} must be an integer >= {low}, got {value!r}")
    return int(value)


def check_sbc_options(n_campaigns, *, n_ranks=99, seed=0, processes=2, ess=400.0, max_steps=5000) -> None:
    """The options of :func:`sbc` (``triadcal validate``), before any campaign runs: counts >= 1,
    ``ess`` finite > 0, the seed in 0 .. 2**32 - 1, and ``n_ranks`` at most ``ess``: a campaign's ranks
    are ``n_ranks`` posterior draws thinned by the autocorrelation time, of which a run that
    converged to ``ess`` gives about ``ess`` (a campaign that still has fewer fails, saying so)."""
    from ..estimation.posterior.options import check_ess, check_max_steps, check_seed

    _count("--campaigns", n_campaigns, 1)
    _count("--ranks", n_ranks, 1)
    _count("--processes", processes, 1)
    ess = check_ess(ess)
    check_seed(seed)
    check_max_steps(max_steps, option="max_steps")
    if n_ranks > ess:
        raise InputError(f"--ranks {n_ranks} exceeds --ess {ess:g}: each campaign ranks the truth among --ranks "
                         f"posterior draws thinned by the autocorrelation time, and a run that reaches --ess gives "
                         f"about --ess of them; give --ranks <= {ess:g} or a larger --ess")


def sbc(n_campaigns: int = 200, effects: Sequence[str] = DEFAULT_EFFECTS, *, n_ranks: int = 99, seed: int = 0,
        processes: int = 2, schedule: Optional[Schedule] = None, plan=None, ess: float = 400,
        max_steps: int = 5000, progress: Optional[Callable[[int, int], None]] = None) -> SBCResult:
    """Run SBC on ``n_campaigns`` campaigns drawn from the prior.

    ``n_ranks`` (L) posterior draws per campaign give ranks 0..L; ``ess``: the ESS the
    posterior runs request (the stop rule's 50 tau and R-hat < 1.01 still apply; L draws
    need far less than the default 2000; L <= ``ess``). ``processes`` worker processes (fork; 1:
    in this process). The options are checked first (:func:`check_sbc_options`). A campaign
    whose fit or sampler fails is recorded with its status and reason (``SBCResult.reasons``),
    never hidden. ``progress(done, total)`` is called as campaigns finish.
    """
    check_sbc_options(n_campaigns, n_ranks=n_ranks, seed=seed, processes=processes, ess=ess, max_steps=max_steps)
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
        statuses=[r["status"] for r in results], reasons=[r["reason"] for r in results],
        seconds=time.perf_counter() - t0,
        settings={"effects": list(effects), "setpoints_C": list(schedule.setpoints_C), "positions": len(plan),
                  "ess": ess, "max_steps": max_steps, "seed": seed, "processes": processes,
                  "noise": "white output noise Q = 3e-9 V^2 s, no temperature-reading noise, no bench errors"})
