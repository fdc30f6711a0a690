"""The ``quantisation`` term (issue 18 item 2): the expected visit-mean error of a digital output
rounded to an LSB q, the simulator's term, ``fit --effects ...,quantisation`` and the diagnosis's
refit-only candidate (docs/diagnosis.md "quantisation", docs/model.md "Quantisation").

The campaigns of the diagnosis tests are made ANOTHER way: ``tests/independent_bench.py`` gives the
true visit outputs (no noise), and here every visit's stream of samples is drawn, rounded with
``np.round`` and averaged -- the formula under test is never used to make the data.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from independent_bench import default_truth, simulate_campaign  # noqa: E402

from triadcal.io.bench_csv import parse_bench_csv  # noqa: E402
from triadcal.judgement.diagnose import diagnose  # noqa: E402
from triadcal.models.effects.quantisation import (  # noqa: E402
    expected_error,
    expected_error_slope,
    resolution_lsb,
    rounded_variance,
)

SIGMA = 5e-4            # per-sample noise SD, V (the independent bench's default noise_sd)
N_SAMPLES = 3000        # samples per visit mean (30 s at 100 Hz)
MODEL = ("angle_tempco", "scale_tempco", "bias_tempco")
#: the candidates a quantisation gap could be mistaken for (a restricted set keeps a test < 5 s;
#: the slow test runs the whole vocabulary)
RIVALS = ("quantisation", "position_error", "heavy_tails", "angle_tempco2", "scale_tempco2", "bias_tempco2",
          "bias_drift")
OPTS = dict(n_draws=100, seed=0, cross_group=False)


def rounded_campaign_text(seed: int, q: float | None, *, truth=None, hide_resolution: bool = False) -> str:
    """Bench CSV text of an independent-bench campaign (12 positions x 5 setpoints) whose visit means
    are averages of N_SAMPLES samples ``x + N(0, SIGMA^2)``, each rounded to ``q`` (``None``: not
    rounded), with ``sd_*`` the SD of those samples. ``hide_resolution``: every mean perturbed by 1e-11
    of itself, so that the means are no longer multiples of q/N (the LSB must then be profiled)."""
    rng = np.random.default_rng(seed)
    text, _ = simulate_campaign(rng, truth=truth if truth is not None else default_truth(rng),
                                noise_sd=0.0, n_samples=N_SAMPLES)
    lines = text.splitlines()
    h = next(i for i, line in enumerate(lines) if line.startswith("unit,"))
    cols = lines[h].split(",")
    iw = [cols.index(f"w_{a}") for a in "xyz"]
    isd = [cols.index(f"sd_{a}") for a in "xyz"]
    out = lines[:h + 1]
    for line in lines[h + 1:]:
        f = line.split(",")
        for a in range(3):
            y = float(f[iw[a]]) + SIGMA * rng.standard_normal(N_SAMPLES)
            if q is not None:
                y = np.round(y / q) * q
            m = float(y.mean())
            if hide_resolution:
                m *= 1.0 + 1e-11 * rng.standard_normal()
            f[iw[a]], f[isd[a]] = repr(m), repr(float(y.std(ddof=1)))
        out.append(",".join(f))
    return "\n".join(out) + "\n"


def _candidate(d, name="quantisation"):
    return next(c for c in d.candidates if c.effect == name)


# -- (a) the formula ---------------------------------------------------------------------------------
@pytest.mark.parametrize("sigma_over_q", [0.1, 0.2, 0.3, 0.45])
def test_the_series_is_the_average_of_rounded_gaussian_samples(sigma_over_q):
    """Brute force: the mean of 2e5 rounded samples of x + N(0, sigma^2) at 11 points of x over two
    periods; each within 4 Monte-Carlo standard errors of the series (P(|z| > 4) = 6e-5 per point)."""
    rng = np.random.default_rng(7)
    q, s, n = 1.0, sigma_over_q, 200_000
    x = np.linspace(-1.37, 0.91, 11)
    y = np.round((x[:, None] + s * rng.standard_normal((x.size, n))) / q) * q
    mc, se = y.mean(axis=1) - x, y.std(axis=1) / np.sqrt(n)
    e = expected_error(x, q, s)
    assert np.all(np.abs(mc - e) < 4 * se), (mc, e, se)
    # the effect is there to see at these sigma (not a trivial zero): largest |e| > 3 SE
    assert np.max(np.abs(e)) > 3 * np.max(se)


def test_the_series_limits_and_slope():
    # sigma << q: the sawtooth round(x) - x (away from its jumps at half-integers)
    x = np.array([-2.3, -1.1, -0.2, 0.0, 0.15, 0.33, 1.4, 7.7])
    assert np.allclose(expected_error(x, 1.0, 1e-3), np.round(x) - x, atol=2e-3)
    # sigma >> q: nothing left (the first term is (q/pi) exp(-2 pi^2) = 8e-10 q at sigma = q)
    assert np.max(np.abs(expected_error(x, 1.0, 1.5))) < 1e-18
    # periodic in x with period q; odd in x
    assert np.allclose(expected_error(x + 3.0, 1.0, 0.3), expected_error(x, 1.0, 0.3), atol=1e-12)
    assert np.allclose(expected_error(-x, 1.0, 0.3), -expected_error(x, 1.0, 0.3), atol=1e-12)
    # slope against central differences
    h = 1e-6
    fd = (expected_error(x + h, 1.0, 0.3) - expected_error(x - h, 1.0, 0.3)) / (2 * h)
    assert np.allclose(expected_error_slope(x, 1.0, 0.3), fd, atol=1e-6)


def test_the_resolution_of_means_of_rounded_samples_gives_the_lsb():
    rng = np.random.default_rng(3)
    q, n = 1.5e-3, 3000
    w = np.round(rng.normal(0.0, 1.0, (60, 3)) * n / q) * q / n
    assert resolution_lsb(w, np.full(60, n)) == pytest.approx(q, rel=1e-9)
    assert resolution_lsb(rng.normal(0.0, 1.0, (60, 3)), np.full(60, n)) is None


# -- (b) named on data rounded per sample ---------------------------------------------------------------
@pytest.mark.parametrize("seed", [1, 2])
def test_rounded_samples_are_named_quantisation_with_the_lsb(seed):
    """q = 3 sigma: the expected error's first term has amplitude (q/pi) exp(-2 pi^2/9) = 53 uV,
    6 times the visit noise 9.1 uV. The means are multiples of q/N, so the LSB is found exactly."""
    q = 3 * SIGMA
    d = diagnose(parse_bench_csv(rounded_campaign_text(seed, q)), model=MODEL, candidates=RIVALS, **OPTS)
    assert d.verdict["effect"] == "quantisation", d.verdict
    c = _candidate(d)
    form = c.refit["form"]
    assert form["lsb"] == pytest.approx(q, rel=1e-9)
    assert form["lsb_unit"] == "V" and form["beats_simpler"]
    assert d.verdict["gap_closed"], d.verdict
    assert "--quantisation-lsb" in d.verdict["fit_options"]


def test_the_lsb_is_profiled_when_the_resolution_is_hidden():
    """The means perturbed by 1e-11: no stated LSB, so q comes from the log grid (ratio 600^(1/39) =
    1.18 between points) refined between the best point's neighbours on the scale q^2/max|W| (relative
    step q/(4 max|W|) = 3.7e-4 here); chi^2(q) is periodic on the scale q/max|W| = 1.5e-3, so q must
    come out within a few of those periods of the truth (1 %) and be named."""
    q = 3 * SIGMA
    d = diagnose(parse_bench_csv(rounded_campaign_text(1, q, hide_resolution=True)), model=MODEL,
                 candidates=RIVALS, **OPTS)
    form = _candidate(d).refit["form"]
    assert form["stated_lsb"] is None
    assert abs(form["lsb"] / q - 1) < 0.01, form["lsb"]
    assert d.verdict["effect"] == "quantisation", d.verdict


# -- (c) clean data: not named --------------------------------------------------------------------------
@pytest.mark.parametrize("q_over_sigma", [None, 0.5])
def test_clean_or_finely_rounded_data_are_not_named(q_over_sigma):
    """No rounding, or an LSB of sigma/2 (first term (q/pi) exp(-8 pi^2) = 1e-35 q): no quantisation."""
    q = None if q_over_sigma is None else q_over_sigma * SIGMA
    d = diagnose(parse_bench_csv(rounded_campaign_text(3, q)), model=MODEL, candidates=RIVALS, **OPTS)
    assert d.verdict["effect"] is None, d.verdict
    c = _candidate(d)
    # not refitted when no q of the coarse profile lowers the chi^2 by half the criterion (3.3)
    assert (c.refit is None and "lowers the chi^2 by more than" in c.reason) or not c.refit["form"]["beats_simpler"]


# -- (d) another structured gap is not named quantisation --------------------------------------------------
def test_a_withheld_quadratic_tempco_is_not_named_quantisation():
    rng = np.random.default_rng(11)
    t = default_truth(rng)
    t["Ca_xy_tempco2"] = 0.004          # arcsec/degC^2: 10 arcsec at 50 degC from T0
    text, _ = simulate_campaign(rng, truth=t, noise_sd=SIGMA, n_samples=N_SAMPLES)
    d = diagnose(parse_bench_csv(text), model=MODEL, candidates=RIVALS, **OPTS)
    assert d.verdict["effect"] == "angle_tempco2", d.verdict
    c = _candidate(d)        # not refitted (no q gains 3.3 on the coarse profile), or refitted and beaten
    assert (c.refit is None and "lowers the chi^2 by more than" in c.reason) or not c.refit["form"]["beats_simpler"]


# -- (e) the fit option on a bench CSV -----------------------------------------------------------------------
def test_cli_fit_with_the_lsb_option(tmp_path):
    from triadcal.cli import main

    q = 3 * SIGMA
    data = tmp_path / "digital.csv"
    data.write_text(rounded_campaign_text(1, q))
    out = tmp_path / "r.json"
    code = main(["fit", str(data), "--effects", ",".join(MODEL) + ",quantisation", "--quantisation-lsb", repr(q),
                 "--quiet", "--json", str(out)])
    r = json.loads(out.read_text())
    block = r["fit"]["quantisation"]
    assert block["lsb"] == q and block["unit"] == "V" and block["how"] == "given"
    assert block["beats_without"] and block["chi2_with"] < block["chi2_without"]
    # with the term the fit is at the noise: chi2/dof within the 99.9 % band of chi2(156)/156
    assert 0.7 < r["fit"]["chi2_dof"] < 1.4
    assert code == (0 if r["status"] == "ok" else 3)
    # the same file without the term: the gates see the misfit
    out0 = tmp_path / "r0.json"
    main(["fit", str(data), "--effects", ",".join(MODEL), "--quiet", "--json", str(out0)])
    assert json.loads(out0.read_text())["fit"]["chi2_dof"] > 3


# -- the simulator ---------------------------------------------------------------------------------------------
def test_the_simulator_adds_the_expected_error_only_when_on():
    from triadcal.models.simulate import NoiseModel, Truth, preset_truth, simulate_campaign as sim

    base = preset_truth("ak18-quartz")
    off = sim(base, seed=5)
    assert "quantisation_lsb" not in base.to_dict()["noise"]           # old truths unchanged
    s_sample = np.sqrt(base.noise.Q_V2s * base.noise.sample_rate_hz)
    q = 3 * s_sample
    on_truth = Truth(unit=base.unit, effects=base.effects, parameters=base.parameters,
                     noise=NoiseModel(**{**base.noise.__dict__, "quantisation_lsb": q}))
    on = sim(on_truth, seed=5)
    assert Truth.from_dict(on_truth.to_dict()).noise.quantisation_lsb == q
    assert float(on.metadata["quantisation_lsb"]) == q
    # same draws: on.w - off.w = e(w_true) + (f - 1) sigma eps, f = sqrt(V)/sigma_sample the wider
    # scatter of rounded samples (V their variance, about sigma^2 + q^2/12)
    f = np.sqrt(rounded_variance(off.w, q, s_sample)) / s_sample
    sigma_mean = np.sqrt(base.noise.Q_V2s / on.tau_s)[:, None]
    e = expected_error(off.w, q, s_sample)           # at off.w = w_true + sigma eps: slope * sigma eps off
    bound = 5 * sigma_mean * (np.abs(f - 1) + np.max(np.abs(expected_error_slope(off.w, q, s_sample))) + 0.01)
    assert np.all(np.abs((on.w - off.w) - e) < bound)
    assert np.max(np.abs(e)) > 3 * np.max(sigma_mean)      # the term is there to see (5.8 visit SDs)
    assert np.allclose(np.sqrt(np.mean(on.sd ** 2, axis=0)), np.sqrt(s_sample ** 2 + q * q / 12), rtol=0.1)
