"""Build pieces of the C decoder core (decoder/*.c) into a ctypes-loadable shared library for the core's tests.

`core_library(["range.c", ...])` compiles the named sources (plus decoder/common.c, tw_fail and friends) with the
core's flags into a temporary directory once per process and returns the `ctypes.CDLL`; tests call
`pytest.skip` through `require_compiler()` when no C compiler is there.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parent.parent / "decoder"
FLAGS = ["-O2", "-std=c99", "-ffp-contract=off", "-fno-fast-math", "-fPIC", "-shared", "-Wall", "-Wextra"]
_CACHE: dict[tuple, ctypes.CDLL] = {}


def compiler() -> str | None:
    """The C compiler to use ($CC, else cc / gcc / clang on PATH), or None."""
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return name
    return None


def require_compiler() -> str:
    cc = compiler()
    if cc is None:
        pytest.skip("no C compiler (install gcc or clang) to build the decoder core")
    return cc


def core_library(sources: list[str], defines: tuple[str, ...] = ()) -> ctypes.CDLL:
    """A shared library of decoder/common.c and `sources` (names under decoder/), built once per process."""
    cc = require_compiler()
    names = ["common.c", *[s for s in sources if s != "common.c"]]
    paths = [CORE / n for n in names]
    digest = hashlib.sha256()
    for p in [*paths, *sorted(CORE.glob("*.h"))]:
        digest.update(p.name.encode() + p.read_bytes())
    digest.update(" ".join(defines).encode())
    key = (digest.hexdigest(),)
    if key in _CACHE:
        return _CACHE[key]
    out = Path(tempfile.mkdtemp(prefix="twcore")) / f"libtwcore_{key[0][:12]}.so"
    cmd = [cc, *FLAGS, *[f"-D{d}" for d in defines], "-o", str(out), *map(str, paths), "-lm", "-pthread"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    lib = ctypes.CDLL(str(out))
    _CACHE[key] = lib
    return lib
