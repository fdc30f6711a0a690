"""Drift of a unit between two calibrations, judged against the uncertainty of both.

The seed paper (Table 3) judges each drift of the orientation angles after a shock or a
vibration against a fixed +-30" (2.5 sigma of one angle measurement, eq. 4). Here a
drift ``d = after - before`` is judged against its own standard uncertainty::

    u^2(d) = u_b^2 + u_a^2 - 2 rho u_b u_a

where ``rho`` is the correlation between the errors of the two calibrations (errors a
shared bench makes identically in both cancel in the difference). For the six angles the
full covariance of the drift vector, built from both results' correlation matrices, gives
a joint test (Mahalanobis distance against chi^2). ISO 13528's normalised error
``En = |d| / sqrt(U_b^2 + U_a^2 - 2 rho U_b U_a)`` with ``U = 2u`` is reported beside.

Decision rule (:func:`decide`, stated in every output; docs/compare.md):

* significant: ``|d| > k2 u(d)``, ``k2`` the two-sided normal quantile of ``level``;
* with a tolerance ``T``: **pass** when ``|d| + k1 u(d) <= T`` (conformance shown with
  confidence ``level``, ``k1`` one-sided: ISO 14253-1 acceptance with a guard band),
  **fail** when the drift is significant and ``|d| > T`` (the unit moved, and its best
  estimate is outside the tolerance), **inconclusive** otherwise;
* without a tolerance: **fail** when significant, **pass** otherwise (no drift detected).

With posteriors the same rule is evaluated on draws of the drift: significant when 0 lies
outside the central ``level`` interval, pass when ``P(|drift| > T) <= 1 - level``, fail when
significant and ``P(|drift| > T) > 1/2``.

Library code: no printing; the CLI (``triadcal compare``) prints.
"""

from __future__ import annotations

from ..errors import InputError

import csv
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Optional, Sequence, Union

import numpy as np
from scipy import stats

from ..io.atomic import atomic_write_json
from ..io.formats import require_format
from ..io.numbers import parse_number
from ..models.sensor import ANGLE_NAMES
from ..estimation.gates import check_result_for_use
from ..estimation.result import CalibrationResult
from ..io.atomic import read_json

FORMAT = "triadcal.comparison"
SEQUENCE_FORMAT = "triadcal.comparison_sequence"
VERSION = 1
VERDICTS = ("pass", "fail", "inconclusive")

#: the six orientation angles of eq. 1, in the order of results-json
ANGLES = tuple(f"Ca_{ab}" for ab in ANGLE_NAMES)
#: properties of the bench, not of the unit: compared as a check, never judged
BENCH_PARAMETERS = ("tilt_x", "tilt_y", "tilt_delta", "tilt_beta")
#: coverage factor of ISO 13528's En (expanded uncertainty U = k u)
EN_COVERAGE_FACTOR = 2.0
#: number of random before/after draw pairs used for posterior drifts
POSTERIOR_PAIRS = 50_000

_TOLERANCE_UNITS = {"arcsec": 1.0, "arcmin": 60.0, "deg": 3600.0}
_TOLERANCE_ALIASES = {'"': "arcsec", "''": "arcsec", "as": "arcsec", "'": "arcmin", "amin": "arcmin",
                      "degree": "deg", "degrees": "deg"}


# -- small pure functions --------------------------------------------------------------

def coverage_factors(level: float) -> tuple[float, float]:
    """``(k2, k1)``: two-sided and one-sided normal coverage factors for ``level``."""
    if not 0.5 < level < 1.0:
        raise InputError(f"level must be between 0.5 and 1 (e.g. 0.95), got {level!r}")
    return float(stats.norm.ppf(0.5 + level / 2)), float(stats.norm.ppf(level))


def parse_tolerance(text: Union[str, float, None]) -> Optional[float]:
    """A tolerance with its unit (``30arcsec``, ``0.5arcmin``, ``0.01deg``) in arcseconds.

    ``none`` (or None) means no tolerance. A bare number is refused: the unit must be said.
    """
    if text is None:
        return None
    if isinstance(text, (int, float)):
        raise InputError(f"tolerance {text!r} has no unit: write e.g. {text}arcsec, {text}arcmin or {text}deg")
    s = str(text).strip()
    if s.lower() == "none":
        return None
    m = re.fullmatch(r"([+]?\d+(?:\.\d*)?(?:[eE][+-]?\d+)?|\.\d+)\s*(.*)", s)
    if not m:
        raise InputError(f"cannot read tolerance {text!r}: write a number and a unit, e.g. 30arcsec")
    value, unit = float(m.group(1)), m.group(2).strip()
    unit = _TOLERANCE_ALIASES.get(unit, unit.lower())
    if not unit:
        raise InputError(f"tolerance {text!r} has no unit: write e.g. {s}arcsec, {s}arcmin or {s}deg")
    if unit not in _TOLERANCE_UNITS:
        raise InputError(f"tolerance {text!r}: unknown unit {m.group(2).strip()!r}; "
                         f"use one of {', '.join(_TOLERANCE_UNITS)}")
    return value * _TOLERANCE_UNITS[unit]


def drift_uncertainty(u_before: float, u_after: float, rho: float = 0.0) -> float:
    """``u(d) = sqrt(u_b^2 + u_a^2 - 2 rho u_b u_a)`` for ``d = after - before`` (GUM 5.2.2)."""
    v = u_before ** 2 + u_after ** 2 - 2.0 * rho * u_before * u_after
    return math.sqrt(max(v, 0.0))


