"""Bench-campaign simulator: the same physics as the estimators (:class:`Model`).

A campaign is a sequence of chamber setpoints; at each, the chamber is commanded,
the unit soaks, then every position of the plan is visited (a bench move and settle,
then an averaging window of ``tau_s``). The chamber follows its setpoint with a
first-order time constant, the unit follows the chamber with another; each
accelerometer's temperature sensor reads the unit's temperature plus its own
self-heating and white reading noise. Outputs come from :meth:`Model.predict` with
per-visit bench positioning errors and wobble (sigma_1, sigma_2 of eq. 4), plus the
white output noise of intensity Q averaged over tau (variance Q / tau).
"""

from __future__ import annotations

from ..errors import InputError

import json
from dataclasses import asdict, dataclass, field
from typing import Mapping, Optional, Sequence

import numpy as np

from .. import __version__
from .campaign import DEFAULT_PLAN, Campaign
from .effects.hysteresis import BRANCH, direction_after
from .effects import DEFAULT_EFFECTS, NOISE_EFFECTS
from .model import Covariates, Model
from .thermal_environment import ramp_sequence, sensor_temperatures, step_sequence
from .units import ARCSEC, DEG, STANDARD_GRAVITY_M_S2

#: 12 positions x 15 setpoints: soaked at ambient, heated to +70, cooled to -40, heated back
STANDARD_SETPOINTS_C = (20.0, 35.0, 55.0, 70.0, 55.0, 35.0, 20.0, 5.0, -10.0, -25.0, -40.0,
                        -25.0, -10.0, 5.0, 20.0)


@dataclass
class Schedule:
    """Thermal and timing plan of a campaign.

    The unit has soaked at ``start_C`` (ambient) with no known history: a first setpoint at
    ``start_C`` is ``none`` (the hysteresis mid-line); one away from it is reached by heating or
    cooling and is on that branch; every later one is ``heating`` or ``cooling`` by comparison
    with the previous setpoint. (Until 2026-12-01 the first setpoint was ``none`` wherever it
    lay: a plan over 30..85 degC labelled 30, reached from 20 by heating, the mid-line; an outside
    probe's unit on the heating branch there fitted with status ok and the angles 5-14 u off.)
    """

    setpoints_C: Sequence[float] = STANDARD_SETPOINTS_C
    start_C: float = 20.0
    soak_s: float = 7200.0
    tau_s: float = 30.0
    move_s: float = 20.0
    chamber_time_constant_s: float = 600.0
    unit_time_constant_s: float = 1200.0
    self_heating_C: tuple = (0.30, 0.35, 0.25)
    #: soak per setpoint (s), in the order of ``setpoints_C``; None: ``soak_s`` at every one
    #: (a plan of ``triadcal plan`` states its own, see triadcal.planning)
    soak_each_s: Optional[Sequence[float]] = None

    def soak_at(self, i: int) -> float:
        """The soak before the visits of setpoint ``i`` (s)."""
        return float(self.soak_s if self.soak_each_s is None else self.soak_each_s[i])

    def directions(self) -> list[str]:
        out, previous = [], self.start_C
        for sp in self.setpoints_C:
            out.append(direction_after(out[-1] if out else "none", previous, sp))
            previous = sp
        return out


