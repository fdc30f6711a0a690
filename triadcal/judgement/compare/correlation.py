"""What the errors of two calibrations share (correlation rho of the drift), and drifts from
posterior draws of both.
"""

from __future__ import annotations
from ...errors import InputError
import math
import os
import re
from dataclasses import dataclass, field
from typing import Sequence
import numpy as np
from ...estimation.result import CalibrationResult
from .rule import drift_uncertainty


#: number of random before/after draw pairs used for posterior drifts
POSTERIOR_PAIRS = 50_000


#: Terms of our model and of the bench, and whether two campaigns of one unit on one bench
#: share their errors (docs/compare.md).
CORRELATION_TERMS = (
    {"term": "output noise (Q, sd_*)", "shared": False,
     "how": "independent between campaigns; each calibration's u holds it; adds in quadrature"},
    {"term": "random bench positioning and wobble per visit (sigma_1, sigma_2 of eq. 4)", "shared": False,
     "how": "drawn anew at every visit; independent between campaigns; adds in quadrature"},
    {"term": "bench_tilt (delta, beta)", "shared": True,
     "how": "the same bench levelling, but estimated in each joint fit (cancelled by pairing in eq. 2-3): "
            "its estimation error is campaign-specific and already in each result's covariance; its "
            "change is reported as a bench check, not judged"},
    {"term": "the lab's systematic errors (encoder zeros, axes non-orthogonality, fixture, local g, "
             "thermometers, voltmeter: the Type B rows of a result fitted with a lab file)", "shared": "optional",
     "how": "in a result's u when it was fitted with a lab file (its budget has Type B rows), else not in u "
            "at all. By default each calibration's rows are independent errors (its own bench setup, the "
            "conservative case: they add in quadrature); with shared equipment (compare(..., "
            "shared_equipment=...), --lab with [compare] shared_equipment, --shared-bench) the rows of that "
            "equipment are one error in both calibrations and 2 sum_s c_b,s c_a,s u_s^2 is subtracted"},
    {"term": "repeatable bench errors not in the lab file (encoder error at the commanded angles, wobble "
             "as a function of angle)", "shared": True,
     "how": "identical in both campaigns, so they cancel in the drift; not in any u, so nothing is subtracted"},
)


def _equipment(key) -> str:
    """The equipment (lab-file section) of a budget row's key: ``"[bench] encoder_zero_u_arcsec"`` -> bench."""
    m = re.match(r"\s*\[([^\]]+)\]", key if isinstance(key, str) else "")
    return m.group(1).strip() if m else ""


def type_b_rows(result: CalibrationResult, name: str) -> list:
    """The Type B rows of one parameter's budget (``[]`` without a budget)."""
    rows = result.parameters[name].uncertainty.get("budget") or []
    return [r for r in rows if isinstance(r, dict) and r.get("type") == "B"]


def budget_equipment(result: CalibrationResult) -> list:
    """The equipment of the Type B rows in a result's budgets (sorted; [] when it has none)."""
    return sorted({_equipment(r.get("key")) or "?" for n in result.parameters for r in type_b_rows(result, n)})


def _describe_budget(tag: str, result: CalibrationResult) -> str:
    eq = budget_equipment(result)
    if not eq:
        return (f"{tag}: u is Type A only (no budget: fitted without a lab file; the lab's systematic errors "
                "are not in its u)")
    return f"{tag}: u is combined (Type A + the lab's systematic errors of {', '.join(f'[{e}]' for e in eq)})"


