"""A comparison's content (per-parameter drifts, the joint test, the overall verdict) and its
``triadcal.comparison`` JSON, read back field by field (docs/results-json.md).
"""

from __future__ import annotations
from ...errors import InputError
import math
from dataclasses import dataclass, field
from typing import Mapping, Optional
import numpy as np
from scipy import stats
from ...io.atomic import atomic_write_json
from ...io.formats import require_format
from ...io.numbers import parse_number
from ...models import effects
from ...models.sensor import ANGLE_NAMES
from ...io.atomic import read_json
from .rule import EN_COVERAGE_FACTOR, VERDICTS, coverage_factors, decide, probability_exceeds, verdict_from_probability


FORMAT = "triadcal.comparison"


SEQUENCE_FORMAT = "triadcal.comparison_sequence"


VERSION = 1


#: the six orientation angles of eq. 1, in the order of results-json
ANGLES = tuple(f"Ca_{ab}" for ab in ANGLE_NAMES)


#: how a parameter's verdict was reached: the rule on (drift, u), on posterior draws, on a published row
BASES = ("normal", "posterior", "published")


#: properties of the bench, not of the unit: compared as a check, never judged
#: (the model's bench parameters, and the tilt's polar form (delta, beta) a result reports)
BENCH_PARAMETERS = effects.BENCH_PARAMETERS + ("tilt_delta", "tilt_beta")


@dataclass
class ParameterDrift:
    """Drift of one parameter between two calibrations, and its verdict."""

    name: str
    unit: str
    drift: float
    u: float
    before: Optional[float] = None
    after: Optional[float] = None
    u_before: Optional[float] = None
    u_after: Optional[float] = None
    rho: float = 0.0
    tolerance: Optional[float] = None
    En: float = float("nan")
    z: float = float("nan")
    p_value: float = float("nan")
    significant: bool = False
    p_exceeds: Optional[float] = None
    verdict: str = "inconclusive"
    basis: str = "normal"
    n_draws: Optional[int] = None
    judged: bool = True
    #: a bias of the drift known only to lie within +-bound (the unmeasured tempcos of rows apart,
    #: ``compare.tempco_bound``), taken at its worst by the rule (:func:`.rule.decide`)
    bound: float = 0.0
    #: the verdict the rule gives from these numbers was held back as inconclusive by compare (it
    #: differed at the correlation the budgets support, or with the bench's errors not shared; a note says
    #: which): a reader accepts "inconclusive" for it, nothing else
    held_back: bool = False

    @property
    def U(self) -> float:
        """Expanded uncertainty of the drift, k = 2."""
        return EN_COVERAGE_FACTOR * self.u

    def to_dict(self) -> dict:
        d = {"drift": self.drift, "u": self.u, "unit": self.unit, "U": self.U, "k": EN_COVERAGE_FACTOR,
             "En": self.En, "z": self.z, "p_value": self.p_value, "significant": self.significant,
             "tolerance": self.tolerance, "p_exceeds": self.p_exceeds, "verdict": self.verdict,
             "basis": self.basis, "rho": self.rho, "judged": self.judged}
        for k in ("before", "after", "u_before", "u_after", "n_draws"):
            if getattr(self, k) is not None:
                d[k] = getattr(self, k)
        if self.bound > 0:
            d["tempco_bound"] = self.bound
        if self.held_back:
            d["held_back"] = True
        return {k: _finite(v) for k, v in d.items()}

    @classmethod
    def from_dict(cls, name: str, d: Mapping, source: str = "<dict>") -> "ParameterDrift":
        where = f"{source}: parameters.{name}"
        if not isinstance(d, Mapping):
            raise InputError(f"{where} is not an object")
        num = _Fields(where, d)
        if d.get("verdict") not in VERDICTS:
            raise InputError(f"{where}.verdict {d.get('verdict')!r} is not one of {VERDICTS}")
        if not isinstance(d.get("unit"), str):
            raise InputError(f"{where}.unit is missing or not a string")
        for key in ("significant", "judged", "held_back"):
            if d.get(key) is not None and not isinstance(d[key], bool):
                raise InputError(f"{where}.{key} = {d[key]!r:.40} is not true/false")
        if name.rsplit(".", 1)[-1] in ANGLES:
            # an angle is in arcsec and always judged (docs/compare.md): a report prints both
            if d["unit"] != "arcsec":
                raise InputError(f"{where}.unit {d['unit']!r}: an angle's drift is in 'arcsec'")
            if d.get("judged") is False:
                raise InputError(f"{where}.judged is false: an angle is always judged")
        if d.get("U") is not None:
            k = num.req("k", low=0.0) if d.get("k") is not None else EN_COVERAGE_FACTOR
            U, u = num.req("U", low=0.0), num.req("u", low=0.0)
            if not math.isclose(U, k * u, rel_tol=1e-9, abs_tol=1e-300):
                raise InputError(f"{where}.U = {U:.6g} is not k u(d) = {k:g} x {u:.6g}")
        return cls(name=name, unit=d["unit"], drift=num.req("drift"), u=num.req("u", low=0.0),
                   before=num.opt("before"), after=num.opt("after"), u_before=num.opt("u_before", low=0.0),
                   u_after=num.opt("u_after", low=0.0), rho=num.opt("rho", -1.0, 1.0, default=0.0),
                   tolerance=num.opt("tolerance", low=0.0), En=num.nan("En"), z=num.nan("z"),
                   p_value=num.nan("p_value"), significant=bool(d.get("significant", False)),
                   p_exceeds=num.opt("p_exceeds", 0.0, 1.0), verdict=d["verdict"], basis=str(d.get("basis", "normal")),
                   n_draws=None if d.get("n_draws") is None else int(num.req("n_draws", low=0.0)),
                   judged=bool(d.get("judged", True)), bound=num.opt("tempco_bound", low=0.0, default=0.0),
                   held_back=d.get("held_back") is True)


