"""Speed of `fit.features.unique_rows` against `np.unique(axis=0)` (its baseline, measured in the same run).

Welding the input's vertices and grouping its edges run in every encode (`detect_features`, twice, and the rim of
open inputs). Prints, per shared mesh, the median of --repeats runs of each and their ratio, and checks that both
give the same rows, inverse and counts.

    python benchmarks/unique_rows_speed.py [--meshes /work/shared/meshes] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import trimesh

from tetweave_codec.fit.features import unique_rows


def _median_seconds(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "meshes")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    print(f"{'mesh':16} {'rows':>9} {'what':8} {'np.unique':>10} {'unique_rows':>12} {'ratio':>6}")
    for path in sorted(args.meshes.glob("*.ply")):
        m = trimesh.load(path, process=False)
        v, f = np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)
        edges = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        for what, rows in (("vertices", v), ("edges", edges)):
            want = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
            got = unique_rows(rows)
            for a, b in zip(want, got, strict=True):
                np.testing.assert_array_equal(np.asarray(a).reshape(b.shape), b)
            base = _median_seconds(
                lambda r=rows: np.unique(r, axis=0, return_inverse=True, return_counts=True), args.repeats
            )
            new = _median_seconds(lambda r=rows: unique_rows(r), args.repeats)
            print(f"{path.stem:16} {len(rows):9,} {what:8} {base:9.3f}s {new:11.3f}s {base / new:5.1f}x")


if __name__ == "__main__":
    main()
