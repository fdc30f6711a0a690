"""A stepped calibration plan and its predicted uncertainty (``triadcal plan``, docs/plan.md).

A plan is a sequence of chamber setpoints (each with its direction: the first ``none``, then
``heating`` or ``cooling``), a set of bench positions visited at every setpoint, the dwell
(averaging time) ``tau_s`` of a visit and the number of repetitions of the position set.

Chamber time (the hours rule, stated in docs/plan.md)::

    per setpoint:  |T_i - T_(i-1)| / rate  +  settle_s  +  n_positions * repetitions * (move_s + tau_s)

with ``T_0`` the ambient start (20 degC), ``rate`` the chamber's ramp rate (1 degC/min),
``settle_s`` = 6300 s (the example's soak: 7200 s for its 15 degC steps at 1 degC/min is a
15-minute ramp plus 6300 s) and ``move_s`` = 20 s (the simulator's bench move and settle).

Predicted uncertainty (the Fisher information of the model on the plan): the plan's
covariates are those the simulator builds (:func:`triadcal.models.simulate.simulate_campaign`,
same thermal history), the residual Jacobian is the joint fit's
(:class:`triadcal.estimation.joint.JointProblem`) at the preset unit's parameter values, each
visit's output variance is ``Q / tau_s`` plus the lab's random bench errors
(:func:`triadcal.models.effects.position_error.bench_variance`), so ``C_A = (J^T W J)^-1``; on
oblique poses, where the bench's errors correlate a visit's outputs, ``W`` is the inverse of each
visit's full 3 x 3 covariance (``covariance_blocks``), as in the fit's GLS;
the lab's systematic errors add ``C_B`` (:func:`triadcal.uncertainty.typeb.propagate`, the
fit's own algebra) and ``U = 2 sqrt(diag(C_A + C_B))``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping, Optional, Sequence

import numpy as np

from ..errors import InputError
from ..models.campaign import DEFAULT_PLAN
from ..models.effects import DEFAULT_EFFECTS
from ..models.simulate import NoiseModel, Schedule, preset_truth, simulate_campaign

#: the positions a plan chooses from: the 12 of bench CSV v1 (gravity along +-X, +-Y, +-Z), and
#: 6 or 12 more with gravity along a face diagonal of the IMU frame (two axes at 45 deg)
DIAGONALS = {
    "D01": (90.0, 45.0), "D02": (90.0, 225.0),     # +X+Y, -X-Y
    "D03": (135.0, 90.0), "D04": (135.0, 270.0),   # +X+Z, -X-Z
    "D05": (0.0, 315.0), "D06": (0.0, 135.0),      # +Y+Z, -Y-Z
    "D07": (90.0, 135.0), "D08": (90.0, 315.0),    # +X-Y, -X+Y
    "D09": (45.0, 90.0), "D10": (45.0, 270.0),     # +X-Z, -X+Z
    "D11": (0.0, 45.0), "D12": (0.0, 225.0),       # +Y-Z, -Y+Z
}
POSITION_SETS = {
    12: dict(DEFAULT_PLAN),
    18: {**DEFAULT_PLAN, **{k: DIAGONALS[k] for k in ("D01", "D02", "D03", "D04", "D05", "D06")}},
    24: {**DEFAULT_PLAN, **DIAGONALS},
}

AMBIENT_C = 20.0
SETTLE_S = 6300.0
MOVE_S = 20.0
CHAMBER_RATE_C_PER_MIN = 1.0
#: the example campaign's white-noise intensity (its ``# Q_V2s`` line)
DEFAULT_Q_V2S = 3e-9
HOURS_CAP = 200.0
#: the temperature readings' noise of a visit (degC; the simulator's ``NoiseModel.temp_noise_C``)
READING_NOISE_C = 0.01
FORMAT = "triadcal.plan"


@dataclass
class Plan:
    """A stepped plan (see the module). ``positions``: label -> (axis1_deg, axis2_deg)."""

    setpoints_C: tuple
    positions: dict = field(default_factory=lambda: dict(DEFAULT_PLAN))
    tau_s: float = 30.0
    repetitions: int = 1
    start_C: float = AMBIENT_C
    chamber_rate_C_per_min: float = CHAMBER_RATE_C_PER_MIN
    settle_s: float = SETTLE_S
    move_s: float = MOVE_S
    soak_s: Optional[tuple] = None       # per setpoint; None: the hours rule (ramp + settle)
    name: str = ""
    effects: Optional[tuple] = None      # the model the plan was made for (its document's predicted.effects)

    def soaks(self) -> list:
        if self.soak_s is not None:
            return [float(s) for s in self.soak_s]
        out, prev = [], self.start_C
        for sp in self.setpoints_C:
            out.append(abs(sp - prev) / self.chamber_rate_C_per_min * 60.0 + self.settle_s)
            prev = sp
        return out

    def schedule(self) -> Schedule:
        return Schedule(setpoints_C=tuple(float(s) for s in self.setpoints_C), start_C=self.start_C,
                        soak_s=self.settle_s, tau_s=float(self.tau_s), move_s=self.move_s,
                        soak_each_s=tuple(self.soaks()))

    def directions(self) -> list:
        return self.schedule().directions()

    def visit_positions(self) -> dict:
        """The positions as visited at each setpoint: the set, repeated ``repetitions`` times
        (labels ``P01``, then ``P01-2`` ...)."""
        out = {}
        for r in range(int(self.repetitions)):
            for k, v in self.positions.items():
                out[k if r == 0 else f"{k}-{r + 1}"] = v
        return out

    @property
    def n_visits(self) -> int:
        return len(self.setpoints_C) * len(self.positions) * int(self.repetitions)

    def chamber_hours(self) -> float:
        per_visit = self.move_s + self.tau_s
        return (sum(self.soaks()) + self.n_visits * per_visit) / 3600.0

    def to_dict(self, predicted: Optional[dict] = None) -> dict:
        soaks = self.soaks()
        d = {"format": FORMAT, "version": 1, "name": self.name,
             "start_C": self.start_C, "chamber_rate_C_per_min": self.chamber_rate_C_per_min,
             "settle_s": self.settle_s, "move_s": self.move_s, "tau_s": float(self.tau_s),
             "repetitions": int(self.repetitions),
             "setpoints": [{"setpoint_C": float(sp), "direction": d, "soak_s": s}
                           for sp, d, s in zip(self.setpoints_C, self.directions(), soaks)],
             "positions": [{"label": k, "axis1_deg": a1, "axis2_deg": a2} for k, (a1, a2) in self.positions.items()],
             "n_visits": self.n_visits, "chamber_hours": self.chamber_hours()}
        if predicted is not None:
            d["predicted"] = predicted
        return d

    def save(self, path, predicted: Optional[dict] = None) -> None:
        from ..io.atomic import atomic_write_json

        atomic_write_json(path, self.to_dict(predicted))

    @classmethod
    def from_dict(cls, d: Mapping, source: str = "plan") -> "Plan":
        """A plan from its document, every field checked (:func:`.plan_fields.check_plan_fields`),
        the directions and the visit count against the plan built."""
        from .plan_fields import check_plan_fields, check_totals, plan_effects

        if not isinstance(d, Mapping) or d.get("format") != FORMAT or d.get("version") != 1:
            got = (d.get("format"), d.get("version")) if isinstance(d, Mapping) else (type(d).__name__, None)
            raise InputError(f"{source}: not a {FORMAT} version 1 document (format={got[0]!r}, version={got[1]!r})")
        check_plan_fields(d, source)
        effects = plan_effects(d, source)
        try:
            sps = d["setpoints"]
            plan = cls(setpoints_C=tuple(float(s["setpoint_C"]) for s in sps),
                       positions={str(p["label"]): (float(p["axis1_deg"]), float(p["axis2_deg"]))
                                  for p in d["positions"]},
                       tau_s=float(d["tau_s"]), repetitions=int(d.get("repetitions", 1)),
                       start_C=float(d.get("start_C", AMBIENT_C)),
                       chamber_rate_C_per_min=float(d.get("chamber_rate_C_per_min", CHAMBER_RATE_C_PER_MIN)),
                       settle_s=float(d.get("settle_s", SETTLE_S)), move_s=float(d.get("move_s", MOVE_S)),
                       soak_s=tuple(float(s["soak_s"]) for s in sps), name=str(d.get("name", "")),
                       effects=effects)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: a plan needs setpoints (setpoint_C, soak_s), positions (label, "
                             f"axis1_deg, axis2_deg) and tau_s: {exc!r}") from None
        for k, (s, want) in enumerate(zip(d["setpoints"], plan.directions())):
            if "direction" in s and s["direction"] != want:
                first = (f"; the unit soaked at start_C {plan.start_C:g} degC reaches {float(s['setpoint_C']):g} degC by "
                         f"{want}, so it is on that branch, not the mid-line (plans written before 2026-12-01 said "
                         "'none' here: plan again)" if k == 0 and s["direction"] == "none" else "")
                raise InputError(f"{source}: field setpoints[{k}].direction: {s['direction']!r}, but the sequence of "
                                 f"setpoints makes it {want!r} (the direction is the sequence's, not a choice){first}")
        if "n_visits" in d and d["n_visits"] != plan.n_visits:
            raise InputError(f"{source}: field n_visits: {d['n_visits']!r}, but the plan's setpoints, positions and "
                             f"repetitions make {plan.n_visits} (an edited plan?)")
        check_totals(d, plan, source)
        return plan

    @classmethod
    def load(cls, path) -> "Plan":
        from ..io.atomic import read_json

        return cls.from_dict(read_json(path), str(path))


def example_plan() -> Plan:
    """The example campaign's plan (examples/data/campaign.csv): 12 positions x 15 setpoints,
    -40..+70 degC, 7200 s soak at every setpoint, tau 30 s: 32.5 chamber hours."""
    from ..models.simulate import STANDARD_SETPOINTS_C

    return Plan(setpoints_C=STANDARD_SETPOINTS_C, tau_s=30.0, soak_s=(7200.0,) * len(STANDARD_SETPOINTS_C),
                name="example: 12 positions x 15 setpoints")


# ---------------------------------------------------------------------------------------
# the Fisher information of the model on a plan
# ---------------------------------------------------------------------------------------
@dataclass
class Design:
    """What the prediction needs of one plan at reps = 1: the raw Jacobian of the outputs
    (3n x p, output unit per reporting unit), the bench variance per output (n, 3), the Type B
    data changes (one (n, 3) array per systematic source) and the names."""

    plan: Plan
    names: tuple
    units: dict
    J: np.ndarray
    var_bench: np.ndarray
    F: list
    sources: list
    values: dict
    problems: dict
    #: the bench's full 3 x 3 covariance per visit (n, 3, 3; output unit^2) when it correlates a visit's
    #: outputs (oblique poses; the fit is then GLS on it, estimation/whitening.py), else None
    bench_blocks: Optional[np.ndarray] = None
    #: the largest rate of the unit's temperature over the visits (degC/s, the simulated covariates)
    max_rate_C_per_s: float = float("nan")
    #: effects the model leaves out that this schedule cannot show: {effect: the smallest fraction of
    #: its signature outside the model's span} below ``structure.DRIFT_VISIBLE_MIN`` (:func:`blind_to`)
    blind: dict = field(default_factory=dict)
    #: the effect of each parameter of the model (name -> effect name) and the value the fit holds a
    #: parameter it cannot estimate at (its nominal value, ``fit_joint``)
    effect_of: dict = field(default_factory=dict)
    nominal: dict = field(default_factory=dict)
    typical: dict = field(default_factory=dict)
    #: the columns of the Jacobian (3n,) of the held parameters (``problems``), as ``J``: what a held
    #: parameter moves (:func:`held_sensitivity`)
    J_held: dict = field(default_factory=dict)


def _model_and_sources(effects, lab, output_unit="V"):
    from ..models.model import Model
    from ..uncertainty.typeb import effects_with_lab, systematic_sources

    sources = systematic_sources(lab, output_unit)
    effects, _ = effects_with_lab(effects, sources)
    if "bench_nonorthogonality" in effects:
        sources = [s for s in sources if s.kind != "axes_nonorthogonality"]
    return Model(effects), tuple(effects), sources


def design(plan: Plan, effects: Sequence[str] = DEFAULT_EFFECTS, lab=None, preset: str = "ak18-quartz",
           hold: Optional[Mapping] = None) -> Design:
    """Covariates, Jacobian and bench variance of ``plan`` (its position set once per setpoint;
    repetitions multiply the information, :func:`predict`). ``plan`` may also be a
    :class:`triadcal.planning.ramp.RampPlan` (its visits as simulated, repetitions 1).

    The parameters the plan cannot determine are held, as the fit holds them
    (:func:`triadcal.estimation.joint.fit_joint`): those of ``identifiability_problems`` on the
    simulated covariates, then those in the null space of the Jacobian probed, as the fit probes
    it, at a generic point (effect terms at their typical size); ``hold`` (name -> reason) adds
    more (:func:`undetermined_time_constants`)."""
    from ..estimation.joint import JointProblem, identifiability_problems, null_space_problems, parameter_unit
    from ..io.lab import bench_errors_of
    from ..estimation.whitening import NEGLIGIBLE_CORRELATION
    from ..models.effects.position_error import bench_variance, covariance_blocks
    from ..uncertainty.typeb import data_change

    model, effects, sources = _model_and_sources(effects, lab)
    truth = preset_truth(preset, [e for e in effects if e != "bench_nonorthogonality"],
                         noise=NoiseModel(Q_V2s=DEFAULT_Q_V2S, temp_noise_C=0.0))
    once = plan.once() if hasattr(plan, "once") else replace(plan, repetitions=1)
    campaign = simulate_campaign(truth, once.visit_positions(), once.schedule(), seed=0)
    values = {n: float(truth.parameters.get(n, model.spec[n].nominal)) for n in model.names}
    problems = identifiability_problems(campaign, model)
    problems.update({k: str(v) for k, v in (hold or {}).items() if k in values})
    fixed = {k: values[k] for k in problems}
    prob = JointProblem(campaign, model, np.ones((campaign.n_visits, 3)), fixed)
    # the fit's probe of the null space: core terms at their values, effect terms at their typical size
    x0 = np.array([values[n] if model.spec[n].effect == "core" else model.spec[n].typical for n in prob.names])
    _, J0 = prob.residuals_and_jacobian(x0)
    if np.all(np.isfinite(J0)):
        problems.update(null_space_problems(J0, prob.names))
    x = np.array([values[n] for n in prob.names])
    _, Jr = prob.residuals_and_jacobian(x)
    problems.update(null_space_problems(Jr, prob.names))
    if set(problems) - set(fixed):
        fixed = {k: values[k] for k in problems}
        prob = JointProblem(campaign, model, np.ones((campaign.n_visits, 3)), fixed)
        x = np.array([values[n] for n in prob.names])
        _, Jr = prob.residuals_and_jacobian(x)
    J = -Jr                                                  # d W / d x, (3n, p) visit-major
    p_int = model.to_internal(values)
    cov = campaign.covariates()
    bench = bench_errors_of(lab) if lab is not None else None
    var_b = (bench_variance(model, p_int, cov, campaign.gravity_g, bench.sigma_position_arcsec,
                            bench.sigma_wobble_arcsec) if bench is not None else np.zeros((campaign.n_visits, 3)))
    blocks = None
    if bench is not None:
        s1, s2 = bench.sigma_position_arcsec, bench.sigma_wobble_arcsec
        C = covariance_blocks(model, p_int, cov, campaign.gravity_g, weights=(s1 * s1, s1 * s1, s2 * s2))
        d = np.sqrt(np.maximum(np.diagonal(C, axis1=1, axis2=2), 1e-300))
        off = np.abs(C / (d[:, :, None] * d[:, None, :]) - np.eye(3)[None])
        blocks = C if float(np.max(off)) > NEGLIGIBLE_CORRELATION else None
    w = prob.predict(x)
    F = [data_change(s, model, p_int, cov, campaign.gravity_g, w, "V") for s in sources]
    units = {n: parameter_unit(model, n, "V") for n in model.names}
    rate = float(np.max(np.abs(campaign.temperature_rate()), initial=0.0))
    J_held = {}
    if problems:
        # every parameter free (the fit holds these, the data do not): their columns, at the values
        full = JointProblem(campaign, model, np.ones((campaign.n_visits, 3)), {})
        _, Jf = full.residuals_and_jacobian(np.array([values[n] for n in full.names]))
        J_held = {n: -Jf[:, full.names.index(n)] for n in problems if n in full.names}
    return Design(plan, prob.names, units, J, np.asarray(var_b), F, sources, values, problems, blocks, rate,
                  blind_to(campaign, J, prob.names), {n: model.spec[n].effect for n in model.names},
                  {n: float(model.spec[n].nominal) for n in model.names},
                  {n: float(model.spec[n].typical) for n in model.names}, J_held)


def blind_to(campaign, J: np.ndarray, names) -> dict:
    """The effects a model without them cannot see on this schedule: ``{"bias_drift" | "hysteresis":
    the smallest visible fraction over the outputs or angles}``, for those below
    ``structure.DRIFT_VISIBLE_MIN`` (estimation/structure.py: ``drift_confounding``,
    ``hysteresis_confounding``; the fit measures the same on the data and notes it). A schedule that
    visits no temperature twice puts a bias drift into the biases and their tempcos; one that visits
    none on both branches puts a hysteresis of the angles into the angle tempcos."""
    from ..estimation.structure import DRIFT_VISIBLE_MIN, drift_confounding, hysteresis_confounding

    u = np.ones(len(names))
    out = {}
    for effect, conf in (("bias_drift", drift_confounding(campaign, J, names, u)),
                         ("hysteresis", hysteresis_confounding(campaign, J, names, u))):
        if conf:
            worst = min(c["visible_fraction"] for c in conf.values())
            if worst < DRIFT_VISIBLE_MIN:
                out[effect] = float(worst)
    return out


def held_sensitivity(d: Design, Q_V2s: float, tau_s: Optional[float] = None) -> dict:
    """What holding a parameter the plan cannot estimate moves: ``{held name: (p,) array}``, the change
    of each estimated parameter (``d.names``, reporting units) per reporting unit of the held one's
    departure from the value it is held at. The fit of the plan, weighted as :func:`predict` (dwell
    ``tau_s``; repetitions do not change it), absorbs the held parameter's signature ``J_h dh`` into
    the estimated ones: ``dx = (J^T W J)^-1 J^T W J_h dh`` (e.g. K3 held on axis-aligned poses,
    where ``a^3 = a``: K moves by -1 ppm per ug/g3)."""
    if not d.J_held:
        return {}
    names = list(d.J_held)
    S = absorbed(d, np.stack([d.J_held[n] for n in names], axis=1), Q_V2s, tau_s)
    return {h: S[:, k] for k, h in enumerate(names)}


def predict(d: Design, Q_V2s: float, tau_s: Optional[float] = None, repetitions: Optional[int] = None) -> dict:
    """Predicted covariance of the design at dwell ``tau_s`` and ``repetitions``: returns
    ``{"names", "u_a", "u", "U", "cov"}`` (reporting units; U = 2 u)."""
    tau = d.plan.tau_s if tau_s is None else tau_s
    reps = d.plan.repetitions if repetitions is None else repetitions
    if d.bench_blocks is None:
        sigma = np.sqrt(Q_V2s / tau + d.var_bench).reshape(-1)
        Jw = d.J / sigma[:, None]
        Fw = [F.reshape(-1) / sigma for F in d.F]
    else:
        # GLS, as the fit on oblique poses: J and F whitened by each visit's Cholesky factor of
        # Q/tau I + C_bench
        n = d.bench_blocks.shape[0]
        L = np.linalg.cholesky(d.bench_blocks + (Q_V2s / tau) * np.eye(3)[None])
        Jw = np.linalg.solve(L, d.J.reshape(n, 3, -1)).reshape(d.J.shape)
        Fw = [np.linalg.solve(L, F.reshape(n, 3, 1)).reshape(-1) for F in d.F]
    s = np.sqrt(np.sum(Jw ** 2, axis=0))
    s[s == 0] = 1.0
    A = (Jw / s)
    C_one = np.linalg.pinv(A.T @ A) / np.outer(s, s)         # one pass of the position set
    C_a = C_one / reps
    C = C_a.copy()
    if d.sources:
        for src, F in zip(d.sources, Fw):
            c = -C_one @ (Jw.T @ F)                           # the fit's sensitivity, reps-invariant
            C += np.outer(c, c) * src.u ** 2
    u_a = np.sqrt(np.diag(C_a))
    u = np.sqrt(np.diag(C))
    return {"names": d.names, "u_a": u_a, "u": u, "U": 2.0 * u, "cov": C}


def undetermined_time_constants(d: Design, Q_V2s: float, tau_s: float, repetitions: int,
                                at_rest: bool = False) -> dict:
    """Time constants of the model (``estimation.gates.TIME_CONSTANTS``: ``thermal_lag``, ...)
    that the plan of ``d`` cannot determine even at dwell ``tau_s`` and ``repetitions`` (pass the
    most informative of the search): the predicted u is not below the value, which the fit's
    ``time_constants_determined`` gate refuses, or the value +- 2u leaves the range of the
    ``time_constants`` gate. name -> the reason (for ``assumptions.not_estimated``). A stepped
    plan's visits are at rest after the soak (temperature rates ~0), so it cannot determine a
    thermal lag; a ramp plan (``plan --ramp``) can.

    ``at_rest`` (a stepped plan): ``thermal_lag`` is held whatever the Fisher information says.
    The rates of a stepped plan's visits are the tail of the soak (at most ~0.004 degC/min over
    -40..85 degC), the fit takes them from central differences of 0.01 degC readings one visit
    (50-320 s) apart, whose noise (0.002-0.02 degC/min) is as large or larger: the information
    the noise-free simulated rates carry is not in a real campaign (errors in the covariate), and
    the fit of a planned stepped campaign estimates a lag of -3.6 +- 3.3 min for a true 4 and is
    refused (``time_constants`` gate)."""
    from ..estimation.gates import TIME_CONSTANTS, _tc_range

    names = list(d.names)
    todo = [n for n in names if n in TIME_CONSTANTS]
    if not todo:
        return {}
    out = {}
    lag = d.values.get("thermal_lag")
    if "thermal_lag" in todo and lag is not None and np.isfinite(d.max_rate_C_per_s):
        shift = d.max_rate_C_per_s * abs(lag) * 60.0            # the lag's whole effect on the element, degC
        if at_rest or shift < READING_NOISE_C:
            out["thermal_lag"] = (
                f"thermal lag needs temperatures that change during the visits: this plan's visits are at rest after "
                f"each soak (rates up to {d.max_rate_C_per_s * 60:.2g} degC/min, the tail of the soak), so a lag of "
                f"{lag:g} min moves the element's temperature by at most {shift:.2g} degC, of the order of the "
                f"{READING_NOISE_C:g} degC noise of the readings the fit takes the rate from; held, as the fit would "
                "hold it (a fit that estimates it is refused by the time_constants gate); a ramp plan "
                "(triadcal plan --ramp) can determine it")
            todo.remove("thermal_lag")
    if not todo:
        return out
    pred = predict(d, Q_V2s, tau_s, repetitions)
    for n in todo:
        v, u = d.values[n], float(pred["u"][names.index(n)])
        lo, hi, unit = _tc_range(n)
        if not (np.isfinite(u) and u < abs(v) and lo <= v - 2 * u and v + 2 * u <= hi):
            out[n] = (f"{TIME_CONSTANTS[n]} is not determined by this plan: predicted u = {u:.3g} {unit} for a value "
                      f"of {v:.3g} {unit} even at tau {tau_s:g} s x {repetitions} (the fit's time_constants gates "
                      "would refuse it); a stepped plan's visits are at rest after each soak (temperature rates ~0), "
                      "so it is held, as the fit would hold it; a ramp plan (triadcal plan --ramp) can determine it")
    return out


def left_out_signatures(plan, effects: Sequence[str] = DEFAULT_EFFECTS, lab=None,
                        preset: str = "ak18-quartz") -> dict:
    """What the effects of the unit the model leaves out would add to the outputs of ``plan``, at
    the preset unit's values: ``{effect: {"signature": (3n,) array (output unit, visit-major as
    :class:`Design` ``J``), "parameters": {name: (preset value, nominal, unit)}}}``, for every
    effect of the vocabulary that is not of the bench (``Effect.bench``: the lab's, not the unit's),
    not in the planned model and whose parameters the preset sets away from their nominal values.
    The signature is the change of the model's outputs on the plan's visits (same simulated
    covariates as :func:`design`) when the effect's parameters go from nominal to the preset's: for
    an effect linear in its parameters (the tempcos of any order, K2, K3, ...) the sum over its
    parameters of the Jacobian's column times the preset's value."""
    from ..estimation.joint import JointProblem
    from ..models.effects import EFFECTS
    from ..models.model import Model
    from ..models.simulate import PRESETS

    model, effs, _ = _model_and_sources(effects, lab)
    table = PRESETS.get(preset, {})
    full_model = Model(tuple(EFFECTS))
    left = []
    for e, cls in EFFECTS.items():
        if e in effs or cls.bench:
            continue
        ps = [n for n in full_model.names if full_model.spec[n].effect == e]
        if any(n in table and float(table[n]) != float(full_model.spec[n].nominal) for n in ps):
            left.append(e)
    if not left:
        return {}
    truth = preset_truth(preset, [e for e in effs if e != "bench_nonorthogonality"],
                         noise=NoiseModel(Q_V2s=DEFAULT_Q_V2S, temp_noise_C=0.0))
    once = plan.once() if hasattr(plan, "once") else replace(plan, repetitions=1)
    campaign = simulate_campaign(truth, once.visit_positions(), once.schedule(), seed=0)
    big = Model(tuple(effs) + tuple(left))
    prob = JointProblem(campaign, big, np.ones((campaign.n_visits, 3)), {})
    base = {n: float(truth.parameters.get(n, big.spec[n].nominal)) if big.spec[n].effect in effs
            else float(big.spec[n].nominal) for n in prob.names}
    x0 = np.array([base[n] for n in prob.names])
    w0 = prob.predict(x0)
    out = {}
    for e in left:
        ps = [n for n in prob.names if big.spec[n].effect == e]
        x = x0.copy()
        for n in ps:
            if n in table:
                x[prob.names.index(n)] = float(table[n])
        sig = (prob.predict(x) - w0).reshape(-1)
        if np.all(np.isfinite(sig)):
            out[e] = {"signature": sig,
                      "parameters": {n: (float(x[prob.names.index(n)]), float(big.spec[n].nominal), big.spec[n].unit)
                                     for n in ps}}
    return out


def absorbed(d: Design, H: np.ndarray, Q_V2s: float, tau_s: Optional[float] = None) -> np.ndarray:
    """The change of the estimated parameters (``d.names``, reporting units; (p, k)) when the data of
    the plan of ``d`` change by the columns of ``H`` (3n, k; output unit) that the model cannot
    represent: the fit, weighted as :func:`predict` (dwell ``tau_s``), absorbs them,
    ``dx = (J^T W J)^-1 J^T W H`` (:func:`held_sensitivity`, :func:`left_out` share it)."""
    tau = d.plan.tau_s if tau_s is None else tau_s
    if d.bench_blocks is None:
        sigma = np.sqrt(Q_V2s / tau + d.var_bench).reshape(-1)
        Jw, Hw = d.J / sigma[:, None], H / sigma[:, None]
    else:
        n = d.bench_blocks.shape[0]
        L = np.linalg.cholesky(d.bench_blocks + (Q_V2s / tau) * np.eye(3)[None])
        Jw = np.linalg.solve(L, d.J.reshape(n, 3, -1)).reshape(d.J.shape)
        Hw = np.linalg.solve(L, H.reshape(n, 3, -1)).reshape(H.shape)
    return np.linalg.lstsq(Jw, Hw, rcond=None)[0]
