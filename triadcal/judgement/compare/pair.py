"""``compare``: the drift of every parameter of two results, their joint test and the verdict.
"""

from __future__ import annotations
from ...errors import InputError
import math
import os
from dataclasses import replace
from typing import Mapping, Optional, Sequence, Union
import numpy as np
from scipy import stats
from ...estimation.one_temperature import ROWS_APART_C, row_temperatures_C
from ...estimation.result_checks import check_result_for_use
from ...estimation.result import CalibrationResult
from ...models.units import canonical_scale_unit
from ...io.lab import EQUIPMENT_SECTIONS, SHAREABLE_SECTIONS
from .rule import (check_tolerance, combined_covariance, coverage_factors, decide, decide_from_draws, drift_uncertainty,
                   normalised_error, probability_exceeds, rule_text)
from .correlation import (budget_rho_limits, rho_rescaled, stated_rho_beyond_budgets,  # noqa: F401
                          CORRELATION_TERMS, check_posterior, derive_correlation, posterior_draws, posterior_drift,
                          read_posterior, shared_errors)
from .results import ANGLES, BENCH_PARAMETERS, ComparisonResult, JointTest, ParameterDrift
from .carry import ROW_QUANTITIES, carry_rows
from ...models.sensor import AXES


#: equipment that can be shared: the lab-file sections with systematic errors of their own (Type B
#: rows, triadcal.uncertainty.typeb), the list the lab file's ``[compare] shared_equipment`` accepts.
#: ``[chamber]`` has none: its ``temperature_uncertainty_C`` is the thermometers' row ``[thermometers] u_C``
SHAREABLE_EQUIPMENT = SHAREABLE_SECTIONS


# NOT_PASS_NOTE (a held-back verdict's note starts with it), refusals and hold-backs of a comparison's own (a negative rho, data out of order, a held-back note)
from .guards import (BENCH_MOUNTED, NEGATIVE_RHO_REASON, NOT_PASS_NOTE, _held_note, _hold,  # noqa: E402,F401
                     COPY_Z_MAX, bench_contradicts_sharing, check_data_order, copied_data,
                     same_calibration)
from .rotation import rotation_verdict  # noqa: E402
from .thermometer import thermometer_verdict  # noqa: E402


def shared_sha256(before: Mapping, after: Mapping) -> Optional[str]:
    """The hash two results' descriptions (``extra``, or the compare JSON's ``before``/``after``)
    share when they are fits of one data set: the same ``data_sha256`` (the same visits, whatever
    the method or options), or one's ``derived_from_sha256`` (a bench CSV averaged from a raw
    recording by ``fit-raw --bench-csv``) equal to the other's hash. None otherwise."""
    def hashes(d):
        return {d.get(k) for k in ("data_sha256", "derived_from_sha256") if isinstance(d.get(k), str) and d.get(k)}

    common = hashes(before) & hashes(after)
    return sorted(common)[0] if common else None


def same_data(before: CalibrationResult, after: CalibrationResult) -> Optional[str]:
    """The hash both results share when they are fits of one data set (:func:`shared_sha256`):
    their differences are the estimators', not a drift of the unit. None when they share none."""
    return shared_sha256(before.extra, after.extra)


#: two single-temperature calibrations whose temperatures differ by at most this (degC) are compared:
#: one chamber setpoint, within its stability and the unit's self-heating
SAME_TEMPERATURE_C = 0.2


def _has_tempcos(r) -> bool:
    return any("_tempco" in n for n in r.parameters)


#: bounds of the temperature coefficients a calibration at one temperature does not measure, per
#: degC: K relative (1e-6 = 1 ppm), S in g, the angles in arcsec. For the rows of two such
#: calibrations that are apart, the drift holds a bias within +-bound x dT, which the rule takes at
#: its worst (:func:`.rule.decide`). The largest the project knows, with margin: its silicon
#: preset's K 130 ppm, S 120 ug, angles 4.9"/degC (the paper's A-18); consumer MEMS datasheets'
#: sensitivity +-0.02 %/degC (MPU-6050) and zero-g offset up to ~0.8 mg/degC (ADXL345 class)
TEMPCO_BOUND = {"K": 300e-6, "S": 1e-3, "Ca": 10.0}


def tempco_bound(name: str, value: float, row_dT: Mapping[str, float]) -> float:
    """The half-width of the bias a temperature coefficient neither calibration measured puts in
    the drift, for rows ``row_dT`` (degC apart, per accelerometer): ``TEMPCO_BOUND x dT`` for K_a
    (relative to its value), S_a and Ca_ab (row a); 0 for any other parameter. An outside probe:
    two calibrations of an unmoved unit with K's tempco 100 ppm/degC, rows 0.15 degC apart, gave
    K_x's drift z -5.1 and the verdict fail; with the bound as a rectangular u (bound/sqrt 3) a unit
    at the bound still failed (K tolerance 20 ppm: 6 of 25; the joint test without a tolerance: 14 of
    25), so the rule takes the bound at its worst."""
    kind, _, rest = name.partition("_")
    if kind not in TEMPCO_BOUND or len(rest) not in (1, 2) or rest[0] not in row_dT or (kind == "Ca") != (len(rest) == 2):
        return 0.0
    scale = abs(value) if kind == "K" else 1.0
    return TEMPCO_BOUND[kind] * scale * row_dT[rest[0]]


