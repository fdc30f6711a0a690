"""The bench CSV reader's checks of misreads (docs/bench-csv.md, "Three misreads refused"):
metadata keys close to the ones triadcal reads, temperatures in degF, and heating/cooling labels
against the setpoint sequence. Each file these refuse used to read silently and give a confident
wrong calibration; :func:`triadcal.io.bench_csv.parse_bench_csv` calls them."""

from __future__ import annotations

import re
from typing import Optional

import numpy as np

from ..models.campaign import Campaign
from .bench_csv import BenchCSVError

#: metadata keys that triadcal reads (``metadata.get`` / ``metadata[...]`` across the package):
#: a key that differs from one of them only by case, or is a close misspelling, is refused
#: rather than ignored (docs/bench-csv.md, "Three misreads refused")
KNOWN_METADATA = ("local_g_m_s2", "local_g_override", "output_unit", "Q_V2s", "power_on_s", "quantisation_lsb",
                  "u_w_method", "dTdt_method", "ramp", "date", "bench", "t_override", "planned_effects")
#: metadata keys triadcal's own writers put in a file (simulate, capture and its noise estimate,
#: fit-raw, the lab file):
#: accepted as they are, however close to a known key they look (``input_unit``, ``temperature``)
WRITTEN_METADATA = ("generator", "seed", "ramp_setpoint", "ramp_labels", "raw_samples", "stabilisation",
                    "settle_s", "plan", "operator", "imu_protocol", "imu_temperature", "noise_method", "readout",
                    "samples_per_window", "unit_temperature", "source", "rate_hz", "input_unit", "temperature",
                    "emulator", "local_g_source", "raw_samples_sha256",
                    *(f"Q_{a}_V2s" for a in "xyz"), *(f"bias_instability_{a}_V" for a in "xyz"))   # hardware/noise.py
#: difflib ratio at or above which a key is a misspelling of a known key
METADATA_CUTOFF = 0.8


def near_metadata_key(key: str) -> Optional[str]:
    """The known metadata key (:data:`KNOWN_METADATA`) that ``key`` is most likely a mistyped
    form of, or None: the same key in another case or with spaces or hyphens for underscores;
    a known key with up to 2 characters more (``output_units``); the start of a known key of
    at least 5 characters and 55 % of its length (``local_g`` for ``local_g_m_s2``); or a
    difflib ratio of at least :data:`METADATA_CUTOFF`. Exact known or written keys are None."""
    import difflib

    if key in KNOWN_METADATA or key in WRITTEN_METADATA:
        return None
    norm = re.sub(r"[\s\-]+", "_", key.lstrip("#").strip()).lower()
    lower = {k.lower(): k for k in KNOWN_METADATA}
    if not norm:
        return None
    if norm in lower:
        return lower[norm]
    if "gravity" in norm or norm.startswith("local_g"):
        return "local_g_m_s2"       # '# Local gravity = 9.8123' was ignored: standard gravity taken
    for low, k in lower.items():
        if norm.startswith(low) and len(norm) - len(low) <= 2:
            return k
        if low.startswith(norm) and len(norm) >= 5 and len(norm) >= 0.55 * len(low):
            return k
    close = difflib.get_close_matches(norm, list(lower), n=1, cutoff=METADATA_CUTOFF)
    return lower[close[0]] if close else None


#: the keys whose ':' form is refused (:func:`check_comment_key`): those the fit reads as numbers,
#: flags or the output unit -- a value ignored there changes the answer
COLON_CHECKED = ("local_g_m_s2", "local_g_override", "output_unit", "Q_V2s", "power_on_s", "quantisation_lsb",
                 "t_override")


def _value_of_kind(key: str, value: str) -> bool:
    """Whether ``value`` is what ``key`` holds: a flag, a unit, or a number."""
    v = value.split()[0] if value.split() else ""
    if key.endswith("override"):
        return v.lower() in ("true", "false")
    if key == "output_unit":
        return v in ("V", "mV", "uV", "counts", "A", "mA", "uA", "g", "mg", "ug", "m/s2", "m/s^2")
    try:
        float(v)
    except ValueError:
        return False
    return True


