"""Benchmark: ``triadcal batch`` of N simulated units (one bench CSV each) on a LocalCluster of
1 and of 2 worker processes (the scaling ratio), against a loop of ``python -m triadcal fit``
command calls on a sample of the units (the per-unit ratio), and the peak memory (max RSS) of
each worker.

    python benchmarks/fleet.py [--units 1000] [--sample 10]

The batch times are of ``triadcal.fleet.batch.batch`` on a running cluster (cluster start-up
printed apart), with the CSV and Parquet summary but without the HTML page.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _max_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--units", type=int, default=1000)
    ap.add_argument("--sample", type=int, default=10, help="units fitted by command calls (default 10)")
    args = ap.parse_args(argv)

    from triadcal.api import simulate
    from triadcal.fleet.batch import batch, start_client

    tmp = Path(tempfile.mkdtemp(prefix="triadcal-fleet-bench-"))
    try:
        t0 = time.perf_counter()
        data = tmp / "data"
        data.mkdir()
        for i in range(args.units):
            simulate(data / f"SN-{i:05d}.csv", unit=f"SN-{i:05d}", seed=1000 + i)
        print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")
        print(f"simulated {args.units} units in {time.perf_counter() - t0:.1f} s")

        times = {}
        for workers in (1, 2):
            t0 = time.perf_counter()
            client, cluster = start_client(None, workers=workers)
            start = time.perf_counter() - t0
            try:
                t0 = time.perf_counter()
                rep = batch([str(data / "*.csv")], tmp / f"out{workers}", client=client, html=False)
                times[workers] = time.perf_counter() - t0
                rss = client.run(_max_rss_mb)
            finally:
                client.close()
                cluster.close()
            assert rep.n_fitted == args.units, (rep.n_fitted, rep.n_errors)
            print(f"batch, {workers} worker(s): cluster start {start:.1f} s, {args.units} units in "
                  f"{times[workers]:.1f} s ({1e3 * times[workers] / args.units:.1f} ms/unit); peak memory per "
                  f"worker {', '.join(f'{v:.0f}' for v in rss.values())} MB")
        print(f"scaling 1 -> 2 workers: {times[1] / times[2]:.2f}x")

        n = min(args.sample, args.units)
        files = sorted(data.glob("*.csv"))[:n]
        env = dict(os.environ, MPLBACKEND="Agg")
        t0 = time.perf_counter()
        for f in files:
            subprocess.run([sys.executable, "-m", "triadcal", "fit", str(f), "--json", str(tmp / "one.json"),
                            "--quiet"], check=True, env=env, stderr=subprocess.DEVNULL)
        per_call = (time.perf_counter() - t0) / n
        per_unit = times[2] / args.units
        print(f"command calls: {n} x `python -m triadcal fit`: {per_call * 1e3:.0f} ms/unit")
        print(f"batch (2 workers) against command calls, per unit: {per_call / per_unit:.1f}x faster")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
