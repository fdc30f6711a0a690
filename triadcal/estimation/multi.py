"""Several units on one bench in one campaign, fitted jointly (``triadcal fit --joint-units``).

The units share the bench: its tilt (``tilt_x``, ``tilt_y``) and, when in the model, the
non-orthogonality of its axes (``bench_nonorth``) are one set of parameters for all of them;
each unit keeps its own scale factors, biases, angles (which absorb its own fixture rotation,
docs/lab.md) and thermal terms. The stacked least squares

    min  sum_u || (W_u - f(theta_bench, theta_u)) / sigma_u ||^2

is solved by the same Levenberg-Marquardt as one unit (:func:`triadcal.estimation.joint.levenberg_marquardt`)
from the units' separate fits, with the same exact Jacobians (each unit's compiled
:class:`~triadcal.estimation.joint.JointProblem`, its columns placed into the stacked ones).
Each unit's result carries the shared bench terms with the joint covariance, is checked by the
answer gates on its own residuals and Jacobian block, and says with which units it shared them.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
from scipy import stats

from ..errors import InputError
from ..models.campaign import Campaign
from ..models import effects
from ..models.effects import DEFAULT_EFFECTS
from ..models.model import Model
from .gates import DEFAULT_CONFIG, FitEvidence, GateConfig, apply_gates
from .joint import (BenchErrors, JointProblem, Solution, fit_joint, levenberg_marquardt, noise_of, parameter_unit,
                    scaled_covariance, with_bench_errors)
from .tilt_polar import tilt_polar_values
from .result import CalibrationResult, ParameterValue

#: parameters of the bench, shared by every unit mounted on it
BENCH_PARAMETERS = effects.BENCH_PARAMETERS


class StackedProblem:
    """The residuals of several units' problems as one vector, in a global parameter vector
    ``[shared..., unit 1's own..., unit 2's own..., ...]``."""

    def __init__(self, problems: Sequence[JointProblem], shared: Sequence[str]):
        self.problems = list(problems)
        self.shared = tuple(shared)
        names = list(self.shared)
        self.maps = []
        for k, p in enumerate(self.problems):
            cols = []
            for n in p.names:
                if n in self.shared:
                    cols.append(self.shared.index(n))
                else:
                    cols.append(len(names))
                    names.append(f"{k}:{n}")
            self.maps.append(np.array(cols, int))
        self.names = tuple(names)

    def unit_x(self, x: np.ndarray, k: int) -> np.ndarray:
        return x[self.maps[k]]

    def residuals_and_jacobian(self, x: np.ndarray):
        rs, Js = [], []
        for k, p in enumerate(self.problems):
            r, J = p.residuals_and_jacobian(self.unit_x(x, k))
            G = np.zeros((len(r), len(self.names)))
            G[:, self.maps[k]] = J
            rs.append(r)
            Js.append(G)
        return np.concatenate(rs), np.vstack(Js)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return np.concatenate([p.residuals(self.unit_x(x, k)) for k, p in enumerate(self.problems)])


def _stacked_whiten(problems):
    """The stacked fit's whitening of normalised residuals: each unit's own (GLS on oblique poses,
    :func:`~triadcal.estimation.joint.fit_joint`) on its rows; None when no unit's fit whitens."""
    ws = [getattr(p, "whitening", None) for p in problems]
    if all(w is None for w in ws):
        return None
    rows = [3 * p.n for p in problems]

    def apply(x):
        out, start = [], 0
        for w, n in zip(ws, rows):
            part = x[start:start + n]
            out.append(part if w is None else w.apply(part))
            start += n
        return np.concatenate(out)
    return apply


