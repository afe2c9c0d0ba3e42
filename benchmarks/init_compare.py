"""What the encoder's initialization gives before any optimization: SDF start vs the paper's random start.

For each mesh (default: the shared meshes in ../shared/meshes) normalized into [-0.9, 0.9]^3 and each
point count, build the initial state with ``initialize.initial_state`` (points in a shell around the input,
s = its signed distance) and ``initialize.random_state`` (the paper's ball of random points, with random s
as in its reference code, and with a sphere guess s = |p| - 0.5),
extract the mesh exactly as the decoder does (Delaunay + marching tets, ``decoder.mesh_from_points``) and
report the time to build the state, the time to extract, the face count and the Chamfer distance to the
input (``metrics.fidelity.chamfer_distance``, normalized frame).

    python -m tetweave_codec.benchmarks.init_compare [--points 4096,16384] [--meshes DIR | MESH ...]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from tetweave_codec.benchmarks.batch import DEFAULT_MESHES, find_meshes
from tetweave_codec.decoder import mesh_from_points
from tetweave_codec.fit.initialize import initial_state, random_state
from tetweave_codec.meshio import load_mesh, normalize
from tetweave_codec.metrics.fidelity import chamfer_distance

# "sdf": initial_state; "random": the paper's start (random s); "sphere": its ball with s = |p| - 0.5
INITS = ("sdf", "random", "sphere")


def run(paths: list[Path], counts: list[int], sh_degree: int = 1, seed: int = 0, samples: int = 100_000) -> list[dict]:
    """One row per (mesh, point count, initialization); see the module docstring for the columns."""
    rows = []
    for path in paths:
        vertices, faces = load_mesh(path)
        vertices, _, _ = normalize(vertices)
        for n in counts:
            for init in INITS:
                t0 = time.perf_counter()
                if init == "sdf":
                    points, s, c = initial_state(vertices, faces, n, sh_degree, seed)
                else:
                    points, s, c = random_state(n, sh_degree, seed, sdf=init)
                t_init = time.perf_counter() - t0
                t0 = time.perf_counter()
                v_out, f_out = mesh_from_points(points, s, c, sh_degree)
                t_extract = time.perf_counter() - t0
                cd = (
                    chamfer_distance(vertices, faces, v_out, f_out, n_samples=samples, seed=seed)
                    if len(f_out)
                    else math.inf
                )
                rows.append(
                    {
                        "mesh": path.stem,
                        "faces_in": len(faces),
                        "points": n,
                        "init": init,
                        "init_s": t_init,
                        "extract_s": t_extract,
                        "faces_out": len(f_out),
                        "chamfer": cd,
                    }
                )
                print(_format_row(rows[-1]), flush=True)
    return rows


HEADER = (
    "| mesh | input faces | points | init | init time (s) | extract time (s) | faces "
    "| Chamfer (1e-3) |\n|---|---:|---:|---|---:|---:|---:|---:|"
)


def _format_row(r: dict) -> str:
    return (
        f"| {r['mesh']} | {r['faces_in']} | {r['points']} | {r['init']} | {r['init_s']:.2f} | "
        f"{r['extract_s']:.2f} | {r['faces_out']} | {r['chamfer'] * 1e3:.3f} |"
    )


def _mesh_paths(args: list[str], directory: Path) -> list[Path]:
    if args:
        return [Path(a) for a in args]
    if not directory.is_dir():
        raise SystemExit(f"no meshes given and {directory} does not exist")
    return find_meshes(directory)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    parser.add_argument("meshes", nargs="*", help="mesh files (default: every mesh in --meshes)")
    parser.add_argument("--meshes-dir", type=Path, default=DEFAULT_MESHES, help="directory of meshes")
    parser.add_argument("--points", default="4096,16384", help="comma-separated point counts")
    parser.add_argument("--sh-degree", type=int, default=1, help="SH degree of the state")
    parser.add_argument("--seed", type=int, default=0, help="seed of the initialization and of the metric")
    parser.add_argument("--samples", type=int, default=100_000, help="surface samples per mesh for Chamfer")
    args = parser.parse_args(argv)
    counts = [int(x) for x in args.points.split(",") if x]
    print(HEADER, flush=True)
    rows = run(_mesh_paths(args.meshes, args.meshes_dir), counts, args.sh_degree, args.seed, args.samples)
    print("\nChamfer distance of the paper's starts relative to the SDF start (random s, sphere s):")
    for (mesh, n), group in _group(rows).items():
        sdf = group["sdf"]["chamfer"]
        ratios = ", ".join(f"{group[k]['chamfer'] / sdf:.0f}x" if sdf > 0 else "n/a" for k in ("random", "sphere"))
        print(f"  {mesh} @ {n}: {ratios}")
    return 0


def _group(rows: list[dict]) -> dict:
    out: dict = {}
    for r in rows:
        out.setdefault((r["mesh"], r["points"]), {})[r["init"]] = r
    return out


if __name__ == "__main__":
    np.set_printoptions(precision=4)
    sys.exit(main())
