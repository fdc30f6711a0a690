"""The emulated unit's physics: what an IMU on the bench in the chamber outputs at an instrument
time (``Model.predict`` of a preset truth, the sensor temperatures behind the chamber air, the
bench's pose and its errors). Read by the emulated IMU stream (:mod:`triadcal.hardware.emulator`)
and the emulated DMMs (:mod:`triadcal.hardware.emulated_instruments`); split from ``emulator.py``.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..models.effects.hysteresis import BRANCH, direction_after
from ..models.model import Covariates
from ..models.simulate import Schedule, Truth
from ..models.thermal_environment import sensor_temperatures, two_lag_step
from ..models.units import ARCSEC, STANDARD_GRAVITY_M_S2

#: bytes the emulator's garbage never contains, so that every damaged frame is counted
#: exactly once (the parsers cope with any bytes; this keeps the tests' accounting exact)


@dataclass
class EmulatorTiming:
    """Timing of the emulated instruments, in instrument seconds (except ``time_scale``)."""

    time_scale: float = 60.0
    rate_hz: float = 10.0
    start_C: float = 20.0
    chamber_time_constant_s: float = 600.0
    unit_time_constant_s: float = 1200.0
    self_heating_C: tuple = (0.30, 0.35, 0.25)
    self_heating_time_constant_s: float = 300.0
    bench_rate_deg_s: float = 10.0
    bench_settle_s: float = 2.0

    @classmethod
    def from_schedule(cls, schedule: Schedule, **kw) -> "EmulatorTiming":
        """The simulator's thermal constants (same chamber and unit)."""
        return cls(start_C=schedule.start_C, chamber_time_constant_s=schedule.chamber_time_constant_s,
                   unit_time_constant_s=schedule.unit_time_constant_s,
                   self_heating_C=tuple(schedule.self_heating_C), **kw)


