"""The joint measurement model: eq. 1 with the bench kinematics and switchable effects.

One definition of the physics serves the simulator (numpy, vectorised over visits)
and the estimators (CasADi symbols): :meth:`Model.predict` only uses
:mod:`triadcal.models.ops` and elementwise arithmetic.
"""

from __future__ import annotations

from ..errors import UnknownName

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from . import kinematics, sensor
from .effects import DEFAULT_EFFECTS, Effect, get_effects
from .parameters import CORE_PARAMETERS, ParameterSpec
from .sensor import ANGLE_NAMES, AXES


@dataclass
class Covariates:
    """What the model needs to know of each visit (arrays over visits, or CasADi values).

    Angles in radians (commanded bench angles; ``axis*_error`` and ``wobble`` are the
    simulator's per-visit bench errors, zero for an estimator), temperatures of the
    three accelerometer sensors in degC, their rates in degC/s, the hysteresis branch
    (+1 cooling, -1 heating, 0 none) and the time since the start of the campaign in s.
    """

    axis1: Any
    axis2: Any
    temp: tuple
    temp_rate: tuple
    branch: Any
    time_s: Any
    axis1_error: Any = 0.0
    axis2_error: Any = 0.0
    wobble: Any = 0.0
    #: a constant rotation of the unit in its fixture (radians about the IMU x, y, z axes);
    #: zero for an estimator, a Type B input of the budget (:func:`kinematics.fixture_rotated`)
    fixture: tuple = (0.0, 0.0, 0.0)

    @classmethod
    def at_rest(cls, temps_C, branch=0.0) -> "Covariates":
        """A unit at rest at the temperatures ``temps_C`` of its three sensors (degC; each a number
        or an array), the rates 0, on hysteresis ``branch`` (0: the loop's mid-line), at the time
        origin: what :meth:`Model.terms` needs for K, S and the angles at a temperature (a
        compensation table, a result carried to another temperature)."""
        z = 0.0 * np.asarray(temps_C[0], float)
        return cls(axis1=z, axis2=z, temp=tuple(temps_C), temp_rate=(z, z, z), branch=z + branch, time_s=z)

    def take(self, index) -> "Covariates":
        """The covariates of a subset of visits (numpy only)."""
        def t(v):
            return v[index] if isinstance(v, np.ndarray) and v.ndim else v
        return Covariates(t(self.axis1), t(self.axis2), tuple(t(v) for v in self.temp),
                          tuple(t(v) for v in self.temp_rate), t(self.branch), t(self.time_s),
                          t(self.axis1_error), t(self.axis2_error), t(self.wobble),
                          tuple(t(v) for v in self.fixture))


class Model:
    """Eq. 1 with bench kinematics and a set of effects.

    ``parameters`` lists the core parameters (K, S, the six angles) followed by those of
    the effects in canonical order. ``gravity_g`` is the magnitude of the local apparent
    gravity in g (local g / standard gravity).
    """

    def __init__(self, effects: Sequence[str] = DEFAULT_EFFECTS, reference_temperature_C: float = 20.0):
        self.effects: tuple[Effect, ...] = get_effects(effects)
        self.reference_temperature_C = float(reference_temperature_C)
        specs: list[ParameterSpec] = list(CORE_PARAMETERS)
        for e in self.effects:
            specs.extend(e.parameters())
        self.parameters: tuple[ParameterSpec, ...] = tuple(specs)
        self.names: tuple[str, ...] = tuple(s.name for s in specs)
        self.spec: dict[str, ParameterSpec] = {s.name: s for s in specs}

    @property
    def effect_names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    def __repr__(self) -> str:
        return f"Model(effects={list(self.effect_names)}, T0={self.reference_temperature_C} degC)"

    # -- conversions ----------------------------------------------------------------
    def to_internal(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """Reporting units -> internal units, for every parameter of the model.

        Missing parameters take their nominal value (1 for K, 0 otherwise).
        """
        unknown = set(values) - set(self.names)
        if unknown:
            raise UnknownName(f"parameters not in {self!r}: {sorted(unknown)}")
        return {s.name: values.get(s.name, s.nominal) * s.to_internal for s in self.parameters}

    def vector(self, values: Mapping[str, float]) -> np.ndarray:
        """Reporting-unit values as a vector in the order of ``names`` (nominal where missing)."""
        return np.array([float(values.get(s.name, s.nominal)) for s in self.parameters])

    def scales(self) -> np.ndarray:
        """Reporting -> internal factors in the order of ``names``."""
        return np.array([s.to_internal for s in self.parameters])

    # -- the physics ------------------------------------------------------------------
    def terms(self, p: Mapping[str, Any], cov: Covariates):
        """Scale factors, biases and orientation angles (internal units) at each visit's
        temperature, branch and time: ``(K, S, angles)`` after every effect's hooks."""
        dT = tuple(t - self.reference_temperature_C for t in cov.temp)
        for e in self.effects:
            dT = e.temperature(p, cov, dT)
        angles = {ab: p[f"Ca_{ab}"] for ab in ANGLE_NAMES}
        K = tuple(p[f"K_{a}"] for a in AXES)
        S = tuple(p[f"S_{a}"] for a in AXES)
        for e in self.effects:
            angles = e.angles(p, cov, dT, angles)
            K = e.scale(p, cov, dT, K)
            S = e.bias(p, cov, dT, S)
        return K, S, angles

    def inverse_transfer(self, p: Mapping[str, Any], cov: Covariates, responded):
        """The acceleration along each sensing axis from the sensor's response (3-tuple, g):
        every effect's :meth:`~triadcal.models.effects.base.Effect.inverse_transfer`, in the
        reverse order of :meth:`predict`."""
        for e in reversed(self.effects):
            responded = e.inverse_transfer(p, cov, responded)
        return responded

    def predict(self, p: Mapping[str, Any], cov: Covariates, gravity_g: Any = 1.0):
        """Outputs ``(W_x, W_y, W_z)`` of every visit (eq. 1 solved for W).

        ``p`` maps every parameter name to its internal value (radians, g, fractions,
        seconds: see :meth:`to_internal`).
        """
        # gravity direction in the base frame, rotated into the IMU frame (bench-csv.md)
        f = (0.0, 0.0, 1.0)
        for e in self.effects:
            f = e.gravity_base(p, cov, f)
        wobble = cov.wobble
        for e in self.effects:
            wobble = e.wobble(p, cov, wobble)
        g_imu = kinematics.gravity_in_imu(cov.axis1 + cov.axis1_error, cov.axis2 + cov.axis2_error,
                                          f, wobble)
        if any(not (isinstance(v, float) and v == 0.0) for v in cov.fixture):
            g_imu = kinematics.fixture_rotated(g_imu, *cov.fixture)
        g_imu = tuple(gravity_g * c for c in g_imu)

        K, S, angles = self.terms(p, cov)
        Ca = sensor.dcm(angles)
        sensed = tuple(sensor.sensed_acceleration(Ca[i], g_imu) for i in range(3))
        for e in self.effects:
            sensed = e.transfer(p, cov, sensed)
        return tuple(sensor.output(sensed[i], K[i], S[i]) for i in range(3))
