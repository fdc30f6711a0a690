"""The lab file given to ``certificate`` must be the one the result was fitted with
(``reports.certificate.content._lab_disagrees``, docs/certificate.md "Refusal"): a systematic error
it declares that no budget of the result holds, or holds with another u, or a local g that differs
from the fit's beyond the lab's own u, refuses the certificate. Before, a result fitted without
[gravity] and [voltmeter] was certified under a lab declaring both, U(K_x) 15 times too small, and
one fitted with g = 9.80665 m/s2 under a lab stating 9.81 (an outside probe)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("XDG_CACHE_HOME", "/tmp/xdg")

from triadcal import api  # noqa: E402
from triadcal.models.effects import DEFAULT_EFFECTS  # noqa: E402
from triadcal.reports import certificate as C  # noqa: E402

pytest.importorskip("reportlab")


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("certlab")
    _, campaign = api.simulate(d / "campaign.csv", seed=12, unit="SN-LAB-0001")
    (d / "lab.toml").write_text(C.EXAMPLE_LAB_TOML)
    result = api.fit(campaign, effects=DEFAULT_EFFECTS, lab=d / "lab.toml")
    result.save(d / "result.json")
    return d


def _lab(d, name, text):
    (d / name).write_text(text)
    return d / name


def test_the_same_lab_issues(fitted):
    cert = C.certificate(fitted / "result.json", lab=fitted / "lab.toml", issue_date="2026-11-29")
    assert cert.issued, cert.reasons


def test_a_source_the_result_never_saw_refuses(fitted):
    text = C.EXAMPLE_LAB_TOML.replace("# [voltmeter]", "[voltmeter]").replace("# gain_u_ppm = 15", "gain_u_ppm = 15")
    cert = C.certificate(fitted / "result.json", lab=_lab(fitted, "volt.toml", text), issue_date="2026-11-29")
    assert not cert.issued
    why = " ".join(cert.reasons)
    assert "budgets do not hold" in why and "voltmeter gain, axis x" in why, why


def test_another_u_for_a_source_refuses(fitted):
    text = C.EXAMPLE_LAB_TOML.replace("encoder_zero_u_arcsec = 2.0", "encoder_zero_u_arcsec = 5.0")
    cert = C.certificate(fitted / "result.json", lab=_lab(fitted, "enc.toml", text), issue_date="2026-11-29")
    assert not cert.issued
    assert any("[bench] encoder_zero_u_arcsec = 5 arcsec in the lab file, 2 in the result" in r
               for r in cert.reasons), cert.reasons


def test_another_local_g_refuses(fitted):
    text = C.EXAMPLE_LAB_TOML.replace("local_g_m_s2 = 9.80665", "local_g_m_s2 = 9.81")
    cert = C.certificate(fitted / "result.json", lab=_lab(fitted, "g.toml", text), issue_date="2026-11-29")
    assert not cert.issued
    assert any("local gravity 9.81000 m/s² differs from the 9.80665 m/s²" in r and "341 ppm" in r
               for r in cert.reasons), cert.reasons


def test_a_fit_with_the_noise_estimated_is_type_a_only_with_its_students_t(tmp_path, fitted):
    """A fit whose noise is estimated from its residuals carries U = k u with k from Student's t on the
    noise's dof and a Type A row alone (estimation/joint.py ``noise_dof``). That U is no lab file: under a
    lab file the certificate says the result is Type A only (not "fitted with another lab file"), and
    without one its method states k from Student's t, not the lab's systematic errors."""
    lines, keep = [], None
    for line in (fitted / "campaign.csv").read_text().splitlines():
        if line.startswith("#"):
            if not line.startswith("# Q_V2s"):
                lines.append(line)
            continue
        f = line.split(",")
        if keep is None:
            keep = [i for i, h in enumerate(f) if not (h.startswith(("sd_", "u_w_")) or h == "n_samples")]
        lines.append(",".join(f[i] for i in keep))
    (tmp_path / "nosd.csv").write_text("\n".join(lines) + "\n")
    result = api.fit(tmp_path / "nosd.csv", effects=DEFAULT_EFFECTS)
    assert result.fit["noise_dof"] > 0 and all(p.U is not None for n, p in result.parameters.items()
                                               if n not in ("tilt_delta", "tilt_beta"))   # derived: u only
    result.save(tmp_path / "r.json")
    cert = C.certificate(tmp_path / "r.json", lab=fitted / "lab.toml", issue_date="2026-12-01")
    why = " ".join(cert.reasons)
    assert not cert.issued and "Type A only (it was fitted without them)" in why and "another lab file" not in why, why
    cert = C.certificate(tmp_path / "r.json", issue_date="2026-12-01")
    text = dict(cert.method)["Uncertainty"]
    assert "Student's t" in text and "Type B" not in text and "Type A only" in text, text
    from triadcal.reports.summary import summary_text

    said = summary_text(result)
    assert "Type A only, the noise estimated on" in said and "lab's Type B" not in said, said


def test_a_lab_without_gravity_refuses_the_data_g_taken_as_exact(tmp_path):
    """An outside probe: data stating # local_g_m_s2 = 9.8112 (a site value uncertain by 20 ppm), a lab
    file of bench and fixture errors without [gravity]: K held by value +- U in 75 of 150 campaigns, and
    the certificate was issued. Now the fit says the g was taken as exact, and no certificate; with
    [gravity] stating the same g and its u, K's budget holds its row and the certificate is issued."""
    import numpy as np

    from independent_bench import simulate_campaign
    from triadcal.io.bench_csv import parse_bench_csv

    text, _ = simulate_campaign(np.random.default_rng(3), setpoints_C=(20,), local_g_m_s2=9.8112)
    (tmp_path / "c.csv").write_text(text)
    no_g = C.EXAMPLE_LAB_TOML.replace("local_g_m_s2 = 9.80665\n", "").replace("u_ppm = 10\n", "")
    for name, lab_text in (("no_g", no_g), ("g", no_g.replace("[gravity]", "[gravity]\nlocal_g_m_s2 = 9.8112\nu_ppm = 20"))):
        lab = _lab(tmp_path, f"{name}.toml", lab_text)
        r = api.fit(parse_bench_csv(text), effects=("bench_tilt",), lab=lab)
        r.save(tmp_path / f"{name}.json")
        cert = C.certificate(tmp_path / f"{name}.json", lab=lab, issue_date="2026-12-01")
        rows = {b["key"] for b in r["K_x"].uncertainty["budget"]}
        if name == "no_g":
            assert any(n.startswith("the lab file declares systematic errors but not the local gravity") for n in r.notes)
            assert "[gravity] u_ppm" not in rows
            assert not cert.issued and any("not the local gravity's" in x and "9.8112" in x for x in cert.reasons)
        else:
            assert not any("not the local gravity" in n for n in r.notes)
            assert "[gravity] u_ppm" in rows
            assert cert.issued, cert.reasons
            # K's u holds the 20 ppm of g one to one (the other rows: noise, bench, fixture)
            row = next(b for b in r["K_x"].uncertainty["budget"] if b["key"] == "[gravity] u_ppm")
            assert row["contribution"] == pytest.approx(20e-6 * r["K_x"].value, rel=0.02)


