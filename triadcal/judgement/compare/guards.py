"""What a comparison refuses or holds back of its own accord: a negative correlation, calibrations out of
the order of their data, and the note and marking of verdicts held back as inconclusive (pair.py's
``compare``; moved out of pair.py unchanged)."""

from __future__ import annotations

import math
from typing import Mapping, Optional, Sequence

from ...errors import InputError
from ...estimation.result import CalibrationResult

#: an overall verdict held back from pass (an angle missing, same data, a correlation beyond the budgets,
#: ...): a note that starts with this
NOT_PASS_NOTE = "overall verdict not pass: "

#: why a stated negative correlation is refused (docs/compare.md): two calibrations' errors are either
#: their own (independent, rho 0) or shared (one bench, one lab: the same error in both, rho > 0). An
#: outside probe: Ca_xy truly moved 1" (2.25 u(d)); at rho = 0 it failed (z 2.21), at -0.9 u(d) grew
#: 0.44" -> 0.61" and the comparison said "overall: pass", exit 0, without a word
NEGATIVE_RHO_REASON = ("a negative rho says the two calibrations' errors tend to opposite signs, and none do: their "
                       "random errors are independent (rho 0) and an error they share (one bench, one lab) is the "
                       "same in both (rho > 0); a negative rho only widens u(d), and a real drift passes. Leave it "
                       "out (derived) or state one in [0, 1); what two budgets share, of either sign per parameter, "
                       "is derived from their rows with --shared-bench or --lab")

#: equipment the bench check (the change of tilt_x, tilt_y) speaks for: a bench re-levelled or moved
#: between the campaigns may have been re-zeroed too, and the unit in its fixture on it remounted
BENCH_MOUNTED = ("bench", "fixture")


def check_data_order(results: Sequence[CalibrationResult], names: Sequence[str]) -> None:
    """Refuse (InputError, one line naming both and their dates) calibrations given out of the order
    of their data: every pair whose results both state a ``data_date`` (ISO) must be in date order
    (equal dates allowed); a ``data_date`` that is not ISO 8601 or lies after today is refused. An outside probe: ``compare after.json before.json`` (data 2026-03-01 and
    2026-01-10) reported every drift with its sign reversed, and ``--sequence`` in reverse order was
    taken as given."""
    from ...io.dates import ISO_HINT, future_problem, iso_date

    days = [iso_date(r.extra.get("data_date")) if r.extra.get("data_date") else None for r in results]
    # a date that is no ISO date, or one after today, is refused as history --add refuses it (an outside
    # probe: '10.02.2026' and '2026-02-30' were dropped in silence, which turned the order check off, and
    # a result without content_sha256 given first was compared with every drift's sign reversed)
    for r, name, day in zip(results, names, days):
        raw = r.extra.get("data_date")
        if raw and day is None:
            raise InputError(f"{name}: data_date = {raw!r} is not {ISO_HINT}")
        late = future_problem(day, "a calibration") if day else None
        if late:
            raise InputError(f"{name}: data_date {late}")
    for i in range(len(results)):
        for j in range(i + 1, len(results)):
            if days[i] and days[j] and days[i] > days[j]:
                raise InputError(f"{names[i]} (data_date {days[i]}) is given before {names[j]} (data_date {days[j]}), "
                                 "whose data are older: calibrations are compared in the order their data were "
                                 "taken (BEFORE, then AFTER), and out of it every drift has the wrong sign; give "
                                 "them in date order")


def _held_note(why: str, params: dict, other: dict, tail: str) -> str:
    """The note of verdicts held back as inconclusive: why, each held parameter's verdict and the other
    one (``other``: name -> verdict), and what to do."""
    return (NOT_PASS_NOTE + f"held back: {why}"
            + ("; parameters held back as inconclusive: " + ", ".join(
                f"{n} ({params[n].verdict} -> {v})" for n, v in other.items()) if other else "") + tail)


def _hold(params: dict, names) -> None:
    for n in names:
        params[n].verdict, params[n].held_back = "inconclusive", True


def bench_contradicts_sharing(bench: dict, bench_shared: list, level: float, params: dict, overall: str, alt,
                              overall_alt: str, notes: list) -> bool:
    """When the bench check (a significant change of tilt_x or tilt_y) contradicts shared bench or fixture
    errors: hold back as inconclusive every parameter whose verdict differs with those errors independent
    (``alt``, the comparison made so; ``overall_alt`` its overall verdict), with a note naming the tilt and
    its z; True when the overall verdict is to be held back too. An outside probe: the bench's encoder
    zeros and non-orthogonality re-drawn (5") between the campaigns, --shared-bench: the tilt_y check said
    +2.7 +- 0.26" and "may then not cancel", yet the unmoved unit "failed" 5 of 5 (D2 62-2116; without
    sharing 3 pass, 2 inconclusive)."""
    moved = [n for n, v in bench.items() if v["significant"]]
    held = [n for n in params if n in alt.parameters and params[n].verdict != alt.parameters[n].verdict]
    eq = ", ".join(f"[{e}]" for e in bench_shared)
    check = "; ".join(f"{n} changed {bench[n]['drift']:+.3g} +- {bench[n]['u']:.2g} {bench[n]['unit']} "
                      f"(z {bench[n]['drift'] / bench[n]['u']:.3g})" if bench[n]["u"] > 0 else
                      f"{n} changed {bench[n]['drift']:+.3g} {bench[n]['unit']}" for n in moved)
    said = (f"the bench check contradicts the shared {eq}: {check}, significant at {level:.0%} (re-levelled or "
            f"moved between the campaigns, its errors need not be the same in both)")
    if held or overall != overall_alt:
        notes.insert(0, _held_note(f"{said}; with {eq} shared the verdict is {overall}, with its errors "
                                   f"independent it is {overall_alt}", params,
                                   {n: alt.parameters[n].verdict for n in held},
                                   "; check the bench, and share it only if it was not adjusted"))
        _hold(params, held)
        return True
    notes.append(f"{said}; the verdicts are the same with {eq} shared and with its errors independent, so they stand")
    return False


#: every drift within this many of its u(d), on at least COPY_MIN_PARAMETERS parameters: the same data
#: (two independent calibrations: probability (1.6 z)^p, below 1e-23 for six at 1e-4)
COPY_Z_MAX, COPY_MIN_PARAMETERS = 1e-4, 6


def copied_data(params: Mapping) -> Optional[float]:
    """The largest |z| of the drifts when every one of at least :data:`COPY_MIN_PARAMETERS` lies within
    :data:`COPY_Z_MAX` of its u(d) -- fits of the same data whose files differ in bytes (rows reordered,
    numbers rewritten to 15 digits, times moved to another epoch: each a new ``data_sha256``; an
    outside probe's three re-exports of one campaign passed, exit 0, largest |z| 2e-10) -- else None."""
    z = [abs(float(v.z)) for v in params.values() if v.z is not None and math.isfinite(float(v.z))]
    if len(z) < COPY_MIN_PARAMETERS or max(z) > COPY_Z_MAX:
        return None
    return max(z)


def same_calibration(before: CalibrationResult, after: CalibrationResult) -> bool:
    """True when ``before`` and ``after`` are one calibration: same unit, method and source, and
    every parameter's value and u identical (a file compared with itself or a copy of it)."""
    if (before.unit, before.method, before.extra.get("source")) != (after.unit, after.method, after.extra.get("source")):
        return False
    if set(before.parameters) != set(after.parameters):
        return False
    return all(before[n].value == after[n].value and before[n].u == after[n].u for n in before.parameters)
