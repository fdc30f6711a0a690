"""The model check of a fit whose noise is estimated from its own residuals (no ``sd_*``, no
``Q_V2s``): chi2 cannot test the model there (it defines the noise), but the residuals' structure
can. Smooth terms the model lacks -- of temperature, time, orientation (even and odd in g) and
direction, each on each output (the diagnosis's generic families, ``judgement/diagnose/generic.py``)
-- are score-tested at the fit, F against the residual variance, Holm over the families.

A family explains the residuals when its Holm-adjusted p < ``gof_p_min`` (0.001) **and** the noise
estimate with that structure in it is more than ``gof_ratio_max`` (1.2) times the estimate without
it (the goodness-of-fit gate's two-part rule: significant and material). Before, an outside
probe's campaign without noise columns and with a quadratic scale term K2 the model lacked was fitted
with status ok, S 6.6-10.6 u from the truth (the same data with the noise stated: chi2/dof 17.4,
model_mismatch)."""

from __future__ import annotations

from typing import Optional

import numpy as np


def structure_gap(campaign, sigma: np.ndarray, r: np.ndarray, J: np.ndarray, dof: int,
                  reference_temperature_C: float) -> Optional[dict]:
    """``{"p_value", "ratio", "family", "what"}`` of the strongest family (Holm-adjusted p), or None
    when no family has a column outside the fit's span. ``r``, ``J``: the fit's standardised
    residuals and Jacobian (least squares, no whitening)."""
    from ..judgement.diagnose.generic import generic_basis, generic_tests
    from ..judgement.diagnose.slices import _holm

    if dof < 2:
        return None
    tests = generic_tests(generic_basis(campaign, sigma, reference_temperature_C), r, J, False, dof)
    # a family needs residual degrees of freedom left beside it (F with dof - k >= 1): one that spans
    # every residual (six faces, dof 6, six terms) would "explain" them all (an outside probe: ratio
    # 1.5e291 on a clean six-face campaign)
    tests = {f: t for f, t in tests.items() if t["k"] < dof}
    if not tests:
        return None
    fams = list(tests)
    adj = dict(zip(fams, _holm([tests[f]["p_value"] for f in fams])))
    fam = min(fams, key=lambda f: (adj[f], -tests[f]["S"]))
    S, k = tests[fam]["S"], tests[fam]["k"]
    rr = float(r @ r)
    ratio = (rr / dof) / max((rr - S) / max(dof - k, 1), 1e-300)
    return {"p_value": float(adj[fam]), "ratio": float(ratio), "family": fam,
            "what": (f"structure of the residuals (the noise estimated from them, so chi2 cannot test the model): "
                     f"the strongest smooth family the model lacks, {fam} ({k} terms), F test Holm-adjusted over "
                     f"{len(fams)} families; ratio = the noise estimate with it over without it")}
