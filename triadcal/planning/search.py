"""Targets, the candidate plans and the choice among them (``triadcal plan``, docs/plan.md).

Criterion (stated in every prediction): the plan with the fewest chamber hours whose predicted
U meets every target; among plans of equal hours (within 1 s), the A-optimal one over the
targeted parameters (the smallest sum of (U / target)^2). The search covers the setpoint
sequences of :func:`candidate_sequences`, the position sets 12 / 18 / 24
(:data:`triadcal.planning.plan.POSITION_SETS`), the dwell ``tau_s`` in :data:`TAUS` and
1-3 repetitions of the position set at each setpoint, under a cap of chamber hours.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Mapping, Optional, Sequence

import numpy as np

from ..errors import InputError
from ..models.effects import DEFAULT_EFFECTS
from ..models.units import ARCSEC
from .plan_fields import MAX_CHAMBER_RATE_C_PER_MIN
from .plan import (AMBIENT_C, DEFAULT_Q_V2S, HOURS_CAP, POSITION_SETS, Plan, absorbed, design, held_sensitivity,
                   left_out_signatures, predict, undetermined_time_constants)

TAUS = (30.0, 60.0, 120.0, 300.0)
REPETITIONS = (1, 2, 3)
LEVELS = (2, 3, 4, 5, 6)

_AB = "(xy|xz|yx|yz|zx|zy)"
#: target family -> (pattern of its parameters, {unit: factor from the results-JSON unit});
#: a factor of None is K's relative ppm: 1e6 / K (K the preset unit's nominal value)
FAMILIES = {
    "Ca": (rf"^Ca_{_AB}$", {"arcsec": 1.0, "urad": ARCSEC * 1e6}),
    "Ca_tempco": (rf"^Ca_{_AB}_tempco$", {"arcsec/degC": 1.0}),
    "Ca_hysteresis": (rf"^Ca_{_AB}_hysteresis$", {"arcsec": 1.0}),
    "K": (r"^K_[xyz]$", {"ppm": None, "g/V": 1.0}),
    "K_tempco": (r"^K_[xyz]_tempco$", {"ppm/degC": 1.0}),
    "S": (r"^S_[xyz]$", {"g": 1.0, "mg": 1e3, "ug": 1e6}),
    "S_tempco": (r"^S_[xyz]_tempco$", {"ug/degC": 1.0}),
    "tilt": (r"^tilt_[xy]$", {"arcsec": 1.0}),
    "thermal_lag": (r"^thermal_lag$", {"min": 1.0, "s": 60.0}),
}


@dataclass
class Target:
    spec: str            # as written
    family: str          # family or single parameter name
    limit: float         # in ``unit``
    unit: str

    def parameters(self, names: Sequence[str]) -> list:
        if self.family in FAMILIES:
            return [n for n in names if re.match(FAMILIES[self.family][0], n)]
        return [self.family] if self.family in names else []

    def in_unit(self, name: str, U: float, values: dict) -> float:
        fam = self.family if self.family in FAMILIES else family_of(name)
        f = FAMILIES[fam][1][self.unit]
        return U * (1e6 / values[name] if f is None else f)


def family_of(name: str) -> Optional[str]:
    for fam, (pat, _) in FAMILIES.items():
        if re.match(pat, name):
            return fam
    return None


def _norm_unit(u: str) -> str:
    return u.strip().replace("µ", "u").replace("°C", "degC").replace("″", "arcsec").replace(" ", "")


def parse_targets(text: str, names: Sequence[str]) -> list:
    """``"Ca:U<=5arcsec, Ca_tempco:U<=0.1arcsec/degC, K:U<=20ppm"`` -> targets; a family
    (``Ca``, ``Ca_tempco``, ``K``, ``S``, ...) means each of its parameters. Refuses an unknown
    parameter, a parameter not in the model, a bad unit or a malformed entry, naming it."""
    out = []
    for part in [p.strip() for p in text.split(",") if p.strip()]:
        m = re.fullmatch(r"([A-Za-z_]+)\s*:\s*U\s*<=\s*([0-9.eE+-]+)\s*(.+)", part)
        if not m:
            raise InputError(f"--target: cannot read {part!r}; write NAME:U<=VALUEUNIT, e.g. Ca:U<=5arcsec")
        name, value, unit = m.group(1), m.group(2), _norm_unit(m.group(3))
        try:
            limit = float(value)
        except ValueError:
            raise InputError(f"--target: {part!r}: {value!r} is not a number") from None
        if not limit > 0:
            raise InputError(f"--target: {part!r}: the target U must be > 0")
        fam = name if name in FAMILIES else family_of(name)
        if fam is None:
            raise InputError(f"--target: unknown parameter {name!r}; give a family ({', '.join(FAMILIES)}) or a "
                             "parameter of the model (Ca_xy, K_x_tempco, ...)")
        t = Target(part, name, limit, unit)
        if unit not in FAMILIES[fam][1]:
            raise InputError(f"--target: {part!r}: unit {m.group(3).strip()!r} is not one for {name}; use "
                             f"{' or '.join(FAMILIES[fam][1])}")
        if not t.parameters(names):
            raise InputError(f"--target: {name!r} is not a parameter of the planned model (effects decide which are)")
        twice = next((o for o in out if o.family == t.family), None)
        if twice is not None:
            # "Ca:U<=5arcsec,Ca:U<=3arcsec" was taken as two targets, without a word (an outside probe); a
            # family and a tighter target of one of its members ("Ca:U<=5arcsec,Ca_xy:U<=2arcsec") stay
            raise InputError(f"--target: {part!r} and {twice.spec!r} are two targets for {name}: give one")
        out.append(t)
    if not out:
        raise InputError("--target: no target given")
    return out


def candidate_sequences(lo: float, hi: float, hysteresis: bool = True) -> list:
    """Setpoint sequences over [lo, hi] with ``m`` levels equally spaced (ends included). Every
    sequence starts at ambient (20 degC, clamped into the range): the unit has soaked there, so its
    first setpoint is on the mid-line (direction ``none``, docs/model.md); then ``up-down``
    (heating sweep to hi, cooling sweep to lo), ``down-up`` (mirrored), each also with the sweep
    back to ambient (the example's shape); without hysteresis in the model also a single sweep.
    With hysteresis every sequence has heating and cooling visits: when the range does not contain
    ambient the start is clamped to one end, and only the sequences that come back through the
    range from the far end are kept."""
    if not hi > lo:
        raise InputError(f"--range: the upper end must exceed the lower ({lo:g}:{hi:g})")
    amb = min(max(AMBIENT_C, lo), hi)
    out = []
    for m in LEVELS:
        lv = [round(float(v), 1) for v in np.linspace(lo, hi, m)]
        up = [v for v in lv if v > amb]                       # amb -> hi
        hi_lo = [v for v in lv[::-1] if v < hi]               # hi -> lo
        lo_amb = [v for v in lv if lo < v < amb] + [amb]      # lo -> amb
        dn = [v for v in lv[::-1] if v < amb]                 # amb -> lo
        lo_hi = [v for v in lv if v > lo]                     # lo -> hi
        hi_amb = [v for v in lv[::-1] if amb < v < hi] + [amb]
        if hysteresis:
            out.append((f"up-down, {m} levels", tuple([amb] + up + hi_lo)))
            out.append((f"up-down-back, {m} levels", tuple([amb] + up + hi_lo + lo_amb)))
            out.append((f"down-up, {m} levels", tuple([amb] + dn + lo_hi)))
            out.append((f"down-up-back, {m} levels", tuple([amb] + dn + lo_hi + hi_amb)))
        else:
            out.append((f"sweep, {m} levels", tuple([amb] + dn + lo_hi)))
            if lo < amb < hi and amb not in lo_hi:
                # back through ambient on the way up: a temperature on both branches, so a hysteresis the
                # model leaves out is visible (a sweep that visits none twice is blind to it: blind_to)
                up_amb = sorted(set(lo_hi) | {amb})
                out.append((f"sweep through ambient, {m} levels", tuple([amb] + dn + up_amb)))
    seen, uniq = set(), []
    for name, seq in out:
        # a clamped ambient coincides with an end: no setpoint twice in a row (a second soak for nothing)
        seq = tuple(float(v) for k, v in enumerate(seq) if k == 0 or v != seq[k - 1])
        if hysteresis and not {"heating", "cooling"} <= set(Plan(setpoints_C=seq).directions()):
            # a range not containing ambient (e.g. 30:85) clamps the start to an end: the sweep
            # away from that end alone is one-directional, no hysteresis (the fit would hold it at
            # 0 while the first visits, direction none, and the rest differ in branch)
            continue
        if len(seq) > 1 and hysteresis:
            # named by its first move (a clamped ambient makes up-down-back of -40:10 go down first)
            name = re.sub(r"^(up-down|down-up)", "up-down" if seq[1] > seq[0] else "down-up", name)
        if seq not in seen:
            seen.add(seq)
            uniq.append((name, seq))
    return uniq


#: the setpoints' resolution, degC (candidate_sequences rounds the levels to it)
SETPOINT_RESOLUTION_C = 0.1


def narrow_range(lo: float, hi: float, effects: Sequence[str]) -> str:
    """The refusal of a range on which no candidate sequence survives: every level rounds to one
    setpoint (a range narrower than :data:`SETPOINT_RESOLUTION_C`), so nothing depending on
    temperature can be estimated; said as for a 0.5 degC range (a tempco needs more than one
    temperature), not as a lack of chamber hours."""
    levels = sorted({round(float(v), 1) for m in LEVELS for v in np.linspace(lo, hi, m)})
    thermal = [e for e in effects if e.endswith("tempco") or e == "hysteresis"]
    what = (f"the effects {', '.join(thermal)} are" if thermal else "nothing that depends on temperature is")
    return (f"--range: {lo:g}:{hi:g} degC spans {hi - lo:.3g} degC: the setpoints (steps of "
            f"{SETPOINT_RESOLUTION_C:g} degC) are {', '.join(f'{v:g}' for v in levels)} degC, "
            f"{'one temperature' if len(levels) == 1 else 'too few temperatures'}, on which {what} not estimated "
            "(a temperature coefficient needs more than one temperature, a hysteresis a heating and a cooling "
            "visit of one temperature); give a wider --range")


@dataclass
class Choice:
    plan: Plan
    prediction: dict
    targets: list
    met: dict            # spec -> (met, worst U in the target's unit, parameter)
    values: dict
    units: dict
    searched: int
    problems: dict
    #: parameters of requested effects the plan holds although they are in --effects, each with what it
    #: moves (all below HELD_NEGLIGIBLE of the targets; :func:`held_moves`)
    held: dict = field(default_factory=dict)
    #: effects of the preset unit the model leaves out (not in --effects) and what each moves among the
    #: targeted parameters on this plan (:func:`left_out_moves`); only those moving some target by more
    #: than HELD_NEGLIGIBLE of it
    left_out: dict = field(default_factory=dict)
    #: the effects checked and found negligible on this plan (each moves every target by less)
    left_out_negligible: list = field(default_factory=list)
    #: the design of the chosen plan (its Jacobian and weights; internal, for :func:`left_out_moves`)
    design: object = None


CRITERION = ("the fewest chamber hours whose predicted U (Fisher information, bench errors and the lab's "
             "systematic errors included) meets every target; ties broken A-optimally (smallest sum of "
             "(U/target)^2 over the targeted parameters)")


#: a parameter of a requested effect that a plan cannot estimate (the fit holds it at its nominal
#: value) is let pass only if, at the preset unit's magnitude, it moves no targeted parameter by more
#: than this fraction of the target (:func:`held_moves`)
HELD_NEGLIGIBLE = 0.01


def warmup_offsets_held(d, hold: Mapping) -> dict:
    """The offsets at power-on of a warm-up whose time constant the plan holds (``hold``): with the
    time constant held the offsets' columns are those of a transient over before the first visit
    (an outside probe: ``--effects bench_tilt,bias_warmup`` planned "met" with ``S_x_warmup`` at a
    predicted U of 3.9e12 g, and the fit of the planned campaign was refused by ``warmup_seen`` and
    ``warmup_offsets``). Held with the time constant, and said: the fit must leave the effect out."""
    out = {}
    for tau, kind, effect in (("S_warmup_tau", "S", "bias_warmup"), ("K_warmup_tau", "K", "scale_warmup")):
        if tau in hold:
            for a in "xyz":
                n = f"{kind}_{a}_warmup"
                if n in d.names:
                    out[n] = (f"the warm-up's time constant is held (not determined by this plan), so its offset at "
                              f"power-on is a transient over before the first visit that the data cannot show: the "
                              f"fit of this plan's campaign with {effect} is refused (warmup_seen); fit without it, "
                              "which it does not move, or record from power-on")
    return out


def requested_but_held(d, effects: Sequence[str], exempt: Mapping = ()) -> dict:
    """The parameters of the effects asked for (``effects``, i.e. --effects) that the plan of ``d``
    holds (``d.problems``), name -> reason; ``exempt`` (the time constants a stepped plan holds by
    rule, :func:`~triadcal.planning.plan.undetermined_time_constants`) left out."""
    req = set(effects)
    return {n: r for n, r in d.problems.items() if d.effect_of.get(n) in req and n not in exempt and n in d.J_held}


def held_magnitude(d, name: str) -> tuple:
    """(departure, what it is): the preset unit's value of the held parameter less the value the fit
    holds it at (its nominal), or the parameter's typical size where the preset has none."""
    dv = d.values.get(name, d.nominal[name]) - d.nominal[name]
    return (dv, "the preset's") if dv != 0 else (d.typical[name], "a typical")


def held_moves(d, targets, held: Mapping, Q_V2s: float, tau_s: float) -> list:
    """What each held parameter (``held``) moves among the targeted ones, at the preset's magnitude:
    a list of dicts (target, parameter, held, effect, held_at, magnitude, per_unit and bias in the
    target's unit, significant: above :data:`HELD_NEGLIGIBLE` of the target)."""
    if not held:
        return []
    S = held_sensitivity(d, Q_V2s, tau_s)
    names = list(d.names)
    out = []
    for h in held:
        dv, what = held_magnitude(d, h)
        for t in targets:
            for m in t.parameters(names):
                per = float(S[h][names.index(m)])
                bias = t.in_unit(m, per * dv, d.values)
                out.append({"target": t.spec, "parameter": m, "held": h, "effect": d.effect_of[h],
                            "held_at": d.nominal[h], "magnitude": dv, "magnitude_is": what,
                            "unit": d.units.get(h, ""), "bias": bias, "target_unit": t.unit,
                            "per_unit": t.in_unit(m, per, d.values), "reason": d.problems[h],
                            "significant": abs(bias) > HELD_NEGLIGIBLE * t.limit})
    return out


def describe_move(mv: dict, preset: str = "") -> str:
    who = f"the {preset} preset's" if mv["magnitude_is"] == "the preset's" and preset else mv["magnitude_is"]
    return (f"{mv['held']} held at {mv['held_at']:g} {mv['unit']}: {who} {mv['magnitude']:g} {mv['unit']} moves "
            f"{mv['parameter']} by {mv['bias']:+.3g} {mv['target_unit']} ({mv['per_unit']:+.3g} {mv['target_unit']} "
            f"per {mv['unit']}), against {mv['target']}")


def refuse_held(blocked, targets, searched: int, hours_cap: float, preset: str, what: str = "plans") -> None:
    """Refuse, naming the effect and what it moves: ``blocked`` = (key, name, hours, significant moves)
    of the cheapest plan that met every target but for a requested effect it cannot estimate."""
    _, name, hours, moves = blocked
    effs = sorted({mv["effect"] for mv in moves})
    limit = {t.spec: t.limit for t in targets}
    moves = sorted(moves, key=lambda mv: -abs(mv["bias"]) / limit[mv["target"]])
    more = f"; and {len(moves) - 3} more such" if len(moves) > 3 else ""
    moves = moves[:3]
    raise InputError(
        f"--effects: {', '.join(effs)} cannot be estimated by any plan within {hours_cap:g} chamber hours that "
        f"meets --target ({searched} {what} searched): on the cheapest plan that otherwise would ({name!r}, "
        f"{hours:.1f} h) " + "; ".join(describe_move(mv, preset) for mv in moves) + more
        + "".join(f" ({e}: {r})" for e, r in {mv["effect"]: mv["reason"] for mv in moves}.items())
        + "; give the plan room (--positions auto, 18 or 24, a wider --range, a larger --max-hours) or leave "
        f"{', '.join(effs)} out of --effects if the unit has none")


def left_out_moves(d, targets, signatures: Mapping, Q_V2s: float, tau_s: float) -> dict:
    """What each effect the model leaves out (``signatures``: :func:`~.plan.left_out_signatures` of the
    plan of ``d``, at the preset's values) moves among the targeted parameters when the plan's fit,
    weighted as :func:`~.plan.predict`, absorbs its signature (:func:`~.plan.absorbed`): ``{effect:
    {"parameters": {name: {"value", "unit"}}, "moves": [{"target", "parameter", "bias", "unit",
    "fraction" (of the target's limit)}], "significant": any move above HELD_NEGLIGIBLE of its target}}``."""
    if not signatures:
        return {}
    effs = list(signatures)
    S = absorbed(d, np.stack([signatures[e]["signature"] for e in effs], axis=1), Q_V2s, tau_s)
    names = list(d.names)
    out = {}
    for k, e in enumerate(effs):
        moves = []
        for t in targets:
            for m in t.parameters(names):
                bias = t.in_unit(m, float(S[names.index(m), k]), d.values)
                moves.append({"target": t.spec, "parameter": m, "bias": bias, "unit": t.unit,
                              "fraction": abs(bias) / t.limit})
        out[e] = {"parameters": {n: {"value": v, "unit": u} for n, (v, _, u) in signatures[e]["parameters"].items()},
                  "moves": moves, "significant": any(mv["fraction"] > HELD_NEGLIGIBLE for mv in moves)}
    return out


def check_left_out(choice: "Choice", effects: Sequence[str], lab, preset: str, Q_V2s: float) -> "Choice":
    """Fill ``choice.left_out`` (the preset's effects outside --effects that move a target by more than
    HELD_NEGLIGIBLE of it on the chosen plan) and ``choice.left_out_negligible``. A note, not a refusal:
    the preset is an example unit, the user's may not have the effect."""
    d = choice.design
    if d is None:
        return choice
    sigs = left_out_signatures(choice.plan, effects, lab, preset)
    moves = left_out_moves(d, choice.targets, sigs, Q_V2s, choice.plan.tau_s)
    choice.left_out = {e: v for e, v in moves.items() if v["significant"]}
    choice.left_out_negligible = [e for e, v in moves.items() if not v["significant"]]
    return choice


def left_out_caveats(choice: "Choice") -> dict:
    """target spec -> [(effect, the largest move of that target's parameters)] for the left-out effects
    that move it by more than HELD_NEGLIGIBLE of its limit (the target is met only if the unit has none)."""
    out: dict = {}
    for e, v in choice.left_out.items():
        for t in choice.targets:
            mvs = [mv for mv in v["moves"] if mv["target"] == t.spec]
            worst = max(mvs, key=lambda mv: abs(mv["bias"]), default=None)
            if worst is not None and worst["fraction"] > HELD_NEGLIGIBLE:
                out.setdefault(t.spec, []).append((e, worst))
    return out


def evaluate(targets, names, U, values, held: Optional[Mapping] = None) -> dict:
    """spec -> (met, worst U in the target's unit, parameter); a parameter the plan holds
    (``held``: not estimated) has no U: infinite, so the target is not met."""
    out = {}
    held = dict(held or {})
    every = list(names) + [n for n in held if n not in names]

    def U_of(t, n):
        return math.inf if n not in names else t.in_unit(n, float(U[names.index(n)]), values)

    for t in targets:
        worst = max(((U_of(t, n), n) for n in t.parameters(every)))
        out[t.spec] = (worst[0] <= t.limit, worst[0], worst[1])
    return out


#: absolute zero, degC: no range may reach below it
ABSOLUTE_ZERO_C = -273.15


def checked_range(lo: float, hi: float) -> None:
    """Refuse a ``--range`` that is not finite, not increasing, reaches below absolute zero or leaves
    the temperatures a plan file may hold (:data:`~triadcal.planning.plan_fields.PLAN_TEMPERATURE_C`,
    which the plan's reader, ``simulate --plan``, enforces: a plan outside it was written, then refused
    by its own reader)."""
    from .plan_fields import PLAN_TEMPERATURE_C

    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise InputError(f"--range: {lo:g}:{hi:g} degC; both ends must be finite numbers")
    if lo < ABSOLUTE_ZERO_C:
        raise InputError(f"--range: {lo:g}:{hi:g} degC reaches below absolute zero ({ABSOLUTE_ZERO_C:g} degC)")
    if not hi > lo:
        raise InputError(f"--range: the upper end must exceed the lower ({lo:g}:{hi:g})")
    t_lo, t_hi = PLAN_TEMPERATURE_C
    if lo < t_lo or hi > t_hi:
        raise InputError(f"--range: {lo:g}:{hi:g} degC leaves the temperatures a plan may hold ({t_lo:g} to "
                         f"{t_hi:g} degC, the range of a setpoint the plan and bench CSV readers accept)")


#: the white-noise intensity a plan may assume, V^2 s (docs/plan.md, "--q"): above, sqrt(Q) = 1 V/sqrt(Hz)
#: is a noise of ~1 g/sqrt(Hz) at K ~ 1 g/V, as large over a 1 s average as gravity, the signal of the
#: calibration (no instrument; a slip of unit); below, 1e-10 V/sqrt(Hz) (0.1 ng/sqrt(Hz)) is far below any
#: accelerometer triad (the preset quartz unit: 3e-9 V^2 s, 55 ug/sqrt(Hz)) and the predicted U would be
#: that of a noiseless unit (1e-300 gave "U 4e-146 arcsec, met")
Q_RANGE_V2S = (1e-20, 1.0)


def checked_hours_cap(hours_cap) -> float:
    """Refuse a ``--max-hours`` that is not a finite number > 0."""
    try:
        h = float(hours_cap)
    except (TypeError, ValueError):
        raise InputError(f"--max-hours: {hours_cap!r}; give a finite number of chamber hours > 0") from None
    if not (math.isfinite(h) and h > 0):
        raise InputError(f"--max-hours: {hours_cap!r}; give a finite number of chamber hours > 0")
    return h


def checked_inputs(chamber_rate_C_per_min: float, Q_V2s: float, positions: str, *, lo: Optional[float] = None,
                   hi: Optional[float] = None, hours_cap: Optional[float] = None) -> list:
    """The position sets to search, after refusing a rate or a noise that is not positive, an
    unknown position set, a range below absolute zero and a cap of hours that is not a finite
    number > 0 (the stepped and the ramp search share them)."""
    if lo is not None and hi is not None:
        checked_range(float(lo), float(hi))
    if hours_cap is not None:
        checked_hours_cap(hours_cap)
    if not chamber_rate_C_per_min > 0:
        raise InputError("--chamber-rate must be > 0 degC/min")
    if not chamber_rate_C_per_min <= MAX_CHAMBER_RATE_C_PER_MIN:
        # an outside probe: 1000 degC/min planned "met" in 5.8 h (exit 0), a plan file its readers refuse
        raise InputError(f"--chamber-rate {chamber_rate_C_per_min:g} degC/min: no chamber moves a unit faster than "
                         f"{MAX_CHAMBER_RATE_C_PER_MIN:g} degC/min (the plan file's limit; docs/plan.md)")
    q_lo, q_hi = Q_RANGE_V2S
    if not (isinstance(Q_V2s, (int, float)) and math.isfinite(Q_V2s) and Q_V2s > 0):
        raise InputError(f"--q must be > 0 V^2 s (got {Q_V2s!r})")
    if not q_lo <= Q_V2s <= q_hi:
        raise InputError(f"--q: {Q_V2s:g} V^2 s is outside the physical range {q_lo:g} to {q_hi:g} V^2 s of an "
                         "accelerometer's white noise (docs/plan.md: above 1 V^2 s the noise of a 1 s average is as "
                         "large as gravity; the example unit's is 3e-9 V^2 s)")
    try:
        sets = sorted(POSITION_SETS) if positions == "auto" else [int(positions)]
    except ValueError:
        raise InputError(f"--positions: {positions!r}; choose auto, 12, 18 or 24") from None
    for s in sets:
        if s not in POSITION_SETS:
            raise InputError(f"--positions: {positions!r}; choose auto, 12, 18 or 24")
    return sets


def search(target_text: str, lo: float, hi: float, *, lab=None, Q_V2s: float = DEFAULT_Q_V2S,
           chamber_rate_C_per_min: float = 1.0, positions: str = "auto",
           effects: Sequence[str] = DEFAULT_EFFECTS, preset: str = "ak18-quartz",
           hours_cap: float = HOURS_CAP, taus: Sequence[float] = TAUS,
           repetitions: Sequence[int] = REPETITIONS, sequences: Optional[list] = None) -> Choice:
    """The chosen plan (see the module); refuses an unreachable target within ``hours_cap``."""
    sets = checked_inputs(chamber_rate_C_per_min, Q_V2s, positions, lo=lo, hi=hi, hours_cap=hours_cap)
    seqs = sequences or candidate_sequences(lo, hi, "hysteresis" in effects)
    if not seqs:
        raise InputError(narrow_range(lo, hi, effects))
    targets = None
    best, best_key, searched = None, None, 0
    reach: dict = {}
    held_reason: dict = {}          # target spec -> {parameter: why some plan holds it}
    blind_skipped: list = []        # (plan name, {effect: visible fraction}) of the schedules left out
    blocked = None                  # the cheapest plan left out for a requested effect it holds (held_moves)
    for name, sps in seqs:
        for npos in sets:
            plan = Plan(setpoints_C=sps, positions=dict(POSITION_SETS[npos]),
                        chamber_rate_C_per_min=chamber_rate_C_per_min, name=f"{name}, {npos} positions")
            d = design(plan, effects, lab, preset)
            if d.blind:
                # a schedule on which an effect the model leaves out would move the answer unseen is no
                # candidate: the fit would pass every gate on a unit that has it (plan.blind_to)
                blind_skipped.append((plan.name, d.blind))
                continue
            # the fit's gates on time constants: hold those the plan cannot determine (thermal_lag)
            hold = undetermined_time_constants(d, Q_V2s, max(taus), max(repetitions), at_rest=True)
            hold.update(warmup_offsets_held(d, hold))
            if hold:
                d = design(plan, effects, lab, preset, hold={**d.problems, **hold})
            if targets is None:
                targets = parse_targets(target_text, list(d.names) + [n for n in d.problems if n not in d.names])
            for t in targets:
                for n in t.parameters(list(d.problems)):
                    held_reason.setdefault(t.spec, {})[n] = d.problems[n]
            dropped = requested_but_held(d, effects, hold)
            for tau in taus:
                moves = held_moves(d, targets, dropped, Q_V2s, tau)
                moved = {mv["target"] for mv in moves if mv["significant"]}
                for reps in repetitions:
                    p = Plan(**{**plan.__dict__, "tau_s": float(tau), "repetitions": int(reps)})
                    hours = p.chamber_hours()
                    if hours > hours_cap:
                        continue
                    searched += 1
                    pred = predict(d, Q_V2s, tau, reps)
                    if not np.all(np.isfinite(pred["U"])):
                        continue
                    met = evaluate(targets, list(d.names), pred["U"], d.values, d.problems)
                    for spec, (ok, worst, n) in met.items():
                        if spec in moved:
                            continue     # its U leaves out what the held parameter moves: no reachable U
                        if spec not in reach or worst < reach[spec][0]:
                            reach[spec] = (worst, n, hours)
                    if moved and all(m[0] for m in met.values()):
                        # met but for a requested effect the plan cannot estimate: not met (an outside probe:
                        # K3 held on 12 axis-aligned poses moved K by -7..-21 ppm against a "met" U of 5.8 ppm)
                        key = (round(hours * 3600.0), plan.name)
                        if blocked is None or key < blocked[0]:
                            blocked = (key, plan.name, hours, [mv for mv in moves if mv["significant"]])
                        continue
                    if all(m[0] for m in met.values()):
                        a = sum((t.in_unit(n, float(pred["U"][d.names.index(n)]), d.values) / t.limit) ** 2
                                for t in targets for n in t.parameters(d.names))
                        # a plan that estimates every requested effect before one that holds some
                        key = (bool(dropped), round(hours * 3600.0), a)
                        if best_key is None or key < best_key:
                            best_key = key
                            best = Choice(p, pred, targets, met, d.values, d.units, 0, d.problems,
                                          {h: {"effect": d.effect_of[h], "reason": r, "held_at": d.nominal[h],
                                               "moves": [mv for mv in moves if mv["held"] == h]}
                                           for h, r in dropped.items()}, design=d)
    if best is None and not searched and blind_skipped:
        name, blind = blind_skipped[0]
        raise InputError("--range: every schedule searched is blind to an effect the model leaves out ("
                         + "; ".join(f"{e}: {100 * f:.2g} % of its signature visible" for e, f in blind.items())
                         + f" on {name!r}): a fit would pass every gate on a unit that has it; add it to --effects")
    if best is None and not searched:
        raise InputError(f"--max-hours: no stepped plan over {lo:g}:{hi:g} degC fits within {hours_cap:g} chamber "
                         "hours (raise --max-hours)")
    if best is None and blocked is not None:
        refuse_held(blocked, targets, searched, hours_cap, preset)
    if best is None:
        never = [t for t in targets if t.spec in reach and not math.isfinite(reach[t.spec][0])]
        if never:
            why = "; ".join(f"{t.spec}: {n} is not estimated by any stepped plan ({r})"
                            for t in never for n, r in held_reason.get(t.spec, {}).items())
            raise InputError(f"--target cannot be met by a stepped plan: {why}")
        bad = [f"{spec}: best reachable U = {w:.3g} {t.unit} ({n}, in {h:.1f} h)"
               for t in targets if t.spec in reach for spec, (w, n, h) in [(t.spec, reach[t.spec])] if w > t.limit]
        why = "; ".join(bad) if bad else "each target alone is reachable, but no searched plan meets them all"
        raise InputError(f"--target cannot be met within {hours_cap:g} chamber hours by any of the {searched} "
                         f"plans searched: {why}")
    best.searched = searched
    return check_left_out(best, effects, lab, preset, Q_V2s)


def prediction_document(choice: Choice, *, Q_V2s: float, lab_source: Optional[str], preset: str,
                        effects: Sequence[str]) -> dict:
    """PRED.json (docs/plan.md)."""
    pred, names = choice.prediction, list(choice.prediction["names"])
    caveats = left_out_caveats(choice)
    params = {n: {"U": float(U), "u": float(u), "u_type_a": float(ua), "k": 2.0, "unit": choice.units[n]}
              for n, U, u, ua in zip(names, pred["U"], pred["u"], pred["u_a"])}
    target = {}
    for t in choice.targets:
        ok, worst, n = choice.met[t.spec]
        target[t.spec] = {"parameters": t.parameters(names), "limit": t.limit, "unit": t.unit,
                          "U_worst": worst, "worst_parameter": n, "met": bool(ok)}
        if t.spec in caveats:
            # met by the U of the planned model only: a left-out effect of the preset moves it by more than
            # HELD_NEGLIGIBLE of the target (assumptions.left_out_effects)
            target[t.spec]["met_if_unit_has_no"] = [e for e, _ in caveats[t.spec]]
    plan = choice.plan
    ramp = hasattr(plan, "program_C")
    if ramp:
        plan_summary = {"kind": "ramp", "name": plan.name, "program_C": list(plan.program_C),
                        "rate_C_per_min": plan.rate_C_per_min, "hold_s": plan.hold_s,
                        "n_positions": len(plan.positions), "tau_s": plan.tau_s, "n_visits": plan.n_visits}
    else:
        plan_summary = {"name": plan.name, "setpoints_C": list(plan.setpoints_C), "directions": plan.directions(),
                        "n_positions": len(plan.positions), "tau_s": plan.tau_s,
                        "repetitions": plan.repetitions, "n_visits": plan.n_visits}
    hours_rule = ("the ramp program's duration: sum |dT| / rate + holds" if ramp else
                  "per setpoint |dT| / chamber rate + settle_s, then per visit move_s + tau_s")
    return {"format": "triadcal.plan_prediction", "version": 1,
            "criterion": CRITERION, "chamber_hours": choice.plan.chamber_hours(),
            "plan": plan_summary,
            "parameters": params, "target": target, "candidates_searched": choice.searched,
            "assumptions": {"Q_V2s": Q_V2s, "lab": lab_source, "preset": preset, "effects": list(effects),
                            "not_estimated": choice.problems,
                            # requested effects the plan holds: what each moves among the targeted parameters
                            # at the preset's magnitude (each below HELD_NEGLIGIBLE of its target)
                            "held_effects": {h: {"effect": v["effect"], "held_at": v["held_at"], "reason": v["reason"],
                                                 "magnitude": v["moves"][0]["magnitude"] if v["moves"] else None,
                                                 "unit": v["moves"][0]["unit"] if v["moves"] else "",
                                                 "moves": {mv["parameter"]: {"bias": mv["bias"], "unit": mv["target_unit"]}
                                                           for mv in v["moves"]}}
                                             for h, v in choice.held.items()},
                            # effects of the preset unit not in --effects that move a targeted parameter on this
                            # plan by more than HELD_NEGLIGIBLE of its target (left_out_moves): the fit's model
                            # cannot represent them; add them to --effects if the unit has them
                            "left_out_effects": {e: {"preset_parameters": v["parameters"],
                                                     "moves": {mv["parameter"]: {"bias": mv["bias"], "unit": mv["unit"],
                                                                                 "target": mv["target"],
                                                                                 "fraction_of_target": mv["fraction"]}
                                                               for mv in v["moves"]},
                                                     "recommendation": f"add {e} to --effects"}
                                                 for e, v in choice.left_out.items()},
                            "left_out_negligible": list(choice.left_out_negligible),
                            "K_ppm": "K's U in ppm is relative: U(K) / K * 1e6, K the preset unit's value",
                            "hours": hours_rule}}
