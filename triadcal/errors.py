"""The project's error types. Everything the library raises on purpose (input it cannot use,
an answer it refuses, an instrument that fails) is a :class:`TriadcalError`; the CLI prints
it as one line on stderr (exit 1). Any other exception is a bug (exit 70)."""

from __future__ import annotations


class TriadcalError(Exception):
    """Base of every error triadcal raises on purpose; its text is one sentence naming the
    file, line and field (or the option) concerned."""


class InputError(TriadcalError, ValueError):
    """Input that cannot be used: a file, a field, an option or an argument. A ``ValueError``
    too, for callers of the library that catch that."""


class IdentifiabilityError(InputError):
    """The plan or the data cannot determine some parameters of the requested model (raised by the
    joint fit, :mod:`triadcal.estimation.joint`, which re-exports it)."""


class UnknownName(InputError, KeyError):
    """A name (parameter, prior, effect) that the model does not have. A ``KeyError`` for
    mapping-style callers; its text is the message, unquoted."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else "unknown name"
