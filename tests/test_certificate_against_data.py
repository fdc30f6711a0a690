"""A certificate given the data re-derives the values from them (reports/certificate/against_data.py).

A result edited and re-signed (content_sha256 recomputed) with K_x and K_y swapped, or with its reference
temperature moved and its values kept, is consistent in itself; only its data can say the values are not
theirs (left open by the session of 2026-12-01). The data here come from the independent simulator
(tests/independent_bench.py: no triadcal model code), so the values the certificate re-derives are
checked against a physics written another way. The step's size is derived by hand: at values moved by
d u from a least-squares optimum, one Gauss-Newton step of a model linear in that parameter returns
exactly -d u (the model is linear in a bias)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

os.environ.setdefault("XDG_CACHE_HOME", "/tmp/xdg")

from triadcal import api  # noqa: E402
from triadcal.estimation.result import CalibrationResult, content_sha256  # noqa: E402
from triadcal.estimation.result_checks import RefusedResult  # noqa: E402
from triadcal.io.bench_csv import read_bench_csv  # noqa: E402
from triadcal.reports import certificate as C  # noqa: E402
from triadcal.reports.certificate.against_data import VALUES_Z_MAX, value_steps  # noqa: E402

from independent_bench import default_truth, simulate_campaign  # noqa: E402

pytest.importorskip("reportlab")

LINEAR = ("bench_tilt", "angle_tempco", "scale_tempco", "bias_tempco")
ISSUE = "2026-12-01"


def _campaign(tmp_path, seed, name="data.csv", **kw):
    text, truth = simulate_campaign(np.random.default_rng(seed), tilt_arcsec=(40.0, -25.0), **kw)
    (tmp_path / name).write_text(text)
    return tmp_path / name, truth


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("against")
    data, truth = _campaign(d, 5)
    res = api.fit(read_bench_csv(data), effects=LINEAR)
    assert res.status == "ok", res.notes
    res.save(d / "result.json")
    return d, data, truth


def forge(d, name, edit) -> str:
    doc = json.loads((d / "result.json").read_text())
    edit(doc)
    doc["content_sha256"] = content_sha256(doc)
    path = d / f"{name}.json"
    path.write_text(json.dumps(doc, indent=1))
    CalibrationResult.load(path)                          # the reader accepts it: the hash matches
    return str(path)


def test_the_fits_own_values_are_its_datas(fitted):
    d, data, _ = fitted
    z = value_steps(CalibrationResult.load(d / "result.json"), read_bench_csv(data))
    assert len(z) >= 26 and max(abs(v) for v in z.values()) < 1e-3, z     # the optimum: a zero step
    cert = C.certificate(d / "result.json", data=data, html=d / "ok.html", issue_date=ISSUE)
    assert cert.issued, cert.reasons


def test_swapped_scale_factors_are_refused(fitted):
    d, data, truth = fitted
    u = CalibrationResult.load(d / "result.json").parameters["K_x"].u
    assert abs(truth["K_x"] - truth["K_y"]) > 20 * u

    def swap(doc):
        p = doc["parameters"]
        p["K_x"]["value"], p["K_y"]["value"] = p["K_y"]["value"], p["K_x"]["value"]
    path = forge(d, "swapped", swap)
    with pytest.raises(RefusedResult) as e:
        C.certificate(path, data=data, html=d / "swapped.html", issue_date=ISSUE)
    msg = str(e.value)
    assert "swapped.json: refused: parameters.K_" in msg and "data.csv" in msg and "Gauss-Newton" in msg, msg
    assert not (d / "swapped.html").exists()
    # without the data the file holds together: the certificate cannot know (docs/certificate.md says so)
    assert C.certificate(path, html=d / "swapped_nodata.html", issue_date=ISSUE).issued


def test_a_moved_reference_temperature_is_refused(fitted):
    """20 -> 25 degC with the values kept: every bias is then S(20) stated at 25, off by 5 degC times its
    tempco (the truth's 2-20 ug/degC against u of about 1 ug)."""
    d, data, _ = fitted
    path = forge(d, "ref25", lambda doc: doc.__setitem__("reference_temperature_C", 25.0))
    with pytest.raises(RefusedResult, match=r"reference temperature \(25 degC\)"):
        C.certificate(path, data=data, html=d / "ref25.html", issue_date=ISSUE)


@pytest.mark.parametrize("moved_u", [4.0, 6.0])
def test_a_bias_moved_by_d_u_comes_back_by_d_u(fitted, moved_u):
    """The model is linear in S_y: one step returns exactly -d; refused beyond VALUES_Z_MAX = 5 only."""
    d, data, _ = fitted

    def move(doc):
        p = doc["parameters"]["S_y"]
        p["value"] += moved_u * p["u"]
    path = forge(d, f"moved{moved_u:g}", move)
    z = value_steps(CalibrationResult.load(path), read_bench_csv(data))
    assert z["S_y"] == pytest.approx(-moved_u, abs=0.01)
    others = max(abs(v) for k, v in z.items() if k != "S_y")
    assert others < 0.05, z
    if moved_u < VALUES_Z_MAX:
        assert C.certificate(path, data=data, html=d / "m4.html", issue_date=ISSUE).issued
    else:
        with pytest.raises(RefusedResult, match=r"parameters\.S_y\.value .* -6 u"):
            C.certificate(path, data=data, html=d / "m6.html", issue_date=ISSUE)


@pytest.mark.parametrize("seed", range(4))
def test_other_weights_and_estimators_are_not_refused(tmp_path, seed):
    """A lab file's bench errors (variance components the certificate's step does not weight by), a robust
    loss and the classical method: each moves the optimum by a fraction of u, far inside 5 u. The data have
    2 arcsec of positioning error per visit (the independent simulator's)."""
    data, _ = _campaign(tmp_path, 100 + seed, sigma_position_arcsec=2.0, sigma_wobble_arcsec=1.0)
    (tmp_path / "lab.toml").write_text(C.EXAMPLE_LAB_TOML)
    camp = read_bench_csv(data)
    fits = {"lab": api.fit(camp, effects=LINEAR, lab=tmp_path / "lab.toml"),
            "huber": api.fit(camp, effects=LINEAR, loss="huber"),
            "classical": api.fit(camp, method="classical")}
    for name, res in fits.items():
        z = value_steps(res, camp)
        assert max(abs(v) for v in z.values()) < 2.0, (name, sorted(z.items(), key=lambda kv: -abs(kv[1]))[:3])


def test_the_state_fitted_is_found_in_a_file_of_several(tmp_path):
    """fit --state B of a file of two states: the data's SHA-256 is that of B's visits; the certificate
    given the whole file takes B's (it said "not the data the result was fitted to" before)."""
    a, _ = _campaign(tmp_path, 7, name="a.csv")
    b, _ = _campaign(tmp_path, 8, name="b.csv")

    def rows(path, state):
        lines = path.read_text().splitlines()
        first = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
        col = lines[first].split(",").index("state")
        body = []
        for ln in lines[first + 1:]:
            f = ln.split(",")
            f[col] = state
            body.append(",".join(f))
        return lines[:first + 1], body
    head, before = rows(a, "before")
    _, after = rows(b, "after")
    (tmp_path / "two.csv").write_text("\n".join(head + before + after) + "\n")
    camp = read_bench_csv(tmp_path / "two.csv")
    part = camp.select(camp.state == "after", own_origin=True)
    res = api.fit(part, effects=LINEAR)
    assert res.status == "ok", res.notes
    res.save(tmp_path / "after.json")
    cert = C.certificate(tmp_path / "after.json", data=tmp_path / "two.csv", html=tmp_path / "after.html",
                         issue_date=ISSUE)
    assert cert.issued, cert.reasons
    doc = json.loads((tmp_path / "after.json").read_text())
    doc["parameters"]["S_x"]["value"] += 50 * doc["parameters"]["S_x"]["u"]
    doc["content_sha256"] = content_sha256(doc)
    (tmp_path / "after_moved.json").write_text(json.dumps(doc))
    with pytest.raises(RefusedResult, match=r"parameters\.S_x"):
        C.certificate(tmp_path / "after_moved.json", data=tmp_path / "two.csv", html=tmp_path / "x.html",
                      issue_date=ISSUE)


def test_a_form_the_plain_model_cannot_reproduce_is_said(fitted):
    d, data, _ = fitted
    path = forge(d, "quantised", lambda doc: doc["fit"].__setitem__("quantisation", {"lsb": 1e-6}))
    cert = C.certificate(path, data=data, html=d / "q.html", issue_date=ISSUE)
    assert any("not re-derived" in n and "quantised output" in n for n in cert.notes), cert.notes


def test_the_fits_own_weights_a_quiet_unit_with_the_labs_bench_errors(tmp_path):
    """An outside probe: a quiet unit (1.8 ug per visit) whose lab file declares 5 arcsec of positioning
    error (the data have it): the fit weights each visit by the bench's variance too, with the full 3 x 3
    covariance on oblique poses; the check's step, weighted by the output noise alone, put the honest bias
    tempcos 10-12 u away and refused 7 of 9 honest results. With the fit's weights the step is zero and the
    data's u is the stated Type A u."""
    data, _ = _campaign(tmp_path, 9, noise_sd=1e-4, sigma_position_arcsec=5.0)
    (tmp_path / "lab.toml").write_text(C.EXAMPLE_LAB_TOML)
    camp = read_bench_csv(data)
    res = api.fit(camp, effects=LINEAR, lab=tmp_path / "lab.toml")
    assert res.fit["bench_errors"]["sigma_position_arcsec"] > 0
    z, ratio = value_steps(res, camp, with_u=True)
    assert max(abs(v) for v in z.values()) < 1e-3, z
    type_a = {n: p.uncertainty.get("u_type_a", p.u) / p.u for n, p in res.parameters.items() if n in ratio}
    assert all(ratio[n] == pytest.approx(type_a[n], rel=1e-3) for n in ratio), (ratio, type_a)


def test_uncertainties_and_gravity_edited_are_refused(fitted):
    """An outside probe divided every u by 100 (and by 10), and set local_g_m_s2 to 9.81 with K scaled to
    match, re-signed: both exported with --data. u is now checked against the data's (stated at least half
    of it) and the local gravity against the data's statement."""
    d, data, _ = fitted

    def shrink(doc):
        for p in doc["parameters"].values():
            p["u"] /= 10.0
    path = forge(d, "u10", shrink)
    with pytest.raises(RefusedResult, match=r"parameters\.\w+\.u = .* 10 times smaller than the standard uncertainty"):
        C.certificate(path, data=data, html=d / "u10.html", issue_date=ISSUE)

    def gravity(doc):
        doc["local_g_m_s2"] = 9.81
        for a in "xyz":
            doc["parameters"][f"K_{a}"]["value"] *= 9.81 / 9.80665
    path = forge(d, "g981", gravity)
    with pytest.raises(RefusedResult, match=r"local_g_m_s2 = 9\.81 m/s\^2 is not the local gravity its data"):
        C.certificate(path, data=data, html=d / "g.html", issue_date=ISSUE)


def test_a_play_hysteresis_is_rederived_on_its_own_branches(tmp_path):
    """fit --hysteresis-form play: the branches of the play (half-width and start from fit.hysteresis) on the
    visits' temperatures. The honest result's step is zero; Ca_xy +50 arcsec re-signed is refused (an outside
    probe's was certified: the form was not re-derived). Data: the independent bench's play backlash."""
    truth = default_truth(np.random.default_rng(40))
    truth.update({f"Ca_{ab}_hysteresis": 8.0 for ab in ("xy", "xz", "yx", "yz", "zx", "zy")})
    text, _ = simulate_campaign(np.random.default_rng(4), tilt_arcsec=(40.0, -25.0), truth=truth,
                                setpoints_C=(20, -40, -10, 20, 50, 80, 50, 20, -10),
                                hysteresis={"form": "play", "half_widths_C": [10.0], "weights": [1.0], "start": "mid"})
    (tmp_path / "play.csv").write_text(text)
    camp = read_bench_csv(tmp_path / "play.csv")
    res = api.fit(camp, hysteresis_form="play")
    assert res.fit["hysteresis"]["form"] == "play"
    res.save(tmp_path / "result.json")
    assert max(abs(v) for v in value_steps(res, camp).values()) < 1e-3
    doc = json.loads((tmp_path / "result.json").read_text())
    doc["parameters"]["Ca_xy"]["value"] += 50.0
    doc["content_sha256"] = content_sha256(doc)
    (tmp_path / "forged.json").write_text(json.dumps(doc))
    with pytest.raises(RefusedResult, match=r"parameters\.Ca_xy\.value"):
        C.certificate(tmp_path / "forged.json", data=tmp_path / "play.csv", html=tmp_path / "f.html",
                      issue_date=ISSUE)


def test_export_compensation_with_the_data_refuses_an_edited_result(fitted, tmp_path):
    """export-compensation writes a firmware's tables from what a result states: with --data, the swapped
    result is refused and nothing is written; the fit's own is written with a note that it was checked;
    another campaign's data are refused by their SHA-256."""
    import subprocess
    import sys

    d, data, _ = fitted

    def swap(doc):
        p = doc["parameters"]
        p["K_x"]["value"], p["K_y"]["value"] = p["K_y"]["value"], p["K_x"]["value"]
    path = forge(d, "swapped_export", swap)
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "xdg"), MPLBACKEND="Agg")

    def export(result, data_file, out):
        return subprocess.run([sys.executable, "-m", "triadcal", "export-compensation", str(result), "--data",
                               str(data_file), "-o", str(out)], capture_output=True, text=True, env=env)
    r = export(path, data, tmp_path / "bad.json")
    assert r.returncode != 0 and "parameters.K_" in r.stderr and "Gauss-Newton" in r.stderr, r.stderr
    assert not (tmp_path / "bad.json").exists()
    r = export(d / "result.json", data, tmp_path / "good.json")
    assert r.returncode == 0, r.stderr
    notes = json.loads((tmp_path / "good.json").read_text())["notes"]
    assert any("values are those the data give" in n for n in notes), notes
    other, _ = _campaign(tmp_path, 99, name="other.csv")
    r = export(d / "result.json", other, tmp_path / "other.json")
    assert r.returncode != 0 and "are not those the result was fitted to" in r.stderr, r.stderr
    assert not (tmp_path / "other.json").exists()


