"""One static pose through a chamber cycle: which thermal form explains the output
(``triadcal thermal-cycle``, docs/model.md "A real chamber cycle").

A unit resting in one pose while the chamber ramps down and up gives, per axis, the output
against the measured temperature history. One pose cannot separate scale from bias: what is
fitted is the output along each axis, ``W_a = (g_a + S_a(T)) / K_a(T)`` with the fixed gravity
component ``g_a``, so a thermal change of K and of S look the same; the forms below describe
that output. Candidate forms (least squares in the coefficients, a grid search in the one
non-linear parameter, :mod:`triadcal.models.thermal_history` for the operators):

- ``linear``, ``quadratic``, ``cubic``: a polynomial in ``T - T_ref``;
- ``offset_hysteresis``, ``quadratic_hysteresis``: linear / quadratic plus ``h b`` with ``b`` the
  hysteron of the reading (:func:`relay_branch`, r = 0.1 degC): +1 after cooling, -1 after heating, held
  through a soak, 0 before the first move (the joint model's hysteresis term: a visit's branch is
  that of the last setpoint change; ``lag_hysteresis`` with tau = 0). Until 2026-12-02 ``b`` was
  0 while the chamber was still (and switched on a 2 min rate, a minute before a turn): an outside
  probe's offset hysteresis held through 20 min soaks was never named (0 of 6), ``lag_hysteresis``
  at its smallest tau instead;
- ``lag``, ``lag_quadratic``: linear / quadratic in the temperature of an element lagging the
  sensor by a first-order time constant tau;
- ``lag_hysteresis``: linear in the lagging element's temperature ``T_e`` plus ``h b_e``, ``b_e``
  the element's branch held through soaks (the hysteron :func:`relay_branch` of ``T_e``, r = 0.1):
  a lag and an offset
  hysteresis at once, which a lag alone took up with a biased tau (+24 % at h = 3 mm/s2, +88 % at
  h = 10), "explained" (an outside probe);
- ``lag_quadratic_hysteresis``: the same on a quadratic tempco (an outside probe's lag of 4 min with
  an offset hysteresis on a quadratic tempco was ``lag_quadratic`` with tau 19 % long, the
  hysteresis lost, "explained" at 1.7 floors);
- ``lag_play``: linear in the play (half-width r) of the lagging element's temperature
  (``play(lag(T, tau), r)``): a lag and a play at once, which a lag with an offset hysteresis took
  up with tau 37 % long, "explained" at 1.09 times the floor (a lag of 4 min with a play of 3 degC
  on legs of 1.2 and 2.4 degC/min); tau, r and the play's start on a coarse grid, then refined by
  Nelder-Mead in (log tau, log r), on the training blocks as every form's parameter;
- ``thermometer_lag``: linear in the temperature of an element that the thermometer lags by tau
  (``T_e = T + tau dT/dt``, the lag's inverse): the reading behind the element, which a cycle at
  two rates tells from an offset hysteresis (the probe's thermometer 2 min behind was named
  ``offset_hysteresis``, at 2.1 times the floor on legs of two rates);
- ``play``, ``play_quadratic``: linear / quadratic in the play operator of the temperature
  (half-width r; the branches join at the turning points);
- ``quadratic_play``: quadratic in T plus ``h (play(T, r) - T)``: a play hysteresis on top of a
  nonlinear tempco (the branch offset is +-r on a ramp and turns over at the turning points);
- ``linear_drift``: a line in T plus a drift linear in time (not thermal: its rival, so that an
  output that drifts is not named a hysteresis; :data:`DRIFT_FORMS`).

Each form is judged on data it was not fitted to: blocked cross-validation over the cycle
(``folds`` contiguous blocks in time; the non-linear parameter chosen on the training blocks
only), RMS of the held-out residuals. The branch gap at ``T_ref`` (cooling minus heating, from
a local line through each branch within +-5 degC) is measured in the data's linear residual and
after each form.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from ..errors import InputError
from ..io.thermal_cycle_csv import (G_IN_UNIT, GLITCH_FRACTION_MAX, GLITCH_SD, MAX_TEMPERATURE_C, glitches,
                                    read_cycle)
from ..models.thermal_history import centred_rate, first_order_lag, play_operator, relay_branch, thermometer_lead
from .thermal_reading import reading_errors, reading_rival, reading_words
from .thermal_cycle_results import (EXPLAINED_FACTOR, FORMAT, VERSION, AxisCycle, FormFit,  # noqa: F401
                                     ThermalCycle, jackknife)

FORMS = ("linear", "quadratic", "cubic", "offset_hysteresis", "quadratic_hysteresis", "lag", "lag_quadratic",
         "lag_hysteresis", "lag_quadratic_hysteresis", "lag_play", "thermometer_lag", "play", "play_quadratic",
         "quadratic_play", "linear_drift")
#: the form that is not thermal: a line in T plus a drift linear in time (per hour from the record's
#: middle; models/effects/bias_drift's term on one pose). Without it an outside probe's output drifting
#: 20 ug/h with no tempco was a play of 30 degC (at the edge of the search), "explained" at 1.2 floors,
#: 9 of 9 axes, with a branch gap of +17..+32 ug where there is none
DRIFT_FORMS = ("linear_drift",)
#: time constants tried for the lag (s) and half-widths for the play (degC). The lag's grid starts at
#: 5 s: from 30 s, an element lagging by 18 s was named a play or an offset hysteresis, "explained",
#: in 5 runs of 5 (an outside probe)
TAU_GRID_S = tuple(float(x) for x in np.geomspace(5.0, 7200.0, 47))
#: the hysteron of ``lag_hysteresis`` (on the element's temperature) and ``offset_hysteresis`` (on the
#: reading): half-width (degC) of its play; +1 after cooling, -1 after heating, held through a soak
RELAY_HALF_WIDTH_C = 0.1
PLAY_GRID_C = tuple(float(x) for x in np.linspace(0.25, 30.0, 120))
#: the play's state before the record, profiled as ``fit --hysteresis-form play`` does: the middle of
#: its band (y0 = T0), after heating (y0 = T0 - r) or after cooling (y0 = T0 + r). Started at the
#: middle only, a play of 5 degC after the chamber had heated was named a lag of 1.7 min, "explained",
#: 20 times in 20 (an outside probe)
PLAY_STARTS = ("mid", "heating", "cooling")
#: the forms of a play of the reading whose start (PLAY_STARTS) is held at its choice on every sample
PLAY_FORMS = ("play", "play_quadratic", "quadratic_play")
#: the coarse grid of ``lag_play`` (two non-linear parameters): every third time constant of the lag's
#: grid (a factor 1.6 apart) and 12 half-widths from 0.25 to 30 degC, a factor 1.5 apart, each start
LAG_PLAY_TAU_S = TAU_GRID_S[::3]
LAG_PLAY_R_C = tuple(float(x) for x in np.geomspace(PLAY_GRID_C[0], PLAY_GRID_C[-1], 12))
#: the forms judged on a record whose temperature only rises or only falls: those without a branch term (a
#: hysteresis's branch is one constant there, the intercept's twin; a play a shift of the reading after its start)
ONE_WAY_FORMS = ("linear", "quadratic", "cubic", "lag", "lag_quadratic", "thermometer_lag", "play", "play_quadratic")
ONE_WAY_NOTE = ("the temperature only {way}: no heating and cooling branches, so no hysteresis is judged (its branch "
                "is one constant here, the bias's twin) and no branch gap is measured; a lag or a play shows only "
                "where the rate changes (the ramp's start and end), and on a ramp of one rate it is an offset of the "
                "temperature, which the bias takes; and a drift of the output in time moves with the temperature "
                "on it, so the tempco holds any such drift (an outside probe's 1.0e-3 per degC with a drift of "
                "9.8e-3 per h on a 1 degC/min ramp: 1.16e-3 +- 1.3e-6, z 126, 'explained'): a cycle that heats "
                "and cools tells them")
#: |dT/dt| below which the chamber counts as still (no branch), degC/min
STILL_RATE_C_MIN = 0.2
#: m/s^2 per g (the conversion constant only: the recording's own g is not known)
G0 = 9.80665


#: ramps whose rates (degC/min: the largest 75th over the smallest 25th percentile of |dT/dt| of a leg,
#: a run of one branch) differ by less than this factor run at one rate, as far as a delay is
#: concerned (:func:`rate_caveat`)
RATE_SPREAD_MIN = 1.5


def rate_caveat(t_s, T, branch, best: str) -> Optional[str]:
    """What a cycle whose ramps all run at about one rate cannot tell, for a named ``best`` form of a
    delay or a branch offset (``lag*``, ``*play*``, ``*hysteresis``), or None. On a ramp of rate v an
    element lagging by tau sits tau v behind the thermometer, a play of half-width r sits r behind,
    a thermometer lagging the element puts the reading tau v behind, and an offset hysteresis is a
    constant by branch: with one v they are nearly the same branches. An outside probe (its own
    simulator, the README's cycle at 2.7 and 3.2 degC/min): a lag of 4 min with a play of 3 degC was a
    lag of 5.1-5.5 min (+28-36 %), "explained", 10 of 10; a thermometer lagging the element by 2 min
    an offset hysteresis, "explained", 10 of 10. A leg at another rate tells them apart (1 and 4
    degC/min: the play's start named right)."""
    if not (best.startswith("lag") or best == "thermometer_lag" or "play" in best or best.endswith("hysteresis")):
        return None
    # each leg (a run of one branch) by its middle half: the turns, rounded by a lag of the reading,
    # are not a second rate (a thermometer 2 min behind put the 10th percentile near the turns)
    b = np.asarray(branch)
    rate = np.abs(rate_of(t_s, T))
    cut = np.flatnonzero(np.diff(b) != 0) + 1
    legs = [(s0, s1) for s0, s1 in zip(np.r_[0, cut], np.r_[cut, len(b)]) if b[s0] != 0 and s1 - s0 >= 10]
    if not legs:
        return None
    lo = min(float(np.percentile(rate[s0:s1], 25)) for s0, s1 in legs)
    hi = max(float(np.percentile(rate[s0:s1], 75)) for s0, s1 in legs)
    if not lo > 0 or hi / lo >= RATE_SPREAD_MIN:
        return None
    return (f"the ramps run at {lo:.2g}-{hi:.2g} degC/min: at one rate an element lagging the thermometer, a play, "
            "a thermometer lagging the element and an offset hysteresis give nearly the same branches: only the turns "
            f"tell them apart, so the form named ({best}) and its tau or half-width rest on the turns (a lag with a play "
            "was taken for a longer lag before the form of both); a leg at another rate (half or twice) tells them "
            "apart on the ramps too")


def rate_of(t_s, T, window_s: float = 120.0) -> np.ndarray:
    """The temperature's rate (degC/min) over ``window_s`` about each sample."""
    return centred_rate(t_s, T, window_s) * 60.0


def branch_of(t_s, T, window_s: float = 120.0) -> np.ndarray:
    """+1 cooling, -1 heating, 0 still, from the temperature's rate over ``window_s`` (degC/min
    above :data:`STILL_RATE_C_MIN`): the convention of the joint model's hysteresis."""
    rate = rate_of(t_s, T, window_s)
    return np.where(rate < -STILL_RATE_C_MIN, 1.0, np.where(rate > STILL_RATE_C_MIN, -1.0, 0.0))


def _design(form: str, t, T, T_ref, branch, p, cache: Optional[dict] = None) -> np.ndarray:
    cache = {} if cache is None else cache

    def op(kind, v):
        if (kind, v) not in cache:
            if kind == "lag":
                cache[(kind, v)] = first_order_lag(t, T, v)
            elif kind == "lead":
                cache[(kind, v)] = thermometer_lead(t, T, v)
            else:                                   # v = (half-width, start)
                r, start = v
                y0 = {"mid": T[0], "heating": T[0] - r, "cooling": T[0] + r}[start]
                cache[(kind, v)] = play_operator(T, r, start=y0)
        return cache[(kind, v)]

    one = np.ones_like(T)
    if form == "linear_drift":
        return np.stack([one, T - T_ref, (t - 0.5 * (t[0] + t[-1])) / 3600.0], axis=1)
    if form in ("linear", "quadratic", "cubic", "offset_hysteresis", "quadratic_hysteresis", "quadratic_play"):
        d = T - T_ref
    elif form == "lag_play":                        # p = (tau_s, half-width, start); not cached (refined)
        tau_s, r, start = p
        Te = op("lag", tau_s) if (("lag", tau_s) in cache or tau_s in TAU_GRID_S) else first_order_lag(t, T, tau_s)
        y0 = {"mid": Te[0], "heating": Te[0] - r, "cooling": Te[0] + r}[start]
        return np.stack([one, play_operator(Te, r, start=y0) - T_ref], axis=1)
    elif form.startswith("lag"):
        d = op("lag", p) - T_ref
        if form in ("lag_hysteresis", "lag_quadratic_hysteresis"):
            if ("relay", p) not in cache:
                Te = op("lag", p)
                cache[("relay", p)] = relay_branch(Te, RELAY_HALF_WIDTH_C)
            return np.stack([one, d] + ([d * d] if "quadratic" in form else []) + [cache[("relay", p)]], axis=1)
    elif form == "thermometer_lag":
        d = op("lead", p) - T_ref
    else:
        d = op("play", p) - T_ref
    cols = [one, d]
    if form in ("quadratic", "cubic", "lag_quadratic", "play_quadratic", "quadratic_hysteresis", "quadratic_play"):
        cols.append(d * d)
    if form == "quadratic_play":
        # a play hysteresis on top of a quadratic tempco: the branch offset (play(T) - T) is +-r
        # on a ramp and changes sign through the turning points
        cols.append(op("play", p) - T)
    if form == "cubic":
        cols.append(d ** 3)
    if form in ("offset_hysteresis", "quadratic_hysteresis"):
        if "relay" not in cache:            # the relay of lag_hysteresis on the thermometer's own reading
            cache["relay"] = relay_branch(T, RELAY_HALF_WIDTH_C)
        cols.append(cache["relay"])
    return np.stack(cols, axis=1)


def _grid(form: str):
    if form.startswith("lag") or form == "thermometer_lag":
        return TAU_GRID_S
    if "play" in form:
        return tuple((r, start) for start in PLAY_STARTS for r in PLAY_GRID_C)
    return (None,)


def branch_gap(T, r, branch, T_ref: float, half_window: float = 5.0) -> Optional[float]:
    """Cooling minus heating at ``T_ref``: a local line through each branch's samples within
    ``+-half_window`` degC; None when a branch has fewer than 10 samples there."""
    T, r = np.asarray(T, float), np.asarray(r, float)
    near = np.abs(T - T_ref) <= half_window
    at = []
    for b in (1.0, -1.0):
        m = near & (branch == b)
        if m.sum() < 10:
            return None
        A = np.stack([np.ones(m.sum()), T[m] - T_ref], axis=1)
        at.append(np.linalg.lstsq(A, r[m], rcond=None)[0][0])
    return float(at[0] - at[1])


# the rules that choose among the forms: thermal_choice.py (re-exported here)
from .thermal_choice import (FLOOR_SE, MATERIAL_MSE, PAIRED_Z, SE_MARGIN, at_floor, floor_rule,  # noqa: E402,F401
                             parsimonious_best)


def _least_squares(X, y):
    c, *_ = np.linalg.lstsq(X, y, rcond=None)
    return float(np.sum((y - X @ c) ** 2)), c


def _best_parameter(f: str, grid_designs: dict, rows, y, design_of) -> tuple:
    """``(rss, p, c)`` of form ``f`` on ``rows``: the grid's best parameter, then (a lag's tau, a
    play's half-width) refined between the grid's neighbours of it by Brent's method on log p.
    A cycle made with tau = 10.6 min was fitted at the grid's 9.8 (8 % off), its held-out RMS 3.3
    times the noise floor, and called "unexplained" (an outside probe)."""
    from scipy.optimize import minimize_scalar

    best = None
    for p, X in grid_designs.items():
        rss, c = _least_squares(X[rows], y[rows])
        if best is None or rss < best[0]:
            best = (rss, p, c)
    if best[1] is None or len(grid_designs) < 3:
        return best
    # a play's key is (half-width, start): the half-width refined with the start held
    start = best[1][1] if isinstance(best[1], tuple) else None
    grid = [k[0] if start is not None else k for k in grid_designs if start is None or k[1] == start]
    i = grid.index(best[1][0] if start is not None else best[1])
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]

    def key(logp):
        v = float(np.exp(logp))
        return v if start is None else (v, start)

    def rss_at(logp):
        return _least_squares(design_of(key(logp))[rows], y[rows])[0]

    m = minimize_scalar(rss_at, bounds=(math.log(lo), math.log(hi)), method="bounded",
                        options={"xatol": 1e-3})
    if m.fun < best[0]:
        p = key(m.x)
        rss, c = _least_squares(design_of(p)[rows], y[rows])
        best = (rss, p, c)
    return best


def _lag_play_best(t, T, y, T_ref, subsets: list, cache: dict) -> list:
    """``(rss, (tau_s, r, start), c)`` of ``lag_play`` on each row subset (boolean masks): the coarse
    grid (:data:`LAG_PLAY_TAU_S` x :data:`LAG_PLAY_R_C` x :data:`PLAY_STARTS`) in one pass, each
    design's two-column least squares on every subset from its sums, then Nelder-Mead in
    (log tau, log r) from the subset's best grid point, its start held."""
    from scipy.optimize import minimize

    y = np.asarray(y, float)
    W = np.array(subsets, float)                     # (k, n)
    ny, sy, syy = W.sum(1), W @ y, W @ (y * y)
    best = [None] * len(subsets)
    for tau in LAG_PLAY_TAU_S:
        for start in PLAY_STARTS:
            for r in LAG_PLAY_R_C:
                d = _design("lag_play", t, T, T_ref, None, (tau, r, start), cache)[:, 1]
                sd, sdd, sdy = W @ d, W @ (d * d), W @ (d * y)
                det = ny * sdd - sd * sd
                with np.errstate(divide="ignore", invalid="ignore"):
                    b = (ny * sdy - sd * sy) / det
                    a0 = (sy - b * sd) / ny
                    rss = syy - a0 * sy - b * sdy
                for k in range(len(subsets)):
                    if det[k] > 0 and (best[k] is None or rss[k] < best[k][0]):
                        best[k] = (float(rss[k]), (float(tau), float(r), start))
    out = []
    for k, rows in enumerate(subsets):
        _, (tau0, r0, start) = best[k]

        def rss_at(x, rows=rows, start=start):
            X = _design("lag_play", t, T, T_ref, None, (float(np.exp(x[0])), float(np.exp(x[1])), start), cache)
            return _least_squares(X[rows], y[rows])[0]

        lo = np.log([TAU_GRID_S[0], PLAY_GRID_C[0]])
        hi = np.log([TAU_GRID_S[-1], PLAY_GRID_C[-1]])
        m = minimize(lambda x: rss_at(np.clip(x, lo, hi)), np.log([tau0, r0]), method="Nelder-Mead",
                     options={"xatol": 0.01, "fatol": 0.0, "maxfev": 60, "initial_simplex": np.log(
                         [[tau0, r0], [tau0 * 1.6, r0], [tau0, r0 * 1.5]])})
        x = np.clip(m.x, lo, hi)
        p = (float(np.exp(x[0])), float(np.exp(x[1])), start)
        rss, c = _least_squares(_design("lag_play", t, T, T_ref, None, p, cache)[rows], y[rows])
        out.append((rss, p, c))
    return out


#: a step between samples longer than this many median steps is a gap in the record, not a sample
GAP_STEPS = 3.0


def white_floor(t, y) -> float:
    """The white-noise floor of an output: the SD of its sample-to-sample differences over sqrt 2,
    leaving out the differences across a gap in the record (a step longer than :data:`GAP_STEPS` median
    steps: the output moves with the temperature across it). An outside probe's record with two gaps
    (30 and 10 min) had its floor doubled (0.0060 for 0.003), and a lag's held-out RMS of 3.5 times the
    true floor passed as "explained" (1.8 times the reported one)."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    dt, dy = np.diff(t), np.diff(y)
    keep = dt <= GAP_STEPS * float(np.median(dt)) if dt.size else np.ones(0, bool)
    d = dy[keep] if np.count_nonzero(keep) >= 10 else dy
    first = float(np.std(d) / math.sqrt(2.0))
    second = _second_difference_floor(y, keep)
    return second if second is not None and second < SECOND_DIFFERENCE_RATIO * first else first


#: the second differences' floor replaces the first differences' where it is below this fraction of it
SECOND_DIFFERENCE_RATIO = 0.8


def _second_difference_floor(y: np.ndarray, keep: np.ndarray):
    """The floor from second differences ``y[i+1] - 2 y[i] + y[i-1]`` (variance 6 sigma^2 for white
    noise), over sample triplets without a gap, those beyond 5 robust SDs (the corners of the cycle)
    left out: a signal linear over two steps cancels in them, where the first differences hold its
    change between samples. An outside probe's record logged every 30 s on ramps of 1-3 degC/min with
    a tempco of 5 mg/degC: the first differences' floor 0.022 for a true 0.003 (7.4x), a bias step and
    a wander "explained" at 7x the true noise, and a line "at 0.13 floors". Used by :func:`white_floor`
    where it is materially smaller (:data:`SECOND_DIFFERENCE_RATIO`), so a finely sampled record keeps
    its floor. None with fewer than 10 triplets."""
    if y.size < 3:
        return None
    ok = keep[:-1] & keep[1:]
    d2 = (y[2:] - 2.0 * y[1:-1] + y[:-2])[ok]
    if d2.size < 10:
        return None
    med = float(np.median(d2))
    mad = 1.4826 * float(np.median(np.abs(d2 - med)))
    if mad > 0:
        d2 = d2[np.abs(d2 - med) <= 5.0 * mad]
    return float(np.std(d2) / math.sqrt(6.0)) if d2.size >= 10 else None


def _uncertainty(form: str, fold_p: list, fold_c: list) -> Optional[dict]:
    """The form's standard uncertainties by the block jackknife over its folds' training estimates:
    the time constant (min), the half-width (degC) and every coefficient."""
    out = {}
    uc = jackknife(np.array(fold_c, float))
    if uc is not None:
        out["coefficients"] = [float(x) for x in uc]
    if form == "lag_play":
        pairs = {"tau_min": [p[0] / 60.0 for p in fold_p], "half_width_C": [p[1] for p in fold_p]}
    elif form.startswith("lag") or form == "thermometer_lag":
        pairs = {"tau_min": [p / 60.0 for p in fold_p]}
    elif "play" in form:
        pairs = {"half_width_C": [p[0] for p in fold_p]}
    else:
        pairs = {}
    for k, v in pairs.items():
        u = jackknife(v)
        if u is not None:
            out[k] = float(u[0])
    return out or None


def analyse_axis(t, T, y, column: str, unit: str, T_ref: float, folds: int, branch,
                 judged: Sequence[str] = FORMS) -> AxisCycle:
    n = len(y)
    edges = np.linspace(0, n, folds + 1).astype(int)
    noise = white_floor(t, y)
    cache = {}
    designs = {f: {p: _design(f, t, T, T_ref, branch, p, cache) for p in _grid(f)} for f in judged if f != "lag_play"}
    tests = []
    for k in range(folds):
        test = np.zeros(n, bool)
        test[edges[k]:edges[k + 1]] = True
        tests.append(test)
    lag_play = (_lag_play_best(t, T, y, T_ref, [~m for m in tests] + [np.ones(n, bool)], cache)
                if "lag_play" in judged else None)
    forms, per_fold, per_sample, size = [], {}, {}, {}
    lin_resid = None
    for f in judged:
        def design_of(p, f=f):
            return designs[f][p] if f in designs and p in designs[f] else _design(f, t, T, T_ref, branch, p, cache)

        # held-out residuals: on each block, the form (and its parameter) fitted to the others. A play's state
        # before the record (its start) is an initial condition that only the first block shows (the play
        # forgets it at its first turn): it is chosen on every sample and held, the half-width on the training
        # blocks; chosen on the training blocks alone, a true play started on a branch was named right but
        # "unexplained" at 4-4.6 floors, 15 of 15 axes (an outside probe)
        grid_f = designs.get(f)
        if f in PLAY_FORMS:
            start = _best_parameter(f, designs[f], np.ones(n, bool), y, design_of)[1][1]
            grid_f = {k: X for k, X in designs[f].items() if k[1] == start}
        sq, fold_mse, fold_p, fold_c = [], [], [], []
        for k, test in enumerate(tests):
            _, p, c = lag_play[k] if f == "lag_play" else _best_parameter(f, grid_f, ~test, y, design_of)
            sq.append((y[test] - design_of(p)[test] @ c) ** 2)
            fold_mse.append(float(np.mean(sq[-1])))
            fold_p.append(p)
            fold_c.append(c)
        per_sample[f] = np.concatenate(sq)
        cv = float(np.sqrt(np.mean(per_sample[f])))
        per_fold[f] = np.array(fold_mse)
        size[f] = 4 if f == "lag_play" else (
            next(iter(designs[f].values())).shape[1] + (0 if _grid(f) == (None,) else 1))
        rss, p, c = lag_play[-1] if f == "lag_play" else _best_parameter(f, designs[f], np.ones(n, bool), y, design_of)
        resid = y - design_of(p) @ c
        if f == "linear":
            lin_resid = resid
        par = None
        if f == "lag_play":
            par = {"tau_min": p[0] / 60.0, "half_width_C": p[1], "start": p[2]}
            span = None
            if p[0] <= TAU_GRID_S[0] * 1.001 or p[0] >= TAU_GRID_S[-1] * 0.999 \
                    or p[1] <= PLAY_GRID_C[0] * 1.001 or p[1] >= PLAY_GRID_C[-1] * 0.999:
                par["at_grid_edge"] = True
        elif f.startswith("lag") or f == "thermometer_lag":
            par = {"tau_min": p / 60.0}
            span = (TAU_GRID_S[0], TAU_GRID_S[-1], p)
        elif "play" in f:
            par = {"half_width_C": p[0], "start": p[1]}
            span = (PLAY_GRID_C[0], PLAY_GRID_C[-1], p[0])
        if p is not None and span is not None and (span[2] <= span[0] * 1.001 or span[2] >= span[1] * 0.999):
            par["at_grid_edge"] = True       # the optimum may lie beyond the searched range
        forms.append(FormFit(f, cv, math.sqrt(rss / n), par, [float(x) for x in c], branch_gap(T, resid, branch, T_ref),
                             _uncertainty(f, fold_p, fold_c)))
    best, simpler = floor_rule(parsimonious_best(forms, per_fold, size), forms, per_sample, size, noise)
    # a delay or a hysteresis must beat the reading's own noise averaged away without one (thermal_reading.py)
    rival = reading_rival(t, T, y, T_ref, tests, best.name, per_sample[best.name], PAIRED_Z)
    if rival is not None and not rival["beaten"]:
        poly = next(f for f in forms if f.name == rival["form"])
        simpler = ((simpler + "; ") if simpler else "") + reading_words(best.name, poly.name, rival, reading_errors(T),
                                                                      noise)
        best = poly
    bp = best.parameter
    p = None if bp is None else ((bp["tau_min"] * 60.0, bp["half_width_C"], bp["start"]) if best.name == "lag_play"
                                 else bp["tau_min"] * 60.0 if "tau_min" in bp else (bp["half_width_C"], bp["start"]))
    pred = _design(best.name, t, T, T_ref, branch, p) @ np.array(best.coefficients)
    return AxisCycle(column, unit, noise, branch_gap(T, lin_resid + 0.0, branch, T_ref) if lin_resid is not None
                     else None, forms, best.name, pred, floor_note=simpler, reading_rival=rival)


def thermal_cycle(path, columns: Sequence[str], *, time_column: str, temperature_column: str, time_unit: str = "s",
                  unit: str = "m/s2", reference_temperature_C: float = 20.0, folds: int = 6) -> ThermalCycle:
    """Analyse a one-pose chamber cycle (see the module)."""
    if folds < 3:
        raise InputError("--folds must be at least 3")
    if not (math.isfinite(reference_temperature_C) and -273.15 <= reference_temperature_C <= MAX_TEMPERATURE_C):
        # nan ended in "internal error: SVD did not converge" (an outside probe)
        raise InputError(f"--reference-temperature {reference_temperature_C!r}: give a temperature in degC")
    t, T, y, lines = read_cycle(path, columns, time_column, time_unit, temperature_column, unit)
    bad = glitches(y)
    if bad.size > GLITCH_FRACTION_MAX * len(y):
        raise InputError(f"{path}: {bad.size} of {len(y)} samples lie beyond {GLITCH_SD:g} robust SDs of their "
                         f"neighbours' running median (lines {', '.join(str(int(lines[k])) for k in bad[:5])}, ...): "
                         "not isolated glitches; the output jumps or bursts, which no thermal form describes")
    glitch_note = None
    if bad.size:
        glitch_note = (f"{bad.size} isolated glitch(es) left out, every column of their row (a sample beyond "
                       f"{GLITCH_SD:g} robust SDs of the running median of 9): line(s) "
                       + ", ".join(f"{int(lines[k])} ({'; '.join(f'{c} {y[k, i]:.6g}' for i, c in enumerate(columns))})"
                                   for k in bad[:10]) + (" ..." if bad.size > 10 else ""))
        keep = np.setdiff1d(np.arange(len(y)), bad)
        t, T, y = t[keep], T[keep], y[keep]
    if np.ptp(T) < 10.0:
        raise InputError(f"{path}: the temperature spans {np.ptp(T):.1f} degC; a thermal form needs a cycle of at "
                         "least 10 degC")
    br = branch_of(t, T)
    if len(t) < 20 * folds:
        raise InputError(f"{path}: {len(t)} samples are too few for {folds} folds")
    one_way = not (np.any(br == 1) and np.any(br == -1))
    judged = ONE_WAY_FORMS if one_way else FORMS
    axes = [analyse_axis(t, T, y[:, i], c, unit, reference_temperature_C, folds, br, judged)
            for i, c in enumerate(columns)]
    for a in axes:
        a.caveat = rate_caveat(t, T, br, a.best)
    notes = ["one static pose: the output along each axis is W = (g_a + S_a(T)) / K_a(T); a thermal change of the "
             "scale factor and of the bias cannot be told apart, so the forms describe that output, not K and S",
             "noise floor: the SD of sample-to-sample differences / sqrt 2, or of second differences / sqrt 6 where "
             "that is below 0.8 of it (a coarsely logged record, whose first differences hold the signal's change) "
             "(white part only); held-out RMS near it "
             "means the form leaves nothing but noise"]
    if glitch_note:
        notes.append(glitch_note)
    if unit not in G_IN_UNIT:
        notes.append(f"the outputs' unit {unit!r} is not one whose g is known ({', '.join(G_IN_UNIT)}): their "
                     "magnitudes are not checked against a unit at rest")
    dt = np.diff(t)
    gaps = dt[dt > GAP_STEPS * float(np.median(dt))] if dt.size else dt
    if gaps.size:
        notes.append(f"the record has {gaps.size} gap(s) (the longest {float(gaps.max()) / 60.0:.3g} min): the noise floor "
                     "leaves out the steps across them; a lag's or a play's state is carried across a gap on the "
                     "reading as the record has it (no reading in it), so held-out errors after a gap may exceed "
                     "the floor whatever the form")
    if one_way:
        # until 2026-12-02 refused ("no heating and cooling branches"); the forms of one branch are judged
        notes.append(ONE_WAY_NOTE.format(way="rises" if np.any(br == -1) else "falls" if np.any(br == 1)
                                         else "hardly moves"))
    if any(a.branch_gap is None for a in axes) and not one_way:
        notes.append(f"no branch gap at {reference_temperature_C:g} degC: a branch has fewer than 10 samples within "
                     "+-5 degC of it (the reference temperature outside the cycle's ramps, or a gap in the record); "
                     "the hysteresis is judged by the forms' held-out errors alone")
    parts = []
    for a in axes:
        lin, best = a.form("linear"), a.form(a.best)
        gap = "" if a.branch_gap is None else (
            f"; branch gap at {reference_temperature_C:g} degC {a.branch_gap:+.3g} {unit} after a line, "
            f"{best.branch_gap:+.3g} after {a.best}" if best.branch_gap is not None else "")
        uu = best.u or {}
        par = "" if not best.parameter else " (" + ", ".join(
            (f"{k} {v:.3g}" + (f" +- {uu[k]:.2g}" if k in uu else "")) if isinstance(v, float) else f"{k} {v}"
            for k, v in best.parameter.items() if k != "at_grid_edge") + (
            ", at the edge of the search" if best.parameter.get("at_grid_edge") else "") + ")"
        left = ("" if best.cv_rms <= EXPLAINED_FACTOR * a.noise_floor else
                f"; UNEXPLAINED: no form comes within {EXPLAINED_FACTOR:g}x the noise floor (held-out RMS "
                f"{best.cv_rms / a.noise_floor:.2g}x it): the output has structure none of these forms holds")
        if a.best in DRIFT_FORMS:
            par = (f" (the output drifts in time by {best.coefficients[2]:+.3g} {unit}/h beside a tempco of "
                   f"{best.coefficients[1]:+.3g} {unit}/degC: not a thermal form; an aging, a warm-up or a creeping "
                   "mount)")
        parts.append(f"{a.column}: {a.best}{par}, the simplest form that predicts held-out blocks as well as the "
                     f"best (within one standard error or 1 %), RMS {best.cv_rms:.3g} {unit} against "
                     f"{lin.cv_rms:.3g} for a line (noise floor {a.noise_floor:.2g}){gap}{left}"
                     + (f"; {a.floor_note}" if a.floor_note else "")
                     + (f"; caution: {a.caveat}" if a.caveat else ""))
    return ThermalCycle(source=str(path), unit=unit, n=len(t), duration_s=float(t[-1]),
                        temperature_range_C=(float(T.min()), float(T.max())),
                        reference_temperature_C=reference_temperature_C, folds=folds, axes=axes,
                        verdict="; ".join(parts), notes=notes, t_s=t, T=T, y=y, branch=br)


def plot_cycle(cycle: ThermalCycle, path) -> None:
    """Each axis's output against temperature (heating and cooling coloured) with its best form,
    and the residuals of a line and of the best form against time."""
    from matplotlib.figure import Figure      # no pyplot: no backend, no global state

    k = len(cycle.axes)
    fig = Figure(figsize=(11, 3.2 * k))
    ax = fig.subplots(k, 2, squeeze=False)
    for i, a in enumerate(cycle.axes):
        y = cycle.y[:, i]
        for b, c, lab in ((-1.0, "tab:red", "heating"), (1.0, "tab:blue", "cooling"), (0.0, "0.6", "still")):
            m = cycle.branch == b
            ax[i, 0].plot(cycle.T[m], y[m], ".", ms=1.5, color=c, label=lab)
        ax[i, 0].plot(cycle.T, a.prediction, "-", color="k", lw=0.8, label=f"{a.best} (fit)")
        ax[i, 0].set_xlabel("temperature (°C)")
        ax[i, 0].set_ylabel(f"{a.column} ({cycle.unit})")
        ax[i, 0].legend(fontsize=7, markerscale=4)
        lin = a.form("linear")
        X = _design("linear", cycle.t_s, cycle.T, cycle.reference_temperature_C, cycle.branch, None)
        ax[i, 1].plot(cycle.t_s / 60.0, y - X @ np.array(lin.coefficients), lw=0.5, color="0.5", label="after a line")
        ax[i, 1].plot(cycle.t_s / 60.0, y - a.prediction, lw=0.5, color="k", label=f"after {a.best}")
        ax[i, 1].set_xlabel("time (min)")
        ax[i, 1].set_ylabel(f"residual ({cycle.unit})")
        ax[i, 1].legend(fontsize=7)
    fig.tight_layout()
    from ..io.atomic import atomic_path

    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
