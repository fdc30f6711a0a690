"""What a robust fit (``--loss huber`` or ``student_t``) may claim about its fit and its outliers.

A robust loss is asked for because a few observations are expected to be gross errors. Judging
its goodness of fit by the chi^2 of every residual against the known noise (as for least
squares) refuses exactly the data it was asked for: an outside case, four 30-sigma outliers in
540 observations of an otherwise exact model, gave chi^2/dof 8.2 and ``model_mismatch``. Two
questions replace it:

1. *Do the other observations fit?* An observation is an outlier when its normalised residual
   exceeds ``z_out = Phi^-1(1 - alpha / 2n)`` (``alpha`` the gates' ``gof_p_min``; under the
   noise, with the model right, any residual of the ``n`` is that far with probability
   ``alpha``, Bonferroni). The chi^2 of the rest against the known noise, ``n_in - p`` dof, is
   the goodness of fit (the truncation at ``z_out`` >= 3.9 lowers its expectation by < 0.1 %).
2. *Do the outliers still move the answer?* The loss bounds each observation's pull ``psi(r)``
   (Huber: ``c`` = 1.345), not removes it. To first order the outliers shift the estimate by
   ``delta = H^-1 J_out^T psi(r_out)`` with ``H = J^T diag(psi'(r)) J`` (Huber 1981, sec. 7.6:
   the influence of a bounded score; ``psi' = 0`` beyond ``c``). A shift of a parameter above
   its stated u (``SHIFT_MAX_U``) means the robust answer is still the outliers' answer in part:
   refused as ``model_mismatch`` naming the parameter and the shift.

Without a known noise level a robust loss had no scale: the residuals were normalised by the
relative weights ``1/sqrt(tau)`` alone, ~1e-5 in a file in V, so every residual was inside
Huber's ``c`` and the "robust" fit was least squares (four 30-sigma outliers moved the answer as
much as without the loss). :func:`robust_scale` estimates each output's scale as
``1.4826 MAD`` of its residuals (Huber 1981, sec. 5.1: the MAD's 50 % breakdown point),
corrected by ``sqrt(n / (n - p/3))`` for the fitted parameters, refits, and repeats until the
scales agree to 1 %; no goodness of fit is then claimed, as for least squares.
"""
from __future__ import annotations

import numpy as np
from scipy import stats

from ..errors import InputError
from .gates import GateOutcome
from .noise_model import NoiseSource

LOSSES = ("l2", "huber", "student_t")

SHIFT_MAX_U = 1.0       # the outliers' first-order pull on any parameter, in its stated u
LISTED_MAX = 6          # outliers named one by one in the note


def robust_weights(r: np.ndarray, loss: str, nu: float = 4.0, c: float = 1.345) -> np.ndarray:
    """IRLS weights ``psi(r)/r`` of normalised residuals for a robust loss: Huber with ``c``, or
    the Student-t of ``nu`` dof scaled to unit variance (the residuals are normalised by the
    output noise's SD), ``psi(r) = (nu + 1) r / (nu - 2 + r^2)`` (the MLE's score; for
    ``nu <= 2``, which has no variance, the standard t's ``nu + r^2``)."""
    if loss == "l2":
        return np.ones_like(r)
    if loss == "huber":
        a = np.abs(r)
        return np.where(a <= c, 1.0, c / np.maximum(a, 1e-300))
    if loss == "student_t":
        return (nu + 1.0) / ((nu - 2.0 if nu > 2.0 else nu) + r * r)
    raise InputError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")


def robust_psi_slope(r: np.ndarray, loss: str, nu: float = 4.0, c: float = 1.345) -> np.ndarray:
    """``psi'(r)`` of :func:`robust_weights`' loss (for the sandwich covariance)."""
    if loss == "l2":
        return np.ones_like(r)
    if loss == "huber":
        return (np.abs(r) <= c).astype(float)
    if loss == "student_t":
        a = nu - 2.0 if nu > 2.0 else nu
        return (nu + 1.0) * (a - r * r) / (a + r * r) ** 2
    raise InputError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")


def outlier_threshold(n: int, alpha: float) -> float:
    """``|r|`` beyond which one of ``n`` standard-normal residuals is an outlier at family-wise ``alpha``."""
    return float(stats.norm.isf(alpha / (2.0 * max(n, 1))))


def robust_check(sol, u, names, loss: str, nu: float, alpha: float, noise_known: bool, campaign, notes: list,
                 by_visit: bool = True):
    """``(gof, [gate])`` of a robust fit ``sol`` (:func:`robust_judgement`); its notes appended to ``notes``."""
    name = loss if loss != "student_t" else f"student_t(nu={nu:g})"
    gof, gate, more = robust_judgement(sol.r, sol.J, sol.weights * sol.r, robust_psi_slope(sol.r, loss, nu), u, names,
                                       name, alpha, noise_known, campaign, by_visit)
    notes.extend(more)
    return gof, [gate]


