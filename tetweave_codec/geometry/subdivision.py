"""Loop subdivision of the decoded surface (`.tw` v2 flags bits 5-6; formats/README.md "Subdivision").

A marching-tets surface is piecewise flat: on a curved input its error falls only as the square of the point
spacing, and its normals jump at every edge. One level of Loop subdivision (Loop, 1987) splits each triangle into
four and moves every vertex by fixed weights of its neighbours, a smooth surface of the same control vertices. The
fit optimizes s and c *through* the subdivision (fit.step.extract), so the subdivided surface is what matches the
input: on smooth shapes the same Chamfer distance takes fewer points (docs/measurements/subdivision.md).

Exact and reproducible by an independent decoder (IEEE 754 binary64, one rounding per operation as written), for
one level of vertices (V,3) and faces (F,3):

* Edges: the undirected edges {a, b} of the faces, each once, in ascending (min(a, b), max(a, b)) order; edge e
  becomes vertex V + e. An edge with exactly two faces has opposite vertices c and d (the third corners of its two
  faces); any other edge has none (never in a decoder's closed mesh).
* Edge vertex: `0.375 * (v_a + v_b) + 0.125 * (v_c + v_d)`; with no opposite vertices `0.5 * (v_a + v_b)`.
* Old vertex i with k distinct neighbours j (summed in ascending j, from 0): beta = 0.1875 when k = 3, 3 / (8k)
  when k > 3 (Warren's weights: rational, so exact; Loop's original ones need a cosine); then
  `v_i' = (1 - k * beta) * v_i + beta * sum_j v_j`. With k < 3 the vertex stays.
* Faces: face f = (a, b, c) with edge vertices m_ab, m_bc, m_ca becomes faces 4f .. 4f + 3:
  (a, m_ab, m_ca), (m_ab, b, m_bc), (m_ca, m_bc, c), (m_ab, m_bc, m_ca), which keeps the orientation.

* Crease rules (files with crease-preserving smoothing, bit 7 of the position-bits byte; `loop_level`'s
  `creases`): the first level's creases are the smoothing's (`smoothing.crease_edges` of the extracted surface),
  a later level's the halves of the level before's; a crease edge's vertex is its midpoint, a vertex on exactly
  two crease edges `0.75 * v_i + 0.125 * (v_j1 + v_j2)` (beta = 1/8 over its two crease neighbours), a vertex on
  one or on three and more stays, every other vertex as above (Hoppe et al. 1994's piecewise smooth surfaces).

Subdivision moves vertices off the piecewise-flat surface, so in rare cases it may touch itself where it was thin;
the decoder then puts the vertices of crossing faces back to the *midpoint* subdivision of the unsmoothed surface
(same faces, edge vertices at `0.5 * (v_a + v_b)`, old vertices unmoved: geometrically the unsmoothed surface
itself; geometry.surface_filter.restore_crossings). Connectivity is a fixed refinement of a closed 2-manifold: it stays
one.
"""

from __future__ import annotations

import os
from typing import Any, NamedTuple

import numpy as np

from tetweave_codec.geometry import smoothing
from tetweave_codec.geometry.smoothing import mesh_edges, neighbours_along_creases

# geometry/_filter_native.c for `loop_and_midpoint` without crease rules (the decoder's Loop levels of a closed
# mesh); the numpy code below is the reference and the fallback (TETWEAVE_NATIVE=0)
NATIVE = smoothing._filter_native is not None and os.environ.get("TETWEAVE_NATIVE", "1") != "0"

EDGE_NEAR = 0.375  # weight of an edge's two ends in its new vertex
EDGE_FAR = 0.125  # weight of the two opposite corners
BETA_VALENCE_3 = 0.1875  # Warren's beta for three neighbours; 3 / (8k) above
BETA_CREASE = 0.125  # a crease vertex's weight of each of its two crease neighbours (the cubic B-spline rule)


class LoopLevel(NamedTuple):
    """The connectivity of one Loop level of a mesh with `num_vertices` vertices (numpy int64).

    edges (E,2): a < b, ascending; opposite (E,2): the third corners of the edge's two faces, -1 -1 when the edge
    does not have exactly two, or is a crease; faces (4F,3): the refined faces (vertex V + e is edge e's new
    vertex); neighbours (2E,2) or fewer: `smoothing.mesh_edges` of the input faces (each edge both ways, sorted by
    (i, j)), whose order is the spec's order of the neighbour sums; with creases, only the edges a vertex averages
    over (`smoothing.crease_neighbours`' rule). creases (E,) bool or None: the crease edges (crease rules, below).
    """

    num_vertices: int
    edges: np.ndarray
    opposite: np.ndarray
    faces: np.ndarray
    neighbours: np.ndarray
    creases: np.ndarray | None = None


