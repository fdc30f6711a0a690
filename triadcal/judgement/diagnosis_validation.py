"""Validation of the diagnosis on campaigns whose effect is withheld (``triadcal validate-diagnosis``).

:func:`validate` simulates campaigns with each effect (and a clean condition) at one or more
magnitudes, fits the model without it and checks that :func:`diagnose` names it
(:func:`scenario`, :func:`run_case`, :class:`ValidationResult`). With ``left_out`` the same
campaign is diagnosed a second time with the effect and every candidate that legitimately
explains the same data (``LEFT_OUT_GROUPS``) removed from the candidate list: the right verdict
is then ``unexplained``. Its design (``DESIGN``, written into every validation file) is derived
in docs/diagnosis.md, "Validation".
"""

from __future__ import annotations

from ..errors import InputError

import contextlib
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from multiprocessing import get_context
from typing import Optional, Sequence

import numpy as np

from ..models.campaign import DEFAULT_PLAN
from ..models.effects import DEFAULT_EFFECTS, NOISE_EFFECTS, VOCABULARY
from ..models.simulate import NoiseModel, Schedule, preset_truth, simulate_campaign
from .diagnose import ALPHA, FORM_CANDIDATES, SIGNATURE, diagnose
from .diagnose.candidates import HYSTERESIS_FAMILY
from .validation_journal import job_key

VALIDATION_PLAN: dict = dict(DEFAULT_PLAN)
#: 16 oblique poses: 8 skew ones (gravity (+-0.5, +-0.71, +-0.5) g, every sign combination)
#: and 8 at 45 deg in the X-Z and X-Y planes
VALIDATION_PLAN.update({f"D{k + 1:02d}": pos for k, pos in enumerate(
    [(45.0, 45.0), (45.0, 135.0), (45.0, 225.0), (45.0, 315.0),
     (135.0, 45.0), (135.0, 135.0), (135.0, 225.0), (135.0, 315.0),
     (45.0, 90.0), (45.0, 270.0), (135.0, 90.0), (135.0, 270.0),   # X-Z plane
     (90.0, 45.0), (90.0, 135.0), (90.0, 225.0), (90.0, 315.0)])})  # X-Y plane
VALIDATION_SOAK_S = 1800.0
#: effects a stepped campaign cannot show, left out of its conditions: a warm-up after power-on
#: (tau_w of minutes) is over before the first visit, which follows the first 1800 s soak; a
#: diagnosis that names nothing there is right. They are validated on ramps (tests/test_warmup.py).
NOT_IN_STEPPED = ("bias_warmup", "scale_warmup")
CONDITIONS = ("clean",) + tuple(e for e in VOCABULARY if e not in NOT_IN_STEPPED)
NONE = "none"
UNEXPLAINED = "unexplained"   #: a structured gap that no candidate closes
#: magnitudes of the full validation: the preset's realistic one and half of it (``MAGNITUDE_DEFINITION``)
MAGNITUDES = (1.0, 0.5)

