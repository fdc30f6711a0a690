"""Hints on the wiring of a unit (swapped columns, an inverted sign, a stuck channel): not gates.

A hint explains why a gate failed; it never sets a status. Used by the classical and joint fits
and by fit-raw with known poses (their notes ``hint: ...``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np


def orientation_hints(w: np.ndarray, gravity: np.ndarray, axes: Sequence[str] = ("x", "y", "z")) -> list[str]:
    """What a per-axis linear fit of the outputs on the nominal gravity says about the wiring:
    an output that follows gravity along another axis (swapped columns, a mislabelled axis)
    or falls when its own axis points up (an inverted sign). Empty when nothing is amiss.

    ``w`` (n, 3) outputs, ``gravity`` (n, 3) nominal gravity in the unit frame (g), from the
    bench kinematics. A hint, not a gate: it explains why a gate failed.
    """
    w, G = np.asarray(w, float), np.asarray(gravity, float)
    if w.shape != G.shape or len(w) < 4 or not (np.all(np.isfinite(w)) and np.all(np.isfinite(G))):
        return []
    A = np.column_stack([G, np.ones(len(G))])
    hints = []
    for i, a in enumerate(axes):
        if np.ptp(G[:, i]) < 1.0:
            continue  # the axis never turns over: nothing to say
        coef, *_ = np.linalg.lstsq(A, w[:, i], rcond=None)
        b = coef[:3]
        j = int(np.argmax(np.abs(b)))
        if not np.isfinite(b).all() or np.abs(b).max() == 0:
            hints.append(f"output w_{a} does not follow gravity at all (a constant or stuck channel?)")
        elif j != i and abs(b[j]) > 2 * abs(b[i]):
            hints.append(f"output w_{a} follows gravity along {axes[j]}, not {a} (swapped columns or a mislabelled "
                         "axis?)")
        elif b[i] < 0:
            hints.append(f"output w_{a} falls when its axis points up (an inverted sign?)")
    return hints
