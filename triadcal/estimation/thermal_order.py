"""The order of each temperature dependence chosen by the data (``triadcal fit --thermal-order
auto``, docs/model.md "Quadratic tempcos").

Starting from the model as given (linear tempcos), each family's quadratic term
(``angle_tempco2``, ``scale_tempco2``, ``bias_tempco2``) is added in turn and kept when the
likelihood-ratio statistic ``chi2_without - chi2_with`` exceeds the 99 % point of chi^2 with as
many degrees of freedom as the term has parameters (6 for the angles, 3 for K or S), with a
known output noise; with the noise estimated from the residuals, when it lowers AIC by more than
2 per parameter. Families are tried in the order angles, scale factors, biases, each against the
model with the terms kept so far. Orders above 2 are not offered.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import stats

from ..errors import InputError
from .joint import fit_joint

FAMILIES = (("angle_tempco", "angle_tempco2", 6), ("scale_tempco", "scale_tempco2", 3),
            ("bias_tempco", "bias_tempco2", 3))
ORDERS = ("1", "2", "auto")


def choose_thermal_order(campaign, effects: Sequence[str], order: str = "auto", **fit_kwargs):
    """The effects with the quadratic terms the order asks for: ``1`` as given, ``2`` every
    family's quadratic term, ``auto`` those the data support (see the module). Returns
    ``(effects, block)``, ``block`` saying what was tried and why (for ``fit.thermal_order``)."""
    if order not in ORDERS:
        raise InputError(f"--thermal-order {order!r}: choose one of {', '.join(ORDERS)}")
    effects = list(effects)
    present = [(lin, quad, k) for lin, quad, k in FAMILIES if lin in effects]
    if not present:
        raise InputError("--thermal-order needs a linear tempco in the model (angle_tempco, scale_tempco, bias_tempco)")
    if order == "1":
        return tuple(effects), {"order": "1", "criterion": "chosen by the user", "added": []}
    if order == "2":
        return tuple(effects + [q for _, q, _ in present if q not in effects]), {
            "order": "2", "criterion": "chosen by the user", "added": [q for _, q, _ in present]}
    kw = dict(fit_kwargs, return_problem=True)
    base = fit_joint(campaign, effects, **kw)
    chi2 = float(np.sum(base[2].r ** 2))
    known = bool(base[0].fit.get("noise_known"))
    n = base[2].r.size
    tried, added = [], []
    for lin, quad, k in present:
        if quad in effects:
            continue
        trial = fit_joint(campaign, effects + [quad], **kw)
        chi2_t = float(np.sum(trial[2].r ** 2))
        if known:
            stat, thr = chi2 - chi2_t, float(stats.chi2.ppf(0.99, k))
            keep = stat > thr
            why = f"chi2 falls by {stat:.4g} against {thr:.3g} (chi2 with {k} dof at 99 %)"
        else:
            stat = n * np.log(chi2 / n) - (n * np.log(chi2_t / n) + 2 * k)
            keep = stat > 2 * k
            why = f"AIC falls by {stat:.4g} against {2 * k} (noise estimated)"
        tried.append({"term": quad, "kept": bool(keep), "why": why})
        if keep:
            effects.append(quad)
            added.append(quad)
            chi2 = chi2_t
    return tuple(effects), {"order": "auto", "criterion": "likelihood ratio at 99 % per family (angles, K, S)",
                            "added": added, "tried": tried}
