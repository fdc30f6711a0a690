"""Calendar dates at the boundaries: ISO 8601 only (a bench CSV's ``# date``, a result's
``data_date``, the history's ``--date``). ``05.01.2025`` reads as 5 January in Europe and 1 May in
the United States, and a history ordered by such text put 20.03.2024 after 12.02.2026 (an outside
probe: the oldest calibration compared as the latest, a drift reversed without a word)."""

from __future__ import annotations

import datetime as _dt
from typing import Optional


def iso_date(text) -> Optional[str]:
    """``YYYY-MM-DD`` of an ISO 8601 date or date-time (``2026-03-01``, ``2026-03-01T10:00:00Z``,
    ``20260301``), None for anything else (a day-first or month-first date, a free text)."""
    s = str(text).strip()
    if len(s) < 8 or not s[:4].isdigit():
        return None
    try:
        return _dt.datetime.fromisoformat(s.replace("Z", "+00:00")).date().isoformat()
    except ValueError:
        try:
            return _dt.date.fromisoformat(s).isoformat()
        except ValueError:
            return None


ISO_HINT = ("an ISO 8601 date (YYYY-MM-DD): day-first and month-first dates read differently in different "
            "countries, and calibrations are ordered by it")


#: a date this many days after today (the machine's clock, UTC) is refused: time zones and a clock a
#: day off are no reason to refuse a calibration of today
FUTURE_SLACK_DAYS = 1


def future_problem(iso: str, what: str) -> Optional[str]:
    """Why the ISO date ``iso`` cannot be ``what`` (a calibration, a measurement): it lies after today
    by more than :data:`FUTURE_SLACK_DAYS` (an outside probe's ``# date = 2099-01-01`` was fitted
    with status ok and certified as "Date of calibration 2099-01-01, date of issue 2026-12-01"),
    or None."""
    today = _dt.datetime.now(_dt.timezone.utc).date()
    day = _dt.date.fromisoformat(iso)
    if (day - today).days > FUTURE_SLACK_DAYS:
        return f"{iso} is after today ({today.isoformat()}): {what} cannot have happened yet"
    return None
