"""Speed of the closest-point trees: the fit's mesh tree on FCPW (`FitSurfaceTree`) against libigl's (`SurfaceTree`).

The fit rebuilds the tree of its current mesh at every topology change and queries it with 8,000 input samples
(fit/surface_loss.py), so both the build and the query count. Per mesh, median of `--repeats` runs after one
warm-up, CPU or wall clock (`--clock`): build, query of `--queries` points near the surface (uniform on the faces,
moved by N(0, 0.003) in the normalized frame), and build + query, libigl then FCPW, with the ratio FCPW / libigl.
Also the largest difference of the two trees' distances (FCPW picks the face in float32).

Meshes: the decoded surfaces of the `.tw` files in `--files DIR` (e.g. decode_speed's cache of the shared meshes'
files: 4x-subdivided surfaces of 74K-326K faces, what the fit's tree holds), else icospheres of 20K / 82K / 328K
faces.

    python -m tetweave_codec.benchmarks.closest_speed --threads 1
    python -m tetweave_codec.benchmarks.closest_speed --files ~/.cache/tetweave/decode_speed --clock wall
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np


def _meshes(files: Path | None) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, vertices (V,3), faces (F,3)) of each decoded file in `files`, or of three icospheres."""
    if files is not None:
        from tetweave_codec.decoder import decode_detailed
        from tetweave_codec.metrics.fidelity import normalization, to_frame

        out = []
        for path in sorted(Path(files).glob("*.tw")):
            r = decode_detailed(path.read_bytes())
            v = np.asarray(r.vertices, np.float64)
            scale, offset = normalization(v)
            out.append((path.stem, to_frame(v, scale, offset), np.asarray(r.faces, np.int64)))
        if out:
            return out
    import trimesh

    return [
        (f"icosphere {k}", np.asarray(m.vertices, np.float64) * 0.9, np.asarray(m.faces, np.int64))
        for k, m in ((k, trimesh.creation.icosphere(subdivisions=k)) for k in (5, 6, 7))
    ]


def _queries(v: np.ndarray, f: np.ndarray, n: int, seed: int) -> np.ndarray:
    from tetweave_codec.geometry.triangles import sample_surface

    points, _ = sample_surface(v, f, n, seed)
    return points + np.random.default_rng(seed).normal(0.0, 0.003, points.shape)


def _time(fn, repeats: int, clock) -> float:
    fn()  # warm-up
    runs = []
    for _ in range(repeats):
        t0 = clock()
        fn()
        runs.append(clock() - t0)
    return statistics.median(runs)


def _measure(tree, v: np.ndarray, f: np.ndarray, q: np.ndarray, repeats: int, clock) -> tuple[float, float, float]:
    """Median seconds of building `tree` over (v, f), of querying q with it, and of both in a row."""
    built = tree(v, f)
    return (
        _time(lambda: tree(v, f), repeats, clock),
        _time(lambda: built.query(q), repeats, clock),
        _time(lambda: tree(v, f).query(q), repeats, clock),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--files", type=Path, default=None, help="a folder of .tw files (default: icospheres)")
    parser.add_argument("--queries", type=int, default=8_000, help="query points per tree (default: 8,000)")
    parser.add_argument("--repeats", type=int, default=7, help="runs per measurement; medians (default: 7)")
    parser.add_argument("--clock", choices=["cpu", "wall"], default="cpu", help="process CPU time or wall clock")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    from tetweave_codec.geometry.closest import FitSurfaceTree, SurfaceTree, fcpw_module

    if fcpw_module() is None:
        print("fcpw is not installed (the `fast` extra): FitSurfaceTree is libigl's tree, nothing to compare")
        return 1
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    print(f"{args.clock} ms, median of {args.repeats}; {args.queries:,} queries per tree")
    print("| mesh | faces | libigl build | query | both | FCPW build | query | both | FCPW / libigl | max |d| diff |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    ratios = []
    for name, v, f in _meshes(args.files):
        q = _queries(v, f, args.queries, args.seed)
        row = [_measure(tree, v, f, q, args.repeats, clock) for tree in (SurfaceTree, FitSurfaceTree)]
        diff = np.abs(np.sqrt(SurfaceTree(v, f).query(q)[0]) - np.sqrt(FitSurfaceTree(v, f).query(q)[0])).max()
        ratio = row[1][2] / row[0][2]
        ratios.append(ratio)
        cells = " | ".join(f"{1e3 * x:.1f}" for part in row for x in part)
        print(f"| {name} | {len(f):,} | {cells} | {ratio:.2f} | {diff:.1e} |", flush=True)
    print(f"build + query, FCPW / libigl: median {statistics.median(ratios):.2f} over {len(ratios)} meshes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
