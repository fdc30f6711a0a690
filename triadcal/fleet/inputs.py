"""The inputs of ``triadcal batch`` and the names of its results: the files a list of paths and globs
names (every match that is not a readable file an error row of its own), the SHA-256 of a file, and
the file-name-safe, one-to-one forms of serials and states (:func:`safe_name`, :func:`result_path`)
with the key under which two spellings are one serial (:func:`same_name_key`). Moved out of
batch.py (603 lines) unchanged; batch.py re-exports them."""

from __future__ import annotations

import glob
import hashlib
import os
import re
import unicodedata
from pathlib import Path
from typing import Optional, Sequence

from ..errors import InputError



def _not_a_file(path) -> Optional[str]:
    """Why ``path`` cannot be read as an input file, or None when it is a readable regular file."""
    p = str(path)
    if os.path.islink(p) and not os.path.exists(p):
        return f"a dangling symbolic link: its target {os.readlink(p)} is not there"
    if os.path.isdir(p):
        return "a directory, not a file"
    if not os.path.exists(p):
        return "no such file"
    if not os.path.isfile(p):
        return "not a regular file (a FIFO, socket or device)"
    try:
        with open(p, "rb"):
            pass
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    return None


def find_inputs(inputs: Sequence) -> tuple[list[Path], list[tuple[str, str]]]:
    """The files named or matched by glob patterns (``*``, ``?``, ``[..]``, ``**``), in the order
    given, each once, and ``(path, why)`` of every glob match that is not a readable regular file
    (a dangling symbolic link, a directory, an unreadable file): batch makes each an error row.
    Before, a glob dropped such a match without a word ("2 ok", exit 0; an outside probe,
    2026-12-01). A pattern that matches nothing, or a file named explicitly that cannot be read, is
    refused."""
    out, bad, seen = [], [], set()
    for item in inputs:
        item = str(item)
        if glob.has_magic(item):
            matches = sorted(glob.glob(item, recursive=True))
            if not matches:
                raise InputError(f"{item}: no file matches this pattern")
        else:
            why = _not_a_file(item)
            if why is not None:
                raise InputError(f"{item}: {why}" if why == "no such file" else f"{item}: no such file ({why})")
            matches = [item]
        for m in matches:
            key = os.path.realpath(m)
            if key in seen:
                continue
            seen.add(key)
            why = _not_a_file(m)
            if why is None:
                out.append(Path(m))
            else:
                bad.append((m, why))
    if not out and not bad:
        raise InputError("no input files given")
    return out, bad


def expand_inputs(inputs: Sequence) -> list[Path]:
    """The files of :func:`find_inputs`; a glob match that is not a readable file is refused here."""
    files, bad = find_inputs(inputs)
    if bad:
        raise InputError(f"{bad[0][0]}: {bad[0][1]}" + (f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""))
    return files


def sha256_of(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


#: the longest serial or state kept as its own file-name part; a longer one is cut and hashed
MAX_NAME_CHARS = 100


def safe_name(text: str) -> str:
    """A file-name-safe form of a serial number or state, one to one: letters, digits, ``.``,
    ``-`` and single ``_`` stay; a text with anything else (or ``__``, the separator of unit and
    state in :func:`result_path`, or a leading ``.``) gets those characters as ``_`` and ``~``
    with the first 10 hex digits of its SHA-256. Before, ``SN/1`` and ``SN_1`` (or unit ``A__B``
    in state ``x`` and unit ``A`` in state ``B__x``) wrote one file, the last fitted winning with
    a warning only. At most :data:`MAX_NAME_CHARS` characters: a longer text is cut to its first
    89 (sanitised) and the hash of the whole text added (an outside probe's serial of 253
    characters raised "File name too long" in a worker and took the whole batch down)."""
    s = re.sub(r"[^A-Za-z0-9._-]", "_", text)
    if s == text and "__" not in text and not text.startswith(".") and text and len(text) <= MAX_NAME_CHARS:
        return text
    head = (s.strip(".") or "_")[:MAX_NAME_CHARS - 11]
    return f"{head}~{hashlib.sha256(text.encode('utf-8')).hexdigest()[:10]}"


def same_name_key(text: str) -> str:
    """A serial or state as batch compares them: without surrounding spaces and in Unicode NFC, so
    that ``SN-\u00c91`` and ``SN-E\u03011`` (NFD, as macOS writes file names) are one serial.
    Before, the two were fitted as two units whose rows print identically (an outside probe)."""
    return unicodedata.normalize("NFC", str(text).strip())


def result_path(out_dir, unit: str, state: str) -> Path:
    return Path(out_dir) / "results" / f"{safe_name(unit)}__{safe_name(state)}.json"
