"""Issue 15: sharp creases. CSG parts (manifold3d) and shared meshes at given sizes, feature-aware start on/off.

Run from outside the repo root, one thread:

    cd /tmp && OMP_NUM_THREADS=1 python /work/wt/crease/benchmarks/creases.py --shapes cube --sizes 1024 2048

Prints bytes, points kept, Chamfer distance (CD), edge Chamfer (ECD), edge F1 and normal consistency of the
decoded mesh against the input (the bench's metrics, 100k samples), and whether the output is watertight and
2-manifold (manifold3d), for each shape, size and mode ("off": no feature points, the start of before) and each
`--smoothing` (the decoder's Taubin steps) and `--sh-degree` (defaults: the encoder's).
"""

from __future__ import annotations

import argparse
import math
import time

import manifold3d as m3
import numpy as np
import torch

from tetweave_codec.encoder import encode
from tetweave_codec.fit import features
from tetweave_codec.metrics.common import MetricOptions
from tetweave_codec.metrics.fidelity import prepare_reference
from tetweave_codec.metrics.summary import evaluate


def _mesh(solid: m3.Manifold) -> tuple[np.ndarray, np.ndarray]:
    m = solid.to_mesh()
    return np.asarray(m.vert_properties, np.float64)[:, :3], np.asarray(m.tri_verts, np.int64)


def csg_shapes() -> dict[str, m3.Manifold]:
    """The three CSG parts of issue 15 and a thin fin (issue 14: thin parts)."""
    cube = m3.Manifold.cube([1, 1, 1], center=True)
    return {
        "cube": cube,
        "cube-cylinder": cube - m3.Manifold.cylinder(1.2, 0.3, 0.3, 64).translate([0, 0, -0.6]),
        "three-boxes": m3.Manifold.cube([1.2, 0.4, 0.4], center=True)
        + m3.Manifold.cube([0.4, 1.2, 0.4], center=True)
        + m3.Manifold.cube([0.4, 0.4, 1.2], center=True).translate([0.3, 0.2, 0.1]),
        # a plate with a fin 2 % of the longest side thick: thinner than the point spacing up to ~8 KB
        "fin": m3.Manifold.cube([1.0, 1.0, 0.2]) + m3.Manifold.cube([0.8, 0.02, 0.6]).translate([0.1, 0.49, 0.2]),
    }


def load(name: str) -> tuple[np.ndarray, np.ndarray]:
    """A CSG part by name, or a shared mesh /work/shared/meshes/NAME.ply."""
    shapes = csg_shapes()
    if name in shapes:
        return _mesh(shapes[name])
    import trimesh

    m = trimesh.load(f"/work/shared/meshes/{name}.ply", process=False)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def watertight(v: np.ndarray, f: np.ndarray) -> bool:
    """True when manifold3d accepts the mesh as a closed 2-manifold."""
    try:
        solid = m3.Manifold(m3.Mesh(np.asarray(v, np.float32), np.asarray(f, np.uint32)))
    except Exception:  # noqa: BLE001 - any refusal means "not a manifold"
        return False
    return solid.status() == m3.Error.NoError and not solid.is_empty()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shapes", nargs="+", default=list(csg_shapes()))
    ap.add_argument("--sizes", nargs="+", type=int, default=[1024, 2048])
    ap.add_argument("--modes", nargs="+", default=["off", "on"], choices=["off", "on"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--smoothing", type=int, nargs="+", default=[None], help="Taubin steps (default: the encoder's)")
    ap.add_argument("--sh-degree", type=int, nargs="+", default=[None], help="SH degrees (default: the encoder's)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    opts = MetricOptions.for_samples(100_000)
    default_length = features.MIN_CREASE_LENGTH
    for name in args.shapes:
        v, f = load(name)
        ref = prepare_reference(v, f, opts)
        for size in args.sizes:
            settings = [(m, k, d) for m in args.modes for k in args.smoothing for d in args.sh_degree]
            for mode, smoothing, degree in settings:
                features.MIN_CREASE_LENGTH = default_length if mode == "on" else math.inf
                t = time.process_time()
                chosen = {} if degree is None else {"sh_degree": degree}
                r = encode(v, f, size=size, device="cpu", seed=args.seed, measure=False, smoothing=smoothing, **chosen)
                met = evaluate(ref, r.vertices, r.faces, opts)
                smooth = ("" if smoothing is None else f" smoothing {smoothing}") + (
                    "" if degree is None else f" sh {degree}"
                )
                print(
                    f"{name:14} {size:6} B {mode:3}{smooth}: {len(r.data):6} B, {r.stats['points_kept']:5} points, "
                    f"CD {met['chamfer']:.2e}, ECD {met['edge_chamfer']:.2e}, EF1 {met['edge_f1']:.3f}, "
                    f"NC {met['normal_consistency']:.4f}, manifold {watertight(r.vertices, r.faces)}, "
                    f"{time.process_time() - t:.0f} s CPU",
                    flush=True,
                )
    features.MIN_CREASE_LENGTH = default_length


if __name__ == "__main__":
    main()