def derive_correlation(before: CalibrationResult, after: CalibrationResult,
                       shared_equipment: Sequence[str] = ()) -> tuple[float, str]:
    """Default correlation ``rho`` between two calibrations' errors, with the reason; the reason
    says, per result, whether its u holds the lab's systematic errors (Type B rows) and, with
    ``shared_equipment``, that the rows of that equipment are one error in both (their covariance
    is subtracted per parameter by :func:`shared_errors`, not by ``rho``)."""
    methods = {before.method, after.method}
    if not methods <= {"joint", "classical", "posterior"}:
        return 0.0, f"rho = 0 assumed for methods {sorted(methods)}: no shared component is known"
    per = "; ".join(_describe_budget(t, r) for t, r in (("before", before), ("after", after)))
    base = ("rho = 0 for the random errors: the Type A part of fitted results comes from each campaign's own "
            "random errors (output noise, per-visit bench errors), independent between campaigns. " + per + ". ")
    any_b = bool(budget_equipment(before) or budget_equipment(after))
    both_b = bool(budget_equipment(before) and budget_equipment(after))
    if shared_equipment:
        eq = ", ".join(f"[{e}]" for e in shared_equipment)
        if any_b and not both_b:
            return 0.0, base + (f"Shared equipment {eq} was requested, but only one result has Type B rows: "
                                "nothing to share (its rows stay in its u, independent)")
        if any_b:
            return 0.0, base + (f"Shared equipment {eq}: its Type B rows are the same error in both calibrations, "
                                "so 2 sum_s c_b,s c_a,s u_s^2 over those sources is subtracted from each drift's "
                                "variance (per-parameter rho = that sum / (u_b u_a)) and from the covariance of "
                                "the angle drifts; every other row is independent")
        return 0.0, base + (f"Shared equipment {eq} was requested, but neither result has Type B rows: nothing "
                            "to share")
    if any_b:
        return 0.0, base + ("Nothing shared (the default): the Type B rows of the two calibrations are taken as "
                            "independent errors (each on its own bench setup, the conservative case), so they add "
                            "in quadrature; if both ran on the same equipment with no adjustment between them, "
                            "share it (--shared-bench, --lab with [compare] shared_equipment)")
    # an outside probe: a unit remounted between its calibrations (its fixture rotation N(0, 10")
    # each time), unchanged, failed 10 of 10 with this note saying the systematic errors cancel
    return 0.0, base + ("Neither u holds the lab's systematic errors. Those that repeat identically in both "
                        "calibrations (the bench's encoder zeros and non-orthogonality, unadjusted between them) "
                        "cancel in the drift; those that do not repeat are in the drift and in no u here: above all "
                        "the seating of the unit in its fixture when it was remounted between the calibrations (a "
                        "10\" remount fails an unchanged unit), and the bench's if it was adjusted. Fit both with "
                        "--lab ([fixture] mounting_u_arcsec) to have them in u")


@dataclass
class SharedErrors:
    """The systematic errors two calibrations share: per source (``source``, ``key``,
    ``equipment``, ``u``, ``unit``) and, per parameter, the sensitivities before and after."""

    equipment: tuple = ()
    sources: list = field(default_factory=list)
    c_before: dict = field(default_factory=dict)     # source -> {name: c}
    c_after: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def cross(self, names: Sequence[str]) -> np.ndarray:
        """``X[i, j] = sum_s c_b,s,i c_a,s,j u_s^2`` (the covariance of before's errors of
        ``names[i]`` with after's of ``names[j]``); the drift covariance is ``C_b + C_a - X - X^T``."""
        X = np.zeros((len(names), len(names)))
        for s in self.sources:
            cb = np.array([self.c_before[s["source"]].get(n, 0.0) for n in names])
            ca = np.array([self.c_after[s["source"]].get(n, 0.0) for n in names])
            X += np.outer(cb, ca) * s["u"] ** 2
        return X

    def covariance(self, name: str) -> float:
        """``sum_s c_b,s c_a,s u_s^2`` of one parameter."""
        return float(self.cross([name])[0, 0])

    def to_dict(self, names: Sequence[str] = ()) -> dict:
        return {"equipment": list(self.equipment), "sources": [dict(s) for s in self.sources],
                "covariance": {n: self.covariance(n) for n in names if self.sources}}


