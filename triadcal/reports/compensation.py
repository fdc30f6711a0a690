"""Compensation tables for a firmware: K, S and Ca (and Ca^-1) per temperature, with the
uncertainty at each grid point and the bound of linear interpolation between grid points
(``triadcal export-compensation``, docs/compensation.md).

A firmware applies ``A_IMU = Ca^-1(T) (K(T) W - S(T))`` (the paper's introduction) with K, S
and Ca^-1 interpolated linearly in T between the two grid points around the reading's
temperature. The table is the result's own thermal model (``Model.terms``, the same
function the fit used) evaluated at the grid, on the mid-line of the hysteresis loop: a
firmware does not know the branch, and the loop's half-width per angle is stated beside it
(a reading is off by +-h from the mid-line, docs/model.md).

- Uncertainty at a grid point: ``u(q(T)) = sqrt(g C g^T)``, ``g = dq(T)/dtheta`` by central
  differences of the model in the parameters, ``C`` the result's covariance (combined with the
  lab's systematic errors when the result was fitted with ``--lab``).
- Interpolation bound of the interval ``[T_i, T_i+1]`` of width Delta: for q twice
  differentiable, the chord's error is ``q(T) - lin(T) = -q''(xi) (T - T_i)(T_i+1 - T) / 2`` for
  some xi in the interval (Rolle applied twice to ``q - lin - k (T - T_i)(T - T_i+1)``), and
  ``(T - T_i)(T_i+1 - T) <= Delta^2 / 4``, so ``|q - lin| <= Delta^2 max|q''| / 8``. The thermal
  model is a polynomial of order <= 3 in T (linear, quadratic and cubic tempcos; K a product
  ``K0 (1 + k1 dT)(1 + k2 dT^2)(1 + k3 dT^3)`` as the fit's model writes it: q'' linear up to the
  cross terms, 6 k1 k2 dT against 2 k2, 2 % at 65 degC for k1 = 100 ppm/degC), so q'' is linear in T
  and its maximum modulus over the
  interval is at an end: the bound is ``Delta^2 max(|q''(T_i)|, |q''(T_i+1)|) / 8``, with q''
  by the central second difference of the model, exact for a cubic. It is the exact maximum
  error for a quadratic term (q'' constant), a bound within a factor 2 of it for a cubic, and 0
  for a linear model. A model of higher order in T is refused.

The model terms a table of T alone cannot hold are refused by name: a time-dependent bias,
a nonlinear or asymmetric scale, which act on W or time, not on T.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..errors import InputError
from ..estimation.one_temperature import row_temperatures_C, rows_apart
from ..estimation.result import CalibrationResult
from ..models.effects import BENCH_EFFECTS, TEMPCO_EFFECTS
from ..models.model import Covariates, Model
from ..models.sensor import ANGLE_NAMES, AXES, dcm
from ..models.units import ARCSEC, scale_factor_unit

FORMAT = "triadcal.compensation"
VERSION = 1
FORMATS = ("json", "csv", "c-header")
#: a table's temperatures: above absolute zero, and no hotter than any bench CSV holds (degC)
ABSOLUTE_ZERO_C = -273.15
TABLE_MAX_C = 300.0
#: effects a table of temperature can represent (bench terms are not properties of the unit)
TABLE_EFFECTS = BENCH_EFFECTS + ("angle_tempco", "angle_tempco2", "scale_tempco", "scale_tempco2", "bias_tempco",
                                 "bias_tempco2", "hysteresis", "thermal_lag", "angle_tempco3", "scale_tempco3",
                                 "bias_tempco3")


@dataclass
class CompensationTable:
    """The table: grid (degC) and, per quantity, value / u / interpolation bound per grid point."""

    unit: str
    output_unit: str
    reference_temperature_C: float
    temperature_range_C: tuple
    grid_C: np.ndarray
    K: np.ndarray          # (n, 3) g per output unit
    S: np.ndarray          # (n, 3) g
    angles: np.ndarray     # (n, 6) arcsec, ANGLE_NAMES order
    Ca_inv: np.ndarray     # (n, 3, 3)
    u_K: np.ndarray
    u_S: np.ndarray
    u_angles: np.ndarray
    interp_K: np.ndarray   # (n, 3): bound on [T_i, T_i+1] (last row 0: no interval after it)
    interp_S: np.ndarray
    interp_angles: np.ndarray
    hysteresis_arcsec: dict = field(default_factory=dict)
    source_sha256: str = ""
    notes: list = field(default_factory=list)

    @property
    def K_unit(self) -> str:
        return scale_factor_unit(self.output_unit)

    @property
    def extrapolated(self) -> np.ndarray:
        """(n,) bool: the grid points outside the calibrated range (written only with
        ``allow_outside``, marked EXTRAPOLATED in every format)."""
        lo, hi = self.temperature_range_C
        return (self.grid_C < lo - 1e-9) | (self.grid_C > hi + 1e-9)

    # -- applying it as a firmware would ------------------------------------------------
    def apply(self, w, temperature_C) -> np.ndarray:
        """``A = Ca^-1(T) (K(T) W - S(T))`` with K, S and Ca^-1 linearly interpolated in T (g).
        ``w`` (n, 3) outputs, ``temperature_C`` (n,) one temperature per reading."""
        w = np.atleast_2d(np.asarray(w, float))
        T = np.asarray(temperature_C, float).reshape(-1)
        lo, hi = self.grid_C[0], self.grid_C[-1]
        if np.any(T < lo - 1e-9) or np.any(T > hi + 1e-9):
            raise InputError(f"temperatures outside the table's grid {lo:g}..{hi:g} degC")

        def interp(q):
            flat = q.reshape(len(self.grid_C), -1)
            return np.stack([np.interp(T, self.grid_C, flat[:, j]) for j in range(flat.shape[1])], axis=1)

        K, S = interp(self.K), interp(self.S)
        Cinv = interp(self.Ca_inv).reshape(-1, 3, 3)
        return np.einsum("nij,nj->ni", Cinv, w * K - S)

    # -- writers ---------------------------------------------------------------------------
    def to_dict(self) -> dict:
        rows = []
        for i, T in enumerate(self.grid_C):
            r = {"T_C": float(T)}
            for j, a in enumerate(AXES):
                r[f"K_{a}"], r[f"u_K_{a}"], r[f"interp_K_{a}"] = (float(self.K[i, j]), float(self.u_K[i, j]),
                                                                   float(self.interp_K[i, j]))
            for j, a in enumerate(AXES):
                r[f"S_{a}"], r[f"u_S_{a}"], r[f"interp_S_{a}"] = (float(self.S[i, j]), float(self.u_S[i, j]),
                                                                   float(self.interp_S[i, j]))
            for j, ab in enumerate(ANGLE_NAMES):
                r[f"Ca_{ab}"], r[f"u_Ca_{ab}"], r[f"interp_Ca_{ab}"] = (
                    float(self.angles[i, j]), float(self.u_angles[i, j]), float(self.interp_angles[i, j]))
            r["Ca_inv"] = self.Ca_inv[i].tolist()
            r["extrapolated"] = bool(self.extrapolated[i])
            rows.append(r)
        return {"format": FORMAT, "version": VERSION, "unit": self.unit, "output_unit": self.output_unit,
                "source_sha256": self.source_sha256, "reference_temperature_C": self.reference_temperature_C,
                "temperature_range_C": list(self.temperature_range_C), "interpolation": "linear in T",
                "branch": "mid-line of the hysteresis loop",
                "units": {"T_C": "degC", "K": self.K_unit, "S": "g", "Ca": "arcsec", "Ca_inv": "1",
                          "u": "standard uncertainty (k = 1) in the quantity's unit",
                          "interp": "bound of linear interpolation on [T_i, T_i+1], the quantity's unit"},
                "apply": "A_IMU = Ca_inv(T) (K(T) W - S(T)), each interpolated linearly in T",
                "extrapolated": "a row with extrapolated true is EXTRAPOLATED: outside the calibrated range, "
                                "where the thermal model is not valid",
                "hysteresis_arcsec": self.hysteresis_arcsec, "rows": rows, "notes": list(self.notes)}

    def to_csv(self) -> str:
        d = self.to_dict()
        cols = [k for k in d["rows"][0] if k not in ("Ca_inv", "extrapolated")] + \
            [f"Ca_inv_{i}{j}" for i in range(3) for j in range(3)] + ["extrapolated"]
        out = [f"# format = {FORMAT}", f"# version = {VERSION}", f"# unit = {_one_line(self.unit)}",
               f"# source_sha256 = {self.source_sha256}", f"# K unit = {_one_line(self.K_unit)}; S unit = g; Ca unit = "
               "arcsec; u_* standard uncertainty; interp_* bound of linear interpolation to the next row",
               f"# calibrated range = {self.temperature_range_C[0]:.1f}..{self.temperature_range_C[1]:.1f} degC; "
               "extrapolated = 1: the row is EXTRAPOLATED (outside the calibrated range, where the thermal model is "
               "not valid)",
               f"# apply = {d['apply']}; mid-line of the hysteresis loop",
               "# hysteresis_arcsec = " + json.dumps(self.hysteresis_arcsec)]
        out += [f"# note = {_one_line(n)}" for n in self.notes]
        out.append(",".join(cols))
        for r in d["rows"]:
            vals = [r[c] for c in cols[:-10]] + [x for row in r["Ca_inv"] for x in row]
            out.append(",".join(f"{v:.10g}" for v in vals) + f",{int(r['extrapolated'])}")
        return "\n".join(out) + "\n"

    def to_c_header(self, prefix: str = "triadcal_comp") -> str:
        n = len(self.grid_C)
        guard = f"{prefix.upper()}_H"

        ext = self.extrapolated
        row_note = [f"/* {T:g} degC" + (", EXTRAPOLATED */" if x else " */") for T, x in zip(self.grid_C, ext)]

        def arr(name, a, unit, shape):
            a = np.asarray(a, float)

            def lit(x):
                return "{" + ", ".join(lit(y) for y in x) + "}" if np.ndim(x) else _c_float(x)

            body = "\n".join("    " + lit(row) + ("," if i < n - 1 else " ") + " " + row_note[i]
                             for i, row in enumerate(a))
            return f"/* {_c_comment(unit)} */\nstatic const float {prefix}_{name}[{n}]{shape} = {{\n{body}\n}};\n"

        T = ", ".join(_c_float(x) for x in self.grid_C)
        flags = ", ".join(str(int(x)) for x in ext)
        notes = [f" * Note: {_c_comment(x)}" for x in self.notes]
        lines = [f"/* Compensation table of accelerometer triad {_c_comment(self.unit)}, written by triadcal "
                 "export-compensation.",
                 f" * Result SHA-256 {self.source_sha256}. Reference temperature {self.reference_temperature_C:g} degC;",
                 f" * calibrated range {self.temperature_range_C[0]:.1f}..{self.temperature_range_C[1]:.1f} degC.",
                 " * Apply: A_IMU[g] = Ca_inv(T) * (K(T) * W - S(T)), K, S, Ca_inv interpolated linearly in T.",
                 " * Mid-line of the hysteresis loop; half-widths (arcsec): "
                 + (", ".join(f"{k} {v:.3g}" for k, v in self.hysteresis_arcsec.items()) or "none modelled") + ".",
                 f" * Largest interpolation bound: K {np.max(self.interp_K):.3g} {_c_comment(self.K_unit)}, S "
                 f"{np.max(self.interp_S):.3g} g, angles {np.max(self.interp_angles):.3g} arcsec.",
                 " * u_* arrays: standard uncertainty (k = 1) of each entry.",
                 f" * {prefix}_extrapolated[i] = 1: row i is EXTRAPOLATED (outside the calibrated range, where the "
                 f"thermal model is not valid): {int(ext.sum())} of {n} rows."] + notes + [" */",
                 f"#ifndef {guard}", f"#define {guard}", f"#define {prefix.upper()}_N {n}",
                 f"/* degC */\nstatic const float {prefix}_T_C[{n}] = {{{T}}};",
                 f"/* 1: EXTRAPOLATED row */\nstatic const unsigned char {prefix}_extrapolated[{n}] = {{{flags}}};",
                 arr("K", self.K, self.K_unit, "[3]"), arr("S", self.S, "g", "[3]"),
                 arr("Ca_inv", self.Ca_inv, "1 (rows X, Y, Z)", "[3][3]"),
                 arr("u_K", self.u_K, self.K_unit, "[3]"), arr("u_S", self.u_S, "g", "[3]"),
                 arr("u_angles", self.u_angles, "arcsec, " + " ".join(f"Ca_{ab}" for ab in ANGLE_NAMES), "[6]"),
                 f"#endif /* {guard} */", ""]
        return "\n".join(lines)

    def write(self, path, fmt: str) -> None:
        from ..io.atomic import atomic_write_json, atomic_write_text

        if fmt == "json":
            atomic_write_json(path, self.to_dict())
        elif fmt == "csv":
            atomic_write_text(path, self.to_csv())
        elif fmt == "c-header":
            atomic_write_text(path, self.to_c_header())
        else:
            raise InputError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")


def _one_line(text) -> str:
    """Text for one comment line: control characters (a newline would end a CSV comment) become spaces."""
    return "".join(c if c.isprintable() else " " for c in str(text))


def _c_comment(text) -> str:
    """Text safe inside a C ``/* */`` comment under ``gcc -Wall -Wextra -Werror``: ``*/`` would end it
    and ``/*`` inside it is a warning (-Wcomment), a backslash at a line end splices lines; non-ASCII
    characters and control characters become ``?`` or a space (a serial is free text)."""
    t = _one_line(text).replace("\\", "/")
    t = "".join(c if ord(c) < 128 else "?" for c in t)
    while "*/" in t or "/*" in t:
        t = t.replace("*/", "* /").replace("/*", "/ *")
    return t.replace("??", "? ?")                    # no trigraph


def _c_float(x: float) -> str:
    """A C float literal: 9 significant digits, always with a point or an exponent (-35.0f, not -35f)."""
    t = f"{float(x):.9g}"
    if not any(c in t for c in ".eEn"):
        t += ".0"
    return t + "f"


def parse_grid(text: str) -> np.ndarray:
    """``LO:HI:STEP`` in degC (``-40:85:5``), both ends included when on the step."""
    parts = str(text).split(":")
    try:
        lo, hi, step = (float(x) for x in parts)
    except ValueError:
        raise InputError(f"--grid {text!r}: write LO:HI:STEP in degC, e.g. -40:85:5") from None
    bad = [f"{n} = {x!r}" for n, x in zip(("LO", "HI", "STEP"), parts) if not math.isfinite(float(x))]
    if bad:
        raise InputError(f"--grid {text!r}: {', '.join(bad)} is not a finite number (degC)")
    if step <= 0 or hi <= lo:
        raise InputError(f"--grid {text!r}: need LO < HI and STEP > 0 (degC)")
    n = int(math.floor((hi - lo) / step + 1e-9)) + 1
    if n > 10_000:
        raise InputError(f"--grid {text!r}: {n} points; a table of more than 10000 points is not a firmware table")
    g = lo + step * np.arange(n)
    return g if abs(g[-1] - hi) < 1e-9 * max(1.0, abs(hi)) else np.append(g, hi)


def _terms(model: Model, p: dict, T: np.ndarray):
    """K (n, 3), S (n, 3), angles (n, 6, arcsec) of the model at temperatures T (all sensors at T,
    steady state, mid-line)."""
    K, S, angles = model.terms(p, Covariates.at_rest((T, T, T)))
    K = np.stack([np.broadcast_to(np.asarray(k, float), T.shape) for k in K], axis=1)
    S = np.stack([np.broadcast_to(np.asarray(s, float), T.shape) for s in S], axis=1)
    A = np.stack([np.broadcast_to(np.asarray(angles[ab], float), T.shape) / ARCSEC for ab in ANGLE_NAMES], axis=1)
    return K, S, A


#: a calibrated range's end more than this (degC) beyond the grid's end is said in the notes
GRID_SHORT_C = 0.05


def _outside_text(outside, rng) -> tuple:
    """Grid points outside the range ``rng`` and the range's ends as text, with the fewest decimals
    (1 to 9) that show each point on its side of the end it passes: "-39.8 outside -39.8..70.4" was
    printed for a point 0.04 degC below -39.76 (an outside probe)."""
    lo, hi = float(rng[0]), float(rng[1])
    for d in range(1, 10):
        def f(x):
            return f"{x:.{d}f}"
        if all(f(x) != f(lo if x < lo else hi) for x in outside):
            break
    return ", ".join(f(x) for x in outside), f(lo), f(hi)


def compensation_table(result: CalibrationResult, grid_C: Sequence[float], *, source_sha256: str = "",
                       allow_outside: bool = False, source: Optional[str] = None) -> CompensationTable:
    """The table of ``result`` on ``grid_C`` (see the module). Refuses a result that is not ok,
    effects a table of T cannot hold, and grid points outside the calibrated range (the thermal
    model is not valid there) unless ``allow_outside`` (then said in the notes)."""
    from ..estimation.result_checks import RefusedResult, check_result_for_use
    from .certificate.refusal import refusal_reasons

    src = source or f"result of {result.unit}"
    check_result_for_use(result, src)
    # what a certificate is refused for, a table that states the same values is refused for (an outside
    # probe: a result with a significant model-data gap, p 4e-4, was refused a certificate and exported, exit 0);
    # a result without content_sha256 is exported with a note (below), as before
    why = refusal_reasons(result, unhashed=False)
    if why:
        raise RefusedResult(f"{src}: refused: " + "; ".join(why) + " (the reasons a certificate is refused for: a "
                            "table states the same values)")
    other = [e for e in result.effects if e not in TABLE_EFFECTS]
    # (every effect of TABLE_EFFECTS is a polynomial of order <= 3 in T: the interpolation bound's premise)
    if other:
        raise InputError(f"the model holds {', '.join(other)}, which act on the outputs or on time, not on the "
                         "temperature alone: a compensation table of T cannot represent them (refit without them, "
                         "or apply the result with CalibrationResult.apply)")
    grid = np.asarray(grid_C, float)
    if grid.ndim != 1 or len(grid) < 1 or not np.all(np.isfinite(grid)) or np.any(np.diff(grid) <= 0):
        raise InputError(f"grid {grid.tolist()!r}: need finite temperatures (degC), increasing")
    unphysical = grid[(grid <= ABSOLUTE_ZERO_C) | (grid > TABLE_MAX_C)]
    if unphysical.size:
        raise InputError(f"grid point {unphysical[0]:g} degC is no temperature a unit is used at (a table runs "
                         f"above {ABSOLUTE_ZERO_C:g} and up to {TABLE_MAX_C:g} degC)")
    notes = []
    if result.content_unhashed:
        # an outside probe: content_sha256 deleted and K_x edited: exported without a word (compare notes it,
        # certificate refuses it)
        notes.append("the result holds no content_sha256 (another writer, or triadcal before 2026-11-30): nothing "
                     "shows that the tabulated values are the fit's answer and not edited; a certificate is refused "
                     "for such a file")
    rng = result.temperature_range_C
    if rng is None:
        raise InputError("the result has no temperature range (no thermal data): a table of T needs one")
    short = [f"{a:.2f}..{b:.2f}" for a, b in ((rng[0], grid[0]), (grid[-1], rng[1])) if b - a > GRID_SHORT_C]
    if short:
        notes.append(f"the grid {grid[0]:g}..{grid[-1]:g} degC leaves {' and '.join(short)} degC of the calibrated "
                     f"range {rng[0]:.2f}..{rng[1]:.2f} degC without a row: a reading there is outside this table "
                     "(the default grid ends at the range's ends)")
    outside = grid[(grid < rng[0] - 1e-9) | (grid > rng[1] + 1e-9)]
    if outside.size:
        pts, lo_txt, hi_txt = _outside_text(outside, rng)
    if outside.size and not allow_outside:
        raise InputError(f"grid points {pts} degC lie outside the calibrated range {lo_txt}..{hi_txt} degC, where the "
                         "thermal model is not valid; choose a grid inside it (or --allow-extrapolation, which says "
                         "so in the table)")
    if outside.size and not any(e in result.effects for e in TEMPCO_EFFECTS):
        # an outside probe: a one-temperature result exported over -40..85 degC repeated its 20 degC values with
        # their 20 degC u (K_x 4.6 ppm) where the truth was 1632 ppm off at 85 degC
        raise InputError(f"grid points {pts} degC lie outside the calibrated range {lo_txt}..{hi_txt} degC and the "
                         "result holds no temperature term: its values hold at the calibration's temperature only, "
                         "and a row elsewhere would repeat them with an uncertainty no data support; calibrate over "
                         "the range the table must cover")
    if outside.size:
        notes.append(f"EXTRAPOLATED: grid points {pts} degC lie outside the calibrated range {lo_txt}..{hi_txt} degC")
    if "thermal_lag" in result.effects:
        notes.append("steady state: the sensing element's lag behind its sensor (thermal_lag) is not in a table "
                     "of T; apply it to the temperature before the lookup")
    rows_T = row_temperatures_C(result)
    if rows_apart(rows_T):
        notes.append("one temperature, sensors apart: each accelerometer's K, S and angles hold at its own sensor's "
                     "temperature (" + ", ".join(f"{a} {v:.2f}" for a, v in rows_T.items()) + " degC), no tempco "
                     "carries them to another")
    unit_effects = [e for e in result.effects if e not in BENCH_EFFECTS]
    model = Model(unit_effects, result.reference_temperature_C)
    missing = [n for n in model.names if n not in result.parameters]
    if missing:
        raise InputError(f"the result lacks {', '.join(missing)} of its own model")
    names = list(model.names)
    x0 = np.array([result.parameters[n].value for n in names])

    def at(x, T):
        return _terms(model, model.to_internal(dict(zip(names, x))), T)

    K, S, A = at(x0, grid)
    # uncertainty at each grid point: g C g^T by central differences in the parameters
    C = result.covariance(names)
    su = np.sqrt(np.maximum(np.diag(C), 0.0))
    G = []
    for j in range(len(names)):
        h = su[j] if su[j] > 0 else 1e-9 * max(1.0, abs(x0[j]))
        xp, xm = x0.copy(), x0.copy()
        xp[j] += h
        xm[j] -= h
        qp, qm = np.concatenate([q.reshape(len(grid), -1) for q in at(xp, grid)], axis=1), \
            np.concatenate([q.reshape(len(grid), -1) for q in at(xm, grid)], axis=1)
        G.append((qp - qm) / (2 * h))
    G = np.stack(G, axis=2)                              # (n grid, 12 quantities, n params)
    u = np.sqrt(np.maximum(np.einsum("gqi,ij,gqj->gq", G, C, G), 0.0))
    # interpolation bound per interval [T_i, T_i+1]: Delta^2 max|q''| / 8, q'' linear in T (module)
    def flat(T):
        return np.concatenate([x.reshape(len(T), -1) for x in at(x0, T)], axis=1)

    e = 1.0                                              # degC; the second difference is exact for a cubic
    q2 = (flat(grid + e) - 2.0 * flat(grid) + flat(grid - e)) / (e * e)          # (n grid, 12)
    interp = np.zeros((len(grid), 12))
    for i in range(len(grid) - 1):
        interp[i] = (grid[i + 1] - grid[i]) ** 2 * np.maximum(np.abs(q2[i]), np.abs(q2[i + 1])) / 8.0
    # rounding of the evaluation (1e-16 of K) is not an interpolation error: below 1e-12 of the
    # quantity's scale it is 0 (a linear thermal model interpolates exactly)
    scale = np.maximum(1.0, np.abs(np.concatenate([K, S, A], axis=1)).max(axis=0))
    interp[interp < 1e-12 * scale] = 0.0
    # an extrapolated row must still be a sensor: finite in a 32-bit float (the C header's type) with K > 0
    # (an outside probe's --grid -1e6:1e6:1e5 wrote negative K and nan in Ca^-1, exit 0)
    q = np.concatenate([K, S, A, u, interp], axis=1)
    bad = np.flatnonzero(~np.all(np.isfinite(q.astype(np.float32)), axis=1) | np.any(K <= 0, axis=1))
    if bad.size:
        i = int(bad[0])
        raise InputError(f"at {grid[i]:g} degC the model gives K = {', '.join(f'{k:.4g}' for k in K[i])} (S, angles "
                         "and their u finite in a 32-bit float, K above 0, are needed for a row): that temperature is "
                         "too far from the calibrated range for its thermal terms")
    Ca_inv = np.stack([np.linalg.inv(np.array(dcm({ab: A[i, j] * ARCSEC for j, ab in enumerate(ANGLE_NAMES)}), float))
                       for i in range(len(grid))])
    hyst = {f"Ca_{ab}": result.parameters[f"Ca_{ab}_hysteresis"].value for ab in ANGLE_NAMES
            if f"Ca_{ab}_hysteresis" in result.parameters}
    if hyst:
        notes.append("mid-line of the hysteresis loop: a reading on the heating or the cooling branch is off by -+h "
                     "(hysteresis_arcsec); the table cannot know the branch")
    return CompensationTable(
        unit=result.unit, output_unit=str(result.extra.get("output_unit") or "V"),
        reference_temperature_C=result.reference_temperature_C, temperature_range_C=tuple(rng), grid_C=grid,
        K=K, S=S, angles=A, Ca_inv=Ca_inv, u_K=u[:, 0:3], u_S=u[:, 3:6], u_angles=u[:, 6:12],
        interp_K=interp[:, 0:3], interp_S=interp[:, 3:6], interp_angles=interp[:, 6:12],
        hysteresis_arcsec=hyst, source_sha256=source_sha256, notes=notes)


def export_compensation(result_path, out_path, fmt: str = "json", grid="-40:85:5",
                        allow_outside: bool = False, source: Optional[str] = None, data=None) -> CompensationTable:
    """Read a result file, build its table (:func:`compensation_table`) and write it; ``grid`` is
    ``LO:HI:STEP`` (:func:`parse_grid`) or the temperatures themselves (degC, increasing). ``data``:
    the bench CSV the result was fitted to; the result is refused, nothing written, when they are not
    its data or do not give its values or range (:func:`~triadcal.reports.certificate.against_data.check_against_data`)."""
    if fmt not in FORMATS:
        raise InputError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    digest = hashlib.sha256(Path(result_path).read_bytes()).hexdigest()
    grid_C = parse_grid(grid) if isinstance(grid, str) else np.asarray(grid, float)
    result = CalibrationResult.load(result_path)
    table = compensation_table(result, grid_C, source=str(result_path),
                               source_sha256=digest, allow_outside=allow_outside)
    if data is not None:
        from .certificate.against_data import check_against_data, not_rederivable

        check_against_data(result, data, str(result_path))
        why = not_rederivable(result)
        table.notes.append(f"checked against {data}: its SHA-256 is the result's data_sha256 and its visits span "
                           "the result's range" + (f"; the values were not re-derived from it ({why})" if why else
                                                   "; the values are those the data give (within 5 u)"))
    table.write(out_path, fmt)
    return table


def load_table(path) -> CompensationTable:
    """Read a JSON table back (validated: format, version, rows with every field)."""
    from ..io.atomic import read_json
    from ..io.formats import require_format

    d = read_json(path)
    require_format(d, FORMAT, VERSION, str(path), "a compensation table", "compensation")
    rows = d.get("rows")
    if not isinstance(rows, list) or len(rows) < 2:
        raise InputError(f"{path}: rows: expected a list of at least two grid points")
    try:
        def col(key):
            return np.array([[float(r[key.format(a)]) for a in AXES] for r in rows])

        def ang(key):
            return np.array([[float(r[key.format(ab)]) for ab in ANGLE_NAMES] for r in rows])

        T = np.array([float(r["T_C"]) for r in rows])
        Cinv = np.array([np.asarray(r["Ca_inv"], float).reshape(3, 3) for r in rows])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: rows: a grid point lacks or garbles a field ({exc})") from None
    if np.any(np.diff(T) <= 0):
        raise InputError(f"{path}: rows: T_C must increase")
    return CompensationTable(
        unit=str(d.get("unit")), output_unit=str(d.get("output_unit")),
        reference_temperature_C=float(d.get("reference_temperature_C", 20.0)),
        temperature_range_C=tuple(d.get("temperature_range_C") or (T[0], T[-1])), grid_C=T,
        K=col("K_{}"), S=col("S_{}"), angles=ang("Ca_{}"), Ca_inv=Cinv, u_K=col("u_K_{}"), u_S=col("u_S_{}"),
        u_angles=ang("u_Ca_{}"), interp_K=col("interp_K_{}"), interp_S=col("interp_S_{}"),
        interp_angles=ang("interp_Ca_{}"), hysteresis_arcsec=dict(d.get("hysteresis_arcsec") or {}),
        source_sha256=str(d.get("source_sha256", "")), notes=list(d.get("notes") or []))
