"""Drifts from a published table (the seed paper's Table 3 format) judged with a stated
measurement uncertainty.
"""

from __future__ import annotations
from ...errors import InputError
import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence
import numpy as np
from scipy import stats
from ...io.numbers import parse_number
from ...io.atomic import read_json
from .rule import EN_COVERAGE_FACTOR, check_tolerance, decide, drift_uncertainty, probability_exceeds, rule_text
from .results import ANGLES, ComparisonResult, MAX_ANGLE_ARCSEC, ParameterDrift, _opt_float
from .pair import NEGATIVE_RHO_REASON, joint_test, overall_verdict
from .sequence import SequenceComparison


@dataclass
class PublishedDrift:
    """One published drift: exposure, sensor, angle (``Ca_xy``), value and uncertainties (arcsec)."""

    exposure: str
    sensor: str
    angle: str
    drift_arcsec: float
    u_measurement_arcsec: Optional[float] = None
    u_drift_arcsec: Optional[float] = None


def angle_name(text: str) -> str:
    """``xY``, ``xy``, ``Ca_xy`` -> ``Ca_xy`` (row axis, then the IMU axis it tilts toward)."""
    s = text.strip()
    s = s[3:] if s.lower().startswith("ca_") else s
    name = f"Ca_{s.lower()}"
    if name not in ANGLES:
        raise InputError(f"unknown angle {text!r}: expected one of {', '.join(ANGLES)} (or the paper's xY form)")
    return name