def _stacked_type_b(sources, model, problems, stacked, sol, subs, noises, units):
    """The lab's systematic errors through the stacked fit: ``c = -(J^T J)^-1 J^T (F/sigma)`` with
    ``J`` the stacked Jacobian and ``F`` the stacked data change: for a source of the bench or the
    gravity the same error in every unit's rows (one source), for a source of the fixture, the
    thermometers or the voltmeter one source per unit, non-zero in that unit's rows only."""
    from dataclasses import replace as _replace

    from ..uncertainty.typeb import TypeB, data_change, sensitivities

    sigma = np.vstack([nz.sigma for nz in noises])
    changes, out_sources = [], []
    p_units = []
    for k, prob in enumerate(problems):
        xk = dict(zip(prob.names, stacked.unit_x(sol.x, k)))
        fixed = dict(prob.fixed)
        p_units.append(model.to_internal({**xk, **fixed}))

    def unit_change(src, k):
        c = subs[k]
        return data_change(src, model, p_units[k], c.covariates(), c.gravity_g, c.w, c.output_unit)

    rows = [p.n for p in problems]
    for src in sources:
        if src.equipment in ("bench", "gravity"):
            changes.append(np.vstack([unit_change(src, k) for k in range(len(problems))]))
            out_sources.append(src)
            continue
        for k, u in enumerate(units):
            F = np.zeros((sum(rows), 3))
            start = sum(rows[:k])
            F[start:start + rows[k]] = unit_change(src, k)
            changes.append(F)
            out_sources.append(_replace(src, source=f"{src.source} ({u})"))
    c = np.array([sensitivities(sol.J, sigma, F, sol.weights, _stacked_whiten(problems)) for F in changes])
    return TypeB(out_sources, stacked.names, c)


