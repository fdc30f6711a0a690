"""`triadcal validate`: its options, failed campaigns in the summary, and the verdict behind the exit
code (docs/posterior.md, "The verdict"): the coverage tests the docs state, valid at any number of
campaigns, on synthetic SBC results (quick; the 200-campaign proof is tests/test_validation.py, slow).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

import triadcal.api
from triadcal.cli import main as cli_main
from triadcal.judgement.validation import LEVELS, METHODS, SBCResult, pooled_coverage_pvalue

P = 32


def _covered(n, level, hits, rng):
    """(n, P) 0/1 indicators, ``hits[k]`` of the n covered for parameter k, at random campaigns."""
    out = np.zeros((n, len(hits)))
    for k, h in enumerate(hits):
        out[rng.permutation(n)[:h], k] = 1.0
    return out


def _result(n, hits95=None, hits68=None, seed=0, statuses=None):
    """A synthetic SBC result: uniform ranks (every bin equally full), and coverage with exactly
    ``hits`` covered per parameter (default: the nominal count)."""
    names = tuple(f"p{k}" for k in range(P))
    ranks = np.array([(np.arange(n) * 100 // n + k) % 100 for k in range(P)], float).T
    hits = {0.95: hits95 if hits95 is not None else [round(0.95 * n)] * P,
            0.68: hits68 if hits68 is not None else [round(0.68 * n)] * P}
    cov = {m: {lv: _covered(n, lv, hits[lv], np.random.default_rng(seed)) for lv in LEVELS} for m in METHODS}
    return SBCResult(names=names, n_ranks=99, truths=np.zeros((n, P)),
                     ranks={m: ranks.copy() for m in METHODS}, covered=cov,
                     statuses=statuses or ["ok"] * n, seconds=1.0)


def _cli(capsys, monkeypatch, result, *argv):
    monkeypatch.setattr(triadcal.api, "validate", lambda *a, **k: result)
    rc = cli_main(["validate", "--campaigns", str(result.n_campaigns), "--processes", "1", "--no-progress",
                   *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


# -- options ----------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, words", [
    (["--processes", "0"], ["--processes must be an integer >= 1"]),
    (["--processes", "-1"], ["--processes must be an integer >= 1"]),
    (["--seed", "-1"], ["--seed must be", "4294967295"]),
    (["--seed", "99999999999999999999"], ["--seed must be", "4294967295"]),
    (["--ess", "nan"], ["--ess must be a finite number > 0"]),
    (["--ess", "-1"], ["--ess must be a finite number > 0"]),
    (["--ranks", "0"], ["--ranks must be an integer >= 1"]),
    (["--ranks", "100000"], ["--ranks 100000 exceeds --ess 400"]),
    (["--campaigns", "0"], ["--campaigns must be an integer >= 1"]),
])
def test_validate_option_out_of_range_is_refused_before_any_campaign(capsys, tmp_path, argv, words):
    out = tmp_path / "s.json"
    # --campaigns 1 first: the old code ran one campaign (or failed it) for what it did not refuse
    rc = cli_main(["validate", "--campaigns", "1", *argv, "--no-progress", "--json", str(out)])
    err = capsys.readouterr().err
    assert rc == 1, err
    assert "internal error" not in err and len(err.strip().splitlines()) == 1, err
    for w in words:
        assert w in err, err
    assert not out.exists()


# -- failed campaigns -------------------------------------------------------------------------
def _all_failed(n=2):
    r = _result(n, statuses=["error"] * n)
    for m in METHODS:
        r.ranks[m][:] = np.nan
        for lv in LEVELS:
            r.covered[m][lv][:] = np.nan
    r.reasons = ["ValueError: Cannot take a larger sample than population when 'replace=False'"] * n
    return r


def test_summary_of_failed_campaigns_holds_status_and_reason_and_is_strict_json():
    s = _all_failed().summary()
    text = json.dumps(s, allow_nan=False)                # no NaN: strict JSON
    assert s["failed"] == 2
    assert s["failed_campaigns"] == [{"campaign": i, "status": "error", "reason": "ValueError: Cannot take a "
                                      "larger sample than population when 'replace=False'"} for i in range(2)]
    assert s["verdict"]["passed"] is False and "larger sample" in text


def test_cli_summary_never_crashes_on_failed_campaigns(capsys, monkeypatch):
    rc, out, err = _cli(capsys, monkeypatch, _all_failed())
    assert rc == 3, err
    assert "internal error" not in err
    assert "2 of 2 campaigns failed" in err and "campaign 0: error (ValueError" in err, err
    assert "n/a" in out


def test_one_campaign_says_why_it_cannot_pass(capsys, monkeypatch):
    rc, out, err = _cli(capsys, monkeypatch, _result(1))
    assert rc == 3
    assert "ranks: the chi-square test of p0 cannot be computed: 1 campaign(s) with a rank, fewer than the 2 " \
           "bins" in err, err
    assert "run at least" in err


# -- the verdict: coverage -------------------------------------------------------------------
def test_calibrated_result_passes_at_200_and_at_20(capsys, monkeypatch):
    for n in (200, 20):
        v = _result(n).verdict()
        assert v["passed"] and v["conclusive"], [c["message"] for c in v["checks"] if not c["passed"]]
        bands = [c for c in v["checks"] if c["test"].endswith("band")]
        assert bool(bands) == (n >= 200)          # the fixed +-0.03 rules only at the docs' 200 campaigns
    rc, out, err = _cli(capsys, monkeypatch, _result(200))
    assert rc == 0 and "verdict: no check failed" in out, err


def test_one_parameter_with_bad_95_coverage_fails_with_its_numbers(capsys, monkeypatch):
    hits = [190] * P
    hits[5] = 160                                          # 0.80 of 200: binomial p ~ 1e-10
    rc, out, err = _cli(capsys, monkeypatch, _result(200, hits95=hits))
    assert rc == 3
    p = stats.binomtest(160, 200, 0.95).pvalue
    assert f"95% coverage of p5 0.800 (160 of 200): two-sided binomial p {p:.3g} <= 0.01/32" in err, err
    # with 20 campaigns a parameter covered 10 times of 20 fails too: the exact test is valid at any N
    hits = [19] * P
    hits[3] = 10
    v = _result(20, hits95=hits).verdict()
    failed = [c for c in v["checks"] if not c["passed"]]
    assert not v["passed"] and {c["test"] for c in failed} == {"coverage_binomial"}
    assert all(c["parameter"] == "p3" and c["level"] == 0.95 for c in failed)


def test_every_parameter_a_little_low_is_caught_by_the_pooled_tests():
    """0.90 for every parameter: no single binomial test rejects (p = 0.0034 > 0.01/32), the pooled
    coverage does (0.90: outside 0.95 +- 0.03, and its bound p < 0.01)."""
    v = _result(200, hits95=[180] * P).verdict()
    failed = {(c["test"], c["method"]) for c in v["checks"] if not c["passed"]}
    assert ("coverage_binomial", "posterior") not in failed
    assert {("coverage_pooled", "posterior"), ("coverage_pooled_band", "posterior"),
            ("coverage_outside_band", "posterior")} <= failed
    msg = [c["message"] for c in v["checks"] if c["test"] == "coverage_outside_band" and not c["passed"]][0]
    assert "32 of 32 parameters outside 0.95 +- 0.03 > 4" in msg


def test_few_campaigns_are_inconclusive_and_exit_3(capsys, monkeypatch):
    """With 2 campaigns the rank tests could not have failed: the verdict passes what it could
    test and says so, and the exit code is 3 (it was 0: a pass no test could have refused)."""
    v = _result(2).verdict()
    assert v["passed"] and not v["conclusive"] and v["campaigns_needed"] == 13
    rc, out, err = _cli(capsys, monkeypatch, _result(2))
    assert rc == 3
    assert "could not have failed with 2 campaigns" in out and "run at least 13 campaigns" in err, (out, err)
    assert "SBC verdict inconclusive" in err and "exit 3" in err


def test_verdict_agrees_with_the_slow_tests_rules_at_200():
    """What tests/test_validation.py asserts at 200 campaigns (Bonferroni min p, pooled 0.95 +- 0.03,
    the count outside +-0.03 against the 99 % quantile of Binomial(32, p_out)) implies the verdict."""
    hits = [190] * P
    hits[:4] = [184, 196, 184, 196]                       # on the band: inside, as the docs count
    s = _result(200, hits95=hits, seed=4).summary()
    p_out = stats.binom.cdf(183, 200, 0.95) + stats.binom.sf(196, 200, 0.95)
    for m in METHODS:
        d = s["methods"][m]
        assert d["coverage_95_n_outside_0.03"] == 0
        assert d["coverage_95_n_outside_0.03"] <= stats.binom.ppf(0.99, P, p_out)
        assert abs(d["coverage_95_pooled"] - 0.95) < 0.03 and d["coverage_95_binomial_min_p"] > 0.01 / P
    assert s["verdict"]["passed"]


def test_pooled_bound_is_valid_for_fully_correlated_indicators():
    """At full correlation each campaign's coverage is 0 or 1: the pooled count is Binomial(N, 0.95),
    and the bound of each tail may not fall below its exact probability; at independence it stays
    valid (conservative); a pooled coverage far off is refused."""
    from triadcal.judgement.validation import _stop_loss_bound

    for n, p in ((200, 0.95), (20, 0.95), (50, 0.68), (5, 0.68)):
        for t in range(n + 1):
            assert _stop_loss_bound(t, n, p) >= stats.binom.sf(t - 1, n, p) - 1e-12, (n, p, t)
        assert _stop_loss_bound(n, n, p) == pytest.approx(p ** n)     # all covered: exact
    rng = np.random.default_rng(1)
    rejected = sum(pooled_coverage_pvalue((rng.random(100) < 0.95).astype(float), 0.95) <= 0.01
                   for _ in range(300))
    assert rejected <= 6                                  # 0.01 of 300 is 3; a bound, so fewer
    assert pooled_coverage_pvalue(np.full(200, 0.88), 0.95) < 1e-3
    assert pooled_coverage_pvalue(np.full(200, 0.95), 0.95) == 1.0


def test_a_campaign_with_fewer_draws_than_ranks_fails_with_that_reason():
    """The library's own check, behind the up-front one (--ranks <= --ess): a campaign whose thinned
    draws are fewer than the ranks is recorded as failed, saying so (not numpy's sampling error)."""
    from triadcal.judgement.validation import _one_campaign, compact_schedule
    from triadcal.models.campaign import DEFAULT_PLAN

    out = _one_campaign((0, 0, (), compact_schedule(), dict(DEFAULT_PLAN), 100_000, 100, 2000))
    assert out["status"] == "error"
    assert "fewer than the 100000 ranks (--ranks)" in out["reason"], out["reason"]
