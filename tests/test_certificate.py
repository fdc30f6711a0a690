"""Calibration certificate and refusal report (HTML, PDF), budget table and plots.

The golden test fits a simulated campaign and checks that every parameter of the JSON
appears, with the same rounded value and U = 2u, in the HTML and in the text that pypdf
extracts from the PDF. Real files, real matplotlib renders, real PDFs.
"""

from __future__ import annotations

import base64
import json
import math
import os
import re

import numpy as np
import pytest

os.environ.setdefault("XDG_CACHE_HOME", "/tmp/xdg")

from triadcal.api import simulate  # noqa: E402
from triadcal.estimation.result import CalibrationResult, ParameterValue, round_to_uncertainty  # noqa: E402
from triadcal.estimation.gates import FitEvidence, apply_gates  # noqa: E402
from triadcal.io.bench_csv import write_bench_csv  # noqa: E402
from triadcal.models.effects import DEFAULT_EFFECTS  # noqa: E402
from triadcal.models.model import Model  # noqa: E402
from triadcal.reports import certificate as C  # noqa: E402
from triadcal.reports.certificate.html import _matrix_str  # noqa: E402
from triadcal.estimation.posterior.diagnostics import _arviz  # noqa: E402
from triadcal.uncertainty.angles import ANGLES, BUDGET_SOURCES, uncertainty_budget  # noqa: E402

pypdf = pytest.importorskip("pypdf")
pytest.importorskip("reportlab")

ISSUE_DATE = "2026-11-22"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# -- inputs -------------------------------------------------------------------------------------
def fitted_result(campaign, lab=None) -> CalibrationResult:
    """The joint fit of the campaign, with the lab file's errors when given (docs/lab.md)."""
    from triadcal import api

    return api.fit(campaign, effects=DEFAULT_EFFECTS, lab=lab)


def hand_result(unit: str = "SN-HAND-0001", status: str = "ok", method: str = "joint",
                typeb: bool = True) -> CalibrationResult:
    """A plausible result by hand: the default-effect parameters in their reporting units; a
    joint one carries a budget per parameter (its Type A row only, as a fit with a lab file
    that declares no systematic error writes it), unless ``typeb`` is False."""
    model = Model(DEFAULT_EFFECTS)
    rng = np.random.default_rng(5)
    u_of = {"g/V": 1.3e-6, "g": 7.6e-7, "arcsec": 0.27, "arcsec/degC": 0.0087, "ppm/degC": 0.041,
            "ug/degC": 0.024}
    params = {}
    for n in model.names:
        s = model.spec[n]
        u = u_of[s.unit]
        extra = {"u_type_a": u, "U": 2 * u, "k": 2.0, "coverage_probability": 0.9545, "dof_eff": None,
                 "U_method": "GUM", "budget": [{"source": "fit: output noise", "type": "A", "distribution": "normal",
                                                "u": u, "unit": s.unit, "sensitivity": 1.0, "sensitivity_unit": "1",
                                                "contribution": u, "dof": None, "key": ""}]}
        params[n] = ParameterValue(s.nominal + s.typical * rng.normal(), u, s.unit,
                                   extra if typeb and method != "classical" else {})
    r = CalibrationResult(unit=unit, method=method, parameters=params, status=status,
                          effects=tuple(DEFAULT_EFFECTS), temperature_range_C=(-39.7, 70.3),
                          fit={"chi2_dof": 1.01, "n_obs": 540, "n_params": len(params), "gap_p_value": 0.4,
                               "noise_known": True},
                          extra={"local_g_m_s2": 9.80665, "output_unit": "V"})
    # the gates a fit records (a status ok needs them on file: the reader refuses one without); the
    # status asked for is kept
    apply_gates(r, FitEvidence(converged=True, chi2=1.01 * (540 - len(params)), dof=540 - len(params),
                               noise_known=True))
    r.status = status
    return r


def fake_posterior(result, chains=4, draws=400, seed=1, shift_chain=None):
    """Independent normal draws with the result's covariance, as an arviz InferenceData whose
    variables are named like the parameters (what the sampler writes)."""
    az = _arviz()
    names = [n for n in result.parameters if not n.startswith("tilt_")]
    mu = np.array([result[n].value for n in names])
    cov = result.covariance(names)
    x = np.random.default_rng(seed).multivariate_normal(mu, cov, size=(chains, draws))
    if shift_chain is not None:
        x[shift_chain] += 5.0 * np.sqrt(np.diag(cov))
    return az.from_dict(posterior={n: x[..., i] for i, n in enumerate(names)})


