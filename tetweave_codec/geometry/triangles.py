"""Triangle primitives, one home for numpy and torch: face cross products, areas, unit normals, surface samples.

`triangle_cross`, `face_cross`, `face_areas`, `face_normals` and `unit_vectors` take numpy arrays or torch tensors
and return the same kind (torch: differentiable, on the input's device; torch is imported only when given a tensor,
so the numpy paths never load it). `sample_surface` is numpy only.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tetweave_codec.geometry.sh import _is_torch


def triangle_cross(tri: Any) -> Any:
    """(c1 - c0) x (c2 - c0) of triangles given by their corners tri (...,3,3): the right-hand normal scaled by twice
    the area (...,3)."""
    e1, e2 = tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]
    if _is_torch(tri):
        import torch

        return torch.linalg.cross(e1, e2, dim=-1)
    return np.cross(e1, e2)


def face_cross(vertices: Any, faces: Any) -> Any:
    """(v1 - v0) x (v2 - v0) per face (F,3): the right-hand normal scaled by twice the face's area.

    vertices (V,3) float, faces (F,3) int; numpy arrays or torch tensors (same kind back).
    """
    if _is_torch(vertices):
        import torch

        v0 = vertices.index_select(0, faces[:, 0])
        e1 = vertices.index_select(0, faces[:, 1]) - v0
        e2 = vertices.index_select(0, faces[:, 2]) - v0
        return torch.linalg.cross(e1, e2, dim=-1)
    return triangle_cross(np.asarray(vertices)[np.asarray(faces)])


def unit_vectors(v: Any) -> Any:
    """Vectors v (...,3) scaled to unit length; zero vectors stay zero."""
    if _is_torch(v):
        import torch

        return v * torch.rsqrt((v * v).sum(-1, keepdim=True).clamp_min(torch.finfo(v.dtype).tiny))
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, length, out=np.zeros_like(v), where=length > 0)


def face_areas(vertices: Any, faces: Any) -> Any:
    """Face areas (F,) (0 for degenerate faces)."""
    cross = face_cross(vertices, faces)
    if _is_torch(cross):
        return 0.5 * cross.norm(dim=-1)
    return 0.5 * np.linalg.norm(cross, axis=-1)


def face_normals(vertices: Any, faces: Any) -> Any:
    """Unit face normals (F,3) by the right-hand rule; zero rows for degenerate faces."""
    return unit_vectors(face_cross(vertices, faces))


def sample_surface(
    vertices: np.ndarray, faces: np.ndarray, n: int, seed: int | np.random.Generator = 0
) -> tuple[np.ndarray, np.ndarray]:
    """`n` area-weighted uniform samples on a triangle mesh (numpy, float64).

    Each sample picks a face with probability proportional to its area, then a uniform point in it (square-root
    barycentrics). `seed` is an int or a numpy Generator (which is advanced): the same seed gives the same samples.
    Returns points (n,3) float64 and the face index (n,) int64 of each. Raises ValueError on a mesh of zero area.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    tri = v[f]
    cdf = np.cumsum(face_areas(v, f))
    if len(cdf) == 0 or not cdf[-1] > 0:
        raise ValueError("cannot sample a mesh with zero surface area")
    rng = np.random.default_rng(seed)
    face = np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right")
    face = np.minimum(face, len(f) - 1)
    r1, r2 = rng.random((2, n))
    s = np.sqrt(r1)
    bary = np.stack([1.0 - s, s * (1.0 - r2), s * r2], axis=1)
    return np.einsum("nk,nkd->nd", bary, tri[face]), face.astype(np.int64)


def sample_surface_torch(vertices: Any, faces: Any, n: int, generator: Any) -> tuple[Any, Any]:
    """`n` area-weighted uniform samples (n,3) on a triangle mesh, differentiable w.r.t. `vertices` (torch).

    As `sample_surface`, with the faces and barycentric coordinates drawn from the torch `generator` (CPU) without
    gradient (`draw_surface_samples`): each sample is a fixed combination of its face's corners, so it moves with
    them. vertices (V,3) float tensor, faces (F,3) int64 tensor on the same device. Returns the samples (n,3) and
    the face index (n,) int64 of each (on the device of `faces`).
    """
    face, bary = draw_surface_samples(vertices, faces, n, generator)
    return points_from_barycentrics(vertices, faces, face, bary), face


