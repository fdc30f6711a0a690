"""Calibration from a raw recording of hand-placed static poses (``triadcal fit-raw``).

Two models, both least squares with CasADi exact Jacobians and the Levenberg-Marquardt
iteration of :mod:`triadcal.estimation.joint`:

**Known poses** (imucal's Ferraris labels ``x_p`` = +X up, ``x_a`` = X down, ...): eq. 1
through :meth:`Model.predict`, each pose put on the bench position of the default plan
that has the same axis up (``y_p`` P01, ``y_a`` P03, ``x_p`` P05, ``x_a`` P07, ``z_p`` P09,
``z_a`` P11). A hand placement is not a bench: the gravity direction of each pose is off
by a small unknown rotation, modelled as a per-pose tilt of the apparent gravity (the
``bench_tilt`` effect's two horizontal components, one pair per pose).

*Identifiability.* To first order the tilt of the +X pose toward Y adds to W_y exactly
as ``Ca_yx`` does, and the -X pose's with the opposite sign: the data determine
``Ca_yx + (t_y(+X) - t_y(-X))/2`` and ``S_y`` plus the sum of the two tilts, never the
angle alone. With 6 poses the 12 tilt components add 6 directions that no recording
can separate from the 6 angles. The tilts are therefore a **random effect**,
independent N(0, sigma_h^2) per component, fitted as penalised least squares (prior
pseudo-observations ``t / sigma_h``). sigma_h is either stated (``placement_sd_deg``) or,
by default (``"auto"``), integrated over a log-uniform hyperprior on 0.02-20 deg with the
weights of its marginal likelihood (:func:`placement_sd_evidence`; the data inform it
through the tilt *sums* of opposite poses). Fixing the mean placement error instead would
not help: the confounded directions are the *differences* between opposite poses, not the
mean.

*The angles need a proper prior too* (N(0, sigma_a^2), default sigma_a = 1 deg,
``misalignment_sd_deg``). The data fix ``Ca + (t_1 - t_2)/2`` only, so the angles'
posterior spread comes from the priors, and it does not stay there: eq. 1's rows of Ca
are unit vectors and the sensed gravity is ``g cos t``, so K and S depend on the
*squares* of the unresolved angles and tilts (1 deg^2 = 3e-4). A flat prior on the
angles lets them spread by sigma_h/sqrt(2) on top of their true size, which biased K by
-0.45 u over 200 simulated units (angles 1 deg), K's z-scores with SD 0.76-0.86; with the
prior matching the units their mean is 0.0 and their SD 1.0. The angles' standard
uncertainty is then ``(1/sigma_a^2 + 2/sigma_h^2)^-1/2`` (0.58 deg at 1 deg / 1 deg). The
dependence on the priors is reported: ``fit.prior_sensitivity`` gives each K and S's move,
in its u, when sigma_a or sigma_h is halved or doubled (typically 0.1-1 u), and a note
says "prior-sensitive" above 0.5 u. The Gaussian posterior covariance of the penalised fit is
the inverse of the augmented normal matrix; the reported values integrate the tilts out
(:func:`marginal_posterior`), and ``--sample`` samples tilts and unit parameters jointly
in sheared coordinates (:func:`sample_known_poses`).

**Unknown poses** (free orientation, Tedaldi et al. 2014 / imu_tk): the cost is the sum
over static intervals of ``(|A| - g)^2`` with ``A = Ca^-1 (K W - S)`` (the paper's
``A_IMU``, :func:`triadcal.models.sensor.calibrated_acceleration`). Norms are invariant
under a rotation of the IMU frame, which removes 3 of the 6 angles: the frame is fixed
as imu_tk fixes it (its upper-triangular misalignment matrix): IMU Z along the Z
sensing axis, the Y sensing axis in the IMU Y-Z plane, so ``Ca_zx = Ca_zy = Ca_yx = 0``
and ``Ca_xy, Ca_xz, Ca_yz`` are estimated with K and S (9 parameters). Uncertainties are
``s^2 (J^T J)^-1`` with ``s^2`` the residual variance (not below the noise of the
interval means), with Student-t intervals on the residual degrees of freedom.
"""

from __future__ import annotations

from ..errors import UnknownName

import math
import time
from dataclasses import dataclass
from typing import Optional, Sequence, Union

import casadi as ca
import numpy as np
from scipy import stats

from ..io.raw import RawRecording, check_declared_unit, read_intervals, read_raw_csv
from ..models.campaign import DEFAULT_PLAN, Campaign
from ..models.model import Covariates, Model
from ..models.sensor import ANGLE_NAMES, AXES, calibrated_acceleration, dcm
from ..models.units import ARCSEC, STANDARD_GRAVITY_M_S2
from .joint import Solution, levenberg_marquardt, scaled_covariance, start_values
from .gates import DEFAULT_CONFIG, FitEvidence, GateConfig, GateOutcome, apply_gates, orientation_hints
from .result import Z95, CalibrationResult, ParameterValue
from .static import (POSE_LABELS, StaticDetection, StaticIntervalError, detect_static_intervals,
                     intervals_from_labels, intervals_from_spec, pose_label_of)

#: imucal pose label -> bench position of DEFAULT_PLAN with the same axis up
POSE_POSITIONS = {"y_p": "P01", "y_a": "P03", "x_p": "P05", "x_a": "P07", "z_p": "P09", "z_a": "P11"}
#: the angles the gravity-norm model can determine (imu_tk's upper-triangular frame)
NORM_ANGLES = ("xy", "xz", "yz")
UNIT_NAMES = tuple(f"K_{a}" for a in AXES) + tuple(f"S_{a}" for a in AXES) + tuple(f"Ca_{ab}" for ab in ANGLE_NAMES)
NORM_NAMES = tuple(f"K_{a}" for a in AXES) + tuple(f"S_{a}" for a in AXES) + tuple(f"Ca_{ab}" for ab in NORM_ANGLES)


# --------------------------------------------------------------------------------------
# position averages
# --------------------------------------------------------------------------------------
@dataclass
class PoseAverages:
    """Mean reading of each static interval and its standard uncertainty.

    ``se`` is the larger of the white-noise ``sd / sqrt(n)`` and a batch-means estimate
    (10 consecutive batches), so slowly correlated noise does not shrink it.
    """

    label: list
    start: np.ndarray
    end: np.ndarray
    w: np.ndarray
    sd: np.ndarray
    n: np.ndarray
    se: np.ndarray
    time_s: np.ndarray
    tau_s: np.ndarray


def pose_averages(rec: RawRecording, detection: StaticDetection, batches: int = 10) -> PoseAverages:
    w, sd, n, se, t, tau, lab, s0, e0 = [], [], [], [], [], [], [], [], []
    for iv in detection.intervals:
        x = rec.acc[iv.start:iv.end]
        if len(x) < 2:
            continue
        m = x.mean(axis=0)
        s = x.std(axis=0, ddof=1)
        white = s / math.sqrt(len(x))
        if len(x) >= 5 * batches:
            bm = np.array([b.mean(axis=0) for b in np.array_split(x, batches)])
            white = np.maximum(white, bm.std(axis=0, ddof=1) / math.sqrt(batches))
        w.append(m), sd.append(s), n.append(len(x)), se.append(white)
        t.append((iv.start + iv.end - 1) / 2 / rec.rate_hz), tau.append(len(x) / rec.rate_hz)
        lab.append(iv.label), s0.append(iv.start), e0.append(iv.end)
    if not w:
        raise StaticIntervalError(f"{rec.source}: no static interval with at least 2 samples")
    se = np.array(se)
    se = np.maximum(se, 1e-12 * np.maximum(np.abs(np.array(w)), 1.0))   # an exactly constant input
    return PoseAverages(lab, np.array(s0), np.array(e0), np.array(w), np.array(sd), np.array(n), se,
                        np.array(t), np.array(tau))


def bench_campaign(avg: PoseAverages, rec: RawRecording, serial: str, local_g_m_s2: float,
                   temperature_C: float = 20.0) -> Campaign:
    """The known-pose averages as bench CSV v1 visits (positions of DEFAULT_PLAN with the same
    axis up). There is no temperature channel: ``t_*`` hold ``temperature_C`` and the
    metadata says so."""
    pos = [POSE_POSITIONS[lab] for lab in avg.label]
    a1 = np.array([DEFAULT_PLAN[p][0] for p in pos])
    a2 = np.array([DEFAULT_PLAN[p][1] for p in pos])
    k = len(pos)
    meta = {"generator": "triadcal fit-raw (position averages of a raw recording)",
            "source": rec.source, "rate_hz": repr(rec.rate_hz), "output_unit": rec.unit,
            "input_unit": rec.unit, "local_g_m_s2": repr(float(local_g_m_s2)),
            "bench": "none: hand-placed poses (imucal labels " + ",".join(avg.label) + ")",
            "temperature": f"not measured; t_x t_y t_z hold a constant {temperature_C:g} degC placeholder"}
    return Campaign(
        unit=np.full(k, serial), setpoint_C=np.full(k, temperature_C), direction=np.full(k, "none"),
        time_s=avg.time_s.astype(float), position=np.array(pos), axis1_deg=a1, axis2_deg=a2,
        tau_s=avg.tau_s.astype(float), w=avg.w.copy(), t=np.full((k, 3), float(temperature_C)),
        cycle=np.zeros(k, int), state=np.full(k, "initial"), sd=avg.sd.copy(), n_samples=avg.n.astype(int),
        metadata=meta, source=rec.source)