def normalised_error(drift: float, u_before: float, u_after: float, rho: float = 0.0,
                     k: float = EN_COVERAGE_FACTOR) -> float:
    """ISO 13528 ``En = |x_a - x_b| / sqrt(U_a^2 + U_b^2 - 2 rho U_a U_b)``, ``U = k u``."""
    U = k * drift_uncertainty(u_before, u_after, rho)
    return abs(drift) / U if U > 0 else (0.0 if drift == 0 else math.inf)


def probability_exceeds(drift: float, u: float, tolerance: Optional[float]) -> Optional[float]:
    """``P(|true drift| > T)`` for a normal state of knowledge ``N(drift, u^2)``."""
    if tolerance is None:
        return None
    if u <= 0:
        return float(abs(drift) > tolerance)
    return float(stats.norm.sf((tolerance - drift) / u) + stats.norm.cdf((-tolerance - drift) / u))


def decide(drift: float, u: float, tolerance: Optional[float], level: float = 0.95) -> tuple[str, bool]:
    """Verdict and significance of one drift under the module's rule (normal approximation)."""
    k2, k1 = coverage_factors(level)
    significant = abs(drift) > k2 * u if u > 0 else drift != 0
    if tolerance is None:
        return ("fail" if significant else "pass"), bool(significant)
    if abs(drift) + k1 * u <= tolerance:
        return "pass", bool(significant)
    if significant and abs(drift) > tolerance:
        return "fail", bool(significant)
    return "inconclusive", bool(significant)


def decide_from_draws(draws: np.ndarray, tolerance: Optional[float], level: float = 0.95):
    """Verdict, significance and ``P(|drift| > T)`` from draws of the drift (posterior form)."""
    lo, hi = np.quantile(draws, [0.5 - level / 2, 0.5 + level / 2])
    significant = bool(lo > 0 or hi < 0)
    if tolerance is None:
        return ("fail" if significant else "pass"), significant, None
    p = float(np.mean(np.abs(draws) > tolerance))
    if p <= 1 - level:
        return "pass", significant, p
    if significant and p > 0.5:
        return "fail", significant, p
    return "inconclusive", significant, p


def rule_text(level: float, tolerance_arcsec: Optional[float], tolerances: Mapping[str, float] = None,
              posterior: bool = False) -> str:
    """The decision rule in words, with its numbers (written into every output)."""
    k2, k1 = coverage_factors(level)
    pct = f"{100 * level:g}%"
    tol = (f"T = {tolerance_arcsec:g} arcsec for the angles" if tolerance_arcsec is not None
           else "no tolerance for the angles")
    if tolerances:
        tol += "; " + ", ".join(f"T = {v:g} for {k}" for k, v in tolerances.items())
    text = (
        f"Drift d = after - before with standard uncertainty u(d) = sqrt(u_b^2 + u_a^2 - 2 rho u_b u_a). "
        f"Significant when |d| > {k2:.3f} u(d) (two-sided {pct}). With a tolerance T: pass when "
        f"|d| + {k1:.3f} u(d) <= T (conformance shown with {pct} confidence, ISO 14253-1 guard band); "
        f"fail when d is significant and |d| > T; inconclusive otherwise. Without a tolerance: fail when "
        f"significant, pass otherwise (no drift detected). {tol}. Overall (angles, and parameters given a "
        f"tolerance): fail when the joint chi2 test of the angle drifts is significant at {pct} and an angle "
        f"fails (without a tolerance: when the joint test is significant); pass when every judged parameter "
        f"passes (without a tolerance: and the joint test is not significant); inconclusive otherwise. "
        f"En (ISO 13528, U = 2u) is reported, not used in the verdict.")
    if posterior:
        text += (f" Where posterior draws are given, the same rule on the draws of the drift: significant "
                 f"when 0 is outside the central {pct} interval, pass when P(|d| > T) <= {1 - level:.3g}, "
                 f"fail when significant and P(|d| > T) > 0.5.")
    return text


# -- correlation between the two calibrations --------------------------------------------

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
    {"term": "repeatable bench errors (encoder error at the commanded angles, axis non-orthogonality, "
             "wobble as a function of angle, fixture)", "shared": True,
     "how": "identical in both campaigns, so they cancel in the drift; the fit's u does not contain them, "
            "so nothing is subtracted (rho = 0); if a result's u includes such a budget term, state rho"},
    {"term": "temperature sensors and reference temperature (thermal terms)", "shared": True,
     "how": "a sensor offset shifts both calibrations alike and cancels; not in the fit's u"},
    {"term": "local gravity value (K)", "shared": True,
     "how": "scales K identically when both use the same value, cancels in the K drift; not in the fit's u"},
)


def derive_correlation(before: CalibrationResult, after: CalibrationResult) -> tuple[float, str]:
    """Default correlation ``rho`` between two calibrations' errors, with the reason."""
    methods = {before.method, after.method}
    if methods <= {"joint", "classical", "posterior"}:
        return 0.0, ("rho = 0: the uncertainties of fitted results come from each campaign's own random "
                     "errors (output noise, per-visit bench errors), which are independent between "
                     "campaigns; the bench's shared systematic errors cancel in the drift and are not in "
                     "these uncertainties, so there is nothing to subtract")
    return 0.0, f"rho = 0 assumed for methods {sorted(methods)}: no shared component is known"


# -- posteriors -------------------------------------------------------------------------

