"""The hysteresis's form chosen by the data: a constant offset between the branches, a play
(backlash) of half-width r on the temperature history, or a Prandtl-Ishlinskii (PI) sum of two
plays (``triadcal fit --hysteresis-form offset|play|pi|auto``, docs/model.md "Hysteresis forms").

The offset form puts every visit on a saturated branch (b = +-1 from the direction); the play
form computes each visit's branch from the history, ``b = (play(T, r) - T) / r``
(:func:`triadcal.models.effects.hysteresis.play_branch`), which is partial after a turn smaller
than 2r; the PI form ``b = (1 - w) b(r1) + w b(r2)`` (:func:`~triadcal.models.effects.hysteresis.pi_branch`,
two plays of half-widths r1 < r2 from the grid, weight 0 < w < 1). ``Ca_ab_hysteresis`` is the
saturated loop's half-width in every form.

**Search.** r (or r1, r2, w) and the unknown state before the campaign (mid / heating / cooling,
common to the plays) are profiled. The model is linear in ``h`` and nearly linear in the other
parameters, so the profile is computed by one Gauss-Newton step from the offset form's optimum:
the hysteresis columns of the Jacobian at unit branch, times each candidate's branch, projected
off the other parameters' columns (exact for a linear model; the chosen candidate is then refitted
with the full nonlinear fit, whose chi^2 enters the criterion). The play's r is searched on
``PLAY_GRID_C`` and then refined between the grid points around the best (``_refine_play``: a scan
and Brent's method; the PI's widths stay on the grid). The interval of r is where the profile's
chi^2 <= chi^2_min + 1 (68 %, one parameter).

**Criterion (nested likelihood ratios, 99 % each).** offset ⊂ play ⊂ pi: the offset is the
play's r -> 0 limit, the play is the PI with w = 0 (or 1). With a known output noise the play is
chosen over the offset when ``chi2_offset - chi2_play`` exceeds the 99 % point of chi^2 with 2
degrees of freedom (r and the start); the PI over the play when ``chi2_play - chi2_pi`` exceeds
the same point (its second width and the weight: 2 dof), or over the offset, when the play was
not chosen, when ``chi2_offset - chi2_pi`` exceeds the 99 % point with 4 dof. (r and the start
are not identified under the smaller model, so the nominal 1 % is approximate — the maximum over
the grid exceeds it; ``tests/test_thermal_forms_statistics.py`` measures the rate.) With the
noise estimated from the residuals, a larger form is chosen when it lowers AIC by more than 10.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Optional, Sequence

import numpy as np
from scipy import stats

from ..errors import InputError
from ..models.campaign import Campaign
from ..models.effects.hysteresis import PLAY_STARTS, pi_branch, play_branch
from .joint import JointProblem, fit_joint

#: half-widths of the play searched (degC); the PI's two plays are pairs of them
PLAY_GRID_C = (0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.5, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0)
#: weights of the wider of the PI's two plays searched
PI_WEIGHTS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
FORMS = ("offset", "play", "pi", "auto")
LEVEL = 0.99
#: likelihood-ratio threshold of the play over the offset, and of the PI over the play (chi^2, 2 dof, 99 %)
LR_THRESHOLD = float(stats.chi2.ppf(LEVEL, 2))
#: ... of the PI over the offset (chi^2, 4 dof, 99 %)
LR_THRESHOLD_PI_OFFSET = float(stats.chi2.ppf(LEVEL, 4))
#: AIC margin of a larger form with the noise estimated
AIC_MARGIN = 10.0


def nested_criterion(chi2_small: float, chi2_big: float, k: int, n_obs: int, noise_known: bool, what: str,
                     level: float = LEVEL, aic_margin: float = AIC_MARGIN) -> tuple:
    """The larger of two nested models over the smaller: with known noise the likelihood ratio
    ``chi2_small - chi2_big`` against the ``level`` point of chi^2 with ``k`` dof; with the noise
    estimated, the AIC lower by more than ``aic_margin``. Returns ``(passes, text)``, the text naming
    the statistic ``what``. Used by every refit-only form (play, PI, lag history, quantisation)."""
    if noise_known:
        thr = float(stats.chi2.ppf(level, k))
        stat = chi2_small - chi2_big
        return bool(stat > thr), (f"{what} = {stat:.4g} against {thr:.3g} (chi2 with {k} dof at "
                                  f"{100 * level:g} %)")
    daic = n_obs * math.log(chi2_small / n_obs) - (n_obs * math.log(max(chi2_big, 1e-300) / n_obs) + 2.0 * k)
    return bool(daic > aic_margin), f"AIC falls by {daic:.4g} ({what}; named when > {aic_margin:g}, noise estimated)"


def visit_temperature(campaign: Campaign) -> np.ndarray:
    """The temperature history the play acts on: the mean of the three sensors at each visit,
    in time order (the campaign's visits are sorted by time by the reader)."""
    return campaign.t.mean(axis=1)


def _with_branch(campaign: Campaign, branch_of_history) -> Campaign:
    order = np.argsort(campaign.time_s, kind="stable")
    b = np.empty(campaign.n_visits)
    b[order] = branch_of_history(visit_temperature(campaign)[order])
    return replace(campaign, branch_values=b)


def with_play(campaign: Campaign, half_width_C: float, start: str) -> Campaign:
    return _with_branch(campaign, lambda T: play_branch(T, half_width_C, start))


def with_pi(campaign: Campaign, half_widths_C, weights, start: str) -> Campaign:
    return _with_branch(campaign, lambda T: pi_branch(T, half_widths_C, weights, start))


def _chi2(out) -> float:
    return float(np.sum(out[2].r ** 2))


class _Profile:
    """chi^2 of any branch vector by one Gauss-Newton step from the offset optimum (see the module)."""

    def __init__(self, campaign: Campaign, off, effects):
        result, problem, sol = off
        hyst = [i for i, n in enumerate(problem.names) if n.endswith("_hysteresis")]
        other = [i for i in range(len(problem.names)) if i not in hyst]
        x = sol.x.copy()
        x[hyst] = 0.0
        r0 = problem.residuals(x)                                  # without the hysteresis
        unit = JointProblem(replace(campaign, branch_values=np.ones(campaign.n_visits)), problem.model,
                            problem.sigma, problem.fixed)
        _, Ju = unit.residuals_and_jacobian(x)
        self.U = Ju[:, hyst]                                       # d r / d h at b = 1, (3n, n_h)
        Jo = sol.J[:, other]
        d = np.linalg.norm(Jo, axis=0)
        d[d == 0] = 1.0
        self.Q = np.linalg.qr(Jo / d, mode="reduced")[0]
        self.r = r0 - self.Q @ (self.Q.T @ r0)
        self.rr = float(self.r @ self.r)
        self.campaign = campaign

    def basis(self, half_width: float, start: str):
        """The projected hysteresis columns of a play's branch, (3n, n_h)."""
        c = with_play(self.campaign, half_width, start)
        C = self.U * np.repeat(c.branch, 3)[:, None]
        return C - self.Q @ (self.Q.T @ C)


def _chi2_of(G: np.ndarray, c: np.ndarray, rr: float) -> np.ndarray:
    """``rr - c^T G^-1 c`` for stacked (…, k, k) Gram matrices and (…, k) vectors."""
    sol = np.linalg.lstsq(G, c, rcond=None)[0] if G.ndim == 2 else np.linalg.solve(
        G + 1e-12 * np.trace(G, axis1=-2, axis2=-1)[..., None, None] * np.eye(G.shape[-1]), c[..., None])[..., 0]
    return rr - np.sum(c * sol, axis=-1)


def _profiles(prof: _Profile, grid, want_pi: bool):
    """Play profile over (r, start) and, with ``want_pi``, the PI's over (r1 < r2, w, start)."""
    play, pi = [], []
    for start in PLAY_STARTS:
        B = [prof.basis(r, start) for r in grid]
        k = B[0].shape[1]
        C = np.concatenate(B, axis=1)
        G = C.T @ C
        c = C.T @ prof.r
        blk = [[G[i * k:(i + 1) * k, j * k:(j + 1) * k] for j in range(len(grid))] for i in range(len(grid))]
        cv = [c[i * k:(i + 1) * k] for i in range(len(grid))]
        for i, r in enumerate(grid):
            play.append({"half_width_C": r, "start": start, "chi2": float(_chi2_of(blk[i][i], cv[i], prof.rr))})
        if not want_pi:
            continue
        w = np.asarray(PI_WEIGHTS)
        for i in range(len(grid)):
            for j in range(i + 1, len(grid)):
                Gs = (((1 - w) ** 2)[:, None, None] * blk[i][i] + (w * w)[:, None, None] * blk[j][j]
                      + (w * (1 - w))[:, None, None] * (blk[i][j] + blk[j][i]))
                cs = (1 - w)[:, None] * cv[i] + w[:, None] * cv[j]
                for wk, x2 in zip(w, _chi2_of(Gs, cs, prof.rr)):
                    pi.append({"half_widths_C": [grid[i], grid[j]], "weights": [float(round(1 - wk, 6)), float(round(wk, 6))],
                               "start": start, "chi2": float(x2)})
    return play, pi


#: points of the fine scan of r between the grid's neighbours of the best grid point (geometric)
FINE_POINTS = 81


def _play_chi2(prof: _Profile, r: float, start: str) -> float:
    B = prof.basis(float(r), start)
    return float(_chi2_of(B.T @ B, B.T @ prof.r, prof.rr))


def _refine_play(prof: _Profile, grid, best: dict) -> list:
    """The play's profile between the grid points two below and two above the grid's best r, for
    its start: a geometric scan of ``FINE_POINTS`` and a bounded Brent minimisation around the
    scan's best. A play whose r lies between grid points was fitted at the nearest one, with an
    interval of that one point and a biased h (an outside probe: r = 17 degC fitted as 15 "15..15",
    Ca_xy_hysteresis 5.6 u off, status ok; and two neighbouring grid plays, a PI, named instead of
    the one play). Returns ``[{"half_width_C", "start", "chi2"}]``."""
    from scipy.optimize import minimize_scalar

    g = list(grid)
    i = g.index(best["half_width_C"])
    lo, hi = g[max(i - 2, 0)], g[min(i + 2, len(g) - 1)]
    start = best["start"]
    out = [{"half_width_C": float(r), "start": start, "chi2": _play_chi2(prof, r, start)}
           for r in np.geomspace(lo, hi, FINE_POINTS)]
    k = int(np.argmin([p["chi2"] for p in out]))
    a = out[max(k - 1, 0)]["half_width_C"]
    b = out[min(k + 1, len(out) - 1)]["half_width_C"]
    if b > a:
        m = minimize_scalar(lambda r: _play_chi2(prof, r, start), bounds=(a, b), method="bounded",
                            options={"xatol": 1e-3 * a})
        out.append({"half_width_C": float(m.x), "start": start, "chi2": float(m.fun)})
    return out


def _crossings(prof: _Profile, start: str, r_best: float, level: float, by_r: dict, interval: list) -> list:
    """The interval's ends where the profile crosses ``level`` (chi2_min + 1), by Brent's root
    finding between the last point below it and the first above on each side; a side on which no
    profiled point rises above it keeps the farthest point below (the interval of the points)."""
    from scipy.optimize import brentq

    f = lambda r: _play_chi2(prof, r, start) - level  # noqa: E731
    pts = sorted(by_r.items())
    out = list(interval)
    above_lo = [r for r, c in pts if r < r_best and c > level]
    if above_lo and f(r_best) < 0:
        a = max(above_lo)
        out[0] = brentq(f, a, r_best, xtol=1e-4 * a)
    above_hi = [r for r, c in pts if r > r_best and c > level]
    if above_hi and f(r_best) < 0:
        b = min(above_hi)
        out[1] = brentq(f, r_best, b, xtol=1e-4 * r_best)
    return out


def fit_hysteresis_form(campaign: Campaign, effects: Sequence[str], form: str = "auto",
                        half_width_C: Optional[float] = None, refine: bool = True, profile_only: bool = False,
                        **fit_kwargs):
    """Fit with the hysteresis form ``form`` (``offset``, ``play``, ``pi`` or ``auto``: chosen by
    the data, see the module); ``half_width_C`` fixes the play's r instead of profiling it;
    ``refine=False`` keeps r on the grid (the diagnosis's play candidate, as validated);
    ``profile_only``: the profiles' optimum only (r, start, its interval, at_grid_edge and the PI's
    widths, weights and start; the diagnosis refits the forms itself), no form refitted or chosen.
    Returns ``(result, problem, solution, campaign)`` of the chosen form, the result's
    ``fit.hysteresis`` saying what was chosen and why."""
    if form not in FORMS:
        raise InputError(f"--hysteresis-form {form!r}: choose one of {', '.join(FORMS)}")
    if "hysteresis" not in effects:
        raise InputError("--hysteresis-form needs the hysteresis effect in --effects")
    if half_width_C is not None and (not np.isfinite(half_width_C) or half_width_C <= 0):
        raise InputError(f"the play's half-width must be > 0 degC, got {half_width_C}")
    if form == "pi" and half_width_C is not None:
        raise InputError("--hysteresis-width fixes a single play's half-width; the pi form profiles its two plays")
    fit_kwargs = dict(fit_kwargs, return_problem=True)
    off = fit_joint(campaign, effects, **fit_kwargs)
    chi2_off = _chi2(off)
    if form == "offset":
        off[0].fit["hysteresis"] = {"form": "offset", "criterion": "chosen by the user"}
        return off + (campaign,)
    if "hysteresis" not in {off[1].model.spec[n].effect for n in off[1].names}:
        raise InputError("the hysteresis could not be estimated from these data (held fixed); no form to choose")
    grid = (half_width_C,) if half_width_C is not None else PLAY_GRID_C
    want_pi = form in ("pi", "auto") and half_width_C is None
    prof = _Profile(campaign, off, effects)
    play_prof, pi_prof = _profiles(prof, grid, want_pi)
    best = min(play_prof, key=lambda p: p["chi2"])
    if half_width_C is None and refine:
        play_prof = play_prof + _refine_play(prof, grid, best)
        best = min(play_prof, key=lambda p: p["chi2"])
    r, start = round(best["half_width_C"], 4), best["start"]
    by_r = {}
    for p in play_prof:
        by_r[p["half_width_C"]] = min(by_r.get(p["half_width_C"], np.inf), p["chi2"])
    lin_min = min(by_r.values())
    inside = [rr for rr, c2 in by_r.items() if c2 <= lin_min + 1.0]
    interval = [min(inside), max(inside)]
    if half_width_C is None and refine:
        interval = _crossings(prof, start, r, lin_min + 1.0, by_r, interval)
    interval = [round(interval[0], 4), round(interval[1], 4)]
    edge = half_width_C is None and (r <= grid[0] * 1.001 or r >= grid[-1] * 0.999)
    bp = min(pi_prof, key=lambda p: p["chi2"]) if want_pi else None
    if profile_only:
        return {"half_width_C": r, "start": start, "half_width_interval_C": interval, "at_grid_edge": edge,
                **({"pi_half_widths_C": bp["half_widths_C"], "pi_weights": bp["weights"], "pi_start": bp["start"]}
                   if want_pi else {})}
    play_c = with_play(campaign, r, start)
    play_out = fit_joint(play_c, effects, **fit_kwargs)
    chi2_play = _chi2(play_out)
    known = bool(off[0].fit.get("noise_known"))
    n = off[2].r.size

    def compare(chi2_small, chi2_big, k, thr, what):
        if known:
            stat = chi2_small - chi2_big
            return stat > thr, (f"likelihood ratio {what} = {stat:.4g} against {thr:.3g} "
                                f"(chi2 with {k} dof at 99 %)")
        daic = n * np.log(chi2_small / n) - (n * np.log(chi2_big / n) + 2.0 * k)
        return daic > AIC_MARGIN, f"AIC falls by {daic:.4g} ({what}; chosen when > {AIC_MARGIN:g}, noise estimated)"

    prefer_play, crit_play = compare(chi2_off, chi2_play, 2, LR_THRESHOLD, "chi2_offset - chi2_play")
    block = {"form": "offset", "criterion": crit_play, "chi2_offset": chi2_off, "chi2_play": chi2_play,
             "half_width_C": r, "start": start, "half_width_interval_C": interval, "at_grid_edge": edge,
             "profile": sorted(({"half_width_C": k, "chi2": v} for k, v in by_r.items() if k in grid),
                               key=lambda x: x["half_width_C"]),
             "profile_method": ("one Gauss-Newton step from the offset optimum, on the grid and refined between "
                                "its neighbours of the best (a scan and Brent's method); the chosen form refitted")}
    chosen = "offset"
    if form == "play" or (form == "auto" and prefer_play):
        chosen = "play"
    pi_out = pi_c = None
    if want_pi:
        pi_c = with_pi(campaign, bp["half_widths_C"], bp["weights"], bp["start"])
        pi_out = fit_joint(pi_c, effects, **fit_kwargs)
        chi2_pi = _chi2(pi_out)
        if prefer_play:
            prefer_pi, crit_pi = compare(chi2_play, chi2_pi, 2, LR_THRESHOLD, "chi2_play - chi2_pi")
        else:
            prefer_pi, crit_pi = compare(chi2_off, chi2_pi, 4, LR_THRESHOLD_PI_OFFSET, "chi2_offset - chi2_pi")
        block.update({"chi2_pi": chi2_pi, "pi_half_widths_C": bp["half_widths_C"], "pi_weights": bp["weights"],
                      "pi_start": bp["start"], "criterion_pi": crit_pi})
        if form == "pi" or (form == "auto" and prefer_pi):
            chosen = "pi"
    block["form"] = chosen
    if chosen == "offset":
        off[0].fit["hysteresis"] = block
        off[0].notes.append(f"hysteresis form: the constant offset; a play does not fit better ({crit_play})"
                            + (f"; nor a Prandtl-Ishlinskii sum of plays ({block['criterion_pi']})" if want_pi else ""))
        return off + (campaign,)
    if chosen == "pi":
        res = pi_out[0]
        res.fit["hysteresis"] = block
        why = "chosen by the user" if form == "pi" else block["criterion_pi"]
        res.notes.append(f"hysteresis form: a Prandtl-Ishlinskii sum of plays of half-widths "
                         f"{block['pi_half_widths_C'][0]:g} and {block['pi_half_widths_C'][1]:g} degC, weights "
                         f"{block['pi_weights'][0]:g} and {block['pi_weights'][1]:g}, from the {block['pi_start']} "
                         f"state; Ca_ab_hysteresis is the half-width of the saturated loop ({why})")
        return pi_out + (pi_c,)
    res = play_out[0]
    res.fit["hysteresis"] = block
    why = "chosen by the user" if form == "play" else crit_play
    res.notes.append(f"hysteresis form: a play of half-width r = {r:.3g} degC (68 % interval "
                     f"{interval[0]:.3g}..{interval[1]:.3g} degC, profile chi2 + 1) from the {start} state; "
                     f"Ca_ab_hysteresis is the half-width of the saturated loop ({why})"
                     + ("; r lies at the edge of the searched grid" if edge else ""))
    return play_out + (play_c,)
