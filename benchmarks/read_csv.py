"""Benchmark: reading a bench CSV v1 file of 10^4 and 10^5 rows (a lab's year of exports,
many units) with triadcal's validating reader, against pyarrow.csv.read_csv, the obvious
fast alternative, which parses the same file without any of the checks (ranges, metadata,
kelvin, unit magnitude, duplicate visits, line numbers in errors).

The file repeats the built-in example campaign (180 visits) with shifted times and one
unit name per ten repeats. Prints best-of-N seconds, rows per second and the ratio. The
issue's target: 10^5 rows in <= 5 s.

    python benchmarks/read_csv.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from pyarrow import csv as pacsv

from triadcal.api import example_path
from triadcal.io.bench_csv import read_bench_csv


def make_file(path: Path, n_rows: int) -> None:
    lines = Path(example_path()).read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#")]
    header = lines[len(head)]
    body = lines[len(head) + 1:]
    cols = header.split(",")
    ti, ui = cols.index("time_s"), cols.index("unit")
    out = head + [header]
    n, rep = 0, 0
    while n < n_rows:
        for ln in body:
            f = ln.split(",")
            f[ti] = repr(float(f[ti]) + rep * 1e6)
            f[ui] = f"{f[ui]}_{rep // 10}"
            out.append(",".join(f))
            n += 1
            if n >= n_rows:
                break
        rep += 1
    path.write_text("\n".join(out) + "\n")


def best_of(fn, repeat):
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        for n in (10_000, 100_000):
            path = Path(d) / f"bench_{n}.csv"
            make_file(path, n)
            skip = sum(1 for ln in path.read_text().splitlines()[:50] if ln.startswith("#"))
            ours = best_of(lambda: read_bench_csv(path), args.repeat)
            arrow = best_of(lambda: pacsv.read_csv(path, read_options=pacsv.ReadOptions(skip_rows=skip)),
                            args.repeat)
            print(f"{n:>7} rows: triadcal (validating) {ours:6.3f} s ({n / ours:,.0f} rows/s); "
                  f"pyarrow (no checks) {arrow:6.3f} s; ratio {ours / arrow:5.1f}x")


if __name__ == "__main__":
    main()
