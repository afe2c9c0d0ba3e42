"""Batch throughput: files per hour of `tetweave encode DIR -o OUT --size 10k` with several runners on one machine.

    python -m tetweave_codec.benchmarks.batch_throughput --only spot,fandisk --generated 2 --out results.md

The inputs are the chosen shared meshes plus generated shapes (sphere, torus, a box with a spherical bite, a
capsule), copied into one folder. Each configuration runs the real command in a subprocess, one after the other
in the same run: by default `--jobs 1 --threads 2`, `--jobs 2 --threads 1` and `--ray --jobs 2 --threads 1` (a
local Ray started for the run). Reported: wall time, files per hour, the per-file seconds of the manifest, and
whether every runner wrote the same bytes where the thread count was the same.

From the measured per-file time at one thread the script writes an estimate for 100,000 meshes on a cluster of
CPU nodes and on GPUs, with its assumptions (cores per node, how much of a fit a GPU speeds up: the Delaunay
share of a fit, measured here on one generated shape, stays on the CPU).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tetweave_codec.benchmarks.common import DEFAULT_MESHES, select_meshes

# name -> (--jobs, --threads, Ray)
CONFIGS = {"jobs1x2": (1, 2, False), "jobs2x1": (2, 1, False), "ray2x1": (2, 1, True)}
GENERATED = ("sphere", "torus", "bitten_box", "capsule")
ESTIMATE_FILES = 100_000


def generated_shape(name: str) -> tuple[np.ndarray, np.ndarray]:
    """A closed test shape by name (manifold3d), vertices (V,3) float64 and faces (F,3) int64."""
    import manifold3d as m3

    m = m3.Manifold
    shapes = {
        "sphere": lambda: m.sphere(1.0, 96),
        "torus": lambda: m.revolve(m3.CrossSection.circle(0.35, 48).translate((1.0, 0.0)), 96),
        "bitten_box": lambda: m.cube((2.0, 1.4, 1.0), center=True) - m.sphere(0.8, 64).translate((1.0, 0.7, 0.5)),
        "capsule": lambda: m.cylinder(1.6, 0.4, 0.4, 64, center=True) + m.sphere(0.4, 64).translate((0, 0, 0.8)),
    }
    mesh = shapes[name]().to_mesh()
    return np.asarray(mesh.vert_properties[:, :3], dtype=np.float64), np.asarray(mesh.tri_verts, dtype=np.int64)


def prepare_inputs(folder: Path, meshes: list[Path], generated: int) -> list[Path]:
    """Copy `meshes` and write the first `generated` shapes of GENERATED into `folder`."""
    from tetweave_codec.meshio import save_mesh

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for path in meshes:
        shutil.copy(path, folder / path.name)
        out.append(folder / path.name)
    for name in GENERATED[:generated]:
        save_mesh(folder / f"gen_{name}.ply", *generated_shape(name))
        out.append(folder / f"gen_{name}.ply")
    return out


def run_config(name: str, inputs: Path, out: Path, args: argparse.Namespace) -> dict:
    """One `tetweave encode` batch in a subprocess; wall time and the manifest's records."""
    jobs, threads, ray = CONFIGS[name]
    cmd = [sys.executable, "-m", "tetweave_codec.cli", "encode", str(inputs), "-o", str(out)]
    cmd += ["--size", args.size, "--quality", args.quality, "--device", "cpu", "--seed", "0", "-q"]
    cmd += ["--jobs", str(jobs), "--threads", str(threads), *(["--ray"] if ray else [])]
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    load = (load_before, os.getloadavg()[0])  # how busy the machine was: others' work slows every runner
    records = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    print(f"{name}: exit {done.returncode}, {wall:.1f}s\n{done.stdout.strip()}", file=sys.stderr)
    command = "tetweave encode INPUTS -o OUT " + " ".join(cmd[7:])
    return {"name": name, "jobs": jobs, "threads": threads, "ray": ray, "wall": wall, "records": records,
            "command": command, "exit": done.returncode, "load": load}  # fmt: skip


def delaunay_share(size: int, quality: str) -> tuple[float, float]:
    """(seconds, Delaunay fraction) of one in-process encode of the generated sphere at `size` bytes, one thread:
    the part of a fit that stays on the CPU when the rest runs on a GPU."""
    import torch

    import tetweave_codec.decoder as decoder
    import tetweave_codec.fit.step as step
    from tetweave_codec.encoder import encode

    torch.set_num_threads(1)
    spent = [0.0]

    def timed(original):
        def wrapper(*a, **k):
            t0 = time.perf_counter()
            try:
                return original(*a, **k)
            finally:
                spent[0] += time.perf_counter() - t0

        return wrapper

    originals = step.tetrahedralize, decoder.tetrahedralize
    step.tetrahedralize, decoder.tetrahedralize = timed(originals[0]), timed(originals[1])
    try:
        t0 = time.perf_counter()
        encode(*generated_shape("sphere"), size=size, quality=quality, device="cpu", seed=0)
        total = time.perf_counter() - t0
    finally:
        step.tetrahedralize, decoder.tetrahedralize = originals
    return total, spent[0] / total


