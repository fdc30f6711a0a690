"""The sampler loop and its stop rule: ``tau_factor`` autocorrelation times, ESS and R-hat
for every parameter, or ``not_converged`` at ``max_steps``.
"""

from __future__ import annotations

from ...errors import InputError

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Optional, Union

import numpy as np

from .diagnostics import diagnostics, integrated_time, split_rhat_quick
from .moves import _emcee, make_moves
from .options import BURN_TAUS, INITIAL_TAU, check_ess, check_max_steps, check_rule, check_seed, walkers_for
from .targets import LogPosterior


#: at most this many draws (walkers x steps after the burn-in) are kept; a longer run is thinned
MAX_SAVED_DRAWS = 200_000


@dataclass
class PosteriorRun:
    """What the sampler produced: the whole chain in whitened coordinates and how it stopped."""

    names: tuple
    units: tuple
    chain_z: np.ndarray            # (steps, walkers, d)
    log_prob: np.ndarray           # (steps, walkers)
    burn: int
    converged: bool
    diagnostics: dict
    target: LogPosterior
    seconds: float
    acceptance: float
    moves: str
    checks: list = field(default_factory=list)
    thin: int = 1                  # every thin-th kept step is a saved draw (1: all of them)
    stop_rule: dict = field(default_factory=dict)   # ess, rhat_max, tau_factor, max_steps

    @property
    def kept_index(self) -> np.ndarray:
        """Steps after the burn-in that are the saved draws: every ``thin``-th, ending at the last."""
        kept = self.chain_z.shape[0] - self.burn
        return np.arange(kept - 1, -1, -self.thin)[::-1]

    @property
    def kept_z(self) -> np.ndarray:
        """The saved draws in whitened coordinates, (draw, walker, d): the draws the summary,
        the convergence verdict and the posterior file all use."""
        return self.chain_z[self.burn:][self.kept_index]

    @property
    def kept_log_prob(self) -> np.ndarray:
        return self.log_prob[self.burn:][self.kept_index]

    def draws(self) -> np.ndarray:
        """Kept draws in reporting units, (steps, walkers, d)."""
        return self.target.to_x(self.kept_z)

    def flat(self) -> np.ndarray:
        return self.draws().reshape(-1, len(self.names))