# --------------------------------------------------------------------------------------
# known poses: eq. 1 with a random placement tilt per pose
# --------------------------------------------------------------------------------------
class KnownPoseProblem:
    """Residuals of the known-pose model (module docstring), compiled once with CasADi.

    ``x`` = the 12 unit parameters in reporting units (K in g per input unit, S in g,
    angles in arcsec) followed by ``tilt_x, tilt_y`` of each pose (arcsec). Residuals:
    ``(W_obs - W_model) / se`` for each pose and axis, then the prior rows
    ``tilt / sigma_h`` and ``Ca / sigma_a``. Duck-types :class:`~triadcal.estimation.joint.JointProblem` for
    :func:`~triadcal.estimation.joint.levenberg_marquardt`.
    """

    def __init__(self, w: np.ndarray, se: np.ndarray, axis1_deg, axis2_deg, gravity_g: float,
                 placement_sd_arcsec: float, misalignment_sd_arcsec: float):
        self.model = Model(("bench_tilt",))
        self.w, self.se = np.asarray(w, float), np.asarray(se, float)
        self.n = len(self.w)
        self.sigma_h = float(placement_sd_arcsec)
        self.sigma_a = float(misalignment_sd_arcsec)
        #: columns of the six angles among the unit parameters
        self.angle_cols = np.array([UNIT_NAMES.index(f"Ca_{ab}") for ab in ANGLE_NAMES])
        self.names = UNIT_NAMES + tuple(f"tilt_{c}[{k}]" for k in range(self.n) for c in "xy")
        t0 = time.perf_counter()
        x = ca.SX.sym("x", len(UNIT_NAMES))
        t = ca.SX.sym("t", 2)
        c = ca.SX.sym("c", 2)
        g = ca.SX.sym("g")
        p = {n: x[i] * self.model.spec[n].to_internal for i, n in enumerate(UNIT_NAMES)}
        p["tilt_x"], p["tilt_y"] = t[0] * ARCSEC, t[1] * ARCSEC
        cov = Covariates(axis1=c[0], axis2=c[1], temp=(20.0, 20.0, 20.0), temp_rate=(0.0, 0.0, 0.0),
                         branch=0.0, time_s=0.0)
        wm = ca.vertcat(*self.model.predict(p, cov, g))
        f = ca.Function("pose", [x, t, c, g], [wm, ca.jacobian(wm, x), ca.jacobian(wm, t)])
        self._mapped = f.map(self.n, "serial")
        self._pose = ca.Function("pose_w", [x, t, c, g], [wm])
        self.cov_matrix = np.vstack([np.radians(axis1_deg), np.radians(axis2_deg)])
        self.gravity_g = float(gravity_g)
        self.build_seconds = time.perf_counter() - t0

    def residuals_and_jacobian(self, x: np.ndarray):
        nu = len(UNIT_NAMES)
        xu, tilts = x[:nu], x[nu:].reshape(self.n, 2)
        wm, Jx, Jt = self._mapped(xu, tilts.T, self.cov_matrix, self.gravity_g)
        wm = np.asarray(wm).T                                             # (n, 3)
        Jx = np.asarray(Jx).reshape(3, self.n, nu).transpose(1, 0, 2)      # (n, 3, 12)
        Jt = np.asarray(Jt).reshape(3, self.n, 2).transpose(1, 0, 2)       # (n, 3, 2)
        r_data = ((self.w - wm) / self.se).reshape(-1)
        J = np.zeros((5 * self.n + 6, len(x)))
        J[:3 * self.n, :nu] = (-Jx / self.se[:, :, None]).reshape(-1, nu)
        for k in range(self.n):
            J[3 * k:3 * k + 3, nu + 2 * k:nu + 2 * k + 2] = -Jt[k] / self.se[k][:, None]
        J[3 * self.n:5 * self.n, nu:] = np.eye(2 * self.n) / self.sigma_h
        J[5 * self.n + np.arange(6), self.angle_cols] = 1.0 / self.sigma_a
        r = np.concatenate([r_data, x[nu:] / self.sigma_h, x[self.angle_cols] / self.sigma_a])
        return r, J

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return self.residuals_and_jacobian(x)[0]


    def residual_function(self) -> ca.Function:
        """``r = f(x, W, inv_se, C, g)``: the normalised data residuals ``(W_obs - W_model) / se``
        (pose-major, 3 per pose) of the full vector (12 unit parameters, then the tilts); the
        tilts' N(0, sigma_h^2) is the posterior's prior, not residual rows."""
        nu = len(UNIT_NAMES)
        x = ca.MX.sym("x", nu + 2 * self.n)
        W = ca.MX.sym("W", 3, self.n)
        ise = ca.MX.sym("inv_se", 3, self.n)
        C = ca.MX.sym("C", 2, self.n)
        g = ca.MX.sym("g")
        T = ca.reshape(x[nu:], 2, self.n)
        wm = self._pose.map(self.n, "serial")(x[:nu], T, C, g)
        return ca.Function("pose_residual", [x, W, ise, C, g], [ca.vec((W - wm) * ise)])

    def data_residuals(self, X: np.ndarray) -> np.ndarray:
        """Normalised data residuals ``(W_obs - W_model) / se``, shape (m, 3 n), for an (m, d) array
        of parameter vectors, with :meth:`Model.predict` on numpy arrays (vectorised over m)."""
        X = np.atleast_2d(X)
        nu, m = len(UNIT_NAMES), len(X)
        p = {n: X[:, i:i + 1] * self.model.spec[n].to_internal for i, n in enumerate(UNIT_NAMES)}
        tilts = X[:, nu:].reshape(m, self.n, 2)
        p["tilt_x"], p["tilt_y"] = tilts[:, :, 0] * ARCSEC, tilts[:, :, 1] * ARCSEC
        cov = Covariates(axis1=self.cov_matrix[0][None, :], axis2=self.cov_matrix[1][None, :],
                         temp=(20.0, 20.0, 20.0), temp_rate=(0.0, 0.0, 0.0), branch=0.0, time_s=0.0)
        W = np.stack(np.broadcast_arrays(*self.model.predict(p, cov, self.gravity_g)), axis=-1)  # (m, n, 3)
        return ((self.w[None] - W) / self.se[None]).reshape(m, -1)


def marginal_posterior(problem: KnownPoseProblem, x_map: np.ndarray, cov_laplace: np.ndarray,
                       J_map: np.ndarray, n_draws: int = 2000, seed: int = 0, dof: float = 6.0):
    """Posterior mean and covariance with the placement tilts integrated out.

    Why not the Laplace approximation alone: the tilts enter eq. 1 at second order too (the
    sensed gravity of a pose is ``g cos t``); the part of each tilt the data cannot see is
    uncertain by ~sigma_h, which biases K by ~sigma_h^2 (3e-4 at 1 deg), more than the
    noise: the posterior is a banana the optimum's curvature cannot describe.

    Rao-Blackwellised importance sampling: tilts are drawn from a Student-t around their
    Laplace marginal; given the tilts the model is nearly linear in the 12 unit
    parameters, so two Gauss-Newton steps from the optimum (data rows and the angles'
    prior rows) give their conditional mean and ``(J_u^T J_u)^-1`` their conditional
    covariance; the weights are the conditional maximum of the posterior over the proposal
    density. The marginal is the weighted mixture. Returns ``(mean, cov, ess)``."""
    rng = np.random.default_rng(seed)
    nu = len(UNIT_NAMES)
    t_map, Ct = x_map[nu:], cov_laplace[nu:, nu:]
    L = np.linalg.cholesky(Ct + 1e-12 * np.max(np.diag(Ct)) * np.eye(len(t_map)))
    z = rng.standard_normal((n_draws, len(t_map)))
    chi = rng.chisquare(dof, n_draws) / dof
    T = t_map + (z / np.sqrt(chi)[:, None]) @ L.T
    q = np.sum(np.square(np.linalg.solve(L, (T - t_map).T)), axis=0)
    log_q = -0.5 * (dof + len(t_map)) * np.log1p(q / dof)
    Xu = np.repeat(x_map[None, :nu], n_draws, axis=0)
    Ju = _conditional_jacobian(problem, J_map)
    H_inv = scaled_covariance(Ju)
    P = H_inv @ Ju.T                 # one Gauss-Newton step given the tilts: x_u <- x_u - P r
    for _ in range(2):
        Xu = Xu - conditional_residuals(problem, Xu, T) @ P.T
    r = conditional_residuals(problem, Xu, T)
    lw = -0.5 * (np.sum(r * r, axis=1) + np.sum((T / problem.sigma_h) ** 2, axis=1)) - log_q
    lw = np.where(np.isfinite(lw), lw, -np.inf)
    w = np.exp(lw - np.max(lw))
    w /= w.sum()
    X = np.hstack([Xu, T])
    mean = w @ X
    dX = X - mean
    cov = (dX * w[:, None]).T @ dX
    cov[:nu, :nu] += H_inv
    return mean, cov, float(1.0 / np.sum(w * w))


