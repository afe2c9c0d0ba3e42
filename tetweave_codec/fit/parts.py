"""The exact outside surface of closed parts: connected components, and the boolean union of the closed ones.

Assets made of parts (CAD assemblies, primitives pushed through each other, boolean test scenes) are often a
concatenation of closed surfaces that overlap or nest, never booleaned. Their outside surface is the boundary of
the union of the solids the parts bound, and manifold3d computes it exactly (no pixels): hidden parts drop out,
faces that pass through another part are cut at the seam. Renders (fit.visible) only decide what they must: open
parts, sheets, soups, inconsistently oriented parts.

A part is a connected component of the input after welding vertices at equal positions (faces sharing an edge).
It is closed when it is a closed, consistently oriented 2-manifold without degenerate faces (each directed edge
used once, with its twin), that manifold3d accepts, with a non-zero volume; a part with a negative volume (inside
out, or the inner wall of a thickened shell) is turned outwards before the union.

The union keeps the input's own faces where the boolean leaves them whole (the input's vertex indices and order,
exactly: a hidden part inside a clean mesh leaves that mesh's faces as they were), then the pieces the boolean cut
or made, in a canonical order (sorted by their corners' positions: the same output on every run).

    split = split_parts(vertices, faces)   # Parts: component per face, closed components, rest (non-closed) faces
    union = closed_union(vertices, faces, split)   # Union: vertices (V',3), faces (F',3), dropped area share
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tetweave_codec.geometry.triangles import face_areas

# Parts that touch face to face: manifold3d's symbolic perturbation leaves coincident opposite faces in the union
# (two solids side by side), a membrane inside the solid. The union is computed again with every closed part moved
# outwards along its vertex normals by this share of the parts' bounding box; when that drops more than
# CONTACT_AREA_SHARE of the exact union's area, the contacts were real and the moved union is the surface (its
# vertices 1e-6 of the box off the input's: far below any quantization step).
TOUCH_OFFSET = 1e-6
CONTACT_AREA_SHARE = 1e-4
# A closed part with |volume| below this share of its bounding box's volume is flat (two coincident sheets): not a
# solid, left to the renders.
MIN_VOLUME_SHARE = 1e-9


@dataclass(frozen=True)
class Parts:
    """The input's connected components after welding by position.

    weld (V,) int64: each vertex's welded index (the first vertex at its position); component (F,) int64: each
    face's component; closed: the closed components' ids (ascending); inverted (len(closed),) bool: whether each
    closed component is inside out (negative volume; turned outwards for the union); rest (F,) bool: faces of
    the components that are not closed (and degenerate faces), which renders decide about; count: components."""

    weld: np.ndarray
    component: np.ndarray
    closed: np.ndarray
    inverted: np.ndarray
    rest: np.ndarray
    count: int


@dataclass(frozen=True)
class Union:
    """The boundary of the union of the closed parts' solids, oriented outwards.

    vertices (V',3) float64 (the input's vertices first, as given, then the vertices the boolean made); faces
    (F',3) int64; kept (F',) int64: the input face each output face is (-1 for a piece the boolean cut or made);
    area: the union's area; parts_area: the closed parts' summed area (their dropped share: 1 - area / parts_area
    of what they had)."""

    vertices: np.ndarray
    faces: np.ndarray
    kept: np.ndarray
    area: float
    parts_area: float


def _components(faces: np.ndarray) -> tuple[int, np.ndarray]:
    """(count, label (F,)): connected components of faces (F,3) joined across shared edges (parts that only touch
    at a vertex are two), numbered in the order of their first face."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, edge_id = np.unique(edges, axis=0, return_inverse=True)
    edge_id = edge_id.reshape(-1)
    rows = np.tile(np.arange(len(faces)), 3)
    size = len(faces) + int(edge_id.max()) + 1
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, len(faces) + edge_id)), shape=(size, size))
    _, labels = connected_components(graph, directed=False)
    face_labels = labels[: len(faces)]
    # renumber in the order of each component's first face (deterministic, independent of scipy's numbering)
    _, first, inverse = np.unique(face_labels, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))
    return len(first), order[inverse.reshape(-1)].astype(np.int64)


def _closed_manifold(wf: np.ndarray) -> bool:
    """Whether faces (F,3) (welded indices, no degenerate face) are a closed, consistently oriented edge-manifold:
    every directed edge used once and its twin used once."""
    tail = wf.reshape(-1)
    head = wf[:, [1, 2, 0]].reshape(-1)
    n = int(wf.max()) + 1
    forward = tail * n + head
    backward = head * n + tail
    fs = np.sort(forward)
    if np.any(fs[1:] == fs[:-1]):
        return False
    return bool(np.isin(backward, fs, assume_unique=False).all())


