"""Mask, depth and normal maps of a mesh: rasterize -> interpolate -> antialias (paper §4.1, §5.1)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from tetweave_codec.geometry.triangles import face_cross, unit_vectors

from .antialias import MeshEdges, mesh_edges
from .antialias import antialias as antialias_silhouettes
from .cameras import Cameras, image_size
from .interpolate import perspective_barycentrics, vertex_normals
from .rasterize import Fragments, check_mesh, gather_triangles, pixel_centres, zbuffer

NORMAL_MODES = ("flat", "smooth")


@dataclass(frozen=True)
class RenderMaps:
    """Rendered maps of a batch of views, in the dtype of the vertices.

    mask (B,H,W): 1 on covered pixels, 0 on background, fractional at antialiased silhouettes.
    depth (B,H,W): camera depth (positive distance along the view axis, world units), 0 on background.
    normals (B,H,W,3): world-space unit normals, 0 on background (blended, so not unit, at silhouettes).
    fragments: the rasterization they were made from (face ids, for error splatting and reuse).
    """

    mask: Tensor
    depth: Tensor
    normals: Tensor
    fragments: Fragments | None = None


def render_maps(
    vertices: Tensor,
    faces: Tensor,
    cameras: Cameras,
    size: int | tuple[int, int],
    antialias: bool = True,
    normals: str = "flat",
    fragments: Fragments | None = None,
    *,
    cull_backfaces: bool | None = None,
    edges: MeshEdges | None = None,
) -> RenderMaps:
    """Render mask, depth and normal maps of a mesh from every camera, differentiable w.r.t. `vertices`.

    vertices (V,3) world positions (float32 or float64; the maps use the same dtype), faces (F,3) long.
    size: int (square) or (H, W). normals: "flat" (face normals, as in the paper) or "smooth" (interpolated
    area-weighted vertex normals). antialias: blend silhouette pixels by analytic coverage, which is what
    gives the mask loss gradients w.r.t. vertex positions. fragments: reuse a rasterization of the same mesh,
    cameras and size (e.g. from `rasterize` or a previous RenderMaps). cull_backfaces: see `rasterize`; None
    (default) culls when the edge topology is known (`edges` given, or computed for antialiasing) and shows a
    closed, consistently oriented, outward mesh: the same result, about a third faster. edges:
    `mesh_edges(faces)`, to reuse the edge topology when rendering the same mesh repeatedly.
    Under torch.no_grad() (targets from big input meshes) memory stays bounded by the image and chunk sizes.
    """
    if normals not in NORMAL_MODES:
        raise ValueError(f"normals must be one of {NORMAL_MODES}, got {normals!r}")
    check_mesh(vertices, faces)
    h, w = image_size(size)
    faces = faces.to(device=vertices.device, dtype=torch.long)
    cameras = cameras.to(device=vertices.device)
    planes = cameras.project_planes(vertices, (h, w))  # (3,B,V) with gradients
    cross = face_cross(vertices, faces)  # (F,3) normals times twice the area
    if edges is None and antialias:
        edges = mesh_edges(faces, vertices.shape[0])
    if cull_backfaces is None:
        cull_backfaces = edges is not None and closed_outward(vertices, faces, edges, cross)
    if fragments is None:
        face_id = zbuffer(planes, faces, h, w, cull_backfaces=cull_backfaces)
    elif tuple(fragments.face_id.shape) != (len(cameras), h, w):
        raise ValueError("fragments do not match the cameras and size")
    else:
        face_id = fragments.face_id
    shape = (len(cameras), h, w)
    n_pix = len(cameras) * h * w

    face_id = face_id.reshape(-1)
    pix = (face_id >= 0).nonzero().squeeze(1)
    fid = face_id.index_select(0, pix)
    b, px, py = pixel_centres(pix, h, w, vertices.dtype)
    bary, depth = perspective_barycentrics(*gather_triangles(planes, faces, b, fid), px, py)
    if normals == "flat":
        nrm = unit_vectors(cross).index_select(0, fid)
    else:
        vn = vertex_normals(vertices, faces, cross).t()[:, None, :]  # (3,1,V)
        corners = gather_triangles(vn, faces, torch.zeros_like(fid), fid)
        nrm = torch.stack([(c * bary).sum(1) for c in corners], dim=1)
        nrm = unit_vectors(nrm)
    zeros = torch.zeros(n_pix, dtype=vertices.dtype, device=vertices.device)
    mask_img = zeros.clone().index_fill_(0, pix, 1.0).view(shape)
    depth_img = zeros.index_copy(0, pix, depth).view(shape)
    normal_img = zeros[:, None].expand(n_pix, 3).index_copy(0, pix, nrm).view(*shape, 3)
    if fragments is None:  # the differentiable pass computed them anyway
        bary_img = zeros[:, None].expand(n_pix, 3).index_copy(0, pix, bary.detach()).view(*shape, 3)
        fragments = Fragments(face_id.view(shape), bary_img, depth_img.detach())
    if antialias:
        mask_img, depth_img, normal_img = antialias_silhouettes(
            [mask_img, depth_img, normal_img],
            fragments.face_id,
            fragments.depth,
            vertices,
            faces,
            cameras,
            planes,
            edges,
            cross,
        )
    return RenderMaps(mask_img, depth_img, normal_img, fragments)


def closed_outward(vertices: Tensor, faces: Tensor, edges: MeshEdges, cross: Tensor | None = None) -> bool:
    """True when the mesh is closed (every edge has exactly two faces), consistently oriented and encloses a
    positive volume, i.e. its normals point outwards: then back faces are never visible."""
    if faces.shape[0] == 0 or bool((edges.faces[:, 1] < 0).any()) or not bool(edges.consistent.all()):
        return False
    with torch.no_grad():
        if cross is None:
            cross = face_cross(vertices, faces)
        volume = (vertices.detach().index_select(0, faces[:, 0]) * cross.detach()).sum()  # 6 x signed volume
    return bool(volume > 0)
