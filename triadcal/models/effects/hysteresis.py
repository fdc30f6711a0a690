"""Thermal hysteresis of the orientation angles (seed paper, eq. 5 and Table 1).

The paper: the temperature dependence of the reference plane's orientation
(dCa_Ta of eq. 5) "has a hysteresis loop" (Table 1: +-4" to +-60"). Modelled as two
branches of the loop, parallel to the mid-line: ``angle = mid-line + h * b`` with
``b = +1`` on the cooling branch, ``-1`` on the heating branch and ``0`` for a setpoint
reached with no known history (direction ``none``, e.g. a unit soaked at ambient).
``h = (cooling - heating) / 2`` as in results-json.md. This saturated-loop form holds
when each sweep spans well more than the loop's own width, as bench campaigns do; for a loop as
wide as the sweeps, :func:`play_branch` gives the branch of a play hysteresis (the same ``h``,
``b`` continuous in [-1, 1]; docs/model.md, "Hysteresis forms").
"""

from __future__ import annotations

from ..parameters import per_angle
from ..sensor import ANGLE_NAMES
from .base import Effect

BRANCH = {"heating": -1.0, "cooling": 1.0, "none": 0.0}


def direction_after(direction: str, previous_setpoint_C, setpoint_C) -> str:
    """The branch a unit is on after its chamber goes from ``previous_setpoint_C`` to
    ``setpoint_C``: heating after a rise, cooling after a fall, unchanged when the setpoint
    stays (or ``none`` before the first change). The simulator's schedule and the emulator's
    chamber both follow this rule."""
    if previous_setpoint_C is None or setpoint_C == previous_setpoint_C:
        return direction
    return "heating" if setpoint_C > previous_setpoint_C else "cooling"


def play_branch(temperature_C, half_width_C: float, start: str = "mid"):
    """The branch of each visit for a play (backlash) hysteresis of half-width ``r`` (degC) on the
    temperature history (Krasnosel'skii-Pokrovskii; :func:`triadcal.models.thermal_history.play_operator`)::

        b = (play(T, r) - T) / r        in [-1, 1]

    -1 on a rise that has crossed the dead band (heating branch), +1 on a fall (cooling), in
    between after a turn smaller than 2r: a loop that does not saturate. ``angle = mid-line +
    h b`` as for the offset form, so ``h`` is the half-width of the saturated loop; as r -> 0,
    b -> the direction's +-1 (the constant-offset form is the limit). ``temperature_C``: the
    history in time order (visits, or a denser record); ``start``: the state before it is
    unknown — ``"mid"`` (y0 = T0, b = 0), ``"heating"`` (y0 = T0 - r) or ``"cooling"``."""
    import numpy as np

    from ..thermal_history import play_operator

    T = np.asarray(temperature_C, float)
    r = float(half_width_C)
    if r <= 0:
        raise ValueError("a play hysteresis needs a half-width > 0 degC (r = 0 is the offset form)")
    y0 = {"mid": T[0], "heating": T[0] - r, "cooling": T[0] + r}[start]
    return (play_operator(T, r, start=y0) - T) / r


PLAY_STARTS = ("mid", "heating", "cooling")


def pi_branch(temperature_C, half_widths_C, weights, start: str = "mid"):
    """The branch of each visit for a Prandtl-Ishlinskii hysteresis: a weighted sum of plays of
    half-widths ``r_i`` (degC) on the temperature history (Brokate & Sprekels 1996, *Hysteresis
    and Phase Transitions*, ch. 2; Kuhnen 2003, *Modeling, identification and compensation of
    complex hysteretic nonlinearities: a modified Prandtl-Ishlinskii approach*, Eur. J. Control 9(4), 407-418), normalised so that the
    saturated loop has half-width ``h`` as for the other forms::

        b = sum_i w_i (play(T, r_i) - T) / r_i  /  sum_i w_i        in [-1, 1],  w_i >= 0

    ``angle = mid-line + h b`` is then the PI operator ``angle = a0 + c T + sum_i p_i F_{r_i}[T]``
    (:func:`triadcal.models.thermal_history.prandtl_ishlinskii`) with density
    ``p_i = h w_i / (r_i sum w)`` and the linear tempco ``c`` taking up ``sum p_i T``: a loop whose
    branches meet smoothly where the temperature turns (the narrow plays saturate after a small
    step, the wide ones only after a long sweep), which one play cannot draw. One play is the
    case of a single nonzero weight; the offset form the limit of every ``r_i -> 0``. ``start``:
    the unknown state before the record, common to the plays (``mid``, ``heating`` or
    ``cooling``, as :func:`play_branch`)."""
    import numpy as np

    r = [float(v) for v in half_widths_C]
    w = np.asarray(weights, float)
    if len(r) != w.size or not r:
        raise ValueError("a Prandtl-Ishlinskii hysteresis needs one weight per play, and at least one play")
    if np.any(w < 0) or not w.sum() > 0:
        raise ValueError("the weights of a Prandtl-Ishlinskii hysteresis must be >= 0 and not all 0")
    return sum(wi * play_branch(temperature_C, ri, start) for wi, ri in zip(w, r)) / w.sum()


def branch_offset(half_width, branch):
    """Offset of the branch from the mid-line: ``h * b`` (b = +1 cooling, -1 heating, 0 none)."""
    return half_width * branch


class Hysteresis(Effect):
    name = "hysteresis"
    description = "half-width of the thermal hysteresis loop of each angle, (cooling - heating)/2 (arcsec)"

    def parameters(self):
        return per_angle("Ca_{ab}_hysteresis", "arcsec", 10.0,
                         "hysteresis of Ca_{ab}: (cooling - heating)/2", self.name)

    def angles(self, p, cov, dT, angles):
        out = dict(angles)
        for ab in ANGLE_NAMES:
            out[ab] = angles[ab] + branch_offset(p[f"Ca_{ab}_hysteresis"], cov.branch)
        return out