@dataclass
class RampSchedule:
    """A continuous-ramp campaign (no soak): the chamber follows a piecewise-linear program
    through ``program_C`` (e.g. 20 -> -40 -> 85 -> 20 degC) at ``rate_C_per_min``, holding
    ``hold_s`` at every interior turning point (0: none), while the bench cycles through the
    positions without pause (a move of ``move_s``, then an averaging window of ``tau_s`` per
    visit) for as long as the program runs; the chamber hours are the program's duration.

    The unit follows the chamber through the thermal environment of :class:`Schedule` (two
    first-order lags, :func:`~triadcal.models.thermal_environment.ramp_sequence`, exact for the
    ramp). Each visit is labelled with the direction in which the unit's temperature moves
    during it (``heating`` on a rise, ``cooling`` on a fall: the ramp as the unit sees it, which
    trails the program's turns by the lags) and with the target of the program's current leg as
    its ``setpoint_C``, so a bench CSV block (consecutive visits of equal setpoint and direction)
    is one leg. Each visit carries the exact mean rate of its readings over the window
    (``dTdt_C_per_min``, as ``capture --ramp`` writes the measured one), which the fit takes as
    the rate for ``thermal_lag``.
    """

    program_C: Sequence[float] = (20.0, -40.0, 85.0, 20.0)
    rate_C_per_min: float = 1.0
    hold_s: float = 0.0
    tau_s: float = 30.0
    move_s: float = 20.0
    chamber_time_constant_s: float = 600.0
    unit_time_constant_s: float = 1200.0
    self_heating_C: tuple = (0.30, 0.35, 0.25)

    @property
    def start_C(self) -> float:
        return float(self.program_C[0])

    @property
    def setpoints_C(self) -> tuple:
        """The program's turning points (for messages; the visits carry their leg's target)."""
        return tuple(float(v) for v in self.program_C)

    def knots(self) -> tuple:
        """``(times_s, values_C)`` of the program, holds included."""
        if len(self.program_C) < 2:
            raise InputError("a ramp program needs at least two temperatures")
        if not self.rate_C_per_min > 0:
            raise InputError("the ramp rate must be > 0 degC/min")
        if self.hold_s < 0 or not self.tau_s > 0 or self.move_s < 0:
            raise InputError("a ramp needs hold_s >= 0, tau_s > 0 and move_s >= 0")
        rate = self.rate_C_per_min / 60.0
        ts, vs = [0.0], [float(self.program_C[0])]
        last = len(self.program_C) - 1
        for k in range(1, len(self.program_C)):
            v = float(self.program_C[k])
            ts.append(ts[-1] + abs(v - vs[-1]) / rate)
            vs.append(v)
            if self.hold_s > 0 and k < last:
                ts.append(ts[-1] + self.hold_s)
                vs.append(v)
        return np.array(ts), np.array(vs)

    @property
    def duration_s(self) -> float:
        return float(self.knots()[0][-1])

    def visit_windows(self) -> np.ndarray:
        """Start times (s) of the averaging windows: visits back to back for the program's duration."""
        per = self.move_s + self.tau_s
        n = int(np.floor(self.duration_s / per + 1e-9))
        return np.arange(n) * per + self.move_s


def ramp_history(schedule: RampSchedule, times) -> tuple:
    """Chamber, unit (degC) and unit rate (degC/s) at ``times`` on the ramp program."""
    kt, kv = schedule.knots()
    return ramp_sequence(times, kt, kv, schedule.chamber_time_constant_s, schedule.unit_time_constant_s)


def _ramp_visits(schedule: RampSchedule, plan: Mapping[str, tuple]):
    """Visits of a ramp campaign: labels, axes, leg targets, directions, mid times, taus, the mean
    sensor temperatures over each window (n, 3) and the mean unit rate over it (n,)."""
    kt, kv = schedule.knots()
    start = schedule.visit_windows()
    tau = float(schedule.tau_s)
    if len(start) == 0:
        raise InputError(f"the ramp program ({schedule.duration_s:.0f} s) is shorter than one visit")
    t0, tm, t1 = start, start + tau / 2, start + tau
    _, u0, _ = ramp_history(schedule, t0)
    _, um, _ = ramp_history(schedule, tm)
    _, u1, _ = ramp_history(schedule, t1)
    unit_mean = (u0 + 4.0 * um + u1) / 6.0            # Simpson: the window's mean temperature
    rate_mean = (u1 - u0) / tau                       # exactly the window's mean rate
    seg = np.clip(np.searchsorted(kt, tm, side="right"), 1, len(kt) - 1)
    target = kv[seg]
    dirs = np.where(rate_mean > 0, "heating", np.where(rate_mean < 0, "cooling", "none"))
    items = list(plan.items())
    labels = [items[k % len(items)][0] for k in range(len(start))]
    a1 = [items[k % len(items)][1][0] for k in range(len(start))]
    a2 = [items[k % len(items)][1][1] for k in range(len(start))]
    sensor_T = sensor_temperatures(unit_mean, schedule.self_heating_C)
    return labels, a1, a2, list(target), list(dirs), tm, [tau] * len(start), sensor_T, rate_mean


