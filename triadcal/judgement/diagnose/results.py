"""What a diagnosis reports: slice tests, candidates with their evidence, the verdict, and the
``triadcal.diagnosis`` JSON (docs/results-json.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

FORMAT = "triadcal.diagnosis"


VERSION = 1


ALPHA = 0.01


# ----------------------------------------------------------------------------------
# results
# ----------------------------------------------------------------------------------
@dataclass
class SliceTest:
    slice: str
    family: str
    axis: str
    test: str                # offset | trend | excess_chi2
    n: int
    statistic: float         # z for offset/trend, chi2 ratio for excess_chi2
    p_value: float
    p_adjusted: float = 1.0  # Holm
    log10_p: float = 0.0     # log10 of p_value without underflow (orders the extreme ones)
    size: float = 0.0
    unit: str = "ug"
    ppc_p: Optional[float] = None

    @property
    def standardised_size(self) -> float:
        """Size per observation in noise units: |mean| for an offset, the r.m.s. of the fitted
        line for a trend, sqrt(chi2/E[chi2] - 1) for excess scatter (all ~ delta for a
        misfit of delta sigma on every visit of the slice)."""
        if self.test == "excess_chi2":
            return math.sqrt(max(self.statistic - 1.0, 0.0))
        return abs(self.statistic) / math.sqrt(max(self.n, 1))

    def to_dict(self) -> dict:
        return {"slice": self.slice, "family": self.family, "axis": self.axis, "test": self.test,
                "n": self.n, "statistic": _f(self.statistic), "size": _f(self.size), "unit": self.unit,
                "size_sigma": _f(self.standardised_size),
                "p_value": _f(self.p_value), "log10_p": _f(self.log10_p), "p_holm": _f(self.p_adjusted),
                "ppc_p": _f(self.ppc_p)}


@dataclass
class Candidate:
    effect: str
    testable: bool
    reason: str = ""
    k: int = 0
    score: float = 0.0
    score_logp: float = 0.0          # natural log of the score test's p-value
    refit: Optional[dict] = None     # evidence of the refit (None when not refitted)
    rank: int = 0
    params: list = field(default_factory=list)   # its parameters the design can determine
    #: a form candidate (FORM_CANDIDATES): no score test, ranked by its refit only
    refit_only: bool = False
    #: a form candidate's prepared refit (state, nested criterion, fit options); not in the JSON
    form: Optional[dict] = None
    #: a candidate with a time constant: its score profiled over it (time_constant.profiled_score)
    score_profile: Optional[dict] = None
    #: and its offsets' whitened columns at each time constant of the grid, ``[(tau_min, J), ...]``
    #: (the detection limits per time constant); not in the JSON
    columns_by_tau: Optional[list] = field(default=None, repr=False)

    @property
    def score_p(self) -> float:
        return math.exp(self.score_logp)

    def to_dict(self) -> dict:
        d = {"effect": self.effect, "rank": self.rank, "testable": self.testable,
             "score": _f(self.score), "score_dof": self.k, "score_p_value": _f(self.score_p),
             "score_log10_p": _f(self.score_logp / math.log(10))}
        if self.refit_only:
            # no score test at the fitted point: score_dof is the refit's parameter count
            d.update({"score": None, "score_p_value": None, "score_log10_p": None, "refit_only": True})
        if self.reason:
            d["reason"] = self.reason
        if self.score_profile is not None:
            d["score_profile"] = dict(self.score_profile)
        if self.refit:
            d.update(self.refit)
        return d


@dataclass
class Diagnosis:
    model: tuple
    noise_known: bool
    noise: str
    gap: dict
    slices: list
    candidates: list
    verdict: dict
    fit: dict
    notes: list = field(default_factory=list)
    source: Optional[str] = None
    alpha: float = ALPHA
    #: families of slices ranked by how much of the misfit their offsets explain
    families: list = field(default_factory=list)
    #: normalised residuals of the base fit, (n_visits, 3); not part of the JSON
    residuals: Optional[np.ndarray] = None

    @property
    def where(self) -> list:
        """The disagreeing slices (Holm p < alpha), ranked by p-value."""
        return [s for s in self.slices if s.p_adjusted < self.alpha]

    @property
    def verdict_effect(self) -> Optional[str]:
        return self.verdict.get("effect")

    def ranked(self) -> list:
        return [c.effect for c in sorted(self.candidates, key=lambda c: c.rank) if c.testable]

    def to_dict(self) -> dict:
        return {
            "format": FORMAT, "version": VERSION, "model": list(self.model), "source": self.source,
            "noise": self.noise, "noise_known": self.noise_known, "alpha": self.alpha,
            "gap": self.gap,
            "where": [s.to_dict() for s in self.where],
            "where_families": self.families,
            "candidates": [c.to_dict() for c in sorted(self.candidates, key=lambda c: c.rank)],
            "verdict": self.verdict,
            "fit": self.fit,
            "slices": [s.to_dict() for s in self.slices],
            "notes": list(self.notes),
            "methods": METHODS_TEXT,
        }

    def save(self, path) -> None:
        from ...io.atomic import atomic_write_json

        atomic_write_json(path, self.to_dict())     # non-finite (e.g. a Pareto k) -> null, never a torn file


METHODS_TEXT = {
    "gap": "chi2 of the normalised residuals vs chi2(n_obs - n_par) with known noise; Anscombe-Glynn "
           "kurtosis test (one-sided) of leverage-standardised residuals; score test of every candidate and "
           "of five generic families of smooth mean terms (temperature, time, orientation even/odd, branch: "
           "judgement/diagnose/generic.py); significant when any rejects after Holm's correction at alpha "
           "(family-wise)",
    "where": "slices x output axis, tests of offset (mean), trend (slope in time) and excess chi2 with exact "
             "null moments of the linearised fit (hat matrix; excess chi2 by Satterthwaite's scaled chi2); "
             "Holm's correction over all tests; posterior predictive p of the slice chi2 from Laplace draws",
    "which": "score (Lagrange multiplier) test at the fitted point with the new parameters at 0; the top "
             "candidates refitted: likelihood ratio, PSIS-LOO elpd (arviz.loo's algorithm, vectorised) from Laplace draws of the LS "
             "covariance with linearised residuals, prediction across heating/cooling branches; ranked by "
             "delta elpd among the refitted, then by score p-value; form candidates (hysteresis_play, "
             "hysteresis_pi, thermal_lag_history) have no score test: always refitted (r, start, tau profiled "
             "by the estimation/ form fits), their LR with the profiled parameters counted, delta elpd less "
             "one per profiled parameter, named only when they beat their simpler form (offset hysteresis, "
             "rate-form lag) by the nested likelihood ratio at 99 %",
    "verdict": "the best refitted candidate is named when its LR p < alpha and delta elpd > 0, the chi2 after "
               "it is within the noise at alpha (known noise) and no generic family is significant after it "
               "(Holm over the families, on the residuals standardised by its noise model); a noise candidate "
               "also needs no significant slice after it, and flicker_noise no generic family explaining the "
               "gap better by AIC (-S + 2k < -2 delta loglik + 2); a mean candidate must beat every rival (other "
               "refitted candidates, single generic terms) by the encompassing test at alpha, else 'unexplained' "
               "with ambiguous_with; a candidate that shrinks the gap without closing "
               "it is the best partial answer of an 'unexplained' verdict, unless it is one order of a "
               "temperature coefficient whose orders the model lacks refitted together (the series: nested LR "
               "over the single order at alpha, higher delta elpd) close the gap and beat the rivals: then "
               "'effects' lists the orders and 'effect' is the one of largest Wald chi2",
}


def _p_is(p) -> str:
    """``"= 0.003"`` or ``"< 1e-300"`` (underflowed to 0): a p-value after its name in the evidence
    ("LR p = 0.003", "LR p < 1e-300"), never a bare "p = 0"."""
    if p is None or p != p:
        return "not computed"
    return f"= {p:.3g}" if p > 0 else "< 1e-300"


def _f(v):
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None