def _temperature_notes(before: CalibrationResult, after: CalibrationResult,
                       tags: tuple = ("before", "after")) -> tuple:
    """The pair's temperatures, row by row (:func:`.row_temperatures_C`: K_a, S_a and Ca_ab hold at
    t_a in a calibration at one temperature whose sensors read apart).

    One with tempcos and one without: the one with tempcos is carried by its own temperature terms to
    the other's rows (:func:`.carry.carry_rows`, within its calibrated range), whatever the two
    reference temperatures; its hysteresis loop, if it has one, becomes a bound of the angles'
    drifts (the check's branch unknown). Both with tempcos: the reference temperatures must agree
    (refit one at the other's). Neither: refuse (InputError) rows more than :data:`SAME_TEMPERATURE_C`
    apart; a note for rows up to that, whose drift also holds the unmeasured tempcos times their
    distance. An outside probe: sensors at +0.45, -0.4, 0 degC in one calibration and at one
    temperature in the other, both means 20 degC, compared silently. Returns ``(notes, dT, before,
    after, carried)``: ``dT`` the rows' distance (degC) per accelerometer, all 0 when no row is
    :data:`ROWS_APART_C` apart; ``before``/``after`` the results as compared (one carried);
    ``carried`` the bound per carried parameter (0 without a loop)."""
    tb, ta = row_temperatures_C(before), row_temperatures_C(after)
    dT = {a: abs(tb[a] - ta[a]) for a in tb}
    worst = max(dT, key=dT.get)
    where = ", ".join(f"{a} {tb[a]:.2f} -> {ta[a]:.2f}" for a in tb)
    tempcos = [tag for tag, r in zip(tags, (before, after)) if _has_tempcos(r)]
    pair = f"{tags[0]} and {tags[1]}"
    if len(tempcos) == 1:
        i = tags.index(tempcos[0])
        ranged, target = (before, ta) if i == 0 else (after, tb)
        moved, bounds, names = carry_rows(ranged, target, f"{tags[i]} (with tempcos)")
        notes = []
        if names:
            notes.append(f"{tags[i]}, calibrated over {ranged.temperature_range_C[0]:.2f}...{ranged.temperature_range_C[1]:.2f}"
                         f" degC with its reference at {ranged.reference_temperature_C:g} degC, is carried by its own "
                         f"temperature terms to the rows of {tags[1 - i]} at one temperature ("
                         + ", ".join(f"{a} {target[a]:.2f}" for a in AXES) + " degC): " + ", ".join(names)
                         + "; their u hold the tempcos' u and correlations (GUM eq. 13)")
        if bounds:
            notes.append(f"{tags[i]} has a thermal hysteresis loop and {tags[1 - i]}, at one temperature, does not say "
                         "on which branch it was: the drift of " + ", ".join(bounds) + " holds a bias within +-the "
                         "loop's half-width (tempco_bound), taken at its worst by the rule")
        # rows of a quantity the tempcos did not carry (no tempco of its family) keep dT and its bound
        left = [n for n in ROW_QUANTITIES if n in ranged.parameters and n not in names and dT[n.split("_", 1)[1][0]] > 0]
        if left and dT[worst] > SAME_TEMPERATURE_C + 1e-9:
            raise InputError(f"{pair}: {tags[i]} has no tempcos of {', '.join(left)}, whose rows differ by up to "
                             f"{dT[worst]:.2f} degC ({where} degC): calibrate again at the other's temperature")
        if names or bounds:
            dT_left = dT if dT[worst] >= ROWS_APART_C else {a: 0.0 for a in dT}
            carried = {n: 0.0 for n in names}
            # a loop on a quantity not carried (no tempco of its family) adds to its unmeasured tempco's bound
            carried.update({n: h + (0.0 if n in names else tempco_bound(n, before[n].value, dT_left))
                            for n, h in bounds.items()})
            return (notes, dT_left) + ((moved, after) if i == 0 else (before, moved)) + (carried,)
    # a calibration with tempcos can be refitted at the other's reference temperature: then it must be
    if len(tempcos) == 2 and before.reference_temperature_C != after.reference_temperature_C:
        raise InputError(f"{pair}: reference temperatures differ ({before.reference_temperature_C:g} vs "
                         f"{after.reference_temperature_C:g} degC): refit {' or '.join(tempcos)}, which has "
                         "tempcos, at the other's reference temperature so the values are comparable")
    # 1e-9: temperatures written to 0.01 degC, 25.1 - 24.9 is 0.20000000000000284 (an outside probe)
    if dT[worst] > SAME_TEMPERATURE_C + 1e-9:
        one = [tag for tag in tags if tag not in tempcos]
        what = ("reference temperatures differ" if abs(before.reference_temperature_C - after.reference_temperature_C)
                > SAME_TEMPERATURE_C + 1e-9 else "the accelerometers' temperatures differ")
        raise InputError(f"{pair}: {what} ({before.reference_temperature_C:g} vs {after.reference_temperature_C:g} "
                         f"degC; per accelerometer {where} degC, up to {dT[worst]:.2f} degC apart in row {worst}): "
                         f"{' and '.join(one)}, without tempcos, may differ from the other's by at most "
                         f"{SAME_TEMPERATURE_C:g} degC, since no tempco carries the values; calibrate again at the "
                         "other's setpoint, or over a range of temperatures")
    if dT[worst] < ROWS_APART_C:
        return [], {a: 0.0 for a in dT}, before, after, {}
    who = ("neither calibration measured" if not tempcos else
           f"{' and '.join(tag for tag in tags if tag not in tempcos)} at one temperature did not measure")
    return [f"one temperature: the rows are at {where} degC ({tags[0]} -> {tags[1]}): the drift also holds the "
            f"unit's temperature coefficients times up to {dT[worst]:.2f} degC (row {worst}), which {who}; each "
            "K, S and angle's drift holds a bias within +-bound x dT of its row (tempco_bound), taken at its worst "
            f"by the rule, bounds K {TEMPCO_BOUND['K'] * 1e6:g} ppm, S {TEMPCO_BOUND['S'] * 1e6:g} ug, angles "
            f"{TEMPCO_BOUND['Ca']:g} arcsec per degC"], dT, before, after, {}