def _source_table(result: CalibrationResult, names: Sequence[str], tag: str, equipment: Sequence[str]):
    """``({source: row info}, {source: {name: c}})`` of the Type B rows of ``equipment``; a source
    whose u differs between two parameters of one result is refused."""
    info, sens = {}, {}
    for n in names:
        for r in type_b_rows(result, n):
            eq = _equipment(r.get("key"))
            if eq not in equipment:
                continue
            src = str(r.get("source"))
            u, unit, c = r.get("u"), r.get("unit"), r.get("sensitivity")
            if not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in (u, c)):
                raise InputError(f"the {tag} calibration: {n}'s budget row {src!r} has no finite u and sensitivity "
                                 "(both are needed to share it)")
            row = {"source": src, "key": r.get("key", ""), "equipment": eq, "u": float(u), "unit": unit}
            if src in info and not (math.isclose(info[src]["u"], row["u"], rel_tol=1e-9)
                                    and info[src]["unit"] == unit):
                raise InputError(f"the {tag} calibration: source {src!r} has u = {info[src]['u']:g} "
                                 f"{info[src]['unit']} in one parameter's budget and {row['u']:g} {unit} in {n}'s")
            info.setdefault(src, row)
            sens.setdefault(src, {})[n] = float(c)
    return info, sens


def shared_errors(before: CalibrationResult, after: CalibrationResult, names: Sequence[str],
                  equipment: Sequence[str]) -> SharedErrors:
    """The Type B sources of ``equipment`` that both results carry (same ``source`` name): one
    error in both calibrations. Their ``u`` must agree (else an InputError naming the source and
    both values); a source in one result only, or a result without budget rows, is said in
    ``notes`` (nothing to share from it)."""
    equipment = tuple(dict.fromkeys(equipment))
    out = SharedErrors(equipment=equipment)
    if not equipment:
        return out
    for tag, r in (("before", before), ("after", after)):
        if not budget_equipment(r):
            out.notes.append(f"shared equipment {', '.join(equipment)} requested, but the {tag} calibration has no "
                             "budget rows (fitted without a lab file: its u is Type A only): nothing to share")
    info_b, sens_b = _source_table(before, names, "before", equipment)
    info_a, sens_a = _source_table(after, names, "after", equipment)
    for src in info_b:
        if src not in info_a:
            continue
        b, a = info_b[src], info_a[src]
        if b["unit"] != a["unit"] or not math.isclose(b["u"], a["u"], rel_tol=1e-9):
            raise InputError(f"shared source {src!r} ({b['key']}): u = {b['u']:g} {b['unit']} in the before "
                             f"calibration and {a['u']:g} {a['unit']} in the after one; one error of shared "
                             "equipment has one uncertainty: fit both with the same lab file, or do not share "
                             f"[{b['equipment']}]")
        out.sources.append(b)
        out.c_before[src], out.c_after[src] = sens_b[src], sens_a[src]
    one = sorted(set(info_b) ^ set(info_a))
    if one and info_b and info_a:
        out.notes.append("not shared (Type B row of shared equipment in one calibration only): " + ", ".join(one))
    missing = [e for e in equipment if not any(s["equipment"] == e for s in out.sources)]
    if missing and budget_equipment(before) and budget_equipment(after):
        out.notes.append(f"shared equipment {', '.join(missing)}: no Type B row in both calibrations, nothing to share")
    return out


def read_posterior(source):
    """An arviz InferenceData from a netCDF path (the one reader,
    :func:`triadcal.io.netcdf.read_inference_data`), an InferenceData as is, a dict of draws as is."""
    if isinstance(source, (str, os.PathLike)):
        from ...io.netcdf import read_inference_data

        return read_inference_data(source)
    return source