def _signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _manifold(vertices: np.ndarray, faces: np.ndarray, face_ids: np.ndarray | None = None):
    """manifold3d.Manifold of a closed part (vertices (V,3) float64, faces (F,3) into them; face_ids (F,): what the
    boolean's output reports as each of its triangles' source face), or None when manifold3d refuses it (not a
    2-manifold at a vertex, ...)."""
    import manifold3d

    ids = np.arange(len(faces)) if face_ids is None else face_ids
    mesh = manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(vertices, dtype=np.float64),
        tri_verts=np.ascontiguousarray(faces, dtype=np.uint64),
        face_id=np.ascontiguousarray(ids, dtype=np.uint64),
    )
    m = manifold3d.Manifold(mesh)
    if m.status() != manifold3d.Error.NoError or m.is_empty():
        return None
    return m


def _moved_out(m):
    """The closed part (manifold3d.Manifold) with each vertex moved outwards along its area-weighted normal by
    TOUCH_OFFSET of its bounding box's longest side (face ids kept)."""
    import manifold3d

    mesh = m.to_mesh64()
    v = np.array(mesh.vert_properties, dtype=np.float64)[:, :3]
    f = np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    normals = np.zeros_like(v)
    for k in range(3):
        np.add.at(normals, f[:, k], cross)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    lo, hi = v.min(axis=0), v.max(axis=0)
    v = v + normals * (TOUCH_OFFSET * float((hi - lo).max()))
    moved = manifold3d.Manifold(
        manifold3d.Mesh64(
            vert_properties=np.ascontiguousarray(v),
            tri_verts=np.ascontiguousarray(f, dtype=np.uint64),
            face_id=np.ascontiguousarray(np.asarray(mesh.face_id), dtype=np.uint64),
        )
    )
    return moved if moved.status() == manifold3d.Error.NoError else m