def posterior_draws(source) -> dict:
    """Posterior draws by parameter name from an arviz InferenceData (object or netCDF path).

    The ``posterior`` group's variables are named like the parameters (``Ca_xy``), in the
    reporting unit; a ``unit``/``units`` attribute, when present, is kept for checking.
    Returns ``{name: (flat draws, unit or None)}``.
    """
    if isinstance(source, dict):
        return {k: (np.asarray(v, float).ravel(), None) for k, v in source.items()}
    if isinstance(source, (str, os.PathLike)):
        from ..io.netcdf import read_inference_data

        idata = read_inference_data(source)
    else:
        idata = source
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


def posterior_drift(draws_before: np.ndarray, draws_after: np.ndarray, seed: int = 0,
                    n_pairs: int = POSTERIOR_PAIRS) -> np.ndarray:
    """Draws of ``after - before`` for independent posteriors: random pairs (fixed seed)."""
    rng = np.random.default_rng(seed)
    i = rng.integers(0, len(draws_before), n_pairs)
    j = rng.integers(0, len(draws_after), n_pairs)
    return draws_after[j] - draws_before[i]


# -- results ----------------------------------------------------------------------------

@dataclass
class ParameterDrift:
    """Drift of one parameter between two calibrations, and its verdict."""

    name: str
    unit: str
    drift: float
    u: float
    before: Optional[float] = None
    after: Optional[float] = None
    u_before: Optional[float] = None
    u_after: Optional[float] = None
    rho: float = 0.0
    tolerance: Optional[float] = None
    En: float = float("nan")
    z: float = float("nan")
    p_value: float = float("nan")
    significant: bool = False
    p_exceeds: Optional[float] = None
    verdict: str = "inconclusive"
    basis: str = "normal"
    n_draws: Optional[int] = None
    judged: bool = True

    @property
    def U(self) -> float:
        """Expanded uncertainty of the drift, k = 2."""
        return EN_COVERAGE_FACTOR * self.u

    def to_dict(self) -> dict:
        d = {"drift": self.drift, "u": self.u, "unit": self.unit, "U": self.U, "k": EN_COVERAGE_FACTOR,
             "En": self.En, "z": self.z, "p_value": self.p_value, "significant": self.significant,
             "tolerance": self.tolerance, "p_exceeds": self.p_exceeds, "verdict": self.verdict,
             "basis": self.basis, "rho": self.rho, "judged": self.judged}
        for k in ("before", "after", "u_before", "u_after", "n_draws"):
            if getattr(self, k) is not None:
                d[k] = getattr(self, k)
        return {k: _finite(v) for k, v in d.items()}

    @classmethod
    def from_dict(cls, name: str, d: Mapping, source: str = "<dict>") -> "ParameterDrift":
        where = f"{source}: parameters.{name}"
        if not isinstance(d, Mapping):
            raise InputError(f"{where} is not an object")
        num = _Fields(where, d)
        if d.get("verdict") not in VERDICTS:
            raise InputError(f"{where}.verdict {d.get('verdict')!r} is not one of {VERDICTS}")
        if not isinstance(d.get("unit"), str):
            raise InputError(f"{where}.unit is missing or not a string")
        return cls(name=name, unit=d["unit"], drift=num.req("drift"), u=num.req("u", low=0.0),
                   before=num.opt("before"), after=num.opt("after"), u_before=num.opt("u_before", low=0.0),
                   u_after=num.opt("u_after", low=0.0), rho=num.opt("rho", -1.0, 1.0, default=0.0),
                   tolerance=num.opt("tolerance", low=0.0), En=num.nan("En"), z=num.nan("z"),
                   p_value=num.nan("p_value"), significant=bool(d.get("significant", False)),
                   p_exceeds=num.opt("p_exceeds", 0.0, 1.0), verdict=d["verdict"], basis=str(d.get("basis", "normal")),
                   n_draws=None if d.get("n_draws") is None else int(num.req("n_draws", low=0.0)),
                   judged=bool(d.get("judged", True)))


class _Fields:
    """Numbers of a JSON object with one-line errors naming the field (``null`` is "not finite")."""

    def __init__(self, where: str, d: Mapping):
        self.where, self.d = where, d

    def _check(self, key, v, low, high):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(f"{self.where}.{key} = {v!r:.40} is not a finite number")
        if not low <= v <= high:
            raise InputError(f"{self.where}.{key} = {v!r} is outside [{low:g}, {high:g}]")
        return float(v)

    def req(self, key, low=-math.inf, high=math.inf) -> float:
        return self._check(key, self.d.get(key), low, high)

    def opt(self, key, low=-math.inf, high=math.inf, default=None):
        v = self.d.get(key)
        return default if v is None else self._check(key, v, low, high)

    def nan(self, key) -> float:
        v = self.d.get(key)
        return float("nan") if v is None else self._check(key, v, -math.inf, math.inf)


@dataclass
class JointTest:
    """Mahalanobis distance of the angle-drift vector against chi^2 with ``dof`` degrees of freedom."""

    names: tuple
    D2: float
    dof: int
    p_value: float
    significant: bool
    level: float

    def to_dict(self) -> dict:
        return {"names": list(self.names), "D2": self.D2, "dof": self.dof, "p_value": self.p_value,
                "significant": self.significant, "level": self.level,
                "critical": float(stats.chi2.ppf(self.level, self.dof))}

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "<dict>") -> "JointTest":
        num = _Fields(f"{source}: joint", d)
        names = d.get("names")
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise InputError(f"{source}: joint.names is not a list of names")
        return cls(tuple(names), num.req("D2", low=0.0), int(num.req("dof", low=1.0)), num.req("p_value", 0.0, 1.0),
                   bool(d.get("significant")), num.req("level", 0.0, 1.0))


