"""A campaign at one temperature: no temperature coefficient is determined, so the values are
those at the data's temperature, and the result must say which temperature that is -- for each
accelerometer, since each row of the model is tied to its own sensor's temperature
(docs/model.md)."""

from __future__ import annotations

from typing import Optional

import numpy as np

from ..errors import InputError
from ..models.campaign import Campaign
from ..models.sensor import AXES
from .gates import GateOutcome


#: a campaign whose accelerometers' mean temperature spans less than this (degC) is at one temperature
TEMPERATURE_SPAN_MIN_C = 1.0


def single_temperature_reference(campaign: Campaign, reference_temperature_C: float) -> tuple:
    """``(reference_temperature_C, note)``: the requested reference, or, for a campaign at one
    temperature (its accelerometers' mean temperature spans less than :data:`TEMPERATURE_SPAN_MIN_C`),
    that temperature's mean (rounded to 0.01 degC) and a note saying so. No temperature coefficient
    can be determined there (:func:`identifiability_problems` holds them at 0), so values at another
    temperature would be those of the data relabelled: a campaign at 50 degC reported its K at
    "20 degC" with status ok, 419 u from the unit's K at 20 degC (an outside probe). As the
    classical method does (docs/classical.md, "One setpoint temperature")."""
    T = np.asarray(campaign.t, float).mean(axis=1)
    ref = float(reference_temperature_C)
    if not len(T) or not np.all(np.isfinite(T)) or np.ptp(T) >= TEMPERATURE_SPAN_MIN_C:
        return ref, None
    Tm = round(float(np.mean(T)), 2)
    if abs(Tm - ref) < 0.005:
        return ref, None
    return Tm, (f"one temperature: the accelerometers' mean temperature spans {np.ptp(T):.2f} degC, so no "
                f"temperature coefficient is determined and the values are at the mean temperature {Tm:.2f} degC, "
                f"not at {ref:g} degC (reference_temperature_C says which)")


#: in a campaign at one temperature, sensors whose means differ by this much (degC) are named in a
#: note: each accelerometer's values are at its own sensor's temperature
SENSOR_SPREAD_NOTE_C = 0.1


def sensor_temperatures(campaign: Campaign) -> tuple[Optional[str], Optional[GateOutcome], Optional[dict]]:
    """``(note, gate, temperatures)`` for a campaign at one temperature whose three sensors read
    apart: K_a, S_a and the angles Ca_ab of accelerometer a are at the mean of t_a, not at the
    sensors' mean that ``reference_temperature_C`` states. A note names each temperature when they
    spread by :data:`SENSOR_SPREAD_NOTE_C` or more; the gate ``one_reference_temperature`` refuses
    (status ``unidentifiable``) when they spread by :data:`TEMPERATURE_SPAN_MIN_C` or more, since no
    one reference temperature then describes the result and no tempco is determined to move the
    values to one (an outside probe: sensors at +4, -3, 0 degC, 10 of 10 ok with a median largest
    error of 17 u at the stated temperature; +1, -0.5, +0.3 degC: 4 of 10 over 4 u). (None, None,
    None) for a campaign over a temperature range, whose tempcos carry each row to T_ref."""
    T = np.asarray(campaign.t, float)
    if not len(T) or not np.all(np.isfinite(T)) or np.ptp(T.mean(axis=1)) >= TEMPERATURE_SPAN_MIN_C:
        return None, None, None
    Ta = T.mean(axis=0)
    spread = float(np.ptp(Ta))
    temps = {a: round(float(v), 2) for a, v in zip(AXES, Ta)}
    if spread < SENSOR_SPREAD_NOTE_C:
        return None, None, temps
    where = ", ".join(f"t_{a} {v:.2f}" for a, v in temps.items())
    note = (f"one temperature, sensors apart: each accelerometer's K, S and angles Ca_ab are at its own sensor's "
            f"mean temperature ({where} degC; the model ties row a to t_a), not at the {float(np.mean(Ta)):.2f} "
            "degC that reference_temperature_C states")
    passed = spread < TEMPERATURE_SPAN_MIN_C
    reason = (f"the accelerometers' sensors read {spread:.2f} degC apart ({where}) in a campaign at one temperature: "
              + ("each row's values are at its own sensor's temperature (noted)" if passed else
                 "no one reference temperature describes the result, and no temperature coefficient is determined to "
                 "carry the values to one; calibrate over a temperature range (the tempcos then carry each row to "
                 "T_ref), or check the sensors' columns"))
    return note, GateOutcome("one_reference_temperature", passed, "unidentifiable", reason, spread,
                             f"< {TEMPERATURE_SPAN_MIN_C:g} degC"), temps


