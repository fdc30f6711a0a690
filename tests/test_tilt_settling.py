"""A bench tilt that settles, ``d (1 - exp(-t/tau_s))`` (models/effects/tilt_drift.py,
``tilt_settling``): the term by hand, its fit and its diagnosis on campaigns made by the independent
bench (tests/independent_bench.py: gravity tilted in the base frame with scipy rotations, per visit,
no model code), the diagnosis telling it from a constant rate, and the gate of its time constant.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from independent_bench import default_truth, simulate_campaign  # noqa: E402

from triadcal.estimation.gates import result_gates  # noqa: E402
from triadcal.estimation.joint import fit_joint  # noqa: E402
from triadcal.estimation.result import ParameterValue  # noqa: E402
from triadcal.io.bench_csv import parse_bench_csv  # noqa: E402
from triadcal.judgement.diagnose import diagnose  # noqa: E402
from triadcal.models.effects.tilt_drift import TiltSettling, settled_fraction  # noqa: E402
from triadcal.models.units import ARCSEC  # noqa: E402

SETPOINTS = (20, 30, 40, 50, 60, 70, 60, 50, 40, 30, 20, 10, 0, -10, -20, -30, -40, -30, -20, -10, 0, 10, 20)
MODEL = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")
OPTS = dict(n_draws=100, seed=0, cross_group=False)
TILT = (52.0, 30.0)                   # arcsec
D = (20.0, -12.0)                     # arcsec, the settled change
TAU_H = 20.0                          # the campaign lasts 97 h (23 setpoints of 4.2 h)


def test_settled_fraction_by_hand():
    """1 - e^-1 at t = tau, 1 - e^-2 at 2 tau, 0 before the start; CasADi's value the same."""
    tau = 3600.0
    assert settled_fraction(tau, tau) == pytest.approx(1 - math.exp(-1), rel=1e-12)
    assert settled_fraction(2 * tau, -tau) == pytest.approx(1 - math.exp(-2), rel=1e-12)   # |tau|
    assert settled_fraction(-50.0, tau) == 0.0
    t = ca.SX.sym("t")
    f = ca.Function("f", [t], [settled_fraction(t, tau)])
    assert float(f(1800.0)) == pytest.approx(1 - math.exp(-0.5), rel=1e-12)


def test_the_term_moves_the_horizontal_components_by_hand():
    """At t = tau_s the tilt has moved by d (1 - 1/e); z renormalised."""
    from types import SimpleNamespace

    p = {"tilt_x_settle": 20 * ARCSEC, "tilt_y_settle": -12 * ARCSEC, "tilt_settle_tau": 7200.0}
    f0 = (52 * ARCSEC, 30 * ARCSEC, 1.0)
    tx, ty, tz = TiltSettling().gravity_base(p, SimpleNamespace(time_s=7200.0), f0)
    s = 1 - math.exp(-1)
    assert tx == pytest.approx((52 + 20 * s) * ARCSEC, rel=1e-12)
    assert ty == pytest.approx((30 - 12 * s) * ARCSEC, rel=1e-12)
    assert tz == pytest.approx(math.sqrt(1 - tx * tx - ty * ty), rel=1e-15)


def bench(seed: int, change: str):
    """The independent bench, 23 setpoints, 12 positions, the tilt changing by ``change``:
    ``settle`` (D (1 - exp(-t / 20 h))) or ``rate`` (the same total change in a straight line)."""
    rng = np.random.default_rng(seed)
    t = default_truth(rng)

    def settle(time_s):
        s = 1.0 - np.exp(-np.asarray(time_s) / (TAU_H * 3600.0))
        return D[0] * s, D[1] * s

    def rate(time_s):
        s = np.asarray(time_s) / 350000.0          # about the campaign's length
        return D[0] * s, D[1] * s

    txt, truth = simulate_campaign(rng, truth=t, setpoints_C=SETPOINTS, tilt_arcsec=TILT,
                                   tilt_change=settle if change == "settle" else rate)
    return parse_bench_csv(txt), truth


def test_the_fit_recovers_the_settling_within_its_uncertainty():
    c, truth = bench(0, "settle")
    r = fit_joint(c, MODEL + ("tilt_settling",))
    assert r.status == "ok", r.notes
    p = r.parameters
    for name, true in (("tilt_x", TILT[0]), ("tilt_y", TILT[1]), ("tilt_x_settle", D[0]),
                       ("tilt_y_settle", D[1]), ("tilt_settle_tau", TAU_H)):
        assert abs(p[name].value - true) < 4 * p[name].u, (name, p[name], true)
    assert p["tilt_settle_tau"].unit == "h"