def report(results: list[dict], args: argparse.Namespace, share: tuple[float, float] | None) -> str:
    lines = [
        "# Batch throughput",
        "",
        f"`python -m tetweave_codec.benchmarks.batch_throughput {' '.join(sys.argv[1:])}`",
        "",
        f"Machine: {os.cpu_count()} cores; load average (1 min) before -> after each run in the last column.",
        "",
        "| runner | command | files | ok | wall s | files per hour | per-file s (median, min-max) | load |",
        "|---|---|---:|---:|---:|---:|---|---|",
    ]
    per_file_1thread = []
    for r in results:
        secs = [x["seconds"] for x in r["records"] if x["status"] == "ok"]
        ok = len(secs)
        n = len(r["records"])
        med = statistics.median(secs) if secs else float("nan")
        if r["threads"] == 1:
            per_file_1thread += secs
        spread = f"{med:.1f} ({min(secs):.1f}-{max(secs):.1f})" if secs else "-"
        load = f"{r['load'][0]:.1f} -> {r['load'][1]:.1f}"
        lines.append(
            f"| {r['name']} | `{r['command']}` | {n} | {ok} | {r['wall']:.0f} | {3600 * n / r['wall']:.0f} | {spread} "
            f"| {load} |"
        )
    lines += ["", "Bytes: " + _same_bytes(results), ""]
    if per_file_1thread:
        t1 = statistics.median(per_file_1thread)
        cpu_h = ESTIMATE_FILES * t1 / 3600
        cluster = ESTIMATE_FILES * t1 / (args.nodes * args.node_cores)
        lines += [
            "## Estimate for 100,000 meshes",
            "",
            f"Measured: median {t1:.1f} s per file at one thread (the runs with --threads 1 above; this machine's "
            f"cores, shared with other work while it ran), so 100,000 meshes are {cpu_h:,.0f} core-hours.",
            "",
            f"* **{args.nodes} CPU nodes** of {args.node_cores} cores each, `--ray auto --threads 1` (one task per "
            f"core, {args.nodes * args.node_cores:,} at once): 100,000 x {t1:.1f} s / {args.nodes * args.node_cores:,}"
            f" = **{cluster / 3600:.1f} h** ({cluster / 60:.0f} min). Assumes cluster cores as fast as these, inputs "
            "shipped by Ray (a few MB each, far below the fit time), and Ray's per-task overhead (milliseconds) "
            "negligible next to a fit.",
        ]
        if share is not None:
            total, frac = share
            slots = args.gpus * args.fits_per_gpu
            t_gpu = t1 * frac + t1 * (1 - frac) / args.gpu_speedup
            t_fast = t1 * frac + t1 * (1 - frac) / (3 * args.gpu_speedup)
            lines.append(
                f"* **{args.gpus} GPUs**, `--device cuda` (Ray asks one GPU per task): no GPU was available here, so "
                f"this is a model. TetGen's Delaunay stays on the CPU: {100 * frac:.0f} % of a one-thread fit "
                f"(measured: the generated sphere at --size {args.size}, {total:.0f} s); assumed: the rest "
                f"(renders, losses, gradients) runs {args.gpu_speedup:g}x faster on a GPU than on one core, and "
                f"{args.fits_per_gpu} fits share each GPU (each with its own CPU core for Delaunay). Per file "
                f"{t_gpu:.1f} s, so 100,000 x {t_gpu:.1f} s / ({args.gpus} x {args.fits_per_gpu}) = "
                f"**{ESTIMATE_FILES * t_gpu / slots / 3600:.1f} h**. With a {args.gpu_speedup * 3:g}x speed-up it "
                f"would be {ESTIMATE_FILES * t_fast / slots / 3600:.1f} h: the Delaunay share bounds what GPUs gain.",
            )
    return "\n".join(lines) + "\n"


def _same_bytes(results: list[dict]) -> str:
    """Whether the runs with the same --threads wrote identical files (compared through the records' sizes and
    the outputs' hashes collected by `main`)."""
    groups: dict[int, list[dict]] = {}
    for r in results:
        groups.setdefault(r["threads"], []).append(r)
    parts = []
    for threads, runs in sorted(groups.items()):
        if len(runs) < 2:
            continue
        hashes = [r["outputs"] for r in runs]
        same = all(h == hashes[0] for h in hashes)
        names = " and ".join(r["name"] for r in runs)
        parts.append(f"{names} (--threads {threads}) wrote {'identical' if same else 'DIFFERENT'} files")
    return "; ".join(parts) or "no two runs at the same --threads"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", type=Path, default=DEFAULT_MESHES)
    ap.add_argument("--only", default="", help="comma-separated mesh stems (default: all)")
    ap.add_argument("--generated", type=int, default=2, help=f"generated shapes added (0-{len(GENERATED)})")
    ap.add_argument("--size", default="10k")
    ap.add_argument("--quality", default="default")
    ap.add_argument("--configs", default=",".join(CONFIGS), help=f"comma-separated among {', '.join(CONFIGS)}")
    ap.add_argument("--nodes", type=int, default=64)
    ap.add_argument("--node-cores", type=int, default=32)
    ap.add_argument("--gpus", type=int, default=8)
    ap.add_argument("--gpu-speedup", type=float, default=10.0, help="assumed GPU speed-up of the non-Delaunay part")
    ap.add_argument("--fits-per-gpu", type=int, default=4)
    ap.add_argument("--no-share", action="store_true", help="skip the Delaunay-share measurement (one more fit)")
    ap.add_argument("--out", type=Path, default=None, help="write the Markdown table here too")
    args = ap.parse_args()

    from tetweave_codec.cli.common import parse_count
    from tetweave_codec.runner.manifest import file_sha256

    meshes = select_meshes(args.meshes, args.only) if args.only != "-" else []
    results = []
    with tempfile.TemporaryDirectory(prefix="tetweave-throughput-") as tmp:
        inputs = Path(tmp) / "inputs"
        prepare_inputs(inputs, meshes, args.generated)
        for name in args.configs.split(","):
            out = Path(tmp) / name
            result = run_config(name, inputs, out, args)
            result["outputs"] = {p.relative_to(out).as_posix(): file_sha256(p) for p in sorted(out.rglob("*.tw"))}
            results.append(result)
    share = None if args.no_share else delaunay_share(parse_count(args.size), args.quality)
    text = report(results, args, share)
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
