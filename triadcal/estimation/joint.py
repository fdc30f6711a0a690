"""Joint calibration: one least-squares fit of every term over all visits at once.

The model is :class:`triadcal.models.model.Model` (eq. 1 with the bench kinematics and
the chosen effects); CasADi builds the residuals and their exact Jacobian once, as a
per-visit function mapped over the visits, and a Levenberg-Marquardt iteration in
numpy solves the normal equations (the problem is nearly linear: it converges in a
few iterations; IPOPT gives the same optimum and is slower, see
``benchmarks/fit.py``). The covariance is the inverse Fisher information at the
optimum, ``(J^T J)^-1`` on the normalised residuals, scaled by the residual variance
when the noise is estimated rather than known.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Optional, Sequence

import casadi as ca
import numpy as np
from scipy import stats

from ..errors import IdentifiabilityError, InputError  # noqa: F401 - IdentifiabilityError importable from here
from ..models.campaign import Campaign, nominal_gravity
from ..models.effects import DEFAULT_EFFECTS
from ..models.model import Covariates, Model
from .dense_call import DenseCall
from ..models.sensor import ANGLE_NAMES, AXES
from ..models.units import ARCSEC, scale_factor_unit
from .gates import DEFAULT_CONFIG, FitEvidence, GateConfig, GateOutcome, apply_gates
from .hints import orientation_hints
from .result import CalibrationResult, ParameterValue
from ..uncertainty.typeb import lab_scope_notes
from .tilt_polar import tilt_polar_values

#: covariates of one visit, in the order of the mapped function's second input
COVARIATES = ("axis1", "axis2", "t_x", "t_y", "t_z", "rate_x", "rate_y", "rate_z", "branch", "time_s")
# the robust losses, their weights and checks: robust_check.py (re-exported here)
from .robust_check import LOSSES, robust_check, robust_psi_slope, robust_scale, robust_weights  # noqa: E402

from .design import axes_not_turned  # noqa: E402

# the noise of the mean outputs and the bench's random errors: noise_model.py (re-exported here)
from .one_temperature import (TEMPERATURE_SPAN_MIN_C, sensor_temperatures,  # noqa: E402,F401
                              single_temperature_reference)
from .noise_model import OVERSTATED_P, overstated_noise_note  # noqa: F401 - importable from here
from .noise_model import (WOBBLE_TO_POSITION, BenchErrors, NoiseSource, _bench_whitening,  # noqa: E402,F401
                          bench_errors_from_replicates, given_output_scale, noise_of, per_output_scale,
                          replicate_groups, with_bench_errors)


class JointProblem:
    """Residuals of a model on a campaign, compiled once with CasADi.

    ``x`` is the parameter vector in reporting units (order of ``names``); the
    residuals are ``(W_obs - W_model) / sigma`` for every visit and axis, shape (3 n,).
    Parameters in ``fixed`` are held at the given values (reporting units). ``output_map``: None, or
    a function of the model outputs ``W`` (n, 3) returning ``(e, de/dW)`` added to them after eq. 1
    (the quantisation of a digital output, :mod:`triadcal.estimation.quantisation_form`).
    """

    def __init__(self, campaign: Campaign, model: Model, sigma: np.ndarray, fixed: Optional[dict] = None,
                 output_map=None):
        self.campaign = campaign
        self.model = model
        self.fixed = dict(fixed or {})
        self.output_map = output_map
        self.names = tuple(n for n in model.names if n not in self.fixed)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.sigma = np.asarray(sigma, float)
        self.n = campaign.n_visits
        t0 = time.perf_counter()
        x = ca.SX.sym("x", len(self.names))
        c = ca.SX.sym("c", len(COVARIATES))
        p = {}
        for s in model.parameters:
            p[s.name] = (x[self.index[s.name]] if s.name in self.index else self.fixed[s.name]) * s.to_internal
        cov = Covariates(axis1=c[0], axis2=c[1], temp=(c[2], c[3], c[4]), temp_rate=(c[5], c[6], c[7]),
                         branch=c[8], time_s=c[9])
        g = ca.SX.sym("g")
        w = ca.vertcat(*model.predict(p, cov, g))
        per_visit = ca.Function("visit", [x, c, g], [w, ca.jacobian(w, x)])
        # x, g shared by the visits; numeric calls through DenseCall (no DM conversion of the Jacobian)
        self._mapped = DenseCall(per_visit.map("visits", "serial", self.n, [0, 2], []))
        self._predict = ca.Function("visit_w", [x, c, g], [w]).map("visits_w", "serial", self.n, [0, 2], [])
        self._predict_dense = DenseCall(self._predict)
        self.cov_matrix = campaign.covariate_matrix()
        self.gravity_g = campaign.gravity_g
        self.build_seconds = time.perf_counter() - t0

    def predict(self, x: np.ndarray) -> np.ndarray:
        """Model outputs (n, 3) at ``x``."""
        w = self._predict_dense(x, self.cov_matrix, self.gravity_g)[0].T
        return w if self.output_map is None else w + self.output_map(w)[0]

    def residuals_and_jacobian(self, x: np.ndarray):
        w, J = self._mapped(x, self.cov_matrix, self.gravity_g)        # (3, n), (3, n npar): visit k at k npar
        w, J = w.T, J.reshape(3, self.n, len(self.names)).transpose(1, 0, 2)   # (n, 3), (n, 3, npar)
        if self.output_map is not None:
            e, de = self.output_map(w)
            w, J = w + e, J * (1.0 + de)[:, :, None]
        r = (self.campaign.w - w) / self.sigma
        Jr = -J / self.sigma[:, :, None]
        return r.reshape(-1), Jr.reshape(-1, len(self.names))

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return ((self.campaign.w - self.predict(x)) / self.sigma).reshape(-1)


def stuck_outputs(campaign: Campaign) -> None:
    """Refuse an output column that holds one value in every visit although the plan turns its
    axis through at least 1 g of gravity (nominal): a stuck or disconnected channel, which carries
    no gravity and would start the fit at an infinite scale factor."""
    G = nominal_gravity(campaign.axis1_deg, campaign.axis2_deg)
    for i, a in enumerate(AXES):
        col = campaign.w[:, i]
        if campaign.n_visits > 1 and np.ptp(G[:, i]) >= 1.0 and np.all(col == col[0]):
            raise InputError(f"{campaign.source or 'campaign'}: w_{a} is {float(col[0]):g} {campaign.output_unit} "
                             "in every one "
                             f"of the {campaign.n_visits} visits, although the positions turn its axis through "
                             f"{np.ptp(G[:, i]):.2g} g: a stuck or disconnected channel (check the column and the unit's "
                             "output)")


def start_values(campaign: Campaign, model: Model) -> dict:
    """Start of the iteration from a per-axis linear fit of the outputs on the nominal
    gravity (eq. 1 with a level, perfect bench): ``W_a = (Ca_a . G + S_a) / K_a``."""
    G = nominal_gravity(campaign.axis1_deg, campaign.axis2_deg) * campaign.gravity_g
    A = np.column_stack([G, np.ones(len(G))])
    start = {}
    for i, a in enumerate(AXES):
        coef, *_ = np.linalg.lstsq(A, campaign.w[:, i], rcond=None)
        b, c = coef[:3], coef[3]
        if np.max(np.abs(G[:, i])) < 0.5 or not np.all(np.isfinite(coef)):
            continue  # the axis never points up or down: no start from the data, nominal values
        K = 1.0 / np.linalg.norm(b)
        start[f"K_{a}"] = K
        start[f"S_{a}"] = K * c
        for j, bb in enumerate(AXES):
            if bb != a:
                start[f"Ca_{a}{bb}"] = K * b[j] / ARCSEC
    return {n: start.get(n, model.spec[n].nominal) for n in model.names}


def identifiability_problems(campaign: Campaign, model: Model) -> dict[str, str]:
    """Parameters the data cannot determine, with the reason, from the design of the campaign."""
    problems = {}
    eff = set(model.effect_names)
    T = campaign.t.mean(axis=1)
    branches = set(np.sign(campaign.branch).tolist())
    # one branch plus the visits of no history (direction none, b = 0) does not count: h would then be
    # the offset of the first setpoint's visits from the rest, which absorbs anything localised there
    # (tried 2026-11-30: a quadratic angle tempco on a -40..80 degC heating sweep was then ok with Ca_xy
    # 8-10 u off in 7 of 8 campaigns -- tests/test_structure_shift.py; held, the structure gate refuses)
    if "hysteresis" in eff and not {-1.0, 1.0} <= branches:
        have = {-1.0: "heating", 1.0: "cooling", 0.0: "visits at a steady temperature (no branch)"}
        one = [have[b] for b in branches if b != 0.0]
        for ab in ANGLE_NAMES:
            problems[f"Ca_{ab}_hysteresis"] = (
                "hysteresis needs visits on both a heating and a cooling branch; the data has only "
                + ", ".join(sorted(have[b] for b in branches))
                # an outside probe: the angles of a heating-only path were 33 u from the mid-line, status ok,
                # and nothing said that they are the branch's
                + (f" (the angles are then those of the {one[0]} branch, not the mid-line between the branches: "
                   "they differ from it by the hysteresis h, which these data cannot measure"
                   # an outside probe: none at 20 degC, heating at 60 degC, h 2-6 arcsec: the angle tempcos
                   # 3.4-5.6 u off (h/40 degC), status ok, and this note spoke of the angles only
                   + (f"; and the visits of no branch lie at other temperatures than the {one[0]} branch's, so the "
                      "angle tempcos take up h over the temperatures between them as well" if 0.0 in branches else "")
                   + ")" if len(one) == 1 else ""))
    if np.ptp(T) < TEMPERATURE_SPAN_MIN_C:
        for e, fmt, names in (("angle_tempco", "Ca_{}_tempco", ANGLE_NAMES), ("scale_tempco", "K_{}_tempco", AXES),
                              ("bias_tempco", "S_{}_tempco", AXES)):
            if e in eff:
                for x in names:
                    problems[fmt.format(x)] = f"a temperature coefficient needs more than one temperature; the data spans {np.ptp(T):.2f} degC"
    if "thermal_lag" in eff and np.max(np.abs(campaign.temperature_rate())) < 1e-5:
        problems["thermal_lag"] = "thermal lag needs temperatures that change during the visits; the rates are ~0"
    if "bias_drift" in eff and np.ptp(campaign.time_s) <= 0:
        for a in AXES:
            problems[f"S_{a}_drift"] = "bias drift needs visits at different times"
    if eff & {"scale_cubic", "cross_coupling", "g_dependent_misalignment"}:
        problems.update(_oblique_problems(campaign, eff))
    return problems


#: a nominal gravity component counts as oblique (neither along nor across an axis) within these
OBLIQUE_RANGE = (0.1, 0.9)


def _oblique_problems(campaign: Campaign, eff) -> dict[str, str]:
    """The third-order and cross-axis terms (models/effects/cross_axis.py) need poses with gravity
    between sensing axes: where every pose has one axis along gravity, ``a^3 = a`` (K3 is the scale
    factor) and the products ``a_a a_b`` vanish (docs/model.md, "Nonlinear and cross-axis terms")."""
    g = np.abs(nominal_gravity(campaign.axis1_deg, campaign.axis2_deg).reshape(-1, 3))
    lo, hi = OBLIQUE_RANGE
    oblique = (g > lo) & (g < hi)
    hint = ("every pose of this plan has each sensing axis along or across gravity; it needs oblique poses "
            "(gravity between two sensing axes: triadcal plan --positions 18|24)")
    out = {}
    for i, a in enumerate(AXES):
        if "scale_cubic" in eff and not oblique[:, i].any():
            out[f"K3_{a}"] = f"a^3 = a along or across gravity, so K3 is part of the scale factor: {hint}"
    for ab in ANGLE_NAMES:
        i, j = AXES.index(ab[0]), AXES.index(ab[1])
        both = (oblique[:, i] & oblique[:, j]).any()
        if "cross_coupling" in eff and not both:
            out[f"Kc_{ab}"] = f"the product a_{ab[0]} a_{ab[1]} vanishes on every pose: {hint}"
        if "g_dependent_misalignment" in eff and not both:
            out[f"Ca_{ab}_g2"] = f"the product a_{ab[0]}^2 a_{ab[1]} vanishes on every pose: {hint}"
    return out


def null_space_problems(J: np.ndarray, names: Sequence[str], rtol: float = 1e-8) -> dict[str, str]:
    """Parameters in the numerical null space of the (column-scaled) Jacobian."""
    norms = np.linalg.norm(J, axis=0)
    out = {}
    for i in np.flatnonzero(norms == 0):
        out[names[i]] = "the data carry no information on it (zero sensitivity)"
    ok = norms > 0
    Js = J[:, ok] / norms[ok]
    _, s, vt = np.linalg.svd(Js, full_matrices=Js.shape[0] < Js.shape[1])
    s = np.concatenate([s, np.zeros(vt.shape[0] - len(s))])   # fewer observations than parameters
    sub = [n for n, k in zip(names, ok) if k]
    for k in np.flatnonzero(s < rtol * s[0]):
        v = vt[k]
        involved = [sub[i] for i in np.flatnonzero(np.abs(v) > 0.2)]
        for n in involved:
            out[n] = ("not separable from " + ", ".join(m for m in involved if m != n)
                      + " with this plan (a combination of them has no effect on the outputs)")
    return out


@dataclass
class Solution:
    x: np.ndarray
    cost: float
    iterations: int
    converged: bool
    r: np.ndarray
    J: np.ndarray
    weights: np.ndarray = field(default=None)


def scaled_covariance(J: np.ndarray) -> np.ndarray:
    """``(J^T J)^-1`` computed on unit-norm columns (parameters differ by 10 orders of
    magnitude), pseudo-inverse for a rank-deficient ``J``; NaN where ``J`` is not finite (a solver
    that ended where the model is not defined: the answer gates then refuse the result)."""
    if not np.all(np.isfinite(J)):
        return np.full((J.shape[1], J.shape[1]), np.nan)
    d = np.linalg.norm(J, axis=0)
    d[d == 0] = 1.0
    return np.linalg.pinv((J / d).T @ (J / d)) / np.outer(d, d)


def levenberg_marquardt(problem: JointProblem, x0: np.ndarray, loss: str = "l2", max_iter: int = 100,
                        nu: float = 4.0) -> Solution:
    """Minimise the (robust) sum of squared normalised residuals with exact Jacobians.

    A trial point where the residuals or the Jacobian are not finite (a model evaluated
    outside its domain, e.g. a row of Ca that is no longer a unit vector) is rejected like a
    step that does not descend; a start that is not finite stops at once, not converged."""
    x = np.array(x0, float)
    r, J = problem.residuals_and_jacobian(x)
    wts = robust_weights(r, loss, nu)
    lam = 1e-3
    converged = False
    it = 0
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J))):
        return Solution(x, float("nan"), 0, False, r, J, wts)
    for it in range(1, max_iter + 1):
        sw = np.sqrt(wts)
        Jw, rw = J * sw[:, None], r * sw
        cost = float(rw @ rw)
        d = np.linalg.norm(Jw, axis=0)
        d[d == 0] = 1.0
        A = Jw / d
        g = A.T @ rw
        H = A.T @ A
        improved = False
        while lam < 1e12:
            try:
                step = -np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), g) / d
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            x_new = x + step
            r_new, J_new = problem.residuals_and_jacobian(x_new)
            w_new = robust_weights(r_new, loss, nu)
            cost_new = float(np.sum(w_new * r_new * r_new))
            if np.isfinite(cost_new) and np.all(np.isfinite(J_new)) and cost_new <= cost * (1 + 1e-15):
                improved = True
                break
            lam *= 10.0
        if not improved:
            # no descent direction left: at the optimum within rounding, if the gradient vanishes
            converged = bool(np.linalg.norm(g) <= 1e-6 * max(1.0, np.sqrt(cost)))
            break
        # done when the cost no longer falls and every step is tiny against its uncertainty
        x, r, J, wts = x_new, r_new, J_new, w_new
        lam = max(lam / 10.0, 1e-12)
        if cost - cost_new <= 1e-9 * max(cost_new, 1.0):
            u = np.sqrt(np.abs(np.diag(np.linalg.pinv(H)))) / d
            if np.all(np.abs(step) <= 1e-4 * u) and np.all(u > 0):
                converged = True
                break
    return Solution(x, float(np.sum(wts * r * r)), it, converged, r, J, wts)


def fit_joint(campaign: Campaign, effects: Sequence[str] = DEFAULT_EFFECTS, *,
              reference_temperature_C: float = 20.0, loss: str = "l2", nu: float = 4.0,
              fix: Optional[dict] = None, unidentifiable: str = "fix", max_iter: int = 100,
              return_problem: bool = False, gates: GateConfig = DEFAULT_CONFIG,
              bench_errors: Optional[BenchErrors] = None, systematics: Sequence = (), output_map=None,
              whitening=None, noise_per_output: bool = False, output_variances=None):
    """Fit the joint model to a campaign (``triadcal fit --method joint``).

    ``whitening``: correlated output noise (``flicker_noise``): an
    :class:`~triadcal.estimation.flicker_noise.AxisWhitening` applied to the normalised residuals and
    the Jacobian, so the fit is generalised least squares on the full covariance.

    ``noise_per_output``: with the noise not in the data (no sd_*, u_w or Q), estimate one noise
    level per output (:func:`per_output_scale`), not one for the three. ``triadcal fit`` and
    ``sample`` do (``api.fit``); the default is off because the forms and the diagnosis compare the
    chi^2 of several fits, which must share their weights (a scale per fit makes every chi^2 its
    dof); ``output_variances`` gives them one (:func:`given_output_scale`, ``api.fit``).

    ``output_map``: a map of the model outputs applied after eq. 1 (:class:`JointProblem`; the
    quantisation of a digital output, :func:`triadcal.estimation.quantisation_form.fit_quantisation`).

    ``systematics``: the lab's systematic errors
    (:func:`triadcal.uncertainty.typeb.systematic_sources`), propagated to every parameter by
    its linearised sensitivity (:mod:`triadcal.uncertainty.typeb`): ``u`` is then the combined
    standard uncertainty and each parameter carries its budget, U, k and dof_eff.

    ``bench_errors``: the lab's random bench errors, added to the output noise as variance
    components (:func:`with_bench_errors`); without them the uncertainties are Type A only
    (output noise) and the result says so.

    ``unidentifiable``: ``"fix"`` holds parameters the data cannot determine at their
    nominal value (0) and says so in the notes (they are then absent from the result),
    ``"refuse"`` raises :class:`IdentifiabilityError`. ``fix`` holds chosen parameters at
    given values. ``loss``: ``l2``, ``huber`` (c = 1.345) or ``student_t`` (``nu`` dof).
    The answer gates (:mod:`triadcal.estimation.gates`, thresholds in ``gates``) set the
    status: ``ok`` only when every gate passes. A campaign with no more observations than
    free parameters is refused (:class:`IdentifiabilityError`).
    """
    if loss not in LOSSES:
        raise InputError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")
    units = campaign.units
    if len(units) != 1 or len(set(campaign.state.tolist())) != 1:
        raise InputError(f"{campaign.source or 'campaign'}: a fit takes one unit in one mechanical state; "
                         f"found units {units} and states {sorted(set(campaign.state.tolist()))} "
                         "(select one, e.g. with Campaign.select)")
    stuck_outputs(campaign)
    axes_not_turned(campaign)           # design.py: every axis turned through gravity
    reference_temperature_C, moved = single_temperature_reference(campaign, reference_temperature_C)
    model = Model(effects, reference_temperature_C)
    own_noise = noise_of(campaign)
    noise = with_bench_errors(campaign, model, own_noise, bench_errors)
    notes = [moved] if moved else []
    from .noise_model import noise_notes

    notes.extend(noise_notes(campaign, own_noise))
    sensor_note, sensor_gate, sensor_temps = sensor_temperatures(campaign)
    if sensor_note:
        notes.append(sensor_note)
    if campaign.gravity_note():
        notes.append(campaign.gravity_note())
    if campaign.thermometer_note():
        notes.append(campaign.thermometer_note())
    if bench_errors is not None:
        whitening = _bench_whitening(campaign, model, noise, bench_errors, whitening, notes)
    notes += lab_scope_notes(campaign, bench_errors, systematics)
    problems = identifiability_problems(campaign, model)
    fixed = dict(fix or {})
    start = start_values(campaign, model)
    # the null space is probed always, with the terms the design cannot determine held
    probe = JointProblem(campaign, model, noise.sigma, {**fixed, **{k: model.spec[k].nominal for k in problems}},
                         output_map=output_map)
    # probe at a generic point: effect terms at their typical size, so that terms whose
    # sensitivity is a product (e.g. thermal lag x tempco) are not judged at zero
    x0 = np.array([start[n] if model.spec[n].effect == "core" else model.spec[n].typical
                   for n in probe.names])
    _, J0 = probe.residuals_and_jacobian(x0)
    if np.all(np.isfinite(J0)):
        problems.update(null_space_problems(J0, probe.names))
    if problems:
        if unidentifiable == "refuse":
            by_reason: dict = {}
            for k, v in problems.items():         # one reason once, with every parameter it concerns
                by_reason.setdefault(v, []).append(k)
            raise IdentifiabilityError(
                f"{campaign.source or 'campaign'}: the data cannot determine "
                + "; ".join(f"{', '.join(ks)}: {v}" for v, ks in by_reason.items()))
        for k, v in problems.items():
            fixed.setdefault(k, model.spec[k].nominal)
            notes.append(f"{k} not estimated, held at {model.spec[k].nominal:g} {model.spec[k].unit}: {v}")
    n_free = len(model.names) - len(set(fixed) | set(problems))
    if n_free < 1:
        # an outside probe's one- and two-row files: every parameter held, then "cannot reshape array"
        raise IdentifiabilityError(
            f"{campaign.source or 'campaign'}: {campaign.n_visits} visit(s) determine none of the model's parameters "
            f"({len(problems)} of {len(model.names)} not identifiable: "
            f"{', '.join([n for n in model.names if n in problems][:6])}"
            f"{' ...' if len(problems) > 6 else ''}); a calibration needs every IMU axis up and down at least")
    if 3 * campaign.n_visits <= n_free:
        raise IdentifiabilityError(
            f"{campaign.source or 'campaign'}: {3 * campaign.n_visits} observations ({campaign.n_visits} visits x 3 axes) "
            f"for {n_free} free parameters of the model {', '.join(model.effect_names) or '(core only)'}: "
            "a fit needs more observations than parameters (use a full campaign, or fewer --effects)")
    q_per_output = None
    if output_variances is not None and not noise.known and loss == "l2" and whitening is None:
        noise, q_per_output = given_output_scale(noise, output_variances)
    if probe.fixed == fixed and probe.sigma is noise.sigma:
        problem = probe         # the same problem: built from the same campaign, model, weights and fixed terms
    else:
        problem = JointProblem(campaign, model, noise.sigma, fixed, output_map=output_map)
    if whitening is not None:
        from .whitening import WhitenedProblem

        problem = WhitenedProblem(problem, whitening)
    x0 = np.array([start[n] for n in problem.names])
    t0 = time.perf_counter()
    r0 = problem.residuals(x0)
    cost_start = float(np.sum(robust_weights(r0, loss, nu) * r0 * r0))
    sol = levenberg_marquardt(problem, x0, loss=loss, nu=nu, max_iter=max_iter)
    if not noise.known and loss == "l2" and whitening is None and noise_per_output and q_per_output is None:
        sol, noise, q_per_output = per_output_scale(problem, sol, noise, max_iter)
        if q_per_output is not None:                 # the start's cost with the weights the answer has
            cost_start = float(np.sum(problem.residuals(x0) ** 2))
    robust_s2 = None
    if not noise.known and loss != "l2" and whitening is None:     # a robust loss needs a scale
        sol, noise, robust_s2 = robust_scale(problem, sol, noise, loss, nu, max_iter)
        if robust_s2 is not None:
            r0 = problem.residuals(x0)
            cost_start = float(np.sum(robust_weights(r0, loss, nu) * r0 * r0))
    solve_seconds = time.perf_counter() - t0

    n_obs, n_par = sol.r.size, len(problem.names)
    dof = n_obs - n_par
    chi2 = float(np.sum(sol.r ** 2))
    chi2_dof = chi2 / dof if dof > 0 else float("nan")
    sw = np.sqrt(sol.weights)
    cov = scaled_covariance(sol.J * sw[:, None])
    if loss != "l2":
        # robust loss: the M-estimator's sandwich covariance in Huber's form (Huber 1981, eq. 7.6.10
        # without its small-sample factor), (J^T J)^-1 * [sum psi^2 / (n - p)] / mean(psi')^2 -- the
        # spread the estimate has whatever the residuals' distribution, not the one the loss assumes
        psi = sol.weights * sol.r
        slope = float(np.mean(robust_psi_slope(sol.r, loss, nu)))
        cov = scaled_covariance(sol.J) * (float(np.sum(psi ** 2)) / max(dof, 1)) / max(slope, 1e-3) ** 2
    elif not noise.known:
        cov = cov * chi2_dof
    u_a = np.sqrt(np.diag(cov))
    units_of = {n: parameter_unit(model, n, campaign.output_unit) for n in problem.names}
    # the dof of an estimated noise level: the residuals', or an output's (per_output_scale)
    noise_dof = None if noise.known else (float(dof) if q_per_output is None else float(dof) / 3.0)
    budgets, tb = {}, None
    t_u = None
    if systematics:
        from ..uncertainty.typeb import propagate, propagated_sources, reference_temperature_u

        t_u = reference_temperature_u(systematics, problem.index)      # one temperature: stated with T0
        systematics = propagated_sources(systematics, problem.index)   # bench_nonorth measured: its own u
    lab_gate = None
    if systematics:
        from ..uncertainty.typeb import NonFiniteSensitivities

        p_hat = model.to_internal({**{n: float(v) for n, v in zip(problem.names, sol.x)}, **fixed})
        try:
            tb = propagate(systematics, model, p_hat, campaign.covariates(), campaign.gravity_g, campaign.w,
                           sol.J, noise.sigma, problem.names, campaign.output_unit, sol.weights, u_a,
                           whiten=None if whitening is None else whitening.apply)
        except NonFiniteSensitivities as e:
            # an answer where the model is degenerate (swapped or inverted columns: an outside probe got this
            # error alone, exit 1, where the fit without --lab names the wiring): the gates judge the answer,
            # and this one refuses it whatever they say
            lab_gate = GateOutcome("lab_sensitivities", False, "model_mismatch",
                                   f"{e}: the lab's systematic errors cannot be propagated at this answer, so its "
                                   "uncertainty budget is incomplete")
            systematics = None
    if systematics:
        type_a = "fit: output noise" + (", bench's random errors per visit" if bench_errors is not None else "")
        dof_a = noise_dof
        budgets = {n: tb.budget(n, units_of[n], float(ua), dof_a, type_a) for n, ua in zip(problem.names, u_a)}
        cov_a, cov = cov, cov + tb.covariance()
    elif noise_dof is not None and noise_dof > 0 and loss == "l2":      # U = k u on the noise's dof
        from ..uncertainty.typeb import type_a_budgets

        budgets = type_a_budgets(problem.names, units_of, u_a, noise_dof, "fit: output noise (estimated from the residuals)")
    u = np.sqrt(np.diag(cov))
    corr = cov / np.outer(u, u)

    from ..uncertainty.typeb import parameter_fields

    params = {n: ParameterValue(float(v), float(s), units_of[n],
                                parameter_fields(budgets[n]) if n in budgets else {})
              for n, v, s in zip(problem.names, sol.x, u)}
    if "tilt_x" in problem.index and "tilt_y" in problem.index:
        params.update(tilt_polar_values(sol.x, cov, problem.index, *((tb, cov_a, dof_a, type_a) if tb is not None else ())))
    if not sol.converged:
        notes.append(f"Levenberg-Marquardt stopped after {sol.iterations} iterations without meeting its "
                     "convergence test (cost still falling or a non-vanishing gradient); the values are not an optimum")
    p_gap = float(stats.chi2.sf(chi2, dof)) if noise.known and dof > 0 else None
    robust_gof, robust_gates = None, []
    if loss != "l2":            # the inliers' fit and what the down-weighted outliers still do
        robust_gof, robust_gates = robust_check(sol, u, problem.names, loss, nu, gates.gof_p_min, noise.known, campaign,
                                                notes, by_visit=whitening is None)
        p_gap = p_gap if robust_gof is None else robust_gof["p_value"]
    if noise.known and dof > 0 and loss == "l2":
        note = overstated_noise_note(chi2, dof, noise.description, bench_errors is not None)
        if note:
            notes.append(note)
    fit = {"chi2_dof": chi2_dof, "n_obs": n_obs, "n_params": n_par, "iterations": sol.iterations,
           "loss": loss if loss != "student_t" else f"student_t(nu={nu:g})",
           "noise": noise.description, "noise_known": noise.known,
           "gap_p_value": p_gap, "build_seconds": problem.build_seconds, "solve_seconds": solve_seconds,
           "bench_errors": (None if bench_errors is None else
                            {"sigma_position_arcsec": bench_errors.sigma_position_arcsec,
                             "sigma_wobble_arcsec": bench_errors.sigma_wobble_arcsec,
                             "source": bench_errors.source, "in_u": True}),
           "systematic_errors": ([{"source": t.source, "key": t.key, "u": t.u, "unit": t.unit,
                                   "distribution": t.distribution, "equipment": t.equipment} for t in systematics]
                                 if systematics else None)}
    if robust_gof is not None:
        fit["robust_goodness_of_fit"] = {k: v for k, v in robust_gof.items() if k not in ("what", "ratio")}
    if "thermal_lag" in model.effect_names:
        fit["temperature_rate"] = campaign.temperature_rate_method()
    if sensor_temps is not None:                     # one temperature: where each row's values are
        fit["sensor_temperatures_C"] = sensor_temps
    if t_u is not None:
        from ..uncertainty.typeb import reference_temperature_note

        fit["reference_temperature_u_C"] = t_u
        notes.append(reference_temperature_note(t_u))
    if not noise.known:
        fit["noise_dof"] = noise_dof
        # weights were 1/sqrt(tau): the residual variance estimates the white-noise intensity Q
        fit["Q_estimate"] = chi2_dof if dof > 0 else None
        if q_per_output is not None and dof > 0:
            fit["Q_estimate_per_output"] = [float(q * chi2_dof) for q in q_per_output]
            fit["Q_estimate"] = float(np.mean(fit["Q_estimate_per_output"]))
        if robust_s2 is not None:               # the robust scale, not the outliers' chi2
            fit["Q_estimate_per_output"] = [float(q) for q in robust_s2]
            fit["Q_estimate"] = float(np.mean(robust_s2))
        fit["Q_unit"] = f"{campaign.output_unit}^2 s"
    T = campaign.t
    result = CalibrationResult(
        unit=units[0], method="joint", parameters=params,
        effects=tuple(model.effect_names), reference_temperature_C=reference_temperature_C,
        temperature_range_C=(float(T.min()), float(T.max())), fit=fit,
        correlation_names=problem.names, correlation=corr, notes=notes,
        extra={"fixed": {k: {"value": v, "unit": model.spec[k].unit} for k, v in fixed.items()},
               "unidentifiable": dict(problems),
               "output_unit": campaign.output_unit, "local_g_m_s2": campaign.local_g_m_s2,
               **campaign.provenance()})
    resid = (sol.r.reshape(-1, 3) * noise.sigma)
    from .structure import one_branch_hysteresis_hint, residual_checks

    structure, extra_gates = residual_checks(result, campaign, noise, sol, dof, chi2_dof, model.reference_temperature_C,
                                             u, problem.names, plain=loss == "l2" and whitening is None,
                                             p_min=gates.gof_p_min)
    if "thermal_lag" in result.parameters and loss == "l2" and whitening is None:
        from .thermal_lag_form import rate_form_play

        extra_gates = extra_gates + rate_form_play(result, campaign, problem, sol, sw, u,
                                                   1.0 if noise.known else float(np.sqrt(max(chi2_dof, 0.0))))
    structure = structure if robust_gof is None else robust_gof      # a robust loss: the inliers' chi2
    extra_gates = extra_gates + robust_gates
    if noise.known and loss == "l2" and whitening is None:
        # the pooled chi2 lets declared noise levels wrong in opposite directions cancel (output_levels.py)
        from .output_levels import output_levels, per_output_gate

        extra_gates = extra_gates + [per_output_gate(output_levels(sol.r, sol.J * sw[:, None]), gates.gof_p_min,
                                                     gates.gof_ratio_max)]
    evidence = FitEvidence(
        converged=sol.converged, cost_start=cost_start, cost_final=sol.cost, jacobian=sol.J * sw[:, None],
        free_names=problem.names, residual_rms=float(np.sqrt(np.mean(resid ** 2))),
        data_rms=float(np.sqrt(np.mean(campaign.w ** 2))), chi2=chi2, dof=dof, noise_known=noise.known,
        gof_p_value=None if structure is None else structure["p_value"],
        gof_ratio=None if structure is None else structure["ratio"],
        gof_what="" if structure is None else structure["what"],
        extra=extra_gates + ([sensor_gate] if sensor_gate is not None else []) + ([lab_gate] if lab_gate else []))
    apply_gates(result, evidence, config=gates)
    if result.status in ("unphysical_scale", "angle_out_of_range", "model_mismatch", "not_converged"):
        G = nominal_gravity(campaign.axis1_deg, campaign.axis2_deg) * campaign.gravity_g
        result.notes.extend(f"hint: {h}" for h in orientation_hints(campaign.w, G))
    result.notes.extend(one_branch_hysteresis_hint(result, problems, campaign))
    if return_problem:
        return result, problem, sol
    return result


def parameter_unit(model: Model, name: str, output_unit: str) -> str:
    """Reporting unit of ``name``: a scale factor is in g per output unit (``g/mV`` for a file in
    mV), every other unit as the model's parameter table says."""
    unit = model.spec[name].unit
    return scale_factor_unit(output_unit) if unit == "g/V" else unit
