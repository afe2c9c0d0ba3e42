"""Decode speed before / after in one run: the committed default files decoded by an older commit's code and by
this tree, interleaved (docs/measurements/decode_speed.md).

    OMP_NUM_THREADS=1 python docs/measurements/decode_speed_ab.py ffee759 [--repeats 5] [--stages] [--unfiltered]

The older commit's source is unpacked into a temporary folder (`git archive`), its C extensions built there
(`setup.py build_ext --inplace`), `cli`, `formats` and `benchmarks` linked into its package (what the editable
install's package-dir mapping does), and each measurement runs in a subprocess with one tree first on PYTHONPATH.
Rows: the API stages (`decoder.decode_detailed`, CPU ms, medians) and the CLI (`python -m tetweave_codec.cli.main
decode FILE -o OUT.ply`, the child's user + system CPU ms, medians), with ratios to the same run's Delaunay time.
`--stages`: the filter's own stages of the 40 KB files (edges, Taubin, Loop + midpoint, first and later crossing
checks, best of 3). `--unfiltered`: the same files with their smoothing and subdivision flags cleared.

`--threads 1,2` (issue 47): wall time instead of CPU time, the older commit's decode against this tree's at each
thread count (`decode(..., threads=N)`, `tetweave decode --threads N`), the 40 KB files (`--sizes` to change):
API and CLI medians, their ratios to TetGen's one-thread Delaunay time of the same points (the median of every
Delaunay time measured for that file in the run, whatever the tree or thread count: TetGen runs on one thread),
the API's CPU / wall (below 1.5 at two threads: the second core did not help), and whether the
decoded meshes are the same bytes: SHA-256 of the API's vertex and face arrays and of the CLI's OBJ file, against
the older commit's. The CLI writes OBJ, the default output. Rounds interleave the trees and thread counts.

    python docs/measurements/decode_speed_ab.py 3678c5c --threads 1,2 --repeats 7
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tetweave_codec.benchmarks.common import REPO, commit_tree

MESHES = ("fandisk", "igea", "spot", "stanford-bunny")
SIZES = (10240, 40960)

API = """
import json, statistics, sys, time
from tetweave_codec.decoder import decode_detailed
data = open(sys.argv[1], "rb").read(); reps = int(sys.argv[2])
decode_detailed(data)
rows = []
for _ in range(reps):
    t = time.process_time(); r = decode_detailed(data, clock=time.process_time); tot = time.process_time() - t
    rows.append(dict(r.seconds, total=tot))
print(json.dumps({k: 1e3 * statistics.median(x[k] for x in rows) for k in rows[0]} | {"faces": len(r.faces)}))
"""

# wall-clock API decode at a thread count ("" = the older tree, without the keyword): medians and the SHA-256
API_WALL = """
import hashlib, json, statistics, sys, time
from tetweave_codec.decoder import decode_detailed
data = open(sys.argv[1], "rb").read(); reps = int(sys.argv[2])
kw = {"threads": int(sys.argv[3])} if sys.argv[3] else {}
r = decode_detailed(data, **kw)
rows = []
for _ in range(reps):
    w, c = time.perf_counter(), time.process_time(); r = decode_detailed(data, **kw)
    rows.append(dict(r.seconds, total=time.perf_counter() - w, cpu=time.process_time() - c))
sha = hashlib.sha256(r.vertices.tobytes() + r.faces.tobytes()).hexdigest()
print(json.dumps({k: 1e3 * statistics.median(x[k] for x in rows) for k in rows[0]}
                 | {"faces": len(r.faces), "sha": sha, "delaunay_all": [1e3 * x["delaunay"] for x in rows]}))
"""

STAGES = """
import inspect, json, sys, time, numpy as np
from tetweave_codec.formats.tw import unpack
from tetweave_codec.geometry.delaunay import tetrahedralize
from tetweave_codec.geometry.marching_tets import marching_tets_numpy
from tetweave_codec.geometry import smoothing as sm, subdivision as sd, surface_filter as sf
tw = unpack(open(sys.argv[1], "rb").read())
pts = np.asarray(tw.points, np.float64); tz = tetrahedralize(pts, tw.backend)
c = None if tw.sh_degree < 0 else np.asarray(tw.c, np.float64)
mt = marching_tets_numpy(pts, tz.tets, np.asarray(tw.s, np.float64), c, tz.hull_faces)
v0, f0 = mt.vertices, mt.faces
T = time.process_time
calls = []
check = sf.self_intersecting_faces
def timed(v, f, only=None, **kw):
    t = T(); r = check(v, f, only=only, **kw); calls.append(T() - t); return r