@pytest.fixture(scope="module")
def issued(tmp_path_factory):
    d = tmp_path_factory.mktemp("cert")
    _, campaign = simulate(d / "campaign.csv", seed=11, unit="SN-GOLD-0001")
    (d / "lab.toml").write_text(C.EXAMPLE_LAB_TOML)
    result = fitted_result(campaign, lab=d / "lab.toml")
    result.save(d / "result.json")
    fake_posterior(result).to_netcdf(d / "post.nc")
    cert = C.certificate(d / "result.json", posterior=d / "post.nc", lab=d / "lab.toml", data=d / "campaign.csv",
                         html=d / "c.html", pdf=d / "c.pdf", plots_dir=d / "plots", issue_date=ISSUE_DATE)
    return {"dir": d, "cert": cert, "json": json.loads((d / "result.json").read_text()),
            "html": (d / "c.html").read_text(encoding="utf-8"), "pdf": pypdf.PdfReader(d / "c.pdf")}


def pdf_text(reader, layout=True) -> str:
    return "\n".join(p.extract_text(extraction_mode="layout" if layout else "plain") for p in reader.pages)


def significant_digits(s: str) -> int:
    return len(s.replace("-", "").replace(".", "").lstrip("0"))


# -- the golden test -------------------------------------------------------------------------------
def test_every_parameter_in_html_and_pdf_with_the_same_rounded_value_and_U(issued):
    assert issued["cert"].issued
    params = issued["json"]["parameters"]
    assert len(params) >= 30  # the default-effect model and the bench tilt
    html = issued["html"]
    lines = pdf_text(issued["pdf"]).splitlines()
    for name, p in params.items():
        value, U = round_to_uncertainty(p["value"], p.get("U", 2.0 * p["u"]))
        assert significant_digits(U) <= 2, (name, U)
        assert abs(float(value) - p["value"]) <= float(U) / 2 + 1e-15, name   # rounded, not moved
        # HTML: the parameter's own row holds exactly this value and U
        m = re.search(rf"<tr data-param='{re.escape(name)}'>(.*?)</tr>", html)
        assert m, f"{name} has no row in the HTML"
        cells = re.findall(r"<td class='num'>(.*?)</td>", m.group(1))
        assert cells == [value, U], (name, cells, value, U)
        # PDF: the line of the parameter's row carries the same strings
        row = [ln.split() for ln in lines if ln.split()[:1] == [name]]
        assert row, f"{name} not found in the PDF text"
        assert value in row[0] and U in row[0], (name, row[0], value, U)


def test_pdf_text_states_the_certificate(issued):
    cert, reader = issued["cert"], issued["pdf"]
    text = pdf_text(reader, layout=False)
    n = len(reader.pages)
    assert re.fullmatch(r"ISCL-20261122-[0-9A-F]{8}", cert.number)
    for i, page in enumerate(reader.pages, 1):
        t = page.extract_text()
        assert cert.number in t and f"page {i} of {n}" in t      # every page identifies the certificate
    for needed in ("Calibration certificate", "SN-GOLD-0001", "triadcal 0.1.0", "U (95.45 %)",
                   "Budgets of the parameters at the reference temperature", "Type B",
                   "least squares", "Uncertainty budget", "Inverse matrix", "Reference temperature",
                   "Local gravity", "Inertial Sensors Calibration Laboratory", "A. N. Engineer",
                   "shall not be reproduced except in full"):
        assert needed in text or needed in re.sub(r"\s+", " ", text), needed


def test_html_is_self_contained_with_every_plot_embedded(issued):
    html, cert = issued["html"], issued["cert"]
    assert not re.search(r"(src|href)\s*=\s*['\"]?(https?:|//)", html), "the HTML refers to the network"
    assert "@import" not in html and "url(" not in html
    images = re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", html)
    assert len(images) == len(cert.plots) == 4 and not cert.skipped_plots
    for b64 in images:
        assert base64.b64decode(b64).startswith(PNG_MAGIC)
    names = sorted(p.name for p in cert.plots)
    assert names == ["angles_temperature", "posterior_pairs", "posterior_trace_rank", "residuals"]
    for name in names:   # also written as PNG files
        assert (issued["dir"] / "plots" / f"{name}.png").read_bytes().startswith(PNG_MAGIC)


def test_inverse_matrix_on_the_certificate_inverts_Ca(issued):
    cert = issued["cert"]
    Ca = cert.result.matrix()
    printed = np.array([[float(_matrix_str(x)) for x in row] for row in cert.inverse_matrix])
    assert np.allclose(printed @ Ca, np.eye(3), atol=2e-9)   # 9 printed decimals
    for row in printed:
        for x in row:
            assert f"<td>{x:.9f}</td>" in issued["html"]


