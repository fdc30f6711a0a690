"""Validation of the diagnosis on campaigns whose effect is withheld (``triadcal validate-diagnosis``).

:func:`validate` simulates campaigns with each effect (and a clean condition), fits the model
without it and checks that :func:`diagnose` names it (:func:`scenario`, :func:`run_case`,
:class:`ValidationResult`); its design (``DESIGN``, written into every validation file) is
derived in docs/diagnosis.md, "Validation".
"""

from __future__ import annotations

from ..errors import InputError

import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from multiprocessing import get_context
from typing import Optional, Sequence

import numpy as np

from ..models.campaign import DEFAULT_PLAN
from ..models.effects import DEFAULT_EFFECTS, VOCABULARY
from ..models.simulate import NoiseModel, Schedule, preset_truth, simulate_campaign
from .diagnose import ALPHA, SIGNATURE, diagnose

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


#: the validation's design in one paragraph (docs/diagnosis.md, "Validation" derives it)
DESIGN = ("ak18-quartz preset, DEFAULT_EFFECTS, VALIDATION_PLAN (28 poses), 15 setpoints with a 1800 s soak, "
          "Q = 3e-9 V^2 s, tau = 30 s, position error 5\"/2\", Student-t with 3 dof; each effect withheld at a "
          "realistic magnitude, the diagnosis must name it first")


def scenario(effect: str, preset: str = "ak18-quartz"):
    """(truth, model effects) of the validation campaign that withholds ``effect`` ('clean': none)."""
    if effect != "clean" and effect not in VOCABULARY:
        raise InputError(f"unknown effect {effect!r}; choose from clean, {', '.join(VOCABULARY)}")
    noise = NoiseModel(sigma_position_arcsec=5.0 if effect == "position_error" else 0.0,
                       sigma_wobble_arcsec=2.0 if effect == "position_error" else 0.0,
                       heavy_tails_dof=3.0 if effect == "heavy_tails" else None)
    truth_effects = tuple(DEFAULT_EFFECTS)
    if effect not in DEFAULT_EFFECTS and effect not in ("clean", "position_error", "heavy_tails"):
        truth_effects = truth_effects + (effect,)
    model = tuple(e for e in DEFAULT_EFFECTS if e != effect)
    return preset_truth(preset, truth_effects, noise=noise), model


def run_case(effect: str, seed: int, preset: str = "ak18-quartz", n_draws: int = 200,
             cross_group: bool = False, top: int = 2) -> dict:
    """Simulate, fit without ``effect``, diagnose; the row of the validation table."""
    truth, model = scenario(effect, preset)
    campaign = simulate_campaign(truth, plan=VALIDATION_PLAN, schedule=Schedule(soak_s=VALIDATION_SOAK_S),
                                 seed=seed)
    t0 = time.perf_counter()
    d = diagnose(campaign, model, n_draws=n_draws, cross_group=cross_group, slices_after=False, top=top,
                 seed=seed)
    named = d.verdict_effect
    ranked = d.ranked()
    after = None
    for c in d.candidates:
        if c.effect == named and c.refit:
            after = c.refit["gap_after"]["chi2_dof"]
    where = d.where
    # localisation: the family of slices whose offsets explain most of the misfit (when
    # significant), and the most significant single slice below the whole-axis level
    local = [w for w in where if w.family != "axis"]
    fams = [f for f in d.families if f["log10_p"] < np.log10(ALPHA / max(len(d.families), 1))]
    top_family = fams[0]["family"] if fams else None
    expected = SIGNATURE.get(effect, ())
    return {"effect": effect, "seed": seed, "verdict": named or NONE,
            "first": ranked[0] if ranked else None,
            "rank_of_truth": (ranked.index(effect) + 1) if effect in ranked else None,
            "gap_significant": d.gap["significant"], "chi2_dof_before": d.gap["chi2_dof"],
            "chi2_dof_after": after, "n_significant_slices": len(where), "top_slice": (local[0] if local else where[0]).slice if where else None,
            "top_slice_family": top_family,
            "localised": (top_family in expected) if expected else top_family is None,
            "seconds": time.perf_counter() - t0}


def _run_star(args):
    return run_case(*args)