@dataclass
class NoiseModel:
    """Random errors of a campaign (eq. 4's terms).

    ``Q_V2s`` white-noise intensity of each output (output unit^2 s); ``sigma_position_arcsec``
    random error of each bench axis per visit (sigma_1); ``sigma_wobble_arcsec`` wobble of
    axis 1 per visit (sigma_2); ``heavy_tails_dof`` draws the averaged output noise from a
    Student-t with that many degrees of freedom and the same standard deviation (the
    ``heavy_tails`` effect; None for Gaussian). ``flicker_Bf`` (output unit, 0 = off) is the
    Allan-deviation floor of independent flicker (1/f) noise on each output (the
    ``flicker_noise`` effect): the visit means get errors drawn from ``N(0, B_f^2 C)``, ``C`` the
    covariance of their deviations from the campaign mean
    (:func:`triadcal.models.effects.flicker_noise.centred_covariance`, from the visits' times
    and windows), from a generator of its own derived from the seed, so the other draws (and a
    campaign without flicker) are unchanged.
    """

    Q_V2s: float = 3e-9
    sample_rate_hz: float = 100.0
    sigma_position_arcsec: float = 0.0
    sigma_wobble_arcsec: float = 0.0
    temp_noise_C: float = 0.01
    heavy_tails_dof: Optional[float] = None
    flicker_Bf: float = 0.0
    #: LSB of a digital output (output unit; None = not quantised): the visit means get the
    #: expected quantisation error (:mod:`triadcal.models.effects.quantisation`)
    quantisation_lsb: Optional[float] = None

    def output_sigma(self, tau_s):
        """Standard deviation of a mean over ``tau_s``: sqrt(Q / tau) (white noise)."""
        return np.sqrt(self.Q_V2s / np.asarray(tau_s, float))


@dataclass
class Truth:
    """What a simulated campaign is made of: the unit's parameters (reporting units),
    the active effects, and the noise."""

    unit: str = "SN-SIM-0001"
    effects: tuple = DEFAULT_EFFECTS
    parameters: dict = field(default_factory=dict)
    noise: NoiseModel = field(default_factory=NoiseModel)
    reference_temperature_C: float = 20.0
    local_g_m_s2: float = STANDARD_GRAVITY_M_S2

    def model(self) -> Model:
        return Model(self.effects, self.reference_temperature_C)

    def to_dict(self) -> dict:
        model = self.model()
        return {
            "format": "triadcal.truth", "version": 1, "unit": self.unit,
            "effects": list(self.effects),
            "reference_temperature_C": self.reference_temperature_C,
            "local_g_m_s2": self.local_g_m_s2,
            "parameters": {n: {"value": float(self.parameters.get(n, model.spec[n].nominal)),
                               "unit": model.spec[n].unit} for n in model.names},
            "noise": {k: v for k, v in asdict(self.noise).items()
                      if not (k in ("flicker_Bf", "quantisation_lsb") and not v)},     # absent when off: old truths unchanged
        }

    @classmethod
    def from_dict(cls, d: Mapping) -> "Truth":
        if d.get("format") != "triadcal.truth" or d.get("version") != 1:
            raise InputError(f"not a triadcal.truth version 1 document (format={d.get('format')!r}, "
                             f"version={d.get('version')!r})")
        return cls(unit=d["unit"], effects=tuple(d["effects"]),
                   parameters={k: v["value"] for k, v in d["parameters"].items()},
                   noise=NoiseModel(**d["noise"]),
                   reference_temperature_C=d["reference_temperature_C"],
                   local_g_m_s2=d["local_g_m_s2"])

    def save(self, path) -> None:
        from ..io.atomic import atomic_write_json

        atomic_write_json(path, self.to_dict())

    @classmethod
    def load(cls, path) -> "Truth":
        with open(path, encoding="utf-8") as fh:
            return cls.from_dict(json.load(fh))


def _angles(values):
    return dict(zip(("xy", "xz", "yx", "yz", "zx", "zy"), values))


