"""fit-raw --diagnose (issue 18, item 5): where / which / how far it shrinks over the static
intervals of a raw recording, scored on held-out intervals.

The synthetic recordings are made here with numpy (free static poses on the sphere, smooth
turns between them, white noise), not with the project's model code: the planted terms are
written out below, independently of triadcal.estimation.raw.terms.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from triadcal.cli import main as cli_main
from triadcal.estimation.raw import fit_raw
from triadcal.io.raw import RawRecording
from triadcal.judgement.raw_diagnosis import diagnose_raw, summary_lines

sys.path.insert(0, str(Path(__file__).parent))
from test_results_contract import assert_valid  # noqa: E402

RATE = 100.0
REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "data" / "mikoff_imu0.csv"


def recording(seed=0, n_poses=40, k2_ug=0.0, contaminate_mg=0.0, outside_ug=0.0, noise_mg=1.0,
              static_s=3.0, turn_s=1.0, asymmetry_ppm=0.0):
    """Readings in g of a triad with scale errors, biases and a non-orthogonality, turned by hand
    through ``n_poses`` random static poses. Planted:

    - ``k2_ug``: K2 of every axis, output_i += K2 a_i^2 (ug/g^2);
    - ``asymmetry_ppm``: a scale asymmetry of every axis, output_i += e |a_i| (no raw candidate);
    - ``contaminate_mg``: interval 7 reads an extra offset of that size on every axis (a knock);
    - ``outside_ug``: output_z += c a_x a_y, a term that none of the candidates models.
    """
    rng = np.random.default_rng(seed)
    v = rng.standard_normal((n_poses, 3))
    poses = v / np.linalg.norm(v, axis=1)[:, None]
    scale = np.array([1.003, 0.998, 1.001])
    bias = np.array([0.012, -0.008, 0.02])
    mix = np.array([[1, 0.002, -0.001], [0, 1, 0.0015], [0, 0, 1]])
    n_st, n_tu = int(static_s * RATE), int(turn_s * RATE)
    chunks = []
    for k in range(n_poses):
        a = np.repeat(poses[k][None], n_st, axis=0)
        extra = np.zeros_like(a)
        extra += k2_ug * 1e-6 * a ** 2 + asymmetry_ppm * 1e-6 * np.abs(a)
        extra[:, 2] += outside_ug * 1e-6 * a[:, 0] * a[:, 1]
        w = (a + extra) @ mix.T * scale + bias
        if k == 7:
            w = w + contaminate_mg * 1e-3
        chunks.append(w)
        if k + 1 < n_poses:
            s = np.linspace(0, 1, n_tu)[:, None]
            t = (1 - s) * poses[k] + s * poses[k + 1] + 0.3 * np.sin(np.pi * s) * rng.standard_normal(3)
            t = t / np.linalg.norm(t, axis=1)[:, None]
            chunks.append(t @ mix.T * scale + bias)
    w = np.concatenate(chunks)
    w = w + noise_mg * 1e-3 * rng.standard_normal(w.shape)
    return RawRecording(w, RATE, "g", ("ax", "ay", "az"), source=f"synthetic-{seed}")


def diagnose(rec):
    out = fit_raw(rec, poses="unknown", local_g_m_s2=9.80665)
    assert len(out.detection.intervals) == 40
    return diagnose_raw(out)


def test_planted_k2_is_named_with_its_held_out_shrink():
    # 0.3 mg a sample: K2 beats its rival the asymmetry held out (at 1 mg the 40 poses cannot tell
    # them apart: test_a_scale_asymmetry_is_never_named_k2)
    d = diagnose(recording(seed=1, k2_ug=800, noise_mg=0.3))
    doc = d.doc
    assert doc["gap"]["significant"]
    assert doc["verdict"]["term"] == "scale_nonlinearity" and doc["verdict"]["effect"] == "scale_nonlinearity"
    c = d.candidate("scale_nonlinearity")
    assert c["significant"] and c["held_out"]["shrink_ug"] > 0.3 * c["held_out"]["rms_base_ug"]
    assert c["full_fit"]["closes_gap"]
    assert all(r["versus_best"]["beaten"] for r in doc["raw"]["rivals"] if r["testable"])
    # a named verdict has a one-sentence reason besides its evidence, and its held-out residual is at the
    # floor (the held-out power against what a term that explains everything leaves there)
    v = doc["verdict"]
    assert v["reason"].startswith("scale_nonlinearity closes the significant gap") and "\n" not in v["reason"]
    assert v["held_out_at_floor"] and c["held_out"]["floor"]["at_floor"] and v["gap_closed"]
    assert v["size"]["unit"] == "ug/g2" and abs(v["size"]["value"] + 800) < 4 * v["size"]["u"] + 50
    # the evidence names the rival beaten by the fewest paired standard errors, with that margin (> 2)
    margin = {r["term"]: r["versus_best"]["mean_diff"] / r["versus_best"]["se"] for r in doc["raw"]["rivals"]
              if r["testable"]}
    closest = min(margin, key=margin.get)
    assert f"beats its closest rival, {closest}, held out" in doc["verdict"]["evidence"]
    assert f"({margin[closest]:.3g} paired SE, 2 and at least 0.01 needed)" in doc["verdict"]["evidence"]
    # the planted size comes back as its correction (-800 ug/g^2 on every axis, within 4 u)
    for name, p in c["full_fit"]["new_parameters"].items():
        assert abs(p["value"] + 800) < 4 * p["u"] + 50, (name, p)
    assert_valid(json.loads(json.dumps(doc)), "triadcal.diagnosis")


def test_planted_contaminated_interval_is_named_and_found():
    d = diagnose(recording(seed=2, contaminate_mg=3.0))
    doc = d.doc
    assert doc["verdict"]["term"] == "contaminated_interval"
    # every raw candidate is in the diagnosis vocabulary: the schema's field names it
    assert doc["verdict"]["effect"] == "contaminated_interval"
    assert_valid(json.loads(json.dumps(doc)), "triadcal.diagnosis")
    c = d.candidate("contaminated_interval")
    assert c["full_fit"]["dropped_interval"] == 8            # the 8th interval (index 7) was knocked
    assert 8 in doc["raw"]["standing_out"]
    assert c["held_out"]["shrink_ug"] > 0
    assert_valid(json.loads(json.dumps(doc)), "triadcal.diagnosis")


def test_clean_recording_is_null_at_the_noise_floor():
    d = diagnose(recording(seed=3))
    doc = d.doc
    assert doc["verdict"]["effect"] is None and doc["verdict"]["term"] is None
    assert "noise floor" in doc["verdict"]["reason"]
    assert not doc["gap"]["significant"]
    assert doc["gap"]["residual_rms_ug"] < 2 * doc["gap"]["noise_floor_ug"]
    assert_valid(json.loads(json.dumps(doc)), "triadcal.diagnosis")


def test_a_term_outside_the_candidates_is_unexplained_not_a_wrong_name():
    d = diagnose(recording(seed=4, outside_ug=1500))
    doc = d.doc
    assert doc["gap"]["significant"]
    assert doc["verdict"]["effect"] == "unexplained" and doc["verdict"]["term"] == "unexplained"
    assert_valid(json.loads(json.dumps(doc)), "triadcal.diagnosis")


@pytest.mark.parametrize("noise_mg", [1.0, 0.3])
def test_a_scale_asymmetry_is_never_named_k2(noise_mg):
    """An asymmetry e |a_i| (800 ppm) is no raw candidate; K2 a_i^2 closes most of its gap. Before
    the rivals K2 was named for it in 11 of 12 seeds at 1 mg (a confident wrong answer). Now:
    'unexplained', either with K2's gap left open or with scale_asymmetry among the rivals K2 does
    not beat on held-out intervals."""
    d = diagnose(recording(seed=1, asymmetry_ppm=800, noise_mg=noise_mg))
    v = d.doc["verdict"]
    assert v["effect"] == "unexplained" and v["best_partial"] == "scale_nonlinearity", v
    assert "scale_asymmetry" in v.get("ambiguous_with", []) or not d.candidate("scale_nonlinearity")[
        "full_fit"]["closes_gap"], v
    assert_valid(json.loads(json.dumps(d.doc)), "triadcal.diagnosis")


@pytest.mark.slow
def test_k2_and_asymmetry_over_seeds():
    """12 seeds each (numbers in docs/diagnosis.md): at 0.3 mg a sample K2 = 800 ug/g^2 is named in
    at least 11 (measured 12); an asymmetry of 800 ppm at 1 mg and at 0.3 mg is never named, and at
    1 mg K2 = 800 ug/g^2 is named or said to be ambiguous with the asymmetry, never anything else."""
    named = sum(diagnose(recording(seed=s, k2_ug=800, noise_mg=0.3)).doc["verdict"]["effect"]
                == "scale_nonlinearity" for s in range(1, 13))
    assert named >= 11, named
    for noise in (1.0, 0.3):
        for s in range(1, 13):
            v = diagnose(recording(seed=s, asymmetry_ppm=800, noise_mg=noise)).doc["verdict"]
            assert v["effect"] == "unexplained", (noise, s, v)
    for s in range(1, 13):
        v = diagnose(recording(seed=s, k2_ug=800)).doc["verdict"]
        assert v["effect"] == "scale_nonlinearity" or (
            v["effect"] == "unexplained" and v.get("ambiguous_with") == ["scale_asymmetry"]), (s, v)


def test_too_few_intervals_are_said_not_faked(tmp_path):
    rec = recording(seed=5, n_poses=9)
    out = fit_raw(rec, poses="unknown", local_g_m_s2=9.80665)
    d = diagnose_raw(out)
    doc = d.doc
    assert doc["verdict"]["effect"] is None and "no residual degree of freedom" in doc["verdict"]["reason"]
    assert all(not c["testable"] for c in doc["raw"]["candidates"])
    assert_valid(json.loads(json.dumps(doc)), "triadcal.diagnosis")
    # the summary says why there is no ratio, never "chi2/dof -" (issue 18, item 6)
    first = summary_lines(d)[0]
    assert "chi2/dof -" not in first and "no chi2: 9 intervals for the 9-parameter norm correction" in first, first


def test_cli_writes_the_diagnosis(tmp_path, capsys):
    rec = recording(seed=1, k2_ug=800, noise_mg=0.3)
    path = tmp_path / "rec.csv"
    np.savetxt(path, rec.acc, delimiter=",", header="ax,ay,az", comments="", fmt="%.7f")
    rc = cli_main(["fit-raw", str(path), "--rate", "100", "--unit", "g", "--poses", "unknown", "--local-g",
                   "9.80665", "--json", str(tmp_path / "r.json"), "--diagnose", str(tmp_path / "d.json")])
    assert rc in (0, 3)
    doc = json.loads((tmp_path / "d.json").read_text())
    assert_valid(doc, "triadcal.diagnosis")
    assert doc["verdict"]["term"] == "scale_nonlinearity"
    assert "verdict: scale_nonlinearity" in capsys.readouterr().out


def test_example_recording_mikoff_imu0():
    out = fit_raw(EXAMPLE, 100.0, unit="m/s2", poses="unknown")
    doc = diagnose_raw(out).doc
    assert_valid(json.loads(json.dumps(doc)), "triadcal.diagnosis")
    assert doc["verdict"]["effect"] is None          # at its noise floor (docs/diagnosis.md)


REAL_CASES = {
    "tomisuarez2": (["tomisuarez2_example_data_calibration.csv"], dict(rate_hz=100.0, poses="unknown")),
    "imucal": (["imucal_annotated_session.csv"], dict(rate_hz=102.4, labels="part")),
}


@pytest.mark.parametrize("case", sorted(REAL_CASES))
def test_shared_real_recordings(case):
    files, kw = REAL_CASES[case]
    if not REAL.is_dir():
        pytest.skip(f"{REAL} is absent (the shared real recordings are not in this repository)")
    out = fit_raw(REAL / files[0], kw.pop("rate_hz"), **kw)
    doc = diagnose_raw(out).doc
    assert_valid(json.loads(json.dumps(doc)), "triadcal.diagnosis")
    # both have too few intervals for a held-out score: said, not faked
    assert doc["verdict"]["effect"] is None
    assert all(not c["testable"] for c in doc["raw"]["candidates"])


def _with_temperature(rec, tempco_ug_per_C, profile):
    """The recording with a bias of ``tempco`` (ug/degC, every axis) on the readings and its
    per-sample temperature: ``profile`` 'cycle' (25 + 10 sin over 1.5 periods, so the temperature
    is not a function of the time) or 'ramp' (20 -> 40 degC, monotonic in the time)."""
    n = len(rec.acc)
    s = np.arange(n) / n
    T = 25.0 + 10.0 * np.sin(2 * np.pi * 1.5 * s) if profile == "cycle" else 20.0 + 20.0 * s
    w = rec.acc + tempco_ug_per_C * 1e-6 * (T - 25.0)[:, None]
    return RawRecording(w, RATE, "g", ("ax", "ay", "az"), source=rec.source), T


def test_a_bias_tempco_is_named_when_the_temperature_is_given_and_not_a_function_of_time():
    rec, T = _with_temperature(recording(seed=6, noise_mg=0.3), 30.0, "cycle")
    out = fit_raw(rec, poses="unknown", local_g_m_s2=9.80665)
    d = diagnose_raw(out, temperature=T)
    v = d.doc["verdict"]
    assert v["effect"] == "bias_tempco", v
    p = d.candidate("bias_tempco")["full_fit"]["new_parameters"]
    # the correction comes back as -30 ug/degC per axis, within 4 u (the planted bias is added to raw
    # readings, which the calibration scales by ~1)
    for name, q in p.items():
        assert q["unit"] == "ug/degC" and abs(q["value"] + 30.0) < 4 * q["u"] + 2.0, (name, q)
    assert_valid(json.loads(json.dumps(d.doc)), "triadcal.diagnosis")
    # without the temperature the candidate is said untestable, and nothing is named for it
    d0 = diagnose_raw(out)
    c0 = d0.candidate("bias_tempco")
    assert not c0["testable"] and "no temperature" in c0["reason"]
    assert d0.doc["verdict"]["effect"] in ("unexplained", None), d0.doc["verdict"]


def test_a_temperature_that_follows_the_time_cannot_be_told_from_a_drift():
    """On a monotonic ramp a bias tempco and a bias drift are the same shape over the intervals:
    the verdict is 'unexplained' with bias_drift among the rivals not beaten."""
    rec, T = _with_temperature(recording(seed=6, noise_mg=0.3), 30.0, "ramp")
    d = diagnose_raw(fit_raw(rec, poses="unknown", local_g_m_s2=9.80665), temperature=T)
    v = d.doc["verdict"]
    assert v["effect"] == "unexplained" and v["best_partial"] == "bias_tempco", v
    assert "bias_drift" in v["ambiguous_with"], v


@pytest.mark.slow   # 8 s
def test_a_drift_on_a_temperature_ramp_written_to_1e4_degC_is_never_named_a_tempco():
    """An outside probe: a bias drifting linearly in time, the temperature a ramp 20 -> 40 degC written to
    1e-4 degC: bias_tempco and bias_drift are one column up to that rounding, their held-out z^2 differ by
    ~1e-7 per fold with an SE smaller still, and "beats its closest rival by 2.51 paired SE" named
    bias_tempco (3 of these 30 recordings before). A rival is beaten only by 0.01 in z^2 per fold too
    (raw_verdict.MIN_RIVAL_Z2)."""
    named = []
    for seed in range(30):
        rec = recording(seed=200 + seed, noise_mg=1.0, n_poses=30)
        n = len(rec.acc)
        s = np.arange(n) / (n - 1)
        w = rec.acc + np.outer(s - 0.5, [1.0e-3, -0.8e-3, 0.6e-3])
        T = np.round(20.0 + 20.0 * s, 4)
        rec = RawRecording(w, RATE, "g", ("ax", "ay", "az"), source=rec.source)
        v = diagnose_raw(fit_raw(rec, poses="unknown", local_g_m_s2=9.80665), temperature=T).doc["verdict"]
        named.append(v["effect"])
        if v["effect"] == "unexplained" and v.get("gap_closed"):
            assert "bias_drift" in v["ambiguous_with"] or v["best_partial"] == "bias_drift", v
    assert "bias_tempco" not in named and "bias_drift" not in named, named


def test_a_temperature_of_the_wrong_length_is_refused():
    from triadcal.errors import InputError

    rec = recording(seed=6)
    out = fit_raw(rec, poses="unknown", local_g_m_s2=9.80665)
    with pytest.raises(InputError, match="one temperature"):
        diagnose_raw(out, temperature=np.zeros(len(rec.acc) - 5))
    T = np.zeros(len(rec.acc))
    T[17] = np.nan
    with pytest.raises(InputError, match="sample 17"):
        diagnose_raw(out, temperature=T)


def test_cli_reads_the_temperature_column_and_refuses_a_bad_field(tmp_path, capsys):
    """fit-raw --temperature-column T --diagnose: the column reaches the diagnosis (bias_tempco is
    named on a cycling temperature); a field that is not a number is refused with its line and
    column; a column not in the header is refused."""
    rec, T = _with_temperature(recording(seed=6, noise_mg=0.3), 30.0, "cycle")
    path = tmp_path / "rec.csv"
    np.savetxt(path, np.column_stack([rec.acc, T]), delimiter=",", header="ax,ay,az,T", comments="",
               fmt="%.7f")
    base = ["fit-raw", str(path), "--rate", "100", "--unit", "g", "--poses", "unknown", "--local-g", "9.80665",
            "--json", str(tmp_path / "r.json"), "--diagnose", str(tmp_path / "d.json")]
    assert cli_main(base + ["--temperature-column", "T"]) in (0, 3)
    doc = json.loads((tmp_path / "d.json").read_text())
    assert doc["verdict"]["effect"] == "bias_tempco", doc["verdict"]
    assert_valid(doc, "triadcal.diagnosis")
    lines = path.read_text().splitlines()
    lines[500] = ",".join(lines[500].split(",")[:3] + ["warm"])
    path.write_text("\n".join(lines) + "\n")
    capsys.readouterr()
    assert cli_main(base + ["--temperature-column", "T"]) == 1
    err = capsys.readouterr().err
    assert "rec.csv:501: column 'T'" in err and "warm" in err, err
    assert cli_main(base + ["--temperature-column", "degC"]) == 1
    assert "temperature column not in the header" in capsys.readouterr().err


def _intervals(poses, A, sigma_g):
    from triadcal.judgement.raw_diagnosis import IntervalData

    n = len(poses)
    return IntervalData(A, np.full(n, sigma_g), np.full(n, sigma_g * 17.3), np.full(n, 300), np.arange(n) * 400,
                        np.arange(n) * 400 + 300, np.arange(n) * 4.0, [""] * n, 1.0)


def test_a_null_verdict_states_its_detection_limits_and_they_hold():
    """A null verdict carries, for each candidate term, the size at which the gap's own rule (chi2 p <
    0.01 and chi2/dof > 1.2) fires with probability 0.95 (raw_limits.detection_limits, linearised).
    Checked by simulation on interval means made here with numpy: 40 poses on the sphere, an interval
    mean's SD 58 ug on each axis, K2 of axis x planted at the limit and at half of it (400 noise draws
    each, the poses fixed): the rule fires in 0.95 and in the noncentral chi2's prediction at a
    quarter of the noncentrality, each within 4 binomial SE; a clean draw does not fire at the limit's
    rate."""
    from scipy import stats

    from triadcal.judgement import raw_diagnosis as rd

    rng = np.random.default_rng(5)
    v = rng.standard_normal((40, 3))
    poses = v / np.linalg.norm(v, axis=1)[:, None]
    sig = 58e-6

    def draw(k2x_ug):
        A = poses.copy()
        A[:, 0] += k2x_ug * 1e-6 * poses[:, 0] ** 2
        return A + sig * rng.standard_normal(A.shape)

    clean = rd.diagnose_intervals(_intervals(poses, draw(0.0), sig))
    v0 = clean.doc["verdict"]
    assert v0["effect"] is None and "detection_limits" in v0, v0
    lim = v0["detection_limits"]
    assert lim["power"] == 0.95 and lim["dof"] == 31
    assert lim["critical_chi2"] == pytest.approx(max(stats.chi2.isf(0.01, 31), 1.2 * 31))
    byname = {e["effect"]: e for e in lim["candidates"]}
    assert set(byname) == {"scale_nonlinearity", "cross_coupling", "g_dependent_misalignment"}   # no temperature
    L = byname["scale_nonlinearity"]["parameters"]["K2_x"]["value"]
    assert byname["scale_nonlinearity"]["parameters"]["K2_x"]["unit"] == "ug/g2" and 100 < L < 2000, L
    assert "scale_nonlinearity" in v0["reason"] and "probability 0.95" in v0["reason"]

    def fires(k2x_ug, n=400):
        hits = 0
        for _ in range(n):
            d = _intervals(poses, draw(k2x_ug), sig)
            base = rd._Model(d, None)
            p, _, _ = base.fit(np.arange(40))
            hits += rd._chi2(rd._residual(d.A, base.B, p, 1.0), d.sigma, 40 - base.n_params)["significant"]
        return hits / n

    se = lambda p: np.sqrt(p * (1 - p) / 400)  # noqa: E731
    assert abs(fires(L) - 0.95) < 4 * se(0.95)
    half = float(stats.ncx2.sf(lim["critical_chi2"], 31, lim["noncentrality"] / 4))
    assert half < 0.5 and abs(fires(L / 2) - half) < 4 * se(half)
