"""The seed paper's classical method: eq. 2-3 at each setpoint, then a linear thermal line.

:func:`fit_classical` pairs each setpoint block's visits by the IMU axis pointing up (from
the bench kinematics), computes Ca, K and S in closed form with first-order uncertainties,
and fits each against its accelerometer's own sensor temperature (Birge-scaled line).
Its SD for the bench's noise model is :mod:`triadcal.uncertainty.classical_sd`.
Derivation/design: docs/classical.md (What it computes; Standard deviation of the classical angle).
Over 500 lines because the estimator and its error propagation read as one derivation; each is a
separate function. Its redundancy gate is :mod:`.classical_redundancy`, its tilt estimate and gate
:mod:`.classical_tilt`, its temperature-drift check :mod:`.classical_drift`.
"""

from __future__ import annotations

from ..errors import InputError

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..models.campaign import Campaign, nominal_gravity
from ..models.kinematics import gravity_in_imu
from ..models.sensor import ANGLE_NAMES, AXES
from .classical_sensitivity import (curvature_gate, curvature_move, curvature_note, curvature_test, hysteresis_tempco_move,
                                    hysteresis_tempco_note)
from .gates import DEFAULT_CONFIG, FitEvidence, GateConfig, apply_gates
from .classical_redundancy import leverages, redundancy_gate, worst_studentised, worst_studentised_known
from .classical_tilt import combined_tilt, tilt_leak_gate, tilt_note
from .hints import orientation_hints
from .result import CalibrationResult, ParameterValue

IMU_AXES = "XYZ"
NOISE_SOURCES = ("residuals", "sd")
THERMAL_EFFECTS = ("angle_tempco", "scale_tempco", "bias_tempco")


class ClassicalPlanError(InputError):
    """The plan of a setpoint does not let eq. 2 be formed (an IMU axis never up or down)."""


# --------------------------------------------------------------------------------------
# eq. 2-3 at one setpoint: coefficients, estimates and their exact linear propagation
# --------------------------------------------------------------------------------------
@dataclass
class Pairing:
    """Linear coefficients of eq. 2-3 over the visits of one setpoint block.

    ``difference[b] @ w`` is ``W^b`` (half the difference of the up and down means of
    IMU axis ``b``); ``balanced @ w`` is the mean over a balanced set (each group
    weighted equally), which cancels gravity; ``groups`` maps '+X', '-X', ... to the
    indices of its visits; ``unused`` are visits with no IMU axis vertical.
    """

    difference: np.ndarray   # (3, n)
    balanced: np.ndarray     # (n,)
    groups: dict
    unused: np.ndarray


def pairing(up_labels, where: str = "campaign") -> Pairing:
    """Coefficients of eq. 2-3 from each visit's up axis ('+X', '-Y', ..., '' for none).

    Raises :class:`ClassicalPlanError` naming every missing group when an IMU axis is
    never up or never down (eq. 2 needs both).
    """
    up = np.asarray(up_labels)
    n = len(up)
    groups = {s + b: np.flatnonzero(up == s + b) for b in IMU_AXES for s in "+-"}
    missing = [g for g, idx in groups.items() if len(idx) == 0]
    if missing:
        raise ClassicalPlanError(
            f"{where}: the classical method (eq. 2) needs every IMU axis pointing up and pointing "
            f"down at least once; missing: {', '.join(g + ' up' for g in missing)} "
            f"(the visits point {', '.join(sorted(set(u or 'no axis' for u in up.tolist())))} up). "
            "Add such positions to the plan or use `triadcal fit --method joint`.")
    D = np.zeros((3, n))
    bal = np.zeros(n)
    for k, b in enumerate(IMU_AXES):
        p, m = groups["+" + b], groups["-" + b]
        D[k, p] = 0.5 / len(p)
        D[k, m] = -0.5 / len(m)
        bal[p] += 0.5 / len(p) / 3.0
        bal[m] += 0.5 / len(m) / 3.0
    return Pairing(D, bal, groups, np.flatnonzero(up == ""))


