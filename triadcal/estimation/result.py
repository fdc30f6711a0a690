"""The calibration result: values with units, saved and loaded as results-json v1.

The stable contract is docs/results-json.md (``format: triadcal.result``,
``version: 1``). A result can be applied to raw readings:
``A_IMU = Ca^-1 (K W - S)`` at the reading's temperature (seed paper, introduction).
"""

from __future__ import annotations

from ..errors import InputError

import math
import re
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
from scipy.special import ndtri

from ..io.atomic import read_json
from ..io.formats import require_format
from ..models.effects import BENCH_EFFECTS
from ..models.model import Covariates, Model
from ..models.sensor import ANGLE_NAMES, dcm
from ..models.units import ARCSEC, TO_INTERNAL
from .result_reader import (_NAME, ResultFormatError, _check_complete, _check_fit, _check_gates,  # noqa: F401
                            _check_intervals, _check_scale_units, _check_unit, _kind, _read_correlation,
                            _read_fixed, _read_uncertainty, _Reader)

#: the 97.5 % point of the standard normal: a 95 % two-sided interval is value +- Z95 u
Z95 = float(ndtri(0.975))

FORMAT = "triadcal.result"
#: the estimators that write results (docs/results-json.md)
METHODS = ("classical", "joint", "posterior")
VERSION = 1
#: the largest |value| or u a result may hold: its square (a variance) must be a finite double
MAX_MAGNITUDE = 1e150


#: the key of a result document's checksum of its own content (:func:`content_sha256`)
CONTENT_HASH_KEY = "content_sha256"


def content_sha256(d: dict) -> str:
    """SHA-256 of a result document without its ``content_sha256`` key, as canonical JSON (keys
    sorted, no whitespace, ASCII, non-finite numbers as null, each number as Python's shortest
    round-trip repr). ``save`` writes it; :meth:`CalibrationResult.from_dict` refuses a document
    whose content no longer matches it: a value, a unit, a u or the reference temperature edited
    after the fit is not the fit's answer (an outside probe: reference_temperature_C changed from
    20 to 25 in a saved result was certified and exported, K_x 69 u off at the stated 25 degC; K_x
    x 1000 and a u of 1e-12 were accepted). It guards against accidental and careless edits, not
    against forgery (anyone can recompute it); a document without it (another writer, or triadcal
    before 2026-11-30) is read as before. :meth:`CalibrationResult.from_dict` records a mismatch
    (``content_mismatch``) and every consumer refuses the result for it, after the reasons its
    fields give; the certificate lists it in its refusal report."""
    import hashlib
    import json

    from ..io.atomic import json_text

    body = json.loads(json_text({k: v for k, v in d.items() if k != CONTENT_HASH_KEY}, None))
    canon = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    return hashlib.sha256(canon.encode("ascii")).hexdigest()


def _check_content_hash(r, d: dict) -> Optional[str]:
    """Refuse (one line, the field named) a ``content_sha256`` that is not a SHA-256; the reason, for
    the consumers, when it does not match the document's content (:func:`content_sha256`); None when
    it matches or is absent. The consumers (:func:`.result_checks.result_problems`) refuse such a
    document after the reasons its fields give, so that a value the gates reject is named."""
    if CONTENT_HASH_KEY not in d:
        return None
    sha = d[CONTENT_HASH_KEY]
    if not (isinstance(sha, str) and re.fullmatch(r"[0-9a-f]{64}", sha)):
        raise r.error(CONTENT_HASH_KEY, f"= {sha!r} is not a SHA-256 (64 lowercase hex digits)")
    if content_sha256(d) != sha:
        return ("content_sha256 does not match the result's content: the file was changed after triadcal wrote it "
                "(a hand edit, a merge, a tool that rewrote its numbers), so its values are not the fit's answer; "
                "refit the data, or restore the file")
    return None