def test_budget_is_sorted_and_follows_eq_4_and_7(issued):
    """The paper's budget for a result without budgets of its own (Type A only): every row of
    eq. 4-7 with the lab file's figures, the systematic rows with sensitivity 1."""
    from triadcal.uncertainty.angles import uncertainty_budget

    res = issued["cert"].result
    bare = CalibrationResult(unit=res.unit, method=res.method, effects=res.effects, status=res.status,
                             parameters={n: ParameterValue(p.value, p.uncertainty.get("u_type_a", p.u), p.unit)
                                         for n, p in res.parameters.items()},
                             temperature_range_C=res.temperature_range_C, fit={})
    from triadcal.reports.plots import per_setpoint_angles
    from triadcal.io.bench_csv import read_bench_csv

    campaign = read_bench_csv(issued["dir"] / "campaign.csv")
    plan = dict(zip(campaign.position.tolist(), zip(campaign.axis1_deg.tolist(), campaign.axis2_deg.tolist())))
    b = uncertainty_budget(bare, C.load_lab(issued["dir"] / "lab.toml"), per_setpoint_angles(campaign), "", plan)
    sources = [c.source for c in b.components]
    assert sorted(sources) == sorted(BUDGET_SOURCES)
    contrib = [c.contribution for c in b.components if c.contribution is not None]
    assert contrib == sorted(contrib, reverse=True)
    assert all(c.contribution is not None for c in b.components)      # lab file and data give every input
    by = {c.source: c for c in b.components}
    lab = C.load_lab(issued["dir"] / "lab.toml")
    P = issued["cert"].result.parameters
    k_ca = max(abs(P[f"{n}_tempco"].value) for n in ANGLES)
    assert by["temperature measurement"].contribution == pytest.approx(lab.temperature_uncertainty_C * k_ca)
    # default plan: the classical angle sees sigma_1 with weight 1/2 (closed form of eq. 2-3)
    assert by["bench positioning"].contribution == pytest.approx(0.5 * lab.sigma_position_arcsec)
    assert by["wobble"].contribution == pytest.approx(0.5 * lab.sigma_wobble_arcsec)
    assert by["hysteresis"].contribution == pytest.approx(max(abs(P[f"{n}_hysteresis"].value) for n in ANGLES))
    assert b.combined_u == pytest.approx(math.sqrt(sum(c ** 2 for c in contrib)))
    # the hysteresis is a two-point +-h: U is the coverage interval of that distribution
    # convolved with the normal rest, checked here by Monte Carlo (JCGM 101), not 2 u_c
    h = by["hysteresis"].contribution
    rest = math.sqrt(sum(c.contribution ** 2 for c in b.components if c.source != "hysteresis"))
    rng = np.random.default_rng(7)
    x = rng.choice([-h, h], 1_000_000) + rng.normal(0.0, rest, 1_000_000)
    assert b.expanded_U == pytest.approx(np.quantile(np.abs(x), 0.9545), rel=3e-3)
    assert b.expanded_U < 2 * b.combined_u and by["hysteresis"].distribution == "two-point"


def test_budget_with_the_results_own_rows(issued):
    """A result fitted with the lab file: the angle budget over the range takes the largest
    angle's own rows (Type A, every Type B with its sensitivity from the model), the thermometers
    through that angle's tempco; the bench's random errors are inside the Type A row."""
    cert = issued["cert"]
    b = cert.budget
    by = {c.source: c for c in b.components}
    P = cert.result.parameters
    worst = max(ANGLES, key=lambda n: P[n].u)
    own = {r["source"]: r for r in P[worst].uncertainty["budget"]}
    for src, row in own.items():
        assert by[src].contribution == pytest.approx(row["contribution"])
    assert "encoder zeros" not in by and "temperature measurement" not in by
    assert by["thermometers"].contribution == pytest.approx(0.2 * abs(P[f"{worst}_tempco"].value), rel=0.02)
    assert by["bench positioning"].contribution == 0.0 and "inside the angles' u" in by["bench positioning"].basis
    contrib = [c.contribution for c in b.components if c.contribution is not None]
    assert contrib == sorted(contrib, reverse=True)
    assert b.combined_u == pytest.approx(math.sqrt(sum(c ** 2 for c in contrib)))
    groups = cert.parameter_budgets
    assert [x.quantity for x in groups["Scale factors"]] == ["K_x", "K_y", "K_z"]
    assert all(x.expanded_U == pytest.approx(P[x.quantity].U) for g in groups.values() for x in g)


