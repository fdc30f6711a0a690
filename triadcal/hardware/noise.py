"""White-noise intensity Q and bias instability from raw samples (Allan deviation).

For white output noise of intensity Q (V^2 s) the Allan variance is
``sigma^2(tau) = Q / tau`` — the same Q as in eq. 4 of the seed paper, where the mean
over an averaging time tau has variance Q / tau. The overlapping Allan deviation
(allantools) of each stationary recording window (one per visit) is pooled over the
windows, weighted by the number of terms at each tau; Q is the weighted mean of
``sigma^2(tau) * tau`` over the shortest averaging times (m = 1, 2, 4 samples), where
white noise dominates; the bias instability is the floor of the deviation divided by
0.664 (IEEE Std 952), an upper bound when the curve is still falling at the longest tau.

Per-visit uncertainty (docs/hardware.md, "Per-visit uncertainty from the noise"): the pooled
overlapping Hadamard variance (a linear drift within a window does not enter it) is fitted with
the IEEE Std 952 power-law model ``sigma^2(tau) = Q/tau + B_f^2 + R tau/3`` in its Hadamard form
(:func:`fit_power_law`, non-negative least squares weighted by each point's confidence), and
:meth:`NoiseEstimate.visit_uncertainty` evaluates the variance of each visit's mean about the
campaign's mean from that model and the visits' times
(:func:`triadcal.models.noise_processes.visit_mean_variance`).
"""

from __future__ import annotations

from ..errors import InputError

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import allantools
import numpy as np

from ..models.noise_processes import allan_variance_power_law, hadamard_variance_power_law


@dataclass
class NoiseEstimate:
    """Q per axis (output unit^2 s), bias instability per axis (output unit), the pooled
    Allan deviation curve, and whether the floor was reached (else an upper bound)."""

    Q_V2s: tuple
    bias_instability_V: tuple
    floor_reached: tuple
    taus_s: np.ndarray
    adev: np.ndarray
    n_windows: int
    n_samples: int
    rate_hz: float
    details: dict = field(default_factory=dict)
    #: per axis the fitted power-law terms (Q unit^2 s, B_f^2 unit^2, R unit^2/s) and their
    #: standard errors (:func:`fit_power_law`); empty when not fitted
    power_law: tuple = ()
    power_law_se: tuple = ()
    #: the longest tau of the pooled curve (s): the model is extrapolated beyond it
    longest_tau_s: float = 0.0

    @property
    def Q_mean_V2s(self) -> float:
        return float(np.mean(self.Q_V2s))

    def metadata(self) -> dict:
        """``key = value`` lines for the bench CSV header."""
        md = {"Q_V2s": f"{self.Q_mean_V2s:.6g}"}
        for i, a in enumerate("xyz"):
            md[f"Q_{a}_V2s"] = f"{self.Q_V2s[i]:.6g}"
            md[f"bias_instability_{a}_V"] = (f"{self.bias_instability_V[i]:.6g}"
                                             + ("" if self.floor_reached[i] else " (upper bound)"))
        md["noise_method"] = (f"overlapping Allan deviation (allantools) over {self.n_windows} recording "
                              f"windows, {self.n_samples} samples at {self.rate_hz:.6g} Hz")
        if self.power_law:
            md["u_w_method"] = self.u_w_method()
        return md

    def u_w_method(self) -> str:
        """The ``u_w_method`` metadata line: how the ``u_w_*`` columns were made, with the terms."""
        terms = "; ".join(f"{a}: Q {q:.4g}, B_f {np.sqrt(bf2):.4g}, R {r:.4g}"
                          for a, (q, bf2, r) in zip("xyz", self.power_law))
        return ("variance of each visit mean about the campaign mean from the IEEE 952 power-law fit "
                "sigma^2(tau) = Q/tau + B_f^2 + R tau/3 of the pooled Hadamard variance (tau "
                f"{self.taus_s[0]:.3g}-{self.longest_tau_s:.3g} s, extrapolated beyond) and the visit times "
                f"(Barnes B2); {terms}")

    def visit_uncertainty(self, time_s, tau_s) -> np.ndarray:
        """Standard uncertainty of each visit's mean output (n, 3), output unit: the square root
        of :func:`~triadcal.models.noise_processes.visit_mean_variance` with this estimate's
        power-law terms per axis, at the visits' centres ``time_s`` and windows ``tau_s``."""
        from ..models.noise_processes import visit_mean_variance

        if not self.power_law:
            raise InputError("this noise estimate has no power-law fit")
        return np.stack([np.sqrt(visit_mean_variance(time_s, tau_s, *self.power_law[i])) for i in range(3)],
                        axis=1)


#: a non-white term is kept only when its estimate exceeds this many standard errors
TERM_SIGNIFICANCE = 3.0


