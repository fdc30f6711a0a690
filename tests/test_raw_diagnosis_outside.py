"""fit-raw --diagnose against an outside tester's simulator: an error outside the candidates must not be
given a candidate's name where the data can tell them apart, and a named verdict says what it cannot
tell its term from.

The recordings are made here with numpy, as the tester's own simulator (rawsim.py) makes them and not
with triadcal's models: free static poses (gravity directions drawn N(0, I) and normalised, 3 s each)
joined by 1 s great-circle turns, a triad with scale errors, a non-orthogonal mixing and biases, white
noise, written to a CSV and read by ``triadcal fit-raw --diagnose`` as the tester's rawrun.sh does.
The planted effects are written out below:

- ``azim3``: output z += A cos(3 phi) (1 - a_z^2), phi the azimuth of gravity in the sensor frame: a
  shape outside every candidate (and rival) of the raw diagnosis;
- ``gdep``: output i += m_ij a_i^2 a_j (m in arcsec/g^2): a genuine g-dependent misalignment.

On the gravity norm at 40 random poses the azim3 pattern lies nearly in the span of
``g_dependent_misalignment`` and the 9-parameter correction (11-14 ug RMS of it outside, against an
interval floor of 67 ug at 1 mg a sample): there the data cannot tell them apart, and the verdict says
so (docs/diagnosis.md, "Diagnosing real recordings").
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from triadcal.cli import main as cli_main

sys.path.insert(0, str(Path(__file__).parent))
from test_results_contract import assert_valid  # noqa: E402

RATE = 100
ARCSEC = np.pi / 180 / 3600
#: the a18-silicon preset's g-dependent misalignments (arcsec/g^2; models/simulate.py), on (i, j) = output
#: i, toward j: a plausible size
SILICON_GDEP = {(0, 1): 20.0, (0, 2): -15.0, (1, 0): 18.0, (1, 2): -22.0, (2, 0): 16.0, (2, 1): 12.0}


def _slerp(u, v, n):
    w = np.arccos(np.clip(u @ v, -1, 1))
    t = np.linspace(0, 1, n)[:, None]
    if w < 1e-9:
        return np.repeat(u[None], n, 0)
    return (np.sin((1 - t) * w) * u + np.sin(t * w) * v) / np.sin(w)


def _poses(seed, npose=40):
    d = np.random.default_rng(seed).normal(size=(npose, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def readings(seed, azim3_ug=0.0, gdep=None, noise_g=1e-3, npose=40, static_s=3.0, move_s=1.0):
    """Readings in g (n, 3), the tester's rawsim.make with its draws in the same order."""
    r = np.random.default_rng(seed)
    dirs = r.normal(size=(npose, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    seg = []
    for i in range(npose):
        seg.append(np.repeat(dirs[i][None], int(static_s * RATE), 0))
        if i + 1 < npose:
            seg.append(_slerp(dirs[i], dirs[i + 1], int(move_s * RATE)))
    g = np.vstack(seg)
    scale = np.array([1.002, 0.997, 1.001])
    mix = np.array([[1, 2e-4, -1e-4], [1.5e-4, 1, 3e-4], [-2e-4, 1e-4, 1]])
    a = g @ mix.T
    out = a.copy()
    if azim3_ug:
        phi = np.arctan2(a[:, 1], a[:, 0])
        out[:, 2] += azim3_ug * 1e-6 * np.cos(3 * phi) * (1 - a[:, 2] ** 2)
    for (i, j), m in (gdep or {}).items():
        out[:, i] += m * ARCSEC * a[:, i] ** 2 * a[:, j]
    return out * scale + np.array([3e-3, -2e-3, 5e-3]) + r.normal(0, noise_g, (len(g), 3))


def diagnose_csv(tmp_path, y, name="rec"):
    """``triadcal fit-raw REC.csv --rate 100 --unit g --poses unknown --diagnose D.json`` (rawrun.sh)."""
    csv = tmp_path / f"{name}.csv"
    np.savetxt(csv, y, delimiter=",", header="acc_x,acc_y,acc_z", comments="", fmt="%.9f")
    diag = tmp_path / f"{name}.diag.json"
    rc = cli_main(["fit-raw", str(csv), "--rate", str(RATE), "--unit", "g", "--poses", "unknown",
                   "--json", str(tmp_path / f"{name}.fit.json"), "--diagnose", str(diag), "--quiet"])
    assert rc in (0, 3), rc
    doc = json.loads(diag.read_text())
    assert_valid(doc, "triadcal.diagnosis")
    return doc


def _cand(doc, name):
    return next(c for c in doc["raw"]["candidates"] if c["term"] == name)


def _one_sentence(text):
    return isinstance(text, str) and text.strip() and "\n" not in text


def test_cos3phi_error_where_only_the_held_out_test_tells_it_from_gdep(tmp_path):
    """cos 3phi at 1500 ug, 1 mg a sample. On seeds 2 and 11 (of 1-12) g_dependent_misalignment's refit
    closes the gap on the intervals it is fitted to (chi2 p > 0.01), but held out its residual is not at
    the floor: each held-out interval misses by more than the floor widened by the uncertainty of its
    15 parameters allows. Before the held-out floor test both were named g_dependent_misalignment
    (with "chi2/dof after its refit 1.70 / 1.33"); now unexplained, with the best partial and how far
    it shrank."""
    for seed in (2, 11):
        doc = diagnose_csv(tmp_path, readings(seed, azim3_ug=1500), f"azim3_1500_s{seed}")
        v = doc["verdict"]
        assert v["effect"] == "unexplained" and v["best_partial"] == "g_dependent_misalignment", (seed, v)
        c = _cand(doc, "g_dependent_misalignment")
        assert c["significant"] and c["full_fit"]["closes_gap"], (seed, c["full_fit"])
        fl = c["held_out"]["floor"]
        assert not fl["at_floor"] and fl["p_value"] < 0.01 and fl["ratio"] > 1.2, (seed, fl)
        assert v["held_out_at_floor"] is False and v["gap_closed"] is False
        assert _one_sentence(v["reason"]) and "not on held-out ones" in v["reason"], v["reason"]
        assert f"{fl['expected_rms_ug']:.3g} ug expected" in v["reason"]
        assert "fitted size" in v["evidence"] and v["size"]["unit"] == "arcsec/g2"


def test_cos3phi_error_is_unexplained_where_the_data_tell_it_from_gdep(tmp_path):
    """cos 3phi at 500 ug, 0.1 mg a sample (interval floor about 7 ug): the 11-14 ug of its pattern
    outside g_dependent_misalignment's span are seen, and the verdict is unexplained."""
    for seed in (1, 2, 3):
        doc = diagnose_csv(tmp_path, readings(seed, azim3_ug=500, noise_g=1e-4), f"azim3_s{seed}")
        v = doc["verdict"]
        assert v["effect"] == "unexplained" and v["best_partial"] == "g_dependent_misalignment", (seed, v)
        assert v["gap_closed"] is False and _one_sentence(v["reason"]) and v["evidence"], v


def _outside_span_rms_ug(seed, azim3_ug):
    """The part of the cos 3phi error's gravity-norm pattern (to first order a . e(a)) at the recording's
    poses that no g-dependent misalignment plus a symmetric correction and a bias (the diagnosis's base)
    can make, least squares with numpy: what a named g_dependent_misalignment cannot see."""
    a = _poses(seed)
    phi = np.arctan2(a[:, 1], a[:, 0])
    pattern = a[:, 2] * azim3_ug * np.cos(3 * phi) * (1 - a[:, 2] ** 2)
    x, y, z = a.T
    cols = [x * x, y * y, z * z, x * y, x * z, y * z, x, y, z]                 # a' D a + a' b
    cols += [a[:, i] * a[:, i] ** 2 * a[:, j] for i, j in SILICON_GDEP]        # a_i m_ij a_i^2 a_j
    X = np.column_stack(cols)
    res = pattern - X @ np.linalg.lstsq(X, pattern, rcond=None)[0]
    return float(np.sqrt(np.mean(res ** 2)))


def test_cos3phi_error_at_1mg_is_never_a_bare_name(tmp_path):
    """cos 3phi at 500 ug, 1 mg a sample (the tester's case: named g_dependent_misalignment in 4 of 6
    recordings, "chi2/dof after 0.999", "beats its closest rival"). Its pattern lies so nearly in the
    candidate's span (11-14 ug RMS outside it against a 67 ug floor: a noncentrality of about 2) that
    no test on these intervals tells them apart, and the held-out residual is at the floor (84 ug against
    87 expected of a term that explains everything). Where it is named, the verdict now says what it
    could not see -- a pattern up to its ``unseen`` RMS beyond the term, here above what the cos 3phi
    leaves -- reports the fitted size with its u, and the held-out floor test; it has a reason."""
    named = 0
    for seed in (1, 2, 3, 6):
        doc = diagnose_csv(tmp_path, readings(seed, azim3_ug=500), f"azim3_1mg_s{seed}")
        v = doc["verdict"]
        assert _one_sentence(v["reason"]), v
        if v["effect"] != "g_dependent_misalignment":
            assert v["effect"] in ("unexplained", None), v
            continue
        named += 1
        c = _cand(doc, "g_dependent_misalignment")
        fl, unseen = c["held_out"]["floor"], c["full_fit"]["unseen"]
        assert v["held_out_at_floor"] and fl["at_floor"]
        assert f"p = {fl['p_value']:.3g}" in v["reason"] and "held-out residual is at the floor" in v["reason"]
        # the held-out RMS is measured against the floor widened by the parameters' uncertainty, not the floor
        assert fl["expected_rms_ug"] > 1.2 * doc["gap"]["noise_floor_ug"]
        size = v["size"]
        assert size["unit"] == "arcsec/g2" and abs(size["value"]) > 2 * size["u"] and size["of"] == 6
        assert f"{size['parameter']} = {size['value']:.4g}" in v["evidence"]
        assert unseen["rms_ug"] > _outside_span_rms_ug(seed, 500.0), (unseen, seed)
        assert f"less than about {unseen['rms_ug']:.3g} ug RMS" in v["caveat"]
    assert named >= 3          # measured: seeds 1, 2, 3 and 6 are all named (2026-12, 4 of 6 over seeds 1-6)


def test_a_genuine_gdep_of_the_silicon_presets_size_is_named(tmp_path):
    """The a18-silicon preset's g-dependent misalignments (12-22 arcsec/g^2) at 0.1 mg a sample: named,
    held out at the floor, its corrections the planted sizes with the opposite sign (within 4 u)."""
    names = {(0, 1): "xy", (0, 2): "xz", (1, 0): "yx", (1, 2): "yz", (2, 0): "zx", (2, 1): "zy"}
    for seed in (1, 2, 3):
        doc = diagnose_csv(tmp_path, readings(seed, gdep=SILICON_GDEP, noise_g=1e-4), f"gdep_s{seed}")
        v = doc["verdict"]
        assert v["effect"] == "g_dependent_misalignment", (seed, v)
        assert v["held_out_at_floor"] and v["gap_closed"] and _one_sentence(v["reason"]) and v["evidence"]
        assert "caveat" in v and v["size"]["unit"] == "arcsec/g2"
        pars = _cand(doc, "g_dependent_misalignment")["full_fit"]["new_parameters"]
        for ij, m in SILICON_GDEP.items():
            q = pars[f"Ca_{names[ij]}_g2"]
            assert abs(q["value"] + m) < 4 * q["u"] + 3.0, (seed, ij, q)


def test_a_clean_recording_is_null(tmp_path):
    for seed in (1, 2, 3):
        doc = diagnose_csv(tmp_path, readings(seed), f"clean_s{seed}")
        v = doc["verdict"]
        assert v["effect"] is None and "noise floor" in v["reason"] and _one_sentence(v["reason"]), v
        assert "evidence" not in v


@pytest.mark.slow          # 5-10 s: slow since the thirteenth session (the quick suite's 10 min)
def test_the_held_out_floor_test_has_its_size():
    """The held-out floor test under its null, on interval means made with numpy (40 poses, an SD of
    58 ug, the floors exact): a genuine g-dependent misalignment (15 parameters with the base), 150
    noise draws. The held-out mean square of the right term is about 1.6 x the floor's, not 1 (each
    held-out interval is predicted by parameters fitted without it); the test's expectation follows it
    (mean ratio 1 within 7 %: 3 SE), and it rejects at most at its level (0.01 + 4 binomial SE)."""
    from test_raw_diagnosis import _intervals

    from triadcal.judgement import raw_diagnosis as rd

    rng = np.random.default_rng(11)
    poses = _poses(11)
    sig = 58e-6
    truth = poses.copy()
    truth[:, 0] += 400 * ARCSEC * poses[:, 0] ** 2 * poses[:, 2]
    truth[:, 2] += 300 * ARCSEC * poses[:, 2] ** 2 * poses[:, 0]
    n_draws = 150
    ms, ratio, rejected, pvals = [], [], 0, []
    for _ in range(n_draws):
        d = _intervals(poses, truth + sig * rng.standard_normal(truth.shape), sig)
        base = rd._Model(d, None)
        p0, _, _ = base.fit(np.arange(40))
        r0 = rd._residual(d.A, base.B, p0, 1.0)
        c = rd._score(d, "g_dependent_misalignment", base, r0, rd._chi2(r0, d.sigma, 31))
        fl = c["held_out"]["floor"]
        ms.append(fl["mean_square"]), ratio.append(fl["ratio"]), pvals.append(fl["p_value"])
        rejected += not fl["at_floor"]
        expected = fl["expected"]
    assert 1.4 < expected < 1.9, expected
    assert abs(np.mean(ms) / expected - 1) < 0.08 and abs(np.mean(ratio) - 1) < 0.07, (np.mean(ms), np.mean(ratio))
    assert rejected / n_draws <= 0.01 + 4 * np.sqrt(0.01 * 0.99 / n_draws)
    assert stats.kstest(pvals, "uniform").pvalue > 0.001


@pytest.mark.parametrize("kind", ["null", "unexplained", "named"])
def test_every_raw_verdict_has_a_one_sentence_reason(tmp_path, kind):
    """A named verdict has a reason as well as its evidence; an unexplained one with a best candidate
    has evidence as well as its reason."""
    y = {"null": lambda: readings(4),
         "unexplained": lambda: readings(4, azim3_ug=500, noise_g=1e-4),
         "named": lambda: readings(4, gdep=SILICON_GDEP, noise_g=1e-4)}[kind]()
    v = diagnose_csv(tmp_path, y, kind)["verdict"]
    assert _one_sentence(v["reason"]), v
    if kind != "null":
        assert _one_sentence(v["evidence"]) and "held-out RMS" in v["evidence"], v
    assert (v["effect"] is None) == (kind == "null") and (v["effect"] == "unexplained") == (kind == "unexplained")
