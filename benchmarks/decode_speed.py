"""Speed of decoding a `.tw` file: Delaunay tetrahedralization and directional marching tets per point count.

Input: points in a thin shell around a torus (R = 0.55, r = 0.25, normalized frame), the kind of point cloud
the encoder writes (only points near the surface are kept): shell half-thickness = mean point spacing,
sqrt(2 * area / N). s is the torus's signed distance, c random SH coefficients of degree 1 (as in the paper's
runtime table), everything rounded to float16 and packed into a real container, so the timings cover the full
`decode_detailed` path (unpack, Delaunay, marching tets; the input-frame transform is included in "total").

Each size is decoded `--repeats` times (after one warm-up run) with the default backend (TetGen) and with the
baseline backend (Qhull), in the same run; the table reports medians and the baseline / default ratio, so that
tables from noisy machines stay comparable.

    python -m tetweave_codec.benchmarks.decode_speed
    python -m tetweave_codec.benchmarks.decode_speed --sizes 8k,64k --repeats 5 --threads 1 --baseline none
    python -m tetweave_codec.benchmarks.decode_speed --clock cpu     # CPU time: steadier on a busy machine
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

TORUS_R, TORUS_r = 0.55, 0.25
DEFAULT_SIZES = "8k,16k,32k,64k,128k"


def parse_sizes(text: str) -> list[int]:
    """'8k,64k,1000' -> [8192, 65536, 1000] (k = 1024)."""
    sizes = []
    for item in text.split(","):
        item = item.strip().lower()
        mult = 1024 if item.endswith("k") else 1
        value = int(float(item[:-1] if item.endswith("k") else item) * mult)
        if value < 4:
            raise argparse.ArgumentTypeError(f"size {item!r} is below 4 points")
        sizes.append(value)
    return sizes


def torus_sdf(p):
    import numpy as np

    q = np.stack([np.hypot(p[:, 0], p[:, 2]) - TORUS_R, p[:, 1]], 1)
    return np.hypot(q[:, 0], q[:, 1]) - TORUS_r


def shell_points(n: int, seed: int = 0):
    """n points uniform in {|sdf| < h} around the torus, h = mean spacing; float16-representable."""
    import numpy as np

    rng = np.random.default_rng(seed)
    area = 4 * np.pi**2 * TORUS_R * TORUS_r
    half = np.sqrt(2 * area / n)
    lo = np.array([-(TORUS_R + TORUS_r + half), -(TORUS_r + half), -(TORUS_R + TORUS_r + half)])
    chunks, have = [], 0
    while have < n:
        p = rng.uniform(lo, -lo, (4 * n, 3))
        p = p[np.abs(torus_sdf(p)) < half]
        chunks.append(p)
        have += len(p)
    return np.concatenate(chunks)[:n].astype(np.float16)


def make_container(n: int, seed: int = 0) -> bytes:
    import numpy as np

    from tetweave_codec.formats.tw import TetWeaveFile, pack

    pts = shell_points(n, seed)
    s = torus_sdf(pts.astype(np.float64)).astype(np.float16)
    c = (np.random.default_rng(seed + 1).normal(size=(n, 4)) * 0.1).astype(np.float16)
    return pack(TetWeaveFile(pts, s, c, 1, 1.0, np.zeros(3)))


def time_decode(data: bytes, backend: str, repeats: int, clock: str = "wall") -> dict:
    """Median seconds per stage ("delaunay", "marching_tets", "total", ...) over `repeats` decodes.

    clock "wall" times stages with time.perf_counter, "cpu" with time.process_time (less sensitive to other jobs
    on a shared machine; decoding is single-threaded, so on a quiet machine both agree).
    """
    from tetweave_codec.decoder import decode_detailed

    timer = time.process_time if clock == "cpu" else time.perf_counter
    decode_detailed(data, backend)  # warm-up: imports, first-touch allocations
    runs = []
    for _ in range(repeats):
        start = timer()
        res = decode_detailed(data, backend, clock=timer)
        total = timer() - start
        runs.append(dict(res.seconds, total=total))
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    med.update(tets=res.num_tets, vertices=len(res.vertices), faces=len(res.faces))
    return med


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=parse_sizes, default=parse_sizes(DEFAULT_SIZES),
                        help=f"point counts, k = 1024 (default: {DEFAULT_SIZES})")  # fmt: skip
    parser.add_argument("--repeats", type=int, default=5, help="runs per size and backend; medians (default: 5)")
    parser.add_argument("--threads", type=int, default=0,
                        help="cap numpy/BLAS/OpenMP threads (0: library defaults) (default: 0)")  # fmt: skip
    parser.add_argument("--backend", default="auto", help="backend under test (default: auto = TetGen)")
    parser.add_argument("--baseline", default="qhull", help="baseline backend, or 'none' (default: qhull)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the point clouds (default: 0)")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="wall-clock or process CPU time (steadier on a busy machine) (default: wall)")  # fmt: skip
    args = parser.parse_args(argv)
    if args.threads:
        # Before numpy is imported (it is imported lazily below): thread pools read these at start-up.
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = str(args.threads)

    from tetweave_codec.geometry.delaunay import resolve_backend

    backend = resolve_backend(args.backend)
    baseline = None if args.baseline == "none" else resolve_backend(args.baseline)
    print(f"# decode speed ({args.clock} clock): torus shell, SH degree 1, median of {args.repeats}; backend {backend}"
          + (f", baseline {baseline}" if baseline else ""))  # fmt: skip
    header = ["points", "tets", "faces", "Delaunay ms", "marching tets ms", "total ms"]
    if baseline:
        header += [f"{baseline} Delaunay ms", f"{baseline} total ms", f"{baseline} / {backend}"]
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join("---:" for _ in header) + "|")
    for n in args.sizes:
        data = make_container(n, args.seed)
        main_t = time_decode(data, backend, args.repeats, args.clock)
        row = [f"{n:,}", f"{main_t['tets']:,}", f"{main_t['faces']:,}", f"{1e3 * main_t['delaunay']:.0f}",
               f"{1e3 * main_t['marching_tets']:.1f}", f"{1e3 * main_t['total']:.0f}"]  # fmt: skip
        if baseline:
            base_t = time_decode(data, baseline, args.repeats, args.clock)
            row += [f"{1e3 * base_t['delaunay']:.0f}", f"{1e3 * base_t['total']:.0f}",
                    f"{base_t['total'] / main_t['total']:.1f}x"]  # fmt: skip
        print("| " + " | ".join(row) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
