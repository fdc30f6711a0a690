"""Error types shared across the package (the CLI maps them to one line on stderr, exit 1)."""

from __future__ import annotations


class UnknownName(KeyError, ValueError):
    """A name (parameter, prior, effect) that the model does not have. A ``KeyError`` for
    mapping-style callers and a ``ValueError`` for the CLI; its text is the message, unquoted."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else "unknown name"
