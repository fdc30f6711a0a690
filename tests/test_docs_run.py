"""Docs that run (issue 22, item 3).

Every fenced ```sh / ```bash / ```console block of README.md, CONTRIBUTING.md, docs/*.md and
docs/spec/*.md is extracted and each ``triadcal ...`` command in it is run, as a subprocess
with the virtualenv's ``triadcal``, in a temporary directory, and must exit with the code
the doc implies (0 unless listed in EXPECTED_EXIT). The numbers the docs quote next to a
command are checked against that command's output (NUMBERS). No link or path in the docs
points outside the repository, and every relative link target exists.

How a doc line becomes a command (the synopsis notation of the docs):

- lines that start with whitespace (or follow a trailing ``\\``) continue the command;
  ``# comments`` and a ``$`` prompt are dropped; ``a && b`` runs the triadcal part(s);
- ``[optional groups]`` are dropped (nested too), so the command runs in its minimal form,
  plus the options EXTRA_ARGS adds for commands whose minimal form does not fit the
  shipped input; a bare ``...`` (and a trailing ``,...``) is dropped;
- ``> FILE`` writes the command's stdout to FILE;
- ``--no-progress`` is added where the subcommand accepts it (NO_PROGRESS);
- each block runs in its own directory: an input named in INPUTS that no earlier command
  of the same block wrote is put there first (copied from examples/data/ or made by the
  command INPUTS gives, which the docs show before the command that uses the file);
  ``examples/...`` paths are the repository's files;
- long statistical commands run with a reduced count (REDUCED), and every block that holds
  one, or a capture (15 s and more of emulated hardware), is marked slow;
- a server the doc runs in another terminal (`triadcal emulate DIR`, SERVERS) is started in
  the background and stopped at the end of its block;
- commands that need real hardware or are not triadcal commands are in NOT_RUN, each with
  its reason; a shell command in a doc that is neither run nor listed fails the test.
"""
from __future__ import annotations

import atexit
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "examples" / "data"
DOCS = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").glob("*.md")),
        *sorted((ROOT / "docs" / "spec").glob("*.md"))]
SHELL_LANGS = {"sh", "bash", "console", "shell"}


def _triadcal_exe() -> str:
    exe = Path(sys.executable).with_name("triadcal")
    return str(exe) if exe.exists() else shutil.which("triadcal") or "triadcal"


TRIADCAL = _triadcal_exe()

# -- the mapping table: placeholder -> where the file comes from ---------------------------
# ("copy", path): a file shipped in examples/data/ (examples/data/README.md says how each was
#   made; licenses next to them).
# ("run", argv, output): made by that triadcal command (the docs show it before the command
#   that uses the file: `triadcal fit DATA.csv --json result.json`, `triadcal compare
#   BEFORE.json AFTER.json --json OUT.json`); its inputs are again resolved by this table.
_FIT_BEFORE = ("run", ["fit", "examples/data/campaign.csv", "--method", "joint", "--json", "{out}"])
# a certificate needs a result fitted with the lab's errors (docs/lab.md)
_FIT_LAB = ("run", ["fit", "examples/data/campaign.csv", "--method", "joint", "--lab", "examples/data/lab.toml",
                    "--json", "{out}"])
