"""The thermometer's own reading noise: the rival a delay or a hysteresis form of ``thermal-cycle`` must beat.

A form of the output in the reading ``T`` sees the reading's errors through the slope: a reading
noise sigma_T (or a resolution q, a staircase on a ramp: a sawtooth error of SD q / sqrt 12) adds
``slope x error`` to every residual. A lag of the reading (``lag``, ``lag_hysteresis``, ...) is a
low-pass filter: it averages that error away, and wins the held-out comparison against a line in
the reading without any delay in the unit. An outside probe (its own simulator: a linear bias
tempco of 2 mg/degC, white output noise 3 mm/s2, no lag, no hysteresis): a thermometer reading in
1 degC steps was named ``lag_hysteresis`` (tau 0.23-0.25 min, a branch gap of -2.25 mm/s2 where the
truth has none), "explained", on 14 of 15 axes; 0.2 degC of white reading noise, 9 of 9 (``lag_hysteresis``
at the grid's smallest tau, or ``offset_hysteresis``).

The rival (:func:`reading_rival`): the polynomial of the named form's degree (linear; quadratic for
a ``*quadratic*`` form) in the reading averaged over a centred window
(:func:`triadcal.models.thermal_history.centred_mean`: zero phase, no delay, no branch), the window
chosen on the training blocks from :data:`WINDOWS_S` as every form's parameter, judged on the same
held-out blocks. A delay or a hysteresis is a difference between the branches that no centred
average makes: the named form must beat the rival by :data:`~.thermal_cycle.PAIRED_Z` standard
errors of the paired held-out squared errors, as it must beat a simpler form at the white-noise
floor. :func:`reading_errors` says what the reading shows of its own noise (the MAD of its second
differences) and resolution (the grid its values lie on), for the verdict's words.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

from ..models.thermal_history import centred_mean

#: the centred windows (s) tried for the reading's average: 5 s to 30 min, a factor 1.25 apart
WINDOWS_S = tuple(float(x) for x in np.geomspace(5.0, 1800.0, 27))
#: forms that are polynomials of the reading: no delay, no branch (nothing for the rival to ask)
POLYNOMIALS = ("linear", "quadratic", "cubic")


def reading_errors(T) -> dict:
    """The reading's own noise, from itself: ``sigma_C`` the robust SD of its white part
    (1.4826 MAD of the second differences / sqrt 6: a ramp's second differences vanish, a white
    noise's have variance 6 sigma^2), and ``resolution_C`` the step of the grid its values lie on
    (the smallest difference of its distinct values when every value is a multiple of it within
    1 % of a step), else None."""
    T = np.asarray(T, float)
    d2 = np.diff(T, 2)
    sigma = float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0)) if d2.size else 0.0
    vals = np.unique(np.round(T, 9))
    q = None
    if vals.size > 2:
        step = float(np.min(np.diff(vals)))
        if step > 0:
            k = (vals - vals[0]) / step
            if np.all(np.abs(k - np.round(k)) < 0.01):
                q = step
    return {"sigma_C": sigma, "resolution_C": q}


def _poly(Ts, T_ref, degree):
    d = Ts - T_ref
    return np.stack([np.ones_like(d)] + [d ** k for k in range(1, degree + 1)], axis=1)


#: named forms that claim a delay and a branch at once: their rival may hold a branch without delay too
#: (the hysteron of the averaged reading), which a coarse thermometer's staircase otherwise passed for a
#: small lag with a hysteresis or a play (an outside probe: a true offset hysteresis of 0.01 m/s2 read in
#: 1 degC steps was lag_play or lag_hysteresis with tau 0.15 min, "explained", 12 of 12 axes)
BRANCH_AND_DELAY = ("lag_hysteresis", "lag_quadratic_hysteresis", "lag_play", "quadratic_play")


def reading_rival(t, T, y, T_ref: float, tests: list, named: str, named_sq: np.ndarray,
                  paired_z: float) -> Optional[dict]:
    """The rival of a delay or hysteresis form ``named`` (module docstring): the polynomial in the
    centred average of the reading and, for a form of :data:`BRANCH_AND_DELAY`, also that polynomial
    with the hysteron of the averaged reading (the offset hysteresis without delay,
    ``relay_branch(centred_mean(T), RELAY_HALF_WIDTH_C)``), taken only when its held-out squared errors
    beat the plain polynomial's by ``paired_z`` standard errors; the window chosen on each fold's
    training blocks (``tests``: the held-out masks, in order), held-out squared errors in the order of
    ``named_sq`` (the named form's, concatenated over the folds). ``{"degree", "branch" (whether the
    rival has the hysteron), "form" (its name among the thermal-cycle forms),
    "window_s" (on all samples), "cv_rms", "z" (how many standard errors of the paired held-out squared
    errors the named form beats it by), "needed" (``paired_z``), "beaten"}``; None for a polynomial
    ``named``."""
    from ..models.thermal_history import relay_branch
    from .thermal_cycle import RELAY_HALF_WIDTH_C

    if named in POLYNOMIALS:
        return None
    degree = 2 if "quadratic" in named else 1
    t, T, y = np.asarray(t, float), np.asarray(T, float), np.asarray(y, float)
    designs = {}
    for w in WINDOWS_S:
        Ts = centred_mean(t, T, w)
        designs[(w, False)] = _poly(Ts, T_ref, degree)
        if named in BRANCH_AND_DELAY:
            designs[(w, True)] = np.column_stack([designs[(w, False)], relay_branch(Ts, RELAY_HALF_WIDTH_C)])

    def held_out(branch):
        """The variant's held-out squared errors (its window chosen on each fold's training blocks) and
        its window on all samples."""
        keys = [k for k in designs if k[1] == branch]

        def best(rows):
            out = None
            for key in keys:
                X = designs[key]
                c, *_ = np.linalg.lstsq(X[rows], y[rows], rcond=None)
                rss = float(np.sum((y[rows] - X[rows] @ c) ** 2))
                if out is None or rss < out[0]:
                    out = (rss, key, c)
            return out

        sq = []
        for test in tests:
            _, key, c = best(~test)
            sq.append((y[test] - designs[key][test] @ c) ** 2)
        return np.concatenate(sq), best(np.ones(y.size, bool))[1][0]

    def paired(a, b):
        """How many standard errors of the paired squared errors b beats a by."""
        d = a - b
        se = float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size > 1 else 0.0
        return float(np.mean(d)) / se if se > 0 else 0.0

    sq, w = held_out(False)
    branch = False
    if named in BRANCH_AND_DELAY:
        # the hysteron only where it beats the plain polynomial as the named form must beat the rival
        sq_b, w_b = held_out(True)
        if paired(sq, sq_b) > paired_z:
            sq, w, branch = sq_b, w_b, True
    z = paired(sq, np.asarray(named_sq, float))
    form = (("offset_hysteresis", "quadratic_hysteresis") if branch else POLYNOMIALS)[degree - 1]
    return {"degree": degree, "branch": branch, "form": form, "window_s": w,
            "cv_rms": float(np.sqrt(np.mean(sq))), "z": z, "needed": paired_z, "beaten": bool(z > paired_z)}


def reading_words(named: str, poly: str, rival: dict, errors: dict, floor: float) -> str:
    """Why ``poly`` (the rival's form) is named instead of ``named``: the rival (:func:`reading_rival`)
    not beaten."""
    q = errors.get("resolution_C")
    shows = f"white noise {errors['sigma_C']:.2g} degC" + (f", resolution {q:.3g} degC" if q else "")
    how = "no delay, its branch held" if rival.get("branch") else "no delay, no branch"
    return (f"{named} does not beat {poly} in the reading averaged over a centred window of {rival['window_s']:.3g} s "
            f"({how}; held-out RMS {rival['cv_rms'] / floor:.3g} x the floor) by more than "
            f"{rival['z']:.2g} standard errors of the paired held-out squared errors (< the {rival['needed']:g} needed): "
            f"what it gains may be the thermometer's own reading error averaged away (the reading shows "
            f"{shows}), not a delay or a hysteresis of the unit, so {poly} is named (a delay or hysteresis that "
            "small is not excluded either: a finer or quieter thermometer can tell)")
