"""Sharp creases and corners of the input, and grid points placed so that no tetrahedron straddles a crease.

A marching-tets surface is linear inside each tet. A tet whose four s values are the signed distances to one
plane reproduces that plane exactly, whatever its size; a tet whose corners "see" different faces of a crease
cuts the crease off (a chamfer). ``feature_points`` places points where the signed distances to all faces
that meet there agree:

* on a crease between faces with unit normals n1, n2: points e +- t * b on the outward bisector
  b = (n1 + n2) / |n1 + n2| of the crease point e, with s = +-t * (n1 . b), the distance to both planes;
* at a corner where k >= 3 faces meet: points v +- t * u with n_i . u = 1 for every incident plane i
  (least squares when k > 3), s = +-t;
* next to a crease, on each of its two faces: a point pair mirrored across the face, s = +- its offset.

Tets built from such points and from ordinary shell points of one face see one plane each. Feature points
are only made when the input has sharp creases of some length (``detect_features``): smooth scans get none
and their fit is unchanged.

All positions are in the normalized frame of the fit (the input's bounding box fits [-0.9, 0.9]^3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from tetweave_codec.formats import quantize as Q
from tetweave_codec.geometry.triangles import face_normals

# An edge is a crease when the normals of its two faces differ by more than this angle.
CREASE_ANGLE_DEG = 40.0
# Feature points are made only when the creases add up to at least this length (normalized frame, where the
# bounding box's longest side is 1.8): a few sharp edges of a scan are noise, not CAD creases.
MIN_CREASE_LENGTH = 1.0
# Connected sets of crease edges shorter than this are dropped (noise on scans: single sharp edges, zigzags).
MIN_CHAIN_LENGTH = 1.0
# Normals closer than this angle count as one face plane when the planes around a corner are collected.
SAME_PLANE_DEG = 10.0
# Offset of the feature points from the surface, in units of the spacing along the crease. The start alone
# (feature points + shell, snapped to the container's grid) on a cube at 450 / 900 points: Chamfer 2.2e-3 /
# 4.8e-4 at 0.5, 3e-7 / 2e-6 at 0.3, 4e-7 / 2e-5 at 0.2 (three boxes and a cube minus a cylinder: about equal).
OFFSET = 0.3
# Distance from the crease of the mirrored face pairs, in units of the spacing along the crease.
FACE_PAIR_DISTANCE = 1.0
# Crease edges are cut into pieces of at most this many spacings before the samples are thinned.
SUBSAMPLE = 0.25
# Corners move along u by t * |u| for t = OFFSET * spacing; |u| is capped so that acute corners stay near.
MAX_CORNER_STRETCH = 3.0


@dataclass
class Features:
    """Creases and corners of a mesh.

    vertices (V,3): the welded vertices. edges (E,2): crease edges (welded vertex indices).
    normals (E,2,3): unit normals of the two faces of each crease edge, the first the face on the edge's left.
    corners (K,): welded vertices where three or more crease edges meet. corner_normals: for each corner, (k,3)
    the distinct face normals around it. length: total crease length.
    """

    vertices: np.ndarray
    edges: np.ndarray
    normals: np.ndarray
    corners: np.ndarray
    corner_normals: list[np.ndarray]
    length: float

    @property
    def found(self) -> bool:
        """True when the creases are long enough to place feature points."""
        return self.length >= MIN_CREASE_LENGTH


def crease_density(features: Features, vertices: np.ndarray, faces: np.ndarray) -> float:
    """Total crease length of `features` / sqrt(surface area) of the mesh vertices (V,3), faces (F,3) it was found on
    (the same frame; `detect_features`' chain lengths are in the normalized frame's units, so use that one): a
    count of how much of a surface its creases bound that does not depend on the mesh's size. Shapes whose every
    face is bounded by creases lie near or above 4.5 (a cube 12 / sqrt(6) = 4.90, a regular tetrahedron or an
    equilateral triangular prism 4.56); a cylinder as tall as it is wide 2.89 (its two rims); 0 without creases or
    area."""
    from tetweave_codec.geometry.triangles import face_areas

    area = float(face_areas(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)).sum())
    if features.length <= 0.0 or not area > 0.0:
        return 0.0
    return float(features.length / math.sqrt(area))


def unique_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct rows of rows (N,k) in lexicographic order (M,k), the index (N,) of each row among them and
    the count (M,) of each: ``np.unique(rows, axis=0, return_inverse=True, return_counts=True)``, 2-3x faster on
    vertices and 5-9x on edges (a stable lexsort of the columns instead of numpy's sort of a structured view;
    benchmarks/unique_rows_speed.py at ffee759). Rows compare by value (-0.0 equals 0.0); no NaN."""
    a = np.asarray(rows)
    if len(a) == 0:
        return a.reshape(0, *a.shape[1:]), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    order = np.lexsort(a.T[::-1])
    ordered = a[order]
    first = np.ones(len(a), dtype=bool)
    first[1:] = np.any(ordered[1:] != ordered[:-1], axis=1)
    group = np.cumsum(first) - 1
    inverse = np.empty(len(a), dtype=np.int64)
    inverse[order] = group
    counts = np.diff(np.append(np.flatnonzero(first), len(a)))
    return ordered[first], inverse, counts


