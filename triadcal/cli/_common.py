"""Helpers shared by the subcommands: parsing of lists and name=value pairs, and the output
flags every command takes (``--no-progress``, ``--quiet``)."""

from __future__ import annotations

import sys

from ..errors import InputError


def name_list(text: str) -> list[str]:
    """'a,b, c' -> ['a', 'b', 'c'] (empty entries dropped; 'none' -> [])."""
    if text.strip().lower() == "none":
        return []
    return [s.strip() for s in text.split(",") if s.strip()]


def float_list(text: str) -> list[float]:
    try:
        return [float(s) for s in name_list(text)]
    except ValueError:
        raise InputError(f"expected comma-separated numbers, got {text!r}") from None


def assignments(items) -> dict[str, float]:
    """['Ca_xy=40', 'K_x_tempco=12'] -> {'Ca_xy': 40.0, 'K_x_tempco': 12.0}."""
    out = {}
    for item in items or ():
        if "=" not in item:
            raise InputError(f"expected NAME=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = float(v)
        except ValueError:
            raise InputError(f"{k.strip()}: not a number: {v!r}") from None
    return out


# -- the same output flags on every command (issue 22, item 6) ------------------------------

def add_output_options(p) -> None:
    """``--no-progress`` and ``--quiet``, with the same meaning on every command.

    A progress bar goes to stderr, and only when stderr is a terminal (never into a log or a
    pipe). ``--quiet`` leaves nothing on stdout but what the command is asked to write there
    (``certificate --lab-example``, for instance); the files it is asked to write are written,
    errors and notes still go to stderr, and the exit code says how it went."""
    g = p.add_argument_group("output")
    g.add_argument("--no-progress", action="store_true",
                   help="no progress bar (one is drawn on stderr only when stderr is a terminal)")
    g.add_argument("--quiet", action="store_true",
                   help="print nothing on stdout but what the command is asked to write there; errors and "
                        "notes still go to stderr, the exit code says how it went (implies --no-progress)")


class Output:
    """The effective output settings of a command (see :func:`output`)."""

    def __init__(self, quiet: bool, progress: bool):
        self.quiet = quiet
        self.progress = progress

    def __repr__(self) -> str:
        return f"Output(quiet={self.quiet}, progress={self.progress})"

    def say(self, *parts, **kwargs) -> None:
        """``print`` to stdout, except with ``--quiet``."""
        if not self.quiet:
            print(*parts, **kwargs)

    def bar(self, **kwargs):
        """A tqdm bar on stderr, or None when there is to be no progress bar."""
        if not self.progress:
            return None
        from tqdm import tqdm

        kwargs.setdefault("dynamic_ncols", True)
        return tqdm(file=sys.stderr, **kwargs)


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):       # replaced by an object without isatty, or closed
        return False


def output(args) -> Output:
    """What ``--quiet`` and ``--no-progress`` (see :func:`add_output_options`) mean for this run:
    quiet implies no progress bar, and there is none either when stderr is not a terminal."""
    quiet = bool(getattr(args, "quiet", False))
    progress = not quiet and not getattr(args, "no_progress", False) and _is_terminal(sys.stderr)
    return Output(quiet=quiet, progress=progress)
