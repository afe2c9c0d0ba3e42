"""Loop subdivision of the decoded surface (`.tw` v2 flags bits 5-6; formats/README.md "Subdivision").

A marching-tets surface is piecewise flat: on a curved input its error falls only as the square of the point
spacing, and its normals jump at every edge. One level of Loop subdivision (Loop, 1987) splits each triangle into
four and moves every vertex by fixed weights of its neighbours, a smooth surface of the same control vertices. The
fit optimizes s and c *through* the subdivision (fit.step.extract), so the subdivided surface is what matches the
input: on smooth shapes the same Chamfer distance takes fewer points (benchmarks/results/subdivision.md).

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

Subdivision moves vertices off the piecewise-flat surface, so in rare cases it may touch itself where it was thin;
the decoder then puts the vertices of crossing faces back to the *midpoint* subdivision of the unsmoothed surface
(same faces, edge vertices at `0.5 * (v_a + v_b)`, old vertices unmoved: geometrically the unsmoothed surface
itself; geometry.surface_filter.restore_crossings). Connectivity is a fixed refinement of a closed 2-manifold: it stays
one.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from tetweave_codec.geometry.smoothing import mesh_edges

EDGE_NEAR = 0.375  # weight of an edge's two ends in its new vertex
EDGE_FAR = 0.125  # weight of the two opposite corners
BETA_VALENCE_3 = 0.1875  # Warren's beta for three neighbours; 3 / (8k) above


class LoopLevel(NamedTuple):
    """The connectivity of one Loop level of a mesh with `num_vertices` vertices (numpy int64).

    edges (E,2): a < b, ascending; opposite (E,2): the third corners of the edge's two faces, -1 -1 when the edge
    does not have exactly two; faces (4F,3): the refined faces (vertex V + e is edge e's new vertex);
    neighbours (2E,2): `smoothing.mesh_edges` of the input faces (each edge both ways, sorted by (i, j)), whose
    order is the spec's order of the neighbour sums.
    """

    num_vertices: int
    edges: np.ndarray
    opposite: np.ndarray
    faces: np.ndarray
    neighbours: np.ndarray


def loop_level(faces: Any, num_vertices: int, neighbours: np.ndarray | None = None) -> LoopLevel:
    """The connectivity of one Loop level: faces (F,3) int (numpy or torch) over `num_vertices` vertices.

    neighbours: `mesh_edges(faces, num_vertices)` when the caller has it (the decoder's smoothing does)."""
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
    return LoopLevel(n, edges, opposite, new, np.asarray(neighbours, dtype=np.int64))


def _vertex_weights(level: LoopLevel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per old vertex: its valence k (float64), beta and 1 - k * beta (as the spec rounds them)."""
    k = np.bincount(level.neighbours[:, 0], minlength=level.num_vertices).astype(np.float64)
    beta = np.where(k > 3, 3.0 / (8.0 * np.maximum(k, 1.0)), BETA_VALENCE_3)
    beta[k < 3] = 0.0
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
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`loop_subdivide(vertices, faces, levels)` and `midpoint_subdivide(reference, faces, levels)` (same faces),
    the connectivity computed once: (vertices', reference', faces'). neighbours: `mesh_edges(faces, V)` if known."""
    v, f, topology = _refine(vertices, faces, levels, midpoint=False, neighbours=neighbours)
    r = np.asarray(reference, dtype=np.float64)
    for level in topology:
        r = _apply_level(r, level, midpoint=True)
    return v, r, f


def _refine(
    vertices, faces, levels: int, midpoint: bool, neighbours: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, list[LoopLevel]]:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    topology = []
    for _ in range(levels):
        if len(f) == 0:
            break
        level = loop_level(f, len(v), neighbours if not topology else None)
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
