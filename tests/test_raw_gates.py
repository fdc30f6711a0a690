"""fit-raw: a start solved from the data for any offset and scale, and the answer gates.

Data made another way than the estimator's model code: a real recording (mikoff imu0, an
MPU-9150, in its own counts and in offset-binary counts) and a recording simulated here
with plain numpy rotations, once with clean static poses and once with slow motion that the
static detector cannot tell from rest (the issue's 10^6-sample case)."""

from pathlib import Path

import numpy as np
import pytest

from triadcal.cli import main
from triadcal.estimation.raw import fit_raw
from triadcal.io.raw import RawRecording

DATA = Path(__file__).parent / "data" / "real"
#: the unit's nominal scale: counts = round(a * 2048 / 9.81), a in m/s^2
K_NOMINAL_G_PER_COUNT = 9.81 / 2048 / 9.80665


def _mikoff_counts(offset):
    a = np.loadtxt(DATA / "mikoff_imu0.log")[:, :3]
    return RawRecording(acc=np.round(a * 2048 / 9.81) + offset, rate_hz=100.0, unit="counts",
                        columns=("ax", "ay", "az"), source=f"mikoff_imu0 counts + {offset:g}")


@pytest.fixture(scope="module")
def signed():
    return fit_raw(_mikoff_counts(0.0), poses="unknown", local_g_m_s2=9.81).result


def test_offset_binary_counts_give_the_signed_answer(signed):
    """The issue's case: offset-binary counts gave K ~ -3e-20 with zero residual, status ok."""
    r = fit_raw(_mikoff_counts(32768.0), poses="unknown", local_g_m_s2=9.81).result
    assert signed.status == "ok" and r.status == "ok", r.notes
    for a in "xyz":
        assert r[f"K_{a}"].value == pytest.approx(signed[f"K_{a}"].value, rel=1e-6)
        assert r[f"K_{a}"].value == pytest.approx(K_NOMINAL_G_PER_COUNT, rel=0.01)   # datasheet: 2048 LSB/g
        # S = K w0: the zero moves by 32768 counts
        assert r[f"S_{a}"].value == pytest.approx(signed[f"S_{a}"].value + 32768 * r[f"K_{a}"].value, abs=1e-5)
    for n in ("Ca_xy", "Ca_xz", "Ca_yz"):
        assert r[n].value == pytest.approx(signed[n].value, abs=0.01 * signed[n].u)
    # the orientations are counted on the calibrated means: the raw ones all point near (32768, 32768,
    # 32768) and read as one orientation, with a note that K, S and the angles cannot be told apart
    assert r.fit["distinct_orientations"] == signed.fit["distinct_orientations"] > 9
    assert not any("distinct orientation" in n for n in r.notes), r.notes
    # the summary gives the gate's goodness of fit, not "chi2/dof not computed"
    from triadcal.reports.summary import summary_text
    assert f"noise floor of the interval means = {r.fit['noise_floor_ratio']:.3f}" in summary_text(r)


@pytest.mark.parametrize("scale, unit", [(9.81 / 2048, "m/s2"), (1.0 / 2048 * 9.81 / 9.80665, "g")])
def test_any_scale_gives_the_same_geometry(signed, scale, unit):
    a = np.loadtxt(DATA / "mikoff_imu0.log")[:, :3]
    counts = np.round(a * 2048 / 9.81)
    rec = RawRecording(acc=counts * scale + 0.05 * scale * 2048, rate_hz=100.0, unit=unit, columns=("x", "y", "z"))
    r = fit_raw(rec, poses="unknown", local_g_m_s2=9.81).result
    assert r.status == "ok", r.notes
    for a_ in "xyz":
        assert r[f"K_{a_}"].value == pytest.approx(signed[f"K_{a_}"].value / scale, rel=1e-5)


def test_a_degenerate_answer_is_refused_not_ok():
    """Every sample the same: no scale can be determined; never a zero residual with status ok."""
    rec = RawRecording(acc=np.full((3000, 3), 32768.0) + np.random.default_rng(0).normal(0, 1, (3000, 3)),
                       rate_hz=100.0, unit="counts", columns=("x", "y", "z"))
    try:
        r = fit_raw(rec, poses="unknown", local_g_m_s2=9.81, intervals=None).result
    except ValueError as exc:                    # too few static intervals: refused by name
        assert "static" in str(exc)
    else:
        assert r.status != "ok"


