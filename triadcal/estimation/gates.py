"""Answer gates: the checks every estimator passes before it may write status ``"ok"``.

An optimiser or sampler that stopped is not an answer. Every estimator (classical, joint,
posterior, fit-raw with known and unknown poses) hands its result and the evidence of its
fit to :func:`apply_gates`; each gate that fails has its own status and a one-line reason
that names the number that failed. Consumers (certificate, compare, any reader of a
result) call :func:`check_result_for_use`, which re-runs the gates a result can be checked
on by itself and refuses what does not pass. The statuses and their thresholds are listed
in docs/statuses.md. About 600 lines on purpose: every gate of the one contract in one place,
so that a change to a threshold is seen against all the others.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Optional, Sequence

import numpy as np
from scipy import stats

from ..models.units import STANDARD_GRAVITY_M_S2, scale_output_unit

#: status of each gate when it fails, in order of precedence (the first failing one is the
#: result's status; all failures are listed in ``result.extra["gates"]`` and the notes)
STATUSES = {
    "ok": "every answer gate passed",
    "non_finite": "a value or an uncertainty is NaN, infinite, or an uncertainty is negative",
    "not_converged": "the optimiser or the sampler stopped without meeting its convergence test",
    "degenerate": "the residuals are zero with free parameters left: the data cannot test the answer",
    "unidentifiable": "fewer observations than free parameters, or a combination of free parameters "
                      "with no effect on the data (rank / null space of the Jacobian)",
    "no_improvement": "the objective at the answer is worse than at the starting point",
    "unphysical_scale": "a scale factor is not positive, or lies outside the band that the declared "
                        "output unit and the local g imply",
    "angle_out_of_range": "an orientation angle beyond the bound (default 3600 arcsec = 1 deg)",
    "unphysical_term": "a term whose physics fixes its sign (a thermal time constant) has the other sign "
                       "by more than 2u",
    "model_mismatch": "the residuals are larger than the noise floor allows (chi2/dof against the noise, "
                      "or the posterior predictive check): the model misses something in the data",
    "inconsistent_redundancy": "classical method: the position pairs that measure the same quantity "
                               "disagree beyond their noise",
}
PRECEDENCE = tuple(STATUSES)[1:]

#: g per output unit for units whose scale is fixed by physics (a reading of 1 g)
NOMINAL_SCALE_G_PER_UNIT = {
    "g": 1.0, "mg": 1e-3, "ug": 1e-6,
    "m/s2": 1.0 / STANDARD_GRAVITY_M_S2, "m/s^2": 1.0 / STANDARD_GRAVITY_M_S2,
    "m/s**2": 1.0 / STANDARD_GRAVITY_M_S2, "m/s²": 1.0 / STANDARD_GRAVITY_M_S2,
    "mm/s2": 1e3 / STANDARD_GRAVITY_M_S2, "mm/s^2": 1e3 / STANDARD_GRAVITY_M_S2,
    "ft/s2": 0.3048 / STANDARD_GRAVITY_M_S2, "ft/s^2": 0.3048 / STANDARD_GRAVITY_M_S2,
}
#: plausible band of K (g per output unit) for units whose scale depends on the instrument:
#: voltage outputs 0.05 mV/g (shock sensors) ... 100 V/g (a tumble reads +-1 g, and no voltage
#: input reads beyond +-100 V: until 2026-12-02 the band reached 1000 V/g, and an outside probe's
#: 1 V/g unit recorded in mV and declared V was certified with K 1000 times too small in 5 of 10
#: seeds, those whose K exceeded 1 g/V); currents (quartz pendulous, ~1.3 mA/g) 1 uA/g ... 1 A/g;
#: digital counts from 1 count/g to 2^31 counts/g
SCALE_BAND_G_PER_UNIT = {
    "V": (1e-2, 2e4), "mV": (1e-5, 2e1), "uV": (1e-8, 2e-2),
    "A": (1.0, 1e6), "mA": (1e-3, 1e3), "uA": (1e-6, 1.0),
    "count": (4e-10, 1.0), "counts": (4e-10, 1.0), "LSB": (4e-10, 1.0), "lsb": (4e-10, 1.0),
    "digit": (4e-10, 1.0), "digits": (4e-10, 1.0),
}


@dataclass(frozen=True)
class GateConfig:
    """Thresholds of the gates (stated in every result's ``gates`` block).

    ``scale_band_rel``: for an output in a physical acceleration unit (g, m/s^2, ...) K must
    lie within this relative distance of its nominal value (a unit whose scale is 20 % off
    its declared unit is mislabelled, not miscalibrated). ``angle_bound_arcsec``: the
    largest orientation angle accepted (1 deg; MEMS datasheets give 1-2 % cross-axis, i.e.
    0.6-1.1 deg). ``gof_p_min``: the chi^2 (or predictive) p-value below which the model
    does not explain the data. ``gof_ratio_max``: the residual variance over the noise floor
    above which the misfit is material. A mismatch needs both, significant and material: on a
    10^6-sample recording a p-value alone rejects a ratio of 1.01, which changes no
    uncertainty by more than 0.5 %; on a 540-visit campaign p < 0.001 already means a ratio
    above 1.2.
    """

    angle_bound_arcsec: float = 3600.0
    scale_band_rel: float = 0.2
    gof_p_min: float = 1e-3
    gof_ratio_max: float = 1.2
    zero_residual_rel: float = 1e-10
    null_space_rtol: float = 1e-8

    def to_dict(self) -> dict:
        return {"angle_bound_arcsec": self.angle_bound_arcsec, "scale_band_rel": self.scale_band_rel,
                "gof_p_min": self.gof_p_min, "gof_ratio_max": self.gof_ratio_max,
                "zero_residual_rel": self.zero_residual_rel, "null_space_rtol": self.null_space_rtol}


DEFAULT_CONFIG = GateConfig()


def config_of(result) -> GateConfig:
    """The gate thresholds a result was judged with (its ``gates.config`` block), so a consumer
    checks it against the bound its fit stated (e.g. a raised ``--angle-bound-arcsec``); the
    defaults when the block is absent or not a set of finite positive numbers. A raised bound is
    never silent: the result's notes and its ``gates`` block carry it into every report."""
    block = (getattr(result, "extra", {}) or {}).get("gates")
    cfg = block.get("config") if isinstance(block, Mapping) else None
    if not isinstance(cfg, Mapping):
        return DEFAULT_CONFIG
    kw = {}
    for k, default in DEFAULT_CONFIG.to_dict().items():
        v = cfg.get(k, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            return DEFAULT_CONFIG
        kw[k] = float(v)
    return GateConfig(**kw)


@dataclass
class FitEvidence:
    """What an estimator knows about its own fit, for the gates that need more than the result.

    Every field is optional: a gate whose evidence is missing is reported as ``skipped`` with
    the reason, never as passed.

    - ``converged``: the optimiser's / sampler's own convergence test.
    - ``cost_start``, ``cost_final``: the objective at the starting point and at the answer.
    - ``n_obs``, ``n_free``: observations and free parameters.
    - ``jacobian``: Jacobian of the normalised residuals at the answer (n_obs x n_free), for
      the rank / null-space gate; ``free_names`` its column names.
    - ``residual_rms`` and ``data_rms``: RMS of the raw residuals and of the raw data, same
      unit, for the zero-residual gate.
    - ``chi2`` and ``dof`` with ``noise_known``: the goodness of fit against a known noise
      floor (chi^2 of the normalised residuals); or ``gof_p_value`` and ``gof_ratio`` given
      directly (posterior predictive check, a recording's own noise floor), with ``gof_what``
      saying what they are.
    - ``extra``: more :class:`GateOutcome` an estimator checks itself (the classical
      redundancy test).
    """

    converged: Optional[bool] = None
    cost_start: Optional[float] = None
    cost_final: Optional[float] = None
    n_obs: Optional[int] = None
    n_free: Optional[int] = None
    jacobian: Optional[np.ndarray] = None
    free_names: Sequence[str] = ()
    residual_rms: Optional[float] = None
    data_rms: Optional[float] = None
    chi2: Optional[float] = None
    dof: Optional[int] = None
    noise_known: Optional[bool] = None
    gof_p_value: Optional[float] = None
    gof_ratio: Optional[float] = None
    gof_what: str = ""
    extra: list = field(default_factory=list)


# one gate's outcome and the readers of a parameter: gate_outcome.py (re-exported here)
from .gate_outcome import GateOutcome, _u, _unit, _value  # noqa: E402,F401


# ------------------------------------------------------------------------------------------
# gates that need only the result
# ------------------------------------------------------------------------------------------
def scale_band(output_unit: Optional[str], local_g_m_s2: Optional[float] = None,
               rel: float = DEFAULT_CONFIG.scale_band_rel) -> Optional[tuple[float, float, str]]:
    """Accepted band ``(low, high, why)`` of K (g per output unit), or None when the unit is unknown.

    For a physical acceleration unit the nominal K is fixed (1 g per g, 1/9.80665 g per
    m/s^2), whatever the local g; the band is ``nominal x (1 -+ rel)``.
    """
    if output_unit is None:
        return None
    u = output_unit.strip()
    if u in NOMINAL_SCALE_G_PER_UNIT:
        k0 = NOMINAL_SCALE_G_PER_UNIT[u]
        return k0 * (1 - rel), k0 * (1 + rel), f"a reading in {u} has K = {k0:.6g} g/{u} within {rel:.0%}"
    if u in SCALE_BAND_G_PER_UNIT:
        lo, hi = SCALE_BAND_G_PER_UNIT[u]
        return lo, hi, f"plausible K of an instrument with output in {u}"
    return None


def _gate_finite(params: Mapping) -> GateOutcome:
    bad = []
    for n, p in params.items():
        v, u = _value(p), _u(p)
        if v is None or u is None or not math.isfinite(v) or not math.isfinite(u) or u < 0:
            bad.append(f"{n} = {v!r} +- {u!r}")
    if not params:
        return GateOutcome("finite", False, "non_finite", "the result has no parameters")
    if bad:
        return GateOutcome("finite", False, "non_finite",
                           "not a finite value with a finite, non-negative uncertainty: " + "; ".join(bad[:4])
                           + (f" (and {len(bad) - 4} more)" if len(bad) > 4 else ""), float(len(bad)), "0")
    return GateOutcome("finite", True, "non_finite", "every value and uncertainty is finite", 0.0, "0")


def _gate_scale(params: Mapping, output_unit: Optional[str], local_g: Optional[float],
                cfg: GateConfig) -> GateOutcome:
    ks = {n: p for n, p in params.items() if n in ("K_x", "K_y", "K_z")}
    if not ks:
        return GateOutcome("scale", None, "unphysical_scale", "no scale factor in the result")
    bad, band_why = [], None
    for n, p in ks.items():
        v = _value(p)
        unit_out = scale_output_unit(_unit(p)) or output_unit
        band = scale_band(unit_out, local_g, cfg.scale_band_rel)
        if v is None or not math.isfinite(v) or v <= 0:
            bad.append(f"{n} = {v!r} {_unit(p)} is not positive")
        elif band is not None and not band[0] <= v <= band[1]:
            bad.append(f"{n} = {v:.6g} {_unit(p)} outside [{band[0]:.4g}, {band[1]:.4g}] ({band[2]})")
        if band is not None:
            band_why = band[2]
    if bad:
        return GateOutcome("scale", False, "unphysical_scale", "; ".join(bad), float(len(bad)),
                           "K > 0" + (f" and {band_why}" if band_why else ""))
    if band_why is None:
        return GateOutcome("scale", True, "unphysical_scale",
                           f"every K is positive (output unit {output_unit!r} has no known band: magnitude not checked)")
    return GateOutcome("scale", True, "unphysical_scale", f"every K is positive and within the band ({band_why})")


def _beyond_2u(v: Optional[float], u: Optional[float]) -> float:
    """``|v| - 2u`` (u taken as 0 when unknown; infinite for a value that is not finite): how far a
    value is known to lie from 0 at about 95 %."""
    if v is None or not math.isfinite(v):
        return math.inf
    return abs(v) - 2 * (u if u is not None and math.isfinite(u) and u >= 0 else 0.0)


def _gate_angles(params: Mapping, cfg: GateConfig) -> GateOutcome:
    """Every angle within the bound: ``|value| - 2 u <= bound`` (an angle beyond the bound by
    less than its expanded uncertainty is not known to be beyond it; an angle so uncertain that
    it is not measured at all is the ``determined`` gate's business). A swapped column gives
    ~206265 arcsec (1 rad) with a small u, far beyond any bound."""
    angles = {n: (_value(p), _u(p)) for n, p in params.items() if n.startswith("Ca_") and len(n) == 5}
    if not angles:
        return GateOutcome("angles", None, "angle_out_of_range", "no orientation angle in the result")

    worst = max(angles, key=lambda n: _beyond_2u(*angles[n]))
    v, u = angles[worst]
    ok = _beyond_2u(v, u) <= cfg.angle_bound_arcsec
    u_txt = f" +- {u:.3g}" if u is not None and math.isfinite(u) else ""
    return GateOutcome("angles", ok, "angle_out_of_range",
                       f"largest angle {worst} = {v:.6g}{u_txt} arcsec" + ("" if ok else
                       f", beyond the bound of {cfg.angle_bound_arcsec:g} arcsec by more than 2u (raise it with "
                       "--angle-bound-arcsec only if the unit really is that far from orthogonal; more often a column "
                       "is swapped, a sign flipped or a position mislabelled)"),
                       abs(v) if v is not None else None, f"|value| - 2u <= {cfg.angle_bound_arcsec:g} arcsec")


def _gate_determined(params: Mapping, cfg: GateConfig) -> GateOutcome:
    """An angle whose standard uncertainty exceeds the angle bound is not measured: whatever its
    value, the data (and prior) leave it anywhere within a degree or more."""
    loose = {n: (_value(p), _u(p)) for n, p in params.items() if n.startswith("Ca_") and len(n) == 5
             and _u(p) is not None and math.isfinite(_u(p)) and _u(p) > cfg.angle_bound_arcsec}
    if not loose:
        return GateOutcome("determined", True, "unidentifiable",
                           f"every angle's u is within the bound of {cfg.angle_bound_arcsec:g} arcsec")
    worst = max(loose, key=lambda n: loose[n][1])
    v, u = loose[worst]
    return GateOutcome("determined", False, "unidentifiable",
                       f"{', '.join(sorted(loose))} not determined by the data: {worst} = {v:.5g} +- {u:.3g} arcsec, "
                       f"u beyond the angle bound of {cfg.angle_bound_arcsec:g} arcsec (more poses, or poses that "
                       "turn the axes involved, determine it)", u, f"u <= {cfg.angle_bound_arcsec:g} arcsec")


#: the largest bias (zero-g offset, g) an accelerometer's calibration returns: three times the worst
#: zero-g offset of MEMS datasheets (ADXL345 +-150 mg over temperature; navigation grades are mg). An
#: output in offset-binary counts read as if zero meant 0 g (``w = 2^(n-1) + a / K``) fits a bias of
#: half the range: 2 g for a 16-bit +-4 g code (an outside probe: S 1.999 +- 7e-6 g, status ok)
BIAS_BOUND_G = 0.5


def _gate_bias(params: Mapping) -> GateOutcome:
    """Every bias ``S_a`` (g) within :data:`BIAS_BOUND_G` by more than 2u, on a result with scale
    tempcos: beyond it the output has an offset no accelerometer has (an offset-binary code, a
    column with a constant added), and the model's ``K(T)``, which scales the whole output, puts
    ``K_tempco x S`` into S's tempco (the probe's: 35 +- 0.23 ug/degC for a true -18.5, 231 u). At
    one temperature (``fit-raw`` of a recording in offset-binary counts, a one-setpoint campaign) the
    offset is calibrated with the code and compensates exactly: not judged there."""
    biases = {n: (_value(p), _u(p)) for n, p in params.items() if n in ("S_x", "S_y", "S_z") and _unit(p) == "g"}
    if not biases:
        return GateOutcome("bias", None, "unphysical_term", "no bias in g in the result")
    if not any(n in params for n in ("K_x_tempco", "K_y_tempco", "K_z_tempco")):
        return GateOutcome("bias", None, "unphysical_term", "no scale tempco: a large offset compensates exactly")

    worst = max(biases, key=lambda n: _beyond_2u(*biases[n]))
    v, u = biases[worst]
    ok = _beyond_2u(v, u) <= BIAS_BOUND_G
    reason = f"largest bias {worst} = {v:.6g} +- {u:.2g} g"
    if not ok:
        reason += (f", beyond {BIAS_BOUND_G:g} g by more than 2u: no accelerometer's zero-g offset is that large (MEMS "
                   "datasheets: up to 0.15 g), and the scale tempcos, which multiply the whole output, put K_tempco "
                   "x S into the bias tempcos. An output in offset-binary counts (mid-scale code = 0 g) read as "
                   "two's complement gives half the range, e.g. 2 g for 16 bits at 16384 counts/g: subtract the "
                   "mid-scale code (32768 for 16 bits) from w_x w_y w_z, or the constant added to the column")
    return GateOutcome("bias", ok, "unphysical_term", reason, abs(v) if v is not None else None,
                       f"|S| - 2u <= {BIAS_BOUND_G:g} g")


# the gates of the physical terms' signs and ranges: term_gates.py (re-exported here)
from .term_gates import (NON_NEGATIVE, TIME_CONSTANT_RANGE_MIN, TIME_CONSTANT_RANGES, TIME_CONSTANTS,  # noqa: E402,F401
                         WARMUP_OFFSET_MAX, WARMUP_SEEN_Z, _gate_signs, _gate_time_constants,
                         _gate_time_constants_determined, _gate_warmup_offsets, _gate_warmup_seen, _tc_range)


def result_gates(parameters: Mapping, *, output_unit: Optional[str] = None, local_g_m_s2: Optional[float] = None,
                 config: GateConfig = DEFAULT_CONFIG) -> list[GateOutcome]:
    """The gates that a result can be checked on by itself: finite values, K, angles, angles
    so uncertain that they are not measured, and terms whose physics fixes their sign."""
    return [_gate_finite(parameters), _gate_scale(parameters, output_unit, local_g_m_s2, config),
            _gate_angles(parameters, config), _gate_determined(parameters, config), _gate_signs(parameters),
            _gate_bias(parameters),
            _gate_time_constants(parameters), _gate_time_constants_determined(parameters),
            _gate_warmup_offsets(parameters), _gate_warmup_seen(parameters)]


# ------------------------------------------------------------------------------------------
# gates that need the fit's evidence
# ------------------------------------------------------------------------------------------
def rank_deficiency(J: np.ndarray, names: Sequence[str], rtol: float) -> tuple[int, list]:
    """Number of null directions of the column-scaled ``J`` (more parameters than rows count
    too) and the parameters involved in them."""
    J = np.asarray(J, float)
    n_par = J.shape[1]
    if n_par == 0:
        return 0, []
    norms = np.linalg.norm(J, axis=0)
    involved = [names[i] for i in np.flatnonzero(norms == 0)] if len(names) == n_par else []
    ok = norms > 0
    if not ok.any():
        return n_par, list(names)
    Js = J[:, ok] / norms[ok]
    if not np.all(np.isfinite(Js)):
        return n_par, list(names)
    try:
        # the right singular vectors only: full_matrices=True also built the rows x rows U
        # (26.8 GiB for 20 000 visits); with fewer rows than parameters vt is padded below
        _, s, vt = np.linalg.svd(Js, full_matrices=Js.shape[0] < Js.shape[1])
    except np.linalg.LinAlgError:
        return n_par, list(names)
    s = np.concatenate([s, np.zeros(vt.shape[0] - len(s))])
    null = np.flatnonzero(s < rtol * s[0]) if s[0] > 0 else np.arange(len(s))
    sub = [n for n, k in zip(names, ok) if k] if len(names) == n_par else []
    for k in null:
        for i in np.flatnonzero(np.abs(vt[k]) > 0.2):
            if sub and sub[i] not in involved:
                involved.append(sub[i])
    return int(np.sum(~ok)) + len(null), involved


def _gate_identifiable(ev: FitEvidence, cfg: GateConfig) -> GateOutcome:
    n_obs, n_free = ev.n_obs, ev.n_free
    if ev.jacobian is not None:
        n_obs, n_free = ev.jacobian.shape
    if n_obs is None or n_free is None:
        return GateOutcome("identifiable", None, "unidentifiable", "the estimator gave no count of observations")
    if n_obs <= n_free:
        return GateOutcome("identifiable", False, "unidentifiable",
                           f"{n_obs} observations for {n_free} free parameters: nothing is left to test the fit "
                           "(at least one more observation than parameters is needed)", float(n_obs - n_free), "> 0")
    if ev.jacobian is None:
        return GateOutcome("identifiable", True, "unidentifiable",
                           f"{n_obs} observations for {n_free} free parameters (rank not checked: no Jacobian)")
    k, involved = rank_deficiency(ev.jacobian, list(ev.free_names), cfg.null_space_rtol)
    if k:
        return GateOutcome("identifiable", False, "unidentifiable",
                           f"the Jacobian at the answer has {k} null direction(s) (relative singular value < "
                           f"{cfg.null_space_rtol:g})" + (": " + ", ".join(involved[:8]) + " not separable" if involved else ""),
                           float(k), "0")
    return GateOutcome("identifiable", True, "unidentifiable",
                       f"full rank: {n_free} free parameters from {n_obs} observations", 0.0, "0")


def _gate_converged(ev: FitEvidence) -> GateOutcome:
    if ev.converged is None:
        return GateOutcome("converged", None, "not_converged", "the estimator has no convergence test")
    return GateOutcome("converged", bool(ev.converged), "not_converged",
                       "the convergence test was met" if ev.converged else
                       "the optimiser/sampler stopped without meeting its convergence test: the values are not an answer")


def _gate_improved(ev: FitEvidence) -> GateOutcome:
    a, b = ev.cost_start, ev.cost_final
    if a is None or b is None:
        return GateOutcome("improved", None, "no_improvement", "no starting objective recorded")
    if not (math.isfinite(b)):
        return GateOutcome("improved", False, "no_improvement", f"the objective at the answer is {b!r}", b)
    ok = (not math.isfinite(a)) or b <= a * (1 + 1e-9) + 1e-300
    return GateOutcome("improved", ok, "no_improvement",
                       f"objective {a:.6g} at the start, {b:.6g} at the answer", b, f"<= {a:.6g}")


def _gate_degenerate(ev: FitEvidence, cfg: GateConfig) -> GateOutcome:
    r, d = ev.residual_rms, ev.data_rms
    if r is None or d is None:
        if ev.chi2 is not None and ev.dof is not None and ev.dof > 0:
            ok = ev.chi2 > 0
            return GateOutcome("residuals", ok, "degenerate",
                               f"chi2 = {ev.chi2:.6g} with {ev.dof} degrees of freedom"
                               + ("" if ok else ": zero residuals with free parameters"), ev.chi2, "> 0")
        return GateOutcome("residuals", None, "degenerate", "no residual scale recorded")
    ok = r > cfg.zero_residual_rel * max(d, 1e-300)
    return GateOutcome("residuals", ok, "degenerate",
                       f"residual RMS {r:.3g} against data RMS {d:.3g}" + ("" if ok else
                       ": the model reproduces the data exactly with free parameters left, a degenerate answer "
                       "(every scale factor driven to 0, or data without noise, which no measurement is)"), r / max(d, 1e-300), f"> {cfg.zero_residual_rel:g}")


def _gate_gof(ev: FitEvidence, cfg: GateConfig) -> GateOutcome:
    if ev.gof_p_value is not None or ev.gof_ratio is not None:
        p, ratio, what = ev.gof_p_value, ev.gof_ratio, ev.gof_what or "goodness of fit"
    elif ev.chi2 is not None and ev.dof:
        if not ev.noise_known:
            return GateOutcome("goodness_of_fit", None, "model_mismatch",
                               "not testable: the noise was estimated from the residuals themselves")
        p = float(stats.chi2.sf(ev.chi2, ev.dof))
        ratio = ev.chi2 / ev.dof
        what = f"chi2/dof against the known noise ({ev.dof} dof)"
    else:
        return GateOutcome("goodness_of_fit", None, "model_mismatch", "no goodness-of-fit statistic recorded")
    p_bad = p is not None and p < cfg.gof_p_min
    r_bad = ratio is not None and (not math.isfinite(ratio) or ratio > cfg.gof_ratio_max)
    # a mismatch needs both: significant (p) and material (ratio); either alone when the other is absent
    fails = (p_bad and r_bad) if (p is not None and ratio is not None) else (p_bad or r_bad)
    txt = f"{what}: ratio {ratio:.4g}" if ratio is not None else what
    if p is not None:
        txt += f", p = {p:.2g}"
    if fails:
        txt += (f" (p < {cfg.gof_p_min:g} and ratio > {cfg.gof_ratio_max:g}): the model misses something in the data;"
                " run `triadcal diagnose` and refit with the missing effect")
    return GateOutcome("goodness_of_fit", not fails, "model_mismatch", txt,
                       ratio, f"p >= {cfg.gof_p_min:g} or ratio <= {cfg.gof_ratio_max:g}")


def answer_gates(parameters: Mapping, evidence: FitEvidence, *, output_unit: Optional[str] = None,
                 local_g_m_s2: Optional[float] = None, config: GateConfig = DEFAULT_CONFIG) -> list[GateOutcome]:
    """Every gate, in order of precedence of their statuses."""
    out = [_gate_finite(parameters), _gate_converged(evidence), _gate_degenerate(evidence, config),
           _gate_identifiable(evidence, config), _gate_determined(parameters, config), _gate_improved(evidence),
           _gate_scale(parameters, output_unit, local_g_m_s2, config), _gate_angles(parameters, config),
           *(o for o in (_gate_signs(parameters), _gate_bias(parameters), _gate_time_constants(parameters),
                         _gate_time_constants_determined(parameters), _gate_warmup_offsets(parameters),
                         _gate_warmup_seen(parameters))
             if o.passed is not None),
           _gate_gof(evidence, config)]
    out.extend(evidence.extra)
    return out


def status_of(outcomes: Sequence[GateOutcome]) -> str:
    """The status of the first failing gate in order of precedence, else ``"ok"``."""
    failed = {o.status for o in outcomes if o.passed is False}
    for s in PRECEDENCE:
        if s in failed:
            return s
    return "ok"


def apply_gates(result, evidence: FitEvidence, *, config: GateConfig = DEFAULT_CONFIG):
    """Run every gate on ``result`` (a :class:`~triadcal.estimation.result.CalibrationResult`)
    and write the outcome: the status (a status the estimator already set other than ok is
    kept when it comes first), one note per failing gate, and ``result.extra["gates"]``.
    Returns the result."""
    output_unit = result.extra.get("output_unit")
    local_g = result.extra.get("local_g_m_s2")
    outcomes = answer_gates(result.parameters, evidence, output_unit=output_unit, local_g_m_s2=local_g,
                            config=config)
    status = status_of(outcomes)
    if result.status != "ok" and (status == "ok" or (result.status in PRECEDENCE and
                                                     PRECEDENCE.index(result.status) < PRECEDENCE.index(status))):
        status = result.status
    result.status = status
    for o in outcomes:
        if o.passed is False:
            note = f"gate {o.gate} failed ({o.status}): {o.reason}"
            if note not in result.notes:
                result.notes.append(note)
    result.extra["gates"] = {"config": config.to_dict(), "outcomes": [o.to_dict() for o in outcomes]}
    return result


def add_outcome(result, outcome: GateOutcome):
    """One more gate's ``outcome`` on a result the gates have judged (its evidence found after the fit):
    recorded with the others, its note when it fails, and the status by precedence."""
    gates = result.extra.setdefault("gates", {"config": DEFAULT_CONFIG.to_dict(), "outcomes": []})
    gates["outcomes"].append(outcome.to_dict())
    if outcome.passed is False:
        note = f"gate {outcome.gate} failed ({outcome.status}): {outcome.reason}"
        if note not in result.notes:
            result.notes.append(note)
        if result.status == "ok" or (result.status in PRECEDENCE and
                                     PRECEDENCE.index(outcome.status) < PRECEDENCE.index(result.status)):
            result.status = outcome.status
    return result


# the consumers' checks (certificate, compare, compensation) live in result_checks.py; imported here
# too, where they were first written
from .result_checks import RefusedResult, check_result_for_use, result_problems  # noqa: E402,F401
