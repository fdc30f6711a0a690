"""The goodness of fit of each output against its own declared noise: the gate ``goodness_of_fit_per_output``.

The ``goodness_of_fit`` gate pools the chi2 of the three outputs. Declared noise levels wrong in
opposite directions cancel there: ``sd_x`` 0.6 times the scatter of x and ``sd_y``, ``sd_z`` twice
theirs give a pooled chi2/dof near 1 ((2.8 + 0.25 + 0.25) / 3 = 1.1), a status ``ok``, and the
parameters of x with intervals 1.7 times too narrow (an outside probe of ``sample``: 6 of 8 seeds
``ok``, 47 of 60 of x's 95 % intervals holding the truth). Per output ``a`` (rows ``a::3`` of the
normalised residuals ``r``, visit-major):

    chi2_a = sum_{i in a} r_i^2,    dof_a = n_a - sum_{i in a} h_i

with ``h`` the leverages of the whitened Jacobian (the hat matrix's diagonal): the parameters' share
of each output's degrees of freedom (``sum_a dof_a = n - p``). Under the declared noise chi2_a is
chi2 on dof_a (Satterthwaite's dof for a residual sum over part of a least-squares fit). An output
fails, as the pooled gate does, when its chi2 is both significant (p below the gates' ``gof_p_min``
after Bonferroni over the three outputs) and material (chi2_a / dof_a above ``gof_ratio_max``).
An output whose scatter is below its declared noise only makes its intervals conservative: said in
the reason, not failed.
"""
from __future__ import annotations

from typing import Optional

import numpy as np
from scipy import stats

from .gate_outcome import GateOutcome

AXES = ("x", "y", "z")


def output_levels(r: np.ndarray, J: np.ndarray) -> Optional[list]:
    """Each output's ``{"axis", "chi2", "dof", "ratio", "p_high"}`` (``p_high`` the upper tail) from
    the normalised residuals ``r`` (3n, visit-major) and the whitened Jacobian ``J`` (3n x p); None
    when an output has no degree of freedom left or the Jacobian is not finite."""
    r = np.asarray(r, float)
    J = np.asarray(J, float)
    if r.size % 3 or J.shape[0] != r.size or not np.all(np.isfinite(J)) or not np.all(np.isfinite(r)):
        return None
    norms = np.linalg.norm(J, axis=0)
    Jn = J[:, norms > 0] / norms[norms > 0]
    if Jn.shape[1]:
        U, sv, _ = np.linalg.svd(Jn, full_matrices=False)
        U = U[:, sv > 1e-10 * sv[0]]
        h = np.sum(U * U, axis=1)
    else:
        h = np.zeros(r.size)
    out = []
    for a, name in enumerate(AXES):
        chi2 = float(np.sum(r[a::3] ** 2))
        dof = float(r[a::3].size - np.sum(h[a::3]))
        if not dof > 0.5:
            return None
        out.append({"axis": name, "chi2": chi2, "dof": dof, "ratio": chi2 / dof,
                    "p_high": float(stats.chi2.sf(chi2, dof))})
    return out


def per_output_gate(levels: Optional[list], gof_p_min: float, gof_ratio_max: float,
                    why_not: str = "") -> GateOutcome:
    """The gate ``goodness_of_fit_per_output`` on :func:`output_levels`' ``levels`` (skipped, with
    ``why_not``, when None)."""
    name = "goodness_of_fit_per_output"
    if levels is None:
        return GateOutcome(name, None, "model_mismatch", why_not or "not testable: an output has no dof left")
    m = len(levels)
    bad = [x for x in levels if min(1.0, m * x["p_high"]) < gof_p_min and x["ratio"] > gof_ratio_max]
    txt = "; ".join(f"{x['axis']}: chi2/dof {x['ratio']:.3g} on {x['dof']:.0f} dof" for x in levels)
    worst = max(levels, key=lambda x: x["ratio"])
    if bad:
        b = bad[0] if len(bad) == 1 else max(bad, key=lambda x: x["ratio"])
        txt = (f"each output against its declared noise ({txt}): output {b['axis']} scatters "
               f"{np.sqrt(b['ratio']):.2g} times its sd_{b['axis']} (p = {min(1.0, m * b['p_high']):.2g} after "
               f"Bonferroni over {m}, ratio > {gof_ratio_max:g}) although the pooled chi2 may pass: its declared "
               f"noise understates its scatter, or a term acting on {b['axis']} is missing; the uncertainties of "
               f"{b['axis']}'s parameters would be understated (run `triadcal diagnose`, or fit without the sd_* "
               "columns so that each output's noise is estimated)")
    else:
        low = [x for x in levels if x["ratio"] < 1.0 / gof_ratio_max
               and stats.chi2.cdf(x["chi2"], x["dof"]) * m < gof_p_min]
        txt = f"each output against its declared noise: {txt}"
        if low:
            txt += ("; below its declared noise: " + ", ".join(x["axis"] for x in low)
                    + " (its parameters' uncertainties conservative)")
    return GateOutcome(name, not bad, "model_mismatch", txt, worst["ratio"],
                       f"p >= {gof_p_min:g} (Bonferroni over {m}) or ratio <= {gof_ratio_max:g}, per output")