@dataclass
class ParameterValue:
    """A value with its standard uncertainty (k = 1) in ``unit``.

    With a lab file's systematic errors (:mod:`triadcal.uncertainty.typeb`), ``u`` is the
    combined standard uncertainty and ``uncertainty`` holds the rest of the budget: ``u_type_a``,
    ``U``, ``k``, ``coverage_probability``, ``dof_eff``, ``U_method`` and ``budget`` (the rows,
    docs/results-json.md); empty when the uncertainty is Type A only."""

    value: float
    u: float
    unit: str
    uncertainty: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"value": float(self.value), "u": float(self.u), "unit": self.unit, **self.uncertainty}

    @property
    def U(self) -> Optional[float]:
        """The expanded uncertainty when the budget gave one."""
        return self.uncertainty.get("U")


@dataclass
class CalibrationResult:
    """A calibration of one unit, in reporting units (arcsec, ppm, g, degC, ...).

    ``correlation`` (optional) is the correlation matrix of the parameters named in
    ``correlation_names``; ``fit`` holds chi2/dof, counts and estimator details;
    ``notes`` carry anything the reader must know (identifiability, priors).
    """

    unit: str
    method: str
    parameters: dict
    status: str = "ok"
    effects: tuple = ()
    reference_temperature_C: float = 20.0
    temperature_range_C: Optional[tuple] = None
    intervals: dict = field(default_factory=dict)
    fit: dict = field(default_factory=dict)
    correlation_names: tuple = ()
    correlation: Optional[np.ndarray] = None
    notes: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)
    #: set by :meth:`from_dict` when the document's content_sha256 does not match its content (the
    #: reason, one line); the consumers' checks (:func:`.result_checks.result_problems`) refuse it,
    #: after the reasons they find in the fields themselves. Not written.
    content_mismatch: Optional[str] = field(default=None, compare=False, repr=False)
    #: set by :meth:`from_dict` when the document holds no content_sha256 (another writer, or triadcal
    #: before 2026-11-30): read as before, but a certificate is refused for it (nothing shows that its
    #: values are the fit's answer). Not written.
    content_unhashed: bool = field(default=False, compare=False, repr=False)

    # -- access --------------------------------------------------------------------
    def __getitem__(self, name: str) -> ParameterValue:
        return self.parameters[name]

    def values(self) -> dict:
        return {k: v.value for k, v in self.parameters.items()}

    def covariance(self, names: Sequence[str]) -> np.ndarray:
        """Covariance (reporting units) of ``names``; uncorrelated where no correlation is known.
        A null (not finite) correlation of a parameter whose u is 0 gives covariance 0 (the only
        place the reader lets a null through, :func:`_read_correlation`)."""
        u = np.array([self.parameters[n].u for n in names])
        R = np.eye(len(names))
        if self.correlation is not None:
            index = {n: i for i, n in enumerate(self.correlation_names)}
            for i, a in enumerate(names):
                for j, b in enumerate(names):
                    if a in index and b in index:
                        c = self.correlation[index[a], index[b]]
                        R[i, j] = 0.0 if not math.isfinite(c) and (u[i] == 0 or u[j] == 0) else c
        return R * np.outer(u, u)

    def budget_rows(self) -> list:
        """Every row of every parameter's uncertainty budget (dicts, as the results JSON's ``budget``)."""
        return [r for p in self.parameters.values() for r in (p.uncertainty.get("budget") or [])
                if isinstance(r, dict)]

    def holds_type_b(self) -> bool:
        """Whether the budgets hold the lab's systematic errors (a Type B row): it was fitted with a lab
        file. A U alone does not say so: a fit whose noise is estimated from its residuals carries U on
        Student's t with its Type A row only (estimation/joint.py, ``noise_dof``)."""
        return any(r.get("type") == "B" for r in self.budget_rows())

    # -- JSON ----------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = {
            "format": FORMAT, "version": VERSION, "unit": self.unit, "method": self.method,
            "status": self.status, "effects": list(self.effects),
            "reference_temperature_C": self.reference_temperature_C,
            "temperature_range_C": None if self.temperature_range_C is None else list(self.temperature_range_C),
            "parameters": {k: v.to_dict() for k, v in self.parameters.items()},
            "intervals": self.intervals, "fit": self.fit, "notes": list(self.notes),
        }
        if self.correlation is not None:
            d["correlation"] = {"names": list(self.correlation_names),
                                "matrix": np.round(np.asarray(self.correlation), 6).tolist()}
        d.update({k: v for k, v in self.extra.items() if k != CONTENT_HASH_KEY})   # recomputed by save
        if "output_unit" not in d:
            # a result built without it (a test's, a library user's): K's own unit names it
            held = (d.get("fixed") or {}).get("K_x")
            k_unit = getattr(self.parameters.get("K_x"), "unit", "") or (
                held.get("unit", "") if isinstance(held, dict) else "")
            if isinstance(k_unit, str) and k_unit.startswith("g/") and len(k_unit) > 2:
                d["output_unit"] = k_unit[2:]
        g = d.get("local_g_m_s2")
        if isinstance(g, (int, float)) and math.isfinite(g):
            from ..io.bench_csv import LOCAL_G_RANGE_M_S2 as G_RANGE

            if not G_RANGE[0] <= g <= G_RANGE[1]:
                # only data that stated an override reach a fit with such a g (the bench CSV reader,
                # fit-raw --local-g-override): the reader refuses one without the flag
                d["local_g_override"] = True
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "<dict>") -> "CalibrationResult":
        """Read a results-json v1 document, validating every field it uses: a
        :class:`ResultFormatError` (one line, naming ``source`` and the JSON path of the field)
        for a wrong type, a missing key, an unknown unit, a unit other than the one the parameter
        is written in, a result that lacks a parameter of its own model, an expanded uncertainty
        that is not k u, a correlation matrix that is not one, and the other violations of the
        schema in docs/results-json.md. ``null`` where a number is expected means "not finite"
        (the writer turns NaN and infinities into null) and is read as NaN: the answer gates of a
        consumer (:func:`~triadcal.estimation.gates.check_result_for_use`) then refuse it by name."""
        require_format(d, FORMAT, VERSION, source, "a calibration result", "result")
        known = {"format", "version", "unit", "method", "status", "effects", "reference_temperature_C",
                 "temperature_range_C", "parameters", "intervals", "fit", "notes", "correlation"}
        r = _Reader(source)
        serial = r.string(d, "unit")
        if not serial.strip():
            # the serial is what compare, history and the certificate identify the unit by: two results
            # with "" compared to a verdict (an outside probe); the bench CSV reader refuses an empty one
            raise r.error("unit", "is empty: the result names no unit (serial number), so nothing can tell "
                                  "whose calibration it is")
        method = r.string(d, "method")
        if method not in METHODS:
            raise r.error("method", f"{method!r} is not one of {', '.join(METHODS)}")
        status = r.string(d, "status")
        from .gates import STATUSES
        if status not in STATUSES:
            raise r.error("status", f"{status!r} is not one of {', '.join(STATUSES)}")
        for key in ("effects", "temperature_range_C", "intervals", "fit", "notes"):
            if key not in d:        # every result this package writes has them (to_dict)
                raise r.error(key, "is missing (a required key of a result; docs/results-json.md)")
        effects = tuple(r.string_list(d, "effects", required=False))
        from ..models.effects import EFFECTS

        unknown = [e for e in effects if e not in EFFECTS]
        if unknown:
            raise r.error("effects", f"{', '.join(map(repr, unknown))} is not an effect of the model "
                                     f"({', '.join(EFFECTS)})")
        if "output_unit" not in d:
            # every result this package writes names it; K is in g per it, so without it a consumer (a
            # compensation table, a history) could not say what K multiplies (an outside probe deleted it)
            raise r.error("output_unit", "is missing: the unit of the outputs K is per (a required key of a result)")
        output_unit = r.optional_string(d, "output_unit")
        if output_unit is not None and not output_unit.strip():
            raise r.error("output_unit", "is empty: K would be in 'g/' of nothing")
        r.optional_string(d, "input_unit")
        if d.get("source") is not None and not isinstance(d["source"], str):
            raise r.error("source", f"is a {_kind(d['source'])}, expected a string or null")
        for key in ("local_g_stated", "reference_temperature_stated"):
            if key in d and not isinstance(d[key], bool):
                raise r.error(key, f"is a {_kind(d[key])}, expected true or false")
        for key in ("data_sha256", "derived_from_sha256"):
            sha = d.get(key)
            if sha is not None and not (isinstance(sha, str) and re.fullmatch(r"[0-9a-f]{64}", sha)):
                raise r.error(key, f"= {sha!r} is not a SHA-256 (64 lowercase hex digits)")
        g = d.get("local_g_m_s2")
        if g is not None:
            g = r.number_value(g, "local_g_m_s2")
            if not (math.isfinite(g) and g > 0):
                raise r.error("local_g_m_s2", f"= {g!r} is not a positive acceleration in m/s^2")
            from ..io.bench_csv import LOCAL_G_RANGE_M_S2 as G_RANGE

            if not G_RANGE[0] <= g <= G_RANGE[1] and d.get("local_g_override") is not True:
                # an outside probe: 98.0665 (m/s^2 and g mixed up) went into a compensation table and a history
                raise r.error("local_g_m_s2", f"= {g:g} m/s^2 is outside {G_RANGE[0]}-{G_RANGE[1]} (Earth's surface) and "
                                              "the result records no override (local_g_override, which a fit of "
                                              "data that stated one writes): K is in g of this value")
        params = {}
        for k, v in r.mapping(d, "parameters", required=True).items():
            where = f"parameters.{k}"
            if not _NAME.match(k):
                raise r.error(where, "is not a parameter name (a letter, then letters, digits and _)")
            if not isinstance(v, dict):
                raise r.error(where, f"is a {_kind(v)}, expected an object with value, u and unit")
            unit = r.string(v, "unit", where)
            if unit not in TO_INTERNAL and not unit.startswith("g/"):
                raise r.error(f"{where}.unit", f"{unit!r} is not a unit this triadcal knows")
            _check_unit(r, k, unit, output_unit, f"{where}.unit")
            value, u = r.number(v, "value", where), r.number(v, "u", where)
            if u < 0:
                raise r.error(f"{where}.u", f"= {u!r} is negative (a standard uncertainty is >= 0)")
            for key, x in (("value", value), ("u", u)):
                if abs(x) > MAX_MAGNITUDE:      # its square (a variance) overflows a double
                    raise r.error(f"{where}.{key}", f"= {x!r} is beyond {MAX_MAGNITUDE:g}: not a measured quantity "
                                                    "(its square, a variance, is not a finite number)")
            params[k] = ParameterValue(value, u, unit, _read_uncertainty(r, v, where, u))
        if not params:
            raise r.error("parameters", "is empty: the result holds no parameters")
        _check_scale_units(r, params)
        fixed = _read_fixed(r, d, output_unit)
        unidentifiable = d.get("unidentifiable")
        if unidentifiable is not None and not (isinstance(unidentifiable, dict)
                                               and all(isinstance(x, str) for x in unidentifiable.values())):
            raise r.error("unidentifiable", f"is a {_kind(unidentifiable)}, expected an object "
                                            "parameter -> reason (a string)")
        fit = r.mapping(d, "fit")
        _check_fit(r, fit)
        _check_complete(r, method, effects, params, fixed, unidentifiable or {}, fit)
        names, matrix = _read_correlation(r, d.get("correlation"), params)
        trange = d.get("temperature_range_C")
        if trange is not None:
            if not (isinstance(trange, list) and len(trange) == 2):
                raise r.error("temperature_range_C", "is not a list [low, high]")
            trange = tuple(r.number_value(x, f"temperature_range_C[{i}]") for i, x in enumerate(trange))
            for i, x in enumerate(trange):
                if not math.isfinite(x):
                    # an outside probe's [null, 70] printed "Temperature range nan degC to 70.0 degC"
                    raise r.error(f"temperature_range_C[{i}]", "is null: the range is two temperatures (degC); a "
                                                                "result without one has temperature_range_C null")
            if trange[0] > trange[1]:
                raise r.error("temperature_range_C", f"= [{trange[0]:g}, {trange[1]:g}]: low is above high "
                                                     "(the range is [lowest, highest] temperature in the data)")
        if "reference_temperature_C" not in d:
            # read as 20 degC before: a result fitted at 55 degC was then compared and certified as at 20
            raise r.error("reference_temperature_C", "is missing: the temperature the values are at (a required key "
                                                     "of a result)")
        ref = d["reference_temperature_C"]
        intervals = r.mapping(d, "intervals")
        _check_intervals(r, intervals)
        _check_gates(r, d.get("gates"), "gates" in d)
        if status == "ok" and "gates" not in d:
            raise r.error("gates", "is missing: status 'ok' is what the answer gates give, and a result that records "
                                   "none cannot show it passed them")
        if status == "ok":
            failed = [f"{o['gate']} ({o['status']})" for o in d["gates"]["outcomes"] if o["passed"] is False]
            if failed:
                raise r.error("status", f"is 'ok' but the result records its gate {', '.join(failed)} as failed: "
                                        "a failing gate gives its own status, never 'ok'")
        mismatch = _check_content_hash(r, d)
        return cls(
            unit=serial, method=method, parameters=params, status=status, effects=effects,
            reference_temperature_C=r.number_value(ref, "reference_temperature_C"),
            temperature_range_C=trange, intervals=intervals, fit=fit,
            correlation_names=names, correlation=matrix,
            notes=r.string_list(d, "notes", required=False), extra={k: v for k, v in d.items() if k not in known},
            content_mismatch=mismatch, content_unhashed=CONTENT_HASH_KEY not in d)

    def save(self, path) -> None:
        """Write results-json v1 atomically; a non-finite number is written as null; with the
        document's own checksum (:func:`content_sha256`), which every reader checks."""
        from ..io.atomic import atomic_write_json

        d = self.to_dict()
        d[CONTENT_HASH_KEY] = content_sha256(d)
        atomic_write_json(path, d)

    @classmethod
    def load(cls, path) -> "CalibrationResult":
        """Read and validate a results-json v1 file (:meth:`from_dict`); one-line errors."""
        return cls.from_dict(read_json(path), str(path))

    # -- applying the calibration -------------------------------------------------
    def model(self) -> Model:
        """The model whose parameters this result holds (effects that act on the readings)."""
        return Model([e for e in self.effects if e not in BENCH_EFFECTS],
                     self.reference_temperature_C)

    def full_model(self) -> tuple[Model, dict]:
        """The full model of this result (bench tilt included) and its internal parameter values.

        Parameters held fixed in the fit (``extra["fixed"]``) take their fixed value; the
        derived ``tilt_delta``/``tilt_beta`` are not model parameters and are left out.
        """
        model = Model(self.effects, self.reference_temperature_C)
        fixed = {k: v.get("value", 0.0) if isinstance(v, dict) else float(v)
                 for k, v in (self.extra.get("fixed") or {}).items()}
        values = {}
        for n in model.names:
            if n in self.parameters:
                values[n] = self.parameters[n].value
            elif n in fixed:
                values[n] = fixed[n]
        return model, model.to_internal(values)

    def angles_at(self, temperature_C, branch: float = 0.0) -> dict:
        """Orientation angles (arcsec) of the fitted model at the given temperatures (all three
        sensors at ``temperature_C``, °C) on a hysteresis branch (+1 cooling, -1 heating, 0
        mid-line; :data:`triadcal.models.effects.hysteresis.BRANCH`)."""
        model, p = self.full_model()
        T = np.asarray(temperature_C, float)
        z = np.zeros_like(T)
        cov = Covariates(axis1=z, axis2=z, temp=(T, T, T), temp_rate=(z, z, z),
                         branch=np.full_like(T, branch), time_s=z)
        _, _, angles = model.terms(p, cov)
        return {ab: np.broadcast_to(np.asarray(angles[ab], float), T.shape) / ARCSEC for ab in ANGLE_NAMES}

    def apply(self, w, temperature_C) -> np.ndarray:
        """Calibrated acceleration in the IMU frame (g): ``A_IMU = Ca^-1 (K W - S)``.

        ``w`` (n, 3) raw outputs, ``temperature_C`` (n, 3) or (n,) the accelerometers'
        temperatures. Thermal terms are evaluated at the reading's temperature, on the
        mid-line of the hysteresis loop (the branch of a reading is not known); a
        second-order or asymmetric transfer is inverted by its effect (Effect.inverse_transfer).
        A warm-up after power-on (``bias_warmup``, ``scale_warmup``) is taken as settled: its
        offsets are not applied (the time since power-on of a reading is not an input here).
        """
        w = np.atleast_2d(np.asarray(w, float))
        T = np.asarray(temperature_C, float)
        T = np.broadcast_to(T[:, None] if T.ndim == 1 else T, w.shape)
        model = self.model()
        missing = [n for n in model.names if n not in self.parameters]
        if missing:
            raise InputError(f"result lacks parameters {missing} of its own model {model!r}")
        settled = {s.name for s in model.parameters
                   if s.effect in ("bias_warmup", "scale_warmup") and not s.name.endswith("_tau")}
        p = model.to_internal({n: 0.0 if n in settled else self.parameters[n].value for n in model.names})
        zeros = np.zeros(len(w))
        cov = Covariates(axis1=zeros, axis2=zeros, temp=tuple(T[:, i] for i in range(3)),
                         temp_rate=(zeros, zeros, zeros), branch=zeros, time_s=zeros)
        K, S, angles = model.terms(p, cov)
        responded = tuple(w[:, i] * K[i] - S[i] for i in range(3))
        sensed = np.stack(model.inverse_transfer(p, cov, responded), axis=1)   # each effect's own inverse
        Ca = np.array([[np.broadcast_to(np.asarray(x, float), (len(w),)) for x in row]
                       for row in dcm(angles)])  # (3, 3, n)
        return np.linalg.solve(np.moveaxis(Ca, -1, 0), sensed[..., None])[..., 0]

    def matrix(self) -> np.ndarray:
        """Ca at the reference temperature (mid-line), 3x3."""
        from ..models.units import ARCSEC
        angles = {k[3:]: self.parameters[k].value * ARCSEC for k in self.parameters
                  if k.startswith("Ca_") and len(k) == 5}
        return np.array(dcm(angles), float)


