"""Stage times of the decoder core (decoder/*.c, `tw_decode`) on real `.tw` files, against TetGen.

Builds benchmarks/core_stages.c (a timing driver linked with the core's sources; see its header for how the
filter's stages are timed) from the working tree's decoder/ and, with `--baseline REV`, from decoder/ at git
revision REV as well, then runs them in alternation (`--rounds` rounds; each run decodes every file once to warm
up, then once timed) with the one-thread TetGen Delaunay of the same points (`geometry.delaunay.tetrahedralize(
points, "tetgen")`, the decoder's float points) timed in this process between the runs. Prints per file and level
the min / median of each stage in ms, and total / TetGen (medians). The builds' output hashes (positions and
indices of the decoded mesh) must agree: a change of the core that is not bit for bit stops the run.

Stages: parse (tw_parse: container, octree, s and c sections, s prediction), delaunay, marching (tets),
filter = edges (half-edges) + taubin (Taubin steps, creases, transforms, copies) + loop (Loop levels) + check (the
first crossing check) + recheck (the restore rounds' checks), holes, export (decode.c's copy into the tw_mesh).

    python benchmarks/core_stages.py
    python benchmarks/core_stages.py --baseline HEAD --levels control,smoothed,full --rounds 7 --clock cpu
    python benchmarks/core_stages.py --files tests/data --sizes '' --rounds 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
COMMITTED = ROOT / "benchmarks" / "results" / "files"  # MESH/size-BYTES-sh-auto.tw
DRIVER = ROOT / "benchmarks" / "core_stages.c"
LEVELS = {"control": 0, "smoothed": 1, "full": 2}
FLAGS = ["-O2", "-ffp-contract=off", "-fno-fast-math", "-pthread"]
# filter.c's calls of these land in the driver's timed wrappers
RENAMES = ["-Dtw_self_intersecting=bench_self_intersecting", "-Dtw_loop_level=bench_loop_level",
           "-Dtw_half_edges=bench_half_edges", "-Dtw_self_intersecting_kept=bench_self_intersecting_kept"]  # fmt: skip
STAGES = ("parse", "delaunay", "marching", "filter", "edges", "taubin", "loop", "check", "recheck", "holes", "export",
          "total")  # fmt: skip


def build(decoder: Path, out: Path, cc: str) -> Path:
    """Compile the core in `decoder` with the driver into `out`/core_stages (objects in parallel, 2 at a time)."""
    out.mkdir(parents=True, exist_ok=True)
    sources = sorted(decoder.glob("*.c"))

    def compile_one(src: Path) -> Path:
        obj = out / (src.stem + ".o")
        extra = RENAMES if src.name == "filter.c" else []
        subprocess.run([cc, *FLAGS, *extra, f"-I{decoder}", "-c", str(src), "-o", str(obj)], check=True)
        return obj

    with ThreadPoolExecutor(2) as pool:
        objs = list(pool.map(compile_one, sources + [DRIVER]))
    exe = out / "core_stages"
    subprocess.run([cc, "-pthread", *map(str, objs), "-lm", "-o", str(exe)], check=True)
    return exe


def baseline_decoder(rev: str, tmp: Path) -> Path:
    """decoder/ at git revision `rev`, extracted under tmp."""
    dest = tmp / "baseline"
    dest.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "decoder"], check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive.stdout, check=True)
    return dest / "decoder"


def run_driver(exe: Path, files: list[Path], level: int, threads: int, clock: str) -> dict[str, dict]:
    """One decode per file to warm up, then one timed: {file: {stage: ms, 'hash': str, ...}}."""
    cmd = [str(exe), "-r", "2", "-l", str(level), "-t", str(threads), "-c", clock, *map(str, files)]
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    rows = {}
    for line in done.stdout.splitlines():
        name, run, *fields = line.split()
        if run == "0":
            continue
        kv = dict(f.split("=", 1) for f in fields)
        rows[name] = {k: (v if k == "hash" else float(v)) for k, v in kv.items()}
    return rows


def tetgen_ms(points, clock: str) -> float:
    from tetweave_codec.geometry.delaunay import tetrahedralize

    timer = time.process_time if clock == "cpu" else time.perf_counter
    start = timer()
    tetrahedralize(points, "tetgen")
    return 1e3 * (timer() - start)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--files", type=Path, default=COMMITTED, help="folder of .tw files (MESH/size-BYTES-*.tw)")
    parser.add_argument("--sizes", default="40960", help="comma-separated BYTES of MESH/size-BYTES-*.tw ('': *.tw)")
    parser.add_argument("--levels", default="full", help="comma-separated: control, smoothed, full")
    parser.add_argument("--rounds", type=int, default=5, help="alternating timed runs per build (default: 5)")
    parser.add_argument("--threads", type=int, default=1, help="threads of the crossing checks (default: 1)")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall")
    parser.add_argument("--baseline", default="", help="git revision whose decoder/ is timed as well")
    parser.add_argument("--no-tetgen", action="store_true", help="do not time TetGen")
    parser.add_argument("--cc", default=os.environ.get("CC", "cc"))
    args = parser.parse_args(argv)
    levels = [x.strip() for x in args.levels.split(",") if x.strip()]
    if not levels or any(x not in LEVELS for x in levels):
        parser.error("--levels: choose from control, smoothed, full")
    sizes = [s.strip() for s in args.sizes.split(",") if s.strip()]
    files = sorted(p for s in sizes for p in args.files.glob(f"*/size-{s}-*.tw")) if sizes else []
    files = files or sorted(args.files.glob("*.tw"))
    if not files:
        print(f"no .tw files under {args.files}", file=sys.stderr)
        return 2
    points = {}
    if not args.no_tetgen:
        from tetweave_codec.formats.tw import unpack

        points = {str(p): unpack(p.read_bytes()).points for p in files}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        builds = {"new": build(ROOT / "decoder", tmp / "new", args.cc)}
        if args.baseline:
            builds = {"base": build(baseline_decoder(args.baseline, tmp), tmp / "base", args.cc), **builds}
        samples: dict = {}  # (build, file, level) -> list of rows
        tet: dict = {}  # file -> list of ms
        for _ in range(args.rounds):
            for level in levels:
                for name, exe in builds.items():
                    for f, row in run_driver(exe, files, LEVELS[level], args.threads, args.clock).items():
                        samples.setdefault((name, f, level), []).append(row)
            for f, pts in points.items():
                tet.setdefault(f, []).append(tetgen_ms(pts, args.clock))
    print(f"# decoder core stages, ms ({args.clock} clock, {args.threads} thread(s)), min / median of {args.rounds} "
          "alternating runs; TetGen: one thread, the same points, in between")  # fmt: skip
    header = ["file", "level", "build", "faces", *STAGES, "TetGen", "total / TetGen"]
    print("| " + " | ".join(header) + " |")
    print("|---|---|---|" + "|".join("---:" for _ in header[3:]) + "|")
    for f in map(str, files):
        label = f"{Path(f).parent.name} {Path(f).stem.split('-')[1]}"
        t_med = statistics.median(tet[f]) if f in tet else float("nan")
        t_cell = f"{min(tet[f]):.1f} / {t_med:.1f}" if f in tet else "-"
        for level in levels:
            hashes = {samples[(b, f, level)][0]["hash"] for b in builds}
            if len(hashes) != 1:
                print(f"{label} {level}: the builds' outputs differ ({sorted(hashes)})", file=sys.stderr)
                return 1
            for b in builds:
                rows = samples[(b, f, level)]
                cells = [f"{min(r[s] for r in rows):.1f} / {statistics.median(r[s] for r in rows):.1f}" for s in STAGES]
                ratio = statistics.median(r["total"] for r in rows) / t_med
                print(f"| {label} | {level} | {b} | {int(rows[0]['faces']):,} | " + " | ".join(cells)
                      + f" | {t_cell} | {ratio:.2f} |")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
