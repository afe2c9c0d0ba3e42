"""The encoder's self-check (metrics.unseen): the share of a decoded mesh's area no outside view sees, its cost and
its agreement with fit.visible's own renders (32 views at 384 px, `Renders.faces_seen`), on the decoded meshes of
the bench's committed files (benchmarks/results/files/MESH/size-BYTES-sh-auto.tw) and on meshes whose unseen
area is known exactly. One torch thread; run it alone (timings).

    python docs/measurements/self_check.py [--files 'benchmarks/results/files/*/*.tw'] [--repeat 3]
"""

from __future__ import annotations

import argparse
import glob
import statistics
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]


def timed(fn, repeat: int):
    """(the last result, median seconds over `repeat` calls)."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, statistics.median(times)


def fit_renders_share(v: np.ndarray, f: np.ndarray) -> float:
    """The share by the fit's render + faces_seen at the fit's settings (every face tested)."""
    from tetweave_codec.geometry.triangles import face_areas
    from tetweave_codec.meshio import normalize
    from tetweave_codec.render.visibility import RESOLUTION, VIEWS, render

    n, _, _ = normalize(v)
    seen, _ = render(n, f, VIEWS, RESOLUTION).faces_seen()
    area = face_areas(v, f)
    return float(area[~seen.any(axis=0)].sum() / area.sum())


def known_meshes() -> list[tuple[str, np.ndarray, np.ndarray, float]]:
    """(name, vertices, faces, the exact share) of meshes built here."""
    import manifold3d
    import trimesh

    from tetweave_codec.geometry.triangles import face_areas

    def mesh(m):
        return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)

    out = []
    outer, inner = mesh(trimesh.creation.icosphere(4, radius=0.9)), mesh(trimesh.creation.icosphere(3, radius=0.3))
    out.append(("sphere", *outer, 0.0))
    v = np.concatenate([outer[0], inner[0] + 0.2])
    f = np.concatenate([outer[1], inner[1] + len(outer[0])])
    a_in, a_out = face_areas(*inner).sum(), face_areas(*outer).sum()
    out.append(("sphere + sphere inside", v, f, float(a_in / (a_in + a_out))))
    box = manifold3d.Manifold.cube((2.0, 1.0, 1.0), center=True)
    slab = manifold3d.Manifold.cube((0.02, 0.8, 0.8), center=True).translate((0.3, 0.0, 0.0))
    m = (box - slab).to_mesh()
    slab_area = 2 * (0.8 * 0.8 + 2 * 0.02 * 0.8)
    out.append(
        (
            "box with a thin bubble (a membrane as decoded)",
            np.asarray(m.vert_properties[:, :3], dtype=np.float64),
            np.asarray(m.tri_verts, dtype=np.int64),
            slab_area / (10.0 + slab_area),
        )
    )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--files", default=str(REPO / "benchmarks/results/files/*/*.tw"))
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    import torch

    torch.set_num_threads(1)
    from tetweave_codec.decoder import decode
    from tetweave_codec.metrics.unseen import resolution_for, unseen_area_share

    unseen_area_share(*known_meshes()[0][1:3])  # warm-up: imports, first allocations
    print("| file | decoded faces | px | self-check % | s | fit renders (384 px, all faces) % | s |")
    print("|---|---|---|---|---|---|---|")
    for path in sorted(glob.glob(args.files)):
        v, f = decode(Path(path).read_bytes())
        share, seconds = timed(lambda v=v, f=f: unseen_area_share(v, f), args.repeat)
        ref, ref_s = timed(lambda v=v, f=f: fit_renders_share(v, f), args.repeat)
        name = f"{Path(path).parent.name}/{Path(path).name}"
        print(
            f"| {name} | {len(f):,} | {resolution_for(len(f))} | {100 * share:.3f} | {seconds:.2f} | "
            f"{100 * ref:.3f} | {ref_s:.2f} |"
        )
    print()
    print("| built mesh | faces | self-check % | exact % | s |")
    print("|---|---|---|---|---|")
    for name, v, f, truth in known_meshes():
        share, seconds = timed(lambda v=v, f=f: unseen_area_share(v, f), args.repeat)
        print(f"| {name} | {len(f):,} | {100 * share:.4f} | {100 * truth:.4f} | {seconds:.2f} |")


if __name__ == "__main__":
    main()