def check_comment_key(path, lineno, body):
    """Refuse a ``#`` line that was meant as metadata of a known key but will not be read as
    it: ``key: value`` instead of ``key = value``, or a key mistyped (case, spelling)."""
    if "=" in body:
        key = body.split("=", 1)[0].strip()
        if ":" in key:                                  # '# local_g_m_s2: 9.78 = measured'
            left = key.split(":", 1)[0].strip()
            known = left if left in KNOWN_METADATA else near_metadata_key(left)
            if known is not None:
                raise BenchCSVError(path, lineno, None,
                                    f"metadata line '# {body}' has ':' after the key '{left}', so its key would be "
                                    f"{key!r} and '{known}' ignored: a metadata line is '# {known} = value'")
        near = near_metadata_key(key)
        if near is not None:
            raise BenchCSVError(path, lineno, None,
                                f"metadata key {key!r} is not one triadcal reads: did you mean {near!r}? (a key "
                                f"close to a known one is refused rather than ignored; write '# {near} = "
                                f"{body.split('=', 1)[1].strip()}')")
        return
    if ":" in body:
        # prose is written 'Key: text' too ('# Power on: 08:00 local time', '# Date: see log book'):
        # a ':' line is refused only when its key is exactly one the model reads (any case, spaces for
        # underscores) and its value is of that key's kind -- a number, true/false, or an output unit
        left, value = (s.strip() for s in body.split(":", 1))
        norm = re.sub(r"[\s\-]+", "_", left).lower()
        known = next((k for k in COLON_CHECKED if k.lower() == norm), None)
        if known is not None and value and _value_of_kind(known, value):
            raise BenchCSVError(path, lineno, None,
                                f"metadata line '# {body}' uses ':' where the format has '=': it would be a "
                                f"comment and '{known}' ignored; write '# {known} = {value}'")


#: degF check (docs/bench-csv.md, "Three misreads refused"), each t_* column on its own.
#: Setpoints spanning at least FAHRENHEIT_SPAN_C: the least-squares slope of t on setpoint_C in
#: FAHRENHEIT_SLOPE (degF: 1.8; degC: about 1, less with a thermal lag), the median |t - setpoint|
#: at least FAHRENHEIT_MIN_OFFSET_C, and the median |(t - 32)/1.8 - setpoint| at most
#: FAHRENHEIT_MAX_RESIDUAL_C or a quarter of the median |t - setpoint|, whichever is more.
FAHRENHEIT_SPAN_C = 10.0
FAHRENHEIT_SLOPE = (1.4, 2.2)
FAHRENHEIT_MIN_OFFSET_C = 5.0
FAHRENHEIT_MAX_RESIDUAL_C = 5.0
#: one setpoint (a span below FAHRENHEIT_SPAN_C): only the offset tells, so it must be larger
FAHRENHEIT_MIN_OFFSET_ONE_SETPOINT_C = 20.0
#: a ramp (setpoint_C the target of a leg, so t is far from it): at least FAHRENHEIT_HOT_SHARE of the
#: visits read FAHRENHEIT_HOT_C above the highest setpoint, t spans at least FAHRENHEIT_HOT_C and
#: 1.2 times the setpoints, and (t - 32)/1.8 lies within FAHRENHEIT_HOT_C / 2 of the setpoints' range
FAHRENHEIT_HOT_C = 20.0
FAHRENHEIT_HOT_SHARE = 0.2


