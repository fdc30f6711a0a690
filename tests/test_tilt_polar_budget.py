"""The bench tilt's polar form (tilt_delta, tilt_beta) with the lab's systematic errors: a budget,
U and k as every parameter of the result (before, its u held the Type B part but it had no budget,
no U and no k). Data from tests/independent_bench.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from independent_bench import simulate_campaign
from test_classical_typeb import LAB
from triadcal import api
from triadcal.estimation.result import CalibrationResult


@pytest.fixture(scope="module")
def tilted(tmp_path_factory):
    d = tmp_path_factory.mktemp("tilt")
    (d / "c.csv").write_text(simulate_campaign(np.random.default_rng(21), tilt_arcsec=(30.0, 4.0),
                                               sigma_position_arcsec=5.0, sigma_wobble_arcsec=2.0)[0])
    return api.fit(d / "c.csv", method="joint", lab=LAB, json_path=d / "r.json"), d / "r.json"


def test_the_polar_tilt_has_a_budget_whose_rows_are_the_components_rows_by_the_gradient(tilted):
    """Hand-derived: delta = sqrt(tx^2 + ty^2) (small angles), so each source's row of tilt_delta is
    (tx c_x + ty c_y) / delta of the components' rows, its Type A row sqrt(g' C_A g), and the
    rows add up (in quadrature) to the u the result states; U = k u."""
    r, _ = tilted
    assert r.status == "ok", r.notes
    d, b = r["tilt_delta"], r["tilt_beta"]
    tx, ty = r["tilt_x"].value, r["tilt_y"].value
    g = np.array([tx, ty]) / math.hypot(tx, ty)
    rows = {row["source"]: row for row in d.uncertainty["budget"]}
    comp = {n: {row["source"]: row for row in r[n].uncertainty["budget"]} for n in ("tilt_x", "tilt_y")}
    for src, row in rows.items():
        if row["type"] != "B":
            continue
        c = g[0] * comp["tilt_x"][src]["sensitivity"] + g[1] * comp["tilt_y"][src]["sensitivity"]
        assert row["sensitivity"] == pytest.approx(c, rel=1e-6, abs=1e-12), src
    total = math.sqrt(sum(row["contribution"] ** 2 for row in d.uncertainty["budget"]))
    assert total == pytest.approx(d.u, rel=1e-6)
    assert d.U == pytest.approx(d.uncertainty["k"] * d.u, rel=1e-9) and d.uncertainty["k"] >= 1.9
    assert b.U == pytest.approx(b.uncertainty["k"] * b.u, rel=1e-9) and b.unit == "deg"
    assert math.sqrt(sum(row["contribution"] ** 2 for row in b.uncertainty["budget"])) == pytest.approx(b.u, rel=1e-6)


def test_the_result_file_with_the_polar_budgets_is_read_back(tilted):
    r, path = tilted
    back = CalibrationResult.load(path)
    assert back["tilt_delta"].U == pytest.approx(r["tilt_delta"].U) and back["tilt_beta"].uncertainty["budget"]
