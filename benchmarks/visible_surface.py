"""Messy inputs a viewer shows correctly, and `tetweave encode` on them: the visible surface (fit/visible.py).

Each kind is built from a clean closed mesh (normalized frame), so the surface a viewer sees is known exactly:

    hidden      the mesh + a scaled copy of itself inside it (a closed part no outside view sees)
    inner_wall  the mesh + an inner wall, its copy moved inwards along the normals by WALL_THICKNESS, reversed
    overlap     the mesh + an icosphere and a box that cut into it, never booleaned (the truth: their union,
                manifold3d)
    orientation the mesh with a random half of its faces reversed
    unwelded    the mesh with every face on its own three vertices (an STL soup)

For each kind and --size, the messy input is encoded with --surface all (the encode before the option) and
auto, the clean truth with auto (the same bytes as all on a clean input), and each decoded mesh is measured
against the truth: Chamfer distance (the truth's normalized frame), normal consistency, the share of the decoded
area no outside view sees (metrics.unseen, the encode summary's self-check), closed 2-manifold. Encodes run one
at a time with --threads.

    python -m tetweave_codec.benchmarks.visible_surface --only spot --sizes 5k,10k --threads 1
"""

from __future__ import annotations

import time

import numpy as np

WALL_THICKNESS = 0.012  # normalized frame: 0.67 % of the box side
KINDS = ("hidden", "inner_wall", "overlap", "orientation", "unwelded")


def hidden_part(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh plus a copy of itself scaled into a ball at its deepest grid point (a closed part inside)."""
    from tetweave_codec.fit.initialize import signed_distance

    g = np.linspace(-0.85, 0.85, 24)
    grid = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    s = signed_distance(grid, v, f)
    centre, depth = grid[np.argmin(s)], -float(s.min())
    c = v.mean(axis=0)
    radius = float(np.linalg.norm(v - c, axis=1).max())
    inner = (v - c) * (0.6 * depth / radius) + centre
    return np.concatenate([v, inner]), np.concatenate([f, f + len(v)])


def inner_wall(v: np.ndarray, f: np.ndarray, thickness: float = WALL_THICKNESS) -> tuple[np.ndarray, np.ndarray]:
    """The mesh plus its inner wall: vertices moved inwards along the area-weighted normals by `thickness` (less
    where the shape is thinner: halved until the moved vertex lies inside by half the step), faces reversed."""
    from tetweave_codec.fit.initialize import signed_distance
    from tetweave_codec.geometry.triangles import face_cross

    n = np.zeros_like(v)
    cross = face_cross(v, f)
    for k in range(3):
        np.add.at(n, f[:, k], cross)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    step = np.full(len(v), thickness)
    for _ in range(5):
        moved = v - n * step[:, None]
        bad = signed_distance(moved, v, f) > -0.5 * step
        if not bad.any():
            break
        step[bad] *= 0.5
    return np.concatenate([v, v - n * step[:, None]]), np.concatenate([f, f[:, ::-1] + len(v)])


def _primitives(v: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """An icosphere at the mesh's highest vertex and a tilted box at its frontmost one, half inside it."""
    import trimesh

    top = v[np.argmax(v[:, 1])]
    front = v[np.argmax(v[:, 2])]
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.22)
    sphere.apply_translation(top)
    box = trimesh.creation.box(extents=(0.45, 0.3, 0.3))
    box.apply_transform(trimesh.transformations.rotation_matrix(0.5, (1.0, 1.0, 0.0)))
    box.apply_translation(front)
    return [(np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)) for m in (sphere, box)]


