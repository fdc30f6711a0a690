"""Continuous-ramp plans and their choice (``triadcal plan --ramp``, docs/plan.md).

A ramp plan is a piecewise-linear chamber program (ambient, then legs between the ends of the
range, e.g. 20 -> -40 -> 85 -> 20 degC) at one rate, an optional hold at every interior turning
point, and a set of bench positions visited back to back (move ``move_s``, dwell ``tau_s``) for
as long as the program runs (:class:`triadcal.models.simulate.RampSchedule`). No soak.

Chamber hours: the program's duration, ``sum |dT| / rate + holds``.

Predicted U: the same Fisher information as a stepped plan (:func:`triadcal.planning.plan.design`
on the covariates the simulator builds for the ramp), with ``thermal_lag`` in the model (the
fit needs it: on a ramp the element trails its sensor by ``tau * rate``, 4 min x 1 degC/min =
4 degC for the preset unit).

Search (criterion as for stepped plans, :data:`triadcal.planning.search.CRITERION`): programs
of 2-5 legs starting down or up (:func:`candidate_programs`), rates of 1, 1/2 and 1/4 of the
chamber's rate, holds of :data:`HOLDS`, positions 12/18/24, dwell :data:`RAMP_TAUS`. Candidates
are evaluated in order of hours; the first group of equal hours with a plan meeting every
target ends the search.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping, Optional, Sequence

import numpy as np

from ..errors import InputError
from ..io.atomic import read_json
from ..io.formats import require_format
from ..models.campaign import DEFAULT_PLAN
from ..models.effects import DEFAULT_EFFECTS
from ..models.simulate import RampSchedule
from .plan_fields import MAX_CHAMBER_RATE_C_PER_MIN
from .plan import AMBIENT_C, CHAMBER_RATE_C_PER_MIN, DEFAULT_Q_V2S, HOURS_CAP, MOVE_S, POSITION_SETS, design, predict

RAMP_FORMAT = "triadcal.ramp_plan"
RATE_FRACTIONS = (1.0, 0.5, 0.25)
HOLDS = (0.0, 1800.0)
RAMP_TAUS = (30.0, 60.0, 120.0)


@dataclass
class RampPlan:
    """A continuous-ramp plan (see the module). ``positions``: label -> (axis1_deg, axis2_deg)."""

    program_C: tuple
    rate_C_per_min: float = CHAMBER_RATE_C_PER_MIN
    hold_s: float = 0.0
    positions: dict = field(default_factory=lambda: dict(DEFAULT_PLAN))
    tau_s: float = 30.0
    move_s: float = MOVE_S
    name: str = ""
    effects: Optional[tuple] = None      # the model the plan was made for (its document's predicted.effects)

    #: the bench cycles through the positions for the whole program: no repetition count
    repetitions = 1

    def once(self) -> "RampPlan":
        return self

    def schedule(self) -> RampSchedule:
        return RampSchedule(program_C=tuple(float(v) for v in self.program_C), rate_C_per_min=self.rate_C_per_min,
                            hold_s=float(self.hold_s), tau_s=float(self.tau_s), move_s=float(self.move_s))

    def visit_positions(self) -> dict:
        return dict(self.positions)

    @property
    def n_visits(self) -> int:
        return len(self.schedule().visit_windows())

    @property
    def setpoints_C(self) -> tuple:
        return tuple(self.program_C)

    def chamber_hours(self) -> float:
        return self.schedule().duration_s / 3600.0

    def describe(self) -> str:
        hold = f", hold {self.hold_s:g} s" if self.hold_s else ""
        return (f"ramp {':'.join(f'{v:g}' for v in self.program_C)} degC at {self.rate_C_per_min:g} degC/min"
                f"{hold}, {len(self.positions)} positions, tau {self.tau_s:g} s, {self.n_visits} visits")

    def to_dict(self, predicted: Optional[dict] = None) -> dict:
        d = {"format": RAMP_FORMAT, "version": 1, "name": self.name,
             "program_C": [float(v) for v in self.program_C], "rate_C_per_min": float(self.rate_C_per_min),
             "hold_s": float(self.hold_s), "move_s": float(self.move_s), "tau_s": float(self.tau_s),
             "positions": [{"label": k, "axis1_deg": a1, "axis2_deg": a2} for k, (a1, a2) in self.positions.items()],
             "n_visits": self.n_visits, "chamber_hours": self.chamber_hours()}
        if predicted is not None:
            d["predicted"] = predicted
        return d

    def save(self, path, predicted: Optional[dict] = None) -> None:
        from ..io.atomic import atomic_write_json

        atomic_write_json(path, self.to_dict(predicted))

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "plan") -> "RampPlan":
        from .plan_fields import check_totals, plan_effects

        require_format(d, RAMP_FORMAT, 1, source, "a ramp plan", "ramp plan")
        check_ramp_fields(d, source)
        effects = plan_effects(d, source)
        try:
            plan = cls(program_C=tuple(float(v) for v in d["program_C"]), rate_C_per_min=float(d["rate_C_per_min"]),
                       hold_s=float(d.get("hold_s", 0.0)), move_s=float(d.get("move_s", MOVE_S)),
                       tau_s=float(d["tau_s"]),
                       positions={str(p["label"]): (float(p["axis1_deg"]), float(p["axis2_deg"]))
                                  for p in d["positions"]}, name=str(d.get("name", "")),
                       effects=effects)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: a ramp plan needs program_C, rate_C_per_min, tau_s and positions "
                             f"(label, axis1_deg, axis2_deg): {exc!r}") from None
        if len(plan.program_C) < 2 or not plan.positions or not plan.tau_s > 0 or not plan.rate_C_per_min > 0:
            raise InputError(f"{source}: a ramp plan needs two program temperatures, one position, tau_s > 0 "
                             "and rate_C_per_min > 0")
        check_totals(d, plan, source)
        return plan


def load_plan(path):
    """A plan file of ``triadcal plan``: a stepped :class:`~triadcal.planning.plan.Plan`
    (``triadcal.plan``) or a :class:`RampPlan` (``triadcal.ramp_plan``)."""
    from .plan import Plan

    d = read_json(path)
    if isinstance(d, dict) and d.get("format") == RAMP_FORMAT:
        return RampPlan.from_dict(d, str(path))
    return Plan.from_dict(d, str(path))


def check_ramp_fields(d: Mapping, path) -> None:
    """Each field of a ramp plan document ``d`` (``triadcal.ramp_plan`` version 1, checked by the
    caller) checked, with an error naming the file and the field: ``program_C`` at least two finite
    temperatures, no leg without a change; ``rate_C_per_min`` in (0, 100]; ``tau_s`` > 0;
    ``hold_s``, ``move_s`` >= 0; ``positions`` a non-empty list of objects with a unique non-empty
    ``label`` and bench angles within +-360 deg. Before, ``RampPlan.from_dict`` took a rate of
    Infinity and a label given twice (the second overwrote the first, one position silently lost)."""
    from .plan_fields import MAX_TAU_S, check_positions, number

    for key in ("program_C", "rate_C_per_min", "tau_s", "positions"):
        if key not in d:
            raise InputError(f"{path}: field {key} is missing (a ramp plan needs program_C, rate_C_per_min, "
                             "tau_s and positions)")
    prog = d["program_C"]
    if not isinstance(prog, list) or len(prog) < 2:
        raise InputError(f"{path}: field program_C: expected a list of at least two temperatures (degC), "
                         f"got {prog!r}")
    values = [number(path, f"program_C[{k}]", v, low=-273.15, high=1000.0) for k, v in enumerate(prog)]
    for k in range(1, len(values)):
        if values[k] == values[k - 1]:
            raise InputError(f"{path}: field program_C[{k}]: {values[k]:g} degC repeats program_C[{k - 1}] "
                             "(a leg must change the temperature; use hold_s for a pause)")
    number(path, "rate_C_per_min", d["rate_C_per_min"], low=0.0, strict_low=True, high=MAX_CHAMBER_RATE_C_PER_MIN)
    number(path, "tau_s", d["tau_s"], low=0.0, strict_low=True, high=MAX_TAU_S)
    for key in ("hold_s", "move_s"):
        if key in d:
            number(path, key, d[key], low=0.0)
    check_positions(d, path)


def read_ramp_plan(path) -> "RampPlan":
    """The ramp plan file of ``triadcal plan --ramp`` (``triadcal.ramp_plan`` version 1) for
    ``capture --ramp``: a stepped plan (``triadcal.plan``) is refused, saying so; the rest as
    :func:`load_plan` (every field checked by :func:`check_ramp_fields`)."""
    d = read_json(path)
    if isinstance(d, dict) and d.get("format") == "triadcal.plan":
        raise InputError(f"{path}: a stepped plan (format 'triadcal.plan'); capture --ramp takes a ramp plan "
                         f"({RAMP_FORMAT!r}, written by 'triadcal plan --ramp'); run a stepped plan with --plan PLAN.json")
    return RampPlan.from_dict(d, str(path))


def candidate_programs(lo: float, hi: float) -> list:
    """Programs from ambient (clamped into [lo, hi]) over the range: ``down-up`` (amb, lo, hi, ...)
    and ``up-down`` (amb, hi, lo, ...) with 2-5 legs; an odd number of legs ends back at ambient."""
    if not hi > lo:
        raise InputError(f"--range: the upper end must exceed the lower ({lo:g}:{hi:g})")
    amb = min(max(AMBIENT_C, lo), hi)
    out = []
    for name, ends in (("down-up", (lo, hi)), ("up-down", (hi, lo))):
        for legs in (2, 3, 4, 5):
            turns = [ends[k % 2] for k in range(2 * ((legs + 1) // 2))]
            if legs % 2:      # 3, 5 legs: (legs - 1) turning points, then back to ambient
                prog = [amb] + turns[: legs - 1] + [amb]
            else:
                prog = [amb] + turns[:legs]
            prog = [float(v) for v in prog]
            if all(abs(a - b) > 0 for a, b in zip(prog, prog[1:])):
                out.append((f"{name}, {len(prog) - 1} legs", tuple(prog)))
    return out


def ramp_effects(effects: Sequence[str]) -> list:
    """The planned model of a ramp: ``effects`` with ``thermal_lag`` (the fit of a ramp needs it)."""
    eff = list(effects)
    return eff if "thermal_lag" in eff else eff + ["thermal_lag"]


def search_ramp(target_text: str, lo: float, hi: float, *, lab=None, Q_V2s: float = DEFAULT_Q_V2S,
                chamber_rate_C_per_min: float = 1.0, positions: str = "auto",
                effects: Sequence[str] = DEFAULT_EFFECTS, preset: str = "ak18-quartz",
                hours_cap: float = HOURS_CAP, rate_fractions: Sequence[float] = RATE_FRACTIONS,
                holds: Sequence[float] = HOLDS, taus: Sequence[float] = RAMP_TAUS,
                programs: Optional[list] = None):
    """The cheapest ramp plan meeting every target (see the module); refuses an unreachable target."""
    from .search import (Choice, check_left_out, checked_inputs, evaluate, held_moves, parse_targets, refuse_held,
                         requested_but_held)

    sets = checked_inputs(chamber_rate_C_per_min, Q_V2s, positions, lo=lo, hi=hi, hours_cap=hours_cap)
    effects = ramp_effects(effects)
    progs = programs or candidate_programs(lo, hi)
    groups: dict = {}
    for name, prog in progs:
        for frac in rate_fractions:
            rate = chamber_rate_C_per_min * frac
            for hold in holds:
                base = RampPlan(program_C=prog, rate_C_per_min=rate, hold_s=hold)
                hours = base.chamber_hours()
                if hours > hours_cap:
                    continue
                for npos in sets:
                    for tau in taus:
                        p = replace(base, positions=dict(POSITION_SETS[npos]), tau_s=float(tau),
                                    name=f"{name}, {rate:g} degC/min, hold {hold:g} s, {npos} positions")
                        groups.setdefault(round(hours * 3600.0), []).append(p)
    targets, best, best_key, searched, reach, blocked = None, None, None, 0, {}, None
    for key in sorted(groups):
        for p in groups[key]:
            if p.n_visits < 2 * len(p.positions):
                continue
            d = design(p, effects, lab, preset)
            if d.blind:                 # blind to an effect the model leaves out (plan.blind_to), as stepped plans
                continue
            if targets is None:
                targets = parse_targets(target_text, d.names)
            searched += 1
            pred = predict(d, Q_V2s)
            if not np.all(np.isfinite(pred["U"])):
                continue
            met = evaluate(targets, list(d.names), pred["U"], d.values)
            # a requested effect the plan cannot estimate (search.held_moves), as stepped plans
            dropped = requested_but_held(d, effects)
            moves = held_moves(d, targets, dropped, Q_V2s, p.tau_s)
            moved = {mv["target"] for mv in moves if mv["significant"]}
            for spec, (ok, worst, n) in met.items():
                if spec not in moved and (spec not in reach or worst < reach[spec][0]):
                    reach[spec] = (worst, n, p.chamber_hours())
            if moved and all(m[0] for m in met.values()):
                if blocked is None or (key, p.name) < blocked[0]:
                    blocked = ((key, p.name), p.name, p.chamber_hours(), [mv for mv in moves if mv["significant"]])
                continue
            if all(m[0] for m in met.values()):
                a = sum((t.in_unit(n, float(pred["U"][d.names.index(n)]), d.values) / t.limit) ** 2
                        for t in targets for n in t.parameters(d.names))
                if best_key is None or (bool(dropped), key, a) < best_key:
                    best_key = (bool(dropped), key, a)
                    best = Choice(p, pred, targets, met, d.values, d.units, 0, d.problems,
                                  {h: {"effect": d.effect_of[h], "reason": r, "held_at": d.nominal[h],
                                       "moves": [mv for mv in moves if mv["held"] == h]} for h, r in dropped.items()}, design=d)
        if best is not None and not best_key[0]:
            break
    if best is None and blocked is not None:
        refuse_held(blocked, targets, searched, hours_cap, preset, "ramp plans")
    if best is None:
        if targets is None:
            raise InputError(f"--ramp: no ramp program over {lo:g}:{hi:g} degC fits within {hours_cap:g} chamber hours")
        bad = [f"{t.spec}: best reachable U = {reach[t.spec][0]:.3g} {t.unit} ({reach[t.spec][1]}, in "
               f"{reach[t.spec][2]:.1f} h)" for t in targets if t.spec in reach and reach[t.spec][0] > t.limit]
        why = "; ".join(bad) if bad else "each target alone is reachable, but no searched plan meets them all"
        raise InputError(f"--target cannot be met within {hours_cap:g} chamber hours by any of the {searched} "
                         f"ramp plans searched: {why}")
    best.searched = searched
    return check_left_out(best, effects, lab, preset, Q_V2s)
