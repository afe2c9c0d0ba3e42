"""Differentiable attribute interpolation at the pixel centres the rasterizer assigned to each triangle.

The rasterizer only says which triangle is visible at a pixel. Here the barycentrics of that pixel centre are
recomputed from the (differentiable) projected vertex positions, so gradients of depth and normals flow to the
vertices of the visible triangles. Screen-space barycentrics are made perspective-correct by weighting with
the inverse vertex depths.
"""

from __future__ import annotations

import torch
from torch import Tensor

from tetweave_codec.geometry.triangles import face_cross, unit_vectors


def perspective_barycentrics(x: Tensor, y: Tensor, z: Tensor, px: Tensor, py: Tensor) -> tuple[Tensor, Tensor]:
    """Perspective-correct barycentrics and depth of pixel centres inside triangles (differentiable).

    x, y, z (N,3): per pixel, the screen x, screen y and camera depth of its triangle's three vertices;
    px, py (N,): the pixel centres in screen coordinates.
    Returns bary (N,3) (sums to 1) and depth (N,) (camera depth of the surface point seen through the pixel).
    """
    dx, dy = x - px[:, None], y - py[:, None]
    # Twice the signed area of (pixel, edge start, edge end) for edge k from vertex k+1 to k+2 (mod 3, see
    # rasterize.EDGE_START): the screen barycentric of vertex k times twice the triangle's area.
    sub = dx.roll(-1, 1) * dy.roll(-2, 1) - dy.roll(-1, 1) * dx.roll(-2, 1)  # (N,3)
    weighted = sub / z
    denom = weighted.sum(-1)
    # A degenerate (zero-area) triangle would divide 0 by 0: its pixels get zero weights and depth instead.
    inv = 1.0 / torch.where(denom == 0, torch.ones_like(denom), denom)
    return weighted * inv[:, None], sub.sum(-1) * inv


def vertex_normals(vertices: Tensor, faces: Tensor, cross: Tensor | None = None) -> Tensor:
    """Unit area-weighted vertex normals (V,3) (zero for unreferenced vertices); cross: `face_cross`."""
    n = face_cross(vertices, faces) if cross is None else cross  # length = 2 * area: area weighting for free
    acc = torch.zeros_like(vertices)
    for k in range(3):
        acc = acc.index_add(0, faces[:, k], n)
    return unit_vectors(acc)