#: a note says "prior-sensitive" when halving or doubling the misalignment prior moves a
#: parameter by more than this many standard uncertainties
SENSITIVITY_NOTE_U = 0.5


def _known_pose_estimate(problem: KnownPoseProblem, sol: Solution, n_draws: int, seed: int):
    """``(mean, cov, ess, estimator)``: the importance-sampled marginal, or the Laplace
    approximation at the optimum if the importance sampling degenerates."""
    cov_laplace = scaled_covariance(sol.J)
    mean, cov, ess = marginal_posterior(problem, sol.x, cov_laplace, sol.J, n_draws=n_draws, seed=seed)
    if ess >= 200:
        return mean, cov, ess, ("known-pose fit of a hand-placed recording: posterior mean and SD, placement "
                                "tilts integrated out (Rao-Blackwellised importance sampling around the Laplace "
                                "approximation)")
    return sol.x, cov_laplace, ess, ("known-pose fit of a hand-placed recording: Laplace approximation at the "
                                     f"optimum (importance sampling ESS {ess:.0f} < 200)")


#: the placement prior SD when none is stated (and the start of ``auto``), deg
DEFAULT_PLACEMENT_SD_DEG = 1.0
#: the grid of placement SDs (deg) of the evidence and of ``auto``'s integral: log-spaced, so
#: equal weights per point are the scale-invariant (log-uniform) hyperprior on 0.02-20 deg
PLACEMENT_GRID_DEG = np.geomspace(0.02, 20.0, 61)

#: the priors of the known-pose model whose SD the sensitivity study varies: result key -> attribute
SENSITIVITY_PRIORS = {"misalignment_sd_deg": "sigma_a", "placement_sd_deg": "sigma_h"}


def _integrate_placement_sd(problem: KnownPoseProblem, evidence: dict, solutions: list, n_draws: int, seed: int):
    """``placement_sd_deg="auto"``: the posterior mean and covariance with the placement SD
    integrated over its grid (log-uniform hyperprior, weights from the marginal likelihood of
    :func:`placement_sd_evidence`), each grid point's own importance-sampled marginal mixed by
    the law of total variance. Grid points below 1e-4 of the largest weight are skipped.
    Leaves ``problem.sigma_h`` at the most probable SD and returns
    ``(mean, cov, ess, estimator, solution at that SD, that SD in deg)``."""
    grid = np.asarray(evidence["grid_deg"])
    ll = np.asarray(evidence["log_likelihood"])
    w = np.exp(ll - ll.max())
    keep = np.nonzero(w >= 1e-4)[0]
    w = w[keep] / w[keep].sum()
    means, covs, esss = [], [], []
    try:
        for j in keep:
            problem.sigma_h = grid[j] * 3600.0
            m, c, e, _ = _known_pose_estimate(problem, solutions[j], n_draws, seed)
            means.append(m), covs.append(c), esss.append(e)
    finally:
        best = int(np.argmax(ll))
        problem.sigma_h = grid[best] * 3600.0
    means = np.array(means)
    mean = w @ means
    d = means - mean
    cov = np.einsum("j,jab->ab", w, np.array(covs)) + (d * w[:, None]).T @ d
    estimator = (f"known-pose fit of a hand-placed recording: posterior mean and SD, placement tilts and their SD "
                 f"integrated out ({len(keep)} grid points of the SD, each by Rao-Blackwellised importance sampling)")
    return mean, cov, float(min(esss)), estimator, solutions[best], float(grid[best])


def prior_sensitivity(problem: KnownPoseProblem, sol: Solution, mean: np.ndarray, u: np.ndarray,
                      n_draws: int, seed: int, factors=(0.5, 2.0), priors=tuple(SENSITIVITY_PRIORS)) -> dict:
    """How far each K and S moves, in its standard uncertainty, when the SD of the angles' prior
    (``misalignment_sd_deg``) or of the placement prior (``placement_sd_deg``) is multiplied by
    each of ``factors``, the other held (refit and importance sampling again, same random
    numbers). K and S depend on both through the second-order terms (module docstring); the
    angles follow their priors by construction and are not listed."""
    nu = len(UNIT_NAMES)
    out = {}
    for key in priors:
        attr = SENSITIVITY_PRIORS[key]
        sd = getattr(problem, attr)
        shifts = []
        try:
            for f in factors:
                setattr(problem, attr, sd * f)
                s2 = levenberg_marquardt(problem, sol.x)
                m2 = _known_pose_estimate(problem, s2, n_draws, seed)[0]
                shifts.append((m2[:nu] - mean[:nu]) / u[:nu])
        finally:
            setattr(problem, attr, sd)
        out[key] = {"sd_deg": [sd * f / 3600.0 for f in factors], "factors": list(factors),
                    "shift_in_u": {n: [float(v[i]) for v in shifts] for i, n in enumerate(UNIT_NAMES)
                                   if not n.startswith("Ca_")}}
    return out


def sensitivity_note(sensitivity: dict) -> Optional[str]:
    """The "prior-sensitive" note: the largest move of :func:`prior_sensitivity` above
    :data:`SENSITIVITY_NOTE_U`, or None."""
    worst = max(((abs(v), n, key, shifts) for key, block in sensitivity.items()
                 for n, shifts in block["shift_in_u"].items() for v in shifts), default=None)
    if worst is None or worst[0] <= SENSITIVITY_NOTE_U:
        return None
    _, n, key, shifts = worst
    what = {"misalignment_sd_deg": "misalignment (angle) prior SD", "placement_sd_deg": "placement prior SD"}[key]
    return (f"prior-sensitive: {n} moves by {shifts[0]:+.2f} u / {shifts[1]:+.2f} u when the {what} is halved / "
            f"doubled (fit.prior_sensitivity); state the priors with the result")


def placement_sd_evidence(problem: KnownPoseProblem, sol: Solution, grid_deg=None, solutions: Optional[list] = None) -> dict:
    """What the data say about the placement SD sigma_h: the Laplace approximation of the
    marginal likelihood ``log p(data | sigma_h)`` (tilts, angles and unit parameters integrated
    out: ``-chi2_min/2 - log det(J^T J)/2 - 2 n log sigma_h``, the angles' prior held) on a
    log grid, its maximum (type-II maximum likelihood) and the likelihood-ratio intervals
    (``2 Delta log L`` below 1 and 3.84). The information comes from the tilt *sums* of
    opposite poses (six numbers), so the estimate is rough (relative SE ~ 30 %); it checks the
    stated prior, or is integrated over (``placement_sd_deg="auto"``); ``solutions``, when a
    list, receives the optimum at each grid point."""
    grid = PLACEMENT_GRID_DEG if grid_deg is None else np.asarray(grid_deg, float)
    sigma_h = problem.sigma_h
    ll = []
    x = sol.x
    try:
        for sd in grid:
            problem.sigma_h = sd * 3600.0
            s2 = levenberg_marquardt(problem, x)
            if solutions is not None:
                solutions.append(s2)
            d = np.linalg.norm(s2.J, axis=0)
            d[d == 0] = 1.0
            _, logdet = np.linalg.slogdet((s2.J / d).T @ (s2.J / d))
            logdet += 2.0 * np.sum(np.log(d))
            ll.append(-0.5 * float(s2.r @ s2.r) - 0.5 * logdet - 2 * problem.n * math.log(problem.sigma_h))
    finally:
        problem.sigma_h = sigma_h
    ll = np.array(ll)
    i = int(np.argmax(ll))
    dev = 2.0 * (ll[i] - ll)

    def interval(level):
        inside = np.nonzero(dev <= level)[0]
        lo, hi = grid[inside.min()], grid[inside.max()]
        return [float(lo) if inside.min() > 0 else 0.0, float(hi) if inside.max() < len(grid) - 1 else None]

    return {"estimate_deg": float(grid[i]) if 0 < i < len(grid) - 1 else (0.0 if i == 0 else None),
            "interval68_deg": interval(1.0), "interval95_deg": interval(3.841),
            "grid_deg": [float(g) for g in grid], "log_likelihood": [float(v) for v in ll - ll[i]],
            "method": "Laplace marginal likelihood on a log grid 0.02-20 deg (type-II maximum likelihood); "
                      "intervals where 2 Delta log L < 1 and < 3.84; 0 or null: at the grid's end"}