def _preset(K, S, angles, tempco, hyst, K_tc, S_tc, K2, asym, drift, lag_min, tilt_arcsec, tilt_beta_deg,
            tempco2=(0.004, -0.003, 0.0035, -0.004, 0.003, 0.0025), K_tc2=(0.05, -0.04, 0.06),
            S_tc2=(0.05, -0.04, 0.06), tempco3=(2e-5, -1.5e-5, 1.8e-5, -2e-5, 1.5e-5, 1.2e-5),
            K_tc3=(2e-4, -1.5e-4, 2.5e-4), S_tc3=(2e-4, -1.5e-4, 2.5e-4)):
    p = {}
    for ab, v in _angles(tempco3).items():
        p[f"Ca_{ab}_tempco3"] = v
    for a, k3c, s3c in zip("xyz", K_tc3, S_tc3):
        p.update({f"K_{a}_tempco3": k3c, f"S_{a}_tempco3": s3c})
    for ab, v in _angles(tempco2).items():
        p[f"Ca_{ab}_tempco2"] = v
    for a, k2c, s2c in zip("xyz", K_tc2, S_tc2):
        p.update({f"K_{a}_tempco2": k2c, f"S_{a}_tempco2": s2c})
    for a, k, s, ktc, stc, k2, e, d in zip("xyz", K, S, K_tc, S_tc, K2, asym, drift):
        p.update({f"K_{a}": k, f"S_{a}": s, f"K_{a}_tempco": ktc, f"S_{a}_tempco": stc,
                  f"K2_{a}": k2, f"K_{a}_asymmetry": e, f"S_{a}_drift": d})
    for ab, v in _angles(angles).items():
        p[f"Ca_{ab}"] = v
    for ab, v in _angles(tempco).items():
        p[f"Ca_{ab}_tempco"] = v
    for ab, v in _angles(hyst).items():
        p[f"Ca_{ab}_hysteresis"] = v
    p["tilt_x"] = tilt_arcsec * np.cos(tilt_beta_deg * DEG)
    p["tilt_y"] = tilt_arcsec * np.sin(tilt_beta_deg * DEG)
    p["thermal_lag"] = lag_min
    # the bench's axes 8" off orthogonal (the paper's bench certificate states a few arcsec)
    p["bench_nonorth"] = 8.0
    # a base that settles by a few arcsec over a day-and-a-half campaign
    p["tilt_x_drift"], p["tilt_y_drift"] = 1.5, -1.0
    # or a freshly mounted base that settles by 15", 10" with a time constant of 4 h
    p["tilt_x_settle"], p["tilt_y_settle"], p["tilt_settle_tau"] = 15.0, -10.0, 4.0
    return p


#: Units drawn from the seed paper's Tables 1-2 (angles within the measured maximum
#: deviation, tempcos of the measured size, hysteresis half-widths of Table 1), on a
#: bench tilted by 60" toward 30 deg. Every effect of the vocabulary has a value, so a
#: preset can switch any of them on.
PRESETS: dict[str, dict] = {
    # quartz AK-18: max deviation 8.5', angle tempco 0.8"/degC, hysteresis +-15"
    "ak18-quartz": _preset(
        K=(1.00021, 0.99987, 1.00043), S=(8.0e-4, -1.2e-3, 5.0e-4),
        angles=(312.0, -145.0, 88.0, -420.0, 240.0, 505.0),
        tempco=(0.8, -0.6, 0.5, 0.7, -0.8, 0.4), hyst=(12.0, -8.0, 15.0, 6.0, -10.0, 9.0),
        K_tc=(15.0, -20.0, 25.0), S_tc=(20.0, -15.0, 30.0), K2=(10.0, -8.0, 12.0),
        asym=(20.0, -15.0, 25.0), drift=(3.0, -2.0, 4.0), lag_min=4.0,
        tilt_arcsec=60.0, tilt_beta_deg=30.0),
    # silicon A-18: max deviation 14.5', angle tempco 4.9"/degC, hysteresis up to +-60"
    "a18-silicon": _preset(
        K=(0.99912, 1.00074, 0.99958), S=(2.1e-3, -1.6e-3, 9.0e-4),
        angles=(-610.0, 420.0, 870.0, -230.0, 515.0, -760.0),
        tempco=(4.9, -3.8, 4.2, -4.6, 3.1, 4.5), hyst=(35.0, -28.0, 40.0, 22.0, -30.0, 33.0),
        K_tc=(110.0, -90.0, 130.0), S_tc=(100.0, -80.0, 120.0), K2=(40.0, -30.0, 50.0),
        asym=(60.0, -45.0, 70.0), drift=(10.0, -8.0, 12.0), lag_min=8.0,
        tilt_arcsec=60.0, tilt_beta_deg=30.0),
}


#: warm-up after power-on (bias_warmup, scale_warmup; models/effects/warmup.py): the offset at
#: power-on (ug, ppm) and its time constant (min). MEMS vendors quote 1-5 mg settling in 2-10 min
#: for a silicon unit; a quartz pendulous unit warms by a few tenths of a mg
_WARMUP = {"ak18-quartz": ((300.0, -200.0, 250.0), 4.0, (20.0, -15.0, 25.0), 4.0),
           "a18-silicon": ((2500.0, -1800.0, 3000.0), 6.0, (150.0, -120.0, 200.0), 6.0)}