_FIT_AFTER = ("run", ["fit", "examples/data/campaign_after.csv", "--method", "joint", "--json", "{out}"])
_COMPARE = ("run", ["compare", "before.json", "after.json", "--tolerance", "30arcsec", "--json", "{out}"])
INPUTS = {
    # bench CSV v1 campaigns: `triadcal simulate -o campaign.csv --truth truth.json --seed 1`
    "DATA.csv": ("copy", DATA / "campaign.csv"),
    "campaign.csv": ("copy", DATA / "campaign.csv"),
    # raw recording: mikoff/imu-calib imu0 (MIT), accelerometer columns in m/s2
    "RECORDING.csv": ("copy", DATA / "mikoff_imu0.csv"),
    # the paper's Table 3 (as tests/test_compare.py writes it)
    "table3.csv": ("copy", DATA / "table3.csv"),
    # `triadcal certificate --lab-example > lab.toml`
    "lab.toml": ("copy", DATA / "lab.toml"),
    # calibration results (results-json v1): the unit before and after (campaign_after.csv:
    # same simulated unit, seed 2), and every exposure of a sequence
    "result.json": _FIT_LAB, "before.json": _FIT_BEFORE, "BEFORE.json": _FIT_BEFORE,
    "initial.json": _FIT_BEFORE,
    "after.json": _FIT_AFTER, "AFTER.json": _FIT_AFTER, "s20g.json": _FIT_AFTER,
    "s40g.json": _FIT_AFTER, "s20.json": _FIT_AFTER, "s40.json": _FIT_AFTER, "v20.json": _FIT_AFTER,
    # comparisons (compare --json), which `certificate` turns into a drift report
    "drift.json": _COMPARE, "comparison.json": _COMPARE,
    # a digital unit's campaign, its outputs rounded to an LSB of 2.5 sample sigmas (docs/model.md)
    "DIGITAL.csv": ("run", ["simulate", "-o", "{out}", "--effects",
                            "bench_tilt,angle_tempco,scale_tempco,bias_tempco,quantisation", "--seed", "1"]),
}
# values that stand for a number in a synopsis
VALUES = {"HZ": "100"}
# options the test adds to a command whose minimal form does not fit the shipped input,
# keyed by (doc, the command's first words); chosen among the command's [optional] ones
EXTRA_ARGS = {
    ("docs/raw.md", "triadcal fit-raw RECORDING.csv"): ["--unit", "m/s2", "--poses", "unknown"],
}
# subcommands with a --no-progress option (their --help lists it)
NO_PROGRESS = {"fit-raw", "sample", "validate", "capture", "batch"}
# long statistical commands: the option set to a reduced count (the block becomes slow)
REDUCED = {
    "validate": {"--campaigns": "4"},
    # three setpoints take minutes even on the emulator's fast clock; one takes ~25 s
    "capture": {"--setpoints": "20"},
    "validate-diagnosis": {"--seeds": "1", "--effects": "clean"},
}
# an option whose presence leaves the command as written (a ramp capture runs its plan's program: no
# --setpoints to reduce; its block is slow anyway)
NOT_REDUCED_WITH = {"capture": "--ramp"}
# and commands of 10 s and more (a thermal cycle's ten forms x folds, a dask cluster's start, a
# plan's search over hundreds of designs): run with the slow tests, to keep the quick ones quick;
# also the blocks that issue certificates (HTML and PDF after fits of the inputs) and compare
# calibrations (fits of both), 15-30 s each in CI: their commands are tested quick by
# tests/test_certificate.py and tests/test_compare.py (CI-10: the quick suite took 656 s)
SLOW_SUBCOMMANDS = {"validate", "validate-diagnosis", "capture", "emulate", "thermal-cycle", "batch", "plan",
                    "certificate", "compare"}
