"""The encompassing test that a named effect must pass against its rivals (diagnose/rivals.py),
on a hand-made linear problem (no simulator, no model of this project): base columns 1 and x,
a second-order term x^2 (the "candidate") and an asymmetry |x| (the "rival") on a grid of x in
[-1, 1]; unit noise. The test statistic's law is known: with the candidate true at amplitude
b, S(c | base + t) is noncentral chi2(1, lambda) with lambda = b^2 |c_perp|^2, c_perp the
candidate's column after projection off span(1, x, |x|). Its rate of "not beaten" must match
that law's P(S < chi2_1 quantile at alpha) within a binomial band.
"""

import numpy as np
import pytest
from scipy import stats

from triadcal.judgement.diagnose.fitting import _hat_q
from triadcal.judgement.diagnose.rivals import SAME_TERM_FRACTION, encompassing, rival_tests, unbeaten_rivals

ALPHA = 0.01
X = np.linspace(-1.0, 1.0, 41)
BASE = np.column_stack([np.ones_like(X), X])
C = (X ** 2)[:, None]
T = np.abs(X)[:, None]


def _residual(y):
    Q = _hat_q(BASE)
    return y - Q @ (Q.T @ y), Q


def _lambda(b):
    A = np.column_stack([BASE, T])
    Q = _hat_q(A)
    cp = C[:, 0] - Q @ (Q.T @ C[:, 0])
    return b * b * float(cp @ cp)


def test_the_alias_of_the_truth_is_not_beaten_and_an_unrelated_term_is():
    rng = np.random.default_rng(7)
    y = 30.0 * np.abs(X) + rng.standard_normal(X.size)          # the truth is the rival |x|
    r, Q = _residual(y)
    S, k, p = encompassing(r, Q, C, T, True, X.size - 2)
    assert k == 1 and p >= ALPHA, (S, p)                          # x^2 adds nothing beyond |x|
    y = 30.0 * X ** 2 + rng.standard_normal(X.size)              # the truth is x^2; rival x^3
    r, Q = _residual(y)
    S, k, p = encompassing(r, Q, C, (X ** 3)[:, None], True, X.size - 2)
    assert p < 1e-6, (S, p)


def test_a_rival_in_the_candidates_span_or_the_base_span_is_no_rival():
    r, Q = _residual(np.random.default_rng(1).standard_normal(X.size))
    assert encompassing(r, Q, C, 3.0 * C + 1e-4 * T, True, 39) is None      # c written another way
    assert encompassing(r, Q, C, (2.0 - X)[:, None], True, 39) is None      # inside the base span
    # a group holding the candidate's own column besides others explains the data by the candidate
    assert encompassing(r, Q, C, np.column_stack([X ** 3, 2.0 * C[:, 0]]), True, 39) is None
    assert SAME_TERM_FRACTION < 0.1
    got = unbeaten_rivals(r, Q, C, {"same": 2.0 * C, "base": BASE[:, [1]]}, True, 39, ALPHA)
    assert got == []


@pytest.mark.parametrize("b", [2.0, 8.0])
def test_rival_tests_put_the_closest_rival_first_and_its_s_is_the_noncentrality_without_noise(b):
    """Noise-free y = b x^2 (the candidate true): S against the rival |x| is exactly the module
    docstring's noncentrality b^2 |c_perp|^2 (the noise's part is zero), and |x| is the closest
    rival (the odd x^3 leaves all of x^2's even part); c's own column written another way is no
    rival; unbeaten_rivals are the tests with p >= alpha, in the same order."""
    r, Q = _residual(b * X ** 2)
    rivals = {"x^3": (X ** 3)[:, None], "|x|": T, "same": 2.0 * C}
    tests = rival_tests(r, Q, C, rivals, True, X.size - 2)
    assert [t[0] for t in tests] == ["|x|", "x^3"]
    label, S, k, p = tests[0]
    assert k == 1 and abs(S - _lambda(b)) <= 1e-9 * _lambda(b), (S, _lambda(b))
    assert abs(p - stats.chi2.sf(_lambda(b), 1)) <= 1e-9 + 1e-6 * p and p >= tests[1][3]
    assert unbeaten_rivals(r, Q, C, rivals, True, X.size - 2, ALPHA) == [t for t in tests if t[3] >= ALPHA]


