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
decoder then restores the vertices of every face that crosses another (`restore_crossings`), which keeps the
decoded mesh free of self-intersections. Connectivity never changes: a closed 2-manifold stays one.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from tetweave_codec.geometry.intersections import self_intersecting_faces

TAUBIN_LAMBDA = 0.5
TAUBIN_MU = -0.53
MAX_STEPS = 3  # the header's two bits
# Self-intersection checks before the decoder gives up on smoothing altogether (the unsmoothed surface of an
# encoder's file never crosses itself; a hostile file's may, through flat tets, and then stays as it is).
MAX_CHECKS = 5


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

    edges: `mesh_edges(faces, V)` when the caller has it (the fit reuses it while the topology stays).
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


class TaubinOperator:
    """`taubin` as a fixed linear map for one connectivity, for the fit (torch, differentiable): built once per
    marching-tets topology and applied at every iteration. On the CPU the map is two scipy CSR factors per step,
    (I + mu (W - I)) (I + lam (W - I)) with W the neighbour-mean matrix, applied forward and (transposed) backward
    through a custom autograd function: 4.6 ms against 24-28 ms for `taubin`'s index_add on a 40K-vertex mesh
    (forward and backward, one thread). Same values up to float rounding (the decoder's exact arithmetic is
    `taubin` on numpy); on other devices it falls back to `taubin`.

    faces (F,3) long, num_vertices V, steps >= 1.
    """

    def __init__(self, faces: Any, num_vertices: int, steps: int, lam: float = TAUBIN_LAMBDA, mu: float = TAUBIN_MU):
        self.faces, self.n, self.steps, self.lam, self.mu = faces, int(num_vertices), int(steps), lam, mu
        self.edges = mesh_edges(faces, self.n)
        self._factors: dict = {}

    def _csr(self, dtype: np.dtype):
        if dtype not in self._factors:
            import scipy.sparse as sps

            e = np.asarray(self.edges.cpu().numpy() if _is_torch(self.edges) else self.edges)
            deg = np.bincount(e[:, 0], minlength=self.n).astype(np.float64)
            mean = sps.csr_matrix((1.0 / deg[e[:, 0]], (e[:, 0], e[:, 1])), shape=(self.n, self.n))
            # vertices without neighbours keep their place (W's row is 0 there: the identity row instead)
            eye = sps.identity(self.n, format="csr")
            lap = mean + sps.diags((deg == 0).astype(np.float64)) - eye
            first = (eye + self.lam * lap).astype(dtype).tocsr()
            second = (eye + self.mu * lap).astype(dtype).tocsr()
            self._factors[dtype] = (first, second, first.T.tocsr(), second.T.tocsr())
        return self._factors[dtype]

    def __call__(self, vertices: Any) -> Any:
        """Smoothed vertices (V,3), same kind as the input (torch: differentiable)."""
        if self.n == 0 or len(self.faces) == 0:
            return vertices
        if not _is_torch(vertices) or vertices.device.type != "cpu":
            return taubin(vertices, self.faces, self.steps, self.lam, self.mu, edges=self.edges)
        factors = self._csr(np.dtype(str(vertices.dtype).replace("torch.", "")))
        return _apply_linear().apply(vertices, factors, self.steps)


@functools.cache
def _apply_linear():
    """The autograd function (built on first use: this module must not import torch, the decoder uses it)."""
    import torch

    class ApplyLinear(torch.autograd.Function):
        """x -> (F2 F1)^k x with scipy CSR factors; the gradient is the transposed map."""

        @staticmethod
        def forward(ctx, x, factors, steps):
            first, second, _, _ = factors
            y = x.detach().numpy()
            for _ in range(steps):
                y = second @ (first @ y)
            ctx.factors, ctx.steps = factors, steps
            return torch.from_numpy(np.ascontiguousarray(y))

        @staticmethod
        def backward(ctx, grad):
            _, _, first_t, second_t = ctx.factors
            g = grad.detach().contiguous().numpy()
            for _ in range(ctx.steps):
                g = first_t @ (second_t @ g)
            return torch.from_numpy(np.ascontiguousarray(g)), None, None

    return ApplyLinear


def restore_crossings(smoothed: np.ndarray, original: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
    """smoothed (V,3) with the vertices of faces that cross another face put back to `original` (V,3), repeated
    until no face crosses (at most MAX_CHECKS checks; if the last still finds crossing faces, or the check cannot
    bound its work, `original` itself). Returns (vertices, number of vertices restored; V when all were)."""
    v = np.array(smoothed, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    restored = np.zeros(len(v), dtype=bool)
    try:
        interest = None  # the first check tests every pair
        for check in range(MAX_CHECKS):
            # later checks test only pairs with a face that just changed or crossed at the last check: a pair of
            # two other faces was tested at these same positions by the last check and did not cross (had it
            # crossed, both faces would be flagged), so the answer is that of a check of every pair
            bad = self_intersecting_faces(v, faces, only=interest)
            if not bad.any():
                return v, int(restored.sum())
            if check == MAX_CHECKS - 1:
                break
            moved = np.zeros(len(v), dtype=bool)
            moved[faces[bad].reshape(-1)] = True
            moved &= ~restored
            if not moved.any():  # the crossing faces are unsmoothed already: more checks would find them again
                break
            v[moved] = original[moved]
            restored |= moved
            interest = moved[faces].any(axis=1) | bad
    except RuntimeError:  # the check cannot bound its work on this mesh (a hostile file): no smoothing
        pass
    return np.array(original, dtype=np.float64), len(v)


def _is_torch(x: Any) -> bool:
    return type(x).__module__.startswith("torch")
