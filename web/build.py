"""Build web/tetweave_decoder.wasm from the C decoder core (decoder/*.c) and web/src/wasm_api.c.

    pip install ziglang==0.17.1
    python3 web/build.py            # rewrites web/tetweave_decoder.wasm
    python3 web/build.py --check    # builds into a temporary file; exit 1 if it differs from the committed one

The compiler is zig's clang from the `ziglang` wheel of PyPI, pinned to one version: the same version on any
machine gives the same bytes (checked by tests/test_web.py), and it brings its own wasm32-wasi libc, so nothing else
needs installing. The module is a WASI *reactor* that imports nothing: the core does no I/O, and wasi-libc's
malloc grows the module's memory itself; vsnprintf (the core's messages) is wasi-libc's.

Bit-identity with the native build and the Python decoder: wasm32 arithmetic is IEEE binary64 with one rounding per
operation (no x87, no fused multiply-add instruction), -ffp-contract=off keeps clang from fusing, and sqrt is the
f64.sqrt instruction (correctly rounded, as glibc's). Other libm functions (tanh, exp, log) are musl's here and
glibc's natively, which differ in the last bit on many arguments: the core must not take an output bit from them.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WASM = ROOT / "web" / "tetweave_decoder.wasm"
API = Path("web/src/wasm_api.c")
ZIG_VERSION = "0.17.1"
STACK_BYTES = 1 << 20  # the core's stages keep their big arrays on the heap; 1 MiB covers their recursion
FLAGS = [
    "-target",
    "wasm32-wasi",
    "-mexec-model=reactor",  # no _start/main: JavaScript calls the exports (after _initialize)
    # -Os: the 60 KB gzipped that the module and its JS may take together. Measured on the core of e0ad368:
    # -Os 115.8 KB, 52.7 KB gzipped; -O2 151.5 KB, 63.8 KB gzipped, decoding 5-15 % faster in node 20 (best of 7:
    # spot 5 KB 24 vs 28 ms, spot 40 KB 202 vs 214 ms, bunny 40 KB 391 vs 434 ms); -O3 is -O2's size, -Oz gives
    # -Os's bytes. -flto (below): on the core of 1fa74ff 125,516 -> 123,228 bytes, 57,102 -> 56,100 gzipped, so
    # that the module and tetweave_decoder.mjs (3,183 gzipped) stay under 60,000 bytes together.
    "-Os",
    "-std=c99",
    "-ffp-contract=off",
    "-fno-fast-math",
    "-DTW_NO_THREADS",  # wasm32 without shared memory: the crossing checks run on the calling thread
    "-DNDEBUG",
    "-Wall",
    "-Wextra",
    "-s",  # no debug sections: smaller, and no build paths in the bytes
    "-flto",
    "-Wl,--gc-sections",
    f"-Wl,-z,stack-size={STACK_BYTES}",
]


class BuildError(RuntimeError):
    """The module cannot be built here (no zig, another zig version, missing sources, a compile error)."""


def zig_version() -> str | None:
    """The installed `ziglang` wheel's version, or None when it is not installed."""
    try:
        return importlib.metadata.version("ziglang")
    except importlib.metadata.PackageNotFoundError:
        return None


def sources() -> list[Path]:
    """decoder/*.c (sorted, so the link order never depends on the file system) and the wasm API, relative to the
    repository: relative paths keep the build directory out of the module (assert's __FILE__ is off anyway)."""
    core = sorted(p.relative_to(ROOT) for p in (ROOT / "decoder").glob("*.c"))
    if Path("decoder/decode.c") not in core:
        raise BuildError("decoder/decode.c (tw_decode) is missing: the core is not complete")
    return [*core, API]


def build(output: Path) -> list[str]:
    """Compile the module into `output`; returns the compiler's warnings (one string per line). Raises BuildError."""
    version = zig_version()
    if version is None:
        raise BuildError(f"ziglang is not installed: pip install ziglang=={ZIG_VERSION}")
    if version != ZIG_VERSION:
        raise BuildError(f"ziglang {version} is installed; the committed module is built by {ZIG_VERSION}")
    cmd = [sys.executable, "-m", "ziglang", "cc", *FLAGS, "-o", str(output), *map(str, sources())]
    run = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if run.returncode != 0:
        raise BuildError(f"zig cc failed ({run.returncode}):\n{run.stderr.strip()}")
    return [line for line in run.stderr.splitlines() if line.strip()]


def imports(wasm: bytes) -> list[str]:
    """The module's imports as 'module.name' (the import section, id 2, parsed by hand: no dependency)."""

    def leb(pos: int) -> tuple[int, int]:
        value, shift = 0, 0
        while True:
            byte = wasm[pos]
            value |= (byte & 0x7F) << shift
            pos, shift = pos + 1, shift + 7
            if byte < 0x80:
                return value, pos

    def name(pos: int) -> tuple[str, int]:
        length, pos = leb(pos)
        return wasm[pos : pos + length].decode(), pos + length

    pos, found = 8, []
    while pos < len(wasm):
        section, size_pos = wasm[pos], pos + 1
        size, pos = leb(size_pos)
        if section == 2:
            count, p = leb(pos)
            for _ in range(count):
                module, p = name(p)
                field, p = name(p)
                kind = wasm[p]
                found.append(f"{module}.{field}")
                p += 1
                if kind == 0:  # function: a type index
                    _, p = leb(p)
                else:  # table, memory, global: their descriptions are not needed, and the core imports none
                    raise BuildError(f"the module imports a non-function {module}.{field}")
        pos += size
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="build into a temporary file and compare")
    args = parser.parse_args(argv)
    try:
        if args.check:
            with tempfile.TemporaryDirectory() as tmp:
                built = Path(tmp) / WASM.name
                build(built)
                same = WASM.exists() and built.read_bytes() == WASM.read_bytes()
                print(f"{WASM.relative_to(ROOT)} {'matches' if same else 'DIFFERS FROM'} the sources' build")
                return 0 if same else 1
        warnings = build(WASM)
    except BuildError as exc:
        print(f"web/build.py: {exc}", file=sys.stderr)
        return 2
    for line in warnings:
        print(line, file=sys.stderr)
    data = WASM.read_bytes()
    extra = imports(data)
    print(f"wrote {WASM.relative_to(ROOT)} ({len(data):,} bytes; imports: {', '.join(extra) or 'none'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
