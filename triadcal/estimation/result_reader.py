"""The validation of a results-json v1 document (:meth:`CalibrationResult.from_dict
<triadcal.estimation.result.CalibrationResult.from_dict>`): every field it reads, one line naming the
source and the JSON path of a field that breaks docs/results-json.md — types, units (one canonical
unit per parameter), the completeness of the result's model, U = k u, budget rows, correlations,
gates, intervals. Split from result.py, which holds the result and its use.
"""

from __future__ import annotations

import math
import re
from typing import Optional

import numpy as np

from ..errors import InputError


class ResultFormatError(InputError):
    """A results-json document with a field of the wrong type, missing or unknown (one line)."""


#: the budget fields of a parameter (docs/results-json.md) and the row fields
UNCERTAINTY_FIELDS = ("u_type_a", "U", "k", "coverage_probability", "dof_eff", "U_method", "budget")
BUDGET_ROW_NUMBERS = ("u", "sensitivity", "contribution")
#: the values of a budget row's ``type`` and ``distribution`` (the schema's enumerations)
BUDGET_ROW_TYPES = ("A", "B")
BUDGET_ROW_DISTRIBUTIONS = ("normal", "two-point", "rectangular", "arcsine")
#: U = k u holds to this relative tolerance (the writer writes full double precision)
U_REL_TOL = 1e-6
#: a parameter's u against the root sum of squares of its budget's contributions (relative)
BUDGET_REL_TOL = 1e-6
#: a GUM k against Student's t at the stated coverage and dof (relative)
K_REL_TOL = 1e-3
#: the correlation matrix is written rounded to 6 decimals: its entries hold to this
CORRELATION_TOL = 2e-6
#: parameters a writer derives from the model's (their unit, as written)
DERIVED_UNITS = {"tilt_delta": "arcsec", "tilt_beta": "deg", "thermal_lag_housing": "min"}
#: the scale factors: in g per output unit (``g/V``, ``g/mV``, ``g/count``, ``g/(m/s2)``)
SCALE_NAMES = ("K_x", "K_y", "K_z")
#: the angles a gravity-norm fit (``fit-raw --poses unknown``) defines as 0 (its frame: Z along
#: the Z sensing axis, Y in the Y-Z plane); it estimates only Ca_xy, Ca_xz, Ca_yz
NORM_FRAME_ANGLES = ("Ca_yx", "Ca_zx", "Ca_zy")
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def canonical_units() -> dict:
    """The unit results-json v1 writes each parameter name in: the model's parameter table
    (:mod:`triadcal.models.parameters` and every effect's ``parameters()``) and the derived
    parameters; the scale factors' ``g/V`` stands for g per output unit."""
    global _CANONICAL
    if _CANONICAL is None:
        from ..models.effects import EFFECTS
        from ..models.parameters import CORE_PARAMETERS

        units = {spec.name: spec.unit for spec in CORE_PARAMETERS}
        for effect in EFFECTS.values():
            units.update({spec.name: spec.unit for spec in effect().parameters()})
        units.update(DERIVED_UNITS)
        _CANONICAL = units
    return _CANONICAL


_CANONICAL: Optional[dict] = None


def _scale_unit_matches(unit: str, output_unit: str) -> bool:
    """Whether the scale factor's ``unit`` is g per ``output_unit``: ``g/V`` for V, ``g/count``
    for counts (the plural written singular), ``g/(m/s2)`` for m/s2 (fit-raw's input units)."""
    per = unit[2:] if unit.startswith("g/") else None
    if per is None:
        return False
    if per.startswith("(") and per.endswith(")"):
        per = per[1:-1]
    return per in (output_unit, output_unit.rstrip("s")) or per.rstrip("s") == output_unit.rstrip("s")


def _check_unit(r: "_Reader", name: str, unit: str, output_unit: Optional[str], where: str) -> None:
    """Refuse a parameter in a unit other than the one results-json v1 writes it in: a reader
    does not convert (every consumer takes the numbers in that unit), so an angle in ``deg``
    would be read as arcsec and a K in ``g/mV`` of an output in V 1000 times off."""
    expected = canonical_units().get(name)
    if expected is None:
        return                      # a parameter the model does not know: its unit is only checked known
    if expected == "g/V":           # a scale factor: g per output unit
        if output_unit is not None and not _scale_unit_matches(unit, output_unit):
            raise r.error(where, f"is {unit!r}, but output_unit is {output_unit!r}: {name} is in g per output "
                                 f"unit, expected g per {output_unit} (a reader does not relabel or convert it)")
        if not unit.startswith("g/"):
            raise r.error(where, f"is {unit!r}, expected g per output unit ('g/V', 'g/count', ...)")
        return
    if unit != expected:
        raise r.error(where, f"is {unit!r}, but {name} is written in {expected!r} (results-json v1 gives every "
                             f"parameter in one unit; a reader does not convert: give value, u, U, intervals and "
                             f"budget in {expected})")


