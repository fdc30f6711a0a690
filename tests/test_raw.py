"""fit-raw: raw recordings, static intervals, known-pose and gravity-norm calibration.

Simulated recordings come from :meth:`Model.predict` (the model's own physics) with a
random hand-placement tilt per pose, white noise, quantisation to counts and moving
transitions between the poses. Real recordings: ../shared/data/real (see its README).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from triadcal.reports.summary import summary_text
from scipy.linalg import rq

from triadcal.cli import main as cli_main
from triadcal.estimation.raw import NORM_NAMES, UNIT_NAMES, fit_raw
from triadcal.estimation.result import CalibrationResult
from triadcal.estimation.raw.detection import (StaticIntervalError, detect_static_intervals, intervals_from_labels,
                                        moving_sd)
from triadcal.io.bench_csv import read_bench_csv
from triadcal.estimation.gates import GateConfig
from triadcal.io.raw import RawRecording, RawRecordingError, read_intervals, read_raw_csv
from triadcal.models.campaign import DEFAULT_PLAN
from triadcal.models.model import Covariates, Model
from triadcal.models.sensor import ANGLE_NAMES, dcm
from triadcal.models.units import ARCSEC, STANDARD_GRAVITY_M_S2

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
if not REAL.exists():
    REAL = Path("/work/shared/data/real")
needs_real = pytest.mark.skipif(not REAL.exists(), reason="real recordings not available")
POSITIONS = {"y_p": "P01", "y_a": "P03", "x_p": "P05", "x_a": "P07", "z_p": "P09", "z_a": "P11"}
LOCAL_G = 9.81
#: the simulated units' misalignment SD: the known-pose fit's default angle prior (1 deg)
CA_SD_ARCSEC = 3600.0


# --------------------------------------------------------------------------------------
# a raw-sample simulator of hand-placed recordings (the model's physics)
# --------------------------------------------------------------------------------------
def random_unit(rng, counts_per_g=2048.0):
    """A MEMS-like triad in counts: scale +-2 %, bias ~30 mg, angles ~1 deg (reporting units)."""
    p = {}
    for a in "xyz":
        p[f"K_{a}"] = (1.0 + 0.02 * rng.standard_normal()) / counts_per_g
        p[f"S_{a}"] = 0.03 * rng.standard_normal()
    for ab in ANGLE_NAMES:
        p[f"Ca_{ab}"] = CA_SD_ARCSEC * rng.standard_normal()
    return p


def simulate_recording(params, poses, *, seed, rate_hz=102.4, static_s=6.0, move_s=2.0,
                       noise_counts=6.0, placement_sd_deg=1.0, orientations=None):
    """Raw samples (counts) of a hand-placed recording.

    ``poses`` labels of known faces (bench angles of DEFAULT_PLAN) or, with
    ``orientations`` (k, 2) bench angles in degrees, free poses. Each pose gets a random
    tilt of its gravity direction (placement SD per component); between poses the
    reading swings along a path with a large excursion (the unit being moved).
    Returns (RawRecording with labels, true tilts in arcsec (k, 2)).

    The random stream is ``(seed, 1)``, independent of a unit drawn with ``default_rng(seed)``
    (with the same stream the placement tilts would equal the unit's draws).
    """
    rng = np.random.default_rng([seed, 1])
    model = Model(("bench_tilt",))
    k = len(poses)
    if orientations is None:
        a1 = np.array([DEFAULT_PLAN[POSITIONS[p]][0] for p in poses])
        a2 = np.array([DEFAULT_PLAN[POSITIONS[p]][1] for p in poses])
    else:
        a1, a2 = orientations[:, 0], orientations[:, 1]
    tilts = rng.normal(0.0, placement_sd_deg * 3600.0, (k, 2))
    p = model.to_internal({n: params[n] for n in UNIT_NAMES})
    p["tilt_x"], p["tilt_y"] = tilts[:, 0] * ARCSEC, tilts[:, 1] * ARCSEC
    z = np.zeros(k)
    cov = Covariates(axis1=np.radians(a1), axis2=np.radians(a2), temp=(z + 20, z + 20, z + 20),
                     temp_rate=(z, z, z), branch=z, time_s=z)
    W = np.stack(model.predict(p, cov, LOCAL_G / STANDARD_GRAVITY_M_S2), axis=1)   # (k, 3)
    n_static, n_move = int(static_s * rate_hz), int(move_s * rate_hz)
    chunks, labels = [], []
    scale = 1.0 / np.mean([params[f"K_{a}"] for a in "xyz"])
    for j in range(k):
        chunks.append(np.repeat(W[j][None, :], n_static, axis=0))
        labels += [poses[j]] * n_static
        nxt = W[(j + 1) % k]
        s = np.linspace(0.0, 1.0, n_move)[:, None]
        swing = 0.4 * scale * np.sin(np.pi * s) * rng.standard_normal(3)[None, :]
        chunks.append((1 - s) * W[j] + s * nxt + swing)
        labels += ["move"] * n_move
    acc = np.vstack(chunks)
    acc = np.round(acc + rng.normal(0.0, noise_counts, acc.shape))
    rec = RawRecording(acc, rate_hz, "counts", ("acc_x", "acc_y", "acc_z"), np.array(labels), "part",
                       source=f"<simulated seed {seed}>")
    return rec, tilts


def triangular_truth(params):
    """The true parameters in the gravity-norm model's frame (imu_tk's: Ca upper triangular).

    Ca = U Q (RQ decomposition): norms cannot see Q, the estimable angles are U's."""
    Ca = np.array(dcm({ab: params[f"Ca_{ab}"] * ARCSEC for ab in ANGLE_NAMES}))
    U, Q = rq(Ca)
    U = U * np.sign(np.diag(U))[None, :]
    out = {n: params[n] for n in NORM_NAMES if not n.startswith("Ca")}
    out.update({"Ca_xy": U[0, 1] / ARCSEC, "Ca_xz": U[0, 2] / ARCSEC, "Ca_yz": U[1, 2] / ARCSEC})
    return out


