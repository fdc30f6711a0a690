"""The consumers' checks of a result they read (certificate, compare, compensation): what a result
must be before it is used, judged on the result alone. :func:`check_result_for_use` re-runs the
answer gates a result can be checked on by itself (:func:`~.gates.result_gates`) and refuses what
does not pass, and what contradicts itself: a status ``ok`` beside a recorded gate that failed, a
chi2/dof against a known noise that its own goodness-of-fit thresholds reject."""

from __future__ import annotations

import math
import numpy as np
from typing import TYPE_CHECKING, Optional

from scipy import stats

from ..errors import InputError

if TYPE_CHECKING:
    from .gates import GateConfig
# gates.py imports this module at its end (its old home of these checks): the gates are imported
# where they are used, not here, so that either module may be imported first


class RefusedResult(InputError):
    """A result that a consumer (certificate, compare, ...) will not use; the message is one line."""


def check_result_for_use(result, source: str = "result", *, need_ok: bool = True,
                         config: Optional[GateConfig] = None, content: bool = True) -> None:
    """Refuse (raise :class:`RefusedResult`, one line naming ``source``) a result a consumer must not
    use: status other than ok, no parameters, missing scale factors, values or u that are not
    finite, negative u, a gate that fails on the result alone, a document edited after the fit
    (``content_mismatch``; with ``content=False`` left to the caller, as the certificate's refusal
    report lists it)."""
    from .gates import config_of

    why = result_problems(result, need_ok=need_ok, config=config_of(result) if config is None else config)
    if not content and getattr(result, "content_mismatch", None):
        why = [w for w in why if w != result.content_mismatch]
    if why:
        raise RefusedResult(f"{source}: refused: " + "; ".join(why))


def result_problems(result, *, need_ok: bool = True, config: Optional[GateConfig] = None) -> list[str]:
    """Reasons why ``result`` cannot be used (empty list: it can); ``config`` defaults to the
    result's own (:func:`config_of`)."""
    from .gates import config_of, result_gates

    config = config_of(result) if config is None else config
    why = []
    if need_ok and result.status != "ok":
        why.append(f"status is {result.status!r}, not 'ok'")
    if not result.parameters:
        why.append("it holds no parameters")
        return why
    try:
        T = float(result.reference_temperature_C)
    except (TypeError, ValueError):
        T = float("nan")
    if not math.isfinite(T) or not -100.0 <= T <= 200.0:
        why.append(f"reference_temperature_C = {result.reference_temperature_C!r} is not a temperature in degC "
                   "between -100 and 200")
    # a parameter estimated from noisy data has u > 0: a u of 0 is an edited or broken file, and a
    # drift judged against it is judged against nothing (an outside probe: compare took u = 0 and
    # said pass)
    if need_ok and result.status == "ok":
        # ... and a u below the value's own floating-point resolution (4 ulp) is no estimate either: a
        # u of 1e-30 arcsec on Ca_xy (hash recomputed) was compared and tabulated as u = 0 (an outside probe)
        zero = [n for n, p in result.parameters.items()
                if p.u == 0 or (math.isfinite(p.value) and p.u < 4.0 * np.finfo(float).eps * abs(p.value))]
        if zero:
            why.append(f"{', '.join(zero[:6])}{' ...' if len(zero) > 6 else ''}: u = 0 or below the value's floating-point "
                       "resolution, which no estimate from measured data has (status ok needs u > 0)")
    for o in result_gates(result.parameters, output_unit=result.extra.get("output_unit"),
                          local_g_m_s2=result.extra.get("local_g_m_s2"), config=config):
        if o.passed is False:
            why.append(f"gate {o.gate} fails ({o.status}): {o.reason}")
    why.extend(_recorded_contradictions(result, config))
    from .one_temperature import sensor_temperature_problems
    why.extend(sensor_temperature_problems(result))
    if getattr(result, "content_mismatch", None):      # last: the fields' own reasons name the field first
        why.append(result.content_mismatch)
    return why


def _recorded_contradictions(result, config: "GateConfig") -> list[str]:
    """A status ``ok`` that the result's own record contradicts: a gate outcome recorded as failed,
    or (joint and classical fits against a known noise) a ``fit.chi2_dof`` over ``n_obs - n_params``
    dof that its goodness-of-fit thresholds reject (p < gof_p_min and ratio > gof_ratio_max)."""
    if result.status != "ok":
        return []
    why = []
    block = (getattr(result, "extra", {}) or {}).get("gates")
    outcomes = block.get("outcomes") if isinstance(block, dict) else None
    for o in outcomes if isinstance(outcomes, list) else []:
        if isinstance(o, dict) and o.get("passed") is False:
            why.append(f"status is 'ok' but its gate {o.get('gate')} is recorded as failed ({o.get('status')}: "
                       f"{o.get('reason')})")
    fit = result.fit if isinstance(result.fit, dict) else {}
    if result.method in ("joint", "classical") and fit.get("noise_known") is True:
        c, n, k = fit.get("chi2_dof"), fit.get("n_obs"), fit.get("n_params")
        if all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in (c, n, k)) and n - k > 0 \
                and math.isfinite(c):
            dof = n - k
            p = float(stats.chi2.sf(c * dof, dof))
            if p < config.gof_p_min and c > config.gof_ratio_max:
                why.append(f"status is 'ok' but fit.chi2_dof = {c:.4g} against the known noise ({dof} dof, p = "
                           f"{p:.2g}) fails its own goodness of fit (p < {config.gof_p_min:g} and ratio > "
                           f"{config.gof_ratio_max:g})")
    return why
