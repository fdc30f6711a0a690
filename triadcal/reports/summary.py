"""Plain-text summary of a calibration result for the terminal."""

from __future__ import annotations

from ..estimation.result import CalibrationResult, round_to_uncertainty
from .notation import display_unit


def coverage_factor(result: CalibrationResult) -> tuple[float, str]:
    """The k of the 95 % intervals the result itself states: Student's t on the residual
    degrees of freedom when its intervals carry ``dof`` (few poses of a raw recording), else 2
    (GUM, coverage about 95 %); and a sentence saying which."""
    dofs = {iv.get("dof") for iv in (result.intervals or {}).values() if isinstance(iv, dict)}
    dofs.discard(None)
    if len(dofs) == 1:
        dof = dofs.pop()
        if isinstance(dof, (int, float)) and dof > 0:
            from scipy import stats

            return float(stats.t.ppf(0.975, dof)), (f"the 95 % interval of the JSON (Student's t with {dof:g} "
                                                     "residual degrees of freedom)")
    fit = result.fit or {}
    res_dof = fit.get("residual_dof") if result.method == "classical" and fit.get("noise_source") == "residuals" else None
    if isinstance(res_dof, list) and res_dof and all(isinstance(d, (int, float)) and d > 0 for d in res_dof):
        # the classical u from the redundant positions' residuals: Student's t on their dof (an outside
        # probe: "U = 2 u, coverage about 95 %" on a 12-position plan, 6 dof, held the truth 87 % of the time)
        from scipy import stats

        dof = min(res_dof)
        return float(stats.t.ppf(0.97725, dof)), (f"coverage about 95 % (Student's t with {dof:g} residual degrees of "
                                                  "freedom per accelerometer: the noise was estimated from the "
                                                  "redundant positions)")
    if result.method == "posterior":
        return 2.0, ("twice the posterior SD; the 95 % intervals of the JSON are the draws' 2.5-97.5 % quantiles, "
                     "which differ where the posterior is not Gaussian")
    return 2.0, "coverage about 95 %"


def _estimated_noise_text(chi2_dof: float, noise: str, output_unit, q_per_output=None) -> str:
    """What the summary says of the fit when the data hold no noise level: no chi2/dof (the
    scatter itself set the level, so it is 1 by construction in its own units and a number printed
    there would mean nothing), but the level estimated and from what. With the weights 1/sqrt(tau_s)
    (``noise_model.noise_of``) chi2/dof is the white-noise intensity Q of the outputs, in the output
    unit squared times s, the unit of the ``Q_V2s`` metadata line."""
    from ..estimation.noise_model import RELATIVE_WEIGHTS

    unit = output_unit or "V"
    if RELATIVE_WEIGHTS in noise and isinstance(q_per_output, list) and len(q_per_output) == 3:
        level = (f"Q = {', '.join(f'{q:.3g}' for q in q_per_output)} {unit}^2 s, the white-noise intensities of "
                 "the x, y, z outputs")
    elif RELATIVE_WEIGHTS in noise:
        level = f"Q = {chi2_dof:.3g} {unit}^2 s, the output's white-noise intensity"
    else:
        level = f"residual scale {chi2_dof ** 0.5:.3g} in the units of the weights"
    return (f"chi2/dof: none, the noise was {noise or 'estimated from the residuals'} ({level}), so no "
            "goodness-of-fit test")


def summary_text(result: CalibrationResult) -> str:
    """A concise table: parameter, value(u) with u to two significant digits, unit."""
    lines = [f"{result.unit}: {result.method} calibration, status {result.status}"]
    gates = (result.extra.get("gates") or {}).get("outcomes") or []
    for o in gates:
        if isinstance(o, dict) and o.get("passed") is False:
            lines.append(f"  FAILED gate {o.get('gate')} ({o.get('status')}): {o.get('reason')}")
    fit = result.fit
    if fit:
        bits = []
        c = fit.get("chi2_dof")
        if isinstance(c, (int, float)) and c == c and fit.get("noise_known") is False:
            bits.append(_estimated_noise_text(c, str(fit.get("noise") or ""), result.extra.get("output_unit"),
                                              fit.get("Q_estimate_per_output")))
        elif isinstance(c, (int, float)) and c == c:
            bits.append(f"chi2/dof = {c:.3f}")
        elif isinstance(fit.get("noise_floor_ratio"), (int, float)):
            # a raw recording's gravity-norm fit: its goodness of fit is the residual variance over the
            # recording's own noise floor of the interval means (the gate's ratio)
            bits.append(f"residual variance / noise floor of the interval means = {fit['noise_floor_ratio']:.3f}"
                        + (f" ({fit['dof']} dof)" if "dof" in fit else ""))
        else:
            bits.append("chi2/dof not computed (no degrees of freedom or no residuals)")
        if "n_obs" in fit:
            det = fit.get("n_params_determined")
            bits.append(f"{fit['n_obs']} observations, {fit.get('n_params', '?')} parameters"
                        + (f" ({det} determined by the data, the rest by their priors)"
                           if det is not None and det != fit.get("n_params") else ""))
        if result.temperature_range_C:
            lo, hi = result.temperature_range_C
            bits.append(f"{lo:.1f} .. {hi:.1f} °C, reference {result.reference_temperature_C:g} °C")
        lines.append("  " + "; ".join(bits))
    k, how = coverage_factor(result)
    if any(p.U is not None for p in result.parameters.values()):
        # a budget per parameter (lab file): its own U and k (from dof_eff, or a Monte Carlo)
        lines.append(f"  {'parameter':<20} {'value':>16} {'U':>12} {'k':>5}  unit")
        for name, p in result.parameters.items():
            kp = p.uncertainty.get("k", k) if p.U is not None else k
            v, U = round_to_uncertainty(p.value, p.U if p.U is not None else k * p.u)
            lines.append(f"  {name:<20} {v:>16} {U:>12} {kp:>5.3g}  {display_unit(p.unit)}")
        type_b = result.holds_type_b()
        lines.append("  U at 95.45 % coverage from each parameter's budget (" + (
            "Type A and the lab's Type B; k from dof_eff, or a Monte Carlo" if type_b else
            "Type A only: k from Student's t on each parameter's dof, its line's over the setpoints where the "
            "Birge ratio widened it, else its accelerometer's residual dof" if result.method == "classical" else
            f"Type A only, the noise estimated on {result.fit.get('noise_dof', float('nan')):.3g} dof: k from "
            "Student's t") + "); the budgets are in the JSON")
    else:
        lines.append(f"  {'parameter':<20} {'value':>16} {f'U (k={k:.3g})':>12}  unit")
        for name, p in result.parameters.items():
            v, U = round_to_uncertainty(p.value, k * p.u)
            lines.append(f"  {name:<20} {v:>16} {U:>12}  {display_unit(p.unit)}")
        lines.append(f"  U = {k:.3g} u, {how}; u (k = 1) in the JSON")
    rec = result.extra.get("intervals_to_use")
    if isinstance(rec, dict) and rec.get("use"):
        which = "the least-squares ones (fit.least_squares)" if rec["use"] == "least_squares" else "the posterior's"
        lines.append(f"  intervals to use: {which}, because {rec.get('why', '')}")
    try:
        from .certificate import refusal_reasons
    except ImportError:  # pragma: no cover - reportlab missing
        return "\n".join(lines)
    for reason in refusal_reasons(result):
        lines.append(f"  no certificate would be issued: {reason}")
    return "\n".join(lines)