def random_orientations(rng, k):
    """Bench angles (deg) of k poses spread over the sphere of up directions."""
    a2 = np.degrees(np.arccos(rng.uniform(-1, 1, k)))
    a1 = rng.uniform(0, 360, k)
    return np.column_stack([a1, a2])


def z_scores(result, truth):
    return np.array([(result[n].value - truth[n]) / result[n].u for n in truth])


FACES = ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a"]


# --------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------
@needs_real
def test_read_mpu6050_file_with_header_lines():
    rec = read_raw_csv(REAL / "tomisuarez2_example_data_calibration.csv", 100.0)
    assert rec.columns == ("ax", "ay", "az")
    assert rec.n == 10245 and rec.metadata["Fs"] == "100"
    assert rec.scale_unit == "g/count"
    with pytest.raises(RawRecordingError, match="disagrees with the file's header"):
        read_raw_csv(REAL / "tomisuarez2_example_data_calibration.csv", 204.8)


def test_bad_field_is_refused_with_line_and_column(tmp_path):
    f = tmp_path / "r.csv"
    f.write_text("acc_x,acc_y,acc_z\n1,2,3\n1,nan,3\n")
    with pytest.raises(RawRecordingError, match=r"r.csv:3: column 'acc_y': not a finite number"):
        read_raw_csv(f, 100.0)
    f.write_text("acc_x,acc_y,acc_z\n1,2,3\n1,x,3\n")
    with pytest.raises(RawRecordingError, match=r":3: column 'acc_y': not a number"):
        read_raw_csv(f, 100.0)
    with pytest.raises(RawRecordingError, match="no header line"):
        read_raw_csv(f, 100.0, columns=("ax", "ay", "az"))


@needs_real
def test_interval_files():
    s = read_intervals(REAL / "tomisuarez2_static_intervals.csv")
    assert len(s.start) == 10 and s.start[0] == 150 and s.end[0] == 3613 and s.labels is None
    j = read_intervals(REAL / "imucal_example_ferraris_session_list.json")
    assert j.labels[:2] == ["x_p", "x_a"] and j.start[0] == 540 and j.end[0] == 1271


# --------------------------------------------------------------------------------------
# static intervals
# --------------------------------------------------------------------------------------
def test_detector_finds_every_simulated_pose_and_its_face():
    rng = np.random.default_rng(3)
    rec, _ = simulate_recording(random_unit(rng), FACES * 2, seed=3)
    det = detect_static_intervals(rec.acc, rec.rate_hz)
    assert len(det.intervals) == 12
    truth = intervals_from_labels(rec.labels, "part")
    for found, true in zip(det.intervals, truth.intervals):
        assert true.start <= found.start and found.end <= true.end      # never a moving sample
        assert found.n >= true.n - 1.5 * rec.rate_hz                   # loses at most the window edges
    # the estimated noise is the simulated one (6 counts, quantised: sqrt(36 + 1/12))
    assert np.all(np.abs(det.noise_sd / math.sqrt(36 + 1 / 12) - 1) < 0.15)
    out = fit_raw(rec, poses="known", local_g_m_s2=LOCAL_G)
    assert [iv.label for iv in out.detection.intervals] == FACES * 2


def test_faces_named_from_the_data_say_that_a_swapped_column_is_not_checked():
    """An outside probe: acc_y,acc_x,acc_z on faces the detector named gave status ok with K_x the
    true K_y and no word; the docs promised a refusal (which only labels can give)."""
    from dataclasses import replace

    rng = np.random.default_rng(3)
    rec, _ = simulate_recording(random_unit(rng), FACES * 2, seed=3)
    swapped = replace(rec, acc=rec.acc[:, [1, 0, 2]], labels=None)
    out = fit_raw(swapped, poses="known", local_g_m_s2=LOCAL_G).result
    assert any("known poses named from the data" in n and "not detected" in n for n in out.notes), out.notes
    labelled = fit_raw(rec, poses="known", local_g_m_s2=LOCAL_G, labels="part").result
    assert not any("known poses named from the data" in n for n in labelled.notes)


