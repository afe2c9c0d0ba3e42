"""Analytic antialiasing of silhouette edges: makes rendered images differentiable w.r.t. the outline.

In the spirit of the antialias operation of Laine et al. 2020 ("Modular Primitives for High-Performance
Differentiable Rendering", §3.3): where the line between two neighbouring pixel centres crosses a visible
silhouette edge, one of the two pixels is blended towards the other by the edge's approximate coverage, and
the crossing point is a differentiable function of the edge's projected end points.

nvdiffrast looks for the silhouette edge among the edges of the triangle visible at the pixel centre. On dense
meshes the triangles along a smooth outline are seen edge-on and almost never contain a pixel centre, so that
test finds nothing (measured here: no blended pixel at all for a 5K-face sphere at 64² or a 20K-face sphere at
256²). This module starts from the edges instead:

1. `mesh_edges`: every edge with its one or two faces (once per mesh; pass it in to reuse it);
2. per view, silhouette edges: boundary edges, and edges whose two faces face opposite ways (a fold in screen
   space), from the 3D facing of every face towards the camera;
3. each silhouette edge is walked along the pixel rows it spans if it is steeper than 45° (columns
   otherwise); at every row it crosses between two horizontally neighbouring centres (vertically for
   columns). The pixel on the edge's face side is the *inner* one; the crossing is kept if the edge is visible
   there: the inner pixel is covered and the outer one is background or farther than the edge;
4. one crossing per pixel pair (the outermost one), at distance `t` in [0, 1] from the inner centre: the
   outer pixel takes the inner colour with weight t - 1/2 when t > 1/2, else the inner pixel takes the outer
   colour with weight 1/2 - t. Along a straight outline the mask's row sum is then the exactly covered
   length.

The colours keep their own gradients; `t` adds the gradients w.r.t. the silhouette vertices.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from tetweave_codec.geometry.triangles import face_cross

from .cameras import Cameras
from .rasterize import NEAR

VIEW_BITS = 52  # views whose facings share one int64 per face (summed as float64 bits: exact up to 2**53)
DEPTH_TOLERANCE = 1e-4  # relative: how much farther than the edge the outer pixel must be to lie behind it


@dataclass(frozen=True)
class MeshEdges:
    """Edge topology of a triangle mesh (E edges).

    ends (E,2) long: end points (a, b) in the winding order of the edge's first face.
    faces (E,2) long: first and second face; second = -1 on boundary edges. An edge of 3+ faces (non-manifold)
        is listed once per face, each as a boundary edge.
    apex (E,) long: vertex of the first face opposite the edge (marks the face's side of the edge).
    consistent (E,) bool: the second face runs the edge b -> a, i.e. the two faces are oriented alike.
    """

    ends: Tensor
    faces: Tensor
    apex: Tensor
    consistent: Tensor


def mesh_edges(faces: Tensor, n_vertices: int | None = None) -> MeshEdges:
    """Edge topology of faces (F,3) long (see MeshEdges). Deterministic; one sort of the 3F edges."""
    if n_vertices is None:
        n_vertices = int(faces.max()) + 1 if faces.numel() else 0
    n_faces = faces.shape[0]
    # Entry 3f+k is edge k of face f, from vertex EDGE_START[k] to EDGE_END[k]; the vertex opposite it is the
    # face's vertex k, i.e. entry 3f+k of faces.reshape(-1).
    a = faces.roll(-1, 1).reshape(-1)
    b = faces.roll(-2, 1).reshape(-1)
    key = torch.minimum(a, b) * n_vertices + torch.maximum(a, b)
    order = _argsort(key, n_vertices * n_vertices)  # equal keys stay in entry order
    skey = key.index_select(0, order)
    # A run of two equal keys is an interior edge; runs of one (boundary) or 3+ (non-manifold) are listed per
    # entry, as boundary edges. Closed manifold meshes have only runs of two: checked first, cheaply.
    paired = n_faces % 2 == 0 and bool((skey[0::2] == skey[1::2]).all()) and bool((skey[1:-1:2] != skey[2::2]).all())
    if paired:
        first, second = order[0::2].contiguous(), order[1::2].contiguous()
    else:
        starts = torch.ones_like(skey, dtype=torch.bool)
        torch.ne(skey[1:], skey[:-1], out=starts[1:])
        run_len = torch.bincount(torch.cumsum(starts, 0) - 1)
        start_pos = starts.nonzero().squeeze(1)
        pair_pos = start_pos.index_select(0, (run_len == 2).nonzero().squeeze(1))
        first = order.index_select(0, pair_pos)
        second = order.index_select(0, pair_pos + 1)
        pos_len = torch.repeat_interleave(run_len, run_len, output_size=skey.numel())
        lone = order.index_select(0, (pos_len != 2).nonzero().squeeze(1))
        first = torch.cat([first, lone])
        second = torch.cat([second, torch.full_like(lone, -1)])
    f1 = torch.div(first, 3, rounding_mode="floor")
    f2 = torch.where(second >= 0, torch.div(second, 3, rounding_mode="floor"), -1)
    a1, b1 = a.index_select(0, first), b.index_select(0, first)
    apex = faces.reshape(-1).index_select(0, first)
    consistent = (second < 0) | (a.index_select(0, second.clamp_min(0)) == b1)
    return MeshEdges(torch.stack([a1, b1], dim=1), torch.stack([f1, f2], dim=1), apex, consistent)


def _argsort(key: Tensor, key_bound: int) -> Tensor:
    """Permutation sorting int64 `key` (values in [0, key_bound)), ties by position. Deterministic.

    On the CPU the positions are packed into the low bits so that numpy's (vectorized) value sort can be used,
    which is several times faster than an argsort.
    """
    n = key.numel()
    bits = max(1, int(n).bit_length())
    if key.device.type == "cpu" and key_bound > 0 and key_bound.bit_length() + bits <= 62:
        packed = (key << bits) | torch.arange(n, dtype=torch.int64)
        return torch.from_numpy(np.sort(packed.numpy())) & ((1 << bits) - 1)
    return torch.sort(key, stable=True).indices


def antialias(
    colors: Sequence[Tensor],
    face_id: Tensor,
    depth: Tensor,
    vertices: Tensor,
    faces: Tensor,
    cameras: Cameras,
    screen: Tensor,
    edges: MeshEdges | None = None,
    normals: Tensor | None = None,
) -> list[Tensor]:
    """Blend pixels across visible silhouette edges by their analytic coverage (differentiable).

    colors: images to antialias (mask, depth, normals, ...), each (B,H,W) or (B,H,W,C), with gradients.
    face_id (B,H,W) long, -1 background; depth (B,H,W) camera depth at the pixel centres (only compared).
    vertices (V,3) world positions and faces (F,3) long of the mesh; cameras: the B views.
    screen (3,B,V): `cameras.project_planes(vertices, (H, W))`, with gradients w.r.t. the vertices.
    edges: `mesh_edges(faces)`, computed here when None.
    normals: `face_cross(vertices, faces)` (or any positive multiple of the face normals), computed when None.
    Returns the images plus the blends, in the same order; equal to the inputs away from silhouettes.
    """
    n_views, h, w = face_id.shape
    colors = list(colors)
    if faces.shape[0] == 0:
        return colors
    if edges is None:
        edges = mesh_edges(faces, vertices.shape[0])
    if normals is None:
        normals = face_cross(vertices.detach(), faces)
    view, edge = _silhouette_edges(vertices.detach(), faces, normals.detach(), cameras, edges)
    if edge.numel() == 0:
        return colors
    crossing = _crossings(screen, view, edge, edges, face_id, depth, h, w)
    if crossing is None:
        return colors
    inner, outer, t = crossing
    alpha = 0.5 - t.clamp(0.0, 1.0)  # > 0: the edge lies before the midpoint: the inner pixel is partly bare
    target = torch.where(alpha > 0, inner, outer)
    source = torch.where(alpha > 0, outer, inner)
    weight = alpha.abs()
    out = []
    for color in colors:
        flat = color.reshape(n_views * h * w, -1)
        diff = flat.index_select(0, source) - flat.index_select(0, target)
        out.append(add_rows(flat, target, weight.to(color.dtype)[:, None] * diff).view(color.shape))
    return out


def add_rows(base: Tensor, index: Tensor, rows: Tensor, ordered: bool | None = None) -> Tensor:
    """base.index_add(0, index, rows) (differentiable), summing repeated indices in a fixed order.

    On the CPU index_add is sequential, hence deterministic. On other devices it uses atomics, whose order
    varies from run to run; there (or with ordered=True) the rows are sorted by index and each index's rows
    are summed in that order first, so that repeated runs give identical images.
    """
    if ordered is None:
        ordered = base.device.type != "cpu"
    if not ordered or index.numel() == 0:
        return base.index_add(0, index, rows)
    order = torch.sort(index, stable=True).indices
    index, rows = index.index_select(0, order), rows.index_select(0, order)
    first = torch.ones_like(index, dtype=torch.bool)
    torch.ne(index[1:], index[:-1], out=first[1:])
    starts = first.nonzero().squeeze(1)
    ends = torch.cat([starts[1:], starts.new_tensor([index.numel()])])
    width = int((ends - starts).max())
    # Sum each segment by adding its k-th rows for k = 0, 1, ... (a fixed order, no atomics).
    total = rows.index_select(0, starts)
    for k in range(1, width):
        has = (ends - starts > k).nonzero().squeeze(1)
        total = total.index_add(0, has, rows.index_select(0, starts.index_select(0, has) + k))
    return base.index_add(0, index.index_select(0, starts), total)


def _silhouette_edges(
    vertices: Tensor, faces: Tensor, normals: Tensor, cameras: Cameras, edges: MeshEdges
) -> tuple[Tensor, Tensor]:
    """(view, edge) index pairs (S,) of the silhouette edges of every view (no gradient).

    The facing of every face in up to VIEW_BITS views is packed into the bits of one int64, so that an edge
    needs two gathers for all those views together.
    """
    views, edge_list = [], []
    with torch.no_grad():
        offset = (normals * vertices.index_select(0, faces[:, 0])).sum(-1, keepdim=True)  # (F,1)
        f1, f2 = edges.faces[:, 0], edges.faces[:, 1]
        f2_or_1 = torch.where(f2 < 0, f1, f2)
        for start in range(0, len(cameras), VIEW_BITS):
            eyes = cameras.eye[start : start + VIEW_BITS].to(vertices.dtype)
            n_views = eyes.shape[0]
            bit = torch.exp2(torch.arange(n_views, device=faces.device, dtype=torch.float64))
            front = (normals @ eyes.t() > offset).to(torch.float64)  # (F,B)
            facing = (front @ bit).long()  # (F,): bit b set when the front side faces view b
            differ = facing.index_select(0, f1) ^ facing.index_select(0, f2_or_1)
            every = (1 << n_views) - 1
            # A fold: the facings differ across a consistently oriented edge, or agree across an inconsistent
            # one. Boundary edges are silhouettes in every view.
            silhouette = torch.where(edges.consistent, differ, differ ^ every)
            silhouette = torch.where(f2 < 0, every, silhouette)
            some = silhouette.nonzero().squeeze(1)
            bits = silhouette.index_select(0, some)
            for b in range(n_views):
                hit = some.index_select(0, ((bits >> b) & 1).nonzero().squeeze(1))
                views.append(torch.full_like(hit, start + b))
                edge_list.append(hit)
    if not edge_list:
        empty = torch.empty(0, dtype=torch.long, device=faces.device)
        return empty, empty
    return torch.cat(views), torch.cat(edge_list)


def _crossings(
    screen: Tensor, view: Tensor, edge: Tensor, edges: MeshEdges, face_id: Tensor, depth: Tensor, h: int, w: int
):
    """Visible crossings of silhouette edges with pixel pairs: inner pixel (K,), outer pixel (K,), t (K,).

    t is differentiable w.r.t. `screen`; at most one crossing per pixel pair is returned (the outermost).
    """
    device = screen.device
    rows = screen.reshape(3, -1)  # (3, B*V): screen x, screen y, depth of every (view, vertex)
    base = view * screen.shape[2]
    ends = edges.ends.index_select(0, edge)
    ia, ib, io = base + ends[:, 0], base + ends[:, 1], base + edges.apex.index_select(0, edge)
    with torch.no_grad():
        det = rows.detach()
        xa, ya, za = (det[c].index_select(0, ia) for c in range(3))
        xb, yb, zb = (det[c].index_select(0, ib) for c in range(3))
        xo, yo, zo = (det[c].index_select(0, io) for c in range(3))
        ok = (za > NEAR) & (zb > NEAR) & (zo > NEAR)
        # (u, v) frame: pairs lie along u, the edge is walked along v (rows if steep, columns otherwise).
        steep = (yb - ya).abs() >= (xb - xa).abs()
        va, vb = torch.where(steep, ya, xa), torch.where(steep, yb, xb)
        n_v = torch.where(steep, h, w)
        k0 = torch.ceil(torch.minimum(va, vb) - 0.5).clamp_(min=0)
        k1 = torch.minimum(torch.ceil(torch.maximum(va, vb) - 0.5) - 1, (n_v - 1).to(k0.dtype))
        count = torch.where(ok, (k1 - k0 + 1).clamp_(min=0), 0).long()
        total = int(count.sum())
        if total == 0:
            return None
        which = torch.repeat_interleave(torch.arange(count.numel(), device=device), count, output_size=total)
        line = (
            k0.long().index_select(0, which)
            + torch.arange(total, device=device)
            - (torch.cumsum(count, 0) - count).index_select(0, which)
        )
        st = steep.index_select(0, which)
        ia_w, ib_w = ia.index_select(0, which), ib.index_select(0, which)
    # Differentiable crossing of edge `which` with the centre line v = line + 0.5.
    xa_g, ya_g = rows[0].index_select(0, ia_w), rows[1].index_select(0, ia_w)
    xb_g, yb_g = rows[0].index_select(0, ib_w), rows[1].index_select(0, ib_w)
    ua_g, ub_g = torch.where(st, xa_g, ya_g), torch.where(st, xb_g, yb_g)
    va_g, vb_g = torch.where(st, ya_g, xa_g), torch.where(st, yb_g, xb_g)
    s = (line.to(screen.dtype) + 0.5 - va_g) / (vb_g - va_g)
    u_cross = ua_g + s * (ub_g - ua_g)
    with torch.no_grad():
        j = torch.floor(u_cross.detach() - 0.5).long()  # pair: centres j + 0.5 and j + 1.5 along u
        valid = (j >= 0) & (j + 1 < torch.where(st, w, h))
        # The first pixel (smaller u) is on the edge's face side iff the apex lies on the same side as it.
        xo_w, yo_w = xo.index_select(0, which), yo.index_select(0, which)
        ua, va_w = ua_g.detach(), va_g.detach()
        du, dv = ub_g.detach() - ua, vb_g.detach() - va_w
        uo = torch.where(st, xo_w, yo_w) - ua
        vo = torch.where(st, yo_w, xo_w) - va_w
        first_inner = ((du * vo - dv * uo) > 0) == (dv > 0)
        b = view.index_select(0, which)
        jc = j.clamp(min=0)
        first = torch.where(st, b * (h * w) + line * w + jc, b * (h * w) + jc * w + line)
        second = first + torch.where(st, 1, w)
        inner = torch.where(first_inner, first, second)
        outer = torch.where(first_inner, second, first)
        # Visibility: the inner pixel is covered, the outer one is background or behind the edge.
        fid, dep = face_id.reshape(-1), depth.reshape(-1)
        inner_c, outer_c = inner.clamp(0, fid.numel() - 1), outer.clamp(0, fid.numel() - 1)
        sd = s.detach()
        z_edge = 1.0 / ((1.0 - sd) / za.index_select(0, which) + sd / zb.index_select(0, which))
        out_fid = fid.index_select(0, outer_c)
        out_behind = (out_fid < 0) | (dep.index_select(0, outer_c) > z_edge * (1.0 + DEPTH_TOLERANCE))
        keep = (valid & (fid.index_select(0, inner_c) >= 0) & out_behind).nonzero().squeeze(1)
        if keep.numel() == 0:
            return None
        inner, outer = inner.index_select(0, keep), outer.index_select(0, keep)
        fi = first_inner.index_select(0, keep)
    t_first = u_cross.index_select(0, keep) - (j.index_select(0, keep).to(screen.dtype) + 0.5)
    t = torch.where(fi, t_first, 1.0 - t_first)
    with torch.no_grad():
        # One crossing per pixel pair: the one farthest from the inner centre (the outermost outline).
        pair = torch.minimum(inner, outer) * 2 + (inner - outer).abs().ne(1).long()
        t_bits = t.detach().clamp(0.0, 1.0).to(torch.float32).view(torch.int32).to(torch.int64)
        order = torch.sort((pair << 32) | t_bits, stable=True).indices
        spair = pair.index_select(0, order)
        last = torch.ones_like(spair, dtype=torch.bool)
        torch.ne(spair[1:], spair[:-1], out=last[:-1])
        win = order.index_select(0, last.nonzero().squeeze(1))
    return inner.index_select(0, win), outer.index_select(0, win), t.index_select(0, win)
