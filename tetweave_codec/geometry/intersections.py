"""Self-intersections of a mesh: the decoder's check after smoothing (geometry.smoothing) and a metric.

- ``self_intersecting_faces``: the faces that cross or touch another face. Candidate pairs come from a uniform
  grid over face bounding boxes. The predicate is conservative (formats/README.md, "Crossing faces"): closed
  triangles, every orientation within TOUCH_3D m^3 (a 2-D cross product within TOUCH_2D m^2) of zero counting
  as zero, m the pair's size, above the worst rounding of either, so faces that meet -- cross or touch -- are
  always flagged, and faces within ~2^-43 m of each other may be. A pair sharing no vertex is flagged when an
  edge of one touches the other, a pair sharing one vertex when the edge opposite it in one face touches the
  other (a fold), a pair sharing an edge never; each segment test ends in a 2-D test of the projections (a
  common point projects to a common point), which decides near-coplanar pairs whose orientations are noise.
  tests/test_exact_check.py checks it against an exact implementation that shares no code with it
  (benchmarks/exact_check.py).

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


def resolve_threads(threads: int) -> int:
    """A thread count as the checks run it: `threads` itself, or for 0 the cores this process may use (its CPU
    affinity where the OS has one). ValueError for a negative count or a non-integer."""
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)):
        raise ValueError(f"threads must be a whole number >= 0, got {threads!r}")
    if threads < 0:
        raise ValueError(f"threads must be >= 0 (0: every core), got {threads}")
    if threads:
        return int(threads)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return max(1, os.cpu_count() or 1)


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


# Contact tolerances of the predicate (formats/README.md, "Crossing faces"): with m the pair's scale
# (`_pair_scale`), an orientation of two of its points' differences errs by at most 384 u m^3 (u = 2^-53: eight
# roundings per term, six terms of differences <= 2m), a 2-D cross product by 32 u m^2. A sign beyond
# TOUCH_3D m^3 (2.7x that) or TOUCH_2D m^2 (4x) is exact; anything within counts as zero, i.e. as contact.
TOUCH_3D = 2.0**-43
TOUCH_2D = 2.0**-46


def _pair_scale(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P,) the largest |coordinate difference| of the six vertices of triangles a, b (P,3,3) from b0."""
    return np.maximum(np.abs(a - b[:, :1]).max(axis=(1, 2)), np.abs(b - b[:, :1]).max(axis=(1, 2)))


def _cross2(o, a, b):
    return (a[:, 0] - o[:, 0]) * (b[:, 1] - o[:, 1]) - (a[:, 1] - o[:, 1]) * (b[:, 0] - o[:, 0])


def _beyond(values, tol):
    """(P,) some value > tol and (P,) some value < -tol, of a list of (P,) arrays."""
    pos = np.zeros(len(tol), dtype=bool)
    neg = np.zeros(len(tol), dtype=bool)
    for x in values:
        pos |= x > tol
        neg |= x < -tol
    return pos, neg


def _point_in_closed_2d(p, t, tol):
    """Point p (P,2) in the closed triangle t (P,3,2), up to `tol` on each 2-D cross product."""
    pos, neg = _beyond([_cross2(t[:, i], t[:, (i + 1) % 3], p) for i in range(3)], tol)
    return ~(pos & neg)


def _segments_touch_2d(p, q, r, s, tol):
    """Closed segments pq and rs (P,2) meet, up to `tol` on each 2-D cross product, and their boxes overlap on
    both axes (a necessary condition of a common point, which settles nearly collinear segments: there the
    cross products are rounding noise around the tolerance)."""
    d1, d2 = _cross2(p, q, r), _cross2(p, q, s)
    d3, d4 = _cross2(r, s, p), _cross2(r, s, q)
    apart = ((d1 > tol) & (d2 > tol)) | ((d1 < -tol) & (d2 < -tol))
    apart |= ((d3 > tol) & (d4 > tol)) | ((d3 < -tol) & (d4 < -tol))
    boxes = np.ones(len(tol), dtype=bool)
    for k in range(2):
        lo = np.maximum(np.minimum(p[:, k], q[:, k]), np.minimum(r[:, k], s[:, k]))
        hi = np.minimum(np.maximum(p[:, k], q[:, k]), np.maximum(r[:, k], s[:, k]))
        boxes &= lo <= hi
    return ~apart & boxes


