"""The joint estimator on campaigns made another way (tests/independent_bench.py).

The simulator shares no code with ``triadcal.models``: these tests check that the
project's conventions (frames, eq. 1, tempcos, units, the g metadata) agree with an
independent re-derivation, through a real CSV file read by the reader of ``triadcal fit``.
"""

import numpy as np
import pytest

from independent_bench import simulate_campaign
from triadcal.estimation.joint import fit_joint
from triadcal.io.bench_csv import read_bench_csv

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")
#: derived from tilt_x/tilt_y; tilt_beta is undefined for an untilted bench
DERIVED = ("tilt_delta", "tilt_beta")


def fit_file(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return fit_joint(read_bench_csv(path), effects=EFFECTS)


def campaign_and_fit(tmp_path, name, seed, **kw):
    text, truth = simulate_campaign(np.random.default_rng(seed), **kw)
    return fit_file(tmp_path, name, text), truth


def z_scores(result, truth, expected_shift=None):
    """(fitted - truth - expected shift) / u for every fitted parameter; all must be in truth."""
    shift = expected_shift or {}
    fitted = {k: p for k, p in result.parameters.items() if k not in DERIVED}
    assert set(fitted) <= set(truth), f"fitted parameters the simulator does not know: {set(fitted) - set(truth)}"
    return {k: (p.value - truth[k] - shift.get(k, 0.0)) / p.u for k, p in fitted.items()}


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_perfect_bench_recovers_truth(tmp_path, seed):
    """(1) No bench error at all: every fitted parameter within 4.5 u of the truth, status ok."""
    result, truth = campaign_and_fit(tmp_path, f"perfect{seed}.csv", seed)
    assert result.status == "ok", (result.status, result.notes)
    # every parameter of the model was estimated (none held as unidentifiable)
    assert set(truth) <= set(result.parameters), set(truth) - set(result.parameters)
    z = z_scores(result, truth)
    bad = {k: round(v, 2) for k, v in z.items() if abs(v) > 4.5}
    assert not bad, bad
    # the noise is what the sd_* columns say: chi2/dof near 1 (60 visits x 3 - 26 parameters = 154 dof)
    assert 0.6 < result.fit["chi2_dof"] < 1.5


def test_fixture_rotation_about_imu_z_moves_ca_xy_and_ca_yx(tmp_path):
    """(2) The unit sits in its fixture rotated by theta = +10 arcsec about IMU z.

    Derivation: R_fix = Rz(theta) (rotation vector (0, 0, theta)). The unit then feels
    G' = R_fix^T G = (Gx cos th + Gy sin th, -Gx sin th + Gy cos th, Gz)
       ~ (Gx + th Gy, Gy - th Gx, Gz)   to first order.
    X sensor: Ca_x . G' = Gx + (Ca_xy + th) Gy + Ca_xz Gz + O(th Ca)  -> fitted Ca_xy = Ca_xy + th
    Y sensor: Ca_y . G' = (Ca_yx - th) Gx + Gy + Ca_yz Gz + O(th Ca)  -> fitted Ca_yx = Ca_yx - th
    The diagonals change only at second order (th^2/2 ~ 1e-9), so K, S and the other
    angles are unchanged. Hence Ca_xy moves by +10 arcsec and Ca_yx by -10 arcsec.
    """
    theta = 10.0
    result, truth = campaign_and_fit(tmp_path, "fixture.csv", 7, fixture_arcsec=(0.0, 0.0, theta))
    assert result.status == "ok", (result.status, result.notes)
    z = z_scores(result, truth, expected_shift={"Ca_xy": +theta, "Ca_yx": -theta})
    assert abs(z["Ca_xy"]) < 5 and abs(z["Ca_yx"]) < 5, (z["Ca_xy"], z["Ca_yx"])
    bad = {k: round(v, 2) for k, v in z.items() if abs(v) > 4.5}
    assert not bad, bad
    # paired with the same campaign without the rotation (same noise): the shift itself
    ref, _ = campaign_and_fit(tmp_path, "fixture_ref.csv", 7)
    d_xy = result["Ca_xy"].value - ref["Ca_xy"].value
    d_yx = result["Ca_yx"].value - ref["Ca_yx"].value
    assert d_xy == pytest.approx(+theta, abs=0.1 * result["Ca_xy"].u)
    assert d_yx == pytest.approx(-theta, abs=0.1 * result["Ca_yx"].u)


def test_gravity_error_scales_k(tmp_path):
    """(3) True gravity 10 ppm above the value in the file's metadata.

    Derivation: the data are W = (g_true/g0) (Ca R^T f + ...)/K_true, ignoring S. The fit
    assumes the gravity g_local/g0, so it needs (g_local/g0) (...)/K_fit = W, i.e.
    K_fit = K_true g_local/g_true = K_true / (1 + 10e-6) ~ K_true (1 - 10 ppm):
    every K comes out 10 ppm low. (S_fit = S K_fit/K_true moves by 1e-5 S ~ 3e-8 g,
    far below u; the tempcos are relative and do not move.)
    """
    g_local = 9.80665
    ratio = 1.0 + 10e-6
    result, truth = campaign_and_fit(tmp_path, "g.csv", 11, local_g_m_s2=g_local, true_g_m_s2=g_local * ratio)
    assert result.status == "ok", (result.status, result.notes)
    assert result.extra["local_g_m_s2"] == g_local
    shift = {f"K_{a}": truth[f"K_{a}"] * (1.0 / ratio - 1.0) for a in "xyz"}
    z = z_scores(result, truth, expected_shift=shift)
    for a in "xyz":
        assert abs(z[f"K_{a}"]) < 4, (a, z[f"K_{a}"])
    bad = {k: round(v, 2) for k, v in z.items() if abs(v) > 4.5}
    assert not bad, bad
    # paired with the same campaign at the right gravity: the relative change is -10 ppm
    ref, _ = campaign_and_fit(tmp_path, "g_ref.csv", 11, local_g_m_s2=g_local)
    for a in "xyz":
        rel = result[f"K_{a}"].value / ref[f"K_{a}"].value - 1.0
        assert rel == pytest.approx(1.0 / ratio - 1.0, abs=0.05e-6), (a, rel)