def _conditional_jacobian(problem: KnownPoseProblem, J_map: np.ndarray) -> np.ndarray:
    """Rows of the unit parameters' conditional problem (tilts fixed): data and angle-prior rows."""
    nu, nd = len(UNIT_NAMES), 3 * problem.n
    return np.vstack([J_map[:nd, :nu], J_map[5 * problem.n:, :nu]])


def conditional_residuals(problem: KnownPoseProblem, Xu: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Data and angle-prior residuals for (m, 12) unit parameters and (m, 2 n) tilts: (m, 3 n + 6)."""
    r = problem.data_residuals(np.hstack([Xu, T]))
    return np.hstack([r, Xu[:, problem.angle_cols] / problem.sigma_a])


def fit_known_poses(avg: PoseAverages, *, gravity_g: float, scale_unit: str, serial: str,
                    placement_sd_deg: Union[float, str] = "auto", misalignment_sd_deg: float = 1.0, n_draws: int = 2000,
                    seed: int = 0, gates: GateConfig = DEFAULT_CONFIG):
    """Known-pose fit; returns ``(CalibrationResult, KnownPoseProblem, Solution)``.

    ``placement_sd_deg``: prior SD of each placement tilt component (the random effect), or
    ``"auto"``: the data's type-II maximum-likelihood value (:func:`placement_sd_evidence`;
    empirical Bayes: its own uncertainty is not propagated, ``fit.prior_sensitivity`` shows
    what it is worth). ``misalignment_sd_deg``: prior SD of each angle Ca_* (module docstring:
    why the angles need a proper prior here)."""
    auto = isinstance(placement_sd_deg, str) and placement_sd_deg.strip().lower() == "auto"
    if not auto:
        try:
            placement_sd_deg = float(placement_sd_deg)
        except ValueError:
            raise ValueError(f"the placement SD must be a number of degrees or 'auto', got {placement_sd_deg!r}")
    start_sd = DEFAULT_PLACEMENT_SD_DEG if auto else placement_sd_deg
    labels = [lab if lab in POSE_POSITIONS else "" for lab in avg.label]
    if "" in labels:
        raise StaticIntervalError("known poses need a pose label (x_p, x_a, y_p, y_a, z_p, z_a) on every interval")
    missing = [p for p in POSE_LABELS if p not in labels]
    if missing:
        raise StaticIntervalError(f"known poses need all six faces; missing: {', '.join(missing)} "
                                  f"(found {', '.join(labels)})")
    if not (start_sd > 0 and math.isfinite(start_sd)):
        raise ValueError("the placement SD must be positive: with no placement error the model is the "
                         "bench model (use triadcal fit on the bench CSV)")
    if not (misalignment_sd_deg > 0 and math.isfinite(misalignment_sd_deg)):
        raise ValueError("the misalignment prior SD must be a positive number of degrees: the angles are "
                         "confounded with the placement and a flat prior biases K (see docs/raw.md)")
    pos = [POSE_POSITIONS[lab] for lab in labels]
    a1 = np.array([DEFAULT_PLAN[p][0] for p in pos])
    a2 = np.array([DEFAULT_PLAN[p][1] for p in pos])
    problem = KnownPoseProblem(avg.w, avg.se, a1, a2, gravity_g, start_sd * 3600.0,
                               misalignment_sd_deg * 3600.0)
    # start: per-axis linear fit on the nominal gravity (the joint fit's start), tilts 0
    k = len(pos)
    c = Campaign(unit=np.full(k, serial), setpoint_C=np.zeros(k), direction=np.full(k, "none"),
                 time_s=np.arange(k, dtype=float), position=np.array(pos), axis1_deg=a1, axis2_deg=a2,
                 tau_s=np.ones(k), w=avg.w, t=np.zeros((k, 3)), cycle=np.zeros(k, int),
                 state=np.full(k, "initial"),
                 metadata={"local_g_m_s2": repr(gravity_g * STANDARD_GRAVITY_M_S2)})
    s0 = start_values(c, Model(()))
    x0 = np.concatenate([[s0[n] for n in UNIT_NAMES], np.zeros(2 * k)])
    t0 = time.perf_counter()
    sol = levenberg_marquardt(problem, x0)
    solve_seconds = time.perf_counter() - t0
    solutions = []
    evidence = placement_sd_evidence(problem, sol, solutions=solutions)
    source = "stated (--placement-sd-deg)"
    if auto:
        mean, cov, ess, estimator, sol, placement_sd_deg = _integrate_placement_sd(problem, evidence, solutions,
                                                                                  n_draws, seed)
        source = ("integrated: hyperprior log-uniform on 0.02-20 deg, posterior from the marginal likelihood "
                  "(fit.placement_sd_from_data); the value here is its maximum")
    else:
        mean, cov, ess, estimator = _known_pose_estimate(problem, sol, n_draws, seed)
    u = np.sqrt(np.diag(cov))
    nu = len(UNIT_NAMES)
    # with auto the placement SD is integrated over: only the angles' prior is varied (at its maximum)
    sensitivity = prior_sensitivity(problem, sol, mean, u, n_draws, seed,
                                    priors=("misalignment_sd_deg",) if auto else tuple(SENSITIVITY_PRIORS))
    units = {"K": scale_unit, "S": "g", "Ca": "arcsec"}
    params = {n: ParameterValue(float(mean[i]), float(u[i]), units[n.split("_")[0]])
              for i, n in enumerate(UNIT_NAMES)}
    corr = cov[:nu, :nu] / np.outer(u[:nu], u[:nu])
    tilts = mean[nu:].reshape(k, 2)
    tilts_u = u[nu:].reshape(k, 2)
    n_data = 3 * k
    chi2 = float(sol.r @ sol.r)
    dof = len(sol.r) - len(sol.x)         # data, tilt-prior and angle-prior rows
    fit = {"model": "known poses: eq. 1 with a random placement tilt per pose",
           "placement_sd_deg": placement_sd_deg, "placement_sd_source": source,
           "misalignment_sd_deg": misalignment_sd_deg,
           "n_obs": n_data, "n_params": nu,
           "n_nuisance": 2 * k, "chi2_dof": chi2 / dof if dof > 0 else None,
           "placement_rms_estimate_deg": float(np.sqrt(np.mean(tilts ** 2))) / 3600.0,
           "iterations": sol.iterations, "build_seconds": problem.build_seconds, "solve_seconds": solve_seconds,
           "noise": "standard error of each pose mean: max(sd/sqrt(n), batch means)",
           "estimator": estimator, "importance_ess": ess, "n_draws": n_draws,
           "prior_sensitivity": sensitivity, "placement_sd_from_data": evidence,
           "angle_uncertainty": {"source": "hand placement (with output noise)", "equation": "eq. 1",
                                 "basis": "standard uncertainty of the angles from the known-pose fit: the placement "
                                          "tilts are confounded with the angles, so the placement SD and the "
                                          "angles' prior set it; Type B"}}
    u_angle = 1.0 / math.sqrt(1.0 / misalignment_sd_deg ** 2 + 2.0 / placement_sd_deg ** 2)
    placement = (f"SD integrated over a log-uniform hyperprior, most probable {placement_sd_deg:.2g} deg" if auto
                 else f"prior SD {placement_sd_deg:g} deg")
    notes = [f"hand placement: each pose's gravity direction has a random tilt ({placement}, per component); the "
             "angles Ca_* are confounded with the difference of the tilts of opposite poses, so their uncertainty "
             f"(~{u_angle:.2g} deg) comes from the placement and the angles' prior (SD {misalignment_sd_deg:g} deg), "
             "not from the data; K and S are determined by the data, but at second order (tilt^2) they depend "
             "on both"]
    note = sensitivity_note(sensitivity)
    if note:
        notes.append(note)
    lo, hi = evidence["interval95_deg"]
    if not auto and (placement_sd_deg < lo or (hi is not None and placement_sd_deg > hi)):
        notes.append(f"the data put the placement SD at {evidence['estimate_deg']:.2g} deg (95 %: "
                     f"{lo:.2g}-{'' if hi is None else f'{hi:.2g}'} deg), outside the {placement_sd_deg:g} deg "
                     "prior used: K and S depend on it at second order (fit.prior_sensitivity); consider "
                     "--placement-sd-deg " + f"{evidence['estimate_deg']:.2g} (or auto)")
    if fit["chi2_dof"] is not None and fit["chi2_dof"] > 3.0:
        notes.append(f"chi2/dof = {fit['chi2_dof']:.3g}: the poses are further from their faces than the "
                     f"{placement_sd_deg:g} deg prior allows (or the unit is not linear); raise --placement-sd-deg")
    status = "ok" if sol.converged else "not_converged"
    result = CalibrationResult(
        unit=serial, method="joint", parameters=params, status=status, effects=(),
        reference_temperature_C=20.0, temperature_range_C=None, fit=fit, correlation_names=UNIT_NAMES,
        correlation=corr, notes=notes,
        extra={"placement_tilts": [{"pose": lab, "tilt_x_deg": float(tx) / 3600.0, "tilt_y_deg": float(ty) / 3600.0,
                                    "u_deg": [float(ux) / 3600.0, float(uy) / 3600.0]}
                                   for lab, (tx, ty), (ux, uy) in zip(labels, tilts, tilts_u)],
               "output_unit": scale_unit.split("/", 1)[-1],
               "local_g_m_s2": gravity_g * STANDARD_GRAVITY_M_S2})
    r0 = problem.residuals(x0)
    apply_gates(result, FitEvidence(
        converged=sol.converged, cost_start=0.5 * float(r0 @ r0), cost_final=0.5 * chi2, n_obs=n_data, n_free=nu,
        residual_rms=float(np.sqrt(np.mean(np.square(sol.r[:n_data])))) if len(sol.r) >= n_data else None,
        data_rms=1.0, chi2=chi2, dof=dof, noise_known=True), config=gates)
    if result.status != "ok":
        from ..models.campaign import nominal_gravity

        for hint in orientation_hints(avg.w, nominal_gravity(a1, a2).reshape(-1, 3)):
            result.notes.append(f"hint: {hint}")
    return result, problem, sol


# --------------------------------------------------------------------------------------
# unknown poses: the gravity-norm model
# --------------------------------------------------------------------------------------
def _calibrated_symbolic(x, w):
    """``A = Ca^-1 (K W - S)`` (sensor.calibrated_acceleration) for CasADi symbols, with the
    norm model's free angles ``Ca_xy, Ca_xz, Ca_yz`` (arcsec) and the other three zero."""
    angles = {ab: 0.0 for ab in ANGLE_NAMES}
    for i, ab in enumerate(NORM_ANGLES):
        angles[ab] = x[6 + i] * ARCSEC
    Ca = ca.vertcat(*[ca.horzcat(*row) for row in dcm(angles)])
    sensed = x[0:3] * w - x[3:6]
    return ca.solve(Ca, sensed)