def posterior_draws(source) -> dict:
    """Posterior draws by parameter name from an arviz InferenceData (object or netCDF path).

    The ``posterior`` group's variables are named like the parameters (``Ca_xy``), in the
    reporting unit; a ``unit``/``units`` attribute, when present, is kept for checking.
    Returns ``{name: (flat draws, unit or None)}``.
    """
    if isinstance(source, dict):
        return {k: (np.asarray(v, float).ravel(), None) for k, v in source.items()}
    idata = read_posterior(source)
    if not hasattr(idata, "posterior"):
        raise InputError(f"{source}: has no 'posterior' group (expected arviz InferenceData)")
    post = idata.posterior
    out = {}
    for name, var in post.data_vars.items():
        if set(var.dims) - {"chain", "draw"}:
            continue  # vector-valued variables are not parameters of results-json
        unit = var.attrs.get("unit", var.attrs.get("units"))
        out[str(name)] = (np.asarray(var.values, float).ravel(), unit)
    return out


#: a posterior whose mean of a parameter lies further than this many standard deviations (the
#: larger of the draws' SD and the result's u) from the result's value is not that result's
#: posterior: a posterior of the same data and model differs from its result by a fraction of u
POSTERIOR_MEAN_TOLERANCE = 1.0
#: ... nor one whose draws' SD of a parameter exceeds this many times the result's u (the result's u
#: is the posterior's SD, or a least-squares u within a few % of it, or larger with Type B rows: never
#: much smaller). An outside probe gave the certificate another campaign's posterior, Ca_xy 300 +- 101
#: arcsec beside a result of 312.3 +- 0.28: the means agreed within one of the draws' SD
POSTERIOR_SD_RATIO_MAX = 2.0


#: a parameter-like variable name (the model's naming, docs/results-json.md)
_PARAMETER_LIKE = re.compile(r"^(K_|S_|Ca_|tilt_)")


#: the bench tilt's polar form: derived from tilt_x, tilt_y, in a posterior or a result or neither
_DERIVED = ("tilt_delta", "tilt_beta")


def check_posterior(source, draws: dict, result: CalibrationResult, what: str) -> None:
    """Refuse a posterior that is not ``result``'s, naming it (``what``: the file, or which side):

    * a parameter in another unit than the result's;
    * the posterior group's ``unit`` attribute (the serial, written by ``triadcal sample``)
      differs from the result's unit;
    * its parameter set differs: a parameter-like variable (``K_``, ``S_``, ``Ca_``, ``tilt_``)
      the result does not have; for a file written by triadcal, a parameter of the result it
      does not have;
    * the certificate's checks of a posterior against its result
      (:func:`triadcal.reports.certificate.refusal.refusal_reasons` with
      :func:`~triadcal.reports.certificate.refusal.posterior_diagnostics`, reused as is): the
      stored convergence fingerprint differs from the result's (not the file written with it),
      or the draws did not converge;
    * a posterior mean further than ``POSTERIOR_MEAN_TOLERANCE`` standard deviations from the
      result's value (swapped posteriors: before's draws with after's result), or an SD above
      ``POSTERIOR_SD_RATIO_MAX`` times its u (:func:`check_posterior_moments`).
    """
    check_posterior_identity(source, draws, result, what)
    idata = None if isinstance(source, dict) else source
    if idata is not None:
        from ...reports.certificate.refusal import posterior_diagnostics, refusal_reasons

        diag = posterior_diagnostics(idata, list(result.parameters), result)
        if diag:
            plain = set(refusal_reasons(result))
            reasons = [r for r in refusal_reasons(result, posterior_diag=diag) if r not in plain]
            if reasons:
                raise InputError(f"{what}: " + "; ".join(reasons))
    check_posterior_moments(draws, result, what)