def split_parts(vertices: np.ndarray, faces: np.ndarray) -> Parts:
    """The connected components of the input (vertices (V,3), faces (F,3)) after welding by position, and which
    are closed parts (module docstring)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    _, first, inverse = np.unique(v, axis=0, return_index=True, return_inverse=True)
    weld = first[inverse.reshape(-1)].astype(np.int64)
    wf = weld[f]
    degenerate = (wf[:, 0] == wf[:, 1]) | (wf[:, 1] == wf[:, 2]) | (wf[:, 2] == wf[:, 0])
    degenerate |= ~np.isfinite(v[f]).all(axis=(1, 2))
    count, component = _components(wf)
    closed, inverted = [], []
    rest = degenerate.copy()
    order = np.argsort(component, kind="stable")
    bounds = np.searchsorted(component[order], np.arange(count + 1))
    for c in range(count):
        idx = order[bounds[c] : bounds[c + 1]]
        if degenerate[idx].any() or len(idx) < 4 or not _closed_manifold(wf[idx]):
            rest[idx] = True
            continue
        used, local = np.unique(wf[idx], return_inverse=True)
        pv, pf = v[used], local.reshape(-1, 3)
        volume = _signed_volume(pv, pf)
        box = np.prod(np.maximum(pv.max(axis=0) - pv.min(axis=0), 1e-12))
        if abs(volume) <= MIN_VOLUME_SHARE * box or _manifold(pv, pf) is None:
            rest[idx] = True
            continue
        closed.append(c)
        inverted.append(volume < 0)
    return Parts(weld, component, np.asarray(closed, dtype=np.int64), np.asarray(inverted, dtype=bool), rest, count)


def closed_union(vertices: np.ndarray, faces: np.ndarray, parts: Parts) -> Union:
    """The exact union of the closed parts (manifold3d's boolean; inverted parts turned outwards), its faces mapped
    back to the input's where the boolean kept them whole (module docstring). vertices (V,3), faces (F,3)."""
    import manifold3d

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    wf = parts.weld[f]
    manifolds = []
    for c, inverted in zip(parts.closed, parts.inverted, strict=True):
        idx = np.flatnonzero(parts.component == c)
        used, local = np.unique(wf[idx], return_inverse=True)
        pf = local.reshape(-1, 3)
        if inverted:
            pf = pf[:, ::-1]
        manifolds.append(_manifold(v[used], pf, idx))  # face ids: the input's face indices
    area = face_areas(v, f)
    parts_area = float(area[~parts.rest].sum())
    if not manifolds:
        return Union(v, np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64), 0.0, 0.0)
    union = manifolds[0] if len(manifolds) == 1 else manifolds[0].batch_boolean(manifolds, manifold3d.OpType.Add)
    mesh = union.to_mesh64()
    if len(manifolds) > 1:
        moved = manifolds[0].batch_boolean([_moved_out(m) for m in manifolds], manifold3d.OpType.Add)
        if moved.surface_area() < (1.0 - CONTACT_AREA_SHARE) * union.surface_area():
            mesh = moved.to_mesh64()
    uv = np.array(mesh.vert_properties, dtype=np.float64)[:, :3]
    uf = np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)
    # an output triangle is an input face kept whole when its corners are that face's corners (in its turn)
    face_id = np.asarray(mesh.face_id, dtype=np.int64)
    ok = (face_id >= 0) & (face_id < len(f))
    fid = np.where(ok, face_id, 0)
    original = f[fid]
    flipped = np.isin(parts.component[fid], parts.closed[parts.inverted])
    original[flipped] = original[flipped][:, ::-1]
    corners, out = v[original], uv[uf]
    same = np.zeros(len(uf), dtype=bool)
    for shift in range(3):
        same |= (np.roll(out, shift, axis=1) == corners).all(axis=(1, 2))
    source = np.where(ok & same, fid, -1)
    whole = np.sort(source[source >= 0])
    if len(np.unique(whole)) != len(whole):  # the boolean kept a face twice: should not happen; keep its pieces
        whole = np.unique(whole)
    kept_faces = f[whole].copy()
    flip = np.isin(parts.component[whole], parts.closed[parts.inverted])
    kept_faces[flip] = kept_faces[flip][:, ::-1]
    # the cut and new pieces: their corners onto the input's vertices where the position is an input vertex's
    cut = uf[source < 0]
    reps = np.unique(parts.weld)
    _, inverse = np.unique(np.concatenate([v[reps], uv]), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    rep_of = np.full(int(inverse.max()) + 1, -1, dtype=np.int64)
    rep_of[inverse[: len(reps)]] = reps
    index = rep_of[inverse[len(reps) :]]
    fresh = np.flatnonzero(index < 0)
    index[fresh] = len(v) + np.arange(len(fresh))
    out_v = np.concatenate([v, uv[fresh]])
    cut = index[cut]
    # canonical order: each piece rotated to start at its smallest corner (by position), pieces sorted by corners
    if len(cut):
        rank = np.lexsort(out_v.T[::-1])
        pos = np.empty(len(out_v), dtype=np.int64)
        pos[rank] = np.arange(len(out_v))
        first = np.argmin(pos[cut], axis=1)
        cut = np.take_along_axis(cut, (first[:, None] + np.arange(3)) % 3, axis=1)
        cut = cut[np.lexsort(pos[cut].T[::-1])]
    out_f = np.concatenate([kept_faces, cut])
    kept = np.concatenate([whole, np.full(len(cut), -1, dtype=np.int64)])
    return Union(out_v, out_f, kept, float(face_areas(out_v, out_f).sum()), parts_area)


def thin_slab(vertices: np.ndarray, faces: np.ndarray, thickness: float) -> tuple[np.ndarray, np.ndarray]:
    """An open surface (vertices (V,3), faces (F,3): sheets, cards, leaves) as a closed slab `thickness` thick:
    welded by position and consistently oriented per component (trimesh), its vertices moved by +-thickness / 2
    along their area-weighted normals (the top with the faces' orientation, the bottom reversed), every boundary
    edge closed by a wall of two triangles. Returns (vertices (2V',3), faces (2F + 4B, 3)), outward-oriented where
    the input is an edge-manifold (the fit's winding number is then 1 inside the slab)."""
    import trimesh

    m = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64), process=True)
    trimesh.repair.fix_winding(m)
    v = np.asarray(m.vertices, dtype=np.float64)
    f = np.asarray(m.faces, dtype=np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    normals = np.zeros_like(v)
    for k in range(3):
        np.add.at(normals, f[:, k], cross)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    n = len(v)
    out_v = np.concatenate([v + 0.5 * thickness * normals, v - 0.5 * thickness * normals])
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = directed[:, 0] * n + directed[:, 1]
    twin = directed[:, 1] * n + directed[:, 0]
    a, b = directed[~np.isin(key, twin)].T  # boundary edges a -> b, as the top's faces run them
    walls = np.concatenate([np.stack([b, a, a + n], axis=1), np.stack([b, a + n, b + n], axis=1)])
    return out_v, np.concatenate([f, f[:, ::-1] + n, walls])
