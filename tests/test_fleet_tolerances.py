"""Fleet tolerances with units (an outside probe, tenth session: a K limit of 0.99-1.01 was applied
to a K in g/counts as if it were g/V). A limit with a unit flags a value in another unit; a limit
without one is refused when the fleet holds the parameter in several units."""

import pytest

from triadcal.errors import InputError
from triadcal.fleet.summary import check_tolerance_units, load_tolerances, out_of_tolerance, write_summary


def tol_file(tmp_path, text):
    p = tmp_path / "tol.toml"
    p.write_text("[tolerances]\n" + text, encoding="utf-8")
    return load_tolerances(p)


def record(unit, K, K_unit):
    return {"unit": unit, "state": "initial", "input": "x.csv", "action": "fitted",
            "result": {"status": "ok", "fit": {}, "parameters": {"K_x": {"value": K, "u": 1e-6, "unit": K_unit}}}}


def test_a_limit_with_a_unit_flags_a_value_in_another(tmp_path):
    tol = tol_file(tmp_path, 'K_x = {range = [0.99, 1.01], unit = "g/V"}\n"Ca_*" = {limit = 120, unit = "arcsec"}\n')
    assert tol == [("K_x", 0.99, 1.01, "g/V"), ("Ca_*", -120.0, 120.0, "arcsec")]
    assert out_of_tolerance({"K_x": {"value": 1.0, "unit": "g/V"}}, tol) == []
    assert out_of_tolerance({"K_x": {"value": 1.0, "unit": "g/counts"}}, tol) == ["K_x (in g/counts, tolerance in g/V)"]
    assert out_of_tolerance({"K_x": {"value": 1.02, "unit": "g/V"}}, tol) == ["K_x"]


def test_a_limit_without_a_unit_on_a_fleet_of_two_units_is_refused(tmp_path):
    tol = tol_file(tmp_path, "K_x = [0.99, 1.01]\n")
    fleet = [record("A", 1.0, "g/V"), record("B", 6.1e-5, "g/counts")]
    with pytest.raises(InputError, match=r"K_x in g/V, g/count\b"):
        check_tolerance_units(fleet, tol)
    with pytest.raises(InputError, match="several units"):
        write_summary(fleet, tmp_path, tol, html_page=False)
    check_tolerance_units(fleet[:1], tol)                 # one unit: the limit is in it


@pytest.mark.parametrize("text", ['K_x = {range = [1, 2]}\n', 'K_x = {limit = 1, unit = ""}\n',
                                  'K_x = {limit = -1, unit = "g/V"}\n', 'K_x = {limit = 1, unit = "g/V", x = 2}\n'])
def test_a_bad_table_is_refused(tmp_path, text):
    with pytest.raises(InputError, match="K_x"):
        tol_file(tmp_path, text)


def test_one_unit_in_two_spellings_is_one_unit(tmp_path):
    """K in counts is written g/count since 2026-11-30 (models/units.scale_factor_unit), g/counts
    before: a tolerance in either spelling applies to both, and a fleet of both is one unit."""
    tol = tol_file(tmp_path, 'K_x = {range = [5e-5, 7e-5], unit = "g/counts"}\n')
    assert out_of_tolerance({"K_x": {"value": 6.1e-5, "unit": "g/count"}}, tol) == []
    assert out_of_tolerance({"K_x": {"value": 6.1e-5, "unit": "g/counts"}}, tol) == []
    bare = tol_file(tmp_path, "K_x = 1.0\n")
    check_tolerance_units([record("A", 6.1e-5, "g/count"), record("B", 6.0e-5, "g/counts")], bare)   # no refusal


def test_a_tolerance_that_matches_no_parameter_is_refused_and_a_pattern_is_warned(tmp_path):
    """An outside probe: ``Ca_xyy = 10`` (a typo) checked nothing and two units with Ca_xy = 150
    arcsec came out ok. A name without wildcards that matches no fitted parameter is refused; a
    pattern that matches none (a shared file's ``"*_hysteresis"``) is a warning."""
    fleet = [record("A", 1.0, "g/V"), record("B", 1.001, "g/V")]
    typo = tol_file(tmp_path, "K_xx = [0.99, 1.01]\n")
    with pytest.raises(InputError, match=r"tolerance 'K_xx' matches no parameter .*\(K_x\)"):
        write_summary(fleet, tmp_path, typo, html_page=False)
    pattern = tol_file(tmp_path, 'K_x = [0.99, 1.01]\n"*_hysteresis" = 60\n')
    _, flags = write_summary(fleet, tmp_path, pattern, html_page=False)
    assert flags["tolerances_unmatched"] == [
        "tolerance pattern '*_hysteresis' matches no parameter of the fleet's results: nothing was checked against it"]
    _, flags = write_summary(fleet, tmp_path, tol_file(tmp_path, "K_x = [0.99, 1.01]\n"), html_page=False)
    assert flags["tolerances_unmatched"] == []
