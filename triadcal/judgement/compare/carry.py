"""A calibration over a temperature range carried to another temperature by its own measured
temperature terms, for ``compare`` against a calibration at one temperature (docs/compare.md,
"A range calibration against one at one temperature").

A unit calibrated over -40...85 degC and checked after a shock at 23 degC: the check has no
tempcos, its rows hold at its sensors' temperatures t_a (:func:`row_temperatures_C`), and the range
calibration's values hold at its reference temperature T0. Its own model carries each row there::

    q_a(t_a) = q_a(T0) + [term_q(theta; t_a) - term_q(theta; T0)]      q = K_a, S_a, Ca_ab

with ``term`` the thermal terms of the model it was fitted with (:meth:`.Model.terms`: linear,
quadratic and cubic tempcos, the lag's element temperature at rest), and its covariance by the
law of propagation (GUM 5.2, eq. 13) from the result's full covariance, the tempcos' uncertainty
and their correlation with the values included: ``C' = G C G^T``, ``G`` the Jacobian of the carried
values with respect to the result's parameters (central differences of one u, exact for terms
linear in each parameter, as these are). The result's own temperature range bounds the carry: its
tempcos are not extrapolated.

A unit with a thermal hysteresis loop is, at one temperature, somewhere on it: the check does not
say on which branch. The carried value is the loop's mid-line, and the drift of each angle holds a
bias within +-h (the loop's half-width at t_a, the model's branch +-1 against 0), a bound the rule
takes at its worst (:func:`.rule.decide`), as the unmeasured tempcos of :func:`.pair.tempco_bound`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping

import numpy as np

from ...errors import InputError, TriadcalError
from ...estimation.result import CalibrationResult, ParameterValue
from ...models.model import Covariates, Model
from ...models.sensor import ANGLE_NAMES, AXES

#: the row quantities a temperature carries: K_a, S_a and the angles Ca_ab of row a (held at t_a)
ROW_QUANTITIES = tuple([f"K_{a}" for a in AXES] + [f"S_{a}" for a in AXES] + [f"Ca_{ab}" for ab in ANGLE_NAMES])


def _row_of(name: str) -> str:
    """The accelerometer whose temperature row quantity ``name`` follows."""
    return name.split("_", 1)[1][0]


def _terms(model: Model, p: Mapping, temps_C: Mapping[str, float], branch: float) -> dict:
    """K_a, S_a and Ca_ab (internal units) of ``model`` at rest at the temperatures ``temps_C`` per
    accelerometer and the hysteresis ``branch`` (0 mid-line, +-1 the loop's branches)."""
    K, S, angles = model.terms(p, Covariates.at_rest(tuple(float(temps_C[a]) for a in AXES), branch))
    out = {f"K_{a}": float(K[i]) for i, a in enumerate(AXES)}
    out.update({f"S_{a}": float(S[i]) for i, a in enumerate(AXES)})
    out.update({f"Ca_{ab}": float(angles[ab]) for ab in ANGLE_NAMES})
    return out


def _carried_type_b(result: CalibrationResult, names, g: np.ndarray, unit: str) -> list:
    """The Type B rows of a carried quantity ``q = sum_j g_j theta_j`` (linearised): per source, the
    sensitivity ``sum_j g_j c_j`` of the parameters' rows (GUM 5.1.3), so that ``compare
    --shared-equipment`` still subtracts what both calibrations share."""
    rows: dict = {}
    for gj, n in zip(g, names):
        if gj == 0.0:
            continue
        for r in result.parameters[n].uncertainty.get("budget") or []:
            if not isinstance(r, dict) or r.get("type") != "B" or not isinstance(r.get("sensitivity"), (int, float)):
                continue
            row = rows.setdefault(str(r.get("source")), {k: r.get(k) for k in ("source", "type", "distribution", "u",
                                                                                "unit", "key", "dof")})
            row["sensitivity"] = row.get("sensitivity", 0.0) + float(gj) * float(r["sensitivity"])
    out = []
    for row in rows.values():
        if isinstance(row.get("u"), (int, float)):
            row["sensitivity_unit"] = f"{unit}/{row['unit']}"
            row["contribution"] = abs(row["sensitivity"]) * float(row["u"])
            out.append(row)
    return out


def carry_rows(result: CalibrationResult, targets_C: Mapping[str, float], what: str = "the calibration"):
    """``(carried, bounds, carried_names)``: ``result`` with every row quantity that its model makes
    depend on temperature carried from its reference temperature to ``targets_C[a]`` (degC) of its
    row, the correlation matrix and u propagated; ``bounds`` the hysteresis loop's half-width at the
    target per row quantity (its unit; absent where the model has no loop); ``carried_names`` the
    names moved. Raises InputError when a target lies outside the result's temperature range."""
    T0 = float(result.reference_temperature_C)
    lo_hi = result.temperature_range_C
    if lo_hi is None:
        raise InputError(f"{what} has no temperature range: its tempcos cannot be carried to another temperature")
    lo, hi = float(lo_hi[0]), float(lo_hi[1])
    outside = {a: t for a, t in targets_C.items() if not lo - 1e-9 <= t <= hi + 1e-9}
    if outside:
        raise InputError(f"{what} was calibrated over {lo:.2f}...{hi:.2f} degC; the other calibration's rows are at "
                         + ", ".join(f"{a} {t:.2f}" for a, t in outside.items())
                         + " degC, outside it: its tempcos are not extrapolated (calibrate over a range that holds "
                         "that temperature, or at one temperature both times)")
    try:
        model = Model(tuple(result.effects), T0)
    except (KeyError, ValueError, TriadcalError) as e:
        raise InputError(f"{what}: its effects {list(result.effects)} are not a model this version can carry to "
                         f"another temperature ({e})") from None
    fixed = {n: float(v["value"] if isinstance(v, Mapping) else v) for n, v in (result.extra.get("fixed") or {}).items()
             if n in model.spec and not isinstance(v, (str, bool))}
    names = [n for n in result.parameters if n in model.spec]
    theta = np.array([result.parameters[n].value for n in names])
    scale = {n: model.spec[n].to_internal for n in ROW_QUANTITIES}
    rows = [n for n in ROW_QUANTITIES if n in result.parameters]
    ref = {a: T0 for a in AXES}

    def carried(x, branch=0.0):
        p = model.to_internal({**fixed, **dict(zip(names, x))})
        at, at0 = _terms(model, p, targets_C, branch), _terms(model, p, ref, 0.0)
        v = dict(zip(names, x))
        return np.array([v[n] + (at[n] - at0[n]) / scale[n] for n in rows])

    G = np.zeros((len(rows), len(names)))
    for j, n in enumerate(names):
        step = result.parameters[n].u if result.parameters[n].u > 0 else 1e-6 * max(abs(theta[j]), 1.0)
        e = np.zeros(len(names))
        e[j] = step
        G[:, j] = (carried(theta + e) - carried(theta - e)) / (2.0 * step)
    own = {n: names.index(n) for n in rows}
    # carried: a row quantity that depends on any parameter but itself (a tempco of its family)
    moved = [n for i, n in enumerate(rows)
             if np.any(np.abs(np.delete(G[i], own[n])) > 0.0) or abs(G[i, own[n]] - 1.0) > 1e-8]
    values = carried(theta)
    loop = {n: float(max(abs(a - m), abs(b - m))) for n, a, b, m in zip(rows, carried(theta, 1.0), carried(theta, -1.0),
                                                                          values)}
    bounds = {n: loop[n] for n in rows if loop[n] > 0.0}
    if not moved:
        return result, bounds, ()
    # full covariance: identity rows for what is not moved, G's rows for what is
    all_names = list(result.parameters)
    C = result.covariance(all_names)
    Gf = np.eye(len(all_names))
    for i, n in enumerate(rows):
        if n in moved:
            k = all_names.index(n)
            Gf[k, :] = 0.0
            for j, m in enumerate(names):
                Gf[k, all_names.index(m)] = G[i, j]
    Cn = Gf @ C @ Gf.T
    u = np.sqrt(np.clip(np.diag(Cn), 0.0, None))
    if not np.all(np.isfinite(u)):
        raise InputError(f"{what}: the carried values' uncertainties are not finite")
    params = dict(result.parameters)
    for i, n in enumerate(rows):
        if n in moved:
            k = all_names.index(n)
            budget = _carried_type_b(result, names, G[i], result.parameters[n].unit)
            params[n] = ParameterValue(float(values[i]), float(u[k]), result.parameters[n].unit,
                                       {"budget": budget} if budget else {})
    safe = np.where(u > 0, u, 1.0)
    out = replace(result, parameters=params, correlation_names=tuple(all_names), correlation=Cn / np.outer(safe, safe),
                  extra={**result.extra, "rows_carried_to_C": {a: float(targets_C[a]) for a in AXES}},
                  notes=list(result.notes))
    return out, bounds, tuple(moved)
