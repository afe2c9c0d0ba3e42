"""Point cloud refinement (paper §4.3-§4.4): importance grids, sampling from them, resampling the points.

A resampling step keeps the points that shape the mesh (active points and their one-ring, chosen by the caller
with ``tetweave_codec.geometry.active``), drops the others and adds new points drawn from an importance grid over the
current mesh: a voxel grid whose values are the mean rendering error of the pixels that land in each voxel
(``voxel_importance``, paper eq. "importance"). New points get s and c by barycentric interpolation in the
tetrahedron of the old triangulation that contains them.

Grids are indexed ``grid[i, j, k]`` with i along x, j along y, k along z; voxel (i, j, k) spans
``bbox_min + (i, j, k) * size`` to ``bbox_min + (i + 1, j + 1, k + 1) * size`` with
``size = (bbox_max - bbox_min) / R``. Random draws use the caller's torch.Generator on its own device (CPU for
a CPU generator) and the results are moved to the device of the inputs, so a seed gives the same points on
every device.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from scipy.spatial import cKDTree

from tetweave_codec.fit.initialize import keep_on_side
from tetweave_codec.geometry.closest import SurfaceTree

# Positions, index arrays and values may be torch tensors or numpy arrays where noted.
Array = torch.Tensor | np.ndarray
BoxCorner = torch.Tensor | np.ndarray | tuple[float, float, float] | list[float]

# Local vertices of the face opposite each local vertex of a tet (face i does not contain vertex i).
TET_FACES = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]], dtype=np.int64)
# A query is inside a tet when all its barycentric coordinates are >= -INSIDE_TOLERANCE.
INSIDE_TOLERANCE = 1e-9
# A walk gives up after this many steps and falls back to the nearest point (never reached on Delaunay grids
# in the tests; it guards against cycles on degenerate input).
MAX_WALK_STEPS = 2048


def _as_tensor(x, device=None, dtype=None) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x.to(device=device if device is not None else x.device, dtype=dtype or x.dtype)
    return torch.as_tensor(np.asarray(x), device=device, dtype=dtype)


def _voxel_index(
    points: torch.Tensor, bbox_min: torch.Tensor, bbox_max: torch.Tensor, resolution: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Flat voxel index (P,) long of each point, and a (P,) bool mask of the points inside the box."""
    extent = (bbox_max - bbox_min).clamp_min(1e-12)
    inside = ((points >= bbox_min) & (points <= bbox_max)).all(-1)
    ijk = torch.floor((points - bbox_min) / extent * resolution).long().clamp(0, resolution - 1)
    flat = (ijk[:, 0] * resolution + ijk[:, 1]) * resolution + ijk[:, 2]
    return flat, inside