def robust_judgement(r: np.ndarray, J: np.ndarray, psi: np.ndarray, psi_slope: np.ndarray, u: np.ndarray, names,
                     loss: str, alpha: float, noise_known: bool, campaign=None, by_visit: bool = True):
    """``(gof, gate, notes)`` of a robust fit. ``r``: normalised residuals at the answer; ``J``
    their Jacobian; ``psi``/``psi_slope`` the loss's score and its slope at ``r``; ``u`` the
    stated uncertainties of ``names``. ``gof``: ``{"p_value", "ratio", "what", ...}`` of the
    inliers against the known noise (None without one); ``gate``: the ``outliers`` gate;
    ``notes``: the down-weighted observations, named (``campaign`` rows when ``by_visit``)."""
    r = np.asarray(r, float)
    n, p = r.size, J.shape[1]
    scale = 1.0
    if not noise_known:
        mad = float(np.median(np.abs(r - np.median(r))))
        scale = 1.4826 * mad if mad > 0 else 1.0
    z = r / scale
    z_out = outlier_threshold(n, alpha)
    out = np.abs(z) > z_out
    n_out = int(out.sum())
    gof = None
    if noise_known:
        dof = n - n_out - p
        if dof > 0:
            chi2_in = float(np.sum(r[~out] ** 2))
            gof = {"p_value": float(stats.chi2.sf(chi2_in, dof)), "ratio": chi2_in / dof,
                   "what": (f"chi2/dof against the known noise of the {n - n_out} observations within "
                            f"{z_out:.2f} sigma ({dof} dof; {n_out} beyond, the {loss} loss's outliers)"),
                   "chi2_inliers": chi2_in, "dof_inliers": dof, "n_outliers": n_out, "outlier_sigma": z_out}
    notes = []
    if n_out == 0:
        gate = GateOutcome("outliers", True, "model_mismatch",
                           f"no observation beyond {z_out:.2f} sigma of the {loss} fit", 0.0,
                           f"first-order shift <= {SHIFT_MAX_U:g} u")
        return gof, gate, notes
    shift = np.zeros(p)
    ok_rows = np.all(np.isfinite(J), axis=1)
    H = J[ok_rows].T @ (J[ok_rows] * psi_slope[ok_rows, None])
    try:
        shift = np.linalg.lstsq(H, J[out].T @ psi[out], rcond=None)[0]
    except np.linalg.LinAlgError:
        shift = np.full(p, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.abs(shift) / np.asarray(u, float)
    worst = int(np.nanargmax(rel)) if np.any(np.isfinite(rel)) else 0
    worst_rel = float(rel[worst]) if np.isfinite(rel[worst]) else float("inf")
    named = _named(z, out, campaign, by_visit)
    notes.append(f"{loss} loss: {n_out} of {n} observations beyond {z_out:.2f} sigma "
                 f"({'of the known noise' if noise_known else 'of the noise estimated robustly'}; "
                 f"any of them by chance: p = {alpha:g}), down-weighted: {named}; together they move {names[worst]} "
                 f"by {worst_rel:.2f} u (first order), the most of any parameter")
    passed = worst_rel <= SHIFT_MAX_U
    reason = (f"{n_out} observation(s) beyond {z_out:.2f} sigma, down-weighted by the {loss} loss, still move "
              f"{names[worst]} by {worst_rel:.2f} u")
    if not passed:
        reason += (f" (> {SHIFT_MAX_U:g} u): the robust answer is still in part the outliers' answer; find and remove "
                   "their cause (or the visits), or the model misses something that looks like outliers "
                   "(`triadcal diagnose`)")
    return gof, GateOutcome("outliers", passed, "model_mismatch", reason, worst_rel,
                            f"first-order shift <= {SHIFT_MAX_U:g} u"), notes


def _named(z, out, campaign, by_visit) -> str:
    idx = np.flatnonzero(out)
    order = idx[np.argsort(-np.abs(z[idx]))][:LISTED_MAX]
    parts = []
    for i in order:
        if by_visit and campaign is not None and z.size == 3 * campaign.n_visits:
            k, a = divmod(int(i), 3)
            line = (f"line {int(campaign.lines[k])} " if getattr(campaign, "lines", None) is not None else "")
            parts.append(f"{line}({campaign.position[k]} at {float(campaign.setpoint_C[k]):g} degC) "
                         f"{'xyz'[a]} {z[i]:+.1f} sigma")
        else:
            parts.append(f"observation {int(i)} {z[i]:+.1f} sigma")
    more = int(out.sum()) - len(parts)
    return "; ".join(parts) + (f"; and {more} more" if more > 0 else "")


def robust_scale(problem, sol, noise: NoiseSource, loss: str, nu: float, max_iter: int):
    """A robust fit's noise scale when the noise is not known: per output ``1.4826 MAD`` of the
    normalised residuals times ``sqrt(n / (n - p/3))``, the weights rescaled and the fit repeated
    (from its answer) until the scales agree to 1 % (:func:`~triadcal.estimation.noise_model.rescaled_outputs`).
    Returns ``(sol, noise, s2)`` with ``s2`` the outputs' variances per unit weight (the white-noise
    intensity Q of each output when the weights were ``1/sqrt(tau)``), or the inputs and None when the
    residuals are not per visit."""
    from ..models.sensor import AXES
    from .noise_model import rescaled_outputs

    r = np.asarray(sol.r, float)
    if r.size % 3:
        return sol, noise, None
    n = r.size // 3
    dof_a = n - len(problem.names) / 3.0
    if dof_a < 3:
        return sol, noise, None

    def mad_squared(res):
        ra = res.reshape(-1, 3)
        mad = 1.4826 * np.median(np.abs(ra - np.median(ra, axis=0)), axis=0) * np.sqrt(n / dof_a)
        return mad ** 2 if np.all(np.isfinite(mad)) and np.all(mad > 0) else None

    refit, s2 = rescaled_outputs(problem, sol, noise, max_iter, mad_squared,
                                 lambda step: np.max(np.abs(np.sqrt(step) - 1.0)) < 0.01, loss=loss, nu=nu)
    if refit is sol:
        return sol, noise, None
    how = (noise.description + f"; the {loss} loss's scale per output, 1.4826 MAD of the residuals (variances per "
           "unit weight " + ", ".join(f"{a} {v:.3g}" for a, v in zip(AXES, s2)) + ")")
    return refit, NoiseSource(problem.sigma, False, how), s2