def row_estimate(w: np.ndarray, pair: Pairing, gravity_g: float, axis: Optional[int] = None,
                 where: str = "campaign"):
    """Eq. 2 for one accelerometer: values and Jacobian w.r.t. its readings ``w`` (n,).

    Returns ``(values, jacobian)`` for the five quantities ``(Ca_a,b1, Ca_a,b2, ... )``
    in the order: the three elements of row ``a`` of Ca (dimensionless, direction
    cosines), ``K_a`` (g per output unit), ``S_a`` (g).

    ``axis`` (0, 1, 2): the accelerometer's own IMU axis. Eq. 1 with a small-angle Ca has
    a diagonal element ``cos`` > 0, so the sign of ``W_a^a`` is the sign of the output: an
    inverted output gives ``K_a < 0`` (which the answer gates refuse), never a row of Ca and
    a bias silently flipped. A row whose norm ``N_a`` is zero (the output does not change
    between up and down: a constant or stuck channel) is refused.
    """
    Wb = pair.difference @ w
    N = float(np.linalg.norm(Wb))
    if not (math.isfinite(N) and N > 0):
        raise ClassicalPlanError(
            f"{where}: output w_{AXES[axis] if axis is not None else '?'} does not change between the up and down "
            f"positions (|W_a| = {N:g}): a constant or stuck channel; eq. 2 cannot form its scale factor")
    sign = -1.0 if axis is not None and Wb[axis] < 0 else 1.0
    N_signed = sign * N
    row = Wb / N_signed
    dN = row @ pair.difference                      # d(N_signed)/dw
    dRow = (pair.difference - np.outer(row, dN)) / N_signed
    K = gravity_g / N_signed
    dK = -gravity_g / N_signed ** 2 * dN
    m = float(pair.balanced @ w)
    S = K * m
    dS = m * dK + K * pair.balanced
    return np.concatenate([row, [K, S]]), np.vstack([dRow, dK, dS])


def tilt_sensitivity(axis1_deg, axis2_deg) -> np.ndarray:
    """Change of the IMU-frame gravity direction per unit horizontal tilt, shape (n, 3, 2).

    From the kinematics (bench-csv.md): gravity_in_imu is linear in the base-frame
    vector, so the columns are the base ``e_x`` and ``e_y`` expressed in the IMU frame.
    """
    a1, a2 = np.radians(np.asarray(axis1_deg, float)), np.radians(np.asarray(axis2_deg, float))
    cols = [np.stack(np.broadcast_arrays(*gravity_in_imu(a1, a2, f)), axis=-1)
            for f in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))]
    return np.stack(cols, axis=-1)


def residual_design(axis1_deg, axis2_deg, row) -> np.ndarray:
    """Columns of the per-setpoint linear model of one output.

    ``W_a = sum_b W_a^b g_b + bias + tilt terms`` with ``g`` the nominal gravity of a
    level bench and the two first-order tilt columns ``row . (base e_x, e_y in the IMU
    frame)`` (``row``: the estimated row of Ca), so that a bench tilt, which the pairing
    cancels in the estimates, does not inflate the noise estimate.
    """
    g = nominal_gravity(axis1_deg, axis2_deg).reshape(-1, 3)
    h = tilt_sensitivity(axis1_deg, axis2_deg).reshape(-1, 3, 2)
    return np.column_stack([g, np.ones(len(g)), np.einsum("b,ibc->ic", np.asarray(row, float), h)])


# the thermal line and the reporting units: classical_lines.py (re-exported here)
from .classical_lines import Line, _block_diag, _line_p, _reporting, _to_reporting, thermal_line  # noqa: E402,F401


# --------------------------------------------------------------------------------------
# the estimator
# --------------------------------------------------------------------------------------
def _quantity_names():
    names = []
    for a in AXES:
        names += [f"Ca_{a}{b}" for b in AXES if b != a]
    return names + [f"K_{a}" for a in AXES] + [f"S_{a}" for a in AXES]


def _chi2_ppf(q: float, dof: float) -> float:
    from scipy import stats

    return float(stats.chi2.ppf(q, dof))


#: below this many residual degrees of freedom per accelerometer the noise is taken from the file's
#: sd_* columns when it has them (the residual estimate is then a draw of chi2 on 1 or 2 dof)
MIN_RESIDUAL_DOF = 3