def _check_scale_units(r: "_Reader", params: dict) -> None:
    units = {n: params[n].unit for n in SCALE_NAMES if n in params}
    if len(set(units.values())) > 1:
        raise r.error("parameters", "K_x, K_y, K_z are in different units (" + ", ".join(
            f"{n}: {u}" for n, u in units.items()) + "): all three are g per the same output unit")


def _read_fixed(r: "_Reader", d: dict, output_unit: Optional[str]) -> dict:
    """``fixed``: parameters held, not estimated, ``name -> {"value", "unit"}``; {} when absent."""
    fixed = d.get("fixed")
    if fixed is None:
        return {}
    if not isinstance(fixed, dict):
        raise r.error("fixed", f"is a {_kind(fixed)}, expected an object parameter -> {{value, unit}}")
    for k, v in fixed.items():
        where = f"fixed.{k}"
        if not isinstance(v, dict):
            raise r.error(where, f"is a {_kind(v)}, expected an object with value and unit")
        x = r.number(v, "value", where)
        if not math.isfinite(x):
            raise r.error(f"{where}.value", "is null: a held parameter has a finite value")
        unit = r.string(v, "unit", where)
        expected = canonical_units().get(k)
        if expected is not None and expected != "g/V" and unit != expected:
            raise r.error(f"{where}.unit", f"is {unit!r}, but {k} is written in {expected!r}")
    return fixed


def _check_fit(r: "_Reader", fit: dict) -> None:
    for key in ("n_obs", "n_params"):
        if key in fit:
            v = fit[key]
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise r.error(f"fit.{key}", f"is {v!r:.40}, expected a count (an integer >= 0)")
    if "chi2_dof" in fit:
        x = r.number_value(fit["chi2_dof"], "fit.chi2_dof")
        if x < 0:
            # an outside probe's -1 went into a certificate and a compensation table
            raise r.error("fit.chi2_dof", f"= {x!r} is negative (a chi-square per degree of freedom is >= 0)")


def _check_complete(r: "_Reader", method: str, effects: tuple, params: dict, fixed: dict,
                    unidentifiable: dict, fit: dict) -> None:
    """Refuse a result that lacks a parameter of its own model (``effects`` over the core K, S
    and the six angles; every estimator, ``method`` whichever, estimates all of them). Absent
    legitimately: a parameter held, not estimated (listed under ``fixed``, or ``unidentifiable``
    with the reason), and the three angles a gravity-norm fit (``fit-raw --poses unknown``)
    defines as 0."""
    from ..models.model import Model

    names = Model(effects).names
    known = canonical_units()
    for n in params:
        if n in known and n not in names and n not in DERIVED_UNITS:
            raise r.error(f"parameters.{n}", f"is a parameter of an effect that is not in effects "
                                             f"[{', '.join(effects)}]: the result's model has no such term")
        if n not in known and n not in DERIVED_UNITS:
            # an outside probe's "foo" was printed on a certificate as a 36th parameter
            raise r.error(f"parameters.{n}", "is not a parameter of triadcal's model (docs/model.md names them)")
    norm = "gravity norm" in str(fit.get("model", ""))
    missing = [n for n in names
               if n not in params and n not in fixed and n not in unidentifiable
               and not (norm and n in NORM_FRAME_ANGLES)]
    if missing:
        raise r.error(f"parameters.{missing[0]}",
                      f"is missing ({len(missing)} parameter{'s' if len(missing) > 1 else ''} of the result's own "
                      f"model absent: {', '.join(missing[:8])}{' ...' if len(missing) > 8 else ''}; method {method}, "
                      f"effects [{', '.join(effects)}]): a parameter the fit did not estimate is listed under "
                      "fixed with its value")


