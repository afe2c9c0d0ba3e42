"""Taubin smoothing of the decoded surface (`.tw` v2 flags bits 3-4; formats/README.md "Smoothing").

A marching-tets surface is piecewise flat with its vertices on tet edges; `k` Taubin steps (Taubin, SIGGRAPH 1995:
one shrinking step lambda > 0 then one inflating step mu < -lambda of the uniform umbrella operator) move every
vertex towards the mean of its neighbours and back, a low-pass filter that keeps the volume. The fit optimizes s
and c *through* the filter (fit.step.extract), so the filtered surface is what matches the input: on smooth
shapes it reaches the same Chamfer distance with fewer points (docs/measurements/smoothing.md).

Exact and reproducible by an independent decoder (IEEE 754 binary64, one rounding per operation as written):

* Neighbours: the undirected edges of the faces (each face (a, b, c) gives a-b, b-c, c-a), each edge once; vertex i's
  neighbours are the other ends of its edges, summed in ascending index order; deg_i is their count.
* One step: for f = TAUBIN_LAMBDA, then f = TAUBIN_MU, every vertex at once:
  `v_i <- v_i + f * (sum_j v_j / deg_i - v_i)` per coordinate (sum in ascending j, then the division, the
  subtraction, the product and the sum, each rounded). A vertex without neighbours stays.

Crease-preserving smoothing (bit 7 of the position-bits byte; `crease_neighbours`): the same steps over fewer
neighbours, so that the creases of the extracted surface (edges whose two faces turn by more than 30 degrees) are
neither rounded nor pulled towards the faces beside them. The encoder asks for it on inputs with sharp creases
(CAD), where the plain filter rounds every edge.

Smoothing moves vertices off their tet edges, so the surface may in rare cases touch itself where it was thin; the
decoder then restores the vertices of every face that crosses another (geometry/surface_filter.py, which also
holds the fit's differentiable form of the filter), which keeps the decoded mesh free of self-intersections.
Connectivity never changes: a closed 2-manifold stays one.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from tetweave_codec.geometry.intersections import row_cross, row_dot

try:  # the compiled fast path of the numpy steps below (optional; bit-identical output)
    from tetweave_codec.geometry import _filter_native
except ImportError:  # not built: the numpy code
    _filter_native = None
# geometry/_filter_native.c for `taubin` and `crease_edges` (numpy arrays); TETWEAVE_NATIVE=0: the numpy code
NATIVE = _filter_native is not None and os.environ.get("TETWEAVE_NATIVE", "1") != "0"

TAUBIN_LAMBDA = 0.5
TAUBIN_MU = -0.53
MAX_STEPS = 3  # the header's two bits
# Crease-preserving smoothing (formats/README.md "Smoothing"): an edge is a crease when the normals of its two faces
# are more than 30 degrees apart, tested as dot(n1, n2) < CREASE_COS |n1| |n2| on the unnormalized normals. The
# literal is the float64 nearest cos(30 degrees), so that an independent decoder compares with the same number.
# 25-35 degrees gave the same errors on fandisk's files (the chamfer that marching tets makes of a 90-degree crease
# splits it into edges of 30-60 degrees; a curved face's edges turn by a few degrees).
CREASE_COS = 0.8660254037844387


def mesh_edges(faces: Any, num_vertices: int, closed: bool = False) -> Any:
    """Undirected edges (E,2) of a triangle mesh, each once, both directions listed: (a, b) and (b, a), sorted by
    (first, second). faces (F,3) int64 numpy or torch. closed: the caller guarantees a closed, consistently
    oriented 2-manifold (the decoder's checked output), whose half-edges already list every edge once each way:
    the same result from half the keys."""
    n = int(num_vertices)
    if _is_torch(faces):
        import torch

        e = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        e = torch.cat([e, e.flip(1)])
        key = torch.unique(e[:, 0] * n + e[:, 1])
        return torch.stack([key // n, key % n], 1)
    faces = np.asarray(faces, dtype=np.int64)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    if closed:
        key = np.sort(e[:, 0] * n + e[:, 1])
        return np.stack([key // n, key % n], 1)
    e = np.concatenate([e, e[:, ::-1]])
    key = np.sort(e[:, 0] * n + e[:, 1])  # np.unique hashes (numpy 2.4): sorting is several times faster
    key = key[np.concatenate([[True], key[1:] != key[:-1]])] if len(key) else key
    return np.stack([key // n, key % n], 1)


def edge_faces(faces: np.ndarray, edges: np.ndarray, num_vertices: int) -> np.ndarray:
    """(E,2) int64: for each directed edge (a, b) of `edges` (E,2), the face (F,3) that lists a then b and the face
    that lists b then a (its twin's); -1 where a closed, consistently oriented 2-manifold would have one and these
    faces do not. Connectivity only: the fit computes it once per topology (`crease_edges`' `sides`)."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    out = np.full((len(e), 2), -1, dtype=np.int64)
    if not len(e) or not len(f):
        return out
    n = int(num_vertices)
    half = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = half[:, 0] * n + half[:, 1]
    order = np.argsort(key, kind="stable")
    key, face = key[order], np.tile(np.arange(len(f)), 3)[order]
    for side, wanted in enumerate((e[:, 0] * n + e[:, 1], e[:, 1] * n + e[:, 0])):
        at = np.minimum(np.searchsorted(key, wanted), len(key) - 1)
        out[:, side] = np.where(key[at] == wanted, face[at], -1)
    return out


def crease_edges(
    vertices: np.ndarray, faces: np.ndarray, edges: np.ndarray, sides: np.ndarray | None = None
) -> np.ndarray:
    """(E,) bool: which directed edges (E,2) of a closed, consistently oriented 2-manifold are creases.

    vertices (V,3) float64, faces (F,3) int64, edges = `mesh_edges(faces, V, closed=True)` (every half-edge once,
    sorted by (first, second)); sides: `edge_faces(faces, edges, V)` when the caller has it. The directed edge
    (a, b) lies in the face that lists a then b and its twin (b, a) in the face across; with n = (v1 - v0) x
    (v2 - v0) of each face (float64, unnormalized), the edge is a crease when dot(n1, n2) < CREASE_COS *
    sqrt(dot(n1, n1)) * sqrt(dot(n2, n2)). A degenerate face (n = 0) makes no crease (0 < 0 is false). Both
    directions of an edge get the same answer. A half-edge without a twin (not a closed manifold) is no crease.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if not len(e) or not len(f):
        return np.zeros(len(e), dtype=bool)
    if NATIVE and sides is None and len(e) == 3 * len(f):  # a closed mesh's rows: the compiled path, same bits
        sharp = np.zeros(len(e), dtype=np.uint8)
        v64, f64, e64 = (np.ascontiguousarray(x) for x in (v, f, e))
        if _filter_native.creases(v64, f64, e64, CREASE_COS, sharp) == 0:
            return sharp.view(bool)
    sides = edge_faces(f, e, len(v)) if sides is None else sides
    # the spec's arithmetic (formats/README.md, "Crossing faces"): the crossing check's own row helpers
    normal = row_cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    found = (sides >= 0).all(axis=1)
    n1, n2 = normal[sides[:, 0]], normal[sides[:, 1]]
    bound = CREASE_COS * np.sqrt(row_dot(n1, n1)) * np.sqrt(row_dot(n2, n2))
    return found & (row_dot(n1, n2) < bound)


def crease_neighbours(
    vertices: np.ndarray, faces: np.ndarray, edges: np.ndarray, sides: np.ndarray | None = None
) -> np.ndarray:
    """The directed edges (E',2) crease-preserving smoothing averages over: a subset of `edges` (`crease_edges`'
    arguments), same order.

    A vertex on no crease edge keeps all its edges; a vertex on exactly two (a point of a crease line) keeps only
    those two, so it moves along the crease and never across it; any other vertex (a corner, a crease's end) keeps
    none and stays where it is. Flat and curved parts are smoothed as by the plain filter; creases are neither
    rounded nor pulled towards the faces beside them.
    """
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    return neighbours_along_creases(e, crease_edges(vertices, faces, e, sides), len(vertices))


def neighbours_along_creases(edges: np.ndarray, sharp: np.ndarray, num_vertices: int) -> np.ndarray:
    """`crease_neighbours`' rule for directed edges (E,2) whose creases `sharp` (E,) are known: the edges of
    vertices on no crease, the crease edges of vertices on exactly two, none of the others; same order."""
    count = np.bincount(edges[sharp, 0], minlength=int(num_vertices))[edges[:, 0]]
    return edges[np.where(count == 0, ~sharp, (count == 2) & sharp)]


def taubin(
    vertices: Any, faces: Any, steps: int, lam: float = TAUBIN_LAMBDA, mu: float = TAUBIN_MU, edges: Any = None
) -> Any:
    """`steps` Taubin steps of vertices (V,3) over faces (F,3) (numpy float64, or torch: differentiable).

    edges: `mesh_edges(faces, V)` when the caller has it (the decoder has it from the closed mesh).
    Returns new vertices (V,3); the input is not modified. steps 0 returns the input itself.
    """
    n = len(vertices)
    if steps <= 0 or n == 0 or len(faces) == 0:
        return vertices
    e = mesh_edges(faces, n) if edges is None else edges
    if _is_torch(vertices):
        import torch

        ones = torch.ones(len(e), dtype=vertices.dtype, device=vertices.device)
        deg = torch.zeros(n, dtype=vertices.dtype, device=vertices.device).index_add_(0, e[:, 0], ones)
        has = (deg > 0)[:, None]
        deg = deg.clamp_min(1)[:, None]
        v = vertices
        for _ in range(steps):
            for f in (lam, mu):
                mean = torch.zeros_like(v).index_add(0, e[:, 0], v[e[:, 1]]) / deg
                v = torch.where(has, v + f * (mean - v), v)
        return v
    if NATIVE:
        v = np.array(vertices, dtype=np.float64, order="C")
        _filter_native.taubin(v, np.ascontiguousarray(e, dtype=np.int64), int(steps), float(lam), float(mu))
        return v
    src, dst = e[:, 0], e[:, 1]
    deg = np.bincount(src, minlength=n).astype(np.float64)
    has = deg > 0
    v = np.array(vertices, dtype=np.float64)
    for _ in range(steps):
        for f in (lam, mu):
            # bincount adds its weights in input order: e is sorted, so each sum runs over ascending neighbours
            # (the decoder avoids scipy.sparse: its import alone costs ~0.1 s per process)
            total = np.stack([np.bincount(src, weights=v[dst, a], minlength=n) for a in range(3)], axis=1)
            v[has] = v[has] + f * (total[has] / deg[has, None] - v[has])
    return v


def _is_torch(x: Any) -> bool:
    return type(x).__module__.startswith("torch")
