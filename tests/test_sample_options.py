"""`triadcal sample`'s options and its not-converged note (docs/posterior.md, "Options and their ranges").

A value outside an option's range is one line naming the option and the range (exit 1), never an
emcee, numpy or CasADi error (exit 70) and never a value replaced in silence (an odd walker count
rounded up, 0 walkers read as the default, ``--ess nan`` running to --max-steps). A run that did not
converge says which number broke the stop rule, of which parameter.
"""

from __future__ import annotations

import re

import pytest

from triadcal.cli import main as cli_main
from triadcal.errors import InputError
from triadcal.estimation.posterior import sample
from triadcal.estimation.posterior.options import MIN_STEPS, SEED_MAX, walkers_for
from triadcal.models.model import Model
from triadcal.models.simulate import preset_truth, simulate_campaign

P = len(Model().names)          # the default effects' free parameters (32)


def _cli(capsys, *argv):
    rc = cli_main(["sample", "--example", "--quiet", "--no-progress", *map(str, argv)])
    return rc, capsys.readouterr().err


# --max-steps 300 keeps the old behaviour of the accepted-in-silence values short (a full run otherwise)
@pytest.mark.parametrize("option, value, words", [
    ("--max-steps", "0", [f">= {MIN_STEPS}"]), ("--max-steps", "1", [f">= {MIN_STEPS}"]),
    ("--max-steps", "2", [f">= {MIN_STEPS}"]), ("--max-steps", "-5", [f">= {MIN_STEPS}"]),
    ("--max-steps", str(MIN_STEPS - 1), [f">= {MIN_STEPS}"]),
    ("--walkers", "2", [f">= {2 * P}", f"{P} free parameters"]),
    ("--walkers", "4", [f">= {2 * P}", f"{P} free parameters"]),
    ("--walkers", "33", [f">= {2 * P}", f"{P} free parameters"]),
    ("--walkers", "-3", [f">= {2 * P}", f"{P} free parameters"]),
    ("--walkers", "0", [f">= {2 * P}", f"{P} free parameters"]),
    ("--walkers", str(2 * P - 1), ["even", f">= {2 * P}"]),
    ("--walkers", str(2 * P + 1), ["even", f">= {2 * P}"]),
    ("--seed", "-1", [str(SEED_MAX)]), ("--seed", str(SEED_MAX + 1), [str(SEED_MAX)]),
    ("--seed", "99999999999999999999", [str(SEED_MAX)]),
    ("--ess", "nan", ["finite number > 0"]), ("--ess", "inf", ["finite number > 0"]),
    ("--ess", "-1", ["finite number > 0"]), ("--ess", "0", ["finite number > 0"]),
])
def test_an_option_out_of_range_is_one_line_naming_it(capsys, tmp_path, option, value, words):
    out = tmp_path / "o.json"
    argv = [option, value, "--json", out]
    if option != "--max-steps":
        argv += ["--max-steps", "300"]
    rc, err = _cli(capsys, *argv)
    assert rc == 1, err
    assert "internal error" not in err and f"{option} must be" in err, err
    for w in words:
        assert w in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_walkers_rule_in_the_library():
    assert walkers_for(None, 32) == 64                  # not given: 2 x parameters
    assert walkers_for(64, 32) == 64 and walkers_for(100, 32) == 100
    for bad in (0, 2, 63, 65, -4, 64.5, "64"):
        with pytest.raises(InputError, match=r"even integer >= 64 \(2 x the 32 free parameters"):
            walkers_for(bad, 32)


@pytest.mark.parametrize("kw, option", [
    (dict(n_walkers=33), "--walkers"), (dict(n_walkers=0), "--walkers"), (dict(n_walkers=4), "--walkers"),
    (dict(seed=-1), "--seed"), (dict(seed=2 ** 40), "--seed"), (dict(max_steps=2), "--max-steps"),
    (dict(ess=float("nan")), "--ess")])
def test_the_library_refuses_them_too(example, kw, option):
    args = dict(max_steps=200, ess=100)
    args.update(kw)
    with pytest.raises(InputError, match=re.escape(option) + " must be"):
        sample(example, **args)


def test_the_smallest_max_steps_runs_and_says_not_converged(example):
    r = sample(example, max_steps=MIN_STEPS, seed=0)
    assert r.status == "not_converged"


def test_not_converged_note_names_the_failing_numbers_and_parameters():
    campaign = simulate_campaign(preset_truth("ak18-quartz"), seed=3)
    r = sample(campaign, max_steps=40, seed=0)
    assert r.status == "not_converged"
    note = r.notes[0]
    assert note.startswith("not converged within 40 steps")
    pp = r.extra["sampler"]["per_parameter"]
    worst_rhat = max(pp, key=lambda n: pp[n]["rhat"])
    low_bulk = min(pp, key=lambda n: pp[n]["ess_bulk"])
    low_tail = min(pp, key=lambda n: pp[n]["ess_tail"])
    broke = False
    if pp[worst_rhat]["rhat"] >= 1.01:
        assert f"R-hat {pp[worst_rhat]['rhat']:.4f} of {worst_rhat}" in note, note
        broke = True
    if pp[low_bulk]["ess_bulk"] < 2000:
        assert f"smallest bulk ESS {pp[low_bulk]['ess_bulk']:.0f} ({low_bulk}" in note, note
        broke = True
    if pp[low_tail]["ess_tail"] < 2000:
        assert f"smallest tail ESS {pp[low_tail]['ess_tail']:.0f} ({low_tail}" in note, note
        broke = True
    assert broke, pp                     # 40 steps cannot give ESS 2000: at least that is named
    # the rule is still stated, and the number follows it
    assert "ESS >= 2000" in note and "did not hold: " in note


def test_not_converged_note_when_only_ess_fails(example):
    r = sample(example, max_steps=300, ess=1e9, seed=0)
    note = r.notes[0]
    pp = r.extra["sampler"]["per_parameter"]
    low = min(pp, key=lambda n: pp[n]["ess_bulk"])
    assert f"smallest bulk ESS {pp[low]['ess_bulk']:.0f} ({low}" in note and "< 1e+09" in note, note