def weld(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with equal coordinates: welded vertices (V',3) and faces (F,3) into them."""
    v = np.asarray(vertices, dtype=np.float64)
    uniq, inverse, _ = unique_rows(v)
    return uniq, inverse[np.asarray(faces, dtype=np.int64)]


def detect_features(
    vertices: np.ndarray,
    faces: np.ndarray,
    angle_deg: float = CREASE_ANGLE_DEG,
    min_chain_length: float = MIN_CHAIN_LENGTH,
) -> Features:
    """Crease edges (dihedral angle between face normals above ``angle_deg``) and corners of a triangle mesh.

    Edges with other than two faces (borders, non-manifold edges) are never creases.

    Args:
        vertices: (V,3) float positions. faces: (F,3) int triangles.
        angle_deg: smallest angle between the two face normals of a crease edge.
        min_chain_length: connected sets of crease edges shorter than this are dropped.
    Returns:
        Features (see the class).
    """
    v, f = weld(vertices, faces)
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    normals = face_normals(v, f)
    half = np.stack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], axis=1).reshape(-1, 2)  # (3F,2) directed
    face_of = np.repeat(np.arange(len(f)), 3)
    key = np.sort(half, axis=1)
    _, inverse, counts = unique_rows(key)
    two = counts[inverse] == 2
    order = np.argsort(inverse[two], kind="stable")
    idx = np.nonzero(two)[0][order].reshape(-1, 2)  # (E2,2) the two half-edges of each manifold edge
    n_a, n_b = normals[face_of[idx[:, 0]]], normals[face_of[idx[:, 1]]]
    cos = np.clip((n_a * n_b).sum(1), -1.0, 1.0)
    sharp = cos < math.cos(math.radians(angle_deg))
    edges = half[idx[sharp, 0]]
    pair = np.stack([n_a[sharp], n_b[sharp]], axis=1)
    long_chain = _chain_lengths(v, edges) >= min_chain_length
    edges, pair = edges[long_chain], pair[long_chain]
    length = float(np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1).sum()) if len(edges) else 0.0
    degree = np.bincount(edges.reshape(-1), minlength=len(v)) if len(edges) else np.zeros(len(v), np.int64)
    corners = np.nonzero(degree >= 3)[0]
    corner_normals = [_distinct_normals(normals[np.nonzero((f == k).any(1))[0]]) for k in corners]
    return Features(v, edges, pair, corners, corner_normals, length)


