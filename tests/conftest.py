import os
import tempfile

os.environ.setdefault("XDG_CACHE_HOME", os.path.join(tempfile.gettempdir(), "triadcal-xdg-cache"))
os.environ.setdefault("MPLBACKEND", "Agg")
# small matrices: one BLAS thread is much faster (see triadcal/cli/__init__.py)
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def example():
    """The built-in example campaign (read once; tests deep-copy it before mutating)."""
    from triadcal.api import example_path
    from triadcal.io.bench_csv import read_bench_csv

    return read_bench_csv(example_path())


@pytest.fixture(scope="session")
def emulated_capture(tmp_path_factory):
    """One `triadcal capture --emulate` of the 12-position plan at 20 degC (bench tilt, self-heating
    of 60 s, seed 3), run once for the tests that read it: test_hardware_capture.py fits it and checks
    its rows against the raw file, test_results_contract.py checks its files against the contract.
    Read-only for them: the folder it wrote (capture.csv, raw, capture.json, emulator_truth.json)."""
    import subprocess
    import sys

    work = tmp_path_factory.mktemp("emulated-capture")
    out = work / "campaign"
    (work / "tmp").mkdir()
    env = dict(os.environ, OMP_NUM_THREADS="1", XDG_CACHE_HOME=str(work / "xdg"), MPLBACKEND="Agg",
               TMPDIR=str(work / "tmp"))
    r = subprocess.run([sys.executable, "-m", "triadcal", "capture", "--emulate", "--out", str(out),
                        "--setpoints", "20", "--time-scale", "240", "--emulate-rate-hz", "5", "--settle-s", "2",
                        "--stab-window-s", "30", "--stab-hold-s", "30", "--emulate-effects", "bench_tilt",
                        "--emulate-self-heating-tau-s", "60", "--emulate-seed", "3", "--no-progress"],
                       cwd=work, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="session")
def cli_reports(tmp_path_factory):
    """Every report of tests/test_reports_render.py made once through the CLI (make_reports there):
    the certificate, refusal and drift reports, and the diagnosis pages (with their stdout) of a
    campaign with the bias drift withheld and of a clean one."""
    from test_reports_render import make_reports

    return make_reports(tmp_path_factory.mktemp("reports"))


# Tests that run emulated hardware on the wall clock (a capture through ptys, a dask cluster's start)
# are marked `wallclock`: CI runs the statistical tests on two workers (pytest-xdist) and these apart
# from them, two at a time (they mostly wait on their paced instruments), so that no CPU-bound
# statistical test competes with their clock (.ci/run).
WALLCLOCK_FILES = ("test_hardware_", "test_instruments_end_to_end.py", "test_ramp_capture.py", "test_fleet.py")


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name.startswith(WALLCLOCK_FILES):
            item.add_marker(pytest.mark.wallclock)