def compare(before: CalibrationResult, after: CalibrationResult, *, tolerance_arcsec: Optional[float] = 30.0,
            tolerances: Optional[Mapping[str, float]] = None, posterior_before=None, posterior_after=None,
            correlation: Union[str, float] = "auto", level: float = 0.95,
            label: Optional[str] = None, shared_equipment: Sequence[str] = (),
            files: Optional[Sequence[str]] = None) -> ComparisonResult:
    """Drift of every parameter from ``before`` to ``after`` and the verdicts (``triadcal compare``).

    ``tolerance_arcsec``: tolerance on the drift of each angle (None: significance only).
    ``tolerances``: tolerances of parameters by name, in their unit (e.g.
    ``{"K_x": 2e-5}``); those parameters then enter the overall verdict. An angle given one
    (``{"Ca_xy": 10}``, arcsec) is judged against it instead of ``tolerance_arcsec`` (a note says so).
    Every tolerance must be a finite number >= 0 (None: significance only).
    ``posterior_before``/``posterior_after``: arviz InferenceData or netCDF paths whose
    ``posterior`` variables are named like the parameters (reporting units).
    ``correlation``: ``"auto"`` (derived, see :func:`derive_correlation`) or a coefficient
    rho in [-1, 1] between the two calibrations' errors, applied to every parameter.
    ``shared_equipment``: lab-file sections (``("bench", "gravity")``) whose systematic errors
    are the same in both calibrations (same equipment, no adjustment between them). Default
    none: the Type B rows of the two budgets are independent (the conservative case). Shared,
    a source of that equipment in both budgets (same ``source``, same ``u``) gives
    ``var(d) = u_b^2 + u_a^2 - 2 sum_s c_b,s c_a,s u_s^2`` per parameter (reported as the
    parameter's ``rho``) and ``C_b + C_a - X - X^T`` for the joint test (docs/compare.md).
    ``files``: the names of the before and after results (and messages name them).

    A posterior is checked against its result (:func:`.correlation.check_posterior`: serial,
    parameter set, the certificate's fingerprint and convergence checks, means against values)
    and refused, named, when it is not that result's. The overall verdict is never pass when
    before and after are the same calibration (:func:`same_calibration`) or an angle is missing
    from a result: inconclusive, with a note starting ``NOT_PASS_NOTE``.
    """
    k2, _ = coverage_factors(level)
    tag_b, tag_a = (str(files[0]), str(files[1])) if files else ("before", "after")
    if tolerance_arcsec is not None:
        tolerance_arcsec = check_tolerance(tolerance_arcsec, "the angles' tolerance (arcsec)")
    tolerances = {str(k): check_tolerance(v, f"the tolerance of {k}") for k, v in dict(tolerances or {}).items()}
    notes = []
    # a drift between calibrations one of which is not an answer is not a drift: refuse, naming
    # the side (status not ok, a value or u not finite, u < 0, a failing answer gate)
    for tag, r in (("before", before), ("after", after)):
        check_result_for_use(r, f"the {tag} calibration ({r.unit}, {r.method})")
    if before.unit != after.unit:
        raise InputError(f"before is unit {before.unit!r} and after is unit {after.unit!r}: a drift compares "
                         "two calibrations of the same unit")
    check_data_order((before, after), (tag_b, tag_a))
    originals = {"before": before, "after": after}        # a posterior is checked against its own result
    t_notes, row_dT, before, after, carried = _temperature_notes(before, after, (tag_b, tag_a))
    notes.extend(t_notes)
    # angles held by definition (under `fixed` and not `unidentifiable`: an angle the data could not
    # determine is a missing angle, below, not a frame)
    frame = {tag: sorted(n for n in (r.extra.get("fixed") or {}) if _is_angle(n) and n not in r.parameters
                         and n not in (r.extra.get("unidentifiable") or {}))
             for tag, r in (("before", before), ("after", after))}
    if frame["before"] != frame["after"]:
        # fit-raw --poses unknown defines its frame by Ca_yx = Ca_zx = Ca_zy = 0 (the gravity-norm
        # method): its angles are not the known-pose fit's, and their difference is the frames'
        held = "; ".join(f"{tag}: {', '.join(v) if v else 'none'}" for tag, v in frame.items())
        raise InputError(f"the angles are in different frames: the angles held fixed by the fit's definition of its "
                         f"frame differ ({held}); a drift compares two calibrations in one frame (both with known "
                         "poses, or both with --poses unknown)")
    if before.method != after.method:
        notes.append(f"methods differ ({before.method} vs {after.method}): a drift also contains the "
                     "difference between the estimators")
    gb, ga = before.extra.get("local_g_m_s2"), after.extra.get("local_g_m_s2")
    if gb is not None and ga is not None and gb != ga:
        # an outside probe: the K drift of a unit calibrated at 9.80665 and at 9.78 m/s^2 was 0 (z 0.5),
        # each fit having scaled K to its own stated g; the note said the drift "contains" the difference
        notes.append(f"local gravity differs ({gb} vs {ga} m/s^2): each fit scaled K to its own stated g, so the K "
                     "drift holds the difference only as far as either stated value is wrong (its u is in a "
                     "result's budget when the lab file states one)")
    unhashed = [t for t, r in ((tag_b, before), (tag_a, after)) if getattr(r, "content_unhashed", False)]
    if unhashed:
        # an outside probe: content_sha256 deleted and Ca_xy edited by +20 arcsec: compared without a word
        notes.append(f"{' and '.join(unhashed)} hold{'s' if len(unhashed) == 1 else ''} no content_sha256 (another "
                     "writer, or triadcal before 2026-11-30): nothing shows that the values compared are the fit's "
                     "answer and not edited; a certificate is refused for such a file")

    if isinstance(shared_equipment, str):
        shared_equipment = (shared_equipment,)
    shared_equipment = tuple(dict.fromkeys(str(e).strip().strip("[]") for e in (shared_equipment or ())))
    unknown_eq = [e for e in shared_equipment if e not in EQUIPMENT_SECTIONS]
    if unknown_eq:
        raise InputError(f"shared equipment {', '.join(map(repr, unknown_eq))} is not a lab-file equipment section "
                         f"({', '.join(EQUIPMENT_SECTIONS)})")
    unshareable = [e for e in shared_equipment if e not in SHAREABLE_EQUIPMENT]
    if unshareable:
        raise InputError(f"shared equipment {', '.join(map(repr, unshareable))} has no systematic error of its own in "
                         "a budget, so there is nothing to share ([chamber] temperature_uncertainty_C is the "
                         "thermometers' row, [thermometers] u_C: share 'thermometers'); shareable: "
                         f"{', '.join(SHAREABLE_EQUIPMENT)}")
    if isinstance(correlation, str):
        if correlation != "auto":
            raise InputError(f"correlation must be 'auto' or a number in [-1, 1], got {correlation!r}")
        rho, reason = derive_correlation(before, after, shared_equipment)
    else:
        rho = float(correlation)
        if not -1.0 < rho < 1.0:
            # rho = 1 makes u(d) = |u_b - u_a| (0 for equal u): the two calibrations would share every
            # error, their noise too, and any drift would be infinitely significant (an outside probe:
            # an unmoved unit failed with D2 4e10, nothing said)
            raise InputError(f"correlation must lie strictly between -1 and 1, got {rho:g}: at +-1 the two "
                             "calibrations would share every error, their noise included, and u(d) vanishes")
        if rho < 0.0:
            raise InputError(f"correlation = {rho:g}: {NEGATIVE_RHO_REASON}")
        reason = f"rho = {rho:g} stated by the user for every parameter"
        if shared_equipment:
            raise InputError("give either a correlation coefficient or shared equipment, not both: the shared "
                             "equipment's correlation is derived from the budgets, parameter by parameter")

    names = [n for n in before.parameters if n in after.parameters and n not in BENCH_PARAMETERS]
    for n in names:
        if canonical_scale_unit(before[n].unit) != canonical_scale_unit(after[n].unit):
            raise InputError(f"{n}: unit {before[n].unit!r} before and {after[n].unit!r} after")
    only = sorted(set(before.parameters) ^ set(after.parameters))
    if only:
        notes.append("not compared (present in one result only): " + ", ".join(only))
    bench = [n for n in tolerances if n in BENCH_PARAMETERS]
    if bench:
        # an outside probe's --param-tolerance tilt_x=5 was told tilt_x is "not in both results"
        raise InputError(f"tolerances given for {bench}: parameters of the bench, not of the unit; compare "
                         "judges the unit and reports the bench's change in bench_check, without a verdict")
    unknown = [n for n in tolerances if n not in names]
    if unknown:
        raise InputError(f"tolerances given for {unknown}, which are not in both results")
    own = [n for n in ANGLES if n in tolerances]
    if own:
        notes.append("judged against their own tolerance (not the angles' "
                     + ("none" if tolerance_arcsec is None else f"{tolerance_arcsec:g} arcsec") + "): "
                     + ", ".join(f"{n} (T = {tolerances[n]:g} arcsec)" for n in own))
    # the six angles are in every result of eq. 1: one missing from a side is not a drift of zero
    missing_angles = [n for n in ANGLES if n not in names]

    shared = shared_errors(before, after, names, shared_equipment)
    notes.extend(shared.notes)
    # a stated rho beyond what the budgets hold: every verdict is also made at the supported rho (per
    # parameter its own limit; the joint test at the least of them) and one that differs is held back.
    # The budgets support rho in [0, limit]: a negative one was refused above, so every stated rho
    # outside what they support is either refused or checked here
    supported = {}
    if not isinstance(correlation, str) and rho > 0:
        over = stated_rho_beyond_budgets(before, after, names, rho)
        if over:
            notes.append(over)
            supported = {n: min(rho, lim) for n, lim in budget_rho_limits(before, after, names).items()}
    verdicts_supported = {}

    if (posterior_before is None) != (posterior_after is None):
        raise InputError("give posteriors for both calibrations (before and after), or for neither")
    post_b = post_a = None
    if posterior_before is not None:
        posts = []
        for tag, source, name in (("before", posterior_before, tag_b), ("after", posterior_after, tag_a)):
            r = originals[tag]
            what = (f"posterior {source} (of the {tag} calibration {name})" if isinstance(source, (str, os.PathLike))
                    else f"the posterior of the {tag} calibration ({name})")
            data = read_posterior(source)
            draws = posterior_draws(data)
            check_posterior(data, draws, r, what)
            posts.append(draws)
        post_b, post_a = posts

    params, type_b_added, bounded = {}, [], []
    for n in names:
        b, a = before[n], after[n]
        T = tolerances.get(n, tolerance_arcsec) if n in ANGLES else tolerances.get(n)
        judged = n in ANGLES or n in tolerances
        d = a.value - b.value
        rho_n = rho
        cov_shared = shared.covariance(n) if shared.sources else 0.0
        if shared.sources:
            # per-parameter rho of the shared systematic errors: u_b^2 + u_a^2 - 2 rho u_b u_a is then
            # u_b^2 + u_a^2 - 2 sum_s c_b,s c_a,s u_s^2
            rho_n = cov_shared / (b.u * a.u) if b.u > 0 and a.u > 0 else 0.0
            if abs(rho_n) > 1.0 + 1e-9:
                raise InputError(f"{n}: the shared systematic errors' covariance {cov_shared:.6g} exceeds "
                                 f"u_b u_a = {b.u * a.u:.6g}: a result's u is smaller than its own budget rows")
            rho_n = max(-1.0, min(1.0, rho_n))
        h = carried[n] if n in carried else tempco_bound(n, b.value, row_dT)
        u = drift_uncertainty(b.u, a.u, rho_n)
        near = math.copysign(max(abs(d) - h, 0.0), d)          # the drift less its bound (the rule's worst)
        z = near / u if u > 0 else (math.inf if near else 0.0)
        verdict, significant = decide(d, u, T, level, h)
        if n in supported:
            verdicts_supported[n] = decide(d, drift_uncertainty(b.u, a.u, supported[n]), T, level, h)[0]
        pd = ParameterDrift(
            name=n, unit=b.unit, drift=d, u=u, before=b.value, after=a.value, u_before=b.u, u_after=a.u,
            rho=rho_n, tolerance=T, En=normalised_error(near, b.u, a.u, rho_n), z=z,
            p_value=float(2 * stats.norm.sf(abs(z))), significant=significant,
            p_exceeds=probability_exceeds(d, u, T, h), verdict=verdict, judged=judged, bound=h)
        if (h > 0 or n in carried) and post_b is not None:
            bounded.append(n)
        elif post_b is not None and n in post_b and n in post_a:
            (db, unit_b), (da, unit_a) = post_b[n], post_a[n]
            for tag, unit_p in (("before", unit_b), ("after", unit_a)):
                if unit_p is not None and unit_p != b.unit:
                    raise InputError(f"posterior {tag}: {n} is in {unit_p!r}, the results give {b.unit!r}")
            draws = posterior_drift(db, da)
            var_b = _type_b_variance(b) + _type_b_variance(a) - 2.0 * cov_shared
            if var_b > 0.0:
                # posterior draws are the Type A part (results-json: u_type_a); the lab's systematic
                # errors (independent, minus what is shared) are added as a normal term (fixed seed)
                draws = draws + np.random.default_rng(1).normal(0.0, math.sqrt(var_b), len(draws))
                type_b_added.append(n)
            if n in supported:
                verdicts_supported[n] = decide_from_draws(rho_rescaled(draws, db, da, supported[n]), T, level)[0]
            draws = rho_rescaled(draws, db, da, rho)
            verdict, significant, p = decide_from_draws(draws, T, level)
            pd.verdict, pd.significant, pd.p_exceeds = verdict, significant, p
            pd.basis, pd.n_draws = "posterior", int(min(len(db), len(da)))
        params[n] = pd
    if post_b is not None:
        missing = [n for n in ANGLES if n in params and params[n].basis != "posterior"]
        if missing:
            notes.append("no posterior draws for " + ", ".join(missing) + ": judged on (value, u)")
        if bounded:
            notes.append("judged on (value, u), not on posterior draws (a bound is no distribution; draws at the "
                         "range calibration's reference temperature are not those of the carried rows): "
                         + ", ".join(bounded))
        if type_b_added:
            notes.append("posterior draws hold the Type A part only: the lab's systematic errors (Type B rows, "
                         + ("minus the shared ones, " if shared.sources else "independent, ")
                         + "as a normal term) were added to the drift draws of " + ", ".join(type_b_added))
        if rho != 0.0:
            notes.append("posterior drifts assume independent calibrations; their spread was rescaled "
                         f"about the mean for rho = {rho:g}")

    angles = [n for n in ANGLES if n in params]
    joint = None
    if angles:
        d = np.array([params[n].drift for n in angles])
        cov = combined_covariance(before.covariance(angles), after.covariance(angles), rho,
                                  cross=shared.cross(angles) if shared.sources else None)
        joint = joint_test(d, cov, angles, level, bounds=[params[n].bound for n in angles])
        if supported:
            rho_joint = min(supported[n] for n in angles if n in supported) if any(
                n in supported for n in angles) else rho
            joint_supported = joint_test(
                d, combined_covariance(before.covariance(angles), after.covariance(angles), rho_joint),
                angles, level, bounds=[params[n].bound for n in angles])

    bench = {}
    tilts = [n for n in ("tilt_x", "tilt_y") if n in before.parameters and n in after.parameters]
    # the shared equipment's errors cancel in the tilt's change too (an encoder zero goes one to one
    # into the tilt about its axis): the same subtraction as for the unit's parameters
    shared_tilt = shared_errors(before, after, tilts, shared_equipment) if tilts else None
    for n in tilts:
        b, a = before[n], after[n]
        dd = a.value - b.value
        cov_t = shared_tilt.covariance(n) if shared_tilt.sources else 0.0
        rho_t = max(-1.0, min(1.0, cov_t / (b.u * a.u))) if b.u > 0 and a.u > 0 else 0.0
        uu = drift_uncertainty(b.u, a.u, rho_t)
        bench[n] = {"drift": dd, "u": uu, "unit": b.unit, "significant": bool(abs(dd) > k2 * uu)}
        if cov_t:
            bench[n]["rho"] = rho_t
    if any(v["significant"] for v in bench.values()):
        notes.append("the bench tilt changed significantly between the campaigns: was the bench re-levelled "
                     "or moved? Shared bench errors may then not cancel")

    corr = {"rho": rho, "source": "derived" if correlation == "auto" else "stated", "reason": reason,
            "terms": [dict(t) for t in CORRELATION_TERMS],
            "within_calibration": ("each result's correlation matrix enters the covariance of the angle "
                                   "drifts (joint test); a single parameter's u(d) needs only its variances")
            if (before.correlation is not None or after.correlation is not None)
            else "no correlation matrix in the results: angles taken as uncorrelated within each calibration",
            "shared": shared.to_dict(names)}
    if shared.sources:
        notes.append("shared between the calibrations (one error in both, subtracted from each drift's variance and "
                     "from the joint test's covariance): " + ", ".join(
                         f"{s['source']} ({s['key']}, u = {s['u']:g} {s['unit']})" for s in shared.sources))
    overall = overall_verdict(params, joint, tolerance_arcsec)
    held_back = False
    if supported:
        params_supported = {n: replace(p, verdict=verdicts_supported.get(n, p.verdict)) for n, p in params.items()}
        overall_supported = overall_verdict(params_supported, joint_supported if angles else None, tolerance_arcsec)
        held = [n for n in params if params[n].verdict != params_supported[n].verdict]
        if held or overall != overall_supported:
            # an outside probe: an unmoved unit at --correlation 0.9 without a lab file "failed" (a note said why)
            notes.insert(0, _held_note(f"at the stated rho = {rho:g} the verdict is {overall}, at the rho the budgets "
                                       f"support (at most {max(supported.values()):.2g}) it is {overall_supported}",
                                       params, {n: params_supported[n].verdict for n in held},
                                       ": the difference rests on shared error that no result's budget holds"))
            overall, held_back = "inconclusive", True
        _hold(params, held)
    bench_shared = sorted({s["equipment"] for s in shared.sources if s["equipment"] in BENCH_MOUNTED})
    if bench_shared and any(v["significant"] for v in bench.values()):
        # the bench check says the sharing does not hold: every verdict made again with the bench's errors
        # independent (the rest stays shared), one that differs held back (guards.bench_contradicts_sharing)
        alone = tuple(e for e in shared_equipment if e not in BENCH_MOUNTED)
        alt = compare(originals["before"], originals["after"], tolerance_arcsec=tolerance_arcsec,
                      tolerances=tolerances, posterior_before=posterior_before, posterior_after=posterior_after,
                      correlation=correlation, level=level, label=label, shared_equipment=alone, files=files)
        if bench_contradicts_sharing(bench, bench_shared, level, params, overall, alt,
                                     overall_verdict(alt.parameters, alt.joint, tolerance_arcsec), notes):
            overall, held_back = "inconclusive", True
    if angles:
        overall, held_back = rotation_verdict(d, cov, angles, level, before, after, shared_equipment, overall,
                                              held_back, notes)
    overall, held_back = thermometer_verdict(params, before, after, level, overall, held_back, notes)
    if same_calibration(before, after):
        src = before.extra.get("source")
        notes.insert(0, NOT_PASS_NOTE + f"{tag_b} and {tag_a} are the same calibration (unit {before.unit}, method "
                     f"{before.method}{f', source {src}' if src else ''}; every parameter's value and u identical): "
                     "its drift is zero by construction and u(d), which treats them as two independent calibrations, "
                     "says nothing about the unit; compare two calibrations")
    data = same_data(before, after)
    if data and not same_calibration(before, after):
        notes.insert(0, NOT_PASS_NOTE + f"{tag_b} and {tag_a} are two fits of the same data (data_sha256 "
                     f"{data[:12]}..., methods {before.method} and {after.method}): their differences are those "
                     "of the estimators and options, not a drift of the unit, and u(d), which treats them as two "
                     "independent calibrations, is not the uncertainty of that difference; compare two "
                     "calibrations")
    copy = None if data or same_calibration(before, after) else copied_data(params)
    if copy is not None:
        notes.insert(0, NOT_PASS_NOTE + f"{tag_b} and {tag_a} agree in all {len(params)} parameters to within "
                     f"{COPY_Z_MAX:g} of u(d) (largest |z| {copy:.2g}), which two independent calibrations do with "
                     "a probability below 1e-23: they are fits of the same data (a copy re-exported -- rows "
                     "reordered, numbers rewritten, times moved -- has another data_sha256), not two "
                     "calibrations; compare two calibrations")
    src_b, src_a = before.extra.get("source"), after.extra.get("source")
    if not data and src_b and src_b == src_a and not (before.extra.get("data_sha256") and after.extra.get("data_sha256")):
        # an outside probe removed data_sha256 from a joint and a classical fit of one file: compare said pass
        notes.append(f"{tag_b} and {tag_a} name the same source ({src_b}) and do not both carry data_sha256: if they "
                     "are fits of one data set, their difference is the estimators', not a drift of the unit, and "
                     "this verdict says nothing about it (results written since 2026-11-29 carry the hash)")
    if missing_angles:
        where = "; ".join(f"{n} missing from " + " and ".join(
            t for t, r in ((tag_b, before), (tag_a, after)) if n not in r.parameters) for n in missing_angles)
        notes.insert(0, NOT_PASS_NOTE + f"{where}: every calibration of eq. 1 holds the six angles, so the drift "
                     "of the unit's axes is not judged in full")
    moved = unjudged_moves(params, level)
    if overall == "pass" and moved:
        notes.insert(0, NOT_PASS_NOTE + "the angles pass, but " + "; ".join(
            f"{p.name} moved {p.drift:+.4g} {p.unit} (z {p.z:.3g}, p {p.p_value:.2g})" for p in moved[:4])
            + (f" and {len(moved) - 4} more" if len(moved) > 4 else "")
            + f" -- significant after Holm's correction over the {len(_unjudged(params))} parameters without a "
            "tolerance (family-wise false alarms at most " + f"{1 - level:.0%}" + "); they enter the overall verdict "
            "only with a tolerance: give --param-tolerance NAME=VALUE to judge them")
    if overall == "pass" and (same_calibration(before, after) or missing_angles or moved or copy is not None):
        overall = "inconclusive"
    if data:  # a "fail" between two fits of one data set would name a drift the unit never had
        overall = "inconclusive"
    return ComparisonResult(
        parameters=params, overall=overall, level=level,
        rule=rule_text(level, tolerance_arcsec, tolerances, posterior=post_b is not None),
        tolerance_arcsec=tolerance_arcsec, tolerances=tolerances, correlation=corr, joint=joint,
        bench_check=bench, before=_describe(before), after=_describe(after), label=label, notes=notes,
        held_back=held_back and overall == "inconclusive")


