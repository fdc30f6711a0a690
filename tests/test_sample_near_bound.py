"""A unit whose angle sits near the prior's bound (3600 arcsec, the answer gates' bound): the
sampler's independence proposal is centred on the MAP held a thousandth of the posterior's SD
inside the bound, not of the prior's (3 arcsec): at 3599 arcsec it sat 8.6 posterior SDs off,
acceptance 0.05, not converged in 6000 steps (an outside probe), and SBC draws that near the
bound made `validate` fail by chance. Campaign from the independent simulator."""

import numpy as np
import pytest

from independent_bench import default_truth, simulate_campaign
from triadcal.estimation.posterior import sample
from triadcal.estimation.posterior.laplace import MARGIN_OF_POSTERIOR_SD
from triadcal.io.bench_csv import read_bench_csv

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")


@pytest.mark.parametrize("angle", [3599.0, -3599.3])
def test_an_angle_near_the_bound_is_sampled_and_covered(tmp_path, angle):
    rng = np.random.default_rng(8)
    truth = {**default_truth(rng), "Ca_zx": angle}
    text, truth = simulate_campaign(rng, truth=truth, noise_sd=5e-4)
    path = tmp_path / "near_bound.csv"
    path.write_text(text, encoding="utf-8")
    r = sample(read_bench_csv(path), EFFECTS, seed=2, max_steps=3000)
    smp = r.extra["sampler"]
    assert r.status == "ok", (r.status, r.notes[-2:])
    assert smp["acceptance"] > 0.5 and smp["steps"] <= 1000, smp     # as far from any bound (0.88, 100-150)
    p = r.parameters["Ca_zx"]
    assert abs(p.value - truth["Ca_zx"]) < 4 * p.u
    assert MARGIN_OF_POSTERIOR_SD * p.u < 1e-3


def test_a_raised_angle_bound_is_the_priors_bound_too(tmp_path):
    """--angle-bound-arcsec 7200 with a unit at 4000 arcsec: the least-squares fit is ok at 4000, and
    the posterior samples within the raised bound (before: the prior kept 3600, pulled the angle to
    3599.95 and ended not converged, chi2/dof 4358, with no word of the bound)."""
    from triadcal.estimation.gates import GateConfig

    rng = np.random.default_rng(9)
    truth = {**default_truth(rng), "Ca_zx": 4000.0}
    text, truth = simulate_campaign(rng, truth=truth, noise_sd=5e-4)
    path = tmp_path / "a4000.csv"
    path.write_text(text, encoding="utf-8")
    r = sample(read_bench_csv(path), EFFECTS, seed=2, max_steps=3000, gates=GateConfig(angle_bound_arcsec=7200.0))
    assert r.status == "ok", (r.status, r.notes[-2:])
    p = r.parameters["Ca_zx"]
    assert abs(p.value - 4000.0) < 4 * p.u
    assert r.to_dict()["priors"]["Ca_zx"]["bounds"] == pytest.approx([-7200.0, 7200.0])
