"""The lab's systematic errors (Type B budget rows) in a drift: independent by default, shared
equipment subtracted on request (compare(..., shared_equipment=...), --lab, --shared-bench)."""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from triadcal.errors import InputError
from triadcal.estimation.result import CalibrationResult, ParameterValue
from triadcal.judgement.compare import ANGLES, compare, compare_sequence

ENCODER = {"source": "encoder zero, axis 1", "type": "B", "distribution": "normal", "u": 5.0, "unit": "arcsec",
           "sensitivity_unit": "arcsec/arcsec", "dof": None, "key": "[bench] encoder_zero_u_arcsec"}


def _param(value, u_a, c=None, u_s=5.0):
    """An angle whose budget has a Type A row ``u_a`` and, with ``c``, the encoder-zero row
    (sensitivity ``c``, u ``u_s``): u = sqrt(u_a^2 + (c u_s)^2)."""
    if c is None:
        return ParameterValue(value, u_a, "arcsec")
    rows = [{"source": "fit (Type A)", "type": "A", "distribution": "normal", "u": u_a, "unit": "arcsec",
             "sensitivity": 1.0, "sensitivity_unit": "1", "contribution": u_a, "dof": None,
             "key": "the fit's standard uncertainty"},
            dict(ENCODER, u=u_s, sensitivity=c, contribution=abs(c) * u_s)]
    u = math.sqrt(u_a ** 2 + (c * u_s) ** 2)
    return ParameterValue(value, u, "arcsec", {"u_type_a": u_a, "U": 2 * u, "k": 2.0, "U_method": "test",
                                               "budget": rows})


def _result(xy, zx, u_a, u_s=5.0, budget=True):
    """Ca_xy (sensitivity +1 to the encoder zero) and Ca_zx (sensitivity -1), Type A ``u_a``
    each; the other four angles 0 +- 2 arcsec without a budget. The correlation matrix is the
    combined one: cov(xy, zx) = (+1)(-1) u_s^2."""
    params = {n: ParameterValue(0.0, 2.0, "arcsec") for n in ANGLES}
    params["Ca_xy"] = _param(xy, u_a, +1.0 if budget else None, u_s)
    params["Ca_zx"] = _param(zx, u_a, -1.0 if budget else None, u_s)
    r = CalibrationResult(unit="SN-1", method="joint", parameters=params, effects=("bench_tilt",))
    from triadcal.models.model import Model
    m = Model(r.effects)       # what it does not hold is held, so that it reads back
    r.extra["fixed"] = {n: {"value": m.spec[n].nominal, "unit": m.spec[n].unit} for n in m.names if n not in params}
    R = np.eye(6)
    if budget:
        i, j = ANGLES.index("Ca_xy"), ANGLES.index("Ca_zx")
        R[i, j] = R[j, i] = -u_s ** 2 / (params["Ca_xy"].u * params["Ca_zx"].u)
    r.correlation_names, r.correlation = ANGLES, R
    from triadcal.estimation.gates import FitEvidence, apply_gates
    apply_gates(r, FitEvidence(converged=True))    # status ok is read back only with its gates
    return r


# Hand derivation. Before: Type A 3", after: Type A 4"; the encoder zero of axis 1 (u_s = 5")
# goes +1 into Ca_xy and -1 into Ca_zx in both.
#   u_b = sqrt(3^2 + 5^2) = sqrt(34) = 5.8310, u_a = sqrt(4^2 + 5^2) = sqrt(41) = 6.4031
#   independent (default): u(d) = sqrt(34 + 41) = sqrt(75) = 8.6603
#   shared bench:          u(d) = sqrt(34 + 41 - 2 (+1)(+1) 25) = sqrt(25) = 5  (= sqrt(3^2 + 4^2):
#                          the encoder zero cancels); rho = 25 / sqrt(34 * 41) = 0.66844
# Joint test with drifts d = (Ca_xy, Ca_zx) = (+4, -3), the other four 0:
#   C_b + C_a on (xy, zx) = [[75, -50], [-50, 75]]; X = c_b c_a^T u_s^2 = [[25, -25], [-25, 25]]
#   independent: D2 = d^T [[75,-50],[-50,75]]^-1 d = (75*16 - 2*50*12 + 75*9) / (75^2 - 50^2) = 675/3125 = 0.216
#   shared:      C - X - X^T = [[25, 0], [0, 25]], D2 = (16 + 9) / 25 = 1.0
BEFORE = dict(xy=100.0, zx=-50.0, u_a=3.0)
AFTER = dict(xy=104.0, zx=-53.0, u_a=4.0)