def joint_test(drift: np.ndarray, cov: np.ndarray, names: Sequence[str], level: float = 0.95,
               bounds: Optional[Sequence[float]] = None) -> JointTest:
    """``D^2 = d^T C^-1 d`` against chi^2 with ``len(d)`` dof (zero drift, Gaussian errors). With
    ``bounds`` (biases of the drifts known only to lie within +-bound, :func:`tempco_bound`): the
    least ``(d - b)^T C^-1 (d - b)`` over ``|b_i| <= bound_i`` (a bounded least-squares problem,
    scipy's ``lsq_linear``), the drift the data show whatever the biases are."""
    drift = np.asarray(drift, float)
    w, V = np.linalg.eigh(cov)
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        raise InputError("the covariance of the angle drifts is singular or not positive definite "
                         f"(eigenvalues {w.min():.3g} .. {w.max():.3g}); check the correlation coefficient")
    h = np.zeros(len(drift)) if bounds is None else np.asarray(bounds, float)
    if np.any(h > 0):
        from scipy.optimize import lsq_linear

        W = (V / np.sqrt(w)).T                    # W'W = C^-1
        res = lsq_linear(W, W @ drift, bounds=(-h - 1e-300, h + 1e-300), method="bvls")
        drift = drift - res.x
    y = V.T @ drift
    D2 = float(np.sum(y * y / w))
    p = float(stats.chi2.sf(D2, len(drift)))
    return JointTest(tuple(names), D2, len(drift), p, bool(p < 1 - level), level)


