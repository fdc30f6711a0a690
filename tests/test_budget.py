"""The paper's error budgets: eq. 4 and eq. 5-7 reproduce its numbers; `triadcal budget`."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from triadcal.uncertainty.paper import (TABLE_1, budget, calibration_budget, correction_error_arcsec,
                                        mounting_drift_arcsec, noise_term_arcsec, sigma_eff_arcsec,
                                        thermal_budget, thermal_drift_arcsec)

# Eq. 5 computed exactly (dCa_Tn = 10.5917", dCa_Tk = 0.3" quartz / 1.2" silicon)
EQ5_EXACT = {"AK-15": 11.326, "AK-18": 18.365, "QA-3000": 19.609, "AAK-02": 22.633,
             "A-18T": 18.402, "BA-3": 22.663, "A-18": 60.940}


def test_eq4_reproduces_paper_example():
    """K = G, Q = 3e-9 V^2 s, tau = 30 s, sigma_1 = 5", sigma_2 = 2" -> 11.52" (+-0.02")."""
    assert sigma_eff_arcsec(1.0, 3e-9, 30.0, 5.0, 2.0) == pytest.approx(11.52, abs=0.02)
    assert sigma_eff_arcsec(1.0, 3e-9, 30.0, 5.0, 2.0) == pytest.approx(11.5333, abs=1e-4)  # exact
    assert noise_term_arcsec(1.0, 3e-9, 30.0) == pytest.approx(2.06, abs=0.005)
    # K and G enter as K/G only
    assert sigma_eff_arcsec(2.0, 3e-9, 30.0, 5.0, 2.0, G_g=2.0) == pytest.approx(sigma_eff_arcsec(1.0, 3e-9, 30.0, 5.0, 2.0))


def test_eq6_mounting_drift():
    """Steel (15e-6) on D-16 (22.9e-6), 85/20 degC -> 5.1e-5 rad = 10.6" (the paper rounds to 11")."""
    assert mounting_drift_arcsec(22.9e-6, 15e-6, 85.0, 20.0) == pytest.approx(10.6, abs=0.05)
    assert mounting_drift_arcsec(15e-6, 22.9e-6, 85.0, 20.0) == pytest.approx(10.6, abs=0.05)  # sign-free


def test_eq7_correction_error():
    assert correction_error_arcsec(0.2, 1.5) == pytest.approx(0.3)
    assert correction_error_arcsec(0.2, 6.0) == pytest.approx(1.2)


@pytest.mark.parametrize("name", ["AK-15", "AK-18", "QA-3000"])
def test_eq5_quartz_units(name):
    """Paper: about 12-19" for quartz. Exactly: AK-15 11.33", AK-18 18.37", QA-3000 19.61"
    (with dCa_Tn rounded to 11" as the paper does: 11.71", 18.60", 19.83")."""
    b = thermal_budget(name)
    assert b.total == pytest.approx(EQ5_EXACT[name], abs=0.005)
    assert 11.0 <= b.total <= 20.0
    assert b.extra["inputs"]["k_ca_arcsec_per_C"] == 1.5


@pytest.mark.parametrize("name", ["A-18T", "BA-3", "A-18"])
def test_eq5_silicon_units(name):
    """Paper: about 19-61" for silicon. Exactly: A-18T 18.40", BA-3 22.66", A-18 60.94"."""
    b = thermal_budget(name)
    assert b.total == pytest.approx(EQ5_EXACT[name], abs=0.005)
    assert 18.0 <= b.total <= 61.0
    assert b.extra["inputs"]["k_ca_arcsec_per_C"] == 6.0


def test_eq5_aak02_is_above_the_papers_quartz_range():
    """AAK-02 (quartz, +-20") gives 22.6", above the paper's quoted 12-19" (docs/budget.md)."""
    assert thermal_budget("AAK-02").total == pytest.approx(22.63, abs=0.01)
    assert thermal_drift_arcsec(20.0, 10.5917, 0.3) > 19.0


def test_table1_is_complete_and_budgets_are_sorted():
    assert [a.name for a in TABLE_1] == ["A-18", "AK-15", "BA-3", "A-18T", "AK-18", "AAK-02", "QA-3000"]
    assert {a.name: a.material for a in TABLE_1}["QA-3000"] == "quartz"
    for b in budget(thermal=True) + [calibration_budget()]:
        c = [x.contribution for x in b.components]
        assert c == sorted(c, reverse=True)
        assert b.total == pytest.approx(sum(x * x for x in c) ** 0.5)
    assert len(budget(thermal=True)) == 7
    assert budget(thermal=True, accelerometer_name="ak-18")[0].extra["accelerometer"]["name"] == "AK-18"
    with pytest.raises(ValueError, match="Table 1 lists"):
        budget(thermal=True, accelerometer_name="XYZ-1")


def test_calibration_budget_relates_eq4_to_classical_sd():
    """Eq. 4 (11.53") is about 4x the SD of the classical estimate (2.70" for five angles,
    1.44" for Ca_xy): the factor 2 and the missing 1/2 of averaging four positions."""
    b = calibration_budget()
    sd = b.extra["classical_sd_arcsec"]
    assert sd["Ca_xy"] == pytest.approx(1.4365, abs=1e-3)
    assert sd["Ca_zy"] == pytest.approx(2.7044, abs=1e-3)
    assert b.total / sd["Ca_zy"] == pytest.approx(4.265, abs=0.01)
    # with only one bench term, eq. 4 is exactly four times the classical SD
    b1 = calibration_budget(sigma2_arcsec=0.0)
    assert b1.total == pytest.approx(4 * b1.extra["classical_sd_arcsec"]["Ca_zy"], rel=1e-12)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "triadcal.cli", "budget", *args], capture_output=True, text=True)


