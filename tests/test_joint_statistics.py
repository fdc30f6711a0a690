"""Statistical properties of the joint fit, by simulation (slow).

1000 campaigns of the standard plan (12 positions x 15 setpoints, heating and cooling
sweeps between -40 and +70 degC), bench tilt, tempcos and hysteresis on, white output
noise of known intensity. Tolerances come from sampling theory, stated at each check.
"""

import numpy as np
import pytest

from triadcal.estimation.classical import fit_classical
from triadcal.estimation.joint import JointProblem, fit_joint
from triadcal.models.model import Model
from triadcal.models.simulate import preset_truth, simulate_campaign

N = 1000
ANGLES = ("Ca_xy", "Ca_xz", "Ca_yx", "Ca_yz", "Ca_zx", "Ca_zy")


def campaign(truth, seed):
    c = simulate_campaign(truth, seed=seed)
    c.sd = None            # weights from the known intensity Q: sigma = sqrt(Q / tau) exactly
    c.n_samples = None
    return c


@pytest.fixture(scope="module")
def runs():
    truth = preset_truth("ak18-quartz")
    names = None
    est, u, classical = [], [], []
    refused = []
    for seed in range(N):
        c = campaign(truth, seed)
        r = fit_joint(c)
        if r.status != "ok":
            # a correct model is refused only by a gate's false alarm: the structure gate's level is
            # Holm 1e-3, so over 1000 campaigns at most 4 (P(5 or more) = 0.004 at p = 1e-3); one
            # (seed 191, orientation_even at Holm p 5.7e-4) when the gate was written
            refused.append((seed, r.status, [o["gate"] for o in r.extra["gates"]["outcomes"] if o["passed"] is False]))
            continue
        cl = fit_classical(c, values_only=True)      # its values only: the gates' work is not read here
        classical.append([cl[n] for n in ANGLES])
        if names is None:
            names = [n for n in r.parameters if n in truth.parameters]
        est.append([r[n].value for n in names])
        u.append([r[n].u for n in names])
    # Cramer-Rao bound: inverse Fisher information at the truth (Gaussian noise, known sigma)
    c0 = campaign(truth, 0)
    model = Model(truth.effects)
    problem = JointProblem(c0, model, np.sqrt(float(c0.metadata["Q_V2s"]) / c0.tau_s)[:, None].repeat(3, 1))
    x = np.array([truth.parameters[n] for n in problem.names])
    _, J = problem.residuals_and_jacobian(x)
    crb = np.linalg.inv(J.T @ J)
    crb_sd = {n: np.sqrt(crb[i, i]) for i, n in enumerate(problem.names)}
    assert len(refused) <= 4 and all(g == ["structure"] for _, _, g in refused), refused
    return truth, names, np.array(est), np.array(u), crb_sd, np.array(classical)


@pytest.mark.slow
def test_coverage_3u(runs):
    truth, names, est, u, _, _ = runs
    z = (est - np.array([truth.parameters[n] for n in names])) / u
    inside = np.mean(np.abs(z) <= 3)
    # Gaussian: 99.73 %; required >= 99 %
    assert inside >= 0.99, inside


@pytest.mark.slow
def test_reported_u_matches_spread(runs):
    truth, names, est, u, _, _ = runs
    spread = est.std(axis=0, ddof=1)
    ratio = spread / u.mean(axis=0)
    # sampling error of an SD from N = 1000: 1/sqrt(2 (N-1)) = 2.2 %; 10 % is 4.5 of those
    bad = {n: round(r, 3) for n, r in zip(names, ratio) if abs(r - 1) > 0.10}
    assert not bad, bad


@pytest.mark.slow
def test_angles_reach_the_cramer_rao_bound(runs, capsys):
    truth, names, est, u, crb_sd, classical = runs
    rows = []
    ratios = []
    for k, n in enumerate(ANGLES):
        i = names.index(n)
        mse = np.mean((est[:, i] - truth.parameters[n]) ** 2)
        mse_classical = np.mean((classical[:, k] - truth.parameters[n]) ** 2)
        ratios.append(mse / crb_sd[n] ** 2)
        rows.append(f"{n}: joint RMSE {np.sqrt(mse):.4f}\" CRB {crb_sd[n]:.4f}\" MSE/CRB {ratios[-1]:.3f}; "
                    f"classical RMSE {np.sqrt(mse_classical):.3f}\" (MSE/CRB {mse_classical / crb_sd[n] ** 2:.0f})")
    pooled = float(np.mean(ratios))
    with capsys.disabled():
        print("\n" + "\n".join(rows) + f"\npooled MSE/CRB over the six angles: {pooled:.3f}")
    # MSE/CRB of an efficient estimator averages 1 with sampling SD sqrt(2/(6 N)) = 1.8 %;
    # 5 % is 2.7 of those. Each angle alone: SD sqrt(2/N) = 4.5 %, allowed 4 of them.
    assert abs(pooled - 1) < 0.05
    assert all(abs(r - 1) < 4 * np.sqrt(2 / N) for r in ratios), ratios


@pytest.mark.slow
def test_bench_errors_as_variance_components_give_honest_angle_u():
    """100 campaigns with the paper's bench (sigma_1 = 5", sigma_2 = 2" per visit, simulated as
    rotations of the bench axes): with the lab's figures as variance components the angles'
    z-scores have SD 1 and value +- 2u covers 95 % (pooled over 600 angles; the band is
    +- 3 binomial SE, widened by sqrt(2) for the correlation of the six angles of a campaign);
    without them the z SD is about 2.8 (the certificate's old 0.54" would not hold)."""
    from triadcal.api import simulate
    from triadcal.estimation.joint import BenchErrors

    z_with, z_without = [], []
    for seed in range(100):
        truth, c = simulate(sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0, seed=1000 + seed)
        a = fit_joint(c)
        b = fit_joint(c, bench_errors=BenchErrors(5.0, 2.0))
        for n in ("Ca_xy", "Ca_xz", "Ca_yx", "Ca_yz", "Ca_zx", "Ca_zy"):
            z_with.append((b[n].value - truth.parameters[n]) / b[n].u)
            z_without.append((a[n].value - truth.parameters[n]) / a[n].u)
    z_with, z_without = np.array(z_with), np.array(z_without)
    cover = float(np.mean(np.abs(z_with) < 2.0))
    se = np.sqrt(0.9545 * 0.0455 / z_with.size) * np.sqrt(2.0)
    print(f"\nbench errors in the fit: z SD {z_with.std():.3f}, 2u coverage {cover:.3f}; "
          f"without: z SD {z_without.std():.3f}")
    assert abs(cover - 0.9545) < 3 * se
    assert 0.88 < z_with.std() < 1.12
    assert z_without.std() > 2.0