def _is_angle(name: str) -> bool:
    return name.rsplit(".", 1)[-1] in ANGLES


def _unjudged(params: Mapping[str, ParameterDrift]) -> list:
    return [p for p in params.values() if not p.judged and not _is_angle(p.name)]


def unjudged_moves(params: Mapping[str, ParameterDrift], level: float = 0.95) -> list:
    """The parameters other than the angles compared without a tolerance (K, S, tempcos, ...) whose drift
    is significant after Holm's step-down correction over all of them at ``1 - level`` (their p-values,
    two-sided; family-wise false alarms at most ``1 - level`` whatever their correlation; Holm 1979),
    largest |z| first. They are kept out of the overall verdict (they have no tolerance to fail), but a
    unit one of them shows moved is not a pass: an outside probe's unit whose S_x moved 1 mg (z 645) and
    K_y 1130 ppm (z 417) got "overall: pass", exit 0, the (fail) of those rows in parentheses only."""
    cand = [p for p in _unjudged(params) if math.isfinite(p.p_value)]
    m, out = len(cand), []
    for i, p in enumerate(sorted(cand, key=lambda q: q.p_value)):
        if p.p_value > (1.0 - level) / (m - i):
            break
        out.append(p)
    return sorted(out, key=lambda q: -abs(q.z) if math.isfinite(q.z) else 0.0)