def fit_joint_units(campaign: Campaign, effects: Sequence[str] = DEFAULT_EFFECTS, *,
                    reference_temperature_C: float = 20.0, bench_errors: Optional[BenchErrors] = None,
                    systematics: Sequence = (), gates: GateConfig = DEFAULT_CONFIG,
                    max_iter: int = 100) -> dict:
    """Fit every unit of a one-state campaign jointly with shared bench terms (see the module).
    Returns ``{unit: CalibrationResult}`` (method ``joint``). ``systematics``: the lab's
    systematic errors, propagated through the stacked fit (:func:`_stacked_type_b`): the bench's
    and the gravity's are one error for every unit, the fixture's, the thermometers' and the
    voltmeter's one per unit."""
    units = campaign.units
    if len(set(campaign.state.tolist())) != 1:
        raise InputError(f"{campaign.source or 'campaign'}: a joint fit of several units takes one mechanical state; "
                         f"found {sorted(set(campaign.state.tolist()))} (select one with --state)")
    if len(units) < 2:
        raise InputError(f"{campaign.source or 'campaign'}: one unit ({units[0]}): nothing to share; use fit without "
                         "--joint-units")
    model = Model(effects, reference_temperature_C)
    shared = [n for n in BENCH_PARAMETERS if n in model.names]
    if not shared:
        raise InputError("the model has no bench terms to share (add bench_tilt to the effects)")
    separate, problems, x_units, noises, subs = {}, [], [], [], []
    for u in units:
        sub = campaign.select(campaign.unit == u)
        r, prob, sol = fit_joint(sub, effects, reference_temperature_C=reference_temperature_C,
                                 bench_errors=bench_errors, return_problem=True, gates=gates, max_iter=max_iter)
        separate[u] = r
        held = [n for n in shared if n not in prob.names]
        if held:
            raise InputError(f"{u}: the data cannot determine the bench terms {held} on their own; a shared fit needs "
                             "each unit to see them")
        problems.append(prob)
        x_units.append(dict(zip(prob.names, sol.x)))
        noises.append(with_bench_errors(sub, model, noise_of(sub), bench_errors))
        subs.append(sub)
    stacked = StackedProblem(problems, shared)
    x0 = np.zeros(len(stacked.names))
    for j, n in enumerate(shared):
        x0[j] = float(np.mean([xu[n] for xu in x_units]))
    for k, xu in enumerate(x_units):
        for n, col in zip(problems[k].names, stacked.maps[k]):
            if n not in shared:
                x0[col] = xu[n]
    sol: Solution = levenberg_marquardt(stacked, x0, max_iter=max_iter)
    n_obs, n_par = sol.r.size, len(stacked.names)
    dof = n_obs - n_par
    chi2 = float(np.sum(sol.r ** 2))
    known = all(nz.known for nz in noises)
    cov = scaled_covariance(sol.J)
    if not known:
        cov = cov * (chi2 / dof)
    cov_a = cov
    tb = None
    if "bench_nonorth" in shared:
        systematics = [t for t in systematics if t.kind != "axes_nonorthogonality"]
    if systematics:
        tb = _stacked_type_b(systematics, model, problems, stacked, sol, subs, noises, units)
        cov = cov + tb.covariance()
    results = {}
    others = ", ".join(units)
    for k, u in enumerate(units):
        idx = stacked.maps[k]
        names = problems[k].names
        xk = sol.x[idx]
        Ck = cov[np.ix_(idx, idx)]
        uk = np.sqrt(np.diag(Ck))
        units_of = {n: parameter_unit(model, n, subs[k].output_unit) for n in names}
        fields, derived = {}, ()
        if tb is not None:
            from ..uncertainty.typeb import TypeB, parameter_fields

            ua = np.sqrt(np.diag(cov_a[np.ix_(idx, idx)]))
            ck = tb.c[:, idx].copy()
            us = np.array([t.u for t in tb.sources])[:, None]
            ck[np.abs(ck) * us < 1e-9 * ua[None, :]] = 0.0      # rounding of the difference quotient
            reach = np.any(ck != 0.0, axis=1)
            own = TypeB([t for t, keep in zip(tb.sources, reach) if keep], names, ck[reach])
            type_a = "fit: output noise" + (", bench's random errors per visit" if bench_errors is not None else "")
            fields = {n: parameter_fields(own.budget(n, units_of[n], float(a), None if known else float(dof), type_a))
                      for n, a in zip(names, ua)}
            derived = (own, cov_a[np.ix_(idx, idx)], None if known else float(dof), type_a)
        params = {n: ParameterValue(float(v), float(s), units_of[n], fields.get(n, {}))
                  for n, v, s in zip(names, xk, uk)}
        index = {n: i for i, n in enumerate(names)}
        if "tilt_x" in index and "tilt_y" in index:
            params.update(tilt_polar_values(xk, Ck, index, *derived))
        rk = problems[k].residuals(xk)
        nk = rk.size
        chi2k = float(np.sum(rk ** 2))
        dofk = nk - (len(names) - len(shared) * (len(units) - 1) / len(units))
        base = separate[u]
        fit = dict(base.fit)
        fit.update({"chi2_dof": chi2k / dofk if dofk > 0 else float("nan"), "n_obs": nk, "n_params": len(names),
                    "iterations": sol.iterations, "gap_p_value": float(stats.chi2.sf(chi2k, dofk)) if known else None,
                    "joint_units": {"units": list(units), "shared": list(shared), "n_obs": n_obs, "n_params": n_par,
                                    "chi2_dof": chi2 / dof if dof > 0 else None}})
        corr = Ck / np.outer(uk, uk)
        notes = [n for n in base.notes] + [
            f"fitted jointly with the units on the same bench ({others}): the bench terms {', '.join(shared)} are "
            "one set of parameters for all of them (their u is the joint fit's)"]
        res = CalibrationResult(unit=u, method="joint", parameters=params, effects=base.effects,
                                reference_temperature_C=reference_temperature_C,
                                temperature_range_C=base.temperature_range_C, fit=fit, correlation_names=names,
                                correlation=corr, notes=notes, extra=dict(base.extra))
        Jk = sol.J[sum(p.n * 3 for p in problems[:k]): sum(p.n * 3 for p in problems[:k + 1])][:, idx]
        ev = FitEvidence(converged=sol.converged, n_obs=nk, n_free=len(names), jacobian=Jk, free_names=names,
                         chi2=chi2k, dof=int(round(dofk)), noise_known=known,
                         residual_rms=float(np.sqrt(np.mean((rk.reshape(-1, 3) * noises[k].sigma) ** 2))),
                         data_rms=float(np.sqrt(np.mean(subs[k].w ** 2))))
        apply_gates(res, ev, config=gates)
        results[u] = res
    return results
