"""Lossless entropy coding of `.tw` version-2 files: bytes per stream and decode time, before and after.

    python -m tetweave_codec.benchmarks.entropy_coding FILE.tw [FILE.tw ...] [--repeats 15] [--markdown OUT.md]

Each file's symbols are packed twice, "before" without flag bit 2 (population count + rank on every octree
level) and "after" with it (the context-coded octree, formats/README.md "Positions section, context-coded"); s
and c are coded the same way in both (the file's flags otherwise). Both must decode to the file's symbols
(checked), and a file written without flag bit 2 must repack to its own bytes (checked: the plain coding did not
change). Reported per file: bytes and bits per point of the positions, s and c sections (each with its models),
the whole file, and decode times as medians over `--repeats` rounds, before and after timed back to back in the
same round: the octree alone (`octree.decode`) and the whole `unpack` (octree, s prediction, c). Times are
process CPU time, which is less disturbed than wall time when other processes share the cores.
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from tetweave_codec.formats import octree, tw
from tetweave_codec.formats.common import FLAG_OCTREE_CONTEXTS
from tetweave_codec.formats.tw2 import TetWeaveFileV2, pack_v2

STREAMS = ("positions", "s", "c")


def _cpu_ms(fn) -> float:
    start = time.process_time()
    fn()
    return (time.process_time() - start) * 1e3


def measure(path: Path, repeats: int) -> dict:
    """One file: {"name", "n", "bits", "same_bytes", "before"/"after": {stream bytes, "total", "octree_ms",
    "unpack_ms"}}."""
    data = path.read_bytes()
    f = tw.unpack(data)
    if not isinstance(f, TetWeaveFileV2):
        raise SystemExit(f"{path}: not a version-2 file")
    files = {
        "before": pack_v2(replace(f, flags=f.flags & ~FLAG_OCTREE_CONTEXTS, sizes=None)),
        "after": pack_v2(replace(f, flags=f.flags | FLAG_OCTREE_CONTEXTS, sizes=None)),
    }
    out = {"name": path.name, "n": f.num_points, "bits": f.position_bits}
    out["same_bytes"] = None if f.flags & FLAG_OCTREE_CONTEXTS else files["before"] == data
    sections = {}
    for key, blob in files.items():
        g = tw.unpack(blob)
        same = np.array_equal(g.cells, f.cells) and np.array_equal(g.s_sym, f.s_sym)
        if not (same and np.array_equal(g.c_sym, f.c_sym)):
            raise SystemExit(f"{path}: the {key} coding does not decode to the file's symbols")
        out[key] = {s: g.sizes[s] for s in STREAMS} | {"total": len(blob)}
        start = g.sizes["header"]
        contexts = key == "after"
        pos = blob[start : start + g.sizes["positions"]]
        size = octree.model_size(pos, f.position_bits, f.num_points, contexts)
        sections[key] = (pos[:size], pos[size:], contexts)
    times = {key: {"octree_ms": [], "unpack_ms": []} for key in files}
    for _ in range(repeats):
        for key, blob in files.items():  # back to back: before and after see the same machine load
            models, words, contexts = sections[key]
            times[key]["octree_ms"].append(
                _cpu_ms(lambda m=models, w=words, c=contexts: octree.decode(m, w, f.position_bits, f.num_points, c))
            )
            times[key]["unpack_ms"].append(_cpu_ms(lambda b=blob: tw.unpack(b)))
    for key in files:
        out[key] |= {k: statistics.median(v) for k, v in times[key].items()}
    return out


def markdown(rows: list[dict]) -> str:
    """A table: bytes (bits/point) per stream before -> after, file bytes and change, decode medians."""
    lines = [
        "| file | N | b | positions B (bits/pt) | s B | c B | file B | change | octree decode ms | unpack ms |",
        "|---|---:|---:|---|---:|---:|---|---:|---|---|",
    ]
    for r in rows:
        b, a, n = r["before"], r["after"], r["n"]
        lines.append(
            f"| {r['name']} | {n:,} | {r['bits']} "
            f"| {b['positions']:,} ({8 * b['positions'] / n:.2f}) -> {a['positions']:,} ({8 * a['positions'] / n:.2f}) "
            f"| {a['s']:,} | {a['c']:,} | {b['total']:,} -> {a['total']:,} "
            f"| {100 * (a['total'] - b['total']) / b['total']:+.1f} % "
            f"| {b['octree_ms']:.1f} -> {a['octree_ms']:.1f} | {b['unpack_ms']:.0f} -> {a['unpack_ms']:.0f} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", type=Path, nargs="+")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--markdown", type=Path, default=None, help="also write the table here")
    args = ap.parse_args()
    rows = []
    for path in args.files:
        rows.append(measure(path, args.repeats))
        r = rows[-1]
        print(
            f"{r['name']}: {r['before']['total']} -> {r['after']['total']} bytes, positions "
            f"{r['before']['positions']} -> {r['after']['positions']}, same bytes before: {r['same_bytes']}",
            flush=True,
        )
    table = markdown(rows)
    print(table)
    if args.markdown:
        args.markdown.write_text(table + "\n")


if __name__ == "__main__":
    main()
