"""The noise of the mean outputs, the weights of every fit: the data's own noise (:func:`noise_of`)
plus the bench's random positioning and wobble errors (seed paper, eq. 4) stated by the lab
(:class:`BenchErrors`, :func:`with_bench_errors`) or estimated from the plan's replicates
(:func:`bench_errors_from_replicates`). On oblique poses the bench's errors correlate a visit's
outputs and the fit whitens by the full 3 x 3 blocks (:func:`_bench_whitening`,
:mod:`triadcal.estimation.whitening`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..errors import InputError
from ..models.campaign import Campaign
from ..models.model import Model


def _start_internal(campaign: Campaign, model: Model) -> np.ndarray:
    """The model's parameters at the fit's start values (internal units): the bench's sensitivities
    depend on K and the angles only at second order."""
    from .joint import start_values

    start = start_values(campaign, model)
    return model.to_internal({n: start.get(n, model.spec[n].nominal) for n in model.names})


@dataclass
class NoiseSource:
    """Standard deviation of each mean output and where it came from."""

    sigma: np.ndarray          # (n, 3), output unit
    known: bool                # True: from the data (sd_*/n or Q); False: relative weights only
    description: str


@dataclass(frozen=True)
class BenchErrors:
    """The bench's random errors per visit, stated by the lab (r.m.s., arcsec): positioning of
    each axis (sigma_1 of eq. 4) and wobble of axis 1 (sigma_2)."""

    sigma_position_arcsec: float
    sigma_wobble_arcsec: float
    source: str = "lab file"


def with_bench_errors(campaign: Campaign, model: Model, noise: "NoiseSource",
                      bench: Optional[BenchErrors]) -> "NoiseSource":
    """The noise of each mean output with the bench's random errors added as variance components
    (:func:`triadcal.models.effects.position_error.bench_variance`, evaluated at the start
    values: the sensitivities depend on K and the angles only at second order). The output
    noise must be known (sd_* or Q_V2s): an absolute bench variance cannot be added to relative
    weights."""
    if bench is None:
        return noise
    if bench.sigma_position_arcsec < 0 or bench.sigma_wobble_arcsec < 0:
        raise InputError("the bench's positioning and wobble SDs must be >= 0 arcsec")
    if not noise.known:
        raise InputError(f"{campaign.source or 'campaign'}: the bench's errors ({bench.source}) add to a known "
                         "output noise, but the data give none (no sd_*/n_samples columns, no Q_V2s metadata)")
    from ..models.effects.position_error import bench_variance

    p = _start_internal(campaign, model)
    var_b = bench_variance(model, p, campaign.covariates(), campaign.gravity_g,
                           bench.sigma_position_arcsec, bench.sigma_wobble_arcsec)
    return NoiseSource(np.sqrt(noise.sigma ** 2 + var_b), True,
                       f"{noise.description}, plus the bench's random errors per visit ({bench.source}: "
                       f"positioning {bench.sigma_position_arcsec:g} arcsec, wobble {bench.sigma_wobble_arcsec:g} "
                       "arcsec) as variance components")


def _bench_whitening(campaign: Campaign, model: Model, noise: "NoiseSource", bench: BenchErrors, whitening,
                     notes: list):
    """The whitening of the fit when the bench's errors correlate a visit's outputs (oblique poses:
    :func:`triadcal.estimation.whitening.bench_whitening`, at the start values as
    :func:`with_bench_errors`); ``whitening`` itself when they do not, or when another whitening
    (flicker_noise's) is given, with a note."""
    from .whitening import bench_whitening

    p = _start_internal(campaign, model)
    bw = bench_whitening(model, p, campaign, noise_of(campaign).sigma, noise.sigma,
                         bench.sigma_position_arcsec, bench.sigma_wobble_arcsec)
    if bw is None:
        return whitening
    if whitening is not None:
        notes.append("the bench's errors correlate the outputs of the oblique poses, but with flicker_noise's "
                     "whitening only their variances are modelled (diagonal)")
        return whitening
    notes.append("the bench's errors move a visit's outputs together on the oblique poses: generalised least "
                 "squares with the full 3 x 3 covariance of each visit's outputs")
    return bw


#: the weights of a fit whose data hold no noise level (``noise_of``): with them chi^2/dof is the
#: outputs' white-noise intensity Q (output unit^2 s), as the summary reports it
RELATIVE_WEIGHTS = "weights 1/sqrt(tau_s)"


#: a visit's stated SD below this fraction of its output's median is taken as zero: numpy's SD of a
#: window whose readings are all one code is ~1e-18, not 0 (an outside probe: a fit weighted by it had
#: chi2/dof 8e31, "the model misses something", and `sample` ended in an internal error)
NEGLIGIBLE_SD_RATIO = 1e-6


#: the resolution term q^2/12 is added (and said) when it is above this fraction of an output's
#: median variance of the mean; below, it changes no weight by more than 0.05 %
RESOLUTION_VARIANCE_FRACTION = 1e-3


def noise_of(campaign: Campaign) -> NoiseSource:
    """Weights of the fit: ``u_w_*`` (the data's own noise) or ``sd_*/sqrt(n_samples)`` where
    present (:meth:`Campaign.output_sigma`), else ``sqrt(Q/tau)`` from a
    ``Q_V2s`` metadata line, else ``1/sqrt(tau)`` relative weights with the scale estimated. A stated
    SD of zero, or below :data:`NEGLIGIBLE_SD_RATIO` of its output's median, cannot weight the fit.

    A stated noise is the noise of the readings' mean; the mean as written is rounded to the step
    ``q`` of its last digit (:func:`~triadcal.io.bench_checks.written_resolution`), which adds
    ``q^2 / 12`` to its variance (rectangular, GUM F.2.2.1), added when above
    :data:`RESOLUTION_VARIANCE_FRACTION` of the output's median variance. An outside probe's means
    rounded to 1e-4 V with a standard error of 1e-5 V: chi2/dof 9.3, model_mismatch."""
    noise = _stated_noise(campaign)
    return with_resolution(campaign, noise) if noise.known else noise


def with_resolution(campaign: Campaign, noise: NoiseSource) -> NoiseSource:
    """``noise`` with the written resolution's ``q^2 / 12`` added per output where it matters and does
    not dominate: above the output's median stated variance it is not added but said. One pose's means
    at nearby temperatures round alike, so the rounding is not independent from visit to visit; where
    it dominates, weights that call it independent gave status ok with a parameter 5.6 u off (the
    independent bench's means written to 1e-4 V, 11 standard errors, 3 seeds; 1e-5 V: every |z| < 3.3),
    while the stated noise alone leaves the goodness-of-fit gate to refuse such a file."""
    q, add, med, matters, dominates = _resolution(campaign, noise)
    if not np.any(matters):
        return noise
    var = np.asarray(noise.sigma, float) ** 2
    added = matters & ~dominates
    text = noise.description
    if np.any(added):
        text += ("; plus the rounding of the means as written, q/sqrt(12) with q the step of their last digit (GUM "
                 "F.2.2.1): " + ", ".join(f"{'xyz'[a]} {q[a]:g}" for a in range(3) if added[a])
                 + f" ({campaign.output_unit})")
    if np.any(dominates):
        text += ("; the means are written to a step whose rounding q/sqrt(12) exceeds their stated noise ("
                 + ", ".join(f"{'xyz'[a]} q {q[a]:g}" for a in range(3) if dominates[a]) + f" {campaign.output_unit}"
                 "): not in the weights, since one pose's means round alike and not independently; write them with "
                 "more digits")
    return NoiseSource(np.sqrt(var + np.where(added, add, 0.0)[None, :]), True, text)


def _resolution(campaign: Campaign, noise: NoiseSource):
    """``(q, q^2/12, median stated variance, matters, dominates)`` per output (arrays of 3)."""
    from ..io.bench_checks import written_resolution

    w = np.asarray(campaign.w, float)
    q = np.array([written_resolution(w[:, a]) for a in range(3)])
    add = q ** 2 / 12.0
    med = np.median(np.asarray(noise.sigma, float) ** 2, axis=0)
    matters = add > RESOLUTION_VARIANCE_FRACTION * med
    return q, add, med, matters, matters & (add > med)


def rounding_note(campaign: Campaign, noise: NoiseSource) -> Optional[str]:
    """The note of a fit whose means are written to a step whose rounding exceeds their stated noise
    (:func:`with_resolution` leaves it out of the weights): a goodness-of-fit gate that fails may fail
    for the rounding, not for a missing effect (an outside probe's means at 1e-4 V, SE 1e-5 V: the
    gates said only "the model misses something"). None otherwise, or with no stated noise."""
    if not noise.known:
        return None
    q, add, med, _, dominates = _resolution(campaign, noise)
    if not np.any(dominates):
        return None
    each = ", ".join(f"{'xyz'[a]} q {q[a]:g} {campaign.output_unit} (q/sqrt(12) {np.sqrt(add[a] / med[a]):.3g} times "
                     "the median stated SD)" for a in range(3) if dominates[a])
    return ("the means are written to a step whose rounding exceeds their stated noise: " + each + "; it is not in "
            "the weights (one pose's means round alike, not independently), so a goodness-of-fit or structure gate "
            "that fails may fail for the rounding, not for a missing effect: write the means with more digits")


def noise_notes(campaign: Campaign, noise: NoiseSource) -> list:
    """The notes a fit gives about its stated noise: two statements apart
    (:func:`noise_statements_note`), a rounding coarser than it (:func:`rounding_note`)."""
    return [n for n in (noise_statements_note(campaign, noise), rounding_note(campaign, noise)) if n]


def _stated_noise(campaign: Campaign) -> NoiseSource:
    s = campaign.output_sigma()
    why = ""
    if s is not None:
        usable = bool(np.all(s > NEGLIGIBLE_SD_RATIO * np.median(s, axis=0)[None, :]))   # and so every s > 0
        if usable and campaign.u_w is None:
            s, how = sd_weights(campaign)
            if s is not None:
                return NoiseSource(s, True, how)
            why = "; " + how
        elif usable:
            return NoiseSource(s, True, campaign.output_sigma_method())
        else:
            why = ("; sd_* is zero (or below 1e-6 of its output's median: readings all on one code) in some visits, "
                   "so it cannot weight the fit")
    if "Q_V2s" in campaign.metadata and float(campaign.metadata["Q_V2s"]) > 0:
        # also where sd_* are there but cannot weight the fit: the file states its noise (an outside
        # probe's sd_x = 0 on every row with Q_V2s stated was fitted as if no noise were stated)
        Q = float(campaign.metadata["Q_V2s"])
        return NoiseSource(np.repeat(np.sqrt(Q / campaign.tau_s)[:, None], 3, axis=1), True,
                           f"white noise Q = {Q:g} (output unit)^2 s from the file's metadata, sqrt(Q/tau_s)"
                           + (f" (the sd_* columns not used{why})" if why else ""))
    return NoiseSource(np.repeat((1.0 / np.sqrt(campaign.tau_s))[:, None], 3, axis=1), False,
                       f"estimated from the residuals ({RELATIVE_WEIGHTS})" + why)



#: the file's Q_V2s and its sd_* columns further apart than this factor (in the visit's SD) are said
NOISE_STATEMENTS_APART = 3.0


def noise_statements_note(campaign: Campaign, noise: NoiseSource) -> Optional[str]:
    """A note when the file states its noise twice and the two disagree by more than
    :data:`NOISE_STATEMENTS_APART` in a visit's SD: ``# Q_V2s`` (``sqrt(Q / tau_s)``) against the
    ``sd_*`` or ``u_w_*`` columns that weight the fit (they take precedence, docs/bench-csv.md). An
    outside probe's Q_V2s 10^6 times too small or large beside honest sd_* was passed over without a
    word; one of the two is in another unit or of another unit (serial)."""
    if "Q_V2s" not in campaign.metadata or not noise.known or noise.description.startswith("white noise Q"):
        return None
    try:
        Q = float(campaign.metadata["Q_V2s"])
    except ValueError:
        return None
    if not Q > 0:
        return None
    from_q = np.sqrt(Q / np.asarray(campaign.tau_s, float))[:, None]
    ratio = float(np.median(from_q / np.asarray(noise.sigma, float)))
    if 1.0 / NOISE_STATEMENTS_APART <= ratio <= NOISE_STATEMENTS_APART:
        return None
    return (f"the file states its noise twice and the two disagree: # Q_V2s = {Q:g} gives a visit's SD "
            f"{ratio:.3g} times the one the fit is weighted by ({noise.description}); the columns take "
            "precedence, so check which statement is in the output's unit (or of this unit)")


#: a visit's own sd_* with fewer degrees of freedom (n_samples - 1) than this is pooled, per axis,
#: with the others of its setpoint block: with nu = 10 the weights 1/s^2 scatter by +-47 % and the
#: fit's chi^2/dof expects nu / (nu - 2) = 1.29, not 1 (an outside probe: 38 of 60 honest
#: files with 10 samples a visit refused by goodness of fit)
POOL_DOF_BELOW = 100
#: Bartlett's test of equal variances within a block: below this p its visits keep their own sd_*
HOMOGENEITY_P = 1e-3
#: more than this fraction of visit-axes left on their own few-sample sd_* (neither their setpoint's nor
#: their pose's pooled) and the sd_* do not weight the fit: the noise is estimated from the residuals
OWN_SD_MAX_FRACTION = 0.1
#: fewer degrees of freedom than this leave 1/s^2 without a usable mean (E[1/s^2] needs nu > 2, its
#: variance nu > 4): the noise is then estimated from the residuals
DOF_MIN = 5


def bartlett_p(var: np.ndarray, dof: np.ndarray) -> float:
    """P-value of Bartlett's test that sample variances ``var`` (with ``dof`` degrees of freedom
    each) come from one normal variance (Bartlett 1937; NIST/SEMATECH e-Handbook 1.3.5.7):
    ``T = (nu ln s_p^2 - sum nu_i ln s_i^2) / (1 + (sum 1/nu_i - 1/nu) / (3 (k - 1)))``, ``T ~ chi^2_(k-1)``."""
    from scipy.stats import chi2

    var, dof = np.asarray(var, float), np.asarray(dof, float)
    k, nu = len(var), float(np.sum(dof))
    pooled = float(np.sum(dof * var) / nu)
    T = (nu * math.log(pooled) - float(np.sum(dof * np.log(var)))) / \
        (1.0 + (float(np.sum(1.0 / dof)) - 1.0 / nu) / (3.0 * (k - 1)))
    return float(chi2.sf(T, k - 1))


def sd_weights(campaign: Campaign) -> tuple[Optional[np.ndarray], str]:
    """The SD of each mean output from ``sd_*`` and ``n_samples`` (white noise: ``sd/sqrt(n)``),
    with the uncertainty of ``sd_*`` itself accounted for. A visit's sample variance ``s^2`` has
    ``nu = n - 1`` degrees of freedom; weighting by ``1/s^2`` overweights on average by
    ``E[sigma^2 / s^2] = nu / (nu - 2)`` (the inverse chi-square's mean), so every variance is
    multiplied by ``nu / (nu - 2)``, and the fit's chi^2 keeps its expectation. Visits with
    ``nu < POOL_DOF_BELOW`` are pooled per axis within their setpoint block (``s_p^2 = sum nu_i
    s_i^2 / sum nu_i``, ``nu = sum nu_i``) when Bartlett's test allows (p >= HOMOGENEITY_P).
    Returns (None, why) when some visit is left with ``nu < DOF_MIN``."""
    sd = np.asarray(campaign.sd, float)
    n = np.asarray(campaign.n_samples, float)
    var = sd * sd
    nu = np.repeat((n - 1.0)[:, None], 3, axis=1)
    small = (nu[:, 0] < POOL_DOF_BELOW) & (nu[:, 0] >= 1)
    own = np.repeat(small[:, None], 3, axis=1)          # small-nu visit-axes still on their own sd_*

    def pool(idx, a) -> bool:
        if len(idx) < 2 or bartlett_p(var[idx, a], nu[idx, a]) < HOMOGENEITY_P:
            return False
        tot = float(np.sum(nu[idx, a]))
        var[idx, a] = float(np.sum(nu[idx, a] * var[idx, a])) / tot
        nu[idx, a] = tot
        own[idx, a] = False
        return True

    pooled = kept = by_pose = 0
    if np.any(small):
        blocks = campaign.setpoint_blocks
        for b in np.unique(blocks[small]):
            idx = np.flatnonzero((blocks == b) & small)
            for a in range(3):
                if pool(idx, a):
                    pooled += 1
                elif len(idx) >= 2:
                    kept += 1
        # what a block could not pool, by pose across the campaign: a pose's noise (one whose axis is
        # vertical, a resonance of the bench at one angle) is the same at every setpoint (an outside
        # probe: Z-up poses 3x noisier refused every block's pooling, and the fit weighted by 9-dof
        # sd_* was ok with an angle tempco 5.5 u off)
        for a in range(3):
            rest = np.flatnonzero(own[:, a])
            for pos in np.unique(campaign.position[rest]):
                if pool(rest[campaign.position[rest] == pos], a):
                    by_pose += 1
        if np.mean(own) > OWN_SD_MAX_FRACTION:
            i, a = np.argwhere(own)[0]
            return None, (f"sd_* of {int(np.sum(own))} of {own.size} visit-axes rest on their own n_samples - 1 < "
                          f"{POOL_DOF_BELOW} samples and differ from their setpoint's and their pose's (Bartlett p < "
                          f"{HOMOGENEITY_P:g}; e.g. line {_line(campaign, i)}, {'xyz'[a]}): weights that uncertain give "
                          "an answer whose errors their u does not describe")
    if np.any(nu < DOF_MIN):
        i, a = np.argwhere(nu < DOF_MIN)[0]
        return None, (f"sd_* of {int(np.sum(nu < DOF_MIN))} visit-axes rest on fewer than {DOF_MIN} samples after "
                      f"pooling (e.g. line {_line(campaign, i)}, {'xyz'[a]}: n_samples = {int(n[i])}), too few to "
                      "weight the fit")
    sigma = np.sqrt(var * nu / (nu - 2.0) / n[:, None])
    how = "sd_*/sqrt(n_samples) of each visit, x sqrt(nu/(nu-2)) for the uncertainty of sd_* (nu = n_samples - 1)"
    if pooled or kept:
        how += (f"; with n_samples - 1 < {POOL_DOF_BELOW}, sd_* pooled per axis within {pooled} setpoint block-axes"
                + (f" (not in {kept}, where Bartlett's test p < {HOMOGENEITY_P:g} says the variances differ"
                   + (f"; those pooled by pose across the setpoints in {by_pose} pose-axes" if by_pose else "")
                   + f"; {int(np.sum(own))} visit-axes on their own sd_*)" if kept else ""))
    return sigma, how


def _line(campaign: Campaign, i: int):
    return int(campaign.lines[i]) if campaign.lines is not None else i + 1


#: the paper's example ratio of the wobble to the positioning error (eq. 4: 2" / 5"), used when
#: the bench's errors are estimated from replicates and the lab states no wobble of its own
WOBBLE_TO_POSITION = 0.4


def replicate_groups(campaign: Campaign) -> list:
    """Visits that repeat one bench position at one setpoint on one branch and cycle (same axis
    angles): index arrays of the groups with at least two visits."""
    keys = {}
    for i, k in enumerate(zip(np.round(campaign.axis1_deg, 6), np.round(campaign.axis2_deg, 6),
                              campaign.setpoint_C, campaign.direction, campaign.cycle)):
        keys.setdefault(k, []).append(i)
    return [np.array(v) for v in keys.values() if len(v) >= 2]


def bench_errors_from_replicates(campaign: Campaign, model: Model, wobble_ratio: float = WOBBLE_TO_POSITION
                                 ) -> BenchErrors:
    """The bench's random positioning error estimated from the plan's replicates (method of
    moments): within a group of visits of one position at one setpoint, the outputs scatter by
    the output noise plus the bench's errors, ``var(W_a) = s_a^2 + sigma_1^2 c_a`` with ``c_a``
    the sensitivity of eq. 4 (:func:`~triadcal.models.effects.position_error.bench_variance` per
    arcsec^2, wobble at ``wobble_ratio`` sigma_1), so

        sigma_1^2 = sum_g,a [(n_g - 1) (S_g,a^2 - mean s_a^2)] / sum_g,a [(n_g - 1) mean c_a]

    (S^2 the group's sample variance), clipped at 0. Needs the output noise (sd_* or Q_V2s) and at
    least 5 groups; the source says how many groups and visits it came from."""
    noise = noise_of(campaign)
    if not noise.known:
        raise InputError(f"{campaign.source or 'campaign'}: estimating the bench's errors from replicates needs the "
                         "output noise in the data (sd_*/n_samples columns or Q_V2s)")
    groups = replicate_groups(campaign)
    if len(groups) < 5:
        raise InputError(f"{campaign.source or 'campaign'}: {len(groups)} groups of replicated visits (one position "
                         "visited twice or more at one setpoint): at least 5 are needed to estimate the bench's errors; "
                         "state them in the lab file instead ([bench] sigma_position_arcsec, sigma_wobble_arcsec)")
    from ..models.effects.position_error import bench_variance

    p = _start_internal(campaign, model)
    c = bench_variance(model, p, campaign.covariates(), campaign.gravity_g, 1.0, wobble_ratio)   # per arcsec^2
    num = den = 0.0
    for g in groups:
        k = len(g) - 1
        S2 = np.var(campaign.w[g], axis=0, ddof=1)
        num += float(np.sum(k * (S2 - np.mean(noise.sigma[g] ** 2, axis=0))))
        den += float(np.sum(k * np.mean(c[g], axis=0)))
    s1 = math.sqrt(max(num / den, 0.0)) if den > 0 else 0.0
    n_vis = int(sum(len(g) for g in groups))
    return BenchErrors(s1, wobble_ratio * s1, source=(f"estimated from the replicates of the plan ({len(groups)} "
                                                      f"groups, {n_vis} visits; wobble taken as {wobble_ratio:g} of "
                                                      "the positioning error)"))


#: the fewest residual dof per output for the outputs' noise levels to be estimated apart. Few dof are no
#: reason to pool: one level for outputs 8 times apart held 0.62 of the noisy row's truths (six faces at two
#: setpoints, 3.3 dof an output, value +- U); apart, with U = k u on each output's dof (Student's t,
#: ``fit.noise_dof``), 0.93 -- where before, value +- 1.96 u on those 3.3 dof held 0.83 (an outside probe)
PER_OUTPUT_MIN_DOF = 2.0


def output_variances(r, n_params: int) -> Optional[np.ndarray]:
    """Each output's variance per unit weight from a fit's normalised residuals ``r`` (3 n,
    visit-major), ``sum_visits r_a^2 / (n - p/3)``; None when fewer than :data:`PER_OUTPUT_MIN_DOF`
    dof remain an output or a variance is not positive and finite (the weights are then left alone)."""
    r = np.asarray(r, float).reshape(-1, 3)
    dof_a = r.shape[0] - n_params / 3.0
    if dof_a < PER_OUTPUT_MIN_DOF:
        return None
    s2 = np.sum(r * r, axis=0) / dof_a
    return s2 if np.all(np.isfinite(s2)) and np.all(s2 > 0) else None


#: passes of the per-output rescaling at most (they stop when the outputs' variances agree to 1 %)
PER_OUTPUT_PASSES = 8


def given_output_scale(noise: NoiseSource, output_variances) -> tuple[NoiseSource, np.ndarray]:
    """``noise`` (estimated, relative weights) with the outputs' relative variances
    ``[s_x^2, s_y^2, s_z^2]`` of a base fit's :func:`per_output_scale` applied, and those variances:
    every candidate fit of a form then shares one set of weights (``fit_joint(output_variances=)``)."""
    from ..errors import InputError
    from ..models.sensor import AXES

    q = np.asarray(output_variances, float)
    if q.shape != (3,) or not np.all(np.isfinite(q)) or np.any(q <= 0):
        raise InputError(f"output_variances = {output_variances!r}: three relative variances > 0 (x, y, z)")
    how = (noise.description + "; one scale per output, from the base fit (the outputs' variances per unit weight "
           + ", ".join(f"{a} {v:.3g}" for a, v in zip(AXES, q)) + ")")
    return NoiseSource(noise.sigma * np.sqrt(q)[None, :], False, how), q


def rescaled_outputs(problem, sol, noise: NoiseSource, max_iter: int, step_of, settled, *, loss: str = "l2",
                     nu: float = 4.0):
    """``(refit, s2)``: the fit repeated from its answer, each output's weights ``1/sigma`` rescaled by
    ``sqrt(s2)``, where every pass multiplies ``s2`` by ``step_of(r)`` (three variances per unit weight of
    the last fit's normalised residuals, None to stop) until ``settled(step)``, at most
    :data:`PER_OUTPUT_PASSES` passes; ``refit`` is ``sol`` when no pass ran. Shared by the per-output
    scale of least squares (:func:`per_output_scale`) and a robust loss's scale
    (:func:`triadcal.estimation.robust_check.robust_scale`)."""
    from .joint import levenberg_marquardt

    s2 = np.ones(3)
    refit = sol
    for _ in range(PER_OUTPUT_PASSES):
        step = step_of(refit.r)
        if step is None:
            break
        s2 = s2 * step
        problem.sigma = noise.sigma * np.sqrt(s2)[None, :]
        refit = levenberg_marquardt(problem, refit.x, loss=loss, nu=nu, max_iter=max_iter)
        if settled(step):
            break
    return refit, s2


def per_output_scale(problem, sol, noise: NoiseSource, max_iter: int):
    """With the noise estimated from the residuals, one noise level per output, not one for all
    three: the outputs of a triad need not share a noise level (another accelerometer, another
    range, another K in the file's unit). From the first fit's residuals (weights 1/sqrt(tau)),
    ``s_a^2 = sum_visits r_a^2 / (n - p/3)`` per output a; the fit is repeated with weights
    ``1/(s_a sqrt(tau))``. Returns the refit, its noise source and ``s_a^2`` (the relative weights'
    variance per output: with the refit's chi^2/dof, the white-noise intensity Q_a).

    An outside probe: an X output 8 times noisier than Y and Z with one scale for all three gave
    the X row's parameters z-scores with SD 1.7 (u understated), Y and Z 0.33, and 2 of 10 ok
    campaigns with a parameter over 4 u off."""
    from ..models.sensor import AXES

    # iterated: a shared parameter (the tilt) fitted with the first weights carries the noisiest
    # output's scatter into the others' residuals (an outside probe: outputs 80x apart gave Q_z 8x
    # its truth after one pass); each pass rescales by the refit's variances until they agree
    refit, s2 = rescaled_outputs(problem, sol, noise, max_iter, lambda r: output_variances(r, len(problem.names)),
                                 lambda step: np.max(np.abs(step / np.mean(step) - 1.0)) < 0.01)
    if refit is sol:
        return sol, noise, None
    how = (noise.description + "; one scale per output (the outputs' variances per unit weight "
           + ", ".join(f"{a} {v:.3g}" for a, v in zip(AXES, s2)) + ", estimated apart)")
    return refit, NoiseSource(problem.sigma, False, how), s2


#: P(chi2 this small) below which the stated noise overstates the data's scatter (the goodness of
#: fit gate's level, GateConfig.gof_p_min, on the lower tail)
OVERSTATED_P = 1e-3


def overstated_noise_note(chi2: float, dof: int, noise_description: str, bench_errors: bool) -> Optional[str]:
    """A note when the residuals scatter improbably less than the stated noise predicts
    (P(chi2 <= observed) < :data:`OVERSTATED_P` with ``dof`` degrees of freedom), or None. The
    answer is not wrong but every u is conservative by up to ``1/sqrt(chi2/dof)``: an outside
    probe's campaign with its ``sd_*`` tripled gave chi2/dof 0.116 on 508 dof and intervals three
    times too wide with no word (the status stays ok: a u too large is no confident wrong answer,
    but the user must know)."""
    from scipy import stats

    p_low = float(stats.chi2.cdf(chi2, dof))
    if p_low >= OVERSTATED_P:
        return None
    ratio = chi2 / dof
    what = "the output noise plus the lab's bench errors" if bench_errors else f"the stated noise ({noise_description})"
    return (f"the data scatter less than {what} predicts (chi2/dof = {ratio:.3g} on {dof} dof, P(chi2 this small) = "
            f"{p_low:.2g}): the stated noise is about {1 / math.sqrt(max(ratio, 1e-12)):.2g} times the scatter, so "
            "every u is conservative by up to that factor; check the sd_*, u_w_* or Q_V2s of the data"
            + (" and the lab file's bench errors" if bench_errors else ""))