def _chain_lengths(vertices: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(E,) total length of the connected set of crease edges (E,2) each edge belongs to."""
    if len(edges) == 0:
        return np.zeros(0)
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(vertices),) * 2)
    _, label = connected_components(graph, directed=False)
    lengths = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    per_label = np.bincount(label[edges[:, 0]], weights=lengths, minlength=label.max() + 1)
    return per_label[label[edges[:, 0]]]


def _distinct_normals(normals: np.ndarray) -> np.ndarray:
    """The normals (k,3) of (n,3) that differ by more than SAME_PLANE_DEG from every earlier one."""
    keep: list[np.ndarray] = []
    cos_same = math.cos(math.radians(SAME_PLANE_DEG))
    for n in normals:
        if all(float(n @ m) < cos_same for m in keep):
            keep.append(n)
    return np.array(keep).reshape(-1, 3)


def feature_points(features: Features, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid points around the creases and corners whose s agrees with every face plane they can see.

    Args:
        features: from ``detect_features`` (normalized frame).
        spacing: distance between samples along a crease.
    Returns:
        points (M,3) float64, s (M,) float64 (negative inside) and the planes each point sees, (M,K,4) rows
        (n, a) with n . p - a the signed distance to the plane, padded with NaN rows (K = the most planes at a
        corner, at least 2). All empty when ``features.found`` is False.
    """
    if not features.found or spacing <= 0:
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 2, 4))
    v = features.vertices
    t = OFFSET * spacing
    pts: list[np.ndarray] = []
    planes: list[np.ndarray] = []  # (m,K_i,4) per group

    def plane_rows(normals: np.ndarray, through: np.ndarray) -> np.ndarray:
        """(m,k,4) planes with unit normals (m,k,3) through points (m,3)."""
        return np.concatenate([normals, (normals * through[:, None, :]).sum(-1, keepdims=True)], axis=-1)

    for k, normals in zip(features.corners, features.corner_normals, strict=True):
        if len(normals) < 3:
            continue
        u = np.linalg.lstsq(normals, np.ones(len(normals)), rcond=None)[0]
        stretch = float(np.linalg.norm(u))
        if not np.isfinite(stretch) or stretch <= 0:
            continue
        u *= min(1.0, MAX_CORNER_STRETCH / stretch)
        pts.append(np.stack([v[k] + t * u, v[k] - t * u]))
        planes.append(plane_rows(np.stack([normals, normals]), np.stack([v[k], v[k]])))
    x, n1, n2, along = _crease_samples(features, spacing)
    if len(features.corners):
        near_corner = cKDTree(v[features.corners]).query(x)[0] < FACE_PAIR_DISTANCE * spacing
        x, n1, n2, along = x[~near_corner], n1[~near_corner], n2[~near_corner], along[~near_corner]
    bis = n1 + n2
    norm = np.linalg.norm(bis, axis=1, keepdims=True)
    ok = norm[:, 0] > 1e-6
    bis = bis[ok] / norm[ok]
    both = plane_rows(np.stack([n1[ok], n2[ok]], axis=1), x[ok])
    for sign in (1.0, -1.0):
        pts.append(x[ok] + sign * t * bis)
        planes.append(both)
    for n, other in ((n1, n2), (n2, n1)):
        # into the face, away from the crease: perpendicular to the edge in the face's plane, on the side away
        # from the other face
        m = np.cross(n, along)
        m *= np.where((m * other).sum(1, keepdims=True) > 0, -1.0, 1.0)
        y = x + FACE_PAIR_DISTANCE * spacing * m
        one = plane_rows(n[:, None, :], y)
        for sign in (1.0, -1.0):
            pts.append(y + sign * t * n)
            planes.append(one)
    if not pts:
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 2, 4))
    width = max(2, max(pl.shape[1] for pl in planes))
    padded = [np.pad(pl, ((0, 0), (0, width - pl.shape[1]), (0, 0)), constant_values=np.nan) for pl in planes]
    points = np.vstack([p.reshape(-1, 3) for p in pts])
    rows = np.concatenate(padded)
    return points, plane_distance(points, rows), rows


