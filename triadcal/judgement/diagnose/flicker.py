"""The ``flicker_noise`` candidate of the diagnosis: 1/f noise that correlates the visit means.

**Score.** The added covariance is ``tau W`` in the normalised residuals, ``W`` block-diagonal
over the outputs with blocks ``G_a = C / (sigma_a sigma_a')`` (``C`` the covariance per unit
``B_f^2`` of the visit means' deviations from the campaign mean,
:func:`triadcal.models.effects.flicker_noise.centred_covariance`; one common ``tau = B_f^2`` for
the three outputs). The restricted-likelihood score at ``tau = 0`` and its expected information
are (H the hat matrix of the base fit)

    U = 1/2 (r' W r - tr(W (I - H))),    I = 1/2 tr((I - H) W (I - H) W),

and ``z = U / sqrt(I)`` is one-sided (a variance cannot be negative; ``score`` = z|z|). Its p is
the larger (less significant) of two tails: (i) the score statistic ``z^2``, capped at the base
fit's excess ``chi2 - dof`` (a variance term cannot gain more than the scatter left to explain),
as chi2_1 (halved, one sided) in Wilson-Hilferty's normal form -- the form the mean candidates'
chi2_k scores take in their far tail, where scipy underflows -- so that a gross misfit of the mean
does not rank flicker above the mean term that explains it and crowd that term out of the refits
(a withheld bias tempco on the validation design: chi2 = 6.0e6, the flicker's z^2 = 1.8e12); (ii) Satterthwaite's scaled chi2
``g chi2_h`` of the quadratic form ``q = r' W r`` (exact null mean ``tr(W (I - H))``, variance
``4 I``), whose tail is heavier than the normal one of ``z`` near the detection limit.
With the noise estimated from the residuals (no sd_* / Q) the white level is a nuisance
parameter, and the test is the locally best invariant one of a variance component against white
noise of unknown level (King & Hillier, JRSS B 47, 98-102, 1985; Durbin & Watson's ratio): ``rho = r' W r /
r' r``, whose null distribution does not depend on the level, referred to
:func:`.correlated.ratio_test` (exact three moments, Pearson III, saddlepoint where it decides) --
the ``correlated`` family's test with the flicker's covariance as the kernel. No cap is needed:
``rho`` is bounded by the largest eigenvalue of ``W``, so a gross misfit of the mean cannot make it
arbitrarily significant.

**Refit.** REML of the common ``tau`` alternating with the GLS refit of the mean (at most 3 rounds, until B_f moves by < 0.1 %;
:func:`triadcal.estimation.flicker_noise.reml_tau` on the linearised problem -- with the noise
estimated :func:`~triadcal.estimation.flicker_noise.reml_tau_profiled`, ``V = s2 (I + tau W)``, the
white level profiled out, ``B_f^2 = s2 tau`` and its u from the joint information
(:func:`~triadcal.estimation.flicker_noise.profiled_u`) --, the mean by the
joint fit's LM on residuals whitened per output with the Cholesky factor of ``I + tau G_a`` in
time order). For the rest of the diagnosis the refit is handed over like ``position_error``'s:
``r = r~ L_ii`` with ``var_scale = L_ii^2`` (``r~`` the whitened residuals, ``L_ii`` the one-step
prediction SDs), so that ``r / sqrt(var_scale)`` are the whitened residuals the slice tests see
after the refit, and the pointwise log-likelihoods ``-r~_i^2 / 2 - ln L_ii`` sum to the exact
Gaussian log-likelihood of the correlated model (``ln det V = 2 sum ln L_ii``; PSIS-LOO then
leaves out one-step predictions, an approximation).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ...estimation.flicker_noise import (AxisWhitening, WhitenedProblem, normalised_components, profiled_u, reml_tau,
                                         reml_tau_profiled)
from ...estimation.joint import levenberg_marquardt
from .fitting import FitState, _chi2_logsf, _Subset, whitened_state
from .results import Candidate

ROUNDS = 3


def _wilson_hilferty_logsf(S: float, k: float) -> float:
    """log P(chi2_k > S) in Wilson-Hilferty's normal form (the far-tail form of the mean
    candidates' scores, fitting._chi2_logsf; conservative against the exact tail for k = 1)."""
    zz = ((S / k) ** (1.0 / 3.0) - (1.0 - 2.0 / (9.0 * k))) / math.sqrt(2.0 / (9.0 * k))
    return float(stats.norm.logsf(zz))


