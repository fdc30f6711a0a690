"""Benchmark: ``triadcal fit-raw --poses unknown`` on a raw recording of 10^7 samples (1 kHz,
2.8 hours, 150 free poses of 60 s with 6.7-s moves), end to end (read, detect, average,
fit), in a fresh process each, timed and with its peak resident memory (``ru_maxrss`` of the
child). Against the obvious alternative reader, ``numpy.loadtxt`` of the same file, in the
same run; and, with ``--before DIR`` (a checkout of an older triadcal, e.g. made with
``git worktree add /tmp/before <commit>``), the same fit by that code. Prints each and the
ratios. The issue's target: <= 10 s and <= 1.5 GB.

    python benchmarks/raw_scale.py [--n 10000000] [--dir /tmp] [--before /tmp/before]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CHILD = r"""
import json, resource, sys, time
t0 = time.perf_counter()
path, how = sys.argv[1], sys.argv[2]
if how == "triadcal":
    from triadcal.estimation.raw import fit_raw
    out = fit_raw(path, 1000.0, poses="unknown", local_g_m_s2=9.80665)
    status, k = out.result.status, out.result["K_x"].value
else:
    import numpy as np
    a = np.loadtxt(path, delimiter=",", skiprows=1)
    status, k = "read only", float(a[0, 0])
dt = time.perf_counter() - t0
print(json.dumps({"seconds": dt, "peak_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "status": status, "K_x": k}))
"""


def make_recording(path: Path, n: int, seed: int = 7) -> None:
    """Counts (offset-binary, 2048 LSB/g) of a unit tumbled through free poses, white noise."""
    import pyarrow as pa
    from pyarrow import csv as pacsv

    rng = np.random.default_rng(seed)
    rate, static_n, move_n = 1000, 60_000, 6_667
    K, S = np.array([1 / 2000, 1 / 2050, 1 / 1990]), np.array([0.02, -0.015, 0.03])
    out = np.empty((n, 3))
    i = 0
    g = rng.normal(size=3)
    while i < n:
        g = g / np.linalg.norm(g)
        g_next = rng.normal(size=3)
        g_next /= np.linalg.norm(g_next)
        while np.degrees(np.arccos(np.clip(g @ g_next, -1, 1))) < 30:
            g_next = rng.normal(size=3)
            g_next /= np.linalg.norm(g_next)
        k = min(static_n, n - i)
        out[i:i + k] = g
        i += k
        k = min(move_n, n - i)
        # slerp: constant angular rate (no slow start the detector could take for rest)
        om = np.arccos(np.clip(g @ g_next, -1, 1))
        t = np.linspace(0, 1, move_n)[:k, None]
        out[i:i + k] = (np.sin((1 - t) * om) * g + np.sin(t * om) * g_next) / np.sin(om)
        i += k
        g = g_next
    w = np.round((out + S) / K + rng.normal(0, 4.0, size=(n, 3)) + 32768).astype(np.int32)
    table = pa.table({"ax": w[:, 0], "ay": w[:, 1], "az": w[:, 2]})
    pacsv.write_csv(table, path, write_options=pacsv.WriteOptions(include_header=True, quoting_style="none"))
    del rate


def run(path: Path, how: str, code_dir=None) -> dict:
    import os

    env = dict(os.environ)
    if code_dir:
        env["PYTHONPATH"] = str(code_dir)
    r = subprocess.run([sys.executable, "-c", CHILD, str(path), how], capture_output=True, text=True, env=env,
                       cwd=path.parent)   # not the current folder: "-c" would import the code found there
    if r.returncode != 0:
        return {"error": r.stderr.strip().splitlines()[-1] if r.stderr else f"exit {r.returncode}"}
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=10_000_000)
    ap.add_argument("--dir", default=None)
    ap.add_argument("--before", default=None, help="a checkout of older triadcal code to time the same fit with")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(dir=args.dir) as d:
        path = Path(d) / "recording.csv"
        make_recording(path, args.n)
        print(f"{args.n:,} samples, {path.stat().st_size / 1e6:.0f} MB of CSV")
        ours = run(path, "triadcal")
        alt = run(path, "loadtxt")
        print(f"triadcal fit-raw (read + detect + fit): {ours}")
        print(f"numpy.loadtxt (read only):              {alt}")
        if args.before:
            before = run(path, "triadcal", args.before)
            print(f"the same fit by {args.before}:  {before}")
            if "seconds" in before and "seconds" in ours:
                print(f"ratio before/now: {before['seconds'] / ours['seconds']:.1f}x the time, "
                      f"{before['peak_MB'] / ours['peak_MB']:.1f}x the peak memory")
        if "seconds" in ours and "seconds" in alt:
            print(f"ratio (loadtxt read / our whole fit): {alt['seconds'] / ours['seconds']:.1f}x faster, "
                  f"peak memory {ours['peak_MB']:.0f} MB vs {alt['peak_MB']:.0f} MB")


if __name__ == "__main__":
    main()