# -- a recording simulated here (numpy rotations, not triadcal's simulator) -----------------
def _rot(axis, angle):
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _recording(slow_drift_deg, seed=1, n_poses=24, rate=100.0, static_s=30.0, drift_s=60.0):
    """Counts (offset-binary) of a unit tumbled through random poses: ``static_s`` at rest, then
    a slow drift of ``slow_drift_deg`` over ``drift_s`` (0: the unit stays put), then a 1-s move."""
    rng = np.random.default_rng(seed)
    K = np.array([1 / 2000.0, 1 / 2050.0, 1 / 1990.0])            # g per count
    S = np.array([0.02, -0.015, 0.03])                            # g
    a = 2e-3
    Ca = np.array([[1.0, a, -a], [0.0, 1.0, 0.5 * a], [0.0, 0.0, 1.0]])
    g = np.array([0.0, 0.0, 1.0])
    R = np.eye(3)
    chunks = []
    for _ in range(n_poses):
        R = _rot(rng.normal(size=3), rng.uniform(0.8, 2.5)) @ R
        gs = [np.tile(R.T @ g, (int(static_s * rate), 1))]
        axis = rng.normal(size=3)
        n_d = int(drift_s * rate)
        ang = np.radians(slow_drift_deg) * np.arange(n_d) / n_d
        gs.append(np.array([(_rot(axis, t) @ R).T @ g for t in ang]))
        R = _rot(axis, np.radians(slow_drift_deg)) @ R
        move = np.array([(_rot(np.array([1.0, 1.0, 0.0]), t) @ R).T @ g for t in np.linspace(0, 2.0, int(rate))])
        gs.append(move)
        R = _rot(np.array([1.0, 1.0, 0.0]), 2.0) @ R
        gi = np.concatenate(gs)
        chunks.append(((gi @ Ca.T) + S) / K)
    w = np.concatenate(chunks) + rng.normal(0, 4.0, size=(sum(len(c) for c in chunks), 3)) + 32768.0
    return RawRecording(acc=w, rate_hz=rate, unit="counts", columns=("x", "y", "z")), K


def test_clean_simulated_recording_is_ok_and_right():
    rec, K = _recording(0.0)
    r = fit_raw(rec, poses="unknown", local_g_m_s2=9.80665).result
    assert r.status == "ok", r.notes
    for i, a in enumerate("xyz"):
        assert abs(r[f"K_{a}"].value - K[i]) < 4 * r[f"K_{a}"].u
    # chi2 of the norm residuals over the data's own noise floor, 24 - 9 = 15 dof: the
    # 99.9 % point of chi2(15)/15 is 2.5, so a clean recording stays below it
    assert r.fit["noise_floor_ratio"] < 2.5


def test_slow_motion_taken_for_rest_is_a_model_mismatch():
    """The detector cannot tell a 0.2 deg/s drift from rest (within-window change below the
    noise): each 'static' mean averages an arc and is shortened, far beyond the recording's
    own noise floor. Must be model_mismatch with the numbers, never ok."""
    rec, _ = _recording(12.0)
    r = fit_raw(rec, poses="unknown", local_g_m_s2=9.80665).result
    gate = {o["gate"]: o for o in r.extra["gates"]["outcomes"]}["goodness_of_fit"]
    if r.status == "ok":     # the detector cut the drift out: then the answer must be right
        pytest.fail(f"slow motion passed as ok: {gate}")
    assert r.status == "model_mismatch", r.notes
    assert gate["value"] > 100 and "noise floor" in gate["reason"]