@pytest.mark.slow          # 5-10 s: slow since the thirteenth session (the quick suite's 10 min)
def test_the_diagnosis_names_the_settling_over_a_constant_rate():
    c, _ = bench(1, "settle")
    d = diagnose(c, MODEL, **OPTS)
    v = d.verdict
    assert v["effect"] == "tilt_settling", v
    assert "tilt_settling" in v["fit_options"] and "tau_s = " in v["evidence"]
    form = next(x for x in d.candidates if x.effect == "tilt_settling").refit["form"]
    assert form["beats_simpler"] and abs(form["tau_h"] - TAU_H) < 0.3 * TAU_H, form


@pytest.mark.slow          # 5-7 s: slow since the thirteenth session (CI quick 573 of 600 s)
def test_a_constant_rate_is_named_tilt_drift_not_a_settling():
    c, _ = bench(2, "rate")
    d = diagnose(c, MODEL, **OPTS)
    assert d.verdict["effect"] == "tilt_drift", d.verdict
    settle = next(x for x in d.candidates if x.effect == "tilt_settling")
    assert settle.testable and not settle.refit["form"]["beats_simpler"], settle.refit["form"]


def test_no_settling_is_searched_without_a_change_of_the_tilt():
    """A clean campaign (no change of the tilt): the linear drift is not a leading candidate, the
    settling is untestable (no profile is computed) and nothing is named."""
    rng = np.random.default_rng(4)
    c = parse_bench_csv(simulate_campaign(rng, setpoints_C=SETPOINTS, tilt_arcsec=TILT)[0])
    d = diagnose(c, MODEL, **OPTS)
    settle = next(x for x in d.candidates if x.effect == "tilt_settling")
    assert not settle.testable and "not a leading candidate" in settle.reason
    assert d.verdict["effect"] is None, d.verdict


def test_the_time_constant_gate_of_the_settling():
    base = {f"K_{a}": ParameterValue(1.0, 1e-6, "g/V") for a in "xyz"}

    def failing(v, u):
        return [o for o in result_gates({**base, "tilt_settle_tau": ParameterValue(v, u, "h")}, output_unit="V")
                if o.passed is False]

    assert failing(4.0, 0.3) == [] and failing(0.05, 0.01) == [] and failing(100.0, 10.0) == []
    bad = failing(500.0, 20.0)
    assert [o.gate for o in bad] == ["time_constants"]
    assert "tilt_settle_tau = 500 +- 20 h is outside [0.05, 100] h" in bad[0].reason
    bad = failing(40.0, 90.0)                   # a settling the campaign cannot tell from a rate
    assert [(o.gate, o.status) for o in bad] == [("time_constants_determined", "unidentifiable")]
    assert "tilt_settle_tau = 40 +- 90 h" in bad[0].reason


def test_fit_and_sample_accept_the_name_and_the_cli_fit_answers_ok(tmp_path):
    """``triadcal fit --effects ...,tilt_settling`` on the independent bench's CSV: status ok, the
    time constant in h in the JSON; ``sample --effects`` takes the name."""
    import json

    from triadcal.cli import build_parser, main

    rng = np.random.default_rng(0)
    t = default_truth(rng)

    def settle(time_s):
        s = 1.0 - np.exp(-np.asarray(time_s) / (TAU_H * 3600.0))
        return D[0] * s, D[1] * s

    csv = tmp_path / "settling.csv"
    csv.write_text(simulate_campaign(rng, truth=t, setpoints_C=SETPOINTS, tilt_arcsec=TILT, tilt_change=settle)[0])
    out = tmp_path / "fit.json"
    assert main(["fit", str(csv), "--effects", ",".join(MODEL + ("tilt_settling",)), "--json", str(out),
                 "--quiet"]) == 0
    doc = json.loads(out.read_text())
    assert doc["status"] == "ok" and "tilt_settling" in doc["effects"], doc["notes"]
    tau = doc["parameters"]["tilt_settle_tau"]
    assert tau["unit"] == "h" and abs(tau["value"] - TAU_H) < 4 * tau["u"], tau
    ns = build_parser().parse_args(["sample", str(out), "--effects", "tilt_settling"])
    assert "tilt_settling" in ns.effects
