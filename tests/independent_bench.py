"""An independent simulator of bench campaigns (bench CSV v1 text), for cross-checks.

It is written without the project's model code: nothing is imported from
``triadcal.models``, ``triadcal.estimation`` or ``triadcal.uncertainty``. The bench
kinematics are rebuilt here from rotation matrices (scipy's ``Rotation``), eq. 1 from
explicit 3x3 matrices, and the CSV text is written by hand. Only the *conventions* follow
the project (docs/model.md, docs/bench-csv.md):

* ``R_base_from_imu = Rx(axis2 + e2) . Ry(wobble) . Rz(axis1 + e1) . M`` with
  ``M = [[1,0,0],[0,0,-1],[0,1,0]]`` (IMU frame -> platform frame at zero angles);
* apparent gravity in the base frame ``(sin d cos b, sin d sin b, cos d)``, given here by its
  horizontal components ``tilt_x = sin d cos b``, ``tilt_y = sin d sin b`` (arcsec, the
  project's reporting unit for ``tilt_x``/``tilt_y``);
* ``G_imu = R_base_from_imu^T f_base * g_true / g0``, then a fixture rotation
  ``G_imu' = R_fix^T G_imu``;
* ``W_a = (sum_b Ca_ab(T_a) G'_b + S_a(T_a)) / K_a(T_a)``, each row of ``Ca`` a unit vector
  whose off-diagonal elements are the angles ``Ca_ab``;
* linear thermal terms about T0 = 20 degC with each accelerometer's own sensor ``t_a``:
  ``Ca_ab(T) = Ca_ab + c_ab (t_a - T0)``, ``K_a(T) = K_a (1 + k_a (t_a - T0))`` (k in
  ppm/degC, a relative factor), ``S_a(T) = S_a + s_a (t_a - T0)`` (s in ug/degC); when the
  truth holds them, quadratic and cubic terms (``*_tempco2``, ``*_tempco3``: per degC^2 and
  degC^3, K's a relative factor too), evaluated here as a polynomial by Horner's rule;
* a hysteresis of the angles ``Ca_ab += h_ab * b`` (``Ca_ab_hysteresis`` = h in arcsec, the
  saturated loop's half-width, (cooling - heating)/2), with ``b`` from :class:`Backlash`, a
  mechanical backlash written as a state machine on the unit's temperature path (the unit soaks
  at each setpoint, so the path between two setpoints is monotone): ``offset`` (b = +-1 from
  the last move, 0 before any), ``play`` (one backlash of half-width r) or ``pi`` (a weighted
  sum of backlashes of several half-widths, normalised so that the saturated loop is h).
* when the truth holds them, IEEE Std 1293's third-order and cross-axis terms on the sensed
  components ``s = Ca G`` (row by row, all from the same ``s``): ``K3_a`` (ug/g3) adds
  ``K3 s_a^3``, ``Kc_ab`` (ug/g2) adds ``Kc s_a s_b``, and ``Ca_ab_g2`` (arcsec/g2) tilts row ``a``
  of ``Ca`` itself: the row is rebuilt as a unit vector with the angle ``Ca_ab + Ca_ab_g2 s_a^2``
  and dotted with ``G`` again (an angle, not the project's product form);
* ``positions``: any set of bench positions (label -> (axis1_deg, axis2_deg)), e.g.
  :data:`OBLIQUE_POSITIONS`, the 12 above plus 12 with gravity along a face diagonal.

Reporting units of the returned truth (as the project's parameter table): K in g/V, S in g,
angles in arcsec, ``Ca_ab_tempco`` in arcsec/degC, ``K_a_tempco`` in ppm/degC,
``S_a_tempco`` in ug/degC, ``tilt_x``/``tilt_y`` in arcsec.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

G0 = 9.80665                                   # standard gravity, m/s^2
ARCSEC_RAD = math.pi / (180.0 * 3600.0)        # radians per arcsecond
T0_C = 20.0                                    # reference temperature of the thermal terms
AXES = "xyz"
ANGLES = ("xy", "xz", "yx", "yz", "zx", "zy")

#: the 12 positions of examples/data/campaign.csv: label -> (axis1_deg, axis2_deg)
POSITIONS = {
    "P01": (0.0, 0.0), "P02": (180.0, 0.0), "P03": (0.0, 180.0), "P04": (180.0, 180.0),
    "P05": (90.0, 90.0), "P06": (270.0, 270.0), "P07": (270.0, 90.0), "P08": (90.0, 270.0),
    "P09": (180.0, 90.0), "P10": (0.0, 270.0), "P11": (0.0, 90.0), "P12": (180.0, 270.0),
}

#: 12 more positions with gravity along a face diagonal of the IMU frame (two axes at 45 deg),
#: the angles of ``triadcal plan --positions 24``; tests check with this module's own rotations
#: that gravity lies where the comment says
DIAGONAL_POSITIONS = {
    "D01": (90.0, 45.0), "D02": (90.0, 225.0),     # +X+Y, -X-Y
    "D03": (135.0, 90.0), "D04": (135.0, 270.0),   # +X+Z, -X-Z
    "D05": (0.0, 315.0), "D06": (0.0, 135.0),      # +Y+Z, -Y-Z
    "D07": (90.0, 135.0), "D08": (90.0, 315.0),    # +X-Y, -X+Y
    "D09": (45.0, 90.0), "D10": (45.0, 270.0),     # +X-Z, -X+Z
    "D11": (0.0, 45.0), "D12": (0.0, 225.0),       # +Y-Z, -Y+Z
}
OBLIQUE_POSITIONS = {**POSITIONS, **DIAGONAL_POSITIONS}

#: IMU frame -> platform frame at zero bench angles (IMU Y up along axis 1, X along axis 2)
MOUNT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

COLUMNS = ("unit", "setpoint_C", "direction", "time_s", "position", "axis1_deg", "axis2_deg", "tau_s",
           "w_x", "w_y", "w_z", "t_x", "t_y", "t_z", "cycle", "state", "sd_x", "sd_y", "sd_z", "n_samples")


def default_truth(rng: np.random.Generator) -> dict:
    """A plausible unit, in reporting units (names as the project's results)."""
    t = {}
    for a in AXES:
        t[f"K_{a}"] = float(rng.uniform(0.99, 1.01))
    for a in AXES:
        t[f"S_{a}"] = float(rng.uniform(-3e-3, 3e-3))
    for ab in ANGLES:
        t[f"Ca_{ab}"] = float(rng.uniform(-100.0, 100.0))
    for ab in ANGLES:
        t[f"Ca_{ab}_tempco"] = float(rng.uniform(-0.3, 0.3))
    for a in AXES:
        t[f"K_{a}_tempco"] = float(rng.uniform(-30.0, 30.0))
    for a in AXES:
        t[f"S_{a}_tempco"] = float(rng.uniform(-20.0, 20.0))     # ug/degC (= +-2e-5 g/degC)
    return t


def _directions(setpoints):
    """'none' for the first setpoint, then heating/cooling against the previous one; a repeated
    setpoint keeps the previous direction (docs/model.md, hysteresis)."""
    out, prev, d = [], None, "none"
    for sp in setpoints:
        if prev is not None:
            if sp > prev:
                d = "heating"
            elif sp < prev:
                d = "cooling"
        out.append(d)
        prev = sp
    return out


class Backlash:
    """A gear with slack 2r driven by the temperature: the follower keeps its position until the
    driver touches one of its two faces, then is pushed along. ``state`` says which face is in
    contact ('free', 'lower' after a rise, 'upper' after a fall); the branch of the visit is the
    follower's offset from the driver in units of r: -1 after a rise has taken up the slack, +1
    after a fall, in between otherwise."""

    def __init__(self, half_width_C: float, T_start: float, start: str = "mid"):
        self.r = float(half_width_C)
        self.follower = {"mid": T_start, "heating": T_start - self.r, "cooling": T_start + self.r}[start]
        self.state = {"mid": "free", "heating": "lower", "cooling": "upper"}[start]

    def move_to(self, T: float) -> float:
        gap = T - self.follower
        if gap >= self.r:                       # the driver's upper face pushes the follower up
            self.follower, self.state = T - self.r, "lower"
        elif gap <= -self.r:                    # the lower face pushes it down
            self.follower, self.state = T + self.r, "upper"
        elif self.state != "free" and abs(gap) < self.r:
            self.state = "free"
        return (self.follower - T) / self.r


def hysteresis_branch(path_C, form: str, half_widths_C=(), weights=(), start: str = "mid"):
    """Branch of each point of a temperature path (degC, in time order) for the forms above."""
    path = [float(v) for v in path_C]
    if form == "offset":
        out, last = [], 0.0
        for k, T in enumerate(path):
            if k and T > path[k - 1]:
                last = -1.0
            elif k and T < path[k - 1]:
                last = 1.0
            out.append(last)
        return np.array(out)
    if form == "play":
        half_widths_C, weights = half_widths_C[:1], (1.0,)
    elif form != "pi":
        raise ValueError(form)
    gears = [Backlash(r, path[0], start) for r in half_widths_C]
    total = float(sum(weights))
    return np.array([sum(w * g.move_to(T) for w, g in zip(weights, gears)) / total for T in path])


def _poly(c0, dT, *coefficients):
    """c0 + c1 dT + c2 dT^2 + ... by Horner's rule."""
    acc = 0.0
    for c in reversed(coefficients):
        acc = (acc + c) * dT
    return c0 + acc


def _ca_matrix(angles_rad: dict) -> np.ndarray:
    """Ca with unit rows; ``angles_rad[ab]`` is the off-diagonal element (row a, column b)."""
    C = np.zeros((3, 3))
    for i, a in enumerate(AXES):
        for j, b in enumerate(AXES):
            if i != j:
                C[i, j] = angles_rad[a + b]
        C[i, i] = math.sqrt(1.0 - sum(C[i, j] ** 2 for j in range(3) if j != i))
    return C


def _nonlinear_response(Ca, angles_rad, G, truth):
    """What the three sensing elements respond to: ``Ca G`` plus, when the truth holds them, the
    third-order term ``K3_a s_a^3``, the cross-coupling ``Kc_ab s_a s_b`` and the g-dependent
    misalignment as a tilted row of Ca (see the module docstring); ``s = Ca G``."""
    s = Ca @ G
    out = s.copy()
    for i, a in enumerate(AXES):
        out[i] += truth.get(f"K3_{a}", 0.0) * 1e-6 * s[i] ** 3
        tilted = dict(angles_rad)
        moved = False
        for j, b in enumerate(AXES):
            if j == i:
                continue
            out[i] += truth.get(f"Kc_{a}{b}", 0.0) * 1e-6 * s[i] * s[j]
            m = truth.get(f"Ca_{a}{b}_g2", 0.0)
            if m:
                tilted[a + b] = angles_rad[a + b] + m * ARCSEC_RAD * s[i] ** 2
                moved = True
        if moved:
            out[i] += _ca_matrix(tilted)[i] @ G - s[i]
    return out


def simulate_campaign(rng, *, truth=None, setpoints_C=(-40, -10, 20, 50, 80), tau_s=30.0, noise_sd=5e-4,
                      n_samples=3000, sigma_position_arcsec=0.0, sigma_wobble_arcsec=0.0,
                      encoder_zero_arcsec=(0.0, 0.0), axes_nonorthogonality_arcsec=0.0,
                      fixture_arcsec=(0.0, 0.0, 0.0), tilt_arcsec=(0.0, 0.0),
                      local_g_m_s2=9.80665, true_g_m_s2=None, unit="SN-IND-0001", hysteresis=None,
                      positions=None, tilt_change=None, encoder_error=None, fixture_change=None,
                      extra_scale=None, extra_bias=None, room_field=None) -> tuple[str, dict]:
    """CSV text of a bench campaign (12 positions at every setpoint, or ``positions``) and the true parameters.

    ``rng``: a ``numpy.random.Generator`` (used for the default truth, the temperature
    readings, the bench's random errors and the output noise, in that order).
    ``local_g_m_s2`` is written to the metadata (what the lab believes); the data are made with
    ``true_g_m_s2`` (default: the same). Systematic bench errors: ``encoder_zero_arcsec``
    (axis 1, axis 2) added to the commanded angles, ``axes_nonorthogonality_arcsec`` (a constant
    Ry between the axes), ``fixture_arcsec`` (rotation vector of the unit in its fixture about
    IMU x, y, z: ``G' = R_fix^T G``), ``tilt_arcsec`` (horizontal components of the gravity
    direction in the base frame); ``tilt_change``: None, or a function of the visits' times (s, the
    file's clock) returning the change of the two tilt components (arcsec, arrays), added to
    ``tilt_arcsec`` (a bench that drifts or settles during the campaign). Random per visit: ``e1, e2 ~ N(0, sigma_position_arcsec)`` and
    a wobble ``~ N(0, sigma_wobble_arcsec)``. The mean output of each visit gets white noise of
    SD ``noise_sd / sqrt(n_samples)``; ``sd_*`` columns say ``noise_sd`` (a float, or a function of
    the setpoint in degC: noise that grows with temperature).

    Effects outside the project's vocabulary, as functions of the schedule (for open-world checks of
    the diagnosis): ``encoder_error(axis1_rad, axis2_rad) -> (e1, e2)`` arcsec added to the angles
    (e.g. an encoder's once-per-revolution error); ``fixture_change(time_s) -> (n, 3)`` rotation
    vectors (arcsec, about IMU x, y, z) applied after the fixture (a unit that slips in its fixture);
    ``extra_scale(k, time_s, temps) -> (3,)`` relative change of K of visit ``k``;
    ``extra_bias(k, time_s, temps, G, direction) -> (3,)`` g added to the biases of visit ``k``
    (``G`` the gravity on the IMU axes, g); ``room_field``: ``(C, b)``, a field ``b`` fixed in the
    base frame (3,) acting on the sensor through the matrix ``C`` (3, 3; g per unit of field): the
    bias ``C R_base_from_imu^T b`` (a magnet in the room; with ``C`` a multiple of the identity and
    ``b`` horizontal it would be a tilt).

    ``hysteresis``: None, or ``{"form": "offset"|"play"|"pi", "half_widths_C": [...], "weights":
    [...], "start": "mid"|"heating"|"cooling"}`` with ``Ca_ab_hysteresis`` in the truth; the
    branch follows the setpoint path (the unit soaked at each setpoint).

    The returned truth dict holds the unit's parameters (reporting units) plus ``tilt_x`` and
    ``tilt_y`` (arcsec).
    """
    truth = dict(default_truth(rng) if truth is None else truth)
    g_true = local_g_m_s2 if true_g_m_s2 is None else true_g_m_s2
    setpoints = [float(s) for s in setpoints_C]
    dirs = _directions(setpoints)
    plan = dict(POSITIONS if positions is None else positions)
    labels = list(plan)
    n = len(setpoints) * len(labels)

    # schedule: 2 h soak per setpoint, 50 s per visit
    sp = np.repeat(setpoints, len(labels))
    direction = np.repeat(dirs, len(labels))
    pos = np.tile(labels, len(setpoints))
    a1_cmd = np.tile([plan[p][0] for p in labels], len(setpoints))
    a2_cmd = np.tile([plan[p][1] for p in labels], len(setpoints))
    time_s = np.array([7200.0 * (1 + k // len(labels)) + 8000.0 * (k // len(labels)) + 50.0 * (k % len(labels))
                       for k in range(n)])
    temps = sp[:, None] + rng.normal(0.0, 0.01, size=(n, 3))     # t_x t_y t_z

    # actual bench angles (radians)
    e1 = rng.normal(0.0, sigma_position_arcsec, n) if sigma_position_arcsec > 0 else np.zeros(n)
    e2 = rng.normal(0.0, sigma_position_arcsec, n) if sigma_position_arcsec > 0 else np.zeros(n)
    wob = rng.normal(0.0, sigma_wobble_arcsec, n) if sigma_wobble_arcsec > 0 else np.zeros(n)
    if encoder_error is not None:
        c1, c2 = encoder_error(np.radians(a1_cmd), np.radians(a2_cmd))
        e1, e2 = e1 + np.asarray(c1, float), e2 + np.asarray(c2, float)
    ax1 = np.radians(a1_cmd) + (encoder_zero_arcsec[0] + e1) * ARCSEC_RAD
    ax2 = np.radians(a2_cmd) + (encoder_zero_arcsec[1] + e2) * ARCSEC_RAD
    wobble = (axes_nonorthogonality_arcsec + wob) * ARCSEC_RAD

    Rx = Rotation.from_euler("x", ax2[:, None]).as_matrix()
    Ry = Rotation.from_euler("y", wobble[:, None]).as_matrix()
    Rz = Rotation.from_euler("z", ax1[:, None]).as_matrix()
    R_base_from_imu = Rx @ Ry @ Rz @ MOUNT                       # (n, 3, 3)

    tx, ty = (np.full(n, v * ARCSEC_RAD) for v in tilt_arcsec)
    if tilt_change is not None:
        dx, dy = tilt_change(time_s)
        tx, ty = tx + np.asarray(dx, float) * ARCSEC_RAD, ty + np.asarray(dy, float) * ARCSEC_RAD
    f_base = np.column_stack([tx, ty, np.sqrt(1.0 - tx * tx - ty * ty)])          # (n, 3), per visit
    G = np.einsum("nji,nj->ni", R_base_from_imu, f_base) * (g_true / G0)  # R^T f, in g
    R_fix = Rotation.from_rotvec(np.asarray(fixture_arcsec, float) * ARCSEC_RAD).as_matrix()
    G = G @ R_fix                                                # rows: (R_fix^T G)^T = G^T R_fix
    if fixture_change is not None:
        R_slip = Rotation.from_rotvec(np.asarray(fixture_change(time_s), float) * ARCSEC_RAD).as_matrix()
        G = np.einsum("nji,nj->ni", R_slip, G)                   # G' = R_slip^T G, per visit

    if hysteresis is None:
        branch = np.zeros(n)
    else:
        branch = hysteresis_branch(sp, hysteresis["form"], hysteresis.get("half_widths_C", ()),
                                   hysteresis.get("weights", ()), hysteresis.get("start", "mid"))

    def coefs(name):
        return [truth.get(f"{name}_tempco", 0.0), truth.get(f"{name}_tempco2", 0.0), truth.get(f"{name}_tempco3", 0.0)]

    W = np.empty((n, 3))
    for k in range(n):
        dT = temps[k] - T0_C
        ang = {ab: (_poly(truth[f"Ca_{ab}"], dT[AXES.index(ab[0])], *coefs(f"Ca_{ab}"))
                    + truth.get(f"Ca_{ab}_hysteresis", 0.0) * branch[k]) * ARCSEC_RAD
               for ab in ANGLES}
        Ca = _ca_matrix(ang)
        K = np.array([truth[f"K_{a}"] * (1.0 + 1e-6 * _poly(0.0, dT[i], *coefs(f"K_{a}")))
                      for i, a in enumerate(AXES)])
        S = np.array([truth[f"S_{a}"] + 1e-6 * _poly(0.0, dT[i], *coefs(f"S_{a}"))
                      for i, a in enumerate(AXES)])
        if extra_scale is not None:
            K = K * (1.0 + np.asarray(extra_scale(k, time_s[k], temps[k]), float))
        if extra_bias is not None:
            S = S + np.asarray(extra_bias(k, time_s[k], temps[k], G[k], direction[k]), float)
        if room_field is not None:
            C, b = (np.asarray(x, float) for x in room_field)
            S = S + C @ (R_base_from_imu[k].T @ b)
        W[k] = (_nonlinear_response(Ca, ang, G[k], truth) + S) / K
    if callable(noise_sd):                  # an SD per setpoint (honest sd_* columns say it)
        sd_k = np.array([float(noise_sd(x)) for x in sp])
        W += rng.normal(0.0, 1.0, size=W.shape) * (sd_k / math.sqrt(n_samples))[:, None]
    else:
        sd_k = np.full(n, float(noise_sd))
        W += rng.normal(0.0, noise_sd / math.sqrt(n_samples), size=W.shape)

    lines = ["# generator = tests/independent_bench.py",
             "# bench = independent simulated two-axis bench",
             "# power_on_s = 0",
             f"# local_g_m_s2 = {local_g_m_s2!r}",
             "# output_unit = V",
             ",".join(COLUMNS)]
    for k in range(n):
        row = [unit, repr(float(sp[k])), direction[k], repr(float(time_s[k])), pos[k],
               repr(float(a1_cmd[k])), repr(float(a2_cmd[k])), repr(float(tau_s)),
               *(repr(float(v)) for v in W[k]), *(repr(float(v)) for v in temps[k]),
               "0", "initial", *([repr(float(sd_k[k]))] * 3), str(int(n_samples))]
        lines.append(",".join(row))
    truth.setdefault("tilt_x", float(tilt_arcsec[0]))
    truth.setdefault("tilt_y", float(tilt_arcsec[1]))
    return "\n".join(lines) + "\n", truth


# ------------------------------------------------------------------------------------------
# thermal lag of the element and warm-up after power-on, by explicit Euler integration of the
# heat equations (not the project's lag or warm-up functions)
# ------------------------------------------------------------------------------------------
def euler_thermal_history(program, *, tau_chamber_min=5.0, tau_housing_min=20.0, tau_element_min=5.0,
                          dt_s=0.5, start_C=None):
    """Air, housing and element temperatures on a grid of ``dt_s`` (explicit Euler)::

        dA/dt = (P(t) - A)/tau_c,  dH/dt = (A - H)/tau_h,  dE/dt = (H - E)/tau_e

    ``program(t)`` is the chamber's programmed temperature (degC); all three start at rest at
    ``program(0)`` (or ``start_C``). Returns ``(t, air, housing, element)``."""
    t_end = program.duration_s
    n = int(math.ceil(t_end / dt_s)) + 1
    t = np.arange(n) * dt_s
    P = program(t)
    a = h = e = float(P[0] if start_C is None else start_C)
    ka, kh, ke = dt_s / (60.0 * tau_chamber_min), dt_s / (60.0 * tau_housing_min), dt_s / (60.0 * tau_element_min)
    A, H, E = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        A[k], H[k], E[k] = a, h, e
        # one explicit Euler step of the three equations (all from the values at step k)
        a, h, e = a + ka * (P[k] - a), h + kh * (a - h), e + ke * (h - e)
    return t, A, H, E


class RampProgram:
    """Piecewise-linear program through ``points_C`` at ``rate_C_per_min`` (a hold of ``hold_min`` at
    each interior turn), then ``tail_min`` held at the last point."""

    def __init__(self, points_C=(20.0, -40.0, 70.0, 20.0), rate_C_per_min=1.0, hold_min=0.0, tail_min=0.0):
        ts, vs = [0.0], [float(points_C[0])]
        for k, v in enumerate(points_C[1:], start=1):
            ts.append(ts[-1] + abs(v - vs[-1]) / rate_C_per_min * 60.0)
            vs.append(float(v))
            if hold_min > 0 and k < len(points_C) - 1:
                ts.append(ts[-1] + hold_min * 60.0)
                vs.append(float(v))
        ts.append(ts[-1] + tail_min * 60.0)
        vs.append(vs[-1])
        self.ts, self.vs = np.array(ts), np.array(vs)
        self.duration_s = float(self.ts[-1])
        self.stepped = False

    def __call__(self, t):
        return np.interp(t, self.ts, self.vs)


class StepProgram:
    """Setpoint steps: ``soak_min`` at each, then the visits of the 12 positions (``visit_s`` each)."""

    def __init__(self, setpoints_C=(20.0, 50.0, 80.0, 50.0, 20.0, -10.0, -40.0, -10.0, 20.0), soak_min=120.0,
                 visit_s=50.0):
        self.setpoints = [float(s) for s in setpoints_C]
        self.block_s = soak_min * 60.0 + len(POSITIONS) * visit_s
        self.soak_s = soak_min * 60.0
        self.duration_s = self.block_s * len(self.setpoints)
        self.stepped = True

    def __call__(self, t):
        k = np.clip((np.asarray(t, float) // self.block_s).astype(int), 0, len(self.setpoints) - 1)
        return np.array(self.setpoints)[k]


def simulate_lag_campaign(rng, *, program=None, tau_element_min=5.0, location="housing", tau_housing_min=20.0,
                          tau_chamber_min=5.0, warmup=None, truth=None, tau_s=30.0, move_s=20.0, noise_sd=5e-4,
                          n_samples=3000, temp_noise_C=0.01, dt_s=0.5, unit="SN-IND-LAG",
                          element_play_C=0.0, measured_rate: bool = False,
                          element_rate_form: bool = False) -> tuple[str, dict]:
    """CSV text of a campaign whose thermal terms follow the sensing element, lagging its
    thermometer, and the true parameters (reporting units, plus ``thermal_lag`` and
    ``thermal_lag_housing`` in min).

    The heat equations are integrated by :func:`euler_thermal_history`. ``location``: where the
    thermometer sits, ``"housing"`` (it reads H; the element lags it by ``tau_element_min``) or
    ``"air"`` (it reads A; housing and element lag behind). ``program``: :class:`RampProgram`
    (visits back to back, default) or :class:`StepProgram` (12 visits after each soak).
    ``warmup``: ``(db_ug (3,), tau_w_min)`` adds ``db exp(-t/tau_w)`` to each bias, ``t`` from
    power-on at ``time_s = 0``. ``element_play_C``: the thermal terms follow the element's temperature
    through a mechanical backlash of that half-width (the state machine below, started mid-band): a
    hysteresis of every thermal term. Each visit's outputs and readings are means over its averaging
    window of the integrated states. ``measured_rate``: a ``dTdt_C_per_min`` column, the least-squares
    slope of the thermometer's integrated reading over each window (as ``capture --ramp`` measures it).
    ``element_rate_form``: the element at ``H - tau_e dH/dt`` (the rate form as the physics, with the
    housing's integrated rate) instead of the first-order stage (housing thermometer only)."""
    program = program or RampProgram()
    truth = dict(default_truth(rng) if truth is None else truth)
    t, A, H, E = euler_thermal_history(program, tau_chamber_min=tau_chamber_min, tau_housing_min=tau_housing_min,
                                       tau_element_min=tau_element_min, dt_s=dt_s)
    reading = H if location == "housing" else A
    if element_rate_form:
        if location != "housing":
            raise ValueError("element_rate_form: the rate form behind a housing thermometer only")
        E = H - 60.0 * tau_element_min * np.gradient(H, t)
    if element_play_C > 0:
        held, pushed = float(E[0]), np.empty_like(E)
        for k, x in enumerate(E):             # the backlash: moves only when pushed at one side of the gap
            if x > held + element_play_C:
                held = x - element_play_C
            elif x < held - element_play_C:
                held = x + element_play_C
            pushed[k] = held
        E = pushed
    labels = list(POSITIONS)
    # window starts
    if program.stepped:
        starts = np.array([b * program.block_s + program.soak_s + k * (move_s + tau_s) + move_s
                           for b in range(len(program.setpoints)) for k in range(len(labels))])
        sp = np.repeat(program.setpoints, len(labels))
        dirs = np.repeat(_directions(program.setpoints), len(labels))
        pos = np.tile(labels, len(program.setpoints))
    else:
        per = move_s + tau_s
        nv = int((program.duration_s - tau_s) // per)
        starts = np.arange(nv) * per + move_s
        starts = starts[starts + tau_s <= program.duration_s]
        mid = starts + tau_s / 2
        slope = np.interp(mid + 1.0, t, reading) - np.interp(mid - 1.0, t, reading)
        dirs = np.where(slope > 0, "heating", np.where(slope < 0, "cooling", "none"))
        # the program leg's target as the setpoint: consecutive visits of one leg form one block
        leg = np.clip(np.searchsorted(program.ts, mid, side="right"), 1, len(program.ts) - 1)
        sp = program.vs[leg]
        pos = np.array([labels[k % len(labels)] for k in range(len(starts))])
    n = len(starts)

    def window_mean(x):
        out = np.empty(n)
        for k, s in enumerate(starts):
            m = (t >= s) & (t <= s + tau_s)
            out[k] = float(np.mean(x[m]))
        return out

    Ew = window_mean(E)
    Rw = window_mean(reading)
    rate_w = np.empty(n)
    for k, s0 in enumerate(starts):
        m = (t >= s0) & (t <= s0 + tau_s)
        rate_w[k] = float(np.polyfit(t[m] - t[m].mean(), reading[m], 1)[0]) * 60.0
    time_s = starts + tau_s / 2
    a1 = np.array([POSITIONS[p][0] for p in pos])
    a2 = np.array([POSITIONS[p][1] for p in pos])
    Rx = Rotation.from_euler("x", np.radians(a2)[:, None]).as_matrix()
    Rz = Rotation.from_euler("z", np.radians(a1)[:, None]).as_matrix()
    G = np.einsum("nji,j->ni", Rx @ Rz @ MOUNT, np.array([0.0, 0.0, 1.0]))
    decay = np.zeros(n)
    db = np.zeros(3)
    if warmup is not None:
        db = np.asarray(warmup[0], float)
        decay = window_mean(np.exp(-t / (60.0 * warmup[1])))
    W = np.empty((n, 3))
    for k in range(n):
        dT = Ew[k] - T0_C
        ang = {ab: (truth[f"Ca_{ab}"] + truth.get(f"Ca_{ab}_tempco", 0.0) * dT) * ARCSEC_RAD for ab in ANGLES}
        Ca = _ca_matrix(ang)
        K = np.array([truth[f"K_{a}"] * (1.0 + truth.get(f"K_{a}_tempco", 0.0) * 1e-6 * dT) for a in AXES])
        S = np.array([truth[f"S_{a}"] + truth.get(f"S_{a}_tempco", 0.0) * 1e-6 * dT for a in AXES])
        S = S + db * 1e-6 * decay[k]
        W[k] = (Ca @ G[k] + S) / K
    W += rng.normal(0.0, noise_sd / math.sqrt(n_samples), size=W.shape)
    temps = Rw[:, None] + rng.normal(0.0, temp_noise_C, size=(n, 3))

    lines = ["# generator = tests/independent_bench.py (Euler heat equations)",
             "# bench = independent simulated two-axis bench",
             "# power_on_s = 0",
             "# local_g_m_s2 = 9.80665",
             "# output_unit = V",
             ",".join(COLUMNS + (("dTdt_C_per_min",) if measured_rate else ()))]
    for k in range(n):
        row = [unit, repr(float(sp[k])), str(dirs[k]), repr(float(time_s[k])), str(pos[k]),
               repr(float(a1[k])), repr(float(a2[k])), repr(float(tau_s)),
               *(repr(float(v)) for v in W[k]), *(repr(float(v)) for v in temps[k]),
               "0", "initial", *([repr(float(noise_sd))] * 3), str(int(n_samples))]
        if measured_rate:
            row.append(repr(float(rate_w[k])))
        lines.append(",".join(row))
    truth["thermal_lag"] = float(tau_element_min)
    truth["thermal_lag_housing"] = float(tau_housing_min)
    if warmup is not None:
        truth.update({f"S_{a}_warmup": float(v) for a, v in zip(AXES, db)})
        truth["S_warmup_tau"] = float(warmup[1])
    return "\n".join(lines) + "\n", truth
