"""The sampler's options, checked before any work (``triadcal sample``, ``fit-raw --sample``,
``validate`` and the library alike): a value outside its range is an :class:`InputError` naming
the option and the range, never an emcee or numpy error and never a value silently replaced
(docs/posterior.md, "Options and their ranges").
"""

from __future__ import annotations

import math
import numbers
from typing import Optional

from ...errors import InputError

#: seeds are those numpy's legacy ``RandomState`` (emcee's) accepts: 0 .. 2**32 - 1
SEED_MAX = 2 ** 32 - 1

#: the tau the first look's burn-in assumes (no chain yet to estimate it from)
INITIAL_TAU = 4.0
#: burn-in, in autocorrelation times
BURN_TAUS = 5.0
#: the fewest steps a run may have: the first look's burn-in (5 x the initial tau of 4 = 20 steps),
#: after which the look keeps at least half the chain (>= 10 draws per walker) for R-hat and ESS.
#: Shorter, the look has too few draws for split R-hat; it cannot give a verdict, only a crash.
MIN_STEPS = int(math.ceil(BURN_TAUS * INITIAL_TAU))


def _integer(value) -> Optional[int]:
    """``value`` as an int when it is an integer (an int, a numpy integer, or a float with no
    fractional part), else None."""
    if isinstance(value, bool):
        return None
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real) and math.isfinite(value) and float(value).is_integer():
        return int(value)
    return None


def check_seed(seed, option: str = "--seed") -> int:
    """A seed: an integer in 0 .. 2**32 - 1."""
    v = _integer(seed)
    if v is None or not 0 <= v <= SEED_MAX:
        raise InputError(f"{option} must be an integer in 0..{SEED_MAX} (2**32 - 1), got {seed!r}")
    return v


def check_ess(ess, option: str = "--ess") -> float:
    """The requested bulk and tail ESS: a finite number > 0."""
    if isinstance(ess, bool) or not isinstance(ess, numbers.Real) or not (math.isfinite(ess) and ess > 0):
        raise InputError(f"{option} must be a finite number > 0 (the bulk and tail ESS every parameter needs), "
                         f"got {ess!r}")
    return float(ess)


def check_max_steps(max_steps, option: str = "--max-steps") -> int:
    """The cap on the chain's length: an integer >= :data:`MIN_STEPS`."""
    v = _integer(max_steps)
    if v is None or v < MIN_STEPS:
        raise InputError(f"{option} must be an integer >= {MIN_STEPS} (the first look's burn-in, "
                         f"{BURN_TAUS:g} x the initial tau of {INITIAL_TAU:g} steps; a shorter chain has too few "
                         f"draws for R-hat and ESS), got {max_steps!r}")
    return v


def walkers_for(n_walkers, d: int, option: str = "--walkers") -> int:
    """The number of walkers for ``d`` free parameters: ``2 d`` when ``n_walkers`` is None (not
    given), else ``n_walkers`` itself when it is an even integer >= ``2 d`` (emcee's DE, snooker
    and stretch moves are red-blue moves: two equal halves, each of at least ``d`` walkers, or the
    walkers stay on a subspace). 0, an odd count or too few are refused, never replaced."""
    if n_walkers is None:
        return 2 * d
    v = _integer(n_walkers)
    if v is None or v < 2 * d or v % 2:
        raise InputError(f"{option} must be an even integer >= {2 * d} (2 x the {d} free parameters: emcee's "
                         f"ensemble moves split the walkers into two equal halves and need at least twice as many "
                         f"walkers as parameters), got {n_walkers!r}")
    return v


def check_rule(rhat_max, tau_factor) -> None:
    """The library-only parts of the stop rule: R-hat bound finite > 1, chain length in taus finite > 0."""
    if isinstance(rhat_max, bool) or not isinstance(rhat_max, numbers.Real) or not (
            math.isfinite(rhat_max) and rhat_max > 1):
        raise InputError(f"rhat_max must be a finite number > 1, got {rhat_max!r}")
    if isinstance(tau_factor, bool) or not isinstance(tau_factor, numbers.Real) or not (
            math.isfinite(tau_factor) and tau_factor > 0):
        raise InputError(f"tau_factor must be a finite number > 0, got {tau_factor!r}")


def check_sampler_options(*, ess, max_steps, seed, rhat_max: float = 1.01, tau_factor: float = 50.0) -> None:
    """Every sampler option that does not depend on the model, before anything is read or fitted
    (the walkers need the number of parameters: :func:`walkers_for`)."""
    check_ess(ess)
    check_max_steps(max_steps)
    check_seed(seed)
    check_rule(rhat_max, tau_factor)
