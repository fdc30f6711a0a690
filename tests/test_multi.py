"""Several units on one bench fitted jointly (issue 21, item 1): the shared bench terms and what
sharing gains, on units made by the independent simulator on one tilted bench."""

from __future__ import annotations

import json

import numpy as np
import pytest

from independent_bench import simulate_campaign
from triadcal.cli import main
from triadcal.errors import InputError
from triadcal.estimation.joint import fit_joint
from triadcal.estimation.multi import fit_joint_units
from triadcal.io.bench_csv import read_bench_csv
from triadcal.io.lab import LabConfig
from triadcal.uncertainty.typeb import systematic_sources

EFFECTS = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")


def _fleet_file(tmp_path, n=4, seed=3, tilt=(40.0, -25.0)):
    rng = np.random.default_rng(seed)
    lines, truths = [], {}
    for k in range(n):
        text, truth = simulate_campaign(rng, unit=f"SN-{k}", tilt_arcsec=tilt)
        truths[f"SN-{k}"] = truth
        rows = text.splitlines()
        lines += rows if k == 0 else [r for r in rows if not r.startswith("#") and not r.startswith("unit,")]
    p = tmp_path / "fleet.csv"
    p.write_text("\n".join(lines) + "\n")
    return p, truths


def test_sharing_the_bench_halves_the_tilts_u_for_four_units_and_keeps_the_angles(tmp_path):
    """Four units see one tilt: its u falls by sqrt(4) = 2 against one unit's fit. On the
    12-position plan the angles do not correlate with the tilt (the half-turn pairs cancel it),
    so their u is that of the separate fits — sharing buys the bench terms, not the angles."""
    path, truths = _fleet_file(tmp_path)
    c = read_bench_csv(path)
    res = fit_joint_units(c, EFFECTS)
    assert set(res) == set(truths)
    tilts = {round(r["tilt_x"].value, 9) for r in res.values()}
    assert len(tilts) == 1                                   # one tilt in every unit's result
    for u, r in res.items():
        sep = fit_joint(c.select(c.unit == u), EFFECTS)
        assert r.status == "ok" and sep.status == "ok"
        assert r["tilt_x"].u / sep["tilt_x"].u == pytest.approx(0.5, abs=0.03)
        assert r["tilt_y"].u / sep["tilt_y"].u == pytest.approx(0.5, abs=0.03)
        for n in ("Ca_xy", "Ca_zx", "K_y", "S_z", "Ca_yz_tempco"):
            assert r[n].u == pytest.approx(sep[n].u, rel=0.02), n
            assert abs(r[n].value - truths[u][n]) < 4 * r[n].u, n
        assert abs(r["tilt_x"].value - 40.0) < 4 * r["tilt_x"].u
        assert "fitted jointly" in " ".join(r.notes) and r.fit["joint_units"]["shared"] == ["tilt_x", "tilt_y"]


def test_refusals(tmp_path, example):
    path, _ = _fleet_file(tmp_path, n=2)
    c = read_bench_csv(path)
    with pytest.raises(InputError, match="nothing to share"):
        fit_joint_units(c.select(c.unit == "SN-0"), EFFECTS)
    with pytest.raises(InputError, match="no bench terms to share"):
        fit_joint_units(c, ("angle_tempco",))



def test_cli_writes_one_result_per_unit(tmp_path):
    path, _ = _fleet_file(tmp_path, n=2, seed=5)
    out = tmp_path / "res"
    code = main(["fit", str(path), "--joint-units", "--effects", ",".join(EFFECTS), "--json-dir", str(out),
                 "--quiet"])
    assert code == 0
    docs = {p.stem: json.loads(p.read_text()) for p in out.glob("*.json")}
    assert set(docs) == {"SN-0", "SN-1"}
    assert docs["SN-0"]["parameters"]["tilt_x"]["value"] == docs["SN-1"]["parameters"]["tilt_x"]["value"]
    assert main(["fit", str(path), "--joint-units", "--json", str(tmp_path / "x.json")]) == 1


@pytest.mark.parametrize("extra", [["--hysteresis-form", "play"], ["--thermal-lag-form", "history"],
                                   ["--thermal-order", "2"], ["--loss", "huber"], ["--strict"],
                                   ["--quantisation-lsb", "0.001"], ["--effects", "bench_tilt,hysteresis_play"],
                                   ["--effects", "bench_tilt,position_error"]])
def test_cli_joint_units_refuses_what_it_would_ignore(tmp_path, capsys, extra):
    """--joint-units fits the joint model's effects by least squares; the options and names of the
    single-unit fit it does not do (forms, orders, losses, noise effects) were silently ignored, or
    met an 'unknown effect'. They are refused, named, before the file is read."""
    path, _ = _fleet_file(tmp_path, n=2, seed=5)
    code = main(["fit", str(path), "--joint-units", "--json-dir", str(tmp_path / "res"), *extra])
    err = capsys.readouterr().err
    assert code == 1 and "--joint-units fits the effects of the joint model" in err, err
    named = extra[1].split(",")[-1] if extra[0] == "--effects" else extra[0]
    assert named in err and not (tmp_path / "res").exists()


def test_the_labs_systematic_errors_through_the_stacked_fit(tmp_path):
    """Type B through the stacked fit: an encoder zero of axis 1 is one error for every unit (it
    turns each unit's Ca_xz/Ca_zx by -1/+1 alike), a fixture rotation one per unit (its own pair
    only): so the encoder zero's rows are one shared source and the fixture's carry the unit's
    name; g goes into every K one to one. u of each angle is then close to the root sum of the
    fixture's and the encoder's u, as for a unit fitted alone."""
    path, truths = _fleet_file(tmp_path, n=3, seed=9)
    c = read_bench_csv(path)
    lab = LabConfig(encoder_zero_u_arcsec=5.0, mounting_u_arcsec=10.0, local_g_u_ppm=10.0, source="t")
    res = fit_joint_units(c, EFFECTS, systematics=systematic_sources(lab))
    for u, r in res.items():
        rows = {x["source"]: x for x in r["Ca_xz"].uncertainty["budget"]}
        assert rows["encoder zero, axis 1"]["sensitivity"] == pytest.approx(-1.0, abs=1e-3)
        assert rows[f"fixture mounting, about y ({u})"]["sensitivity"] == pytest.approx(-1.0, abs=1e-3)
        assert not any(k.startswith("fixture mounting") and f"({u})" not in k for k in rows)
        assert r["Ca_xz"].u == pytest.approx(np.sqrt(10.0 ** 2 + 5.0 ** 2 + r["Ca_xz"].uncertainty["u_type_a"] ** 2),
                                             rel=1e-3)
        k_rows = {x["source"]: x for x in r["K_x"].uncertainty["budget"]}
        assert k_rows["local gravity"]["sensitivity"] == pytest.approx(-r["K_x"].value * 1e-6, rel=1e-3)
        single = fit_joint(c.select(c.unit == u), EFFECTS, systematics=systematic_sources(lab))
        assert r["Ca_xz"].u == pytest.approx(single["Ca_xz"].u, rel=0.01)
