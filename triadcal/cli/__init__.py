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
import re
import sys

from .. import __version__
from ..errors import TriadcalError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="triadcal",
        description="Probabilistic calibration of accelerometer triads on a two-axis bench in a thermal chamber.")
    parser.add_argument("--version", action="version", version=f"triadcal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
        importlib.import_module(f"{__name__}.{mod}").register(sub)
    return parser


def _warning_line(message, category, filename, lineno, file=None, line=None):
    """Warnings as one line without the library's absolute paths: ``warning: <message>``."""
    print(f"triadcal: warning: {message}", file=file or sys.stderr)


#: options whose value may start with a minus sign that is not a number (a range: -40:85:5)
NEGATIVE_VALUE_OPTIONS = ("--grid", "--range")


#: a negative number in e-notation (-1e-3, -2.5E+1): argparse counts only -12 and -1.5 as numbers
_NEGATIVE_E = re.compile(r"^-(\d+\.?\d*|\.\d+)[eE][-+]?\d+$")


def _negative_values(argv: list) -> list:
    """``--grid -40:85:5`` as ``--grid=-40:85:5``, and ``--k-ca -1.5e-3`` as ``--k-ca=-1.5e-3``:
    argparse takes a value that starts with '-' and is not a plain number for an option, and the
    documented form would fail ("expected one argument"; an outside probe of ``budget``)."""
    out, i = [], 0
    while i < len(argv):
        a = str(argv[i])
        nxt = str(argv[i + 1]) if i + 1 < len(argv) else ""
        if a.startswith("--") and "=" not in a and _NEGATIVE_E.match(nxt) or \
                a in NEGATIVE_VALUE_OPTIONS and nxt.startswith("-") and ":" in nxt:
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


#: the options that name a file a command writes (``--posterior`` and ``--diagnose`` only where
#: they are outputs: certificate and compare read a posterior)
OUTPUT_OPTIONS = ("json", "netcdf", "html", "pdf", "plot", "bench_csv")
OUTPUT_OPTIONS_OF = {"sample": ("posterior",), "fit-raw": ("posterior", "diagnose")}


def _check_output_folders(args) -> None:
    """Refuse, before any work, an output file whose folder does not exist (io.atomic)."""
    from ..io.atomic import check_output_folder

    for dest in OUTPUT_OPTIONS + OUTPUT_OPTIONS_OF.get(getattr(args, "command", ""), ()):
        value = getattr(args, dest, None)
        if isinstance(value, (str, os.PathLike)) and str(value) not in ("", "-"):
            check_output_folder(value)


def _unrecognised(parser: argparse.ArgumentParser, args, extra: list) -> None:
    """Arguments no parser took: the command's own usage and error (exit 2), with the option it
    most likely meant (``--jsn`` -> ``--json``), not the top level's usage."""
    import difflib

    sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
    command = sub.choices.get(getattr(args, "command", None)) if sub is not None else None
    if command is None:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    known = [o for a in command._actions for o in a.option_strings if o.startswith("--")]
    hints = []
    for e in extra:
        if e.startswith("--"):
            close = difflib.get_close_matches(e.split("=", 1)[0], known, n=1, cutoff=0.6)
            if close:
                hints.append(f"{e.split('=', 1)[0]} -> {close[0]}")
    command.error(f"unrecognized arguments: {' '.join(extra)}"
                  + (f" (did you mean: {', '.join(hints)}?)" if hints else ""))


def main(argv=None) -> int:
    """Run one command. Exit codes: 0 done, 1 refused input or a failed precondition (one line on
    stderr naming the file and the place), 2 usage, 3 a result whose status is not ok (or no
    certificate issued), 70 an internal error (a bug: one line, and the traceback with
    ``TRIADCAL_DEBUG=1``)."""
    import warnings

    os.environ.setdefault("XDG_CACHE_HOME", os.path.join(os.path.expanduser("~"), ".cache"))
    parser = build_parser()
    args, extra = parser.parse_known_args(_negative_values(sys.argv[1:] if argv is None else list(argv)))
    if extra:
        _unrecognised(parser, args, extra)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    debug = os.environ.get("TRIADCAL_DEBUG") == "1"
    previous = warnings.showwarning
    if not debug:
        warnings.showwarning = _warning_line
    try:
        _check_output_folders(args)
        code = int(args.func(args) or 0)
        sys.stdout.flush()        # the last block here, where a closed pipe is caught, not at exit
        return code
    except BrokenPipeError:
        return _broken_pipe()
    except TriadcalError as exc:
        print(f"triadcal {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        if exc.filename is None or not exc.strerror:
            return _internal_error(args.command, exc, debug)
        # a file the user named that the system cannot open: "PATH: no such file or directory"
        print(f"triadcal {args.command}: error: {exc.filename}: {exc.strerror.lower()}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"triadcal {args.command}: interrupted (files written so far are whole; nothing half-written "
              "was left)", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the last line of defence: a bug, said as one
        return _internal_error(args.command, exc, debug)
    finally:
        warnings.showwarning = previous


def _internal_error(command: str, exc: BaseException, debug: bool) -> int:
    """Anything that is not a :class:`TriadcalError` is a bug: one line (exit 70), or the
    traceback with ``TRIADCAL_DEBUG=1``."""
    if debug:
        raise exc
    print(f"triadcal {command}: internal error: {type(exc).__name__}: {exc} (a bug: please report it "
          "with the command and its input; TRIADCAL_DEBUG=1 shows the traceback)", file=sys.stderr)
    return 70


def _broken_pipe() -> int:
    """stdout closed by the reader (``triadcal ... | head``): stop quietly."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