def plane_distance(points: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """(M,) mean signed distance of points (M,3) to the planes (M,K,4) each sees (NaN rows ignored)."""
    d = (planes[..., :3] * points[:, None, :]).sum(-1) - planes[..., 3]
    return np.nanmean(d, axis=1)


def snap_to_grid(
    points: np.ndarray, s: np.ndarray, planes: np.ndarray, bits: int, scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Move feature points to cell centres of the container's 2^bits grid where their planes still agree.

    Each point takes, among the cell centres of the 3x3x3 cells around it that keep the sign of s and
    |s| >= a quarter cell, the one whose plane distances differ least (ties: the nearest); s becomes the mean
    plane distance there. A point stored on its cell centre is not moved by the container, so the distances
    the fit starts from are exactly those of the decoded positions (axis-aligned faces: exactly equal).

    Args:
        points (M,3), s (M,), planes (M,K,4) from ``feature_points``; bits: the container's position bits;
        scale: its grid scale (formats.quantize.quantize_positions).
    Returns:
        snapped points (M,3) float64 and their s (M,).
    """
    if len(points) == 0:
        return points, s
    cell = Q.cell_size(bits) / scale
    base = Q.quantize_positions(points, bits, scale)
    offsets = np.array([[i, j, k] for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])
    top = (1 << bits) - 1
    cand = Q.dequantize_positions(np.clip(base[:, None, :] + offsets[None], 0, top).reshape(-1, 3), bits, scale)
    cand = cand.reshape(len(points), len(offsets), 3)
    d = (planes[:, None, :, :3] * cand[:, :, None, :]).sum(-1) - planes[:, None, :, 3]  # (M,27,K)
    spread = np.nanmax(d, axis=2) - np.nanmin(d, axis=2)
    mean = np.nanmean(d, axis=2)
    near = np.linalg.norm(cand - points[:, None, :], axis=2)
    bad = (np.sign(mean) != np.sign(s)[:, None]) | (np.abs(mean) < 0.25 * cell)
    score = np.where(bad, np.inf, spread + 1e-3 * near)
    best = np.argmin(score, axis=1)
    usable = np.isfinite(score[np.arange(len(points)), best])
    rows = np.arange(len(points))
    out_p = np.where(usable[:, None], cand[rows, best], points)
    out_s = np.where(usable, mean[rows, best], s)
    return out_p, out_s


def _crease_samples(features: Features, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points about ``spacing`` apart along the creases: positions (M,3), the two face normals (M,3) each and
    the unit crease direction (M,3). Each edge is cut into pieces of at most SUBSAMPLE * spacing, then a greedy
    pass (in edge order, deterministic) keeps samples at least ``spacing`` from every kept one."""
    v = features.vertices
    a, b = v[features.edges[:, 0]], v[features.edges[:, 1]]
    lengths = np.linalg.norm(b - a, axis=1)
    count = np.maximum(1, np.ceil(lengths / (SUBSAMPLE * spacing)).astype(np.int64))
    edge = np.repeat(np.arange(len(a)), count)
    first = np.cumsum(count) - count
    frac = (np.arange(len(edge)) - first[edge] + 0.5) / count[edge]
    x = a[edge] + frac[:, None] * (b - a)[edge]
    along = (b - a)[edge] / np.maximum(lengths[edge], 1e-30)[:, None]
    tree = cKDTree(x)
    taken = np.zeros(len(x), dtype=bool)
    blocked = np.zeros(len(x), dtype=bool)
    for i in range(len(x)):
        if blocked[i]:
            continue
        taken[i] = True
        blocked[tree.query_ball_point(x[i], spacing * (1.0 - 1e-9))] = True
    e = edge[taken]
    return x[taken], features.normals[e, 0], features.normals[e, 1], along[taken]


def crease_distance(features: Features, queries: np.ndarray) -> np.ndarray:
    """(M,) distance from each query (M,3) to the nearest crease edge (inf without creases)."""
    return _nearest_crease(features, queries)[0]


def _nearest_crease(features: Features, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (M,) from each query (M,3) to the nearest crease edge (inf without creases) and that edge's index
    (M,) into ``features.edges`` (-1 without creases)."""
    q = np.asarray(queries, dtype=np.float64).reshape(-1, 3)
    if len(features.edges) == 0 or len(q) == 0:
        return np.full(len(q), np.inf), np.full(len(q), -1, dtype=np.int64)
    a = features.vertices[features.edges[:, 0]]
    ab = features.vertices[features.edges[:, 1]] - a
    best = np.full(len(q), np.inf)
    which = np.full(len(q), -1, dtype=np.int64)
    chunk = max(1, 4_000_000 // max(len(q), 1))
    for lo in range(0, len(a), chunk):
        aa, dd = a[lo : lo + chunk], ab[lo : lo + chunk]
        rel = q[:, None, :] - aa[None]
        tt = np.clip((rel * dd[None]).sum(-1) / np.maximum((dd * dd).sum(-1), 1e-30)[None], 0.0, 1.0)
        d = np.linalg.norm(rel - tt[..., None] * dd[None], axis=-1)
        k = d.argmin(1)
        dk = d[np.arange(len(q)), k]
        better = dk < best
        best[better], which[better] = dk[better], lo + k[better]
    return best, which


def polyhedral_distance(features: Features, queries: np.ndarray, sdf: np.ndarray) -> np.ndarray:
    """The input's signed distance ``sdf`` (M,) at queries (M,3), replaced by a plane distance where the closest
    surface point is on a crease or a corner.

    Near a crease the Euclidean signed distance is not linear: outside a convex crease (inside a concave one) it
    grows like the distance to the crease line, while the faces' planes give max(d1, d2) (min for concave). A
    tet whose corners carry the plane distances of one face reproduces that face exactly; Euclidean distances
    at a crease's outside make every tet there cut the crease off. A query whose crease distance equals |sdf|
    (its closest surface point lies on the crease) takes max(d1, d2) of the crease's two face planes when
    outside, min(d1, d2) when inside; at a corner, the max or min over the corner's planes. The result keeps
    the sign of ``sdf`` (never more than |sdf| away from it: a plane is never farther than a point on it), or
    ``sdf`` is kept (saddle corners, planes seen from the wrong side). Queries elsewhere keep ``sdf``.

    Args:
        features: from ``detect_features`` (same frame as the queries).
        queries: (M,3) positions. sdf: (M,) their signed distances to the input, negative inside.
    Returns:
        (M,) float64 signed distances.
    """
    q = np.asarray(queries, dtype=np.float64).reshape(-1, 3)
    base = np.asarray(sdf, dtype=np.float64).reshape(-1)
    out = base.copy()
    if not features.found or len(q) == 0:
        return out
    tol = 1e-6 * np.abs(base) + 1e-12
    dist, edge = _nearest_crease(features, q)
    on = dist <= np.abs(base) + tol
    if on.any():
        i = np.nonzero(on)[0]
        e = edge[i]
        origin = features.vertices[features.edges[e, 0]]
        d = np.einsum("mkd,md->mk", features.normals[e], q[i] - origin)  # (m,2) distances to the two planes
        out[i] = _same_sign(np.where(base[i] > 0, d.max(1), d.min(1)), base[i])
    if len(features.corners):
        corner_pos = features.vertices[features.corners]
        dc, k = cKDTree(corner_pos).query(q)
        for i in np.nonzero(dc <= np.abs(base) + tol)[0]:
            normals = features.corner_normals[k[i]]
            if len(normals) < 3:
                continue
            d = normals @ (q[i] - corner_pos[k[i]])
            out[i] = _same_sign(np.array([d.max() if base[i] > 0 else d.min()]), base[i : i + 1])[0]
    return out


def _same_sign(candidate: np.ndarray, sdf: np.ndarray) -> np.ndarray:
    """candidate where it has the sign of sdf and is nonzero, else sdf."""
    ok = (np.sign(candidate) == np.sign(sdf)) & (candidate != 0)
    return np.where(ok, candidate, sdf)
