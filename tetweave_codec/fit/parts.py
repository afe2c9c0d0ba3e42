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
# Faces around a shared edge whose angles about it differ by less than this (radians) are coincident (`_wedge_pairs`).
ANGLE_TIE = 1e-9
# A closed part with |volume| below this share of its bounding box's volume is flat (two coincident sheets): not a
# solid, left to the renders.
MIN_VOLUME_SHARE = 1e-9


@dataclass(frozen=True)
class Parts:
    """The input's connected components after welding by position.

    weld (V,) int64: each vertex's welded index (the first vertex at its position); component (F,) int64: each
    face's component; closed: the closed components' ids (ascending); inverted (len(closed),) bool: whether each
    closed component is inside out (negative volume; turned outwards for the union); rest (F,) bool: faces of
    the components that are not closed (and degenerate faces), which renders decide about; count: components;
    duplicate (F,) bool: faces that repeat an earlier face with the same corners in the same turn (two identical
    parts on top of each other): in no part and not in rest, the earlier face stands for them."""

    weld: np.ndarray
    component: np.ndarray
    closed: np.ndarray
    inverted: np.ndarray
    rest: np.ndarray
    count: int
    duplicate: np.ndarray | None = None


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


def _components(vertices: np.ndarray, faces: np.ndarray, usable: np.ndarray) -> tuple[int, np.ndarray]:
    """(count, label (F,)): the parts of faces (F,3) (welded indices into vertices (V,3)), numbered in the order of
    their first face; faces not `usable` (degenerate) are parts of their own.

    Faces are joined across an edge used by exactly two faces, and across an edge used by more (parts welded along
    a shared edge, as an assembly exported as one mesh has them) only in the pairs that bound one solid wedge
    (`_wedge_pairs`): two boxes sharing an edge stay two closed parts, a part's own faces stay one. Parts that only
    touch at a vertex are two."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n_faces = len(faces)
    rows = np.flatnonzero(usable)
    uf = faces[rows]
    tail = np.concatenate([uf[:, 0], uf[:, 1], uf[:, 2]])
    head = np.concatenate([uf[:, 1], uf[:, 2], uf[:, 0]])
    third = np.concatenate([uf[:, 2], uf[:, 0], uf[:, 1]])
    owner = np.tile(rows, 3)
    lo, hi = np.minimum(tail, head), np.maximum(tail, head)
    order = np.lexsort((hi, lo))
    lo, hi = lo[order], hi[order]
    start = np.flatnonzero(np.r_[True, (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])])
    size = np.diff(np.r_[start, len(lo)])
    pair_a, pair_b = [], []
    two = start[size == 2]
    pair_a.append(owner[order[two]])
    pair_b.append(owner[order[two + 1]])
    many = size > 2
    if many.any():
        a, b = _wedge_pairs(vertices, tail[order], head[order], third[order], start[many], size[many])
        pair_a.append(owner[order[a]])
        pair_b.append(owner[order[b]])
    pa, pb = np.concatenate(pair_a), np.concatenate(pair_b)
    graph = coo_matrix((np.ones(len(pa), dtype=np.int8), (pa, pb)), shape=(n_faces, n_faces))
    _, labels = connected_components(graph, directed=False)
    # renumber in the order of each component's first face (deterministic, independent of scipy's numbering)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.argsort(np.argsort(first))
    return len(first), rank[inverse.reshape(-1)].astype(np.int64)


def _wedge_pairs(
    vertices: np.ndarray, tail: np.ndarray, head: np.ndarray, third: np.ndarray, start: np.ndarray, size: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Which faces around edges used by more than two faces bound one solid wedge: rows (a, b) of the pairs.

    tail, head, third (M,): each face's use of an edge and its third corner, rows grouped by edge; start, size:
    the groups of the edges used by more than two faces. Around the edge's axis e (from its smaller to its larger
    vertex index), a face that runs the edge along e has its outward normal turning counter-clockwise (towards
    larger angles of its third corner about e), so its solid lies clockwise of it; a face that runs against e has
    its solid counter-clockwise. Sorted by angle, each face running against e therefore opens a wedge that the
    next face closes, when that one runs along e. Faces of closed parts that touch along the edge without
    overlapping alternate so around it, and are paired part by part; an edge around which they do not alternate
    (solids that overlap there, inconsistent orientation) joins nothing: its faces go to parts that are not closed,
    which the renders decide about."""
    group = np.repeat(np.arange(len(start)), size)
    offsets = np.cumsum(np.r_[0, size[:-1]])
    pos = np.arange(int(size.sum())) - np.repeat(offsets, size)  # each row's place in its edge's group
    rows = np.repeat(start, size) + pos
    t, h, c = tail[rows], head[rows], third[rows]
    lo = np.minimum(t, h)
    hi = np.maximum(t, h)
    axis = vertices[hi] - vertices[lo]
    axis /= np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-300)
    # a reference direction perpendicular to each edge, the same for all its faces: the first face's third corner
    first = np.repeat(offsets, size)
    w = vertices[c] - vertices[lo]
    w -= np.einsum("ij,ij->i", w, axis)[:, None] * axis
    ref = w[first] / np.maximum(np.linalg.norm(w[first], axis=1, keepdims=True), 1e-300)
    other = np.cross(axis, ref)
    angle = np.arctan2(np.einsum("ij,ij->i", w, other), np.einsum("ij,ij->i", w, ref))
    # coincident faces (a lid on a housing's rim, a cube on a cube) lie at one angle up to rounding: equal angles
    # within ANGLE_TIE (and -pi with pi), and at a tie the face that closes a wedge before the one that opens the
    # next, as solids that touch there without overlapping have them
    angle = np.round(np.where(angle < -np.pi + ANGLE_TIE, np.pi, angle) / ANGLE_TIE)
    along = t == lo
    order = np.lexsort((~along, angle, group))
    g, al = group[order], along[order]
    nxt = offsets[g] + (pos + 1) % size[g]
    opener = ~al
    closes = al[nxt]
    ok_edge = np.ones(len(start), dtype=bool)
    np.logical_and.at(ok_edge, g[opener], closes[opener])
    ok_edge &= np.bincount(g, weights=al, minlength=len(start)) * 2 == size
    take = opener & ok_edge[g]
    return rows[order[take]], rows[order[nxt[take]]]


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
    """The parts of the input (vertices (V,3), faces (F,3)) after welding by position, and which are closed parts
    (module docstring). Vectorised over parts: one pass over the edges, one manifold3d check per closed part."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    _, first, inverse = np.unique(v, axis=0, return_index=True, return_inverse=True)
    weld = first[inverse.reshape(-1)].astype(np.int64)
    wf = weld[f]
    degenerate = (wf[:, 0] == wf[:, 1]) | (wf[:, 1] == wf[:, 2]) | (wf[:, 2] == wf[:, 0])
    degenerate |= ~np.isfinite(v[f]).all(axis=(1, 2))
    # a face repeating an earlier one (corners rotated to start at the smallest, so the turn is kept)
    turn = np.take_along_axis(wf, (np.argmin(wf, axis=1)[:, None] + np.arange(3)) % 3, axis=1)
    first = np.unique(turn, axis=0, return_index=True)[1]
    duplicate = np.ones(len(f), dtype=bool)
    duplicate[first] = False
    duplicate &= ~degenerate
    count, component = _components(v, wf, ~degenerate & ~duplicate)
    candidate = _closed_components(wf, component, count) & (np.bincount(component, minlength=count) >= 4)
    candidate &= np.bincount(component, weights=degenerate, minlength=count) == 0
    # signed volume and bounding box of each component (flat ones are two coincident sheets, not solids)
    a, b, c = (v[wf[:, k]] for k in range(3))
    volume = np.bincount(component, weights=np.einsum("ij,ij->i", a, np.cross(b, c)), minlength=count) / 6.0
    corners = v[wf].reshape(-1, 3)
    lo = np.full((count, 3), np.inf)
    hi = np.full((count, 3), -np.inf)
    np.minimum.at(lo, np.repeat(component, 3), corners)
    np.maximum.at(hi, np.repeat(component, 3), corners)
    box = np.prod(np.maximum(hi - lo, 1e-12), axis=1)
    candidate &= np.abs(volume) > MIN_VOLUME_SHARE * box
    order = np.argsort(component, kind="stable")
    bounds = np.searchsorted(component[order], np.arange(count + 1))
    closed = []
    for comp in np.flatnonzero(candidate):
        idx = order[bounds[comp] : bounds[comp + 1]]
        used, local = np.unique(wf[idx], return_inverse=True)
        if _manifold(v[used], local.reshape(-1, 3)) is not None:
            closed.append(comp)
    closed = np.asarray(closed, dtype=np.int64)
    is_closed = np.zeros(count, dtype=bool)
    is_closed[closed] = True
    rest = degenerate | (~is_closed[component] & ~duplicate)
    return Parts(weld, component, closed, volume[closed] < 0, rest, count, duplicate)


def _closed_components(wf: np.ndarray, component: np.ndarray, count: int) -> np.ndarray:
    """bool (count,): whether each component's faces (welded faces wf (F,3), component (F,)) are a closed,
    consistently oriented edge-manifold: within the component every edge used by exactly two faces, once in each
    direction."""
    tail = wf.reshape(-1)
    head = wf[:, [1, 2, 0]].reshape(-1)
    comp = np.repeat(component, 3)
    lo, hi = np.minimum(tail, head), np.maximum(tail, head)
    order = np.lexsort((hi, lo, comp))
    lo, hi, comp, along = lo[order], hi[order], comp[order], (tail == np.minimum(tail, head))[order]
    start = np.flatnonzero(np.r_[True, (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1]) | (comp[1:] != comp[:-1])])
    size = np.diff(np.r_[start, len(lo)])
    good = (size == 2) & (np.add.reduceat(along.astype(np.int64), start) == 1)
    bad = np.bincount(comp[start[~good]], minlength=count)
    return bad == 0


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
    face_id = np.asarray(mesh.face_id, dtype=np.int64)
    outer = outer_shells(uv, uf)
    uf, face_id = uf[outer], face_id[outer]
    # an output triangle is an input face kept whole when its corners are that face's corners (in its turn)
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


def outer_shells(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """bool (F,): the faces of the outer shells of a closed, outward-oriented solid (vertices (V,3), faces (F,3)
    into them, e.g. a union): a sealed cavity (the clearance around a bolt between its head and its nut, the air
    inside a closed housing) is bounded by a shell of negative volume, and whatever lies in a cavity by a shell
    inside another; no outside view sees either, so both go. A shell is a connected component (across edges); one
    of positive volume is outer when a vertex of it has winding number 0 with respect to the other positive shells
    (solid angles summed over their faces, exact to rounding; the shells of a union do not overlap)."""
    n = len(faces)
    if not n:
        return np.zeros(0, dtype=bool)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, edge_id = np.unique(edges, axis=0, return_inverse=True)
    edge_id = edge_id.reshape(-1)
    rows = np.tile(np.arange(n), 3)
    size = n + int(edge_id.max()) + 1
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, n + edge_id)), shape=(size, size))
    _, labels = connected_components(graph, directed=False)
    shell = np.unique(labels[:n], return_inverse=True)[1].reshape(-1)
    count = int(shell.max()) + 1
    if count == 1:
        return np.ones(n, dtype=bool)
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    volume = np.bincount(shell, weights=np.einsum("ij,ij->i", a, np.cross(b, c)), minlength=count)
    keep = volume > 0
    solid = np.flatnonzero(keep)
    if len(solid) > 1:
        first = np.unique(shell, return_index=True)[1]  # each shell's first face
        probe = vertices[faces[first[solid], 0]]
        inside = keep[shell]
        for k, s in enumerate(solid):
            others = inside & (shell != s)
            if _winding_number(probe[k], a[others], b[others], c[others]) > 0.5:
                keep[s] = False
    return keep[shell]


def _winding_number(point: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """Winding number of closed, outward triangles (corners a, b, c (F,3)) at `point` (3,): their solid angles (Van
    Oosterom and Strackee) over 4 pi."""
    x, y, z = a - point, b - point, c - point
    lx, ly, lz = (np.linalg.norm(u, axis=1) for u in (x, y, z))
    det = np.einsum("ij,ij->i", x, np.cross(y, z))
    den = lx * ly * lz + np.einsum("ij,ij->i", x, y) * lz + np.einsum("ij,ij->i", y, z) * lx
    den += np.einsum("ij,ij->i", z, x) * ly
    return float(2.0 * np.arctan2(det, den).sum() / (4.0 * np.pi))


def thin_slab(
    vertices: np.ndarray, faces: np.ndarray, thickness: float, solid=None, reach: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """An open surface (vertices (V,3), faces (F,3): sheets, cards, leaves, a shirt), its faces turned towards the
    views that see them, as a closed slab `thickness` thick behind it: welded by position and consistently oriented
    per component (trimesh; each component keeps the orientation most of its area had), the top on the surface
    itself (what a viewer sees stays where it was), the bottom `thickness` behind it along the area-weighted vertex
    normals and reversed, every boundary edge closed by a wall of two triangles. Returns (vertices (2V',3), faces
    (2F + 4B, 3)), outward-oriented where the input is an edge-manifold (the fit's winding number is then 1 inside
    the slab). solid: (vertices, faces) of a closed surface the sheet may rest on (a shirt on a body): where a
    vertex of the sheet is within `reach` of it, the bottom goes down to it and `thickness` into it, so that the
    union of the slab and the solid leaves no gap a viewer cannot see into anyway."""
    import trimesh

    given_v = np.asarray(vertices, dtype=np.float64)
    given_f = np.asarray(faces, dtype=np.int64)
    m = trimesh.Trimesh(given_v, given_f, process=True)
    before = m.face_normals.copy() * m.area_faces[:, None]
    trimesh.repair.fix_winding(m)
    v = np.asarray(m.vertices, dtype=np.float64)
    f = np.asarray(m.faces, dtype=np.int64).copy()
    if len(f) == len(before):  # fix_winding may turn a whole component against the views: turn it back
        label = trimesh.graph.connected_component_labels(m.face_adjacency, node_count=len(f))
        agree = np.bincount(label, weights=np.einsum("ij,ij->i", m.face_normals, before))
        back = agree[label] < 0
        f[back] = f[back][:, ::-1]
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    normals = np.zeros_like(v)
    for k in range(3):
        np.add.at(normals, f[:, k], cross)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    n = len(v)
    depth = np.full(n, thickness)
    if solid is not None and reach > 0 and len(solid[1]):
        from tetweave_codec.geometry.closest import SurfaceTree

        gap = np.sqrt(SurfaceTree(*solid).query(v)[0])
        near = gap <= reach
        depth[near] = gap[near] + thickness
    out_v = np.concatenate([v, v - depth[:, None] * normals])
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = directed[:, 0] * n + directed[:, 1]
    twin = directed[:, 1] * n + directed[:, 0]
    a, b = directed[~np.isin(key, twin)].T  # boundary edges a -> b, as the top's faces run them
    walls = np.concatenate([np.stack([b, a, a + n], axis=1), np.stack([b, a + n, b + n], axis=1)])
    return out_v, np.concatenate([f, f[:, ::-1] + n, walls])


def union_with(vertices: np.ndarray, faces: np.ndarray, other_v: np.ndarray, other_f: np.ndarray):
    """The exact union (manifold3d) of two closed, outward surfaces (vertices (V,3) / faces (F,3) each), sealed
    cavities dropped (`outer_shells`): (vertices, faces), or None when manifold3d refuses either (a slab that folds
    over itself where the sheet curves tighter than its thickness)."""

    pieces = []
    for v, f in ((vertices, faces), (other_v, other_f)):
        used, local = np.unique(np.asarray(f, dtype=np.int64), return_inverse=True)
        m = _manifold(np.asarray(v, dtype=np.float64)[used], local.reshape(-1, 3))
        if m is None:
            return None
        pieces.append(m)
    mesh = (pieces[0] + pieces[1]).to_mesh64()
    uv = np.array(mesh.vert_properties, dtype=np.float64)[:, :3]
    uf = np.array(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)
    if not len(uf):
        return None
    return uv, uf[outer_shells(uv, uf)]