def test_a_normal_budget_keeps_k_2_and_a_pure_two_point_one_its_half_width():
    from triadcal.uncertainty.budget import Budget, BudgetComponent

    normal = Budget("x", [BudgetComponent("a", 3.0), BudgetComponent("b", 4.0)])
    assert normal.expanded_U == pytest.approx(10.0) and normal.effective_k == pytest.approx(2.0)
    two = Budget("x", [BudgetComponent("h", 5.0, distribution="two-point")])
    assert two.expanded_U == pytest.approx(5.0)


def test_budget_taken_from_the_result_when_the_estimator_wrote_one():
    r = hand_result()
    r.extra["budget"] = {"components": [
        {"source": "bench positioning", "standard_uncertainty": 5.0, "unit": "arcsec", "sensitivity": 2.0,
         "sensitivity_unit": "1", "contribution": 10.0, "symbol": "sigma_1"},
        {"source": "output noise", "standard_uncertainty": 1e-5, "unit": "V", "sensitivity": 4.1e5,
         "sensitivity_unit": "arcsec/V", "contribution": 4.1, "symbol": "noise"}]}
    b = uncertainty_budget(r)
    assert [c.source for c in b.components] == ["bench positioning", "output noise"]
    assert b.combined_u == pytest.approx(math.hypot(10.0, 4.1))


# -- refusal -----------------------------------------------------------------------------------------
def test_not_converged_gives_the_refusal_report_not_a_certificate(tmp_path):
    r = hand_result(status="not_converged")
    r.notes.append("Levenberg-Marquardt stopped after 100 iterations")
    r.save(tmp_path / "bad.json")
    cert = C.certificate(tmp_path / "bad.json", html=tmp_path / "bad.html", pdf=tmp_path / "bad.pdf",
                         issue_date=ISSUE_DATE)
    assert not cert.issued and cert.number is None and not cert.rows and cert.budget is None
    assert any("not_converged" in x for x in cert.reasons)
    html = (tmp_path / "bad.html").read_text(encoding="utf-8")
    assert "No certificate issued" in html and "not_converged" in html
    assert "data-param" not in html and "Calibration certificate</h1>" not in html
    assert "ISCL-" not in html and "TC-" not in html                 # no certificate number
    text = pdf_text(pypdf.PdfReader(tmp_path / "bad.pdf"), layout=False)
    assert "No certificate issued" in text and "not_converged" in text and "Refusal report" in text
    for name, p in r.parameters.items():                               # no values are certified
        v, U = round_to_uncertainty(p.value, 2 * p.u)
        assert f"{v} " not in text and name not in html


def test_cli_refuses_with_status_3_and_issues_with_0(tmp_path, capsys):
    from triadcal.cli import main

    bad = hand_result(status="not_converged")
    bad.save(tmp_path / "bad.json")
    assert main(["certificate", str(tmp_path / "bad.json"), "--html", str(tmp_path / "b.html")]) == 3
    assert "no certificate issued" in capsys.readouterr().err
    good = hand_result()
    good.save(tmp_path / "good.json")
    rc = main(["certificate", str(tmp_path / "good.json"), "--pdf", str(tmp_path / "g.pdf"), "--date", ISSUE_DATE,
               "--number", "LAB-2026-0042"])
    out = capsys.readouterr().out
    assert rc == 0 and "certificate LAB-2026-0042 issued" in out
    assert (tmp_path / "g.pdf").read_bytes().startswith(b"%PDF")
    assert "LAB-2026-0042" in pdf_text(pypdf.PdfReader(tmp_path / "g.pdf"), layout=False)
    assert main(["certificate", str(tmp_path / "good.json")]) == 1       # no output asked for


@pytest.mark.parametrize("case, expect", [
    ("gap", "significant gap between the model and the data"),
    ("unidentified", "could not determine Ca_xy_hysteresis"),
    ("no_u", "no finite value or uncertainty for S_x"),
    ("diagnosis", "the diagnosis finds a significant model-data gap"),
])
def test_other_failed_diagnostics_refuse(case, expect):
    r = hand_result()
    diagnosis = None
    if case == "gap":
        r.fit["gap_p_value"] = 1e-9
        r.fit["chi2_dof"] = 3.4
    elif case == "unidentified":
        r.notes.append("Ca_xy_hysteresis not estimated, held at 0 arcsec: hysteresis needs visits on both a "
                       "heating and a cooling branch; the data has only heating")
    elif case == "no_u":
        r.parameters["S_x"] = ParameterValue(1e-3, float("nan"), "g")
    else:
        diagnosis = {"format": "triadcal.diagnosis", "version": 1, "gap": {"chi2_dof": 3.4, "significant": True},
                     "verdict": {"effect": "hysteresis"}}
    cert = C.build_certificate(r, diagnosis=diagnosis, issue_date=ISSUE_DATE, plots=False)
    assert not cert.issued
    assert any(expect in x for x in cert.reasons), cert.reasons
    assert "No certificate issued" in C.render_html(cert)


