"""Plain-text summary of a calibration result for the terminal."""

from __future__ import annotations

from ..estimation.result import CalibrationResult, round_to_uncertainty


def summary_text(result: CalibrationResult) -> str:
    """A concise table: parameter, value(u) with u to two significant digits, unit."""
    lines = [f"{result.unit}: {result.method} calibration, status {result.status}"]
    fit = result.fit
    if fit:
        bits = []
        if fit.get("chi2_dof") is not None:
            bits.append(f"chi2/dof = {fit['chi2_dof']:.3f}")
        if "n_obs" in fit:
            bits.append(f"{fit['n_obs']} observations, {fit.get('n_params', '?')} parameters")
        if result.temperature_range_C:
            lo, hi = result.temperature_range_C
            bits.append(f"{lo:.1f} .. {hi:.1f} degC, reference {result.reference_temperature_C:g} degC")
        lines.append("  " + "; ".join(bits))
    lines.append(f"  {'parameter':<20} {'value':>16} {'U (k=2)':>12}  unit")
    for name, p in result.parameters.items():
        v, U = round_to_uncertainty(p.value, 2.0 * p.u)
        lines.append(f"  {name:<20} {v:>16} {U:>12}  {p.unit}")
    lines.append("  U = 2u, coverage about 95 %; u (k = 1) in the JSON")
    try:
        from .certificate import refusal_reasons
    except ImportError:  # pragma: no cover - reportlab missing
        return "\n".join(lines)
    for reason in refusal_reasons(result):
        lines.append(f"  no certificate would be issued: {reason}")
    return "\n".join(lines)