def test_values_at_a_reference_temperature_outside_the_range_are_refused(tmp_path, fitted):
    """An outside probe fitted --reference-temperature 100 on data of -20..60 degC: the certificate
    stated every value "at the reference temperature 100 degC" and, in its section 5, that the model is
    not valid outside the range. Refused now, naming the range; at 20 degC (inside) the same fit is
    not refused for it."""
    from triadcal.reports.certificate.refusal import reference_outside_range

    result = api.fit(fitted / "campaign.csv", effects=DEFAULT_EFFECTS, reference_temperature_C=100.0)
    lo, hi = result.temperature_range_C
    assert hi < 99.0
    result.save(tmp_path / "r100.json")
    cert = C.certificate(tmp_path / "r100.json", issue_date="2026-12-01")
    why = " ".join(cert.reasons)
    assert not cert.issued and "reference temperature 100 degC, outside the calibrated range" in why, why
    assert reference_outside_range(api.fit(fitted / "campaign.csv", effects=DEFAULT_EFFECTS)) is None


def test_a_lab_file_of_random_errors_only_is_not_called_no_lab_file(tmp_path, fitted):
    """A lab file stating only the bench's random errors (sigma_1, sigma_2: in the fit's weights) and no
    systematic one: the certificate's method said "Type A only: no lab file with the lab's own errors"
    (an outside probe). It says the random errors are in and no systematic one is stated."""
    lab = _lab(tmp_path, "random.toml", C.EXAMPLE_LAB_TOML.split("[bench]")[0]
               + '[bench]\nname = "table"\nsigma_position_arcsec = 5.0\nsigma_wobble_arcsec = 2.0\n')
    result = api.fit(fitted / "campaign.csv", effects=DEFAULT_EFFECTS, lab=lab)
    assert isinstance(result.fit.get("bench_errors"), dict)
    result.save(tmp_path / "r.json")
    cert = C.certificate(tmp_path / "r.json", lab=lab, issue_date="2026-12-01")
    assert cert.issued, cert.reasons
    text = dict(cert.method)["Uncertainty"]
    assert "with the bench's random errors (positioning, wobble)" in text and "no lab file" not in text, text
    assert "it states none of the lab's systematic errors" in text and "Type B" not in text, text