# commands that run emulated hardware or a dask cluster on the wall clock (tests/conftest.py)
WALLCLOCK_SUBCOMMANDS = {"capture", "emulate", "batch"}
# exit codes other than 0 that a doc implies, keyed by (doc, command's first words)
EXPECTED_EXIT: dict = {}
# the exit code of a command REDUCED here when the reduction itself changes it: 4 SBC campaigns
# cannot make a conclusive verdict, and validate exits 3 then (docs/posterior.md, "The verdict")
REDUCED_EXIT = {"validate": 3}
# commands not run, by their first words, each with the reason
NOT_RUN = {
    "python3 -m venv": "installs the package into a fresh virtualenv (what CI's clean-clone job does)",
    ".venv/bin/pip install": "installs the package (and its test extras) into that virtualenv",
    ".venv/bin/python -m pytest": "the test suite itself",
    ".venv/bin/python benchmarks/": "benchmarks time against alternatives (minutes), not doc behaviour",
    "bash .ci/run": "what CI runs on a clean clone (the whole suite)",
    "dask scheduler": "starts a Dask scheduler that serves until stopped (docs/fleet.md, on a cluster)",
    "OMP_NUM_THREADS=1 dask worker": "starts Dask workers on a cluster's machines (docs/fleet.md)",
    "triadcal batch data/*.csv --out fleet --scheduler": "needs a running Dask scheduler at the address; "
                                            "the same batch runs on a LocalCluster (docs/fleet.md)",
    "duplicates --change": "a developer tool of the environment, not part of triadcal",
    "triadcal capture --config examples/data/ports.toml": "needs the real instruments on the serial ports of "
                                            "examples/data/ports.toml; the same capture runs "
                                            "against the emulator (capture --emulate, hardware.md)",
    "triadcal capture --instruments examples/data/instruments.toml": "needs the real instruments on the serial "
                                            "ports of examples/data/instruments.toml; the same capture runs "
                                            "against `triadcal emulate` (capture --instruments, hardware.md)",
}
# commands that serve until stopped (the doc runs them in another terminal): started in the
# background, the block goes on once the file they announce exists, stopped at its end
SERVERS = {"emulate": "{0}/ports.toml"}


# -- extraction ----------------------------------------------------------------------------

def shell_blocks(doc: Path):
    """(line number, language, text) of every fenced shell block of a markdown file."""
    text = doc.read_text(encoding="utf-8")
    out = []
    for m in re.finditer(r"^```([\w-]*)[^\n]*\n(.*?)^```", text, re.S | re.M):
        if m.group(1) in SHELL_LANGS:
            out.append((text[:m.start()].count("\n") + 1, m.group(1), m.group(2)))
    return out


def _drop_optional(line: str) -> str:
    prev = None
    while prev != line:
        prev, line = line, re.sub(r"\[[^\[\]]*\]", " ", line)
    return line


def commands(block: str):
    """The commands of a block: lists of words, optional groups and `...` dropped."""
    lines = []
    for raw in block.splitlines():
        if not raw.strip():
            continue
        s = raw.rstrip()
        if lines and (lines[-1].endswith("\\") or raw[:1].isspace()):
            lines[-1] = lines[-1].rstrip("\\") + " " + s.strip()
        else:
            lines.append(s.strip())
    cmds = []
    for line in lines:
        line = re.sub(r"^\$\s+", "", line)
        words = shlex.split(_drop_optional(line), comments=True)
        words = [w[:-4] if w.endswith(",...") else w for w in words if w != "..."]
        cmd = []
        for w in words + ["&&"]:
            if w == "&&":
                if cmd:
                    cmds.append(cmd)
                cmd = []
            else:
                cmd.append(w)
    return cmds


def _first_words(cmd, n=None):
    return " ".join(cmd[:n] if n else cmd)


def _not_run_reason(cmd):
    line = _first_words(cmd)
    for key, reason in NOT_RUN.items():
        if line.startswith(key):
            return reason
    return None


def _is_triadcal(cmd):
    return Path(cmd[0]).name == "triadcal"


def _rel(doc):
    return doc.relative_to(ROOT).as_posix()


def _blocks():
    items = []
    for doc in DOCS:
        for line, lang, text in shell_blocks(doc):
            cmds = commands(text)
            run = [c for c in cmds if _is_triadcal(c) and _not_run_reason(c) is None]
            slow = any(len(c) > 1 and c[1] in SLOW_SUBCOMMANDS for c in run)
            marks = [pytest.mark.slow] if slow else []
            if any(len(c) > 1 and c[1] in WALLCLOCK_SUBCOMMANDS for c in run):
                marks.append(pytest.mark.wallclock)
            items.append(pytest.param(_rel(doc), line, cmds, marks=marks, id=f"{_rel(doc)}:{line}"))
    return items


BLOCKS = _blocks()


# -- running -------------------------------------------------------------------------------

def _env(tmp):
    env = dict(os.environ, MPLBACKEND="Agg", XDG_CACHE_HOME=os.environ.get("XDG_CACHE_HOME") or str(tmp / "xdg"))
    env.pop("TRIADCAL_DEBUG", None)
    return env