@dataclass
class ComparisonResult:
    """Drifts of a unit between two calibrations (results-json ``triadcal.comparison`` v1)."""

    parameters: dict
    overall: str
    rule: str
    level: float = 0.95
    tolerance_arcsec: Optional[float] = 30.0
    tolerances: dict = field(default_factory=dict)
    correlation: dict = field(default_factory=dict)
    joint: Optional[JointTest] = None
    bench_check: dict = field(default_factory=dict)
    before: dict = field(default_factory=dict)
    after: dict = field(default_factory=dict)
    label: Optional[str] = None
    notes: list = field(default_factory=list)

    def __getitem__(self, name: str) -> ParameterDrift:
        return self.parameters[name]

    def verdicts(self) -> dict:
        return {k: p.verdict for k, p in self.parameters.items()}

    def failing(self, judged_only: bool = True) -> list:
        """Names whose verdict is fail (by default only the judged ones: angles and parameters
        given a tolerance; the others' verdict is a significance test only)."""
        return [k for k, p in self.parameters.items() if p.verdict == "fail" and (p.judged or not judged_only)]

    def to_dict(self) -> dict:
        d = {"format": FORMAT, "version": VERSION, "rule": self.rule, "level": self.level,
             "tolerance": {"angles_arcsec": self.tolerance_arcsec, **self.tolerances},
             "parameters": {k: p.to_dict() for k, p in self.parameters.items()},
             "joint": None if self.joint is None else self.joint.to_dict(),
             "correlation": self.correlation, "bench_check": self.bench_check,
             "before": self.before, "after": self.after, "overall": self.overall, "notes": list(self.notes)}
        if self.label is not None:
            d["label"] = self.label
        return d

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "<dict>") -> "ComparisonResult":
        require_format(d, FORMAT, VERSION, source, "a comparison", "comparison")
        if not isinstance(d.get("parameters"), Mapping) or not d["parameters"]:
            raise InputError(f"{source}: parameters is missing or empty")
        if not isinstance(d.get("rule"), str):
            raise InputError(f"{source}: rule is missing or not a string")
        for key in ("tolerance", "correlation", "bench_check", "before", "after"):
            if d.get(key) is not None and not isinstance(d[key], Mapping):
                raise InputError(f"{source}: {key} is not an object")
        if d.get("notes") is not None and not isinstance(d["notes"], list):
            raise InputError(f"{source}: notes is not a list")
        level = _Fields(source + ":", d).opt("level", 0.0, 1.0, default=0.95)
        if d.get("overall") not in VERDICTS:
            raise InputError(f"{source}: overall verdict {d.get('overall')!r} is not one of {VERDICTS}")
        tol = dict(d.get("tolerance") or {})
        angles_tol = tol.pop("angles_arcsec", None)
        params = {k: ParameterDrift.from_dict(k, p, source) for k, p in d["parameters"].items()}
        if d["overall"] == "pass" and any(p.verdict == "fail" and p.judged for p in params.values()):
            raise InputError(f"{source}: overall verdict 'pass' contradicts a judged parameter whose verdict is 'fail'")
        return cls(parameters=params,
                   overall=d["overall"], rule=d["rule"], level=level,
                   tolerance_arcsec=angles_tol, tolerances=tol, correlation=d.get("correlation", {}),
                   joint=None if not d.get("joint") else JointTest.from_dict(d["joint"], source),
                   bench_check=d.get("bench_check", {}), before=d.get("before", {}),
                   after=d.get("after", {}), label=d.get("label"), notes=list(d.get("notes", [])))

    def save(self, path) -> None:
        _save_json(self.to_dict(), path)

    @classmethod
    def load(cls, path) -> "ComparisonResult":
        return cls.from_dict(_load_json(path), str(path))


# -- the comparison ---------------------------------------------------------------------

