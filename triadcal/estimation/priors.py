"""Weakly informative priors of the joint model, in physical (reporting) units.

:func:`default_priors` gives every parameter an independent normal :class:`Prior` centred
on its nominal value with SD ``PRIOR_WIDTH x typical``, truncated to physical bounds
(K > 0, the answer gates' angle bound, |tilt| < 0.5 rad, every thermal time constant >= 0);
:func:`prior_arrays` and :func:`draw_parameters` serve the sampler and SBC.
Derivation/design: docs/posterior.md (Decisions and why: Priors).
"""

from __future__ import annotations

from ..errors import UnknownName

import math
from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np

from ..models.model import Model
from ..models.units import ARCSEC, TO_INTERNAL
from .gates import DEFAULT_CONFIG, TIME_CONSTANTS

#: prior standard deviation in units of the parameter's typical spread among units
PRIOR_WIDTH = 10.0
#: half a radian: bound of the angle-like parameters (see module docstring)
HALF_RADIAN = 0.5


@dataclass(frozen=True)
class Prior:
    """Normal(mean, sd) truncated to [low, high], in the parameter's reporting unit."""

    name: str
    unit: str
    mean: float
    sd: float
    low: float = -np.inf
    high: float = np.inf
    reason: str = ""

    def to_dict(self) -> dict:
        d = {"distribution": "normal", "mean": float(self.mean), "sd": float(self.sd), "unit": self.unit}
        if np.isfinite(self.low) or np.isfinite(self.high):
            d["bounds"] = [None if not np.isfinite(self.low) else float(self.low),
                           None if not np.isfinite(self.high) else float(self.high)]
        if self.reason:
            d["reason"] = self.reason
        return d

    def logpdf(self, x):
        """Log density up to the normalisation of the truncation (vectorised)."""
        x = np.asarray(x, float)
        out = -0.5 * ((x - self.mean) / self.sd) ** 2 - np.log(self.sd * np.sqrt(2 * np.pi))
        return np.where((x > self.low) & (x < self.high), out, -np.inf)

    def draw(self, rng: np.random.Generator, size=None):
        """Draws from the truncated normal (rejection; the bounds are far in the tails)."""
        out = rng.normal(self.mean, self.sd, size)
        bad = ~((out > self.low) & (out < self.high))
        while np.any(bad):
            out = np.where(bad, rng.normal(self.mean, self.sd, np.shape(out)), out)
            bad = ~((out > self.low) & (out < self.high))
        return out


def default_priors(model: Model, width: float = PRIOR_WIDTH,
                   overrides: Optional[Mapping[str, Prior]] = None,
                   angle_bound_arcsec: Optional[float] = None) -> dict[str, Prior]:
    """The documented weakly informative prior of every parameter of ``model``. The angles' bound
    is the answer gates' (``angle_bound_arcsec``, default ``DEFAULT_CONFIG``'s 3600): a fit with a
    raised ``--angle-bound-arcsec`` samples within the raised bound (before, the prior kept 3600
    and pulled a unit at 4000 arcsec to 3599.95, refused as not converged with no word of why)."""
    bound_arcsec = DEFAULT_CONFIG.angle_bound_arcsec if angle_bound_arcsec is None else float(angle_bound_arcsec)
    priors = {}
    for s in model.parameters:
        low, high, reason = -np.inf, np.inf, ""
        if s.name.startswith("K_") and s.unit == "g/V" and s.name.count("_") == 1:
            low, reason = 0.0, "a scale factor is positive"
        elif s.name.startswith("Ca_") and s.name.count("_") == 1:
            b = bound_arcsec * ARCSEC / TO_INTERNAL[s.unit]
            low, high, reason = -b, b, ("the answer gates' bound on an orientation angle "
                                        f"(|angle| <= {bound_arcsec:g} arcsec)")
        elif s.name in TIME_CONSTANTS:
            low, reason = 0.0, f"a time constant is not negative ({TIME_CONSTANTS[s.name]})"
        elif s.name in ("tilt_x", "tilt_y"):
            b = HALF_RADIAN / TO_INTERNAL[s.unit]
            low, high, reason = -b, b, "the gravity direction stays a unit vector (|tilt| < 0.5 rad)"
        priors[s.name] = Prior(s.name, s.unit, float(s.nominal), float(width * s.typical), low, high, reason)
    for k, v in (overrides or {}).items():
        if k not in priors:
            raise UnknownName(f"prior for {k!r}: not a parameter of {model!r}")
        priors[k] = v
    return priors


