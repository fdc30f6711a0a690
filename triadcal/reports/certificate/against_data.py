"""Whether the values a result states are the values its data give, before a certificate prints them.

A result file edited and re-signed (its ``content_sha256`` recomputed) passes the reader's hash check
and, when only values are edited, every check of :mod:`.consistency`: K_x and K_y swapped, or the
reference temperature moved with the values kept, make a self-consistent file whose values are not the
data's (left open by the session of 2026-12-01). With the data given (``--data``, their SHA-256 the
result's), the certificate re-derives the values from them.

The test is one Gauss-Newton step of the result's own model (eq. 1 with its effects, reference
temperature, fixed parameters and local gravity: :meth:`CalibrationResult.full_model`) from the stated
values, weighted by the data's noise (:func:`~triadcal.estimation.noise_model.noise_of`) and, for a
robust fit, by the loss's IRLS weights at the stated values. At a least-squares optimum the gradient is
zero and the step is zero (Nocedal & Wright, *Numerical Optimization*, 2nd ed., eq. 10.23); at values
off it by ``d`` the step returns ``-d`` to first order. The step of each parameter is in units of the
stated standard uncertainty ``u``: ``z = step / u``.

Weights other than the fit's (a lab file's bench errors as variance components, a robust loss's scale)
move the optimum by a fraction of ``u``: both are consistent estimators of the same values, and the
variance of their difference is at most that of the less efficient one (Aitken; for WLS against GLS,
``Var(b_W - b_G) = Var(b_W) - Var(b_G)``). ``VALUES_Z_MAX`` = 5 leaves that room, so values moved by
less than 5 u are not detected (a design limit: they change U's coverage, not the verdict of a reader),
and values moved further are refused, naming the parameter, the value stated, the value the data give
and z.

Not re-derived (the certificate says so in its notes): results whose model the plain eq. 1 on the
data's covariates does not reproduce: a thermal-lag form estimated from the temperature history
(``fit.thermal_lag``), a quantised output (``fit.quantisation``), a play or Preisach hysteresis
(``fit.hysteresis.form``), correlated-noise GLS (``flicker_noise``), results of ``fit-raw``.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from ...models.units import STANDARD_GRAVITY_M_S2

#: a stated value further than this many of its stated standard uncertainties from the value one
#: Gauss-Newton step of the data gives is not the data's (see the module)
VALUES_Z_MAX = 5.0
#: Huber's constant of the fit's ``huber`` loss (triadcal.estimation.joint: c = 1.345)
HUBER_C = 1.345


def not_rederivable(result) -> Optional[str]:
    """Why the values of ``result`` cannot be re-derived from its data by the plain model, or None."""
    fit = result.fit or {}
    if result.method not in ("joint", "classical", "posterior"):
        return f"method {result.method!r}"
    if fit.get("thermal_lag"):
        return "a thermal-lag form estimated from the temperature history (fit.thermal_lag)"
    if fit.get("quantisation"):
        return "a quantised output (fit.quantisation)"
    hyst = fit.get("hysteresis")
    if isinstance(hyst, dict) and hyst.get("form", "offset") != "offset":
        return f"the {hyst.get('form')} hysteresis form (fit.hysteresis)"
    if "flicker_noise" in (result.extra.get("noise_effects") or ()) or result.extra.get("flicker_noise"):
        return "correlated noise fitted by generalised least squares (flicker_noise)"
    return None


def _robust_weights(r: np.ndarray, loss: str, nu: float) -> np.ndarray:
    """IRLS weights psi(r)/r of the fit's loss at normalised residuals ``r`` (scale: 1.4826 MAD)."""
    if loss == "l2":
        return np.ones_like(r)
    s = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    x = r / s if s > 0 else r
    if loss == "huber":
        return np.minimum(1.0, HUBER_C / np.maximum(np.abs(x), 1e-300))
    return (nu + 1.0) / (nu + x * x)                 # student_t


