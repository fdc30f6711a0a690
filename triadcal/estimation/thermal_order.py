"""The order of each temperature dependence chosen by the data (``triadcal fit --thermal-order
1|2|3|auto``, docs/model.md "Quadratic and cubic tempcos").

``1`` keeps the model as given, ``2`` adds every family's quadratic term (``angle_tempco2``,
``scale_tempco2``, ``bias_tempco2``), ``3`` adds the quadratic and the cubic terms
(``*_tempco3``). ``auto`` chooses each family's order, 1, 2 or 3, by likelihood-ratio tests of
nested models, **top down**: the family's cubic term is kept (with its quadratic) when
``chi2(order 2) - chi2(order 3)`` exceeds the 99 % point of chi^2 with as many degrees of freedom
as the family has parameters (6 for the angles, 3 for K or S); otherwise its quadratic term is kept
when ``chi2(order 1) - chi2(order 2)`` exceeds the same point; otherwise the family stays linear.
The top-down order finds a cubic bend whose quadratic part is small (over a range symmetric about
T0 a cubic is nearly orthogonal to a parabola, so a bottom-up search would stop at order 1). With
a known output noise the statistic is chi^2-distributed under the smaller model (the models are
nested and the terms enter linearly), so each test adds a term wrongly in 1 % of linear campaigns:
two tests per family, three families, about 6 % of linear campaigns get some term they do not
need. With the noise estimated from the residuals, a term is kept when it lowers AIC by more
than 2 per parameter. Families are tried in the order angles, scale factors, biases, each against
the model with the terms kept so far.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import stats

from ..errors import InputError
from .joint import fit_joint

#: (linear, quadratic, cubic, parameters per term) of each family
FAMILIES = (("angle_tempco", "angle_tempco2", "angle_tempco3", 6), ("scale_tempco", "scale_tempco2", "scale_tempco3", 3),
            ("bias_tempco", "bias_tempco2", "bias_tempco3", 3))
ORDERS = ("1", "2", "3", "auto")
#: level of each likelihood-ratio test of ``auto``
LEVEL = 0.99


class _SubModels:
    """chi^2 of the model without some of the full fit's thermal terms, by one Gauss-Newton step
    from the full optimum: ``min |r + J d|^2`` with the dropped parameters' steps fixed at minus
    their values (exact for a model linear in its parameters; the tempcos enter linearly but for
    the small products of eq. 1, and the chosen model is refitted in full by the caller)."""

    def __init__(self, full):
        _, problem, sol = full
        self.problem, self.sol = problem, sol
        self.effect_of = [problem.model.spec[nm].effect for nm in problem.names]

    def chi2(self, effects) -> float:
        keep = np.array([e in effects or e == "core" for e in self.effect_of])
        J, r, x = self.sol.J, self.sol.r, self.sol.x
        rp = r - J[:, ~keep] @ x[~keep] if np.any(~keep) else r
        A = J[:, keep]
        d = np.linalg.norm(A, axis=0)
        d[d == 0] = 1.0
        Q = np.linalg.qr(A / d, mode="reduced")[0]
        res = rp - Q @ (Q.T @ rp)
        return float(res @ res)


def choose_thermal_order(campaign, effects: Sequence[str], order: str = "auto", **fit_kwargs):
    """The effects with the higher-order terms the order asks for: ``1`` as given, ``2`` every
    family's quadratic term, ``3`` quadratic and cubic, ``auto`` those the data support (see the
    module). Returns ``(effects, block)``, ``block`` saying what was tried and why (for
    ``fit.thermal_order``: ``order``, ``criterion``, ``added``, ``tried``, ``orders`` per family)."""
    order = str(order)
    if order not in ORDERS:
        raise InputError(f"--thermal-order {order!r}: choose one of {', '.join(ORDERS)}")
    effects = list(effects)
    present = [f for f in FAMILIES if f[0] in effects]
    if not present:
        raise InputError("--thermal-order needs a linear tempco in the model (angle_tempco, scale_tempco, bias_tempco)")
    if order == "1":
        return tuple(effects), {"order": "1", "criterion": "chosen by the user", "added": []}
    if order in ("2", "3"):
        terms = [t for f in present for t in (f[1:3] if order == "3" else f[1:2])]
        added = [t for t in terms if t not in effects]
        return tuple(effects + added), {"order": order, "criterion": "chosen by the user", "added": added}
    kw = dict(fit_kwargs, return_problem=True)
    # every candidate term at once; each smaller model's chi^2 by one Gauss-Newton step from it
    full = fit_joint(campaign, effects + [t for f in present for t in f[1:3] if t not in effects], **kw)
    sub = _SubModels(full)
    known = bool(full[0].fit.get("noise_known"))
    n = full[2].r.size
    tried, added, orders = [], [], {}

    def _chi2(model_effects):
        return sub.chi2(model_effects)

    chi2 = _chi2(effects)

    def test(chi2_small, chi2_big, k, term):
        if known:
            stat, thr = chi2_small - chi2_big, float(stats.chi2.ppf(LEVEL, k))
            return stat > thr, f"{term}: chi2 falls by {stat:.4g} against {thr:.3g} (chi2 with {k} dof at 99 %)"
        stat = n * np.log(chi2_small / n) - (n * np.log(chi2_big / n) + 2 * k)
        return stat > 2 * k, f"{term}: AIC falls by {stat:.4g} against {2 * k} (noise estimated)"

    for lin, quad, cub, k in present:
        if cub in effects:
            orders[lin] = 3
            continue
        have_quad = quad in effects
        with_quad = effects if have_quad else effects + [quad]
        chi2_2 = chi2 if have_quad else _chi2(with_quad)
        chi2_3 = _chi2(with_quad + [cub])
        keep3, why3 = test(chi2_2, chi2_3, k, cub)
        tried.append({"term": cub, "kept": bool(keep3), "why": why3})
        if keep3:
            new = [t for t in (quad, cub) if t not in effects]
            effects += new
            added += new
            chi2, orders[lin] = chi2_3, 3
            continue
        if have_quad:
            orders[lin] = 2
            continue
        keep2, why2 = test(chi2, chi2_2, k, quad)
        tried.append({"term": quad, "kept": bool(keep2), "why": why2})
        if keep2:
            effects.append(quad)
            added.append(quad)
            chi2 = chi2_2
        orders[lin] = 2 if keep2 else 1
    return tuple(effects), {"order": "auto",
                            "criterion": "likelihood ratio at 99 % per family (angles, K, S), top down: cubic "
                                         "against quadratic, then quadratic against linear",
                            "added": added, "tried": tried, "orders": orders}
