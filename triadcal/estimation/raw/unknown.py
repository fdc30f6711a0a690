"""Unknown poses (Tedaldi et al. 2014 / imu_tk): least squares of ``|A| - g`` over the static
intervals with ``A = Ca^-1 (K W - S)``; the IMU frame is imu_tk's upper-triangular one, so
only Ca_xy, Ca_xz, Ca_yz are estimated (docs/raw.md, "Unknown poses").
"""

from __future__ import annotations

import math
import time
from typing import Optional

import casadi as ca
import numpy as np
from scipy import stats

from ...io.raw import RawRecording
from ...models.sensor import ANGLE_NAMES, AXES, calibrated_acceleration, dcm
from ...models.units import ARCSEC, STANDARD_GRAVITY_M_S2
from ..gates import (
    DEFAULT_CONFIG,
    FitEvidence,
    GateConfig,
    apply_gates,
)
from ..dense_call import DenseCall
from ..joint import levenberg_marquardt, scaled_covariance
from ..result import CalibrationResult, ParameterValue
from .detection import (
    StaticDetection,
    StaticIntervalError,
)
from .poses import (MIN_OWN_SD_SAMPLES, NORM_ANGLES, NORM_NAMES, PoseAverages, correlated_mean_factor,
                    integrated_autocorrelation, pooled_sd)


# --------------------------------------------------------------------------------------
# unknown poses: the gravity-norm model
# --------------------------------------------------------------------------------------
def _calibrated_symbolic(x, w):
    """``A = Ca^-1 (K W - S)`` (:func:`triadcal.models.sensor.calibrated_acceleration`) on CasADi
    symbols, with the norm model's free angles ``Ca_xy, Ca_xz, Ca_yz`` (arcsec), the others zero."""
    return calibrated_acceleration(x[0:3], x[3:6], dcm(_norm_angles(x)), w)


def _norm_angles(x) -> dict:
    """The six angles (rad) of the norm model's parameter vector: ``Ca_xy, Ca_xz, Ca_yz`` free."""
    angles = {ab: 0.0 for ab in ANGLE_NAMES}
    for i, ab in enumerate(NORM_ANGLES):
        angles[ab] = x[6 + i] * ARCSEC
    return angles


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
        self._mapped = DenseCall(f.map("intervals", "serial", self.n, [0, 2], []))   # x, g shared
        self._interval = ca.Function("norm_interval", [x, wk, g], [r])
        self.build_seconds = time.perf_counter() - t0

    #: residuals are returned in micro-g: the LM stop rule compares steps with the uncertainty
    #: of unit-variance residuals, so the scale must not exceed the noise (1 ug is below any MEMS)
    RESIDUAL_UNIT_G = 1e-6

    def residuals_and_jacobian(self, x: np.ndarray):
        r, J = self._mapped(x, self.w.T, self.gravity_g)
        return (r.reshape(-1) / self.RESIDUAL_UNIT_G,
                J.reshape(self.n, len(self.names)) / self.RESIDUAL_UNIT_G)

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


#: two static intervals are the same orientation when their mean directions are closer than this
ORIENTATION_SEPARATION_DEG = 10.0


def distinct_orientations(w: np.ndarray, separation_deg: float = ORIENTATION_SEPARATION_DEG) -> int:
    """How many distinct directions the interval means ``w`` (n, 3) point in: greedy clusters
    of unit vectors closer than ``separation_deg``. Give calibrated means (g): a raw reading's
    offset need not be small against g (offset-binary counts sit at 32768)."""
    u = np.asarray(w, float)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    centres = []
    cos_sep = np.cos(np.radians(separation_deg))
    for v in u:
        if not any(float(v @ c) > cos_sep for c in centres):
            centres.append(v)
    return len(centres)


