"""The diagnosis candidate ``quantisation`` (issue 18 item 2; docs/diagnosis.md "quantisation").

A digital output rounded to an LSB q leaves in every visit mean the expected error
``e(W; q, sigma)`` of :mod:`triadcal.models.effects.quantisation` (periodic in W, period q,
damped by the per-sample noise sigma). Its derivative at q = 0 vanishes, so a score test at the
fitted point has no power: like the refit-only form candidates (``FORM_CANDIDATES``) q is
profiled -- over the log grid of :func:`triadcal.estimation.quantisation_form.q_grid` plus the
LSB the campaign states or its visit means imply -- by one Gauss-Newton step of the fitted model
at each q, the best grid point refined between its neighbours on the scale q^2/max|W|
(:func:`~triadcal.estimation.quantisation_form.refine_q`), the best q refitted in full on the diagnosis's compiled full problem (the term applied
as its output map), and the candidate is named only when it beats the model without it by the
nested likelihood ratio at 99 % with q counted (chi^2 with 1 dof: 6.63; AIC with the noise
estimated).
"""

from __future__ import annotations

import copy

import numpy as np
from scipy import stats

from ...estimation import quantisation_form as qf
from .fitting import FitState, _fit

NAME = "quantisation"
#: the one-step chi^2 gain of the coarse profile from which q is refined and refitted (no LSB stated):
#: half the 99 % point of chi^2 with 1 dof, the criterion a refit must pass
PRESCREEN_GAIN = 0.5 * float(stats.chi2.ppf(0.99, 1))


def quantisation_candidates(campaign, full, model, names, base: FitState, noise_known: bool):
    """``[Candidate('quantisation')]`` with its prepared refit (``form``), or untestable with the
    reason: no per-sample noise in the data."""
    from .candidates import _untestable
    from .results import Candidate

    s0, why = qf.sample_sigma_of(campaign, 0.0)
    if s0 is None:
        return _untestable([NAME], why)
    q_stated, why_stated = qf.stated_lsb(campaign)
    grid = qf.q_grid(campaign, [q_stated] if q_stated else [])
    cols = np.array([full.index[n] for n in names], int)
    # the coarse profile with Sheppard's sigma (a ranking; the refit below uses the exact sigma of its
    # q); with no LSB stated or implied and no q lowering the one-step chi^2 by half the criterion's
    # threshold, there is nothing to refine or refit
    chi2 = qf.profile_chi2(full, base.x_full, cols, campaign, grid, sigma=qf.sheppard_sigma(campaign))
    gain = float(base.chi2 - np.min(chi2)) if np.isfinite(np.min(chi2)) else 0.0
    if not q_stated and gain < PRESCREEN_GAIN:
        return [Candidate(NAME, False, (
            f"no LSB stated or implied by the data's resolution, and no q of the profile ({len(grid)} points, "
            f"{grid.min():.3g}-{grid.max():.3g} {campaign.output_unit}) lowers the chi^2 by more than {gain:.3g} in "
            f"one step (refined and refitted from {PRESCREEN_GAIN:.3g}, half the 99 % point of chi^2(1))"),
            refit_only=True)]
    tries = [qf.refine_q(full, base.x_full, cols, campaign, grid, chi2)[0]]
    if q_stated and q_stated not in tries:
        tries.append(float(q_stated))
    best = None
    for q in tries:
        s, _ = qf.sample_sigma_of(campaign, q)
        prob = copy.copy(full)
        prob.output_map = qf.output_map(q, s)
        st = _fit(prob, names, base.x_full, noise_known)
        if best is None or st.chi2 < best[1].chi2:
            best = (q, st, s)
    q, st, s = best
    ok, crit = qf.criterion(base.chi2, st.chi2, st.r.size, noise_known)
    unit = campaign.output_unit
    # the 68 % interval of q on the grid: where the one-step chi^2 is within 1 of its minimum
    inside = grid[chi2 <= np.min(chi2) + 1.0]
    st.extra_params = {"quantisation_lsb": {"value": q, "unit": unit}}
    from ...models.effects import EFFECTS

    effects_opt = ",".join(e for e in EFFECTS if e in model)
    c = Candidate(NAME, True, k=1, refit_only=True, params=[])
    c.form = {"state": st, "profiled": ["quantisation_lsb"], "simpler": "the model without quantisation",
              "chi2_simpler": base.chi2, "nested_passes": ok, "criterion": crit,
              "details": {"lsb": q, "lsb_unit": unit,
                          "lsb_grid_interval": [float(inside.min()), float(inside.max())] if inside.size else None,
                          "sigma_sample": [float(v) for v in np.broadcast_to(s, (3,))],
                          "sigma_source": why, "stated_lsb": q_stated, "stated_lsb_source": why_stated or None,
                          "grid_points": int(len(grid))},
              "fit_options": f"--effects {effects_opt + ',' if effects_opt else ''}quantisation "
                             f"--quantisation-lsb {q:.9g}"}
    return [c]