#: candidates that legitimately explain the same data as a withheld effect, left out of the
#: candidate list together with it in the left-out mode (docs/diagnosis.md, "Validation"):
#: the refit-only forms of the same mechanism, the other polynomial orders of the same
#: temperature coefficient (a cubic absorbs most of a missing linear term over -40..+70 degC,
#: and naming the wrong order still names the right quantity), the drift of the tilt the
#: model lacks (tilt_drift needs bench_tilt: r t from the campaign's start carries a constant
#: tilt's pattern), the two laws of a bias that changes in time (a warm-up whose time constant is
#: long against the campaign is a constant rate, b exp(-t/tau) ~ b - (b/tau) t, as with the tilt's
#: settling; a rate fits much of an exponential), and the two models of excess output scatter (a Student-t is a scale
#: mixture of normals, which is what per-visit positioning errors make of the residuals).
_FAMILIES = (
    ("bench_tilt", "tilt_drift", "tilt_settling"),
    HYSTERESIS_FAMILY,
    ("thermal_lag", "thermal_lag_history"),
    ("angle_tempco", "angle_tempco2", "angle_tempco3"),
    ("scale_tempco", "scale_tempco2", "scale_tempco3"),
    ("bias_tempco", "bias_tempco2", "bias_tempco3"),
    ("position_error", "heavy_tails"),
    ("bias_drift", "bias_warmup"),
)
#: the forms of one effect that name it (a first mechanism's verdict is right with either): the
#: history form of the thermal lag is the rate form's exact solution (the rate form is its first
#: order in tau), so on a campaign lagged over its whole history it may beat the rate form (by the
#: 99 % point, candidates._thermal_lag_history) and names the same lag. The hysteresis forms are
#: not here: a play is another law than the offset, not its exact form.
SAME_EFFECT = {"thermal_lag": ("thermal_lag", "thermal_lag_history")}
LEFT_OUT_GROUPS: dict = {}
for _fam in _FAMILIES:
    for _e in _fam:
        # a change of the tilt withheld leaves both its laws out (bench_tilt is in the model): a settling
        # of a long time constant is a constant rate, a rate fits much of a settling
        LEFT_OUT_GROUPS[_e] = ("tilt_drift", "tilt_settling") if _e in ("tilt_drift", "tilt_settling") else _fam


def left_out_group(effect: str) -> tuple:
    """Candidates removed from the list when ``effect`` is left out: itself and its group."""
    return tuple(dict.fromkeys((effect,) + tuple(LEFT_OUT_GROUPS.get(effect, ()))))


def condition_name(effect: str, magnitude: float) -> str:
    """Row label of a condition: the effect, with ``@m`` when the magnitude is not 1."""
    return effect if effect == "clean" or magnitude == 1.0 else f"{effect}@{magnitude:g}"


#: the validation's design in one paragraph (docs/diagnosis.md, "Validation" derives it)
DESIGN = ("ak18-quartz preset, DEFAULT_EFFECTS, VALIDATION_PLAN (28 poses), 15 setpoints with a 1800 s soak, "
          "Q = 3e-9 V^2 s, tau = 30 s, position error 5\"/2\", Student-t with 3 dof; each effect withheld at a "
          "realistic magnitude, the diagnosis must name it first")
#: how a magnitude m scales the withheld effect (written into every validation file)
MAGNITUDE_DEFINITION = ("magnitude m: every parameter of the withheld effect in the preset truth times m "
                        "(thermal_lag: its tau; bench_tilt: the tilt; tilt_settling: its offsets d, tau_s 4 h kept); "
                        "position_error: sigma_1 = 5\" m, "
                        "sigma_2 = 2\" m; heavy_tails: 1/nu = m/3 (nu = 3/m dof); flicker_noise: B_f = 3e-6 V m; "
                        "clean has no magnitude")
LEFT_OUT_DEFINITION = ("left-out mode: the same campaign diagnosed again with the withheld effect and its "
                       "group (LEFT_OUT_GROUPS) removed from the candidate list; right verdict 'unexplained'")


NOISE_ESTIMATED_DEFINITION = ("noise estimated: each campaign's noise columns removed before the diagnosis (no "
                              "sd_*, n_samples, u_w_* or Q_V2s), so that the white level is estimated from the "
                              "residuals; quantisation, which needs the declared noise, is untestable; "
                              "flicker_noise is tested with the white level profiled out")


def without_noise(campaign):
    """``campaign`` with no declared noise: its ``sd``, ``n_samples``, ``u_w`` and the ``Q_V2s``
    metadata line removed (a bench CSV without those columns), so the diagnosis estimates the level."""
    import dataclasses

    meta = {k: v for k, v in campaign.metadata.items() if k != "Q_V2s"}
    return dataclasses.replace(campaign, sd=None, n_samples=None, u_w=None, metadata=meta)


#: parameters of a withheld effect that the magnitude does not scale: the settling's time constant
#: (its size is the offsets d; a shorter tau_s would be another law, not a smaller one)
UNSCALED = ("tilt_settle_tau",)