def flicker_candidate(campaign, base: FitState, sigma: np.ndarray, noise_known: bool) -> Candidate:
    """The one-sided REML score test of a common flicker floor at ``B_f = 0`` (module docstring)."""
    name = "flicker_noise"
    if campaign.n_visits < 4 or np.ptp(campaign.time_s) <= 0:
        return Candidate(name, False, "flicker needs visits at four or more different times")
    from ...estimation import flicker_noise as fl

    G = normalised_components(campaign, sigma)
    if not noise_known:
        # the level-free ratio test (module docstring)
        from .correlated import ratio_test
        from .fitting import _hat_q

        t = ratio_test(np.asarray(base.r, float), _hat_q(base.J), G)
        if t is None:
            return Candidate(name, False, "the campaign's visits carry no information on a flicker floor")
        z = float(t["z"])
        return Candidate(name, True, k=1, score=z * abs(z), score_logp=min(float(t["logp"]), 0.0))
    _, U, info, trace = fl.reml_pieces(base.r, base.J, G, np.zeros(3), campaign.time_s, [[0, 1, 2]],
                                       return_trace=True)
    if not info[0, 0] > 0:
        return Candidate(name, False, "the campaign's visits carry no information on a flicker floor")
    z = float(U[0] / math.sqrt(info[0, 0]))
    # p from Satterthwaite's scaled chi2 of the quadratic form q = r'Wr (null mean m = tr(W(I-H)),
    # variance 2 tr((W(I-H))^2) = 4 I): its tail is exponential, where the normal form of z would
    # make a large score look far more significant than a mean candidate's chi2 of the same misfit
    m = float(trace[0])
    v = 4.0 * float(info[0, 0])
    q = 2.0 * float(U[0]) + m
    g, h = v / (2.0 * m), 2.0 * m * m / v
    logp = float(stats.norm.logsf(z))
    if z > 0:
        # the score statistic z^2 ~ chi2_1 (one-sided: half its tail), on the scale of the mean
        # candidates' chi2_k scores (same function, same far-tail form): ranks the refits fairly
        excess = max(float(base.chi2) - float(base.dof), 0.0)
        logp = math.log(0.5) + _wilson_hilferty_logsf(min(z * z, excess), 1.0)
        if m > 0:      # Satterthwaite's tail of q: the less significant of the two is kept
            logp = max(logp, _chi2_logsf(max(q, 0.0) / g, h))
    return Candidate(name, True, k=1, score=z * abs(z), score_logp=min(logp, 0.0))


def fit_flicker(full, campaign, base: FitState, names, sigma: np.ndarray, noise_known: bool = True) -> FitState:
    """REML of a common ``B_f^2`` with the GLS refit of the mean (module docstring); the state's
    ``extra_params`` hold ``flicker_Bf`` (output unit, and ug) and ``flicker_Bf2`` with u. With the
    noise estimated (``noise_known`` False) the white level is profiled out of the REML and ``B_f^2``
    is ``s2 tau``, in the output unit as with the noise known."""
    G = normalised_components(campaign, sigma)
    sub = _Subset(full, names, base.x_full)
    x = base.x_full[sub.cols].copy()
    tau, u_tau, whitening, s2 = np.zeros(3), math.inf, None, 1.0
    sol = None
    for k in range(ROUNDS):
        r_raw, J_raw = sub.residuals_and_jacobian(x)
        if noise_known:
            new, u, _, _ = reml_tau(r_raw, J_raw, G, campaign.time_s, [[0, 1, 2]], tau0=tau)
        else:
            new, s2_new = reml_tau_profiled(r_raw, J_raw, G, campaign.time_s, [[0, 1, 2]])
            u = profiled_u(r_raw, J_raw, G, new, s2_new, campaign.time_s, [[0, 1, 2]]) / s2_new
        u_tau = float(u[0])
        if k > 0 and abs(math.sqrt(new[0]) - math.sqrt(tau[0])) <= 1e-3 * math.sqrt(max(new[0], 1e-300)):
            break                      # B_f moved by < 0.1 %: the mean of the last round stands
        tau = new
        if not noise_known:
            s2 = s2_new                # the level of the tau the whitening uses
        whitening = AxisWhitening(G, tau, campaign.time_s)
        sol = levenberg_marquardt(WhitenedProblem(sub, whitening), x, max_iter=60)
        x = sol.x
    x_full = sub.embed(x)
    state = whitened_state(names, x_full, sol, whitening, noise_known)
    K = np.array([abs(x_full[full.index[f"K_{a}"]]) for a in "xyz"])
    bf2 = float(tau[0]) * s2
    u_tau = u_tau * s2
    bf = math.sqrt(bf2)
    u_bf = u_tau / (2.0 * bf) if bf > 0 else math.sqrt(u_tau)
    unit = campaign.output_unit
    state.extra_params = {
        "flicker_Bf": {"value": bf, "u": u_bf, "unit": unit, "value_ug": bf * float(np.mean(K)) * 1e6,
                       "u_ug": u_bf * float(np.mean(K)) * 1e6},
        "flicker_Bf2": {"value": bf2, "u": u_tau, "unit": f"{unit}^2"},
    }
    return state
