"""Taubin smoothing of the decoded surface (`.tw` v2 flags bits 3-4; formats/README.md "Smoothing").

A marching-tets surface is piecewise flat with its vertices on tet edges; `k` Taubin steps (Taubin, SIGGRAPH 1995:
one shrinking step lambda > 0 then one inflating step mu < -lambda of the uniform umbrella operator) move every
vertex towards the mean of its neighbours and back, a low-pass filter that keeps the volume. The fit optimizes s
and c *through* the filter (fit.step.extract), so the filtered surface is what matches the input: on smooth
shapes it reaches the same Chamfer distance with fewer points (benchmarks/results/smoothing.md).

Exact and reproducible by an independent decoder (IEEE 754 binary64, one rounding per operation as written):

* Neighbours: the undirected edges of the faces (each face (a, b, c) gives a-b, b-c, c-a), each edge once; vertex i's
  neighbours are the other ends of its edges, summed in ascending index order; deg_i is their count.
* One step: for f = TAUBIN_LAMBDA, then f = TAUBIN_MU, every vertex at once:
  `v_i <- v_i + f * (sum_j v_j / deg_i - v_i)` per coordinate (sum in ascending j, then the division, the
  subtraction, the product and the sum, each rounded). A vertex without neighbours stays.

Smoothing moves vertices off their tet edges, so the surface may in rare cases touch itself where it was thin; the
decoder then restores the vertices of every face that crosses another (geometry/surface_filter.py, which also
holds the fit's differentiable form of the filter), which keeps the decoded mesh free of self-intersections.
Connectivity never changes: a closed 2-manifold stays one.
"""

from __future__ import annotations

from typing import Any

import numpy as np

TAUBIN_LAMBDA = 0.5
TAUBIN_MU = -0.53
MAX_STEPS = 3  # the header's two bits


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