def test_a_posterior_that_did_not_mix_refuses():
    r = hand_result()
    cert = C.build_certificate(r, idata=fake_posterior(r, shift_chain=2), issue_date=ISSUE_DATE, plots=False)
    assert not cert.issued and any("R-hat" in x for x in cert.reasons)
    ok = C.build_certificate(r, idata=fake_posterior(r), issue_date=ISSUE_DATE, plots=False)
    assert ok.issued, ok.reasons


def _with_verdict(idata, converged, rhat_max=1.004):
    idata.posterior.attrs.update({"converged": int(converged), "rhat_max": rhat_max, "rhat_worst": "Ca_xy",
                                  "ess_bulk_min": 2500.0, "ess_bulk_worst": "K_x", "ess_tail_min": 2400.0,
                                  "stop_rule_ess": 2000.0, "stop_rule_rhat_max": 1.01})
    return idata


def test_the_certificate_reads_the_samplers_verdict_instead_of_recomputing_it():
    """One verdict per posterior: the one stored with the draws decides, even where a
    recomputation on the same draws would say otherwise; a refusal names the option."""
    r = hand_result()
    good_draws_bad_verdict = _with_verdict(fake_posterior(r), converged=False, rhat_max=1.012)
    cert = C.build_certificate(r, idata=good_draws_bad_verdict, issue_date=ISSUE_DATE, plots=False)
    assert not cert.issued
    why = " ".join(cert.reasons)
    assert "stored by the sampler" in why and "--max-steps" in why and "1.0120" in why
    bad_draws_good_verdict = _with_verdict(fake_posterior(r, shift_chain=2), converged=True)
    assert C.build_certificate(r, idata=bad_draws_good_verdict, issue_date=ISSUE_DATE, plots=False).issued


def test_a_posterior_file_of_another_run_is_refused():
    r = hand_result()
    r.method = "posterior"
    r.extra["sampler"] = {"rhat_max": 1.003, "stop_rule": {"ess": 2000, "rhat_max": 1.01}}
    mine = C.build_certificate(r, idata=_with_verdict(fake_posterior(r), True, rhat_max=1.003),
                               issue_date=ISSUE_DATE, plots=False)
    assert mine.issued, mine.reasons
    other = C.build_certificate(r, idata=_with_verdict(fake_posterior(r), True, rhat_max=1.006),
                                issue_date=ISSUE_DATE, plots=False)
    assert not other.issued and "not the one written with this result" in " ".join(other.reasons)


# -- pieces ---------------------------------------------------------------------------------------------
def test_plots_that_cannot_be_drawn_are_skipped_with_the_reason():
    from triadcal.reports.plots import report_plots

    ps = report_plots(hand_result())
    assert [p.name for p in ps.plots] == ["angles_temperature"] and ps.plots[0].png.startswith(PNG_MAGIC)
    assert set(ps.skipped) == {"residuals", "posterior_pairs", "posterior_trace_rank"}
    assert "--data" in ps.skipped["residuals"] and "--posterior" in ps.skipped["posterior_pairs"]


def test_model_curves_come_from_the_model(issued):
    """The plotted branches are the model's own: mid-line +- hysteresis, slope = tempco."""

    r = issued["cert"].result
    T = np.array([r.reference_temperature_C, r.reference_temperature_C + 10.0])
    mid, cool, heat = (r.angles_at(T, b) for b in (0.0, 1.0, -1.0))
    for ab in ("xy", "zx"):
        assert mid[ab][0] == pytest.approx(r[f"Ca_{ab}"].value, abs=1e-9)
        assert mid[ab][1] - mid[ab][0] == pytest.approx(10 * r[f"Ca_{ab}_tempco"].value, rel=1e-9)
        assert cool[ab][0] - heat[ab][0] == pytest.approx(2 * r[f"Ca_{ab}_hysteresis"].value, rel=1e-9)


def test_certificate_numbers_differ_between_results_and_repeat_for_the_same():
    a, b = hand_result("SN-A"), hand_result("SN-B")
    assert C.certificate_number(a, "TC", ISSUE_DATE) == C.certificate_number(a, "TC", ISSUE_DATE)
    assert C.certificate_number(a, "TC", ISSUE_DATE) != C.certificate_number(b, "TC", ISSUE_DATE)
    assert C.certificate_number(a, "TC", ISSUE_DATE) != C.certificate_number(a, "TC", "2026-11-23")