def fit_power_law(taus_s, avar, edf, variance: str = "allan") -> tuple:
    """``(Q, B_f^2, R), (se_Q, se_Bf2, se_R)`` of the IEEE Std 952-1997 (Annex C) model
    ``sigma^2(tau) = Q/tau + B_f^2 + R tau/3`` fitted to an Allan-variance curve, or with
    ``variance="hadamard"`` to a Hadamard-variance curve
    (:func:`~triadcal.models.noise_processes.hadamard_variance_power_law`: the same terms, the
    flicker's and the random walk's with their Hadamard factors).

    Non-negative least squares (scipy ``nnls``), each point weighted by its confidence: an
    Allan variance estimated with ``edf`` equivalent degrees of freedom has the relative
    standard error ``sqrt(2/edf)``, so the residual of point k is divided by
    ``avar_k sqrt(2/edf_k)`` — first with the measured ``avar_k``, then once more with the fitted
    curve's value (a point that came out low must not weigh more). The standard errors come from the weighted normal equations of the
    terms kept, scaled by the fit's chi^2/dof when above 1. The white term is always kept; the
    flicker and random-walk terms only when their estimate exceeds ``TERM_SIGNIFICANCE`` (3)
    standard errors (and while the curve has more points than terms), else they are 0: a term
    the curve does not show is not extrapolated."""
    from scipy.optimize import nnls

    taus = np.asarray(taus_s, float)
    y = np.asarray(avar, float)
    rel = np.sqrt(2.0 / np.maximum(np.asarray(edf, float), 1.0))
    # a point of zero variance (a quantised output that did not change at that tau) has no
    # relative error to weigh it by: it is left out of the fit, never divided by
    pos = y > 0
    if not pos.any():
        raise InputError("the Allan variance is 0 at every tau: no noise to fit")
    taus, y, rel = taus[pos], y[pos], rel[pos]
    law = {"allan": allan_variance_power_law, "hadamard": hadamard_variance_power_law}.get(variance)
    if law is None:
        raise ValueError(f"variance {variance!r}: 'allan' or 'hadamard'")
    # one column per term: the curve of that term alone at unit size
    A_full = np.stack([np.broadcast_to(law(taus, *unit), taus.shape) for unit in ((1, 0, 0), (0, 1, 0), (0, 0, 1))],
                      axis=1)
    keep = [0, 1, 2]
    while True:
        sig = y * rel
        A = A_full[:, keep] / sig[:, None]
        x, _ = nnls(A, y / sig)
        # once more with the weights of the fitted curve (a low point must not weigh more)
        model = A_full[:, keep] @ x
        if np.all(model > 0):
            sig = model * rel
            A = A_full[:, keep] / sig[:, None]
            x, _ = nnls(A, y / sig)
        dof = len(y) - len(keep)
        chi2 = float(np.sum((A @ x - y / sig) ** 2))
        cov = np.linalg.pinv(A.T @ A) * max(1.0, chi2 / dof if dof > 0 else 1.0)
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        weak = [k for j, k in enumerate(keep) if k != 0 and (dof <= 0 or x[j] <= TERM_SIGNIFICANCE * se[j])]
        if not weak:
            break
        # drop the weakest (smallest t) non-white term and refit
        t = {k: x[keep.index(k)] / max(se[keep.index(k)], 1e-300) for k in weak}
        keep.remove(min(t, key=t.get))
    terms, errs = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    for j, k in enumerate(keep):
        terms[k], errs[k] = float(x[j]), float(se[j])
    return tuple(terms), tuple(errs)


def _pooled(windows, taus, rate_hz, deviation) -> tuple:
    """The variance ``deviation`` (allantools ``oadev`` or ``ohdev``) of each output at ``taus``,
    pooled over the windows weighted by each window's number of terms: ((3, k) variance, weights)."""
    var = np.zeros((3, len(taus)))
    weight = np.zeros((3, len(taus)))
    for w in windows:
        for i in range(3):
            t_used, dev, _, ns = deviation(w[:, i], rate=rate_hz, data_type="freq", taus=taus)
            idx = np.searchsorted(taus, t_used)
            ok = (idx < len(taus))
            idx = idx[ok]
            var[i, idx] += np.asarray(ns)[ok] * np.asarray(dev)[ok] ** 2
            weight[i, idx] += np.asarray(ns)[ok]
    return var, weight


def _white_edf(windows, ms, d: int) -> np.ndarray:
    """Equivalent degrees of freedom of the pooled overlapping Allan (``d = 2``) or Hadamard
    (``d = 3``) variance at each averaging factor ``m`` for white noise: Greenhall's (allantools
    ``edf_greenhall``; Greenhall and Riley, PTTI 2003) of each window, summed over the windows.
    The count of (m-mean) differences counted before overstated it 1.3-1.7x at m = 1, 2 (38 for
    22.8 at m = 1 in a 40-sample window): the white level's standard error came out too small (of two
    outputs of white noise read as a 3-SE flicker floor in 102 of emulated ramp captures, one is not
    with this edf)."""
    cache: dict = {}

    def one(n: int, m: int) -> float:
        if (n, m) not in cache:
            cache[n, m] = (float(allantools.edf_greenhall(alpha=0, d=d, m=int(m), N=int(n), overlapping=True,
                                                          modified=False)) if n >= d * m + 1 else 0.0)
        return cache[n, m]

    return np.array([sum(one(len(w), m) for w in windows) for m in ms], float)