def check_posterior_identity(source, draws: dict, result: CalibrationResult, what: str) -> None:
    """The first checks of :func:`check_posterior`: the posterior is of ``result``'s unit (its
    ``unit`` attribute), in its parameters' units, with its parameter set. Also used by the
    certificate, whose convergence checks are its refusal report's."""
    for n, (_, unit_p) in draws.items():
        if n in result.parameters and unit_p is not None and unit_p != result[n].unit:
            raise InputError(f"{what}: {n} is in {unit_p!r}, the result gives {result[n].unit!r}")
    idata = None if isinstance(source, dict) else source
    attrs = dict(getattr(getattr(idata, "posterior", None), "attrs", {}) or {})
    serial = attrs.get("unit")
    if isinstance(serial, str) and serial != result.unit:
        raise InputError(f"{what} is a posterior of unit {serial!r}, its result is of unit {result.unit!r}: "
                         "give the posterior written with that result")
    extra = sorted(n for n in draws if _PARAMETER_LIKE.match(n) and n not in result.parameters
                   and n not in _DERIVED)
    missing = sorted(n for n in result.parameters if n not in draws and n not in _DERIVED)
    by_triadcal = str(attrs.get("created_by", "")).startswith("triadcal")
    if extra or (missing and by_triadcal):
        bits = ([f"holds {', '.join(extra)}, which its result does not have"] if extra else []) + \
               ([f"lacks {', '.join(missing)}, which its result has"] if missing and by_triadcal else [])
        raise InputError(f"{what}: its parameter set differs from its result's ({'; '.join(bits)}): a posterior "
                         "of another model or unit; give the posterior written with that result")


def check_posterior_moments(draws: dict, result: CalibrationResult, what: str) -> None:
    """Refuse draws that are not ``result``'s posterior by their moments: a mean further than
    :data:`POSTERIOR_MEAN_TOLERANCE` standard deviations from the value, or an SD above
    :data:`POSTERIOR_SD_RATIO_MAX` times the result's u (compare; the certificate)."""
    bad = [n for n, (d, _) in draws.items() if not np.all(np.isfinite(np.asarray(d, float)))]
    if bad:
        # one NaN draw read as "wider ... (SD nan ... nan times)" (an outside fuzz probe)
        raise InputError(f"{what}: its draws of {', '.join(bad[:3])}{' ...' if len(bad) > 3 else ''} hold a value "
                         "that is not a finite number: not a posterior `triadcal sample` wrote")
    wide = []
    for n, (d, _) in draws.items():
        if n not in result.parameters or n in _DERIVED or len(d) < 2:
            continue
        sd, u = float(np.std(d)), result[n].u
        if u > 0 and not sd <= POSTERIOR_SD_RATIO_MAX * u:
            wide.append((sd / u, n, sd, u, result[n].unit))
    if wide:
        wide.sort(reverse=True)
        worst = "; ".join(f"{n}: SD {sd:.4g} against the result's u {u:.4g} {unit} ({k:.3g} times)"
                          for k, n, sd, u, unit in wide[:3])
        raise InputError(f"{what}: its draws are wider than its result's uncertainties by more than "
                         f"{POSTERIOR_SD_RATIO_MAX:g} times ({worst}"
                         f"{f'; and {len(wide) - 3} more' if len(wide) > 3 else ''}): not this result's posterior; "
                         "give the netCDF that `triadcal sample` wrote with it")
    _check_posterior_means(draws, result, what)


def _check_posterior_means(draws: dict, result: CalibrationResult, what: str) -> None:
    off = []
    for n, (d, _) in draws.items():
        if n not in result.parameters or n in _DERIVED or len(d) == 0:
            continue
        p = result[n]
        scale = max(float(np.std(d)), p.u)
        gap = abs(float(np.mean(d)) - p.value)
        if not gap <= POSTERIOR_MEAN_TOLERANCE * scale:
            off.append((gap / scale if scale > 0 else math.inf, n, float(np.mean(d)), p.value, scale, p.unit))
    if off:
        off.sort(reverse=True)
        worst = "; ".join(f"{n}: mean {m:.6g} against the result's {v:.6g} {unit} ({k:.3g} sd)"
                          for k, n, m, v, _, unit in off[:3])
        raise InputError(f"{what}: its means disagree with its result's values by more than "
                         f"{POSTERIOR_MEAN_TOLERANCE:g} standard deviation ({worst}"
                         f"{f'; and {len(off) - 3} more' if len(off) > 3 else ''}): not this result's posterior "
                         "(another run's, an edited file, or before and after swapped?)")