def scenario(effect: str, preset: str = "ak18-quartz", magnitude: float = 1.0):
    """(truth, model effects) of the validation campaign that withholds ``effect`` ('clean': none)
    at ``magnitude`` (``MAGNITUDE_DEFINITION``: 1 is the preset's realistic magnitude). A second
    mechanism (``'hysteresis~2'``, :mod:`.second_mechanisms`) is checked by name only and gives
    (None, None): its campaign is made by :func:`~.second_mechanisms.second_campaign`."""
    from . import second_mechanisms as sm

    if sm.is_second(effect):
        sm.base_effect(effect)
        return None, None
    if effect != "clean" and effect not in VOCABULARY:
        raise InputError(f"unknown effect {effect!r}; choose from clean, {', '.join(VOCABULARY)}")
    m = float(magnitude)
    if not (m > 0 and np.isfinite(m)):
        raise InputError(f"the magnitude must be a positive number, not {magnitude!r}")
    noise = NoiseModel(sigma_position_arcsec=5.0 * m if effect == "position_error" else 0.0,
                       sigma_wobble_arcsec=2.0 * m if effect == "position_error" else 0.0,
                       heavy_tails_dof=3.0 / m if effect == "heavy_tails" else None)
    if effect == "flicker_noise" and hasattr(noise, "flicker_Bf"):
        noise.flicker_Bf = 3e-6 * m        # the simulator's default floor (api.simulate), about 3 ug
    truth_effects = tuple(DEFAULT_EFFECTS)
    if effect not in DEFAULT_EFFECTS and effect != "clean" and effect not in NOISE_EFFECTS:
        truth_effects = truth_effects + (effect,)
    model = tuple(e for e in DEFAULT_EFFECTS if e != effect)
    truth = preset_truth(preset, truth_effects, noise=noise)
    if m != 1.0 and effect != "clean" and effect not in NOISE_EFFECTS:
        from ..models.model import Model

        for spec in Model(truth.effects).parameters:
            if spec.effect == effect and spec.name not in UNSCALED:
                truth.parameters[spec.name] = float(truth.parameters[spec.name]) * m
    return truth, model


