"""The lab's systematic errors (Type B) propagated into every parameter of a classical result.

The classical estimate (eq. 2-3 per setpoint and the linear thermal correction,
:func:`triadcal.estimation.classical.fit_classical`) is a fixed function ``theta(W)`` of the
visits' mean outputs. A systematic error ``delta`` of the lab (an encoder zero, the bench axes'
non-orthogonality, the unit's rotation in its fixture, the local g, a thermometer's offset, a
voltmeter's gain and offset: :func:`triadcal.uncertainty.typeb.systematic_sources`) changes the
data by ``dW = F delta`` (``F`` from the model at the classical values,
:func:`triadcal.uncertainty.typeb.data_change`), so the estimate moves by (JCGM 100 5.1.3)::

    c = d(theta)/d(delta) = (theta(W + F h) - theta(W - F h)) / (2 h)

the classical estimate itself re-run on the changed data: its own sensitivity, whatever the
pairing cancels (a bench tilt, an axis-2 encoder zero on the half-turn pairs) and whatever it
does not -- not the sensitivity of 1 the certificate's eq. 4-7 budget assumed for every
rotation. ``u_c^2 = u_A^2 + sum_s (c_s u_s)^2`` and the covariance ``C_A + sum_s c_s c_s^T u_s^2``
(the correlations include the shared errors), as for the joint fit
(:func:`triadcal.uncertainty.typeb.propagate`). docs/classical.md, "The lab's systematic errors".
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Callable, Mapping, Sequence

import numpy as np

from ..errors import InputError
from ..models.campaign import Campaign
from ..models.model import Model
from .result import CalibrationResult, ParameterValue

#: the Type A row of a classical parameter's budget
TYPE_A_SOURCE = "classical estimate (eq. 2-3): per-visit errors (output noise, bench positioning and wobble)"


def _type_a_dof(result: CalibrationResult, name: str) -> float | None:
    """Degrees of freedom of a classical parameter's Type A u: those of its line over the setpoints
    when the Birge ratio widened it (chi2/dof > 1 of its line), else those of the residual noise of
    its accelerometer (row ``a`` of Ca, K_a, S_a); None (infinite) when the noise was declared."""
    fit = result.fit
    base = name[:-len("_tempco")] if name.endswith("_tempco") else name
    axis = "xyz".index(base.split("_")[1][0])
    ratio = (fit.get("chi2_dof_by_parameter") or {}).get(base)      # None with one setpoint (no line)
    if isinstance(ratio, (int, float)) and ratio > 1.0:
        n_sp = int(fit.get("n_setpoints") or 0)
        k = 2 if result.effects else 1
        return float(n_sp - k) if n_sp > k else None
    dof = fit.get("residual_dof")
    if fit.get("noise_source") == "residuals" and isinstance(dof, (list, tuple)) and len(dof) == 3:
        return float(dof[axis])
    return None


def with_type_a_budgets(result: CalibrationResult) -> CalibrationResult:
    """``result`` with every parameter's Type A budget (``U``, ``k``, ``dof_eff``): k from Student's t on
    the dof of :func:`_type_a_dof`. A line whose scatter the Birge ratio took into u holds that scatter
    on n_setpoints - 2 dof, not on the residuals' many (an outside probe: one setpoint block relabelled
    by 40 degC, every line widened up to x159 on 3 dof, "U (k=2.09)" for all, Ca_yx 3.8 u off with
    status ok); where the lab's systematic errors are propagated (:func:`propagate_classical`) the same
    rows are the budgets' Type A."""
    from ..uncertainty.typeb import TypeB, parameter_fields

    names = tuple(result.parameters)
    tb = TypeB([], names, np.zeros((0, len(names))))
    params = {n: ParameterValue(pv.value, pv.u, pv.unit,
                                parameter_fields(tb.budget(n, pv.unit, float(pv.u), _type_a_dof(result, n), TYPE_A_SOURCE)))
              for n, pv in result.parameters.items()}
    return replace(result, parameters=params)


def bench_at_one_setpoint(result: CalibrationResult, campaign: Campaign, sigma_position_arcsec,
                          sigma_wobble_arcsec) -> CalibrationResult:
    """At one setpoint (no line over temperature, ``result.effects`` empty) the angles' u from the
    pooled residuals does not see the bench's geometry: a positioning error moves an output fully
    where its axis is horizontal and not at all where it is vertical, and the angle takes the first
    kind of visits only, while the residual variance pools both (an outside probe: five angles with
    RMS error/u 1.24-1.48, coverage 0.91 at sigma_1 = 5"). With the lab's sigma_1 and sigma_2 the
    angles' Type A u become ``sqrt(u_res^2 + sd_bench^2)``, ``sd_bench`` the classical estimate's
    own SD from the bench errors on the campaign's plan (:func:`classical_angle_sd`, eq. 2-4):
    conservative by the bench part the residuals already hold. Over several setpoints the line's
    Birge ratio sees that scatter, and nothing is added."""
    from ..uncertainty.classical_sd import classical_angle_sd

    s1, s2 = float(sigma_position_arcsec or 0.0), float(sigma_wobble_arcsec or 0.0)
    if result.effects or not (s1 > 0 or s2 > 0):
        return result
    plan = dict(zip(campaign.position.tolist(), zip(campaign.axis1_deg.tolist(), campaign.axis2_deg.tolist())))
    sd = classical_angle_sd(plan, Q_V2s=0.0, tau_s=1.0, sigma_position_arcsec=s1, sigma_wobble_arcsec=s2)
    names = tuple(result.parameters)
    cov = result.covariance(list(names))
    params = dict(result.parameters)
    for n, extra in sd.items():
        if n in params:
            pv = params[n]
            params[n] = ParameterValue(pv.value, math.sqrt(pv.u ** 2 + extra ** 2), pv.unit, dict(pv.uncertainty))
            j = names.index(n)
            cov[j, j] += extra ** 2
    u = np.sqrt(np.diag(cov))
    safe = np.where(u > 0, u, 1.0)
    out = replace(result, parameters=params, correlation_names=names, correlation=cov / np.outer(safe, safe),
                  fit={**result.fit, "bench_errors": {"sigma_position_arcsec": s1, "sigma_wobble_arcsec": s2,
                                                      "source": "lab file", "in_u": True,
                                                      "how": "one setpoint: added to the angles' u through the "
                                                             "classical estimate of the plan"}},
                  notes=list(result.notes) + [
                      f"one setpoint: the lab's bench errors (sigma_1 {s1:g}, sigma_2 {s2:g} arcsec) are added to the "
                      "angles' u through the classical estimate of the plan (the residuals do not see their geometry)"])
    return out