def test_drift_u_independent_and_shared_by_hand():
    before, after = _result(**BEFORE), _result(**AFTER)
    assert before["Ca_xy"].u == pytest.approx(math.sqrt(34)) and after["Ca_xy"].u == pytest.approx(math.sqrt(41))

    c = compare(before, after, tolerance_arcsec=None)
    assert c["Ca_xy"].u == pytest.approx(math.sqrt(75))
    assert c["Ca_zx"].u == pytest.approx(math.sqrt(75))
    assert c["Ca_xy"].rho == 0.0
    assert c.joint.D2 == pytest.approx(0.216)
    assert c.correlation["shared"]["equipment"] == [] and c.correlation["shared"]["sources"] == []
    assert "independent" in c.correlation["reason"] and "combined" in c.correlation["reason"]

    s = compare(before, after, tolerance_arcsec=None, shared_equipment=("bench", "gravity"))
    assert s["Ca_xy"].u == pytest.approx(5.0)
    assert s["Ca_zx"].u == pytest.approx(5.0)
    assert s["Ca_xy"].rho == pytest.approx(25 / math.sqrt(34 * 41))
    assert s["Ca_xy"].En == pytest.approx(4.0 / 10.0)              # |d| / (2 u(d))
    assert s["Ca_yx"].u == pytest.approx(2 * math.sqrt(2))          # no budget: unchanged
    assert s.joint.D2 == pytest.approx(1.0)
    sh = s.correlation["shared"]
    assert sh["equipment"] == ["bench", "gravity"]
    assert [x["source"] for x in sh["sources"]] == ["encoder zero, axis 1"]
    assert sh["sources"][0]["u"] == 5.0 and sh["sources"][0]["key"] == "[bench] encoder_zero_u_arcsec"
    assert sh["covariance"]["Ca_xy"] == pytest.approx(25.0) and sh["covariance"]["Ca_zx"] == pytest.approx(25.0)
    assert "Shared equipment [bench], [gravity]" in s.correlation["reason"]
    assert any("encoder zero, axis 1" in n for n in s.notes)

    # sharing only equipment that has no row here (the fixture) changes nothing
    f = compare(before, after, tolerance_arcsec=None, shared_equipment=("fixture",))
    assert f["Ca_xy"].u == pytest.approx(math.sqrt(75)) and f.joint.D2 == pytest.approx(0.216)
    assert any("fixture" in n and "nothing to share" in n for n in f.notes)

    # a sequence passes it on
    seq = compare_sequence([before, after], tolerance_arcsec=None, shared_equipment=("bench",))
    assert seq.steps[0]["Ca_xy"].u == pytest.approx(5.0)


def test_shared_source_with_different_u_is_refused():
    before, after = _result(**BEFORE), _result(**AFTER, u_s=6.0)
    compare(before, after)                                          # independent: fine
    with pytest.raises(InputError, match=r"encoder zero, axis 1.*u = 5 arcsec.*6 arcsec"):
        compare(before, after, shared_equipment=("bench",))


def test_sharing_without_budgets_says_nothing_to_share():
    before, after = _result(**BEFORE, budget=False), _result(**AFTER)
    c = compare(before, after, tolerance_arcsec=None, shared_equipment=("bench", "gravity"))
    assert any("before calibration has no budget rows" in n and "nothing to share" in n for n in c.notes)
    assert c["Ca_xy"].u == pytest.approx(math.sqrt(9 + 41))
    assert "Type A only" in c.correlation["reason"]
    with pytest.raises(InputError, match="not a lab-file equipment section"):
        compare(before, after, shared_equipment=("benchh",))
    with pytest.raises(InputError, match="not both"):
        compare(before, after, correlation=0.3, shared_equipment=("bench",))