def draw_surface_samples(vertices: Any, faces: Any, n: int, generator: Any) -> tuple[Any, Any]:
    """Faces (n,) int64 and barycentric coordinates (n,3) of `n` area-weighted uniform samples (torch, no gradient).

    The samples come in face order (sorted uniforms inverted through the area CDF): closest-point queries on nearby
    faces then share their tree walk, which halved the input tree's query time against samples in random order. A
    mesh of zero area samples its faces uniformly. Faces on the device of `faces`, barycentrics of `vertices`.
    """
    import torch

    with torch.no_grad():
        area = face_areas(vertices, faces).double().cpu()
        if not float(area.sum()) > 0:
            area = torch.ones_like(area)
        cdf = torch.cumsum(area, 0)
        u = torch.rand(n, generator=generator, dtype=torch.float64).sort().values * cdf[-1]
        face = torch.searchsorted(cdf, u, right=True).clamp_max(len(area) - 1)
        a, b = torch.rand(2, n, generator=generator, dtype=torch.float64)
        root = a.sqrt()
        bary = torch.stack([1.0 - root, root * (1.0 - b), root * b], dim=-1).to(vertices)
    return face.to(faces.device), bary


def points_from_barycentrics(vertices: Any, faces: Any, face: Any, bary: Any) -> Any:
    """Points (n,3) at barycentric coordinates bary (n,3) of faces face (n,) of a mesh; torch, differentiable."""
    corners = vertices[faces[face]]  # (n,3,3)
    return (bary[..., None] * corners).sum(1)


def closest_on_triangles(points: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest point (n,3) on each triangle tri (n,3,3) to points (n,3), and its barycentric coordinates (n,3).

    numpy float64, exact up to rounding: the Voronoi-region tests of Ericson's *Real-Time Collision Detection*
    (5.1.5), vectorized. A degenerate triangle (a segment or a point) gets the closest point of its region tests,
    which is on the triangle's closure.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(tri, dtype=np.float64).reshape(-1, 3, 3)
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp, cp = p - b, p - c
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        # interior: (va, vb, vc) / sum are the barycentrics; the regions below override it where they apply
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        bary = np.stack([1.0 - v - w, v, w], axis=1)
        # the regions, tested in Ericson's order; later assignments are guarded by `todo` so that the first holds
        todo = np.ones(len(p), dtype=bool)

        def take(mask: np.ndarray, value: np.ndarray) -> None:
            m = mask & todo
            bary[m] = value[m]
            todo[m] = False

        n = len(p)
        one, zero = np.ones(n), np.zeros(n)
        take((d1 <= 0) & (d2 <= 0), np.stack([one, zero, zero], 1))  # vertex a
        take((d3 >= 0) & (d4 <= d3), np.stack([zero, one, zero], 1))  # vertex b
        s_ab = d1 / (d1 - d3)
        take((vc <= 0) & (d1 >= 0) & (d3 <= 0), np.stack([1.0 - s_ab, s_ab, zero], 1))  # edge ab
        take((d6 >= 0) & (d5 <= d6), np.stack([zero, zero, one], 1))  # vertex c
        s_ac = d2 / (d2 - d6)
        take((vb <= 0) & (d2 >= 0) & (d6 <= 0), np.stack([1.0 - s_ac, zero, s_ac], 1))  # edge ac
        s_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        take((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), np.stack([zero, 1.0 - s_bc, s_bc], 1))  # edge bc
    bary = np.nan_to_num(bary, nan=1.0 / 3.0, posinf=1.0 / 3.0, neginf=1.0 / 3.0)
    closest = (bary[:, :, None] * t).sum(1)
    return closest, bary