def compare(before: CalibrationResult, after: CalibrationResult, *, tolerance_arcsec: Optional[float] = 30.0,
            tolerances: Optional[Mapping[str, float]] = None, posterior_before=None, posterior_after=None,
            correlation: Union[str, float] = "auto", level: float = 0.95,
            label: Optional[str] = None) -> ComparisonResult:
    """Drift of every parameter from ``before`` to ``after`` and the verdicts (``triadcal compare``).

    ``tolerance_arcsec``: tolerance on the drift of each angle (None: significance only).
    ``tolerances``: tolerances of other parameters by name, in their unit (e.g.
    ``{"K_x": 2e-5}``); those parameters then enter the overall verdict.
    ``posterior_before``/``posterior_after``: arviz InferenceData or netCDF paths whose
    ``posterior`` variables are named like the parameters (reporting units).
    ``correlation``: ``"auto"`` (derived, see :func:`derive_correlation`) or a coefficient
    rho in [-1, 1] between the two calibrations' errors, applied to every parameter.
    """
    k2, _ = coverage_factors(level)
    tolerances = dict(tolerances or {})
    if tolerance_arcsec is not None and tolerance_arcsec < 0:
        raise InputError(f"tolerance must be >= 0, got {tolerance_arcsec} arcsec")
    notes = []
    # a drift between calibrations one of which is not an answer is not a drift: refuse, naming
    # the side (status not ok, a value or u not finite, u < 0, a failing answer gate)
    for tag, r in (("before", before), ("after", after)):
        check_result_for_use(r, f"the {tag} calibration ({r.unit}, {r.method})")
    if before.unit != after.unit:
        raise InputError(f"before is unit {before.unit!r} and after is unit {after.unit!r}: a drift compares "
                         "two calibrations of the same unit")
    if before.reference_temperature_C != after.reference_temperature_C:
        raise InputError(f"reference temperatures differ ({before.reference_temperature_C:g} vs "
                         f"{after.reference_temperature_C:g} degC): refit one of them at the other's "
                         "reference temperature so the angles are comparable")
    if before.method != after.method:
        notes.append(f"methods differ ({before.method} vs {after.method}): a drift also contains the "
                     "difference between the estimators")
    gb, ga = before.extra.get("local_g_m_s2"), after.extra.get("local_g_m_s2")
    if gb is not None and ga is not None and gb != ga:
        notes.append(f"local gravity differs ({gb} vs {ga} m/s^2): the K drift contains that difference")

    if isinstance(correlation, str):
        if correlation != "auto":
            raise InputError(f"correlation must be 'auto' or a number in [-1, 1], got {correlation!r}")
        rho, reason = derive_correlation(before, after)
    else:
        rho = float(correlation)
        if not -1.0 <= rho <= 1.0:
            raise InputError(f"correlation must lie in [-1, 1], got {rho}")
        reason = f"rho = {rho:g} stated by the user for every parameter"

    names = [n for n in before.parameters if n in after.parameters and n not in BENCH_PARAMETERS]
    for n in names:
        if before[n].unit != after[n].unit:
            raise InputError(f"{n}: unit {before[n].unit!r} before and {after[n].unit!r} after")
    only = sorted(set(before.parameters) ^ set(after.parameters))
    if only:
        notes.append("not compared (present in one result only): " + ", ".join(only))
    unknown = [n for n in tolerances if n not in names]
    if unknown:
        raise InputError(f"tolerances given for {unknown}, which are not in both results")

    post_b = posterior_draws(posterior_before) if posterior_before is not None else None
    post_a = posterior_draws(posterior_after) if posterior_after is not None else None
    if (post_b is None) != (post_a is None):
        raise InputError("give posteriors for both calibrations (before and after), or for neither")

    params = {}
    for n in names:
        b, a = before[n], after[n]
        T = tolerance_arcsec if n in ANGLES else tolerances.get(n)
        judged = n in ANGLES or n in tolerances
        d = a.value - b.value
        u = drift_uncertainty(b.u, a.u, rho)
        z = d / u if u > 0 else (math.inf if d else 0.0)
        verdict, significant = decide(d, u, T, level)
        pd = ParameterDrift(
            name=n, unit=b.unit, drift=d, u=u, before=b.value, after=a.value, u_before=b.u, u_after=a.u,
            rho=rho, tolerance=T, En=normalised_error(d, b.u, a.u, rho), z=z,
            p_value=float(2 * stats.norm.sf(abs(z))), significant=significant,
            p_exceeds=probability_exceeds(d, u, T), verdict=verdict, judged=judged)
        if post_b is not None and n in post_b and n in post_a:
            (db, unit_b), (da, unit_a) = post_b[n], post_a[n]
            for tag, unit_p in (("before", unit_b), ("after", unit_a)):
                if unit_p is not None and unit_p != b.unit:
                    raise InputError(f"posterior {tag}: {n} is in {unit_p!r}, the results give {b.unit!r}")
            draws = posterior_drift(db, da)
            if rho != 0.0:
                # shared error: shrink the spread of the (independent-posterior) drift about its mean
                s0 = math.sqrt(np.var(db) + np.var(da))
                s_rho = drift_uncertainty(float(np.std(db)), float(np.std(da)), rho)
                draws = draws.mean() + (draws - draws.mean()) * (s_rho / s0 if s0 > 0 else 1.0)
            verdict, significant, p = decide_from_draws(draws, T, level)
            pd.verdict, pd.significant, pd.p_exceeds = verdict, significant, p
            pd.basis, pd.n_draws = "posterior", int(min(len(db), len(da)))
        params[n] = pd
    if post_b is not None:
        missing = [n for n in ANGLES if n in params and params[n].basis != "posterior"]
        if missing:
            notes.append("no posterior draws for " + ", ".join(missing) + ": judged on (value, u)")
        if rho != 0.0:
            notes.append("posterior drifts assume independent calibrations; their spread was rescaled "
                         f"about the mean for rho = {rho:g}")

    angles = [n for n in ANGLES if n in params]
    joint = None
    if angles:
        d = np.array([params[n].drift for n in angles])
        cov = combined_covariance(before.covariance(angles), after.covariance(angles), rho)
        joint = joint_test(d, cov, angles, level)

    bench = {}
    for n in ("tilt_x", "tilt_y"):
        if n in before.parameters and n in after.parameters:
            dd = after[n].value - before[n].value
            uu = drift_uncertainty(before[n].u, after[n].u, 0.0)
            bench[n] = {"drift": dd, "u": uu, "unit": before[n].unit,
                        "significant": bool(abs(dd) > k2 * uu)}
    if any(v["significant"] for v in bench.values()):
        notes.append("the bench tilt changed significantly between the campaigns: was the bench re-levelled "
                     "or moved? Shared bench errors may then not cancel")

    corr = {"rho": rho, "source": "derived" if correlation == "auto" else "stated", "reason": reason,
            "terms": [dict(t) for t in CORRELATION_TERMS],
            "within_calibration": ("each result's correlation matrix enters the covariance of the angle "
                                   "drifts (joint test); a single parameter's u(d) needs only its variances")
            if (before.correlation is not None or after.correlation is not None)
            else "no correlation matrix in the results: angles taken as uncorrelated within each calibration"}
    return ComparisonResult(
        parameters=params, overall=overall_verdict(params, joint, tolerance_arcsec), level=level,
        rule=rule_text(level, tolerance_arcsec, tolerances, posterior=post_b is not None),
        tolerance_arcsec=tolerance_arcsec, tolerances=tolerances, correlation=corr, joint=joint,
        bench_check=bench, before=_describe(before), after=_describe(after), label=label, notes=notes)


