"""The decision rule, stated in every output: significant when ``|d| > k2 u(d)``; with a
tolerance T, pass when ``|d| + k1 u(d) <= T`` (guard band), fail when significant and
``|d| > T``, inconclusive otherwise; the same on posterior draws (docs/compare.md).
"""

from __future__ import annotations
from ...errors import InputError
import math
import re
from typing import Mapping, Optional, Union
import numpy as np
from scipy import stats


VERDICTS = ("pass", "fail", "inconclusive")


#: the six orientation angles (results.ANGLES, without importing it here)
_ANGLES = tuple(f"Ca_{ab}" for ab in ("xy", "xz", "yx", "yz", "zx", "zy"))


#: coverage factor of ISO 13528's En (expanded uncertainty U = k u)
EN_COVERAGE_FACTOR = 2.0


_TOLERANCE_UNITS = {"arcsec": 1.0, "arcmin": 60.0, "deg": 3600.0}


_TOLERANCE_ALIASES = {'"': "arcsec", "''": "arcsec", "as": "arcsec", "'": "arcmin", "amin": "arcmin",
                      "degree": "deg", "degrees": "deg"}


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
    m = re.fullmatch(r"([+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)\s*(.*)", s)
    if not m:
        raise InputError(f"cannot read tolerance {text!r}: write a number and a unit, e.g. 30arcsec")
    value, unit = float(m.group(1)), m.group(2).strip()
    unit = _TOLERANCE_ALIASES.get(unit, unit.lower())
    if not unit:
        raise InputError(f"tolerance {text!r} has no unit: write e.g. {s}arcsec, {s}arcmin or {s}deg")
    if unit not in _TOLERANCE_UNITS:
        raise InputError(f"tolerance {text!r}: unknown unit {m.group(2).strip()!r}; "
                         f"use one of {', '.join(_TOLERANCE_UNITS)}")
    return check_tolerance(value * _TOLERANCE_UNITS[unit], f"tolerance {text!r}")


