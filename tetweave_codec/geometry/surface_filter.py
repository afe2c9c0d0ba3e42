"""The decoder's filter of the extracted surface: Taubin smoothing, then Loop subdivision, then no crossings.

A version-2 file's flags ask for k Taubin steps (bits 3-4, geometry/smoothing.py) and L Loop levels (bits 5-6,
geometry/subdivision.py). `filter_surface` is the decoder's exact sequence (formats/README.md "Smoothing" and
"Subdivision"); `FilterMap` is the same map for the fit, differentiable, built once per marching-tets topology.

Both steps move vertices off the piecewise-flat surface that marching tets guarantees free of self-intersections,
so the decoder checks the result and puts the vertices of crossing faces back to their *reference* positions: the
unsmoothed surface, refined by midpoints to the subdivided faces (geometrically the unsmoothed surface itself). If
that does not settle within MAX_CHECKS checks, the result is the unsmoothed, unsubdivided surface. The checks run
on the coordinates the decoder returns (after the output transform), and every path ends with one: the
unfiltered surface, returned without a filter or when the filter is dropped, is checked too, and a file whose
unfiltered surface crosses or touches itself is refused (ContainerError), so no decoded mesh fails the check.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import numpy as np

from tetweave_codec.errors import ContainerError
from tetweave_codec.geometry.intersections import self_intersecting_faces
from tetweave_codec.geometry.smoothing import (
    TAUBIN_LAMBDA,
    TAUBIN_MU,
    crease_edges,
    mesh_edges,
    neighbours_along_creases,
    taubin,
)
from tetweave_codec.geometry.subdivision import level_matrix, loop_and_midpoint, loop_level

# Self-intersection checks before the decoder gives up on the filter altogether (the unsmoothed surface of an
# encoder's file never crosses itself; a hostile file's may, through flat tets, and then stays as it is). Where a
# thin part's two sides cross, putting back one ring of faces can make the next ring cross: stanford-bunny at
# 40 KB took 4 checks (one thread) and more than 5 (two threads: the whole filter was dropped, Chamfer 6.4e-4
# instead of 4.6e-4). Checks after the first test only the pairs with a face that changed, a fraction of the cost.
MAX_CHECKS = 16
# Largest subdivided surface a decoder builds (faces; 4^L times the extracted ones): ~2.4 GB of vertices and
# faces. A file asking for more is refused (ContainerError); an encoder's files stay far below (a 40 KB file
# has ~80K faces before subdivision).
MAX_SUBDIVIDED_FACES = 1 << 26


class FilteredSurface(NamedTuple):
    """vertices (V',3) float64 and faces (F',3) int64 of the filtered surface; restored: vertices put back to
    their reference positions; gave_up: the filter was dropped (the result is the unfiltered surface)."""

    vertices: np.ndarray
    faces: np.ndarray
    restored: int
    gave_up: bool


def filter_surface(
    vertices: np.ndarray,
    faces: np.ndarray,
    smoothing: int,
    subdivision: int,
    creases: bool = False,
    scale: float = 1.0,
    offset: np.ndarray | None = None,
    threads: int = 1,
) -> FilteredSurface:
    """The decoder's filter of a closed, consistently oriented marching-tets surface vertices (V,3), faces (F,3):
    `smoothing` Taubin steps, `subdivision` Loop levels (both in the frame of `vertices`), then the output
    transform `v * scale + offset` (none when offset is None) and `restore_crossings` against the reference, so
    the guarantee holds for the coordinates returned. With `creases`, both keep the creases found on the surface
    as extracted (`smoothing.crease_edges`): the Taubin steps average over `smoothing.crease_neighbours`, the Loop
    levels follow the crease rules (`subdivision.loop_level`).

    Every path ends checked (formats/README.md, "No self-intersections"): the unfiltered surface (no filter, or
    the filter dropped) is checked as it is returned. ContainerError when the subdivided surface would have more
    than MAX_SUBDIVIDED_FACES faces, and when the unfiltered surface itself has faces that cross or touch (or the
    check cannot bound its work there): a file no encoder writes. threads: the crossing checks' threads
    (`intersections.self_intersecting_faces`; the result is the same on any count)."""
    v0 = np.asarray(vertices, dtype=np.float64)
    f0 = np.asarray(faces, dtype=np.int64)
    if subdivision > 0 and len(f0) * 4**subdivision > MAX_SUBDIVIDED_FACES:
        raise ContainerError(
            f"invalid .tw file: {subdivision} subdivision levels of {len(f0):,} faces exceed the decoder's "
            f"{MAX_SUBDIVIDED_FACES:,}"
        )
    if (smoothing <= 0 and subdivision <= 0) or len(f0) == 0:
        return FilteredSurface(_checked_control(v0, f0, scale, offset, threads), f0, 0, False)
    # marching tets' output is a checked closed 2-manifold: its half-edges are the edges, once each way
    edges = mesh_edges(f0, len(v0), closed=True)
    smooth_edges, loop_creases = edges, None
    if creases:
        sharp = crease_edges(v0, f0, edges)
        smooth_edges = neighbours_along_creases(edges, sharp, len(v0))
        loop_creases = sharp[edges[:, 0] < edges[:, 1]]  # per undirected edge, in the Loop level's order
    v = taubin(v0, f0, smoothing, edges=smooth_edges) if smoothing > 0 else v0
    reference, f = v0, f0
    if subdivision > 0:
        v, reference, f = loop_and_midpoint(v, v0, f0, subdivision, neighbours=edges, creases=loop_creases)
    v, reference = _transformed(v, scale, offset), _transformed(reference, scale, offset)
    out, restored, gave_up = restore_crossings(v, reference, f, children=4 if subdivision > 0 else 1, threads=threads)
    if gave_up:
        return FilteredSurface(_checked_control(v0, f0, scale, offset, threads), f0, len(v0), True)
    return FilteredSurface(out, f, restored, False)


def _transformed(v: np.ndarray, scale: float, offset: np.ndarray | None) -> np.ndarray:
    """v * scale + offset (two roundings per coordinate, the decoder's output transform); v itself without an
    offset."""
    return v if offset is None else v * float(scale) + offset


def _checked_control(
    v0: np.ndarray, f0: np.ndarray, scale: float, offset: np.ndarray | None, threads: int = 1
) -> np.ndarray:
    """The unfiltered surface in the output frame, checked: ContainerError when two of its faces cross or touch
    (marching tets on a proper tetrahedralization never makes such faces in exact arithmetic; a file can through
    saturated SH terms, which put vertices on the points, and through rounding at its extremes) or when the check
    cannot bound its work."""
    out = _transformed(v0, scale, offset)
    if len(f0) < 2:
        return out
    try:
        bad = int(self_intersecting_faces(out, f0, threads=threads).sum())
    except RuntimeError:
        raise ContainerError(
            "invalid .tw file: its surface cannot be checked for self-intersections within the decoder's work bound"
        ) from None
    if bad:
        raise ContainerError(f"invalid .tw file: {bad:,} faces of its surface cross or touch other faces")
    return out


def restore_crossings(
    moved: np.ndarray, reference: np.ndarray, faces: np.ndarray, children: int = 1, threads: int = 1
) -> tuple[np.ndarray, int, bool]:
    """moved (V,3) with the vertices of faces that cross another face put back to `reference` (V,3), repeated
    until no face crosses (at most MAX_CHECKS checks). Returns (vertices, number of vertices restored, gave_up):
    gave_up when the last check still finds crossing faces, when crossing faces are all at their reference
    already, or when the check cannot bound its work; the vertices are then `reference`. children: 4 when the
    faces are a Loop level's output (runs of four children), a hint for the check's speed, and threads the
    check's threads (`intersections.self_intersecting_faces`); neither changes the result."""
    v = np.array(moved, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    restored = np.zeros(len(v), dtype=bool)
    try:
        interest = None  # the first check tests every pair
        for check in range(MAX_CHECKS):
            # later checks test only pairs with a face that just changed or crossed at the last check: a pair of
            # two other faces was tested at these same positions by the last check and did not cross (had it
            # crossed, both faces would be flagged), so the answer is that of a check of every pair
            bad = self_intersecting_faces(v, faces, only=interest, children=children, threads=threads)
            if not bad.any():
                return v, int(restored.sum()), False
            if check == MAX_CHECKS - 1:
                break
            back = np.zeros(len(v), dtype=bool)
            back[faces[bad].reshape(-1)] = True
            back &= ~restored
            if not back.any():  # the crossing faces are at their reference already: more checks find them again
                break
            v[back] = reference[back]
            restored |= back
            interest = back[faces].any(axis=1) | bad
    except RuntimeError:  # the check cannot bound its work on this mesh (a hostile file): no filter
        pass
    return np.array(reference, dtype=np.float64), len(v), True


class FilterMap:
    """`filter_surface` without its crossing check, as a fixed linear map for one connectivity (the fit's,
    torch, differentiable): built once per marching-tets topology and applied at every iteration.

    faces (F,3) long over num_vertices V; `faces_out` (4^L F, 3) long are the filtered mesh's faces. On the CPU the
    map is a list of scipy CSR factors (two per Taubin step, (I + mu (W - I)) (I + lam (W - I)) with W the
    neighbour-mean matrix, then one per Loop level) applied forward and, transposed, backward through a custom
    autograd function: 4.6 ms against 24-28 ms for torch index_add for one Taubin step of a 40K-vertex mesh
    (forward and backward, one thread). Same values as the decoder's up to float rounding. On other devices the
    factors are (row, column, weight) tensors applied with index_add, as the fit's other mesh operators are
    (deterministic under the fit's deterministic mode).
    """

    def __init__(
        self,
        faces: Any,
        num_vertices: int,
        smoothing: int,
        subdivision: int,
        sharp: np.ndarray | None = None,
        edges: np.ndarray | None = None,
    ):
        self.smoothing, self.subdivision = int(smoothing), int(subdivision)
        self.num_vertices = int(num_vertices)
        # the creases (E,) bool over `smoothing.mesh_edges(faces, V)` that the filter keeps (None: the plain
        # filter), kept so that the fit can tell when they changed; edges: that mesh_edges when the caller has it
        self.sharp = sharp
        # the factors in the order they apply (scipy CSR, float64) and the filtered faces (numpy int64)
        self.matrices, self._faces_np = _factors(
            faces, self.num_vertices, self.smoothing, self.subdivision, sharp, edges
        )
        self._by_kind: dict = {}
        self.faces_out = None  # set on first call, on the input's device

    def __call__(self, vertices: Any) -> Any:
        """Filtered vertices (V',3), same kind as the input (torch: differentiable)."""
        import torch

        factors = self._for(vertices.dtype, vertices.device)
        if self.faces_out is None or self.faces_out.device != vertices.device:
            self.faces_out = torch.from_numpy(self._faces_np).to(vertices.device)
        if vertices.device.type == "cpu":
            return _apply_csr().apply(vertices, factors)
        return _apply_indexed(vertices, factors)

    def _for(self, dtype, device):
        key = (dtype, device)
        if key not in self._by_kind:
            mats = self.matrices
            if device.type == "cpu":
                np_dtype = np.dtype(str(dtype).replace("torch.", ""))
                cast = [m.astype(np_dtype).tocsr() for m in mats]
                self._by_kind[key] = (cast, [m.T.tocsr() for m in cast])
            else:
                self._by_kind[key] = _indexed(mats, dtype, device)
        return self._by_kind[key]


def _indexed(mats: list, dtype, device) -> list:
    """scipy matrices as (rows, row indices, column indices, weights) tensors of `dtype` on `device`."""
    import torch

    out = []
    for m in mats:
        coo = m.tocoo()
        out.append(
            (
                m.shape[0],
                torch.from_numpy(coo.row.astype(np.int64)).to(device),
                torch.from_numpy(coo.col.astype(np.int64)).to(device),
                torch.from_numpy(coo.data).to(device, dtype),
            )
        )
    return out


def _apply_indexed(vertices: Any, factors: list) -> Any:
    """x -> M_k ... M_1 x with each M as (rows, row, col, weight): differentiable torch on any device."""
    import torch

    v = vertices
    for rows, row, col, weight in factors:
        v = torch.zeros((rows, v.shape[1]), dtype=v.dtype, device=v.device).index_add(0, row, weight[:, None] * v[col])
    return v


def _factors(faces: Any, n: int, smoothing: int, subdivision: int, sharp: np.ndarray | None = None, edges=None):
    """([CSR factors in the order they apply], faces after subdivision (numpy int64)); with `sharp` (E,) bool over
    `mesh_edges(faces, n)` (`edges` when given), the filter keeps those creases (as `filter_surface(...,
    creases=True)`)."""
    import scipy.sparse as sps

    f = np.asarray(faces.cpu().numpy() if hasattr(faces, "cpu") else faces, dtype=np.int64)
    mats = []
    e = (mesh_edges(f, n) if edges is None else np.asarray(edges, dtype=np.int64)) if len(f) else None
    loop_creases = None
    if sharp is not None and len(f):
        loop_creases = sharp[e[:, 0] < e[:, 1]]
    if smoothing > 0 and len(f):
        se = e if sharp is None else neighbours_along_creases(e, sharp, n)
        deg = np.bincount(se[:, 0], minlength=n).astype(np.float64)
        mean = sps.csr_matrix((1.0 / deg[se[:, 0]], (se[:, 0], se[:, 1])), shape=(n, n))
        # vertices without neighbours keep their place (W's row is 0 there: the identity row instead)
        eye = sps.identity(n, format="csr")
        lap = mean + sps.diags((deg == 0).astype(np.float64)) - eye
        mats += [(eye + TAUBIN_LAMBDA * lap).tocsr(), (eye + TAUBIN_MU * lap).tocsr()] * smoothing
    level = None
    for _ in range(subdivision if len(f) else 0):
        level = loop_level(f, n, e, loop_creases) if level is None else loop_level(f, n, parent=level)
        e = None  # the next level's faces are new
        mats.append(level_matrix(level))
        f, n = level.faces, n + len(level.edges)
    return mats, f


@functools.cache
def _apply_csr():
    """The autograd function (built on first use: this module must not import torch, the decoder uses it)."""
    import torch

    class ApplyCSR(torch.autograd.Function):
        """x -> M_k ... M_1 x with scipy CSR factors; the gradient is the transposed map."""

        @staticmethod
        def forward(ctx, x, factors):
            mats, transposed = factors
            y = x.detach().numpy()
            for m in mats:
                y = m @ y
            ctx.transposed = transposed
            return torch.from_numpy(np.ascontiguousarray(y))

        @staticmethod
        def backward(ctx, grad):
            g = grad.detach().contiguous().numpy()
            for m in reversed(ctx.transposed):
                g = m @ g
            return torch.from_numpy(np.ascontiguousarray(g)), None

    return ApplyCSR
