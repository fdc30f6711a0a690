"""The diagnosis does not depend on the unit of the outputs (issue 18; "units explicit at every
boundary").

Found 2026-11-29: one campaign of the independent bench (cross-coupling and a quadratic bias
tempco) written in volts and in counts (the outputs and their SDs times 16384, ``output_unit =
counts``: a digital unit's raw LSB) gave the same scores and chi^2 but not the same verdict. The
Laplace draws of PSIS-LOO took a square root of the parameters' covariance by an eigen-decomposition
of the covariance itself; in counts K is 6e-5 g/count, its variance 1e-21 beside the angles' arcsec^2,
and the decomposition lost it: Pareto k inf, delta elpd nan, and the refitted candidates ordered by
a broken elpd (the best partial answer ``bias_tempco2`` in counts, ``cross_coupling`` in volts). The
square root is now taken of the correlation matrix and scaled back (``fitting._chol``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from test_two_effects import B2, KC, bench_text  # noqa: E402

from triadcal.io.bench_csv import parse_bench_csv  # noqa: E402
from triadcal.judgement.diagnose import diagnose  # noqa: E402
from triadcal.judgement.diagnose.fitting import _chol  # noqa: E402

LSB_PER_V = 16384.0
W_COLUMNS = ("w_x", "w_y", "w_z", "sd_x", "sd_y", "sd_z")


def in_counts(text: str) -> str:
    """The same bench CSV with the outputs and their SDs in counts (times ``LSB_PER_V``)."""
    out, header = [], None
    for line in text.splitlines():
        if line.startswith("# output_unit"):
            out.append("# output_unit = counts")
        elif line.startswith("#") or not line.strip():
            out.append(line)
        elif header is None:
            header = line.split(",")
            out.append(line)
        else:
            f = line.split(",")
            for name in W_COLUMNS:
                i = header.index(name)
                f[i] = repr(float(f[i]) * LSB_PER_V)
            out.append(",".join(f))
    return "\n".join(out) + "\n"


def test_the_square_root_of_an_ill_scaled_covariance():
    """L L^T = C to rounding in every entry relative to its scale sqrt(C_ii C_jj), for a covariance
    whose variances span 1e-21 .. 1e4 (K in g/count beside angles and tempcos); and the factor of
    D C D is D times the factor of C (the parameters' units do not enter)."""
    rng = np.random.default_rng(3)
    A = rng.standard_normal((6, 6))
    R = A @ A.T + 6 * np.eye(6)
    d = np.array([1e-21, 1.0, 1e4, 3e-8, 2.0, 5e-15]) ** 0.5
    C = R * np.outer(d, d)
    L = _chol(C)
    scale = np.sqrt(np.outer(np.diag(C), np.diag(C)))
    assert np.max(np.abs(L @ L.T - C) / scale) < 1e-13
    D = np.diag([7.0, 1e-3, 1e5, 2.0, 1.0, 3e-4])
    assert np.allclose(_chol(D @ C @ D), D @ L, rtol=1e-12, atol=0)
    # a singular correlation (two parameters the same) still gives a square root
    C2 = np.array([[1e-20, 1e-10 * 1e-10], [1e-20, 1e-20]])
    L2 = _chol((C2 + C2.T) / 2)
    assert np.allclose(L2 @ L2.T, (C2 + C2.T) / 2, rtol=0, atol=1e-33)


def test_a_campaign_in_counts_is_diagnosed_as_in_volts():
    text = bench_text({**KC, **B2}, 1)       # the first two-effect pair of test_two_effects.py, seed 1
    model = ["angle_tempco", "scale_tempco", "bias_tempco"]
    cands = ["cross_coupling", "bias_tempco2", "position_error", "scale_cubic"]
    v, c = (diagnose(parse_bench_csv(t), model, candidates=cands, n_draws=100, seed=1, top=4)
            for t in (text, in_counts(text)))
    keys = ("effect", "best_partial", "gap_closed", "effects")
    assert {k: v.verdict.get(k) for k in keys} == {k: c.verdict.get(k) for k in keys}
    ev = {x.effect: x.refit for x in v.candidates if x.refit}
    ec = {x.effect: x.refit for x in c.candidates if x.refit}
    assert list(ev) == list(ec)
    for e in ev:
        assert np.isfinite(ec[e]["delta_elpd"]), (e, ec[e]["delta_elpd"])
        assert abs(ec[e]["delta_elpd"] - ev[e]["delta_elpd"]) < 1e-6 * max(1.0, abs(ev[e]["delta_elpd"])), e
        assert abs(ec[e]["lr_p_value"] - ev[e]["lr_p_value"]) <= 1e-9 + 1e-6 * ev[e]["lr_p_value"], e
    assert v.verdict["effect"] == "unexplained" and v.verdict["best_partial"] == "cross_coupling"