def _fahrenheit(t, S):
    """Why the readings ``t`` of one column look like degF against the setpoints ``S``, or None."""
    d, u = t - S, (t - 32.0) / 1.8
    md, mf = float(np.median(np.abs(d))), float(np.median(np.abs(u - S)))
    span = float(np.ptp(S))
    close = mf <= max(FAHRENHEIT_MAX_RESIDUAL_C, 0.25 * md)
    why = (f"median |t - setpoint_C| over the {len(t)} visits {md:.3g} degC, while (t - 32)/1.8 is within "
           f"{mf:.2g} degC of the setpoint (median)")
    if span >= FAHRENHEIT_SPAN_C:
        b, a = np.polyfit(S, t, 1)
        if FAHRENHEIT_SLOPE[0] <= b <= FAHRENHEIT_SLOPE[1] and md >= FAHRENHEIT_MIN_OFFSET_C and close:
            return np.abs(d) >= 0.5 * md, why + f"; t = {a:.3g} + {b:.3g} setpoint_C (degF: 32 + 1.8 setpoint_C)"
    elif md >= FAHRENHEIT_MIN_OFFSET_ONE_SETPOINT_C and close:
        return np.abs(d) >= 0.5 * md, why
    lo, hi = float(np.min(S)), float(np.max(S))
    hot = t > hi + FAHRENHEIT_HOT_C
    inside = (u >= lo - FAHRENHEIT_HOT_C / 2) & (u <= hi + FAHRENHEIT_HOT_C / 2)
    if (hot.mean() >= FAHRENHEIT_HOT_SHARE and inside.all()
            and np.ptp(t) >= max(FAHRENHEIT_HOT_C, 1.2 * span)):
        return hot, (f"{100 * hot.mean():.0f} % of the visits read more than {FAHRENHEIT_HOT_C:g} degC above the "
                     f"highest setpoint, {hi:g} degC, while (t - 32)/1.8 lies within the setpoints' "
                     f"{lo:g} to {hi:g} degC")
    return None


def check_temperature_unit(path, c: Campaign) -> None:
    """Refuse t_* columns that read as degF against the setpoints (:func:`_fahrenheit`,
    docs/bench-csv.md, "Three misreads refused"); ``# t_override = true`` skips the check. A ramp's
    file (``capture --ramp``) is held against its ``program_C`` column, the program's value at each
    visit: its ``setpoint_C`` is the leg's target, 30 degC from a unit that has just left the other end
    (a ramp killed in its first leg could not be resumed: "the temperatures look like degF")."""
    S = np.asarray(c.setpoint_C, float)
    program = (c.extra or {}).get("program_C")
    if program is not None:
        try:
            P = np.asarray([float(x) for x in program], float)
        except (TypeError, ValueError):
            P = None
        if P is not None and P.shape == S.shape and np.all(np.isfinite(P)):
            S = P
    for j, col in enumerate(("t_x", "t_y", "t_z")):
        t = np.asarray(c.t[:, j], float)
        found = _fahrenheit(t, S)
        if found is None:
            continue
        shows, why = found
        i = int(np.flatnonzero(shows)[0])           # the first visit, in file order, that shows it
        raise BenchCSVError(
            path, int(c.lines[i]) if c.lines is not None else i + 1, col,
            f"{col} = {t[i]:g} at setpoint_C {S[i]:g}: the temperatures look like degF, not degC ({why}); the "
            "t_* columns are degC: convert with (t - 32)/1.8. If they are degC readings (an oven-controlled "
            "unit far from the chamber's setpoint), add the line '# t_override = true'")


#: distinct setpoints from which their pattern can tell degF: every (s - 32)/1.8 a multiple of 5 degC
#: while the setpoints as read are not all multiples of 5
FAHRENHEIT_PATTERN_MIN_SETPOINTS = 4