def _run(argv, cwd, stdout_to=None):
    p = subprocess.run([TRIADCAL, *argv], cwd=cwd, env=_env(Path(cwd)), capture_output=True, text=True)
    if stdout_to is not None:
        (Path(cwd) / stdout_to).write_text(p.stdout, encoding="utf-8")
    return p


def _materialise(name, cwd):
    """Put the input ``name`` into ``cwd`` from the mapping table (copy or run)."""
    kind, *rest = INPUTS[name]
    target = Path(cwd) / name
    target.parent.mkdir(parents=True, exist_ok=True)
    if kind == "copy":
        shutil.copyfile(rest[0], target)
        return
    key = tuple(rest[0])
    if key not in _MADE:  # made once per test session, then copied (the same command, the same file)
        argv = _prepare(rest[0], cwd, out=name)
        p = _run(argv, cwd)
        assert p.returncode == 0, f"making {name} with `triadcal {' '.join(argv)}` failed:\n{p.stderr[-2000:]}"
        _MADE[key] = Path(tempfile.mkdtemp(prefix="triadcal-docs-")) / "made"
        atexit.register(shutil.rmtree, _MADE[key].parent, True)
        shutil.copyfile(target, _MADE[key])
    else:
        shutil.copyfile(_MADE[key], target)


_MADE: dict = {}


def _prepare(argv, cwd, out=None):
    """Words -> argv: {out}, repository paths, values, inputs put in place."""
    res = []
    for w in argv:
        if w == "{out}":
            res.append(out)
            continue
        if w.startswith("examples/") and (ROOT / w).exists():
            w = str(ROOT / w)
        w = VALUES.get(w, w)
        if w in INPUTS and not (Path(cwd) / w).exists():
            _materialise(w, cwd)
        res.append(w)
    return res


def _reduce(argv):
    sub = argv[0]
    reduced = {} if NOT_REDUCED_WITH.get(sub) in argv else REDUCED.get(sub, {})
    for opt, value in reduced.items():
        if opt in argv:
            argv[argv.index(opt) + 1] = value
        else:
            argv += [opt, value]
    if sub in NO_PROGRESS and "--no-progress" not in argv:
        argv.append("--no-progress")
    return argv


def run_doc_command(doc, cmd, cwd):
    """Run one doc command (words, starting with triadcal) in cwd; return (argv, process)."""
    words = list(cmd[1:])
    stdout_to = None
    if ">" in words:
        i = words.index(">")
        stdout_to = words[i + 1]
        del words[i:i + 2]
    for (d, head), extra in EXTRA_ARGS.items():
        if d == doc and _first_words(["triadcal", *words]).startswith(head):
            words += extra
    argv = _reduce(_prepare(words, cwd))
    return argv, _run(argv, cwd, stdout_to=stdout_to)


def _start_server(cmd, cwd):
    """Start a server command and wait for the event that it is ready (the file it writes), not
    for the clock: a server that stops first fails the test with its log."""
    argv = _prepare(list(cmd[1:]), cwd)
    log = open(Path(cwd) / f"{argv[0]}.log", "w", encoding="utf-8")
    proc = subprocess.Popen([TRIADCAL, *argv], cwd=cwd, env=_env(Path(cwd)), stdout=log, stderr=subprocess.STDOUT)
    ready = Path(cwd) / SERVERS[argv[0]].format(*argv[1:])
    while not ready.exists():
        assert proc.poll() is None, f"`triadcal {' '.join(argv)}` stopped: {(Path(cwd) / log.name).read_text()}"
        time.sleep(0.2)
    return proc, log


@pytest.mark.parametrize("doc,line,cmds", BLOCKS)
def test_doc_block_runs(doc, line, cmds, tmp_path):
    servers = []
    try:
        _run_block(doc, line, cmds, tmp_path, servers)
    finally:
        for proc, log in servers:
            proc.terminate()
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            log.close()


