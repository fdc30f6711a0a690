"""The results of ``triadcal thermal-cycle`` (:mod:`.thermal_cycle`): each form's fit, each axis's
choice, the cycle's verdict, their JSON (format ``triadcal.thermal_cycle`` v1), and the block
jackknife that gives the forms' parameters their uncertainty."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .thermal_choice import PAIRED_Z

FORMAT = "triadcal.thermal_cycle"
VERSION = 1
#: a form "explains" an axis when its held-out RMS is within this factor of the white-noise floor
EXPLAINED_FACTOR = 3.0


JACKKNIFE_METHOD = ("delete-a-block jackknife over the cross-validation's contiguous folds (k - 1 degrees of "
                    "freedom): each fold's training estimate, sqrt((k - 1)/k sum (x_i - mean)^2)")


def jackknife(estimates) -> Optional[np.ndarray]:
    """The delete-a-block jackknife standard uncertainty (Kunsch 1989) of a quantity estimated on each
    of k training sets that leave one contiguous block out: ``sqrt((k - 1) / k * sum (x_i - mean)^2)``
    per component; None with fewer than 3 blocks or a non-finite estimate. Contiguous blocks keep a
    record's correlation in time inside them, which a formula from the residuals' white floor ignores."""
    x = np.asarray(estimates, float)
    if x.ndim == 1:
        x = x[:, None]
    k = x.shape[0]
    if k < 3 or not np.all(np.isfinite(x)):
        return None
    return np.sqrt((k - 1) / k * np.sum((x - x.mean(axis=0)) ** 2, axis=0))


@dataclass
class FormFit:
    name: str
    cv_rms: float
    fit_rms: float
    parameter: Optional[dict]
    coefficients: list
    branch_gap: Optional[float]
    #: standard uncertainties by the block jackknife over the folds (:func:`jackknife`): the parameter's
    #: (same keys, e.g. ``tau_min``) and the coefficients' (``coefficients``), or None
    u: Optional[dict] = None

    def to_dict(self) -> dict:
        return {"form": self.name, "cv_rms": self.cv_rms, "fit_rms": self.fit_rms, "parameter": self.parameter,
                "coefficients": self.coefficients, "branch_gap_after": self.branch_gap,
                "u": self.u, **({"u_method": JACKKNIFE_METHOD} if self.u else {})}


@dataclass
class AxisCycle:
    column: str
    unit: str
    noise_floor: float
    branch_gap: Optional[float]
    forms: list
    best: str
    prediction: np.ndarray = field(repr=False, default=None)
    caveat: Optional[str] = None
    #: why a simpler form than the fold rule's was named (:func:`floor_rule`, the reading's rival), or None
    floor_note: Optional[str] = None
    #: the reading-noise rival of a delay or hysteresis form (thermal_reading.reading_rival), or None
    reading_rival: Optional[dict] = None

    def form(self, name: str) -> FormFit:
        return next(f for f in self.forms if f.name == name)

    def to_dict(self) -> dict:
        lin = self.form("linear")
        best = self.form(self.best)
        return {"column": self.column, "unit": self.unit, "noise_floor": self.noise_floor,
                "branch_gap_linear": self.branch_gap, "best": self.best,
                "choice": "the simplest form (fewest parameters) whose held-out mean square is within one standard "
                          "error (over the folds) or 1 % of the lowest; a simpler one at the white-noise floor unless "
                          f"beaten by {PAIRED_Z:g} standard errors of the paired held-out squared errors",
                **({"floor_rule": self.floor_note} if self.floor_note else {}),
                "explained": bool(best.cv_rms <= EXPLAINED_FACTOR * self.noise_floor),
                "explained_criterion": f"held-out RMS <= {EXPLAINED_FACTOR:g} x the white-noise floor",
                "cv_improvement_over_linear": 1.0 - best.cv_rms / lin.cv_rms if lin.cv_rms > 0 else None,
                "forms": [f.to_dict() for f in self.forms], **({"caveat": self.caveat} if self.caveat else {}),
                **({"reading_rival": self.reading_rival} if self.reading_rival else {})}


@dataclass
class ThermalCycle:
    source: str
    unit: str
    n: int
    duration_s: float
    temperature_range_C: tuple
    reference_temperature_C: float
    folds: int
    axes: list
    verdict: str
    notes: list
    t_s: np.ndarray = field(repr=False, default=None)
    T: np.ndarray = field(repr=False, default=None)
    y: np.ndarray = field(repr=False, default=None)
    branch: np.ndarray = field(repr=False, default=None)

    def to_dict(self) -> dict:
        return {"format": FORMAT, "version": VERSION, "source": self.source, "unit": self.unit, "n_samples": self.n,
                "duration_s": self.duration_s, "temperature_range_C": list(self.temperature_range_C),
                "reference_temperature_C": self.reference_temperature_C, "folds": self.folds,
                "validation": "blocked cross-validation over time (contiguous folds; the form's non-linear "
                              "parameter chosen on the training folds)",
                "axes": [a.to_dict() for a in self.axes], "verdict": self.verdict, "notes": list(self.notes)}