def _segment_sums(keys: torch.Tensor, values: torch.Tensor, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-key sums (float64) and counts of ``values (P,)`` over ``keys (P,)`` in [0, size).

    Sort + cumulative sum instead of index_add_/bincount: those use atomics on CUDA, whose summation order
    (and so the last bits of the result) varies from run to run.
    """
    sums = torch.zeros(size, dtype=torch.float64, device=keys.device)
    counts = torch.zeros(size, dtype=torch.long, device=keys.device)
    if keys.numel() == 0:
        return sums, counts
    keys_sorted, order = torch.sort(keys, stable=True)
    csum = torch.cumsum(values[order].to(torch.float64), 0)
    uniq, cnt = torch.unique_consecutive(keys_sorted, return_counts=True)
    ends = torch.cumsum(cnt, 0) - 1
    seg = csum[ends] - torch.cat([csum.new_zeros(1), csum[ends[:-1]]])
    sums[uniq] = seg
    counts[uniq] = cnt
    return sums, counts


def voxel_importance(
    surface_points: torch.Tensor, errors: torch.Tensor, bbox_min: BoxCorner, bbox_max: BoxCorner, resolution: int = 32
) -> torch.Tensor:
    """Importance h of paper eq. (importance): mean error of the pixels whose surface points fall in a voxel.

    Args:
        surface_points: (P,3) 3-D points of the pixels that see the current mesh (all views together).
        errors: (P,) per-pixel error (e.g. L1 normal-map error), >= 0.
        bbox_min, bbox_max: (3,) corners of the gridded box (tensors or sequences).
        resolution: R, voxels per axis.
    Returns:
        (R,R,R) float32 grid on the device of ``surface_points``: mean error per voxel, 0 where no pixel
        lands. Points outside the box are ignored.
    """
    device = surface_points.device
    lo = _as_tensor(bbox_min, device, surface_points.dtype)
    hi = _as_tensor(bbox_max, device, surface_points.dtype)
    flat, inside = _voxel_index(surface_points.reshape(-1, 3), lo, hi, resolution)
    sums, counts = _segment_sums(flat[inside], errors.reshape(-1)[inside], resolution**3)
    mean = torch.where(counts > 0, sums / counts.clamp_min(1), torch.zeros_like(sums))
    return mean.to(torch.float32).reshape(resolution, resolution, resolution)


def sample_from_importance(
    grid: torch.Tensor,
    bbox_min: BoxCorner,
    bbox_max: BoxCorner,
    k: int,
    generator: torch.Generator,
    *,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    """Draw k points with density proportional to the importance grid (paper §4.3).

    The number of points per voxel is multinomial(k, grid / grid.sum()). Inside a voxel that receives c points
    they are stratified (jittered): the voxel is split into m^3 sub-cells, m = ceil(c^(1/3)), c distinct
    sub-cells are chosen at random and each gets one uniform point, so that points in one voxel do not clump
    (a cheap stand-in for the paper's blue-noise tiles). Negative or non-finite grid values count as 0; an
    all-zero grid samples the box uniformly.

    Args:
        grid: (R,R,R) importance (any float dtype, any device).
        bbox_min, bbox_max: (3,) corners of the gridded box.
        k: number of points to draw.
        generator: torch.Generator, the only source of randomness (draws happen on its device).
        dtype: float dtype of the result (default: the grid's dtype).
    Returns:
        (k,3) points on the device of ``grid``, sorted by voxel.
    """
    device = grid.device
    dtype = dtype or (grid.dtype if grid.is_floating_point() else torch.float32)
    gdev = generator.device
    r = grid.shape[0]
    if grid.shape != (r, r, r):
        raise ValueError(f"grid must be (R,R,R), got {tuple(grid.shape)}")
    lo = _as_tensor(bbox_min, gdev, torch.float64)
    hi = _as_tensor(bbox_max, gdev, torch.float64)
    if k <= 0:
        return torch.zeros((0, 3), dtype=dtype, device=device)
    weights = grid.detach().to(gdev, torch.float64).reshape(-1)
    weights = torch.where(torch.isfinite(weights) & (weights > 0), weights, torch.zeros_like(weights))
    if float(weights.sum()) <= 0:
        weights = torch.ones_like(weights)
    voxel = torch.multinomial(weights / weights.sum(), k, replacement=True, generator=generator)
    uniq, count = torch.unique(voxel, return_counts=True)  # sorted voxels, points per voxel
    m = torch.ceil(count.to(torch.float64).pow(1.0 / 3.0) - 1e-9).long().clamp_min(1)
    cells = m**3
    # enumerate every sub-cell of every chosen voxel, shuffle within each voxel, keep the first `count`
    group = torch.repeat_interleave(torch.arange(len(uniq), device=gdev), cells)
    start = torch.cumsum(cells, 0) - cells
    sub = torch.arange(int(cells.sum()), device=gdev) - start[group]
    shuffle = torch.rand(len(sub), generator=generator, device=gdev, dtype=torch.float64)
    order = torch.argsort(group.to(torch.float64) + shuffle, stable=True)  # groups stay in order
    rank = torch.arange(len(order), device=gdev) - start[group[order]]
    chosen = order[rank < count[group[order]]]
    g, sub = group[chosen], sub[chosen]
    mg = m[g]
    sub_ijk = torch.stack([sub // (mg * mg), (sub // mg) % mg, sub % mg], dim=1).to(torch.float64)
    jitter = torch.rand((len(g), 3), generator=generator, device=gdev, dtype=torch.float64)
    vox = uniq[g]
    vox_ijk = torch.stack([vox // (r * r), (vox // r) % r, vox % r], dim=1).to(torch.float64)
    size = (hi - lo) / r
    pts = lo + size * (vox_ijk + (sub_ijk + jitter) / mg.unsqueeze(1).to(torch.float64))
    return pts.to(device=device, dtype=dtype)


def tet_neighbors(tets: Array) -> np.ndarray:
    """(T,4) int64 neighbour of each tet across the face opposite each local vertex, -1 on the boundary.

    Args:
        tets: (T,4) int vertex indices of a conforming tetrahedralization (each face shared by at most two
        tets).
    """
    tets = np.asarray(tets, dtype=np.int64)
    n_tets = len(tets)
    # face 4t+i is opposite local vertex i; its sorted corners from elementwise min/max (much faster than
    # np.sort along a length-3 axis)
    c0, c1, c2 = (tets[:, TET_FACES[:, k]].ravel() for k in range(3))
    lo = np.minimum(np.minimum(c0, c1), c2)
    hi = np.maximum(np.maximum(c0, c1), c2)
    mid = c0 + c1 + c2 - lo - hi
    if n_tets and hi.max() < (1 << 21):
        key = (lo << 42) | (mid << 21) | hi
        order = np.argsort(key)  # ties are the two sides of one face: their order does not matter
        same = key[order[1:]] == key[order[:-1]]
    else:
        order = np.lexsort((hi, mid, lo))
        fs = np.stack([lo, mid, hi], axis=1)[order]
        same = (fs[1:] == fs[:-1]).all(1)
    a, b = order[:-1][same], order[1:][same]
    nb = np.full(4 * n_tets, -1, dtype=np.int64)
    nb[a] = b // 4
    nb[b] = a // 4
    return nb.reshape(n_tets, 4)


def _barycentric(corners: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(A,4) barycentric coordinates of q (A,3) in tets with corners (A,4,3); NaN rows for flat tets."""
    a = corners[:, 1] - corners[:, 0]
    b = corners[:, 2] - corners[:, 0]
    c = corners[:, 3] - corners[:, 0]
    d = q - corners[:, 0]
    bxc = np.cross(b, c)
    det = np.einsum("ij,ij->i", a, bxc)
    with np.errstate(divide="ignore", invalid="ignore"):
        l1 = np.einsum("ij,ij->i", d, bxc) / det
        l2 = np.einsum("ij,ij->i", a, np.cross(d, c)) / det
        l3 = np.einsum("ij,ij->i", a, np.cross(b, d)) / det
    return np.stack([1.0 - l1 - l2 - l3, l1, l2, l3], axis=1)


def locate_in_tets(
    points: Array, tets: Array, queries: Array, neighbors: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Find the tetrahedron that contains each query (visibility walk) and its barycentric coordinates.

    Each walk starts in a tet around the query's nearest grid point (cKDTree) and repeatedly crosses the face
    whose barycentric coordinate is the most negative; on a Delaunay tetrahedralization this visibility walk
    terminates, and from the nearest point it takes a few steps. A walk that leaves through a boundary face
    means the query is outside the triangulated region.

    Args:
        points: (N,3) grid points (array or tensor; computed in float64 on the CPU).
        tets: (T,4) tetrahedra.
        queries: (K,3) query positions.
        neighbors: optional (T,4) result of ``tet_neighbors(tets)``, to reuse across calls.
    Returns:
        tet (K,) int64 containing tet or -1 (outside / not found), bary (K,4) float64 (clipped to >= 0 and
        renormalized; zeros where tet == -1), nearest (K,) int64 nearest grid point used by some tet (any
        point if there is no tet; -1 if there is no point).
    """
    p = _to_numpy64(points).reshape(-1, 3)
    t = _to_numpy(tets).astype(np.int64).reshape(-1, 4)
    q = _to_numpy64(queries).reshape(-1, 3)
    k = len(q)
    tet = np.full(k, -1, dtype=np.int64)
    bary = np.zeros((k, 4))
    if k == 0 or len(p) == 0:
        return tet, bary, np.full(k, -1, dtype=np.int64)
    if len(t) == 0:
        return tet, bary, cKDTree(p).query(q)[1].astype(np.int64)
    nb = tet_neighbors(t) if neighbors is None else neighbors
    # one tet around each point: the first one that uses it
    incident = np.full(len(p), np.iinfo(np.int64).max, dtype=np.int64)
    np.minimum.at(incident, t.ravel(), np.arange(t.size, dtype=np.int64) // 4)
    used = np.nonzero(incident < len(t))[0]
    incident = incident[used]
    _, nearest_used = cKDTree(p[used]).query(q)
    nearest = used[nearest_used]
    cur = incident[nearest_used].copy()
    active = np.arange(k)
    for step in range(MAX_WALK_STEPS):
        if len(active) == 0:
            break
        lam = _barycentric(p[t[cur[active]]], q[active])
        flat_tet = ~np.isfinite(lam).all(1)
        lam_safe = np.where(np.isfinite(lam), lam, 0.0)
        done = ~flat_tet & (lam_safe.min(1) >= -INSIDE_TOLERANCE)
        idx = active[done]
        tet[idx] = cur[idx]
        bary[idx] = lam_safe[done]
        exit_face = np.argmin(lam_safe, axis=1)
        # a flat tet gives no direction: leave it through faces in turn
        exit_face[flat_tet] = step % 4
        nxt = nb[cur[active], exit_face]
        moving = ~done & (nxt >= 0)
        cur[active[moving]] = nxt[moving]
        active = active[moving]
    found = tet >= 0
    bary[found] = np.clip(bary[found], 0.0, None)
    bary[found] /= bary[found].sum(1, keepdims=True)
    return tet, bary, nearest


def _to_numpy(x: Array) -> np.ndarray:
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def _to_numpy64(x: Array) -> np.ndarray:
    return _to_numpy(x).astype(np.float64)


def interpolate_in_tets(
    points: Array, tets: Array, values: Array, queries: Array, neighbors: np.ndarray | None = None
) -> Array:
    """Barycentric interpolation of per-point values at query positions (paper §4.3).

    Each query takes sum_i bary_i * values[tet_i] in the tet that contains it (``locate_in_tets``); queries
    outside every tet take the values of their nearest grid point. Linear functions are reproduced exactly.

    Args:
        points: (N,3) grid points. tets: (T,4). queries: (K,3).
        values: (N,D) or (N,) per-point values, tensor (result on its device and dtype) or array.
        neighbors: optional precomputed ``tet_neighbors(tets)``.
    Returns:
        (K,D) (or (K,) for 1-D values) interpolated values, same type as ``values``.
    """
    t = _to_numpy(tets).astype(np.int64).reshape(-1, 4)
    tet, bary, nearest = locate_in_tets(points, t, queries, neighbors)
    k = len(tet)
    found = tet >= 0
    corners = nearest[:, None].repeat(4, axis=1)
    corners[found] = t[tet[found]]
    weights = np.where(found[:, None], bary, np.array([1.0, 0.0, 0.0, 0.0]))
    if isinstance(values, torch.Tensor):
        vals = values.detach()
        squeeze = vals.dim() == 1
        vals = vals.reshape(vals.shape[0], -1)
        if k == 0 or vals.shape[0] == 0 or (nearest < 0).any():
            out = torch.zeros((k, vals.shape[1]), dtype=vals.dtype, device=vals.device)
        else:
            idx = torch.from_numpy(corners).to(vals.device)
            w = torch.from_numpy(weights).to(device=vals.device, dtype=torch.float64)
            out = (vals[idx].to(torch.float64) * w.unsqueeze(-1)).sum(1).to(vals.dtype)
        return out.reshape(-1) if squeeze else out
    vals = np.asarray(values)
    squeeze = vals.ndim == 1
    vals = vals.reshape(vals.shape[0], -1)
    if k == 0 or vals.shape[0] == 0 or (nearest < 0).any():
        out = np.zeros((k, vals.shape[1]), dtype=vals.dtype)
    else:
        out = (vals[corners].astype(np.float64) * weights[..., None]).sum(1).astype(vals.dtype)
    return out.reshape(-1) if squeeze else out


class NearSurface(NamedTuple):
    """Where `sample_near_surface` puts new points: fixed input surface samples (M,3) with their unit normals
    (M,3), moved along the normal by t * half_width with |t| uniform in [gap, 1] and a random sign. With the
    input's closest-point `tree` and its unit face normals (F,3), offsets that would cross a thin part are
    shortened (`fit.initialize.keep_on_side`)."""

    samples: np.ndarray
    normals: np.ndarray
    half_width: float
    gap: float
    tree: SurfaceTree | None = None
    face_normals: np.ndarray | None = None


def sample_near_surface(
    grid: torch.Tensor, bbox_min: BoxCorner, bbox_max: BoxCorner, near: NearSurface, k: int, generator: torch.Generator
) -> torch.Tensor:
    """Draw k points in a shell around the input surface, denser where the importance grid (R,R,R) is high.

    Each point picks one of ``near.samples`` with probability proportional to the importance of the voxel it lies
    in (so a voxel gets points in proportion to its error times its surface area; uniform over the samples when
    no sample sees a positive importance) and moves along its normal as in the initial shell
    (``fit.initialize.initial_points``). Returns (k,3) float64 on the generator's device.
    """
    gdev = generator.device
    samples = torch.as_tensor(near.samples, dtype=torch.float64, device=gdev)
    if k <= 0:
        return samples[:0]
    r = grid.shape[0]
    values = torch.nan_to_num(grid.to(device=gdev, dtype=torch.float64).reshape(-1), nan=0.0, posinf=0.0)
    flat, inside = _voxel_index(
        samples, _as_tensor(bbox_min, gdev, torch.float64), _as_tensor(bbox_max, gdev, torch.float64), r
    )
    weights = torch.where(inside, values[flat].clamp_min(0.0), torch.zeros_like(values[flat]))
    if not bool((weights > 0).any()):
        weights = torch.ones_like(weights)
    pick = torch.multinomial(weights, k, replacement=True, generator=generator)
    t = torch.rand(k, generator=generator, device=gdev, dtype=torch.float64) * (1.0 - near.gap) + near.gap
    sign = torch.where(torch.rand(k, generator=generator, device=gdev) < 0.5, -1.0, 1.0).to(torch.float64)
    normals = torch.as_tensor(near.normals, dtype=torch.float64, device=gdev)[pick]
    offsets = near.half_width * t * sign
    if near.tree is not None and near.face_normals is not None:
        idx = pick.cpu().numpy()
        kept = keep_on_side(near.samples[idx], near.normals[idx], offsets.cpu().numpy(), near.tree, near.face_normals)
        offsets = torch.from_numpy(kept).to(offsets)
    return samples[pick] + offsets[:, None] * normals


def resample(
    points: torch.Tensor,
    s: torch.Tensor,
    c: torch.Tensor,
    tets: Array,
    keep: torch.Tensor,
    grid: torch.Tensor,
    bbox: tuple[BoxCorner, BoxCorner],
    n_target: int,
    generator: torch.Generator,
    near: NearSurface | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Keep the points that matter, drop the rest and draw new ones from an importance grid (paper §4.3).

    Args:
        points: (N,3) current positions. s: (N,) base signed distances. c: (N,q) SH coefficients.
        tets: (T,4) current (old) triangulation of ``points`` (tensor or array).
        keep: (N,) bool, the points to keep (the caller's active points and their one-ring).
        grid: (R,R,R) importance over ``bbox``.
        bbox: (bbox_min (3,), bbox_max (3,)) of the grid.
        n_target: number of points returned.
        generator: torch.Generator, the only source of randomness.
        near: draw the new points in a shell around the input (`sample_near_surface`) instead of uniformly
            inside the voxels (`sample_from_importance`).
    Returns:
        points (n_target,3), s (n_target,), c (n_target,q), detached, on the input's device and dtypes: first
        the kept points in their original order, unchanged, then the new points with s and c interpolated
        barycentrically in the old triangulation (nearest point outside it). When more than n_target points are
        kept, only a random n_target of them stay.
    """
    device = points.device
    keep = _as_tensor(keep, device).bool()
    kept = torch.nonzero(keep).squeeze(1)
    if len(kept) > n_target:
        # too many points to keep: drop at random
        rank = torch.rand(len(kept), generator=generator, device=generator.device, dtype=torch.float64)
        rank = rank.to(device)
        kept = torch.sort(kept[torch.argsort(rank, descending=True, stable=True)[:n_target]]).values
    n_new = n_target - len(kept)
    if near is None:
        new_points = sample_from_importance(grid, bbox[0], bbox[1], n_new, generator, dtype=points.dtype)
    else:
        new_points = sample_near_surface(grid, bbox[0], bbox[1], near, n_new, generator).to(points.dtype)
    new_points = new_points.to(device)
    values = torch.cat([s.detach().reshape(-1, 1), c.detach().reshape(len(s), -1)], dim=1)
    new_values = interpolate_in_tets(points, tets, values, new_points)
    out_points = torch.cat([points.detach()[kept], new_points])
    out_s = torch.cat([s.detach()[kept], new_values[:, 0].to(s.dtype)])
    out_c = torch.cat([c.detach().reshape(len(s), -1)[kept], new_values[:, 1:].to(c.dtype)])
    return out_points, out_s, out_c