def _run_block(doc, line, cmds, tmp_path, servers):
    for cmd in cmds:
        if _not_run_reason(cmd) is not None:
            continue
        assert _is_triadcal(cmd), (f"{doc}:{line}: `{' '.join(cmd)}` is neither a triadcal command "
                                   "nor in NOT_RUN (add it there with its reason)")
        if cmd[1] in SERVERS:
            servers.append(_start_server(cmd, tmp_path))
            continue
        argv, p = run_doc_command(doc, cmd, tmp_path)
        want = EXPECTED_EXIT.get((doc, _first_words(cmd)), 0)
        if cmd[1] in REDUCED_EXIT and any(str(a) in REDUCED.get(cmd[1], {}) for a in argv):
            want = REDUCED_EXIT[cmd[1]]
        assert p.returncode == want, (
            f"{doc}:{line}: `triadcal {' '.join(argv)}` exited {p.returncode}, the doc implies {want}"
            f"\nstdout:\n{p.stdout[-3000:]}\nstderr:\n{p.stderr[-3000:]}")
        assert "Traceback" not in p.stderr


def test_every_doc_has_its_shell_blocks_found():
    """The synopsis blocks are tagged as shell, so the test above sees them."""
    found = {(b.values[0]) for b in BLOCKS}
    for doc in ("README.md", "docs/budget.md", "docs/certificate.md", "docs/compare.md",
                "docs/diagnosis.md", "docs/hardware.md", "docs/joint.md", "docs/posterior.md",
                "docs/raw.md"):
        assert doc in found, f"{doc}: no ```sh block found"
    untagged = []
    for doc in DOCS:
        text = doc.read_text(encoding="utf-8")
        for m in re.finditer(r"^```\n(.*?)^```", text, re.S | re.M):
            if re.search(r"^\s*(\$\s+)?triadcal\s", m.group(1), re.M):
                untagged.append(f"{_rel(doc)}:{text[:m.start()].count(chr(10)) + 1}")
    assert not untagged, f"blocks of triadcal commands without ```sh: {untagged}"


def test_not_run_entries_are_still_in_the_docs():
    lines = [_first_words(c) for b in BLOCKS for c in b.values[2]]
    for key in NOT_RUN:
        assert any(line.startswith(key) for line in lines), f"NOT_RUN entry no doc uses any more: {key}"


def test_mapped_example_files_ship_with_the_repository():
    for name, (kind, *rest) in INPUTS.items():
        if kind == "copy":
            assert rest[0].is_file(), f"{name} -> {rest[0]} missing"
            assert ROOT in rest[0].resolve().parents
    assert (DATA / "README.md").is_file()
    assert (DATA / "LICENSE-mikoff-imu-calib.txt").is_file()


# -- numbers the docs quote ----------------------------------------------------------------

def _budget_eq4(d):
    return d["tables"][0]


def _thermal(d, name):
    return next(t for t in d["tables"] if f", {name} (" in t["title"])["total"]


def _t3_fails(d):
    return sorted((s["label"], n, p["drift"]) for s in d["steps"] for n, p in s["parameters"].items()
                  if p["verdict"] == "fail")