def prior_arrays(priors: Mapping[str, Prior], names) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(mean, sd, low, high)`` vectors in the order of ``names``."""
    p = [priors[n] for n in names]
    return (np.array([q.mean for q in p]), np.array([q.sd for q in p]),
            np.array([q.low for q in p]), np.array([q.high for q in p]))


def draw_parameters(priors: Mapping[str, Prior], rng: np.random.Generator) -> dict[str, float]:
    """One draw of every parameter from its prior (reporting units), for SBC."""
    return {n: float(p.draw(rng)) for n, p in priors.items()}


#: a least-squares value beyond this many SDs of its default prior (prior and data in conflict: the
#: prior's SD and the value's own u combined) gets a prior on the data's scale (:func:`autoscaled_priors`)
AUTOSCALE_SDS = 3.0


def autoscaled_priors(priors: Mapping[str, Prior], least_squares: Mapping[str, float],
                      user: Mapping = (), width: float = PRIOR_WIDTH,
                      u: Optional[Mapping[str, float]] = None) -> tuple[dict, list]:
    """``(priors, notes)``: the default priors put on the data's scale where they would pull.

    **Scale factors, recentred.** The default ``K ~ N(1, 0.1)`` is in the file's own output unit
    (g/V, g/count, ...): right for a unit of about 1 V/g, but a 5 mV/g analog unit (K = 200 g/V) sat
    2 000 prior SDs from it and the prior pulled the posterior 6 u below the truth with status ok
    (K = 1 000 g/V: 225 u; an outside probe). A data scale is what the prior should carry (rstanarm's
    autoscaled priors, Gabry & Goodrich 2020): where the least-squares ``K`` lies beyond
    :data:`AUTOSCALE_SDS` prior SDs, its prior is ``N(K0, width x 1 % x K0)``, ``K0`` the least-squares
    value rounded to two significant digits (a scale, not the fit: 200.0 for 199.998), the default's
    relative width (10 %), still ``K > 0``.

    **Every other parameter, widened.** Where the least-squares value ``x`` lies beyond
    :data:`AUTOSCALE_SDS` ``sqrt(sd^2 + u^2)`` of the prior's mean (a prior-data conflict: the
    prior-predictive SD of the estimate, ``u`` its least-squares uncertainty when given), the prior
    keeps its mean and bounds and its SD becomes ``|x - mean|`` rounded to two significant digits:
    the estimate then sits about 1 prior SD out, and the pull left, ``|x - mean| u / (sd^2 + u^2)`` in
    units of u, is below ``u / |x - mean|``. Before, biases of 0.3-0.5 g against the default
    ``S ~ N(0, 0.02 g)`` were pulled 4 u toward 0 with status ok (95 % intervals holding 3 of 30 true
    biases; ``intervals_to_use`` recommended them) or refused as model mismatch (chi2 at the pulled
    posterior mean; an outside probe): a prior ten times the spread of units is no bound on one unit.

    Priors the user gave (``user``) are kept; so is every prior the data do not contradict (the
    simulation-based calibration's, whose draws come from the default, beyond 3 SD one time in 370)."""
    out, notes = dict(priors), []
    for n, p in priors.items():
        if n in user or n not in least_squares:
            continue
        x = float(least_squares[n])
        if not math.isfinite(x):
            continue
        if n.startswith("K_") and n.count("_") == 1:
            if not x > 0 or abs(x - p.mean) <= AUTOSCALE_SDS * p.sd:
                continue
            k0 = float(f"{x:.2g}")
            sd = width * 0.01 * k0
            out[n] = Prior(n, p.unit, k0, sd, 0.0, p.high,
                           f"autoscaled: the least-squares {n} = {x:.6g} is {abs(x - p.mean) / p.sd:.3g} SD from the "
                           f"default prior's {p.mean:g}; centred on the unit's scale {k0:g}, {width * 0.01:.0%} wide "
                           "(a scale factor is positive)")
            notes.append(f"prior of {n}: N({k0:g}, {sd:.3g}) in the file's unit, centred on the unit's scale (the "
                         f"least squares give {x:.6g}, {abs(x - p.mean) / p.sd:.3g} SD from the default N({p.mean:g}, "
                         f"{p.sd:g}), which would pull the posterior)")
            continue
        ux = float((u or {}).get(n, 0.0) or 0.0)
        ux = ux if math.isfinite(ux) else 0.0
        d = abs(x - p.mean)
        if d <= AUTOSCALE_SDS * math.hypot(p.sd, ux) or not p.low < x < p.high:
            continue
        sd = float(f"{d:.2g}")
        pull = d * ux / (p.sd ** 2 + ux ** 2) if ux > 0 else float("nan")
        said = f", which would pull the posterior {pull:.2g} u toward {p.mean:g}" if math.isfinite(pull) else ""
        out[n] = Prior(n, p.unit, p.mean, sd, p.low, p.high,
                       f"widened: the least-squares {n} = {x:.6g} is {d / math.hypot(p.sd, ux):.3g} SD from the "
                       f"default prior N({p.mean:g}, {p.sd:g}); its SD set to the distance, {sd:g} {p.unit}"
                       + (f" ({p.reason})" if p.reason else ""))
        notes.append(f"prior of {n}: N({p.mean:g}, {sd:g}) {p.unit}, widened to the data's scale (the least squares "
                     f"give {x:.6g}, {d / math.hypot(p.sd, ux):.3g} SD from the default N({p.mean:g}, {p.sd:g}){said})")
    return out, notes
