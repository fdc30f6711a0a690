"""Campaign data: the position-averaged visits of a multi-position thermal test.

The data object every estimator takes, whether it came from bench CSV v1
(docs/spec/bench-csv-v1.md), the simulator or the capture layer.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np

from ..errors import InputError

from .effects.hysteresis import BRANCH
from .kinematics import gravity_in_imu
from .model import Covariates
from .units import DEG, STANDARD_GRAVITY_M_S2

#: The default 12-position plan of bench-csv.md: label -> (axis1_deg, axis2_deg).
DEFAULT_PLAN: dict[str, tuple[float, float]] = {
    "P01": (0.0, 0.0), "P02": (180.0, 0.0), "P03": (0.0, 180.0), "P04": (180.0, 180.0),
    "P05": (90.0, 90.0), "P06": (270.0, 270.0), "P07": (270.0, 90.0), "P08": (90.0, 270.0),
    "P09": (180.0, 90.0), "P10": (0.0, 270.0), "P11": (0.0, 90.0), "P12": (180.0, 270.0),
}

DIRECTIONS = tuple(BRANCH)


def nominal_gravity(axis1_deg, axis2_deg):
    """Unit gravity vector in the IMU frame of a level, perfect bench: shape (n, 3)."""
    return base_direction_in_imu(axis1_deg, axis2_deg, (0.0, 0.0, 1.0))


def base_direction_in_imu(axis1_deg, axis2_deg, v_base):
    """A fixed direction ``v_base`` of the bench's base frame (z up) in the IMU frame of a level,
    perfect bench, ``R_base_from_imu^T v`` (kinematics.gravity_in_imu): shape (n, 3). Gravity is
    ``(0, 0, 1)``; the horizontal ``(1, 0, 0)`` and ``(0, 1, 0)`` carry what gravity does not, the
    rotation about the vertical (a field fixed in the room, a bearing's run-out)."""
    g = gravity_in_imu(np.radians(np.asarray(axis1_deg, float)), np.radians(np.asarray(axis2_deg, float)),
                       tuple(float(x) for x in v_base))
    return np.stack(np.broadcast_arrays(*g), axis=-1)


#: an IMU axis whose nominal gravity spans less than this (g) over a campaign's poses is not turned through
#: gravity: its scale factor is not told from its bias (the fit refuses, the reader's span check leaves it out)
AXIS_GRAVITY_SPAN_MIN_G = 0.5


def axes_not_turned(axis1_deg, axis2_deg) -> list:
    """``[(axis index, lowest, highest nominal gravity component (g))]`` of each IMU axis the poses do not
    turn through gravity: its nominal component spans less than :data:`AXIS_GRAVITY_SPAN_MIN_G`."""
    g = nominal_gravity(axis1_deg, axis2_deg).reshape(-1, 3)
    if len(g) == 0:
        return []
    lo, hi = g.min(axis=0), g.max(axis=0)
    return [(i, float(lo[i]), float(hi[i])) for i in range(3) if hi[i] - lo[i] < AXIS_GRAVITY_SPAN_MIN_G]


def up_axis_label(axis1_deg, axis2_deg, threshold: float = 0.99):
    """Label of the IMU axis that points up or down ('+X', '-Z', ...; '' when none does)."""
    g = nominal_gravity(axis1_deg, axis2_deg).reshape(-1, 3)
    out = []
    for row in g:
        i = int(np.argmax(np.abs(row)))
        out.append(("+" if row[i] > 0 else "-") + "XYZ"[i] if abs(row[i]) >= threshold else "")
    return np.array(out)



#: every sensor's median distance from the chamber's setpoints beyond which a result notes it (degC; a
#: self-heated unit reads 1-5 degC above, a ramp's lag a few degC behind its program)
THERMOMETER_OFFSET_NOTE_C = 10.0
#: the three sensors' median spread within a visit beyond which a result notes it (degC)
THERMOMETER_SPREAD_NOTE_C = 5.0

@dataclass
class Campaign:
    """Visits of a bench campaign (one row of bench CSV v1 each).

    Units are in the names: ``setpoint_C``, ``time_s``, ``axis1_deg``, ``tau_s``; ``w`` holds
    the mean outputs of the X, Y, Z accelerometers (volts or the instrument's unit,
    ``output_unit``), ``t`` their temperature sensors in degC.
    """

    unit: np.ndarray
    setpoint_C: np.ndarray
    direction: np.ndarray
    time_s: np.ndarray
    position: np.ndarray
    axis1_deg: np.ndarray
    axis2_deg: np.ndarray
    tau_s: np.ndarray
    w: np.ndarray
    t: np.ndarray
    cycle: np.ndarray
    state: np.ndarray
    sd: Optional[np.ndarray] = None
    n_samples: Optional[np.ndarray] = None
    metadata: dict = field(default_factory=dict)
    source: Optional[str] = None
    lines: Optional[np.ndarray] = None
    #: columns the format does not define, kept as text so nothing is dropped
    extra: dict = field(default_factory=dict)
    #: the hysteresis branch of each visit when not the direction's +-1/0: a play hysteresis's
    #: continuous branch (:func:`triadcal.models.effects.hysteresis.play_branch`); not written to files
    branch_values: Optional[np.ndarray] = None
    #: standard uncertainty of each mean output (n, 3), output unit, from the data's own noise
    #: (bench CSV ``u_w_x u_w_y u_w_z``; how it was made: metadata ``u_w_method``)
    u_w: Optional[np.ndarray] = None
    #: measured rate of the unit's temperature over each visit (n,), degC/min (bench CSV
    #: ``dTdt_C_per_min``; how it was measured: metadata ``dTdt_method``); when present,
    #: :meth:`temperature_rate` takes it instead of central differences of the visit means
    dTdt_C_per_min: Optional[np.ndarray] = None
    #: the origin of the clock of the terms that change in time (s on the ``time_s`` clock), carried
    #: by :meth:`select` so that a part of a campaign keeps its whole's origin; None: :attr:`time_origin_s`
    origin_s: Optional[float] = None

    def __post_init__(self):
        n = len(self.time_s)
        for name in ("unit", "setpoint_C", "direction", "position", "axis1_deg", "axis2_deg",
                     "tau_s", "cycle", "state"):
            if len(getattr(self, name)) != n:
                raise InputError(f"campaign field {name} has {len(getattr(self, name))} entries, expected {n}")
        if self.w.shape != (n, 3) or self.t.shape != (n, 3):
            raise InputError("campaign fields w and t must have shape (n_visits, 3)")
        if self.u_w is not None and np.shape(self.u_w) != (n, 3):
            raise InputError("campaign field u_w must have shape (n_visits, 3)")
        if self.dTdt_C_per_min is not None and np.shape(self.dTdt_C_per_min) != (n,):
            raise InputError("campaign field dTdt_C_per_min must have shape (n_visits,)")

    # -- basic facts ---------------------------------------------------------------
    @property
    def n_visits(self) -> int:
        return len(self.time_s)

    @property
    def output_unit(self) -> str:
        return str(self.metadata.get("output_unit", "V"))

    @property
    def local_g_m_s2(self) -> float:
        """The local gravity the data state (metadata ``local_g_m_s2``), m/s^2; standard gravity
        when they state none (:attr:`local_g_stated` is then False)."""
        return float(self.metadata.get("local_g_m_s2", STANDARD_GRAVITY_M_S2))

    @property
    def local_g_stated(self) -> bool:
        """Whether the data state their local gravity. K and S are in g of that gravity: assumed
        standard (9.80665) where the site's is 9.78-9.83, a K is off by up to 0.3 % (260 u on the
        example's design for 9.81) although the fit cannot tell; a certificate needs it stated."""
        return "local_g_m_s2" in self.metadata

    def gravity_note(self) -> Optional[str]:
        """The note of a result whose data state no local gravity (None when they state it)."""
        if self.local_g_stated:
            return None
        return ("the data state no local gravity (# local_g_m_s2): standard gravity 9.80665 m/s^2 assumed, so K and S "
                "are in g of it; a site's is 9.78-9.83 m/s^2 (up to 0.3 % in K, beyond these u): state it for a "
                "certificate")

    def thermometer_note(self) -> Optional[str]:
        """A note when the thermometers read far from the chamber (every sensor's median of ``t - setpoint``
        beyond :data:`THERMOMETER_OFFSET_NOTE_C`; not on a ramp, whose unit trails its program by its lag) or from each
        other (their median spread within a visit beyond :data:`THERMOMETER_SPREAD_NOTE_C`), else None.
        The fit takes the readings as the temperature: an oven-controlled unit reads so, but thermometers
        off by ``d`` put every value "at T_ref" at the true ``T_ref - d``, moved by its tempco times ``d``
        with status ok (a probe's file with readings 40 degC above the setpoints: no word)."""
        S = np.asarray(self.setpoint_C, float)
        t = np.asarray(self.t, float)
        if t.size == 0 or not np.all(np.isfinite(t)):
            return None
        off = np.median(t - S[:, None], axis=0)
        spread = float(np.median(np.ptp(t, axis=1)))
        parts = []
        ramp = (self.extra or {}).get("program_C") is not None
        if not ramp and np.all(np.abs(off) > THERMOMETER_OFFSET_NOTE_C):
            parts.append("the accelerometers' temperatures read " + ", ".join(f"{o:+.3g}" for o in off)
                         + " degC (x, y, z) from the chamber's setpoints (median over the visits)")
        if spread > THERMOMETER_SPREAD_NOTE_C:
            parts.append(f"the three sensors differ by {spread:.3g} degC within a visit (median)")
        if not parts:
            return None
        return ("; ".join(parts) + ": an oven-controlled or self-heated unit reads so, thermometers off by d do too; "
                "the fit takes the readings as the temperature, so with thermometers off by d every value at the "
                "reference temperature is the unit's at the true T_ref - d, moved by its tempco times d (a K "
                "tempco of 20 ppm/degC and d = 10 degC: 200 ppm); check the thermometers, or state their "
                "uncertainty as Type B ([thermometers] u_C of --lab)")

    @property
    def gravity_g(self) -> float:
        """Magnitude of the local apparent gravity in g (standard gravity)."""
        return self.local_g_m_s2 / STANDARD_GRAVITY_M_S2

    @property
    def branch(self) -> np.ndarray:
        """Hysteresis branch of each visit: +1 cooling, -1 heating, 0 none (or ``branch_values``)."""
        if self.branch_values is not None:
            return np.asarray(self.branch_values, float)
        return np.array([BRANCH[d] for d in self.direction])

    @property
    def units(self) -> list[str]:
        return sorted(set(self.unit.tolist()))

    @property
    def setpoint_blocks(self) -> np.ndarray:
        """Index of the setpoint visit each row belongs to (consecutive in time)."""
        order = np.argsort(self.time_s, kind="stable")
        key = list(zip(self.unit[order], self.state[order], self.cycle[order],
                       self.setpoint_C[order], self.direction[order]))
        block = np.zeros(self.n_visits, int)
        b = 0
        for k in range(1, len(order)):
            if key[k] != key[k - 1]:
                b += 1
            block[order[k]] = b
        return block

    def temperature_rate(self) -> np.ndarray:
        """Rate of change of each temperature sensor (degC/s), shape (n, 3).

        The measured rate of each visit when the campaign has one (``dTdt_C_per_min``, the rate
        of the unit's temperature reading over the visit's window, e.g. from the raw readings by
        ``capture --ramp``), the same for the three sensors (they sit on one unit and share its
        thermal history; see docs/bench-csv.md). Otherwise central differences of the visit means
        against ``time_s`` within each setpoint block (one-sided at its ends); zero for a block
        with a single visit.
        """
        if self.dTdt_C_per_min is not None:
            r = np.asarray(self.dTdt_C_per_min, float) / 60.0
            return np.repeat(r[:, None], 3, axis=1)
        return self.central_difference_rate()

    def temperature_rate_method(self) -> str:
        """How :meth:`temperature_rate` gets the rates: measured per visit (with the file's
        ``dTdt_method`` metadata when it has one) or central differences of the visit means."""
        if self.dTdt_C_per_min is not None:
            how = self.metadata.get("dTdt_method")
            return "measured per visit (bench CSV dTdt_C_per_min" + (f": {how})" if how else ")")
        return "central differences of the visit means within each setpoint block (one-sided at its ends)"

    def central_difference_rate(self) -> np.ndarray:
        """Rate of each temperature sensor (degC/s, (n, 3)) from central differences of the visit
        means within each setpoint block (one-sided at its ends; zero for a single visit): the
        rate :meth:`temperature_rate` falls back to when the campaign has no measured rate."""
        rate = np.zeros_like(self.t)
        blocks = self.setpoint_blocks
        for b in np.unique(blocks):
            idx = np.flatnonzero(blocks == b)
            idx = idx[np.argsort(self.time_s[idx])]
            t_idx = self.time_s[idx]
            if len(idx) >= 2 and np.all(np.diff(t_idx) > 0):
                rate[idx] = np.gradient(self.t[idx], t_idx, axis=0)
        return rate

    def up_axis(self) -> np.ndarray:
        """Nominal up axis of each visit ('+X', '-Y', ...), from the bench kinematics."""
        return up_axis_label(self.axis1_deg, self.axis2_deg)

    def output_sigma(self) -> Optional[np.ndarray]:
        """Standard uncertainty of each mean output: ``u_w`` (the data's own noise, flicker and
        bias instability included) when present, else ``sd_*/sqrt(n_samples)`` (white noise
        only), else None. :meth:`output_sigma_method` says which."""
        if self.u_w is not None:
            return np.asarray(self.u_w, float)
        if self.sd is None or self.n_samples is None:
            return None
        return self.sd / np.sqrt(self.n_samples)[:, None]

    def output_sigma_method(self) -> Optional[str]:
        """Where :meth:`output_sigma` comes from, in words (None when it is None)."""
        if self.u_w is not None:
            how = self.metadata.get("u_w_method")
            return "u_w_* of each visit" + (f" ({how})" if how else " (method not stated)")
        if self.sd is None or self.n_samples is None:
            return None
        return "sd_*/sqrt(n_samples) of each visit"

    @property
    def data_sha256(self) -> str:
        """SHA-256 of what was measured: the unit, setpoints, directions, times, poses (axis angles),
        mean outputs w and temperatures t of every visit, in order (float64 bytes), not the file's
        name or formatting. Two results with the same ``data_sha256`` are fits of one data set, not
        two calibrations (``compare`` says so)."""
        import hashlib

        h = hashlib.sha256()
        for a in (self.unit, self.direction, self.position):
            h.update("\x1f".join(map(str, a)).encode())
            h.update(b"\x1e")
        for a in (self.setpoint_C, self.time_s, self.axis1_deg, self.axis2_deg, self.w, self.t):
            h.update(np.ascontiguousarray(np.asarray(a, dtype="<f8")).tobytes())
        return h.hexdigest()

    @property
    def derived_from_sha256(self) -> Optional[str]:
        """The ``data_sha256`` of the raw recording this file's visits were averaged from (``fit-raw
        --bench-csv`` writes it as ``# raw_samples_sha256 = ...``), or None: a fit of the file and
        the fit-raw of the recording are fits of one data set (``compare`` says so)."""
        sha = str(self.metadata.get("raw_samples_sha256", "")).strip()
        return sha if re.fullmatch(r"[0-9a-f]{64}", sha) else None

    def provenance(self) -> dict:
        """What a result says of its data: the source, ``data_sha256`` and, for a file averaged from a
        raw recording, ``derived_from_sha256``; and whether the local g was stated."""
        d = {"source": self.source, "data_sha256": self.data_sha256, "local_g_stated": self.local_g_stated}
        from ..io.dates import iso_date

        day = iso_date(self.metadata.get("date", "")) if self.metadata.get("date") else None
        if day:
            d["data_date"] = day          # the date the data were taken (history --add records it)
        if self.derived_from_sha256:
            d["derived_from_sha256"] = self.derived_from_sha256
        states = sorted(set(np.asarray(self.state).astype(str).tolist())) if self.n_visits else []
        if len(states) == 1 and states[0] != "initial":
            # the mechanical state fitted (fit --state after): history listed "state -" for every
            # calibration of a serial (an outside probe); the state of the default, unnamed, is not said
            d["state"] = states[0]
        return d

    @property
    def time_origin_s(self) -> float:
        """The zero of the clock of the terms that change in time (``bias_drift``, ``tilt_drift``,
        ``tilt_settling``, the warm-ups), in s on the ``time_s`` clock: the campaign's start. The
        ``power_on_s`` metadata line when the file has one (the simulator and the emulator write 0:
        their clocks start at power-on); else the start of the first visit's window,
        ``min(time_s - tau_s / 2)``. A file stamped with Unix time (1.7e9 s) is then read as the same
        campaign as one whose clock starts at 0: without the origin its drift's bias was the bias of
        1970 (u of tens of mg, status ok) and a warm-up's exponential underflowed to nothing."""
        if self.origin_s is not None:
            return float(self.origin_s)
        v = self.metadata.get("power_on_s")
        if v is not None:
            try:
                t_on = float(v)
            except (TypeError, ValueError):
                raise InputError(f"metadata 'power_on_s' = {v!r} is not a number of seconds") from None
            if not np.isfinite(t_on):
                raise InputError(f"metadata 'power_on_s' = {v!r} is not a finite number of seconds")
            return t_on
        if not len(self.time_s):
            return 0.0
        return float(np.min(np.asarray(self.time_s, float) - np.asarray(self.tau_s, float) / 2.0))

    def elapsed_s(self) -> np.ndarray:
        """Each visit's time since :attr:`time_origin_s` (s): the time of the terms that change in time."""
        return np.asarray(self.time_s, float) - self.time_origin_s

    def covariates(self) -> Covariates:
        rate = self.temperature_rate()
        return Covariates(
            axis1=self.axis1_deg * DEG, axis2=self.axis2_deg * DEG,
            temp=tuple(self.t[:, i] for i in range(3)),
            temp_rate=tuple(rate[:, i] for i in range(3)),
            branch=self.branch, time_s=self.elapsed_s())

    def covariate_matrix(self) -> np.ndarray:
        """The covariates as rows (``estimation.joint.COVARIATES``: axis1, axis2 in rad, the three
        temperatures, their rates, the branch, the elapsed time), one column a visit: the compiled
        problems' argument."""
        return np.vstack([np.radians(self.axis1_deg), np.radians(self.axis2_deg), self.t.T,
                          self.temperature_rate().T, self.branch, self.elapsed_s()])

    def select(self, mask, own_origin: bool = False) -> "Campaign":
        """A campaign with the visits selected by a boolean mask or index array.

        The selection keeps this campaign's :attr:`time_origin_s` (a held-out subset is on the
        same clock), unless ``own_origin``: then, when the file states no ``power_on_s``, its origin
        is the start of its own first visit's window. That is the selection of one unit or one
        state of a file that holds several (``--unit``, ``--state``, ``batch``): each was powered
        on at its own time, a unit calibrated ten hours after the first one did not warm up at
        the file's start, and its drift's bias is its bias at its own start, not an extrapolation
        ten hours back."""
        idx = np.asarray(mask)
        origin = self.time_origin_s
        if own_origin and "power_on_s" not in self.metadata:
            sel = np.arange(self.n_visits)[idx]
            if sel.size:
                origin = float(np.min(np.asarray(self.time_s, float)[sel] - np.asarray(self.tau_s, float)[sel] / 2.0))
        def t(v):
            return None if v is None else v[idx]
        return replace(self, unit=self.unit[idx], setpoint_C=self.setpoint_C[idx],
                       direction=self.direction[idx], time_s=self.time_s[idx],
                       position=self.position[idx], axis1_deg=self.axis1_deg[idx],
                       axis2_deg=self.axis2_deg[idx], tau_s=self.tau_s[idx], w=self.w[idx],
                       t=self.t[idx], cycle=self.cycle[idx], state=self.state[idx],
                       sd=t(self.sd), n_samples=t(self.n_samples), lines=t(self.lines),
                       metadata=dict(self.metadata), extra={k: v[idx] for k, v in self.extra.items()},
                       branch_values=t(self.branch_values), u_w=t(self.u_w),
                       dTdt_C_per_min=t(self.dTdt_C_per_min), origin_s=origin)