def loop_level(
    faces: Any,
    num_vertices: int,
    neighbours: np.ndarray | None = None,
    creases: np.ndarray | None = None,
    parent: LoopLevel | None = None,
) -> LoopLevel:
    """The connectivity of one Loop level: faces (F,3) int (numpy or torch) over `num_vertices` vertices.

    neighbours: `mesh_edges(faces, num_vertices)` when the caller has it (the decoder's smoothing does). creases:
    (E,) bool over this level's edges (ascending), the crease rules (Hoppe et al. 1994): a crease edge's new
    vertex is its midpoint, a vertex on two crease edges moves by 3/4 of itself and 1/8 of each crease neighbour,
    a vertex on one or three and more stays, the others follow Loop's rule. parent: the level these faces came
    from, whose crease edges' halves are this level's creases (creases then None)."""
    n = int(num_vertices)
    f = np.asarray(faces.cpu().numpy() if hasattr(faces, "cpu") else faces, dtype=np.int64).reshape(-1, 3)
    if neighbours is None:
        neighbours = mesh_edges(f, n)
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    u = np.concatenate([a, b, c])  # half-edges (a,b), (b,c), (c,a) of every face, then their opposite corners
    w = np.concatenate([b, c, a])
    opp = np.concatenate([c, a, b])
    key = np.minimum(u, w) * n + np.maximum(u, w)
    order = np.argsort(key, kind="stable")
    sk = key[order]
    first = np.concatenate([[True], sk[1:] != sk[:-1]]) if len(sk) else np.zeros(0, bool)
    starts = np.flatnonzero(first)
    edge_of_sorted = np.cumsum(first) - 1
    edge_of = np.empty_like(edge_of_sorted)
    edge_of[order] = edge_of_sorted
    ukey = sk[starts]
    edges = np.stack([ukey // n, ukey % n], 1) if n else np.zeros((0, 2), np.int64)
    count = np.diff(np.append(starts, len(sk)))
    opposite = np.full((len(ukey), 2), -1, dtype=np.int64)
    two = count == 2
    opposite[two, 0] = opp[order[starts[two]]]
    opposite[two, 1] = opp[order[starts[two] + 1]]
    m = n + edge_of.reshape(3, -1).T  # (F,3): new vertex of (a,b), (b,c), (c,a)
    mab, mbc, mca = m[:, 0], m[:, 1], m[:, 2]
    new = np.stack(
        [
            np.stack([a, mab, mca], 1),
            np.stack([mab, b, mbc], 1),
            np.stack([mca, mbc, c], 1),
            np.stack([mab, mbc, mca], 1),
        ],
        1,
    ).reshape(-1, 3)
    neighbours = np.asarray(neighbours, dtype=np.int64)
    if parent is not None and parent.creases is not None:
        creases = _child_creases(parent, edges)
    if creases is not None:
        creases = np.asarray(creases, dtype=bool)
        opposite[creases] = -1  # a crease edge's new vertex is its midpoint
        # a vertex averages over its neighbours if it is on no crease, over its two crease neighbours if on two
        lo, hi = np.minimum(neighbours[:, 0], neighbours[:, 1]), np.maximum(neighbours[:, 0], neighbours[:, 1])
        at = np.searchsorted(edges[:, 0] * n + edges[:, 1], lo * n + hi)  # each directed edge's undirected one
        sharp = creases[np.minimum(at, len(creases) - 1)] if len(creases) else np.zeros(len(neighbours), bool)
        neighbours = neighbours_along_creases(neighbours, sharp, n)
    return LoopLevel(n, edges, opposite, new, neighbours, creases)


def _child_creases(parent: LoopLevel, edges: np.ndarray) -> np.ndarray:
    """(E',) bool: which edges (E',2) of a level made from `parent`'s faces are halves of its crease edges: {a, m}
    with a an old vertex and m = the new vertex of a crease edge that has a as an end."""
    n = parent.num_vertices
    old, new = edges[:, 0], edges[:, 1]  # a < b: an old vertex comes first
    half = (old < n) & (new >= n)
    e = np.where(half, new - n, 0)
    return half & parent.creases[e] & ((parent.edges[e, 0] == old) | (parent.edges[e, 1] == old))


def _vertex_weights(level: LoopLevel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per old vertex: its valence k (float64), beta and 1 - k * beta (as the spec rounds them). With creases, a
    vertex with two neighbours is on a crease: beta = 1/8 (3/4 of itself, 1/8 of each)."""
    k = np.bincount(level.neighbours[:, 0], minlength=level.num_vertices).astype(np.float64)
    beta = np.where(k > 3, 3.0 / (8.0 * np.maximum(k, 1.0)), BETA_VALENCE_3)
    beta[k < 3] = 0.0
    if level.creases is not None:
        beta[k == 2] = BETA_CREASE
    return k, beta, 1.0 - k * beta


def loop_subdivide(vertices: np.ndarray, faces: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """`levels` Loop levels of vertices (V,3) float64 and faces (F,3), exactly as the decoder computes them.

    Returns vertices (V + E, 3) float64 and faces (4F, 3) int64 for one level (and so on). levels 0 returns the
    input (as float64 / int64 arrays).
    """
    return _refine(vertices, faces, levels, midpoint=False)[:2]


def midpoint_subdivide(vertices: np.ndarray, faces: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """The same refinement with edge vertices at `0.5 * (v_a + v_b)` and old vertices unmoved: the input surface
    itself, on `loop_subdivide`'s faces (the decoder's reference for crossing faces)."""
    return _refine(vertices, faces, levels, midpoint=True)[:2]


def loop_and_midpoint(
    vertices: np.ndarray,
    reference: np.ndarray,
    faces: np.ndarray,
    levels: int,
    neighbours: np.ndarray | None = None,
    creases: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`loop_subdivide(vertices, faces, levels)` and `midpoint_subdivide(reference, faces, levels)` (same faces),
    the connectivity computed once: (vertices', reference', faces'). neighbours: `mesh_edges(faces, V)` if known.
    creases: (E,) bool over the first level's edges: the crease rules (`loop_level`), kept by their halves."""
    if NATIVE and creases is None:
        out = _native_levels(vertices, reference, faces, levels, neighbours)
        if out is not None:
            return out
    v, f, topology = _refine(vertices, faces, levels, midpoint=False, neighbours=neighbours, creases=creases)
    r = np.asarray(reference, dtype=np.float64)
    for level in topology:
        r = _apply_level(r, level, midpoint=True)
    return v, r, f


def _native_levels(vertices, reference, faces, levels: int, neighbours=None):
    """`loop_and_midpoint` without creases through geometry/_filter_native.c (the same bits), or None when the
    faces are not a closed, consistently oriented 2-manifold (the reference handles those). neighbours: the first
    level's rows when the caller has them (the C code checks that they are the faces' half-edges)."""
    native = smoothing._filter_native
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    r = np.ascontiguousarray(reference, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    for level in range(levels):
        if len(f) == 0:
            break
        half = neighbours if level == 0 and neighbours is not None else mesh_edges(f, len(v), closed=True)
        half = np.ascontiguousarray(half, dtype=np.int64)
        if len(half) != 3 * len(f):
            return None
        size = len(v) + len(half) // 2
        nv, nr, nf = np.empty((size, 3)), np.empty((size, 3)), np.empty((4 * len(f), 3), dtype=np.int64)
        if native.loop(v, r, f, half, nv, nr, nf) != 0:
            return None
        v, r, f = nv, nr, nf
    return v, r, f


def _refine(
    vertices, faces, levels: int, midpoint: bool, neighbours: np.ndarray | None = None, creases=None
) -> tuple[np.ndarray, np.ndarray, list[LoopLevel]]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    topology = []
    for _ in range(levels):
        if len(f) == 0:
            break
        if topology:
            level = loop_level(f, len(v), parent=topology[-1])
        else:
            level = loop_level(f, len(v), neighbours, creases)
        v = _apply_level(v, level, midpoint)
        f = level.faces
        topology.append(level)
    return v, f, topology


def _apply_level(v: np.ndarray, level: LoopLevel, midpoint: bool) -> np.ndarray:
    e, o = level.edges, level.opposite
    ends = v[e[:, 0]] + v[e[:, 1]]
    if midpoint:
        return np.concatenate([v, 0.5 * ends])
    two = o[:, 0] >= 0
    edge_v = 0.5 * ends
    edge_v[two] = EDGE_NEAR * ends[two] + EDGE_FAR * (v[o[two, 0]] + v[o[two, 1]])
    n = level.num_vertices
    # bincount adds in input order: the neighbour list is sorted by (i, j), so each sum runs over ascending j
    src, dst = level.neighbours[:, 0], level.neighbours[:, 1]
    total = np.stack([np.bincount(src, weights=v[dst, a], minlength=n) for a in range(3)], axis=1)
    _, beta, keep = _vertex_weights(level)
    old = keep[:, None] * v + beta[:, None] * total
    return np.concatenate([old, edge_v])


def level_matrix(level: LoopLevel, midpoint: bool = False):
    """One level as a scipy CSR matrix (V + E, V): new vertices = matrix @ old vertices (for the fit)."""
    import scipy.sparse as sps

    n, e, o = level.num_vertices, level.edges, level.opposite
    num_e = len(e)
    rows, cols, vals = [], [], []
    ids = np.arange(num_e)
    two = o[:, 0] >= 0
    near = np.where(two & (not midpoint), EDGE_NEAR, 0.5)
    rows += [n + ids, n + ids]
    cols += [e[:, 0], e[:, 1]]
    vals += [near, near]
    if not midpoint:
        rows += [n + ids[two], n + ids[two]]
        cols += [o[two, 0], o[two, 1]]
        vals += [np.full(two.sum(), EDGE_FAR)] * 2
        _, beta, keep = _vertex_weights(level)
        nb = level.neighbours
        rows += [np.arange(n), nb[:, 0]]
        cols += [np.arange(n), nb[:, 1]]
        vals += [keep, beta[nb[:, 0]]]
    else:
        rows.append(np.arange(n))
        cols.append(np.arange(n))
        vals.append(np.ones(n))
    return sps.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n + num_e, n))
