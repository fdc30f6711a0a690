"""Static intervals of a recording as pose averages (mean, its uncertainty from batch means) and
as a bench CSV campaign on the default plan's positions (docs/raw.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ...errors import InputError
from ...io.raw import RawRecording
from ...models.campaign import DEFAULT_PLAN, Campaign
from ...models.sensor import ANGLE_NAMES, AXES
from .detection import (
    StaticDetection,
    StaticIntervalError,
)

#: imucal pose label -> bench position of DEFAULT_PLAN with the same axis up
POSE_POSITIONS = {"y_p": "P01", "y_a": "P03", "x_p": "P05", "x_a": "P07", "z_p": "P09", "z_a": "P11"}


#: the angles the gravity-norm model can determine (imu_tk's upper-triangular frame)
NORM_ANGLES = ("xy", "xz", "yz")


UNIT_NAMES = tuple(f"K_{a}" for a in AXES) + tuple(f"S_{a}" for a in AXES) + tuple(f"Ca_{ab}" for ab in ANGLE_NAMES)


NORM_NAMES = tuple(f"K_{a}" for a in AXES) + tuple(f"S_{a}" for a in AXES) + tuple(f"Ca_{ab}" for ab in NORM_ANGLES)


# --------------------------------------------------------------------------------------
# position averages
# --------------------------------------------------------------------------------------
@dataclass
class PoseAverages:
    """Mean reading of each static interval and its standard uncertainty.

    ``se`` is the larger of the white-noise ``sd / sqrt(n)`` and a batch-means estimate
    (10 consecutive batches), so slowly correlated noise does not shrink it. ``sd`` is the
    interval's own sample SD, floored by the pooled SD of all the intervals when the interval
    has fewer than :data:`MIN_OWN_SD_SAMPLES` samples (:func:`pose_averages`).
    """

    label: list
    start: np.ndarray
    end: np.ndarray
    w: np.ndarray
    sd: np.ndarray
    n: np.ndarray
    se: np.ndarray
    time_s: np.ndarray
    tau_s: np.ndarray
    #: each interval's own sample SD per axis (NaN for a 1-sample interval); ``sd`` is the SD used
    sd_own: Optional[np.ndarray] = None
    #: the pooled sample SD per axis over all intervals (:func:`pooled_sd`) and its degrees of freedom
    sd_pooled: Optional[np.ndarray] = None
    pooled_dof: int = 0
    #: indices of the intervals whose SD is floored by the pooled SD (fewer than MIN_OWN_SD_SAMPLES)
    pooled_floor: list = field(default_factory=list)
    #: what the fit should say about the averages (short intervals, the pool's size)
    notes: list = field(default_factory=list)
    #: per axis: the readings' resolution (LSB, the recording's unit; 0 when they are on no grid), the
    #: per-sample noise before rounding, and the RMS rounding error of a mean that ``se`` includes
    #: (:func:`rounding_floor`)
    lsb: Optional[np.ndarray] = None
    sigma_before_rounding: Optional[np.ndarray] = None
    rounding_u: Optional[np.ndarray] = None


#: a static interval with at least this fraction of one channel's samples on the recording's extreme
#: value is a pile, examined as a clipped channel (:func:`clipped_intervals`). It was 0.2: an outside
#: probe's channel clipped at one noise SD above its +1 g face (16-17 % of the face on the rail, 30 s at
#: 200 Hz) went through with S_x 3-4.8 u off in 4 of 20 fits, status ok; a rail at 1 SD moves the
#: face's mean by 0.08 SD, several times its standard error over thousands of samples
PILE_FRACTION = 0.05


def clipped_intervals(rec: RawRecording, detection: StaticDetection) -> list:
    """``[(interval, axis, extreme, count, n, expected_fraction), ...]``: the static intervals in
    which a channel sits on the recording's largest or smallest value far more often than its noise
    allows: a channel clipped at full scale (its readings beyond the range collapse onto one value).

    A channel whose noise elsewhere has SD ``sigma`` (the median SD of its other static intervals)
    and whose readings come in steps ``q`` (the smallest difference of its distinct values: one
    count of a digital output, ~0 for floats) puts at most ``q phi(z) / sigma`` of an interval's
    samples on a value ``z = |value - median| / sigma`` SDs from the interval's median (a normal
    density there times the step; the peak's ``q / (sigma sqrt(2 pi))`` at z = 0, a clipped face's
    median is pulled toward the rail, which only raises the bound; 1 when the noise is below a step).
    A pile of at least :data:`PILE_FRACTION` and three times that bound on the recording's extreme is
    clipping: an axis clipped at 2075 counts held 684 of its samples there, with sigma 8 counts
    (bound 5 %), and the fit said ok with K_x 19 u off (an outside probe)."""
    out = []
    ivs = [iv for iv in detection.intervals if iv.end - iv.start >= 2]
    if len(ivs) < 2:
        return out
    for a in range(rec.acc.shape[1]):
        col = rec.acc[:, a]
        values = np.unique(col)
        if len(values) < 2:
            continue
        q = float(np.min(np.diff(values)))
        sds = [float(np.std(col[iv.start:iv.end], ddof=1)) for iv in ivs]
        for ext in (float(values[-1]), float(values[0])):
            for k, iv in enumerate(ivs):
                x = col[iv.start:iv.end]
                count = int(np.count_nonzero(x == ext))
                if count < PILE_FRACTION * len(x):
                    continue
                others = [v for j, v in enumerate(sds) if j != k and v > 0]
                if not others:
                    continue
                sigma = float(np.median(others))
                zt = abs(ext - float(np.median(x))) / sigma
                bound = min(1.0, q * math.exp(-0.5 * zt * zt) / (sigma * math.sqrt(2.0 * math.pi)))
                if count > max(PILE_FRACTION, 3.0 * bound) * len(x):
                    out.append((iv, a, ext, count, len(x), bound))
    return out


def _channel_in(iv, a: int) -> str:
    """``"x in the interval LABEL (samples s-e)"``: where a refusal of one channel's readings is."""
    return f"{'xyz'[a] if a < 3 else a} in the interval {iv.label or '(unlabelled)'} (samples {iv.start}-{iv.end - 1})"