class UnitPhysics:
    """The unit on the bench in the chamber, as functions of instrument time (thread-safe)."""

    def __init__(self, truth: Truth, timing: EmulatorTiming, seed: int = 0, flicker_Bf_V: float = 0.0):
        """``flicker_Bf_V``: flicker (1/f, bias instability) output noise added in :meth:`sample`,
        given by its Allan-deviation floor B_f = 0.664 B (V; 0: white noise only)."""
        self.flicker_Bf_V = float(flicker_Bf_V)
        self._flicker: Optional[np.ndarray] = None
        if self.flicker_Bf_V > 0:
            # one periodic 1/f record (models/noise_processes.flicker_noise: it wraps without a jump)
            # of 2^20 samples at the timing's rate, indexed by instrument time in sample()
            from ..models.noise_processes import flicker_noise

            frng = np.random.default_rng([seed, 952])
            self._flicker = np.stack([flicker_noise(2 ** 20, timing.rate_hz, self.flicker_Bf_V ** 2, frng)
                                      for _ in range(3)], axis=1)
        self.truth = truth
        self.timing = timing
        self.model = truth.model()
        self.p = self.model.to_internal(truth.parameters)
        self.gravity_g = truth.local_g_m_s2 / STANDARD_GRAVITY_M_S2
        self.rng = np.random.default_rng(seed)
        self.lock = threading.Lock()
        T0 = timing.start_C
        # thermal segment: since t0, setpoint sp, chamber c0 and unit u0 at t0
        self._seg = (0.0, T0, T0, T0)
        # the recent segments, oldest first: a sample of a time before the last setpoint change
        # (the IMU thread computes its frames a tick after their times) takes the segment then in force
        self._segs: list = [self._seg]
        self.setpoint_C = T0
        # the unit soaked at the start temperature: a first setpoint away from it is a move onto a
        # branch (Schedule.directions), one at it leaves the unit on the mid-line
        self._last_sp: Optional[float] = float(T0)
        # from the first change of setpoint on, the hysteresis branch follows the unit's own
        # temperature (heating while it rises): see set_setpoint and branches
        self._follow_from = math.inf          # instrument time from which it does
        self._directions: list = [(-math.inf, "none")]   # (from instrument time, direction set by a setpoint)
        # bench: a move from (a0) at t0 to (a1) arriving at t_arrive, in position at t_ready
        self._move = (0.0, (0.0, 0.0), (0.0, 0.0), 0.0, 0.0)
        #: once in position, axis 1 creeps on at this rate, deg/s (FaultPlan.bench_creep_deg_s), from
        #: ``creep_from`` (instrument s; set by the bench when it first reports the position in position)
        self.creep_deg_s = 0.0
        self.creep_from: Optional[float] = None
        self._errors = self._draw_bench_errors()

    # -- thermal ----------------------------------------------------------------------
    def _thermal(self, t):
        """Chamber, unit (degC) and the unit's rate (degC/s) at instrument times ``t`` (increasing):
        the two first-order lags of models/thermal_environment, in closed form since the last
        setpoint, so a setpoint written every few seconds (a ramp program) is followed exactly.
        The hysteresis branch at each time: :meth:`branches`."""
        t = np.asarray(t, float)
        t0, sp, c0, u0 = self._seg
        if len(self._segs) > 1 and np.min(t, initial=t0) < t0:
            seg = np.array(self._segs)
            k = np.clip(np.searchsorted(seg[:, 0], t, side="right") - 1, 0, len(seg) - 1)
            t0, sp, c0, u0 = seg[k, 0], seg[k, 1], seg[k, 2], seg[k, 3]
        return two_lag_step(t - t0, sp, c0, u0,
                            self.timing.chamber_time_constant_s, self.timing.unit_time_constant_s)

    def branches(self, t, rate) -> np.ndarray:
        """The hysteresis branch (:data:`BRANCH` values) of each sample at instrument times ``t``
        with the unit's rates ``rate`` (degC/s), each at its own time: the direction the setpoints
        set (:meth:`set_setpoint`) before the branch follows the unit, from then on the sign of the
        unit's rate (the setpoints' direction where it is 0). Call under :attr:`lock`. The frames of
        a batch took the branch of its latest sample: the IMU thread computes its frames a tick after
        their times, and a loaded machine made a tick of 0.2 s wall, 100 s of instrument time at x500;
        a batch spanning the unit's turn labelled the frames before the turn with the branch after it
        (a fit of the captured ramp then found a negative play of the thermal terms, z -3.4)."""
        t = np.atleast_1d(np.asarray(t, float))
        rate = np.broadcast_to(np.asarray(rate, float), t.shape)
        starts = np.array([d[0] for d in self._directions])
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(starts) - 1)
        out = np.array([BRANCH[self._directions[i][1]] for i in k], float)
        follow = (t >= self._follow_from) & (rate != 0.0)
        out[follow] = np.where(rate[follow] > 0, BRANCH["heating"], BRANCH["cooling"])
        return out

    def chamber_C(self, t: float) -> float:
        with self.lock:
            return float(self._thermal(t)[0])

    def set_setpoint(self, t: float, sp: float) -> None:
        """Command the chamber at instrument time ``t``. The hysteresis branch: ``none`` while the
        setpoint stays at the start temperature (the unit has soaked at ambient, as
        :meth:`Schedule.directions`); at the first change from it, the direction of the change; from then on, the direction in which the unit's
        own temperature moves (heating while it rises, as :class:`RampSchedule` labels a visit),
        which on a stepped campaign is the direction of the last change once the unit has turned,
        and on a ramp program (a setpoint written every few seconds) trails the program's turns
        as the unit does."""
        with self.lock:
            c, u, _ = self._thermal(t)
            self._seg = (float(t), float(sp), float(c), float(u))
            self._segs = self._segs[-255:] + [self._seg]
            direction = direction_after(self._directions[-1][1], self._last_sp, float(sp))
            self._directions = self._directions[-255:] + [(float(t), direction)]
            if float(sp) != self._last_sp and math.isinf(self._follow_from):
                self._follow_from = float(t)       # the first change: from now on the unit's rate
            self._last_sp = float(sp)
            self.setpoint_C = float(sp)

    # -- bench ------------------------------------------------------------------------
    def _draw_bench_errors(self):
        n = self.truth.noise
        return (self.rng.normal(0.0, n.sigma_position_arcsec * ARCSEC),
                self.rng.normal(0.0, n.sigma_position_arcsec * ARCSEC),
                self.rng.normal(0.0, n.sigma_wobble_arcsec * ARCSEC))

    def move(self, t: float, a1: float, a2: float) -> None:
        with self.lock:
            start = self._angles(t)
            start = (float(start[0]), float(start[1]))
            self.creep_from = None
            dist = max(abs(a1 - start[0]), abs(a2 - start[1]))
            arrive = t + dist / self.timing.bench_rate_deg_s
            self._move = (t, start, (float(a1), float(a2)), arrive, arrive + self.timing.bench_settle_s)
            self._errors = self._draw_bench_errors()

    def _angles(self, t):
        t0, a0, a1, arrive, _ = self._move
        frac = np.clip((np.asarray(t, float) - t0) / max(arrive - t0, 1e-12), 0.0, 1.0)
        creep = (self.creep_deg_s * np.clip(np.asarray(t, float) - self.creep_from, 0.0, None)
                 if self.creep_deg_s and self.creep_from is not None else 0.0)
        return a0[0] + (a1[0] - a0[0]) * frac + creep, a0[1] + (a1[1] - a0[1]) * frac

    def bench_state(self, t: float, start_creep: bool = False):
        """(present angles, target angles, in position) at instrument time ``t``; ``start_creep``:
        a creeping bench (``creep_deg_s``) starts to creep now if it is in position."""
        with self.lock:
            if start_creep and self.creep_deg_s and self.creep_from is None and t >= self._move[4]:
                self.creep_from = float(t)
            a = self._angles(t)
            return (float(a[0]), float(a[1])), self._move[2], t >= self._move[4]

    # -- outputs ----------------------------------------------------------------------
    def sample(self, t: np.ndarray, rate_hz: Optional[float] = None):
        """Outputs (n, 3) in V and temperature readings (n, 3) in degC at times ``t``
        (white noise for samples at ``rate_hz``, by default the timing's rate)."""
        tm = self.timing
        t = np.asarray(t, float)
        n = len(t)
        with self.lock:
            _, unit, rate = self._thermal(t)
            a1, a2 = self._angles(t)
            e1, e2, wob = self._errors
            branch = self.branches(t, rate)
        sensor = sensor_temperatures(unit, tm.self_heating_C, t, tm.self_heating_time_constant_s)
        cov = Covariates(axis1=np.radians(a1), axis2=np.radians(a2),
                         temp=tuple(sensor[:, i] for i in range(3)), temp_rate=(rate, rate, rate),
                         branch=branch, time_s=t, axis1_error=e1, axis2_error=e2, wobble=wob)
        w = np.stack(np.broadcast_arrays(*self.model.predict(self.p, cov, self.gravity_g)), axis=1)
        noise = self.truth.noise
        w = w + self.rng.normal(0.0, math.sqrt(noise.Q_V2s * (rate_hz or tm.rate_hz)), (n, 3))
        if self._flicker is not None:          # flicker: continuous across calls (indexed by time)
            k = np.floor(t * tm.rate_hz).astype(np.int64) % len(self._flicker)
            w = w + self._flicker[k]
        temps = sensor + self.rng.normal(0.0, noise.temp_noise_C, (n, 3))
        return w, temps
