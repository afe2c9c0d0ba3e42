"""Speed of decoding real `.tw` version-2 files: each stage against the Delaunay tetrahedralization it feeds.

Input: rate-controlled files of the shared meshes (../shared/meshes) at 5-40 KB. Fitting them takes minutes each,
so they are cached outside git: `--files DIR` (default: $TETWEAVE_DECODE_FILES or ~/.cache/tetweave/decode_speed)
holds MESH_SIZE.tw; a missing one is encoded first with
`tetweave encode MESH --size SIZE --quality fast --threads 1 -q` (the decoder's work depends on the points and the
bytes, not on how long the fit ran). `--no-encode` times only the files already there.

Per file, median of `--repeats` runs after one warm-up, with the clock of `--clock`:

* the API stages of `decode_detailed`: unpack (range decoding, the octree and the s prediction), Delaunay,
  marching tets, smoothing (the decoder's filter: Taubin steps, Loop subdivision and the self-intersection check;
  0 for unfiltered files), and their
  total (input-frame transform included);
* "s pred": the part of unpack spent in the s prediction (`predict.reconstruct`: neighbour search, weights and
  the sequential pass), timed on its own;
* "CLI": `tetweave decode FILE -o OUT.ply` as a fresh process, from process start to the file written (with
  `--clock cpu` the process's user + system CPU time, else wall clock), so interpreter start-up and imports count;
* ratios of unpack, total and CLI to the Delaunay time of the same file.

`--committed` times the default (filtered: Taubin smoothing, Loop subdivision) files the benchmark committed,
benchmarks/results/files/MESH/size-BYTES-sh-auto.tw, instead of the cache. `--levels control,smoothed,full` times
each decode level (`tetweave decode --level`) of every file, API and CLI, against the same file's Delaunay time
measured in the same run. `--memory` adds the peak resident memory (ru_maxrss) of one `tetweave decode` process
per file and level.

`--native both` times every file twice in turn, with the compiled fast paths (formats/_native.c,
geometry/_mt_native.c, geometry/_intersect_native.c) and with the numpy/Python reference code alone
(`TETWEAVE_NATIVE=0` for the CLI): the before/after comparison in one run. `off` and `on` time one of them
(default: `on`, whatever is built).

    python -m tetweave_codec.benchmarks.decode_speed --threads 1
    python -m tetweave_codec.benchmarks.decode_speed --sizes 40k --meshes fandisk,spot --repeats 9 --no-encode
    python -m tetweave_codec.benchmarks.decode_speed --threads 1 --no-encode --sizes 10k,40k --clock cpu --native both
    python -m tetweave_codec.benchmarks.decode_speed --threads 1 --committed --sizes 10k,40k --clock cpu \
        --levels control,smoothed,full --memory
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DEFAULT_SIZES = "5k,10k,20k,40k"
LEVELS = ("control", "smoothed", "full")
COMMITTED = Path(__file__).resolve().parent / "results" / "files"  # MESH/size-BYTES-sh-auto.tw
DEFAULT_MESH_DIR = Path(__file__).resolve().parent.parent.parent / "shared" / "meshes"
CACHE_ENV = "TETWEAVE_DECODE_FILES"


def default_cache() -> Path:
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "tetweave" / "decode_speed")


def parse_sizes(text: str) -> list[tuple[str, int]]:
    """'5k,40k,1000' -> [('5k', 5120), ('40k', 40960), ('1000', 1000)] (k = 1024)."""
    out = []
    for item in text.split(","):
        item = item.strip().lower()
        if not item:
            continue
        mult = 1024 if item.endswith("k") else 1
        value = int(float(item[:-1] if item.endswith("k") else item) * mult)
        if value < 100:
            raise argparse.ArgumentTypeError(f"size {item!r} is below 100 bytes")
        out.append((item, value))
    return out


def ensure_file(mesh: Path, size: str, cache: Path, encode: bool) -> Path | None:
    """cache/MESH_SIZE.tw, encoded from `mesh` when missing and `encode` is set (None when missing)."""
    path = cache / f"{mesh.stem}_{size}.tw"
    if path.exists() or not encode:
        return path if path.exists() else None
    cache.mkdir(parents=True, exist_ok=True)
    print(f"# encoding {path} (--size {size} --quality fast --threads 1) ...", file=sys.stderr, flush=True)
    cmd = [sys.executable, "-m", "tetweave_codec.cli.main", "encode", str(mesh), "-o", str(path)]
    subprocess.run(cmd + ["--size", size, "--quality", "fast", "--threads", "1", "-q"], check=True)
    return path


def committed_file(mesh: Path, size: int) -> Path | None:
    """The committed default file of `mesh` at `size` bytes (None when there is none)."""
    path = COMMITTED / mesh.stem / f"size-{size}-sh-auto.tw"
    return path if path.exists() else None


def set_native(on: bool) -> None:
    """Switch the compiled fast paths of the decoder on (where built) or off (the numpy/Python reference)."""
    from tetweave_codec.formats import predict
    from tetweave_codec.geometry import intersections, marching_tets, smoothing, subdivision

    predict.NATIVE = on and predict._native is not None
    marching_tets.NATIVE = on and marching_tets._mt_native is not None
    intersections.NATIVE = on and intersections._intersect_native is not None
    smoothing.NATIVE = subdivision.NATIVE = on and smoothing._filter_native is not None


def time_api(data: bytes, repeats: int, clock: str, level: str = "full") -> dict:
    """Median seconds per stage of `decode_detailed` at `level` and of the s prediction alone over `repeats`
    runs."""
    from tetweave_codec.decoder import decode_detailed
    from tetweave_codec.formats import predict
    from tetweave_codec.formats.common import FLAG_S_PREDICTED

    timer = time.process_time if clock == "cpu" else time.perf_counter
    res = decode_detailed(data, level=level)  # warm-up: imports, first-touch allocations
    tw = res.container
    predicted = getattr(tw, "version", 1) == 2 and tw.flags & FLAG_S_PREDICTED
    residual = predict.residuals(tw.cells, tw.s_sym) if predicted else None
    runs = []
    for _ in range(repeats):
        start = timer()
        res = decode_detailed(data, clock=timer, level=level)
        total = timer() - start
        row = dict(res.seconds, total=total)
        if predicted:
            start = timer()
            predict.reconstruct(tw.cells, residual)
            row["s_pred"] = timer() - start
        runs.append(row)
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    med.update(points=tw.num_points, faces=len(res.faces))
    return med


def time_cli(path: Path, repeats: int, native: bool = True, level: str = "full", clock: str = "wall") -> float:
    """Median seconds of `tetweave decode path -o tmp.ply --level level` in a fresh process, start to file
    written: wall clock, or (clock "cpu") the process's user + system CPU time. Its modules' bytecode is cached
    (written by a warm-up run), as an installed package's is."""
    import resource

    env = dict(os.environ, TETWEAVE_NATIVE="1" if native else "0")
    # bytecode cached as an installed package's is (the warm-up run writes it): not the compiling of the modules
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.ply"
        cmd = [sys.executable, "-m", "tetweave_codec.cli.main", "decode", str(path), "-o", str(out), "--level", level]
        subprocess.run(cmd, check=True, capture_output=True, env=env)  # warm-up: file system caches
        for _ in range(repeats):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            start = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True, env=env)
            wall = time.perf_counter() - start
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            times.append(cpu if clock == "cpu" else wall)
    return statistics.median(times)