@pytest.mark.parametrize("reach_s", [0.0, 0.5, 1.0])
def test_labels_reaching_into_the_moves_are_refused_naming_them(reach_s):
    """An outside probe: face labels 1.5 s into the next move ended in NaN everywhere (status non_finite,
    a note blaming swapped columns). A labelled interval whose SD is beyond the detector's threshold x the
    noise holds motion: refused with its name, samples and ratio; the labels as recorded pass."""
    from dataclasses import replace

    from triadcal.estimation.raw.detection import StaticIntervalError

    rng = np.random.default_rng(5)
    rec, _ = simulate_recording(random_unit(rng), FACES, seed=5)
    labels = np.array(rec.labels, dtype=object)
    reach = int(reach_s * rec.rate_hz)
    if reach:
        ends = [i for i in range(1, len(labels)) if labels[i] == "move" and labels[i - 1] != "move"]
        for e in ends:
            labels[e:e + reach] = labels[e - 1]
    moved = replace(rec, labels=list(labels))
    if reach_s == 0.0:
        assert fit_raw(moved, poses="known", local_g_m_s2=LOCAL_G, labels="part").result.status == "ok"
        return
    with pytest.raises(StaticIntervalError, match=r"of the labels' intervals move .*x_p \(samples 0\.\.\d+"):
        fit_raw(moved, poses="known", local_g_m_s2=LOCAL_G, labels="part")


def test_detector_never_nan_and_says_why_it_found_too_few():
    still = np.round(np.tile([0.0, 0.0, 2048.0], (3000, 1)))          # a perfectly quantised still unit
    det = detect_static_intervals(still, 100.0)
    assert len(det.intervals) == 1 and np.all(np.isfinite(det.noise_sd)) and np.all(det.noise_sd > 0)
    rng = np.random.default_rng(0)
    t = np.arange(3000) / 100.0                                        # turning all the time, |a| = g
    moving = np.column_stack([2048 * np.cos(0.5 * t), 2048 * np.sin(0.5 * t), np.zeros_like(t)])
    moving = np.round(moving + rng.normal(0, 6, moving.shape))
    with pytest.raises(StaticIntervalError, match=r"found 0 static intervals .* --intervals FILE"):
        detect_static_intervals(moving, 100.0, min_intervals=6)
    with pytest.raises(ValueError, match="NaN"):
        detect_static_intervals(np.full((100, 3), np.nan), 100.0)
    assert np.allclose(moving_sd(np.ones((50, 3)), 10), 0.0)


# --------------------------------------------------------------------------------------
# known poses
# --------------------------------------------------------------------------------------
def test_known_poses_recover_truth_and_write_bench_csv(tmp_path):
    rng = np.random.default_rng(11)
    truth = random_unit(rng)
    rec, _ = simulate_recording(truth, FACES, seed=11)
    out = fit_raw(rec, poses="known", labels="part", local_g_m_s2=LOCAL_G, placement_sd_deg=1.0,
                  bench_csv_path=tmp_path / "b.csv", json_path=tmp_path / "r.json")
    r = out.result
    assert r.status == "ok"
    assert np.all(np.abs(z_scores(r, {n: truth[n] for n in UNIT_NAMES})) < 3)
    # K and S from the data (noise); each angle from its prior N(0, sa^2) and the data's
    # "angle + half the tilt difference of opposite poses" (prior SD sh / sqrt(2)):
    # u = (1/sa^2 + 2/sh^2)^-1/2 = 1 deg / sqrt(3) for sa = sh = 1 deg
    assert all(abs(r[f"Ca_{ab}"].u / (3600 / math.sqrt(3)) - 1) < 0.05 for ab in ANGLE_NAMES)
    assert r["K_x"].u / r["K_x"].value < 1e-3 and r["K_x"].unit == "g/count"
    rms = r.fit["rms_norm_residual_m_s2"]
    assert rms["after"] < rms["before"]
    c = read_bench_csv(tmp_path / "b.csv")
    assert list(c.up_axis()) == ["+X", "-X", "+Y", "-Y", "+Z", "-Z"]
    assert c.metadata["input_unit"] == "counts" and "not measured" in c.metadata["temperature"]
    assert c.local_g_stated and c.local_g_m_s2 == LOCAL_G      # the g the user stated, carried over
    assert np.allclose(c.w, out.averages.w)
    loaded = CalibrationResult.load(tmp_path / "r.json")
    assert loaded["S_y"].value == pytest.approx(r["S_y"].value)


