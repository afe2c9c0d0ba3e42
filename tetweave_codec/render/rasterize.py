"""Z-buffer rasterization of a triangle mesh into a batch of views (no gradient).

Stages, each vectorized over all (view, triangle) pairs of a chunk:

1. project the vertices to screen space once per view (`Cameras.project_planes`), shifted by half a pixel so
   that pixel centres sit at integer coordinates;
2. per (view, triangle) pair: cull pairs behind the near plane, degenerate or (optionally) back-facing, and
   compute the range of pixel centres inside the screen bounding box;
3. group the surviving triangles by bounding-box size (the larger side rounded up to a power of two) and test
   every pixel centre of every box as one dense array per group: three incremental edge equations (signed
   distances in pixels) and the perspective-correct inverse depth, which is affine in screen space;
4. scatter-reduce ("amin") a packed int64 key per covered candidate into the pixel buffer: high 32 bits =
   order of the depth, low 32 bits = face id. The minimum key is the nearest triangle, ties go to the lower
   face id, and integer min is order-independent, so the result is deterministic on every device.

`zbuffer` is this visibility pass alone (what `render_maps` uses: it recomputes barycentrics and depth itself,
with gradients); `rasterize` adds barycentrics and depth in the dtype of the vertices.

A pixel centre within EDGE_TOLERANCE outside an edge counts as inside: triangles sharing an edge then overlap
by a hair instead of leaving pinholes where rounding puts a centre outside both; the z-buffer resolves that.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .cameras import Cameras, image_size

NEAR = 1e-2  # camera depth (world units) below which a vertex counts as behind the camera (triangle culled)
FACE_CHUNK = 1 << 19  # triangles set up at once per view; bounds memory for 1-2M-face inputs
CANDIDATE_CHUNK = 1 << 22  # (triangle, pixel) candidates tested at once
# Pixels: a centre this close outside an edge counts as inside, so that shared edges leave no pinholes (the
# rounding error of the edge equations is ~1e-6 px); the z-buffer resolves the overlap.
EDGE_TOLERANCE = 1e-4
FACE_BITS = 32  # low bits of the z-buffer key hold the face id
FACE_MASK = (1 << FACE_BITS) - 1
BACKGROUND_KEY = torch.iinfo(torch.int64).max
FLOAT_INF_BITS = 0x7F800000  # bit pattern of +inf in float32: positive floats order like their bit patterns
EDGE_START = (1, 2, 0)  # edge k of a triangle is opposite its vertex k and runs from EDGE_START[k] ...
EDGE_END = (2, 0, 1)  # ... to EDGE_END[k]


@dataclass(frozen=True)
class Fragments:
    """Per-pixel visibility of a batch of views.

    face_id (B,H,W) long: front triangle at each pixel centre, -1 for background.
    bary (B,H,W,3): perspective-correct barycentric coordinates of the pixel centre in that triangle (weights
        of its vertices faces[face_id, 0..2]); 0 on background.
    depth (B,H,W): camera depth (positive distance along the view axis) of the surface; 0 on background.
    """

    face_id: Tensor
    bary: Tensor
    depth: Tensor

    @property
    def mask(self) -> Tensor:
        """(B,H,W) bool: pixels covered by the mesh."""
        return self.face_id >= 0


def check_mesh(vertices: Tensor, faces: Tensor) -> None:
    """Raise ValueError unless vertices is (V,3) floating point and faces is (F,3) integer indices into it."""
    if vertices.ndim != 2 or vertices.shape[1] != 3 or not vertices.is_floating_point():
        raise ValueError(
            f"vertices must be a floating-point (V,3) tensor, got {tuple(vertices.shape)} {vertices.dtype}"
        )
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.is_floating_point() or faces.dtype == torch.bool:
        raise ValueError(f"faces must be an integer (F,3) tensor, got {tuple(faces.shape)} {faces.dtype}")
    if faces.numel() and (int(faces.min()) < 0 or int(faces.max()) >= vertices.shape[0]):
        raise ValueError("faces index vertices out of range")


def rasterize(
    vertices: Tensor,
    faces: Tensor,
    cameras: Cameras,
    size: int | tuple[int, int],
    *,
    cull_backfaces: bool = False,
    near: float = NEAR,
) -> Fragments:
    """Rasterize a mesh into len(cameras) views.

    vertices (V,3) world positions, faces (F,3) long vertex indices, size: int (square) or (H, W).
    cull_backfaces: skip triangles whose normal (right-hand rule over faces[:, 0..2]) points away from the
        camera. Only correct for closed, consistently outward-oriented meshes (then about 2x faster).
    near: triangles with a vertex at camera depth <= near are culled (they cross or lie behind the camera).
    Returns Fragments in the dtype of `vertices`; no gradient flows through it (see `render_maps`).
    """
    check_mesh(vertices, faces)
    h, w = image_size(size)
    n_views = len(cameras)
    faces = faces.to(device=vertices.device, dtype=torch.long)
    with torch.no_grad():
        proj = cameras.to(device=vertices.device).project_planes(vertices.detach(), (h, w))  # (3,B,V)
        face_id = zbuffer(proj, faces, h, w, cull_backfaces=cull_backfaces, near=near)
        bary, depth = _fragment_attributes(proj, faces, face_id.view(-1), h, w)
    return Fragments(face_id, bary.view(n_views, h, w, 3), depth.view(n_views, h, w))


def zbuffer(
    planes: Tensor, faces: Tensor, h: int, w: int, *, cull_backfaces: bool = False, near: float = NEAR
) -> Tensor:
    """The visibility pass of `rasterize`: face ids (B,H,W) long, -1 background (no gradient).

    planes (3,B,V): `Cameras.project_planes` of the vertices; faces (F,3) long.
    """
    n_views = planes.shape[1]
    with torch.no_grad():
        # Shifted by half a pixel: pixel centres sit at integer coordinates, which saves a subtraction per
        # triangle corner (edge equations and areas do not change under the shift).
        shift = torch.tensor([0.5, 0.5, 0.0], device=planes.device)[:, None, None]
        planes = planes.detach().to(torch.float32) - shift
        keys = torch.full((n_views * h * w,), BACKGROUND_KEY, dtype=torch.int64, device=planes.device)
        for start in range(0, faces.shape[0], FACE_CHUNK):
            chunk = faces[start : start + FACE_CHUNK]
            flat = chunk.t().reshape(-1)  # (3Fc,): all first vertices, then all second, then all third
            for view in range(n_views):
                setup = _setup_view(planes[:, view], flat, start, view, h, w, near, cull_backfaces)
                for level, coef, ints in setup:
                    step = max(1, CANDIDATE_CHUNK >> (2 * level))
                    for i in range(0, coef.shape[1], step):
                        _cover_group(coef[:, i : i + step], [t[i : i + step] for t in ints], level, w, keys)
        face_id = torch.where(keys == BACKGROUND_KEY, torch.full_like(keys, -1), keys & FACE_MASK)
    return face_id.view(n_views, h, w)


def _setup_view(
    plane: Tensor, flat_faces: Tensor, face_offset: int, view: int, h: int, w: int, near: float, cull_backfaces: bool
) -> list[tuple[int, Tensor, list[Tensor]]]:
    """Triangle setup of one view: cull, bound, group by box size and derive incremental equations.

    plane (3,V) float32 screen x - 0.5, y - 0.5 (pixel centres at integers) and depth of the vertices in this
    view; flat_faces (3Fc,) the chunk's
    first, second and third vertices one after the other; its first face has global index face_offset.
    Returns, per non-empty box level L (boxes of at most 2**L x 2**L pixel centres), (L, coef (12,P), ints):
    coef rows 0-2 hold the three edges' signed distances in pixels at the box's first pixel centre (inside
    >= 0), rows 3-5 and 6-8 their steps per column and per row, rows 9-11 the same three numbers for the
    inverse depth 1/z; ints = [columns, rows, first pixel (flat index), face id], each (P,) long.
    """
    n = flat_faces.numel() // 3
    # Whole-view checks first: usually every vertex is in front of the camera and inside the image, and then
    # the per-triangle near-plane test and clamping can be skipped.
    all_in_front = bool(plane[2].min() > near) if plane.shape[1] else True
    inside_image = (
        all_in_front
        and bool(
            (plane[0].min() >= -0.5)
            & (plane[0].max() <= w - 0.5)
            & (plane[1].min() >= -0.5)
            & (plane[1].max() <= h - 0.5)
        )
        if plane.shape[1]
        else True
    )
    x, y = (plane[c].index_select(0, flat_faces).view(3, n) for c in range(2))  # (3,Fc) each
    col0 = torch.minimum(torch.minimum(x[0], x[1]), x[2]).ceil_()
    ncol = torch.maximum(torch.maximum(x[0], x[1]), x[2]).floor_()
    row0 = torch.minimum(torch.minimum(y[0], y[1]), y[2]).ceil_()
    nrow = torch.maximum(torch.maximum(y[0], y[1]), y[2]).floor_()
    if not inside_image:
        col0.clamp_(0, w)
        ncol.clamp_(-1, w - 1)
        row0.clamp_(0, h)
        nrow.clamp_(-1, h - 1)
    ncol -= col0
    nrow -= row0
    keep = (ncol >= 0) & (nrow >= 0)
    if not all_in_front:
        z = plane[2].index_select(0, flat_faces).view(3, n)
        keep &= torch.minimum(torch.minimum(z[0], z[1]), z[2]) > near
    if cull_backfaces:
        # In screen space (y down) a triangle whose normal faces the camera winds clockwise: area2 < 0.
        keep &= (x[1] - x[0]) * (y[2] - y[0]) < (x[2] - x[0]) * (y[1] - y[0])
    ncol += 1
    nrow += 1
    # Box level: ceil(log2(larger side)). float32 log2 is exact at powers of two and, for sides below 2**16,
    # at least 4e-5 above the integer otherwise (far more than its rounding error), so ceil is exact.
    level = torch.maximum(ncol, nrow).clamp_min_(1.0).log2_().ceil_()
    level = torch.where(keep, level, -1.0)
    top = int(level.max()) if n else -1
    groups = []
    for lv in range(top + 1):
        members = (level == lv).nonzero().squeeze(1)
        if members.numel():
            groups.append((lv, members))
    if not groups:
        return []
    face = torch.cat([m for _, m in groups]) if len(groups) > 1 else groups[0][1]  # kept faces, by level
    x, y = x.index_select(1, face), y.index_select(1, face)  # (3,P)
    z = plane[2].index_select(0, flat_faces.view(3, n).index_select(1, face).view(-1)).view(3, -1)
    col0, row0, ncol, nrow = (t.index_select(0, face) for t in (col0, row0, ncol, nrow))
    area2 = (x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0])

    # Edge k runs from vertex EDGE_START[k] = k+1 to EDGE_END[k] = k+2 (mod 3): rolled rows.
    xs, ys = x.roll(-1, 0), y.roll(-1, 0)
    ex, ey = x.roll(-2, 0) - xs, y.roll(-2, 0) - ys
    # Unnormalized edge function E_k(p) = cross(edge, p - start): E_k / area2 is the screen barycentric of
    # vertex k. Differences of nearby float32 coordinates are exact, so these are accurate to ~1e-7 relative.
    e_first = ex * (row0 - ys) - ey * (col0 - xs)
    inv_len = torch.sign(area2) / torch.sqrt(ex * ex + ey * ey).clamp_min(1e-30)
    inv_az = 1.0 / (area2 * z)  # (3,P): 1/z = sum_k E_k / (area2 z_k)
    coef = torch.empty(12, face.numel(), dtype=x.dtype, device=x.device)
    torch.mul(e_first, inv_len, out=coef[0:3])
    coef[0].masked_fill_(area2 == 0, -torch.inf)  # degenerate: covers nothing (and has no inverse depth)
    torch.mul(ey, inv_len.neg_(), out=coef[3:6])
    torch.mul(ex, inv_len.neg_(), out=coef[6:9])
    torch.sum(e_first * inv_az, 0, out=coef[9])
    torch.sum(ey * inv_az, 0, out=coef[10]).neg_()
    torch.sum(ex * inv_az, 0, out=coef[11])
    base = row0.long() * w + col0.long() + view * (h * w)
    ints = [ncol.long(), nrow.long(), base, face + face_offset]
    out, at = [], 0
    for lv, members in groups:
        k = members.numel()
        out.append((lv, coef[:, at : at + k], [t[at : at + k] for t in ints]))
        at += k
    return out


def _cover_group(coef: Tensor, ints: list[Tensor], level: int, w: int, keys: Tensor) -> None:
    """Test every pixel centre of boxes of at most 2**level x 2**level centres; scatter-min the covered keys.

    coef (12,P), ints as made by `_setup_view`. The boxes are tested as one dense (P, 4**level) array: no
    per-candidate gathers, at most ~4x padding; most triangles of dense meshes have level 0 (one pixel).
    """
    ncol, nrow, base, face = ints
    side = 1 << level
    if level == 0:
        inside = (coef[0] >= -EDGE_TOLERANCE) & (coef[1] >= -EDGE_TOLERANCE) & (coef[2] >= -EDGE_TOLERANCE)
    else:
        offs = torch.arange(side * side, device=coef.device)
        icol, irow = offs & (side - 1), offs >> level
        fcol, frow = icol.to(coef.dtype), irow.to(coef.dtype)
        inside = (icol < ncol[:, None]) & (irow < nrow[:, None])  # (P,S)
        for k in range(3):
            edge = torch.addcmul(coef[k, :, None], coef[3 + k, :, None], fcol)
            edge.addcmul_(coef[6 + k, :, None], frow)
            inside &= edge >= -EDGE_TOLERANCE
    sel = inside.view(-1).nonzero().squeeze(1)
    if sel.numel() == 0:
        return
    if level == 0:
        tri = sel
        inv_z = coef[9].index_select(0, tri)
        pixel = base.index_select(0, tri)
    else:
        tri = sel >> (2 * level)
        off = sel & (side * side - 1)
        dcol, drow = off & (side - 1), off >> level
        inv_z = coef[9].index_select(0, tri)
        inv_z.addcmul_(coef[10].index_select(0, tri), dcol.to(coef.dtype))
        inv_z.addcmul_(coef[11].index_select(0, tri), drow.to(coef.dtype))
        pixel = base.index_select(0, tri) + drow * w + dcol
    inv_z.clamp_min_(torch.finfo(torch.float32).tiny)
    depth_order = FLOAT_INF_BITS - inv_z.view(torch.int32).to(torch.int64)  # nearer -> larger 1/z -> smaller
    key = (depth_order << FACE_BITS) | face.index_select(0, tri)
    keys.scatter_reduce_(0, pixel, key, reduce="amin")


def _fragment_attributes(planes: Tensor, faces: Tensor, face_id: Tensor, h: int, w: int) -> tuple[Tensor, Tensor]:
    """Perspective-correct barycentrics (B*H*W,3) and depth (B*H*W,) at covered pixel centres, 0 elsewhere."""
    from .interpolate import perspective_barycentrics

    bary = torch.zeros(face_id.numel(), 3, dtype=planes.dtype, device=planes.device)
    depth = torch.zeros(face_id.numel(), dtype=planes.dtype, device=planes.device)
    pix = (face_id >= 0).nonzero().squeeze(1)
    if pix.numel():
        b, px, py = pixel_centres(pix, h, w, planes.dtype)
        x, y, z = gather_triangles(planes, faces, b, face_id.index_select(0, pix))
        pix_bary, pix_depth = perspective_barycentrics(x, y, z, px, py)
        bary.index_copy_(0, pix, pix_bary)
        depth.index_copy_(0, pix, pix_depth)
    return bary, depth


def gather_triangles(planes: Tensor, faces: Tensor, view: Tensor, face: Tensor) -> list[Tensor]:
    """planes (C,B,V) per-view vertex data, view (N,), face (N,) -> C tensors (N,3): the data of the three
    vertices of `face` in `view`. Flat index_selects: differentiable, and much faster on CPU than advanced
    indexing."""
    n_verts = planes.shape[2]
    rows = (faces.index_select(0, face) + (view * n_verts)[:, None]).view(-1)
    flat = planes.reshape(planes.shape[0], -1)
    return [flat[c].index_select(0, rows).view(-1, 3) for c in range(planes.shape[0])]


def pixel_centres(pixel: Tensor, h: int, w: int, dtype: torch.dtype) -> tuple[Tensor, Tensor, Tensor]:
    """Flat pixel indices (N,) into a (B,H,W) buffer -> view (N,) long, screen x (N,), screen y (N,)."""
    b = torch.div(pixel, h * w, rounding_mode="floor")
    rem = pixel - b * (h * w)
    row = torch.div(rem, w, rounding_mode="floor")
    col = rem - row * w
    return b, col.to(dtype) + 0.5, row.to(dtype) + 0.5