def run_case(effect: str, seed: int, preset: str = "ak18-quartz", n_draws: int = 200,
             cross_group: bool = False, top: int = 2, magnitude: float = 1.0, left_out: bool = False,
             noise_estimated: bool = False) -> dict:
    """Simulate, fit without ``effect``, diagnose; the row of the validation table.

    ``noise_estimated``: the campaign's declared noise removed first (:func:`without_noise`).

    With ``left_out`` (and an effect, not 'clean') the same campaign is diagnosed a second time
    with ``left_out_group(effect)`` removed from the candidates; the row then also holds
    ``left_out_verdict`` (right: 'unexplained'), ``left_out_first`` and ``left_out_seconds``. The
    left-out diagnosis redoes the slice tests after each refit (``slices_after``, as ``triadcal
    diagnose`` does): that is the guard that keeps a noise effect from being named while slices
    keep structure; without it position_error was named in 16 of 18 left-out diagnoses of a first run.
    """
    from . import second_mechanisms as sm

    second = sm.is_second(effect)
    base_effect = sm.base_effect(effect)
    if second:
        campaign, model = sm.second_campaign(base_effect, seed, magnitude, preset)
    else:
        truth, model = scenario(effect, preset, magnitude)
        campaign = simulate_campaign(truth, plan=VALIDATION_PLAN, schedule=Schedule(soak_s=VALIDATION_SOAK_S),
                                     seed=seed)
    if noise_estimated:
        campaign = without_noise(campaign)
    #: the verdicts that are right: the effect (none for clean), or any of its family for a second mechanism
    right = (sm.FAMILY[base_effect] if second else
             (NONE,) if effect == "clean" else SAME_EFFECT.get(effect, (effect,)))
    t0, c0 = time.perf_counter(), time.process_time()
    d = diagnose(campaign, model, n_draws=n_draws, cross_group=cross_group, slices_after=False, top=top,
                 seed=seed)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    named = d.verdict_effect
    ranked = d.ranked()
    after = None
    for c in d.candidates:
        if c.effect == named and c.refit:
            after = c.refit["gap_after"]["chi2_dof"]
    if d.verdict.get("effects"):              # named as a series of one tempco's orders: the series' gap
        after = next(c.refit["series"]["gap_after"]["chi2_dof"] for c in d.candidates
                     if c.refit and "series" in c.refit)
    where = d.where
    # localisation: the family of slices whose offsets explain most of the misfit (when
    # significant), and the most significant single slice below the whole-axis level
    local = [w for w in where if w.family != "axis"]
    fams = [f for f in d.families if f["log10_p"] < np.log10(ALPHA / max(len(d.families), 1))]
    top_family = fams[0]["family"] if fams else None
    expected = SIGNATURE.get(base_effect, ())
    row = {"effect": effect, "condition": condition_name(effect, magnitude),
           "magnitude": None if effect == "clean" else float(magnitude), "seed": seed, "verdict": named or NONE,
            "right": (named or NONE) in right, "right_verdicts": list(right),
            # 'unexplained' with a best partial answer: whether it closed the gap (then ambiguous with rivals)
            "best_partial": d.verdict.get("best_partial"), "gap_closed": d.verdict.get("gap_closed"),
            "first": ranked[0] if ranked else None,
            "rank_of_truth": min((ranked.index(e) + 1 for e in right if e in ranked), default=None),
            "gap_significant": d.gap["significant"], "chi2_dof_before": d.gap["chi2_dof"],
            "chi2_dof_after": after, "n_significant_slices": len(where), "top_slice": (local[0] if local else where[0]).slice if where else None,
            "top_slice_family": top_family,
            "localised": (top_family in expected) if expected else top_family is None,
            "noise_known": bool(d.noise_known), "seconds": seconds, "cpu_seconds": cpu}
    if left_out and effect != "clean":
        group = tuple(dict.fromkeys(left_out_group(base_effect) + (tuple(right) if second else ())))
        cands = [c for c in VOCABULARY + FORM_CANDIDATES if c not in group]
        t1, c1 = time.perf_counter(), time.process_time()
        dl = diagnose(campaign, model, candidates=cands, n_draws=n_draws, cross_group=cross_group,
                      slices_after=True, top=top, seed=seed)
        ranked_l = dl.ranked()
        row.update({"left_out": list(group), "left_out_verdict": dl.verdict_effect or NONE,
                    "left_out_first": ranked_l[0] if ranked_l else None,
                    # a named candidate with the gap still open says "more is missing": less confident
                    "left_out_gap_closed": dl.verdict.get("gap_closed"),
                    "left_out_reason": dl.verdict.get("reason") or dl.verdict.get("evidence"),
                    "left_out_seconds": time.perf_counter() - t1, "left_out_cpu_seconds": time.process_time() - c1})
    return row


def _run_star(args):
    return run_case(*args)


