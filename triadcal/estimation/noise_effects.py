"""The noise effects as options of the fit: ``fit --effects ...,position_error`` and
``fit --effects ...,heavy_tails`` (issue 18: every name the diagnosis can answer is one command
away from its refit).

``position_error`` is a variance component, not a mean term: the bench's random positioning and
wobble errors add ``tau C_i`` to the covariance of visit ``i``'s three mean outputs, with ``C_i`` the
3 x 3 block of eq. 4 of the seed paper per arcsec^2 of positioning error
(:func:`triadcal.models.effects.position_error.covariance_blocks`, wobble at ``wobble_ratio`` of
the positioning error; diagonal when gravity lies along one sensing axis, not on oblique poses) and
``tau = sigma_1^2``. ``tau`` is estimated by restricted maximum likelihood (REML, Patterson &
Thompson 1971) of the linearised problem (:func:`reml_block_component`; with diagonal blocks it is
the score equation ``sum_i c_i (r_i^2 - (1 - h_i) v_i) / v_i^2 = 0`` of
:func:`reml_variance_component`, ``v_i = s_i^2 + tau c_i`` and ``h_i`` the leverages of the weighted
fit), alternating with the refit of the mean on the new covariance (GLS on oblique poses,
:func:`triadcal.estimation.whitening.bench_whitening`). Its standard uncertainty is from the expected
information, ``u(sigma_1) = u(tau) / (2 sigma_1)`` (delta method). The result is the lab file's
bench errors with the source "estimated from the residuals": a residual misfit of the mean model is
absorbed into it, which is why the diagnosis lets a noise candidate win only when no structure is
left. (The diagnosis's refit estimates the two variances, bench axes and wobble, separately.)

``heavy_tails`` is the Student-t likelihood of the fit (``loss = "student_t"``), its dof ``nu``
and its scale (the t's SD in units of the noise model's) chosen by profile likelihood
(:func:`triadcal.models.effects.heavy_tails.logpdf`, ``profile_scale``) over a grid at the
least-squares fit. The fit's IRLS weights are those of the unit-scale t, and its covariance the
M-estimator's sandwich, which holds whatever the scale; ``sample``'s Student-t likelihood has the
fitted scale (the output noise's SD times it), so that contamination, which adds variance as well
as tails, does not narrow the credible intervals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from scipy import optimize

from ..errors import InputError
from ..models.effects import NOISE_EFFECTS
from ..models.effects import heavy_tails as ht
from ..models.model import Model
from .joint import WOBBLE_TO_POSITION, BenchErrors, fit_joint, noise_of

#: Student-t dof tried by the profile likelihood of ``heavy_tails``
NU_GRID = ht.NU_GRID


def split_effects(effects: Sequence[str]) -> tuple[list, list]:
    """(mean effects, noise effects) of a list of effect names."""
    effects = list(effects)
    return [e for e in effects if e not in NOISE_EFFECTS], [e for e in effects if e in NOISE_EFFECTS]


def reml_variance_component(r: np.ndarray, s2: np.ndarray, c: np.ndarray, h: np.ndarray) -> tuple[float, float]:
    """``(tau, u(tau))`` solving the linearised REML equation of the module docstring for the
    variance component ``tau >= 0`` multiplying the sensitivities ``c`` (all arrays of one shape:
    residuals ``r``, known variances ``s2``, leverages ``h``)."""
    r2, s2, c, q = (np.asarray(a, float).reshape(-1) for a in (np.square(r), s2, c, 1.0 - np.asarray(h)))

    def score(tau):
        v = s2 + tau * c
        return float(np.sum(c * (r2 - q * v) / v ** 2))

    if score(0.0) <= 0.0:
        tau = 0.0
    else:
        hi = max(float(np.max(r2 / np.maximum(c, 1e-300))), 1e-12)
        while score(hi) > 0.0:
            hi *= 10.0
        tau = optimize.brentq(score, 0.0, hi, xtol=1e-14 * hi, rtol=1e-12)
    v = s2 + tau * c
    info = 0.5 * float(np.sum(q * c ** 2 / v ** 2))
    return tau, (1.0 / math.sqrt(info) if info > 0 else math.inf)


def reml_block_component(r: np.ndarray, X: np.ndarray, G: np.ndarray) -> tuple[float, float]:
    """``(tau, u(tau))``: the REML estimate of ``tau >= 0`` in ``V = I + tau G`` with ``G`` block-diagonal
    over visits, (n, 3, 3), for the linearised problem of residuals ``r`` (3n,) and Jacobian ``X``
    (3n, p), both normalised by the known noise. With ``P = V^-1 - V^-1 X (X' V^-1 X)^-1 X' V^-1`` the
    score and the expected information are (Patterson & Thompson 1971; Harville 1977, eqs. 4.3, 4.5)

        U = 1/2 (r' P G P r - tr(P G)),    I = 1/2 tr(P G P G),

    computed in the space whitened by ``V``'s blocks (``M = L^-1 G L^-T``, ``Q`` an orthonormal basis of
    the whitened ``X``, ``e`` the whitened residual off ``Q``: ``r' P G P r = e' M e``,
    ``tr(P G) = tr M - tr(Q' M Q)``, ``tr(P G P G) = tr M^2 - 2 tr(Q' M^2 Q) + ||Q' M Q||^2``); ``U = 0``
    solved by Brent's method. With diagonal blocks it is :func:`reml_variance_component` with the
    leverages of the weighted fit."""
    from .flicker_noise import _orthobasis
    from .whitening import BlockWhitening

    G = np.asarray(G, float)
    n = G.shape[0]
    eye = np.eye(3)[None]

    def pieces(tau):
        W = BlockWhitening(eye + tau * G)
        Q, _ = _orthobasis(W.apply(X))
        rt = W.apply(r)
        e = rt - Q @ (Q.T @ rt)
        M = np.linalg.solve(W.L, np.swapaxes(np.linalg.solve(W.L, G), 1, 2))      # L^-1 G L^-T (symmetric)
        Q3, e3 = Q.reshape(n, 3, -1), e.reshape(n, 3)
        QMQ = np.einsum("nak,nab,nbl->kl", Q3, M, Q3)
        score = 0.5 * (float(np.einsum("na,nab,nb->", e3, M, e3)) - float(np.trace(M, axis1=1, axis2=2).sum())
                       + float(np.trace(QMQ)))
        M2 = M @ M
        info = 0.5 * (float(np.trace(M2, axis1=1, axis2=2).sum())
                      - 2.0 * float(np.einsum("nak,nab,nbk->", Q3, M2, Q3)) + float(np.sum(QMQ * QMQ)))
        return score, info

    if pieces(0.0)[0] <= 0.0:
        tau = 0.0
    else:
        hi = 1.0 / max(float(np.max(np.trace(G, axis1=1, axis2=2))), 1e-300)
        while pieces(hi)[0] > 0.0:
            hi *= 10.0
        tau = optimize.brentq(lambda t: pieces(t)[0], 0.0, hi, xtol=1e-12 * hi, rtol=1e-10)
    info = pieces(tau)[1]
    return tau, (1.0 / math.sqrt(info) if info > 0 else math.inf)


@dataclass(frozen=True)
class PositionErrorEstimate:
    """sigma_1 (arcsec) estimated from the residuals, with its standard uncertainty."""

    sigma_position_arcsec: float
    u_arcsec: float
    rounds: int
    bench_errors: BenchErrors

    def to_dict(self) -> dict:
        return {"position_error_sigma": {"value": self.sigma_position_arcsec, "u": self.u_arcsec,
                                         "unit": "arcsec"},
                "method": "REML from the residuals, alternating with the refit of the mean",
                "rounds": self.rounds}


def _all_values(result, model: Model) -> dict:
    fixed = result.extra.get("fixed", {})
    return {n: (result.parameters[n].value if n in result.parameters
                else fixed.get(n, {}).get("value", model.spec[n].nominal)) for n in model.names}


def position_error_from_residuals(campaign, effects: Sequence[str], *, reference_temperature_C: float = 20.0,
                                  wobble_ratio: float = WOBBLE_TO_POSITION, rounds: int = 5,
                                  **fit_kw) -> PositionErrorEstimate:
    """The bench's positioning error sigma_1 by REML from the residuals of the joint fit of
    ``effects`` (module docstring); needs the output noise in the data (sd_*/u_w_* or Q_V2s)."""
    from .whitening import bench_blocks

    noise = noise_of(campaign)
    if not noise.known:
        raise InputError(f"{campaign.source or 'campaign'}: position_error is a variance added to the output noise, "
                         "but the data give no output noise (no sd_*/n_samples or u_w_* columns, no Q_V2s "
                         "metadata): the two cannot be told apart")
    model = Model(effects, reference_temperature_C)
    s = noise.sigma
    s1, u1, be, done = 0.0, math.inf, None, 0
    for done in range(1, rounds + 1):
        result, problem, sol = fit_joint(campaign, effects, reference_temperature_C=reference_temperature_C,
                                         bench_errors=be, return_problem=True, **fit_kw)
        raw = getattr(problem, "raw", problem)       # not whitened (the fit is GLS on oblique poses)
        r, X = raw.residuals_and_jacobian(sol.x)
        scale = (np.asarray(raw.sigma, float) / s).reshape(-1)      # normalised by the data's noise only
        p = model.to_internal(_all_values(result, model))
        G = bench_blocks(model, p, campaign, s, (1.0, 1.0, wobble_ratio ** 2))
        tau, u_tau = reml_block_component(r * scale, X * scale[:, None], G)
        new = math.sqrt(tau)
        u1 = u_tau / (2.0 * new) if new > 0 else math.sqrt(u_tau)
        converged = abs(new - s1) <= 1e-3 * max(new, 1e-3)
        s1 = new
        be = BenchErrors(s1, wobble_ratio * s1,
                         source=(f"estimated from the residuals (position_error: REML, sigma_1 = {s1:.3g} +- "
                                 f"{u1:.2g} arcsec; wobble taken as {wobble_ratio:g} of the positioning error)"))
        if converged:
            break
    return PositionErrorEstimate(s1, u1, done, be)


def heavy_tails_dof(campaign, effects: Sequence[str], *, reference_temperature_C: float = 20.0,
                    **fit_kw) -> tuple[float, dict, float]:
    """``(nu, log likelihood at each dof, scale)``: the Student-t dof of the normalised residuals by
    profile likelihood over :data:`NU_GRID` (``inf`` kept when the normal is likelier), the scale
    profiled at each (:func:`triadcal.models.effects.heavy_tails.profile_scale`: the t's SD in units
    of the noise model's, 1 when the noise model holds; contamination makes it larger)."""
    noise = noise_of(campaign)
    result, problem, sol = fit_joint(campaign, effects, reference_temperature_C=reference_temperature_C,
                                     return_problem=True, **fit_kw)
    z = np.asarray(sol.r, float)
    if not noise.known:
        z = z / max(float(np.sqrt(np.mean(z ** 2))), 1e-300)
    nu, scale, ll = ht.profile_dof(z, NU_GRID + (math.inf,))
    return nu, ll, scale


def resolve_noise_effects(campaign, effects: Sequence[str], *, bench_errors: Optional[BenchErrors] = None,
                          loss: str = "l2", nu: float = 4.0, **fit_kw) -> dict:
    """What the noise effects among ``effects`` turn into for ``fit_joint``: ``effects`` (the mean
    effects), ``bench_errors`` (``position_error``: a variance component estimated from the
    residuals), ``loss`` and ``nu`` (``heavy_tails``: the Student-t likelihood, its dof by profile
    likelihood), ``notes`` and ``extra`` for the result. Conflicts are refused: the lab's (or the
    replicates') bench errors with ``position_error``, another robust loss with ``heavy_tails``."""
    mean, noise_fx = split_effects(effects)
    out = {"effects": mean, "bench_errors": bench_errors, "loss": loss, "nu": nu, "t_scale": 1.0, "notes": [],
           "extra": {}, "whitening": None}
    if not noise_fx:
        return out
    out["extra"]["noise_effects"] = list(noise_fx)
    if "heavy_tails" in noise_fx:
        if loss != "l2":
            raise InputError(f"heavy_tails is the Student-t likelihood: it cannot be combined with --loss {loss}")
        nu_hat, _, scale = heavy_tails_dof(campaign, mean, **fit_kw)
        out["extra"]["heavy_tails"] = {"dof": None if math.isinf(nu_hat) else nu_hat, "scale": scale,
                                       "scale_unit": "1 (of the noise model's SD)"}
        if math.isinf(nu_hat):
            out["notes"].append("heavy_tails: the profile likelihood prefers the normal (no dof of the grid "
                                f"{', '.join(f'{g:g}' for g in NU_GRID)} is likelier); fitted by least squares")
        else:
            out["loss"], out["nu"], out["t_scale"] = "student_t", nu_hat, scale
            out["notes"].append(f"heavy_tails: Student-t likelihood, dof nu = {nu_hat:g} and scale {scale:.3g} (of "
                                "the noise model's SD) by profile likelihood over "
                                f"{', '.join(f'{g:g}' for g in NU_GRID)}; the fit's covariance is the M-estimator's "
                                "sandwich, whatever the scale; sample's likelihood has the scale")
    if "position_error" in noise_fx:
        if bench_errors is not None:
            raise InputError("position_error estimates the bench's random errors from the residuals, but they are "
                             f"also given ({bench_errors.source}): choose one")
        pe = position_error_from_residuals(campaign, mean, loss=out["loss"], nu=out["nu"], **fit_kw)
        out["bench_errors"] = pe.bench_errors
        out["extra"]["position_error"] = pe.to_dict()
        out["notes"].append(f"position_error: the bench's random errors estimated from the residuals, sigma_1 = "
                            f"{pe.sigma_position_arcsec:.3g} +- {pe.u_arcsec:.2g} arcsec (REML); a misfit of the "
                            "mean model would be absorbed here too: check the diagnosis")
    if "flicker_noise" in noise_fx:
        from .flicker_noise import flicker_from_residuals

        fl, _ = flicker_from_residuals(campaign, mean, bench_errors=out["bench_errors"], loss=out["loss"],
                                       nu=out["nu"], **fit_kw)
        out["whitening"] = fl.whitening
        out["extra"]["flicker_noise"] = fl.to_dict()
        out["notes"].append("flicker_noise: 1/f noise floor B_f per output by REML, mean by GLS (residuals whitened "
                            "with the covariance of the visit means), B_f = " + ", ".join(
                                f"{a} {b * k:.3g} +- {u * k:.2g} ug" for a, b, u, k in
                                zip("xyz", fl.Bf, fl.u_Bf, fl.to_ug))
                            + "; u of the parameters from the GLS; the biases are the campaign's mean bias")
    return out


def fit_with_noise_effects(campaign, effects: Sequence[str], *, bench_errors: Optional[BenchErrors] = None,
                           loss: str = "l2", nu: float = 4.0, **kw):
    """``fit_joint`` with the noise effects among ``effects`` resolved by
    :func:`resolve_noise_effects`."""
    r = resolve_noise_effects(campaign, effects, bench_errors=bench_errors, loss=loss, nu=nu, **kw)
    result = fit_joint(campaign, r["effects"], bench_errors=r["bench_errors"], loss=r["loss"], nu=r["nu"],
                       whitening=r["whitening"], **kw)
    result.notes.extend(r["notes"])
    result.extra.update(r["extra"])
    return result