class NormProblem:
    """Gravity-norm residuals ``|A_k| - g`` (g) of each static interval mean, CasADi-compiled."""

    def __init__(self, w: np.ndarray, gravity_g: float):
        self.w = np.asarray(w, float)
        self.n = len(self.w)
        self.names = NORM_NAMES
        self.gravity_g = float(gravity_g)
        t0 = time.perf_counter()
        x = ca.SX.sym("x", len(NORM_NAMES))
        wk = ca.SX.sym("w", 3)
        g = ca.SX.sym("g")
        r = ca.norm_2(_calibrated_symbolic(x, wk)) - g
        f = ca.Function("interval", [x, wk, g], [r, ca.jacobian(r, x)])
        self._mapped = f.map(self.n, "serial")
        self._interval = ca.Function("norm_interval", [x, wk, g], [r])
        self.build_seconds = time.perf_counter() - t0

    #: residuals are returned in micro-g: the LM stop rule compares steps with the uncertainty
    #: of unit-variance residuals, so the scale must not exceed the noise (1 ug is below any MEMS)
    RESIDUAL_UNIT_G = 1e-6

    def residuals_and_jacobian(self, x: np.ndarray):
        r, J = self._mapped(x, self.w.T, self.gravity_g)
        return (np.asarray(r).reshape(-1) / self.RESIDUAL_UNIT_G,
                np.asarray(J).reshape(self.n, len(self.names)) / self.RESIDUAL_UNIT_G)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return self.residuals_and_jacobian(x)[0]

    def residual_function(self) -> ca.Function:
        """``r = f(x, W, g, inv_sigma)``: the normalised residuals ``(|A_k| - g) / sigma_k`` of
        every interval (column), ``W`` (3, n) the interval means: the likelihood of the
        posterior (:class:`~triadcal.estimation.posterior.ResidualTarget`)."""
        x = ca.MX.sym("x", len(self.names))
        W = ca.MX.sym("W", 3, self.n)
        g = ca.MX.sym("g")
        isg = ca.MX.sym("inv_sigma", self.n)
        r = ca.transpose(self._interval.map(self.n, "serial")(x, W, g)) * isg
        return ca.Function("norm_residual", [x, W, g, isg], [r])


def norm_start(w: np.ndarray, gravity_g: float) -> np.ndarray:
    """Start of the norm fit, solved from the data for any offset and scale (offset-binary
    counts centred at 32768, signed counts, mV, g, m/s^2).

    The interval means are first centred on their mean and scaled by their median distance
    from it (so the algebraic fit is well conditioned however far the zero lies from the
    origin: offset-binary means sit at 32768 +- 2048), then an axis-aligned ellipsoid
    ``a u_x^2 + b u_y^2 + c u_z^2 + d u_x + e u_y + f u_z = 1`` is fitted by linear least
    squares (Tedaldi et al. 2014 start, a linear ellipsoid fit) and mapped back: centre ``c``
    and semi-axes ``r`` in the input unit give ``K = g / r`` and ``S = K c`` (eq. 1 with
    Ca = I: ``|K (w - c)| = g``). A fit that is not an ellipsoid (fewer than 6 intervals, or a
    non-positive coefficient) falls back to a sphere ``|w - c| = r`` (linear in ``c`` and
    ``r^2 - |c|^2``), and that to the centroid and the median radius."""
    w = np.asarray(w, float)
    m = w.mean(axis=0)
    d = w - m
    s = float(np.median(np.linalg.norm(d, axis=1)))
    if not (s > 0 and math.isfinite(s)):
        s = 1.0
    u = d / s
    centre_u, radius_u = np.zeros(3), np.ones(3) * float(np.median(np.linalg.norm(u, axis=1)) or 1.0)
    fitted = False
    if len(u) >= 6:
        A = np.column_stack([u ** 2, u])
        coef, *_ = np.linalg.lstsq(A, np.ones(len(u)), rcond=None)
        q, l_ = coef[:3], coef[3:]
        if np.all(q > 0):
            c = -l_ / (2 * q)
            rhs = 1.0 + np.sum(l_ ** 2 / (4 * q))
            r = np.sqrt(rhs / q) if rhs > 0 else np.full(3, np.nan)
            if np.all(np.isfinite(r)) and np.all(r > 0):
                centre_u, radius_u, fitted = c, r, True
    if not fitted and len(u) >= 4:
        # sphere: |u|^2 = 2 c.u + (r^2 - |c|^2)
        A = np.column_stack([2 * u, np.ones(len(u))])
        coef, *_ = np.linalg.lstsq(A, np.sum(u ** 2, axis=1), rcond=None)
        c, k = coef[:3], coef[3]
        r2 = k + c @ c
        if r2 > 0 and np.all(np.isfinite(c)):
            centre_u, radius_u = c, np.full(3, math.sqrt(r2))
    centre, radius = m + s * centre_u, s * radius_u
    K = gravity_g / radius
    return np.concatenate([K, K * centre, np.zeros(3)])