@dataclass
class ValidationResult:
    rows: list
    conditions: tuple                 # row labels: 'clean', the effects, 'effect@m' at magnitude m != 1
    labels: tuple                     # verdict columns: the vocabulary, the forms, 'unexplained' and 'none'
    seeds: int
    design: str = DESIGN
    seconds: float = 0.0
    summary: dict = field(default_factory=dict)
    magnitudes: tuple = (1.0,)
    left_out: bool = False            # each effect also diagnosed with its group left out
    noise_estimated: bool = False     # the campaigns' declared noise removed (without_noise)
    resumed: int = 0                  # rows taken from the journal of a stopped run (validate's journal_dir)

    @property
    def left_out_conditions(self) -> tuple:
        """Rows of the left-out block: every condition but 'clean' (nothing to leave out)."""
        return tuple(c for c in self.conditions if c != "clean") if self.left_out else ()

    def confusion(self, left_out: bool = False) -> np.ndarray:
        """Counts: rows the withheld effect (or clean), columns the verdict (labels). With
        ``left_out``: the verdicts of the left-out diagnoses (rows ``left_out_conditions``)."""
        conds = self.left_out_conditions if left_out else self.conditions
        M = np.zeros((len(conds), len(self.labels)), int)
        for r in self.rows:
            c = r.get("condition", r["effect"])
            if left_out:
                if c in conds and r.get("left_out_verdict") is not None:
                    M[conds.index(c), self.labels.index(r["left_out_verdict"])] += 1
            else:
                M[conds.index(c), self.labels.index(r["verdict"])] += 1
        return M

    def _block(self, left_out: bool) -> list:
        conds = self.left_out_conditions if left_out else self.conditions
        M = self.confusion(left_out)
        if not conds:           # e.g. only clean data: nothing is left out
            return ["(no effect condition: nothing was left out)"] if left_out else []
        # columns by number (the legend is :meth:`table`'s first line): verdict names cut to a
        # width repeated themselves (angle_tempco, angle_tempco2, angle_tempco3 were all "angle_tem")
        cw = max(3, len(str(len(self.labels))), len(str(int(M.max()) if M.size else 0)))
        w = max(len(c) for c in conds) + 1
        tail = ("   unexpl.  named, gap open  named, gap closed  left out with it" if left_out
                else "   correct  localised  chi2/dof after (range)")
        lines = [" " * w + " ".join(f"{j + 1:>{cw}}" for j in range(len(self.labels))) + tail]
        for i, c in enumerate(conds):
            s = self.summary[c]
            if left_out:
                extra = (f"   {s['unexplained_rate']:6.0%}   {s['left_out_named_gap_open_rate']:14.0%}   "
                         f"{s['left_out_confident_wrong_rate']:16.0%}   "
                         + (",".join(e for e in s["left_out_group"] if e != s["effect"]) or "-"))
            else:
                rng = s["chi2_dof_after_range"]
                extra = (f"   {s['correct_rate']:6.0%}   {s['localised_rate']:7.0%}    "
                         + (f"[{rng[0]:.2f}, {rng[1]:.2f}]" if rng else
                            "none (noise estimated)" if self.noise_estimated else "-"))
            lines.append(f"{c:<{w}}" + " ".join(f"{v:>{cw}d}" for v in M[i]) + extra)
        return lines

    def table(self) -> str:
        """The confusion matrix as a text table (rows true, columns verdict) with the rates; with
        the left-out mode a second block: the verdicts with the effect's group left out."""
        lines = ["verdict columns: " + ", ".join(f"{j + 1} {lab}" for j, lab in enumerate(self.labels)),
                 ""] + self._block(False)
        if self.left_out:
            lines += ["", "left out (the effect and its group removed from the candidates; right verdict "
                          "'unexplained'):"] + self._block(True)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        d = {"format": "triadcal.diagnosis_validation", "version": 1, "seeds": self.seeds,
             "conditions": list(self.conditions), "labels": list(self.labels),
             "confusion": self.confusion().tolist(), "summary": self.summary, "rows": self.rows,
             "design": self.design.strip(), "seconds": self.seconds,
             "magnitudes": [float(m) for m in self.magnitudes], "magnitude_definition": MAGNITUDE_DEFINITION,
             "left_out": self.left_out, "noise_estimated": self.noise_estimated}
        if self.noise_estimated:
            d["noise_estimated_definition"] = NOISE_ESTIMATED_DEFINITION
        if self.left_out:
            d.update({"left_out_definition": LEFT_OUT_DEFINITION,
                      "left_out_conditions": list(self.left_out_conditions),
                      "confusion_left_out": self.confusion(True).tolist(),
                      "left_out_groups": {c: self.summary[c]["left_out_group"] for c in self.left_out_conditions}})
        return d


