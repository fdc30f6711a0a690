"""Field checks of the plan files (``triadcal.plan``, ``triadcal.ramp_plan``): every field named in
the error with its file. Split from ``ramp.py``, whose ramp-plan check they serve too.

Before, a stepped plan was read with ``float(...)`` alone (an outside fuzz probe): a label given
twice dropped a position silently (44 visits instead of 48), a setpoint of 1e6 degC, a bench angle
of 1e9 deg, a soak of -100 s, 1.5 repetitions, a rate of 0, numbers written as text and a direction
that contradicts the sequence were all accepted, and ``simulate --plan`` wrote NaN outputs (exit 0).
"""

from __future__ import annotations

import math
from typing import Mapping

from ..errors import InputError

#: the fastest chamber a plan may assume, degC/min (plan and ramp files; `plan --chamber-rate`)
MAX_CHAMBER_RATE_C_PER_MIN = 100.0

#: the temperatures a plan may hold, degC (the bench CSV reader's accepted range of a setpoint)
PLAN_TEMPERATURE_C = (-100.0, 200.0)
#: the keys of a stepped plan document (``Plan.to_dict``)
PLAN_KEYS = ("format", "version", "name", "start_C", "chamber_rate_C_per_min", "settle_s", "move_s", "tau_s",
             "repetitions", "setpoints", "positions", "n_visits", "chamber_hours", "predicted")