def propagate_classical(result: CalibrationResult, campaign: Campaign, sources: Sequence,
                        refit: Callable[[Campaign], Mapping[str, float]]) -> CalibrationResult:
    """``result`` with every parameter's ``u`` the combined standard uncertainty and its budget
    (``uncertainty``: ``u_type_a``, ``U``, ``k``, ``budget`` ... as the joint fit writes them), the
    correlation including the systematic terms and ``fit["systematic_errors"]``. ``refit`` is the
    classical estimate's values (``fit_classical(..., values_only=True)``) with the settings ``result``
    was made with, applied to a changed campaign.
    No sources: ``result`` unchanged."""
    from ..uncertainty.typeb import (KINDS, TypeB, data_change, parameter_fields, propagated_sources,
                                     reference_temperature_note, reference_temperature_u)

    names = tuple(result.parameters)
    t_u = reference_temperature_u(sources, names)
    sources = propagated_sources(sources, names)       # one temperature: the thermometers go with T0
    if not sources:
        if t_u is not None:
            result.fit["reference_temperature_u_C"] = t_u
            result.notes.append(reference_temperature_note(t_u))
        return result
    model = Model(tuple(result.effects), result.reference_temperature_C)
    p = model.to_internal({n: v.value for n, v in result.parameters.items()})
    cov, w = campaign.covariates(), np.asarray(campaign.w, float)
    unit = str(result.extra.get("output_unit") or campaign.output_unit)
    u_a = np.array([result.parameters[n].u for n in names])
    c = np.zeros((len(sources), len(names)))
    for i, s in enumerate(sources):
        F = data_change(s, model, p, cov, campaign.gravity_g, w, unit)
        h = KINDS[s.kind][1]
        hi, lo = refit(replace(campaign, w=w + h * F)), refit(replace(campaign, w=w - h * F))
        missing = [n for n in names if n not in hi or n not in lo]
        if missing:
            raise InputError(f"the classical estimate on the data changed by {s.source} ({h:g} {s.unit}) lost "
                             f"{', '.join(missing)}: its sensitivity to that error cannot be formed")
        c[i] = [(hi[n] - lo[n]) / (2.0 * h) for n in names]
    if not np.all(np.isfinite(c)):
        raise InputError("the sensitivities of the classical parameters to the lab's systematic errors are not finite")
    # a source that does not reach a parameter leaves c at the rounding level of the difference
    # quotient of two re-runs (1e-8 arcsec per arcsec): below 1e-6 of the parameter's Type A u, 0
    u_s = np.array([s.u for s in sources])[:, None]
    c[np.abs(c) * u_s < 1e-6 * u_a[None, :]] = 0.0
    tb = TypeB(list(sources), names, c)
    cov_a = result.covariance(list(names))
    cov_all = cov_a + tb.covariance()
    u = np.sqrt(np.diag(cov_all))
    params = {}
    for j, n in enumerate(names):
        pv = result.parameters[n]
        b = tb.budget(n, pv.unit, float(pv.u), _type_a_dof(result, n), TYPE_A_SOURCE)
        params[n] = ParameterValue(pv.value, float(u[j]), pv.unit, parameter_fields(b))
    safe = np.where(u > 0, u, 1.0)
    out = replace(result, parameters=params, correlation_names=names, correlation=cov_all / np.outer(safe, safe),
                  fit={**result.fit, "systematic_errors": [
                      {"source": s.source, "key": s.key, "u": s.u, "unit": s.unit, "distribution": s.distribution,
                       "equipment": s.equipment} for s in sources],
                       **({"reference_temperature_u_C": t_u} if t_u is not None else {})},
                  notes=list(result.notes))
    if t_u is not None:
        out.notes.append(reference_temperature_note(t_u))
    out.notes.append("the lab file's systematic errors are propagated into every parameter's u and U by the "
                     "classical estimate itself, re-run on the data each error changes (central difference; "
                     "docs/classical.md)")
    if not math.isfinite(float(np.max(u))):
        raise InputError("a classical parameter's combined uncertainty is not finite")
    return out