def significant(x: float, digits: int) -> str:
    """``x`` to ``digits`` significant digits, halves rounded up (an uncertainty is never
    understated by its rounding, GUM 7.2.6): 30.5 -> "31", 15.25 -> "15.3"."""
    if x == 0 or not math.isfinite(x):
        return f"{x:g}"
    from decimal import ROUND_HALF_UP, Decimal

    d = Decimal(repr(abs(x)))
    q = Decimal(1).scaleb(d.adjusted() - digits + 1)
    r = d.quantize(q, rounding=ROUND_HALF_UP)
    if r.adjusted() > d.adjusted():                  # 9.96 -> 10.0: one digit fewer after the point
        r = r.quantize(q.scaleb(1), rounding=ROUND_HALF_UP)
    text = f"{r:f}"
    return ("-" if x < 0 else "") + text


def round_to_uncertainty(value: float, u: float, digits: int = 2) -> tuple[str, str]:
    """Value and uncertainty as strings, ``u`` to ``digits`` significant digits (GUM 7.2.6)."""
    if not (u > 0 and math.isfinite(u)):
        return f"{value:.6g}", f"{u:g}"
    exponent = math.floor(math.log10(u)) - (digits - 1)
    if round(u / 10.0 ** exponent) >= 10 ** digits:   # u rounds up to a power of ten: 0.0996 -> 0.10
        exponent += 1
    decimals = max(0, -exponent)
    q = 10.0 ** exponent
    u_r = round(u / q) * q
    v_r = round(value / q) * q
    return f"{v_r:.{decimals}f}", f"{u_r:.{decimals}f}"
