"""Warm-up after power-on: the bias (and the scale factor) settle as the unit heats itself.

When an accelerometer is powered, its electronics and the element warm by their own
dissipation (self-heating); the bias and the scale factor move with that internal gradient,
which the temperature sensors beside the element do not see in full, and settle with a
thermal time constant of a few minutes (IEEE Std 1293-2018, turn-on characteristics and
warm-up; MEMS vendors quote a bias warm-up of 1-5 mg settling in 2-10 min). Per axis::

    b_a(t) = b_inf,a + db_a exp(-(t - t_on) / tau_w)          (bias_warmup)
    K_a(t) = K_inf,a (1 + dk_a exp(-(t - t_on) / tau_k))       (scale_warmup)

``b_inf = S_a`` (with its tempco and drift terms) is the settled bias, ``db_a`` (ug) the
warm-up offset at power-on ``t_on``, one time constant ``tau_w`` (min) for the unit.
``t`` is the campaign's elapsed time ``Campaign.elapsed_s`` and ``t_on`` its zero,
``Campaign.time_origin_s`` (:func:`power_on_time`): the ``power_on_s`` metadata line (the
simulator writes 0, its clock starting at power-on), else the start of the first visit.
:func:`offset_at` converts ``db`` between two origins: the exponential has no other memory,
so a different ``t_on`` only rescales ``db`` by ``exp(dt_on / tau_w)``. Before ``t_on``
the term is held at ``db`` (the unit was not yet on: a visit before power-on is an error of
the file, not physics).

The time constants are positive by their physics; the hook uses ``|tau|`` so that the sign
carries no information and the answer gate (``estimation.gates``, time constants outside
[0.5, 300] min) refuses a value that is not a time constant.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from .. import ops
from ..parameters import ParameterSpec, per_axis
from ..sensor import AXES
from .base import Effect


def _exp(x):
    return ca.exp(x) if ops.is_symbolic(x) else np.exp(x)


def warmup_decay(t_s, tau_s, t_on_s=0.0):
    """``exp(-max(t - t_on, 0) / |tau|)``: the fraction of the warm-up offset left at ``t``."""
    x = t_s - t_on_s
    return _exp(-0.5 * (x + ops.fabs(x)) / ops.fabs(tau_s))


def warming_bias(S, offset, tau_s, t_s, t_on_s=0.0):
    """``S + db exp(-(t - t_on)/tau)`` (bias_warmup)."""
    return S + offset * warmup_decay(t_s, tau_s, t_on_s)


def warming_scale(K, offset_rel, tau_s, t_s, t_on_s=0.0):
    """``K (1 + dk exp(-(t - t_on)/tau))`` (scale_warmup, ``dk`` relative)."""
    return K * (1.0 + offset_rel * warmup_decay(t_s, tau_s, t_on_s))


def power_on_time(campaign) -> float:
    """The campaign's power-on time on its own clock (s): the ``power_on_s`` metadata line, else
    the time of the first visit's window start (the unit is taken to be switched on as the
    campaign starts)."""
    return campaign.time_origin_s


def offset_at(offset, tau_min: float, from_t_on_s: float, to_t_on_s: float):
    """The warm-up offset referred to another origin: ``db(t_on') = db(t_on) exp(-(t_on' - t_on)/tau)``."""
    return offset * math.exp(-(to_t_on_s - from_t_on_s) / (60.0 * abs(tau_min)))


class BiasWarmup(Effect):
    name = "bias_warmup"
    description = "warm-up of each bias after power-on, db exp(-t/tau_w) (ug; one tau_w per unit, min)"

    def parameters(self):
        return per_axis("S_{a}_warmup", "ug", 2000.0, "warm-up offset of S_{ax} at power-on", self.name) + (
            ParameterSpec("S_warmup_tau", "min", 5.0, "time constant of the bias warm-up after power-on",
                          self.name, nominal=5.0),)

    def bias(self, p, cov, dT, S):
        tau = p["S_warmup_tau"]
        return tuple(warming_bias(S[i], p[f"S_{a}_warmup"], tau, cov.time_s) for i, a in enumerate(AXES))


class ScaleWarmup(Effect):
    name = "scale_warmup"
    description = "warm-up of each scale factor after power-on, K (1 + dk exp(-t/tau_k)) (ppm; one tau_k, min)"

    def parameters(self):
        return per_axis("K_{a}_warmup", "ppm", 200.0, "warm-up offset of K_{ax} at power-on (relative)",
                        self.name) + (
            ParameterSpec("K_warmup_tau", "min", 5.0, "time constant of the scale-factor warm-up after power-on",
                          self.name, nominal=5.0),)

    def scale(self, p, cov, dT, K):
        tau = p["K_warmup_tau"]
        return tuple(warming_scale(K[i], p[f"K_{a}_warmup"], tau, cov.time_s) for i, a in enumerate(AXES))