def test_prior_sensitivity_is_what_a_refit_gives():
    """fit.prior_sensitivity: K and S's moves (in u) when a prior SD is halved / doubled are the
    moves of a real refit with that prior (same random numbers), and the note says so above 0.5 u."""
    rng = np.random.default_rng(11)
    truth = random_unit(rng)
    rec, _ = simulate_recording(truth, FACES, seed=11)
    base = fit_raw(rec, poses="known", labels="part", local_g_m_s2=LOCAL_G, placement_sd_deg=1.0).result
    sens = base.fit["prior_sensitivity"]
    assert set(sens) == {"misalignment_sd_deg", "placement_sd_deg"}
    assert set(sens["placement_sd_deg"]["shift_in_u"]) == {n for n in UNIT_NAMES if not n.startswith("Ca_")}
    for key, arg in (("misalignment_sd_deg", "misalignment_sd_deg"), ("placement_sd_deg", "placement_sd_deg")):
        assert sens[key]["sd_deg"] == pytest.approx([0.5, 2.0])
        kw = {"placement_sd_deg": 1.0, arg: 2.0}
        refit = fit_raw(rec, poses="known", labels="part", local_g_m_s2=LOCAL_G, **kw).result
        for n, shifts in sens[key]["shift_in_u"].items():
            assert shifts[1] == pytest.approx((refit[n].value - base[n].value) / base[n].u, abs=0.02), (key, n)
    worst = max(abs(v) for block in sens.values() for shifts in block["shift_in_u"].values() for v in shifts)
    assert (worst > 0.5) == any(n.startswith("prior-sensitive:") for n in base.notes)
    # with the placement SD integrated (the default) only the angles' prior is varied
    auto = fit_raw(rec, poses="known", labels="part", local_g_m_s2=LOCAL_G).result
    assert set(auto.fit["prior_sensitivity"]) == {"misalignment_sd_deg"}
    assert auto.fit["placement_sd_source"].startswith("integrated")


def test_placement_sd_from_the_data():
    """The data's placement SD (Laplace marginal likelihood): a unit placed to 0.3 deg is found
    there, a stated 1 deg prior is then said to disagree with the data, and the default (auto)
    integrates the SD with most weight near 0.3 deg."""
    rng = np.random.default_rng(21)
    truth = random_unit(rng)
    rec, _ = simulate_recording(truth, FACES, seed=21, placement_sd_deg=0.3)
    stated = fit_raw(rec, poses="known", labels="part", local_g_m_s2=LOCAL_G, placement_sd_deg=1.0).result
    ev = stated.fit["placement_sd_from_data"]
    lo, hi = ev["interval95_deg"]
    assert lo < 0.3 < hi < 1.0 and 0.15 < ev["estimate_deg"] < 0.6
    assert any(n.startswith("the data put the placement SD at") for n in stated.notes)
    auto = fit_raw(rec, poses="known", labels="part", local_g_m_s2=LOCAL_G).result
    assert lo <= auto.fit["placement_sd_deg"] <= hi
    assert not any(n.startswith("the data put the placement SD at") for n in auto.notes)
    assert "integrated out" in auto.fit["estimator"]
    # the angles' u shrinks with the placement SD (1 deg / sqrt(3) at a stated 1 deg)
    assert auto["Ca_xy"].u < 0.75 * stated["Ca_xy"].u


def test_certificate_budget_of_a_hand_placed_result_names_the_placement():
    """The certificate's budget of an angle: for a hand-placed recording the angles' u is the
    placement's (through the priors), not output noise, and the budget says so."""
    from triadcal.uncertainty.angles import uncertainty_budget

    rng = np.random.default_rng(11)
    truth = random_unit(rng)
    rec, _ = simulate_recording(truth, FACES, seed=11)
    r = fit_raw(rec, poses="known", labels="part", local_g_m_s2=LOCAL_G).result
    b = uncertainty_budget(r)
    top = b.components[0]
    assert top.source.startswith("hand placement")
    assert top.contribution == pytest.approx(max(r[f"Ca_{ab}"].u for ab in ANGLE_NAMES))
    assert "output noise" not in [c.source for c in b.components]
    from triadcal.reports.certificate import build_certificate
    cert = build_certificate(r, plots=False)
    assert cert.source_of_u.startswith("known-pose fit") and "integrated out" in cert.source_of_u


def test_known_poses_need_all_six_faces():
    rng = np.random.default_rng(1)
    rec, _ = simulate_recording(random_unit(rng), FACES[:5], seed=1)
    with pytest.raises(StaticIntervalError, match="missing: z_a"):
        fit_raw(rec, poses="known", labels="part")


def known_pose_z(n_units, base_seed, placement_true_deg=1.0, **fit_kwargs):
    """z-scores (units, 12) of known-pose fits of simulated units: angles and tilts N(0, 1 deg^2)
    unless ``placement_true_deg`` says otherwise."""
    z = []
    for seed in range(n_units):
        rng = np.random.default_rng(base_seed + seed)
        truth = random_unit(rng)
        rec, _ = simulate_recording(truth, FACES, seed=base_seed + seed, static_s=4.0,
                                    placement_sd_deg=placement_true_deg)
        r = fit_raw(rec, poses="known", labels="part", local_g_m_s2=LOCAL_G, **fit_kwargs).result
        z.append(z_scores(r, {n: truth[n] for n in UNIT_NAMES}))
    return np.array(z)