def _turning_recording(rate_deg_s, seed=2, n_poses=30, rate=100.0, hold_s=20.0):
    """Counts of a unit that turns steadily at ``rate_deg_s`` about a random horizontal axis through each
    ``hold_s`` hold, then moves 2 rad in 1 s to the next pose: a turn too slow for the detector's
    1 s windows (an outside probe's case: every hold taken as static)."""
    rng = np.random.default_rng(seed)
    K = np.array([1 / 2000.0, 1 / 2050.0, 1 / 1990.0])
    S = np.array([0.02, -0.015, 0.03])
    Ca = np.array([[1.0, 2e-3, -2e-3], [0.0, 1.0, 1e-3], [0.0, 0.0, 1.0]])
    g = np.array([0.0, 0.0, 1.0])
    R = np.eye(3)
    chunks = []
    for _ in range(n_poses):
        R = _rot(rng.normal(size=3), rng.uniform(0.8, 2.5)) @ R
        phi = rng.uniform(0.0, 2.0 * np.pi)
        axis = np.array([np.cos(phi), np.sin(phi), 0.0])          # horizontal: gravity turns by the whole angle
        n_h = int(hold_s * rate)
        ang = np.radians(rate_deg_s) * np.arange(n_h) / rate
        hold = np.array([(_rot(axis, t) @ R).T @ g for t in ang])
        R = _rot(axis, ang[-1]) @ R
        move = np.array([(_rot(np.array([1.0, 1.0, 0.0]), t) @ R).T @ g for t in np.linspace(0, 2.0, int(rate))])
        R = _rot(np.array([1.0, 1.0, 0.0]), 2.0) @ R
        chunks.append(((np.concatenate([hold, move]) @ Ca.T) + S) / K)
    w = np.concatenate(chunks) + rng.normal(0, 1.0, size=(sum(len(c) for c in chunks), 3))
    return RawRecording(acc=w, rate_hz=rate, unit="counts", columns=("x", "y", "z")), K


@pytest.mark.parametrize("rate_deg_s", [0.0, 0.3])
def test_a_unit_turning_through_its_holds_is_refused_with_the_bias_it_leaves(rate_deg_s):
    """A steady turn theta through every hold shortens every mean by theta^2/24 (6 deg: 460 ppm),
    which the norm fit takes into K without a residual: before, status ok with K tens of u high.
    The gate's predicted shift of K (in u) must match the error the fit made."""
    rec, K = _turning_recording(rate_deg_s)
    r = fit_raw(rec, poses="unknown", local_g_m_s2=9.80665).result
    gate = {o["gate"]: o for o in r.extra["gates"]["outcomes"]}["static_intervals_still"]
    err_u = max(abs(r[f"K_{a}"].value - K[i]) / r[f"K_{a}"].u for i, a in enumerate("xyz"))
    if rate_deg_s == 0.0:
        assert r.status == "ok" and gate["passed"] and gate["value"] < 0.05, r.notes
        return
    # the turn over each interval the detector kept (19.5 of the 20 s hold)
    theta = np.radians(rate_deg_s) * np.array([iv["duration_s"] for iv in r.extra["static_intervals"]["intervals"]])
    assert r.status == "model_mismatch" and gate["passed"] is False
    assert err_u > 5.0                                         # what the gate prevents
    rel = min(r[f"K_{a}"].u / r[f"K_{a}"].value for a in "xyz")
    assert gate["value"] == pytest.approx(np.mean(theta ** 2) / 24 / rel, rel=0.1)      # theta^2/24 by hand
    assert 0.5 * err_u < gate["value"] < 2.0 * err_u


def test_cli_angle_bound_and_refusal(tmp_path, capsys):
    rec = np.loadtxt(DATA / "mikoff_imu0.log")[:, :3]
    path = tmp_path / "r.csv"
    np.savetxt(path, np.round(rec * 2048 / 9.81) + 32768, delimiter=",", header="ax,ay,az", comments="", fmt="%d")
    code = main(["fit-raw", str(path), "--rate", "100", "--poses", "unknown", "--local-g", "9.81",
                 "--json", str(tmp_path / "r.json")])
    out, err = capsys.readouterr()
    assert code == 0 and "status ok" in out
    code = main(["fit-raw", str(path), "--rate", "100", "--poses", "unknown", "--local-g", "9.81",
                 "--angle-bound-arcsec", "1", "--json", str(tmp_path / "r.json")])
    out, err = capsys.readouterr()
    assert code == 3 and "Traceback" not in out + err
    assert "angle_out_of_range" in out
