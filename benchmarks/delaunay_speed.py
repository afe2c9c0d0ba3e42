"""Speed of the Delaunay backends: "exact" (geometry/_delaunay_native.c) against TetGen (one thread) and Qhull.

Inputs: the points of real version-2 files, by default the files the benchmark committed,
benchmarks/results/files/MESH/size-BYTES-sh-auto.tw (`--sizes`, default 40k: the 40 KB bench files; `--files DIR`
reads DIR/MESH/size-*.tw or DIR/*.tw instead), decoded with `formats.tw.unpack` (the dequantized cell centres the
decoder triangulates); plus synthetic sets of `--points` (default 65536) float16-rounded points: a thin spherical
shell (radius 0.9-0.92, like a surface's sample points) and a uniform cube ([-1, 1]^3), unless `--no-synthetic`.

Per input, `geometry.delaunay.tetrahedralize(points, backend)` (the API call the decoder makes: "exact" includes
snapping the points to its integer lattice) is run `--repeats` times per backend, alternating, after one warm-up;
the median of `--clock` (cpu: this process's CPU time, robust on a loaded machine; wall: wall clock) is printed,
with the ratio TetGen / exact, and Qhull's time once (`--no-qhull` skips it). The tet counts of both are printed
too: they differ where points are cospherical (each backend breaks ties its own way). `--decode` also times the
API decode of each real file (`decoder.decode_detailed`, default level) with each backend.

    python -m tetweave_codec.benchmarks.delaunay_speed
    python -m tetweave_codec.benchmarks.delaunay_speed --sizes 5k,40k --repeats 9 --clock wall
    python -m tetweave_codec.benchmarks.delaunay_speed --only spot,igea --no-synthetic --no-qhull
    python -m tetweave_codec.benchmarks.delaunay_speed --no-synthetic --no-qhull --decode
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

COMMITTED = Path(__file__).resolve().parent / "results" / "files"  # MESH/size-BYTES-sh-auto.tw


def parse_sizes(text: str) -> list[int]:
    """'5k,40k,1000' -> [5120, 40960, 1000] (k = 1024)."""
    out = []
    for item in text.split(","):
        item = item.strip().lower()
        out.append(int(float(item[:-1]) * 1024) if item.endswith("k") else int(item))
    return out


def real_inputs(root: Path, sizes: list[int], only: str) -> list[tuple[str, np.ndarray, bytes]]:
    """(name, points (N, 3) float64, file bytes) of the v2 files under `root` at `sizes` (MESH/size-BYTES-*.tw,
    or *.tw)."""
    from tetweave_codec.formats.tw import unpack

    keep = set(only.split(",")) if only else None
    paths = sorted(p for b in sizes for p in root.glob(f"*/size-{b}-*.tw")) or sorted(root.glob("*.tw"))
    out = []
    for p in paths:
        mesh = p.parent.name if p.parent != root else p.stem
        if keep and mesh not in keep:
            continue
        tw = unpack(p.read_bytes())
        if getattr(tw, "cells", None) is None:
            continue  # a version-1 file: no grid
        out.append((f"{mesh} {p.stem.split('-')[1]} B", np.ascontiguousarray(tw.points), p.read_bytes()))
    return out


def synthetic_inputs(n: int, seed: int = 0) -> list[tuple[str, np.ndarray, None]]:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    shell = v * rng.uniform(0.9, 0.92, (n, 1))
    cube = rng.uniform(-1, 1, (n, 3))
    as16 = [np.unique(x.astype(np.float16).astype(np.float64), axis=0) for x in (shell, cube)]
    return [(f"shell {n // 1024}K", as16[0], None), (f"cube {n // 1024}K", as16[1], None)]


def time_backends(points: np.ndarray, backends: list[str], repeats: int, clock) -> dict[str, tuple[float, int]]:
    """Median seconds and tet count per backend: one warm-up each, then `repeats` rounds over the backends."""
    from tetweave_codec.geometry.delaunay import tetrahedralize

    counts = {b: len(tetrahedralize(points, b).tets) for b in backends}
    samples: dict[str, list[float]] = {b: [] for b in backends}
    for _ in range(repeats):
        for b in backends:
            t0 = clock()
            tetrahedralize(points, b)
            samples[b].append(clock() - t0)
    return {b: (statistics.median(samples[b]), counts[b]) for b in backends}


def time_decode(data: bytes, backends: list[str], repeats: int, clock) -> dict[str, float]:
    """Median seconds of `decoder.decode_detailed(data, backend)` per backend (a backend other than the file's gives
    another mesh where points are cospherical: the same work)."""
    import warnings

    from tetweave_codec.decoder import decode_detailed

    samples: dict[str, list[float]] = {b: [] for b in backends}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for b in backends:
            decode_detailed(data, b)
        for _ in range(repeats):
            for b in backends:
                t0 = clock()
                decode_detailed(data, b)
                samples[b].append(clock() - t0)
    return {b: statistics.median(samples[b]) for b in backends}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--files", type=Path, default=COMMITTED, help="folder of v2 files (default: the committed ones)")
    ap.add_argument("--sizes", default="40k", help="file sizes to take from --files, e.g. 5k,40k (k = 1024)")
    ap.add_argument("--only", default="", help="comma-separated mesh stems (default: all)")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--points", type=int, default=65536, help="points of the synthetic sets")
    ap.add_argument("--no-synthetic", action="store_true")
    ap.add_argument("--no-qhull", action="store_true")
    ap.add_argument("--clock", choices=["cpu", "wall"], default="cpu")
    ap.add_argument("--decode", action="store_true", help="also time the API decode of each file with each backend")
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.points < 4:
        ap.error("--repeats must be >= 1 and --points >= 4")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # no idle BLAS threads competing for the 2 cores
    from tetweave_codec.geometry.delaunay import available_backends

    have_tetgen = "tetgen" in available_backends()
    backends = ["exact"] + (["tetgen"] if have_tetgen else [])
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    inputs = real_inputs(args.files, parse_sizes(args.sizes), args.only) if args.files.is_dir() else []
    if not args.no_synthetic:
        inputs += synthetic_inputs(args.points)
    if not inputs:
        print(f"no inputs: no v2 files of sizes {args.sizes} under {args.files}", file=sys.stderr)
        return 2
    print(f"clock: {args.clock}, median of {args.repeats} (after one warm-up); TetGen one thread; Qhull once")
    cols = ("exact ms", "TetGen ms", "ratio", "Qhull ms")
    print(f"{'input':<22} {'points':>7} {cols[0]:>9} {cols[1]:>10} {cols[2]:>6} {cols[3]:>9}  tets exact / TetGen")
    ratios = []
    decodes = []
    for name, pts, data in inputs:
        res = time_backends(pts, backends, args.repeats, clock)
        ex_t, ex_n = res["exact"]
        tg = f"{1e3 * res['tetgen'][0]:10.1f}" if have_tetgen else f"{'-':>10}"
        ratio = res["tetgen"][0] / ex_t if have_tetgen else float("nan")
        ratios.append(ratio)
        qh = "-"
        if not args.no_qhull:
            from tetweave_codec.geometry.delaunay import tetrahedralize

            t0 = clock()
            tetrahedralize(pts, "qhull")
            qh = f"{1e3 * (clock() - t0):.0f}"
        counts = f"{ex_n} / {res['tetgen'][1]}" if have_tetgen else f"{ex_n}"
        print(f"{name:<22} {len(pts):>7} {1e3 * ex_t:9.1f} {tg} {ratio:6.2f} {qh:>9}  {counts}")
        if args.decode and data is not None and have_tetgen:
            decodes.append((name, time_decode(data, backends, args.repeats, clock)))
    if have_tetgen:
        print(f"TetGen / exact: median {statistics.median(ratios):.2f} (range {min(ratios):.2f}-{max(ratios):.2f})")
    if decodes:
        print("API decode (decoder.decode_detailed, default level) with each backend:")
        for name, res in decodes:
            ex, tg = res["exact"], res["tetgen"]
            faster = 100 * (1 - ex / tg)
            print(f"{name:<22} exact {1e3 * ex:7.1f} ms  TetGen {1e3 * tg:7.1f} ms  {faster:5.1f} % faster")
    return 0


if __name__ == "__main__":
    sys.exit(main())
