"""A robust loss (``--loss huber`` / ``student_t``) on data with gross outliers, made another way
(tests/independent_bench.py, outliers added to the file's lines).

Before: the goodness of fit counted the down-weighted outliers (four 30-sigma outliers in 540
observations of an exact model: chi2/dof 8.2, ``model_mismatch``), and without a known noise the
loss had no scale (residuals ~1e-5 in V, all inside Huber's c: the "robust" fit was least squares,
S_x 8.7 u off). Now the inliers' chi2 is the goodness of fit, the outliers' remaining pull is the
``outliers`` gate, and an unknown noise gets a robust scale (triadcal/estimation/robust_check.py).
"""
import math

import numpy as np
import pytest

from independent_bench import simulate_campaign
from triadcal.estimation.joint import fit_joint
from triadcal.estimation.robust_check import outlier_threshold, robust_judgement
from triadcal.io.bench_csv import read_bench_csv

EFFECTS = ["bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco"]
NOISE_SD, N_SAMPLES = 5e-4, 3000
SIGMA = NOISE_SD / math.sqrt(N_SAMPLES)          # SD of a visit's mean output, V


def with_outliers(text: str, rows, axis: int = 0, size_sigma: float = 30.0, drop_sd: bool = False) -> str:
    """The CSV ``text`` with ``size_sigma`` x the visit noise added to output ``axis`` of data rows
    ``rows`` (0-based), optionally without the sd_* and n_samples columns (noise unknown)."""
    lines = text.splitlines()
    head = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    cols = lines[head].split(",")
    keep = [i for i, c in enumerate(cols) if not (drop_sd and (c.startswith("sd_") or c == "n_samples"))]
    iw = cols.index("w_" + "xyz"[axis])
    out = lines[:head] + [",".join(cols[i] for i in keep)]
    for k, ln in enumerate(lines[head + 1:]):
        f = ln.split(",")
        if k in rows:
            f[iw] = repr(float(f[iw]) + size_sigma * SIGMA)
        out.append(",".join(f[i] for i in keep))
    return "\n".join(out) + "\n"


def fit(tmp_path, text, name, loss):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return fit_joint(read_bench_csv(p), effects=EFFECTS, loss=loss)


def worst_z(result, truth):
    return max(abs(p.value - truth[k]) / p.u for k, p in result.parameters.items() if k in truth)


@pytest.mark.parametrize("seed", [1, 2])
def test_a_few_gross_outliers_are_what_the_robust_loss_is_for(tmp_path, seed):
    text, truth = simulate_campaign(np.random.default_rng(seed), noise_sd=NOISE_SD, n_samples=N_SAMPLES)
    bad = with_outliers(text, rows={7, 33})
    l2 = fit(tmp_path, bad, "l2.csv", "l2")
    assert l2.status == "model_mismatch"              # least squares: the outliers are a misfit
    hub = fit(tmp_path, bad, "hub.csv", "huber")
    assert hub.status == "ok", hub.notes
    assert worst_z(hub, truth) < 3.5
    note = next(n for n in hub.notes if n.startswith("huber loss: 2 of 180 observations"))
    # the file's lines: 5 metadata lines and the column names come first (1-based line numbers)
    assert "line 14 " in note and "line 40 " in note
    gof = hub.fit["robust_goodness_of_fit"]
    assert gof["n_outliers"] == 2 and gof["dof_inliers"] == 180 - 2 - len(hub.correlation_names)
    assert gof["outlier_sigma"] == pytest.approx(outlier_threshold(180, 1e-3))


def test_many_outliers_still_pull_the_answer_and_are_refused(tmp_path):
    text, truth = simulate_campaign(np.random.default_rng(3), noise_sd=NOISE_SD, n_samples=N_SAMPLES)
    hub = fit(tmp_path, with_outliers(text, rows=set(range(0, 60, 5))), "hub.csv", "huber")
    assert hub.status == "model_mismatch"
    gate = next(g for g in hub.extra["gates"]["outcomes"] if g["gate"] == "outliers")
    assert gate["passed"] is False and gate["value"] > 1.0
    assert "12 observation(s) beyond" in gate["reason"]


def test_a_missing_effect_is_not_excused_as_outliers(tmp_path):
    """A quadratic scale tempco (not in the model) with Huber: the inliers' chi2 still refuses."""
    rng = np.random.default_rng(4)
    text, truth = simulate_campaign(rng, noise_sd=NOISE_SD, n_samples=N_SAMPLES,
                                    truth={**_truth(rng), "K_x_tempco2": 0.05})
    hub = fit(tmp_path, text, "hub.csv", "huber")
    assert hub.status == "model_mismatch"


def _truth(rng):
    from independent_bench import default_truth

    return default_truth(rng)


def test_unknown_noise_gets_a_robust_scale(tmp_path):
    """No sd_* columns, no Q: the loss's scale from the residuals' MAD; before, Huber was least squares."""
    text, truth = simulate_campaign(np.random.default_rng(5), noise_sd=NOISE_SD, n_samples=N_SAMPLES)
    bad = with_outliers(text, rows={7, 33, 50}, drop_sd=True)
    clean = with_outliers(text, rows=set(), drop_sd=True)
    l2 = fit(tmp_path, bad, "l2.csv", "l2")
    hub = fit(tmp_path, bad, "hub.csv", "huber")
    ref = fit(tmp_path, clean, "ref.csv", "huber")
    assert not hub.fit["noise_known"] and hub.status == "ok"
    shift = max(abs(p.value - ref.parameters[k].value) / ref.parameters[k].u for k, p in hub.parameters.items())
    shift_l2 = max(abs(p.value - ref.parameters[k].value) / ref.parameters[k].u for k, p in l2.parameters.items())
    assert shift < 1.0 < shift_l2
    # the robust scale estimates the noise: Q = var(mean) * tau with tau 30 s
    q_true = SIGMA ** 2 * 30.0
    assert ref.fit["Q_estimate"] == pytest.approx(q_true, rel=0.35)     # 180 obs: SD of a MAD variance ~ 17 %
    assert "3 of 180 observations" in " ".join(hub.notes)


def test_first_order_pull_of_huber_outliers_on_a_mean():
    """Hand-derived: a mean of n observations, k at +30 sigma. Huber's estimate m solves
    sum psi(r_i - m) = 0; its shift from the outliers, to first order, is k c / n_c (n_c the
    residuals inside c). Checked against the M-estimate itself, computed here by bisection."""
    rng = np.random.default_rng(0)
    n, k, c = 400, 6, 1.345
    y = rng.normal(size=n)
    y[:k] += 30.0

    def score(m, data):
        return np.sum(np.clip(data - m, -c, c))

    def m_est(data):
        lo, hi = -5.0, 5.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if score(mid, data) > 0 else (lo, mid)
        return 0.5 * (lo + hi)

    m_all, m_clean = m_est(y), m_est(y[k:])
    r = y - m_all
    psi = np.clip(r, -c, c)
    slope = (np.abs(r) <= c).astype(float)
    J = -np.ones((n, 1))
    u = np.array([1.0 / math.sqrt(n)])
    gof, gate, notes = robust_judgement(r, J, psi, slope, u, ["m"], "huber", 1e-3, True)
    predicted = gate.value * u[0]
    assert gof["n_outliers"] == k
    assert predicted == pytest.approx(k * c / slope.sum() / 1.0, rel=1e-9)
    assert predicted == pytest.approx(abs(m_all - m_clean), rel=0.15)
