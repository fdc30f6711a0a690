"""The joint fit's gate ``correlated_residuals`` (triadcal/estimation/serial_correlation.py).

An outside probe's campaigns with AR(1) visit errors (rho 0.9 between consecutive visits, each
visit's error of its stated SD) were fitted and sampled with status ok in 7 of 14, five of them with
a parameter 4.4-6.7 u off, and a note on their low chi2 called every u conservative. The campaigns
here are made by the independent bench (tests/independent_bench.py, no project model code) with a
bias that wanders by two mechanisms of its own: a Gauss-Markov process sampled exactly at the
visits' times, and a random walk (Brownian motion); the null is its white noise."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from independent_bench import simulate_campaign
from triadcal.api import fit
from triadcal.io.bench_csv import parse_bench_csv

NOISE_SD, N_SAMPLES = 5e-4, 3000
SIGMA_V = NOISE_SD / math.sqrt(N_SAMPLES)      # the SD of a visit mean, V (K ~ 1 g/V)


def wander(seed: int, kind: str, size: float, tau_s: float = 7200.0):
    """``extra_bias`` of the independent bench: a bias of SD ``size`` x the visit noise that wanders
    in time, the same process on the three outputs (independent draws): ``gauss_markov`` (exact
    discretisation, e_k = e_{k-1} exp(-dt/tau) + sqrt(1 - exp(-2 dt/tau)) s eta) or ``random_walk``
    (increments of variance s^2 dt / tau, from 0)."""
    rng = np.random.default_rng(1000 + seed)
    state = {"t": None, "e": None}
    s = size * SIGMA_V

    def extra_bias(k, t, temps, G, direction):
        if state["t"] is None:
            state["e"] = rng.normal(0.0, s, 3) if kind == "gauss_markov" else np.zeros(3)
        else:
            dt = max(float(t) - state["t"], 0.0)
            if kind == "gauss_markov":
                a = math.exp(-dt / tau_s)
                state["e"] = a * state["e"] + math.sqrt(1.0 - a * a) * s * rng.normal(size=3)
            else:
                state["e"] = state["e"] + s * math.sqrt(dt / tau_s) * rng.normal(size=3)
        state["t"] = float(t)
        return state["e"]

    return extra_bias


def campaign(seed: int, extra_bias=None, stated_factor: float = 1.0):
    """The independent bench's campaign; ``stated_factor`` scales its ``sd_*`` (the noise the file
    states: with a wander, the visits' marginal SD, as the probe's files had it)."""
    text, truth = simulate_campaign(np.random.default_rng(seed), noise_sd=NOISE_SD, n_samples=N_SAMPLES,
                                    extra_bias=extra_bias)
    c = parse_bench_csv(text)
    return (replace(c, sd=c.sd * stated_factor) if stated_factor != 1.0 else c), truth


def gate(result):
    return next((o for o in result.extra["gates"]["outcomes"] if o["gate"] == "correlated_residuals"), None)


@pytest.mark.parametrize("kind,size,stated,alone", [
    # a Gauss-Markov bias of 1.5 visit SDs, 2 h, the sd_* its marginal SD (chi2/dof 0.70-0.84; the
    # structure gate refuses these too)
    ("gauss_markov", 1.5, math.sqrt(1 + 1.5 ** 2), False),
    # a random walk of 1 visit SD per 2 h, the sd_* twice the white noise: chi2/dof 0.33-0.42, every other
    # gate passes (status ok before this gate), values 5-13 u off
    ("random_walk", 1.0, 2.0, True)])
def test_a_bias_that_wanders_is_refused_with_the_correlation_named(kind, size, stated, alone):
    worst = []
    for seed in (1, 2, 3):
        c, truth = campaign(seed, wander(seed, kind, size), stated)
        r = fit(c, method="joint")
        g = gate(r)
        assert g is not None and g["passed"] is False and r.status == "model_mismatch", (seed, g, r.status)
        assert "not independent" in g["reason"] and "flicker_noise" in g["reason"]
        assert r.fit["correlated_residuals"]["p_value"] < 1e-3 and r.fit["chi2_dof"] < 1.0
        failed = {o["gate"] for o in r.extra["gates"]["outcomes"] if o["passed"] is False}
        assert not alone or failed == {"correlated_residuals"}, failed
        assert not any("so every u is conservative" in n for n in r.notes), r.notes
        worst.append(max(abs(r.parameters[n].value - v) / r.parameters[n].u for n, v in truth.items()
                         if n in r.parameters))
    # what the gate stops: values further from the truth than their u allow
    assert max(worst) > 4.0, worst


def test_white_noise_passes_and_the_gate_is_recorded():
    for seed in (1, 2, 3, 4, 5):
        r = fit(campaign(seed)[0], method="joint")
        g = gate(r)
        assert g is not None and g["passed"] is True, (seed, g)
        assert g["threshold"] == "p >= 0.001" and 0.0 < r.fit["correlated_residuals"]["p_value"] <= 1.0


@pytest.mark.slow
def test_false_refusals_of_white_noise_stay_within_the_level():
    """100 white-noise campaigns of the independent bench: the gate's size is at most 0.001 (Bonferroni
    over three exact tests), so three or more refusals have probability 1.5e-4; and its p (Bonferroni's,
    conservative) is below 0.05 at most as often as a level-0.05 test: 5 expected, more than 14 has
    probability 3e-4 (binomial)."""
    ps = []
    for seed in range(100, 200):
        r = fit(campaign(seed)[0], method="joint")
        ps.append(r.fit["correlated_residuals"]["p_value"])
    ps = np.array(ps)
    assert np.sum(ps < 1e-3) <= 2, np.sort(ps)[:5]
    assert np.sum(ps < 0.05) <= stats.binom.isf(3e-4, len(ps), 0.05), np.sort(ps)[:20]
