"""Second mechanisms of the effect families, for the diagnosis's validation (issue 18, items 3-4).

The validation (``diagnosis_validation``) makes each effect with the model's own term, the code
the candidates are refitted with: the check is partly circular. Here each family is made a
second way: a different physical mechanism, written with numpy on the visit means of a campaign
simulated without the effect, not with the term of ``models/effects``. The decision rules of the
diagnosis (its alpha, the rivals' fractions, the generic families) were set on the first
mechanism; ``validate-diagnosis --second-mechanisms`` tests them on these (docs/diagnosis.md,
"Second mechanisms"). A verdict is right when it names any effect of the family (``FAMILY``):
a play hysteresis named ``hysteresis_play`` names the hysteresis.

Mechanisms (``m`` the magnitude; 1 is the preset's realistic size of the first mechanism):

* ``hysteresis~2`` -- a **play** (backlash) of half-width 8 degC on the visit temperatures
  instead of an offset that follows the direction: the branch ``b = (T - y) / w`` of the play
  operator ``y_k = max(T_k - w, min(T_k + w, y_{k-1}))`` moves through 0 over the first step
  after each reversal; the six hysteresis angles of the preset (6-15 arcsec) times ``m b``.
* ``thermal_lag~2`` -- the thermometer measures the **chamber air**, the housing lags the air
  and the element the housing (two stages; the simulator's ``thermal_lag_location="air"``)
  instead of one stage behind a thermometer on the housing.
* ``tilt_drift~2`` -- the bench **settles**: its tilt changes by ``d (1 - exp(-t / tau_s))``,
  ``tau_s`` a third of the campaign, ``d`` the preset's drift rates (1.5, -1.0 arcsec/h) times
  the campaign's hours times ``m``, instead of a constant rate; gravity tilted in the base frame
  (``kinematics.gravity_in_imu``), not the model's tilt term; right: either law of the change
  (``tilt_drift``, ``tilt_settling``).
* ``bench_tilt~2`` -- the same constant tilt as the preset (52, 30 arcsec, times ``m``), made by
  tilting gravity in the base frame with numpy.
* ``bias_tempco~2`` -- a bias curving **exponentially** with temperature,
  ``2 c theta^2 (exp(x) - 1 - x)``, ``x = (T - 20 degC) / theta``, ``theta`` = 40 degC, ``c`` the
  preset's quadratic tempcos (0.05, -0.04, 0.06 ug/degC^2) times ``m``: every order beyond the
  linear one, which the model holds; right: any order of the bias tempco.
* ``scale_tempco~2`` -- the scale factors' temperature law **exponential** (a material property
  with an Arrhenius-like law, e.g. a magnet's remanence, rather than a polynomial): each K
  changes by the relative ``2 c theta^2 (exp(x) - 1 - x)``, ``x = (T_a - 20 degC) / theta``,
  ``theta`` = 40 degC, ``c`` the preset's quadratic scale tempcos (0.05, -0.04, 0.06 ppm/degC^2)
  times ``m``, applied to the outputs as ``W / (1 + delta)``; right: any order of the scale tempco.
* ``angle_tempco~2`` -- the **mount bends** with the unit's mean temperature (the three sensors'
  mean, not each accelerometer's own reading, which the model's angle tempcos follow), by the same
  exponential law: each sensing-axis angle gains ``2 c theta^2 (exp(x) - 1 - x)`` arcsec, ``c``
  the preset's quadratic angle tempcos (0.0025-0.004 arcsec/degC^2) times ``m``; right: any
  order of the angle tempco.
* ``bias_drift~2`` -- an **ageing** bias that settles, ``r tau (1 - exp(-t / tau))``, ``tau`` the
  campaign's length, ``r`` the preset's rates (3, -2, 4 ug/h) times ``m``.
* ``heavy_tails~2`` -- **contamination**: each output mean is, with probability 0.05 m, hit by
  an extra error of 5 sigma SD (a mixture, not a Student-t).
* ``position_error~2`` -- **uniform** errors of both bench axes per visit (an encoder's
  quantisation), SD 5 arcsec times ``m``, through the bench geometry, instead of normal ones
  on the axes and the wobble.
* ``flicker_noise~2`` -- the bias of each output is a **sum of four Ornstein-Uhlenbeck
  processes** (time constants 0.3, 1.5, 7.5 and 37.5 h, SD 4.8e-6 V m each: an Allan floor near
  3e-6 V m over 0.5-50 h, the classic approximation of 1/f noise) instead of Gaussian noise
  with the 1/f covariance.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..models.kinematics import gravity_in_imu
from .diagnose.candidates import HYSTERESIS_FAMILY

ARCSEC = np.pi / (180.0 * 3600.0)
AXES = "xyz"
PAIRS = ("xy", "xz", "yx", "yz", "zx", "zy")
SUFFIX = "~2"
#: the temperature scale of the exponential laws of the tempco families (degC)
EXP_THETA_C = 40.0



def _exp_curvature(T) -> np.ndarray:
    """``exp(x) - 1 - x``, ``x = (T - 20 degC) / EXP_THETA_C``: what the exponential law of the
    tempco families has beyond its linear term (times ``2 c theta^2``, ``c`` its quadratic tempco)."""
    x = (np.asarray(T, float) - 20.0) / EXP_THETA_C
    return np.exp(x) - 1.0 - x


#: the effects a second mechanism's verdict may name and be right (its family)
FAMILY = {
    "hysteresis": HYSTERESIS_FAMILY,
    "thermal_lag": ("thermal_lag", "thermal_lag_history"),
    "tilt_drift": ("tilt_drift", "tilt_settling"),
    "bench_tilt": ("bench_tilt",),
    "bias_tempco": ("bias_tempco", "bias_tempco2", "bias_tempco3"),
    "scale_tempco": ("scale_tempco", "scale_tempco2", "scale_tempco3"),
    "angle_tempco": ("angle_tempco", "angle_tempco2", "angle_tempco3"),
    "bias_drift": ("bias_drift",),
    "heavy_tails": ("heavy_tails",),
    "position_error": ("position_error",),
    "flicker_noise": ("flicker_noise",),
}
CONDITIONS = tuple(e + SUFFIX for e in FAMILY)


def is_second(condition: str) -> bool:
    return condition.endswith(SUFFIX)


def base_effect(condition: str) -> str:
    """``'hysteresis~2'`` -> ``'hysteresis'``."""
    e = condition[:-len(SUFFIX)] if is_second(condition) else condition
    if is_second(condition) and e not in FAMILY:
        raise InputError(f"no second mechanism for {e!r}; there is one for {', '.join(FAMILY)}")
    return e


def _gravity(campaign, f_base=(0.0, 0.0, 1.0), d1=0.0, d2=0.0) -> np.ndarray:
    """(n, 3) gravity in the IMU frame of each visit with the base-frame gravity ``f_base`` (3,) or
    (3, n) and axis errors ``d1``, ``d2`` (rad)."""
    a1 = np.radians(np.asarray(campaign.axis1_deg, float)) + d1
    a2 = np.radians(np.asarray(campaign.axis2_deg, float)) + d2
    return np.column_stack(gravity_in_imu(a1, a2, f_base))


def _tilted(tx, ty):
    """Base-frame gravity under a tilt (rad) about x and y: ``(ty, -tx, sqrt(1 - ...))``."""
    tx, ty = np.asarray(tx, float), np.asarray(ty, float)
    return np.array([ty, -tx, np.sqrt(1.0 - tx * tx - ty * ty)])


def _K(P) -> np.ndarray:
    return np.array([float(P[f"K_{a}"]) for a in AXES])


def _angle_offsets(G: np.ndarray, angles_rad: dict) -> np.ndarray:
    """Output a gains ``angle_ab g_b`` (small angles of the sensing axes), (n, 3) in g."""
    out = np.zeros_like(G)
    for ab in PAIRS:
        i, j = AXES.index(ab[0]), AXES.index(ab[1])
        out[:, i] += angles_rad[ab] * G[:, j]
    return out


def play_branch(T: np.ndarray, half_width_C: float) -> np.ndarray:
    """The play operator's branch ``(T_k - y_k) / w`` in [-1, 1] over the visit sequence, started
    in the middle (y_0 = T_0)."""
    y = float(T[0])
    out = np.empty(len(T))
    for k, t in enumerate(T):
        y = max(t - half_width_C, min(t + half_width_C, y))
        out[k] = (t - y) / half_width_C
    return out


def _ou_sum(times_s: np.ndarray, taus_h, sd: float, rng) -> np.ndarray:
    """Sum of independent stationary Ornstein-Uhlenbeck processes sampled at ``times_s`` (exact
    discretisation: ``x_k = x_{k-1} e^{-dt/tau} + sd sqrt(1 - e^{-2 dt/tau}) N(0, 1)``)."""
    t = np.asarray(times_s, float)
    total = np.zeros(len(t))
    for tau in np.asarray(taus_h, float) * 3600.0:
        x = sd * rng.standard_normal()
        for k in range(len(t)):
            if k:
                a = np.exp(-(t[k] - t[k - 1]) / tau)
                x = a * x + sd * np.sqrt(1.0 - a * a) * rng.standard_normal()
            total[k] += x
    return total


def second_campaign(effect: str, seed: int, magnitude: float = 1.0, preset: str = "ak18-quartz"):
    """(campaign, fitted model) of the validation campaign whose ``effect`` (a key of ``FAMILY``)
    is made by its second mechanism at ``magnitude`` (module docstring)."""
    from ..models.effects import DEFAULT_EFFECTS
    from ..models.simulate import Schedule, simulate_campaign
    from .diagnosis_validation import VALIDATION_PLAN, VALIDATION_SOAK_S, scenario

    if effect not in FAMILY:
        raise InputError(f"no second mechanism for {effect!r}; there is one for {', '.join(FAMILY)}")
    m = float(magnitude)
    sched = Schedule(soak_s=VALIDATION_SOAK_S)
    # withheld from the truth and the fit: the families the model holds as a first mechanism; the
    # bias tempco's exponential law adds curvature to the linear term, which both keep
    withheld = effect if effect in ("hysteresis", "bench_tilt") else None
    model = tuple(e for e in DEFAULT_EFFECTS if e != withheld)
    if effect == "thermal_lag":
        truth, model = scenario("thermal_lag", preset, m)
        return simulate_campaign(truth, plan=VALIDATION_PLAN, schedule=sched, seed=seed,
                                 thermal_lag_location="air"), model
    truth, _ = scenario("clean", preset)
    P = dict(truth.parameters)                  # the preset's values, the withheld effect's too
    truth.effects = tuple(e for e in truth.effects if e != withheld)
    names = set(truth.model().names)
    truth.parameters = {k: v for k, v in P.items() if k in names}
    c = simulate_campaign(truth, plan=VALIDATION_PLAN, schedule=sched, seed=seed)
    rng = np.random.default_rng([int(seed), 2])
    K = _K(P)
    n = c.n_visits
    hours = (np.asarray(c.time_s, float) - float(c.time_s[0])) / 3600.0
    span_h = max(float(hours[-1]), 1e-9)
    T = np.asarray(c.t, float)
    dA = np.zeros((n, 3))                       # g
    dW = np.zeros((n, 3))                       # output unit
    if effect == "hysteresis":
        b = play_branch(T.mean(axis=1), 8.0)
        ang = {ab: m * float(P[f"Ca_{ab}_hysteresis"]) * ARCSEC for ab in PAIRS}
        dA = _angle_offsets(_gravity(c), ang) * b[:, None]
    elif effect == "bench_tilt":              # the simulated campaign has no tilt: add all of it
        tilt = np.full(n, m * ARCSEC)
        dA = _gravity(c, _tilted(tilt * float(P["tilt_x"]), tilt * float(P["tilt_y"]))) - _gravity(c)
    elif effect == "tilt_drift":              # it holds the constant tilt already: add the change only
        tx0, ty0 = float(P["tilt_x"]) * ARCSEC, float(P["tilt_y"]) * ARCSEC
        settle = span_h * ARCSEC * (1.0 - np.exp(-hours / (span_h / 3.0)))
        dA = (_gravity(c, _tilted(tx0 + m * 1.5 * settle, ty0 - m * 1.0 * settle))
              - _gravity(c, _tilted(np.full(n, tx0), np.full(n, ty0))))
    elif effect == "bias_tempco":
        c2 = m * np.array([0.05, -0.04, 0.06])   # ug/degC^2
        dW = 1e-6 / K * 2.0 * c2 * EXP_THETA_C ** 2 * _exp_curvature(T)
    elif effect == "scale_tempco":
        c2 = m * np.array([0.05, -0.04, 0.06])   # ppm/degC^2
        delta = 1e-6 * 2.0 * c2 * EXP_THETA_C ** 2 * _exp_curvature(T)
        dW = np.asarray(c.w, float) / (1.0 + delta) - np.asarray(c.w, float)
    elif effect == "angle_tempco":
        law = 2.0 * EXP_THETA_C ** 2 * _exp_curvature(T.mean(axis=1))
        c2 = dict(zip(PAIRS, (0.004, -0.003, 0.0035, -0.004, 0.003, 0.0025)))      # arcsec/degC^2
        dA = _angle_offsets(_gravity(c), {ab: m * c2[ab] * law * ARCSEC for ab in PAIRS})
    elif effect == "bias_drift":
        r = m * np.array([3.0, -2.0, 4.0])       # ug/h
        dW = 1e-6 / K * r * span_h * (1.0 - np.exp(-hours / span_h))[:, None]
    elif effect == "heavy_tails":
        sigma = np.sqrt(truth.noise.Q_V2s / np.asarray(c.tau_s, float))[:, None] * np.ones((1, 3))
        hit = rng.random((n, 3)) < 0.05 * m
        dW = np.where(hit, 5.0 * sigma * rng.standard_normal((n, 3)), 0.0)
    elif effect == "position_error":
        half = np.sqrt(3.0) * 5.0 * m * ARCSEC
        d1, d2 = rng.uniform(-half, half, n), rng.uniform(-half, half, n)
        f = _tilted(np.full(n, float(P["tilt_x"]) * ARCSEC),
                    np.full(n, float(P["tilt_y"]) * ARCSEC))
        dA = _gravity(c, f, d1, d2) - _gravity(c, f)
    elif effect == "flicker_noise":
        taus = (0.3, 1.5, 7.5, 37.5)
        dW = np.column_stack([_ou_sum(c.time_s, taus, 4.8e-6 * m, rng) for _ in range(3)])
    # eq. 1 solved for W: W = (Ca G + S) / K, K in g per output unit
    c.w = np.asarray(c.w, float) + dA / K + dW
    return c, model


__all__ = ["CONDITIONS", "FAMILY", "base_effect", "is_second", "play_branch", "second_campaign"]
