"""Assets made of parts (issue 55): closed parts that overlap or nest, with long faces, and a sheet through a solid;
`tetweave encode` on them against the exact outside surface, measured by code independent of the encoder's.

Each kind is a concatenation of parts, never booleaned (the messy input), and its truth: manifold3d's exact union
of the solids the parts bound, computed here from the primitives (not by fit.parts), or the solid plus the part of
the sheet outside it (the sheet's plane minus the solid's cross-section, manifold3d):

    cyl48       two spheres (icosphere, 1280 faces) and a 48-sided cylinder through both (long side faces)
    cyl12       the same with a 12-sided cylinder
    boxes       three boxes through each other, two triangles per side
    housing     a hollow box (its cavity an inner box, reversed) with a shaft through it, a gear and a ball inside
    touching    a box with two boxes on it, face to face (the contact faces coincide, opposite; the truth without
                them)
    spot_cyl    spot with a 48-sided cylinder through its body and a box through its back
    sheet       spot with a single-sided square (two triangles) through it, poking out on every side
    slabT       spot and that square as a closed box T thick (spot's normalized frame), unioned: what fitting a
                sheet as a thin slab costs, against the sheet's truth

For each kind and --size: the truth given clean (`clean`: one closed surface, auto keeps it whole), the messy input
with this tree's --surface auto (`auto`) and, with --before COMMIT, the messy input with that commit's default
encode (`before`, in a subprocess from `common.commit_tree`). Each decoded mesh against the truth: Chamfer distance
(`chamfer`: trimesh's surface samples, the truth's frame scaled as the encoder normalizes: bounding box into
[-0.9, 0.9]^3; each sample's distance to the nearest of the other mesh's faces among those of its K nearest dense
samples, scipy's cKDTree and trimesh's point-triangle distance, not the encoder's metric), normal consistency (mean
|cos| between a sample's face normal and its nearest face's), the share of the decoded area no outside view sees
(metrics.unseen, or fit.visible's renders), closed 2-manifold (trimesh). Encodes run one at a time.

    python -m tetweave_codec.benchmarks.parts --kinds cyl48,boxes --sizes 5k,10k --threads 1 --before 0a60d8a
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

KINDS = ("cyl48", "cyl12", "boxes", "housing", "touching", "spot_cyl", "sheet")
SAMPLES = 100_000
DENSE = 400_000  # samples of the other side whose faces are the nearest-face candidates
NEAREST = 8


def _arrays(m) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V,3) float64, faces (F,3) int64) of a trimesh.Trimesh or a manifold3d.Manifold."""
    if hasattr(m, "to_mesh64"):
        mesh = m.to_mesh64()
        return np.array(mesh.vert_properties, dtype=np.float64)[:, :3].copy(), np.array(mesh.tri_verts, np.int64)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def join(*parts: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """One mesh of the parts [(vertices (V,3), faces (F,3))], concatenated (no welding, no boolean)."""
    offsets = np.cumsum([0] + [len(v) for v, _ in parts])
    faces = [f + o for (_, f), o in zip(parts, offsets[:-1], strict=True)]
    return np.concatenate([v for v, _ in parts]), np.concatenate(faces)


def union(*parts: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """manifold3d's exact union of closed, outward-oriented parts."""
    import manifold3d

    meshes = [(np.ascontiguousarray(v, dtype=np.float64), np.ascontiguousarray(f, dtype=np.uint64)) for v, f in parts]
    ms = [manifold3d.Manifold(manifold3d.Mesh64(vert_properties=v, tri_verts=f)) for v, f in meshes]
    return _arrays(manifold3d.Manifold.batch_boolean(ms, manifold3d.OpType.Add))


def _tm(m, transform=None) -> tuple[np.ndarray, np.ndarray]:
    if transform is not None:
        m.apply_transform(transform)
    return _arrays(m)


def _spot() -> tuple[np.ndarray, np.ndarray]:
    """spot, its bounding box into [-0.9, 0.9]^3 (closed, 23K faces)."""
    from tetweave_codec.benchmarks.common import DEFAULT_MESHES
    from tetweave_codec.meshio import load_mesh, normalize

    v, f = load_mesh(DEFAULT_MESHES / "spot.ply")
    return normalize(v)[0], f


def cylinders_through_spheres(sections: int):
    """(parts, truth parts): two icospheres (radius 0.5 at x = -+0.45) and a `sections`-sided cylinder (radius 0.2,
    length 2.0 along x, tilted 0.15 rad) through both."""
    import trimesh
    from trimesh.transformations import rotation_matrix, translation_matrix

    spheres = [_tm(trimesh.creation.icosphere(subdivisions=3, radius=0.5), translation_matrix((x, 0.0, 0.0)))
               for x in (-0.45, 0.45)]  # fmt: skip
    turn = rotation_matrix(0.15, (0.0, 0.0, 1.0)) @ rotation_matrix(np.pi / 2, (0.0, 1.0, 0.0))
    cylinder = _tm(trimesh.creation.cylinder(radius=0.2, height=2.0, sections=sections), turn)
    return [*spheres, cylinder]


def boxes():
    """Three boxes (12 faces each) through each other."""
    import trimesh
    from trimesh.transformations import rotation_matrix, translation_matrix

    a = _tm(trimesh.creation.box(extents=(1.6, 0.6, 0.6)))
    b = _tm(trimesh.creation.box(extents=(1.4, 0.5, 0.5)), rotation_matrix(0.8, (0.0, 0.0, 1.0)))
    c = _tm(trimesh.creation.box(extents=(0.4, 0.4, 1.5)), translation_matrix((0.3, 0.1, 0.0)))
    return [a, b, c]


def housing():
    """(parts, truth parts): a hollow box (outer 1.4 x 1.0 x 1.0, its cavity 1.2 x 0.8 x 0.8 as a reversed inner
    box), a 48-sided shaft (radius 0.08, length 2.0) through it, a gear-like disc (48 sides, radius 0.3) and a ball
    inside. The truth: the outer box and the shaft's ends (everything else is hidden)."""
    import trimesh
    from trimesh.transformations import rotation_matrix, translation_matrix

    outer = _tm(trimesh.creation.box(extents=(1.4, 1.0, 1.0)))
    cv, cf = _tm(trimesh.creation.box(extents=(1.2, 0.8, 0.8)))
    cavity = (cv, cf[:, ::-1])
    along_x = rotation_matrix(np.pi / 2, (0.0, 1.0, 0.0))
    shaft = _tm(trimesh.creation.cylinder(radius=0.08, height=2.0, sections=48), along_x)
    gear = _tm(
        trimesh.creation.cylinder(radius=0.3, height=0.1, sections=48), translation_matrix((0.2, 0, 0)) @ along_x
    )
    ball = _tm(trimesh.creation.icosphere(subdivisions=2, radius=0.15), translation_matrix((-0.35, 0.2, 0.2)))
    return [outer, cavity, shaft, gear, ball], [outer, shaft]


def touching(overlap: float = 0.0):
    """A box (1.2 x 0.8 x 0.6) with two boxes standing on it, face to face, one of them over its edge; with
    `overlap`, the two reach that far down into the box (manifold3d's union of boxes that only touch keeps the
    contact faces: the truth is made with 1e-6)."""
    import trimesh
    from trimesh.transformations import translation_matrix

    base = _tm(trimesh.creation.box(extents=(1.2, 0.8, 0.6)))
    a = _tm(
        trimesh.creation.box(extents=(0.4, 0.4, 0.5 + overlap)), translation_matrix((-0.3, 0.0, 0.55 - overlap / 2))
    )
    b = _tm(trimesh.creation.box(extents=(0.5, 0.3, 0.3 + overlap)), translation_matrix((0.5, 0.1, 0.45 - overlap / 2)))
    return [base, a, b]


def spot_cylinder():
    """spot with a 48-sided cylinder (radius 0.12) through its body and a tilted box through its back."""
    import trimesh
    from trimesh.transformations import rotation_matrix, translation_matrix

    v, f = _spot()
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    cylinder = _tm(trimesh.creation.cylinder(radius=0.12, height=2.2, sections=48), translation_matrix(centre))
    top = v[np.argmax(v[:, 1])]
    box = _tm(
        trimesh.creation.box(extents=(0.5, 0.25, 0.25)), translation_matrix(top) @ rotation_matrix(0.5, (1, 1, 0))
    )
    return [(v, f), cylinder, box]


def sheet():
    """(parts, truth): spot and a single-sided square (two triangles, 2.4 x 2.4 in the plane y = c) through it;
    the truth is spot plus the square minus spot's cross-section there (manifold3d slice and 2-D difference)."""
    import manifold3d

    v, f = _spot()
    y = 0.5 * (v[:, 1].min() + v[:, 1].max()) + 0.05
    h = 1.2
    corners = np.array([[-h, y, -h], [h, y, -h], [h, y, h], [-h, y, h]])
    square = (corners, np.array([[0, 2, 1], [0, 3, 2]]))  # facing +y
    # the solid's cross-section in the plane: a copy with y and z swapped (a mirror: faces reversed), sliced at z = y
    swapped = manifold3d.Mesh64(vert_properties=v[:, [0, 2, 1]].copy(), tri_verts=f[:, ::-1].astype(np.uint64))
    solid = manifold3d.Manifold(swapped)
    section = solid.slice(y)  # CrossSection in (x, z)
    outside = manifold3d.CrossSection.square((2 * h, 2 * h), center=True) - section
    polygons = outside.to_polygons()
    points = np.concatenate([np.asarray(p, dtype=np.float64) for p in polygons])
    tris = np.asarray(manifold3d.triangulate(polygons), dtype=np.int64)
    sheet_v = np.stack([points[:, 0], np.full(len(points), y), points[:, 1]], axis=1)
    normals = np.cross(sheet_v[tris[:, 1]] - sheet_v[tris[:, 0]], sheet_v[tris[:, 2]] - sheet_v[tris[:, 0]])
    tris[normals[:, 1] < 0] = tris[normals[:, 1] < 0][:, ::-1]
    return [(v, f), square], join((v, f), (sheet_v, tris))


def manifold3d_box(extents, centre) -> tuple[np.ndarray, np.ndarray]:
    import manifold3d

    return _arrays(manifold3d.Manifold.cube(extents, center=True).translate(centre))


def build(kind: str):
    """(messy (V,3), (F,3)), (truth (V,3), (F,3)) of `kind` (KINDS)."""
    if kind in ("cyl48", "cyl12"):
        parts = cylinders_through_spheres(48 if kind == "cyl48" else 12)
        return join(*parts), union(*parts)
    if kind == "boxes":
        parts = boxes()
        return join(*parts), union(*parts)
    if kind == "housing":
        parts, solids = housing()
        return join(*parts), union(*solids)
    if kind == "touching":
        return join(*touching()), union(*touching(1e-6))
    if kind == "spot_cyl":
        parts = spot_cylinder()
        return join(*parts), union(*parts)
    if kind == "sheet":
        parts, truth = sheet()
        return join(*parts), truth
    if kind.startswith("slab"):  # slabT: the sheet given as a closed box T thick (what a thickened sheet costs)
        (solid, square), truth = sheet()
        y, t = square[0][0, 1], float(kind[4:])
        slab = manifold3d_box((2.4, t, 2.4), (0.0, y, 0.0))
        return union(solid, slab), truth
    raise ValueError(f"unknown kind {kind!r}")


def _frame(v: np.ndarray) -> tuple[float, np.ndarray]:
    """The encoder's normalization of the truth: bounding box centred, its longest side 1.8."""
    lo, hi = v.min(axis=0), v.max(axis=0)
    return 1.8 / float((hi - lo).max()), 0.5 * (lo + hi)


def _one_way(points: np.ndarray, normals: np.ndarray, target, dense_points: np.ndarray, dense_faces: np.ndarray):
    """Each point's distance to the target mesh (trimesh.Trimesh) and |cos| between its normal and that face's:
    the nearest of the faces of its NEAREST nearest dense samples."""
    from scipy.spatial import cKDTree
    from trimesh.triangles import closest_point

    _, near = cKDTree(dense_points).query(points, k=NEAREST)
    cand = dense_faces[near]  # (P,K)
    tri = target.triangles[cand.reshape(-1)]
    q = np.repeat(points, NEAREST, axis=0)
    d = np.linalg.norm(closest_point(tri, q) - q, axis=1).reshape(-1, NEAREST)
    best = np.argmin(d, axis=1)
    face = cand[np.arange(len(points)), best]
    cos = np.abs(np.einsum("ij,ij->i", normals, target.face_normals[face]))
    return d[np.arange(len(points)), best], cos


def measure(truth, out_v: np.ndarray, out_f: np.ndarray, seed: int = 0) -> dict:
    """The decoded mesh (out_v (V,3), out_f (F,3)) against the truth (module docstring)."""
    import trimesh

    tv, tf = truth
    scale, centre = _frame(tv)
    a = trimesh.Trimesh((tv - centre) * scale, tf, process=False)
    b = trimesh.Trimesh((out_v - centre) * scale, out_f, process=False)
    sides = []
    for src, dst, s in ((a, b, seed), (b, a, seed + 1)):
        pts, fid = trimesh.sample.sample_surface(src, SAMPLES, seed=s)
        dense, dfid = trimesh.sample.sample_surface(dst, DENSE, seed=s + 10)
        sides.append(_one_way(pts, src.face_normals[fid], dst, dense, dfid))
    chamfer = 0.5 * (sides[0][0].mean() + sides[1][0].mean())
    nc = 0.5 * (sides[0][1].mean() + sides[1][1].mean())
    closed = bool(b.is_watertight and b.is_winding_consistent)
    return {"chamfer": float(chamfer), "nc": float(nc), "unseen": unseen_share(out_v, out_f), "closed": closed}


def unseen_share(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Share of the mesh's area no outside view sees (metrics.unseen when present, else fit.visible's renders)."""
    try:
        from tetweave_codec.metrics.unseen import unseen_area_share
    except ImportError:
        from tetweave_codec.fit.visible import visible_surface
        from tetweave_codec.meshio import normalize

        return visible_surface(normalize(vertices)[0], faces).hidden_share
    return unseen_area_share(vertices, faces)


ENCODE_OLD = """
import json, sys
import torch
torch.set_num_threads(int(sys.argv[3]))
from tetweave_codec.encoder import encode
from tetweave_codec.meshio import load_mesh
v, f = load_mesh(sys.argv[1])
r = encode(v, f, size=int(sys.argv[2]))
open(sys.argv[4], "wb").write(r.data)
print(json.dumps({"bytes": len(r.data), "chamfer": float(r.stats["chamfer"]), "surface": r.stats.get("surface")}))
"""


def encode_before(tree: Path, mesh: Path, size: int, threads: int, out: Path) -> dict:
    """The older commit's default encode (--size) of a mesh file, in a subprocess: its stats and decoded mesh."""
    import os

    from tetweave_codec.decoder import decode

    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS=str(threads))
    done = subprocess.run([sys.executable, "-c", ENCODE_OLD, str(mesh), str(size), str(threads), str(out)],
                          capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())  # fmt: skip
    if done.returncode != 0:
        raise RuntimeError(done.stderr.strip().splitlines()[-1:])
    row = json.loads(done.stdout.strip().splitlines()[-1])
    v, f = decode(out.read_bytes())
    return row | {"vertices": v, "faces": f}


def main() -> None:
    from tetweave_codec.benchmarks.common import commit_tree, script_parser
    from tetweave_codec.encoder import encode
    from tetweave_codec.meshio import save_mesh
    from tetweave_codec.options import EncodeOptions

    ap = script_parser(__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="5k,10k", help="comma-separated --size values (k = 1024)")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--runs", default="clean,auto", help="which of clean, auto, before to encode")
    ap.add_argument("--before", default="", help="the commit whose default encode is the `before` run, or a folder"
                    " common.commit_tree made for it (reused)")  # fmt: skip
    ap.add_argument("--before-sizes", default="", help="sizes of the before run (default: --sizes)")
    ap.add_argument("--save", default="", help="folder for the messy inputs and the files (for tetweave render)")
    args = ap.parse_args()
    threads = args.threads or 1
    import torch

    torch.set_num_threads(threads)

    def parse(text: str) -> list[int]:
        return [int(float(s[:-1]) * 1024) if s.endswith("k") else int(s) for s in text.split(",") if s]

    sizes = parse(args.sizes)
    before_sizes = parse(args.before_sizes) if args.before_sizes else sizes
    runs = args.runs.split(",")
    save = Path(args.save) if args.save else None
    if save:
        save.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tree = None
        if "before" in runs and args.before:
            tree = Path(args.before) if Path(args.before).is_dir() else commit_tree(args.before, Path(tmp))
        for kind in args.kinds.split(","):
            messy, truth = build(kind)
            messy_path = (save or Path(tmp)) / f"parts_{kind}.ply"
            save_mesh(messy_path, *messy)
            for size in sizes:
                clean_err = None
                for label in runs:
                    if label == "before" and (tree is None or size not in before_sizes):
                        continue
                    t0 = time.perf_counter()
                    tw = (save or Path(tmp)) / f"parts_{kind}_{size // 1024}k_{label}.tw"
                    if label == "before":
                        r = encode_before(tree, messy_path, size, threads, tw)
                        nbytes, summary, out_v, out_f, surface = (
                            r["bytes"], r["chamfer"], r["vertices"], r["faces"], r["surface"]
                        )  # fmt: skip
                    else:
                        mv, mf = truth if label == "clean" else messy
                        res = encode(mv, mf, options=EncodeOptions(size=size, threads=threads))
                        tw.write_bytes(res.data)
                        nbytes, summary, out_v, out_f = (
                            len(res.data),
                            float(res.stats["chamfer"]),
                            res.vertices,
                            res.faces,
                        )
                        surface = res.stats.get("surface")
                    secs = time.perf_counter() - t0
                    m = measure(truth, out_v, out_f)
                    if label == "clean":
                        clean_err = m["chamfer"]
                    ratio = m["chamfer"] / clean_err if clean_err else float("nan")
                    rows.append((kind, f"{size // 1024}k", label, nbytes, m["chamfer"], clean_err, ratio, summary,
                                 m["nc"], m["unseen"], m["closed"], f"{secs:.0f}s {surface}"))  # fmt: skip
                    print(*rows[-1], flush=True)
    print("| kind | size | run | bytes | error vs truth | clean-union error | ratio | summary's error | NC | unseen "
          "area | closed | time, surface |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        cells = [f"{x:.3g}" if isinstance(x, float) else str(x) for x in r]
        cells[9] = f"{100 * r[9]:.2f} %"
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
