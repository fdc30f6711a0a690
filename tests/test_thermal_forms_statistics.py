"""The proof of the hysteresis forms (offset, play, Prandtl-Ishlinskii) and the thermal orders
(1, 2, 3) over many campaigns made another way (issue 17, item 3; slow).

Data: tests/independent_bench.py, which shares no code with ``triadcal.models`` — its hysteresis
is a backlash state machine, its tempcos a polynomial by Horner's rule — written as bench CSV
text and read by the reader of ``triadcal fit``. Units at the presets' magnitudes
(``triadcal.models.simulate.PRESETS``): the quartz AK-18 near linear over the standard −40…+70 °C
schedule; the silicon A-18 over −40…+85 °C with quadratic (and cubic) tempcos of realistic size.
Four scenarios of 50 seeds each (``PROOF``): every form (offset, play, pi) and every order (1, 2,
3) is the truth in at least 50 campaigns. About 2 min on one quiet core (``threadpool_limits(1)``).

Per scenario:
- with the right model (true effects, true form with its widths profiled), the fraction of seeds
  with |z| < 2 per parameter: under a correct u it is Binomial(50, 0.954) — mean 47.7, and below
  43 with probability < 0.3 % — so each parameter's count must be >= 43 of 50 (a play's or PI's
  h is conditional on the profiled widths, which can cost a little coverage; stated below);
- chi^2/dof: the mean over seeds within [0.9, 1.1], each seed within the central 99.9 % of
  chi^2 with its dof divided by the dof;
- the angles at the reference temperature: |z| < 3 in every seed;
- the model choice of ``fit --thermal-order auto --hysteresis-form auto``: the true thermal order
  of every family and the true hysteresis form in >= 90 % of seeds.
"""

from __future__ import annotations

import functools
import math
import time

import numpy as np
import pytest
from scipy import stats

from independent_bench import simulate_campaign
from triadcal import api
from triadcal.io.bench_csv import read_bench_csv
from triadcal.models.simulate import PRESETS, STANDARD_SETPOINTS_C

SEEDS = 50
BASE = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco", "hysteresis")
ANGLES = ("xy", "xz", "yx", "yz", "zx", "zy")
SILICON_SETPOINTS_C = (20.0, 40.0, 60.0, 85.0, 60.0, 40.0, 20.0, 0.0, -20.0, -40.0, -20.0, 0.0, 20.0)
#: bench noise: 5e-4 V per sample, 3000 samples per visit -> 9.1e-6 V per visit (about 1.9" or 9 ug)
NOISE = dict(noise_sd=5e-4, n_samples=3000)


def _truth(preset: str, order: int) -> dict:
    P = PRESETS[preset]
    names = [f"K_{a}" for a in "xyz"] + [f"S_{a}" for a in "xyz"] + [f"Ca_{ab}" for ab in ANGLES]
    for suffix in ("tempco", "tempco2", "tempco3")[:order]:
        names += [f"Ca_{ab}_{suffix}" for ab in ANGLES] + [f"K_{a}_{suffix}" for a in "xyz"] \
            + [f"S_{a}_{suffix}" for a in "xyz"]
    names += [f"Ca_{ab}_hysteresis" for ab in ANGLES]
    t = {n: float(P[n]) for n in names}
    for a in "xyz":                                  # S in g in the presets, ug/degC^k for the tempcos
        t[f"S_{a}"] = float(P[f"S_{a}"])
    return t


#: name -> (preset, thermal order, hysteresis spec, setpoints)
SCENARIOS = {
    "quartz-linear-offset": ("ak18-quartz", 1, {"form": "offset"}, STANDARD_SETPOINTS_C),
    "quartz-linear-play": ("ak18-quartz", 1, {"form": "play", "half_widths_C": [15.0], "start": "mid"},
                           STANDARD_SETPOINTS_C),
    "silicon-quadratic-play": ("a18-silicon", 2, {"form": "play", "half_widths_C": [20.0], "start": "mid"},
                               SILICON_SETPOINTS_C),
    "silicon-cubic-pi": ("a18-silicon", 3, {"form": "pi", "half_widths_C": [3.0, 30.0], "weights": [0.5, 0.5],
                                            "start": "mid"}, SILICON_SETPOINTS_C),
}
HIGHER = {2: ("angle_tempco2", "scale_tempco2", "bias_tempco2"),
          3: ("angle_tempco2", "scale_tempco2", "bias_tempco2", "angle_tempco3", "scale_tempco3", "bias_tempco3")}
TILT = (60.0 * math.cos(math.radians(30)), 60.0 * math.sin(math.radians(30)))