def fit_unknown_poses(rec: RawRecording, avg: PoseAverages, *, gravity_g: float, serial: str,
                      gates: GateConfig = DEFAULT_CONFIG):
    """Gravity-norm fit; returns ``(CalibrationResult, NormProblem, Solution)``."""
    n = len(avg.w)
    if n < len(NORM_NAMES):
        raise StaticIntervalError(
            f"the gravity-norm model has {len(NORM_NAMES)} parameters and needs at least as many static poses; "
            f"found {n} static intervals (record more poses, or check the detector's report)")
    problem = NormProblem(avg.w, gravity_g)
    t0 = time.perf_counter()
    x0 = norm_start(avg.w, gravity_g)
    r0 = problem.residuals(x0) * problem.RESIDUAL_UNIT_G
    sol = levenberg_marquardt(problem, x0)
    solve_seconds = time.perf_counter() - t0
    dof = n - len(NORM_NAMES)
    sol.r, sol.J = sol.r * problem.RESIDUAL_UNIT_G, sol.J * problem.RESIDUAL_UNIT_G   # back to g
    rss = float(sol.r @ sol.r)
    # noise floor: variance of the mean of |A| within each interval, from the samples of |A|
    # themselves: the larger of the white-noise sd^2/m and a batch-means estimate (10 batches),
    # so slowly correlated noise does not shrink it. |A| does not change when the unit turns,
    # so motion inside an interval does not inflate this floor; it shortens the mean vector
    # instead, which the residual sees (the slow-motion case of issue 14)
    K, S, Ca = norm_matrices(sol.x)
    var_means = []
    for s_, e_, m in zip(avg.start, avg.end, avg.n):
        a = np.linalg.norm(calibrated_acceleration(K, S, Ca, rec.acc[s_:e_]), axis=1)
        v = np.var(a, ddof=1) / m if m > 1 else 0.0
        if m >= 50:
            bm = np.array([b.mean() for b in np.array_split(a, 10)])
            v = max(v, float(np.var(bm, ddof=1)) / 10)
        var_means.append(v)
    s2_noise = float(np.mean(var_means))
    s2_resid = rss / dof if dof > 0 else None
    s2 = max(s2_resid if s2_resid is not None else 0.0, s2_noise)
    cov = scaled_covariance(sol.J) * s2
    u = np.sqrt(np.diag(cov))
    units = {"K": rec.scale_unit, "S": "g", "Ca": "arcsec"}
    params = {nm: ParameterValue(float(v), float(s), units[nm.split("_")[0]])
              for nm, v, s in zip(NORM_NAMES, sol.x, u)}
    intervals = {}
    if dof > 0:
        q = float(stats.t.ppf(0.975, dof))
        intervals = {nm: {"level": 0.95, "low": float(v - q * s), "high": float(v + q * s), "dof": dof}
                     for nm, v, s in zip(NORM_NAMES, sol.x, u)}
    notes = ["gravity-norm model: a rotation of the IMU frame is unobservable from norms, so the frame is imu_tk's "
             "(Z along the Z sensing axis, the Y sensing axis in the Y-Z plane): Ca_zx = Ca_zy = Ca_yx = 0 by "
             "definition and only Ca_xy, Ca_xz, Ca_yz are estimated"]
    if dof <= 0:
        notes.append(f"{n} static intervals for {len(NORM_NAMES)} parameters: no residual degrees of freedom, so "
                     "the misfit of the model cannot be judged; the uncertainties carry the sample noise only "
                     "(a lower bound): record more poses")
    elif dof < 10:
        notes.append(f"only {dof} residual degrees of freedom: the residual variance is itself uncertain; "
                     "the 95 % intervals use Student's t")
    fit = {"model": "unknown poses: gravity norm (Tedaldi et al. 2014)", "n_obs": n, "n_params": len(NORM_NAMES),
           "dof": dof, "residual_variance_g2": s2_resid, "noise_variance_g2": s2_noise,
           "variance_used": "residual" if s2_resid is not None and s2_resid >= s2_noise else "noise floor",
           "iterations": sol.iterations, "build_seconds": problem.build_seconds, "solve_seconds": solve_seconds}
    corr = cov / np.outer(np.where(u > 0, u, 1.0), np.where(u > 0, u, 1.0))
    result = CalibrationResult(unit=serial, method="joint", parameters=params,
                               status="ok" if sol.converged else "not_converged", effects=(),
                               fit=fit, intervals=intervals, correlation_names=NORM_NAMES, correlation=corr,
                               notes=notes, extra={"fixed": {f"Ca_{ab}": {"value": 0.0, "unit": "arcsec"}
                                                             for ab in ("yx", "zx", "zy")},
                                                   "output_unit": rec.unit,
                                                   "local_g_m_s2": gravity_g * STANDARD_GRAVITY_M_S2})
    gof_p = float(stats.chi2.sf(rss / s2_noise, dof)) if dof > 0 and s2_noise > 0 else None
    gof_ratio = (s2_resid / s2_noise) if s2_resid is not None and s2_noise > 0 else None
    fit["noise_floor_ratio"] = gof_ratio
    apply_gates(result, FitEvidence(
        converged=sol.converged, cost_start=0.5 * float(r0 @ r0), cost_final=0.5 * rss, n_obs=n,
        n_free=len(NORM_NAMES), jacobian=sol.J, free_names=NORM_NAMES,
        residual_rms=math.sqrt(rss / n), data_rms=gravity_g, gof_p_value=gof_p, gof_ratio=gof_ratio,
        gof_what=f"residual variance of |A| - g over the recording's own noise floor of the interval means "
                 f"({dof} dof)"), config=gates)
    return result, problem, sol


def norm_matrices(x: np.ndarray):
    """K, S, Ca (numpy) from the norm model's parameter vector (reporting units)."""
    angles = {ab: 0.0 for ab in ANGLE_NAMES}
    for i, ab in enumerate(NORM_ANGLES):
        angles[ab] = x[6 + i] * ARCSEC
    return np.asarray(x[:3], float), np.asarray(x[3:6], float), np.array(dcm(angles), float)


def result_matrices(result: CalibrationResult):
    """K, S, Ca (numpy, internal units) of a fit-raw result."""
    K = np.array([result[f"K_{a}"].value for a in AXES])
    S = np.array([result[f"S_{a}"].value for a in AXES])
    angles = {ab: (result[f"Ca_{ab}"].value * ARCSEC if f"Ca_{ab}" in result.parameters else 0.0)
              for ab in ANGLE_NAMES}
    return K, S, np.array(dcm(angles), float)


# --------------------------------------------------------------------------------------
# the figure imu_tk users compare: RMS of |A| - g over the static intervals
# --------------------------------------------------------------------------------------
def norm_residual_rms_m_s2(rec: RawRecording, detection: StaticDetection, K, S, Ca, gravity_g: float) -> dict:
    """RMS of ``|A| - g`` in m/s^2 over every sample of the static intervals, and over the
    interval means (the systematic part, without the sample noise)."""
    per_sample, per_mean = [], []
    for iv in detection.intervals:
        a = calibrated_acceleration(K, S, Ca, rec.acc[iv.start:iv.end])
        nrm = np.linalg.norm(a, axis=1) - gravity_g
        per_sample.append(nrm)
        per_mean.append(np.linalg.norm(calibrated_acceleration(K, S, Ca, rec.acc[iv.start:iv.end].mean(axis=0)))
                        - gravity_g)
    ps = np.concatenate(per_sample)
    return {"samples": float(np.sqrt(np.mean(ps ** 2))) * STANDARD_GRAVITY_M_S2,
            "means": float(np.sqrt(np.mean(np.square(per_mean)))) * STANDARD_GRAVITY_M_S2}


def nominal_scale(rec: RawRecording, detection: StaticDetection, gravity_g: float,
                  counts_per_g: Optional[float] = None) -> tuple[float, str]:
    """Scale factor of the 'before' figure (g per input unit) and how it was chosen."""
    if rec.unit == "m/s2":
        return 1.0 / STANDARD_GRAVITY_M_S2, "nominal: 1 g = 9.80665 m/s2"
    if rec.unit == "g":
        return 1.0, "nominal: readings in g"
    if counts_per_g:
        return 1.0 / counts_per_g, f"nominal: {counts_per_g:g} counts/g (datasheet)"
    norms = np.concatenate([np.linalg.norm(rec.acc[iv.start:iv.end], axis=1) for iv in detection.intervals])
    k = gravity_g / float(np.median(norms))
    return k, f"no datasheet scale given: one isotropic scale, {1 / k:.6g} counts/g (median |W| over the static samples = g)"


# --------------------------------------------------------------------------------------
# posterior sampling through the bench's path (triadcal.estimation.posterior)
# --------------------------------------------------------------------------------------
#: priors of the raw models, ten times the spread of MEMS units (as the bench's are ten times
#: the spread of its units): K ~ N(k0, 0.1 k0) with k0 the isotropic scale of the recording
#: (10 x a 1 % scale-factor spread), S ~ N(0, 0.5 g) (10 x a 50 mg offset),
#: Ca ~ N(0, 5 deg) (10 x a 0.5 deg misalignment), |Ca| < 0.5 rad
RAW_PRIOR_K_REL = 0.1
RAW_PRIOR_S_G = 0.5
RAW_PRIOR_CA_ARCSEC = 5 * 3600.0


def raw_priors(names: Sequence[str], k0: float, scale_unit: str, placement_sd_arcsec: Optional[float] = None,
               overrides=None, misalignment_sd_arcsec: Optional[float] = None) -> dict:
    """The documented weakly informative priors of the raw models (reporting units); tilts (known
    poses) get the placement random effect's N(0, sigma_h^2), and there the angles get the
    known-pose model's misalignment prior N(0, sigma_a^2) (module docstring)."""
    from .priors import HALF_RADIAN, Prior

    out = {}
    for n in names:
        if n.startswith("K_"):
            out[n] = Prior(n, scale_unit, float(k0), RAW_PRIOR_K_REL * float(k0), 0.0, np.inf,
                           "a scale factor is positive; 10 x a 1 % spread around the isotropic scale of the recording")
        elif n.startswith("S_"):
            out[n] = Prior(n, "g", 0.0, RAW_PRIOR_S_G, reason="10 x a 50 mg MEMS offset")
        elif n.startswith("Ca_"):
            b = HALF_RADIAN / ARCSEC
            if misalignment_sd_arcsec is None:
                out[n] = Prior(n, "arcsec", 0.0, RAW_PRIOR_CA_ARCSEC, -b, b,
                               "10 x a 0.5 deg MEMS misalignment; each row of Ca stays a unit vector")
            else:
                out[n] = Prior(n, "arcsec", 0.0, float(misalignment_sd_arcsec), -b, b,
                               "known poses: the misalignment prior of the least-squares fit "
                               "(--misalignment-sd-deg); the angles are confounded with the placement")
        elif n.startswith("tilt_"):
            out[n] = Prior(n, "arcsec", 0.0, float(placement_sd_arcsec),
                           reason="hand placement: the random effect's prior (--placement-sd-deg)")
        else:
            raise UnknownName(n)
    for k, v in (overrides or {}).items():
        if k not in out:
            raise UnknownName(f"prior for {k!r}: not a parameter of this model ({', '.join(names)})")
        out[k] = v
    return out


