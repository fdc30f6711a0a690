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
  ppm/degC, a relative factor), ``S_a(T) = S_a + s_a (t_a - T0)`` (s in ug/degC).

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


def _ca_matrix(angles_rad: dict) -> np.ndarray:
    """Ca with unit rows; ``angles_rad[ab]`` is the off-diagonal element (row a, column b)."""
    C = np.zeros((3, 3))
    for i, a in enumerate(AXES):
        for j, b in enumerate(AXES):
            if i != j:
                C[i, j] = angles_rad[a + b]
        C[i, i] = math.sqrt(1.0 - sum(C[i, j] ** 2 for j in range(3) if j != i))
    return C


def simulate_campaign(rng, *, truth=None, setpoints_C=(-40, -10, 20, 50, 80), tau_s=30.0, noise_sd=5e-4,
                      n_samples=3000, sigma_position_arcsec=0.0, sigma_wobble_arcsec=0.0,
                      encoder_zero_arcsec=(0.0, 0.0), axes_nonorthogonality_arcsec=0.0,
                      fixture_arcsec=(0.0, 0.0, 0.0), tilt_arcsec=(0.0, 0.0),
                      local_g_m_s2=9.80665, true_g_m_s2=None, unit="SN-IND-0001") -> tuple[str, dict]:
    """CSV text of a bench campaign (12 positions at every setpoint) and the true parameters.

    ``rng``: a ``numpy.random.Generator`` (used for the default truth, the temperature
    readings, the bench's random errors and the output noise, in that order).
    ``local_g_m_s2`` is written to the metadata (what the lab believes); the data are made with
    ``true_g_m_s2`` (default: the same). Systematic bench errors: ``encoder_zero_arcsec``
    (axis 1, axis 2) added to the commanded angles, ``axes_nonorthogonality_arcsec`` (a constant
    Ry between the axes), ``fixture_arcsec`` (rotation vector of the unit in its fixture about
    IMU x, y, z: ``G' = R_fix^T G``), ``tilt_arcsec`` (horizontal components of the gravity
    direction in the base frame). Random per visit: ``e1, e2 ~ N(0, sigma_position_arcsec)`` and
    a wobble ``~ N(0, sigma_wobble_arcsec)``. The mean output of each visit gets white noise of
    SD ``noise_sd / sqrt(n_samples)``; ``sd_*`` columns say ``noise_sd``.

    The returned truth dict holds the unit's parameters (reporting units) plus ``tilt_x`` and
    ``tilt_y`` (arcsec).
    """
    truth = dict(default_truth(rng) if truth is None else truth)
    g_true = local_g_m_s2 if true_g_m_s2 is None else true_g_m_s2
    setpoints = [float(s) for s in setpoints_C]
    dirs = _directions(setpoints)
    labels = list(POSITIONS)
    n = len(setpoints) * len(labels)

    # schedule: 2 h soak per setpoint, 50 s per visit
    sp = np.repeat(setpoints, len(labels))
    direction = np.repeat(dirs, len(labels))
    pos = np.tile(labels, len(setpoints))
    a1_cmd = np.tile([POSITIONS[p][0] for p in labels], len(setpoints))
    a2_cmd = np.tile([POSITIONS[p][1] for p in labels], len(setpoints))
    time_s = np.array([7200.0 * (1 + k // len(labels)) + 8000.0 * (k // len(labels)) + 50.0 * (k % len(labels))
                       for k in range(n)])
    temps = sp[:, None] + rng.normal(0.0, 0.01, size=(n, 3))     # t_x t_y t_z

    # actual bench angles (radians)
    e1 = rng.normal(0.0, sigma_position_arcsec, n) if sigma_position_arcsec > 0 else np.zeros(n)
    e2 = rng.normal(0.0, sigma_position_arcsec, n) if sigma_position_arcsec > 0 else np.zeros(n)
    wob = rng.normal(0.0, sigma_wobble_arcsec, n) if sigma_wobble_arcsec > 0 else np.zeros(n)
    ax1 = np.radians(a1_cmd) + (encoder_zero_arcsec[0] + e1) * ARCSEC_RAD
    ax2 = np.radians(a2_cmd) + (encoder_zero_arcsec[1] + e2) * ARCSEC_RAD
    wobble = (axes_nonorthogonality_arcsec + wob) * ARCSEC_RAD

    Rx = Rotation.from_euler("x", ax2[:, None]).as_matrix()
    Ry = Rotation.from_euler("y", wobble[:, None]).as_matrix()
    Rz = Rotation.from_euler("z", ax1[:, None]).as_matrix()
    R_base_from_imu = Rx @ Ry @ Rz @ MOUNT                       # (n, 3, 3)

    tx, ty = (v * ARCSEC_RAD for v in tilt_arcsec)
    f_base = np.array([tx, ty, math.sqrt(1.0 - tx * tx - ty * ty)])
    G = np.einsum("nji,j->ni", R_base_from_imu, f_base) * (g_true / G0)   # R^T f, in g
    R_fix = Rotation.from_rotvec(np.asarray(fixture_arcsec, float) * ARCSEC_RAD).as_matrix()
    G = G @ R_fix                                                # rows: (R_fix^T G)^T = G^T R_fix

    W = np.empty((n, 3))
    for k in range(n):
        dT = temps[k] - T0_C
        ang = {ab: (truth[f"Ca_{ab}"] + truth.get(f"Ca_{ab}_tempco", 0.0) * dT[AXES.index(ab[0])]) * ARCSEC_RAD
               for ab in ANGLES}
        Ca = _ca_matrix(ang)
        K = np.array([truth[f"K_{a}"] * (1.0 + truth.get(f"K_{a}_tempco", 0.0) * 1e-6 * dT[i])
                      for i, a in enumerate(AXES)])
        S = np.array([truth[f"S_{a}"] + truth.get(f"S_{a}_tempco", 0.0) * 1e-6 * dT[i]
                      for i, a in enumerate(AXES)])
        W[k] = (Ca @ G[k] + S) / K
    W += rng.normal(0.0, noise_sd / math.sqrt(n_samples), size=W.shape)

    lines = ["# generator = tests/independent_bench.py",
             "# bench = independent simulated two-axis bench",
             f"# local_g_m_s2 = {local_g_m_s2!r}",
             "# output_unit = V",
             ",".join(COLUMNS)]
    for k in range(n):
        row = [unit, repr(float(sp[k])), direction[k], repr(float(time_s[k])), pos[k],
               repr(float(a1_cmd[k])), repr(float(a2_cmd[k])), repr(float(tau_s)),
               *(repr(float(v)) for v in W[k]), *(repr(float(v)) for v in temps[k]),
               "0", "initial", *([repr(float(noise_sd))] * 3), str(int(n_samples))]
        lines.append(",".join(row))
    truth.setdefault("tilt_x", float(tilt_arcsec[0]))
    truth.setdefault("tilt_y", float(tilt_arcsec[1]))
    return "\n".join(lines) + "\n", truth