def norm_mean_noise(rec: RawRecording, avg: PoseAverages, K, S, Ca, batches: int = 10) -> tuple:
    """``(sd, var_mean)`` (g, g^2) per static interval: the SD of the calibrated norm |A| over its samples
    and the variance of its mean, the noise floor of the gravity-norm fit and of the raw diagnosis.

    From the samples of |A| themselves: the larger of ``sd^2/m`` (times the correlated-noise factor of
    the norms' pooled integrated autocorrelation time, :func:`~.poses.correlated_mean_factor`) and a
    batch-means estimate (``batches`` batches, when ``m >= 5 batches``), so slowly correlated noise does not shrink
    it. |A| does not change when the unit turns, so motion inside an interval does not inflate this
    floor; it shortens the mean vector instead, which the residual sees (the slow-motion case of
    issue 14). An interval of fewer than MIN_OWN_SD_SAMPLES samples has the larger of its own and the
    pooled sample SD of |A| (a 1-sample interval the pooled one; NaN when no interval has two): the
    averages' rule (:func:`~.poses.pose_averages`). The rounding of the readings
    (``avg.rounding_u``, :func:`~.poses.rounding_floor`) is added, projected on |A|:
    ``d|A| = (A/|A|)^T Ca^-1 diag(K) dW``."""
    norms = [np.linalg.norm(calibrated_acceleration(K, S, Ca, rec.acc[s_:e_]), axis=1)
             for s_, e_ in zip(avg.start, avg.end)]
    pooled = float(pooled_sd([a[:, None] for a in norms])[0][0]) if norms else float("nan")
    acf_tau = integrated_autocorrelation([a[:, None] for a in norms])[0] if norms else np.ones(1)
    M = np.linalg.solve(np.asarray(Ca, float), np.diag(np.asarray(K, float)))
    u_round = avg.rounding_u
    sd, var = [], []
    for k, (a, m) in enumerate(zip(norms, avg.n)):
        s = float(a.std(ddof=1)) if m > 1 else float("nan")
        if m < MIN_OWN_SD_SAMPLES:
            s = float(np.fmax(s, pooled))
        v = s * s * float(correlated_mean_factor(acf_tau, int(m))[0]) / m
        if m >= 5 * batches:
            bm = np.array([b.mean() for b in np.array_split(a, batches)])
            v = max(v, float(np.var(bm, ddof=1)) / batches)
        if u_round is not None:
            am = calibrated_acceleration(K, S, Ca, avg.w[k])
            v += float(np.sum(((am / np.linalg.norm(am)) @ M * u_round) ** 2))
        sd.append(s), var.append(v)
    return np.array(sd), np.array(var)


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
    K, S, Ca = norm_matrices(sol.x)
    var_means = norm_mean_noise(rec, avg, K, S, Ca)[1]
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
             "definition and only Ca_xy, Ca_xz, Ca_yz are estimated",
             # an outside probe: x and y swapped gave ok with K_x the true K_y (389 u off), nothing said
             "free poses: the norm of gravity is the same whichever column holds which axis and whatever a column's "
             "sign, so a swapped or inverted column fits as well and is not detected: the columns are taken as "
             "labelled (a six-face or bench calibration checks them)"]
    # on the calibrated means: the raw ones of offset-binary counts all point near (32768, 32768, 32768)
    # and counted as one orientation (an outside probe); equal raw means stay equal whatever K and S
    k_orient = distinct_orientations(calibrated_acceleration(K, S, Ca, avg.w))
    if k_orient < len(NORM_NAMES):
        notes.append(f"the {n} static intervals show only {k_orient} distinct orientation{'s' if k_orient != 1 else ''} "
                     f"(directions {ORIENTATION_SEPARATION_DEG:g} deg apart or more): the gravity-norm model's "
                     f"{len(NORM_NAMES)} parameters need poses spread over the sphere, so K, S and the angles "
                     "cannot be told apart (a thermal run in one pose calibrates no scale factor)")
    if avg.pooled_floor:
        med = float(np.median(var_means))
        loud = [k for k in avg.pooled_floor if med > 0 and var_means[k] > 4.0 * med]
        if loud:
            notes.append("the gravity-norm fit weights every interval equally: the short interval"
                         f"{'s' if len(loud) > 1 else ''} "
                         + ", ".join(f"{avg.label[k] or k + 1} ({int(avg.n[k])} sample{'s' if avg.n[k] != 1 else ''}, "
                                     f"the noise of its mean {math.sqrt(var_means[k] / med):.2g} times the median "
                                     "interval's)" for k in loud)
                         + (" raise" if len(loud) > 1 else " raises")
                         + " the noise floor and the uncertainties of every parameter; leave "
                         + ("them" if len(loud) > 1 else "it") + " out (--intervals) if not a pose")
    if dof <= 0:
        notes.append(f"{n} static intervals for {len(NORM_NAMES)} parameters: no residual degrees of freedom, so "
                     "the misfit of the model cannot be judged; the uncertainties carry the sample noise only "
                     "(a lower bound): record more poses")
    elif dof < 10:
        notes.append(f"only {dof} residual degree{'s' if dof != 1 else ''} of freedom: the residual variance is itself uncertain; "
                     "the 95 % intervals use Student's t")
    fit = {"model": "unknown poses: gravity norm (Tedaldi et al. 2014)", "n_obs": n, "n_params": len(NORM_NAMES),
           "dof": dof, "distinct_orientations": k_orient,
           "residual_variance_g2": s2_resid, "noise_variance_g2": s2_noise,
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
    if dof > 0 and s2 > 0 and np.all(np.isfinite(u)):
        sens = nonlinearity_sensitivity(calibrated_acceleration(K, S, Ca, avg.w), sol.J, NORM_NAMES, u, math.sqrt(s2))
        fit["nonlinearity_sensitivity"] = sens
        note = nonlinearity_note(sens)
        if note:
            notes.append(note)
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


#: a term of the output the gravity-norm model leaves out, below what the residuals detect (2 SD), that
#: moves a parameter by more than this many u is said (:func:`nonlinearity_sensitivity`)
UNSEEN_MOVE_U = 1.0
#: the even and odd nonlinearities of IEEE Std 1293 the free-pose fit does not hold: name -> (term of
#: triadcal.estimation.raw.terms, the unit of 1e-6 of it)
NONLINEAR_TERMS = {"scale_nonlinearity": ("K2", "ug/g2"), "scale_asymmetry": ("scale asymmetry", "ppm")}


def nonlinearity_sensitivity(A: np.ndarray, J: np.ndarray, names, u: np.ndarray, noise_scale: float) -> dict:
    """What a K2 (``k2_a a_a^2``) or a scale asymmetry (``e_a |a_a|``) of the outputs, left out of the
    gravity-norm model, does to the answer. Per term, its three coefficients (one per output) have
    signatures ``B`` on the residuals ``|A_k| - g``: the interval's direction ``n_k = A_k / |A_k|``
    times the term at its mean ``A_k``, per 1e-6 of it (1 ug/g2, 1 ppm). Left out, the fit moves the
    parameters by ``M = -(J'J)^-1 J'B`` (``moves_u``: per output's coefficient, every parameter's
    move in its u, signed, largest first); the rest shows in the residuals, which measure the
    coefficients with covariance ``s^2 (B_perp' B_perp)^-1`` (``sd`` per output, ``B_perp`` = ``B``
    off the model's span, ``s`` = ``noise_scale``); ``unseen_u``: the largest move of each parameter
    over the coefficients within 2 SD of 0 (the ellipsoid ``k' C^-1 k <= 4``: ``2 sqrt(m_i' C m_i) /
    u_i``), the three largest — what a nonlinearity no test of the residuals sees can do.

    An outside probe (its own simulator, 30-40 free poses, noise 1 mg or 0.3 mg): K2 = 200 ug/g2 on
    each output moved every S by about 120 ug, 4-5 u, a scale asymmetry of 300 ppm by 8 u, status
    ok, the diagnosis null in half the runs (its detection limits 530-780 ug/g2)."""
    from .terms import scale_asymmetry, scale_nonlinearity

    A = np.asarray(A, float)
    J = np.asarray(J, float)
    n = A / np.linalg.norm(A, axis=1, keepdims=True)
    u = np.asarray(u, float)
    out = {}
    for term, f in (("scale_nonlinearity", scale_nonlinearity), ("scale_asymmetry", scale_asymmetry)):
        B = np.stack([np.sum(n * f(A, 1e-6 * np.eye(3)[i]), axis=1) for i in range(3)], axis=1)
        # the residuals' change when the readings hold the term; the fit moves against it
        M = -np.linalg.lstsq(J, B, rcond=None)[0]                  # (parameters, 3)
        perp = B + J @ M
        G = perp.T @ perp
        visible = np.sqrt(np.diag(G)) / np.maximum(np.linalg.norm(B, axis=0), 1e-300)
        mu = M / u[:, None]
        block = {"unit": NONLINEAR_TERMS[term][1],
                 "visible_fraction": {a: float(v) for a, v in zip(AXES, visible)},
                 "moves_u": {a: {names[i]: float(mu[i, j]) for i in np.argsort(-np.abs(mu[:, j]))}
                             for j, a in enumerate(AXES)}}
        if np.linalg.cond(G) < 1e12:
            C = noise_scale ** 2 * np.linalg.inv(G)
            block["sd"] = {a: float(np.sqrt(C[j, j])) for j, a in enumerate(AXES)}
            unseen = 2.0 * np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", M, C, M), 0.0)) / u
            block["unseen_u"] = {names[i]: float(unseen[i]) for i in np.argsort(-unseen)[:3]}
        else:
            block["sd"], block["unseen_u"] = None, None
        out[term] = block
    return out


def nonlinearity_note(sens: dict) -> Optional[str]:
    """The result's note when a nonlinearity below detection moves a parameter by more than
    :data:`UNSEEN_MOVE_U` u (:func:`nonlinearity_sensitivity`), or None."""
    parts = []
    for term, v in sens.items():
        label, unit = NONLINEAR_TERMS[term]
        if v["unseen_u"] is None:
            parts.append(f"a {label} is not seen at all by these poses")
            continue
        big = {k: m for k, m in v["unseen_u"].items() if m > UNSEEN_MOVE_U}
        if big:
            sds = ", ".join(f"{a} {2 * v['sd'][a]:.3g}" for a in AXES)
            parts.append(f"a {label} within 2 SD of 0 on each output ({sds} {unit}) moves "
                         + ", ".join(f"{k} by up to {m:.2g} u" for k, m in big.items()))
    if not parts:
        return None
    return ("the gravity-norm model is linear in the readings, and a nonlinearity of the outputs too small for the "
            "residuals to show would move the answer: " + "; ".join(parts)
            + " (fit.nonlinearity_sensitivity). MEMS accelerometers have a K2 of 100-1000 ug/g2 (the datasheet's "
            "nonlinearity): the values hold for a linear unit; a bench calibration with the K2 term (`triadcal fit "
            "--effects ...,scale_nonlinearity`) measures it")


def norm_matrices(x: np.ndarray):
    """K, S, Ca (numpy) from the norm model's parameter vector (reporting units)."""
    return np.asarray(x[:3], float), np.asarray(x[3:6], float), np.array(dcm(_norm_angles(x)), float)


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
    if rec.unit == "mg":
        return 1e-3, "nominal: readings in mg (1 g = 1000 mg)"
    if counts_per_g:
        return 1.0 / counts_per_g, f"nominal: {counts_per_g:g} counts/g (datasheet)"
    norms = np.concatenate([np.linalg.norm(rec.acc[iv.start:iv.end], axis=1) for iv in detection.intervals])
    k = gravity_g / float(np.median(norms))
    return k, f"no datasheet scale given: one isotropic scale, {1 / k:.6g} counts/g (median |W| over the static samples = g)"