def sensor_temperature_problems(result) -> list[str]:
    """What is wrong with a result's recorded ``fit.sensor_temperatures_C`` (empty: nothing, or not
    recorded): it must map x, y and z to temperatures in degC between -100 and 200, and, in a result
    with status ok, spread by less than :data:`TEMPERATURE_SPAN_MIN_C` (the gate
    ``one_reference_temperature`` refuses from there)."""
    fit = result.fit if isinstance(getattr(result, "fit", None), dict) else {}
    if "sensor_temperatures_C" not in fit:
        return []
    temps = fit["sensor_temperatures_C"]
    field = "fit.sensor_temperatures_C"
    if not isinstance(temps, dict) or sorted(temps) != sorted(AXES):
        return [f"{field} = {temps!r} is not a mapping of x, y and z to temperatures (degC)"]
    bad = [a for a in AXES if isinstance(temps[a], bool) or not isinstance(temps[a], (int, float))
           or not np.isfinite(temps[a]) or not -100.0 <= temps[a] <= 200.0]
    if bad:
        return [f"{field}.{a} = {temps[a]!r} is not a temperature in degC between -100 and 200" for a in bad]
    spread = max(temps.values()) - min(temps.values())
    if getattr(result, "status", None) == "ok" and spread >= TEMPERATURE_SPAN_MIN_C:
        return [f"status is 'ok' but {field} spread {spread:.2f} degC, which the gate one_reference_temperature "
                f"refuses (>= {TEMPERATURE_SPAN_MIN_C:g} degC)"]
    # the file's other temperatures must be those of the same data (an outside probe edited them apart,
    # with the checksum removed, and compare judged the rows' edited temperatures: K_x z 11.6, fail)
    why = []
    ref, mean = getattr(result, "reference_temperature_C", None), float(np.mean(list(temps.values())))
    if isinstance(ref, (int, float)) and np.isfinite(ref) and abs(mean - ref) > SENSOR_MEAN_TOLERANCE_C:
        why.append(f"{field} average {mean:.3f} degC but reference_temperature_C is {ref:g}: a calibration at one "
                   "temperature states its values at its sensors' mean (each rounded to 0.01 degC)")
    rng = getattr(result, "temperature_range_C", None)
    if rng is not None and len(rng) == 2 and all(isinstance(v, (int, float)) and np.isfinite(v) for v in rng):
        lo, hi = float(min(rng)), float(max(rng))
        if hi - lo > RANGE_AT_ONE_TEMPERATURE_C:
            why.append(f"temperature_range_C spans {hi - lo:.2f} degC ({lo:g} to {hi:g}) in a result that records "
                       f"{field} (a calibration at one temperature, its readings within "
                       f"{RANGE_AT_ONE_TEMPERATURE_C:g} degC)")
        elif not all(lo - SENSOR_MEAN_TOLERANCE_C <= v <= hi + SENSOR_MEAN_TOLERANCE_C for v in temps.values()):
            why.append(f"{field} = {temps!r} lies outside temperature_range_C [{lo:g}, {hi:g}]")
    return why


#: |mean of fit.sensor_temperatures_C - reference_temperature_C| allowed (degC): both are rounded to
#: 0.01 degC from one data set's temperatures
SENSOR_MEAN_TOLERANCE_C = 0.02
#: the readings of a calibration at one temperature span at most its visits' means' 1 degC
#: (TEMPERATURE_SPAN_MIN_C) plus the sensors' spread (< 1 degC); this bound leaves margin
RANGE_AT_ONE_TEMPERATURE_C = 3.0


#: rows whose temperatures differ by less than this (degC) are at one temperature (the 0.01 degC
#: the results write them to)
ROWS_APART_C = 0.005


def rows_apart(rows_T: dict) -> float:
    """The spread of the rows' temperatures (:func:`row_temperatures_C`), 0 below :data:`ROWS_APART_C`."""
    spread = max(rows_T.values()) - min(rows_T.values())
    return spread if spread >= ROWS_APART_C else 0.0


def row_temperatures_C(result) -> dict:
    """The temperature (degC) at which each accelerometer's row of ``result`` holds -- K_a, S_a and
    the angles Ca_ab: each sensor's own mean temperature for a calibration at one temperature that
    recorded them (``fit.sensor_temperatures_C``, :func:`sensor_temperatures`; row a of the model is
    tied to t_a, eq. in docs/model.md, and no tempco moves it), else ``reference_temperature_C`` for
    every row (the tempcos carry each row there). Raises :class:`~triadcal.errors.InputError` for a
    recorded value that :func:`sensor_temperature_problems` rejects."""
    why = sensor_temperature_problems(result)
    if why:
        raise InputError("; ".join(why))
    temps = (result.fit or {}).get("sensor_temperatures_C") if isinstance(result.fit, dict) else None
    if temps:
        return {a: float(temps[a]) for a in AXES}
    return {a: float(result.reference_temperature_C) for a in AXES}
