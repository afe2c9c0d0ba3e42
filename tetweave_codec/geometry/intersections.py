"""Self-intersections of a mesh: the decoder's check after smoothing (geometry.smoothing) and a metric.

- ``self_intersecting_faces``: the faces that properly intersect another face. Candidate pairs come from a
  uniform grid over face bounding boxes. A pair sharing no vertex intersects, if the two are coplanar, when
  their interiors overlap in the plane, else when an edge of one crosses the interior of the other (strict
  orientation tests in float64, with both ends of the edge farther than 1e-12 of the pair's size from the
  other's plane: on coplanar pairs and on edges lying in a plane the signs would be rounding noise). A pair
  sharing exactly one vertex intersects, if coplanar, when their interiors overlap in the plane, else when the
  edge opposite the shared vertex of one crosses the interior of the other (a fold around the vertex). Pairs
  sharing an edge are not tested (their only possible intersection is an exactly coplanar fold), and touching
  without crossing is not counted.

A compiled fast path (geometry/_intersect_native.c, built by setup.py when a C compiler is there) makes the same
grid decisions and evaluates the same predicate with every binary64 operation in the same order (the arithmetic
below is written out for that reason: no einsum, no np.cross, no norm), so both flag the same faces
(tests/test_intersections.py); this module stays the reference and the fallback (`NATIVE`, environment
TETWEAVE_NATIVE=0). Two shorter compiled ways give the same flags where they can prove it and decline otherwise:
`marked` for the decoder's later checks (few faces marked), `stars` for its first check of a filtered surface
(pairs of neighbouring faces shown free of crossings patch by patch, the others found through their parents).
"""

from __future__ import annotations

import os

import numpy as np

try:  # the compiled fast path (optional; identical output)
    from tetweave_codec.geometry import _intersect_native
except ImportError:  # not built: the numpy code below
    _intersect_native = None
NATIVE = _intersect_native is not None and os.environ.get("TETWEAVE_NATIVE", "1") != "0"


# `only` marking at most 1/MARKED_SHARE of the faces: the compiled path's short way first (the decoder's later
# checks mark a few hundred of 320K faces; the short way's hash grid is slower than the full grid for many)
MARKED_SHARE = 8
_MAX_CANDIDATE_PAIRS = 30_000_000  # refine the grid rather than materialise more pairs than this
_PAIR_CHUNK = 500_000


