"""Checks of a campaign's design before a fit: what its poses can determine at all."""

from __future__ import annotations

from ..errors import IdentifiabilityError
from ..models.campaign import AXIS_GRAVITY_SPAN_MIN_G, Campaign, axes_not_turned as not_turned
from ..models.sensor import AXES


def axes_not_turned(campaign: Campaign) -> None:
    """Refuse (:class:`IdentifiabilityError`, one line) a campaign whose poses do not turn an IMU axis
    through gravity (:func:`triadcal.models.campaign.axes_not_turned`): with g_a nearly constant,
    ``W_a = (g_a + S_a) / K_a`` cannot tell K_a from S_a. An outside probe's plan P01-P08 (z never up or
    down) was refused by the reader as "w_z in another unit" and, past it, the fit stopped after one
    iteration with chi2/dof 2e5, naming Ca_xz and Ca_yz."""
    bad = not_turned(campaign.axis1_deg, campaign.axis2_deg)
    if bad:
        a = [AXES[i] for i, _, _ in bad]
        raise IdentifiabilityError(
            f"{campaign.source or 'campaign'}: the poses never turn the IMU's "
            + ", ".join(f"{AXES[i]} (nominal g_{AXES[i]} {lo:+.2f} .. {hi:+.2f} g)" for i, lo, hi in bad)
            + f" through gravity (a span of at least {AXIS_GRAVITY_SPAN_MIN_G:g} g is needed): "
            + ", ".join(f"K_{x}" for x in a) + " cannot be told from " + ", ".join(f"S_{x}" for x in a)
            + "; add poses with each axis up and down (the 12-position plan of docs/bench-csv.md)")
