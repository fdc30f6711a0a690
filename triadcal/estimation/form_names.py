"""The names of the refit-only forms as ``fit --effects`` and ``sample --effects`` accept them.

The diagnosis can answer ``hysteresis_play``, ``hysteresis_pi`` and ``thermal_lag_history``
(docs/diagnosis.md, "Form candidates"). They are not effects of the joint model but forms of two of
its effects, fitted in ``estimation/``: the angles' hysteresis with its branch from a play (or a
Prandtl-Ishlinskii sum of plays) on the temperature history (:mod:`.hysteresis_form`), and the
thermal lag with the element's temperature from the record passed through one or two first-order
stages (:mod:`.thermal_lag_form`). Issue 18 asks that every name the diagnosis answers be one
command away in ``fit`` and ``sample``; :func:`resolve_form_names` turns each name into its
effect and the form option, so ``--effects ...,hysteresis_play`` is ``--effects ...,hysteresis
--hysteresis-form play`` and ``--effects ...,thermal_lag_history`` is ``--thermal-lag-form
history`` (the thermometer's location chosen by the data).
"""

from __future__ import annotations

from typing import Sequence

from ..errors import InputError

#: form name -> (the effect it is a form of, the option, the option's value)
FORM_NAMES = {
    "hysteresis_play": ("hysteresis", "hysteresis_form", "play"),
    "hysteresis_pi": ("hysteresis", "hysteresis_form", "pi"),
    "thermal_lag_history": ("thermal_lag", "thermal_lag_form", "history"),
}
#: the option values a form name agrees with (the defaults, and the name's own value)
_AGREES = {"hysteresis_form": ("offset",), "thermal_lag_form": ("rate",)}
#: thermal-lag forms that already are a history form (a location given explicitly)
_HISTORY_FORMS = ("housing", "air", "history")


def resolve_form_names(effects: Sequence[str], hysteresis_form: str = "offset",
                       thermal_lag_form: str = "rate") -> tuple:
    """``(effects, hysteresis_form, thermal_lag_form)`` with every form name of ``effects`` replaced
    by its effect and its option set. A form name and an option that disagree (``hysteresis_play``
    with ``--hysteresis-form pi``, both ``hysteresis_play`` and ``hysteresis_pi``) are refused;
    ``thermal_lag_history`` keeps an explicit location (``--thermal-lag-form housing`` or ``air``)."""
    effects = list(effects)
    options = {"hysteresis_form": hysteresis_form, "thermal_lag_form": thermal_lag_form}
    named = [e for e in effects if e in FORM_NAMES]
    for opt in options:
        mine = [e for e in named if FORM_NAMES[e][1] == opt]
        if len(mine) > 1:
            raise InputError(f"--effects names {' and '.join(mine)}: two forms of one effect; name one")
        if not mine:
            continue
        name = mine[0]
        value = FORM_NAMES[name][2]
        given = options[opt]
        if opt == "thermal_lag_form" and given in _HISTORY_FORMS:
            continue                     # the location given explicitly, or history already
        if given not in _AGREES[opt] + (value,):
            flag = "--" + opt.replace("_", "-")
            raise InputError(f"--effects {name} is {flag} {value}, but {flag} {given} was given; drop one")
        options[opt] = value
    out = []
    for e in effects:
        e = FORM_NAMES[e][0] if e in FORM_NAMES else e
        if e not in out:
            out.append(e)
    return out, options["hysteresis_form"], options["thermal_lag_form"]


def held_form(campaign, effects: Sequence[str], hysteresis_form: str, thermal_lag_form: str, **fit_kwargs):
    """A form (``hysteresis_play``, ``hysteresis_pi``, ``thermal_lag_history``) held at its
    least-squares profile, for ``sample`` and for ``diagnose --model``: the least-squares fit of the
    form profiles its nonlinear parameters (the play's half-width and start state, the PI's widths
    and weight, the lag's time constants and the thermometer's location), and the campaign is
    returned with the form's branch (or the element's temperatures) in place, so that the model's
    linear terms act through it (a plug-in, like the flicker floor and the quantisation LSB).
    Returns ``(campaign, effects, form_result, block_key, held)``: the effects to use (the lag's own
    term dropped: the element's temperature carries it), the form's least-squares result (its
    status says whether the form is an answer), the key of its block in ``result.fit`` and what is
    held, in words."""
    from ..models.effects import EFFECTS

    if hysteresis_form != "offset" and thermal_lag_form != "rate":
        raise InputError("a hysteresis form and the lag's history form are not held together (as in fit); name "
                         "one of them")
    mean = [e for e in effects if e in EFFECTS]
    if thermal_lag_form != "rate":
        from .thermal_lag_form import fit_thermal_lag_history, with_element_temperature

        ls = fit_thermal_lag_history(campaign, mean, **fit_kwargs)
        blk = ls.fit["thermal_lag"]
        tb = blk["bridge"]["tau_min"] if blk.get("bridge") else None
        campaign = with_element_temperature(campaign, blk["tau_min"], blk["location"],
                                            blk["tau_housing_min"] or 0.0, tb)
        taus = f"tau = {blk['tau_min']:.4g} min" + (f", tau_housing = {blk['tau_housing_min']:.4g} min"
                                                     if blk["tau_housing_min"] else "")
        held = (f"thermal_lag_history: the thermal terms at the element's temperature, the thermometer in the "
                f"{blk['location']} ({taus}" + (f", the record's gaps bridged by {tb:.3g} min" if tb else "")
                + ") held at the least-squares profile's values")
        return campaign, [e for e in effects if e != "thermal_lag"], ls, "thermal_lag", held
    from .hysteresis_form import fit_hysteresis_form

    ls, _, _, campaign = fit_hysteresis_form(campaign, mean, hysteresis_form, None, **fit_kwargs)
    blk = ls.fit["hysteresis"]
    if hysteresis_form == "play":
        what = f"a play of half-width r = {blk['half_width_C']:g} degC from the {blk['start']} state"
    else:
        what = (f"a Prandtl-Ishlinskii sum of plays of half-widths {blk['pi_half_widths_C'][0]:g} and "
                f"{blk['pi_half_widths_C'][1]:g} degC, weights {blk['pi_weights'][0]:g} and {blk['pi_weights'][1]:g}")
    held = f"hysteresis_{hysteresis_form}: the branch of each visit from {what}, held at the least-squares profile's values"
    return campaign, effects, ls, "hysteresis", held
