"""emcee move mixtures: differential evolution, snooker and an independence proposal from the
Laplace approximation (why this mixture: docs/posterior.md, ``benchmarks/sample.py``).
"""

from __future__ import annotations

from ...errors import InputError

import numpy as np

MOVES = ("de-snooker-laplace", "de-snooker", "stretch")


def _emcee():
    import emcee
    return emcee


def laplace_move(scale: float = 1.0):
    """Independence Metropolis proposal ``z' ~ N(0, scale^2 I)`` in the whitened coordinates,
    i.e. from the (inflated) Laplace approximation of the posterior; the Hastings factor
    ``log q(z) - log q(z')`` keeps the posterior exact whatever its shape."""
    emcee = _emcee()

    class LaplaceMove(emcee.moves.MHMove):
        def __init__(self):
            self.scale = float(scale)
            super().__init__(self._propose)

        def _propose(self, coords, random):
            new = random.standard_normal(coords.shape) * self.scale
            factor = 0.5 * (np.sum(new * new, axis=1) - np.sum(coords * coords, axis=1)) / self.scale ** 2
            return new, factor

    return LaplaceMove()


def make_moves(kind: str = "de-snooker-laplace"):
    """The emcee move mixture by name (why this mixture: docs/posterior.md)."""
    emcee = _emcee()
    if kind == "de-snooker-laplace":
        return [(emcee.moves.DEMove(), 0.15), (emcee.moves.DESnookerMove(), 0.05), (laplace_move(1.0), 0.8)]
    if kind == "de-snooker":
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    if kind == "stretch":
        return [(emcee.moves.StretchMove(), 1.0)]
    raise InputError(f"unknown moves {kind!r}; choose one of {', '.join(MOVES)}")
