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
(``fit.thermal_lag``), a quantised output (``fit.quantisation``), correlated-noise GLS (``flicker_noise``), results of ``fit-raw``. A play or
Prandtl-Ishlinskii hysteresis (``fit.hysteresis``) is re-derived on the branches of its form.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from ...models.units import STANDARD_GRAVITY_M_S2

#: a stated value further than this many of its stated standard uncertainties from the value one
#: Gauss-Newton step of the data gives is not the data's (see the module)
VALUES_Z_MAX = 5.0
#: a stated standard uncertainty smaller than the one the data give (with the fit's weights) by more than
#: this factor is not the data's: an outside probe divided every u by 100 (and by 10) and re-signed the file,
#: and export-compensation wrote the firmware table with u_K_x 2.3e-8 for 1.2e-6. A robust fit's sandwich or
#: a posterior's SD differ from the least-squares u by far less; a Birge-widened or Type B u is larger
U_RATIO_MAX = 2.0


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
    if isinstance(hyst, dict) and hyst.get("form", "offset") not in ("offset", "play", "pi"):
        return f"the {hyst.get('form')} hysteresis form (fit.hysteresis)"
    if "flicker_noise" in (result.extra.get("noise_effects") or ()) or result.extra.get("flicker_noise"):
        return "correlated noise fitted by generalised least squares (flicker_noise)"
    return None


def _robust_weights(r: np.ndarray, loss: str, nu: float) -> np.ndarray:
    """IRLS weights psi(r)/r of the fit's loss (``fit.loss``: ``l2``, ``huber``, ``student_t(nu=...)``) at
    normalised residuals ``r`` scaled by their 1.4826 MAD: the fit's own weight function
    (:func:`triadcal.estimation.robust_check.robust_weights`)."""
    from ...estimation.robust_check import robust_weights

    name = loss.split("(", 1)[0]
    if name == "l2":
        return np.ones_like(r)
    s = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    return robust_weights(r / s if s > 0 else r, name, nu)


def _with_form(result, campaign):
    """The campaign with the branches of the result's hysteresis form (``fit.hysteresis``: a play of
    half-width r from its start, or a Prandtl-Ishlinskii sum, on the visits' temperature history, as
    :mod:`triadcal.estimation.hysteresis_form` fitted them); the campaign itself for the offset form. An
    outside probe's play results with Ca_xy +50 arcsec and K_x +1000 ppm were certified (not re-derived)."""
    from ...estimation.hysteresis_form import with_pi, with_play

    h = (result.fit or {}).get("hysteresis")
    if not isinstance(h, dict):
        return campaign
    if h.get("form") == "play":
        return with_play(campaign, float(h["half_width_C"]), str(h["start"]))
    if h.get("form") == "pi":
        return with_pi(campaign, [float(x) for x in h["pi_half_widths_C"]], [float(x) for x in h["pi_weights"]],
                       str(h["pi_start"]))
    return campaign