def summarise(rows, conditions) -> dict:
    out = {}
    for c in conditions:
        rs = [r for r in rows if r.get("condition", r["effect"]) == c]
        if not rs:
            continue
        effect = rs[0]["effect"]
        target = NONE if effect == "clean" else effect
        ok = [r.get("right", r["verdict"] == target) for r in rs]     # rows of old files have no "right"
        after = [r["chi2_dof_after"] for r, k in zip(rs, ok) if k and r["chi2_dof_after"] is not None]
        base = effect.split("~")[0]
        s = {
            "effect": effect,
            "magnitude": rs[0].get("magnitude"),
            "n": len(rs),
            "correct_rate": float(np.mean(ok)),
            # not named, but pointed at: 'unexplained' whose best partial answer is a right verdict
            "best_partial_right_rate": float(np.mean([
                r["verdict"] == UNEXPLAINED and r.get("best_partial") in r.get("right_verdicts", (effect,))
                for r in rs])),
            "ranked_first_rate": (float(np.mean([r["first"] in r.get("right_verdicts", (effect,)) for r in rs]))
                                  if effect != "clean" else None),
            "false_alarm_rate": (float(np.mean([r["verdict"] != NONE for r in rs])) if effect == "clean" else None),
            # a noise effect named on a mean effect's (structured) gap
            "noise_named_rate": (float(np.mean([r["verdict"] in NOISE_EFFECTS for r in rs]))
                                 if base not in NOISE_EFFECTS else None),
            "localised_rate": float(np.mean([bool(r["localised"]) for r in rs])),
            # None with the noise estimated (no chi2/dof against a declared level)
            "chi2_dof_before_median": (float(np.median(before)) if (before := [
                r["chi2_dof_before"] for r in rs if r["chi2_dof_before"] is not None]) else None),
            "chi2_dof_after_range": [float(min(after)), float(max(after))] if after else None,
            "chi2_dof_after_in_0.8_1.2": (float(np.mean([0.8 <= a <= 1.2 for a in after])) if after else None),
            "median_seconds": float(np.median([r["seconds"] for r in rs])),
        }
        lo = [r for r in rs if r.get("left_out_verdict") is not None]
        if lo:
            verdicts = [r["left_out_verdict"] for r in lo]
            s.update({
                "left_out_group": list(lo[0]["left_out"]),
                "left_out_n": len(lo),
                "unexplained_rate": float(np.mean([v == UNEXPLAINED for v in verdicts])),
                # a confident wrong answer: a candidate named although the cause was left out
                "left_out_named_rate": float(np.mean([v not in (UNEXPLAINED, NONE) for v in verdicts])),
                "left_out_noise_rate": float(np.mean([v in NOISE_EFFECTS for v in verdicts])),
                "left_out_none_rate": float(np.mean([v == NONE for v in verdicts])),
                # named, but the verdict says the gap stays open ("more is missing") ...
                "left_out_named_gap_open_rate": float(np.mean([
                    r["left_out_verdict"] not in (UNEXPLAINED, NONE) and r.get("left_out_gap_closed") is False
                    for r in lo])),
                # ... or named with the gap closed: the confident wrong answer
                "left_out_confident_wrong_rate": float(np.mean([
                    r["left_out_verdict"] not in (UNEXPLAINED, NONE) and r.get("left_out_gap_closed") is not False
                    for r in lo])),
                "left_out_verdicts": {v: verdicts.count(v) for v in sorted(set(verdicts))},
                # the campaigns where the effect was detectable at all: its in-vocabulary diagnosis
                # found a significant gap (with its own score test among the gap's tests); a left-out
                # 'none' elsewhere is an effect below what any test here sees, not a wrong answer
                "left_out_detected_n": int(sum(bool(r["gap_significant"]) for r in lo)),
                "unexplained_rate_when_detected": (float(np.mean([
                    r["left_out_verdict"] == UNEXPLAINED for r in lo if r["gap_significant"]]))
                    if any(r["gap_significant"] for r in lo) else None),
                "left_out_median_seconds": float(np.median([r["left_out_seconds"] for r in lo])),
            })
        out[c] = s
    return out


_BLAS_LIMIT = None


def _one_blas_thread():
    """Worker initializer: one BLAS thread in this process (threadpoolctl; the matrices are
    small and threaded BLAS only adds overhead). The environment is not touched."""
    global _BLAS_LIMIT
    from threadpoolctl import threadpool_limits

    _BLAS_LIMIT = threadpool_limits(1)