def _read_correlation(r: "_Reader", corr, params: dict):
    """``correlation``: names (unique strings) and a square matrix of numbers in [-1, 1] or null,
    symmetric, 1 on the diagonal, positive semi-definite, all to the 6 decimals it is written
    with. A null (not finite) or a 0 on the diagonal is a correlation of a parameter whose u is
    0 or not finite (its row has no correlation); anywhere else it is refused."""
    if corr is None:
        return (), None
    if not isinstance(corr, dict):
        raise r.error("correlation", f"is a {_kind(corr)}, expected an object with names and matrix")
    names = tuple(r.string_list(corr, "names", "correlation"))
    seen = set()
    for i, n in enumerate(names):
        if n in seen:
            raise r.error(f"correlation.names[{i}]", f"{n!r} is named twice")
        if n not in params and n not in canonical_units():
            raise r.error(f"correlation.names[{i}]", f"{n!r} is not a parameter of the result or of triadcal's model")
        seen.add(n)
    rows = corr.get("matrix")
    if not (isinstance(rows, list) and len(rows) == len(names)
            and all(isinstance(row, list) and len(row) == len(names) for row in rows)):
        raise r.error("correlation.matrix", f"is not a {len(names)} x {len(names)} list of lists")
    matrix = np.array([[r.number_value(x, f"correlation.matrix[{i}][{j}]") for j, x in enumerate(row)]
                       for i, row in enumerate(rows)], float)

    def no_u(n):                      # a parameter with no (finite, non-zero) u: no correlation
        p = params.get(n)
        return p is None or not (math.isfinite(p.u) and p.u > 0)

    blank = np.array([no_u(n) for n in names], bool)
    for i, j in zip(*np.nonzero(~np.isfinite(matrix))):
        if not (blank[i] or blank[j]):
            raise r.error(f"correlation.matrix[{i}][{j}]",
                          f"is null (not finite), but {names[i]} and {names[j]} have a finite, non-zero u: "
                          "their correlation is a number in [-1, 1]")
    finite = np.where(np.isfinite(matrix), matrix, 0.0)
    for i, j in zip(*np.nonzero(np.abs(finite) > 1.0 + CORRELATION_TOL)):
        raise r.error(f"correlation.matrix[{i}][{j}]",
                      f"= {matrix[i, j]:g} ({names[i]}, {names[j]}) is not a correlation (in [-1, 1])")
    for i in range(len(names)):
        x = matrix[i, i]
        if not (abs(x - 1.0) <= CORRELATION_TOL or (blank[i] and (x == 0.0 or not math.isfinite(x)))):
            raise r.error(f"correlation.matrix[{i}][{i}]", f"= {x:g}: the correlation of {names[i]} with itself is 1")
    asym = np.abs(finite - finite.T) > CORRELATION_TOL
    asym |= np.isfinite(matrix) != np.isfinite(matrix.T)
    for i, j in zip(*np.nonzero(asym)):
        raise r.error(f"correlation.matrix[{i}][{j}]",
                      f"= {matrix[i, j]:g} but correlation.matrix[{j}][{i}] = {matrix[j, i]:g}: the matrix is "
                      "not symmetric")
    if len(names):
        low = float(np.linalg.eigvalsh(finite)[0])
        if low < -len(names) * CORRELATION_TOL:
            raise r.error("correlation.matrix", f"is not a correlation matrix: not positive semi-definite "
                                                f"(smallest eigenvalue {low:.3g}; no set of parameters can "
                                                "correlate so)")
    return names, matrix


def _check_intervals(r: "_Reader", intervals: dict) -> None:
    for k, iv in intervals.items():
        where = f"intervals.{k}"
        if not isinstance(iv, dict):
            raise r.error(where, f"is a {_kind(iv)}, expected an object with level, low and high")
        level = r.number(iv, "level", where)
        if not 0 < level < 1:
            raise r.error(f"{where}.level", f"= {level!r} is not a probability strictly between 0 and 1")
        low, high = r.number(iv, "low", where), r.number(iv, "high", where)
        if low > high:
            raise r.error(where, f"low {low:g} is above high {high:g}")