def _segment_touches_in_plane(p, q, t, normal, tol2):
    """Segment pq (P,3) and triangle t (P,3,3) projected to the coordinate plane that drops the first axis of
    largest |normal| (t's): the closed segment meets the closed triangle there, up to tol2."""
    axis = np.argmax(np.abs(normal), axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    rows = np.arange(len(p))[:, None]
    p2, q2 = p[rows, keep], q[rows, keep]
    t2 = np.stack([t[:, i][rows, keep] for i in range(3)], axis=1)
    hit = _point_in_closed_2d(p2, t2, tol2) | _point_in_closed_2d(q2, t2, tol2)
    for j in range(3):
        hit |= _segments_touch_2d(p2, q2, t2[:, j], t2[:, (j + 1) % 3], tol2)
    return hit


def _segment_touches_triangle(p, q, t, normal, sp, sq, tol, tol2):
    """The closed segment pq (P,3) meets the closed triangle t (P,3,3) or comes within the tolerances of it.

    normal: (t1 - t0) x (t2 - t0); sp, sq: orient(t0, t1, t2, p), orient(t0, t1, t2, q) as normal . (x - t0).
    Apart when both ends are beyond tol on one side of the plane, or when the segment is not within tol of the
    plane at both ends and the line through p and q passes beyond tol outside an edge of t (orient(p, q, t_i,
    t_i+1) of both signs); else the 2-D test of `_segment_touches_in_plane` decides (a common point projects to
    a common point, so it is a necessary condition of every contact: near-coplanar pairs, whose orientations
    are rounding noise, are decided there)."""
    maybe = ~(((sp > tol) & (sq > tol)) | ((sp < -tol) & (sq < -tol)))
    slanted = maybe & ~((np.abs(sp) <= tol) & (np.abs(sq) <= tol))
    if slanted.any():
        i = np.nonzero(slanted)[0]
        a, b, c, pp, qq = t[i, 0], t[i, 1], t[i, 2], p[i], q[i]
        pos, neg = _beyond([_orient(pp, qq, a, b), _orient(pp, qq, b, c), _orient(pp, qq, c, a)], tol[i])
        maybe[i] = ~(pos & neg)
    hit = np.zeros(len(p), dtype=bool)
    if maybe.any():
        i = np.nonzero(maybe)[0]
        hit[i] = _segment_touches_in_plane(p[i], q[i], t[i], normal[i], tol2[i])
    return hit


def _pairs_intersect(t1: np.ndarray, t2: np.ndarray, free1: np.ndarray, free2: np.ndarray) -> np.ndarray:
    """Contact test of triangle pairs t1, t2 (P,3,3) sharing at most one vertex; free1, free2 (P,3) bool: the
    corners not shared. See formats/README.md "Crossing faces": apart when one face's free corners lie beyond
    the tolerance on one side of the other's plane, else touching when an edge of free corners (all three of a
    pair sharing nothing, the one opposite the shared vertex otherwise) touches the other face."""
    scale = _pair_scale(t1, t2)
    tol = TOUCH_3D * scale * scale * scale
    tol2 = TOUCH_2D * scale * scale
    normals, sides = [], []
    apart = np.zeros(len(t1), dtype=bool)
    for x, y, free in ((t1, t2, free1), (t2, t1, free2)):
        n = row_cross(y[:, 1] - y[:, 0], y[:, 2] - y[:, 0])
        o = np.stack([row_dot(n, x[:, i] - y[:, 0]) for i in range(3)], axis=1)
        above = np.where(free, o > tol[:, None], True).all(axis=1)
        below = np.where(free, o < -tol[:, None], True).all(axis=1)
        apart |= above | below
        normals.append(n)
        sides.append(o)
    hit = np.zeros(len(t1), dtype=bool)
    for (x, y, free), n, o in zip(((t1, t2, free1), (t2, t1, free2)), normals, sides, strict=True):
        for i in range(3):
            j = (i + 1) % 3
            use = np.nonzero(~apart & ~hit & free[:, i] & free[:, j])[0]
            if len(use):
                hit[use] |= _segment_touches_triangle(
                    x[use, i], x[use, j], y[use], n[use], o[use, i], o[use, j], tol[use], tol2[use]
                )
    return hit


def self_intersecting_faces(
    vertices: np.ndarray, faces: np.ndarray, only: np.ndarray | None = None, children: int = 1, threads: int = 1
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

    threads: threads of the compiled path (1: the calling thread alone; 0: every core this process may use, see
    `resolve_threads`). The flags are the same on any count (the C file says why); the numpy path ignores it.
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError("face index out of range")
    mark = np.ones(len(f), dtype=bool) if only is None else np.asarray(only, dtype=bool).reshape(-1)
    if mark.shape != (len(f),):
        raise ValueError("only must be one flag per face")
    workers = resolve_threads(threads)
    if NATIVE:
        flags = np.zeros(len(f), dtype=np.uint8)
        only_u8 = np.ascontiguousarray(mark).view(np.uint8)
        if only is not None and MARKED_SHARE * int(mark.sum()) <= len(f):
            if _intersect_native.marked(v, f, flags, only_u8, workers) == 0:
                return flags.view(np.bool_)
        elif children == 4 and _intersect_native.stars(v, f, flags, only_u8, 4, workers) == 0:
            return flags.view(np.bool_)
        if _intersect_native.faces(v, f, flags, only_u8, workers):
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
        chunk, fa, fb, equal = chunk[test], fa[test], fb[test], equal[test]
        hit = _pairs_intersect(v[fa], v[fb], ~equal.any(axis=2), ~equal.any(axis=1))
        flagged[chunk[hit, 0]] = True
        flagged[chunk[hit, 1]] = True
    return flagged