for _name, (_db, _tau_b, _dk, _tau_k) in _WARMUP.items():
    for _a, _b, _k in zip("xyz", _db, _dk):
        PRESETS[_name].setdefault(f"S_{_a}_warmup", _b)
        PRESETS[_name].setdefault(f"K_{_a}_warmup", _k)
    PRESETS[_name].setdefault("S_warmup_tau", _tau_b)
    PRESETS[_name].setdefault("K_warmup_tau", _tau_k)


#: third-order and cross-axis terms of IEEE Std 1293 (scale_cubic, cross_coupling,
#: g_dependent_misalignment; models/effects/cross_axis.py): K3 in ug/g3, Kc in ug/g2 (xy, xz, yx, yz,
#: zx, zy), the g-dependent misalignment in arcsec/g2. A pendulous quartz unit holds them to tens of
#: ug; a MEMS unit's K3 is 50-200 ug/g3 and its cross-coupling 100-500 ug/g2
_CROSS_AXIS = {"ak18-quartz": ((15.0, -10.0, 12.0), (30.0, -20.0, 25.0, -15.0, 20.0, -30.0),
                               (3.0, -2.0, 2.5, -3.0, 2.0, 1.5)),
               "a18-silicon": ((120.0, -80.0, 150.0), (250.0, -180.0, 300.0, -220.0, 200.0, -260.0),
                               (20.0, -15.0, 18.0, -22.0, 16.0, 12.0))}
for _name, (_k3, _kc, _m) in _CROSS_AXIS.items():
    for _a, _v in zip("xyz", _k3):
        PRESETS[_name].setdefault(f"K3_{_a}", _v)
    for _ab, _c, _g in zip(("xy", "xz", "yx", "yz", "zx", "zy"), _kc, _m):
        PRESETS[_name].setdefault(f"Kc_{_ab}", _c)
        PRESETS[_name].setdefault(f"Ca_{_ab}_g2", _g)


def preset_truth(name: str = "ak18-quartz", effects: Sequence[str] = DEFAULT_EFFECTS,
                 noise: Optional[NoiseModel] = None, unit: str = "SN-SIM-0001", **overrides) -> Truth:
    """A :class:`Truth` from a preset, keeping the parameters of the chosen effects.

    ``overrides`` set parameters by name (reporting units).
    """
    if name not in PRESETS:
        raise InputError(f"unknown preset {name!r}; presets: {', '.join(PRESETS)}")
    effects = tuple(e for e in effects if e not in NOISE_EFFECTS)
    model = Model(effects)
    params = {n: PRESETS[name][n] for n in model.names}
    for k, v in overrides.items():
        if k not in model.spec:
            raise InputError(f"parameter {k!r} is not in the model with effects {list(effects)}")
        params[k] = float(v)
    return Truth(unit=unit, effects=tuple(model.effect_names), parameters=params,
                 noise=noise or NoiseModel())


def thermal_history(schedule: Schedule, times: np.ndarray, setpoint_start: np.ndarray,
                    setpoint_values: np.ndarray):
    """Chamber and unit temperatures (degC) and the unit's rate (degC/s) at ``times``.

    The chamber follows its setpoint with time constant tau_c, the unit follows the
    chamber with tau_u: two first-order lags in series, in closed form
    (:func:`triadcal.models.thermal_environment.step_sequence`).
    """
    return step_sequence(times, setpoint_start, setpoint_values, schedule.start_C,
                         schedule.chamber_time_constant_s, schedule.unit_time_constant_s)


