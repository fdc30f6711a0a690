"""Bias drift in time: ``S(t) = S + d t`` with ``t`` the time since the start of the campaign (ug/h)."""

from __future__ import annotations

from ..parameters import per_axis
from .base import Effect


def drifting(value, rate, t):
    """``value + rate t``."""
    return value + rate * t


class BiasDrift(Effect):
    name = "bias_drift"
    description = "linear drift of each bias with time since the start of the campaign (ug/h)"

    def parameters(self):
        return per_axis("S_{a}_drift", "ug/h", 5.0, "drift rate of S_{ax}", self.name)

    def bias(self, p, cov, dT, S):
        return tuple(drifting(S[i], p[f"S_{a}_drift"], cov.time_s) for i, a in enumerate("xyz"))
