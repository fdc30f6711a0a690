"""Switchable effects of the model, by their names in results-json.md.

``EFFECTS`` lists them in the canonical order in which their hooks are applied.
``position_error`` and ``heavy_tails`` act on the noise, not the mean: the simulator
draws them (:class:`triadcal.models.simulate.NoiseModel`), and their likelihood terms
(output variance from bench positioning errors; Student-t log-density) are in
:mod:`.position_error` and :mod:`.heavy_tails`, used by the diagnosis.
"""

from ...errors import InputError
from .asymmetry import ScaleAsymmetry
from .base import Effect
from .bench_geometry import BenchNonorthogonality
from .bias_drift import BiasDrift
from .cross_axis import CrossCoupling, GDependentMisalignment, ScaleCubic
from .hysteresis import Hysteresis
from .nonlinearity import ScaleNonlinearity
from .thermal import AngleTempco, BiasTempco, ScaleTempco
from .thermal2 import AngleTempco2, BiasTempco2, ScaleTempco2
from .thermal3 import AngleTempco3, BiasTempco3, ScaleTempco3
from .thermal_lag import ThermalLag
from .tilt import BenchTilt
from .tilt_drift import TiltDrift, TiltSettling
from .warmup import BiasWarmup, ScaleWarmup

EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (BenchTilt, TiltDrift, TiltSettling, BenchNonorthogonality, ThermalLag, AngleTempco, AngleTempco2, AngleTempco3, Hysteresis, ScaleTempco, ScaleTempco2,
                ScaleTempco3, BiasTempco, BiasTempco2, BiasTempco3, BiasDrift, BiasWarmup, ScaleWarmup, ScaleNonlinearity, ScaleAsymmetry,
                ScaleCubic, CrossCoupling, GDependentMisalignment)
}
NOISE_EFFECTS = ("position_error", "heavy_tails", "flicker_noise")
#: effects of the bench, not of the unit (``Effect.bench``), in canonical order
BENCH_EFFECTS = tuple(name for name, cls in EFFECTS.items() if cls.bench)
#: their parameters, in canonical order (the order in which units on one bench share them)
BENCH_PARAMETERS = tuple(spec.name for name in BENCH_EFFECTS for spec in EFFECTS[name]().parameters())
VOCABULARY = tuple(EFFECTS) + NOISE_EFFECTS

#: the temperature coefficients of every order: the effects that carry a value away from the data's
#: temperatures to another (the reference temperature, a table's rows)
TEMPCO_EFFECTS = ("angle_tempco", "scale_tempco", "bias_tempco", "angle_tempco2", "scale_tempco2", "bias_tempco2",
                  "angle_tempco3", "scale_tempco3", "bias_tempco3")

#: the model a metrologist uses for a thermal campaign on a tilted bench
DEFAULT_EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis")


def get_effects(names) -> tuple[Effect, ...]:
    """Effect instances for ``names`` in canonical order; unknown names raise ValueError."""
    names = list(dict.fromkeys(names))
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise InputError(
            f"unknown effect(s) {', '.join(unknown)}; the model's effects are: {', '.join(EFFECTS)}"
            + (" (position_error and heavy_tails are noise options of the simulator)"
               if set(unknown) & set(NOISE_EFFECTS) else ""))
    return tuple(cls() for n, cls in EFFECTS.items() if n in names)