def value_steps(result, campaign, with_u: bool = False, gof: Optional[dict] = None):
    """``{name: z}``: the Gauss-Newton step of the data from each stated value, in stated ``u``; with
    ``with_u``, also ``{name: u_data / u}``: the standard uncertainty the data give each parameter (the
    fit's weights, the covariance of the step), over the stated one.

    The weights are the fit's: the data's noise (:func:`~triadcal.estimation.noise_model.noise_of`) plus
    the bench's random errors the result was fitted with (``fit.bench_errors``: a lab file's, or
    ``position_error``'s estimate) as variance components and, on oblique poses, the full covariance of
    each visit's outputs (generalised least squares), as :func:`~triadcal.estimation.joint.fit_joint`
    weights them. With the output noise alone, a quiet unit whose lab file declares 5 arcsec of
    positioning error had its honest bias tempcos 10-12 u from the step (an outside probe: 7 of 9 refused)."""
    from ...estimation.noise_model import BenchErrors, _bench_whitening, noise_of, with_bench_errors

    campaign = _with_form(result, campaign)
    model, p0 = result.full_model()
    fixed = set(result.extra.get("fixed") or {})
    names = [n for n, q in result.parameters.items()
             if n in model.spec and n not in fixed and q.u is not None and math.isfinite(q.u) and q.u > 0]
    if not names:
        return ({}, {}) if with_u else {}
    g_m_s2 = result.extra.get("local_g_m_s2")
    gravity = float(g_m_s2) / STANDARD_GRAVITY_M_S2 if g_m_s2 else campaign.gravity_g
    cov = campaign.covariates()
    n = campaign.n_visits

    def predict(p) -> np.ndarray:
        w = model.predict(p, cov, gravity)
        return np.stack([np.broadcast_to(np.asarray(c, float), (n,)) for c in w], axis=1)

    own = noise_of(campaign)
    noise, white = own, None
    be = (result.fit or {}).get("bench_errors")
    if isinstance(be, dict) and own.known:
        bench = BenchErrors(float(be.get("sigma_position_arcsec") or 0.0), float(be.get("sigma_wobble_arcsec") or 0.0),
                            str(be.get("source", "the result's fit.bench_errors")))
        noise = with_bench_errors(campaign, model, own, bench)
        white = _bench_whitening(campaign, model, noise, bench, None, [])
    sigma = np.asarray(noise.sigma, float)
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
    if white is not None and np.all(np.isfinite(r)) and np.all(np.isfinite(J)):
        r, J = white.apply(r), white.apply(J)
    ok = np.isfinite(r) & np.all(np.isfinite(J), axis=1)
    nu = (result.extra.get("heavy_tails") or {}).get("dof") or 4.0      # fit_joint's default nu
    sw = np.sqrt(_robust_weights(r[ok], str((result.fit or {}).get("loss", "l2")), float(nu)))
    A, b = J[ok] * sw[:, None], r[ok] * sw
    z, *_ = np.linalg.lstsq(A, b, rcond=1e-10)
    steps = dict(zip(names, (float(v) for v in z)))
    if gof is not None:
        # what typeb_problem needs to propagate a source as the fit did: the weighted design (per stated u)
        # and the map of a data change onto its rows
        def rows_of(F):
            x = (np.asarray(F, float) / sigma).ravel()
            if white is not None:
                x = white.apply(x)
            return x[ok] * sw
        gof.update(design=A, rows_of=rows_of, names=names, model=model, p0=p0, cov=cov, gravity=gravity)
    if gof is not None and own.known:
        # the data's own goodness of fit at the step's values (the linearised optimum): for a least-squares
        # fit with a known noise, what the result's goodness-of-fit gates judged (goodness_of_fit_problem)
        e = b - A @ z
        gof.update(chi2=float(e @ e), dof=int(len(b) - np.linalg.matrix_rank(A)),
                   per_output=[float(np.sum(e[a::3] ** 2)) for a in range(3)] if len(e) == 3 * n else None)
    if not with_u:
        return steps
    # the covariance of the step, in stated u: (A^T A)^-1 (pseudo-inverse: a direction the data do not
    # determine gets no variance, so it is never called too narrow); scaled by chi2/dof when the data
    # state no noise level (the fit estimates it)
    cov_z = np.linalg.pinv(A.T @ A, rcond=1e-12, hermitian=True)
    if not own.known and len(b) > len(names):
        cov_z = cov_z * float(np.sum((b - A @ z) ** 2)) / (len(b) - len(names))
    ratio = dict(zip(names, (float(math.sqrt(max(v, 0.0))) for v in np.diag(cov_z))))
    return steps, ratio


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


