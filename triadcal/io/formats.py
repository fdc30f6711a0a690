"""The one check every versioned JSON document of triadcal gets when it is read."""

from __future__ import annotations

from ..errors import InputError

from typing import Mapping


def require_format(d: Mapping, fmt: str, version: int, source: str, what: str, short: str) -> None:
    """Refuse ``d`` unless it is ``fmt`` at ``version``: e.g. ``what`` "a comparison", ``short``
    "comparison" give "SOURCE: not a comparison (format ..., expected ...)" and
    "SOURCE: comparison version ... is not known to this triadcal (it reads version N)". A
    boolean ``version`` is refused (``true == 1`` in Python; JSON tells them apart)."""
    if not isinstance(d, Mapping):
        raise InputError(f"{source}: not {what} (a JSON {type(d).__name__}, expected an object with "
                         f"format {fmt!r})")
    if d.get("format") != fmt:
        raise InputError(f"{source}: not {what} (format {d.get('format')!r}, expected {fmt!r})")
    v = d.get("version")
    if isinstance(v, bool) or v != version:      # true == 1 in Python, not in JSON
        raise InputError(f"{source}: {short} version {d.get('version')!r} is not known to this "
                         f"triadcal (it reads version {version})")