def fit_classical(campaign: Campaign, reference_temperature_C: float = 20.0, *,
                  noise: str = "residuals", temperature: str = "own",
                  gates: GateConfig = DEFAULT_CONFIG, values_only: bool = False):
    """The paper's classical calibration (``triadcal fit --method classical``).

    Eq. 2-3 at every setpoint block with the up/down pairing of the bench kinematics,
    then the paper's linear thermal correction of every angle, scale factor and bias
    against the setpoint's mean temperature of its own sensor (values at
    ``reference_temperature_C`` plus ``*_tempco``). With a single setpoint temperature
    no tempco can be formed: they are absent, and the values are reported at the
    measured mean temperature (``reference_temperature_C`` of the result says which).

    ``noise``: ``"residuals"`` (default) estimates the variance of each mean output from
    the residuals of the per-setpoint linear model, pooled over the setpoints for each
    accelerometer (it contains every per-visit error the pairing does not cancel:
    output noise, bench positioning and wobble); ``"sd"`` uses ``sd_* / sqrt(n_samples)``
    of the file (output noise only). The per-setpoint estimates are in
    ``result.extra["per_setpoint"]``.

    ``values_only``: return the values ``{name: value}`` only, before the gates (no result and so no
    status: the re-runs of :func:`.classical_typeb.propagate_classical` need the estimate's values).

    ``temperature``: ``"own"`` (the default) regresses row ``a`` of Ca, ``K_a`` and ``S_a`` on
    accelerometer ``a``'s own sensor ``t_a``, the convention of every result (docs/model.md: the
    joint model ties row a to t_a); ``"mean"`` (the paper) regresses every quantity on the mean
    of ``t_x t_y t_z``. The slopes agree; the values at the reference temperature differ by
    ``tempco * (offset of t_a from the mean)`` (an outside probe: sensors +1, -0.5, +0.3 degC
    apart put the mean convention's K and S 8 u, median, from the unit's at T_ref, status ok).
    At one setpoint the rows are at their own sensors' temperatures; a note names them, and
    sensors 1 degC or more apart are refused (:func:`.one_temperature.sensor_temperatures`).
    """
    if noise not in NOISE_SOURCES:
        raise InputError(f"unknown noise source {noise!r}: choose one of {', '.join(NOISE_SOURCES)}")
    if temperature not in ("mean", "own"):
        raise InputError(f"unknown temperature choice {temperature!r}: choose 'mean' (the paper) or 'own'")
    src = campaign.source or "campaign"
    units = campaign.units
    if len(units) != 1 or len(set(campaign.state.tolist())) != 1:
        raise InputError(f"{src}: a fit takes one unit in one mechanical state; found units {units} and "
                         f"states {sorted(set(campaign.state.tolist()))} (select one, e.g. with Campaign.select)")
    G = campaign.gravity_g
    notes: list[str] = [n for n in (campaign.gravity_note(), campaign.thermometer_note()) if n]
    blocks = campaign.setpoint_blocks
    up = campaign.up_axis()
    block_ids = sorted(np.unique(blocks), key=lambda b: float(np.min(campaign.time_s[blocks == b])))

    # -- pairing and residual noise per block ------------------------------------------
    per_block = []
    rss = np.zeros(3)
    dof = np.zeros(3, int)
    red_chi2 = np.zeros(3)
    even_blocks: list = [[], [], []]       # per output: (design, outputs, known variances or None, visits, tau_s)
    resid: list = [[], [], []]
    design_w: list = [[], [], []]           # per block: design, outputs, known variances, visits (when known)
    from .joint import noise_of

    known = noise_of(campaign)
    from .noise_model import noise_notes

    notes.extend(noise_notes(campaign, known))
    if campaign.n_visits < 6 or not np.all(np.isfinite(campaign.w)):
        raise ClassicalPlanError(f"{src}: {campaign.n_visits} visits; the classical method needs every IMU axis up "
                                 "and down (at least 6 visits) with finite readings")
    for b in block_ids:
        idx = np.flatnonzero(blocks == b)
        idx = idx[np.argsort(campaign.time_s[idx], kind="stable")]
        sp, direction, cycle = float(campaign.setpoint_C[idx[0]]), str(campaign.direction[idx[0]]), int(campaign.cycle[idx[0]])
        where = f"{src}: setpoint {sp:g} degC ({direction}, cycle {cycle}"
        if campaign.lines is not None:
            where += f", lines {int(np.min(campaign.lines[idx]))}-{int(np.max(campaign.lines[idx]))}"
        where += ")"
        pair = pairing(up[idx], where)
        if len(pair.unused):
            notes.append(f"{where}: positions {', '.join(sorted(set(campaign.position[idx][pair.unused].tolist())))} "
                         "have no IMU axis vertical; eq. 2 does not use them (they enter the noise estimate)")
        h = tilt_sensitivity(campaign.axis1_deg[idx], campaign.axis2_deg[idx])  # (n, 3, 2)
        leak = np.einsum("bi,iac->bac", pair.difference, h)   # tilt -> W^b of axis a
        for k, bb in enumerate(IMU_AXES):
            for ai, a in enumerate(AXES):
                if a != bb.lower() and np.max(np.abs(leak[k, ai])) > 1e-9:
                    notes.append(f"{where}: the up/down groups of {bb} are not half-turn pairs; a bench tilt "
                                 f"enters Ca_{a}{bb.lower()} with factor {np.max(np.abs(leak[k, ai])):.3g}")
        sqrt_tau = np.sqrt(campaign.tau_s[idx])
        tilts = []
        for ai in range(3):
            v_row = row_estimate(campaign.w[idx, ai], pair, G, ai, where)[0]
            row = v_row[:3]
            X = residual_design(campaign.axis1_deg[idx], campaign.axis2_deg[idx], row) * sqrt_tau[:, None]
            y = campaign.w[idx, ai] * sqrt_tau
            coef, *_ = np.linalg.lstsq(X, y, rcond=None)
            rank = np.linalg.matrix_rank(X)
            e = y - X @ coef
            if rank == X.shape[1] and len(idx) > rank:      # the tilt columns determined on this block
                # (output units) x K / g: radians, with its covariance from the residuals; an axis
                # sees one tilt component well and the other barely (inverse-covariance weights)
                f = v_row[3] / G
                C = np.linalg.inv(X.T @ X)[4:6, 4:6] * float(e @ e) / (len(idx) - rank) * f * f
                tilts.append((coef[4:6] * f, C))
            rss[ai] += float(np.sum(e ** 2))
            dof[ai] += len(idx) - rank
            # residuals and leverages of the per-setpoint model, for the studentised residuals
            resid[ai].append((e, leverages(X), idx))
            even_blocks[ai].append((X / sqrt_tau[:, None], campaign.w[idx, ai],
                                    known.sigma[idx, ai] ** 2 if known.known else None, idx, campaign.tau_s[idx]))
            if known.known:
                # the same model weighted by the known noise of each mean output: its chi^2
                # is the disagreement of the redundant positions against that noise, and its
                # residuals are studentised against a noise that may differ from visit to visit
                Xk = X / sqrt_tau[:, None] / known.sigma[idx, ai][:, None]
                yk = campaign.w[idx, ai] / known.sigma[idx, ai]
                ck, *_ = np.linalg.lstsq(Xk, yk, rcond=None)
                red_chi2[ai] += float(np.sum((yk - Xk @ ck) ** 2)) if len(idx) > rank else 0.0
                design_w[ai].append((X / sqrt_tau[:, None], campaign.w[idx, ai], known.sigma[idx, ai] ** 2, idx))
        off = [leak[k, ai] for k, bb in enumerate(IMU_AXES) for ai, a in enumerate(AXES) if a != bb.lower()]
        per_block.append(dict(idx=idx, pair=pair, setpoint_C=sp, direction=direction, cycle=cycle, where=where,
                              leak=float(np.max(np.abs(off))) if off else 0.0,
                              tilt=combined_tilt(tilts)))

    # -- output noise ------------------------------------------------------------------
    sd_sigma = campaign.output_sigma()
    use = noise
    dof_total = int(dof.min())
    if use == "residuals" and dof_total == 0:
        if sd_sigma is None:
            raise InputError(f"{src}: cannot estimate the output noise: the per-setpoint linear model leaves no "
                             "residual degrees of freedom with this plan, and the file has no sd_*/n_samples "
                             "columns; add positions or those columns")
        use = "sd"
        notes.append("no residual degrees of freedom: output noise from sd_*/sqrt(n_samples) instead")
    elif use == "residuals" and dof_total < MIN_RESIDUAL_DOF and sd_sigma is not None:
        # an outside probe: six faces at one setpoint leave 1 dof per accelerometer; its residual estimate was
        # 0.016 of the declared noise on x, the angles' u 100 times too small (z 80 with a tilt-free bench,
        # up to 448 with a 9" tilt that the tilt test, F(2, 1), could not see), status ok, 10 of 10
        use = "sd"
        notes.append(f"{dof_total} residual degree(s) of freedom per accelerometer (fewer than {MIN_RESIDUAL_DOF}): "
                     "output noise from sd_*/sqrt(n_samples) instead (a residual estimate on so few is anywhere "
                     "from a hundredth to several times the noise); bench positioning errors are then not in the u")
    if use == "sd" and sd_sigma is None:
        raise InputError(f"{src}: noise='sd' needs the sd_x, sd_y, sd_z and n_samples columns, which the file lacks")
    fit_noise: dict = {}
    Q_res = rss / dof if dof_total > 0 else None   # output-unit^2 s (variance x tau)
    if Q_res is not None:
        fit_noise["Q_effective_from_residuals"] = [float(q) for q in Q_res]
        fit_noise["residual_dof"] = [int(d) for d in dof]
    if sd_sigma is not None:
        Q_sd = np.mean(sd_sigma ** 2 * campaign.tau_s[:, None], axis=0)
        fit_noise["Q_from_sd"] = [float(q) for q in Q_sd]
        if Q_res is not None:
            fit_noise["residual_to_sd_ratio"] = [float(math.sqrt(r / s)) if s > 0 else None
                                                 for r, s in zip(Q_res, Q_sd)]
    from .classical_structure import bench_shape, even_term, even_term_gate, geometry_variance, odd_term_gate

    shape = bench_shape(campaign.axis1_deg, campaign.axis2_deg)
    if use == "residuals":
        sigma = np.sqrt(Q_res[None, :] / campaign.tau_s[:, None])
        noise_desc = (f"residuals of the per-setpoint linear model (nominal gravity, bias, first-order tilt), "
                      f"pooled over {len(block_ids)} setpoint(s), {dof_total} dof per accelerometer; "
                      "variance of a mean taken as Q_eff / tau_s")
        # eq. 2's propagation: each visit's own variance, the noise plus the bench's scatter where the
        # kinematics let it move the output (classical_structure.geometry_variance)
        geo = [geometry_variance(even_blocks[ai], shape[:, ai], campaign.n_visits) for ai in range(3)]
        if all(v is not None for v in geo):
            sigma_eq2 = np.sqrt(np.column_stack(geo))
            noise_desc += ("; eq. 2 propagates each visit's own variance, " + (
                "the stated noise (sd_*) plus" if known.known else "a noise level plus") + " the bench's scatter "
                "where its random rotations move the output (the kinematics' shape, Paule-Mandel or moments)")
        else:
            sigma_eq2 = sigma
    else:
        sigma = sigma_eq2 = sd_sigma
        noise_desc = f"{campaign.output_sigma_method()} (output noise only; bench positioning errors not included)"

    # -- eq. 2 per block with exact linear propagation ------------------------------------
    qnames = _quantity_names()
    est = np.zeros((len(per_block), len(qnames)))
    var = np.zeros_like(est)
    temps = np.zeros(len(per_block))
    temps_own = np.zeros((len(per_block), 3))
    per_setpoint = []
    tilt_notes = []
    for k, blk in enumerate(per_block):
        idx, pair = blk["idx"], blk["pair"]
        vals, us = {}, {}
        # a bench tilt delta scales the vertical gravity by cos(delta): eq. 2's K and S come out divided
        # by it (docs/classical.md). The block's redundant positions estimate the tilt (the per-setpoint
        # model's tilt columns), and K, S are multiplied back (an outside probe: a 0.2-0.5 deg tilt left
        # K 20-35 ppm, up to 27 u, high with status ok; 60" is 4e-8)
        t_hat = blk.get("tilt")
        cos_tilt = 1.0 if t_hat is None else math.sqrt(max(0.0, 1.0 - float(t_hat @ t_hat)))
        tilt_arcsec = None if t_hat is None else math.degrees(math.acos(cos_tilt)) * 3600.0
        if tilt_arcsec is not None:
            tilt_notes.append(tilt_arcsec)
        for ai, a in enumerate(AXES):
            v, J = row_estimate(campaign.w[idx, ai], pair, G, ai, blk["where"])
            V = np.sum(J * J * (sigma_eq2[idx, ai] ** 2)[None, :], axis=1)
            for bi, b in enumerate(AXES):
                if b != a:
                    vals[f"Ca_{a}{b}"], us[f"Ca_{a}{b}"] = v[bi], V[bi]
            vals[f"K_{a}"], us[f"K_{a}"] = v[3] * cos_tilt, V[3] * cos_tilt ** 2
            vals[f"S_{a}"], us[f"S_{a}"] = v[4] * cos_tilt, V[4] * cos_tilt ** 2
        est[k] = [vals[n] for n in qnames]
        var[k] = [us[n] for n in qnames]
        temps[k] = float(np.mean(campaign.t[idx]))
        temps_own[k] = np.mean(campaign.t[idx], axis=0)
        per_setpoint.append({
            "setpoint_C": blk["setpoint_C"], "direction": blk["direction"], "cycle": blk["cycle"],
            "mean_temperature_C": temps[k], "sensor_temperature_C": [float(x) for x in temps_own[k]],
            "tilt_arcsec": tilt_arcsec,
            "time_s": float(np.mean(campaign.time_s[idx])),
            "n_visits": int(len(idx)),
            "parameters": {n: _reporting(n, est[k, j], math.sqrt(var[k, j]), campaign.output_unit)
                           for j, n in enumerate(qnames)},
        })

    if tilt_note(tilt_notes):
        notes.append(tilt_note(tilt_notes))
    # -- the paper's linear thermal correction -------------------------------------------
    distinct = len(set(round(t, 6) for t in (b["setpoint_C"] for b in per_block)))
    slope = distinct >= 2
    T_ref = float(reference_temperature_C)
    if not slope:
        T_ref = float(np.mean(temps))
        notes.append(f"a single setpoint temperature: no thermal correction and no tempcos; the values are at the "
                     f"accelerometers' mean temperature {T_ref:.2f} degC, not at {reference_temperature_C:g} degC")
    dirs = set(np.asarray(campaign.direction).astype(str).tolist())
    if slope and not {"heating", "cooling"} <= dirs:
        # an outside probe: 20 degC (none) then 60 degC (heating), angle hysteresis 2-6 arcsec: the angle
        # tempcos 3.9-6.4 u off, status ok, no word; on both branches the lines' scatter shows it (Birge)
        seen = sorted(d for d in dirs if d in ("heating", "cooling")) or ["no branch"]
        notes.append(f"the setpoints were visited on {' and '.join(seen)} only"
                     + (" (and at steady temperatures)" if "none" in dirs and seen != ["no branch"] else "")
                     + ": a thermal hysteresis of the angles is not seen (on both branches the lines' scatter "
                       "shows it and widens u), so the angles hold up to its half-width h and, where visits of "
                       "different history lie at different temperatures, the tempcos up to h over the span between "
                       "them; visit both branches to measure it (--method joint estimates h)")
    if not np.all(var > 0):
        notes.append("the per-setpoint variances are zero (no output noise); the thermal line is unweighted and "
                     "its uncertainty comes from its scatter alone")
    params: dict = {}
    hyst_moves: dict = {}
    curv_moves: dict = {}
    curv_tests: dict = {}
    branch_of_block = np.array([{"cooling": 1.0, "heating": -1.0}.get(str(b["direction"]), 0.0) for b in per_block])
    corr_names: list = []
    blocks_cov: list = []
    chi2_by, chi2_sum, dof_sum = {}, 0.0, 0
    off_line = []
    unit_out = campaign.output_unit
    slopes = np.zeros(len(qnames))              # per degC, internal units (the drift check's)
    for j, n in enumerate(qnames):
        T_j = temps if temperature == "mean" else temps_own[:, AXES.index(n.split("_")[1][0])]
        if slope and np.ptp(T_j) == 0.0:
            # a stuck thermometer the reader let through (# t_override = true): no line to fit
            raise InputError(f"{campaign.source}: the temperature of the {n.split('_')[1][0]} accelerometer's sensor "
                             f"is {T_j[0]:g} degC at every setpoint while the setpoints differ: the thermal line of "
                             f"{n} cannot be fitted (a stuck thermometer? repair the column)")
        line = thermal_line(T_j, est[:, j], var[:, j], T_ref, slope)
        slopes[j] = float(line.coef[1]) if slope else 0.0
        if slope and n.startswith("Ca_") and {"heating", "cooling"} <= dirs and len(T_j) > 2:
            hyst_moves[n] = hysteresis_tempco_move(T_j, var[:, j], branch_of_block, T_ref,
                                                   float(np.sqrt(line.cov[1, 1])))
        curv = curvature_move(T_j, var[:, j], T_ref, line.cov, line.birge) if slope else None
        if curv is not None:
            curv_moves[n] = curv
            curv_tests[n] = curvature_test(T_j, est[:, j], var[:, j], T_ref)
        chi2_by[n] = line.chi2_dof
        p_line = _line_p(line, var[:, j])
        if p_line is not None and p_line < gates.gof_p_min and line.chi2_dof > gates.gof_ratio_max:
            off_line.append((n, line.chi2_dof, p_line))
        chi2_sum += line.chi2
        dof_sum += line.dof
        names_j, vals_j, cov_j = _to_reporting(n, line, slope, unit_out)
        for nm, (v, u, unit) in zip(names_j, vals_j):
            params[nm] = ParameterValue(float(v), float(u), unit)
        corr_names += names_j
        blocks_cov.append(cov_j)
    if off_line:
        off_line.sort(key=lambda x: -x[1])
        notes.append(
            f"the per-setpoint values of {len(off_line)} quantit{'y' if len(off_line) == 1 else 'ies'} do not lie on "
            f"a {'straight line in temperature' if slope else 'constant'} within their uncertainty (p < "
            f"{gates.gof_p_min:g} and chi2/dof > {gates.gof_ratio_max:g}): "
            + ", ".join(f"{n} chi2/dof {r:.3g} (p {f'= {p:.2g}' if p > 0 else '< 1e-300'}; u widened x{math.sqrt(r):.3g})"
                        for n, r, p in off_line)
            + ". The Birge ratio widens their u instead of ignoring the scatter, and their value at the reference "
            "temperature is the line's: a hysteresis, a change of the unit during the campaign or a law of "
            "temperature that is not a line would do this; `triadcal diagnose` says which, and the joint fit "
            "models it")
    for note in (hysteresis_tempco_note(hyst_moves), curvature_note(curv_moves, T_ref)):
        if note:
            notes.append(note)
    order = [f"Ca_{ab}" for ab in ANGLE_NAMES] + [f"K_{a}" for a in AXES] + [f"S_{a}" for a in AXES]
    ordered = {}
    for base in order:
        for nm in (base, base + "_tempco"):
            if nm in params:
                ordered[nm] = params[nm]
    if values_only:                  # the estimate's values, for a sensitivity; no result, so no status
        return {n: p.value for n, p in ordered.items()}
    cov_all = _block_diag(blocks_cov)
    u_all = np.sqrt(np.diag(cov_all))
    corr = cov_all / np.outer(np.where(u_all > 0, u_all, 1.0), np.where(u_all > 0, u_all, 1.0))

    fit = {"n_obs": int(est.size), "temperature": ("mean of t_x t_y t_z" if temperature == "mean"
                                                   else "each accelerometer's own sensor t_a"), "n_params": int(len(params)),
           "chi2_dof": (chi2_sum / dof_sum) if dof_sum > 0 else None,
           "chi2_dof_by_parameter": chi2_by,
           "n_setpoints": len(per_block), "n_visits": int(campaign.n_visits),
           "thermal_model": ("straight line against the setpoint's "
                             + ("mean accelerometer temperature" if temperature == "mean"
                                else "mean of each accelerometer's own sensor") + ", weighted "
                             "least squares, covariance scaled by max(1, chi2/dof) (Birge ratio)")
           if slope else "none (single setpoint temperature)",
           "noise_source": use, "noise": noise_desc, **fit_noise}
    T = campaign.t
    # against the known noise of each visit plus the bench's own scatter, else the unweighted
    # residuals (their level pooled where the blocks agree on it)
    worst = (worst_studentised_known(design_w, dof, campaign) if known.known
             else worst_studentised(resid, rss, dof, campaign))
    redundancy = redundancy_gate(red_chi2, dof, known.known, known.description, gates, use, worst)
    fit["redundancy"] = redundancy.to_dict()
    if hyst_moves:
        fit["hysteresis_sensitivity"] = hyst_moves
    if curv_moves:
        fit["curvature_sensitivity"] = curv_moves
    # the tilt test's noise: the residuals' (F on their dof), or the sd columns' (chi2) where the residuals
    # show no significant excess over them (no bench error to hold). On F(2, 5) a six-face campaign at five
    # setpoints with a 9" tilt was ok with angles 10-17 u off in 5 of 10 (an outside probe)
    t_sigma, t_dof = sigma, (dof_total if use == "residuals" else None)
    if use == "residuals" and sd_sigma is not None and Q_res is not None and \
            all(d > 0 and r <= s * _chi2_ppf(0.99, d) / d for r, s, d in zip(Q_res, Q_sd, dof)):
        t_sigma, t_dof = sd_sigma, None
    g_nom = nominal_gravity(campaign.axis1_deg, campaign.axis2_deg).reshape(-1, 3)
    from .planned_effects import planned

    plan = planned(campaign) or ()
    even = even_term_gate([even_term(even_blocks[ai], g_nom, ai, known.known, shape, j)
                           for ai in range(3) for j in range(3)],
                          {a: ordered[f"S_{a}"].u for a in AXES}, {a: ordered[f"K_{a}"].value for a in AXES},
                          campaign.output_unit, gates,
                          planned=next((e for e in ("scale_nonlinearity", "scale_asymmetry") if e in plan), None))
    if even is not None:
        fit["orientation_even_term"] = even.to_dict()
    # K3: the faces read (1 + K3) g, and only oblique poses (|g_a| between 0 and 1) tell it from K_a
    odd, odd_note = odd_term_gate([even_term(even_blocks[ai], g_nom, ai, known.known, shape, power=3,
                                             move_of=[b["pair"].difference[ai] for b in per_block])
                                   for ai in range(3)],
                                  {a: ordered[f"K_{a}"].u for a in AXES}, {a: ordered[f"K_{a}"].value for a in AXES},
                                  G, campaign.output_unit, gates, planned="scale_cubic" in plan)
    if odd is not None:
        fit["orientation_odd_term"] = odd.to_dict()
    if odd_note:
        notes.append(odd_note)
    tilt = tilt_leak_gate(campaign, per_block, t_sigma, gates, noise_dof=t_dof)
    if tilt is not None:
        fit["tilt_leak"] = tilt.to_dict()
    curvature = curvature_gate(curv_tests, gates.gof_p_min) if slope else None
    drift = None
    if slope:
        from .classical_drift import DRIFT_BIAS_U_NOTE, drift_bias, drift_gate

        spread = max(float(np.max(np.ptp(campaign.t[b["idx"]], axis=0))) for b in per_block)
        drift = drift_gate(drift_bias(campaign, per_block, est, var, slopes, qnames, G, temperature == "own"),
                           ordered, spread)
        if drift is not None:
            fit["temperature_drift"] = drift.to_dict()
            if drift.passed and drift.value is not None and drift.value > DRIFT_BIAS_U_NOTE:
                notes.append(drift.reason)
    result = CalibrationResult(
        unit=units[0], method="classical", parameters=ordered, status="ok",
        effects=THERMAL_EFFECTS if slope else (), reference_temperature_C=T_ref,
        temperature_range_C=(float(T.min()), float(T.max())), fit=fit,
        correlation_names=tuple(corr_names), correlation=corr, notes=notes,
        extra={"per_setpoint": per_setpoint, "output_unit": unit_out,
               "local_g_m_s2": campaign.local_g_m_s2, **campaign.provenance()})
    sensor_gate = None
    if temperature == "own" and not slope:           # one setpoint: each row at its own sensor's temperature
        from .one_temperature import sensor_temperatures

        sensor_note, sensor_gate, sensor_temps = sensor_temperatures(campaign)
        if sensor_note:
            result.notes.append(sensor_note)
        if sensor_temps is not None:
            result.fit["sensor_temperatures_C"] = sensor_temps
    apply_gates(result, FitEvidence(converged=True, n_obs=3 * campaign.n_visits, n_free=15 * len(per_block),
                                    extra=[redundancy] + [g for g in (tilt, drift, curvature, sensor_gate, even, odd)
                                                                          if g is not None]),
                config=gates)
    if result.status != "ok":
        for hint in orientation_hints(campaign.w, g_nom):
            result.notes.append(f"hint: {hint}")
    from .classical_typeb import with_type_a_budgets

    return with_type_a_budgets(result)
