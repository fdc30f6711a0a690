"""heavy_tails on campaigns whose sd_* columns differ from visit to visit, made another way
(tests/independent_bench.py for the means; the noise drawn here).

An outside probe (2026-12-02): Student-t noise (nu = 3, 5; a 5 % x 5 sigma mixture) with the sd_* columns
right was never named heavy_tails (0 of 19): after the Student-t refit its normal scores were tested by
slice tests built for least-squares residuals (orthogonal to the fit's columns); the t fit's are not, and
with per-visit sigma an S column is not quite constant, so a whole-axis offset came out at z = -63. The
project's simulator gives every visit one sigma and never showed it. These files: 0 of 4 named before,
4 of 4 now; Gaussian noise with the same sd_* stays `none`.
"""
import math

import numpy as np
import pytest

from independent_bench import simulate_campaign
from triadcal.io.bench_csv import read_bench_csv
from triadcal.judgement.diagnose import diagnose

SETPOINTS = (20, 35, 50, 70, 55, 40, 25, 10, -5, -25, -40, -25, -10, 5, 20)


def campaign_file(path, seed, nu):
    """The independent bench's means (noise-free) plus noise drawn here: Student-t of ``nu`` dof
    scaled to the declared variance (``nu`` inf: normal), the sd_* 5e-4 V +- 22 % with the setpoint."""
    text, _ = simulate_campaign(np.random.default_rng(seed), noise_sd=1e-12, setpoints_C=SETPOINTS)
    rng = np.random.default_rng(1000 + seed)
    lines = text.splitlines()
    head = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    cols = lines[head].split(",")
    iw = [cols.index(f"w_{a}") for a in "xyz"]
    isd = [cols.index(f"sd_{a}") for a in "xyz"]
    isp, ins = cols.index("setpoint_C"), cols.index("n_samples")
    out = lines[:head + 1]
    for ln in lines[head + 1:]:
        f = ln.split(",")
        sd = 5e-4 * (1.0 + 0.004 * (float(f[isp]) - 20.0))
        se = sd / math.sqrt(float(f[ins]))
        for a in range(3):
            e = rng.standard_normal() if math.isinf(nu) else rng.standard_t(nu) / math.sqrt(nu / (nu - 2.0))
            f[iw[a]] = repr(float(f[iw[a]]) + se * e)
            f[isd[a]] = repr(sd)
        out.append(",".join(f))
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    return read_bench_csv(path)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_student_t_noise_with_per_visit_sd_is_named_heavy_tails(tmp_path, seed):
    d = diagnose(campaign_file(tmp_path / "t.csv", seed, 3.0))
    assert d.verdict["effect"] == "heavy_tails", d.verdict


@pytest.mark.parametrize("seed", [1, 2])
def test_normal_noise_with_the_same_sd_is_at_the_floor(tmp_path, seed):
    d = diagnose(campaign_file(tmp_path / "n.csv", seed, math.inf))
    assert d.verdict["effect"] in (None, "none"), d.verdict
