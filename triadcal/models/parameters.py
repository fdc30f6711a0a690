"""Parameter specifications: names, reporting units and typical sizes.

Names follow docs/spec/bench-csv-v1.md and docs/results-json.md (``K_x``, ``S_x``,
``Ca_xy``, ``Ca_xy_tempco``, ...). Values cross the library boundary in their
reporting unit (the ``unit`` field); the physics works in internal units
(:mod:`triadcal.models.units`).
"""

from __future__ import annotations

from dataclasses import dataclass

from .sensor import ANGLE_NAMES, AXES
from .units import TO_INTERNAL


@dataclass(frozen=True)
class ParameterSpec:
    """One model parameter.

    ``typical`` is a typical magnitude of the parameter's spread among units, in the
    reporting unit; it sets the scale of the simulator's presets and of weakly
    informative priors.
    """

    name: str
    unit: str
    typical: float
    description: str
    effect: str = "core"
    nominal: float = 0.0

    @property
    def to_internal(self) -> float:
        """Factor from the reporting unit to the internal unit."""
        return TO_INTERNAL[self.unit]


def per_axis(fmt: str, unit: str, typical: float, description: str, effect: str, nominal: float = 0.0):
    """Specs of one quantity for the X, Y and Z accelerometers; in ``description``, ``{a}`` is
    the axis as a word (X) and ``{ax}`` as in parameter names (x: ``K_{ax}`` reads K_x)."""
    return tuple(
        ParameterSpec(fmt.format(a=a), unit, typical, description.format(a=a.upper(), ax=a), effect, nominal)
        for a in AXES
    )


def per_angle(fmt: str, unit: str, typical: float, description: str, effect: str):
    """Specs of one quantity for the six orientation angles; in ``description``, ``{a}``, ``{b}``
    are the axes as words (X, Y) and ``{ab}`` as in parameter names (``Ca_{ab}`` reads Ca_xy)."""
    return tuple(
        ParameterSpec(fmt.format(ab=ab), unit, typical,
                      description.format(a=ab[0].upper(), b=ab[1].upper(), ab=ab), effect)
        for ab in ANGLE_NAMES
    )


CORE_PARAMETERS = (
    per_axis("K_{a}", "g/V", 0.01, "scale factor of the {a} accelerometer (eq. 1)", "core", 1.0)
    + per_axis("S_{a}", "g", 2e-3, "bias (zero offset) of the {a} accelerometer (eq. 1)", "core")
    + per_angle("Ca_{ab}", "arcsec", 300.0,
                "orientation angle: tilt of the {a} sensing axis toward IMU {b} (eq. 1)", "core")
)
