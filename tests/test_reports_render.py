"""Every HTML report rendered by a real browser, every PDF read back (issue 22, item 5).

The reports are produced through the CLI, as a user would: the certificate of the example
joint fit, the drift report of a comparison of two fitted campaigns, and the diagnosis page
of a campaign with a withheld effect and of a clean one. Headless Chromium (Debian package
``chromium``) loads each page through the DevTools protocol on a pipe (standard library
only): no console error, no uncaught exception, no failed resource, every image decoded,
and a screenshot. pypdf reads the PDFs back: every value of the JSON the report states is
in the text, rounded as the report rounds it. No report shows a Python repr.

The browser tests are skipped only when ``chromium`` is not installed (.ci/run installs it).
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from html.parser import HTMLParser
from pathlib import Path
from types import SimpleNamespace

import pypdf
import pytest

os.environ.setdefault("XDG_CACHE_HOME", "/tmp/xdg")

from triadcal.estimation.result import round_to_uncertainty  # noqa: E402


CHROMIUM = shutil.which("chromium")
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="the browser tests need headless Chromium: "
                                                             "`apt-get install chromium` (.ci/run installs it)")
ISSUE_DATE = "2026-11-22"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
HTML_REPORTS = ("certificate", "refusal", "drift", "diagnosis", "diagnosis_clean")
PDF_REPORTS = ("certificate", "refusal", "drift")

#: what a Python value printed with str()/repr() looks like in a report
PYTHON_REPR = re.compile(
    r"\b(?:True|False|None)\b"                 # bool / None
    r"|\[?\{'|\['|\(\('"                         # dict, list of dicts, list or tuple of str
    r"|\bnp\.\w+|\barray\(|\bdtype\b|<[\w.]+ object at 0x"
    r"|(?i:(?<![\w.])-?(?:nan|inf|infinity)\b)"  # non-finite numbers
    r"|\bp(?:_value|_holm)?\s*[=:]\s*0(?![.\d])"  # a p-value that underflowed, printed as 0
)


# -- producing the reports through the CLI ----------------------------------------------------------
def _cli(*args, cwd, status=0):
    env = dict(os.environ, MPLBACKEND="Agg", OMP_NUM_THREADS="1", XDG_CACHE_HOME=str(cwd / "xdg"))
    r = subprocess.run([sys.executable, "-m", "triadcal", *map(str, args)], cwd=cwd, env=env,
                       capture_output=True, text=True)
    assert r.returncode == status, f"triadcal {' '.join(map(str, args))}: {r.stderr}"
    return r


def _certificates(d):
    """Certificate of the example joint fit, with its data (residual and angle plots), and the
    refusal report (exit status 3) of the same fit, had its estimator not converged."""
    from triadcal.api import example_path

    _cli("fit", "--example", "--method", "joint", "--json", "result.json", cwd=d)
    _cli("certificate", "result.json", "--data", example_path(), "--html", "certificate.html",
         "--pdf", "certificate.pdf", "--date", ISSUE_DATE, cwd=d)
    doc = json.loads((d / "result.json").read_text())
    from triadcal.estimation.result import content_sha256

    nc = dict(doc, status="not_converged")
    nc["content_sha256"] = content_sha256(nc)          # as the fit would have written it
    (d / "not_converged.json").write_text(json.dumps(nc))
    _cli("certificate", "not_converged.json", "--html", "refusal.html", "--pdf", "refusal.pdf", "--date",
         ISSUE_DATE, cwd=d, status=3)


def _drift(d):
    """Drift report: two fitted campaigns of one unit, the second with Ca_xy moved by ~18 arcsec."""
    for i, extra in ((1, ()), (2, ("--set", "Ca_xy=330"))):
        _cli("simulate", "-o", f"s{i}.csv", "--seed", i, *extra, cwd=d)
        _cli("fit", f"s{i}.csv", "--json", f"s{i}.json", cwd=d)
    _cli("compare", "s1.json", "s2.json", "--tolerance", "10arcsec", "--json", "comparison.json", cwd=d)
    _cli("certificate", "comparison.json", "--html", "drift.html", "--pdf", "drift.pdf", "--date", ISSUE_DATE,
         cwd=d)


def _diagnosis(d, name, model):
    # five candidates (a mean term among them, the noise ones): the page is what is tested here,
    # and each candidate of the whole vocabulary costs its score and refit (test_diagnose.py)
    return _cli("diagnose", f"{name}.csv", "--model", ",".join(model), "--json", f"{name}.json",
         "--html", f"{name}.html", "--draws", "200",
         "--candidates", "bias_drift,scale_nonlinearity,tilt_drift,position_error,heavy_tails", cwd=d)


def make_reports(d: Path) -> dict:
    """Every report (HTML and PDF) made through the CLI in ``d``: the folder, the JSON each
    reports, and the stdout of each diagnosis (conftest.py's session fixture cli_reports, which
    other modules may read too: the diagnosis of the withheld bias drift is a CLI run of its own).

    The four chains of CLI runs (the certificates; the drift report's fits and comparison; each
    diagnosis) share no file, so they run at the same time, each in a thread that waits for its
    subprocesses: the same commands and files as one after the other, on the cores a serial test
    run leaves idle."""
    from triadcal.io.bench_csv import write_bench_csv

    # diagnosis pages: a campaign with the bias drift withheld from the model, and a clean one
    sys.path.insert(0, str(Path(__file__).parent))
    try:
        from test_diagnose import validation_campaign
    finally:
        sys.path.pop(0)
    models = {}
    for name, effect, seed in (("diagnosis", "bias_drift", 5), ("diagnosis_clean", "clean", 3)):
        campaign, models[name] = validation_campaign(effect, seed)
        write_bench_csv(campaign, d / f"{name}.csv")
    with ThreadPoolExecutor(max_workers=4) as pool:
        jobs = [pool.submit(_certificates, d), pool.submit(_drift, d)]
        diagnoses = {name: pool.submit(_diagnosis, d, name, model) for name, model in models.items()}
        for job in jobs:
            job.result()                                # re-raises a failed command's assertion
        stdout = {name: job.result().stdout for name, job in diagnoses.items()}
    return {"dir": d, "json": {"certificate": d / "result.json", "drift": d / "comparison.json",
                               "diagnosis": d / "diagnosis.json", "diagnosis_clean": d / "diagnosis_clean.json"},
            "stdout": stdout}


@pytest.fixture(scope="module")
def reports(cli_reports):
    """Paths of every report (HTML and PDF) and of the JSON each reports (make_reports)."""
    return cli_reports


# -- headless Chromium over the DevTools protocol (--remote-debugging-pipe: fd 3 in, fd 4 out) ------
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--window-size=1200,2000", "--remote-debugging-pipe")


class Chromium:
    """One headless Chromium driven over its DevTools pipe; messages are JSON ended by NUL."""

    def __init__(self):
        self.profile = tempfile.mkdtemp(prefix="triadcal-chromium-")
        cmd_r, self._cmd_w = os.pipe()
        self._out_r, out_w = os.pipe()

        def child():  # the browser reads commands on fd 3 and writes answers on fd 4
            a, b = os.dup(cmd_r), os.dup(out_w)      # both above 4, so that dup2 really copies them
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.log = open(Path(self.profile) / "stderr.log", "w")
        self.proc = subprocess.Popen([CHROMIUM, *CHROMIUM_FLAGS, f"--user-data-dir={self.profile}", "about:blank"],
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=self.log,
                                     preexec_fn=child, close_fds=False)
        os.close(cmd_r)
        os.close(out_w)
        self._buf, self._id, self.events = b"", 0, []

    def _message(self) -> dict:
        """The next DevTools message: waits for Chromium's answer (an event, not the clock); a
        Chromium that exits closes the pipe and fails the test with its log."""
        while b"\0" not in self._buf:
            chunk = os.read(self._out_r, 1 << 20)
            if not chunk:
                raise RuntimeError("chromium closed its DevTools pipe: "
                                   + (Path(self.profile) / "stderr.log").read_text()[-2000:])
            self._buf += chunk
        msg, self._buf = self._buf.split(b"\0", 1)
        return json.loads(msg)

    def send(self, method: str, session: str | None = None, **params) -> dict:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = session
        os.write(self._cmd_w, json.dumps(msg).encode() + b"\0")
        while True:
            m = self._message()
            if m.get("id") == self._id:
                if "error" in m:
                    raise RuntimeError(f"{method}: {m['error']}")
                return m.get("result", {})
            self.events.append(m)

    def wait_for(self, method: str, session: str | None = None) -> dict:
        """The next event ``method`` (of the page attached as ``session``, when given)."""
        def wanted(m):
            return m.get("method") == method and (session is None or m.get("sessionId") == session)

        for i, m in enumerate(self.events):
            if wanted(m):
                return self.events.pop(i)
        while True:
            m = self._message()
            if wanted(m):
                return m
            self.events.append(m)

    def close(self) -> None:
        try:
            self.send("Browser.close")
        except Exception:
            pass
        try:
            self.proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for fd in (self._cmd_w, self._out_r):
            try:
                os.close(fd)
            except OSError:
                pass
        self.log.close()
        shutil.rmtree(self.profile, ignore_errors=True)


def console_errors(events) -> list:
    """Errors a developer console would show: console.error/assert, uncaught exceptions, and the
    browser's own error entries (a resource that failed to load, a blocked request, ...)."""
    errors = []
    for m in events:
        p = m.get("params", {})
        if m.get("method") == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            errors.append("console." + p["type"] + ": " + " ".join(
                str(a.get("value", a.get("description", ""))) for a in p.get("args", ())))
        elif m.get("method") == "Runtime.exceptionThrown":
            x = p.get("exceptionDetails", {})
            errors.append("uncaught: " + str(x.get("exception", {}).get("description") or x.get("text")))
        elif m.get("method") == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            errors.append(f"{p['entry'].get('source')}: {p['entry'].get('text')} {p['entry'].get('url', '')}".strip())
    return errors


