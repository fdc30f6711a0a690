"""The effects a campaign was planned for (docs/plan.md, "From the plan to the fit").

`triadcal plan` predicts U for a model (its ``--effects``) and writes them into the plan
(``predicted.effects``); ``simulate --plan`` and ``capture --ramp PLAN.json`` carry them into the bench
CSV's header as ``# planned_effects``. A fit without ``--effects`` fits those; a fit with other effects
says which of the plan's it leaves out or adds, since the plan's predicted U holds for its own model.

An outside probe (2026-12-02): a plan made with ``--effects ...,scale_cubic`` (K3 planned), fitted
with the default effects (no K3): status ok in 7 of 14 seeds with K 7-11 ppm low, z -7 to -11; and a
plan made without ``hysteresis`` fitted with it (the default): U(Ca_tempco) 0.075 arcsec/degC
against the 0.039 predicted and a target of 0.05 "met", with no word.
"""

from __future__ import annotations

from typing import Optional, Sequence

from ..errors import InputError
from ..models.effects import DEFAULT_EFFECTS, EFFECTS, NOISE_EFFECTS

#: the bench CSV header key
KEY = "planned_effects"


def known_effect_names() -> set:
    """Every name ``fit --effects`` takes: the model's effects, the noise effects, quantisation and
    the diagnosis's forms."""
    from .form_names import FORM_NAMES

    return set(EFFECTS) | set(NOISE_EFFECTS) | {"quantisation"} | set(FORM_NAMES)


def check_effect_names(names, where: str) -> tuple:
    """``names`` (a list of texts) as a tuple, each a name ``fit --effects`` takes, else refused naming
    ``where``."""
    if not isinstance(names, (list, tuple)) or not all(isinstance(n, str) and n for n in names):
        raise InputError(f"{where}: expected a list of effect names, got {names!r}")
    known = known_effect_names()
    bad = [n for n in names if n not in known]
    if bad:
        raise InputError(f"{where}: {bad[0]!r} is not an effect triadcal fits (known: {', '.join(sorted(known))})")
    return tuple(names)


def planned(campaign) -> Optional[tuple]:
    """The data's ``# planned_effects`` (checked), or None."""
    text = (campaign.metadata or {}).get(KEY)
    if text is None:
        return None
    names = [s.strip() for s in str(text).split(",") if s.strip()]
    if str(text).strip().lower() == "none":
        names = []
    return check_effect_names(names, f"{campaign.source or 'campaign'}: metadata # {KEY}")


def resolve(effects: Optional[Sequence[str]], campaign, method: str = "joint") -> tuple:
    """``(effects, note)``: ``effects`` when given, else the data's planned effects, else
    :data:`DEFAULT_EFFECTS`; ``note`` says where they came from or how they differ from the plan's
    (None when there is nothing to say)."""
    plan = planned(campaign)
    if plan is None:
        return list(DEFAULT_EFFECTS) if effects is None else list(effects), None
    given = effects is not None
    if method != "joint":
        # the classical method fits no effects of the joint model: the plan's are not its (they made it
        # refuse "--effects ... would be ignored" on a planned file that no --effects was given for)
        return (list(effects) if given else list(DEFAULT_EFFECTS)), (f"the data were planned for a joint fit with the effects {', '.join(plan) or 'none'} "
                         f"(# {KEY}); the plan's predicted U holds for that fit, not for the {method} method")
    effects = list(effects) if given else list(plan)
    left, added = [e for e in plan if e not in effects], [e for e in effects if e not in plan]
    if not given:
        return effects, (f"effects from the plan these data follow (# {KEY}): {', '.join(plan) or 'none'}; the "
                         "plan's predicted U holds for them")
    if not left and not added:
        return effects, None
    return effects, (f"the plan these data follow was made for the effects {', '.join(plan) or 'none'} (# {KEY}); "
                     "this fit's differ (" + "; ".join(
                         ([f"left out: {', '.join(left)}"] if left else []) + ([f"added: {', '.join(added)}"] if added
                                                                               else []))
                     + "): the plan's predicted U holds for its own effects"
                     + (", and a planned effect left out biases what it moves where the unit has it" if left else ""))