def run_sampler(target: LogPosterior, n_walkers: int, *, ess: float = 2000, rhat_max: float = 1.01,
                tau_factor: float = 50.0, max_steps: int = 20000, seed: int = 0,
                moves: str = "de-snooker-laplace", start_scale: float = 1.2,
                progress: Union[bool, Callable, None] = None, first_check: int = 100,
                progress_every: int = 50, max_seconds: Optional[float] = None,
                max_saved_draws: int = MAX_SAVED_DRAWS) -> PosteriorRun:
    """Run emcee until the stop rule holds (docs/posterior.md), ``max_steps`` or ``max_seconds``.

    The draws after the burn-in are the saved draws (thinned only beyond ``max_saved_draws``);
    the convergence verdict (R-hat, bulk and tail ESS, ``converged``) is computed once, on
    exactly those draws, and every consumer reads it (docs/posterior.md, "One verdict").

    ``target`` is a :class:`LogPosterior` (or any object with its ``d``, ``names``, ``model``,
    ``to_x`` and vectorised ``__call__``).

    The options are checked first (:mod:`.options`): ``n_walkers`` an even integer >= 2 d,
    ``max_steps`` >= :data:`~.options.MIN_STEPS`, ``ess`` finite > 0, ``seed`` in 0 .. 2**32 - 1;
    otherwise an :class:`InputError` naming the option."""
    d = target.d
    ess, max_steps, seed = check_ess(ess), check_max_steps(max_steps), check_seed(seed)
    check_rule(rhat_max, tau_factor)
    n_walkers = walkers_for(n_walkers, d)
    emcee = _emcee()
    rng = np.random.default_rng(seed)
    z0 = rng.standard_normal((n_walkers, d)) * start_scale
    for _ in range(100):                  # every walker starts where the posterior is positive
        bad = ~np.isfinite(target(z0))
        if not bad.any():
            break
        z0[bad] = rng.standard_normal((int(bad.sum()), d)) * start_scale * 0.5
    else:
        raise InputError("cannot place the walkers inside the bounds of the priors around the MAP; "
                         "check the priors (a bound at the estimate?) or the data")
    sampler = emcee.EnsembleSampler(n_walkers, d, target, vectorize=True, moves=make_moves(moves))
    sampler.random_state = np.random.RandomState(seed).get_state()
    bar = None
    if progress is True:
        from tqdm.auto import tqdm
        bar = tqdm(total=max_steps, desc="sampling", unit="step")
        callback = None
    else:
        callback = progress if callable(progress) else None
    t0 = time.perf_counter()
    state = z0
    steps = 0
    target_steps = min(first_check, max_steps)
    checks = []
    converged = False
    diag = None
    burn = 0
    tau_last = INITIAL_TAU
    while True:
        while steps < target_steps:
            n_run = min(progress_every, target_steps - steps)
            state = sampler.run_mcmc(state, n_run, progress=False)
            steps += n_run
            if bar is not None:
                bar.update(n_run)
            if callback is not None and steps < target_steps:
                callback(steps, max_steps, None)
        # diagnostics of the reported parameters (x), not of the walkers' coordinates
        chain = target.to_x(sampler.get_chain())
        # burn-in: 5 tau of the previous look (the start is already near the posterior)
        burn = int(min(math.ceil(BURN_TAUS * tau_last), steps // 2))
        kept = steps - burn
        tau_vec = integrated_time(chain[burn:])
        tau = tau_last = float(np.max(tau_vec))
        ess_guess = n_walkers * kept / tau
        rhat_guess = float(np.max(split_rhat_quick(chain[burn:])))
        check = {"steps": steps, "burn": burn, "tau_max": tau, "ess_estimate": ess_guess,
                 "rhat_classic_max": rhat_guess}
        # arviz (rank-normalised, slower) only once the cheap screens pass
        if kept >= tau_factor * tau and ess_guess >= ess and rhat_guess < rhat_max:
            diag = diagnostics(chain[burn:], target.names, tau=tau_vec)
            check.update({"ess_bulk_min": float(diag["ess_bulk"].min()),
                          "ess_tail_min": float(diag["ess_tail"].min()), "rhat_max": float(diag["rhat"].max())})
            if (min(check["ess_bulk_min"], check["ess_tail_min"]) >= ess and check["rhat_max"] < rhat_max
                    ):
                converged = True
        checks.append(check)
        if bar is not None:
            bar.set_postfix(tau=f"{tau:.1f}", ess=f"{ess_guess:.0f}", rhat=f"{rhat_guess:.3f}")
        if callback is not None:
            callback(steps, max_steps, check)
        out_of_time = max_seconds is not None and time.perf_counter() - t0 >= max_seconds
        if converged or steps >= max_steps or out_of_time:
            if diag is None or "ess_bulk_min" not in check:
                diag = diagnostics(chain[burn:], target.names, tau=tau_vec)
            break
        # next look: long enough for the length rule at the current tau, the ESS, and R-hat
        # (split R-hat - 1 ~ (tau - 1) / steps for walkers as chains)
        need = max(burn + 1.1 * tau_factor * tau, burn + 1.1 * kept * ess / max(ess_guess, 1.0),
                   burn + 1.1 * kept * (rhat_guess - 1.0) / (0.8 * (rhat_max - 1.0)))
        target_steps = int(min(max_steps, max(need, steps + 25)))
        if max_seconds is not None:
            per_step = (time.perf_counter() - t0) / steps
            left = max(max_seconds - (time.perf_counter() - t0), 0.0)
            target_steps = int(min(target_steps, steps + max(25, left / per_step)))
    if bar is not None:
        bar.close()
    kept = steps - burn
    thin = max(1, math.ceil(kept * n_walkers / max_saved_draws))
    if thin > 1:            # the verdict of the draws that are saved, not of the longer chain
        saved = chain[burn:][np.arange(kept - 1, -1, -thin)[::-1]]
        diag = diagnostics(saved, target.names, tau=integrated_time(saved))
        converged = converged and bool(min(diag["ess_bulk"].min(), diag["ess_tail"].min()) >= ess
                                       and diag["rhat"].max() < rhat_max)
    units = (tuple(target.units) if getattr(target, "units", None) is not None
             else tuple(target.model.spec[n].unit for n in target.names))
    return PosteriorRun(names=target.names, units=units,
                        chain_z=sampler.get_chain(), log_prob=sampler.get_log_prob(), burn=burn,
                        converged=converged, diagnostics=diag, target=target, thin=thin,
                        stop_rule={"ess": ess, "rhat_max": rhat_max, "tau_factor": tau_factor,
                                   "max_steps": max_steps},
                        seconds=time.perf_counter() - t0,
                        acceptance=float(np.mean(sampler.acceptance_fraction)), moves=moves, checks=checks)