@dataclass
class ValidationResult:
    rows: list
    conditions: tuple
    labels: tuple                     # verdict columns: the vocabulary and 'none'
    seeds: int
    design: str = DESIGN
    seconds: float = 0.0
    summary: dict = field(default_factory=dict)

    def confusion(self) -> np.ndarray:
        """Counts: rows the withheld effect (or clean), columns the verdict (labels)."""
        M = np.zeros((len(self.conditions), len(self.labels)), int)
        for r in self.rows:
            M[self.conditions.index(r["effect"]), self.labels.index(r["verdict"])] += 1
        return M

    def table(self) -> str:
        """The confusion matrix as a text table (rows true, columns verdict) with the rates."""
        M = self.confusion()
        short = [lab[:9] for lab in self.labels]
        w = max(len(c) for c in self.conditions) + 1
        lines = [" " * w + " ".join(f"{s:>9}" for s in short)
                 + "   correct  localised  chi2/dof after (range)"]
        for i, c in enumerate(self.conditions):
            s = self.summary[c]
            rng = s["chi2_dof_after_range"]
            lines.append(f"{c:<{w}}" + " ".join(f"{v:>9d}" for v in M[i])
                         + f"   {s['correct_rate']:6.0%}   {s['localised_rate']:7.0%}    "
                         + (f"[{rng[0]:.2f}, {rng[1]:.2f}]" if rng else "-"))
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"format": "triadcal.diagnosis_validation", "version": 1, "seeds": self.seeds,
                "conditions": list(self.conditions), "labels": list(self.labels),
                "confusion": self.confusion().tolist(), "summary": self.summary, "rows": self.rows,
                "design": self.design.strip(), "seconds": self.seconds}


def summarise(rows, conditions) -> dict:
    out = {}
    for c in conditions:
        rs = [r for r in rows if r["effect"] == c]
        if not rs:
            continue
        target = NONE if c == "clean" else c
        after = [r["chi2_dof_after"] for r in rs if r["verdict"] == target and r["chi2_dof_after"] is not None]
        out[c] = {
            "n": len(rs),
            "correct_rate": float(np.mean([r["verdict"] == target for r in rs])),
            "ranked_first_rate": (float(np.mean([r["first"] == c for r in rs])) if c != "clean" else None),
            "false_alarm_rate": (float(np.mean([r["verdict"] != NONE for r in rs])) if c == "clean" else None),
            "localised_rate": float(np.mean([bool(r["localised"]) for r in rs])),
            "chi2_dof_before_median": float(np.median([r["chi2_dof_before"] for r in rs])),
            "chi2_dof_after_range": [float(min(after)), float(max(after))] if after else None,
            "chi2_dof_after_in_0.8_1.2": (float(np.mean([0.8 <= a <= 1.2 for a in after])) if after else None),
            "median_seconds": float(np.median([r["seconds"] for r in rs])),
        }
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
             progress=None) -> ValidationResult:
    """Run the validation: ``seeds`` campaigns per condition (clean and each effect).

    Runs in ``processes`` worker processes (spawned with one BLAS thread each: the
    matrices are small and threaded BLAS only adds overhead). ``progress`` (optional)
    is called with each finished row.
    """
    conditions = tuple(effects) if effects else CONDITIONS
    jobs = [(e, first_seed + s, preset, n_draws) for e in conditions for s in range(seeds)]
    t0 = time.perf_counter()
    rows = []
    if processes <= 1:
        for j in jobs:
            rows.append(run_case(*j))
            if progress:
                progress(rows[-1])
    else:
        with ProcessPoolExecutor(processes, mp_context=get_context("spawn"), initializer=_one_blas_thread) as ex:
            for row in ex.map(_run_star, jobs, chunksize=4):
                rows.append(row)
                if progress:
                    progress(row)
    from .diagnose import FORM_CANDIDATES        # refit-only forms may be named too (a confusion)
    labels = tuple(VOCABULARY) + FORM_CANDIDATES + (UNEXPLAINED, NONE)
    res = ValidationResult(rows, conditions, labels, seeds, seconds=time.perf_counter() - t0)
    res.summary = summarise(rows, conditions)
    return res


__all__ = ["ALPHA", "CONDITIONS", "VALIDATION_PLAN", "ValidationResult", "run_case", "scenario", "validate"]
