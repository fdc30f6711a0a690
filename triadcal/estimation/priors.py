"""Weakly informative priors of the joint model, in physical (reporting) units.

Every parameter gets an independent normal prior centred on its nominal value (1 g/V
for a scale factor, 0 for everything else) with a standard deviation of
``PRIOR_WIDTH x typical`` (:class:`~triadcal.models.parameters.ParameterSpec.typical`,
the spread of the parameter among units), truncated to physical bounds where they
exist:

- scale factors ``K_a > 0`` (a sensor with a negative or zero scale factor is not an
  accelerometer of this kind);
- orientation angles ``|Ca_ab| <= 3600 arcsec``, the bound of the answer gates
  (:mod:`triadcal.estimation.gates`; it also keeps each row of Ca in eq. 1 a unit vector).
  The least-squares fit has no such bound, and its gate carries over to the posterior, so a
  unit beyond the bound is refused rather than pulled inside it;
- bench tilt components ``|tilt_x|, |tilt_y| < 0.5 rad`` (the same reason for the
  gravity direction of the bench, bench-csv.md);
- thermal lag ``>= 0`` (a first-order time constant: the element lags its sensor).

With ``PRIOR_WIDTH = 10`` the priors are ten times wider than the spread of real units
(seed paper, Tables 1-2: angles up to ~15', tempcos up to ~6"/degC, hysteresis up to
+-60"), so a campaign that measures a parameter overrules its prior by orders of
magnitude, while a parameter the campaign cannot see (e.g. hysteresis from a heating
sweep alone) keeps its prior, and is reported as prior-dominated.
"""

from __future__ import annotations

from ..errors import UnknownName

from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np

from ..models.model import Model
from ..models.units import ARCSEC, TO_INTERNAL
from .gates import DEFAULT_CONFIG

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
                   overrides: Optional[Mapping[str, Prior]] = None) -> dict[str, Prior]:
    """The documented weakly informative prior of every parameter of ``model``."""
    priors = {}
    for s in model.parameters:
        low, high, reason = -np.inf, np.inf, ""
        if s.name.startswith("K_") and s.unit == "g/V" and s.name.count("_") == 1:
            low, reason = 0.0, "a scale factor is positive"
        elif s.name.startswith("Ca_") and s.name.count("_") == 1:
            b = DEFAULT_CONFIG.angle_bound_arcsec * ARCSEC / TO_INTERNAL[s.unit]
            low, high, reason = -b, b, ("the answer gates' bound on an orientation angle "
                                        f"(|angle| <= {DEFAULT_CONFIG.angle_bound_arcsec:g} arcsec)")
        elif s.name == "thermal_lag":
            low, reason = 0.0, "a time constant is not negative (the element lags its sensor)"
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