def goodness_of_fit_problem(result, gof: dict, source: str, data_name: str = "the campaign") -> Optional[str]:
    """Why the goodness of fit a result states (its status ok, ``fit.chi2_dof``) is not its data's
    (``gof``: :func:`value_steps`' chi2 and dof at the data's values), or None. An outside probe edited a
    model_mismatch result to status ok, its gates to passed and chi2_dof to 1.0, re-signed it, and a
    certificate was issued with --data saying "chi2/dof 1.000" where the data give 1.577. Refused when the
    data fail the pooled goodness-of-fit gate (p below its gof_p_min and chi2/dof above its gof_ratio_max,
    the result's own gate configuration) while the result is ok, or when the stated chi2/dof differs
    from the data's by more than 5 % (a refit's weights move it far less). The joint least-squares fit
    only (the classical u's noise holds the bench's errors, which the data's sd_* do not; a posterior
    states means, not the optimum)."""
    from scipy import stats

    from ...estimation.gates import config_of

    if not gof or gof.get("dof", 0) <= 0 or str((result.fit or {}).get("loss", "l2")) != "l2" or \
            result.method != "joint":
        return None               # the classical noise holds the bench's errors, a posterior's values are means
    ratio = gof["chi2"] / gof["dof"]
    p = float(stats.chi2.sf(gof["chi2"], gof["dof"]))
    cfg = config_of(result)
    if result.status == "ok" and p < cfg.gof_p_min and ratio > cfg.gof_ratio_max:
        return (f"{source}: refused: status ok, but its data ({data_name}) misfit the result's model: chi2/dof "
                f"{ratio:.4g} on {gof['dof']} dof, p = {p:.2g} (the goodness-of-fit gate needs p >= {cfg.gof_p_min:g} "
                f"or chi2/dof <= {cfg.gof_ratio_max:g}): status or gates edited: fit again")
    stated = (result.fit or {}).get("chi2_dof")
    if isinstance(stated, (int, float)) and math.isfinite(stated) and stated > 0 and \
            abs(stated - ratio) > 0.05 * ratio:
        return (f"{source}: refused: fit.chi2_dof = {stated:.4g} is not its data's: they give {ratio:.4g} on "
                f"{gof['dof']} dof at the result's values: goodness of fit edited: fit again")
    return None


#: a stated Type B sensitivity smaller than the one the data and the lab file give by more than this
#: factor, on a row that matters (its recomputed contribution at least TYPEB_MATERIAL of the parameter's u),
#: is not the fit's (typeb_problem)
TYPEB_RATIO_MAX = 1.5
TYPEB_MATERIAL = 0.2


def typeb_problem(result, campaign, lab, source: str, gof: Optional[dict] = None) -> Optional[str]:
    """Why the Type B rows a joint result states are not those its data and lab file give, or None. Each
    source of the lab file the fit propagated (:func:`~triadcal.uncertainty.typeb.propagated_sources`) is
    propagated again as the fit does: its sensitivity ``c = -(J'J)^-1 J' F/sigma`` (``F`` the change of the
    data per unit of the source, :func:`~triadcal.uncertainty.typeb.data_change`), with the fit's weights,
    at the result's values (:func:`value_steps`' design). A row whose stated |c| is smaller than that by more
    than :data:`TYPEB_RATIO_MAX`, where the recomputed contribution is at least :data:`TYPEB_MATERIAL` of the
    parameter's u, refuses. An outside probe halved u(K_x) with its Type A row and every Type B sensitivity
    scaled to match, and set the thermometers' sensitivity of K_z to 0, re-signed: certified with U(K_z)
    0.000020 for 0.000045. Rows of sources the fit did not propagate are not asked (the lab file's check,
    ``_lab_disagrees``, says whether the result was fitted with this lab file)."""
    from ...uncertainty.typeb import data_change, propagated_sources, systematic_sources

    if lab is None or result.method != "joint" or not result.holds_type_b() or not_rederivable(result) is not None:
        return None
    if gof is None:
        gof = {}
        value_steps(result, campaign, gof=gof)
    if "design" not in gof:
        return None
    try:
        sources = propagated_sources(systematic_sources(lab, campaign.output_unit), result.parameters)
    except Exception:                        # the lab file's own refusals are said by its checks
        return None
    A, names = gof["design"], gof["names"]
    worst = None
    for s in sources:
        F = data_change(s, gof["model"], gof["p0"], gof["cov"], gof["gravity"], np.asarray(campaign.w, float),
                        campaign.output_unit)
        rhs = gof["rows_of"](F)
        if not np.all(np.isfinite(rhs)):
            continue
        zc, *_ = np.linalg.lstsq(A, rhs, rcond=1e-10)
        for name, zj in zip(names, zc):
            q = result.parameters[name]
            c_data = abs(float(zj)) * q.u
            row = next((r for r in (q.uncertainty.get("budget") or []) if isinstance(r, dict)
                        and r.get("type") == "B" and r.get("source") == s.source), None)
            if row is None or not isinstance(row.get("sensitivity"), (int, float)):
                continue
            if c_data * s.u < TYPEB_MATERIAL * q.u:
                continue
            ratio = c_data / max(abs(float(row["sensitivity"])), 1e-300)
            if ratio > TYPEB_RATIO_MAX and (worst is None or ratio > worst[0]):
                worst = (ratio, name, s, row, c_data)
    if worst is None:
        return None
    ratio, name, s, row, c_data = worst
    stated = float(row["sensitivity"])
    how = f"{ratio:.3g} times smaller than" if stated != 0 else "where"
    return (f"{source}: refused: parameters.{name}'s Type B row '{s.source}' states a sensitivity "
            f"{stated:.4g} {row.get('sensitivity_unit', '')}, {how} its data ({campaign.source or 'the campaign'}) and "
            f"the lab file give {c_data:.4g} (the fit's propagation at the result's values): budget edited: fit again")