def overall_verdict(params: Mapping[str, ParameterDrift], joint: Optional[JointTest],
                    tolerance_arcsec: Optional[float]) -> str:
    """Overall verdict of the judged parameters (rule in :func:`rule_text`): the angles (the
    joint test guards the family against false alarms) and parameters given a tolerance."""
    angle_set = [p for p in params.values() if _is_angle(p.name)]
    others = [p for p in params.values() if p.judged and not _is_angle(p.name)]
    joint_significant = joint is not None and joint.significant
    if any(p.verdict == "fail" for p in others):
        return "fail"
    if tolerance_arcsec is None:
        if joint_significant:
            return "fail"
    elif joint_significant and any(p.verdict == "fail" for p in angle_set):
        return "fail"
    judged = angle_set + others
    if judged and all(p.verdict == "pass" for p in judged):
        return "pass"
    return "inconclusive"


def _type_b_variance(p) -> float:
    """``u^2 - u_type_a^2`` of a parameter with a budget (the lab's systematic errors), else 0."""
    ua = p.uncertainty.get("u_type_a")
    if ua is None or not p.uncertainty.get("budget"):
        return 0.0
    return max(p.u ** 2 - float(ua) ** 2, 0.0)


def _describe(r: CalibrationResult) -> dict:
    d = {"unit": r.unit, "method": r.method, "status": r.status,
         "reference_temperature_C": r.reference_temperature_C}
    for k in ("source", "data_sha256", "derived_from_sha256", "rows_carried_to_C"):
        if r.extra.get(k):
            d[k] = r.extra[k]
    return d