def refuse_clipped(rec: RawRecording, detection: StaticDetection) -> None:
    """Refuse a recording with a clipped static interval (:func:`clipped_intervals`), naming it."""
    clipped = clipped_intervals(rec, detection)
    if not clipped:
        return
    parts = [f"{_channel_in(iv, a)}: {count} of {n} samples on the recording's {'largest' if ext == float(np.max(rec.acc[:, a])) else 'smallest'}"
             f" value {ext:g} {rec.unit}, where its noise elsewhere puts at most {bound:.1%} on one value"
             for iv, a, ext, count, n, bound in clipped]
    raise InputError(f"{rec.source}: a channel is clipped at full scale: " + "; ".join(parts)
                     + ". The readings of that pose are not the unit's: redo it with a range that holds it, or "
                       "leave the interval out (--intervals)")


#: an interval with fewer samples than this gets the pooled SD of the recording's intervals as the
#: floor of its own (its own SD is uncertain by more than 10 %, 1/sqrt(2 (n - 1)), and too short for
#: the batch means that check correlated noise: the same 50 = 5 x 10 batches)
MIN_OWN_SD_SAMPLES = 50


def pooled_sd(x_blocks) -> tuple:
    """``(sd, dof)``: the pooled sample SD per column over blocks of samples (GUM 4.2.4: the
    within-block variances weighted by their degrees of freedom ``n_i - 1``); blocks of one sample
    add nothing. ``sd`` is NaN when no block has two samples."""
    ss, dof = 0.0, 0
    for x in x_blocks:
        if len(x) >= 2:
            ss = ss + np.sum((x - x.mean(axis=0)) ** 2, axis=0)
            dof += len(x) - 1
    if dof == 0:
        return np.full(np.shape(x_blocks[0])[1:] if len(x_blocks) else (3,), np.nan), 0
    return np.sqrt(ss / dof), dof


#: the longest lag of the pooled autocorrelation (samples): beyond it a correlation is the batch means'
MAX_ACF_LAG = 2000
#: correction steps for the bias of the subtracted means (:func:`integrated_autocorrelation`)
STEPS = 2
#: the samples of an interval the autocorrelation is estimated from (its first)
ACF_BLOCK = 10 * MAX_ACF_LAG