def overlap(v: np.ndarray, f: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """(messy, truth): the mesh with two primitives concatenated, and their exact union (manifold3d)."""
    import manifold3d

    parts = [(v, f), *_primitives(v)]
    union = None
    for pv, pf in parts:
        m = manifold3d.Manifold(manifold3d.Mesh(pv.astype(np.float32), pf.astype(np.uint32)))
        union = m if union is None else union + m
    mesh = union.to_mesh()
    truth = (np.asarray(mesh.vert_properties[:, :3], dtype=np.float64), np.asarray(mesh.tri_verts, dtype=np.int64))
    offsets = np.cumsum([0] + [len(pv) for pv, _ in parts])
    faces = [pf + o for (_, pf), o in zip(parts, offsets[:-1], strict=True)]
    messy = (np.concatenate([pv for pv, _ in parts]), np.concatenate(faces))
    return messy, truth


def random_orientation(v: np.ndarray, f: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The mesh with a random half of its faces reversed."""
    flip = np.random.default_rng(seed).random(len(f)) < 0.5
    out = f.copy()
    out[flip] = out[flip][:, ::-1]
    return v, out


def unwelded(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every face on its own three vertices."""
    return v[f].reshape(-1, 3), np.arange(3 * len(f), dtype=np.int64).reshape(-1, 3)


def build(kind: str, v: np.ndarray, f: np.ndarray):
    """(messy (V,3), (F,3)), (truth (V,3), (F,3)) of `kind` (KINDS) from a clean closed mesh in its normalized
    frame."""
    if kind == "overlap":
        return overlap(v, f)
    builder = {"hidden": hidden_part, "inner_wall": inner_wall, "orientation": random_orientation}
    builder["unwelded"] = unwelded
    return builder[kind](v, f), (v, f)


def measure(truth, out_v: np.ndarray, out_f: np.ndarray, samples: int = 100_000) -> dict:
    """The decoded mesh against the truth: Chamfer (truth's normalized frame), normal consistency, the share of its
    area no outside view sees (metrics.unseen), closed 2-manifold."""
    from tetweave_codec.geometry.marching_tets import check_manifold
    from tetweave_codec.metrics.fidelity import chamfer_distance, fidelity, normalization, prepare_mesh, to_frame
    from tetweave_codec.metrics.unseen import unseen_area_share

    tv, tf = truth
    scale, offset = normalization(tv)
    a = prepare_mesh(to_frame(tv, scale, offset), tf)
    b = prepare_mesh(to_frame(out_v, scale, offset), out_f)
    fid = fidelity(a, b)
    try:
        check_manifold(out_f, len(out_v))
        closed = True
    except Exception:
        closed = False
    hidden = unseen_area_share(out_v, out_f)  # the encode summary's self-check
    return {
        "chamfer": chamfer_distance(tv, tf, out_v, out_f, samples),
        "nc": fid.get("normal_consistency"),
        "hidden": hidden,
        "closed": closed,
    }


def main() -> None:
    from tetweave_codec.benchmarks.common import script_meshes, script_parser
    from tetweave_codec.encoder import encode
    from tetweave_codec.meshio import load_mesh, normalize
    from tetweave_codec.options import EncodeOptions

    ap = script_parser(__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="5k", help="comma-separated --size values (k = 1024)")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--runs", default="clean,all,auto", help="which of clean, all, auto to encode")
    args = ap.parse_args()
    sizes = [int(float(s[:-1]) * 1024) if s.endswith("k") else int(s) for s in args.sizes.split(",")]
    rows = []
    for path in script_meshes(args):
        v0, f0 = load_mesh(path)
        v, _, _ = normalize(v0)
        for kind in args.kinds.split(","):
            messy, truth = build(kind, v, f0)
            for size in sizes:
                runs = [("clean", truth, "auto"), ("all", messy, "all"), ("auto", messy, "auto")]
                runs = [r for r in runs if r[0] in args.runs.split(",")]
                for label, (mv, mf), surface in runs:
                    if label == "clean" and kind != "overlap" and rows and rows[-1][0] == path.stem:
                        prior = [
                            r for r in rows if r[:1] == (path.stem,) and r[1] != "overlap" and r[2:4] == (size, "clean")
                        ]
                        if prior:  # the same clean mesh: measured once per size
                            rows.append((path.stem, kind, size, label, *prior[0][4:]))
                            print(*rows[-1], flush=True)
                            continue
                    t0 = time.perf_counter()
                    try:
                        res = encode(mv, mf, options=EncodeOptions(size=size, surface=surface))
                    except Exception as exc:  # the failure is the row
                        rows.append((path.stem, kind, size, label, f"failed: {exc}", None, None, None, None, ""))
                        print(*rows[-1], flush=True)
                        continue
                    secs = time.perf_counter() - t0
                    m = measure(truth, res.vertices, res.faces)
                    rows.append(
                        (path.stem, kind, size, label, res.stats["bytes"], m["chamfer"], m["nc"], m["hidden"],
                         m["closed"], f"{secs:.0f}s {res.stats.get('surface')}")
                    )  # fmt: skip
                    print(*rows[-1], flush=True)
    print("| mesh | kind | size | run | bytes | Chamfer vs visible truth | NC | hidden area | closed | time, surface |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        cells = [f"{x:.3g}" if isinstance(x, float) else str(x) for x in r]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