def allan_noise(windows: Sequence[np.ndarray], rate_hz: float) -> NoiseEstimate:
    """Pool the overlapping Allan deviation of stationary windows (each (n_i, 3), output unit).

    The power-law terms (the ``u_w_*`` columns) are fitted to the pooled overlapping Hadamard
    variance (:func:`fit_power_law` with ``variance="hadamard"``), which a linear drift within a
    window does not enter: on a temperature ramp each window's outputs drift with the unit's
    temperature (held by the fit's model), and the Allan curve, raised by ``D^2 tau^2 / 2``, was
    fitted with a bias random walk white noise did not have (numpy windows whose drift raised the
    Allan curve 58 % at 8 s: u_w 32-59x sqrt(Q/tau); tests/test_hadamard_noise.py)."""
    windows = [np.asarray(w, float) for w in windows if len(w) >= 8]
    if not windows:
        raise InputError("no recording window with at least 8 samples: cannot estimate the noise")
    shortest = min(len(w) for w in windows)
    ms = 2 ** np.arange(0, int(np.log2(max(shortest // 4, 1))) + 1)
    taus = ms / rate_hz
    # equivalent dof of the pooled Hadamard points: each window's for white noise (the hypothesis the
    # fit's non-white terms are tested against), summed over the windows
    edf_h = _white_edf(windows, ms, 3)
    avar, weight = _pooled(windows, taus, rate_hz, allantools.oadev)
    hvar, weight_h = _pooled(windows, taus, rate_hz, allantools.ohdev)
    good = (weight.min(axis=0) > 0) & (weight_h.min(axis=0) > 0)
    avar, weight, taus = avar[:, good] / weight[:, good], weight[:, good], taus[good]
    hvar, edf_h = hvar[:, good] / weight_h[:, good], edf_h[good]
    flat = [a for i, a in enumerate("xyz") if not np.any(avar[i] > 0)]
    if flat:
        raise InputError(f"output {', '.join(flat)} is constant within every recording window "
                         f"({len(windows)} windows, {int(sum(len(w) for w in windows))} samples): a stuck "
                         "channel, or a resolution coarser than the noise; its noise cannot be estimated")
    adev = np.sqrt(avar)
    short = taus <= 4.0 / rate_hz
    Q = tuple(float(np.sum(weight[i, short] * avar[i, short] * taus[short]) / np.sum(weight[i, short]))
              for i in range(3))
    k_min = np.argmin(adev, axis=1)
    bi = tuple(float(adev[i, k_min[i]] / 0.664) for i in range(3))
    floor = tuple(bool(k_min[i] < len(taus) - 1) for i in range(3))
    fits = [fit_power_law(taus, hvar[i], edf_h, variance="hadamard") for i in range(3)]
    return NoiseEstimate(Q, bi, floor, taus, adev, len(windows), int(sum(len(w) for w in windows)),
                         float(rate_hz), power_law=tuple(f[0] for f in fits),
                         power_law_se=tuple(f[1] for f in fits), longest_tau_s=float(taus[-1]))


def campaign_noise(raw_path: Path, rows: list, run, metadata: dict) -> Optional[NoiseEstimate]:
    """The campaign's noise from the recording windows (:func:`_campaign_noise`), its header keys
    put in ``metadata``; when it cannot be estimated (a stuck output), ``noise_method`` says why
    and so does a warning of the run: a header without Q_* and u_w_* is never silent."""
    est = _campaign_noise(raw_path, rows, run.rate_hz)
    if isinstance(est, str):
        metadata["noise_method"] = f"not estimated: {est}"
        run.warnings.append(f"noise not estimated ({est}); campaign.csv has no Q_* nor u_w_* columns, "
                            "and a fit estimates the noise from its residuals")
        return None
    if est is not None:
        metadata.update(est.metadata())
    return est


def _campaign_noise(raw_path: Path, rows: list, rate_hz: Optional[float]):
    """The Allan-deviation noise of the recording windows of ``rows`` (a :class:`NoiseEstimate`),
    None when there is nothing to estimate from, or the reason (str) it cannot be estimated."""
    from .storage import read_raw

    if not rows:
        return None
    raw = read_raw(raw_path)
    rec = raw["phase"] == "record"
    wanted = {r["raw_visit"] for r in rows}
    windows = []
    for tag in wanted:
        m = rec & (raw["visit"] == tag)
        if m.sum() >= 8:
            windows.append(raw["w"][m])
    if rate_hz is None:
        dt = np.diff(raw["time_s"][rec])
        dt = dt[dt > 0]
        if not len(dt):
            return None
        rate_hz = 1.0 / float(np.median(dt))
    try:
        est = allan_noise(windows, rate_hz)
    except (InputError, ValueError) as exc:
        # no Q_* / u_w_* in the header: said once, in the report and the CSV (never silently)
        return str(exc)
    # per-visit standard uncertainty from the power-law fit and the visit times (u_w_* columns)
    u = est.visit_uncertainty([r["time_s"] for r in rows], [r["tau_s"] for r in rows])
    for r, u_i in zip(rows, u):
        r["u_w"] = u_i
    return est
