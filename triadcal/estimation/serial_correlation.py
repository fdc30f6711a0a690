"""The gate ``correlated_residuals``: are the errors of visits close in time alike?

The joint fit's u assume independent visit errors. A noise that wanders -- bias instability (1/f),
a Gauss-Markov bias, a random walk -- breaks that: the fit takes the slow part into its values (a
bias, a tempco, whatever the wander resembles), the residuals come out *smaller* than the stated
noise, and the u stay those of white noise. An outside probe's campaigns with AR(1) visit errors
(rho 0.9 between consecutive visits, each visit's error of exactly its stated SD): 7 of 14 were
fitted and sampled with status ok, five of them with a parameter 4.4-6.7 u from the truth, and the
only note, on chi2/dof 0.57, called every u "conservative".

The test is the diagnosis's ``correlated`` family (:mod:`triadcal.judgement.diagnose.correlated`) on
the standardised residuals ``z`` (its kernel with unit sigma):
``rho = z' K z / z' z`` for Gauss-Markov kernels ``exp(-|t_i - t_j| / tau)`` at three correlation
times (a soak, a tenth and the whole of the campaign), its null distribution exact in three moments
under the fit's projection (Durbin & Watson) with a saddlepoint tail where decisions are made,
Bonferroni over the three. ``rho`` does not depend on the residuals' scale, so the test is the same
with known and estimated noise. It fails at the goodness-of-fit gate's level (``gof_p_min``); the
remedy is a fit with the wander in the noise model (``--effects ...,flicker_noise``: 1/f by REML,
the mean by GLS) or the diagnosis (``triadcal diagnose``), which names it."""

from __future__ import annotations

from typing import Optional

import numpy as np

from .gate_outcome import GateOutcome

#: campaigns with more visits than this are not tested here (the kernels are n x n per output)
MAX_VISITS = 3000


def correlated_residuals_gate(campaign, sigma: np.ndarray, r: np.ndarray, J: np.ndarray, p_min: float,
                              result=None) -> Optional[GateOutcome]:
    """The gate (module docstring) on the fit's standardised residuals ``r`` (3n, visit-major) and
    Jacobian ``J``; its evidence in ``result.fit["correlated_residuals"]``. None (not asked) on fewer
    than the family's 20 visits, more than :data:`MAX_VISITS`, or one time."""
    from ..judgement.diagnose.correlated import correlated_test

    n = campaign.n_visits
    if n > MAX_VISITS or not np.all(np.isfinite(J)) or not np.all(np.isfinite(r)):
        return None
    # the kernel on the standardised residuals themselves (sigma 1): a wander is alike in them too, and
    # a weighting that is right in its correlations but not in its levels (a lab file's bench errors
    # stated larger than the data's: chi2/dof 0.53) does not read as a correlation -- with the kernel
    # in the outputs' units (the diagnosis's, exp(...) / (sigma_i sigma_j)) the visits of small sigma
    # dominate and such a campaign was refused at p 4e-8
    Q, _ = np.linalg.qr(np.asarray(J, float))
    res = correlated_test(np.asarray(r, float), Q, campaign.time_s, np.ones((n, 3)))
    if res is None:
        return None
    p = float(res["p_value"])
    ok = p >= p_min
    tau_h = res["tau_s"] / 3600.0
    if result is not None:
        result.fit["correlated_residuals"] = {"p_value": p, "rho": res["rho"], "z": res["z"], "tau_h": tau_h,
                                              "kernel": "exp(-|t_i - t_j| / tau), tau of 0.01, 0.1, 1 x the span"}
    reason = (f"residuals of visits close in time: rho {res['rho']:.3g} at a correlation time of {tau_h:.3g} h "
              f"(z {res['z']:+.2g}, p {p:.2g} Bonferroni over 3 times)")
    if not ok:
        reason += (": the visits' errors are not independent, as the fit's u assume -- a noise that wanders (bias "
                   "instability, 1/f, a Gauss-Markov bias) whose slow part the fit takes into its values, so a low "
                   "chi2 does not make the u conservative; fit with it in the noise model (--effects ...,flicker_noise) "
                   "or run `triadcal diagnose`")
    if not ok and result is not None:
        # the low chi2's note (noise_model.overstated_noise_note) does not hold for correlated errors
        result.notes[:] = [n.replace("so every u is conservative by up to that factor",
                                     "which would make every u conservative were the visits' errors independent; "
                                     "they are not (gate correlated_residuals), so the u are not conservative")
                           for n in result.notes]
    return GateOutcome("correlated_residuals", ok, "model_mismatch", reason, p, f"p >= {p_min:g}")