def test_an_edited_goodness_of_fit_or_output_unit_is_refused(fitted):
    """Probe AF re-signed results with (a) the chi2/dof edited, (b) output_unit and the K units relabelled
    V -> mV: both were certified with --data. Now the data's own chi2/dof at the result's values (the
    Gauss-Newton step's residual) must be the stated one within 5 %, and the unit the data's."""
    d, data, _ = fitted
    path = forge(d, "chi2", lambda doc: doc["fit"].__setitem__("chi2_dof", 0.5 * doc["fit"]["chi2_dof"]))
    with pytest.raises(RefusedResult, match=r"fit\.chi2_dof = .* is not its data's: they give"):
        C.certificate(path, data=data, html=d / "chi2.html", issue_date=ISSUE)

    def relabel(doc):
        doc["output_unit"] = "mV"
        for n in ("K_x", "K_y", "K_z"):
            doc["parameters"][n]["unit"] = "g/mV"
    path = forge(d, "mV", relabel)
    with pytest.raises(RefusedResult, match=r"output_unit = 'mV' is not the unit its data .* state, 'V'"):
        C.certificate(path, data=data, html=d / "mV.html", issue_date=ISSUE)


def test_a_misfit_forged_to_status_ok_is_refused_by_its_data(tmp_path):
    """A bias quadratic in temperature (0.1 ug/degC^2 on x, numpy) fitted with linear tempcos only:
    model_mismatch. Re-signed as ok with every gate passed and chi2/dof 1.0 (probe AF certified such a
    file, "chi2/dof 1.000, p = 0.5", its data giving 1.58): refused, the data's chi2/dof named."""
    data, _ = _campaign(tmp_path, 6, extra_bias=lambda k, t, T, G, dr: np.array([1e-7 * (np.mean(T) - 20.0) ** 2, 0.0, 0.0]))
    res = api.fit(read_bench_csv(data), effects=LINEAR)
    assert res.status == "model_mismatch", res.status
    res.save(tmp_path / "result.json")

    def ok(doc):
        doc["status"] = "ok"
        for o in doc["gates"]["outcomes"]:
            if o["passed"] is False:
                o["passed"] = True
        doc["fit"]["chi2_dof"] = 1.0
        doc["notes"] = [n for n in doc["notes"] if "gate" not in n]
    path = forge(tmp_path, "forged_ok", ok)
    with pytest.raises(RefusedResult, match=r"status ok, but its data \(.*data\.csv\) misfit the result's model: "
                                            r"chi2/dof \d"):
        C.certificate(path, data=data, html=tmp_path / "forged.html", issue_date=ISSUE)