def values_problem(result, campaign, source: str) -> Optional[str]:
    """Why the values ``result`` states are not those its data give (one line), or None; see the module.
    Also refused: a local gravity other than the one the data state, and a stated u less than half the
    standard uncertainty the data give (:data:`U_RATIO_MAX`)."""
    g_res = result.extra.get("local_g_m_s2")
    if campaign.local_g_stated and g_res is not None and \
            abs(float(g_res) - float(campaign.local_g_m_s2)) > 1e-9 * float(campaign.local_g_m_s2):
        # an outside probe: local_g_m_s2 9.81 and K scaled to match, re-signed: exported
        return (f"{source}: refused: local_g_m_s2 = {float(g_res):.8g} m/s^2 is not the local gravity its data "
                f"({campaign.source or 'the campaign'}) state, {float(campaign.local_g_m_s2):.8g} m/s^2: K takes g "
                "one to one; values edited: fit again")
    unit_res = result.extra.get("output_unit")
    if unit_res is not None and campaign.output_unit and str(unit_res) != str(campaign.output_unit):
        # an outside probe relabelled output_unit and the K units V -> mV, re-signed: certified "K_x 0.998975 g/mV"
        return (f"{source}: refused: output_unit = {unit_res!r} is not the unit its data "
                f"({campaign.source or 'the campaign'}) state, {campaign.output_unit!r}: K is per output unit; "
                "edited: fit again")
    if not_rederivable(result) is not None or campaign.n_visits == 0:
        return None
    gof = {}
    z, ratio = value_steps(result, campaign, with_u=True, gof=gof)
    if not z:
        return None
    why = goodness_of_fit_problem(result, gof, source, campaign.source or "the campaign")
    if why:
        return why
    skip = set((result.extra.get("flags") or {}).get("prior_dominated") or ())   # a posterior's prior-only terms
    narrow = {k: v for k, v in ratio.items() if k not in skip and v > U_RATIO_MAX}
    if narrow:
        worst = max(narrow, key=narrow.get)
        q = result.parameters[worst]
        unit = f" {q.unit}" if q.unit else ""
        return (f"{source}: refused: parameters.{worst}.u = {q.u:.4g}{unit} is {narrow[worst]:.3g} times smaller than "
                f"the standard uncertainty its data ({campaign.source or 'the campaign'}) give, "
                f"{narrow[worst] * q.u:.4g}{unit} (with the fit's weights; more than {U_RATIO_MAX:g} times)"
                + (f" (also {', '.join(sorted(narrow, key=lambda k: -narrow[k])[1:4])})" if len(narrow) > 1 else "")
                + ": uncertainties edited: fit again")
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


__all__ = ["TYPEB_RATIO_MAX", "U_RATIO_MAX", "VALUES_Z_MAX", "check_against_data", "fitted_visits",
           "goodness_of_fit_problem", "not_rederivable", "typeb_problem", "value_steps", "values_problem"]