def render(html_path: Path, screenshot: Path, browser: Chromium) -> dict:
    """Load a page in a new tab of headless Chromium: its console errors, its images, its text; a
    screenshot. Each page has its own tab (target) and session: only that session's events count."""
    target = browser.send("Target.createTarget", url="about:blank")["targetId"]
    try:
        s = browser.send("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            browser.send(f"{domain}.enable", session=s)
        browser.events.clear()
        browser.send("Page.navigate", session=s, url=html_path.resolve().as_uri())
        browser.wait_for("Page.loadEventFired", session=s)

        def js(expression):
            return browser.send("Runtime.evaluate", session=s, expression=expression,
                                returnByValue=True)["result"].get("value")

        images = js("Array.from(document.images).map(i => [i.alt, i.complete && i.naturalWidth > 0])")
        text = js("document.body.innerText")
        png = base64.b64decode(browser.send("Page.captureScreenshot", session=s, format="png")["data"])
        screenshot.write_bytes(png)
        events = [m for m in browser.events if m.get("sessionId") == s]
        return {"errors": console_errors(events), "images": images, "text": text, "png": screenshot}
    finally:
        browser.send("Target.closeTarget", targetId=target)
        browser.events.clear()


@pytest.fixture(scope="module")
def browser():
    """One headless Chromium for the module (its start and stop cost more than a page); each page
    is loaded in its own tab (render)."""
    if CHROMIUM is None:
        pytest.skip("headless Chromium is not installed (`apt-get install chromium`)")
    b = Chromium()
    yield b
    b.close()


@pytest.fixture(scope="module")
def rendered(reports, browser):
    shots = reports["dir"] / "screenshots"
    shots.mkdir()
    return {name: render(reports["dir"] / f"{name}.html", shots / f"{name}.png", browser) for name in HTML_REPORTS}


# -- reading the reports back without a browser -----------------------------------------------------
class _Text(HTMLParser):
    """The text a reader sees (no <style>, <script> or attribute values)."""

    def __init__(self):
        super().__init__()
        self.parts, self._skip = [], 0

    def handle_starttag(self, tag, attrs):
        self._skip += tag in ("style", "script")
        if tag in ("td", "th", "p", "li", "div", "br", "tr", "h1", "h2", "h3", "figcaption"):
            self.parts.append("\n")

    def handle_endtag(self, tag):
        self._skip -= tag in ("style", "script")

    def handle_data(self, data):
        if not self._skip:
            self.parts.append(data)


def html_text(path: Path) -> str:
    p = _Text()
    p.feed(path.read_text(encoding="utf-8"))
    return "".join(p.parts)


def pdf_text(path: Path, layout: bool = False) -> str:
    reader = pypdf.PdfReader(path)
    return "\n".join(p.extract_text(extraction_mode="layout" if layout else "plain") for p in reader.pages)


def pdf_row(lines, name) -> list:
    """The tokens of the PDF table row that starts with ``name`` (layout text)."""
    rows = [ln.split() for ln in lines if ln.split()[:1] == [name]]
    assert rows, f"{name}: no row in the PDF text"
    return rows[0]


def png_size(png: bytes) -> tuple[int, int]:
    assert png[:8] == PNG_MAGIC and png[12:16] == b"IHDR", "not a PNG"
    return struct.unpack(">II", png[16:24])


def repr_hits(text: str) -> list:
    return [text[max(0, m.start() - 50):m.end() + 30].replace("\n", " | ") for m in PYTHON_REPR.finditer(text)]


# -- the browser -------------------------------------------------------------------------------------
@needs_chromium
@pytest.mark.parametrize("name", HTML_REPORTS)
def test_report_loads_in_chromium_without_console_errors_and_renders(rendered, name):
    page = rendered[name]
    assert page["errors"] == [], f"{name}.html: console errors {page['errors']}"
    if name != "refusal":                           # the refusal report has no plot
        assert page["images"], f"{name}.html has no image"
    broken = [alt for alt, ok in page["images"] if not ok]
    assert not broken, f"{name}.html: images that did not decode: {broken}"
    assert len(page["text"]) > 500, f"{name}.html: the browser shows almost no text"
    png = page["png"].read_bytes()
    width, height = png_size(png)
    assert width >= 1000 and height >= 1000, (name, width, height)
    assert len(png) > 50_000, f"{name}: screenshot of {len(png)} bytes: a blank page?"


@needs_chromium
@pytest.mark.parametrize("name", HTML_REPORTS)
def test_the_browser_shows_no_python_repr(rendered, name, request):
    hits = repr_hits(rendered[name]["text"])
    assert not hits, f"{name}.html shows Python reprs: {hits}"


@needs_chromium
def test_the_browser_helper_sees_console_errors_failed_resources_and_exceptions(tmp_path, browser):
    """The check above is only worth something if it fails on a broken page."""
    page = tmp_path / "broken.html"
    page.write_text("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>x</title></head><body>"
                    "<p>text</p><img alt='gone' src='missing.png'>"
                    "<script>console.log('harmless log line'); console.error('boom'); undefinedFunction();</script>"
                    "</body></html>", encoding="utf-8")
    out = render(page, tmp_path / "broken.png", browser)
    joined = " ".join(out["errors"])
    assert len(out["errors"]) == 3, out["errors"]
    assert "boom" in joined and "undefinedFunction" in joined and "missing.png" in joined
    assert "harmless" not in joined
    assert out["images"] == [["gone", False]]
    assert png_size(out["png"].read_bytes())[0] >= 1000


# -- the PDFs: every value of the JSON, as the report rounds it --------------------------------------
def test_certificate_pdf_and_html_hold_every_parameter_of_the_json(reports):
    """Value and U = 2u of every parameter, rounded as the certificate rounds them (U to two
    significant digits, the value to the same decimal place: round_to_uncertainty)."""
    doc = json.loads(reports["json"]["certificate"].read_text())
    assert doc["status"] == "ok" and len(doc["parameters"]) >= 30
    lines = pdf_text(reports["dir"] / "certificate.pdf", layout=True).splitlines()
    html = (reports["dir"] / "certificate.html").read_text(encoding="utf-8")
    for name, p in doc["parameters"].items():
        value, U = round_to_uncertainty(p["value"], 2.0 * p["u"])
        assert abs(float(value) - p["value"]) <= float(U) / 2 + 1e-15, name
        tokens = pdf_row(lines, name)
        assert value in tokens and U in tokens, (name, tokens, value, U)
        row = re.search(rf"<tr data-param='{re.escape(name)}'>(.*?)</tr>", html)
        assert row, f"{name}: no row in the HTML"
        assert re.findall(r"<td class='num'>(.*?)</td>", row.group(1)) == [value, U], name


def test_certificate_pdf_states_the_fit_and_conditions_of_the_json(reports):
    doc = json.loads(reports["json"]["certificate"].read_text())
    text = pdf_text(reports["dir"] / "certificate.pdf")
    fit = doc["fit"]
    lo, hi = doc["temperature_range_C"]
    for needed in (doc["unit"], f"{fit['chi2_dof']:.3g}", f"{fit['n_obs']} observations",
                   f"{fit['n_params']} parameters", f"p = {fit['gap_p_value']:.2g}",
                   f"{lo:.1f} °C to {hi:.1f} °C", f"{doc['reference_temperature_C']:g} °C",
                   f"{doc['local_g_m_s2']:g}", "ok", "joint"):
        assert needed in text, f"{needed!r} not in the certificate's PDF text"


def test_drift_pdf_and_html_hold_every_drift_of_the_json(reports):
    """Drift and U rounded as on a certificate; E_n to 2 decimals; P(|d| > T) to 4 significant
    digits; the tolerance with %g; the verdict: as render_drift_pdf formats them."""
    doc = json.loads(reports["json"]["drift"].read_text())
    assert doc["overall"] == "fail" and len(doc["parameters"]) >= 30
    lines = pdf_text(reports["dir"] / "drift.pdf", layout=True).splitlines()
    html = (reports["dir"] / "drift.html").read_text(encoding="utf-8")
    assert "FAIL" in pdf_text(reports["dir"] / "drift.pdf") and "FAIL" in html
    for name, p in doc["parameters"].items():
        U = p["U"] if p.get("U") is not None else 2.0 * p["u"]
        d, Us = round_to_uncertainty(p["drift"], U)
        verdict = p["verdict"] if p.get("judged", True) else "not judged"
        expected = [d, Us, f"{p['En']:.2f}"]
        if p.get("p_exceeds") is not None:
            expected.append(f"{p['p_exceeds']:.4g}")
        if p.get("tolerance") is not None:
            expected.append(f"{p['tolerance']:g}")
        tokens = pdf_row(lines, name)
        missing = [x for x in expected + verdict.split()[:1] if x not in tokens]
        assert not missing, (name, missing, tokens)
        row = re.search(rf"<tr data-param='{re.escape(name)}'>(.*?)</tr>", html)
        assert row, f"{name}: no row in the HTML"
        cells = re.findall(r"<td[^>]*>(.*?)</td>", row.group(1))
        assert not [x for x in expected + [verdict] if x not in cells], (name, cells, expected)


def test_drift_report_states_the_joint_test_and_the_bench_check_of_the_json(reports):
    doc = json.loads(reports["json"]["drift"].read_text())
    assert doc["bench_check"] and doc["joint"]
    for text in (pdf_text(reports["dir"] / "drift.pdf"), html_text(reports["dir"] / "drift.html")):
        assert f"{doc['joint']['D2']:.4g}" in text
        for name in doc["joint"]["names"]:
            assert name in text.split("Decision rule")[0], f"joint test: angle {name} not named"
        for name, b in doc["bench_check"].items():
            assert name in text, f"bench check {name} not in the report"
            assert f"{b['drift']:+.2f}" in text or f"{b['drift']:.2f}" in text, (name, b)


def test_drift_report_tells_significance_only_verdicts_from_judged_ones(reports):
    doc = json.loads(reports["json"]["drift"].read_text())
    unjudged = {n: p for n, p in doc["parameters"].items() if not p["judged"]}
    assert unjudged and any(p["verdict"] == "fail" for p in unjudged.values())
    lines = pdf_text(reports["dir"] / "drift.pdf", layout=True).splitlines()
    html = (reports["dir"] / "drift.html").read_text(encoding="utf-8")
    for name, p in unjudged.items():
        assert pdf_row(lines, name)[-1] != p["verdict"], (name, pdf_row(lines, name))
        cells = re.findall(r"<td[^>]*>(.*?)</td>", re.search(rf"<tr data-param='{name}'>(.*?)</tr>", html).group(1))
        assert cells[-1] != p["verdict"], (name, cells)
    # separate columns: a significant change, and within tolerance; the overall verdict says why
    # an unjudged significant change does not make it fail
    ca = re.findall(r"<td[^>]*>(.*?)</td>", re.search(r"<tr data-param='Ca_xy'>(.*?)</tr>", html).group(1))
    assert "yes" in ca and "no" in ca       # Ca_xy moved by ~18.6" > T = 10": significant, not within
    changed = [n for n, p in unjudged.items() if p["significant"]]
    text = html_text(reports["dir"] / "drift.html")
    assert "Significant change" in text and "Within tolerance" in text
    for n in changed:
        assert f"{n}" in text.split("Identification")[0] and "no tolerance" in text.split("Identification")[0]


# -- no Python repr anywhere -------------------------------------------------------------------------
@pytest.mark.parametrize("name,kind", [(n, "html") for n in HTML_REPORTS] + [(n, "pdf") for n in PDF_REPORTS])
def test_no_python_repr_in_any_report(reports, name, kind, request):
    path = reports["dir"] / f"{name}.{kind}"
    text = html_text(path) if kind == "html" else pdf_text(path)
    hits = repr_hits(text)
    assert not hits, f"{path.name} shows Python reprs: {hits}"


def test_the_repr_pattern_catches_what_it_should_and_not_prose():
    for bad in ("significant: True", "verdict: None", "{'a': 1}", "[{'a': 1}]", "np.float64(1.5)", "u = nan",
                "-inf", "p = 0", "p_value: 0", "['x', 'y']", "<triadcal.X object at 0x7f>"):
        assert PYTHON_REPR.search(bad), bad
    for fine in ("p = 0.03", "p = 1e-202", "none of the candidates", "information", "infinite", "nano",
                 "significant: yes", "Ca_xy = 312.04", "p < 1e-300"):
        assert not PYTHON_REPR.search(fine), fine


# -- the diagnosis page --------------------------------------------------------------------------------
def test_diagnosis_page_states_the_verdict_and_gap_of_its_json(reports):
    for name in ("diagnosis", "diagnosis_clean"):
        doc = json.loads(reports["json"][name].read_text())
        text = html_text(reports["dir"] / f"{name}.html")
        g = doc["gap"]
        assert f"chi2/dof = {g['chi2_dof']:.3g} ({g['dof']} dof)" in text, name
        assert f"significant: {'yes' if g['significant'] else 'no'}" in text, name
        effect = doc["verdict"]["effect"]
        if effect is None:
            assert "no missing effect named" in text and doc["verdict"]["reason"] in text
        else:
            assert effect == "bias_drift" and f"\n{effect} — score p = " in text
        for c in doc["candidates"]:
            assert c["effect"] in text
        listed = doc["where"][:25]                      # the page lists the 25 with the smallest p
        for s in listed:
            assert s["slice"] in text, s["slice"]
        if len(doc["where"]) > len(listed):
            assert f"{len(doc['where'])} slices disagree significantly; the 25 with the smallest p" in text


def test_diagnosis_p_values_that_underflow_are_not_printed_as_zero():
    from triadcal.reports.diagnosis import _p, _ppc_p

    assert _p(0.0, -412.3) == "5.01e-413" and _p(0.0) == "< 1e-300" and _p(3.2e-5) == "3.2e-05"
    assert _p(None) == "not computed" and _ppc_p(0.0) == "no draw as extreme" and _ppc_p(0.25) == "0.25"
    # after its name: "LR p < 1e-300", never "LR p = < 1e-300" or "p = 0" (the page and the JSON's evidence)
    from triadcal.judgement.diagnose.results import _p_is as evidence_p
    from triadcal.reports.diagnosis import _p_is

    assert _p_is(0.0) == "< 1e-300" and _p_is(0.0, -412.3) == "= 5.01e-413" and _p_is(0.003) == "= 0.003"
    assert evidence_p(0.0) == "< 1e-300" and evidence_p(0.003) == "= 0.003" and evidence_p(None) == "not computed"


def test_diagnosis_slice_chart_has_both_axis_labels():
    from triadcal.judgement.diagnose import SliceTest
    from triadcal.reports.diagnosis import slices_figure

    slices = [SliceTest(f"setpoint={t}C", "setpoint", "z", "offset", 12, 4.0 + t / 10, 1e-4, 1e-3, -4.0 - t / 10,
                        3.0) for t in (20, 35, 55)]
    fig = slices_figure(SimpleNamespace(slices=slices, alpha=0.01))
    ax = fig.axes[0]
    assert ax.get_xlabel() and ax.get_ylabel(), (ax.get_xlabel(), ax.get_ylabel())