def test_cli_budget_eq4_and_json(tmp_path):
    out = tmp_path / "b.json"
    run = _cli("--K", "1", "--Q", "3e-9", "--tau", "30", "--sigma1", "5", "--sigma2", "2", "--json", str(out))
    assert run.returncode == 0, run.stderr
    assert "11.53 arcsec" in run.stdout and "Ca_xy 1.44" in run.stdout
    doc = json.loads(out.read_text())
    assert doc["format"] == "triadcal.budget" and doc["version"] == 1
    t = doc["tables"][0]
    assert t["total"] == pytest.approx(11.533, abs=1e-3)
    assert [c["symbol"] for c in t["components"]] == ["sigma_1", "noise", "sigma_2"]
    # eq. 4 is the paper's 2 sigma_eff, no expanded uncertainty at a coverage (an outside probe: the JSON
    # said U = 2 x total at 95.45 %, four standard deviations of the classical estimate each)
    assert t["U"] is None and t["k"] is None and t["coverage_probability"] is None
    assert t["U_method"].startswith("none: eq. 4 is the paper's own figure")


def test_cli_budget_thermal(tmp_path):
    run = _cli("--thermal", "--accelerometer", "AK-18")
    assert run.returncode == 0, run.stderr
    assert "18.37 arcsec" in run.stdout and "dCa_Ta" in run.stdout
    out = tmp_path / "t.json"
    run = _cli("--thermal", "--json", str(out))
    assert run.returncode == 0, run.stderr
    assert "A-18" in run.stdout and "60.94" in run.stdout
    totals = {t["accelerometer"]["name"]: t["total"] for t in json.loads(out.read_text())["tables"]}
    assert totals == pytest.approx(EQ5_EXACT, abs=0.005)


def test_cli_budget_refuses_unknown_unit():
    run = _cli("--thermal", "--accelerometer", "XYZ-1")
    assert run.returncode == 1
    assert "unknown accelerometer 'XYZ-1'" in run.stderr


@pytest.mark.parametrize("args, says", [
    (("--tau", "0"), "--tau (tau_s) = 0: must be > 0"),
    (("--G", "0"), "--G (G_g) = 0: must be > 0"),
    (("--G", "9.80665"), "local gravity is in g, 0.9-1.1 g on a bench (9.80665 m/s2 is 1 g)"),
    (("--sigma1", "1e200"), "overflows with these inputs (--sigma1 1e+200)"),
    (("--Q", "-1"), "--Q (Q_V2s) = -1: must be >= 0"),
    (("--K", "-1"), "--K (K_g_per_V) = -1: must be > 0"),
    (("--sigma1", "-5"), "--sigma1 (sigma1_arcsec) = -5: must be >= 0"),
    (("--sigma2", "nan"), "--sigma2 (sigma2_arcsec) = nan: not finite"),
    (("--thermal", "--dT", "-0.2"), "--dT (dT_C) = -0.2: must be >= 0"),
    (("--thermal", "--k-ca", "-1"), "--k-ca (k_ca_arcsec_per_C) = -1: must be >= 0"),
    # a negative number in e-notation reaches the check (argparse took -1.5e0 for an option: "expected one argument")
    (("--thermal", "--k-ca", "-1.5e0"), "--k-ca (k_ca_arcsec_per_C) = -1.5: must be >= 0"),
    (("--thermal", "--T0", "-3E+2"), "--T0 (T0_C) = -300: must be >= -273.15"),
    (("--thermal", "--T-max", "10"), "--T-max (10 degC) is below --T0 (20 degC)"),
    (("--thermal", "--cte-body", "inf"), "--cte-body (cte_body_per_C) = inf: not finite"),
    # an outside probe: each printed a table, exit 0 (or "internal error", exit 70)
    (("--dT", "5"), "--dT is eq. 5-7's: add --thermal"),
    (("--k-ca", "100", "--T-max", "300"), "--k-ca, --T-max are eq. 5-7's: add --thermal"),
    (("--thermal", "--accelerometer", "AK-15", "--K", "5", "--sigma1", "0"),
     "--K, --sigma1 are eq. 4's (the bench test): not used by --thermal"),
    (("--thermal", "--T0", "-300"), "--T0 (T0_C) = -300: must be >= -273.15"),
    # an outside probe: the other budget's options at their default values were accepted in silence
    (("--thermal", "--K", "1"), "--K is eq. 4's (the bench test): not used by --thermal"),
    (("--T0", "20", "--dT", "0.2"), "--dT, --T0 are eq. 5-7's: add --thermal"),
    (("--thermal", "--cte-body", "22.9", "--cte-accelerometer", "15"), "beyond any solid's expansion"),
    (("--K", "1e300", "--Q", "1e300"), "the budget overflows"),
])
def test_cli_budget_refuses_inputs_that_are_no_budget(args, says):
    """A zero averaging time or gravity, a negative noise intensity or standard deviation: each
    used to be an internal error (exit 70) or a budget with a negative part; now exit 1 naming
    the option and the value."""
    run = _cli(*args)
    assert run.returncode == 1, (run.returncode, run.stderr)
    assert says in run.stderr and "internal error" not in run.stderr


def test_budget_function_refuses_the_same_inputs():
    from triadcal.errors import InputError
    with pytest.raises(InputError, match="tau_s"):
        budget(tau_s=0.0)
    assert budget(Q_V2s=0.0, sigma1_arcsec=0.0, sigma2_arcsec=0.0)[0].total == 0.0
