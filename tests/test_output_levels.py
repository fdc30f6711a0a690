"""The gate ``goodness_of_fit_per_output`` (estimation/output_levels.py): each output's chi2 against its
own declared noise, so that declared levels wrong in opposite directions cannot cancel in the pooled
chi2 (an outside probe of ``sample``: sd_x 0.6 times x's scatter, sd_y and sd_z twice theirs, pooled
chi2/dof 0.8-1.3: 6 of 8 seeds ``ok``, 47 of 60 of x's 95 % intervals holding the truth).

Made another way: the data by the independent bench (tests/independent_bench.py, numpy), the sd_*
columns rewritten; the dof split by hand on a linear model whose expectation is exact."""
from __future__ import annotations

import numpy as np
import pytest

from triadcal.estimation.output_levels import output_levels, per_output_gate


def test_each_outputs_dof_is_its_expected_chi2_on_a_linear_model():
    """For a linear least-squares fit E r_i^2 = 1 - h_i exactly, so E chi2_a = dof_a for each output
    however the parameters load the outputs; the dofs sum to n - p. 2000 noise draws on one design whose
    parameters act on x far more than on z: the mean chi2 of each output within 4 SE (SE sqrt(2 dof /
    2000)) of its dof, and the dofs far from the naive (n - p) / 3."""
    rng = np.random.default_rng(3)
    n = 60
    J = rng.standard_normal((3 * n, 9))
    J[2::3] *= 0.05                  # z hardly informs the parameters: its dof close to n
    Q, _ = np.linalg.qr(J)
    lev = output_levels(np.zeros(3 * n), J)
    dofs = np.array([x["dof"] for x in lev])
    assert abs(dofs.sum() - (3 * n - 9)) < 1e-9
    assert dofs[2] > n - 0.2 and dofs[0] < n - 3.5, dofs
    E = rng.standard_normal((3 * n, 2000))
    R = E - Q @ (Q.T @ E)
    for a in range(3):
        chi2 = np.sum(R[a::3] ** 2, axis=0)
        assert abs(chi2.mean() - dofs[a]) < 4 * np.sqrt(2 * dofs[a] / 2000), (a, chi2.mean(), dofs[a])


def test_the_gate_by_hand():
    """Fails on a significant and material excess of one output; a low output only noted; a
    significant but immaterial one (ratio 1.1 on 10^5 dof) passes, as the pooled gate."""
    mk = lambda ratios, dof=50.0: [{"axis": a, "chi2": r * dof, "dof": dof, "ratio": r,
                                    "p_high": float(__import__("scipy").stats.chi2.sf(r * dof, dof))}
                                   for a, r in zip("xyz", ratios)]
    g = per_output_gate(mk((2.5, 0.2, 0.2)), 1e-3, 1.2)
    assert g.passed is False and g.status == "model_mismatch" and "output x scatters 1.6 times its sd_x" in g.reason
    g = per_output_gate(mk((1.0, 0.2, 1.0)), 1e-3, 1.2)
    assert g.passed is True and "below its declared noise: y" in g.reason
    assert per_output_gate(mk((1.1, 1.0, 1.0), 1e5), 1e-3, 1.2).passed is True
    assert per_output_gate(None, 1e-3, 1.2, "a robust loss").passed is None


def _campaign(tmp_path, seed, factors):
    """The independent bench at five setpoints, with the sd_x, sd_y, sd_z columns multiplied by
    ``factors`` (what the file declares; the data keep the true noise)."""
    from independent_bench import simulate_campaign

    text, truth = simulate_campaign(np.random.default_rng(seed), setpoints_C=(20, 60, 20, -20, 20),
                                    tilt_arcsec=(30.0, -20.0))
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("unit,"))
    cols = lines[i].split(",")
    out = lines[: i + 1]
    for ln in lines[i + 1:]:
        f = ln.split(",")
        for c, m in zip(("sd_x", "sd_y", "sd_z"), factors):
            f[cols.index(c)] = repr(float(f[cols.index(c)]) * m)
        out.append(",".join(f))
    path = tmp_path / f"levels_{seed}.csv"
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    return path


def _fit(path):
    from triadcal.estimation.joint import fit_joint
    from triadcal.io.bench_csv import read_bench_csv

    return fit_joint(read_bench_csv(path))


def _gate(res):
    return next(o for o in res.extra["gates"]["outcomes"] if o["gate"] == "goodness_of_fit_per_output")


@pytest.mark.parametrize("seed", [1, 2])
def test_declared_levels_that_cancel_in_the_pooled_chi2_are_refused_naming_the_output(tmp_path, seed):
    """sd_x 0.65 times the truth, sd_y and sd_z twice: the pooled goodness of fit passes (chi2/dof
    (2.37 + 0.25 + 0.25) / 3 ~ 0.96), the per-output gate fails naming x, the status model_mismatch.
    With the columns as written by the bench, the gate passes and the fit is ok."""
    res = _fit(_campaign(tmp_path, seed, (0.65, 2.0, 2.0)))
    pooled = next(o for o in res.extra["gates"]["outcomes"] if o["gate"] == "goodness_of_fit")
    assert pooled["passed"] is True, pooled
    g = _gate(res)
    assert g["passed"] is False and "output x scatters" in g["reason"] and 1.4 < g["value"] < 4.0, g
    assert res.status == "model_mismatch"
    ok = _fit(_campaign(tmp_path, seed, (1.0, 1.0, 1.0)))
    assert ok.status == "ok" and _gate(ok)["passed"] is True, (ok.status, ok.notes)