def sample_unknown_poses(ls: CalibrationResult, problem: NormProblem, sol: Solution, *, serial: str,
                         scale_unit: str, priors=None, posterior_path=None, shear: bool = True, **sampler):
    """Posterior of the gravity-norm model (:func:`triadcal.estimation.posterior.sample_target`).

    Likelihood: ``|A_k| - g ~ N(0, s^2)`` per interval with ``s^2`` the variance the
    least-squares fit used (the residual variance, not below the noise of the interval means),
    held fixed. The least-squares intervals the flags compare with are the Gaussian ones
    (``value +- 1.96 u``, the same ``s``), so a ``non_gaussian`` flag is about the shape of
    the posterior, not the Student-t factor. Parameters whose least-squares SD exceeds half
    their prior SD (a nearly singular design: the MPU-6050's Ca_xy) are the slow coordinates of
    a :func:`~triadcal.estimation.posterior.conditional_shear` (``shear=False``: plain whitened
    coordinates, for comparison). Returns ``(CalibrationResult, PosteriorRun)``."""
    from .posterior import PRIOR_DOMINATED_RATIO, ResidualTarget, conditional_shear, sample_target

    f = ls.fit
    s2 = max(f["residual_variance_g2"] or 0.0, f["noise_variance_g2"])
    sigma = np.full(problem.n, math.sqrt(s2))
    k0 = float(np.mean(sol.x[:3]))
    names = NORM_NAMES
    units = tuple(ls[n].unit for n in names)
    cov = ls.covariance(list(names))
    pri = raw_priors(names, k0, scale_unit, overrides=priors)
    data = (problem.w.T, problem.gravity_g, 1.0 / sigma)
    # parameters the data determine no better than the prior: the walkers move along them and
    # the others follow through the conditional shear (the ridge of a nearly singular design)
    slow = [i for i, n in enumerate(names) if ls[n].u > PRIOR_DOMINATED_RATIO * pri[n].sd]
    transform = inverse = None
    if slow and shear:
        transform, inverse = conditional_shear(problem.residual_function(), data, pri, names, sol.x, slow)
    target = ResidualTarget(
        name="norm", residual=problem.residual_function(), data=data,
        names=names, units=units, priors=pri, x_ls=sol.x, transform=transform, inverse=inverse,
        cov_ls=cov, sigma=sigma, obs_dim="interval", obs_name="norm_residual",
        observed={"w": (("interval", "axis"), problem.w, {"units": scale_unit.split("/")[-1]})},
        obs_coords={"axis": ["x", "y", "z"]}, unit_serial=serial)
    notes = [f"noise of |A| - g held at the least-squares value (s = {math.sqrt(s2):.3g} g, "
             f"{f['variance_used']}); the posterior does not include its uncertainty"
             + (f" (with {f['dof']} residual dof the Student-t least-squares intervals are the safer ones)"
                if 0 < f["dof"] < 10 else "")]
    result, run = sample_target(target, posterior_path=posterior_path, notes=notes, **sampler)
    result.notes.extend(ls.notes)
    result.fit.update({"model": f["model"], "dof": f["dof"], "variance_used": f["variance_used"],
                       "sigma_g": math.sqrt(s2),
                       "least_squares": {"status": ls.status, "estimator": "gravity-norm least squares",
                                         "parameters": {n: ls[n].to_dict() for n in names},
                                         "intervals": ls.intervals}})
    result.extra["fixed"] = ls.extra.get("fixed", {})
    result.extra["sampler"]["coordinates"] = (
        "sheared: the walkers move along " + ", ".join(names[i] for i in slow) + "; the other parameters about "
        "their conditional optimum" if transform is not None else "whitened (Laplace approximation)")
    return result, run


def sample_known_poses(ls: CalibrationResult, problem: KnownPoseProblem, sol: Solution, labels: Sequence[str], *,
                       serial: str, scale_unit: str, priors=None, posterior_path=None, shear: bool = True,
                       **sampler):
    """Posterior of the known-pose model: the 12 unit parameters and the 12 placement tilts
    (prior N(0, sigma_h^2), the random effect), sampled jointly, so the tilts are integrated out
    exactly (no importance sampling); the angles' prior N(0, sigma_a^2) is the least-squares
    fit's. The walkers move in sheared coordinates
    (:func:`~triadcal.estimation.posterior.conditional_shear`): the tilts, and the unit
    parameters about their conditional optimum given the tilts; along the unresolved directions
    K and S move with the squares of the tilts, a curved ridge the shear straightens."""
    from .posterior import ResidualTarget, conditional_shear, sample_target

    nu = len(UNIT_NAMES)
    tilt_names = tuple(f"tilt_{c}_{lab}" for lab in labels for c in "xy")
    names = UNIT_NAMES + tilt_names
    units = tuple(ls[n].unit for n in UNIT_NAMES) + ("arcsec",) * len(tilt_names)
    k0 = float(np.mean(sol.x[:3]))
    pri = raw_priors(names, k0, scale_unit, problem.sigma_h, overrides=priors,
                     misalignment_sd_arcsec=problem.sigma_a)
    cov_ls = scaled_covariance(sol.J)
    z = Z95
    ls_intervals = {n: (ls[n].value - z * ls[n].u, ls[n].value + z * ls[n].u) for n in UNIT_NAMES}
    data = (problem.w.T, 1.0 / problem.se.T, problem.cov_matrix, problem.gravity_g)
    transform = inverse = None
    if shear:
        transform, inverse = conditional_shear(problem.residual_function(), data, pri, names, sol.x,
                                               slow=range(nu, len(names)))
    target = ResidualTarget(
        name="known_poses", residual=problem.residual_function(), data=data,
        names=names, units=units, priors=pri, x_ls=sol.x, cov_ls=cov_ls, sigma=problem.se.reshape(-1),
        ls_intervals=ls_intervals, obs_dim="reading", obs_name="w",
        observed={"w": (("reading",), problem.w.reshape(-1), {"units": scale_unit.split("/")[-1]})},
        obs_coords={"pose": ("reading", np.repeat(np.asarray(labels, str), 3)),
                    "axis": ("reading", np.tile(["x", "y", "z"], problem.n))},
        unit_serial=serial, transform=transform, inverse=inverse)
    notes = []
    if str(ls.fit.get("placement_sd_source", "")).startswith("integrated"):
        notes.append(f"the sampler holds the placement SD at the data's most probable value "
                     f"({problem.sigma_h / 3600.0:.2g} deg); the least-squares result (fit.least_squares) integrates "
                     "it, so its intervals are the slightly wider, safer ones")
    result, run = sample_target(target, posterior_path=posterior_path, notes=notes, **sampler)
    tilts = {n: result.parameters.pop(n) for n in tilt_names}
    for n in tilt_names:
        result.intervals.pop(n, None)
    keep = [i for i, n in enumerate(names) if n in UNIT_NAMES]
    result.correlation = result.correlation[np.ix_(keep, keep)]
    result.correlation_names = UNIT_NAMES
    flags = result.extra["flags"]
    for key in ("non_gaussian", "prior_dominated", "prior_influenced"):
        flags[key] = [n for n in flags[key] if n in UNIT_NAMES]
    result.notes = [n for n in result.notes if not n.startswith("tilt_")] + list(ls.notes)
    result.extra["sampler"]["coordinates"] = (
        "sheared: the walkers move along the placement tilts; the unit parameters about their conditional "
        "optimum given the tilts" if transform is not None else "whitened (Laplace approximation)")
    result.fit.update({"model": ls.fit["model"], "placement_sd_deg": ls.fit["placement_sd_deg"],
                       "placement_sd_source": ls.fit.get("placement_sd_source"),
                       "misalignment_sd_deg": ls.fit.get("misalignment_sd_deg"),
                       "n_nuisance": len(tilt_names),
                       "least_squares": {"status": ls.status, "estimator": ls.fit.get("estimator"),
                                         "parameters": {n: {"value": ls[n].value, "u": ls[n].u}
                                                        for n in UNIT_NAMES}}})
    result.extra["placement_tilts"] = [
        {"pose": lab, "tilt_x_deg": tilts[f"tilt_x_{lab}"].value / 3600.0,
         "tilt_y_deg": tilts[f"tilt_y_{lab}"].value / 3600.0,
         "u_deg": [tilts[f"tilt_x_{lab}"].u / 3600.0, tilts[f"tilt_y_{lab}"].u / 3600.0]} for lab in labels]
    return result, run


