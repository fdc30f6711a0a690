"""A stated noise larger than the data's scatter (an outside probe: the sd_* columns tripled gave
chi2/dof 0.116 on 508 dof and every interval three times too wide, status ok, no word). The answer
is not wrong, so the status stays; a note says by how much the u are conservative. Campaigns from
the independent simulator (tests/independent_bench.py), read from a real file."""

import re

import numpy as np

from independent_bench import simulate_campaign
from triadcal.estimation.joint import OVERSTATED_P, fit_joint
from triadcal.io.bench_csv import read_bench_csv

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")


def fit_with_sd_times(tmp_path, factor, seed=3):
    text, _ = simulate_campaign(np.random.default_rng(seed), noise_sd=5e-4)
    path = tmp_path / f"sd_x{factor}.csv"
    path.write_text(text, encoding="utf-8")
    c = read_bench_csv(path)
    c.sd = c.sd * factor
    return fit_joint(c, effects=EFFECTS)


def test_a_tripled_noise_is_said_with_its_factor_and_the_status_stays(tmp_path):
    r = fit_with_sd_times(tmp_path, 3.0)
    notes = [n for n in r.notes if "scatter less than the stated noise" in n]
    assert r.status == "ok" and len(notes) == 1, r.notes
    factor = float(re.search(r"about ([\d.]+) times the scatter", notes[0]).group(1))
    assert 2.6 < factor < 3.4                         # sqrt(1/(chi2/dof)) ~ 3 (chi2 on ~ 500 dof: +-5 %)


def test_the_stated_noise_itself_gives_no_note(tmp_path):
    """The note's level is P(chi2 this small) < 1e-3: at the stated noise, one campaign in 1000."""
    assert OVERSTATED_P == 1e-3
    r = fit_with_sd_times(tmp_path, 1.0)
    assert not [n for n in r.notes if "scatter less than" in n], r.notes
    assert 0.85 < r.fit["chi2_dof"] < 1.15
