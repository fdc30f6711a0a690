"""The classical method's thermal lines against a curved tempco (gate ``thermal_curvature``).

An outside probe (its own simulator): K2 0.1-0.2 ppm/degC^2 and S2 0.05-0.08 ug/degC^2 over
-40..70 degC; the classical lines' chi2/dof up to 3340 was widened by the Birge ratio (x58), status
ok, and the values at 20 degC were 1.2-1.3 U from the truth (a line through a parabola is biased at
the reference temperature, which widening does not correct); its compensation table was 4 u off.
Made here with the independent bench (tests/independent_bench.py), not the project's simulator.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from independent_bench import default_truth, simulate_campaign  # noqa: E402
from triadcal.estimation.classical import fit_classical  # noqa: E402
from triadcal.estimation.classical_sensitivity import curvature_test  # noqa: E402
from triadcal.io.bench_csv import read_bench_csv  # noqa: E402

SETPOINTS = (-40.0, -25.0, -10.0, 5.0, 20.0, 35.0, 50.0, 70.0)


def _campaign(tmp_path, seed, **extra):
    truth = default_truth(np.random.default_rng(seed))
    truth.update(extra.pop("truth", {}))
    text, _ = simulate_campaign(np.random.default_rng(seed + 100), truth=truth, setpoints_C=SETPOINTS, **extra)
    path = tmp_path / f"c{seed}.csv"
    path.write_text(text, encoding="utf-8")
    return read_bench_csv(path)


def _gate(result):
    return next((g for g in result.extra["gates"]["outcomes"] if g["gate"] == "thermal_curvature"), None)


def test_the_curvature_is_the_weighted_quadratic_fits():
    """Hand-checked against numpy's weighted polynomial fit: c2 equals the quadratic coefficient
    of ``np.polyfit(T, y, 2, w=1/sigma)``, and its t is that over the scatter about the quadratic
    (floored at the known variances)."""
    rng = np.random.default_rng(5)
    T = np.array([-40.0, -20.0, 0.0, 20.0, 40.0, 60.0, 80.0])
    sd = np.full(T.size, 2e-6)
    y = 1.0 + 3e-5 * (T - 20) + 2e-7 * (T - 20) ** 2 + rng.normal(0, 2e-6, T.size)
    v = curvature_test(T, y, sd ** 2, 20.0)
    c = np.polyfit(T - 20.0, y, 2, w=1.0 / sd)
    assert abs(v["c2"] - c[0]) < 1e-12
    resid = y - np.polyval(c, T - 20.0)
    s2 = max(1.0, float(np.sum((resid / sd) ** 2)) / (T.size - 3))
    X = np.column_stack([(T - 20) ** 2, T - 20, np.ones_like(T)]) / sd[:, None]
    sd_c2 = np.sqrt(s2 * np.linalg.inv(X.T @ X)[0, 0])
    assert abs(v["c2_sd"] / sd_c2 - 1) < 1e-9 and v["dof"] == 4
    assert curvature_test(T[:3], y[:3], sd[:3] ** 2, 20.0) is None          # three temperatures: no test


def test_a_curved_scale_factor_tempco_is_refused(tmp_path):
    c = _campaign(tmp_path, 1, truth={"K_y_tempco2": 0.15, "S_z_tempco2": 0.06e-6})
    r = fit_classical(c)
    g = _gate(r)
    assert r.status == "model_mismatch" and g["passed"] is False, (r.status, g)
    assert "K_y is curved" in g["reason"] or "S_z is curved" in g["reason"], g["reason"]
    assert "--thermal-order auto" in g["reason"]


def test_straight_tempcos_and_a_hysteresis_pass(tmp_path):
    """Linear tempcos over ten seeds: the gate passes (its family-wise false refusal is 0.001 per
    campaign); a hysteresis of 5 arcsec on every angle with the setpoints on both branches (a scatter
    without a curved shape, which the Birge ratio widens for: coverage 0.99 by an outside probe)
    passes too."""
    for seed in range(10):
        g = _gate(fit_classical(_campaign(tmp_path, seed)))
        assert g is not None and g["passed"] is True, (seed, g)
    hyst = {f"Ca_{ab}_hysteresis": 5.0 for ab in ("xy", "xz", "yx", "yz", "zx", "zy")}
    truth = default_truth(np.random.default_rng(3))
    truth.update(hyst)
    text, _ = simulate_campaign(np.random.default_rng(4), truth=truth, setpoints_C=(20, 50, 80, 50, 20, -10, -40, -10, 20),
                                hysteresis={"form": "offset"})
    (tmp_path / "h.csv").write_text(text, encoding="utf-8")
    g = _gate(fit_classical(read_bench_csv(tmp_path / "h.csv")))
    assert g is not None and g["passed"] is True, g