def read_published_table(path) -> list[PublishedDrift]:
    """Published drifts from CSV (header ``exposure,sensor,angle,drift_arcsec[,u_arcsec|u_drift_arcsec]``,
    ``#`` comments) or JSON (``{"drifts": [{...same keys...}]}`` or a list)."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        data = read_json(path)
        rows = data.get("drifts") if isinstance(data, dict) else data
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise InputError(f"{path}: expected a list of drift objects (or {{\"drifts\": [...]}})")
        start = None
    else:
        try:
            text = path.read_bytes().decode("utf-8")
        except UnicodeDecodeError as exc:
            raise InputError(f"{path}: not UTF-8 text (byte {exc.start})") from None
        lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
        rows = list(csv.DictReader(lines))
        start = 2
    out = []
    for i, row in enumerate(rows):
        where = f"{path}:row {i + 1}" if start is None else f"{path}: data row {i + 1}"
        if None in row:
            raise InputError(f"{where}: more fields than the header names")
        if start is None:
            # JSON carries numbers as numbers: a string "50" (or true) is not a drift; CSV cells are text
            bad = [k for k in ("drift_arcsec", "u_arcsec", "u_drift_arcsec")
                   if row.get(k) is not None and (isinstance(row[k], bool) or not isinstance(row[k], (int, float)))]
            if bad:
                raise InputError(f"{where}: {bad[0]} = {row[bad[0]]!r:.40} is not a JSON number")
        row = {str(k).strip(): (v.strip() if isinstance(v, str) else v) for k, v in row.items() if k}
        if row.get("u_arcsec") not in (None, "") and row.get("u_drift_arcsec") not in (None, ""):
            raise InputError(f"{where}: both u_arcsec ({row['u_arcsec']}) and u_drift_arcsec ({row['u_drift_arcsec']}) "
                             "are given: u_arcsec is the uncertainty of each angle measurement, u_drift_arcsec that "
                             "of the drift; give one")
        missing = [k for k in ("exposure", "angle", "drift_arcsec") if row.get(k) in (None, "")]
        if missing:
            raise InputError(f"{where}: missing {', '.join(missing)} (columns: exposure, sensor, angle, "
                             "drift_arcsec, optional u_arcsec or u_drift_arcsec)")
        try:
            out.append(PublishedDrift(
                exposure=str(row["exposure"]), sensor=str(row.get("sensor") or ""), angle=angle_name(str(row["angle"])),
                drift_arcsec=parse_number(row["drift_arcsec"], low=-MAX_ANGLE_ARCSEC, high=MAX_ANGLE_ARCSEC,
                                          what="drift_arcsec"),
                u_measurement_arcsec=_opt_float(row.get("u_arcsec"), "u_arcsec"),
                u_drift_arcsec=_opt_float(row.get("u_drift_arcsec"), "u_drift_arcsec")))
        except ValueError as exc:
            raise InputError(f"{where}: {exc}") from None
    if not out:
        raise InputError(f"{path}: no drifts in the table")
    return out


def judge_published(rows: Sequence[PublishedDrift], *, u_measurement_arcsec: Optional[float] = None,
                    tolerance_arcsec: Optional[float] = 30.0, correlation: float = 0.0,
                    level: float = 0.95) -> SequenceComparison:
    """Judge published drifts (``triadcal compare --published``) by the same rule.

    Each drift is the difference of two angle measurements with standard uncertainty
    ``u_measurement_arcsec`` each (a row's ``u_measurement_arcsec`` overrides it; a row's
    ``u_drift_arcsec`` gives u(d) directly), so ``u(d) = u_m sqrt(2 (1 - rho))``. Drifts of
    one exposure form one comparison (parameters ``sensor.Ca_xy``), joint test over them
    with a diagonal covariance. Returns a :class:`SequenceComparison` whose ``steps`` are the
    exposures in table order (``kind="published"``; what the table's drifts are relative to
    is the publication's business).
    """
    if not -1.0 <= correlation <= 1.0:
        raise InputError(f"correlation must lie in [-1, 1], got {correlation}")
    if correlation < 0:
        raise InputError(f"correlation = {correlation:g}: {NEGATIVE_RHO_REASON}")
    if tolerance_arcsec is not None:
        tolerance_arcsec = check_tolerance(tolerance_arcsec, "the angles' tolerance (arcsec)")
    if u_measurement_arcsec is not None and not (isinstance(u_measurement_arcsec, (int, float))
                                                 and not isinstance(u_measurement_arcsec, bool)
                                                 and math.isfinite(u_measurement_arcsec) and u_measurement_arcsec > 0):
        raise InputError(f"the uncertainty of each angle measurement (--u-arcsec) = {u_measurement_arcsec!r} is not a "
                         "finite number > 0")
    exposures = list(dict.fromkeys(r.exposure for r in rows))
    comps = []
    for e in exposures:
        params = {}
        for r in (r for r in rows if r.exposure == e):
            key = f"{r.sensor}.{r.angle}" if r.sensor else r.angle
            if key in params:
                raise InputError(f"exposure {e!r}: {key} appears twice")
            um = r.u_measurement_arcsec if r.u_measurement_arcsec is not None else u_measurement_arcsec
            if r.u_drift_arcsec is not None:
                u = r.u_drift_arcsec
                um = u / math.sqrt(2 * (1 - correlation)) if correlation < 1 else None
            elif um is not None:
                u = drift_uncertainty(um, um, correlation)
            else:
                raise InputError(f"exposure {e!r}, {key}: no uncertainty; give u_arcsec per angle measurement "
                                 "(--u-arcsec) or u_drift_arcsec in the table")
            d = r.drift_arcsec
            verdict, significant = decide(d, u, tolerance_arcsec, level)
            z = d / u if u > 0 else (math.inf if d else 0.0)
            params[key] = ParameterDrift(
                name=key, unit="arcsec", drift=d, u=u, u_before=um, u_after=um, rho=correlation,
                tolerance=tolerance_arcsec, En=abs(d) / (EN_COVERAGE_FACTOR * u) if u > 0 else math.inf, z=z,
                p_value=float(2 * stats.norm.sf(abs(z))), significant=significant,
                p_exceeds=probability_exceeds(d, u, tolerance_arcsec), verdict=verdict, basis="published")
        names = list(params)
        drift = np.array([params[n].drift for n in names])
        joint = joint_test(drift, np.diag([params[n].u ** 2 for n in names]), names, level)
        comps.append(ComparisonResult(
            parameters=params, overall=overall_verdict(params, joint, tolerance_arcsec),
            rule=rule_text(level, tolerance_arcsec), level=level, tolerance_arcsec=tolerance_arcsec,
            correlation={"rho": correlation, "source": "stated",
                         "reason": (f"rho = {correlation:g}: published drifts carry no covariance; each drift is "
                                    "the difference of two measurements whose errors (eq. 4: output noise, "
                                    "bench positioning sigma_1 and wobble sigma_2, all random per measurement) "
                                    "are independent unless stated otherwise")},
            joint=joint, label=e))
    return SequenceComparison(labels=exposures, steps=comps, cumulative=[], kind="published",
                              rule=comps[0].rule)
