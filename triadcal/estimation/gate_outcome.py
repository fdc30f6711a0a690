"""One answer gate's outcome, and the readers of a parameter (a ParameterValue or its JSON mapping)
the gates share: gates.py and term_gates.py (which gates.py re-exports) import them from here."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np


@dataclass
class GateOutcome:
    """One gate: ``passed`` True, False, or None (skipped, with the reason)."""

    gate: str
    passed: Optional[bool]
    status: str
    reason: str
    value: Optional[float] = None
    threshold: Optional[str] = None

    def to_dict(self) -> dict:
        v = self.value
        return {"gate": self.gate, "passed": self.passed, "status": self.status, "reason": self.reason,
                "value": None if v is None or not math.isfinite(v) else float(v), "threshold": self.threshold}


def _value(p):
    v = getattr(p, "value", None) if not isinstance(p, Mapping) else p.get("value")
    return float(v) if isinstance(v, (int, float, np.floating)) and not isinstance(v, bool) else None


def _u(p):
    u = getattr(p, "u", None) if not isinstance(p, Mapping) else p.get("u")
    return float(u) if isinstance(u, (int, float, np.floating)) and not isinstance(u, bool) else None


def _unit(p):
    return getattr(p, "unit", None) if not isinstance(p, Mapping) else p.get("unit")