def coverage_line(label, z):
    return (f"{label}: {100 * np.mean(np.abs(z) <= 1.96):.1f} % within 1.96u, {100 * np.mean(np.abs(z) <= 3):.2f} % "
            f"within 3u; mean z {np.round(z.mean(axis=0), 2)}; SD {np.round(z.std(axis=0), 2)}")


@pytest.mark.slow
def test_known_pose_coverage_over_100_seeds():
    """The default (placement SD integrated over a log-uniform hyperprior): the k = 2 intervals
    cover 95 % (+-0.03: binomial SE 0.006 for 1200 z, x1.5 for their correlation within a
    unit, 3 SE); each parameter's mean z within 4/sqrt(100); pooled SD of z 1 +- 0.1. Within
    3u: at least 98 %, because integrating the SD makes the posterior a scale mixture of
    normals with tails like a Student-t with ~6 dof (the six tilt sums inform the SD), which
    puts 98.96 % within 3 SD, not 99.73 %."""
    z = known_pose_z(100, 1000)
    print(coverage_line("known poses, placement SD integrated", z))
    assert abs(np.mean(np.abs(z) <= 1.96) - 0.95) < 0.03
    assert np.mean(np.abs(z) <= 3) >= 0.98
    assert np.all(np.abs(z.mean(axis=0)) < 4 / math.sqrt(len(z))), z.mean(axis=0)
    assert 0.9 < np.std(z) < 1.1


@pytest.mark.slow
def test_known_pose_stated_placement_prior_matching_the_units():
    """A stated placement prior equal to the units' spread (1 deg): >= 99 % of the estimates within
    3u (normal theory 99.73 %), each mean z within 4/sqrt(100), pooled SD 1 +- 0.1."""
    z = known_pose_z(100, 1000, placement_sd_deg=1.0)
    print(coverage_line("known poses, stated 1 deg placement prior", z))
    assert np.mean(np.abs(z) <= 3) >= 0.99
    assert np.all(np.abs(z.mean(axis=0)) < 4 / math.sqrt(len(z))), z.mean(axis=0)
    assert 0.9 < np.std(z) < 1.1


@pytest.mark.slow
def test_known_pose_wrong_placement_prior_is_overconfident_and_auto_is_not():
    """Why the placement SD is integrated by default: units placed to 2 deg, fitted with a stated
    1 deg prior, get k = 2 intervals that cover far less than 95 % (measured 78 %); with the
    default the coverage stays 95 +- 3 %."""
    stated = known_pose_z(100, 3000, placement_true_deg=2.0, placement_sd_deg=1.0)
    auto = known_pose_z(100, 3000, placement_true_deg=2.0)
    print(coverage_line("placed to 2 deg, stated 1 deg", stated))
    print(coverage_line("placed to 2 deg, auto", auto))
    assert np.mean(np.abs(stated) <= 1.96) < 0.85
    assert abs(np.mean(np.abs(auto) <= 1.96) - 0.95) < 0.03


@pytest.mark.slow
def test_known_pose_flat_angle_prior_biases_k():
    """Why the angles have a proper prior: with a (nearly) flat one the unresolved angles spread
    beyond the units' and their squares pull K down, by ~0.45 u over these 100 units (K's mean z
    at most -0.25 for every axis; with the prior it is within +-0.4 for all parameters, above)."""
    z = known_pose_z(100, 1000, placement_sd_deg=1.0, misalignment_sd_deg=100.0)
    assert np.all(z.mean(axis=0)[:3] < -0.25), z.mean(axis=0)[:3]


def test_known_pose_posterior_agrees_with_importance_sampling():
    """--sample for known poses: the walkers move in sheared coordinates (conditional optimum of
    the unit parameters given the tilts), so the curved posterior mixes: converged quickly, and
    the joint posterior agrees with the least squares' importance-sampled marginal (both
    Monte Carlo, ESS >= 1000: means within 0.15 u, SDs within 10 %)."""
    rng = np.random.default_rng(3)
    truth = random_unit(rng)
    rec, _ = simulate_recording(truth, FACES, seed=3, static_s=4.0)
    # the simulated unit's angles are drawn with SD 1 deg, beyond the default 1 deg gate: raised, as the
    # user of such a unit would (--angle-bound-arcsec)
    out = fit_raw(rec, poses="known", labels="part", local_g_m_s2=LOCAL_G, placement_sd_deg=1.0, sample=True,
                  max_steps=3000, gates=GateConfig(angle_bound_arcsec=4 * CA_SD_ARCSEC))
    r, run = out.result, out.posterior_run
    assert r.status == "ok" and r.method == "posterior"
    assert run.acceptance > 0.3 and run.checks[-1]["tau_max"] < 10
    ls = r.fit["least_squares"]["parameters"]
    for n in UNIT_NAMES:
        assert abs(r[n].value - ls[n]["value"]) < 0.15 * ls[n]["u"], n
        assert r[n].u == pytest.approx(ls[n]["u"], rel=0.1), n
    assert len(r.extra["placement_tilts"]) == 6 and "tilt_x_x_p" not in r.parameters


