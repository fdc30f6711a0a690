"""The answer gates of the physical terms' signs and ranges: a term whose physics fixes its sign
(``signs``), the thermal time constants and the bench's settling within what a campaign resolves
(``time_constants``, ``time_constants_determined``), the warm-up's offsets at power-on
(``warmup_offsets``, ``warmup_seen``). Moved from gates.py (which re-exports them); each gate returns
a :class:`~triadcal.estimation.gates.GateOutcome`, ``passed`` None when its terms are absent."""
from __future__ import annotations

import math
from typing import Mapping

from .gate_outcome import GateOutcome, _u, _unit, _value


#: terms whose physics fixes their sign: name -> (what it is, why it cannot be negative)
NON_NEGATIVE = {"thermal_lag": ("the sensing elements' thermal time constant",
                                "an element cannot respond before its temperature changes")}


def _gate_signs(params: Mapping) -> GateOutcome:
    """Every term in :data:`NON_NEGATIVE` is >= 0 within 2u: a negative thermal time constant
    (forced onto a lag of the chamber air, or a lead of the sensors) is not a physical answer."""
    present = {n: (_value(p), _u(p)) for n, p in params.items() if n in NON_NEGATIVE}
    if not present:
        return GateOutcome("signs", None, "unphysical_term", "no sign-constrained term in the result")
    bad = [f"{n} = {v:.4g} +- {u:.2g} {_unit(params[n])} is negative beyond 2u ({NON_NEGATIVE[n][0]}: "
           f"{NON_NEGATIVE[n][1]})" for n, (v, u) in present.items()
           if v is not None and math.isfinite(v) and v + 2 * (u if u is not None and math.isfinite(u) else 0.0) < 0]
    if bad:
        return GateOutcome("signs", False, "unphysical_term", "; ".join(bad), float(len(bad)), "value + 2u >= 0")
    return GateOutcome("signs", True, "unphysical_term", "every sign-constrained term is >= 0 within 2u")


#: thermal time constants and their accepted range (min): name -> what it is. A lag or a warm-up
#: shorter than 0.5 min is not resolved by visits of tens of seconds, and one longer than 300 min
#: (5 h) exceeds any soak or ramp leg of a campaign: a value outside is not a measured time
#: constant (a lag forced onto data without one, or a negative lag of sensors that lead)
TIME_CONSTANTS = {"thermal_lag": "the sensing elements' thermal time constant",
                  "thermal_lag_housing": "the housing's thermal time constant behind the chamber air",
                  "S_warmup_tau": "the time constant of the bias warm-up after power-on",
                  "K_warmup_tau": "the time constant of the scale-factor warm-up after power-on",
                  "tilt_settle_tau": "the time constant of the bench's settling"}
TIME_CONSTANT_RANGE_MIN = (0.5, 300.0)
#: a time constant with another range, in its own unit: the bench's settling acts over the whole
#: campaign (h): shorter than 3 min it is over before a setpoint's visits begin, longer than 100 h
#: it is a drift no campaign of days tells from a constant rate (tilt_drift)
TIME_CONSTANT_RANGES = {"tilt_settle_tau": (0.05, 100.0, "h")}


def _tc_range(name: str) -> tuple:
    """(lo, hi, unit) of a time constant of :data:`TIME_CONSTANTS`."""
    return TIME_CONSTANT_RANGES.get(name, TIME_CONSTANT_RANGE_MIN + ("min",))


def _gate_time_constants(params: Mapping) -> GateOutcome:
    """Every time constant of :data:`TIME_CONSTANTS` within its range ([0.5, 300] min; the bench's
    settling [0.05, 100] h), whatever its u (a value already negative beyond 2u is the ``signs``
    gate's refusal and not repeated here)."""
    present = {n: (_value(p), _u(p)) for n, p in params.items() if n in TIME_CONSTANTS}
    if not present:
        return GateOutcome("time_constants", None, "unphysical_term", "no thermal time constant in the result")
    bad = []
    for n, (v, u) in present.items():
        lo, hi, unit = _tc_range(n)
        uu = u if u is not None and math.isfinite(u) else 0.0
        if v is None or not math.isfinite(v):
            continue                                   # the finite gate's business
        if n in NON_NEGATIVE and v + 2 * uu < 0:
            continue                                   # the signs gate refuses it
        if not lo <= v <= hi:
            bad.append(f"{n} = {v:.4g} +- {uu:.2g} {_unit(params[n]) or unit} is outside [{lo:g}, {hi:g}] {unit} "
                       f"({TIME_CONSTANTS[n]}: " + ("not a positive time constant resolved by the visits; refit "
                       "without the term" if v < lo else "longer than any campaign can measure") + ")")
    if bad:
        lo, hi = TIME_CONSTANT_RANGE_MIN
        return GateOutcome("time_constants", False, "unphysical_term", "; ".join(bad), float(len(bad)),
                           f"{lo:g} <= tau <= {hi:g} min (" + "; ".join(
                               f"{n} {a:g}-{b:g} {u}" for n, (a, b, u) in TIME_CONSTANT_RANGES.items()) + ")")
    return GateOutcome("time_constants", True, "unphysical_term", "every time constant within its range")