def _check_gates(r: "_Reader", block, present: bool) -> None:
    """``gates``: ``config`` (the six thresholds, positive numbers; a consumer judges with them)
    and ``outcomes`` (one object per gate). Absent is allowed (a result not made by a fit)."""
    if not present:
        return
    if not isinstance(block, dict):
        raise r.error("gates", f"is a {_kind(block)}, expected an object with config and outcomes")
    from .gates import DEFAULT_CONFIG, STATUSES

    cfg = block.get("config")
    if not isinstance(cfg, dict):
        raise r.error("gates.config", "is missing" if cfg is None else f"is a {_kind(cfg)}, expected an object")
    for key in DEFAULT_CONFIG.to_dict():
        if key not in cfg:
            raise r.error(f"gates.config.{key}", "is missing")
    for key, v in cfg.items():
        x = r.number_value(v, f"gates.config.{key}")
        if not (math.isfinite(x) and x > 0):
            raise r.error(f"gates.config.{key}", f"= {v!r} is not a positive number (a threshold the result "
                                                 "was judged with)")
    outcomes = block.get("outcomes")
    if not isinstance(outcomes, list) or not outcomes:
        raise r.error("gates.outcomes", "is missing" if outcomes is None
                      else f"is a {_kind(outcomes)}, expected a non-empty list of outcomes")
    for i, o in enumerate(outcomes):
        where = f"gates.outcomes[{i}]"
        if not isinstance(o, dict):
            raise r.error(where, f"is a {_kind(o)}, expected an object")
        r.string(o, "gate", where)
        r.string(o, "reason", where)
        st = r.string(o, "status", where)
        if st not in STATUSES or st == "ok":
            raise r.error(f"{where}.status", f"{st!r} is not a status a failing gate gives (one of "
                                             f"{', '.join(x for x in STATUSES if x != 'ok')})")
        if "passed" not in o:
            raise r.error(f"{where}.passed", "is missing")
        if o["passed"] is not None and not isinstance(o["passed"], bool):
            raise r.error(f"{where}.passed", f"is a {_kind(o['passed'])}, expected true, false or null")
        if o.get("value") is not None:
            r.number_value(o["value"], f"{where}.value")
        if o.get("threshold") is not None and not isinstance(o["threshold"], str):
            raise r.error(f"{where}.threshold", f"is a {_kind(o['threshold'])}, expected a string or null")


def _read_uncertainty(r: "_Reader", v: dict, where: str, u: float = math.nan) -> dict:
    """The budget fields of ``parameters.NAME``, validated (numbers finite and >= 0 where they
    are uncertainties, the rows' fields typed, U = k u); {} when there is no budget."""
    out = {}
    for key in UNCERTAINTY_FIELDS:
        if key not in v:
            continue
        x = v[key]
        if key == "budget":
            if not isinstance(x, list):
                raise r.error(f"{where}.budget", f"is a {_kind(x)}, expected a list of rows")
            out[key] = [_read_budget_row(r, row, f"{where}.budget[{i}]") for i, row in enumerate(x)]
        elif key == "U_method":
            out[key] = r.string(v, key, where)
        elif key == "dof_eff" and x is None:
            out[key] = None           # infinite
        else:
            val = r.number(v, key, where)
            if val < 0 or (key == "coverage_probability" and not 0 < val < 1) or (key == "dof_eff" and val <= 0):
                raise r.error(f"{where}.{key}", f"= {val!r} is out of range")
            out[key] = val
    U, k = out.get("U"), out.get("k")
    if U is not None and k is not None and all(map(math.isfinite, (U, k, u))):
        if abs(U - k * u) > U_REL_TOL * max(abs(U), abs(k * u)):
            raise r.error(f"{where}.U", f"= {U:.6g} is not k u = {k:.6g} x {u:.6g} = {k * u:.6g} (the expanded "
                                        "uncertainty is the coverage factor times the standard uncertainty)")
    _check_budget_sums(r, out, where, u)
    return out


def _check_budget_sums(r: "_Reader", out: dict, where: str, u: float) -> None:
    """The budget against its own u and k (an outside probe re-signed results whose K_x u and U were
    divided by 100, whose k was 0.1 at 95.45 %, whose u_type_a exceeded u: a certificate and a
    compensation table were made from each). ``u`` is the root sum of squares of the rows'
    contributions (JCGM 100 5.1.2; :class:`~triadcal.uncertainty.budget.Budget`), ``u_type_a`` at
    most ``u``, and with ``U_method`` GUM ``k = t_p(dof_eff)`` (2 at infinite dof and p = 95.45 %,
    JCGM 100 G.3); any other method's k is at least 1 (a two-point row alone: exactly 1)."""
    rows = out.get("budget") or []
    contributions = [row.get("contribution") for row in rows if row.get("contribution") is not None]
    if contributions and math.isfinite(u):
        total = math.sqrt(sum(float(c) ** 2 for c in contributions))
        if abs(total - u) > BUDGET_REL_TOL * max(total, u):
            raise r.error(f"{where}.u", f"= {u:.6g} is not the root sum of squares of its budget's contributions "
                                        f"({total:.6g}): the combined standard uncertainty is that sum")
    ua = out.get("u_type_a")
    if ua is not None and math.isfinite(u) and ua > u * (1.0 + BUDGET_REL_TOL):
        raise r.error(f"{where}.u_type_a", f"= {ua:.6g} exceeds the combined u = {u:.6g}, of which it is a part")
    k, p, method = out.get("k"), out.get("coverage_probability"), out.get("U_method")
    if k is None or not math.isfinite(k):
        return
    if method == "GUM" and p is not None:
        from scipy import stats

        nu = out.get("dof_eff")
        # Budget: k = t_p(nu) for the certificate's k = 2 (p = erf(2/sqrt 2)) at finite nu, else the
        # stated normal k itself (JCGM 100 G.3)
        expected = float(stats.t.ppf((1 + p) / 2, nu)) if nu is not None and abs(p - 0.9545) < 5e-4 \
            else float(stats.norm.ppf((1 + p) / 2))
        if abs(k - expected) > K_REL_TOL * expected:
            raise r.error(f"{where}.k", f"= {k:.6g} is not the GUM coverage factor for coverage {p:g} and "
                                        f"{'infinite' if nu is None else f'{nu:.4g}'} effective degrees of freedom "
                                        f"({expected:.4g}, Student's t; JCGM 100 G.3)")
    elif k < 1.0 - K_REL_TOL and (p is None or p >= 0.68):
        raise r.error(f"{where}.k", f"= {k:.6g}: a coverage factor below 1 cannot give coverage {p} (a two-point "
                                    "row alone, the narrowest case, needs 1)")