# --------------------------------------------------------------------------------------
# unknown poses (gravity norm)
# --------------------------------------------------------------------------------------
def test_unknown_poses_recover_the_identifiable_terms():
    rng = np.random.default_rng(5)
    truth = random_unit(rng)
    k = 30
    rec, _ = simulate_recording(truth, [f"p{i}" for i in range(k)], seed=5, static_s=3.0, move_s=1.5,
                                orientations=random_orientations(rng, k))
    out = fit_raw(rec, poses="unknown", local_g_m_s2=LOCAL_G)
    r = out.result
    assert len(out.detection.intervals) == k
    assert set(r.parameters) == set(NORM_NAMES)       # Ca_yx, Ca_zx, Ca_zy are not identifiable
    assert np.all(np.abs(z_scores(r, triangular_truth(truth))) < 3.5)
    assert r.intervals["K_x"]["dof"] == k - 9
    rms = r.fit["rms_norm_residual_of_means_m_s2"]
    assert rms["after"] < 0.01 * rms["before"]


def test_unknown_poses_refuse_too_few_intervals():
    rng = np.random.default_rng(2)
    rec, _ = simulate_recording(random_unit(rng), FACES, seed=2)
    with pytest.raises(StaticIntervalError, match="9 parameters .* found 6 static intervals"):
        fit_raw(rec, poses="unknown")


@pytest.mark.slow
def test_unknown_pose_coverage_over_100_seeds():
    """Student-t with 51 dof: P(|t| > 3) = 0.42 %, so >= 99 % of estimates within 3u."""
    z = []
    for seed in range(100):
        rng = np.random.default_rng(5000 + seed)
        truth = random_unit(rng)
        k = 60
        rec, _ = simulate_recording(truth, [f"p{i}" for i in range(k)], seed=5000 + seed, static_s=2.5,
                                    move_s=1.0, orientations=random_orientations(rng, k))
        r = fit_raw(rec, poses="unknown", labels="part", local_g_m_s2=LOCAL_G).result
        z.append(z_scores(r, triangular_truth(truth)))
    z = np.array(z)
    inside = np.mean(np.abs(z) <= 3)
    assert inside >= 0.99, f"only {100 * inside:.2f} % within 3u"
    assert 0.7 < np.std(z) < 1.3


# --------------------------------------------------------------------------------------
# real recordings beside their projects' own answers
# --------------------------------------------------------------------------------------
@needs_real
def test_imucal_session_beside_imucal(tmp_path):
    """imucal: W = K_i R a + b with a in m/s2 (|a| = 9.81), rows of R unit vectors. Ours:
    W = (Ca G + S)/K with G in g, so K = 1/(9.80665 K_i), S = K b, Ca = R."""
    out = fit_raw(REAL / "imucal_annotated_session.csv", 102.4, labels="part", local_g_m_s2=9.81)
    r = out.result
    ref = json.loads((REAL / "imucal_tests_snapshot_example_cal.json").read_text())
    Ki = np.diag(ref["K_a"])
    K_ref = 1.0 / (STANDARD_GRAVITY_M_S2 * Ki)
    S_ref = K_ref * np.array(ref["b_a"])
    R = np.array(ref["R_a"])
    for i, a in enumerate("xyz"):
        assert abs(r[f"K_{a}"].value - K_ref[i]) < 3 * r[f"K_{a}"].u, a
        assert abs(r[f"S_{a}"].value - S_ref[i]) < 3 * r[f"S_{a}"].u, a
    for ab in ANGLE_NAMES:
        i, j = "xyz".index(ab[0]), "xyz".index(ab[1])
        assert abs(r[f"Ca_{ab}"].value * ARCSEC - R[i, j]) < 3 * r[f"Ca_{ab}"].u * ARCSEC
    rms = r.fit["rms_norm_residual_m_s2"]
    # before: one isotropic scale (2064 counts/g), 0.21 m/s2; after: the sample noise, 0.033 m/s2
    assert rms["before"] == pytest.approx(0.213, abs=0.005)
    assert rms["after"] == pytest.approx(0.0325, abs=0.002)
    # of the interval means: 0.21 -> 0.0006 m/s2 (the posterior mean of K carries the placement
    # tilts' second-order term, so it does not interpolate the six norms exactly)
    assert r.fit["rms_norm_residual_of_means_m_s2"]["after"] < 0.002
    # what the data say about the placement: 0.4 deg, well inside 1 deg
    ev = r.fit["placement_sd_from_data"]
    assert 0.25 < ev["interval95_deg"][0] < ev["estimate_deg"] < ev["interval95_deg"][1] < 1.0


