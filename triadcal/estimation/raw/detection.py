"""Static intervals of a raw recording: detected, or taken from labels or an interval file.

:func:`detect_static_intervals` (steps 1-4: noise per axis, moving SD of each axis,
threshold, runs extended and trimmed) returns a :class:`StaticDetection` or raises
:class:`StaticIntervalError` with the numbers; :func:`intervals_from_labels` and
:func:`intervals_from_spec` take them from a label column or an interval file.
Derivation/design: docs/raw.md (Static intervals: steps 1-4, why these choices).
"""

from __future__ import annotations

from ...errors import InputError

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

#: imucal's labels of the six Ferraris poses: x_p = +X up, x_a = X down (a for "anti")
POSE_LABELS = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")


class StaticIntervalError(InputError):
    """Too few (or no usable) static intervals for the requested calibration."""


@dataclass
class StaticInterval:
    """Samples ``[start, end)`` of one static interval and their pose label ('' if unknown)."""

    start: int
    end: int
    label: str = ""

    @property
    def n(self) -> int:
        return self.end - self.start


@dataclass
class StaticDetection:
    """What the static-interval step found, and how."""

    intervals: list
    method: str                       # "detector", "labels COLUMN", "intervals FILE"
    noise_sd: Optional[np.ndarray] = None   # per axis, input unit (detector only)
    threshold: Optional[float] = None
    window_s: Optional[float] = None
    min_duration_s: Optional[float] = None
    static_fraction: Optional[float] = None
    ignored: list = field(default_factory=list)   # e.g. labels that are not static poses

    def summary(self, rate_hz: float) -> str:
        d = [iv.n / rate_hz for iv in self.intervals]
        text = (f"{len(self.intervals)} static intervals from {self.method}"
                + (f", {min(d):.1f} .. {max(d):.1f} s long" if d else ""))
        if self.noise_sd is not None:
            text += (f"; noise SD per axis {', '.join(f'{s:.3g}' for s in self.noise_sd)}, "
                     f"threshold {self.threshold:g} x noise over {self.window_s:g} s windows, "
                     f"minimum {self.min_duration_s:g} s; {100 * self.static_fraction:.0f} % of samples static")
        if self.ignored:
            text += f"; ignored: {', '.join(self.ignored)}"
        return text

    def to_dict(self, rate_hz: float) -> dict:
        return {"method": self.method, "n_intervals": len(self.intervals),
                "intervals": [{"start": iv.start, "end": iv.end, "label": iv.label,
                               "duration_s": iv.n / rate_hz} for iv in self.intervals],
                "noise_sd": None if self.noise_sd is None else [float(s) for s in self.noise_sd],
                "threshold": self.threshold, "window_s": self.window_s,
                "min_duration_s": self.min_duration_s, "static_fraction": self.static_fraction,
                "ignored": list(self.ignored)}


#: a sample farther than this many robust ranges from a column's median is a spike to :func:`moving_sd`
SPIKE_RANGES = 100.0