def posterior_drift(draws_before: np.ndarray, draws_after: np.ndarray, seed: int = 0,
                    n_pairs: int = POSTERIOR_PAIRS) -> np.ndarray:
    """Draws of ``after - before`` for independent posteriors: random pairs (fixed seed)."""
    rng = np.random.default_rng(seed)
    i = rng.integers(0, len(draws_before), n_pairs)
    j = rng.integers(0, len(draws_after), n_pairs)
    return draws_after[j] - draws_before[i]


def _type_b_u(p) -> float:
    """The Type B part of a parameter's u: its budget's Type B rows in quadrature (0 without)."""
    rows = [r for r in (p.uncertainty.get("budget") or []) if isinstance(r, dict) and r.get("type") == "B"]
    return math.sqrt(sum(float(r.get("contribution") or 0.0) ** 2 for r in rows))


def budget_rho_limits(before: CalibrationResult, after: CalibrationResult, names) -> dict:
    """The most correlation the two results' budgets can hold, per parameter: errors two fitted
    calibrations share are systematic (the lab's, in their Type B rows): a shared source gives the
    covariance ``c_b c_a u_s^2 <= uB_b uB_a``, so ``rho <= uB_b uB_a / (u_b u_a)``; their Type A
    parts come from separate campaigns and are independent. Parameters with ``u = 0`` are left out."""
    out = {}
    for n in names:
        b, a = before[n], after[n]
        if b.u > 0 and a.u > 0:
            out[n] = _type_b_u(b) * _type_b_u(a) / (b.u * a.u)
    return out


def stated_rho_beyond_budgets(before: CalibrationResult, after: CalibrationResult, names, rho: float):
    """The note when a stated ``rho > 0`` claims more shared error than the two results can share
    (:func:`budget_rho_limits`), or None. An outside probe: an unmoved unit without a lab file,
    ``--correlation 0.9``: u(d) 7.0 -> 2.2 arcsec, five of six angles "fail", no word."""
    worst = None
    for n, limit in budget_rho_limits(before, after, names).items():
        b, a = before[n], after[n]
        if rho > limit + 1e-9 and (worst is None or rho - limit > worst[1]):
            worst = (n, rho - limit, limit, drift_uncertainty(b.u, a.u, rho), drift_uncertainty(b.u, a.u, 0.0), b.unit)
    if worst is None:
        return None
    n, _, limit, u_rho, u_0, unit = worst
    return (f"rho = {rho:g} stated: more shared error than the results hold — two fitted calibrations share only "
            f"systematic errors (their budgets' Type B rows; the Type A parts come from separate campaigns and are "
            f"independent), which allow at most rho = {limit:.2g} for {n}; its u(d) is {u_rho:.3g} {unit} with the "
            f"stated rho against {u_0:.3g} at 0, so a drift judged significant here may be noise. Fit both "
            "calibrations with the lab file and name the shared equipment (--lab with --shared-bench) instead")


def rho_rescaled(draws: np.ndarray, db: np.ndarray, da: np.ndarray, rho: float) -> np.ndarray:
    """Drift draws of independent posteriors with their spread about the mean rescaled for a shared
    error ``rho`` (the spread of ``u(d) = sqrt(u_b^2 + u_a^2 - 2 rho u_b u_a)``)."""
    if rho == 0.0:
        return draws
    s0 = math.sqrt(np.var(db) + np.var(da))
    s_rho = drift_uncertainty(float(np.std(db)), float(np.std(da)), rho)
    return draws.mean() + (draws - draws.mean()) * (s_rho / s0 if s0 > 0 else 1.0)
