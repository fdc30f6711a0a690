"""What a raw recording's ``null`` verdict could not have seen (``fit-raw --diagnose``).

Split from :mod:`.raw_diagnosis` (2026-11-29), whose ``diagnose_intervals`` calls it for a ``null``
verdict with residual degrees of freedom: the same question as :mod:`.diagnose.detection` answers for
a campaign's ``none``, asked of the raw diagnosis's own gap rule (docs/diagnosis.md, "Diagnosing real
recordings", "What a null could not have seen").
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..estimation.raw import terms as T
from .diagnose.detection import lambda_beyond, limit_ranges
from .diagnose.fitting import _hat_q
from .raw_diagnosis import ALPHA, CANDIDATES, RATIO_MAX, IntervalData, _jacobian, _Model, covariate

#: the probability with which a term at a null verdict's detection limit makes the gap significant
LIMIT_POWER = 0.95


def detection_limits(d: IntervalData, base: "_Model", p0: np.ndarray, dof0: int,
                     power: float = LIMIT_POWER) -> dict:
    """What a ``null`` verdict could not have seen: for each candidate term with parameters, the size
    of each parameter (the others at zero) at which the gap would have been significant with
    probability ``power`` -- the gap's own rule, chi2 over the intervals with p < ALPHA **and**
    chi2/dof > RATIO_MAX, so the critical value is the larger of chi2_dof0^{-1}(1 - ALPHA) and
    RATIO_MAX dof0.

    Linearised at the base fit ``p0`` (as docs/diagnosis.md "What a none verdict could not have
    seen" for campaigns): a term ``theta`` adds ``J_c theta`` to the normalised residuals (``J_c``
    its columns of :func:`_jacobian` at ``p = (p0, 0)``), the base refit absorbs its projection on
    the base columns, and the chi2 of the rest is noncentral with ``lambda = theta_j^2 |M_j|^2``,
    ``M = (I - Q Q') J_c``; the limit is ``sqrt(lambda* / |M_j|^2)``, ``lambda*`` from
    ``detection.lambda_beyond``. A column the norm correction absorbs (nothing outside its span) has
    no finite limit (None). Checked by simulation in tests/test_raw_diagnosis.py."""
    crit = max(float(stats.chi2.isf(ALPHA, dof0)), RATIO_MAX * dof0)
    lam = lambda_beyond(int(dof0), crit, power)
    Q = _hat_q(_jacobian(d, base.B, p0))
    out = []
    for name in CANDIDATES:
        if name not in T.TERMS and name not in T.COVARIATE_TERMS:
            continue                                   # contaminated_interval: no parameter to size
        if name in T.COVARIATE_TERMS and covariate(d, name) is None:
            continue
        m = _Model(d, name)
        _, names, unit = T.TERMS[name] if name in T.TERMS else T.COVARIATE_TERMS[name]
        Jc = _jacobian(d, m.B, np.concatenate([p0, np.zeros(m.k)]))[:, len(T.BASE_NAMES):]
        M = Jc - Q @ (Q.T @ Jc)
        m2 = np.sum(M * M, axis=0)
        scale = float(np.max(np.sum(Jc * Jc, axis=0), initial=0.0))
        f = T.UNIT_FACTOR[unit]
        out.append({"effect": name, "k": int(m.k), "parameters": {
            nm: {"value": (float(math.sqrt(lam / v)) * f if v > 1e-12 * max(scale, 1e-300) else None), "unit": unit}
            for nm, v in zip(names, m2)}})
    return {"power": power, "rule": f"the gap's own test: chi2 over the {dof0 + base.n_params} intervals with "
                                    f"p < {ALPHA:g} and chi2/dof > {RATIO_MAX:g} (critical chi2 {crit:.4g} on "
                                    f"{dof0} dof)",
            "critical_chi2": crit, "dof": int(dof0), "noncentrality": lam, "candidates": out}


def limits_text(limits: dict) -> str:
    """``"a term this size or larger would have made the gap significant with probability 0.95:
    scale_nonlinearity 310-420 ug/g2, ..."``; empty when no term has a finite limit."""
    parts = limit_ranges(limits["candidates"])
    if not parts:
        return ""
    return (f"a term this size or larger would have made the gap significant with probability "
            f"{limits['power']:g}: " + ", ".join(parts))


__all__ = ["LIMIT_POWER", "detection_limits", "limits_text"]