# --------------------------------------------------------------------------------------
# the library function behind `triadcal fit-raw`
# --------------------------------------------------------------------------------------
@dataclass
class RawFit:
    """Everything ``fit-raw`` produced: the result, what the static step found, the averages,
    and (known poses) the bench campaign of the averages."""

    result: CalibrationResult
    detection: StaticDetection
    averages: PoseAverages
    recording: RawRecording
    campaign: Optional[Campaign] = None
    solution: Optional[Solution] = None
    posterior_run: Optional[object] = None     # PosteriorRun when sampled


def static_intervals_of(rec: RawRecording, *, labels: Optional[str] = None, intervals=None,
                        poses: str = "known", window_s: float = 1.0, threshold: float = 4.0,
                        min_duration_s: float = 2.0) -> StaticDetection:
    """The static intervals from the label column, an interval file, or the detector. In known-pose
    mode detected intervals are labelled by the up axis of their mean reading."""
    if labels is not None and intervals is not None:
        raise ValueError("give either a label column or an interval file, not both")
    if labels is not None:
        if rec.labels is None:
            raise ValueError(f"{rec.source}: the recording was read without its label column '{labels}'")
        det = intervals_from_labels(rec.labels, labels, POSE_LABELS if poses == "known" else None)
    elif intervals is not None:
        spec = read_intervals(intervals)
        det = intervals_from_spec(spec.start, spec.end, spec.labels, rec.n, spec.source,
                                  POSE_LABELS if poses == "known" else None)
    else:
        det = detect_static_intervals(rec.acc, rec.rate_hz, window_s=window_s, threshold=threshold,
                                      min_duration_s=min_duration_s)
    if poses == "known":
        for iv in det.intervals:
            if not iv.label:
                iv.label = pose_label_of(rec.acc[iv.start:iv.end].mean(axis=0))
    if not det.intervals:
        raise StaticIntervalError(f"{rec.source}: no static intervals ({det.summary(rec.rate_hz)})")
    return det


def fit_raw(data, rate_hz: Optional[float] = None, *, columns: Optional[Sequence[str]] = None,
            unit: str = "counts", poses: str = "known", labels: Optional[str] = None, intervals=None,
            local_g_m_s2: float = 9.81, placement_sd_deg: Union[float, str] = "auto", misalignment_sd_deg: float = 1.0,
            counts_per_g: Optional[float] = None,
            serial: Optional[str] = None, window_s: float = 1.0, threshold: float = 4.0,
            min_duration_s: float = 2.0, json_path=None, bench_csv_path=None, sample: bool = False,
            posterior_path=None, priors=None, ess: float = 2000, seed: int = 0, max_steps: int = 20000,
            progress=None, n_walkers: Optional[int] = None, gates: GateConfig = DEFAULT_CONFIG) -> RawFit:
    """Calibrate from a raw recording (``triadcal fit-raw``).

    ``data`` is a CSV path (read with :func:`triadcal.io.raw.read_raw_csv` at the stated
    ``rate_hz``) or a :class:`RawRecording`. ``poses``: ``known`` (imucal's six faces) or
    ``unknown`` (free orientations, gravity norm). The result's ``fit`` block carries
    ``rms_norm_residual_m_s2`` (RMS of |A| - g over the static samples) before (nominal
    scaling) and after the calibration.

    ``sample``: the posterior through the bench's path (:mod:`triadcal.estimation.posterior`:
    same moves, stop rule, diagnostics, flags); the result is then the posterior's (method
    ``posterior``, the least-squares values under ``fit.least_squares``), ``posterior_path``
    receives the arviz InferenceData, ``priors`` overrides :func:`raw_priors` by name, ``ess``,
    ``seed``, ``max_steps``, ``progress`` as in :func:`triadcal.estimation.posterior.sample`.
    """
    if posterior_path is not None and not sample:
        raise ValueError("a posterior file needs sampling (--sample)")
    if poses not in ("known", "unknown"):
        raise ValueError(f"poses must be 'known' or 'unknown', got {poses!r}")
    if not (local_g_m_s2 > 0 and math.isfinite(local_g_m_s2)):
        raise ValueError(f"local g must be a positive number of m/s2, got {local_g_m_s2}")
    if isinstance(data, RawRecording):
        rec = data
    else:
        if rate_hz is None:
            raise ValueError("state the sample rate (--rate HZ): it cannot be guessed safely (imucal issue #25)")
        rec = read_raw_csv(data, rate_hz, columns, unit, labels)
    gravity_g = local_g_m_s2 / STANDARD_GRAVITY_M_S2
    serial = serial or (str(rec.source).rsplit("/", 1)[-1].rsplit(".", 1)[0])
    try:
        det = static_intervals_of(rec, labels=labels, intervals=intervals, poses=poses, window_s=window_s,
                                  threshold=threshold, min_duration_s=min_duration_s)
        avg = pose_averages(rec, det)
        check_declared_unit(rec, avg.w, local_g_m_s2)
        return _fit_raw_detected(rec, det, avg, poses=poses, gravity_g=gravity_g, serial=serial,
                                 local_g_m_s2=local_g_m_s2, placement_sd_deg=placement_sd_deg,
                                 misalignment_sd_deg=misalignment_sd_deg, counts_per_g=counts_per_g,
                                 json_path=json_path, bench_csv_path=bench_csv_path, sample=sample,
                                 posterior_path=posterior_path, priors=priors, ess=ess, seed=seed,
                                 max_steps=max_steps, progress=progress, n_walkers=n_walkers, gates=gates)
    except StaticIntervalError as exc:
        if str(rec.source) in str(exc):
            raise
        raise StaticIntervalError(f"{rec.source}: {exc}") from None


def _fit_raw_detected(rec, det, avg, *, poses, gravity_g, serial, local_g_m_s2, placement_sd_deg,
                      misalignment_sd_deg, counts_per_g, json_path, bench_csv_path, sample, posterior_path, priors,
                      ess, seed, max_steps, progress, n_walkers, gates) -> RawFit:
    campaign = None
    if poses == "known":
        result, problem, sol = fit_known_poses(avg, gravity_g=gravity_g, scale_unit=rec.scale_unit,
                                               serial=serial, placement_sd_deg=placement_sd_deg,
                                               misalignment_sd_deg=misalignment_sd_deg, gates=gates)
        campaign = bench_campaign(avg, rec, serial, local_g_m_s2)
    else:
        result, problem, sol = fit_unknown_poses(rec, avg, gravity_g=gravity_g, serial=serial, gates=gates)
    run = None
    if sample:
        opts = dict(serial=serial, scale_unit=rec.scale_unit, priors=priors, posterior_path=posterior_path,
                    ess=ess, seed=seed, max_steps=max_steps, progress=progress, n_walkers=n_walkers)
        ls = result
        if poses == "known":
            result, run = sample_known_poses(result, problem, sol, avg.label, **opts)
        else:
            result, run = sample_unknown_poses(result, problem, sol, **opts)
        # the posterior is no better an answer than its least-squares fit: that fit's gates carry over
        result.extra.update({"output_unit": rec.unit, "local_g_m_s2": local_g_m_s2})
        ls_gate = GateOutcome("least_squares", ls.status in ("ok", "not_converged"),
                              ls.status if ls.status != "ok" else "model_mismatch",
                              f"the least-squares fit of the same model has status {ls.status!r}")
        apply_gates(result, FitEvidence(converged=run.converged, extra=[ls_gate]), config=gates)
    k0, how = nominal_scale(rec, det, gravity_g, counts_per_g)
    before = norm_residual_rms_m_s2(rec, det, np.full(3, k0), np.zeros(3), np.eye(3), gravity_g)
    after = norm_residual_rms_m_s2(rec, det, *result_matrices(result), gravity_g)
    result.fit.update({
        "rms_norm_residual_m_s2": {"before": before["samples"], "after": after["samples"]},
        "rms_norm_residual_of_means_m_s2": {"before": before["means"], "after": after["means"]},
        "before_scaling": how, "local_g_m_s2": local_g_m_s2})
    result.extra.update({"input_unit": rec.unit, "output_unit": rec.unit, "local_g_m_s2": local_g_m_s2,
                         "source": rec.source, "rate_hz": rec.rate_hz,
                         "static_intervals": det.to_dict(rec.rate_hz)})
    if json_path is not None:
        result.save(json_path)
    if bench_csv_path is not None:
        if campaign is None:
            raise ValueError("--bench-csv needs known poses: free orientations have no bench angles")
        from ..io.bench_csv import write_bench_csv

        write_bench_csv(campaign, bench_csv_path)
    return RawFit(result, det, avg, rec, campaign, sol, run)
