"""Tiny inputs through `tetweave encode` (docs/measurements/small_inputs.md): wall time, bytes, Chamfer distance, the
summary's plain-Draco line and whether the decoded mesh is a closed 2-manifold, for a tetrahedron, a cube, an
icosahedron, an 80-face sphere and a 500-face torus (the CLI's defaults: one torch thread).

    python docs/measurements/small_inputs.py [--tree DIR]   # DIR: another checkout's source (PYTHONPATH), e.g. before

Run it under the shared torch lock when other fits run on the machine.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh


def shapes() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """name -> (vertices (V,3), faces (F,3))."""
    tet_v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    tet_f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    meshes = {
        "cube": trimesh.creation.box(),
        "icosahedron": trimesh.creation.icosahedron(),
        "sphere80": trimesh.creation.icosphere(subdivisions=1),
        "torus500": trimesh.creation.torus(1.0, 0.4, major_sections=25, minor_sections=10),
    }
    others = {k: (np.asarray(m.vertices), np.asarray(m.faces)) for k, m in meshes.items()}
    return {"tetrahedron": (tet_v, tet_f), **others}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", help="source tree to run (PYTHONPATH), default: the installed package")
    args = parser.parse_args()
    env = dict(os.environ)
    if args.tree:
        env["PYTHONPATH"] = args.tree
    print("| input | faces | exit | wall s | bytes | Chamfer | plain Draco (summary) | decoded closed |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name, (v, f) in shapes().items():
            src, out = Path(tmp) / f"{name}.obj", Path(tmp) / f"{name}.tw"
            trimesh.Trimesh(v, f, process=False).export(src)
            cmd = [sys.executable, "-m", "tetweave_codec.cli", "encode", str(src), "-o", str(out)]
            t0 = time.perf_counter()
            run = subprocess.run(cmd, env=env, capture_output=True, text=True)
            wall = time.perf_counter() - t0
            chamfer = re.search(r"Chamfer distance to the input[^:]*: ([0-9.e-]+)", run.stdout)
            draco = re.search(r"plain Draco[^\n]*", run.stdout)
            closed = "-"
            if out.exists():
                check = subprocess.run(
                    [sys.executable, "-c", _CHECK, str(out)], env=env, capture_output=True, text=True
                )
                closed = check.stdout.strip() or check.stderr.strip().splitlines()[-1]
            size = out.stat().st_size if out.exists() else "-"
            print(
                f"| {name} | {len(f)} | {run.returncode} | {wall:.1f} | {size} | "
                f"{chamfer.group(1) if chamfer else '-'} | {draco.group(0) if draco else '-'} | {closed} |"
            )


_CHECK = """
import sys
from tetweave_codec.decoder import decode
from tetweave_codec.geometry.marching_tets import check_manifold
v, f = decode(open(sys.argv[1], "rb").read())
check_manifold(f, len(v))
print(f"yes ({len(f)} faces)")
"""

if __name__ == "__main__":
    main()