def _grid_pairs(lo: np.ndarray, hi: np.ndarray, cell: float) -> tuple[np.ndarray | None, str]:
    """Pairs (P,2) of boxes that share a grid cell of side `cell`, each pair once (a < b).

    Returns (None, "coarser") when the boxes cover too many cells, (None, "finer") when a cell holds so many
    boxes that the pairs would not fit in memory, else (pairs, "").
    """
    n = len(lo)
    origin = lo.min(axis=0)
    c0 = np.floor((lo - origin) / cell).astype(np.int64)
    c1 = np.floor((hi - origin) / cell).astype(np.int64)
    span = c1 - c0 + 1
    per_box = span.prod(axis=1)
    if per_box.sum() > 64 * n + 1_000_000:
        return None, "coarser"
    box = np.repeat(np.arange(n), per_box)
    local = np.arange(per_box.sum()) - np.repeat(np.cumsum(per_box) - per_box, per_box)
    sx, sy = span[box, 0], span[box, 1]
    cx = c0[box, 0] + local % sx
    cy = c0[box, 1] + (local // sx) % sy
    cz = c0[box, 2] + local // (sx * sy)
    dims = c1.max(axis=0) + 1
    key = (cz * dims[1] + cy) * dims[0] + cx
    order = np.argsort(key, kind="stable")
    box, key = box[order], key[order]
    _, start, size = np.unique(key, return_index=True, return_counts=True)
    # each element pairs with the ones after it in its cell
    rank = np.arange(len(key)) - np.repeat(start, size)
    after = np.repeat(size, size) - 1 - rank
    total = int(after.sum())
    if total > _MAX_CANDIDATE_PAIRS:
        return None, "finer"
    if total == 0:  # no two boxes share a cell (the dedupe below needs one pair)
        return np.zeros((0, 2), dtype=np.int64), ""
    first = np.repeat(np.arange(len(key)), after)
    step = np.arange(total) - np.repeat(np.cumsum(after) - after, after) + 1
    a, b = box[first], box[first + step]
    # a pair of boxes sharing several cells appears once per cell; dedupe on one int64 key (fast sort)
    key = np.sort(np.minimum(a, b) * n + np.maximum(a, b))  # np.unique hashes: ~60x slower on millions of keys
    key = key[np.concatenate([[True], key[1:] != key[:-1]])]
    return np.stack([key // n, key % n], axis=1), ""


def _candidate_pairs(tri: np.ndarray) -> np.ndarray:
    """Pairs (P,2) of triangles (P,3,3) whose bounding boxes overlap, each pair once."""
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    extent = (hi - lo).max(axis=1)
    # a cell of twice the median face size: most faces touch 1-8 cells, few cells hold many faces
    cell = 2.0 * float(np.median(extent))
    if not cell > 0:
        cell = float(extent.max()) or 1.0
    tried = set()
    while True:
        pairs, retry = _grid_pairs(lo, hi, cell)
        if pairs is not None:
            break
        tried.add(retry)
        if len(tried) == 2:  # neither coarser nor finer works: pathological, e.g. one huge face over many
            raise RuntimeError("self-intersection test: too many candidate face pairs")
        cell *= 2.0 if retry == "coarser" else 0.5
    overlap = np.all((lo[pairs[:, 0]] <= hi[pairs[:, 1]]) & (lo[pairs[:, 1]] <= hi[pairs[:, 0]]), axis=1)
    return pairs[overlap]


def row_dot(u, w):
    """Row-wise u . w of (P,3) arrays, summed in the order x, y, z (as the compiled path does)."""
    return (u[:, 0] * w[:, 0] + u[:, 1] * w[:, 1]) + u[:, 2] * w[:, 2]


def row_cross(u, w):
    """Row-wise u x w of (P,3) arrays (np.cross's formula, written out so that the compiled path matches it)."""
    return np.stack(
        [
            u[:, 1] * w[:, 2] - u[:, 2] * w[:, 1],
            u[:, 2] * w[:, 0] - u[:, 0] * w[:, 2],
            u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0],
        ],
        axis=1,
    )


def _orient(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Signed volume (x6) of tetrahedron (a, b, c, d); positive when d is on the side of (b-a)x(c-a)."""
    return row_dot(row_cross(b - a, c - a), d - a)


def _segment_crosses_triangle(p, q, a, b, c, scale) -> np.ndarray:
    """Segment pq properly crosses the interior of triangle abc (strict signs; touching is not crossing).

    p and q must lie on opposite sides of abc's plane by more than 1e-12 |n| scale (n = (b - a) x (c - a),
    scale (P,) the pair's size): an end within that of the plane touches it. Why: a segment lying in the plane
    (a subdivided surface's flat reference has many, through its edge midpoints) has orientations that are
    rounding noise, whose signs must not decide."""
    n = row_cross(b - a, c - a)
    sp, sq = row_dot(n, p - a), row_dot(n, q - a)
    tol = 1e-12 * np.sqrt(row_dot(n, n)) * scale
    s1, s2, s3 = _orient(p, q, a, b), _orient(p, q, b, c), _orient(p, q, c, a)
    same = ((s1 > 0) & (s2 > 0) & (s3 > 0)) | ((s1 < 0) & (s2 < 0) & (s3 < 0))
    return (sp * sq < 0) & (np.abs(sp) > tol) & (np.abs(sq) > tol) & same


def _coplanar_overlap(t1: np.ndarray, t2: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Interiors of coplanar triangles t1, t2 (P,3,3) overlap: projected on the dominant plane of `normal`
    (the first axis of largest |normal|)."""
    axis = np.argmax(np.abs(normal), axis=1)
    keep = np.broadcast_to(np.array([[1, 2], [0, 2], [0, 1]])[axis][:, None, :], (len(t1), 3, 2))
    u, w = np.take_along_axis(t1, keep, axis=2), np.take_along_axis(t2, keep, axis=2)

    def cross2(o, a, b):
        return (a[:, 0] - o[:, 0]) * (b[:, 1] - o[:, 1]) - (a[:, 1] - o[:, 1]) * (b[:, 0] - o[:, 0])

    def strictly_inside(p, t):
        d1, d2, d3 = cross2(t[:, 0], t[:, 1], p), cross2(t[:, 1], t[:, 2], p), cross2(t[:, 2], t[:, 0], p)
        return ((d1 > 0) & (d2 > 0) & (d3 > 0)) | ((d1 < 0) & (d2 < 0) & (d3 < 0))

    def centroid(t):
        return ((t[:, 0] + t[:, 1]) + t[:, 2]) / 3.0

    hit = strictly_inside(centroid(u), w) | strictly_inside(centroid(w), u)
    for i in range(3):
        hit |= strictly_inside(u[:, i], w) | strictly_inside(w[:, i], u)
        p, q = u[:, i], u[:, (i + 1) % 3]
        for j in range(3):
            r, s = w[:, j], w[:, (j + 1) % 3]
            hit |= (cross2(p, q, r) * cross2(p, q, s) < 0) & (cross2(r, s, p) * cross2(r, s, q) < 0)
    return hit


def _pair_scale(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P,) the largest |coordinate difference| of the six vertices of triangles a, b (P,3,3) from b0."""
    return np.maximum(np.abs(a - b[:, :1]).max(axis=(1, 2)), np.abs(b - b[:, :1]).max(axis=(1, 2)))


def _coplanar(a: np.ndarray, b: np.ndarray, n: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Triangles a (P,3,3) lie in the plane of triangles b (P,3,3) with normals n (P,3) = (b1 - b0) x (b2 - b0),
    up to 1e-12 of |n| times `_pair_scale(a, b)`."""
    bound = 1e-12 * np.sqrt(row_dot(n, n)) * scale
    coplanar = np.ones(len(a), dtype=bool)
    for k in range(3):
        coplanar &= np.abs(row_dot(a[:, k] - b[:, 0], n)) <= bound
    return coplanar


def _pairs_intersect(t1: np.ndarray, t2: np.ndarray, shared_one: np.ndarray, opp1, opp2) -> np.ndarray:
    """Intersection test of triangle pairs t1, t2 (P,3,3); see the module docstring."""
    hit = np.zeros(len(t1), dtype=bool)
    disjoint = ~shared_one
    if disjoint.any():
        a, b = t1[disjoint], t2[disjoint]
        scale = _pair_scale(a, b)
        h = np.zeros(len(a), dtype=bool)
        for x, y in ((a, b), (b, a)):
            for i in range(3):
                h |= _segment_crosses_triangle(x[:, i], x[:, (i + 1) % 3], y[:, 0], y[:, 1], y[:, 2], scale)
        # coplanar pairs: no edge can properly cross (the segment tests above decide on rounding noise there),
        # the overlap in the plane decides
        n = row_cross(b[:, 1] - b[:, 0], b[:, 2] - b[:, 0])
        coplanar = _coplanar(a, b, n, scale)
        h[coplanar] = False
        if coplanar.any():
            h[coplanar] = _coplanar_overlap(a[coplanar], b[coplanar], n[coplanar])
        hit[disjoint] = h
    if shared_one.any():
        idx = np.nonzero(shared_one)[0]
        a, b = t1[idx], t2[idx]
        rows = np.arange(len(idx))
        # coplanar pairs (a subdivided surface's flat reference has many): the segment tests below would decide
        # on rounding noise, so the overlap in the plane decides (a fold around the shared vertex)
        n = row_cross(b[:, 1] - b[:, 0], b[:, 2] - b[:, 0])
        scale = _pair_scale(a, b)
        coplanar = _coplanar(a, b, n, scale)
        # opp* (P,2): local indices of the two vertices not shared, per triangle
        p1, q1 = a[rows, opp1[idx, 0]], a[rows, opp1[idx, 1]]
        p2, q2 = b[rows, opp2[idx, 0]], b[rows, opp2[idx, 1]]
        h = _segment_crosses_triangle(p1, q1, b[:, 0], b[:, 1], b[:, 2], scale)
        h |= _segment_crosses_triangle(p2, q2, a[:, 0], a[:, 1], a[:, 2], scale)
        h[coplanar] = False
        if coplanar.any():
            h[coplanar] = _coplanar_overlap(a[coplanar], b[coplanar], n[coplanar])
        hit[idx] = h
    return hit


def self_intersecting_faces(
    vertices: np.ndarray, faces: np.ndarray, only: np.ndarray | None = None, children: int = 1
) -> np.ndarray:
    """Boolean mask (F,) of faces that properly intersect another face (see the module docstring).

    Degenerate (zero-area) faces are neither tested nor flagged. only: (F,) bool, test only the pairs with at
    least one face marked (the decoder's later rounds, where every other pair is known not to cross); the
    candidate grid and its work bound are those of the whole mesh either way. With few faces marked (at most
    1/MARKED_SHARE of them) the compiled path first tries `_intersect_native.marked`: O(F) passes that prove the
    whole mesh's grid feasible at its first cell size (exact entry and pair counts) and then test only the marked
    faces' pairs, found through a hash grid of their cells -- the same answer (the proof is in the C file), or no
    answer, and then the full check runs.

    children: 4 when the faces come in runs of four children of one face (a Loop level's output,
    geometry.subdivision.loop_level), else 1. Only a hint for speed: with 4 and many faces marked the compiled path
    first tries `_intersect_native.stars`, which tests the pairs of faces whose parents share no vertex and shows
    the others free of crossings patch by patch around each vertex where it can (the proof is in the C file) -- the
    same answer, or no answer (the runs are not Loop children, a grid would be too large), and then `faces` runs.
    (`stars` also takes single faces as their own parents, but there it saves only the fold tests and is no
    faster than `faces`: fandisk's 40 KB smoothed surface, 57 ms against 75.)
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError("face index out of range")
    mark = np.ones(len(f), dtype=bool) if only is None else np.asarray(only, dtype=bool).reshape(-1)
    if mark.shape != (len(f),):
        raise ValueError("only must be one flag per face")
    if NATIVE:
        flags = np.zeros(len(f), dtype=np.uint8)
        only_u8 = np.ascontiguousarray(mark).view(np.uint8)
        if only is not None and MARKED_SHARE * int(mark.sum()) <= len(f):
            if _intersect_native.marked(v, f, flags, only_u8) == 0:
                return flags.view(np.bool_)
        elif children == 4 and _intersect_native.stars(v, f, flags, only_u8, 4) == 0:
            return flags.view(np.bool_)
        if _intersect_native.faces(v, f, flags, only_u8):
            raise RuntimeError("self-intersection test: too many candidate face pairs")
        return flags.view(np.bool_)
    flagged = np.zeros(len(f), dtype=bool)
    if len(f) < 2:
        return flagged
    tri = v[f]
    n = row_cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    valid = np.nonzero(row_dot(n, n) > 0)[0]
    if len(valid) < 2:
        return flagged
    pairs = valid[_candidate_pairs(tri[valid])]
    pairs = pairs[mark[pairs[:, 0]] | mark[pairs[:, 1]]]
    for s in range(0, len(pairs), _PAIR_CHUNK):
        chunk = pairs[s : s + _PAIR_CHUNK]
        fa, fb = f[chunk[:, 0]], f[chunk[:, 1]]
        equal = fa[:, :, None] == fb[:, None, :]  # (P,3,3): vertex i of a == vertex j of b
        n_shared = equal.any(axis=2).sum(axis=1)
        test = n_shared <= 1
        chunk, fa, fb, equal, n_shared = chunk[test], fa[test], fb[test], equal[test], n_shared[test]
        shared_one = n_shared == 1
        # local indices of the non-shared vertices: sort puts the shared one (True) last
        opp1 = np.argsort(equal.any(axis=2), axis=1, kind="stable")[:, :2]
        opp2 = np.argsort(equal.any(axis=1), axis=1, kind="stable")[:, :2]
        hit = _pairs_intersect(v[fa], v[fb], shared_one, opp1, opp2)
        flagged[chunk[hit, 0]] = True
        flagged[chunk[hit, 1]] = True
    return flagged