sf.self_intersecting_faces = timed
# the hint that the faces are a Loop level's children, where the tree's restore_crossings takes it
kw = {'children': 4} if tw.subdivision > 0 and 'children' in inspect.signature(sf.restore_crossings).parameters else {}
best = None
for _ in range(3):
    calls.clear()
    t0 = T(); e = sm.mesh_edges(f0, len(v0), closed=True); t1 = T()
    v = sm.taubin(v0, f0, tw.smoothing, edges=e); t2 = T()
    v2, r2, f2 = sd.loop_and_midpoint(v, v0, f0, tw.subdivision, neighbours=e); t3 = T()
    sf.restore_crossings(v2, r2, f2, **kw)
    row = [t1 - t0, t2 - t1, t3 - t2, calls[0], sum(calls[1:])]
    best = row if best is None or sum(row) < sum(best) else best
print(json.dumps([1e3 * x for x in best] + [len(calls) - 1]))
"""


def env_for(tree: Path) -> dict:
    """One thread each; bytecode cached as an installed package's is (PYTHONDONTWRITEBYTECODE dropped: the
    warm-up run writes it), so that the CLI's time is not the compiling of its modules."""
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(tree))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def run_code(code: str, tree: Path, *args: str) -> object:
    done = subprocess.run([sys.executable, "-c", code, *args], check=True, capture_output=True, text=True,
                          env=env_for(tree), cwd=tempfile.gettempdir())  # fmt: skip
    return json.loads(done.stdout)


