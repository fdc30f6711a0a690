"""A step of the angles in time (judgement/diagnose/rivals.py ``angle_step_rival``; generic.py
``step_test``): the suffix-sum profile over the break against brute force, the Bonferroni level of
the family under the null, and a rival that is never "the candidate written another way".

Hand-made linear problems (numpy random matrices), no campaign: the algebra is checked by itself.
"""

import numpy as np
import pytest

from triadcal.judgement.diagnose.generic import step_test
from triadcal.judgement.diagnose.rivals import STEP_MIN_SIDE, angle_step_rival, rival_tests


def _problem(seed, n=60, p=8):
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(3 * n, p))
    Q, _ = np.linalg.qr(J)
    A = rng.normal(size=(3 * n, 6))
    t = np.sort(rng.uniform(0, 1e5, n))
    return rng, Q, A, t


def _brute(r, Q, A, t, min_side=STEP_MIN_SIDE):
    """S of every admissible break by least squares, one by one."""
    n = t.size
    out = {}
    for m in range(min_side, n - min_side + 1):
        H = np.repeat((np.arange(n) >= m).astype(float), 3)
        T = A * H[:, None]
        X = np.column_stack([Q, T])
        fit_b = Q @ (Q.T @ r)
        coef, *_ = np.linalg.lstsq(X, r, rcond=None)
        out[m] = float(np.sum((X @ coef - fit_b) ** 2))
    return out


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_profile_over_the_break_is_the_brute_force_one(seed):
    rng, Q, A, t = _problem(seed)
    m0, d = 23, rng.normal(0, 3.0, 6)
    r = rng.normal(size=Q.shape[0]) + A @ d * np.repeat((np.arange(t.size) >= m0).astype(float), 3)
    r = r - Q @ (Q.T @ r)                       # residuals of the base fit
    T, t_break, S, k, searched = angle_step_rival(r, Q, A, t)
    brute = _brute(r, Q, A, t)
    m_best = max(brute, key=brute.get)
    assert S == pytest.approx(brute[m_best], rel=1e-8)
    assert t[m_best - 1] < t_break < t[m_best]                 # the brute force's break
    assert abs(m_best - m0) <= 1, (m_best, m0)                 # next to the planted one
    assert k == 6 and searched == len(brute)
    assert np.allclose(T[: 3 * m_best], 0.0) and np.allclose(T[3 * m_best:], A[3 * m_best:])


def test_the_family_keeps_its_level_under_the_null():
    """Bonferroni over the breaks: the rejection rate at 0.01 is at most 0.01 (300 seeds: the
    binomial bound 0.01 + 3 SE = 0.027); it is conservative, neighbouring breaks being nearly the
    same test."""
    hits = 0
    for seed in range(300):
        rng, Q, A, t = _problem(1000 + seed)
        r = rng.normal(size=Q.shape[0])
        r = r - Q @ (Q.T @ r)
        res = step_test(r, Q, A, t, noise_known=True, dof=r.size - Q.shape[1])
        hits += res["p_value"] < 0.01
    assert hits / 300 <= 0.01 + 3 * np.sqrt(0.01 * 0.99 / 300), hits


def test_a_step_of_five_standard_errors_is_found():
    rng, Q, A, t = _problem(7)
    m0 = 30
    d = np.zeros(6)
    d[0] = 1.0
    H = np.repeat((np.arange(t.size) >= m0).astype(float), 3)
    step = A @ d * H
    step = step - Q @ (Q.T @ step)
    r = rng.normal(size=Q.shape[0]) + 5.0 * step / np.linalg.norm(step) * np.sqrt(6)
    r = r - Q @ (Q.T @ r)
    res = step_test(r, Q, A, t, noise_known=True, dof=r.size - Q.shape[1])
    assert res["p_value"] < 1e-3 and t[m0 - 2] < res["time_s"] < t[m0 + 1], res


def test_a_step_the_candidate_holds_is_an_alias_not_the_candidate_itself():
    """A play wide enough to switch once is a step on the campaign: its columns hold the rival's.
    Skipped as "the same term", the play was named (a knock of 8 arcsec, noise estimated); a step in
    time is never a term of temperature written another way, so it is an alias that the candidate
    does not beat: S = 0 on 0 dof, p = 1."""
    rng, Q, A, t = _problem(11)
    T, *_ = angle_step_rival(rng.normal(size=Q.shape[0]), Q, A, t)
    C = T.copy()
    r = rng.normal(size=Q.shape[0]) + C @ rng.normal(0, 3.0, 6)
    r = r - Q @ (Q.T @ r)
    assert rival_tests(r, Q, C, {"step": T}, True, r.size - 8) == []            # skipped: "c itself"
    (label, S, k, p), = rival_tests(r, Q, C, {"step": T}, True, r.size - 8, never_same=("step",))
    assert (label, S, k, p) == ("step", 0.0, 0, 1.0)
