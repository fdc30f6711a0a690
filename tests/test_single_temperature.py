"""A campaign at one temperature (docs/joint.md, "One temperature"): no temperature coefficient can
be determined, so the values are at the data's mean temperature and the result says so
(``reference_temperature_C`` moved there, a note). Before, a campaign at 50 degC reported its K
at "20 degC" with status ok, 419 u from the unit's K at 20 degC (an outside probe). The data are
made by tests/independent_bench.py; the truth at the reference is derived by hand from its laws
(``K (1 + k1 dT)``, ``S + s1 dT``, ``Ca + c1 dT`` with dT from 20 degC)."""

from __future__ import annotations

import numpy as np
import pytest

from independent_bench import T0_C, simulate_campaign
from triadcal.errors import InputError
from triadcal.estimation.joint import fit_joint
from triadcal.io.bench_csv import parse_bench_csv
from triadcal.judgement.compare import compare

EFFECTS = ["bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco"]


def _at(setpoint, seed):
    text, truth = simulate_campaign(np.random.default_rng(seed), setpoints_C=(setpoint,))
    return parse_bench_csv(text), truth


def test_one_temperature_is_reported_at_that_temperature():
    c, truth = _at(50.0, 5)
    r = fit_joint(c, EFFECTS)
    assert r.status == "ok", r.notes
    Tm = float(np.mean(c.t))
    assert r.reference_temperature_C == pytest.approx(Tm, abs=0.006) and abs(Tm - 50.0) < 1.0
    assert any("one temperature" in n and f"{r.reference_temperature_C:.2f} degC" in n for n in r.notes), r.notes
    assert not any("_tempco" in n for n in r.parameters)                 # held: not in the result
    dT = r.reference_temperature_C - T0_C
    for a, i in zip("xyz", range(3)):
        K = truth[f"K_{a}"] * (1.0 + 1e-6 * truth[f"K_{a}_tempco"] * dT)
        S = truth[f"S_{a}"] + 1e-6 * truth[f"S_{a}_tempco"] * dT
        pk, ps = r.parameters[f"K_{a}"], r.parameters[f"S_{a}"]
        assert abs(pk.value - K) < 4 * pk.u, (a, pk, K)
        assert abs(ps.value - S) < 4 * ps.u, (a, ps, S)
        # and far from the unit at 20 degC, where the old label put these values
        K20 = truth[f"K_{a}"]
        assert abs(K - K20) < 4 * pk.u or abs(pk.value - K20) > 4 * pk.u
    # a campaign whose one temperature is the reference keeps it
    c20, _ = _at(20.0, 6)
    Tm20 = float(np.mean(c20.t))
    r20 = fit_joint(c20, EFFECTS, reference_temperature_C=round(Tm20, 2))
    assert r20.reference_temperature_C == round(Tm20, 2)
    assert not any("values are at the mean temperature" in n for n in r20.notes), r20.notes
    # several temperatures: the requested reference, whatever the data's mean
    cm, _ = simulate_campaign(np.random.default_rng(7), setpoints_C=(40.0, 60.0))
    assert fit_joint(parse_bench_csv(cm), EFFECTS).reference_temperature_C == 20.0


def test_two_calibrations_at_one_setpoint_are_compared_with_a_note():
    before, _ = _at(50.0, 8)
    after, _ = _at(50.1, 9)                     # the chamber held 0.1 degC higher
    rb, ra = fit_joint(before, EFFECTS), fit_joint(after, EFFECTS)
    dT = abs(rb.reference_temperature_C - ra.reference_temperature_C)
    assert 0 < dT <= 0.2
    out = compare(rb, ra)
    assert any("one temperature each" in n for n in out.notes), out.notes
    # another setpoint is another temperature: refused
    other, _ = _at(60.0, 10)
    with pytest.raises(InputError, match="reference temperatures differ"):
        compare(rb, fit_joint(other, EFFECTS))