def peak_memory(path: Path, native: bool = True, level: str = "full") -> float:
    """Peak resident memory (MB) of one `tetweave decode path -o tmp.ply --level level` process: VmHWM of
    /proc/self/status where there is one (Linux; reset by exec, where ru_maxrss keeps the forking parent's peak),
    else ru_maxrss."""
    env = dict(os.environ, TETWEAVE_NATIVE="1" if native else "0")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.ply"
        code = (
            "import resource, sys\n"
            "from tetweave_codec.cli.main import main\n"
            f"try:\n    main(['decode', {str(path)!r}, '-o', {str(out)!r}, '--level', {level!r}])\n"
            "except SystemExit:\n    pass\n"
            "try:\n"
            "    kb = next(int(x.split()[1]) for x in open('/proc/self/status') if x.startswith('VmHWM:'))\n"
            "except (OSError, StopIteration):\n"
            "    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
            "print(kb, file=sys.stderr)\n"
        )
        done = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True, env=env)
    return float(done.stderr.strip().splitlines()[-1]) / 1024.0  # KB (macOS' ru_maxrss would be bytes)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--meshes-dir", type=Path, default=DEFAULT_MESH_DIR,
                        help=f"folder of the input meshes (default: {DEFAULT_MESH_DIR})")  # fmt: skip
    parser.add_argument("--meshes", default="", help="comma-separated mesh names (default: every mesh there)")
    parser.add_argument("--sizes", type=parse_sizes, default=parse_sizes(DEFAULT_SIZES),
                        help=f"file sizes, k = 1024 (default: {DEFAULT_SIZES})")  # fmt: skip
    parser.add_argument("--files", type=Path, default=None,
                        help=f"cached .tw files (default: ${CACHE_ENV} or ~/.cache/tetweave/decode_speed)")  # fmt: skip
    parser.add_argument("--no-encode", action="store_true", help="time only the cached files; encode none")
    parser.add_argument("--committed", action="store_true",
                        help="time the committed default files (benchmarks/results/files), not the cache")  # fmt: skip
    parser.add_argument("--levels", default="full",
                        help="comma-separated decode levels: control, smoothed, full (default: full)")  # fmt: skip
    parser.add_argument("--memory", action="store_true",
                        help="also the peak resident memory of a decode process per file and level")  # fmt: skip
    parser.add_argument("--repeats", type=int, default=5, help="runs per file; medians (default: 5)")
    parser.add_argument("--cli-repeats", type=int, default=5, help="CLI runs per file, 0: none (default: 5)")
    parser.add_argument("--threads", type=int, default=0,
                        help="cap numpy/BLAS/OpenMP threads (0: library defaults) (default: 0)")  # fmt: skip
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="wall-clock or process CPU time of the API stages (default: wall)")  # fmt: skip
    parser.add_argument("--native", choices=("on", "off", "both"), default="on",
                        help="compiled fast paths on, off (numpy/Python reference) or both (default: on)")  # fmt: skip
    args = parser.parse_args(argv)
    levels = [x.strip() for x in args.levels.split(",") if x.strip()]
    if not levels or any(x not in LEVELS for x in levels):
        parser.error(f"--levels: choose from {', '.join(LEVELS)}")
    if args.threads:
        # Before numpy is imported (lazily, below; the CLI subprocesses inherit them): pools read these at start-up.
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[var] = str(args.threads)
    from tetweave_codec.bench.batch import find_meshes

    wanted = {m.strip() for m in args.meshes.split(",") if m.strip()}
    meshes = [m for m in find_meshes(args.meshes_dir) if not wanted or m.stem in wanted]
    cache = args.files or default_cache()
    source = "the committed default files (benchmarks/results/files)" if args.committed else str(cache)
    print(f"# decode speed ({args.clock} clock for the API stages and the CLI): real v2 files from {source}, "
          f"median of {args.repeats} (CLI {args.cli_repeats}); ratios against the same file's Delaunay (TetGen) "
          "time in the same run")  # fmt: skip
    header = ["file", "level", "bytes", "points", "faces", "code", "unpack ms", "s pred ms", "Delaunay ms",
              "marching tets ms", "filter ms", "total ms", "unpack / Delaunay", "total / Delaunay", "CLI ms",
              "CLI / Delaunay"] + (["peak MB"] if args.memory else [])  # fmt: skip
    print("| " + " | ".join(header) + " |")
    print("|---|" + "|".join("---:" for _ in header[1:]) + "|")
    for label, size in sorted(set(args.sizes), key=lambda item: item[1]):
        for mesh in meshes:
            if args.committed:
                path = committed_file(mesh, size)
            else:
                path = ensure_file(mesh, label, cache, not args.no_encode)
            if path is None:
                continue
            data = path.read_bytes()
            name = f"{mesh.stem}_{label}" if args.committed else path.stem
            natives = {"on": (True,), "off": (False,), "both": (False, True)}[args.native]
            for level, native in [(lv, nat) for lv in levels for nat in natives]:
                set_native(native)
                t = time_api(data, args.repeats, args.clock, level)
                dl = t["delaunay"]
                cli = time_cli(path, args.cli_repeats, native, level, args.clock) if args.cli_repeats else float("nan")
                s_pred = f"{1e3 * t['s_pred']:.1f}" if "s_pred" in t else "-"
                ms = {
                    k: f"{1e3 * t.get(k, 0.0):.1f}"
                    for k in ("unpack", "delaunay", "marching_tets", "smoothing", "total")
                }
                row = [name, level, f"{len(data):,}", f"{t['points']:,}", f"{t['faces']:,}",
                       "compiled" if native else "reference", ms["unpack"], s_pred, ms["delaunay"],
                       ms["marching_tets"], ms["smoothing"], ms["total"], f"{t['unpack'] / dl:.2f}",
                       f"{t['total'] / dl:.2f}",
                       f"{1e3 * cli:.0f}", f"{cli / dl:.1f}"]  # fmt: skip
                if args.memory:
                    row.append(f"{peak_memory(path, native, level):.0f}")
                print("| " + " | ".join(row) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