@needs_real
def test_mpu6050_beside_tomisuarez2():
    """tomisuarez2 (Tedaldi): a = T K (w + b), K in m/s2 per count with g = 9.80665,
    T upper triangular. Ours: K = K_t / 9.80665 g/count, S = -K b."""
    out = fit_raw(REAL / "tomisuarez2_example_data_calibration.csv", 100.0, poses="unknown",
                  local_g_m_s2=STANDARD_GRAVITY_M_S2)
    r = out.result
    assert len(out.detection.intervals) == 10
    ref = np.loadtxt(REAL / "tomisuarez2_params_acc.csv")
    K_ref = ref[3:6] / STANDARD_GRAVITY_M_S2
    S_ref = -K_ref * ref[6:9]
    for i, a in enumerate("xyz"):
        assert abs(r[f"K_{a}"].value - K_ref[i]) < 3 * r[f"K_{a}"].u, a
        assert abs(r[f"S_{a}"].value - S_ref[i]) < 3 * r[f"S_{a}"].u, a
    rms = r.fit["rms_norm_residual_m_s2"]
    # before: one isotropic scale (14.9k counts/g); after: the sample noise of an MPU-6050
    assert rms["before"] == pytest.approx(0.658, abs=0.01)
    assert rms["after"] == pytest.approx(0.0452, abs=0.002)
    assert r.fit["rms_norm_residual_of_means_m_s2"]["after"] < 1e-3
    # 10 poses for 9 parameters: one residual dof, said so; the variance is the noise floor
    assert r.fit["dof"] == 1 and any("only 1 residual" in n for n in r.notes)


@needs_real
def test_cli_fit_raw(tmp_path, capsys):
    out = tmp_path / "r.json"
    rc = cli_main(["fit-raw", str(REAL / "imucal_annotated_session.csv"), "--rate", "102.4", "--labels", "part",
                   "--json", str(out), "--bench-csv", str(tmp_path / "b.csv")])
    text = capsys.readouterr().out
    assert rc == 0 and "6 static intervals from labels column 'part'" in text and "RMS of |a| - g" in text
    d = json.loads(out.read_text())
    assert d["parameters"]["K_x"]["unit"] == "g/count" and d["input_unit"] == "counts"
    assert set(d["fit"]["rms_norm_residual_m_s2"]) == {"before", "after"}
    rc = cli_main(["fit-raw", str(REAL / "imucal_annotated_session.csv"), "--rate", "102.4", "--poses", "unknown",
                   "--json", str(out)])
    assert rc == 1 and "needs at least as many static poses" in capsys.readouterr().err


# --------------------------------------------------------------------------------------
# posterior sampling through the bench's path (--sample)
# --------------------------------------------------------------------------------------
def test_unknown_pose_posterior_agrees_with_least_squares(tmp_path):
    """30 free poses, 21 residual dof: a near-Gaussian posterior, so the sampled mean and SD equal
    the least-squares value and u up to Monte Carlo error (ESS >= 2000: SE of the mean 0.022 u,
    relative SE of the SD ~1.6 %) and the prior's negligible pull; tolerances 0.15 u and 10 %
    are > 6 standard errors."""
    import arviz as az

    rng = np.random.default_rng(5)
    truth = random_unit(rng)
    k = 30
    rec, _ = simulate_recording(truth, [f"p{i}" for i in range(k)], seed=5, static_s=3.0, move_s=1.5,
                                orientations=random_orientations(rng, k))
    ls = fit_raw(rec, poses="unknown", local_g_m_s2=LOCAL_G).result
    nc = tmp_path / "post.nc"
    out = fit_raw(rec, poses="unknown", local_g_m_s2=LOCAL_G, sample=True, posterior_path=nc)
    r = out.result
    smp = r.extra["sampler"]
    assert r.method == "posterior" and r.status == "ok"
    assert smp["rhat_max"] < 1.01 and min(smp["ess_bulk_min"], smp["ess_tail_min"]) >= 2000
    assert smp["steps"] - smp["burn"] >= 50 * smp["tau_max"]
    for n in NORM_NAMES:
        assert abs(r[n].value - ls[n].value) < 0.15 * ls[n].u, n
        assert r[n].u == pytest.approx(ls[n].u, rel=0.10), n
        assert not r.intervals[n]["non_gaussian"] and not r.intervals[n]["prior_dominated"], n
    assert not r.extra["flags"]["prior_influenced"]
    assert r.fit["least_squares"]["parameters"]["K_x"]["value"] == ls["K_x"].value
    assert r.fit["rms_norm_residual_of_means_m_s2"]["after"] < 0.01 * r.fit["rms_norm_residual_of_means_m_s2"]["before"]
    d = az.from_netcdf(str(nc))
    assert set(d.posterior.data_vars) == set(NORM_NAMES) and d.posterior["Ca_xy"].attrs["units"] == "arcsec"
    assert d.log_likelihood["norm_residual"].shape[-1] == k and d.observed_data["w"].shape == (k, 3)


