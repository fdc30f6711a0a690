"""One number parser for every boundary: finite, inside a stated range, or refused.

Accepted: an optional sign, ASCII digits, a decimal point and an exponent, as C's strtod
reads them, finite; not accepted: NaN, infinities, digit separators (``1_000``, which
Python's ``float`` takes), non-ASCII digits, hexadecimal, empty fields, a non-zero number that
underflows to 0 (``1e-400``).
A reader hands each field to :func:`parse_number` with the range its instrument allows
(docs/bench-csv.md and docs/raw.md list them); a value outside is refused with the file,
the line and the field, never clipped or dropped. ``1e300`` is not a reading.
"""

from __future__ import annotations

from ..errors import InputError

import math
from typing import Optional


class NumberError(InputError):
    """A field that is not a finite number inside its range. ``problem`` is the text without the place."""

    def __init__(self, problem: str):
        super().__init__(problem)
        self.problem = problem


#: the largest magnitude accepted from any instrument reading (output units): a 32-bit ADC
#: in counts is 2.1e9; anything beyond is a corrupted field, not a reading
MAX_READING = 1e10


def parse_number(text, *, low: float = -math.inf, high: float = math.inf, what: str = "value",
                 integer: bool = False, low_open: bool = False) -> float:
    """``text`` as a finite float (or int) within ``[low, high]`` (``(low, high]`` when
    ``low_open``); raise :class:`NumberError` saying what is wrong and what is accepted."""
    if isinstance(text, bool):
        raise NumberError(f"not a number: {text!r}")
    if isinstance(text, (int, float)):
        v = float(text)
        s = repr(text)
    else:
        s = str(text).strip()
        if s == "":
            raise NumberError("empty field")
        if "_" in s or not s.isascii():
            # Python's float() reads '1_000' and Arabic-Indic digits; no instrument writes them
            raise NumberError(f"not a number: {s!r}")
        try:
            v = float(s)
        except ValueError:
            raise NumberError(f"not a number: {s!r}") from None
    if not math.isfinite(v):
        raise NumberError(f"not a finite number: {s!r}")
    if v == 0.0 and any(c in "123456789" for c in s.lower().split("e")[0]):
        # 1e-400 reads as 0: a field written non-zero taken as zero (an outside probe's tolerance)
        raise NumberError(f"{s!r} underflows to 0 (below the smallest double, 5e-324)")
    if integer:
        if v != math.floor(v):
            raise NumberError(f"not an integer: {s!r}")
    if (v <= low if low_open else v < low) or v > high:
        lo = "(" if low_open else "["
        raise NumberError(f"{what} {s} outside the accepted range {lo}{low:g}, {high:g}]")
    return int(v) if integer else v


def optional_number(text, **kw) -> Optional[float]:
    """As :func:`parse_number`, but an empty field or None gives None."""
    if text is None or (isinstance(text, str) and text.strip() == ""):
        return None
    return parse_number(text, **kw)