def integrated_autocorrelation(blocks) -> tuple:
    """``(tau, lag)`` per column: the integrated autocorrelation time of the noise within the static
    intervals (samples; 1 for white noise) and the lag where its sum stopped, from the autocovariance
    pooled over the intervals (each about its own mean; the noise is one instrument's, so every
    interval's samples estimate it) by Geyer's initial positive sequence (Geyer 1992, Statistical
    Science 7: 473): ``tau = -1 + 2 sum_{m=0}^{M} Gamma_m``, ``Gamma_m = rho_2m + rho_2m+1``, summed while
    positive and made non-increasing. Each interval's mean, subtracted, lowers every ``rho_k`` by about
    ``tau / n`` (n the sample-weighted mean length of the intervals): put back as
    ``rho_k (1 - tau/n) + tau/n`` and the sum taken again, :data:`STEPS` times (at most ``n / 2``; to the
    fixed point the iteration can run away). On AR(1) noise in 30 intervals (20 draws each): tau 19,
    n 400: 19.5 (SD 2.5); tau 39, n 400: the truncated sum alone 29 (SD 2), corrected 41.4 (SD 7); tau 39,
    n 300: 37.4 (SD 5); tau 99, n 400: 80 (SD 15), low where an interval holds only a few correlation
    times (the batch means are the guard there).

    The variance of an interval's mean is then ``tau sd^2 / n``, where ``sd^2 / n`` (white noise) took it
    as 1: an output filtered by a one-pole low-pass of ``y += 0.05 (x - y)`` (tau 39) had floors 0.64-0.74
    of the exact ones, chi2 inflated 2.7-3.1 times, and the raw diagnosis said "unexplained" 14 of 20
    times or named g_dependent_misalignment on a clean recording (an outside probe); ten batch means of
    30-40 samples, about one correlation time, do not see it."""
    cols = blocks[0].shape[1] if blocks and np.ndim(blocks[0]) == 2 else 1
    # at most ACF_BLOCK samples of each interval: ten times the longest lag, the noise's
    # autocovariance needs no more (10^7 samples in 150 intervals: 0.3 s saved)
    usable = [np.asarray(b[:ACF_BLOCK], float).reshape(min(len(b), ACF_BLOCK), -1) for b in blocks if len(b) >= 8]
    if not usable:
        return np.ones(cols), np.zeros(cols, int)
    L = int(min(MAX_ACF_LAG, max(len(b) for b in usable) // 2))
    acov, count = np.zeros((L + 1, cols)), np.zeros(L + 1)
    for b in usable:
        x = b - b.mean(axis=0)
        n = len(x)
        m = 1 << int(np.ceil(np.log2(2 * n)))
        f = np.fft.rfft(x, m, axis=0)
        ac = np.fft.irfft(f * np.conj(f), m, axis=0)[:min(L, n - 1) + 1]
        acov[:len(ac)] += ac
        count[:len(ac)] += n - np.arange(len(ac))
    ok = count > 0
    acov, count = acov[ok], count[ok]
    gamma = acov / count[:, None]
    n_bar = float(sum(len(b) ** 2 for b in usable) / sum(len(b) for b in usable))
    tau, lag = np.ones(cols), np.zeros(cols, int)

    def ips(rho):
        pairs = len(rho) // 2
        G = rho[:2 * pairs].reshape(pairs, 2).sum(axis=1)
        stop = np.flatnonzero(G <= 0)
        M = int(stop[0]) if stop.size else pairs
        if not M:
            return 1.0, 0
        return max(-1.0 + 2.0 * float(np.minimum.accumulate(G[:M]).sum()), 1.0), 2 * M - 1

    for c in range(cols):
        if not gamma[0, c] > 0:
            continue
        rho_hat = gamma[:, c] / gamma[0, c]
        t, L_used = ips(rho_hat)
        for _ in range(STEPS):          # rho_k = rho_hat_k (1 - tau/n) + tau/n: the means' bias put back
            f = min(t, n_bar / 2.0) / n_bar
            t_new, L_used = ips(rho_hat * (1.0 - f) + f)
            t_new = min(t_new, n_bar / 2.0)
            if abs(t_new - t) <= 1e-3 * t:
                t = t_new
                break
            t = t_new
        tau[c], lag[c] = float(min(max(t, 1.0), n_bar / 2.0)), L_used
    return tau, lag


#: an integrated autocorrelation time below this is taken as white noise (its estimate's own scatter)
TAU_WHITE = 1.2


def correlated_mean_factor(tau, n: int):
    """The variance of a mean of ``n`` samples of noise with integrated autocorrelation time ``tau``
    (:func:`integrated_autocorrelation`) over the white-noise ``sd^2 / n`` with ``sd`` the samples' own
    SD about their mean: ``tau (n - 1) / (n - tau)`` (the SD about the mean is itself short by
    ``(n - tau)/(n - 1)``), at most ``n`` (a mean of samples that all move together is one sample);
    1 where ``tau <= TAU_WHITE`` (white noise, as before)."""
    t = np.asarray(tau, float)
    f = np.where(n > t, t * (n - 1) / np.maximum(n - t, 1e-9), float(n))
    return np.where(t > TAU_WHITE, np.minimum(f, float(n)), 1.0)


def rounding_floor(blocks, sd_pooled) -> tuple:
    """``(lsb, sigma, u)`` per axis: the readings' resolution, the noise before rounding and the
    standard uncertainty that rounding leaves in each interval's mean (docs/raw.md, "Readings on a grid").

    ``lsb`` is the step every static reading of the axis is a multiple of
    (:func:`~triadcal.models.effects.quantisation.resolution_lsb` on the distinct readings; 0 when they
    lie on no grid, as most scaled or filtered outputs). ``sigma`` is the per-sample SD before rounding
    that the pooled within-interval SD implies, the poses' signals taken as spread uniformly over the LSB
    (:func:`~triadcal.models.effects.quantisation.sigma_from_phase_averaged_variance`). ``u`` is the RMS
    over that phase of the error of a long mean (:func:`~triadcal.models.effects.quantisation.phase_rms_error`:
    ``lsb/sqrt(12)`` when the counts of the intervals never change, JCGM 100:2008 F.2.2.1; below 1e-8 LSB
    once sigma > 1 LSB): a pose's error is fixed for its signal, random over poses, and no number of
    samples averages it away. Before, an interval whose counts never change had a sample SD of 0 and its
    mean was taken as exact (its ``se`` 1e-12 of the reading): 30 poses of a 64 counts/g triad with
    0.05 LSB of noise failed the goodness of fit (ratio 334) and the raw diagnosis called the rounding
    "unexplained" (chi2/dof 6.5e17). Each interval's own phase is not used: a constant interval's mean
    does not say where between two codes its signal lies, and the mean of one that flips between two
    codes is as far from its signal (up to 0.4 LSB at sigma = 0.05 LSB)."""
    from ...models.effects.quantisation import (
        phase_rms_error,
        resolution_lsb,
        sigma_from_phase_averaged_variance,
    )

    n_ax = len(sd_pooled)
    lsb, sig, u = np.zeros(n_ax), np.full(n_ax, np.nan), np.zeros(n_ax)
    # the distinct readings of at most ~2e5 samples evenly spread (10^7 samples: a second saved per axis),
    # taken from each interval without copying the rest; a grid broken only in the samples skipped is
    # taken as a grid (it matters only below 1 LSB)
    step = max(1, sum(len(b) for b in blocks) // 200_000)
    for a in range(n_ax):
        q = resolution_lsb(np.unique(np.concatenate([b[::step, a] for b in blocks])))
        if q is None or not math.isfinite(float(sd_pooled[a])):
            continue
        lsb[a] = q
        sig[a] = sigma_from_phase_averaged_variance(float(sd_pooled[a]) ** 2, q)
        u[a] = float(phase_rms_error(q, sig[a]))
    return lsb, sig, u


def pose_averages(rec: RawRecording, detection: StaticDetection, batches: int = 10) -> PoseAverages:
    """Each static interval's mean, SD and the standard uncertainty of its mean (docs/raw.md, "The
    noise of each interval's mean"). Every interval is used, none dropped: the noise is one
    instrument's, so an interval of fewer than :data:`MIN_OWN_SD_SAMPLES` samples has as its SD the
    larger of its own and the pooled SD of all the intervals (:func:`pooled_sd`), and a 1-sample
    interval the pooled SD; ``notes`` names them. Before, a face of 2 samples whose SD happened to
    be small gave K_x 9.7 u off with status ok, and a 1-sample interval was left out without a word."""
    refuse_wrapped(rec, detection)           # first: a wrapped channel also piles on the range's ends
    refuse_clipped(rec, detection)
    ivs = list(detection.intervals)
    blocks = [rec.acc[iv.start:iv.end] for iv in ivs]
    sd_pool, dof_pool = pooled_sd(blocks)
    if dof_pool == 0:
        raise StaticIntervalError(f"{rec.source}: no static interval with at least 2 samples: the noise of the "
                                  "means cannot be estimated (give intervals of more samples)")
    acf_tau, _ = integrated_autocorrelation(blocks)
    w, sd, sd_own, n, se, t, tau, lab, s0, e0, floored = [], [], [], [], [], [], [], [], [], [], []
    for k, (iv, x) in enumerate(zip(ivs, blocks)):
        m = x.mean(axis=0)
        own = x.std(axis=0, ddof=1) if len(x) >= 2 else np.full(x.shape[1], np.nan)
        s = own
        if len(x) < MIN_OWN_SD_SAMPLES:
            s = np.fmax(own, sd_pool)           # fmax: the pool where the own SD is NaN (one sample)
            floored.append(k)
        white = s * np.sqrt(correlated_mean_factor(acf_tau, len(x)) / len(x))
        if len(x) >= 5 * batches:
            bm = np.array([b.mean(axis=0) for b in np.array_split(x, batches)])
            white = np.maximum(white, bm.std(axis=0, ddof=1) / math.sqrt(batches))
        w.append(m), sd.append(s), sd_own.append(own), n.append(len(x)), se.append(white)
        t.append((iv.start + iv.end - 1) / 2 / rec.rate_hz), tau.append(len(x) / rec.rate_hz)
        lab.append(iv.label), s0.append(iv.start), e0.append(iv.end)
    lsb, sig_q, u_q = rounding_floor(blocks, sd_pool)
    white = np.array(se)
    se = np.sqrt(white ** 2 + u_q[None, :] ** 2)                          # the rounding of each mean
    se = np.maximum(se, 1e-12 * np.maximum(np.abs(np.array(w)), 1.0))   # an exactly constant input
    notes = []
    frozen = np.array([[float(np.ptp(x[:, a])) == 0.0 for a in range(len(lsb))] for x in blocks]) & (lsb > 0)
    big = u_q > 0.1 * np.median(white, axis=0)
    if np.any(big):
        parts = [f"{AXES[a]}: LSB {lsb[a]:.4g}, {int(np.sum(frozen[:, a]))} of {len(blocks)} intervals without a "
                 f"change, noise {sig_q[a]:.3g} before rounding, u {u_q[a]:.3g}" for a in range(len(lsb)) if big[a]]
        notes.append(f"the readings are on a grid ({'; '.join(parts)}; {rec.unit}): a mean of rounded readings "
                     "keeps a rounding error that no number of samples averages away (LSB/sqrt(12) when the "
                     "counts never change, JCGM 100 F.2.2.1; less as the noise dithers them), u, added to each "
                     "interval's standard uncertainty (docs/raw.md, \"Readings on a grid\")")
    if floored:
        names = ", ".join(f"{ivs[k].label or k + 1} (samples {ivs[k].start}..{ivs[k].end - 1}, {ivs[k].n} "
                          f"sample{'s' if ivs[k].n != 1 else ''})" for k in floored)
        notes.append(f"{len(floored)} static interval{'s' if len(floored) != 1 else ''} of fewer than "
                     f"{MIN_OWN_SD_SAMPLES} samples: {names}; each is used with the larger of its own SD and the "
                     f"pooled SD of all {len(ivs)} intervals ({', '.join(f'{v:.3g}' for v in sd_pool)} {rec.unit}, "
                     f"{dof_pool} dof) as its noise: a few samples' own SD can be small by chance (docs/raw.md)")
    if dof_pool < 30:
        notes.append(f"the pooled noise SD of the static intervals has only {dof_pool} degrees of freedom: the "
                     f"uncertainties are themselves uncertain by about {100 / math.sqrt(2 * dof_pool):.0f} % "
                     "(record longer static intervals)")
    return PoseAverages(lab, np.array(s0), np.array(e0), np.array(w), np.array(sd), np.array(n), se,
                        np.array(t), np.array(tau), np.array(sd_own), sd_pool, dof_pool, floored, notes,
                        lsb, sig_q, u_q)


def wrapped_intervals(rec: RawRecording, detection: StaticDetection) -> list:
    """``[(interval, axis, bits, low, high, sd, sd_unwrapped), ...]``: static intervals in which a
    channel of whole, non-negative counts jumps between the bottom and the top of a ``bits``-bit
    range the way signed (two's-complement) counts read as unsigned do: readings just below zero
    appear just below ``2^bits``. Unwrapped (``v - 2^bits`` for ``v >= 2^(bits-1)``), the interval's
    samples of that channel scatter ten times less than as read. Before, the imucal session with its
    16-bit counts read as unsigned ended in an internal error (exit 70, LinAlgError) after the fit had
    pushed the placement SD to the grid's 20 deg edge (an outside probe)."""
    out = []
    for iv in detection.intervals:
        x = rec.acc[iv.start:iv.end]
        if len(x) < 2:
            continue
        for a in range(x.shape[1]):
            v = x[:, a]
            top = float(v.max())
            if v.min() < 0 or top < 255 or not np.all(v == np.round(v)):
                continue
            bits = int(math.floor(math.log2(top))) + 1          # the smallest range holding the readings
            full = float(2 ** bits)
            high = v >= full / 2
            if not (high.any() and (~high).any()):
                continue
            u = np.where(high, v - full, v)
            sd, sd_u = float(v.std(ddof=1)), float(u.std(ddof=1))
            if sd > 10.0 * max(sd_u, 0.5):
                out.append((iv, a, bits, (float(v[~high].min()), float(v[~high].max())),
                            (float(v[high].min()), float(v[high].max())), sd, sd_u))
    return out


def refuse_wrapped(rec: RawRecording, detection: StaticDetection) -> None:
    """Refuse a recording with a wrapped channel (:func:`wrapped_intervals`), naming the interval."""
    wrapped = wrapped_intervals(rec, detection)
    if not wrapped:
        return
    parts = [f"{_channel_in(iv, a)} jumps between {lo[0]:g}..{lo[1]:g} and {hi[0]:g}..{hi[1]:g} (SD {sd:.4g}; "
             f"{sd_u:.3g} with the values from {2 ** (bits - 1)} up taken as negative, minus {2 ** bits})"
             for iv, a, bits, lo, hi, sd, sd_u in wrapped]
    bits = wrapped[0][2]
    more = f"; and {len(parts) - 3} more" if len(parts) > 3 else ""
    raise InputError(f"{rec.source}: the readings look like signed {bits}-bit (two's-complement) counts read as "
                     f"unsigned: " + "; ".join(parts[:3]) + more + f". Convert the columns to signed counts (subtract "
                     f"{2 ** bits} from every value of {2 ** (bits - 1)} or more) and fit again")


def bench_campaign(avg: PoseAverages, rec: RawRecording, serial: str, local_g_m_s2: Optional[float],
                   temperature_C: float = 20.0) -> Campaign:
    """The known-pose averages as bench CSV v1 visits (positions of DEFAULT_PLAN with the same
    axis up). There is no temperature channel: ``t_*`` hold ``temperature_C`` and the
    metadata says so. ``local_g_m_s2`` None (the user stated none): the file states none either,
    so a fit of it says so (``Campaign.local_g_stated``) instead of taking the assumed value for the
    site's."""
    pos = [POSE_POSITIONS[lab] for lab in avg.label]
    a1 = np.array([DEFAULT_PLAN[p][0] for p in pos])
    a2 = np.array([DEFAULT_PLAN[p][1] for p in pos])
    k = len(pos)
    meta = {"generator": "triadcal fit-raw (position averages of a raw recording)",
            "source": rec.source, "rate_hz": repr(rec.rate_hz), "output_unit": rec.unit,
            "input_unit": rec.unit,
            "bench": "none: hand-placed poses (imucal labels " + ",".join(avg.label) + ")",
            "temperature": f"not measured; t_x t_y t_z hold a constant {temperature_C:g} degC placeholder"}
    if local_g_m_s2 is not None:
        meta["local_g_m_s2"] = repr(float(local_g_m_s2))
    if avg.lsb is not None and np.all(avg.lsb > 0) and np.ptp(avg.lsb) <= 1e-9 * float(np.max(avg.lsb)):
        # readings on one grid (rounding_floor): the bench path's quantisation term reads it
        meta["quantisation_lsb"] = repr(float(avg.lsb[0]))
    return Campaign(
        unit=np.full(k, serial), setpoint_C=np.full(k, temperature_C), direction=np.full(k, "none"),
        time_s=avg.time_s.astype(float), position=np.array(pos), axis1_deg=a1, axis2_deg=a2,
        tau_s=avg.tau_s.astype(float), w=avg.w.copy(), t=np.full((k, 3), float(temperature_C)),
        cycle=np.zeros(k, int), state=np.full(k, "initial"), sd=avg.sd.copy(), n_samples=avg.n.astype(int),
        metadata=meta, source=rec.source)
