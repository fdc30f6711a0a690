"""The hysteresis's form chosen by the data: a constant offset between the branches, or a play
(backlash) of half-width r on the temperature history (``triadcal fit --hysteresis-form``,
docs/model.md "Hysteresis forms").

The offset form puts every visit on a saturated branch (b = +-1 from the direction); the play
form computes each visit's branch from the history, ``b = (play(T, r) - T) / r``
(:func:`triadcal.models.effects.hysteresis.play_branch`), which is partial after a turn smaller
than 2r. ``r`` and the unknown state before the campaign (mid / heating / cooling) are found by
profiling the joint fit's chi^2 over a grid of r and the three starts (the rest of the model is
linear enough in its parameters for the fit to be re-solved at each grid point); the interval of
r is where chi^2 <= chi^2_min + 1 (68 %, one parameter). The play form is chosen over the offset
when the likelihood-ratio statistic ``chi2_offset - chi2_play`` exceeds the 99 % point of chi^2
with 2 degrees of freedom (r and the start), with a known output noise; with the noise
estimated from the residuals, when it lowers AIC by more than 10.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Optional, Sequence

import numpy as np
from scipy import stats

from ..errors import InputError
from ..models.campaign import Campaign
from ..models.effects.hysteresis import PLAY_STARTS, play_branch
from .joint import fit_joint

#: half-widths of the play searched (degC)
PLAY_GRID_C = (0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.5, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0)
FORMS = ("offset", "play", "auto")
#: likelihood-ratio threshold of the play over the offset (chi^2, 2 dof, 99 %)
LR_THRESHOLD = float(stats.chi2.ppf(0.99, 2))


def visit_temperature(campaign: Campaign) -> np.ndarray:
    """The temperature history the play acts on: the mean of the three sensors at each visit,
    in time order (the campaign's visits are sorted by time by the reader)."""
    return campaign.t.mean(axis=1)


def with_play(campaign: Campaign, half_width_C: float, start: str) -> Campaign:
    order = np.argsort(campaign.time_s, kind="stable")
    b = np.empty(campaign.n_visits)
    b[order] = play_branch(visit_temperature(campaign)[order], half_width_C, start)
    return replace(campaign, branch_values=b)


def fit_hysteresis_form(campaign: Campaign, effects: Sequence[str], form: str = "auto",
                        half_width_C: Optional[float] = None, **fit_kwargs):
    """Fit with the hysteresis form ``form`` (``offset``, ``play`` or ``auto``: chosen by the
    data, see the module); ``half_width_C`` fixes the play's r instead of profiling it.
    Returns ``(result, problem, solution, campaign)`` of the chosen form, the result's
    ``fit.hysteresis`` saying what was chosen and why."""
    if form not in FORMS:
        raise InputError(f"--hysteresis-form {form!r}: choose one of {', '.join(FORMS)}")
    if "hysteresis" not in effects:
        raise InputError("--hysteresis-form needs the hysteresis effect in --effects")
    if half_width_C is not None and (not np.isfinite(half_width_C) or half_width_C <= 0):
        raise InputError(f"the play's half-width must be > 0 degC, got {half_width_C}")
    fit_kwargs = dict(fit_kwargs, return_problem=True)
    off = fit_joint(campaign, effects, **fit_kwargs)
    chi2_off = float(np.sum(off[2].r ** 2))
    if form == "offset":
        off[0].fit["hysteresis"] = {"form": "offset", "criterion": "chosen by the user"}
        return off + (campaign,)
    grid = (half_width_C,) if half_width_C is not None else PLAY_GRID_C
    profile = []
    best = None
    for r in grid:
        for start in PLAY_STARTS:
            c = with_play(campaign, r, start)
            out = fit_joint(c, effects, **fit_kwargs)
            chi2 = float(np.sum(out[2].r ** 2))
            profile.append({"half_width_C": r, "start": start, "chi2": chi2})
            if best is None or chi2 < best[0]:
                best = (chi2, r, start, out, c)
    chi2_play, r, start, play_out, play_c = best
    known = bool(off[0].fit.get("noise_known"))
    n = off[2].r.size
    if known:
        stat = chi2_off - chi2_play
        prefer_play = stat > LR_THRESHOLD
        criterion = (f"likelihood ratio chi2_offset - chi2_play = {stat:.4g} against {LR_THRESHOLD:.3g} "
                     "(chi2 with 2 dof at 99 %: r and the start)")
    else:
        daic = n * np.log(chi2_off / n) - (n * np.log(chi2_play / n) + 4.0)
        prefer_play = daic > 10.0
        criterion = f"AIC of the offset minus AIC of the play = {daic:.4g} (play when > 10; noise estimated)"
    # 68 % interval of r from the profile (best start at each r)
    by_r = {}
    for p in profile:
        by_r[p["half_width_C"]] = min(by_r.get(p["half_width_C"], np.inf), p["chi2"])
    inside = [rr for rr, c2 in by_r.items() if c2 <= chi2_play + 1.0]
    interval = [min(inside), max(inside)] if inside else None
    edge = r in (grid[0], grid[-1]) and half_width_C is None
    block = {"form": "play" if (form == "play" or prefer_play) else "offset", "criterion": criterion,
             "chi2_offset": chi2_off, "chi2_play": chi2_play, "half_width_C": r, "start": start,
             "half_width_interval_C": interval, "at_grid_edge": edge,
             "profile": sorted(({"half_width_C": k, "chi2": v} for k, v in by_r.items()), key=lambda x: x["half_width_C"])}
    if form == "auto" and not prefer_play:
        off[0].fit["hysteresis"] = dict(block, form="offset")
        off[0].notes.append(f"hysteresis form: the constant offset; a play does not fit better ({criterion})")
        return off + (campaign,)
    res = play_out[0]
    res.fit["hysteresis"] = block
    why = "chosen by the user" if form == "play" else criterion
    res.notes.append(f"hysteresis form: a play of half-width r = {r:g} degC (68 % interval "
                     f"{interval[0]:g}..{interval[1]:g} degC on the searched grid) from the {start} state; "
                     f"Ca_ab_hysteresis is the half-width of the saturated loop ({why})"
                     + ("; r lies at the edge of the searched grid" if edge else ""))
    return play_out + (play_c,)