def validate(seeds: int = 20, effects: Optional[Sequence[str]] = None, processes: int = 2,
             preset: str = "ak18-quartz", first_seed: int = 1000, n_draws: int = 200,
             progress=None, magnitudes: Sequence[float] = (1.0,), left_out: bool = False,
             noise_estimated: bool = False, journal_dir=None) -> ValidationResult:
    """Run the validation: ``seeds`` campaigns per condition (clean and each effect at each of
    ``magnitudes``; clean once). With ``left_out`` each effect's campaign is diagnosed a second
    time with the effect's group left out of the candidates (:func:`run_case`); with
    ``noise_estimated`` without its declared noise (:func:`without_noise`).

    Runs in ``processes`` worker processes (spawned with one BLAS thread each: the
    matrices are small and threaded BLAS only adds overhead). ``progress`` (optional)
    is called with each row diagnosed in this run.

    ``journal_dir``: every finished row is appended to ``journal_dir/rows.jsonl`` as it comes, and
    the rows a stopped run of the same settings and code left there are taken instead of diagnosed
    again (:mod:`.validation_journal`; the folder is locked for the run). ``result.resumed`` counts them.
    """
    effects = tuple(effects) if effects else CONDITIONS
    magnitudes = tuple(dict.fromkeys(float(m) for m in magnitudes))
    if not magnitudes or not all(m > 0 and np.isfinite(m) for m in magnitudes):
        raise InputError(f"magnitudes must be positive numbers, not {magnitudes!r}")
    cases = [(e, m) for e in effects for m in (magnitudes[:1] if e == "clean" else magnitudes)]
    conditions = tuple(condition_name(e, m) for e, m in cases)
    for e, _ in cases:
        scenario(e, preset)                        # unknown effects fail here, before the workers
    jobs = [(e, first_seed + s, preset, n_draws, False, 2, m, left_out, noise_estimated)
            for e, m in cases for s in range(seeds)]
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        journal = None
        if journal_dir is not None:
            from ..hardware.storage import folder_lock
            from .validation_journal import Journal

            stack.enter_context(folder_lock(journal_dir, "validate-diagnosis"))
            journal = Journal(journal_dir, {"preset": preset, "n_draws": n_draws, "left_out": bool(left_out),
                                            "noise_estimated": bool(noise_estimated), "cross_group": False, "top": 2})
            stack.callback(journal.close)
            for note in journal.notes:
                print(f"note: {note}", file=sys.stderr)
        done = {} if journal is None else {job_key(j): journal.rows[job_key(j)] for j in jobs
                                           if job_key(j) in journal.rows}
        todo = [j for j in jobs if job_key(j) not in done]

        def finished(job, row):
            if journal is not None:
                journal.append(job_key(job), row)
            done[job_key(job)] = row
            if progress:
                progress(row)

        resumed = len(done)
        if processes <= 1:
            for j in todo:
                finished(j, run_case(*j))
        elif todo:
            with ProcessPoolExecutor(processes, mp_context=get_context("spawn"), initializer=_one_blas_thread) as ex:
                for j, row in zip(todo, ex.map(_run_star, todo, chunksize=2 if left_out else 4)):
                    finished(j, row)
    rows = [done[job_key(j)] for j in jobs]
    labels = tuple(VOCABULARY) + FORM_CANDIDATES + (UNEXPLAINED, NONE)
    design = (DESIGN + "; " + MAGNITUDE_DEFINITION + (("; " + LEFT_OUT_DEFINITION) if left_out else "")
              + (("; " + NOISE_ESTIMATED_DEFINITION) if noise_estimated else ""))
    res = ValidationResult(rows, conditions, labels, seeds, design=design, seconds=time.perf_counter() - t0,
                           magnitudes=magnitudes, left_out=left_out, noise_estimated=noise_estimated,
                           resumed=resumed)
    res.summary = summarise(rows, conditions)
    return res


__all__ = ["ALPHA", "CONDITIONS", "LEFT_OUT_GROUPS", "MAGNITUDES", "VALIDATION_PLAN", "ValidationResult",
           "condition_name", "left_out_group", "run_case", "scenario", "validate", "without_noise"]