def test_an_alias_of_the_design_is_not_beaten_and_the_term_written_another_way_is_skipped():
    """On a design of x in {-1, 0, 1} only (a tumble test's g_a) x^2 and |x| are the same column:
    without a reference design the rival |x| is skipped as "the candidate written another way";
    with the reference (the 41-point grid, where they differ by 0.2 of the norm after the base) it is
    an alias that the candidate does not beat (S = 0 on 0 dof), while 2 x^2 stays skipped there too."""
    x = np.tile([-1.0, 0.0, 1.0], 10)
    base = np.column_stack([np.ones_like(x), x])
    Qb = _hat_q(base)
    y = 5.0 * np.abs(x) + np.random.default_rng(3).standard_normal(x.size)
    r = y - Qb @ (Qb.T @ y)
    c, rivals = (x ** 2)[:, None], {"|x|": np.abs(x)[:, None], "2 x^2": 2.0 * (x ** 2)[:, None]}
    assert encompassing(r, Qb, c, rivals["|x|"], True, x.size - 2) is None
    assert unbeaten_rivals(r, Qb, c, rivals, True, x.size - 2, ALPHA) == []
    calls = []

    def reference():
        calls.append(1)
        return _hat_q(BASE), C, {"|x|": T, "2 x^2": 2.0 * C}

    got = unbeaten_rivals(r, Qb, c, rivals, True, x.size - 2, ALPHA, reference)
    assert [g[0] for g in got] == ["|x|"] and got[0][1:] == (0.0, 0, 1.0), got
    assert calls == [1]                                  # the reference is built once
    # on the grid itself nothing is an alias: |x| is tested, not skipped, and x^2 is beaten there
    rg, Qg = _residual(30.0 * X ** 2 + np.random.default_rng(4).standard_normal(X.size))
    assert unbeaten_rivals(rg, Qg, C, {"|x|": T}, True, X.size - 2, ALPHA, reference) == []


@pytest.mark.parametrize("shape", ["asymmetry", "k2"])
def test_on_a_tumble_test_k2_and_an_asymmetry_are_never_named_one_for_the_other(shape):
    """The 12 poses of bench CSV v1 put every axis along or across gravity: K2 g_a^2 and an
    asymmetry |g_a| are the same columns there. A clean simulated campaign with either added with
    numpy (W_a += 25e-6 |W_a - median W_a|, or 25e-6 (W_a - median W_a)^2 / V per V^2) gets no
    named effect: 'unexplained', the gap closed, with the other shape among ``ambiguous_with``.
    Before the reference design the asymmetry was named K2 on 1 of 3 seeds and K2 the asymmetry
    on 2 of 3: a coin toss reported as a verdict."""
    from triadcal.judgement.diagnose import diagnose
    from triadcal.judgement.diagnosis_validation import scenario
    from triadcal.models.campaign import DEFAULT_PLAN
    from triadcal.models.simulate import Schedule, simulate_campaign

    truth, model = scenario("clean")
    c = simulate_campaign(truth, plan=DEFAULT_PLAN, schedule=Schedule(soak_s=1800.0), seed=11)
    w = np.asarray(c.w, float)
    dw = w - np.median(w, axis=0)
    amp = np.max(np.abs(dw), axis=0)
    c.w = w + (25e-6 * np.abs(dw) if shape == "asymmetry" else 25e-6 * dw ** 2 / amp)
    v = diagnose(c, model, n_draws=100, cross_group=False, slices_after=False, top=2, seed=11).verdict
    assert v["effect"] == "unexplained" and v["gap_closed"] is True, v
    pair = {"scale_nonlinearity", "scale_asymmetry"}
    assert v["best_partial"] in pair and (pair - {v["best_partial"]}) <= set(v["ambiguous_with"]), v
    assert "other poses tell them apart" in v["reason"], v["reason"]


@pytest.mark.parametrize("b", [0.0, 4.0, 8.0])
def test_not_beaten_rate_follows_the_noncentral_chi2(b):
    """Over 1000 seeds with the candidate x^2 true at amplitude b: the rate at which |x| is not
    beaten equals P(ncx2(1, lambda) < chi2_1 quantile) (lambda = 0: 1 - alpha) within 4.5
    binomial SD."""
    lam = _lambda(b)
    crit = stats.chi2.isf(ALPHA, 1)
    expect = stats.ncx2.cdf(crit, 1, lam) if lam > 0 else stats.chi2.cdf(crit, 1)
    rng = np.random.default_rng(2026)
    n = 1000
    lost = 0
    for _ in range(n):
        y = b * X ** 2 + rng.standard_normal(X.size)
        r, Q = _residual(y)
        lost += bool(unbeaten_rivals(r, Q, C, {"|x|": T}, True, X.size - 2, ALPHA))
    sd = np.sqrt(expect * (1 - expect) / n)
    assert abs(lost / n - expect) <= 4.5 * sd + 1e-9, (b, lam, lost / n, expect)


def test_estimated_noise_uses_the_f_form():
    """With the noise estimated (F form) the null rate of "beaten" is alpha as well: 1000 seeds of
    data with neither term, noise SD 3 (the F statistic is scale-free)."""
    rng = np.random.default_rng(11)
    n, beaten = 1000, 0
    for _ in range(n):
        y = 3.0 * rng.standard_normal(X.size)
        r, Q = _residual(y)
        r = r / np.sqrt(float(r @ r) / (X.size - 2))
        res = encompassing(r, Q, C, T, False, X.size - 2)
        beaten += res[2] < ALPHA
    sd = np.sqrt(ALPHA * (1 - ALPHA) / n)
    assert abs(beaten / n - ALPHA) <= 4.5 * sd, beaten / n