@needs_real
def test_mpu6050_posterior_says_ca_xy_is_prior_influenced():
    """10 poses for 9 parameters: Ca_xy's least-squares SD (~14000") is of the prior's size
    (18000"), so the posterior of Ca_xy is the prior's as much as the data's, and says so. The
    posterior is a curved ridge along Ca_xy (tau ~1000 steps in plain whitened coordinates);
    the walkers move along Ca_xy with the other parameters sheared to their conditional optimum,
    which mixes (tau < 10) and converges."""
    out = fit_raw(REAL / "tomisuarez2_example_data_calibration.csv", 100.0, poses="unknown",
                  local_g_m_s2=STANDARD_GRAVITY_M_S2, sample=True, max_steps=3000)
    r, run = out.result, out.posterior_run
    # the sampler converged, and the answer is refused: Ca_xy is not measured (its u is beyond 1 deg)
    assert run.converged and run.checks[-1]["tau_max"] < 10
    assert r.status == "unidentifiable" and any("Ca_xy" in n and "not determined" in n for n in r.notes)
    flags = r.extra["flags"]
    assert "Ca_xy" in flags["prior_influenced"] or "Ca_xy" in flags["prior_dominated"]
    assert r.intervals["Ca_xy"]["ls_prior_sd_ratio"] > 0.5
    assert any(n.startswith("Ca_xy: prior-") for n in r.notes)
    assert r["Ca_xy"].u > 10 * max(r["Ca_xz"].u, r["Ca_yz"].u)          # the poorly determined angle
    assert "Ca_xz" not in flags["prior_influenced"] + flags["prior_dominated"]
    assert "K_z" not in flags["prior_influenced"] + flags["prior_dominated"]
    # one recommendation: with 1 residual dof the posterior holds the noise level fixed, so the
    # Student-t least-squares intervals are the ones to use, and no note says otherwise
    assert r.extra["intervals_to_use"]["use"] == "least_squares"
    assert sum(n.startswith("intervals to use:") for n in r.notes) == 1
    assert not any("use the posterior interval" in n or "safer" in n for n in r.notes
                   if not n.startswith("intervals to use:"))
    text = summary_text(r)
    assert "intervals to use: the least-squares ones" in text and "quantiles" in text


@needs_real
def test_cli_fit_raw_sample(tmp_path, capsys):
    out, nc = tmp_path / "r.json", tmp_path / "r.nc"
    rc = cli_main(["fit-raw", str(REAL / "tomisuarez2_example_data_calibration.csv"), "--rate", "100",
                   "--poses", "unknown", "--sample", "--max-steps", "400", "--posterior", str(nc), "--json", str(out)])
    text = capsys.readouterr().out
    d = json.loads(out.read_text())
    assert d["method"] == "posterior" and "posterior:" in text and nc.exists()
    assert rc == (0 if d["status"] == "ok" else 3)


def test_a_tab_separated_recording_is_read_and_one_pose_is_said(tmp_path):
    """Separators other than commas (tofupilot's climate-chamber run is tab-separated, with dotted
    column names): the header decides. A recording in one pose is refused by the gates, and a
    note says why in words: one orientation cannot tell K, S and the angles apart."""
    from triadcal.estimation.raw import fit_raw
    from triadcal.io.raw import read_raw_csv

    rng = np.random.default_rng(3)
    n = 4000
    acc = np.column_stack([0.18 + 0.01 * rng.standard_normal(n), -0.1 + 0.01 * rng.standard_normal(n),
                           -9.55 + 0.01 * rng.standard_normal(n)])
    lines = ["timestamp\timu.acc.x\timu.acc.y\timu.acc.z\timu.temperature"]
    lines += [f"{i * 505400}\t{a:.6f}\t{b:.6f}\t{c:.6f}\t{20 + i / 100:.3f}" for i, (a, b, c) in enumerate(acc)]
    path = tmp_path / "tab.csv"
    path.write_text("\n".join(lines) + "\n")
    cols = ("imu.acc.x", "imu.acc.y", "imu.acc.z")
    rec = read_raw_csv(path, 2.0, columns=cols, unit="m/s2")
    assert rec.acc.shape == (n, 3) and np.allclose(rec.acc[:, 2].mean(), acc[:, 2].mean(), atol=1e-6)
    bad = path.read_text().replace("\t-9.5", "\tnine", 1)
    (tmp_path / "bad.csv").write_text(bad)
    with pytest.raises(ValueError, match=r"bad\.csv:\d+.*imu\.acc\.z"):
        read_raw_csv(tmp_path / "bad.csv", 2.0, columns=cols, unit="m/s2")
    (tmp_path / "iv.csv").write_text("start,end\n" + "".join(f"{k},{k + 200}\n" for k in range(0, n, 400)))
    out = fit_raw(path, 2.0, columns=cols, unit="m/s2", poses="unknown", intervals=tmp_path / "iv.csv")
    r = out.result
    assert r.status != "ok"
    assert r.fit["distinct_orientations"] == 1
    assert any("only 1 distinct orientation" in note for note in r.notes)