def lagged_element_history(schedule, times, step_starts, tau_s: float, location: str, self_heating_C):
    """Thermometer readings and element temperatures (n, 3) at ``times`` for a thermal lag over the
    whole history (docs/model.md, "Thermal lag: where the thermometer sits"): the element lags the
    unit's housing by ``tau_s`` (:func:`~triadcal.models.effects.thermal_lag.element_temperature` on
    the unit's temperature on a 5 s grid), and the thermometer reads the housing (``"housing"``, with
    the sensors' self-heating) or the chamber air (``"air"``: the housing then lags the air by the
    schedule's ``unit_time_constant_s``)."""
    from .effects.thermal_lag import LOCATIONS, element_temperature

    if location not in LOCATIONS:
        raise InputError(f"unknown thermometer location {location!r}; choose one of {', '.join(LOCATIONS)}")
    times = np.asarray(times, float)
    grid = np.arange(0.0, float(times.max()) + 10.0, 5.0)
    if isinstance(schedule, RampSchedule):
        chamber, unit, _ = ramp_history(schedule, grid)
    else:
        chamber, unit, _ = thermal_history(schedule, grid, np.asarray(step_starts, float),
                                           np.asarray(schedule.setpoints_C, float))
    element = np.interp(times, grid, element_temperature(grid, unit, tau_s, "housing"))
    reading = np.interp(times, grid, unit if location == "housing" else chamber)
    heat = self_heating_C if location == "housing" else (0.0, 0.0, 0.0)
    return sensor_temperatures(reading, heat), sensor_temperatures(element, self_heating_C)