def number(path, name: str, value, *, low=-math.inf, high=math.inf, strict_low=False) -> float:
    """``value`` as a float: a finite JSON number (not text, not a bool) within [low, high] (low
    excluded with ``strict_low``), else refused naming the file and the field."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{path}: field {name}: expected a finite number, got {value!r}")
    if value < low or (strict_low and value == low) or value > high:
        rng = f"> {low:g}" if strict_low else f">= {low:g}"
        if math.isfinite(high):
            rng += f" and <= {high:g}"
        raise InputError(f"{path}: field {name}: {value!r} out of range (must be {rng})")
    return float(value)


#: the longest averaging window a plan may hold, s (the bench CSV's ``tau_s`` range: a plan whose
#: window the reader refuses made ``simulate --plan`` write a file it then could not read)
MAX_TAU_S = 86400.0


def plan_effects(d: Mapping, path):
    """The effects the plan was made for (``predicted.effects``, written by ``triadcal plan``), checked:
    a tuple of names ``fit --effects`` takes, or None (a plan written before 2026-12-02, or by hand)."""
    from ..estimation.planned_effects import check_effect_names

    pred = d.get("predicted")
    if pred is None:
        return None
    if not isinstance(pred, Mapping):
        raise InputError(f"{path}: field predicted: expected an object, got {pred!r}")
    if "effects" not in pred:
        return None
    return check_effect_names(pred["effects"], f"{path}: field predicted.effects")


def check_totals(d: Mapping, plan, path) -> None:
    """``chamber_hours`` as the plan's setpoints, soaks, positions and dwell make it (as ``n_visits``):
    an edited plan that states 1.0 h for 10.75 was read."""
    if "chamber_hours" in d:
        stated = number(path, "chamber_hours", d["chamber_hours"], low=0.0)
        made = float(plan.chamber_hours())
        if abs(stated - made) > 1e-6 * max(1.0, made):
            raise InputError(f"{path}: field chamber_hours: {stated!r}, but the plan's setpoints, soaks, positions and "
                             f"dwell make {made:.6g} h (an edited plan?)")


def check_positions(d: Mapping, path) -> None:
    """``positions``: a non-empty list of objects with a unique non-empty ``label`` and bench angles
    within +-360 deg (a label given twice overwrote the first: one position silently lost)."""
    pos = d["positions"]
    if not isinstance(pos, list) or not pos:
        raise InputError(f"{path}: field positions: expected a non-empty list of {{label, axis1_deg, axis2_deg}}")
    seen = set()
    for k, p in enumerate(pos):
        if not isinstance(p, dict):
            raise InputError(f"{path}: field positions[{k}]: expected an object {{label, axis1_deg, axis2_deg}}, "
                             f"got {p!r}")
        for key in ("label", "axis1_deg", "axis2_deg"):
            if key not in p:
                raise InputError(f"{path}: field positions[{k}].{key} is missing")
        if not isinstance(p["label"], str) or not p["label"].strip():
            raise InputError(f"{path}: field positions[{k}].label: expected a non-empty text, got {p['label']!r}")
        if p["label"] in seen:
            raise InputError(f"{path}: field positions[{k}].label: {p['label']!r} appears twice")
        seen.add(p["label"])
        for key in ("axis1_deg", "axis2_deg"):
            number(path, f"positions[{k}].{key}", p[key], low=-360.0, high=360.0)


def check_plan_fields(d: Mapping, path) -> None:
    """Each field of a stepped plan (``triadcal.plan`` version 1, checked by the caller): no key the
    format does not have; ``setpoints`` a non-empty list of objects with ``setpoint_C`` within
    :data:`PLAN_TEMPERATURE_C` and ``soak_s`` >= 0; ``tau_s`` > 0; ``repetitions`` a whole number
    >= 1; ``start_C`` a plan temperature; ``chamber_rate_C_per_min`` in (0, 100]; ``settle_s``,
    ``move_s`` >= 0; the positions (:func:`check_positions`). The directions and ``n_visits`` are
    checked against the plan by :meth:`Plan.from_dict` once it is built."""
    unknown = [k for k in d if k not in PLAN_KEYS]
    if unknown:
        raise InputError(f"{path}: field {unknown[0]}: not a field of a plan (known: {', '.join(PLAN_KEYS)})")
    for key in ("setpoints", "positions", "tau_s"):
        if key not in d:
            raise InputError(f"{path}: field {key} is missing (a plan needs setpoints, positions and tau_s)")
    sps = d["setpoints"]
    if not isinstance(sps, list) or not sps:
        raise InputError(f"{path}: field setpoints: expected a non-empty list of {{setpoint_C, soak_s}}")
    lo, hi = PLAN_TEMPERATURE_C
    for k, s in enumerate(sps):
        if not isinstance(s, dict):
            raise InputError(f"{path}: field setpoints[{k}]: expected an object {{setpoint_C, soak_s}}, got {s!r}")
        for key in ("setpoint_C", "soak_s"):
            if key not in s:
                raise InputError(f"{path}: field setpoints[{k}].{key} is missing")
        bad = [key for key in s if key not in ("setpoint_C", "soak_s", "direction")]
        if bad:
            raise InputError(f"{path}: field setpoints[{k}].{bad[0]}: not a field of a setpoint")
        number(path, f"setpoints[{k}].setpoint_C", s["setpoint_C"], low=lo, high=hi)
        number(path, f"setpoints[{k}].soak_s", s["soak_s"], low=0.0)
    number(path, "tau_s", d["tau_s"], low=0.0, strict_low=True, high=MAX_TAU_S)
    if "repetitions" in d:
        r = d["repetitions"]
        if isinstance(r, bool) or not isinstance(r, int) or r < 1:
            raise InputError(f"{path}: field repetitions: expected a whole number >= 1, got {r!r}")
    if "start_C" in d:
        number(path, "start_C", d["start_C"], low=lo, high=hi)
    if "chamber_rate_C_per_min" in d:
        number(path, "chamber_rate_C_per_min", d["chamber_rate_C_per_min"], low=0.0, strict_low=True,
               high=MAX_CHAMBER_RATE_C_PER_MIN)
    for key in ("settle_s", "move_s"):
        if key in d:
            number(path, key, d[key], low=0.0)
    if "name" in d and not isinstance(d["name"], str):
        raise InputError(f"{path}: field name: expected a text, got {d['name']!r}")
    check_positions(d, path)
    # a soak shorter than the chamber's move to its setpoint: the visits would be labelled with a
    # temperature the chamber had not reached (an edited plan of soak_s 1 at 1 degC/min: the
    # simulated visits of -40 degC read about 20)
    from .plan import AMBIENT_C, CHAMBER_RATE_C_PER_MIN

    rate = float(d.get("chamber_rate_C_per_min", CHAMBER_RATE_C_PER_MIN))
    prev = float(d.get("start_C", AMBIENT_C))
    for k, s in enumerate(sps):
        sp = float(s["setpoint_C"])
        need = abs(sp - prev) / rate * 60.0
        if float(s["soak_s"]) < need:
            raise InputError(f"{path}: field setpoints[{k}].soak_s: {s['soak_s']!r} s, but the chamber at {rate:g} degC/min "
                             f"needs {need:.6g} s to move from {prev:g} to {sp:g} degC")
        prev = sp
