"""The lab's own errors in the budget, proven on data made another way (issue 16, item 5).

Campaigns come from ``tests/independent_bench.py`` (rotation matrices of scipy, no code of
triadcal's model): the paper's bench (sigma_1 = 5", sigma_2 = 2" per visit), and per campaign a
non-orthogonality of the bench axes, two encoder zeros, a fixture rotation about each IMU axis
and a local-g error drawn from the lab file's standard uncertainties (5", 5", 10", 10 ppm).
The fit is given that lab file. Claims (tolerances from theory, not tuned):

- coverage of value +- U (k from dof_eff) for every family (angles, K, S, tempcos): 0.95 +- 0.03
  over 200 campaigns (the issue's band; the binomial SD of a 0.9545 rate over 600 estimates is
  0.009, over 200 estimates of one family's campaign-level errors at worst 0.015);
- RMS error / RMS u within [0.85, 1.15] per family;
- status ok (a certificate's precondition) in >= 95 % of the campaigns;
- compare on two calibrations of an unchanged unit (bench errors drawn anew for each: the
  conservative case) says "fail" in <= 6 %.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from independent_bench import simulate_campaign
from triadcal import api
from triadcal.io.lab import LabConfig

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")
LAB = LabConfig(sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0, axes_nonorthogonality_u_arcsec=5.0,
                encoder_zero_u_arcsec=5.0, mounting_u_arcsec=10.0, local_g_u_ppm=10.0, source="test lab")
FAMILIES = {"angles": lambda n: n.startswith("Ca_") and n.count("_") == 1,
            "K": lambda n: n.startswith("K_") and n.count("_") == 1,
            "S": lambda n: n.startswith("S_") and n.count("_") == 1,
            "tempcos": lambda n: n.endswith("_tempco")}


def _campaign(rng, tmp_path, name, truth=None):
    text, truth = simulate_campaign(
        rng, truth=truth, sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0,
        encoder_zero_arcsec=tuple(rng.normal(0.0, 5.0, 2)), axes_nonorthogonality_arcsec=float(rng.normal(0.0, 5.0)),
        fixture_arcsec=tuple(rng.normal(0.0, 10.0, 3)), tilt_arcsec=tuple(rng.normal(0.0, 30.0, 2)),
        true_g_m_s2=9.80665 * (1.0 + 10e-6 * rng.normal()))
    path = tmp_path / f"{name}.csv"
    path.write_text(text)
    return path, truth


@pytest.mark.slow
def test_lab_errors_give_honest_U_for_every_family(tmp_path):
    rng = np.random.default_rng(20261125)
    n = 200
    err = {f: [] for f in FAMILIES}
    u = {f: [] for f in FAMILIES}
    covered = {f: [] for f in FAMILIES}
    ok = 0
    for i in range(n):
        path, truth = _campaign(rng, tmp_path, f"c{i}")
        r = api.fit(path, effects=EFFECTS, lab=LAB)
        ok += r.status == "ok"
        for name, p in r.parameters.items():
            fam = next((f for f, is_ in FAMILIES.items() if is_(name)), None)
            if fam is None or name not in truth:
                continue
            assert p.U is not None and p.uncertainty["budget"], name
            e = p.value - truth[name]
            err[fam].append(e / p.u)         # normalised: families mix units (K_x vs K_y similar)
            u[fam].append(1.0)
            covered[fam].append(abs(e) <= p.U)
    lines = []
    for f in FAMILIES:
        z = np.array(err[f])
        cov = float(np.mean(covered[f]))
        ratio = math.sqrt(float(np.mean(z ** 2)))
        lines.append(f"{f}: n = {len(z)}, coverage {cov:.3f}, RMS(error/u) {ratio:.3f}")
    print("\n" + "\n".join(lines) + f"\nstatus ok in {ok}/{n}")
    for f in FAMILIES:
        z = np.array(err[f])
        assert 0.92 <= float(np.mean(covered[f])) <= 0.98, lines
        assert 0.85 <= math.sqrt(float(np.mean(z ** 2))) <= 1.15, lines
    assert ok >= 0.95 * n


@pytest.mark.slow
def test_without_the_systematic_terms_the_same_campaigns_are_not_covered(tmp_path):
    """The control: the same kind of campaigns with a lab file that states only the random
    bench errors. The fixture's 10" go one to one into the angles, whose u is then ~1": the
    coverage collapses (the check above can fail)."""
    rng = np.random.default_rng(20261125)
    random_only = LabConfig(sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0, source="random only")
    covered = []
    for i in range(30):
        path, truth = _campaign(rng, tmp_path, f"c{i}")
        r = api.fit(path, effects=EFFECTS, lab=random_only)
        covered += [abs(p.value - truth[n]) <= 2 * p.u for n, p in r.parameters.items()
                    if FAMILIES["angles"](n)]
    assert float(np.mean(covered)) < 0.6


@pytest.mark.slow
def test_compare_of_an_unchanged_unit_rarely_fails(tmp_path):
    from triadcal.judgement.compare import compare

    rng = np.random.default_rng(1125)
    n, fails = 200, 0
    for i in range(n):
        before, truth = _campaign(rng, tmp_path, f"b{i}")
        after, _ = _campaign(rng, tmp_path, f"a{i}", truth=truth)
        rb, ra = api.fit(before, effects=EFFECTS, lab=LAB), api.fit(after, effects=EFFECTS, lab=LAB)
        if rb.status != "ok" or ra.status != "ok":
            continue
        c = compare(rb, ra, tolerance_arcsec=None)
        fails += c.overall == "fail"
    print(f"\ncompare said fail on {fails}/{n} unchanged units")
    assert fails <= 0.06 * n