class _Fields:
    """Numbers of a JSON object with one-line errors naming the field (``null`` is "not finite")."""

    def __init__(self, where: str, d: Mapping):
        self.where, self.d = where, d

    def _check(self, key, v, low, high):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InputError(f"{self.where}.{key} = {v!r:.40} is not a finite number")
        if not low <= v <= high:
            raise InputError(f"{self.where}.{key} = {v!r} is outside [{low:g}, {high:g}]")
        return float(v)

    def req(self, key, low=-math.inf, high=math.inf) -> float:
        return self._check(key, self.d.get(key), low, high)

    def opt(self, key, low=-math.inf, high=math.inf, default=None):
        v = self.d.get(key)
        return default if v is None else self._check(key, v, low, high)

    def nan(self, key) -> float:
        v = self.d.get(key)
        return float("nan") if v is None else self._check(key, v, -math.inf, math.inf)


@dataclass
class JointTest:
    """Mahalanobis distance of the angle-drift vector against chi^2 with ``dof`` degrees of freedom."""

    names: tuple
    D2: float
    dof: int
    p_value: float
    significant: bool
    level: float

    def to_dict(self) -> dict:
        return {"names": list(self.names), "D2": self.D2, "dof": self.dof, "p_value": self.p_value,
                "significant": self.significant, "level": self.level,
                "critical": float(stats.chi2.ppf(self.level, self.dof))}

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "<dict>") -> "JointTest":
        num = _Fields(f"{source}: joint", d)
        names = d.get("names")
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise InputError(f"{source}: joint.names is not a list of names")
        D2, dof, p = num.req("D2", low=0.0), int(num.req("dof", low=1.0)), num.req("p_value", 0.0, 1.0)
        level = num.req("level", 0.0, 1.0)
        significant = d.get("significant")
        if not isinstance(significant, bool):
            raise InputError(f"{source}: joint.significant is missing or not true/false")
        # the stored numbers must give the stored decision (a report prints both)
        p_calc = float(stats.chi2.sf(D2, dof))
        if not math.isclose(p, p_calc, rel_tol=1e-6, abs_tol=1e-300):
            raise InputError(f"{source}: joint.p_value = {p:.6g} but chi2({dof}).sf(D2 = {D2:.6g}) = {p_calc:.6g}")
        if significant != (p < 1 - level):
            raise InputError(f"{source}: joint.significant = {str(significant).lower()} contradicts p = {p:.3g} "
                             f"at level {level:g}")
        return cls(tuple(names), D2, dof, p, significant, level)


