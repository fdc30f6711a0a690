"""The certificate's uncertainty budget of an orientation angle of the matrix as applied over
the temperature range (seed paper, eq. 4-7): output noise, bench positioning and wobble,
tilt, temperature measurement, thermal-model residual and hysteresis (docs/certificate.md,
"Uncertainty budget")."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from ..estimation.result import CalibrationResult
from ..io.lab import LabConfig
from ..models.effects.hysteresis import BRANCH
from ..models.sensor import ANGLE_NAMES
from .budget import Budget, BudgetComponent
from .paper import correction_error_arcsec

ANGLES = tuple(f"Ca_{ab}" for ab in ANGLE_NAMES)


BUDGET_SOURCES = ("output noise", "bench positioning", "wobble", "tilt", "bench axes non-orthogonality",
                  "encoder zeros", "fixture mounting", "temperature measurement", "thermal coefficients",
                  "thermal-model residual", "hysteresis")

#: the lab's systematic angle errors: (budget row, LabConfig field, lab-file key)
SYSTEMATIC = (("bench axes non-orthogonality", "axes_nonorthogonality_u_arcsec",
               "[bench] axes_nonorthogonality_u_arcsec"),
              ("encoder zeros", "encoder_zero_u_arcsec", "[bench] encoder_zero_u_arcsec"),
              ("fixture mounting", "mounting_u_arcsec", "[fixture] mounting_u_arcsec"))


def _given_budget(given) -> Optional[list]:
    """Components written by an estimator into ``result.extra["budget"]``: a list of rows, or a
    :meth:`triadcal.uncertainty.budget.Budget.to_dict` (``components`` with ``standard_uncertainty``,
    ``sensitivity``, ``contribution``)."""
    rows = given.get("components") if isinstance(given, dict) else given
    if not isinstance(rows, list) or not rows:
        return None
    out = []
    for c in rows:
        contribution = c.get("contribution", c.get("u"))
        out.append(BudgetComponent(
            str(c["source"]), None if contribution is None else float(contribution),
            u=c.get("standard_uncertainty", c.get("u")), unit=str(c.get("unit", "arcsec")),
            sensitivity=c.get("sensitivity", 1.0), sensitivity_unit=str(c.get("sensitivity_unit", "1")),
            basis=str(c.get("basis", c.get("symbol", ""))), equation=str(c.get("equation", ""))))
    return out


def _bench_sd(plan, sigma_position: float, sigma_wobble: float) -> float:
    """Largest standard deviation (arcsec) of a single-setpoint classical angle from the bench
    errors alone (:func:`triadcal.uncertainty.classical_sd.classical_angle_sd`, eq. 2-4)."""
    from .classical_sd import classical_angle_sd

    sd = classical_angle_sd(plan, Q_V2s=0.0, tau_s=1.0, sigma_position_arcsec=sigma_position,
                            sigma_wobble_arcsec=sigma_wobble)
    return max(sd.values())


def uncertainty_budget(result: CalibrationResult, lab: Optional[LabConfig] = None,
                       per_setpoint: Optional[list] = None, source_of_u: str = "", plan=None) -> Budget:
    """Budget of an orientation angle of the matrix as applied over the temperature range.

    Components are taken from ``result.extra["budget"]`` when the estimator wrote one;
    otherwise they are assembled from the result, the lab's bench figures and the
    per-setpoint estimates with :mod:`triadcal.uncertainty.paper` and
    :mod:`triadcal.estimation.classical` (seed paper, eq. 4-7):

    - output noise: the estimator's standard uncertainty of the angles (largest of six), under
      the name and basis the estimator gives in ``fit.angle_uncertainty`` when it gives one
      (``fit-raw``, known poses: "hand placement");
    - bench positioning and wobble: sigma_1, sigma_2 of eq. 4 through the classical estimate
      of one setpoint on ``plan`` (sensitivity 1/2 on the default plan); an upper bound for
      a joint fit, which averages them over the setpoints;
    - tilt: estimated with the calibration (its uncertainty is in the angles' u) or
      cancelled by the half-turn pairs of eq. 2-3;
    - temperature measurement: ``Delta T * k_ca`` of eq. 7 with the largest fitted tempco;
    - thermal-model residual: scatter of the per-setpoint estimates about the fitted
      thermal model beyond their own uncertainty (what a linear correction leaves, eq. 5);
    - hysteresis: the half-width ``h`` of the loop (largest of six; dCa_Ta of eq. 5): the
      matrix is stated on the mid-line, a reading on either branch is off by ``+-h``.
    """
    quantity = "orientation angle Ca_ab applied over the temperature range"
    given = _given_budget(result.extra.get("budget"))
    if given:
        return Budget(quantity, given, "arcsec")
    

    P = result.parameters
    angles = [n for n in ANGLES if n in P]
    comps = []
    declared = result.fit.get("angle_uncertainty")
    from .typeb import budget_of

    own = budget_of(max(angles, key=lambda n: P[n].u), P[max(angles, key=lambda n: P[n].u)]) if angles else None
    if own is not None:
        # the fit propagated the lab's systematic errors: the largest angle's own budget (Type A
        # and every Type B row with its sensitivity from the model), not sensitivity-1 rows
        worst = own.quantity
        for c in own.components:
            c.basis = (f"{c.basis}; " if c.basis else "") + f"{worst}'s budget in the result (sensitivity from the model)"
            c.equation = c.equation or "eq. 1"
            comps.append(c)
    elif angles and declared:
        # the estimator says what sets its angles' u (fit-raw, known poses: the hand placement)
        worst = max(angles, key=lambda n: P[n].u)
        comps.append(BudgetComponent(declared["source"], P[worst].u, P[worst].u,
                                     basis=f"{declared['basis']} (largest: {worst})",
                                     equation=declared.get("equation", "")))
    elif angles:
        worst = max(angles, key=lambda n: P[n].u)
        comps.append(BudgetComponent("output noise", P[worst].u, P[worst].u, basis=(
            f"standard uncertainty of the angles from the {source_of_u or result.method} (largest: {worst}); "
            "Type A"), equation="eq. 4, 1st term"))
    else:
        comps.append(BudgetComponent("output noise", None, basis="the result has no orientation angles",
                                     equation="eq. 4"))
    s1 = lab.sigma_position_arcsec if lab is not None else None
    s2 = lab.sigma_wobble_arcsec if lab is not None else None
    upper = " (one setpoint; an upper bound for the joint fit)" if result.method != "classical" else ""
    in_fit = (result.fit.get("bench_errors") or {}) if isinstance(result.fit.get("bench_errors"), dict) else {}
    for src, s, sym, key, args in (("bench positioning", s1, "σ1", "[bench] sigma_position_arcsec", (1.0, 0.0)),
                                   ("wobble", s2, "σ2", "[bench] sigma_wobble_arcsec", (0.0, 1.0))):
        stated = in_fit.get("sigma_position_arcsec" if args[0] else "sigma_wobble_arcsec")
        if result.method == "classical" and result.fit.get("noise_source") == "residuals":
            # the classical u from the pooled residuals holds every per-visit error the pairs do not
            # cancel (fit_classical): adding sigma_1 and sigma_2 again counted them twice
            comps.append(BudgetComponent(src, 0.0, s, sensitivity=0.0, basis=(
                f"{sym}{'' if s is None else f' = {s:g} arcsec'}: a per-visit error, inside the classical angles' u "
                "estimated from the residuals (output-noise row)"), equation="eq. 2-4"))
            continue
        if in_fit.get("in_u") and stated is not None:
            comps.append(BudgetComponent(src, 0.0, float(stated), sensitivity=0.0, basis=(
                f"{sym} = {float(stated):g} arcsec ({in_fit.get('source', 'lab file')}) modelled per visit in the fit: "
                "already inside the angles' u (output-noise row)"), equation="eq. 4"))
            continue
        if s is None:
            comps.append(BudgetComponent(src, None, basis=f"{sym} not stated (give {key} in the lab file)",
                                         equation="eq. 4"))
        else:
            c = _bench_sd(plan, *args)
            comps.append(BudgetComponent(src, c * s, s, sensitivity=c, basis=(
                f"{sym} = {s:g} arcsec (lab file) through the classical estimate of the plan{upper}"),
                equation="eq. 2-4"))
    if "bench_tilt" in result.effects:
        td = P.get("tilt_delta")
        txt = (f"estimated with the calibration (δ = {td.value:.1f} arcsec, u = {td.u:.2g} arcsec); "
               "its uncertainty is inside the angles' u") if td else "estimated with the calibration"
        comps.append(BudgetComponent("tilt", 0.0, td.u if td else None, sensitivity=0.0, basis=txt,
                                     equation="eq. 1"))
    elif result.method == "classical":
        comps.append(BudgetComponent("tilt", 0.0, sensitivity=0.0, basis="cancels in the half-turn pairs of the plan",
                                     equation="eq. 2-3"))
    else:
        comps.append(BudgetComponent("tilt", None, basis="bench tilt not modelled", equation=""))
    for src, attr, key in SYSTEMATIC:
        v = getattr(lab, attr, None) if lab is not None else None
        if own is not None:
            continue                      # in the angle's own budget above
        if v is None:
            comps.append(BudgetComponent(src, None, basis=f"not stated (give {key} in the lab file)",
                                         equation="eq. 1"))
        else:
            # a rotation of a bench axis or of the unit in its fixture turns the sensed gravity
            # by the same angle: one to one into an orientation angle (the largest case)
            comps.append(BudgetComponent(src, float(v), float(v), sensitivity=1.0, basis=(
                f"{key} = {float(v):g} arcsec (lab file), one to one into an angle; the same in every "
                "calibration on this bench, so it cancels in a drift"), equation="eq. 1"))
    tempcos = [P[f"{n}_tempco"].value for n in angles if f"{n}_tempco" in P]
    if not tempcos:
        comps.append(BudgetComponent("temperature measurement", 0.0, basis="no thermal terms in the model",
                                     equation="eq. 7"))
    elif own is not None and any(c.source == "thermometers" for c in own.components):
        pass                              # propagated through the fit: the "thermometers" row above
    elif lab is None or lab.temperature_uncertainty_C is None:
        comps.append(BudgetComponent("temperature measurement", None, basis=(
            "ΔT not stated (give [thermometers] u_C in the lab file)"), equation="eq. 7"))
    else:
        k = max(abs(t) for t in tempcos)
        dT = lab.temperature_uncertainty_C
        comps.append(BudgetComponent("temperature measurement", correction_error_arcsec(dT, k), dT, "°C",
                                     sensitivity=k, sensitivity_unit="arcsec/°C", basis=(
                                         "ΔT (lab file) times k_ca, the largest fitted tempco"), equation="eq. 7"))
    coeff = _thermal_coefficients_component(result)
    if coeff is not None:
        comps.append(coeff)
    comps.append(_thermal_residual_component(result, per_setpoint))
    hyst = [abs(P[f"{n}_hysteresis"].value) for n in angles if f"{n}_hysteresis" in P]
    if hyst:
        comps.append(BudgetComponent("hysteresis", max(hyst), max(hyst), basis=(
            "largest half-width h of the loop; the matrix is stated on the mid-line, a reading on a branch "
            "is off by ±h (two-point distribution, sd h: U is its coverage interval, not 2h)"),
            equation="eq. 5, ΔCa_Ta", distribution="two-point"))
    else:
        comps.append(BudgetComponent("hysteresis", None, basis="not modelled (in the thermal-model residual)",
                                     equation="eq. 5, ΔCa_Ta"))
    return Budget(quantity, comps)


#: the angles' thermal terms and their power of (T - T0) (models/effects/thermal*.py)
ANGLE_TEMPCO_ORDERS = (("tempco", 1), ("tempco2", 2), ("tempco3", 3))


def _thermal_coefficients_component(result) -> Optional[BudgetComponent]:
    """The fitted tempcos' own uncertainty where the matrix is applied away from T0: an angle applied at
    T is ``Ca(T) = Ca + sum_k c_k dT^k`` (dT = T - T0), so ``u(T)^2 = u(T0)^2 + 2 sum_k dT^k cov(Ca, c_k)
    + sum_jk dT^(j+k) cov(c_j, c_k)`` (GUM 5.2, the result's covariance). The component is the square
    root of that increment, the largest over the angles and the two ends of the calibrated range. An
    outside probe: "U = 7.5 arcsec (u_c 3.77) within the calibrated range" where u(Ca_xz_tempco) =
    0.033 arcsec/degC at 40 degC from T0 made u 4.00. None without angle tempcos or a range."""
    P, rng = result.parameters, result.temperature_range_C
    if not rng:
        return None
    T0 = float(result.reference_temperature_C)
    best = None
    for ab in ANGLE_NAMES:
        n = f"Ca_{ab}"
        terms = [(f"{n}_{suf}", k) for suf, k in ANGLE_TEMPCO_ORDERS if f"{n}_{suf}" in P and n in P]
        if not terms or any(P[t].u is None or not math.isfinite(P[t].u) for t, _ in terms):
            continue
        C = result.covariance([n] + [t for t, _ in terms])
        for T in rng:
            dT = float(T) - T0
            a = np.array([dT ** k for _, k in terms])
            inc = float(2.0 * a @ C[0, 1:] + a @ C[1:, 1:] @ a)
            if best is None or inc > best[0]:
                best = (inc, n, dT)
    if best is None:
        return None
    inc, n, dT = best
    u = math.sqrt(max(inc, 0.0))
    return BudgetComponent("thermal coefficients", u, u, basis=(
        f"the fitted tempcos' own uncertainty at the end of the range farthest in effect from T0 ({n}, T − T0 = "
        f"{dT:+.1f} °C; with their correlation with the angle, from the result's covariance)"),
        equation="GUM 5.2: u(T)² = u(T0)² + this²")


def _thermal_residual_component(result, per_setpoint) -> BudgetComponent:
    given = result.extra.get("thermal_residual_arcsec")
    if isinstance(given, (int, float)):
        return BudgetComponent("thermal-model residual", float(given), float(given), basis="from the result file",
                               equation="eq. 5")
    if not per_setpoint:
        return BudgetComponent("thermal-model residual", None, basis=(
            "needs per-setpoint estimates (--data DATA.csv and the classical estimator)"), equation="eq. 5")
    dev, var = [], []
    for r in per_setpoint:
        m = result.angles_at(np.array([r["temperature_C"]]), BRANCH.get(r["direction"], 0.0))
        for ab in ANGLE_NAMES:
            if f"Ca_{ab}" in r:
                dev.append(r[f"Ca_{ab}"] - float(m[ab][0]))
                var.append(r.get(f"u_Ca_{ab}", 0.0) ** 2)
    if not dev:
        return BudgetComponent("thermal-model residual", None, basis="no per-setpoint angles", equation="eq. 5")
    rms2 = float(np.mean(np.square(dev)))
    u = math.sqrt(max(0.0, rms2 - float(np.mean(var))))
    return BudgetComponent("thermal-model residual", u, u, basis=(
        f"scatter of the {len(per_setpoint)} per-setpoint classical estimates about the model (rms "
        f"{math.sqrt(rms2):.2g} arcsec) less their own uncertainty (rms {math.sqrt(float(np.mean(var))):.2g})"),
        equation="eq. 5")