def cli_cpu(tree: Path, path: Path, repeats: int) -> float:
    """Median user + system CPU ms of `tetweave decode path -o tmp.ply` in a fresh process."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "tetweave_codec.cli.main", "decode", str(path), "-o", str(Path(tmp) / "o.ply")]
        kw = dict(check=True, capture_output=True, env=env_for(tree), cwd=tmp)
        subprocess.run(cmd, **kw)  # warm-up: file system caches
        times = []
        for _ in range(repeats):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            subprocess.run(cmd, **kw)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            times.append(1e3 * ((after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)))
    return statistics.median(times)


def busy_cores(seconds: float = 0.3) -> float:
    """Cores busy with other processes over `seconds` (this process sleeps meanwhile), from /proc/stat; 0 elsewhere."""

    def sample():
        with open("/proc/stat") as fh:
            x = [int(v) for v in fh.readline().split()[1:]]
        return sum(x), x[3] + x[4]  # all jiffies, idle + iowait

    try:
        (t0, i0), _, (t1, i1) = sample(), time.sleep(seconds), sample()
    except OSError:
        return 0.0
    return (os.cpu_count() or 1) * (1 - (i1 - i0) / max(1, t1 - t0))


def wait_idle(limit_s: float) -> bool:
    """Wait up to `limit_s` for the other cores to be idle (< 0.25 of a core busy): two-thread timings mean nothing
    while another process holds a core. True when they were idle."""
    end = time.monotonic() + limit_s
    while True:
        if busy_cores() < 0.25:
            return True
        if time.monotonic() > end:
            return False
        time.sleep(1.0)


def cli_wall(tree: Path, path: Path, threads: str, out: Path) -> float:
    """Wall ms of one `tetweave decode path -o out.obj [--threads N]` in a fresh process (bytecode cached)."""
    cmd = [sys.executable, "-m", "tetweave_codec.cli.main", "decode", str(path), "-o", str(out)]
    cmd += ["--threads", threads] if threads else []
    start = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, env=env_for(tree), cwd=out.parent)
    return 1e3 * (time.perf_counter() - start)


def threads_table(trees: dict, files: list[Path], counts: list[str], repeats: int, tmp: Path, idle_s: float) -> None:
    """The `--threads` table (module docstring): per file, the older tree and this tree at each thread count; each
    measurement waits up to `idle_s` for the other cores to be idle (the count that did not get them is
    printed at the end)."""
    busy = 0
    print("| file | code | threads | faces | Delaunay | API | API / Delaunay | API CPU / wall | CLI | CLI / Delaunay "
          "| SHA-256 API / OBJ | same as before |")  # fmt: skip
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|")
    runs = [("before", trees["before"], "")] + [("after", trees["after"], n) for n in counts]
    for path in files:
        api, cli, outputs = {}, {}, {}
        for name, tree, n in runs:  # API medians (each its own process), then the CLI rounds interleaved
            busy += not wait_idle(idle_s)
            api[(name, n)] = run_code(API_WALL, tree, str(path), str(repeats), n)
        for _ in range(repeats + 1):  # the first round warms the file system caches and the bytecode
            for name, tree, n in runs:
                busy += not wait_idle(idle_s)
                out = tmp / f"{name}{n}.obj"
                cli.setdefault((name, n), []).append(cli_wall(tree, path, n, out))
                outputs[(name, n)] = hashlib.sha256(out.read_bytes()).hexdigest()
        delaunay = statistics.median(d for r in api.values() for d in r["delaunay_all"])
        base_api, base_cli = api[("before", "")]["sha"], outputs[("before", "")]
        for name, _, n in runs:
            r, c = api[(name, n)], statistics.median(cli[(name, n)][1:])
            same = "-" if name == "before" else (
                "yes" if r["sha"] == base_api and outputs[(name, n)] == base_cli else "**no**")  # fmt: skip
            hashes = f"{r['sha'][:10]} / {outputs[(name, n)][:10]}"
            print(f"| {path.parent.name} {path.stem} | {name} | {n or 1} | {r['faces']:,} | {delaunay:.1f} | "
                  f"{r['total']:.1f} | {r['total'] / delaunay:.2f} | {r['cpu'] / r['total']:.2f} | {c:.0f} | "
                  f"{c / delaunay:.2f} | {hashes} | {same} |", flush=True)  # fmt: skip
    print(f"\n{busy} measurements started while another process held a core (waited up to {idle_s:.0f} s each)")


def unfiltered(path: Path, out: Path) -> Path:
    """A copy of the file at `path` with its smoothing and subdivision flags cleared (same points)."""
    from dataclasses import replace

    from tetweave_codec.formats import common
    from tetweave_codec.formats.tw import unpack
    from tetweave_codec.formats.tw2 import pack_v2

    tw = unpack(path.read_bytes())
    flags = tw.flags & ~common.FLAG_SMOOTHING & ~common.FLAG_SUBDIVISION
    out.write_bytes(pack_v2(replace(tw, flags=flags, creases=False)))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("commit", help="the 'before' commit")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--stages", action="store_true", help="the filter's stages of the 40 KB files instead")
    parser.add_argument("--unfiltered", action="store_true", help="the files with their filter flags cleared")
    parser.add_argument("--threads", default="", help="e.g. 1,2: the wall-clock table at these thread counts")
    parser.add_argument("--sizes", default="", help="file sizes in bytes, e.g. 10240,40960 (default: both; 40960 "
                        "with --threads)")  # fmt: skip
    parser.add_argument("--wait-idle", type=float, default=0.0, help="with --threads: seconds each measurement "
                        "may wait for the other cores to be idle (default: 0)")  # fmt: skip
    args = parser.parse_args(argv)
    sizes = [int(x) for x in args.sizes.split(",") if x] or ([40960] if args.threads else list(SIZES))
    files = [REPO / "benchmarks/results/files" / m / f"size-{s}-sh-auto.tw" for s in sizes for m in MESHES]
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"before": commit_tree(args.commit, Path(tmp)), "after": REPO}
        if args.threads:
            counts = [x.strip() for x in args.threads.split(",") if x.strip()]
            threads_table(trees, files, counts, args.repeats, Path(tmp), args.wait_idle)
            return 0
        if args.stages:
            print("| file | code | edges | Taubin | Loop + midpoint | first crossing check | later checks | count |")
            print("|---|---|---:|---:|---:|---:|---:|---:|")
            for path in files[len(MESHES) :]:
                for name, tree in trees.items():
                    row = run_code(STAGES, tree, str(path))
                    cells = " | ".join(f"{x:.1f}" for x in row[:5])
                    print(f"| {path.parent.name} {path.stem} | {name} | {cells} | {row[5]} |", flush=True)
            return 0
        if args.unfiltered:
            files = [unfiltered(p, Path(tmp) / f"{p.parent.name}_{p.name}") for p in files]
        print("| file | code | faces | unpack | Delaunay | marching tets | filter | API total | API / Delaunay | CLI | "
              "CLI / Delaunay |")  # fmt: skip
        print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
        for path in files:
            for name, tree in trees.items():
                r = run_code(API, tree, str(path), str(args.repeats))
                cli = cli_cpu(tree, path, args.repeats)
                d = r["delaunay"]
                label = path.stem if args.unfiltered else f"{path.parent.name} {path.stem}"
                print(f"| {label} | {name} | "
                      f"{r['faces']:,} | {r['unpack']:.1f} | {d:.1f} | {r['marching_tets']:.1f} | "
                      f"{r['smoothing']:.1f} | {r['total']:.1f} | {r['total'] / d:.2f} | {cli:.0f} | {cli / d:.1f} |",
                      flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
