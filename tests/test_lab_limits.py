"""Lab files an outside probe (eleventh session) got through: a u for an unmeasured g, absurd
uncertainties propagated linearly, two keys for one quantity decided by their order; the classical
fit ignoring the lab's g; a voltmeter on counts ignored by the certificate."""

import numpy as np
import pytest

from triadcal import api
from triadcal.errors import InputError
from triadcal.io.lab import EXAMPLE_LAB_TOML, load_lab
from triadcal.models.simulate import preset_truth, simulate_campaign


def lab(tmp_path, text):
    p = tmp_path / "lab.toml"
    p.write_text(text, encoding="utf-8")
    return load_lab(p)


@pytest.mark.parametrize("text, match", [
    ("[gravity]\nu_ppm = 10\n", "u_ppm = 10 without local_g_m_s2"),
    ("[fixture]\nmounting_u_arcsec = 1e6\n", r"\[fixture\] mounting_u_arcsec = 1e\+06 is above 3600"),
    ("[gravity]\nlocal_g_m_s2 = 9.81\nu_ppm = 1e6\n", r"\[gravity\] u_ppm = 1e\+06 is above 3000"),
    ("[gravity]\nlocal_g_m_s2 = 9.81\n", r"local_g_m_s2 = 9.81 without u_ppm"),
    ("[voltmeter]\noffset_u_V = 2.0\n", r"\[voltmeter\] offset_u_V = 2 is above 0.01"),
    ("[bench]\nsigma_position_arcsec = 5\npositioning_sd_arcsec = 50\n", "state the same quantity"),
    ("[chamber]\ntemperature_uncertainty_C = 0.2\n[thermometers]\nu_C = 0.5\n", "state the same quantity"),
])
def test_a_lab_file_the_budget_cannot_use_is_refused(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        lab(tmp_path, text)


def test_the_example_lab_file_still_reads(tmp_path):
    assert lab(tmp_path, EXAMPLE_LAB_TOML).mounting_u_arcsec == 3.0


def test_the_classical_fit_takes_the_labs_gravity(tmp_path):
    """Data that state no g, a lab at 9.8112: before, the classical fit used 9.80665 (K 464 ppm off,
    status ok); now the lab's, as the joint fit does."""
    c = simulate_campaign(preset_truth(), seed=3)
    c.metadata.pop("local_g_m_s2", None)
    l_ = lab(tmp_path, "[gravity]\nlocal_g_m_s2 = 9.8112\nu_ppm = 10\n")
    r = api.fit(c, method="classical", lab=l_)
    assert r.extra["local_g_m_s2"] == pytest.approx(9.8112)
    r0 = api.fit(c, method="classical")
    assert r0.extra["local_g_m_s2"] == pytest.approx(9.80665)
    k, k0 = r.parameters["K_x"].value, r0.parameters["K_x"].value
    assert k / k0 - 1 == pytest.approx(9.8112 / 9.80665 - 1, rel=1e-6)


def test_a_voltmeter_on_counts_is_refused_by_the_certificate_too(tmp_path):
    from triadcal.reports.certificate.content import build_certificate

    c = simulate_campaign(preset_truth(), seed=3)
    r = api.fit(c)
    r.extra["output_unit"] = "counts"
    l_ = lab(tmp_path, "[voltmeter]\ngain_u_ppm = 15\n")
    cert = build_certificate(r, lab=l_, issue_date="2026-11-29", plots=False)
    assert not cert.issued and any("voltmeter" in x and "counts" in x for x in cert.reasons), cert.reasons
    assert np.isfinite(r.parameters["K_x"].value)
