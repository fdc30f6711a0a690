"""The ``triadcal`` command: argument parsing and printing only.

Each subcommand lives in its own module of this package and defines
``register(subparsers)``, which adds its parser and sets ``func``; the library does
the work (every command has a library function of the same name).
"""

from __future__ import annotations

import os

# The matrices here are small (hundreds x tens): a threaded BLAS is far slower on them
# than one thread (an 810 x 35 SVD: 86 ms threaded, 1.2 ms single). Set before numpy loads.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import importlib
import pkgutil
import sys

from .. import __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="triadcal",
        description="Probabilistic calibration of accelerometer triads on a two-axis bench in a thermal chamber.")
    parser.add_argument("--version", action="version", version=f"triadcal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
        importlib.import_module(f"{__name__}.{mod}").register(sub)
    return parser


def main(argv=None) -> int:
    os.environ.setdefault("XDG_CACHE_HOME", os.path.join(os.path.expanduser("~"), ".cache"))
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (ValueError, OSError, KeyError) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"triadcal {args.command}: error: {msg}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
