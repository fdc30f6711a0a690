"""The scale factors' prior on the unit's own scale (``priors.autoscaled_scale_priors``,
docs/posterior.md "Priors"). The default ``K ~ N(1, 0.1)`` is in the file's own unit: a 5 mV/g
analog unit (K = 200 g/V) sat 2 000 prior SDs from it and the posterior was pulled 6 u below the
truth with status ok (an outside probe). The campaign is made by tests/independent_bench.py."""

from __future__ import annotations

import numpy as np
import pytest

from independent_bench import default_truth, simulate_campaign
from triadcal.estimation.posterior import sample
from triadcal.estimation.priors import AUTOSCALE_SDS, Prior, autoscaled_scale_priors, default_priors
from triadcal.io.bench_csv import parse_bench_csv
from triadcal.models.model import Model

EFFECTS = ["bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco"]


def test_which_priors_are_autoscaled_by_hand():
    pri = default_priors(Model(tuple(EFFECTS)))
    assert (pri["K_x"].mean, pri["K_x"].sd) == (1.0, 0.1)
    ls = {"K_x": 199.998, "K_y": 1.0 + AUTOSCALE_SDS * 0.1 - 1e-9, "K_z": 0.05, "S_x": 0.5}
    user = {"K_z": Prior("K_z", "g/V", 0.05, 0.005, 0.0)}
    out, notes = autoscaled_scale_priors({**pri, **user}, ls, user=user)
    assert (out["K_x"].mean, out["K_x"].sd, out["K_x"].low) == (200.0, pytest.approx(20.0), 0.0)
    assert out["K_x"].reason.startswith("autoscaled") and len(notes) == 1 and "K_x" in notes[0]
    assert out["K_y"] is pri["K_y"]                 # within 3 SD: the default (and SBC's) prior
    assert out["K_z"] is user["K_z"]                # the user's prior is kept
    assert out["S_x"] is pri["S_x"]                 # only the scale factors


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
