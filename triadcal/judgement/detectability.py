"""How detectable is a withheld effect on the validation's design? The noncentrality of its signal.

The validation (``diagnosis_validation``) counts how often the diagnosis names an effect; at half
the realistic magnitude it misses many. This module says whether *any* rule could do better on
that design, from theory rather than from another run. For an effect of mean ``s`` (the change it
makes to the visit means) and a fitted model whose linearised Jacobian spans ``J``, the whitened
residuals of the fit are ``r = P s / sigma + P e`` with ``P`` the projector orthogonal to ``J`` and
``e ~ N(0, I)``. Then

* ``lambda_total = |P s / sigma|^2`` is the noncentrality of the signal left after the fit. The
  most powerful level-alpha test of "no effect" against this one alternative -- its shape, sign and
  size known (Neyman-Pearson: the projection of ``r`` on ``P s``) -- detects it with probability
  ``Phi(sqrt(lambda_total) - z_{1-alpha})``. No test with a false-alarm rate alpha on clean data
  does better, whatever it knows; the diagnosis's gap test, which knows neither shape nor size, does
  worse. For 95 % at alpha = 0.01 it needs lambda_total >= (2.326 + 1.645)^2 = 15.8.
* ``lambda_own`` is the noncentrality of the effect's own score test (chi2 with ``k_own`` dof: the
  part of ``P s / sigma`` in the span of the effect's columns, made orthogonal to ``J``) and
  ``power_own`` the probability that it alone passes the first step of Holm's procedure over the
  gap's ``n_gap_tests`` tests, ``chi2_k(lambda_own) > chi2_k^{-1}(1 - alpha / n)``.

* ``lambda_rival`` is the noncentrality of the encompassing test (``diagnose/rivals.py``) of the
  effect against its closest rival (``verdict.closest_rival`` of the noise-free diagnosis: the rival
  of the smallest ``S``, ``k_rival`` dof): the part of the effect's signal that neither the model nor
  that rival holds. ``power_rival`` is that test's power at ``alpha``, ``P(chi2_k(lambda_rival) >
  chi2_k^{-1}(1 - alpha))``: the diagnosis names the effect only when it passes, so its rate of
  right names is at most ``min(power_own, power_rival)``. ``power_rival_bound`` =
  ``Phi(sqrt(lambda_rival) - z_{1-alpha})`` bounds any rule that tells the effect from that rival
  with a rate alpha of naming it when the rival is the truth. None when no rival is one, or when the
  noise-free diagnosis does not end on the effect.

All are computed on the validation campaign itself, simulated with the output noise scaled by
1e-7 in SD and the thermometers' reading noise (0.01 degC) off (every random draw is still made, so
the design is the seed's) and given the noisy campaign's ``sd_*`` columns, so that the diagnosis's
own fit and score tests read them: its base chi2 is ``lambda_total`` and its candidate's score ``S``
is ``lambda_own`` (a clean campaign gives 1e-11; with the reading noise on it gives 0.8, an
errors-in-variables misfit of the tempcos that is not the effect's). Linearised at the fit, as the
score tests are.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

from scipy import stats

from ..errors import InputError
from ..models.effects import NOISE_EFFECTS, VOCABULARY
from .diagnose import ALPHA, diagnose
from .diagnose.detection import power_chi2

#: the noise intensity's factor in the noise-free campaign (its SD: 1e-7 of the real one)
NOISE_FACTOR = 1e-14


def noise_free_campaign(effect: str, magnitude: float = 1.0, preset: str = "ak18-quartz", seed: int = 1000):
    """(campaign, model): the validation campaign of ``effect`` at ``magnitude`` with the output noise
    scaled by ``NOISE_FACTOR`` in intensity, no reading noise, and the noisy campaign's ``sd_*`` and
    metadata."""
    from . import diagnosis_validation as dv

    if effect != "clean" and effect not in VOCABULARY:
        raise InputError(f"unknown effect {effect!r}; choose from {', '.join(VOCABULARY)}")
    if effect == "clean" or effect in NOISE_EFFECTS:
        raise InputError(f"{effect!r} has no mean signal to measure; choose a mean effect of the vocabulary "
                         f"({', '.join(e for e in VOCABULARY if e not in NOISE_EFFECTS)})")
    truth, model = dv.scenario(effect, preset, magnitude)
    schedule = dv.Schedule(soak_s=dv.VALIDATION_SOAK_S)
    noisy = dv.simulate_campaign(truth, plan=dv.VALIDATION_PLAN, schedule=schedule, seed=seed)
    quiet = dataclasses.replace(truth, noise=dataclasses.replace(truth.noise, Q_V2s=truth.noise.Q_V2s * NOISE_FACTOR,
                                                                 temp_noise_C=0.0))
    c = dv.simulate_campaign(quiet, plan=dv.VALIDATION_PLAN, schedule=schedule, seed=seed)
    return dataclasses.replace(c, sd=noisy.sd, metadata=dict(noisy.metadata)), model


def power_bound(lambda_total: float, alpha: float = ALPHA) -> float:
    """``Phi(sqrt(lambda) - z_{1-alpha})``: the power of the most powerful level-alpha test of a
    known signal of noncentrality ``lambda`` (module docstring)."""
    return float(stats.norm.cdf(math.sqrt(max(lambda_total, 0.0)) - stats.norm.ppf(1.0 - alpha)))


def detectability(effect: str, magnitude: float = 1.0, preset: str = "ak18-quartz", seed: int = 1000,
                  alpha: float = ALPHA) -> dict:
    """The noncentralities and powers of the module docstring for one condition."""
    c, model = noise_free_campaign(effect, magnitude, preset, seed)
    d = diagnose(c, model, candidates=list(VOCABULARY), n_draws=20, slices_after=False, top=2, seed=seed)
    lam_total = float(d.gap["chi2_dof"]) * int(d.gap["dof"])
    own = next((x for x in d.candidates if x.effect == effect), None)
    lam_own = float(own.score) if own is not None and own.testable else None
    k_own = int(own.k) if lam_own is not None else None
    n = len(d.gap["tests"])
    v = d.verdict
    cr = v.get("closest_rival") if effect in (v.get("effect"), v.get("best_partial")) else None
    lam_rival = float(cr["S"]) if cr and cr["k"] > 0 else 0.0 if cr else None
    return {"effect": effect, "magnitude": float(magnitude), "seed": int(seed), "alpha": float(alpha),
            "lambda_total": lam_total, "lambda_own": lam_own, "k_own": k_own, "n_gap_tests": n,
            "power_bound": power_bound(lam_total, alpha),
            "power_own": power_chi2(lam_own, k_own, alpha / n) if lam_own is not None else None,
            "closest_rival": cr["rival"] if cr else None, "lambda_rival": lam_rival,
            "k_rival": int(cr["k"]) if cr else None,
            "power_rival": (None if cr is None else 0.0 if cr["k"] == 0 else power_chi2(lam_rival, cr["k"], alpha)),
            "power_rival_bound": power_bound(lam_rival, alpha) if cr else None}


def detectability_table(effects: Sequence[str], magnitudes: Sequence[float] = (1.0, 0.5), **kw) -> list:
    """:func:`detectability` of every mean effect of ``effects`` at every magnitude (noise effects
    and 'clean' skipped: they have no mean signal)."""
    rows = []
    for e in effects:
        if e == "clean" or e in NOISE_EFFECTS:
            continue
        for m in magnitudes:
            rows.append(detectability(e, m, **kw))
    return rows


def format_table(rows: Sequence[dict]) -> str:
    """A text table of :func:`detectability_table`'s rows."""
    lines = [f"{'condition':<28} {'m':>4} {'lambda':>9} {'P bound':>8} {'lambda_own':>10} {'k':>3} {'P own':>7}"
             f"  {'closest rival':<22} {'lambda':>8} {'k':>3} {'P rival':>7} {'bound':>6}"]
    for r in rows:
        own = (f"{r['lambda_own']:10.1f} {r['k_own']:3d} {r['power_own']:7.2f}" if r["lambda_own"] is not None
               else f"{'-':>10} {'-':>3} {'-':>7}")
        riv = (f"{r['closest_rival'][:22]:<22} {r['lambda_rival']:8.1f} {r['k_rival']:3d} {r['power_rival']:7.2f} "
               f"{r['power_rival_bound']:6.2f}" if r.get("closest_rival") is not None
               else f"{'-':<22} {'-':>8} {'-':>3} {'-':>7} {'-':>6}")
        lines.append(f"{r['effect']:<28} {r['magnitude']:4g} {r['lambda_total']:9.1f} {r['power_bound']:8.2f} {own}"
                     f"  {riv}")
    return "\n".join(lines)