def test_type_b_rows_edited_to_match_a_smaller_u_are_refused(tmp_path):
    """Probe AF re-signed a result fitted with the lab file with (a) a row's sensitivity set to 0 and u
    recomputed, (b) u halved with its Type A row and every Type B sensitivity scaled to match: both were
    certified with --data (u within 2 times the data's Type A u). Each source is now propagated again
    from the data and the lab file at the result's values, as the fit does: the honest result's rows are
    reproduced (issued), the edited ones refused naming the row. The independent bench, the example lab."""
    from triadcal.reports.certificate import EXAMPLE_LAB_TOML

    lab = tmp_path / "lab.toml"
    lab.write_text(EXAMPLE_LAB_TOML, encoding="utf-8")
    data, _ = _campaign(tmp_path, 7, sigma_position_arcsec=2.0)
    res = api.fit(read_bench_csv(data), effects=LINEAR, lab=lab)
    assert res.status == "ok", res.notes
    res.save(tmp_path / "result.json")
    assert C.certificate(tmp_path / "result.json", lab=lab, data=data, html=tmp_path / "ok.html",
                         issue_date=ISSUE).issued

    def zero_thermometers(doc):
        p = doc["parameters"]["K_z"]
        for r in p["budget"]:
            if r["source"] == "thermometers":
                r["sensitivity"], r["contribution"] = 0.0, 0.0
        p["u"] = float(np.sqrt(sum(r["contribution"] ** 2 for r in p["budget"])))
        p["U"] = 2.0 * p["u"]
    path = forge(tmp_path, "no_thermo", zero_thermometers)
    with pytest.raises(RefusedResult, match=r"parameters\.K_z's Type B row 'thermometers' states a sensitivity 0"):
        C.certificate(path, lab=lab, data=data, html=tmp_path / "t.html", issue_date=ISSUE)

    def halve(doc):
        p = doc["parameters"]["Ca_xy"]
        for r in p["budget"]:
            r["sensitivity"] *= 0.5
            r["contribution"] *= 0.5
        for k in ("u", "U", "u_type_a"):
            if isinstance(p.get(k), (int, float)):
                p[k] *= 0.5
    path = forge(tmp_path, "halved", halve)
    with pytest.raises(RefusedResult, match=r"parameters\.Ca_xy's Type B row '.*' states a sensitivity .*, 2 times "
                                            r"smaller than its data"):
        C.certificate(path, lab=lab, data=data, html=tmp_path / "h.html", issue_date=ISSUE)
