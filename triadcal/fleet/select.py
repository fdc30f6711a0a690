"""One unit in one mechanical state out of a bench CSV that holds several (``--unit``/``--state``
of ``fit``, ``sample`` and ``diagnose``), and every (unit, state) pair of a campaign (``batch``)."""

from __future__ import annotations

from typing import Optional

import numpy as np

from ..errors import InputError


def pairs(campaign) -> list[tuple[str, str]]:
    """Every (unit, state) pair with at least one visit, sorted."""
    return sorted(set(zip(campaign.unit.tolist(), campaign.state.tolist())))


def pair_mask(campaign, unit: Optional[str], state: Optional[str]) -> np.ndarray:
    mask = np.ones(campaign.n_visits, bool)
    if unit:
        mask &= campaign.unit == unit
    if state:
        mask &= campaign.state == state
    return mask


def select_unit_state(campaign, unit: Optional[str] = None, state: Optional[str] = None, source=None):
    """The visits of ``unit`` in ``state`` (either may be None: no selection on it).

    A unit or state that is not in the file is refused with the units and states it holds; so is
    a selection that still holds several units or states ("choose one with --unit and --state")."""
    source = source or campaign.source or "campaign"
    units = campaign.units
    states = sorted(set(campaign.state.tolist()))
    if unit and unit not in units:
        raise InputError(f"{source}: no unit {unit!r}; its units are {', '.join(units)}")
    if state and state not in states:
        raise InputError(f"{source}: no state {state!r}; its states are {', '.join(states)}")
    mask = pair_mask(campaign, unit, state)
    if not mask.any():
        present = ", ".join(f"{u}/{s}" for u, s in pairs(campaign))
        raise InputError(f"{source} has no visit of unit {unit} in state {state}; its unit/state pairs are "
                         f"{present}")
    if not mask.all():
        campaign = campaign.select(np.flatnonzero(mask), own_origin=True)
    sel_units = campaign.units
    sel_states = sorted(set(campaign.state.tolist()))
    if len(sel_units) > 1 or len(sel_states) > 1:
        raise InputError(f"{source} holds units {', '.join(sel_units)} and states {', '.join(sel_states)}: "
                         "choose one with --unit SN and --state NAME (triadcal batch fits every one)")
    return campaign