def moving_sd(x: np.ndarray, window: int) -> np.ndarray:
    """Centred moving standard deviation of each column (edges use the nearest full window).

    Running sums of the centred samples and their squares (float64), differenced by slices
    (no index arrays), one column at a time: memory ~4 n floats whatever the length. A sample
    beyond :data:`SPIKE_RANGES` times the column's robust range (its 0.1 % .. 99.9 % quantiles)
    from the median enters the sums at that distance: every window holding it is still far from
    static, and the sums keep their precision. One reading of 1e9 in a recording of ~10 m/s2 put
    1e18 into the running sum of squares, whose differences then lost every digit: most intervals
    of the file were lost ("found 4 static intervals", an outside probe)."""
    x = np.asarray(x, float)
    n = len(x)
    window = max(2, min(window, n))
    out = np.empty_like(x)
    half = window // 2
    for j in range(x.shape[1]):
        col = x[:, j] - x[:, j].mean()
        lo, med, hi = np.quantile(col[::max(1, n // 100_000)], (0.001, 0.5, 0.999))   # a sample is enough
        reach = SPIKE_RANGES * max(hi - lo, 1e-300)
        if np.any(np.abs(col - med) > reach):
            np.clip(col, med - reach, med + reach, out=col)
            col -= col.mean()                   # the spike had moved the mean, and the centre, far off
        c = np.empty(n + 1)
        c[0] = 0.0
        np.cumsum(col, out=c[1:])
        m = c[window:] - c[:-window]                                # windows starting at 0 .. n - window
        m /= window
        np.square(col, out=col)
        np.cumsum(col, out=c[1:])
        del col
        sd = c[window:] - c[:-window]
        sd /= window
        m *= m
        sd -= m
        del m
        np.maximum(sd, 0.0, out=sd)
        sd *= window / (window - 1)
        np.sqrt(sd, out=sd)
        out[half:half + len(sd), j] = sd
        out[:half, j] = sd[0]
        out[half + len(sd):, j] = sd[-1]
    return out


def _flat_windows(diffs: np.ndarray, n: int, window: int) -> np.ndarray:
    """Which centred windows of :func:`moving_sd` (``n`` of them, its alignment) hold one reading
    only, from the column's successive differences ``diffs`` (integer counts: exact)."""
    window = max(2, min(window, n))
    changes = np.concatenate([[0], np.cumsum(diffs != 0)])
    starts = changes[window - 1:] - changes[:len(changes) - window + 1] == 0      # windows starting at 0 .. n - window
    out = np.empty(n, bool)
    half = window // 2
    out[half:half + len(starts)] = starts
    out[:half] = starts[0]
    out[half + len(starts):] = starts[-1]
    return out


def robust_noise_sd(acc: np.ndarray, window: int, sd: Optional[np.ndarray] = None) -> np.ndarray:
    """Per-axis white-noise SD (step 1 of the module docstring), never zero or NaN; ``sd`` the
    :func:`moving_sd` of ``acc`` when the caller has it already. One axis at a time, so the
    temporaries are one column long (a 10^7-sample recording stays within its memory budget)."""
    acc = np.asarray(acc, float)
    sd = moving_sd(acc, window) if sd is None else sd
    out = np.empty(acc.shape[1])
    for i in range(acc.shape[1]):
        d = np.diff(acc[:, i])
        med = np.median(d)
        a = np.abs(d - med)
        sd_diff = 1.4826 * float(np.median(a)) / np.sqrt(2.0)
        col_sd = sd[:, i]
        if sd_diff > 0:
            # a noise above the output's step leaves no window flat: a flat one (every reading the same) is
            # the channel stuck or clipped at its full scale, not its noise (an outside probe: a face clipped
            # on x for 13.5 % of the recording put the 10th percentile at 0, only the clipped face looked
            # static, and the refusal blamed missing faces, not the clipping). Flat is counted exactly, on
            # the readings: the running sums leave a flat window of floats an SD of ~1e-7, not 0
            flat = _flat_windows(d, len(col_sd), window)
            if not np.all(flat):
                col_sd = col_sd[~flat]
        sd_low = float(np.percentile(col_sd, 10))
        np.abs(d, out=d)
        nz = d[d > 0]
        step = float(nz.min()) if len(nz) else 1.0
        out[i] = max(min(sd_low, 2.0 * sd_diff), step / np.sqrt(12.0))
    return out


def detect_static_intervals(acc: np.ndarray, rate_hz: float, *, window_s: float = 1.0,
                            threshold: float = 3.0, min_duration_s: float = 2.0,
                            trim_s: float = 0.25, min_intervals: int = 1) -> StaticDetection:
    """Find the static intervals of a recording (module docstring, steps 1-4)."""
    acc = np.asarray(acc, float)
    if not np.all(np.isfinite(acc)):
        raise InputError("the recording holds NaN or infinite samples; clean them before detecting static intervals")
    n = len(acc)
    window = max(3, int(round(window_s * rate_hz)))
    min_len = int(round(min_duration_s * rate_hz))
    trim = int(round(trim_s * rate_hz))
    if n < max(window, min_len + 2 * trim):
        raise StaticIntervalError(f"the recording has {n} samples ({n / rate_hz:.1f} s at {rate_hz:g} Hz): "
                                  f"too short for a {window_s:g} s window and {min_duration_s:g} s intervals")
    sd = moving_sd(acc, window)
    sigma = robust_noise_sd(acc, window, sd)
    static = np.all(sd <= threshold * sigma, axis=1)
    edges = np.diff(np.concatenate([[0], static.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    intervals = []
    half = window // 2
    for s, e in zip(starts, ends):
        # every sample of a quiet window is static: extend the run of quiet centres by half a
        # window on each side, then cut the settling time
        s2, e2 = max(0, s - half) + trim, min(n, e + window - half - 1) - trim
        if e2 - s2 >= max(min_len, 2):
            intervals.append(StaticInterval(int(s2), int(e2)))
    det = StaticDetection(intervals, "detector", sigma, float(threshold), float(window_s), float(min_duration_s),
                          float(static.mean()))
    if len(intervals) < min_intervals:
        longest = max(((e - s) / rate_hz for s, e in zip(starts, ends)), default=0.0)
        raise StaticIntervalError(
            f"found {len(intervals)} static intervals of at least {min_duration_s:g} s, {min_intervals} needed "
            f"({100 * static.mean():.0f} % of samples look static, longest run {longest:.1f} s; noise SD per axis "
            f"{', '.join(f'{s:.3g}' for s in sigma)}). Check the stated rate, lower --min-static-s, raise "
            "--static-threshold, or give the intervals with --intervals FILE / --labels COLUMN" + _repeats(acc))
    return det


def _repeats(acc: np.ndarray) -> str:
    """A hint when at least 40 % of the samples repeat the one before on all three channels while the
    noise moves them otherwise: a logger that wrote each sample twice (an outside probe's file was
    refused as "no static intervals" with a noise SD at the quantisation floor, the repeats named
    nowhere)."""
    d = np.diff(acc, axis=0)
    same = np.all(d == 0.0, axis=1)
    if len(d) < 10 or same.mean() < 0.4 or not np.any(d[~same] != 0.0):
        return ""
    return (f"; {100 * same.mean():.0f} % of the samples repeat the one before on all three channels: each sample "
            "written twice (or more)? the noise and the rate are then wrong; remove the repeats, or state the rate "
            "of the repeated samples")


#: labels that never mark a static pose (imucal's rotation parts, a simulator's moves, blanks)
MOTION_LABELS = ("x_rot", "y_rot", "z_rot", "move", "moving", "")


def intervals_from_labels(labels: Sequence[str], column: str = "labels",
                          keep: Optional[Sequence[str]] = POSE_LABELS) -> StaticDetection:
    """One interval per contiguous run of a label in ``keep`` (``None``: every label except
    :data:`MOTION_LABELS`); other labels are listed as ignored."""
    labels = np.asarray(labels).astype(str)
    if len(labels) == 0:
        raise StaticIntervalError("the label column is empty")
    change = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(labels)]])
    intervals, ignored = [], []
    for s, e in zip(starts, ends):
        lab = labels[s]
        if (lab in keep) if keep is not None else (lab not in MOTION_LABELS):
            intervals.append(StaticInterval(int(s), int(e), lab))
        elif lab not in ignored:
            ignored.append(lab)
    return StaticDetection(intervals, f"labels column '{column}'", ignored=ignored)


def intervals_from_spec(start, end, labels: Optional[Sequence[str]], n_samples: int, source: str,
                        keep: Optional[Sequence[str]] = POSE_LABELS) -> StaticDetection:
    """Intervals from an interval file; labelled entries not in ``keep`` are ignored (e.g. imucal's
    ``x_rot``), limits beyond the recording are refused."""
    intervals, ignored = [], []
    for k, (s, e) in enumerate(zip(start, end)):
        lab = labels[k] if labels else ""
        if labels and ((lab not in keep) if keep is not None else (lab in MOTION_LABELS)):
            ignored.append(lab)
            continue
        if s < 0 or e > n_samples:
            raise StaticIntervalError(f"{source}: interval {k + 1} ({lab or ''} {s}..{e}) lies outside the "
                                      f"recording's {n_samples} samples")
        intervals.append(StaticInterval(int(s), int(e), lab))
    return StaticDetection(intervals, f"intervals file {source}", ignored=ignored)


def pose_label_of(mean_acc: np.ndarray) -> str:
    """imucal label of the pose whose up axis is the largest component of the mean reading."""
    i = int(np.argmax(np.abs(mean_acc)))
    return "xyz"[i] + ("_p" if mean_acc[i] > 0 else "_a")