def test_lab_file_errors_name_the_file_and_key(tmp_path):
    p = tmp_path / "lab.toml"
    p.write_text(C.EXAMPLE_LAB_TOML)
    lab = C.load_lab(p)
    assert lab.sigma_position_arcsec == 5.0 and lab.certificate_prefix == "ISCL"
    p.write_text("[bench]\nsigma_positon_arcsec = 5\n")
    with pytest.raises(ValueError, match=r"lab.toml: unknown key 'sigma_positon_arcsec' in \[bench\]"):
        C.load_lab(p)
    p.write_text("[chamber]\ntemperature_uncertainty_C = \"0.2\"\n")
    with pytest.raises(ValueError, match=r"temperature_uncertainty_C must be a non-negative number"):
        C.load_lab(p)
    p.write_text("[lab\n")
    with pytest.raises(ValueError, match="not valid TOML"):
        C.load_lab(p)


def test_data_of_another_unit_is_refused(tmp_path):
    _, campaign = simulate(None, seed=2, unit="SN-OTHER")
    write_bench_csv(campaign, tmp_path / "other.csv")
    with pytest.raises(ValueError, match="SN-OTHER"):
        C.certificate(hand_result("SN-HAND-0001"), data=tmp_path / "other.csv", html=tmp_path / "x.html")


# -- drift report ---------------------------------------------------------------------------------------
COMPARISON = {
    "format": "triadcal.comparison", "version": 1, "unit": "SN-GOLD-0001",
    "rule": "fail when the drift exceeds 30 arcsec with probability > 95 %",
    "parameters": {"Ca_xy": {"drift": 13.83, "u": 4.1, "unit": "arcsec", "En": 1.69, "tolerance": 30.0,
                             "verdict": "pass"},
                   "Ca_yz": {"drift": -51.34, "u": 4.1, "unit": "arcsec", "En": 6.3, "tolerance": 30.0,
                             "verdict": "fail"},
                   "K_x": {"drift": 3.1e-6, "u": 1.9e-6, "unit": "g/V", "En": 0.82, "p_exceeds": 0.01,
                           "verdict": "pass"}},
    "overall": "fail"}


def test_drift_report_states_every_drift_with_its_U_and_verdict(tmp_path):
    from triadcal.cli import main

    (tmp_path / "comp.json").write_text(json.dumps(COMPARISON))
    assert main(["certificate", str(tmp_path / "comp.json"), "--html", str(tmp_path / "d.html"),
                 "--pdf", str(tmp_path / "d.pdf"), "--date", ISSUE_DATE]) == 0
    html = (tmp_path / "d.html").read_text(encoding="utf-8")
    lines = pdf_text(pypdf.PdfReader(tmp_path / "d.pdf")).splitlines()
    for name, p in COMPARISON["parameters"].items():
        d, U = round_to_uncertainty(p["drift"], 2 * p["u"])
        row = re.search(rf"<tr data-param='{name}'>(.*?)</tr>", html).group(1)
        assert re.findall(r"<td class='num'>(.*?)</td>", row)[2:4] == [d, U] and p["verdict"] in row
        tokens = next(ln.split() for ln in lines if ln.split()[:1] == [name])
        assert d in tokens and U in tokens and p["verdict"] in tokens
    assert "FAIL" in html and "data:image/png;base64," in html
    bad = dict(COMPARISON, version=2)
    with pytest.raises(ValueError, match="comparison version 2 is not known"):
        C.render_drift_html(bad)


# -- a certificate a metrologist signs as it is (issue 22) ------------------------------------------
def test_one_angle_uncertainty_for_using_the_matrix_stated_consistently(issued):
    """The U of an angle when the matrix is used at a temperature is stated once, in the results
    section, HTML and PDF alike, with u_c and U from the same unrounded budget."""
    from triadcal.estimation.result import significant

    cert = issued["cert"]
    b = cert.budget
    U, uc = significant(b.expanded_U, 2), significant(b.total, 3)
    assert b.expanded_U == pytest.approx(b.effective_k * b.total, rel=1e-12)
    kind = f"coverage 95.45 %, k = U/u_c = {b.effective_k:.3g}"
    assert f"U = {U} arcsec ({kind}" in cert.angle_statement
    assert "hysteresis" in cert.angle_statement and "thermal model" in cert.angle_statement
    pdf = " ".join(pdf_text(issued["pdf"], layout=False).split())
    html = " ".join(re.sub(r"<[^>]+>", " ", issued["html"]).split())
    for text in (pdf, html):
        assert f"U = {U} arcsec ({kind}" in text and f"u_c = {uc} arcsec" in text
        # the budget's totals print the same two numbers
        assert re.search(rf"u_c \(root sum of squares\)\s+{re.escape(uc)}\b", text)
        assert re.search(rf"k = U/u_c = {b.effective_k:.3g}\)\s+{re.escape(U)}\b", text)


