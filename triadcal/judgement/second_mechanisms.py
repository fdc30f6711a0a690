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
  campaign's length, ``r`` the preset's rates (3, -2, 4 ug/h) times ``m``; right: either law of a
  bias that changes in time, the rate (``bias_drift``) or the exponential (``bias_warmup``, whose
  form this is, with a time constant of hours instead of a power-on's minutes), as for the tilt.
* ``heavy_tails~2`` -- **contamination**: each output mean is, with probability 0.05 m, hit by
  an extra error of 5 sigma SD (a mixture, not a Student-t).
* ``position_error~2`` -- **uniform** errors of both bench axes per visit (an encoder's
  quantisation), SD 5 arcsec times ``m``, through the bench geometry, instead of normal ones
  on the axes and the wobble.
* ``flicker_noise~2`` -- the bias of each output is a **sum of four Ornstein-Uhlenbeck
  processes** (time constants 0.3, 1.5, 7.5 and 37.5 h, SD 4.8e-6 V m each: an Allan floor near
  3e-6 V m over 0.5-50 h, the classic approximation of 1/f noise) instead of Gaussian noise
  with the 1/f covariance.
* ``scale_nonlinearity~2`` -- the even nonlinearity is the **readout's** (the integral
  nonlinearity of the front end and ADC, a bow over the full scale), quadratic in the output
  voltage ``W`` itself, bias and misalignment included, not in the specific force along the
  sensing axis: ``W + c W^2`` with ``c = K2 K`` (``K2`` the preset's, 10, -8, 12 ug/g^2, times ``m``),
  which is ``K2 (K W)^2`` in g: the first mechanism's law to a relative 2 K2 S (about 1e-8).
* ``scale_asymmetry~2`` -- the two gains of a **push-pull output stage** with a smooth crossover:
  ``W (1 + e tanh(K W / 0.05 g))``, ``e`` the preset's asymmetries (20, -15, 25 ppm) times ``m``,
  switching on the sign of the output (bias included), not of the input; ``e |a|`` beyond
  0.15 g, smooth through 0.
* ``scale_cubic~2`` -- an open-loop element on a **Duffing spring**: the deflection ``x`` solves
  ``x + beta x^3 = a`` (Newton's method, ``a = K W`` the linear response in g), ``beta = -K3``
  (the preset's K3, 15, -10, 12 ug/g^3, times ``m``: softening for K3 > 0, stiffening for K3 < 0);
  ``x = a - beta a^3 + 3 beta^2 a^5 ...``, every odd order.
* ``cross_coupling~2`` -- **pendulous elements**: each element's pendulum deflects about its hinge
  by ``delta_a = k_a s_a`` (rad, ``s_a`` its input) and tilts its input axis toward its pendulous
  axis ``p``: the output is ``cos(delta) s_a + sin(delta) s_p`` (an exact rotation), with the
  pendulous axes x -> y, y -> z, z -> x and ``k`` the preset's ``Kc_xy``, ``Kc_yz``, ``Kc_zx``
  (30, -15, 20 ug/g^2) times ``m``: IEEE 1293's physical origin of ``K_ip``, three of the model's
  six coefficients.
* ``g_dependent_misalignment~2`` -- each element's **flexure bows** under the load along its axis:
  its input axis turns toward each other axis ``b`` by ``phi_ab = m_ab s_a^2`` and is rebuilt as
  the unit vector ``(e_a + tan(phi_ab) e_b + tan(phi_ac) e_c) / norm`` dotted with gravity (a
  geometric rotation, not the model's product ``m_ab a_a^2 a_b``), ``m_ab`` the preset's
  ``Ca_ab_g2`` (1.5-3 arcsec/g^2) times ``m``.
* ``bench_nonorthogonality~2`` -- axis 1's **bearing is inclined** by ``w0`` (the preset's 8 arcsec
  times ``m``) in axis 2's platform: the unit turns about ``n = (sin w0, 0, cos w0)`` (Rodrigues'
  formula, written here with numpy), not by a rotation ``Ry(w0)`` inserted between the axes; the
  two differ by a constant rotation of the unit, which its own angles and the tilt absorb.
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
    "bias_drift": ("bias_drift", "bias_warmup"),
    "heavy_tails": ("heavy_tails",),
    "position_error": ("position_error",),
    "flicker_noise": ("flicker_noise",),
    "scale_nonlinearity": ("scale_nonlinearity",),
    "scale_asymmetry": ("scale_asymmetry",),
    "scale_cubic": ("scale_cubic",),
    "cross_coupling": ("cross_coupling",),
    "g_dependent_misalignment": ("g_dependent_misalignment",),
    "bench_nonorthogonality": ("bench_nonorthogonality",),
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


def _preset_values(effect: str, preset: str) -> dict:
    """The preset's values of ``effect``'s parameters (reporting units: ug/g^2, ppm, arcsec ...):
    what the validation's first mechanism is given at magnitude 1."""
    from .diagnosis_validation import scenario

    truth, _ = scenario(effect, preset)
    clean, _ = scenario("clean", preset)
    return {k: float(v) for k, v in truth.parameters.items() if k not in clean.parameters}


def duffing_deflection(a, beta, iterations: int = 4) -> np.ndarray:
    """The root ``x`` of ``x + beta x^3 = a`` near ``a`` (Newton's method from ``x = a``; for
    ``|beta a^2|`` of 1e-5 the error after two steps is below 1e-15): the static deflection of an
    element on a Duffing spring, in units of its linear deflection per g."""
    a = np.asarray(a, float)
    x = a.copy()
    for _ in range(iterations):
        x = x - (x + beta * x ** 3 - a) / (1.0 + 3.0 * beta * x * x)
    return x


def inclined_bearing_gravity(campaign, f_base, w0: float) -> np.ndarray:
    """(n, 3) gravity in the IMU frame when axis 1 turns about ``n = (sin w0, 0, cos w0)`` of axis
    2's platform (its bearing inclined by ``w0`` rad) instead of its z axis: ``u = Rx(axis2)^T f``,
    ``v = Rot(n, axis1)^T u`` by Rodrigues' formula ``v = u cos t - (n x u) sin t + n (n.u)(1 - cos t)``,
    ``G = (v0, v2, -v1)`` (the mounting of bench-csv.md). With ``w0 = 0`` it is the bench's nominal
    kinematics; written here, not taken from ``models.kinematics``."""
    a1 = np.radians(np.asarray(campaign.axis1_deg, float))
    a2 = np.radians(np.asarray(campaign.axis2_deg, float))
    f = np.broadcast_to(np.asarray(f_base, float).reshape(3, -1), (3, len(a1)))
    c2, s2 = np.cos(a2), np.sin(a2)
    u = np.array([f[0], c2 * f[1] + s2 * f[2], -s2 * f[1] + c2 * f[2]])
    n = np.array([np.sin(w0), 0.0, np.cos(w0)])[:, None]
    c1, s1 = np.cos(a1), np.sin(a1)
    v = u * c1 - np.cross(n, u, axis=0) * s1 + n * (n * u).sum(axis=0) * (1.0 - c1)
    return np.column_stack([v[0], v[2], -v[1]])


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
    elif effect in ("scale_nonlinearity", "scale_asymmetry", "scale_cubic"):   # laws of the readout
        v = _preset_values(effect, preset)
        W = np.asarray(c.w, float)
        a = K * W                                                               # g, bias included
        if effect == "scale_nonlinearity":
            k2 = m * 1e-6 * np.array([v[f"K2_{x}"] for x in AXES])              # 1/g
            dW = k2 * K * W * W
        elif effect == "scale_asymmetry":
            e = m * 1e-6 * np.array([v[f"K_{x}_asymmetry"] for x in AXES])
            dW = W * e * np.tanh(a / 0.05)
        else:
            beta = -m * 1e-6 * np.array([v[f"K3_{x}"] for x in AXES])           # 1/g^2
            dW = duffing_deflection(a, beta) / K - W
    elif effect == "cross_coupling":
        v = _preset_values(effect, preset)
        G = _gravity(c)
        for i, ab in enumerate(("xy", "yz", "zx")):                         # element -> pendulous axis
            p = AXES.index(ab[1])
            delta = m * 1e-6 * v[f"Kc_{ab}"] * G[:, i]                           # rad
            dA[:, i] = (np.cos(delta) - 1.0) * G[:, i] + np.sin(delta) * G[:, p]
    elif effect == "g_dependent_misalignment":
        v = _preset_values(effect, preset)
        G = _gravity(c)
        for i, a in enumerate(AXES):
            row = np.zeros((n, 3))
            row[:, i] = 1.0
            for j, b in enumerate(AXES):
                if j != i:
                    row[:, j] = np.tan(m * v[f"Ca_{a}{b}_g2"] * ARCSEC * G[:, i] ** 2)
            row /= np.linalg.norm(row, axis=1)[:, None]
            dA[:, i] = (row * G).sum(axis=1) - G[:, i]
    elif effect == "bench_nonorthogonality":
        v = _preset_values(effect, preset)
        f = _tilted(np.full(n, float(P["tilt_x"]) * ARCSEC), np.full(n, float(P["tilt_y"]) * ARCSEC))
        dA = (inclined_bearing_gravity(c, f, m * v["bench_nonorth"] * ARCSEC)
              - inclined_bearing_gravity(c, f, 0.0))
    # eq. 1 solved for W: W = (Ca G + S) / K, K in g per output unit
    c.w = np.asarray(c.w, float) + dA / K + dW
    return c, model


__all__ = ["CONDITIONS", "FAMILY", "base_effect", "duffing_deflection", "inclined_bearing_gravity", "is_second",
           "play_branch", "second_campaign"]
