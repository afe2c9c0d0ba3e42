"""Faces and Chamfer distance of each `tetweave decode --level` on the bench's committed files.

Usage, from the repository root (the meshes next to it, as for `tetweave bench`):

    OMP_NUM_THREADS=1 python3 docs/measurements/decode_levels.py ../shared/meshes

Decodes every `benchmarks/results/files/<mesh>/<setting>.tw` at each level and measures it against
`<meshes>/<mesh>.ply` with the bench's metric (symmetric point-to-surface Chamfer distance, 200K samples, seed 0,
input's normalized frame). Prints one Markdown table row per file and level, plus the decode's CPU seconds.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from tetweave_codec.decoder import LEVELS, decode
from tetweave_codec.meshio import load_mesh
from tetweave_codec.metrics.fidelity import chamfer_distance

FILES = Path("benchmarks/results/files")


def main(meshes: Path) -> None:
    print("| mesh | file | level | faces | Chamfer | decode CPU s |")
    print("|---|---|---|---:|---:|---:|")
    for folder in sorted(p for p in FILES.iterdir() if p.is_dir()):
        vi, fi = load_mesh(meshes / f"{folder.name}.ply")
        # size-5120-sh-auto.tw ... size-40960-sh-auto.tw, smallest first
        for path in sorted(folder.glob("*.tw"), key=lambda p: int(p.stem.split("-")[1])):
            data = path.read_bytes()
            for level in LEVELS:
                t0 = time.process_time()
                v, f = decode(data, level=level)
                seconds = time.process_time() - t0
                cd = chamfer_distance(vi, fi, v, f)
                print(f"| {folder.name} | {path.name} | {level} | {len(f):,} | {cd:.3g} | {seconds:.2f} |", flush=True)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python3 docs/measurements/decode_levels.py MESH_DIR")
    main(Path(sys.argv[1]))
