"""CasADi functions compiled to C once per machine (cached on disk under ``$XDG_CACHE_HOME``),
or run on CasADi's virtual machine when no C compiler is found: the same numbers, slower.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable

import casadi as ca

_COMPILED: dict = {}


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "triadcal" / "casadi"


def _compile(key, build: Callable[[], ca.Function]) -> tuple[ca.Function, bool]:
    """Build a CasADi function and compile its generated C code (cached per process, and on
    disk by a hash of the code under ``$XDG_CACHE_HOME/triadcal/casadi``, so a model is
    compiled once per machine). Without a working C compiler the function runs on CasADi's
    virtual machine: the same numbers, slower."""
    if key in _COMPILED:
        return _COMPILED[key]
    f = build()
    try:
        import hashlib
        import shutil
        import subprocess

        cc = shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")
        if cc is None:
            raise RuntimeError("no C compiler")
        folder = _cache_dir()
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False})
            cg.add(f)
            cg.generate(tmp + os.sep)
            src = Path(tmp) / f"{f.name()}.c"
            digest = hashlib.sha256(src.read_bytes() + cc.encode()).hexdigest()[:20]
            lib = folder / f"{f.name()}_{digest}.so"
            if not lib.exists():
                out = Path(tmp) / "f.so"
                subprocess.run([cc, "-O3", "-fPIC", "-shared", str(src), "-o", str(out), "-lm"],
                               check=True, capture_output=True)
                os.replace(out, lib)
        compiled_f = ca.external(f.name(), str(lib))
        result = (compiled_f, True)
    except Exception:  # no compiler or a failed build: the virtual machine
        result = (f, False)
    _COMPILED[key] = result
    return result