def combined_covariance(cov_before: np.ndarray, cov_after: np.ndarray, rho: float = 0.0) -> np.ndarray:
    """Covariance of ``after - before``: ``S_b + S_a - rho (D_b R D_a + D_a R D_b)``, ``R`` the mean
    correlation matrix of the two calibrations (reduces to ``u_b^2 + u_a^2 - 2 rho u_b u_a``)."""
    cov_before, cov_after = np.asarray(cov_before, float), np.asarray(cov_after, float)
    cov = cov_before + cov_after
    if rho != 0.0:
        ub, ua = np.sqrt(np.diag(cov_before)), np.sqrt(np.diag(cov_after))
        R = 0.5 * (cov_before / np.outer(ub, ub) + cov_after / np.outer(ua, ua))
        cross = rho * (ub[:, None] * R * ua[None, :])
        cov = cov - cross - cross.T
    return cov


def joint_test(drift: np.ndarray, cov: np.ndarray, names: Sequence[str], level: float = 0.95) -> JointTest:
    """``D^2 = d^T C^-1 d`` against chi^2 with ``len(d)`` dof (zero drift, Gaussian errors)."""
    drift = np.asarray(drift, float)
    w, V = np.linalg.eigh(cov)
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        raise InputError("the covariance of the angle drifts is singular or not positive definite "
                         f"(eigenvalues {w.min():.3g} .. {w.max():.3g}); check the correlation coefficient")
    y = V.T @ drift
    D2 = float(np.sum(y * y / w))
    p = float(stats.chi2.sf(D2, len(drift)))
    return JointTest(tuple(names), D2, len(drift), p, bool(p < 1 - level), level)


def _is_angle(name: str) -> bool:
    return name.rsplit(".", 1)[-1] in ANGLES


def overall_verdict(params: Mapping[str, ParameterDrift], joint: Optional[JointTest],
                    tolerance_arcsec: Optional[float]) -> str:
    """Overall verdict of the judged parameters (rule in :func:`rule_text`): the angles (the
    joint test guards the family against false alarms) and parameters given a tolerance."""
    angle_set = [p for p in params.values() if _is_angle(p.name)]
    others = [p for p in params.values() if p.judged and not _is_angle(p.name)]
    joint_significant = joint is not None and joint.significant
    if any(p.verdict == "fail" for p in others):
        return "fail"
    if tolerance_arcsec is None:
        if joint_significant:
            return "fail"
    elif joint_significant and any(p.verdict == "fail" for p in angle_set):
        return "fail"
    judged = angle_set + others
    if judged and all(p.verdict == "pass" for p in judged):
        return "pass"
    return "inconclusive"


def _describe(r: CalibrationResult) -> dict:
    d = {"unit": r.unit, "method": r.method, "status": r.status,
         "reference_temperature_C": r.reference_temperature_C}
    if r.extra.get("source"):
        d["source"] = r.extra["source"]
    return d


# -- sequences of exposures ---------------------------------------------------------------