# (doc, text quoted in the doc, argv (the doc's command with --json), value from the JSON,
#  quoted value, tolerance, where the tolerance comes from)
HALF_LAST = "half a unit of the last digit quoted (the doc rounds the output)"
NUMBERS = [
    ("README.md", "(11.53″, noise term n = 2.06″", ["budget", "--json", "o.json"],
     lambda d: _budget_eq4(d)["total"], 11.53, 0.005, HALF_LAST),
    ("README.md", "(11.53″, noise term n = 2.06″", ["budget", "--json", "o.json"],
     lambda d: _budget_eq4(d)["noise_term_arcsec"], 2.06, 0.005, HALF_LAST),
    ("README.md", "1.44″ and 2.70″ for the paper's bench", ["budget", "--json", "o.json"],
     lambda d: _budget_eq4(d)["classical_sd_arcsec"]["Ca_xy"], 1.44, 0.005, HALF_LAST),
    ("README.md", "1.44″ and 2.70″ for the paper's bench", ["budget", "--json", "o.json"],
     lambda d: _budget_eq4(d)["classical_sd_arcsec"]["Ca_yz"], 2.70, 0.005, HALF_LAST),
    ("docs/budget.md", "noise term 2.063″, **σ_eff = 11.533″**", ["budget", "--json", "o.json"],
     lambda d: _budget_eq4(d)["total"], 11.533, 0.0005, HALF_LAST),
    ("docs/budget.md", "noise term 2.063″, **σ_eff = 11.533″**", ["budget", "--json", "o.json"],
     lambda d: _budget_eq4(d)["noise_term_arcsec"], 2.063, 0.0005, HALF_LAST),
    ("README.md", "(eq. 6: 10.6″;", ["budget", "--thermal", "--json", "o.json"],
     lambda d: next(c for c in d["tables"][0]["components"] if c["symbol"] == "dCa_Tn")["contribution"],
     10.6, 0.05, HALF_LAST),
    ("README.md", "quartz 11.3–19.6″", ["budget", "--thermal", "--json", "o.json"],
     lambda d: _thermal(d, "AK-15"), 11.3, 0.05, HALF_LAST),
    ("README.md", "quartz 11.3–19.6″", ["budget", "--thermal", "--json", "o.json"],
     lambda d: _thermal(d, "QA-3000"), 19.6, 0.05, HALF_LAST),
    ("README.md", "silicon 18.4–60.9″", ["budget", "--thermal", "--json", "o.json"],
     lambda d: _thermal(d, "A-18T"), 18.4, 0.05, HALF_LAST),
    ("README.md", "silicon 18.4–60.9″", ["budget", "--thermal", "--json", "o.json"],
     lambda d: _thermal(d, "A-18"), 60.9, 0.05, HALF_LAST),
    ("README.md", "AAK-02 gives 22.6″", ["budget", "--thermal", "--json", "o.json"],
     lambda d: _thermal(d, "AAK-02"), 22.6, 0.05, HALF_LAST),
    ("docs/budget.md", "| AK-18 | quartz | 15 | **18.37″**", ["budget", "--thermal", "--accelerometer", "AK-18",
                                                          "--json", "o.json"],
     lambda d: d["tables"][0]["total"], 18.37, 0.005, HALF_LAST),
    # Table 3 with u = 12″: exactly the two 20g-vibration entries fail, with these drifts
    ("README.md", "(gyro xY −33.38″, accel yZ −51.34″)",
     ["compare", "--published", "examples/data/table3.csv", "--u-arcsec", "12", "--json", "o.json"],
     lambda d: [(lab, n) for lab, n, _ in _t3_fails(d)], [("vib 20g", "accel.Ca_yz"), ("vib 20g", "gyro.Ca_xy")],
     None, "exact: a set of verdicts"),
    ("README.md", "(gyro xY −33.38″, accel yZ −51.34″)",
     ["compare", "--published", "examples/data/table3.csv", "--u-arcsec", "12", "--json", "o.json"],
     lambda d: [dr for _, _, dr in _t3_fails(d)], [-51.34, -33.38], 0.005, HALF_LAST),
    ("docs/compare.md", "|d| > 1.960·16.97″",
     ["compare", "--published", "examples/data/table3.csv", "--u-arcsec", "12", "--json", "o.json"],
     lambda d: d["steps"][0]["parameters"]["gyro.Ca_xy"]["u"], 16.97, 0.005, HALF_LAST),
    # the example campaign's joint fit: its size, counted (12 × 15 visits × 3 axes)
    ("README.md", "campaign (12 positions × 15 setpoints, 32 parameters)",
     ["fit", "--example", "--method", "joint", "--json", "o.json"],
     lambda d: (d["fit"]["n_obs"], d["fit"]["n_params"]), (12 * 15 * 3, 32), None, "exact: counts"),
    # the example campaign's joint fit: the tilt the README states (60″) within 3 U of the fit
    ("README.md", "bench tilted by 60″", ["fit", "--example", "--method", "joint", "--json", "o.json"],
     lambda d: d["parameters"]["tilt_delta"]["value"], 60.0, None, "3u of the fit (u from the JSON)"),
]