#: the largest warm-up offset at power-on a unit can have (reporting units): for the bias ten times
#: the largest figure of the warm-up literature (MEMS vendors quote 1-5 mg), for the scale fifty
#: times the presets' 200 ppm (models/effects/warmup.py). A larger offset is an extrapolation of a few visits' offset
#: back to power-on through a short time constant (a warm-up of 10 min fitted to a 1/f offset of the
#: first visits, two hours after power-on: -34 g +- 149 g), not a warm-up
WARMUP_OFFSET_MAX = {"S_{a}_warmup": (5e4, "ug"), "K_{a}_warmup": (1e4, "ppm")}


def _gate_warmup_offsets(params: Mapping) -> GateOutcome:
    """Every warm-up offset at power-on within :data:`WARMUP_OFFSET_MAX` (50 mg, 1 %)."""
    present = {f.format(a=a): lim for f, lim in WARMUP_OFFSET_MAX.items() for a in "xyz"
               if f.format(a=a) in params}
    if not present:
        return GateOutcome("warmup_offsets", None, "unphysical_term", "no warm-up in the result")
    bad = [f"{n} = {_value(params[n]):.3g} {unit}" for n, (lim, unit) in present.items()
           if _value(params[n]) is not None and abs(_value(params[n])) > lim]
    if bad:
        return GateOutcome("warmup_offsets", False, "unphysical_term",
                           "; ".join(bad) + " at power-on: no warm-up is that large (vendors quote 1-5 mg); a short "
                           "time constant extrapolates a few visits' offset back to power-on; refit without the term",
                           float(len(bad)), "|offset| <= 5e4 ug (bias), 1e4 ppm (scale)")
    return GateOutcome("warmup_offsets", True, "unphysical_term", "every warm-up offset within 50 mg / 1 %")


def _gate_time_constants_determined(params: Mapping) -> GateOutcome:
    """A time constant of :data:`TIME_CONSTANTS` within its range whose standard uncertainty exceeds
    its value is not measured (a warm-up that decayed before the first visit, a lag the data do not
    show, a settling the campaign cannot tell from a drift); one outside the range is the
    ``time_constants`` gate's refusal, not repeated here."""
    loose = {n: (_value(p), _u(p)) for n, p in params.items() if n in TIME_CONSTANTS and _value(p) is not None
             and _u(p) is not None and math.isfinite(_u(p)) and math.isfinite(_value(p)) and _u(p) > abs(_value(p))
             and _tc_range(n)[0] <= _value(p) <= _tc_range(n)[1]}   # else refused by range
    if not any(n in params for n in TIME_CONSTANTS):
        return GateOutcome("time_constants_determined", None, "unidentifiable", "no thermal time constant in the result")
    if not loose:
        return GateOutcome("time_constants_determined", True, "unidentifiable",
                           "every thermal time constant is determined (u below its value)")
    txt = "; ".join(f"{n} = {v:.4g} +- {u:.3g} {_tc_range(n)[2]}" for n, (v, u) in loose.items())
    return GateOutcome("time_constants_determined", False, "unidentifiable",
                       f"not determined by the data (u larger than the value): {txt}; the term is not in the data "
                       "(a warm-up over before the first visit, a lag the record does not show, a settling the "
                       "campaign cannot tell from a constant drift): refit without it",
                       float(len(loose)), "u <= |value|")


#: a warm-up is seen in the data when at least one axis's offset at power-on differs from 0 by this many u
WARMUP_SEEN_Z = 2.0


def _gate_warmup_seen(params: Mapping) -> GateOutcome:
    """A warm-up (bias or scale) whose offsets at power-on all lie within :data:`WARMUP_SEEN_Z` u of 0 is
    not in the data, and its time constant is then a fit to noise whatever its own u: an outside probe's
    warm-up of 2 min, 12 min before the first visit (a factor 0.002 left), gave status ok with
    S_warmup_tau = 28 +- 24 min and S_x_warmup = -1.8 +- 5.4 ug where the truth was 2 500 ug (468 u);
    the posterior of the same data did not converge."""
    if not any(f"{k}_{a}_warmup" in params for k in "SK" for a in "xyz"):
        return GateOutcome("warmup_seen", None, "unidentifiable", "no warm-up in the result")
    out = []
    for kind, what in (("S", "bias"), ("K", "scale-factor")):
        names = [f"{kind}_{a}_warmup" for a in "xyz" if f"{kind}_{a}_warmup" in params]
        if not names:
            continue
        z = {n: abs(_value(params[n])) / _u(params[n]) for n in names
             if _value(params[n]) is not None and _u(params[n]) is not None and _u(params[n]) > 0
             and math.isfinite(_u(params[n])) and math.isfinite(_value(params[n]))}
        if len(z) == len(names) and max(z.values()) < WARMUP_SEEN_Z:
            out.append(f"the {what} warm-up's offsets at power-on are all within {WARMUP_SEEN_Z:g} u of 0 ("
                       + ", ".join(f"{n} = {_value(params[n]):.3g} +- {_u(params[n]):.2g} {_unit(params[n])}"
                                   for n in names) + ")")
    if out:
        return GateOutcome("warmup_seen", False, "unidentifiable",
                           "; ".join(out) + ": the warm-up is not in the data (over before the first visit, or "
                           "absent), so its time constant and its offsets at power-on are not measured; refit "
                           "without the term", float(len(out)), f"max |offset|/u >= {WARMUP_SEEN_Z:g}")
    return GateOutcome("warmup_seen", True, "unidentifiable", "every warm-up in the result is seen in the data")