def _read_budget_row(r: "_Reader", row, w: str) -> dict:
    """One row of a budget (the schema's ``budget_row``): source, type, distribution, u (>= 0 or
    null), unit, sensitivity (signed), contribution (>= 0 or null), dof (> 0 or null)."""
    if not isinstance(row, dict):
        raise r.error(w, f"is a {_kind(row)}, expected an object")
    if not r.string(row, "source", w):
        raise r.error(f"{w}.source", "is empty")
    for key, allowed in (("type", BUDGET_ROW_TYPES), ("distribution", BUDGET_ROW_DISTRIBUTIONS)):
        x = r.string(row, key, w)
        if x not in allowed:
            raise r.error(f"{w}.{key}", f"{x!r} is not one of {', '.join(allowed)}")
    r.string(row, "unit", w)
    for key in ("sensitivity_unit", "key"):
        if key in row:
            r.string(row, key, w)
    for n in BUDGET_ROW_NUMBERS:
        x = r.number(row, n, w)
        if n != "sensitivity" and x < 0:
            raise r.error(f"{w}.{n}", f"= {x!r} is negative (an uncertainty is >= 0)")
    if row.get("dof") is not None:
        x = r.number(row, "dof", w)
        if not x > 0:
            raise r.error(f"{w}.dof", f"= {x!r} is not a positive number of degrees of freedom (null: infinite)")
    return dict(row)


def _kind(v) -> str:
    return {type(None): "null", bool: "boolean", str: "string", list: "list", dict: "object"}.get(
        type(v), "number" if isinstance(v, (int, float)) else type(v).__name__)


class _Reader:
    """Typed access to a JSON tree with errors naming the source and the field's JSON path."""

    def __init__(self, source: str):
        self.source = source

    def error(self, where: str, what: str) -> ResultFormatError:
        return ResultFormatError(f"{self.source}: {where} {what}")

    def number_value(self, v, where: str) -> float:
        if v is None:
            return math.nan                  # the writer's null: "not finite"
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.error(where, f"is a {_kind(v)} ({v!r:.40}), expected a number")
        return float(v)

    def number(self, d: dict, key: str, where: str) -> float:
        if key not in d:
            raise self.error(f"{where}.{key}", "is missing")
        return self.number_value(d[key], f"{where}.{key}")

    def string(self, d: dict, key: str, where: str = "") -> str:
        path = f"{where}.{key}" if where else key
        if key not in d:
            raise self.error(path, "is missing")
        v = d[key]
        if not isinstance(v, str):
            raise self.error(path, f"is a {_kind(v)}, expected a string")
        return v

    def optional_string(self, d: dict, key: str) -> Optional[str]:
        """A non-empty string, or None when ``key`` is absent."""
        if key not in d:
            return None
        v = d[key]
        if not isinstance(v, str) or not v:
            raise self.error(key, f"is a {_kind(v)}{' (empty)' if v == '' else ''}, expected a non-empty string")
        return v

    def string_list(self, d: dict, key: str, where: str = "", required: bool = True) -> list:
        path = f"{where}.{key}" if where else key
        v = d.get(key)
        if v is None and not required:
            return []
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
            raise self.error(path, f"is a {_kind(v)}, expected a list of strings")
        return list(v)

    def mapping(self, d: dict, key: str, required: bool = False) -> dict:
        v = d.get(key)
        if v is None and not required:
            return {}
        if not isinstance(v, dict):
            raise self.error(key, "is missing" if v is None else f"is a {_kind(v)}, expected an object")
        return v
