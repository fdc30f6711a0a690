"""Helpers shared by the subcommands (parsing of lists and name=value pairs)."""

from __future__ import annotations

from ..errors import InputError


def name_list(text: str) -> list[str]:
    """'a,b, c' -> ['a', 'b', 'c'] (empty entries dropped; 'none' -> [])."""
    if text.strip().lower() == "none":
        return []
    return [s.strip() for s in text.split(",") if s.strip()]


def float_list(text: str) -> list[float]:
    try:
        return [float(s) for s in name_list(text)]
    except ValueError:
        raise InputError(f"expected comma-separated numbers, got {text!r}") from None


def assignments(items) -> dict[str, float]:
    """['Ca_xy=40', 'K_x_tempco=12'] -> {'Ca_xy': 40.0, 'K_x_tempco': 12.0}."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise InputError(f"expected NAME=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = float(v)
        except ValueError:
            raise InputError(f"{k.strip()}: not a number: {v!r}") from None
    return out