def test_significant_rounds_halves_up():
    from triadcal.estimation.result import significant

    assert [significant(30.5, 2), significant(15.25, 3), significant(0.0996, 2), significant(9.96, 2)] == \
        ["31", "15.3", "0.10", "10"]


def test_no_placeholder_printed_as_fact():
    """Date of calibration from the data, or the lab file, or said to be missing; standard
    gravity marked as such."""
    r = hand_result()
    cert = C.build_certificate(r, issue_date=ISSUE_DATE, plots=False)
    ident, cond = dict(cert.identification), dict(cert.conditions)
    assert ident["Date of calibration"].startswith("not stated")
    assert "standard gravity, not measured" in cond["Local gravity"]
    from triadcal.io.lab import LabConfig

    dated = C.build_certificate(r, lab=LabConfig(calibration_date="2026-11-02"), issue_date=ISSUE_DATE, plots=False)
    assert dict(dated.identification)["Date of calibration"] == "2026-11-02 (lab file)"
    r.extra["local_g_m_s2"] = 9.8112
    assert "local value stated in the data" in dict(
        C.build_certificate(r, issue_date=ISSUE_DATE, plots=False).conditions)["Local gravity"]
    assert "calibration_date" not in "".join(
        ln for ln in C.EXAMPLE_LAB_TOML.splitlines() if not ln.lstrip().startswith("#"))


def test_one_notation_in_the_certificate(issued):
    """Ca_xy (not Ca_XY), µg/°C and arcsec/°C (not ug/degC) in the HTML and the PDF."""
    pdf = pdf_text(issued["pdf"], layout=False)
    for text in (issued["html"], pdf):
        assert not re.search(r"Ca_[XYZ]{2}\b", text)
        assert not re.search(r"\bdegC\b|\bug/", text)
        assert "Ca_xy_tempco" in text and "µg/°C" in text


# -- the lab's equipment (issue 16, item 1) ---------------------------------------------------------
def _lab(tmp_path, text):
    path = tmp_path / "lab.toml"
    path.write_text(text)
    return C.load_lab(path)


#: the example lab file without its systematic errors (a Type A result under it is not refused for them)
NO_TYPE_B = "\n".join(line for line in C.EXAMPLE_LAB_TOML.splitlines()
                      if not line.startswith(("axes_nonorthogonality_u_arcsec", "encoder_zero_u_arcsec",
                                              "mounting_u_arcsec", "u_C", "local_g_m_s2", "u_ppm")))


def test_expired_equipment_refuses_the_certificate_unless_allowed_and_then_prints_it(tmp_path):
    r = hand_result(method="classical")     # Type A only: under a lab without systematic errors
    lab = _lab(tmp_path, NO_TYPE_B.replace("due = 2027-06-30", "due = 2025-06-30"))
    assert lab.equipment["bench"] == {"instrument": "two-axis table, serial 0001", "certificate": "ANG-2026-0417",
                                      "due": "2025-06-30"}
    cert = C.build_certificate(r, lab=lab, issue_date=ISSUE_DATE, plots=False)
    assert not cert.issued and any("due for calibration on 2025-06-30" in x and "--allow-expired-equipment" in x
                                   for x in cert.reasons)
    allowed = C.build_certificate(r, lab=lab, issue_date=ISSUE_DATE, plots=False, allow_expired_equipment=True)
    assert allowed.issued and "EXPIRED" in dict(allowed.identification)["Equipment: bench"]
    current = C.build_certificate(r, lab=_lab(tmp_path, NO_TYPE_B), issue_date=ISSUE_DATE, plots=False)
    assert current.issued and "due 2027-06-30" in dict(current.identification)["Equipment: bench"]