def check_fahrenheit_setpoints(path, c: Campaign) -> None:
    """Refuse a file whose setpoints read as degF, t_* with them (the t_* check above compares the two
    columns, so a file converted whole passes it): at least :data:`FAHRENHEIT_PATTERN_MIN_SETPOINTS`
    distinct setpoints that are the degF of multiples of 5 degC (68, 95, 131, 158, 41, 14, -13, -40)
    and not multiples of 5 themselves. An outside probe's campaign with every temperature in degF
    was fitted, status ok: K_x 400 ppm (300 u) and Ca_xy 80 u off, the range "-39.5..158.6 degC".
    ``# t_override = true`` skips it. A file in degF whose setpoints are not round in degC cannot be
    told from degC by its numbers (a setpoint of 150 or 175 degC is a downhole tool's range, read as
    it is)."""
    S = np.asarray(c.setpoint_C, float)
    hint = ("if the whole file is in degF, convert setpoint_C and t_* with (x - 32)/1.8; if they are degC, "
            "add the line '# t_override = true'")
    distinct = np.unique(np.round(S, 6))
    if len(distinct) < FAHRENHEIT_PATTERN_MIN_SETPOINTS:
        return
    as_c = (distinct - 32.0) / 1.8

    def round5(x):
        return bool(np.all(np.abs(x / 5.0 - np.round(x / 5.0)) * 5.0 <= 0.05))

    if round5(as_c) and not round5(distinct):
        i = int(np.flatnonzero(np.abs(S / 5.0 - np.round(S / 5.0)) * 5.0 > 0.05)[0])
        raise BenchCSVError(
            path, int(c.lines[i]) if c.lines is not None else i + 1, "setpoint_C",
            f"setpoint_C = {S[i]:g}: the setpoints {', '.join(f'{x:g}' for x in distinct)} are the degF of "
            f"{', '.join(f'{x:g}' for x in np.round(as_c, 2))} degC (multiples of 5), and not multiples of 5 "
            f"themselves: {hint}")


#: a t_* column of one unit that spans at most this (degC) over its visits ...
STUCK_SPAN_C = 0.01
#: ... while another of its t_* columns spans at least this (degC) is a stuck thermometer
STUCK_OTHER_SPAN_C = 1.0


def check_stuck_thermometer(path, c: Campaign) -> None:
    """Refuse a ``t_*`` column that reads one value (within :data:`STUCK_SPAN_C`) on every visit of
    a unit while another of its sensors spans :data:`STUCK_OTHER_SPAN_C` or more: a stuck or
    disconnected thermometer (docs/bench-csv.md, "A stuck thermometer"). Read, its accelerometer's
    tempcos had no temperature to follow: the classical fit stopped on a singular matrix, and the
    joint fit held K_z, S_z and its angles at their nominal values and blamed a missing effect (an
    outside probe: t_z = 20.35 on every visit of a -20...60 degC campaign). ``# t_override = true``
    skips it, as the degF check."""
    units = np.asarray(c.unit).astype(str)
    for u in dict.fromkeys(units.tolist()):
        idx = np.flatnonzero(units == u)
        t = np.asarray(c.t[idx], float)
        span = np.ptp(t, axis=0)
        j_other = int(np.argmax(span))
        if span[j_other] < STUCK_OTHER_SPAN_C:
            continue
        for j, col in enumerate(("t_x", "t_y", "t_z")):
            if span[j] <= STUCK_SPAN_C:
                other = ("t_x", "t_y", "t_z")[j_other]
                S = np.asarray(c.setpoint_C, float)[idx]
                raise BenchCSVError(
                    path, int(c.lines[idx[0]]) if c.lines is not None else int(idx[0]) + 1, col,
                    f"{col} reads {t[0, j]:g} degC on every visit of unit {u!r} (spread {span[j]:.3g} degC) while "
                    f"{other} spans {t[:, j_other].min():g} to {t[:, j_other].max():g} degC and the setpoints "
                    f"{S.min():g} to {S.max():g} degC: a stuck or disconnected thermometer, which the tempcos of "
                    f"its accelerometer's row cannot follow; repair or replace the column (if the sensor truly "
                    "held one temperature, add the line '# t_override = true')")


#: the three outputs' spans over a campaign (each axis up and down: 2 g over its K) may differ by at
#: most this factor: a triad's channels are alike, and mixed-range triads stay within it
AXIS_SPAN_RATIO_MAX = 100.0