def campaign(name: str, seed: int, tmp_dir):
    preset, order, hyst, setpoints = SCENARIOS[name]
    text, truth = simulate_campaign(np.random.default_rng(seed), truth=_truth(preset, order), setpoints_C=setpoints,
                                    tilt_arcsec=TILT, hysteresis=hyst, unit=f"SN-{name}-{seed}", **NOISE)
    path = tmp_dir / f"{name}-{seed}.csv"
    path.write_text(text, encoding="utf-8")
    return read_bench_csv(path), truth


@functools.lru_cache(maxsize=None)
def run(name: str, tmp_dir_str: str):
    """Every seed of a scenario: z of each parameter of the right model, chi^2/dof and dof, and the
    choices of ``thermal_order=auto, hysteresis_form=auto``."""
    from pathlib import Path

    from threadpoolctl import threadpool_limits

    preset, order, hyst, _ = SCENARIOS[name]
    effects = BASE + HIGHER.get(order, ())
    want = {"angle_tempco": order, "scale_tempco": order, "bias_tempco": order}
    out = {"z": {}, "chi2_dof": [], "dof": [], "form": [], "orders": [], "seconds": 0.0}
    t0 = time.perf_counter()
    with threadpool_limits(1):            # small matrices: threads only contend (7x slower on a busy machine)
        for seed in range(SEEDS):
            c, truth = campaign(name, seed, Path(tmp_dir_str))
            chosen = api.fit(c, thermal_order="auto", hysteresis_form="auto")
            out["form"].append(chosen.fit["hysteresis"]["form"])
            out["orders"].append(chosen.fit["thermal_order"].get("orders"))
            # the right model: the chosen one when the choice is right (the same fit), else fitted so
            right = (chosen if out["form"][-1] == hyst["form"] and out["orders"][-1] == want
                     else api.fit(c, effects=effects, hysteresis_form=hyst["form"]))
            for k, p in right.parameters.items():
                if k in truth:
                    out["z"].setdefault(k, []).append((p.value - truth[k]) / p.u)
            out["chi2_dof"].append(right.fit["chi2_dof"])
            out["dof"].append(right.fit["n_obs"] - right.fit["n_params"])
    out["seconds"] = time.perf_counter() - t0
    return out


def summary(name: str, res) -> str:
    z = {k: np.abs(np.array(v)) for k, v in res["z"].items()}
    cov = {k: int(np.sum(v < 2)) for k, v in z.items()}
    c = np.array(res["chi2_dof"])
    preset, order, hyst, _ = SCENARIOS[name]
    ok_order = sum(o == {"angle_tempco": order, "scale_tempco": order, "bias_tempco": order} for o in res["orders"])
    return (f"{name}: |z|<2 per parameter min {min(cov.values())}/{SEEDS} (mean {np.mean(list(cov.values())):.1f}), "
            f"chi2/dof {c.mean():.3f} +- {c.std(ddof=1):.3f}, form {hyst['form']} chosen "
            f"{res['form'].count(hyst['form'])}/{SEEDS} (others {sorted(set(res['form']) - {hyst['form']})}), "
            f"thermal order {order} chosen {ok_order}/{SEEDS}, {res['seconds']:.0f} s")


#: the scenarios of the test: every form and every order the truth in at least 50 campaigns, both presets
PROOF = ("quartz-linear-offset", "quartz-linear-play", "silicon-quadratic-play", "silicon-cubic-pi")


@pytest.mark.slow
@pytest.mark.parametrize("name", PROOF)
def test_forms_and_orders_over_50_campaigns_made_another_way(name, tmp_path_factory):
    res = run(name, str(tmp_path_factory.mktemp(name)))
    print("\n" + summary(name, res))
    preset, order, hyst, _ = SCENARIOS[name]
    # coverage: Binomial(50, 0.954) falls below 43 with probability 0.3 %
    low = {k: int(np.sum(np.abs(v) < 2)) for k, v in res["z"].items() if np.sum(np.abs(np.array(v)) < 2) < 43}
    assert not low, low
    # chi^2/dof
    c, dof = np.array(res["chi2_dof"]), np.array(res["dof"])
    assert 0.9 <= c.mean() <= 1.1, c.mean()
    lo, hi = stats.chi2.ppf(0.0005, dof) / dof, stats.chi2.ppf(0.9995, dof) / dof
    assert np.all((c >= lo) & (c <= hi)), [(s, round(x, 3)) for s, x in enumerate(c) if not lo[s] <= x <= hi[s]]
    # the angles at T0
    for ab in ANGLES:
        assert np.max(np.abs(res["z"][f"Ca_{ab}"])) < 3, (ab, np.round(res["z"][f"Ca_{ab}"], 2))
    # the model choice
    assert res["form"].count(hyst["form"]) >= 0.9 * SEEDS, res["form"]
    want = {"angle_tempco": order, "scale_tempco": order, "bias_tempco": order}
    assert sum(o == want for o in res["orders"]) >= 0.9 * SEEDS, res["orders"]