@pytest.mark.slow
def test_an_asymmetry_added_with_numpy_is_named_and_never_k2_when_it_is_not_a_candidate():
    """End to end on the validation's 28-pose campaign (clean, from the simulator) with a scale
    asymmetry of 25 ppm added with numpy (W_a += e |W_a - median W_a|, not the project's asymmetry
    term). With every candidate, ``scale_asymmetry`` is named: it beats K2, its near-alias, by the
    encompassing test. With ``scale_asymmetry`` left out, K2 closes most of that gap but is not
    named: 'unexplained', with the gap left open or with |g_a| (the asymmetry's shape, a generic
    term) among the rivals K2 does not beat. (Measured at 12, 18, 25 and 40 ppm: named in
    vocabulary each time; left out, 'unexplained' with the gap open each time.)"""
    from triadcal.judgement.diagnose import FORM_CANDIDATES, diagnose
    from triadcal.judgement.diagnosis_validation import VALIDATION_PLAN, VALIDATION_SOAK_S, scenario
    from triadcal.models.effects import VOCABULARY
    from triadcal.models.simulate import Schedule, simulate_campaign

    truth, model = scenario("clean")
    c = simulate_campaign(truth, plan=VALIDATION_PLAN, schedule=Schedule(soak_s=VALIDATION_SOAK_S), seed=7)
    w = np.asarray(c.w, float)
    c.w = w + 25e-6 * np.abs(w - np.median(w, axis=0))
    kw = dict(n_draws=100, cross_group=False, slices_after=True, top=2, seed=7)
    named = diagnose(c, model, **kw).verdict
    assert named["effect"] == "scale_asymmetry"
    # named, it carries the evidence that it beats its closest rival (K2's g_a^2 or the like)
    cr = named["closest_rival"]
    assert cr["k"] >= 1 and cr["p_value"] < ALPHA and f"beats its closest rival, {cr['rival']}" in named["evidence"]
    cands = [e for e in VOCABULARY + FORM_CANDIDATES if e != "scale_asymmetry"]
    v = diagnose(c, model, candidates=cands, **kw).verdict
    assert v["effect"] == "unexplained", v
    assert v.get("gap_closed") is False or "|g_a| on output a" in v.get("ambiguous_with", []), v


@pytest.mark.slow
def test_an_ambiguous_verdict_follows_the_contract_and_says_so():
    """The validation's K2 campaign at m = 1, seed 1000: K2 and the asymmetry both close the gap
    and neither beats the other (S about 3-7 on 3 dof), so the verdict is 'unexplained' with
    ``ambiguous_with`` naming the other; the JSON follows docs/results-json.md and the summary's
    verdict line says that the data cannot tell them apart."""
    import json
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_results_contract import assert_valid

    from triadcal.judgement.diagnose import diagnose
    from triadcal.judgement.diagnosis_validation import VALIDATION_PLAN, VALIDATION_SOAK_S, scenario
    from triadcal.models.simulate import Schedule, simulate_campaign
    from triadcal.reports.diagnosis import summary_text

    truth, model = scenario("scale_nonlinearity", magnitude=1.0)
    c = simulate_campaign(truth, plan=VALIDATION_PLAN, schedule=Schedule(soak_s=VALIDATION_SOAK_S), seed=1000)
    d = diagnose(c, model, n_draws=100, cross_group=False, slices_after=False, top=2, seed=1000)
    v = d.verdict
    assert v["effect"] == "unexplained" and v["gap_closed"] is True, v
    pair = {"scale_nonlinearity", "scale_asymmetry"}
    assert v["best_partial"] in pair and (pair - {v["best_partial"]}) <= set(v["ambiguous_with"]), v
    # the rival it beats least, with its test: not beaten at alpha
    assert v["closest_rival"]["rival"] == v["ambiguous_with"][0] and v["closest_rival"]["p_value"] >= 0.01, v
    assert_valid(json.loads(json.dumps(d.to_dict())), "triadcal.diagnosis")
    line = next(x for x in summary_text(d).splitlines() if x.startswith("verdict"))
    assert "cannot tell it from" in line, line


def test_a_zero_column_of_a_rival_neither_hides_nor_aliases_it():
    """A rival group with a column that vanishes on the design (a term zero at every pose) is
    judged by its other columns: beaten or not as they are, not skipped for the zero one."""
    rng = np.random.default_rng(9)
    r, Q = _residual(30.0 * X ** 2 + rng.standard_normal(X.size))
    T2 = np.column_stack([np.zeros(X.size), (X ** 3)])
    got = encompassing(r, Q, C, T2, True, X.size - 2)
    assert got is not None and got[2] < 1e-6, got