def check_axis_spans(path, c: Campaign) -> None:
    """Refuse a campaign whose outputs' spans (max - min of the visit means, each unit and state)
    differ by more than :data:`AXIS_SPAN_RATIO_MAX`: one column in another unit than the file states
    (an outside probe's w_x in mV in a file in V: the classical fit gave K_x = 0.001 g/V with status ok
    and a certificate). Units of fewer than 6 visits and outputs that do not move (span 0: a dead or
    stuck output, named by its own check) are left out, and so are outputs the plan does not turn
    through gravity (their nominal gravity spans less than :data:`AXIS_GRAVITY_SPAN_MIN_G`: a plan of
    P01-P08, z never up or down, was refused as "w_z in another unit", an outside probe)."""
    from ..models.campaign import axes_not_turned

    units = np.asarray(c.unit).astype(str)
    w = np.asarray(c.w, float)
    a1, a2 = np.asarray(c.axis1_deg, float), np.asarray(c.axis2_deg, float)
    lines = c.lines if c.lines is not None else np.arange(1, len(w) + 1)
    for u in dict.fromkeys(units.tolist()):
        idx = np.flatnonzero(units == u)
        if len(idx) < 6:
            continue
        turned = np.ones(3, bool)
        turned[[i for i, _, _ in axes_not_turned(a1[idx], a2[idx])]] = False
        span = np.nanmax(w[idx], axis=0) - np.nanmin(w[idx], axis=0)
        if turned.sum() < 2 or not np.all(np.isfinite(span[turned])) or np.min(span[turned]) <= 0:
            continue
        ratio = float(span[turned].max() / span[turned].min())
        if ratio > AXIS_SPAN_RATIO_MAX:
            keep = np.flatnonzero(turned)
            med = np.median(span[keep])
            odd = int(keep[np.argmax(np.abs(np.log(span[keep] / med)))])     # the one apart from the others
            names = ("w_x", "w_y", "w_z")
            others = " and ".join(f"{names[i]} {span[i]:.4g}" for i in keep if i != odd)
            raise BenchCSVError(
                path, int(lines[idx[0]]), names[odd],
                f"{names[odd]} spans {span[odd]:.4g} {c.output_unit} over the visits of unit {u!r}, {others} (a "
                f"factor {ratio:.3g} between the outputs, beyond {AXIS_SPAN_RATIO_MAX:g}): a triad's channels are "
                f"alike, so one column is in another unit than output_unit = {c.output_unit} (mV in a file of V?); "
                "convert it")


#: two noisy means equal to the last written digit are a copy only when that digit is finer than this
#: fraction of their standard error on every output (the chance of equal independent means is then
#: below (0.1 / 2 sqrt(pi))^3 = 2e-5 per pair of one pose at one truth)
REPEAT_RESOLUTION_FRACTION = 0.1


def written_resolution(x) -> float:
    """The step to which the values ``x`` were written: the largest ``10^-d`` (d from -3) of which
    every finite value is an integer multiple, or 0 when they hold more than 9 significant digits
    (finer than any noise tells). 0.1235, -0.7062 give 1e-4; a value printed in full gives 0."""
    v = np.asarray(x, float)
    v = v[np.isfinite(v)]
    top = float(np.max(np.abs(v))) if v.size else 0.0
    if top == 0.0:
        return 0.0
    for d in range(-3, 16):
        if 10.0 ** d * top > 1e9:
            break
        s = v * 10.0 ** d
        if np.all(np.abs(s - np.round(s)) < 1e-6):
            return 10.0 ** -d
    return 0.0


