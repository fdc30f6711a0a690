"""How ``thermal-cycle`` chooses among its forms (estimation/thermal_cycle.py, which re-exports these):
the fold rule (:func:`parsimonious_best`, a standard-error rule of cross-validation) and the white-noise
floor's rule (:func:`floor_rule`: a richer form must beat the simplest one at the floor by
:data:`PAIRED_Z` standard errors of the paired held-out squared errors). Moved here from
thermal_cycle.py (2026-12-02, behaviour-neutral) when that module passed 600 lines."""

from __future__ import annotations

import math

import numpy as np


#: a form with more parameters is chosen only when it beats a simpler one's held-out error by more than
#: this many standard errors (over the folds) and by more than MATERIAL_MSE of the lowest mean square
SE_MARGIN = 1.0
MATERIAL_MSE = 0.01


def parsimonious_best(forms: list, per_fold: dict, size: dict) :
    """The simplest form whose held-out error is not beaten materially and significantly by the lowest
    (a standard-error rule of cross-validation, Breiman et al. 1984, sec. 3.4.3; Hastie, Tibshirani
    and Friedman 2009, sec. 7.10): each form's mean squared held-out error per fold, its difference
    from the lowest form's fold by fold; a form is within when that difference's mean is at most
    :data:`SE_MARGIN` standard errors of it (over the folds) or :data:`MATERIAL_MSE` of the lowest
    mean square (1 %: 0.5 % of the RMS). "Simplest": fewest parameters (coefficients, plus the lag's
    tau or the play's half-width), then the lower held-out error. Before, the lowest held-out RMS
    won outright: on clean quadratic cycles 4 of 15 axes were named a hysteresis by 1e-5 of the RMS
    (an outside probe); with one standard error alone, 2 of 15 still were, with the 1 % none of 24.
    Two standard errors would be too strict for six folds: the real cycle's z axis, whose play on a
    quadratic halves the held-out RMS (33 against 72 mm/s2), beats the quadratic by 1.95 of them."""
    lowest = min(forms, key=lambda x: x.cv_rms)
    base = per_fold[lowest.name]
    margin_material = MATERIAL_MSE * float(np.mean(base))
    within = []
    for f in forms:
        d = per_fold[f.name] - base
        se = float(np.std(d, ddof=1) / math.sqrt(len(d))) if len(d) > 1 else 0.0
        if float(np.mean(d)) <= max(SE_MARGIN * se, margin_material):
            within.append(f)
    return min(within, key=lambda f: (size[f.name], f.cv_rms))


#: a form is at the white-noise floor when its held-out mean square is within this many standard errors
#: of the floor's square: the ratio of two variance estimates of n samples, the held-out one (relative SE
#: sqrt(2/n)) and the floor from first differences (sqrt(3/n): the differences' lag-1 correlation -1/2)
FLOOR_SE = 3.0
#: a form more complex than the simplest one at the floor is named only when its held-out squared errors
#: beat that one's by this many standard errors, sample by sample (paired; the residuals at the floor are
#: white): one-sided p 0.0013 per rival, about 2 % over the twelve
PAIRED_Z = 3.0


def at_floor(cv_rms: float, floor: float, n: int) -> bool:
    """Whether a held-out RMS is the white-noise floor's within :data:`FLOOR_SE` standard errors."""
    return floor > 0 and cv_rms * cv_rms <= floor * floor * (1.0 + FLOOR_SE * math.sqrt(5.0 / n))


def floor_rule(chosen, forms: list, per_sample: dict, size: dict, floor: float) -> tuple:
    """``(form, why)``: the simplest form at the white-noise floor (:func:`at_floor`) instead of a more
    complex ``chosen`` that does not beat it by :data:`PAIRED_Z` standard errors of the paired held-out
    squared errors; ``chosen`` and None otherwise. The fold rule (:func:`parsimonious_best`) compares
    six fold means with a one-standard-error margin, which the lowest of thirteen forms, four with a
    tuned time constant or half-width, clears by chance: an outside probe's axes with no thermal
    effect at all (a constant or a line and white noise, 286 samples) were named play, lag,
    lag_quadratic, offset_hysteresis, thermometer_lag or quadratic, "explained", 12 of 39, by 0.7-2 %
    of the RMS. At the floor there is nothing left for a richer form to explain."""
    n = len(next(iter(per_sample.values())))
    adequate = [f for f in forms if at_floor(f.cv_rms, floor, n)]
    if not adequate:
        return chosen, None
    simplest = min(adequate, key=lambda f: (size[f.name], f.cv_rms))
    if size[chosen.name] <= size[simplest.name]:
        return chosen, None
    d = per_sample[simplest.name] - per_sample[chosen.name]
    se = float(np.std(d, ddof=1) / math.sqrt(len(d))) if len(d) > 1 else 0.0
    z = float(np.mean(d)) / se if se > 0 else 0.0
    if z > PAIRED_Z:
        return chosen, None
    return simplest, (f"{simplest.name} is at the white-noise floor (held-out RMS {simplest.cv_rms / floor:.3g} x the "
                      f"floor) and {chosen.name} beats it by {z:.2g} standard errors of the paired held-out squared "
                      f"errors (< {PAIRED_Z:g}): {chosen.name} is not established over it by this cycle (an effect "
                      f"that small is not excluded either: a longer cycle, or faster ramps for a short lag, can tell)")