def test_a_classical_result_fitted_without_the_lab_is_refused_under_a_lab_with_systematic_errors(tmp_path):
    """A classical result fitted without --lab has Type A u only. Before, such a certificate was
    issued: its results table left the lab's errors out (an outside probe: Ca_zx 22.0 arcsec off
    with U 5.8, value +- U covering the truth in 20-26 % of 150 campaigns) and said "Type A only:
    no lab file". Fitted with --lab it propagates them (tests/test_classical_typeb.py)."""
    r = hand_result(method="classical")
    r.extra["local_g_m_s2"] = 9.8112          # fitted with the lab's g (another g is refused)
    text = C.EXAMPLE_LAB_TOML.replace("# local_g_m_s2 = 9.8112", "local_g_m_s2 = 9.8112").replace(
        "# u_ppm = 10", "u_ppm = 10")
    cert = C.build_certificate(r, lab=_lab(tmp_path, text), issue_date=ISSUE_DATE, plots=False)
    assert not cert.issued
    assert any("classical result" in x and "--method classical --lab" in x and "[fixture] mounting_u_arcsec" in x
               for x in cert.reasons), cert.reasons
    without = C.build_certificate(r, issue_date=ISSUE_DATE, plots=False)     # no lab file: Type A, said so
    assert without.issued


def test_a_type_a_result_with_a_lab_that_declares_systematic_errors_is_refused(tmp_path):
    r = hand_result(typeb=False)
    cert = C.build_certificate(r, lab=_lab(tmp_path, C.EXAMPLE_LAB_TOML), issue_date=ISSUE_DATE, plots=False)
    assert not cert.issued
    assert any("Type A only" in x and "[fixture] mounting_u_arcsec" in x and "--lab" in x for x in cert.reasons)
    # a lab file without systematic errors: nothing to leave out
    plain = _lab(tmp_path, "[lab]\nname = \"L\"\n")
    assert C.build_certificate(r, lab=plain, issue_date=ISSUE_DATE, plots=False).issued


@pytest.mark.parametrize("text, message", [
    ("[fixture]\nmounting_u_arcsec = -1\n", "must be a non-negative number"),
    ("[fixture]\nwobble = 1\n", "unknown key 'wobble' in \\[fixture\\]"),
    ("[bench]\ndue = \"soon\"\n", "is not a date"),
    ("[gravity]\nlocal_g_m_s2 = 1.0\n", "not a gravity on the Earth's surface"),
])
def test_a_lab_file_that_cannot_be_used_is_refused(tmp_path, text, message):
    with pytest.raises(ValueError, match=message):
        _lab(tmp_path, text)


def test_a_posterior_of_another_unit_is_refused(issued, tmp_path):
    """Before: a certificate of SN-GOLD-0001 was issued with another unit's posterior, its R-hat,
    ESS and plots (an outside probe); compare refused the same mix-up."""
    from triadcal.errors import InputError
    from triadcal.estimation.result import CalibrationResult

    d = issued["dir"]

    result = CalibrationResult.load(d / "result.json")
    post = fake_posterior(result)
    post.posterior.attrs["unit"] = "SN-OTHER-0002"
    post.to_netcdf(tmp_path / "other.nc")
    with pytest.raises(InputError, match="is a posterior of unit 'SN-OTHER-0002'"):
        C.certificate(d / "result.json", posterior=tmp_path / "other.nc", lab=d / "lab.toml",
                      data=d / "campaign.csv", issue_date=ISSUE_DATE)


@pytest.mark.parametrize("edit,match", [
    ("shift", "its means disagree with its result's values"),      # Ca_xy's draws moved by 50 of its u
    ("wide", "its draws are wider than its result's uncertainties")])  # another campaign's, 100x wider
def test_a_posterior_whose_draws_are_not_the_results_is_refused(issued, tmp_path, edit, match):
    """An outside probe: the result's own netCDF with Ca_xy's draws moved by +500 arcsec (its stored
    verdict kept), and another campaign's posterior of the same serial (Ca_xy 300 +- 101 against
    312.3 +- 0.28), were both certified. The draws' moments are now checked against the result
    (compare's rule, reused); the result's own posterior is still issued."""
    from triadcal.errors import InputError
    from triadcal.estimation.result import CalibrationResult

    d = issued["dir"]
    result = CalibrationResult.load(d / "result.json")
    post = fake_posterior(result)
    post.to_netcdf(tmp_path / "own.nc")
    cert = C.certificate(d / "result.json", posterior=tmp_path / "own.nc", lab=d / "lab.toml",
                         data=d / "campaign.csv", issue_date=ISSUE_DATE)
    assert cert.issued
    u = result["Ca_xy"].u
    v = post.posterior["Ca_xy"]
    post.posterior["Ca_xy"] = v + 50 * u if edit == "shift" else v.mean() + (v - v.mean()) * 100
    post.to_netcdf(tmp_path / "bad.nc")
    with pytest.raises(InputError, match=match):
        C.certificate(d / "result.json", posterior=tmp_path / "bad.nc", lab=d / "lab.toml",
                      data=d / "campaign.csv", issue_date=ISSUE_DATE)
