"""Known poses (imucal's Ferraris labels): eq. 1 through :meth:`Model.predict` with each pose's
placement error as a random tilt of apparent gravity, N(0, sigma_h^2) per component, and a
proper prior on the angles; sigma_h stated or integrated out. Why both priors are needed, and
what they cost, is derived in docs/raw.md ("Known poses").
"""

from __future__ import annotations

from ...errors import InputError

import math
import time
from typing import Optional, Union

import casadi as ca
import numpy as np

from ...models.campaign import DEFAULT_PLAN, Campaign
from ...models.model import Covariates, Model
from ...models.sensor import ANGLE_NAMES
from ...models.units import ARCSEC, STANDARD_GRAVITY_M_S2
from ..gates import (
    DEFAULT_CONFIG,
    FitEvidence,
    GateConfig,
    apply_gates,
)
from ..dense_call import DenseCall
from ..hints import orientation_hints
from ..joint import Solution, levenberg_marquardt, scaled_covariance, start_values
from ..result import CalibrationResult, ParameterValue
from .detection import (
    POSE_LABELS,
    StaticIntervalError,
)
from .poses import POSE_POSITIONS, UNIT_NAMES, PoseAverages


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
        self._mapped = DenseCall(f.map("poses", "serial", self.n, [0, 3], []))   # x, g shared
        self._pose = ca.Function("pose_w", [x, t, c, g], [wm])
        self.cov_matrix = np.vstack([np.radians(axis1_deg), np.radians(axis2_deg)])
        self.gravity_g = float(gravity_g)
        self.build_seconds = time.perf_counter() - t0

    def residuals_and_jacobian(self, x: np.ndarray):
        nu = len(UNIT_NAMES)
        xu, tilts = x[:nu], x[nu:].reshape(self.n, 2)
        wm, Jx, Jt = self._mapped(xu, tilts.T, self.cov_matrix, self.gravity_g)
        wm = wm.T                                                          # (n, 3)
        Jx = Jx.reshape(3, self.n, nu).transpose(1, 0, 2)                  # (n, 3, 12)
        Jt = Jt.reshape(3, self.n, 2).transpose(1, 0, 2)                   # (n, 3, 2)
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


def _proposal_factor(C: np.ndarray) -> np.ndarray:
    """A square root ``L`` (``L L^T = C``) of the tilts' Laplace covariance for the proposal: the
    Cholesky factor (with a 1e-12 relative jitter), or, when ``C`` is not positive definite in
    floating point (a pseudo-inverse of a Jacobian conditioned beyond 1e12, e.g. when the placement
    SD runs to the grid's 20 deg edge), the symmetric factor of ``C`` with its eigenvalues raised
    to 1e-12 of the largest. Before, such a ``C`` ended in numpy's LinAlgError (exit 70)."""
    C = 0.5 * (C + C.T)
    scale = float(np.max(np.abs(np.diag(C)))) if C.size else 0.0
    if not np.isfinite(scale) or scale <= 0:
        scale = 1.0
    try:
        return np.linalg.cholesky(C + 1e-12 * scale * np.eye(len(C)))
    except np.linalg.LinAlgError:
        ev, V = np.linalg.eigh(np.nan_to_num(C))
        return V * np.sqrt(np.maximum(ev, 1e-12 * max(float(ev.max()), scale)))[None, :]


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
    L = _proposal_factor(Ct)
    z = rng.standard_normal((n_draws, len(t_map)))
    chi = rng.chisquare(dof, n_draws) / dof
    T = t_map + (z / np.sqrt(chi)[:, None]) @ L.T
    q = np.sum(np.square(np.linalg.solve(L, (T - t_map).T)), axis=0)
    log_q = -0.5 * (dof + len(t_map)) * np.log1p(q / dof)
    Xu = np.repeat(x_map[None, :nu], n_draws, axis=0)
    Ju = _conditional_jacobian(problem, J_map)
    H_inv = scaled_covariance(Ju)
    P = H_inv @ Ju.T                 # one Gauss-Newton step given the tilts: x_u <- x_u - P r
    # draws whose angles leave the model's domain (a row of Ca past 90 deg: swapped or inverted
    # columns) have no residual; they get weight 0, without numpy's warnings on stderr
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        for _ in range(2):
            Xu = Xu - conditional_residuals(problem, Xu, T) @ P.T
        r = conditional_residuals(problem, Xu, T)
        lw = -0.5 * (np.sum(r * r, axis=1) + np.sum((T / problem.sigma_h) ** 2, axis=1)) - log_q
    lw = np.where(np.isfinite(lw), lw, -np.inf)
    if not np.isfinite(lw).any():          # no draw is usable: the Laplace approximation, ESS 0
        return x_map, cov_laplace, 0.0
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
            raise InputError(f"the placement SD must be a number of degrees or 'auto', got {placement_sd_deg!r}")
    start_sd = DEFAULT_PLACEMENT_SD_DEG if auto else placement_sd_deg
    labels = [lab if lab in POSE_POSITIONS else "" for lab in avg.label]
    if "" in labels:
        raise StaticIntervalError("known poses need a pose label (x_p, x_a, y_p, y_a, z_p, z_a) on every interval")
    missing = [p for p in POSE_LABELS if p not in labels]
    if missing:
        raise StaticIntervalError(f"known poses need all six faces; missing: {', '.join(missing)} "
                                  f"(found {', '.join(labels)})")
    if not (start_sd > 0 and math.isfinite(start_sd)):
        raise InputError("the placement SD must be positive: with no placement error the model is the "
                         "bench model (use triadcal fit on the bench CSV)")
    if not (misalignment_sd_deg > 0 and math.isfinite(misalignment_sd_deg)):
        raise InputError("the misalignment prior SD must be a positive number of degrees: the angles are "
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
           "noise": "standard error of each pose mean: max(sd/sqrt(n), batch means); sd floored by the pooled "
                    "SD of all the intervals for intervals of fewer than 50 samples",
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
    # an outside probe: K2 = 3 mg/g^2 on each axis moved every S by 3 mg (30 u), status ok, no word; a bias
    # drifting 4 mg over the recording moved K by 2-3 u
    notes.append("six faces: each axis sees +1 g, -1 g and 0 g only, and a pose's placement tilt takes up what its "
                 "0 g readings say about the bias, so S_a is the bias as the +-1 g readings give it, "
                 "K_a (W(+1 g) + W(-1 g))/2: an even nonlinearity K2_a adds to it in full (IEEE Std 1293's K0 + K2 g^2), "
                 + (f"and {k} intervals leave no redundancy beyond the placement tilts" if k <= 9 else
                    f"and {k} intervals leave {k - 9} degrees of freedom beyond the placement tilts")
                 + " to test the model with, so a bias that drifts during the recording moves K and S unseen too, "
                 "as does a wander slower than an interval (bias instability: each pose mean's u is the noise "
                 "within its interval, which cannot hold it; an outside probe's AR(1) wander of 0.3 mg with a "
                 "10 s correlation time under 1 mg white noise, 4 s faces: K and S covered 60-90 %, not 95 %); "
                 "free poses (--poses unknown, whose --diagnose names a K2 as scale_nonlinearity) or a bench "
                 "calibration separate them")
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
        from ...models.campaign import nominal_gravity

        for hint in orientation_hints(avg.w, nominal_gravity(a1, a2).reshape(-1, 3)):
            result.notes.append(f"hint: {hint}")
    return result, problem, sol
