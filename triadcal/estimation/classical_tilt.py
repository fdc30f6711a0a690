"""The classical method's check of the bench tilt on a plan whose up/down groups are not half-turn
pairs (docs/classical.md, "Tilt on other plans").

Eq. 2's pairing cancels a bench tilt exactly when the two positions of a group are a half turn apart
about the vertical (docs/classical.md, "Tilt cancels exactly"). On other plans (the six faces of a
cube, reached by a two-axis bench) the tilt enters the angles and the biases with a factor up to 1
(``classical.tilt_sensitivity``; the per-block notes give it), and the method's uncertainty knows
nothing of it: a 6-face campaign on a bench tilted by 50 arcsec gave Ca_zx 91 u and S_x 88 u off the
truth with status ok (an outside probe).

The redundant positions can see the tilt: the per-setpoint linear model of each output,
``W_a = sum_b W_a^b g_b + bias`` (:func:`~triadcal.estimation.classical.residual_design`'s first
four columns), against the same model with the two first-order tilt columns ``e_a . (base e_x, e_y
in the IMU frame)``. The drop of the residual sum of squares over the blocks and outputs, with each
mean output divided by its standard uncertainty (the noise the method uses), is chi^2 with the
estimable tilt directions' count as dof when there is no tilt (a nested linear test; Seber & Lee
2003, ch. 4). Significant at the goodness-of-fit gate's level (p < ``gof_p_min``): the gate fails
with status ``model_mismatch`` and says to fit with ``--method joint``, which estimates the tilt.

On every plan the same tilt columns give the tilt's size (:func:`combined_tilt`), by which eq. 2's
K and S, divided by cos(tilt), are multiplied back (``fit_classical``; :func:`tilt_note`).
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
from scipy import stats

from .gates import DEFAULT_CONFIG, GateConfig, GateOutcome

#: a block whose largest leak factor (tilt -> an angle) is below this is a half-turn-pair block
LEAK_MIN = 1e-6


def tilt_leak_gate(campaign, blocks, sigma: np.ndarray, config: GateConfig = DEFAULT_CONFIG,
                   noise_dof: Optional[int] = None):
    """The gate ``tilt_leak`` (None when every block's groups are half-turn pairs: the tilt cancels).

    ``blocks``: dicts with ``idx`` (the block's visits) and ``leak`` (its largest leak factor);
    ``sigma``: (n, 3) standard uncertainty of each mean output (output unit); ``noise_dof``: the
    degrees of freedom of ``sigma`` when it was estimated from residuals (then the statistic over its
    dof is F(dof, noise_dof), not chi2/dof: with the 5 dof of a 6-face campaign at 5 setpoints the
    chi2 test rejected 37 % of tilt-free campaigns, the F test 10 % at the 10 % level), None when it
    is the data's own noise (``sd_*``)."""
    from .classical import residual_design

    leaky = [b for b in blocks if b["leak"] > LEAK_MIN]
    if not leaky:
        return None
    worst = max(b["leak"] for b in leaky)
    chi2, dof = 0.0, 0
    for b in leaky:
        idx = b["idx"]
        for a in range(3):
            s = sigma[idx, a]
            X = residual_design(campaign.axis1_deg[idx], campaign.axis2_deg[idx], np.eye(3)[a]) / s[:, None]
            y = campaign.w[idx, a] / s
            full, red = np.linalg.matrix_rank(X), np.linalg.matrix_rank(X[:, :4])
            if full <= red or len(idx) <= full:
                continue                   # no estimable tilt direction, or no redundancy left to test it
            r_full = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
            r_red = y - X[:, :4] @ np.linalg.lstsq(X[:, :4], y, rcond=None)[0]
            chi2 += float(r_red @ r_red - r_full @ r_full)
            dof += full - red
    what = (f"the up/down groups of {len(leaky)} of {len(blocks)} setpoint(s) are not half-turn pairs, so a bench "
            f"tilt enters the angles with a factor up to {worst:.3g}")
    if dof == 0:
        return GateOutcome("tilt_leak", None, "model_mismatch",
                           what + "; the plan cannot test for a tilt (no redundant position sees it): the angles "
                                  "hold whatever tilt the bench has")
    p = float(stats.chi2.sf(chi2, dof) if not noise_dof else stats.f.sf(chi2 / dof, dof, noise_dof))
    test = "chi2" if not noise_dof else f"F({dof}, {noise_dof}) = {chi2 / dof:.4g}, chi2"
    fails = p < config.gof_p_min
    reason = (what + f"; the redundant positions test for a tilt: {test} = {chi2:.4g} on {dof} dof, p = {p:.2g}"
              + (f" < {config.gof_p_min:g}: the bench is tilted, and the classical angles and biases carry it "
                 "(their u does not); fit with --method joint, which estimates the tilt" if fails else ""))
    return GateOutcome("tilt_leak", not fails, "model_mismatch", reason, p, f"p >= {config.gof_p_min:g}")


#: a bench tilt (arcsec) from which the correction of K and S by cos(tilt) is named in a note (at
#: 300" it is 1.1 ppm)
TILT_NOTE_ARCSEC = 300.0


def combined_tilt(tilts) -> Optional[np.ndarray]:
    """The block's tilt (rad, base x and y) from each axis's estimate and covariance, by inverse-
    covariance weighting; its squared norm less the trace of its covariance (the noise's share of
    |t|^2), so that cos(tilt) is not biased by the noise. None when no axis determines it."""
    try:
        W = [np.linalg.inv(C) for _, C in tilts]
        cov = np.linalg.inv(sum(W))
    except (np.linalg.LinAlgError, ValueError, TypeError):
        return None
    t = cov @ sum(w @ t for w, (t, _) in zip(W, tilts))
    if not np.all(np.isfinite(t)):
        return None
    norm2 = max(float(t @ t) - float(np.trace(cov)), 0.0)
    return t * math.sqrt(norm2 / float(t @ t)) if float(t @ t) > 0 else t


def tilt_note(tilts_arcsec) -> Optional[str]:
    """The note on the correction of K and S by cos(tilt) (eq. 2 divides them by it), when the
    blocks' tilts reach :data:`TILT_NOTE_ARCSEC`; None otherwise."""
    if not tilts_arcsec or max(tilts_arcsec) < TILT_NOTE_ARCSEC:
        return None
    worst = max(tilts_arcsec)
    return (f"bench tilt estimated from the redundant positions of each setpoint: up to {worst:.0f}\" "
            f"({np.median(tilts_arcsec):.0f}\" median); K and S were multiplied by cos(tilt) (up to "
            f"{(1.0 - math.cos(math.radians(worst / 3600.0))) * 1e6:.3g} ppm), which eq. 2 divides them by")