def _cli(*args, cwd):
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run([sys.executable, "-m", "triadcal", "compare", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, env=env)


@pytest.mark.slow
def test_cli_shared_bench_and_lab(tmp_path):
    _result(**BEFORE).save(tmp_path / "b.json")
    _result(**AFTER).save(tmp_path / "a.json")
    r = _cli("b.json", "a.json", "--shared-bench", "--tolerance", "none", "--json", "out.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "shared equipment: bench, gravity" in r.stdout
    assert "encoder zero, axis 1 ([bench] encoder_zero_u_arcsec, u = 5 arcsec)" in r.stdout
    d = json.loads((tmp_path / "out.json").read_text())
    assert d["correlation"]["shared"]["equipment"] == ["bench", "gravity"]
    assert d["correlation"]["shared"]["sources"][0]["source"] == "encoder zero, axis 1"
    assert d["parameters"]["Ca_xy"]["u"] == pytest.approx(5.0)

    (tmp_path / "lab.toml").write_text('[compare]\nshared_equipment = ["bench"]\n')
    r = _cli("b.json", "a.json", "--lab", "lab.toml", "--tolerance", "none", "--json", "lab.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "shared equipment: bench;" in r.stdout
    assert json.loads((tmp_path / "lab.json").read_text())["parameters"]["Ca_xy"]["u"] == pytest.approx(5.0)

    r = _cli("b.json", "a.json", "--tolerance", "none", "--json", "ind.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "shared equipment: none" in r.stdout
    assert json.loads((tmp_path / "ind.json").read_text())["parameters"]["Ca_xy"]["u"] == pytest.approx(math.sqrt(75))


def test_end_to_end_shared_encoder_zero(tmp_path):
    """One unchanged unit, two campaigns on one bench whose encoder zeros are (5", 5") in both:
    the encoder zero of axis 1 goes one to one into Ca_xz and Ca_zx, so sharing the bench
    removes its 5" (twice, in quadrature) from the drift's u."""
    sys.path.insert(0, os.path.dirname(__file__))
    from independent_bench import simulate_campaign
    from triadcal import api
    from triadcal.io.lab import LabConfig

    lab = LabConfig(sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0, encoder_zero_u_arcsec=5.0, source="t")
    effects = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")
    rng = np.random.default_rng(7)
    paths, truth = [], None
    for name in ("before", "after"):
        text, truth = simulate_campaign(rng, truth=truth, encoder_zero_arcsec=(5.0, 5.0),
                                        sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0)
        paths.append(tmp_path / f"{name}.csv")
        paths[-1].write_text(text)
    rb, ra = (api.fit(p, effects=effects, lab=lab) for p in paths)
    assert rb.status == "ok" and ra.status == "ok"
    rows = {r["source"]: r for r in rb["Ca_xz"].uncertainty["budget"] if r["type"] == "B"}
    assert abs(rows["encoder zero, axis 1"]["sensitivity"]) == pytest.approx(1.0, abs=0.05)

    ind = compare(rb, ra, tolerance_arcsec=None)
    sh = compare(rb, ra, tolerance_arcsec=None, shared_equipment=("bench", "gravity"))
    for n in ("Ca_xz", "Ca_zx"):
        u_ind, u_sh = ind[n].u, sh[n].u
        ua_b, ua_a = rb[n].uncertainty["u_type_a"], ra[n].uncertainty["u_type_a"]
        print(f"{n}: u(d) independent {u_ind:.3f}, shared {u_sh:.3f}, Type A only {math.hypot(ua_b, ua_a):.3f}")
        # independent: >= the two encoder zeros in quadrature (5 sqrt 2 = 7.07"); shared: they cancel
        assert u_ind >= 5.0 * math.sqrt(2) * 0.95
        assert u_sh < 0.6 * u_ind
        assert u_sh == pytest.approx(math.hypot(ua_b, ua_a), rel=0.1)
    assert sh.joint.D2 != pytest.approx(ind.joint.D2)
    assert any(s["source"] == "encoder zero, axis 1" for s in sh.correlation["shared"]["sources"])


def test_posterior_draws_get_the_type_b_part():
    """Posterior draws are Type A only (3" and 4"): the drift draws get the Type B part, 25 + 25
    independent (sd sqrt(9 + 16 + 50) = 8.66") and 25 + 25 - 2*25 = 0 shared (sd 5"). With
    d = 4, T = 10: P(|d| > 10) = Phi(-6/8.66) + Phi(-14/8.66) = 0.297 and
    Phi(-6/5) + Phi(-14/5) = 0.118."""
    before, after = _result(**BEFORE), _result(**AFTER)
    rng = np.random.default_rng(0)
    pb = {"Ca_xy": 100.0 + 3.0 * rng.standard_normal(20000)}
    pa = {"Ca_xy": 104.0 + 4.0 * rng.standard_normal(20000)}
    ind = compare(before, after, tolerance_arcsec=10.0, posterior_before=pb, posterior_after=pa)
    sh = compare(before, after, tolerance_arcsec=10.0, posterior_before=pb, posterior_after=pa,
                 shared_equipment=("bench",))
    assert ind["Ca_xy"].basis == "posterior" and ind["Ca_xy"].p_exceeds == pytest.approx(0.297, abs=0.01)
    assert sh["Ca_xy"].p_exceeds == pytest.approx(0.118, abs=0.01)
    assert any("Type A part only" in n for n in ind.notes)
