"""A fit with the lab file on wrongly wired data: the lab's errors cannot be propagated at a degenerate
answer. An outside probe (its own simulator with the lab's errors): swapped w_x/w_y or an inverted
output, fitted with --lab, stopped with "the sensitivities of the parameters to the lab's systematic
errors are not finite" alone (exit 1, no result, no hint) in 5 of 6 files, where the same fit without
--lab names the wiring. Now the gate lab_sensitivities refuses the answer (model_mismatch) naming the
parameters, and the wiring hint is said. Data by the independent bench (numpy)."""
from __future__ import annotations

import numpy as np
import pytest

from triadcal import api
from triadcal.io.bench_csv import read_bench_csv
from triadcal.reports.certificate import EXAMPLE_LAB_TOML

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")


def _campaign(tmp_path, seed, how):
    from independent_bench import simulate_campaign

    text, _ = simulate_campaign(np.random.default_rng(seed), setpoints_C=(-20, 20, 60), tilt_arcsec=(30.0, -20.0),
                                sigma_position_arcsec=3.0, sigma_wobble_arcsec=1.0)
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("unit,"))
    cols = lines[i].split(",")
    jx, jy, jz = cols.index("w_x"), cols.index("w_y"), cols.index("w_z")
    out = lines[: i + 1]
    for ln in lines[i + 1:]:
        f = ln.split(",")
        if how == "swap":
            f[jx], f[jy] = f[jy], f[jx]
        elif how == "invert":
            f[jz] = repr(-float(f[jz]))
        out.append(",".join(f))
    p = tmp_path / f"{how}_{seed}.csv"
    p.write_text("\n".join(out) + "\n", encoding="utf-8")
    return p


@pytest.mark.parametrize("how, hint", [("swap", "output w_x follows gravity along y"),
                                       ("invert", "output w_z falls when its axis points up")])
def test_wrongly_wired_data_with_the_lab_file_are_refused_with_the_hint(tmp_path, how, hint):
    lab = tmp_path / "lab.toml"
    lab.write_text(EXAMPLE_LAB_TOML, encoding="utf-8")
    res = api.fit(read_bench_csv(_campaign(tmp_path, 3, how)), effects=EFFECTS, lab=lab)
    assert res.status != "ok", res.status
    assert any(hint in n for n in res.notes), res.notes
    outcomes = {o["gate"]: o for o in res.extra["gates"]["outcomes"]}
    if "lab_sensitivities" in outcomes:
        assert outcomes["lab_sensitivities"]["passed"] is False
        assert "cannot be propagated" in outcomes["lab_sensitivities"]["reason"]
    ok = api.fit(read_bench_csv(_campaign(tmp_path, 3, "none")), effects=EFFECTS, lab=lab)
    assert ok.status == "ok" and "lab_sensitivities" not in {o["gate"] for o in ok.extra["gates"]["outcomes"]}
