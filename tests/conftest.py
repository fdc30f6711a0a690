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