# Not checked here, too expensive for a docs test (each has its own slow test, or is a
# measurement the doc dates): the SBC numbers of `validate --campaigns 200` (4 min; README,
# docs/posterior.md, tests/test_validation.py), the 500-campaign classical SDs
# (docs/classical.md), the 1000-pair false-alarm rates of compare, the 20-seed diagnosis
# validation, benchmark timings.


@pytest.fixture(scope="module")
def number_outputs(tmp_path_factory):
    cache = {}

    def get(argv):
        key = tuple(argv)
        if key not in cache:
            cwd = tmp_path_factory.mktemp("numbers")
            p = _run(_prepare(list(argv), cwd), cwd)
            assert p.returncode == 0, p.stderr[-2000:]
            cache[key] = json.loads((cwd / "o.json").read_text(encoding="utf-8"))
        return cache[key]
    return get


@pytest.mark.parametrize("doc,quote,argv,get,want,tol,why", NUMBERS,
                         ids=[f"{n[0]}:{n[1][:30]}" for n in NUMBERS])
def test_doc_numbers_match_the_output(doc, quote, argv, get, want, tol, why, number_outputs):
    text = " ".join((ROOT / doc).read_text(encoding="utf-8").split())
    assert quote in text, f"{doc} no longer says {quote!r}: update NUMBERS"
    d = number_outputs(argv)
    got = get(d)
    if why.startswith("3u"):
        u = d["parameters"]["tilt_delta"]["u"]
        assert abs(got - want) <= 3 * u, (doc, quote, got, u)
    elif tol is None:
        assert got == want, (doc, quote, got)
    elif isinstance(want, list):
        assert len(got) == len(want) and all(abs(g - w) <= tol for g, w in zip(got, want)), (doc, quote, got)
    else:
        assert abs(got - want) <= tol, f"{doc}: {quote!r}: output {got} vs quoted {want} (tolerance {tol}: {why})"


# -- links and paths -----------------------------------------------------------------------

LINK_DOCS = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").rglob("*.md")),
             DATA / "README.md"]
OUTSIDE = [re.compile(p) for p in (r"\.\./shared", r"\bshared/(docs|data)\b", r"/work/",
                                    r"(?:^|[\s`(])/(?:home|tmp|Users|root|mnt)/")]


@pytest.mark.parametrize("doc", LINK_DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_links_stay_in_the_repository(doc):
    text = doc.read_text(encoding="utf-8")
    bad = [f"{p.pattern}: {m.group(0)!r}" for p in OUTSIDE for m in p.finditer(text)]
    assert not bad, f"{doc.relative_to(ROOT)}: references outside the repository: {bad}"
    for m in re.finditer(r"\]\(([^)\s]+)\)", text):
        target = m.group(1)
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        assert not target.startswith("/"), f"{doc.relative_to(ROOT)}: absolute link {target}"
        path = (doc.parent / target.split("#")[0]).resolve()
        assert ROOT in path.parents or path == ROOT, f"{doc.relative_to(ROOT)}: link leaves the repository: {target}"
        assert path.exists(), f"{doc.relative_to(ROOT)}: link target missing: {target}"


@pytest.mark.parametrize("doc", LINK_DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_repository_paths_named_in_the_docs_exist(doc):
    """A path such as `docs/raw.md`, `tests/data/real/...`, `examples/data/table3.csv`
    named in the text (not only in links) is a file or folder of the repository."""
    text = doc.read_text(encoding="utf-8")
    missing = [m.group(1) for m in re.finditer(
        r"(?<![\w/.])((?:docs|tests|examples|benchmarks|triadcal)/[\w./-]*\w)", text)
        if not (ROOT / m.group(1)).exists() and not (doc.parent / m.group(1)).exists()]
    assert not missing, f"{doc.relative_to(ROOT)}: paths that do not exist: {missing}"
