"""A drift that is the unit's tempcos times one temperature error: a thermometer read differently.

A calibration over a temperature range states each value at the reference temperature as its
thermometers read it. Where the thermometers of one calibration read ``delta`` too high, its
values are the unit's at ``T_ref - delta`` (models/effects/thermal.py: ``v(T) = v(T_ref) + c (T -
T_ref)``), so every parameter with a tempco ``c`` drifts by::

    d = -c delta     (K: relative, ppm/degC x 1e-6 x K; S: ug/degC x 1e-6 g; angles: arcsec/degC)

An outside probe's unit, unchanged, calibrated twice over -10..50 degC with tempcos K 50 ppm/degC,
S 50 ug/degC and angles 6 arcsec/degC, the after campaign's thermometers 0.5 degC high: "fail" 4 of
4 with every K, S and angle significant (D2 62-125) and nothing said of the pattern.

``delta`` is fitted by weighted least squares over the parameters whose tempco both results hold
(the tempco the mean of the two, each drift's weight ``1 / u(d)^2``; the drifts' correlations are
left out, so the fit is a signature, not a test of its own): ``delta = -sum(c d / u^2) / sum(c^2 /
u^2)``, with ``z = delta / sd`` and what is left ``sum((d + c delta)^2 / u^2)`` on ``m - 1`` dof. Where
``delta`` is beyond 3.29 sd (two-sided 0.001) and what is left is not significant at 0.001
(:data:`REST_P_MIN`), a note gives ``delta``; a fail it explains is held back as inconclusive where
neither calibration's u holds a thermometer's error (no lab file's ``[thermometers]``)."""

from __future__ import annotations

import math
from typing import Mapping, Optional

from scipy import stats

#: |z| of the fitted temperature error beyond which it is significant (two-sided 0.001)
DELTA_Z_MIN = float(stats.norm.isf(0.0005))
#: what is left after it must not be significant at this p: the drifts' correlations are left out of the
#: fit, so its chi2 is only roughly chi2(m - 1) (the independent bench's 0.5 degC: p 0.049 on 11 dof)
REST_P_MIN = 1e-3


def _per_degC(name: str, value: float, tempco: float) -> float:
    """The change of parameter ``name`` per degC of its tempco ``tempco`` (its reporting units)."""
    if name.startswith("K_"):
        return value * tempco * 1e-6
    if name.startswith("S_"):
        return tempco * 1e-6
    return tempco


def thermometer_offset(params: Mapping, before, after) -> Optional[dict]:
    """The fit of one temperature error to the drifts (module docstring), or None with fewer than
    three parameters with tempcos."""
    rows = []
    for n, p in params.items():
        t = f"{n}_tempco"
        if t not in before.parameters or t not in after.parameters or n.endswith("_tempco"):
            continue
        c = 0.5 * (_per_degC(n, before[n].value, before[t].value) + _per_degC(n, after[n].value, after[t].value))
        if not (math.isfinite(c) and math.isfinite(p.drift) and p.u > 0 and c != 0):
            continue
        rows.append((n, c, p.drift, p.u))
    if len(rows) < 3:
        return None
    sw = sum(c * c / u ** 2 for _, c, _, u in rows)
    delta = -sum(c * d / u ** 2 for _, c, d, u in rows) / sw
    sd = 1.0 / math.sqrt(sw)
    rest = sum(((d + c * delta) / u) ** 2 for _, c, d, u in rows)
    return {"delta_C": delta, "sd_C": sd, "z": delta / sd, "n": len(rows), "chi2_rest": rest,
            "p_rest": float(stats.chi2.sf(rest, len(rows) - 1))}


def thermometer_verdict(params: Mapping, before, after, level: float, overall: str, held_back: bool,
                        notes: list) -> tuple:
    """``(overall, held_back)`` after the signature's test; its note in ``notes``."""
    from .correlation import budget_equipment
    from .guards import NOT_PASS_NOTE

    fit = thermometer_offset(params, before, after)
    if fit is None or abs(fit["z"]) <= DELTA_Z_MIN or fit["p_rest"] < REST_P_MIN:
        return overall, held_back
    in_u = "thermometers" in (set(budget_equipment(before)) | set(budget_equipment(after)))
    note = (f"the drifts of the {fit['n']} parameters with tempcos are their tempcos times one temperature error: "
            f"the after calibration's thermometers read {fit['delta_C']:+.3g} +- {fit['sd_C']:.2g} degC from the "
            f"before's (z {fit['z']:+.3g}; what is left after it not significant, p {fit['p_rest']:.2g}): a "
            "thermometer offset or a chamber read differently, not a drift of the unit, would give the same")
    if overall == "fail" and not in_u and not held_back:
        notes.insert(0, NOT_PASS_NOTE + note + "; neither calibration's u holds a thermometer's error (no lab file's "
                     "[thermometers]), so the data cannot tell them apart")
        return "inconclusive", True
    notes.append(note)
    return overall, held_back
