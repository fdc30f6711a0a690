"""One way to write a file: atomically, or not at all.

Every file triadcal writes goes through :func:`atomic_write`, :func:`atomic_write_text`,
:func:`atomic_write_bytes`, :func:`atomic_path` (for libraries that write by path) or
:func:`atomic_write_json` (strict JSON: non-finite numbers become ``null``; :func:`json_text`).
Derivation/design: docs/results-json.md (conventions: written atomically, ``null``).
"""

from __future__ import annotations

from ..errors import InputError

import contextlib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Iterator, Union

import numpy as np

PathLike = Union[str, os.PathLike]


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:          # pragma: no cover - a folder that cannot be opened (some file systems)
        return
    try:
        os.fsync(fd)
    except OSError:          # pragma: no cover
        pass
    finally:
        os.close(fd)


def _umask() -> int:
    """The process's umask: from /proc on Linux (no global state touched); elsewhere by setting
    it and setting it back (POSIX has no getter)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def check_output_folder(path: PathLike) -> None:
    """Refuse an output path whose folder does not exist (or is a file), naming it: checked by the
    commands before they work, so that an hour's sampling is not lost to a typo in ``--json``
    (before: the error named the internal ``.name.xyz.part`` file, after the work was done)."""
    parent = Path(path).parent
    if not parent.is_dir():
        raise InputError(f"{path}: the folder {parent} does not exist" if not parent.exists() else
                         f"{path}: {parent} is not a folder")


def _temporary(path: Path, suffix: str):
    try:
        return tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    except FileNotFoundError:
        check_output_folder(path)
        raise


@contextlib.contextmanager
def atomic_path(path: PathLike, suffix: str = "") -> Iterator[Path]:
    """A temporary path in the target's folder for a library that writes by path (netCDF,
    matplotlib, reportlab); renamed onto ``path`` when the block ends without error, removed
    otherwise. ``suffix`` (e.g. ``".png"``) for libraries that pick the format by extension."""
    path = Path(path)
    fd, tmp = _temporary(path, (suffix or "") + ".part")
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        # mkstemp makes the file 0600; give it the mode an ordinary open() would (0666 less the umask)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    _fsync_dir(path.parent)


@contextlib.contextmanager
def atomic_write(path: PathLike, mode: str = "w", encoding: str = "utf-8", newline=None):
    """Open a temporary file for writing (``mode`` "w" or "wb"); on success it replaces
    ``path`` (flushed, fsync'd, renamed, folder fsync'd); on error it is removed."""
    if mode not in ("w", "wb"):
        raise InputError(f"atomic_write writes whole files: mode 'w' or 'wb', not {mode!r}")
    kw = {} if mode == "wb" else {"encoding": encoding, "newline": newline}
    with atomic_path(path) as tmp, open(tmp, mode, **kw) as fh:
        yield fh


def atomic_write_text(path: PathLike, text: str, encoding: str = "utf-8") -> None:
    with atomic_write(path, "w", encoding=encoding, newline="") as fh:
        fh.write(text)


def atomic_write_bytes(path: PathLike, data: bytes) -> None:
    with atomic_write(path, "wb") as fh:
        fh.write(data)


def json_safe(obj):
    """``obj`` with numpy types converted and every non-finite float replaced by None."""
    if isinstance(obj, dict):
        return {str(k) if not isinstance(k, str) else k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


def json_text(obj, indent: int = 2) -> str:
    """JSON text of ``obj`` (:func:`json_safe`), strict: NaN and Infinity cannot appear."""
    return json.dumps(json_safe(obj), indent=indent, allow_nan=False) + "\n"


def atomic_write_json(path: PathLike, obj, indent: int = 2) -> None:
    """Write ``obj`` as JSON atomically; non-finite numbers become null (never NaN/Infinity).
    The text is made before the file is opened, so an object that cannot be serialised
    leaves nothing behind."""
    atomic_write_text(path, json_text(obj, indent))


def _no_constant(name):
    raise InputError(f"{name} is not JSON (a non-finite number must be written as null)")


class _DuplicateKey(ValueError):
    """A key that occurs twice in one JSON object (raised by :func:`_unique_keys`)."""

    def __init__(self, key: str):
        super().__init__(key)
        self.key = key


def _unique_keys(pairs):
    """``object_pairs_hook`` of :func:`read_json`: an object, refused when a key repeats (the
    standard library would keep the last value without a word: ``"status": "model_mismatch",
    "status": "ok"`` would read as ok)."""
    out = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


def _duplicate_key_at(text: str):
    """``(key, line, path)`` of the first key that repeats in an object of ``text`` (JSON that
    the parser has read up to that key), or None. A walk over the tokens that keeps one set of
    keys per open object; only run once the parser has found a duplicate."""
    stack = []          # per open container: [its keys (None: a list), its path, last key or index]
    i, n, line = 0, len(text), 1
    expect_key = False  # after "{" or after "," in an object: the next string is a key
    while i < n:
        c = text[i]
        if c in " \t\r\n":
            line += c == "\n"
            i += 1
            continue
        if c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            token = text[i:j + 1]
            k = j + 1
            while k < n and text[k] in " \t\r\n":
                k += 1
            if expect_key and stack and stack[-1][0] is not None and k < n and text[k] == ":":
                try:
                    key = json.loads(token)
                except ValueError:
                    key = token
                if key in stack[-1][0]:
                    return key, line, stack[-1][1]
                stack[-1][0].add(key)
                stack[-1][2] = key
            line += token.count("\n")
            i = j + 1
            expect_key = False
            continue
        expect_key = False
        if c == "{":
            stack.append([set(), _child_path(stack), None])
            expect_key = True
        elif c == "[":
            stack.append([None, _child_path(stack), 0])
        elif c in "}]":
            if stack:
                stack.pop()
        elif c == "," and stack:
            if stack[-1][0] is None:
                stack[-1][2] += 1
            else:
                expect_key = True
        i += 1
    return None


def _child_path(stack) -> str:
    """The JSON path of a container that opens inside the innermost one of ``stack``."""
    if not stack:
        return ""
    keys, path, last = stack[-1]
    if keys is None:
        return f"{path}[{last}]"
    return f"{path}.{last}" if path else str(last)


def read_toml(path, what: str = "a TOML file") -> dict:
    """A TOML document from ``path`` with one-line errors naming the file: not there ("no such lab
    file" for ``what`` = "a lab file"), not UTF-8 (a lab file saved as UTF-16 ended in
    "internal error: UnicodeDecodeError", an outside probe), not valid TOML (line and column). A
    UTF-8 byte-order mark is skipped, as the CSV readers skip it (it was "Invalid statement (line 1,
    column 1)"). ``what`` names the kind of file in the messages."""
    import tomllib

    try:
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: no such {what.split(' ', 1)[-1]}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        utf16 = raw[:2] in (b"\xff\xfe", b"\xfe\xff")
        raise InputError(f"{path}: not UTF-8 text (byte {exc.start}{'; it is UTF-16' if utf16 else ''}): save the "
                         f"{what.split(' ', 1)[-1]} as UTF-8") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML ({what}): {exc}") from None


def read_json(path):
    """A JSON document from ``path`` with one-line errors naming the file and line: not UTF-8,
    not JSON, NaN or Infinity tokens (not JSON), a key given twice in one object (JSON leaves
    its meaning open; Python would keep the last one silently), nesting too deep, a file that
    is not there."""
    try:
        text = Path(path).read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    try:
        return json.loads(text, parse_constant=_no_constant, object_pairs_hook=_unique_keys)
    except _DuplicateKey as exc:
        found = _duplicate_key_at(text)
        if found is None:
            raise InputError(f"{path}: the key {exc.key!r} occurs twice in one object (which value is meant "
                             "is ambiguous)") from None
        key, line, where = found
        field = f"{where}.{key}" if where else key
        raise InputError(f"{path}:{line}: {field}: the key {key!r} occurs twice in one object (which value is "
                         "meant is ambiguous)") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}:{exc.lineno}: not valid JSON: {exc.msg}") from None
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
    except RecursionError:
        raise InputError(f"{path}: JSON nested too deeply") from None