def check_repeated_readings(path, c: Campaign) -> None:
    """Refuse two visits of a unit (and state) whose three mean outputs are equal to the last digit
    when their averaging windows overlap (``|dt| < (tau_i + tau_j)/2``) or either has noise
    (``sd_*`` or ``u_w_*`` above 0): two averages of noisy readings are never equal, so it is one
    visit written twice, which would be counted as two independent ones (every u 1/sqrt 2 too small).
    An outside probe wrote every visit twice, the copy 1 s later: status ok, every u 0.707 of the
    single file's, the note calling them conservative. Equal readings without noise (a quantised,
    quiet output visiting one position twice) are kept, and so are noisy averages written to a
    resolution (:func:`written_resolution`) not finer than a tenth of their standard error on every
    output: rounded, two visits of one pose may read equal (another probe's means rounded to 1e-4 V
    with a standard error of 1e-5 V were refused as copies, lines of one pose at setpoints 30 degC
    apart)."""
    units = np.asarray(c.unit).astype(str)
    states = np.asarray(c.state).astype(str)
    w = np.asarray(c.w, float)
    noisy = np.zeros(len(w), bool)
    for extra in (c.sd, c.u_w):
        if extra is not None:
            noisy |= np.any(np.nan_to_num(np.asarray(extra, float)) > 0, axis=1)
    lines = c.lines if c.lines is not None else np.arange(1, len(w) + 1)
    # a unit with an output that reads one value throughout is a stuck output, named by its own check
    stuck = {u for u in set(units.tolist())
             if any(len(np.unique(w[units == u][:, a])) <= 1 for a in range(3))}
    # the standard error of each visit's mean, where the file states one (sd / sqrt(n), or u_w)
    se = np.full(w.shape, np.nan)
    if c.sd is not None and c.n_samples is not None:
        se = np.asarray(c.sd, float) / np.sqrt(np.maximum(np.asarray(c.n_samples, float), 1.0))[:, None]
    if c.u_w is not None:
        se = np.where(np.isfinite(se), se, np.asarray(c.u_w, float))
    q = np.array([written_resolution(w[:, a]) for a in range(3)])
    try:
        Q = float(c.metadata.get("Q_V2s", "nan"))
    except (TypeError, ValueError):
        Q = float("nan")
    if Q > 0:
        # a stated white noise makes every visit a noisy average too, sqrt(Q / tau) its SE (an outside
        # probe: every visit written twice, noise as # Q_V2s without sd_*: status ok in 6 of 12, u 0.71x)
        noisy[:] = True
        se = np.where(np.isfinite(se), se, np.sqrt(Q / np.asarray(c.tau_s, float))[:, None])
    elif not np.any(noisy) and np.all(q == 0.0):
        # no noise stated, but every output written to 10 significant digits or more: readings that
        # equal to the last of them are one average written twice (a quantised quiet output's equal
        # means are written to its code's step, which q holds)
        noisy[:] = True

    def equal_unlikely(k: int) -> bool:
        """Visit k's three means were written finer than a tenth of their standard error (or it is unknown)."""
        return bool(np.all(~(se[k] > 0) | (q < REPEAT_RESOLUTION_FRACTION * se[k])))

    first: dict = {}
    for i in range(len(w)):
        if not np.all(np.isfinite(w[i])) or units[i] in stuck:
            continue
        j = first.setdefault((units[i], states[i], *w[i].tolist()), i)
        if j == i:
            continue
        dt, span = abs(float(c.time_s[i]) - float(c.time_s[j])), 0.5 * (float(c.tau_s[i]) + float(c.tau_s[j]))
        if dt >= span and not (equal_unlikely(i) and equal_unlikely(j)):
            continue                     # rounded to their noise: equal by chance, two visits
        if dt < span or noisy[i] or noisy[j]:
            why = (f"their averaging windows overlap (time_s {float(c.time_s[j]):g} and {float(c.time_s[i]):g} s, "
                   f"tau_s {float(c.tau_s[j]):g} and {float(c.tau_s[i]):g} s)" if dt < span else
                   "both average noisy readings (sd or u_w above 0, or the file's Q_V2s; or, with no noise "
                   "stated, written to 10 significant digits), and two such averages are never equal")
            raise BenchCSVError(
                path, int(lines[i]), "w_x",
                f"the same visit twice: w_x, w_y, w_z repeat line {int(lines[j])}'s to the last digit "
                f"({', '.join(f'{v:.10g}' for v in w[i])}) and {why}; counted as two visits, every "
                "uncertainty would be 1/sqrt(2) too small. Remove the copy")