@dataclass
class ComparisonResult:
    """Drifts of a unit between two calibrations (results-json ``triadcal.comparison`` v1)."""

    parameters: dict
    overall: str
    rule: str
    level: float = 0.95
    tolerance_arcsec: Optional[float] = 30.0
    tolerances: dict = field(default_factory=dict)
    correlation: dict = field(default_factory=dict)
    joint: Optional[JointTest] = None
    bench_check: dict = field(default_factory=dict)
    before: dict = field(default_factory=dict)
    after: dict = field(default_factory=dict)
    label: Optional[str] = None
    notes: list = field(default_factory=list)
    #: the overall verdict the rule gives was held back as inconclusive (a note says why)
    held_back: bool = False

    def __getitem__(self, name: str) -> ParameterDrift:
        return self.parameters[name]

    def verdicts(self) -> dict:
        return {k: p.verdict for k, p in self.parameters.items()}

    def failing(self, judged_only: bool = True) -> list:
        """Names whose verdict is fail (by default only the judged ones: angles and parameters
        given a tolerance; the others' verdict is a significance test only)."""
        return [k for k, p in self.parameters.items() if p.verdict == "fail" and (p.judged or not judged_only)]

    def to_dict(self) -> dict:
        d = {"format": FORMAT, "version": VERSION, "rule": self.rule, "level": self.level,
             "tolerance": {"angles_arcsec": self.tolerance_arcsec, **self.tolerances},
             "parameters": {k: p.to_dict() for k, p in self.parameters.items()},
             "joint": None if self.joint is None else self.joint.to_dict(),
             "correlation": self.correlation, "bench_check": self.bench_check,
             "before": self.before, "after": self.after, "overall": self.overall, "notes": list(self.notes)}
        if self.label is not None:
            d["label"] = self.label
        if self.held_back:
            d["held_back"] = True
        return d

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "<dict>") -> "ComparisonResult":
        require_format(d, FORMAT, VERSION, source, "a comparison", "comparison")
        if not isinstance(d.get("parameters"), Mapping) or not d["parameters"]:
            raise InputError(f"{source}: parameters is missing or empty")
        if not isinstance(d.get("rule"), str):
            raise InputError(f"{source}: rule is missing or not a string")
        for key in ("tolerance", "correlation", "bench_check", "before", "after"):
            if d.get(key) is not None and not isinstance(d[key], Mapping):
                raise InputError(f"{source}: {key} is not an object")
        if d.get("notes") is not None and not isinstance(d["notes"], list):
            raise InputError(f"{source}: notes is not a list")
        for side in ("before", "after"):
            carried = (d.get(side) or {}).get("rows_carried_to_C")
            if carried is not None:
                if not isinstance(carried, Mapping) or sorted(carried) != ["x", "y", "z"]:
                    raise InputError(f"{source}: {side}.rows_carried_to_C is not a mapping of x, y and z to degC")
                for a in "xyz":
                    _Fields(f"{source}: {side}.rows_carried_to_C", carried).req(a, -100.0, 200.0)
        level = _Fields(f"{source}: comparison", d).opt("level", 0.0, 1.0, default=0.95)
        if d.get("overall") not in VERDICTS:
            raise InputError(f"{source}: overall verdict {d.get('overall')!r} is not one of {VERDICTS}")
        tol = dict(d.get("tolerance") or {})
        angles_tol = tol.pop("angles_arcsec", None)
        try:
            coverage_factors(level)
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None
        if angles_tol is not None:
            angles_tol = _Fields(f"{source}: tolerance", {"angles_arcsec": angles_tol}).req("angles_arcsec", low=0.0)
        params = {k: ParameterDrift.from_dict(k, p, source) for k, p in d["parameters"].items()}
        for k, p in params.items():
            check_verdict(p, level, source, significance_stated=d["parameters"][k].get("significant") is not None)
        if d["overall"] == "pass" and any(p.verdict == "fail" and p.judged for p in params.values()):
            raise InputError(f"{source}: overall verdict 'pass' contradicts a judged parameter whose verdict is 'fail'")
        joint = None if not d.get("joint") else JointTest.from_dict(d["joint"], source)
        from .pair import overall_verdict

        expected = overall_verdict(params, joint, angles_tol)
        # a pass must be the rule's (compare may hold a pass back as inconclusive, with a note: a same
        # calibration, an angle missing on one side), a fail the rule gives must be stated, and a fail
        # must not contradict a rule's pass
        stored = d["overall"]
        # two fits of one data set (the same data_sha256 before and after) are inconclusive whatever
        # the rule gives: their difference is the estimators', not the unit's
        from .pair import shared_sha256

        sha_b = shared_sha256(*[d[k] if isinstance(d.get(k), dict) else {} for k in ("before", "after")])
        one_data = bool(sha_b)
        if one_data and stored != "inconclusive":
            raise InputError(f"{source}: overall verdict {stored!r}, but before and after are two fits of the same "
                             f"data (data_sha256 {sha_b}): the verdict of such a pair is 'inconclusive'")
        if d.get("held_back") is not None and not isinstance(d["held_back"], bool):
            raise InputError(f"{source}: held_back = {d['held_back']!r:.40} is not true/false")
        # compare held the rule's verdict back as inconclusive (its note says why): nothing else is accepted
        held = d.get("held_back") is True and stored == "inconclusive"
        if not one_data and not held and ((stored == "pass" and expected != "pass") or (expected == "fail" and stored != "fail")
                             or (stored == "fail" and expected == "pass")):
            raise InputError(f"{source}: overall verdict {d['overall']!r} contradicts the per-parameter verdicts and "
                             f"the joint test, from which the rule gives {expected!r}")
        return cls(parameters=params,
                   overall=d["overall"], rule=d["rule"], level=level,
                   tolerance_arcsec=angles_tol, tolerances=tol, correlation=d.get("correlation", {}),
                   joint=joint,
                   bench_check=d.get("bench_check", {}), before=d.get("before", {}),
                   after=d.get("after", {}), label=d.get("label"), notes=list(d.get("notes", [])),
                   held_back=d.get("held_back") is True)

    def save(self, path) -> None:
        _save_json(self.to_dict(), path)

    @classmethod
    def load(cls, path) -> "ComparisonResult":
        return cls.from_dict(_load_json(path), str(path))


