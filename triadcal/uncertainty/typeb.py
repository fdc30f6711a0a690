"""The lab's systematic errors (Type B) propagated to every fitted parameter.

A systematic error of the lab is the same in every visit of a campaign: an encoder zero, the
non-orthogonality of the bench's axes, the unit's rotation in its fixture, the local g, a
thermometer's offset, a voltmeter's gain and offset. The fit assumes each is zero. If the
true setup deviates by ``delta``, the data differ by ``dW = F delta`` (``F`` from the
model, :meth:`triadcal.models.model.Model.predict` with the error put in) and the
least-squares estimate moves by the linearised sensitivity (JCGM 100 5.1.3)::

    c = d(theta_hat)/d(delta) = -(J^T J)^-1 J^T (F / sigma)

with ``J`` the fit's Jacobian of its normalised residuals ``(W - f)/sigma``. The combined
standard uncertainty of each parameter is then ``u_c^2 = u_A^2 + sum_s (c_s u_s)^2`` and the
covariance ``C_A + sum_s c_s c_s^T u_s^2`` (so the correlations of the parameters include the
systematic terms). What a constant rotation does is left to the algebra: a fixture rotation or
an encoder zero of axis 1 goes one to one into a pair of angles (sensitivity +-1); an encoder
zero of axis 2 is a tilt of gravity in the base frame and goes into the bench tilt when it is
fitted; a g error goes into K one to one (ppm per ppm). docs/lab.md lists every source.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Optional, Sequence

import numpy as np

from ..errors import InputError
from ..models.units import ARCSEC
from .budget import Budget, BudgetComponent


@dataclass(frozen=True)
class SystematicSource:
    """One Type B input: its name on the budget, the lab-file key it comes from, its standard
    uncertainty ``u`` in ``unit``, its distribution, the equipment it belongs to and how it
    acts on the data (``kind``; ``axis`` for the per-axis ones)."""

    source: str
    key: str
    u: float
    unit: str
    kind: str
    axis: int = 0
    distribution: str = "normal"
    equipment: str = ""


#: kind -> (unit of u, step of the central difference in that unit)
KINDS = {"encoder_zero_1": ("arcsec", 10.0), "encoder_zero_2": ("arcsec", 10.0),
         "axes_nonorthogonality": ("arcsec", 10.0), "fixture": ("arcsec", 10.0),
         "gravity": ("ppm", 10.0), "thermometer": ("degC", 0.1),
         "voltmeter_gain": ("ppm", 10.0), "voltmeter_offset": ("V", 1e-5),
         "bias_drift": ("ug/h", 1.0)}

#: the equipment whose systematic errors are the same in two calibrations on one bench with no
#: adjustment between them (``compare --shared-bench``)
BENCH_EQUIPMENT = ("bench", "gravity")


def systematic_sources(lab, output_unit: str = "V") -> list:
    """The Type B sources a lab file declares (:class:`triadcal.io.lab.LabConfig`), one per
    independent error: an encoder zero per axis, a fixture rotation about each IMU axis, a
    voltmeter gain and offset per axis (one meter per axis; a scanner's common meter gives the
    same u of every parameter). A voltmeter on outputs that are not volts is refused."""
    if lab is None:
        return []
    dist = getattr(lab, "distributions", {}) or {}
    out = []

    def add(source, key, u, kind, equipment, axis=0):
        if u is not None and u > 0:
            out.append(SystematicSource(source, key, float(u), KINDS[kind][0], kind, axis,
                                        dist.get(equipment, "normal"), equipment))

    add("bench axes non-orthogonality", "[bench] axes_nonorthogonality_u_arcsec",
        lab.axes_nonorthogonality_u_arcsec, "axes_nonorthogonality", "bench")
    for i in (1, 2):
        add(f"encoder zero, axis {i}", "[bench] encoder_zero_u_arcsec", lab.encoder_zero_u_arcsec,
            f"encoder_zero_{i}", "bench")
    for i, a in enumerate("xyz"):
        add(f"fixture mounting, about {a}", "[fixture] mounting_u_arcsec", lab.mounting_u_arcsec, "fixture",
            "fixture", i)
    add("local gravity", "[gravity] u_ppm", getattr(lab, "local_g_u_ppm", None), "gravity", "gravity")
    add("thermometers", "[thermometers] u_C", lab.temperature_uncertainty_C, "thermometer", "thermometers")
    gain, offset = getattr(lab, "voltmeter_gain_u_ppm", None), getattr(lab, "voltmeter_offset_u_V", None)
    if (gain or offset) and output_unit not in VOLTS:
        raise InputError(f"{lab.source or 'lab file'}: [voltmeter] states a gain or offset uncertainty, but the "
                         f"outputs are in {output_unit!r}, not volts: a voltmeter reads an analog unit")
    for i, a in enumerate("xyz"):
        add(f"voltmeter gain, axis {a}", "[voltmeter] gain_u_ppm", gain, "voltmeter_gain", "voltmeter", i)
        add(f"voltmeter offset, axis {a}", "[voltmeter] offset_u_V", offset, "voltmeter_offset", "voltmeter", i)
    for i, a in enumerate("xyz"):
        add(f"bias drift of the unit during the campaign, axis {a}", "[item] bias_drift_u_ug_per_h",
            getattr(lab, "bias_drift_u_ug_per_h", None), "bias_drift", "item", i)
    return out


def lab_scope_notes(campaign, bench_errors, systematics) -> list:
    """What a joint fit's u leaves out of the lab's own errors, in words: no bench errors and no
    systematic errors (Type A only); no systematic errors; or systematic errors without the local
    gravity's u. The last: the data's ``# local_g_m_s2`` carries no u (bench CSV v1 has no key for
    one), so with a lab file that declares no ``[gravity]`` the fit took it as exact -- an outside
    probe's site value uncertain by 20 ppm, fitted with a lab file of bench and fixture errors: K
    held in 75 of 150 with U ~ 9 ppm, and the certificate was issued; with ``[gravity] u_ppm = 20``
    144 of 150."""
    if bench_errors is None and not systematics:
        # an independent bench's encoder zeros of 30 arcsec: Ca_xz and Ca_zx 66-101 u off, on the 12 positions
        # and on an oblique plan alike (docs/lab.md: axis 1's zero is a rotation of the unit about its y axis)
        return ["uncertainties are Type A only: the bench's own errors are not in them, neither the random ones "
                "(positioning, wobble) nor the systematic ones -- an encoder zero of axis 1 moves Ca_xz and Ca_zx "
                "one to one (1 arcsec of it: 1 arcsec of each), the fixture's rotation, the axes' non-orthogonality "
                "and the local g too; give them with --lab LAB.toml ([bench] sigma_position_arcsec, "
                "sigma_wobble_arcsec, encoder_zero_u_arcsec, ...; docs/lab.md)"]
    if not systematics:
        return ["no systematic errors of the lab declared (encoder zeros, non-orthogonality, fixture, g): "
                "u holds the output noise and the bench's random errors only"]
    if not any(s.kind == "gravity" for s in systematics):
        return [f"the lab file declares systematic errors but not the local gravity's: the fit took g = "
                f"{campaign.local_g_m_s2:.7g} m/s^2 ({'stated in the data' if campaign.local_g_stated else 'assumed'}) "
                "as exact, and K takes it one to one (a site value from a gravity model is uncertain by 10-50 ppm); "
                "state it in the lab file ([gravity] local_g_m_s2, u_ppm) for its row in the budget -- a "
                "certificate is refused without it"]
    return []


#: output units a voltmeter can read, and volts per unit
VOLTS = {"V": 1.0, "mV": 1e-3, "uV": 1e-6}


def data_change(source: SystematicSource, model, p: dict, cov, gravity_g: float, w: np.ndarray,
                output_unit: str = "V") -> np.ndarray:
    """``F``: the change of each visit's outputs (n, 3, in the output unit) per unit of the
    source (arcsec, ppm, degC, V) when the true setup deviates from the assumed one by it, by a
    central difference of :meth:`Model.predict` (the error put into its covariates)."""
    unit, h = KINDS[source.kind]
    k = source.kind
    if k == "voltmeter_gain":
        # the meter reads W (1 + g): the data change by W g
        F = np.zeros_like(w)
        F[:, source.axis] = w[:, source.axis] * 1e-6
        return F
    if k == "voltmeter_offset":
        F = np.zeros_like(w)
        F[:, source.axis] = 1.0 / VOLTS[output_unit]
        return F
    if k == "bias_drift":
        return _drift_change(source, model, p, cov, gravity_g, w, h)

    def at(step):
        c, g = cov, gravity_g
        if k == "encoder_zero_1":
            c = replace(cov, axis1_error=cov.axis1_error + step * ARCSEC)
        elif k == "encoder_zero_2":
            c = replace(cov, axis2_error=cov.axis2_error + step * ARCSEC)
        elif k == "axes_nonorthogonality":
            c = replace(cov, wobble=cov.wobble + step * ARCSEC)
        elif k == "fixture":
            rot = [0.0, 0.0, 0.0]
            rot[source.axis] = step * ARCSEC
            c = replace(cov, fixture=tuple(rot))
        elif k == "gravity":
            g = gravity_g * (1.0 + step * 1e-6)
        elif k == "thermometer":
            # the sensors are truly warmer by step than the thermometers read
            c = replace(cov, temp=tuple(t + step for t in cov.temp))
        return np.stack([np.asarray(v, float) * np.ones(len(w)) for v in model.predict(p, c, g)], axis=1)

    return (at(h) - at(-h)) / (2.0 * h)


def _drift_change(source: SystematicSource, model, p: dict, cov, gravity_g: float, w: np.ndarray, h: float):
    """``F`` of the unit's bias drift on output ``source.axis``, per ug/h: the model's own
    ``bias_drift`` term (models/effects/bias_drift.py, ``S(t) = S + d t``) with its clock's origin
    at the campaign's middle, ``t -> t - (t_first + t_last)/2``. A model without the drift holds one
    bias for the campaign; for a drifting unit that is its bias near the middle, so the values hold
    there and the budget's row is what an unknown drift of u ug/h moves them by from it (the tempcos
    most, when the temperatures were visited in order: estimation/structure.py,
    ``drift_confounding``). A campaign whose clock does not move has no drift to fear: F = 0."""
    from ..models.model import Model

    t = np.asarray(cov.time_s, float) * np.ones(len(w))
    if not np.ptp(t) > 0:
        return np.zeros_like(w)
    names = tuple(e.name for e in model.effects)
    drift = model if "bias_drift" in names else Model(names + ("bias_drift",), model.reference_temperature_C)
    c = replace(cov, time_s=t - 0.5 * (t.min() + t.max()))
    name = f"S_{'xyz'[source.axis]}_drift"
    base = {n: p.get(n, drift.spec[n].nominal * drift.spec[n].to_internal) for n in drift.names}

    def at(step):
        q = dict(base)
        q[name] = base[name] + step * drift.spec[name].to_internal
        return np.stack([np.asarray(v, float) * np.ones(len(w)) for v in drift.predict(q, c, gravity_g)], axis=1)

    return (at(h) - at(-h)) / (2.0 * h)


def sensitivities(jacobian: np.ndarray, sigma: np.ndarray, F: np.ndarray, weights: Optional[np.ndarray] = None,
                  whiten=None) -> np.ndarray:
    """``c = -(J^T J)^-1 J^T (F/sigma)`` for the fit's residual Jacobian ``J`` (3n x p, of
    ``(W - f)/sigma``, robust weights applied by the caller or given as ``weights``): the
    shift of each free parameter (reporting units) per unit of the source. ``whiten``: the fit's
    whitening of the normalised residuals (GLS: the bench's errors on oblique poses, flicker), when
    ``J`` is the whitened Jacobian; ``F/sigma`` is whitened the same way."""
    from ..estimation.joint import scaled_covariance

    rhs = (F / sigma).reshape(-1)
    if whiten is not None:
        rhs = whiten(rhs)
    J = jacobian
    if weights is not None:
        sw = np.sqrt(weights)
        J, rhs = J * sw[:, None], rhs * sw
    return -scaled_covariance(J) @ (J.T @ rhs)


@dataclass
class TypeB:
    """The Type B part of a fit: per source, the sensitivity of every free parameter."""

    sources: list
    names: tuple
    c: np.ndarray          # (n_sources, n_names)

    def covariance(self) -> np.ndarray:
        """``sum_s c_s c_s^T u_s^2`` in reporting units."""
        u = np.array([s.u for s in self.sources])
        cu = self.c * u[:, None]
        return cu.T @ cu

    def budget(self, name: str, unit: str, u_a: float, dof_a: Optional[float], type_a_source: str) -> Budget:
        """The budget of one parameter: the fit's own (Type A) row and one row per source."""
        j = self.names.index(name)
        rows = [BudgetComponent(type_a_source, float(u_a), float(u_a), unit=unit, sensitivity=1.0,
                                sensitivity_unit="1", type="A", dof=dof_a,
                                basis="the fit's standard uncertainty")]
        for s, c in zip(self.sources, self.c[:, j]):
            per = f"({s.unit})" if "/" in s.unit else s.unit          # ug/degC per (ug/h)
            rows.append(BudgetComponent(s.source, float(abs(c) * s.u), s.u, unit=s.unit, sensitivity=float(c),
                                        sensitivity_unit=f"{unit}/{per}", basis=s.key,
                                        distribution=s.distribution, type="B"))
        return Budget(name, rows, unit)


class NonFiniteSensitivities(InputError):
    """The lab's systematic errors cannot be propagated at this answer: a sensitivity is not finite."""


def propagate(sources: Sequence[SystematicSource], model, p: dict, cov, gravity_g: float, w: np.ndarray,
              jacobian: np.ndarray, sigma: np.ndarray, names: Sequence[str], output_unit: str = "V",
              weights: Optional[np.ndarray] = None, type_a_u: Optional[np.ndarray] = None, whiten=None) -> TypeB:
    """Sensitivities of the free parameters ``names`` to every source (see the module); ``whiten``
    as :func:`sensitivities`."""
    with np.errstate(invalid="ignore", over="ignore"):      # a degenerate answer: said below, not warned
        c = np.array([sensitivities(jacobian, sigma, data_change(s, model, p, cov, gravity_g, w, output_unit), weights,
                                    whiten) for s in sources]).reshape(len(sources), len(names))
    if not np.all(np.isfinite(c)):
        bad = sorted({names[j] for j in np.flatnonzero(~np.all(np.isfinite(c), axis=0))})
        raise NonFiniteSensitivities("the sensitivities of the parameters to the lab's systematic errors are not "
                                     "finite (" + ", ".join(bad[:6]) + (", ..." if len(bad) > 6 else "") + ")")
    # a source that does not reach a parameter gives c at the rounding level of the difference
    # quotient (1e-18 g/V per arcsec for K and a fixture rotation): such c are exactly 0 in the
    # algebra of eq. 1; below 1e-9 of the parameter's Type A u per unit of the source, set 0
    if type_a_u is not None:
        u = np.array([s.u for s in sources])[:, None]
        c[np.abs(c) * u < 1e-9 * np.asarray(type_a_u)[None, :]] = 0.0
    return TypeB(list(sources), tuple(names), c)


def parameter_fields(b: Budget) -> dict:
    """What the results JSON adds to a parameter with a budget (docs/results-json.md)."""
    nu = b.dof_eff
    return {"u_type_a": next((c.contribution for c in b.components if c.type == "A"), None),
            "U": b.expanded_U, "k": b.effective_k, "coverage_probability": b.coverage_probability,
            "dof_eff": None if math.isinf(nu) else nu, "U_method": b.method,
            "budget": [{"source": c.source, "type": c.type, "distribution": c.distribution, "u": c.u,
                        "unit": c.unit, "sensitivity": c.sensitivity, "sensitivity_unit": c.sensitivity_unit,
                        "contribution": c.contribution, "dof": c.dof, "key": c.basis}
                       for c in b.components]}


def type_a_budgets(names: Sequence[str], units: dict, u_a, dof_a: float, type_a_source: str) -> dict:
    """name -> the :class:`Budget` of its Type A row alone, with ``dof_a`` degrees of freedom: a fit whose
    noise is estimated from its residuals, without a lab file, so that ``U = k u`` has k from Student's t
    on those dof (JCGM 100 G.3; the results JSON's ``U``, ``k``, ``dof_eff``). An outside probe: three
    noise levels on 3.3 dof each, value +- 1.96 u held 0.83 of the truths with status ok."""
    own = TypeB([], tuple(names), np.zeros((0, len(names))))
    return {n: own.budget(n, units[n], float(u), dof_a, type_a_source) for n, u in zip(names, u_a)}


def with_type_a(name: str, unit: str, u_a: float, dof_a: Optional[float], type_a_source: str, rows: list
                ) -> Budget:
    """A budget whose Type A row is ``u_a`` and whose Type B rows are those of another budget of
    the same parameter (``rows``, the results JSON's ``budget``): how the posterior's standard
    deviation is combined with the systematic errors propagated through the least squares."""
    comps = [BudgetComponent(type_a_source, float(u_a), float(u_a), unit=unit, type="A", dof=dof_a,
                             basis="the fit's standard uncertainty")]
    for r in rows:
        if r.get("type") == "B":
            comps.append(BudgetComponent(r["source"], r["contribution"], r["u"], unit=r["unit"],
                                         sensitivity=r["sensitivity"], sensitivity_unit=r["sensitivity_unit"],
                                         basis=r.get("key", ""), distribution=r.get("distribution", "normal"),
                                         type="B"))
    return Budget(name, comps, unit)


def effects_with_lab(effects: Sequence[str], sources: Sequence[SystematicSource]) -> tuple:
    """The model's effects with ``bench_nonorthogonality`` added when the lab declares a
    non-orthogonality of its bench axes: it turns with axis 2, so a plan with several axis-2
    angles measures it (its Type B row is then replaced by the fit's estimate); linearised as a
    Type B input it would leave its trace in the residuals, not in u. Returns ``(effects,
    note)`` (note "" when nothing was added)."""
    effects = tuple(effects)
    if any(s.kind == "axes_nonorthogonality" for s in sources) and "bench_nonorthogonality" not in effects:
        return effects + ("bench_nonorthogonality",), (
            "bench_nonorthogonality added to the model: the lab declares a non-orthogonality of its bench axes "
            "([bench] axes_nonorthogonality_u_arcsec), which the data measure (it turns with axis 2)")
    return effects, ""


def temperature_dependent(parameter_names) -> bool:
    """Whether a fit has a parameter through which a thermometer's offset reaches the values (a
    tempco of any order, a thermal lag). Without one (a campaign at one temperature) the values are
    the unit's at the temperature the thermometers read, and their u is that temperature's own
    (``reference_temperature_u_C``), not a Type B row of sensitivity 0."""
    return any("_tempco" in n or n.startswith("thermal_lag") for n in parameter_names)


def propagated_sources(sources: Sequence[SystematicSource], parameter_names) -> list:
    """The sources propagated as Type B into a fit's budgets: all of ``sources`` but the bench
    axes' non-orthogonality when the fit estimates it (``bench_nonorth`` among ``parameter_names``,
    :func:`effects_with_lab`): then its row is the estimate's own u; but the unit's bias drift of an
    output whose drift the fit estimates (``S_a_drift``); and but the thermometers when
    no parameter depends on temperature (:func:`temperature_dependent`: their u is then stated
    with the reference temperature). Used by the joint and classical fits and by the certificate's
    check that a result was fitted with the lab file it is issued under, so that they agree by
    construction."""
    names = set(parameter_names)
    out = list(sources)
    if "bench_nonorth" in names:
        out = [s for s in out if s.kind != "axes_nonorthogonality"]
    drifts = {n for n in names if n.startswith("S_") and n.endswith("_drift")}
    if drifts:      # the fit measures the drift of these outputs: its u is the estimate's own
        out = [s for s in out if not (s.kind == "bias_drift" and f"S_{'xyz'[s.axis]}_drift" in drifts)]
    if not temperature_dependent(names):
        out = [s for s in out if s.kind != "thermometer"]
    return out


def reference_temperature_note(u_C: float) -> str:
    """The note of a result whose values hold at the thermometers' reading (one temperature)."""
    return (f"one temperature: the values are the unit's at the temperature the thermometers read, whose "
            f"uncertainty (u = {u_C:g} degC, the lab's [thermometers]) is stated with the reference temperature; "
            "no tempco is determined to carry it into the values (a user at another temperature needs one)")


def reference_temperature_u(sources: Sequence[SystematicSource], parameter_names) -> Optional[float]:
    """u of the reference temperature (degC) when the values are the unit's at the thermometers'
    reading (no temperature-dependent parameter) and the lab states the thermometers' u; else None."""
    if temperature_dependent(set(parameter_names)):
        return None
    return next((s.u for s in sources if s.kind == "thermometer"), None)


def budget_of(name: str, p) -> Optional[Budget]:
    """The :class:`Budget` of a parameter read from a result (``ParameterValue.uncertainty``,
    the results JSON's rows), or None when it has none (Type A only)."""
    rows = p.uncertainty.get("budget") if getattr(p, "uncertainty", None) else None
    if not rows:
        return None
    comps = [BudgetComponent(r["source"], r.get("contribution"), r.get("u"), unit=r.get("unit", p.unit),
                             sensitivity=r.get("sensitivity"), sensitivity_unit=r.get("sensitivity_unit", "1"),
                             basis=r.get("key", ""), distribution=r.get("distribution", "normal"),
                             type=r.get("type", "B"), dof=r.get("dof"))
             for r in rows]
    return Budget(name, comps, p.unit)


def type_b_covariance(values: Sequence) -> np.ndarray:
    """``sum_s c_s c_s^T u_s^2`` of parameters (``ParameterValue`` with budgets, in order) from
    their Type B rows: the same source (by name) in two budgets is one error."""
    n = len(values)
    by_source = {}
    for i, p in enumerate(values):
        for r in (p.uncertainty.get("budget") or []) if getattr(p, "uncertainty", None) else []:
            if r.get("type") == "B" and r.get("sensitivity") is not None and r.get("u") is not None:
                by_source.setdefault(r["source"], [float(r["u"]), np.zeros(n)])[1][i] = float(r["sensitivity"])
    C = np.zeros((n, n))
    for u, c in by_source.values():
        C += np.outer(c, c) * u * u
    return C


def draw(rng: np.random.Generator, distribution: str, u: float, size: int) -> np.ndarray:
    """Draws of an error of standard deviation ``u`` from its distribution (JCGM 101 6.4)."""
    if distribution == "rectangular":
        return rng.uniform(-math.sqrt(3.0) * u, math.sqrt(3.0) * u, size)
    if distribution == "arcsine":
        return math.sqrt(2.0) * u * np.sin(2.0 * math.pi * rng.random(size))
    if distribution == "two-point":
        return u * rng.choice((-1.0, 1.0), size)
    return rng.normal(0.0, u, size)


def with_type_b_draws(draws: np.ndarray, values: Sequence, seed: int = 0) -> np.ndarray:
    """Posterior draws (M x n, the Type A part) plus the lab's systematic errors drawn from their
    distributions through the budget rows' signed sensitivities (one draw of each source shared
    by every parameter): the JCGM 101 propagation whose quantiles are the combined intervals."""
    n = len(values)
    sources = {}
    for i, p in enumerate(values):
        for r in (p.uncertainty.get("budget") or []) if getattr(p, "uncertainty", None) else []:
            if r.get("type") == "B" and r.get("sensitivity") and r.get("u"):
                sources.setdefault(r["source"], [float(r["u"]), r.get("distribution", "normal"), np.zeros(n)])[2][i] = \
                    float(r["sensitivity"])
    rng = np.random.default_rng(seed)
    out = np.array(draws, float, copy=True)
    for u, dist, c in sources.values():
        out += draw(rng, dist, u, out.shape[0])[:, None] * c[None, :]
    return out