#: consecutive visits (of one unit, state and cycle, in time order) whose setpoints differ by at most
#: this (degC) are one block of the direction check
SETPOINT_SAME_C = 0.01
#: a block whose setpoint differs from the previous block's by less than this (degC) is not checked
SETPOINT_STEP_C = 1.0
#: a visit labelled with the previous block's direction against a setpoint change is the unit not yet
#: turned (a ramp as the unit sees it) only while its temperature has moved toward the new setpoint
#: by at most this fraction of the step since the previous block's last visit
CARRY_OVER_FRACTION = 0.25
#: in a ramp file, a direction opposed to the visit's temperature rate by more than this (degC/min) is refused
DIRECTION_RATE_C_PER_MIN = 0.2
#: ... or when more than half the labelled visits whose rate is at least this (degC/min) are against it
DIRECTION_RATE_NOISE_C_PER_MIN = 0.02
OPPOSITE = {"heating": "cooling", "cooling": "heating"}


#: the direction check refuses a stepped file when at least this many of its setpoint changes, and
#: more than half of those checked, contradict their heating/cooling labels
DIRECTION_MIN_AGAINST = 2


def check_directions(path, c: Campaign) -> None:
    """Refuse a ``direction`` that contradicts the file's own thermal history (docs/bench-csv.md,
    "Three misreads refused"), for each unit, state and cycle in time order.

    A ramp file (metadata ``ramp`` or the column ``dTdt_C_per_min``: ``simulate --ramp``,
    ``capture --ramp``) labels each visit with the sign of the unit's rate (docs/hardware.md):
    ``heating`` is refused where the reading falls faster than :data:`DIRECTION_RATE_C_PER_MIN`,
    ``cooling`` where it rises that fast. Any other file: after the first block of visits at one
    setpoint, ``heating`` needs a setpoint above the previous block's and ``cooling`` one below
    (``none`` is always accepted; a change below :data:`SETPOINT_STEP_C` is not checked), except at the start of a block, before any visit with the
    expected label, for visits that keep the previous block's last label while the unit's
    temperature has not moved toward the new setpoint by more than :data:`CARRY_OVER_FRACTION`
    of the step (a ramp labelled as the unit sees it, which turns after the program)."""
    n = c.n_visits
    if n < 2:
        return
    lines = c.lines if c.lines is not None else np.arange(1, n + 1)
    groups: dict = {}
    for i, key in enumerate(zip(c.unit.tolist(), c.state.tolist(), np.asarray(c.cycle).tolist())):
        groups.setdefault(key, []).append(i)
    ramp = "ramp" in c.metadata or c.dTdt_C_per_min is not None
    T = np.mean(np.asarray(c.t, float), axis=1)
    for idx in groups.values():
        idx = np.array(idx)[np.argsort(c.time_s[idx], kind="stable")]
        if len(idx) < 2:
            continue
        if ramp:
            rate = _group_rate(c, idx)
            sign = np.array([{"heating": 1.0, "cooling": -1.0}.get(d, 0.0) for d in c.direction[idx]])
            bad = np.flatnonzero(sign * rate < -DIRECTION_RATE_C_PER_MIN)
            moving = (sign != 0) & (np.abs(rate) >= DIRECTION_RATE_NOISE_C_PER_MIN)
            against = moving & (sign * rate < 0)
            most = ""
            if not len(bad) and moving.sum() >= 10 and against.sum() > 0.5 * moving.sum():
                bad = np.flatnonzero(against)       # a slow ramp: most labels against their rates
                most = (f"; {int(against.sum())} of the {int(moving.sum())} labelled visits moving faster than "
                        f"{DIRECTION_RATE_NOISE_C_PER_MIN:g} degC/min are against their rate")
            if len(bad):
                i, r = int(idx[bad[0]]), float(rate[bad[0]])
                src = ("dTdt_C_per_min" if c.dTdt_C_per_min is not None
                       else "central differences of the mean t_* within its block")
                raise BenchCSVError(
                    path, int(lines[i]), "direction",
                    f"direction '{c.direction[i]}', but the unit's temperature {'falls' if r < 0 else 'rises'} at "
                    f"{abs(r):.3g} degC/min during this visit ({src}{most}): in a ramp file the direction is the "
                    "sign of the unit's rate (heating on a rise, cooling on a fall); are heating and cooling swapped?")
            continue
        sp = np.asarray(c.setpoint_C, float)[idx]
        starts = [0] + [k for k in range(1, len(idx)) if abs(sp[k] - sp[k - 1]) > SETPOINT_SAME_C] + [len(idx)]
        checked, against = 0, []
        for b in range(1, len(starts) - 1):
            S, P, last = sp[starts[b]], sp[starts[b] - 1], int(idx[starts[b] - 1])
            if abs(S - P) < SETPOINT_STEP_C:
                continue                # too small a change to say (a setpoint written as measured)
            want, turned = ("heating" if S > P else "cooling"), False
            labels = {str(c.direction[i]) for i in idx[starts[b]:starts[b + 1]]}
            checked += bool(labels & {"heating", "cooling"})
            for i in idx[starts[b]:starts[b + 1]]:
                d = str(c.direction[i])
                turned = turned or d == want
                if d != OPPOSITE[want]:
                    continue
                moved = (T[i] - T[last]) * np.sign(S - P)
                if not turned and d == str(c.direction[last]) and moved <= CARRY_OVER_FRACTION * abs(S - P):
                    continue            # the unit has not turned yet: the previous block's direction goes on
                against.append((i, P, S, want, d, last))
                break
        # swapped labels contradict (nearly) every block; a unit taken beyond the next setpoint and back
        # without logging it (a preconditioning excursion) contradicts one or a few, rightly: refuse only
        # when at least MIN_AGAINST blocks and more than half of those checked contradict the sequence
        if len(against) >= DIRECTION_MIN_AGAINST and len(against) > 0.5 * checked:
            i, P, S, want, d, last = against[0]
            raise BenchCSVError(
                path, int(lines[i]), "direction",
                f"the setpoint went from {P:g} degC (line {int(lines[last])}) to {S:g} degC: that is {want}, "
                f"not {d} (direction says how the chamber arrived at this setpoint from the previous one), and "
                f"{len(against)} of the {checked} setpoint changes checked contradict their labels so; are heating "
                "and cooling swapped? (a unit taken past a setpoint without a logged visit contradicts only its "
                "own block; give such excursions visits, or their own cycle numbers)")


def _group_rate(c: Campaign, idx) -> np.ndarray:
    """Rate of the unit's temperature reading (degC/min) at the visits ``idx`` (one unit, state
    and cycle, in time order): ``dTdt_C_per_min`` when the file has it, else central differences
    of the mean of t_x, t_y, t_z within each run of visits of one setpoint and direction (one-sided
    at its ends, 0 for a run of one visit), so a soak between two setpoints is not a rate."""
    if c.dTdt_C_per_min is not None:
        return np.asarray(c.dTdt_C_per_min, float)[idx]
    T = np.mean(np.asarray(c.t, float)[idx], axis=1)
    time = np.asarray(c.time_s, float)[idx]
    key = list(zip(c.setpoint_C[idx].tolist(), c.direction[idx].tolist()))
    out = np.zeros(len(idx))
    start = 0
    for k in range(1, len(idx) + 1):
        if k == len(idx) or key[k] != key[start]:
            if k - start >= 2 and np.all(np.diff(time[start:k]) > 0):
                out[start:k] = np.gradient(T[start:k], time[start:k]) * 60.0
            start = k
    return out