def check_verdict(p: ParameterDrift, level: float, source: str = "<dict>", significance_stated: bool = True) -> None:
    """Refuse a stored verdict (or significance) that the decision rule (:mod:`.rule`) does not
    give from the parameter's own numbers: drift, u(d), tolerance and, for a verdict on
    posterior draws, P(|d| > T). A report prints the verdict next to the numbers; they must agree.
    ``significance_stated``: False when the file does not state ``significant`` (nothing to check;
    a report then prints none)."""
    where = f"{source}: parameters.{p.name}"
    if p.basis not in BASES:
        raise InputError(f"{where}.basis {p.basis!r} is not one of {BASES}")
    if p.bound > 0 and p.basis != "normal":
        raise InputError(f"{where}: tempco_bound = {p.bound:.6g} on a {p.basis} verdict (a bound is judged on "
                         "drift and u(d) only)")
    T = "none" if p.tolerance is None else f"{p.tolerance:g}"
    if p.basis == "posterior":
        if p.tolerance is not None and p.p_exceeds is None:
            raise InputError(f"{where}: a posterior verdict against T = {T} needs p_exceeds")
        if p.tolerance is None and not significance_stated:
            raise InputError(f"{where}: a posterior verdict without a tolerance needs significant")
        expected = verdict_from_probability(p.p_exceeds, p.significant, p.tolerance, level)
        numbers = f"P(|d| > T) = {p.p_exceeds}, significant = {str(p.significant).lower()}, T = {T}"
    else:
        expected, significant = decide(p.drift, p.u, p.tolerance, level, p.bound)
        numbers = (f"drift = {p.drift:.6g}, u(d) = {p.u:.6g}, T = {T}"
                   + (f", tempco_bound = {p.bound:.6g}" if p.bound > 0 else ""))
        if significance_stated and significant != p.significant:
            raise InputError(f"{where}.significant = {str(p.significant).lower()} contradicts its numbers "
                             f"({numbers}, level {level:g}): the rule gives {str(significant).lower()}")
        if p.tolerance is not None and p.p_exceeds is not None:
            pe = probability_exceeds(p.drift, p.u, p.tolerance, p.bound)
            if not math.isclose(p.p_exceeds, pe, rel_tol=1e-6, abs_tol=1e-9):
                raise InputError(f"{where}.p_exceeds = {p.p_exceeds:.6g} contradicts its numbers ({numbers}): "
                                 f"P(|d| > T) = {pe:.6g}")
    if expected != p.verdict and not (p.held_back and p.verdict == "inconclusive"):
        raise InputError(f"{where}.verdict {p.verdict!r} contradicts its numbers ({numbers}, level {level:g}): "
                         f"the decision rule gives {expected!r}")


def _finite(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (np.floating,)):
        return _finite(float(v))
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def _num(v) -> float:
    return float("nan") if v is None else float(v)


MAX_ANGLE_ARCSEC = 1_296_000.0   # 360 deg: no drift of an angle is larger


def _opt_float(v, what: str = "value") -> Optional[float]:
    """An optional uncertainty of a published row: empty or absent is None; otherwise a finite
    number in (0, 360 deg] (arcsec)."""
    if v is None or v == "":
        return None
    return parse_number(v, low=0.0, high=MAX_ANGLE_ARCSEC, low_open=True, what=what)


def _save_json(d: dict, path) -> None:
    atomic_write_json(path, d)


def _load_json(path) -> dict:
    return read_json(path)