def simulate_campaign(truth: Truth, plan: Optional[Mapping[str, tuple]] = None,
                      schedule: Optional[Schedule] = None, seed: int = 0,
                      state: str = "initial", thermal_lag_location: Optional[str] = None) -> Campaign:
    """Simulate a bench campaign; the same seed gives the same campaign. ``schedule``: a stepped
    :class:`Schedule` (default) or a continuous :class:`RampSchedule`. ``thermal_lag_location``
    (``"housing"`` or ``"air"``): with ``thermal_lag`` among the truth's effects, the element lags
    over the whole history (:func:`lagged_element_history`) instead of the model's rate form."""
    plan = dict(DEFAULT_PLAN if plan is None else plan)
    schedule = schedule or Schedule()
    rng = np.random.default_rng(seed)
    noise = truth.noise
    model = truth.model()

    if isinstance(schedule, RampSchedule):
        labels, a1, a2, sp_c, dirs, times, taus, sensor_T, unit_rate = _ramp_visits(schedule, plan)
        n = len(labels)
    else:
        labels, a1, a2, sp_c, dirs, times, taus, starts = [], [], [], [], [], [], [], []
        t = 0.0
        for i_sp, (sp, d) in enumerate(zip(schedule.setpoints_C, schedule.directions())):
            starts.append(t)
            t += schedule.soak_at(i_sp)
            for label, (ax1, ax2) in plan.items():
                t += schedule.move_s
                labels.append(label)
                a1.append(ax1)
                a2.append(ax2)
                sp_c.append(sp)
                dirs.append(d)
                times.append(t + schedule.tau_s / 2)
                taus.append(schedule.tau_s)
                t += schedule.tau_s
        n = len(labels)
        times = np.array(times)
        _, unit_T, unit_rate = thermal_history(schedule, times, np.array(starts),
                                               np.array(schedule.setpoints_C, float))
        sensor_T = sensor_temperatures(unit_T, schedule.self_heating_C)
    branch = np.array([BRANCH[d] for d in dirs])
    model_T = sensor_T
    # a ramp's measured rate (bench CSV dTdt_C_per_min, as capture --ramp writes it): the exact mean
    # rate of the readings over each window; the simulator draws no per-sample readings, so there is
    # no reading noise to put in it (a capture's: 0.001 degC/min rms on 120 s windows, 0.01 on 20 s;
    # docs/hardware.md)
    dTdt = unit_rate * 60.0 if isinstance(schedule, RampSchedule) else None
    if thermal_lag_location is not None and "thermal_lag" in truth.effects:
        tau_lag = float(truth.parameters["thermal_lag"]) * 60.0
        sensor_T, model_T = lagged_element_history(schedule, np.asarray(times, float),
                                                   None if isinstance(schedule, RampSchedule) else starts,
                                                   tau_lag, thermal_lag_location, schedule.self_heating_C)
        unit_rate = np.zeros(len(labels))      # the rate form is inert: the element's temperature is given
        if dTdt is not None:                   # the readings are the housing's or the air's: their rate
            half = np.asarray(taus, float) / 2.0
            r0, _ = lagged_element_history(schedule, np.asarray(times, float) - half, None, tau_lag,
                                           thermal_lag_location, schedule.self_heating_C)
            r1, _ = lagged_element_history(schedule, np.asarray(times, float) + half, None, tau_lag,
                                           thermal_lag_location, schedule.self_heating_C)
            dTdt = (r1 - r0).mean(axis=1) / (2.0 * half) * 60.0

    cov = Covariates(
        axis1=np.radians(a1), axis2=np.radians(a2),
        temp=tuple(model_T[:, i] for i in range(3)),
        temp_rate=tuple(unit_rate for _ in range(3)),
        branch=branch, time_s=times,
        axis1_error=rng.normal(0.0, noise.sigma_position_arcsec * ARCSEC, n),
        axis2_error=rng.normal(0.0, noise.sigma_position_arcsec * ARCSEC, n),
        wobble=rng.normal(0.0, noise.sigma_wobble_arcsec * ARCSEC, n))
    gravity_g = truth.local_g_m_s2 / STANDARD_GRAVITY_M_S2
    w_true = np.stack(model.predict(model.to_internal(truth.parameters), cov, gravity_g), axis=1)

    tau = np.array(taus)
    sigma = noise.output_sigma(tau)[:, None]
    if noise.heavy_tails_dof is not None:
        nu = float(noise.heavy_tails_dof)
        if nu <= 2:
            raise InputError("heavy_tails_dof must exceed 2 for a finite variance")
        eps = rng.standard_t(nu, size=(n, 3)) * np.sqrt((nu - 2) / nu)
    else:
        eps = rng.standard_normal((n, 3))
    q_lsb = noise.quantisation_lsb
    if q_lsb:
        # quantisation (docs/model.md "Quantisation"): the visit mean of N samples rounded to q has
        # the expectation w_true + e(w_true; q, sigma_sample), e the characteristic-function series;
        # its scatter is that of the rounded samples, V/N with V their variance at w_true
        # (quantisation.rounded_variance; about sigma_sample^2 + q^2/12, Sheppard)
        from .effects.quantisation import expected_error, rounded_variance

        s_sample = np.sqrt(noise.Q_V2s * noise.sample_rate_hz)
        var_q = rounded_variance(w_true, float(q_lsb), s_sample)
        w_true = w_true + expected_error(w_true, float(q_lsb), s_sample)
        sigma = sigma * np.sqrt(var_q) / s_sample
    w = w_true + sigma * eps
    if noise.flicker_Bf and noise.flicker_Bf > 0:
        from .effects.flicker_noise import draw_visit_errors

        frng = np.random.default_rng(None if seed is None else [int(seed), 0xF11C4E5])
        w = w + draw_visit_errors(np.asarray(times, float), tau, float(noise.flicker_Bf) ** 2, frng)
    t_read = sensor_T + rng.normal(0.0, noise.temp_noise_C, (n, 3))

    n_samples = np.maximum(1, np.round(tau * noise.sample_rate_hz)).astype(int)
    sd_raw = np.sqrt(noise.Q_V2s * noise.sample_rate_hz) if not q_lsb else np.sqrt(var_q)
    sd = sd_raw * np.sqrt(rng.chisquare(np.maximum(n_samples - 1, 1)[:, None], (n, 3))
                          / np.maximum(n_samples - 1, 1)[:, None])

    metadata = {
        "generator": f"triadcal {__version__} simulate",
        "seed": str(seed),
        "bench": "simulated two-axis bench",
        "local_g_m_s2": repr(truth.local_g_m_s2),
        "output_unit": "V",
        "Q_V2s": repr(noise.Q_V2s),
        "power_on_s": "0",          # the simulator's clock starts at power-on (Campaign.time_origin_s)
    }
    if q_lsb:
        metadata["quantisation_lsb"] = repr(float(q_lsb))
    if isinstance(schedule, RampSchedule):
        metadata["ramp"] = (":".join(f"{v:g}" for v in schedule.program_C) + f" degC at "
                            f"{schedule.rate_C_per_min:g} degC/min, hold {schedule.hold_s:g} s")
        metadata["dTdt_method"] = ("exact: the mean rate of the readings over each window from the simulator's "
                                   "thermal model (no per-sample readings are simulated, so no reading noise)")
    return Campaign(
        unit=np.full(n, truth.unit), setpoint_C=np.array(sp_c, float), direction=np.array(dirs),
        time_s=times, position=np.array(labels), axis1_deg=np.array(a1, float),
        axis2_deg=np.array(a2, float), tau_s=tau, w=w, t=t_read, cycle=np.zeros(n, int),
        state=np.full(n, state), sd=sd, n_samples=n_samples, metadata=metadata, dTdt_C_per_min=dTdt)
