"""Encode CPU and rate-distortion before / after in one run: an older commit's encoder against this tree's.

    python -m tetweave_codec.benchmarks.encode_ab 59b4afb [--cases spot:10k,igea:e1e-3,spot:default]
                                                          [--without fcpw] [--threads 1]

Each case is MESH:MODE, MODE one of SIZE (`encode(size=...)`, k = 1024), eERROR (`encode(max_error=...)`) or
`default` (no rate option: the input-sized point count); the default cases are issue 47's targets on the
development meshes (--meshes). For every case the older commit's encode runs, then this tree's, each in a fresh
process at --quality with --threads torch threads (default 1; OMP/MKL/OpenBLAS pools at the same count), one
process at a time: torch's threads slow down badly while another process keeps a core busy. The older commit runs
from its own source (`common.commit_tree`); `--without fcpw` hides an optional package from it (a module of that
name that fails to import, first on its path), so that it runs as the README's plain install would.

Per case: bytes and Chamfer distance (the encoder's own report, the summary's metric in the input's normalized
frame), the child's CPU seconds (user + system of the whole process, start-up and imports included), wall seconds;
then bytes x Chamfer and CPU, this tree / the older commit, and their medians over the cases. Same seed (0) in
both; bytes and Chamfer are deterministic, CPU is not: run it on idle cores. `--save DIR` keeps this tree's files
as DIR/MESH/size-BYTES-sh-auto.tw (the bench's names, benchmarks/results/files/) or DIR/MESH/MODE.tw.
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tetweave_codec.benchmarks.common import commit_tree, script_parser, select_meshes

CASES = (
    "spot:10k,igea:10k,stanford-bunny:10k,fandisk:10k,spot:e1e-3,igea:e1e-3,stanford-bunny:e1e-3,fandisk:e1e-3,"
    "spot:default,stanford-bunny:default,spot:40k,igea:40k"
)

ENCODE = """
import json, sys
import torch
torch.set_num_threads(int(sys.argv[3]))
from tetweave_codec.encoder import encode
from tetweave_codec.meshio import load_mesh
mode = sys.argv[2]
kw = {}
if mode.startswith("e"):
    kw["max_error"] = float(mode[1:])
elif mode != "default":
    kw["size"] = int(float(mode[:-1]) * 1024) if mode.endswith("k") else int(mode)
v, f = load_mesh(sys.argv[1])
res = encode(v, f, device="cpu", seed=0, quality=sys.argv[4], **kw)
st = res.stats
if len(sys.argv) > 5:
    open(sys.argv[5], "wb").write(res.data)
print(json.dumps({"bytes": st["bytes"], "chamfer": st["chamfer"], "points": st["points_kept"]}))
"""


def run_encode(
    tree: Path | None, mesh: Path, mode: str, threads: int, quality: str, hide: Path | None, save: Path | None = None
) -> dict:
    """One encode in a fresh process (`tree` None: this tree, as installed); bytes, Chamfer, CPU and wall seconds;
    the file written to `save` when given."""
    pools = str(threads)
    env = dict(os.environ, OMP_NUM_THREADS=pools, MKL_NUM_THREADS=pools, OPENBLAS_NUM_THREADS=pools)
    if tree is not None:
        env["PYTHONPATH"] = os.pathsep.join(str(p) for p in (tree, hide) if p is not None)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    command = [sys.executable, "-c", ENCODE, str(mesh), mode, str(threads), quality]
    if save is not None:
        save.parent.mkdir(parents=True, exist_ok=True)
        command.append(str(save))
    done = subprocess.run(command, capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"encode of {mesh.name} {mode} failed: {done.stderr.strip().splitlines()[-1:]}")
    row = json.loads(done.stdout.strip().splitlines()[-1])
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return row | {"cpu": cpu, "wall": wall}


def saved_name(mode: str) -> str:
    """The file name of a case's file: the bench's `size-BYTES-sh-auto.tw` for a size, else `MODE.tw`."""
    if mode.startswith("e") or mode == "default":
        return f"{mode}.tw"
    size = int(float(mode[:-1]) * 1024) if mode.endswith("k") else int(mode)
    return f"size-{size}-sh-auto.tw"


def hidden_modules(names: list[str], where: Path) -> Path | None:
    """A folder of modules that fail to import, one per name (None when there are none)."""
    if not names:
        return None
    folder = where / "hidden"
    folder.mkdir()
    for name in names:
        (folder / f"{name}.py").write_text(f'raise ImportError("{name} hidden by encode_ab --without")\n')
    return folder


def main(argv: list[str] | None = None) -> int:
    ap = script_parser(__doc__)
    ap.add_argument("commit", help="the older commit (anything git archive takes)")
    ap.add_argument("--cases", default=CASES, help="comma-separated MESH:MODE (default: issue 47's targets)")
    ap.add_argument("--without", default="", help="comma-separated optional packages hidden from the older commit")
    ap.add_argument("--save", type=Path, default=None, help="folder for this tree's files (the bench's names)")
    args = ap.parse_args(argv)
    threads = args.threads or 1
    meshes = {p.stem: p for p in select_meshes(args.meshes)}
    cases = [c.split(":", 1) for c in args.cases.split(",") if c]
    unknown = sorted({m for m, _ in cases} - set(meshes))
    if unknown:
        raise SystemExit(f"no mesh named {', '.join(unknown)} in {args.meshes}")
    print(f"# {args.commit} against this tree, {threads} torch thread(s), one process at a time")
    print("| case | before bytes, Chamfer, CPU s | after bytes, Chamfer, CPU s | bytes x Chamfer | CPU |")
    print("|---|---|---|---:|---:|")
    quality, cpu = [], []
    with tempfile.TemporaryDirectory() as tmp:
        old = commit_tree(args.commit, Path(tmp))
        hide = hidden_modules([n for n in args.without.split(",") if n], Path(tmp))
        for name, mode in cases:
            a = run_encode(old, meshes[name], mode, threads, args.quality, hide)
            save = None if args.save is None else args.save / name / saved_name(mode)
            b = run_encode(None, meshes[name], mode, threads, args.quality, None, save)
            q = (b["bytes"] * b["chamfer"]) / (a["bytes"] * a["chamfer"])
            c = b["cpu"] / a["cpu"]
            quality.append(q)
            cpu.append(c)
            print(f"| {name} {mode} | {a['bytes']:,}, {a['chamfer']:.3e}, {a['cpu']:.1f} | {b['bytes']:,}, "
                  f"{b['chamfer']:.3e}, {b['cpu']:.1f} | {q:.3f} | {c:.2f}x |", flush=True)  # fmt: skip
    print(f"\nbytes x Chamfer after / before: median {statistics.median(quality):.3f} "
          f"({min(quality):.3f}-{max(quality):.3f}); CPU: median {statistics.median(cpu):.2f}x "
          f"({min(cpu):.2f}-{max(cpu):.2f})")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
