"""The default priors on the data's scale (``priors.autoscaled_priors``, docs/posterior.md "Priors").
The default ``K ~ N(1, 0.1)`` is in the file's own unit: a 5 mV/g analog unit (K = 200 g/V) sat
2 000 prior SDs from it and the posterior was pulled 6 u below the truth with status ok (an outside
probe). The default ``S ~ N(0, 0.02 g)``: biases of 0.3-0.5 g were pulled 4 u toward 0 with status ok,
95 % intervals holding 3 of 30 true biases (a second outside probe, its own numpy bench). The
campaigns are made by tests/independent_bench.py."""

from __future__ import annotations

import numpy as np
import pytest

from independent_bench import default_truth, simulate_campaign
from triadcal.estimation.posterior import sample
from triadcal.estimation.priors import AUTOSCALE_SDS, Prior, autoscaled_priors, default_priors
from triadcal.io.bench_csv import parse_bench_csv
from triadcal.models.model import Model

EFFECTS = ["bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco"]


def test_which_priors_are_autoscaled_by_hand():
    pri = default_priors(Model(tuple(EFFECTS)))
    assert (pri["K_x"].mean, pri["K_x"].sd) == (1.0, 0.1)
    s_sd = pri["S_x"].sd
    ls = {"K_x": 199.998, "K_y": 1.0 + AUTOSCALE_SDS * 0.1 - 1e-9, "K_z": 0.05, "S_x": 0.5,
          "S_y": AUTOSCALE_SDS * s_sd * 1.2, "S_z": -0.4}
    u = {"S_y": s_sd, "S_z": 0.004}       # S_y: 3.6 prior SDs, but within 3 of sqrt(sd^2 + u^2) = 1.41 sd
    user = {"K_z": Prior("K_z", "g/V", 0.05, 0.005, 0.0)}
    out, notes = autoscaled_priors({**pri, **user}, ls, user=user, u=u)
    assert (out["K_x"].mean, out["K_x"].sd, out["K_x"].low) == (200.0, pytest.approx(20.0), 0.0)
    assert out["K_x"].reason.startswith("autoscaled") and "K_x" in notes[0]
    assert out["K_y"] is pri["K_y"]                 # within 3 SD: the default (and SBC's) prior
    assert out["K_z"] is user["K_z"]                # the user's prior is kept
    # a bias the data put 25 prior SDs out: mean and bounds kept, the SD the distance (2 digits)
    assert (out["S_x"].mean, out["S_x"].sd) == (pri["S_x"].mean, 0.5) and out["S_x"].reason.startswith("widened")
    assert out["S_y"] is pri["S_y"]                 # the prior-predictive SD includes the estimate's u
    assert out["S_z"].sd == 0.4
    # the default's pull, |x| u / (sd^2 + u^2) = 0.4 x 0.004 / (0.02^2 + 0.004^2) = 3.85 u, is said
    assert "would pull the posterior 3.8 u toward 0" in [n for n in notes if "S_z" in n][0]
    assert len(notes) == 3


def test_a_200_g_per_volt_unit_is_not_pulled_by_the_prior():
    rng = np.random.default_rng(41)
    truth = default_truth(rng)
    for a, k in zip("xyz", (200.0, 210.0, 190.0)):
        truth[f"K_{a}"] = k
    text, truth = simulate_campaign(rng, truth=truth, noise_sd=5e-6)
    r = sample(parse_bench_csv(text), EFFECTS, ess=400, max_steps=4000, seed=1)
    assert r.status == "ok", r.notes
    for a in "xyz":
        p = r.parameters[f"K_{a}"]
        assert abs(p.value - truth[f"K_{a}"]) < 4 * p.u, (a, p, truth[f"K_{a}"])
        assert r.extra["priors"][f"K_{a}"]["mean"] == float(f"{truth[f'K_{a}']:.2g}")
    assert sum("centred on the unit's scale" in n for n in r.notes) == 3, r.notes


def test_biases_of_half_a_g_are_not_pulled_toward_zero():
    rng = np.random.default_rng(43)
    truth = default_truth(rng)
    for a, b in zip("xyz", (-0.46, 0.34, -0.36)):
        truth[f"S_{a}"] = b
    text, truth = simulate_campaign(rng, truth=truth, noise_sd=0.5, n_samples=100)   # 50 mg per visit mean
    r = sample(parse_bench_csv(text), EFFECTS, ess=400, max_steps=4000, seed=1)
    assert r.status == "ok", r.notes
    for a in "xyz":
        p = r.parameters[f"S_{a}"]
        # before: 3.6-5.1 u toward 0 (the default prior's pull 0.0043 x 0.4 / 0.02^2 ~ 4 u)
        assert abs(p.value - truth[f"S_{a}"]) < 3 * p.u, (a, p, truth[f"S_{a}"])
        assert r.extra["priors"][f"S_{a}"]["reason"].startswith("widened")
    assert sum("widened to the data's scale" in n for n in r.notes) == 3, r.notes