def check_tolerance(value, what: str = "tolerance") -> float:
    """A tolerance as a finite number >= 0, else an InputError naming ``what`` and the value.

    An infinite tolerance is not "no tolerance" (that is ``none``/None: significance only) and
    would pass any drift; NaN compares false with everything; a negative one cannot be met."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{what} = {value!r} is not a number")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{what} = {value!r} is not finite: give a finite tolerance (for significance only, "
                         "none: --tolerance none, or no --param-tolerance for that parameter)")
    if v < 0:
        raise InputError(f"{what} = {value!r} is negative: a tolerance is a bound on |drift|, >= 0")
    return v


def drift_uncertainty(u_before: float, u_after: float, rho: float = 0.0) -> float:
    """``u(d) = sqrt(u_b^2 + u_a^2 - 2 rho u_b u_a)`` for ``d = after - before`` (GUM 5.2.2)."""
    v = u_before ** 2 + u_after ** 2 - 2.0 * rho * u_before * u_after
    return math.sqrt(max(v, 0.0))


def normalised_error(drift: float, u_before: float, u_after: float, rho: float = 0.0,
                     k: float = EN_COVERAGE_FACTOR) -> float:
    """ISO 13528 ``En = |x_a - x_b| / sqrt(U_a^2 + U_b^2 - 2 rho U_a U_b)``, ``U = k u``."""
    U = k * drift_uncertainty(u_before, u_after, rho)
    return abs(drift) / U if U > 0 else (0.0 if drift == 0 else math.inf)


def probability_exceeds(drift: float, u: float, tolerance: Optional[float], bound: float = 0.0) -> Optional[float]:
    """``P(|true drift| > T)`` for a normal state of knowledge ``N(drift, u^2)``; with a ``bound``
    (a bias of the drift known only to lie within +-bound: the unmeasured tempcos of rows apart,
    ``compare.tempco_bound``), its largest value over that interval, at ``|drift| + bound``."""
    if tolerance is None:
        return None
    d = abs(drift) + bound
    if u <= 0:
        return float(d > tolerance)
    return float(stats.norm.sf((tolerance - d) / u) + stats.norm.cdf((-tolerance - d) / u))


def decide(drift: float, u: float, tolerance: Optional[float], level: float = 0.95,
           bound: float = 0.0) -> tuple[str, bool]:
    """Verdict and significance of one drift under the module's rule (normal approximation).

    ``bound``: a bias of the drift known only to lie within +-bound (not a distribution: the
    unmeasured tempcos of rows apart times their distance), taken at its worst for each decision:
    significant when ``|d| - bound > k2 u``, pass when ``|d| + bound + k1 u <= T``, fail when
    significant and ``|d| - bound > T``. As a rectangular u (bound/sqrt 3) it let an unmoved unit
    at the bound fail (an outside probe: K tolerance 20 ppm, rows 0.05 degC apart, 6 of 25)."""
    k2, k1 = coverage_factors(level)
    near = max(abs(drift) - bound, 0.0)
    significant = near > k2 * u if u > 0 else near > 0
    if tolerance is None:
        return ("fail" if significant else "pass"), bool(significant)
    if abs(drift) + bound + k1 * u <= tolerance:
        return "pass", bool(significant)
    if significant and near > tolerance:
        return "fail", bool(significant)
    return "inconclusive", bool(significant)


def decide_from_draws(draws: np.ndarray, tolerance: Optional[float], level: float = 0.95):
    """Verdict, significance and ``P(|drift| > T)`` from draws of the drift (posterior form)."""
    lo, hi = np.quantile(draws, [0.5 - level / 2, 0.5 + level / 2])
    significant = bool(lo > 0 or hi < 0)
    if tolerance is None:
        return ("fail" if significant else "pass"), significant, None
    p = float(np.mean(np.abs(draws) > tolerance))
    return verdict_from_probability(p, significant, tolerance, level), significant, p


def verdict_from_probability(p_exceeds: Optional[float], significant: bool, tolerance: Optional[float],
                             level: float = 0.95) -> str:
    """The posterior form of the rule from ``P(|d| > T)`` and the significance: pass when
    ``P <= 1 - L``, fail when significant and ``P > 1/2``, inconclusive otherwise; without a
    tolerance fail when significant, pass otherwise."""
    if tolerance is None:
        return "fail" if significant else "pass"
    if p_exceeds is None:
        raise InputError("a posterior verdict against a tolerance needs P(|d| > T)")
    if p_exceeds <= 1 - level:
        return "pass"
    if significant and p_exceeds > 0.5:
        return "fail"
    return "inconclusive"


def rule_text(level: float, tolerance_arcsec: Optional[float], tolerances: Mapping[str, float] = None,
              posterior: bool = False) -> str:
    """The decision rule in words, with its numbers (written into every output)."""
    k2, k1 = coverage_factors(level)
    pct = f"{100 * level:g}%"
    tol = (f"T = {tolerance_arcsec:g} arcsec for the angles" if tolerance_arcsec is not None
           else "no tolerance for the angles")
    if tolerances:
        tol += "; " + ", ".join(f"T = {v:g} for {k}" for k, v in tolerances.items())
        if any(k.rsplit(".", 1)[-1] in _ANGLES for k in tolerances):
            tol += " (an angle given its own tolerance is judged against it, not against the angles' T)"
    text = (
        f"Drift d = after - before with standard uncertainty u(d) = sqrt(u_b^2 + u_a^2 - 2 rho u_b u_a). "
        f"Significant when |d| > {k2:.3f} u(d) (two-sided {pct}). With a tolerance T: pass when "
        f"|d| + {k1:.3f} u(d) <= T (conformance shown with {pct} confidence, ISO 14253-1 guard band); "
        f"fail when d is significant and |d| > T; inconclusive otherwise. Without a tolerance: fail when "
        f"significant, pass otherwise (no drift detected). {tol}. Overall (angles, and parameters given a "
        f"tolerance): fail when the joint chi2 test of the angle drifts is significant at {pct} and an angle "
        f"fails (without a tolerance: when the joint test is significant); pass when every judged parameter "
        f"passes (without a tolerance: and the joint test is not significant); inconclusive otherwise. "
        f"En (ISO 13528, U = 2u) is reported, not used in the verdict. Where two calibrations at one "
        f"temperature each have rows at temperatures apart, a drift also holds the unit's unmeasured "
        f"tempcos times that distance, a bias within +-h (tempco_bound: h = bound x dT), taken at its worst: "
        f"|d| - h for significance and fail (and in z, p_value and En), |d| + h for pass and P(|d| > T); the "
        f"joint test's D2 is its least value over the biases within +-h. A calibration over a temperature range "
        f"against one at one temperature is carried to the other's rows by its own temperature terms (u by GUM "
        f"propagation, within its calibrated range); its hysteresis loop, if any, is such a bound h on each angle "
        f"(the branch unknown).")
    if posterior:
        text += (f" Where posterior draws are given, the same rule on the draws of the drift: significant "
                 f"when 0 is outside the central {pct} interval, pass when P(|d| > T) <= {1 - level:.3g}, "
                 f"fail when significant and P(|d| > T) > 0.5.")
    return text


def combined_covariance(cov_before: np.ndarray, cov_after: np.ndarray, rho: float = 0.0,
                        cross: Optional[np.ndarray] = None) -> np.ndarray:
    """Covariance of ``after - before``: ``S_b + S_a - rho (D_b R D_a + D_a R D_b)``, ``R`` the mean
    correlation matrix of the two calibrations (reduces to ``u_b^2 + u_a^2 - 2 rho u_b u_a``).

    ``cross``: the covariance ``X`` of before's errors with after's from shared systematic
    errors, ``X[i, j] = sum_s c_b,s,i c_a,s,j u_s^2`` (:func:`.correlation.shared_errors`);
    then ``- (X + X^T)`` is subtracted as well."""
    cov_before, cov_after = np.asarray(cov_before, float), np.asarray(cov_after, float)
    cov = cov_before + cov_after
    if rho != 0.0:
        ub, ua = np.sqrt(np.diag(cov_before)), np.sqrt(np.diag(cov_after))
        R = 0.5 * (cov_before / np.outer(ub, ub) + cov_after / np.outer(ua, ua))
        c = rho * (ub[:, None] * R * ua[None, :])
        cov = cov - c - c.T
    if cross is not None:
        X = np.asarray(cross, float)
        cov = cov - X - X.T
    return cov