@dataclass
class SequenceComparison:
    """A sequence of exposures compared step by step and against the first state.

    ``steps[i]`` compares state i with state i+1; ``cumulative[i]`` state 0 with state i+1.
    A published table carries only one kind (``kind``: what the table's drifts are).
    """

    labels: list
    steps: list
    cumulative: list
    kind: str = "results"
    rule: str = ""
    notes: list = field(default_factory=list)

    @property
    def overall(self) -> str:
        verdicts = [c.overall for c in self.steps + self.cumulative]
        if "fail" in verdicts:
            return "fail"
        return "pass" if verdicts and all(v == "pass" for v in verdicts) else "inconclusive"

    def to_dict(self) -> dict:
        return {"format": SEQUENCE_FORMAT, "version": VERSION, "kind": self.kind, "labels": list(self.labels),
                "rule": self.rule, "steps": [c.to_dict() for c in self.steps],
                "cumulative": [c.to_dict() for c in self.cumulative], "overall": self.overall,
                "notes": list(self.notes)}

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "<dict>") -> "SequenceComparison":
        require_format(d, SEQUENCE_FORMAT, VERSION, source, "a comparison sequence", "sequence")
        for key in ("labels", "steps", "cumulative"):
            if not isinstance(d.get(key), list):
                raise InputError(f"{source}: {key} is missing or not a list")
        return cls(labels=list(d["labels"]), steps=[ComparisonResult.from_dict(c, source) for c in d["steps"]],
                   cumulative=[ComparisonResult.from_dict(c, source) for c in d["cumulative"]],
                   kind=d.get("kind", "results"), rule=d.get("rule", ""), notes=list(d.get("notes", [])))

    def save(self, path) -> None:
        _save_json(self.to_dict(), path)

    @classmethod
    def load(cls, path) -> "SequenceComparison":
        return cls.from_dict(_load_json(path), str(path))

    def table(self, which: str = "step", names: Optional[Sequence[str]] = None, digits: int = 2) -> str:
        """The drifts as a text table like the paper's Table 3: a row per parameter, a column
        per exposure; each cell ``drift(u)`` and a mark: ``F`` fail, ``?`` inconclusive."""
        comps = self.comparisons(which)
        if not comps:
            return "(no comparisons)"
        if names is None:
            names = [n for n in comps[0].parameters if comps[0].parameters[n].judged]
        cols = [c.label or f"#{i + 1}" for i, c in enumerate(comps)]
        width = max(17, *(len(c) + 2 for c in cols))
        head = f"{'parameter':<16}" + "".join(f"{c:>{width}}" for c in cols)
        lines = [head]
        for n in names:
            cells = []
            for c in comps:
                p = c.parameters.get(n)
                if p is None:
                    cells.append(f"{'-':>{width}}")
                    continue
                mark = {"fail": " F", "inconclusive": " ?", "pass": "  "}[p.verdict] if p.judged else "  "
                cells.append(f"{p.drift:+.{digits}f}({p.u:.{max(digits - 1, 0)}f}){mark}".rjust(width))
            lines.append(f"{n:<16}" + "".join(cells))
        lines.append(f"{'joint p (chi2)':<16}" + "".join(
            (f"{c.joint.p_value:.3g}" if c.joint is not None else "-").rjust(width) for c in comps))
        lines.append(f"{'overall':<16}" + "".join(f"{c.overall:>{width}}" for c in comps))
        return "\n".join(lines)

    def comparisons(self, which: str) -> list:
        if which not in ("step", "cumulative"):
            raise InputError(f"which must be 'step' or 'cumulative', got {which!r}")
        return self.steps if which == "step" else self.cumulative


def compare_sequence(results: Sequence[CalibrationResult], labels: Optional[Sequence[str]] = None,
                     **kwargs) -> SequenceComparison:
    """Compare a sequence of calibrations (initial, after exposure 1, ...) step by step and
    against the initial one; ``kwargs`` as :func:`compare` (posteriors: a list per state as
    ``posteriors=[...]``)."""
    if len(results) < 2:
        raise InputError("a sequence needs at least two calibrations (the initial state and one exposure)")
    labels = list(labels) if labels is not None else [f"state {i}" for i in range(len(results))]
    if len(labels) != len(results):
        raise InputError(f"{len(labels)} labels for {len(results)} calibrations")
    posteriors = kwargs.pop("posteriors", None) or [None] * len(results)
    if len(posteriors) != len(results):
        raise InputError(f"{len(posteriors)} posteriors for {len(results)} calibrations")
    steps, cumulative = [], []
    for i in range(1, len(results)):
        steps.append(compare(results[i - 1], results[i], posterior_before=posteriors[i - 1],
                             posterior_after=posteriors[i], label=f"{labels[i - 1]} -> {labels[i]}", **kwargs))
        cumulative.append(compare(results[0], results[i], posterior_before=posteriors[0],
                                  posterior_after=posteriors[i], label=f"{labels[0]} -> {labels[i]}", **kwargs))
    notes = ["consecutive steps share a calibration, so their drifts are negatively correlated "
             "(each comparison is right on its own; do not add step drifts and their u in quadrature)"]
    return SequenceComparison(labels=labels, steps=steps, cumulative=cumulative, kind="results",
                              rule=steps[0].rule, notes=notes)


# -- published drift tables -------------------------------------------------------------

@dataclass
class PublishedDrift:
    """One published drift: exposure, sensor, angle (``Ca_xy``), value and uncertainties (arcsec)."""

    exposure: str
    sensor: str
    angle: str
    drift_arcsec: float
    u_measurement_arcsec: Optional[float] = None
    u_drift_arcsec: Optional[float] = None


def angle_name(text: str) -> str:
    """``xY``, ``xy``, ``Ca_xy`` -> ``Ca_xy`` (row axis, then the IMU axis it tilts toward)."""
    s = text.strip()
    s = s[3:] if s.lower().startswith("ca_") else s
    name = f"Ca_{s.lower()}"
    if name not in ANGLES:
        raise InputError(f"unknown angle {text!r}: expected one of {', '.join(ANGLES)} (or the paper's xY form)")
    return name