def value_steps(result, campaign) -> dict:
    """``{name: z}``: the Gauss-Newton step of the data from each stated value, in stated ``u``."""
    from ...estimation.noise_model import noise_of

    model, p0 = result.full_model()
    fixed = set(result.extra.get("fixed") or {})
    names = [n for n, q in result.parameters.items()
             if n in model.spec and n not in fixed and q.u is not None and math.isfinite(q.u) and q.u > 0]
    if not names:
        return {}
    g_m_s2 = result.extra.get("local_g_m_s2")
    gravity = float(g_m_s2) / STANDARD_GRAVITY_M_S2 if g_m_s2 else campaign.gravity_g
    cov = campaign.covariates()
    n = campaign.n_visits

    def predict(p) -> np.ndarray:
        w = model.predict(p, cov, gravity)
        return np.stack([np.broadcast_to(np.asarray(c, float), (n,)) for c in w], axis=1)

    sigma = np.asarray(noise_of(campaign).sigma, float)
    w_obs = np.asarray(campaign.w, float)
    r = ((w_obs - predict(p0)) / sigma).ravel()
    cols = []
    for name in names:
        step = result.parameters[name].u * model.spec[name].to_internal
        hi, lo = dict(p0), dict(p0)
        hi[name] = p0[name] + step
        lo[name] = p0[name] - step
        cols.append(((predict(hi) - predict(lo)) / (2.0 * sigma)).ravel())   # d(w/sigma) per u
    J = np.stack(cols, axis=1)
    ok = np.isfinite(r) & np.all(np.isfinite(J), axis=1)
    nu = (result.extra.get("heavy_tails") or {}).get("dof") or 4.0      # fit_joint's default nu
    sw = np.sqrt(_robust_weights(r[ok], str((result.fit or {}).get("loss", "l2")), float(nu)))
    z, *_ = np.linalg.lstsq(J[ok] * sw[:, None], r[ok] * sw, rcond=1e-10)
    return dict(zip(names, (float(v) for v in z)))


def fitted_visits(data, result):
    """The visits of ``data`` the result was fitted to: the file, or the one unit/state of a file of
    several (``fit --unit --state``) whose SHA-256 is the result's ``data_sha256``; the file when none is."""
    sha = result.extra.get("data_sha256")
    if not sha or data.data_sha256 == sha:
        return data
    from ...fleet.select import pair_mask, pairs

    for unit, state in pairs(data):
        if unit == result.unit:
            part = data.select(np.flatnonzero(pair_mask(data, unit, state)), own_origin=True)
            if part.data_sha256 == sha:
                return part
    return data


def check_against_data(result, data_path, source: str):
    """Refuse (:class:`RefusedResult`, one line) a result whose data ``data_path`` are not its data (their
    SHA-256), whose temperature range reaches beyond the data's visits, or whose values the data do not
    give (:func:`values_problem`); the campaign of the fitted visits otherwise. For the consumers that
    write what a result states without a certificate (``export-compensation --data``)."""
    from ...estimation.result_checks import RefusedResult
    from ...io.bench_csv import read_bench_csv
    from .consistency import range_problem

    campaign = fitted_visits(read_bench_csv(data_path), result)
    sha = result.extra.get("data_sha256")
    if not sha:
        raise RefusedResult(f"{source}: refused: the result states no data_sha256, so {data_path} cannot be shown to "
                            "be its data")
    if campaign.data_sha256 != sha:
        raise RefusedResult(f"{source}: refused: the data given ({data_path}) are not those the result was fitted "
                            f"to: their SHA-256 {campaign.data_sha256[:12]}... differs from the result's data_sha256 "
                            f"{sha[:12]}...")
    for why in (range_problem(result, campaign, source), values_problem(result, campaign, source)):
        if why:
            raise RefusedResult(why)
    return campaign


def values_problem(result, campaign, source: str) -> Optional[str]:
    """Why the values ``result`` states are not those its data give (one line), or None; see the module."""
    if not_rederivable(result) is not None or campaign.n_visits == 0:
        return None
    z = value_steps(result, campaign)
    if not z:
        return None
    worst = max(z, key=lambda k: abs(z[k]))
    if abs(z[worst]) <= VALUES_Z_MAX:
        return None
    q = result.parameters[worst]
    gives = q.value + z[worst] * q.u
    moved = sorted((k for k in z if abs(z[k]) > VALUES_Z_MAX), key=lambda k: -abs(z[k]))
    also = f" (also {', '.join(moved[1:4])}{' ...' if len(moved) > 4 else ''})" if len(moved) > 1 else ""
    unit = f" {q.unit}" if q.unit else ""
    return (f"{source}: refused: parameters.{worst}.value = {q.value:.10g}{unit} is not the value its data "
            f"({campaign.source or 'the campaign'}, SHA-256 the result's) give: one Gauss-Newton step of the "
            f"result's model from the stated values moves it to {gives:.10g}{unit}, {z[worst]:+.3g} u "
            f"(more than {VALUES_Z_MAX:g} u){also}; values edited, or the reference temperature "
            f"({result.reference_temperature_C:g} degC) or effects changed after the fit: fit again")


__all__ = ["VALUES_Z_MAX", "check_against_data", "fitted_visits", "not_rederivable", "value_steps", "values_problem"]
