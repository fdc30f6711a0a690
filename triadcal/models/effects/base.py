"""The interface every switchable effect of the model implements.

An effect is a small class with a ``name`` from the vocabulary of
docs/results-json.md, its parameters, and one or more hooks that modify an
intermediate quantity of eq. 1. The default hooks leave everything unchanged, so an
effect overrides only what it touches. Hooks receive ``p`` (parameter name ->
internal value) and ``cov`` (:class:`triadcal.models.model.Covariates`) and must be
written with :mod:`triadcal.models.ops` so they run on numpy and CasADi alike.
"""

from __future__ import annotations

from typing import ClassVar


class Effect:
    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    #: True for a property of the bench (its tilt, its axes), not of the unit: it acts on the
    #: apparent gravity, is shared by every unit mounted on the bench, and is no part of the
    #: unit's calibration (certificate, compensation table, comparison of two calibrations)
    bench: ClassVar[bool] = False

    def parameters(self):
        """Tuple of :class:`~triadcal.models.parameters.ParameterSpec`."""
        return ()

    def gravity_base(self, p, cov, f):
        """Apparent gravity direction in the base frame (3-tuple)."""
        return f

    def wobble(self, p, cov, wobble):
        """Rotation about the platform's y axis between the bench's two axes (rad): the
        per-visit wobble of axis 1 plus, for a bench whose axes are not orthogonal, a constant."""
        return wobble

    def temperature(self, p, cov, dT):
        """Temperature of each sensing element, as deviations from the reference (3-tuple, degC)."""
        return dT

    def angles(self, p, cov, dT, angles):
        """Orientation angles in rad (dict ``'xy' -> value``)."""
        return angles

    def scale(self, p, cov, dT, K):
        """Scale factors (3-tuple, g per output unit)."""
        return K

    def bias(self, p, cov, dT, S):
        """Biases (3-tuple, g)."""
        return S

    def transfer(self, p, cov, sensed):
        """Acceleration along each sensing axis as the sensor responds to it (3-tuple, g)."""
        return sensed

    def inverse_transfer(self, p, cov, responded):
        """The inverse of :meth:`transfer`: the acceleration along each sensing axis from what
        the sensor responded (3-tuple, g), used when a calibration is applied to readings.
        An effect that overrides :meth:`transfer` overrides this too (to first order in its
        small parameters where no closed form exists, and says so)."""
        return responded

    def __repr__(self) -> str:
        return f"<effect {self.name}>"