def read_published_table(path) -> list[PublishedDrift]:
    """Published drifts from CSV (header ``exposure,sensor,angle,drift_arcsec[,u_arcsec|u_drift_arcsec]``,
    ``#`` comments) or JSON (``{"drifts": [{...same keys...}]}`` or a list)."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        data = read_json(path)
        rows = data.get("drifts") if isinstance(data, dict) else data
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise InputError(f"{path}: expected a list of drift objects (or {{\"drifts\": [...]}})")
        start = None
    else:
        try:
            text = path.read_bytes().decode("utf-8")
        except UnicodeDecodeError as exc:
            raise InputError(f"{path}: not UTF-8 text (byte {exc.start})") from None
        lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
        rows = list(csv.DictReader(lines))
        start = 2
    out = []
    for i, row in enumerate(rows):
        where = f"{path}:row {i + 1}" if start is None else f"{path}: data row {i + 1}"
        if None in row:
            raise InputError(f"{where}: more fields than the header names")
        row = {str(k).strip(): (v.strip() if isinstance(v, str) else v) for k, v in row.items() if k}
        missing = [k for k in ("exposure", "angle", "drift_arcsec") if row.get(k) in (None, "")]
        if missing:
            raise InputError(f"{where}: missing {', '.join(missing)} (columns: exposure, sensor, angle, "
                             "drift_arcsec, optional u_arcsec or u_drift_arcsec)")
        try:
            out.append(PublishedDrift(
                exposure=str(row["exposure"]), sensor=str(row.get("sensor") or ""), angle=angle_name(str(row["angle"])),
                drift_arcsec=parse_number(row["drift_arcsec"], low=-MAX_ANGLE_ARCSEC, high=MAX_ANGLE_ARCSEC,
                                          what="drift_arcsec"),
                u_measurement_arcsec=_opt_float(row.get("u_arcsec"), "u_arcsec"),
                u_drift_arcsec=_opt_float(row.get("u_drift_arcsec"), "u_drift_arcsec")))
        except ValueError as exc:
            raise InputError(f"{where}: {exc}") from None
    if not out:
        raise InputError(f"{path}: no drifts in the table")
    return out


def judge_published(rows: Sequence[PublishedDrift], *, u_measurement_arcsec: Optional[float] = None,
                    tolerance_arcsec: Optional[float] = 30.0, correlation: float = 0.0,
                    level: float = 0.95) -> SequenceComparison:
    """Judge published drifts (``triadcal compare --published``) by the same rule.

    Each drift is the difference of two angle measurements with standard uncertainty
    ``u_measurement_arcsec`` each (a row's ``u_measurement_arcsec`` overrides it; a row's
    ``u_drift_arcsec`` gives u(d) directly), so ``u(d) = u_m sqrt(2 (1 - rho))``. Drifts of
    one exposure form one comparison (parameters ``sensor.Ca_xy``), joint test over them
    with a diagonal covariance. Returns a :class:`SequenceComparison` whose ``steps`` are the
    exposures in table order (``kind="published"``; what the table's drifts are relative to
    is the publication's business).
    """
    if not -1.0 <= correlation <= 1.0:
        raise InputError(f"correlation must lie in [-1, 1], got {correlation}")
    exposures = list(dict.fromkeys(r.exposure for r in rows))
    comps = []
    for e in exposures:
        params = {}
        for r in (r for r in rows if r.exposure == e):
            key = f"{r.sensor}.{r.angle}" if r.sensor else r.angle
            if key in params:
                raise InputError(f"exposure {e!r}: {key} appears twice")
            um = r.u_measurement_arcsec if r.u_measurement_arcsec is not None else u_measurement_arcsec
            if r.u_drift_arcsec is not None:
                u = r.u_drift_arcsec
                um = u / math.sqrt(2 * (1 - correlation)) if correlation < 1 else None
            elif um is not None:
                u = drift_uncertainty(um, um, correlation)
            else:
                raise InputError(f"exposure {e!r}, {key}: no uncertainty; give u_arcsec per angle measurement "
                                 "(--u-arcsec) or u_drift_arcsec in the table")
            d = r.drift_arcsec
            verdict, significant = decide(d, u, tolerance_arcsec, level)
            z = d / u if u > 0 else (math.inf if d else 0.0)
            params[key] = ParameterDrift(
                name=key, unit="arcsec", drift=d, u=u, u_before=um, u_after=um, rho=correlation,
                tolerance=tolerance_arcsec, En=abs(d) / (EN_COVERAGE_FACTOR * u) if u > 0 else math.inf, z=z,
                p_value=float(2 * stats.norm.sf(abs(z))), significant=significant,
                p_exceeds=probability_exceeds(d, u, tolerance_arcsec), verdict=verdict, basis="published")
        names = list(params)
        drift = np.array([params[n].drift for n in names])
        joint = joint_test(drift, np.diag([params[n].u ** 2 for n in names]), names, level)
        comps.append(ComparisonResult(
            parameters=params, overall=overall_verdict(params, joint, tolerance_arcsec),
            rule=rule_text(level, tolerance_arcsec), level=level, tolerance_arcsec=tolerance_arcsec,
            correlation={"rho": correlation, "source": "stated",
                         "reason": (f"rho = {correlation:g}: published drifts carry no covariance; each drift is "
                                    "the difference of two measurements whose errors (eq. 4: output noise, "
                                    "bench positioning sigma_1 and wobble sigma_2, all random per measurement) "
                                    "are independent unless stated otherwise")},
            joint=joint, label=e))
    return SequenceComparison(labels=exposures, steps=comps, cumulative=[], kind="published",
                              rule=comps[0].rule)


# -- helpers ----------------------------------------------------------------------------

def _finite(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (np.floating,)):
        return _finite(float(v))
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def _num(v) -> float:
    return float("nan") if v is None else float(v)


MAX_ANGLE_ARCSEC = 1_296_000.0   # 360 deg: no drift of an angle is larger


def _opt_float(v, what: str = "value") -> Optional[float]:
    """An optional uncertainty of a published row: empty or absent is None; otherwise a finite
    number in (0, 360 deg] (arcsec)."""
    if v is None or v == "":
        return None
    return parse_number(v, low=0.0, high=MAX_ANGLE_ARCSEC, low_open=True, what=what)


def _save_json(d: dict, path) -> None:
    atomic_write_json(path, d)


def _load_json(path) -> dict:
    return read_json(path)
