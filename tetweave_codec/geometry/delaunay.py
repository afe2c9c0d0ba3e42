"""Delaunay tetrahedralization of a bare point set: TetGen by default, scipy's Qhull as permissive fallback.

Backends, measured on the 2-core development machine for 64K float16-rounded points in a thin shell
(one run, a machine shared with other jobs, so +-30 %):

=========================  ===========  ==============  ==========================================
backend                    64K points   license         notes
=========================  ===========  ==============  ==========================================
TetGen 1.6 (``tetgenpy``)  0.29-0.36 s  AGPL-3.0        switches ``Qz``; exact predicates
scipy Qhull                1.9-2.3 s    BSD (Qhull)     ``Qbb Qc Qz Q12 Qt``; flat tets, see below
=========================  ===========  ==============  ==========================================

License consequence: TetGen is AGPL-3.0, so tetweave as distributed (depending on ``tetgenpy``) is
AGPL-3.0-or-later. Without ``tetgenpy`` installed everything still works through Qhull (``backend="auto"``
falls back to it), only about 6x slower.

Degenerate (cospherical) point sets have several Delaunay tetrahedralizations and the two backends may pick
different ones. Measured on float16-rounded point sets: uniform in a cube, in sphere and torus shells (27 sets
of 2K-64K points): identical tets every time; points crowded on the float16 lattice (a cube 0.04 wide around
0.5, about 80 float16 values per axis; 27 sets) and regular lattices: different tets every time. Decoding must
reproduce exactly the mesh the encoder reported, so the `.tw` container records which backend triangulated the
points (flags bit 0) and the decoder uses the same one.

Guarantees of `delaunay` / `tetrahedralize`:

* tets index the caller's point array (TetGen silently drops exact duplicate points and renumbers the rest; we
  map back, and of exactly coincident points only the first is referenced);
* tets are positively oriented, ``det[p1 - p0, p2 - p0, p3 - p0] > 0``, decided with an exact predicate where
  float64 is not certain. Qhull may emit exactly flat tets for cospherical points; these get the orientation
  their neighbours imply, so the complex stays consistently oriented (which is what marching tets needs);
* deterministic (both libraries are deterministic for the same input and options);
* fewer than 4 points, or points that span no volume (all (nearly) coplanar or collinear), give no tets
  (shape (0, 4)).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

BACKENDS = ("tetgen", "qhull")

# TetGen switches: Q quiet, z zero-based indices. No 'F': the convex hull faces come out for free and the
# decoder needs them to close surfaces that reach the hull.
TETGEN_SWITCHES = "Qz"

# Outward faces of a positively oriented tet (p0, p1, p2, p3): the face opposite vertex k, ordered so that its
# normal (right-hand rule) points away from vertex k.
TET_OUTWARD_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)

# A point set is treated as spanning no volume when its thinnest extent (smallest singular value of the
# centred points) is below this fraction of its largest; such sets also make TetGen fail or crash.
_FLATNESS_RATIO = 1e-6

# float64 orientation determinants whose magnitude exceeds this multiple of their permanent have a certain
# sign (Shewchuk's orient3d bound is ~7.8e-16; we keep a wide margin and decide the rest exactly).
_ORIENT_ERRBOUND = 1e-14


class Tetrahedralization(NamedTuple):
    """Result of `tetrahedralize`.

    tets: (T, 4) int64, positively oriented, indices into the caller's points.
    hull_faces: (H, 3) int64, the convex hull's triangles (faces of exactly one tet), oriented outward.
    backend: "tetgen" or "qhull", the library that produced `tets`.
    """

    tets: np.ndarray
    hull_faces: np.ndarray
    backend: str


def available_backends() -> tuple[str, ...]:
    """Backends usable in this environment, in order of preference."""
    try:
        import tetgenpy  # noqa: F401
    except ImportError:
        return ("qhull",)
    return BACKENDS


def resolve_backend(backend: str = "auto") -> str:
    """Map "auto" to the fastest available backend; validate explicit names (ValueError / ImportError)."""
    if backend == "auto":
        return available_backends()[0]
    if backend not in BACKENDS:
        raise ValueError(f"unknown Delaunay backend {backend!r}; choose one of auto, {', '.join(BACKENDS)}")
    if backend not in available_backends():
        raise ImportError(f"Delaunay backend {backend!r} needs the tetgenpy package, which is not installed")
    return backend


def delaunay(points: np.ndarray, backend: str = "auto") -> np.ndarray:
    """Delaunay tetrahedralization.

    Args:
        points: (N, 3) finite coordinates (any float dtype; computed in float64).
        backend: "auto" (TetGen if installed, else Qhull), "tetgen" or "qhull".
    Returns:
        tets (T, 4) int64, positively oriented, indices into `points`.
    """
    return tetrahedralize(points, backend).tets


def tetrahedralize(points: np.ndarray, backend: str = "auto") -> Tetrahedralization:
    """Delaunay tetrahedralization with the convex hull faces; see `Tetrahedralization`."""
    backend = resolve_backend(backend)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points must be finite")
    if _spans_no_volume(pts):
        return Tetrahedralization(np.zeros((0, 4), np.int64), np.zeros((0, 3), np.int64), backend)
    if backend == "tetgen":
        tets, hull = _tetgen(pts)
    else:
        tets, hull = _qhull(pts)
    return Tetrahedralization(tets, hull, backend)


def _spans_no_volume(pts: np.ndarray) -> bool:
    if len(pts) < 4:
        return True
    centred = pts - pts.mean(axis=0)
    # 3x3 Gram matrix instead of an SVD of (N, 3): same singular values squared, far cheaper. Plain numpy sums
    # instead of BLAS keep the sum order (and so this decision) independent of the thread count.
    cols = centred.T.copy()
    gram = np.array([[(cols[i] * cols[j]).sum() for j in range(3)] for i in range(3)])
    eig = np.linalg.eigvalsh(gram)
    return not eig[-1] > 0 or eig[0] <= (_FLATNESS_RATIO**2) * eig[-1]


def _tetgen(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import tetgenpy

    io = tetgenpy.TetgenIO()
    io.setup_points(pts)
    try:
        out = tetgenpy.tetrahedralize(TETGEN_SWITCHES, io)
    except RuntimeError:  # TetGen's own "(nearly) coplanar / trivial point set" errors: no volume to fill
        return np.zeros((0, 4), np.int64), np.zeros((0, 3), np.int64)
    tets = np.asarray(out.tetrahedra(), dtype=np.int64).reshape(-1, 4)
    hull = np.asarray(out.trifaces(), dtype=np.int64).reshape(-1, 3)
    kept = np.asarray(out.points(), dtype=np.float64).reshape(-1, 3)
    if len(kept) != len(pts) or not np.array_equal(kept, pts):
        remap = _match_kept_points(pts, kept)
        tets, hull = remap[tets], remap[hull]
    if len(tets):
        # TetGen's tets are consistently oriented by construction (exact predicates); only its sign convention
        # is checked, on the first tets whose float64 orientation is certain.
        signs = orientation(pts, tets[: min(len(tets), 64)])
        if not signs.any():
            signs = orientation(pts, tets)
        certain = np.flatnonzero(signs)
        if len(certain) and signs[certain[0]] < 0:
            tets = tets[:, [1, 0, 2, 3]]
    hull = _orient_hull_faces(pts, hull)
    return np.ascontiguousarray(tets), np.ascontiguousarray(hull)


def _match_kept_points(pts: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """For each point TetGen kept, the index of the first caller point with the same coordinates."""
    keys = np.ascontiguousarray(pts).view(np.dtype((np.void, 24))).ravel()
    _, first = np.unique(keys, return_index=True)
    first = np.sort(first)
    if len(first) == len(kept) and np.array_equal(pts[first], kept):
        return first
    lookup: dict[bytes, int] = {}
    for idx in first.tolist():
        lookup[pts[idx].tobytes()] = idx
    try:
        return np.array([lookup[row.tobytes()] for row in kept], dtype=np.int64)
    except KeyError as exc:  # pragma: no cover - TetGen never moves input points
        raise RuntimeError("TetGen returned a point that is not in the input") from exc


def _qhull(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from scipy.spatial import Delaunay, QhullError

    try:
        tri = Delaunay(pts)
    except QhullError:
        return np.zeros((0, 4), np.int64), np.zeros((0, 3), np.int64)
    tets = tri.simplices.astype(np.int64)
    neighbors = tri.neighbors.astype(np.int64)
    if len(tri.coplanar):
        # Qhull keeps an arbitrary one of several coincident points; refer to the first, as with TetGen.
        keys = pts.view(np.dtype((np.void, 24))).ravel()
        _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
        tets = first[inverse.reshape(-1)][tets]
    signs = orientation(pts, tets)
    flip = signs < 0
    tets[flip] = tets[flip][:, [1, 0, 2, 3]]
    neighbors[flip] = neighbors[flip][:, [1, 0, 2, 3]]
    flat = np.flatnonzero(signs == 0)
    if len(flat):
        _orient_flat_tets(tets, neighbors, flat)
    # Hull faces straight from the (now consistently oriented) tets: exactly the faces marching tets sees.
    t_idx, k_idx = np.nonzero(neighbors < 0)
    hull = np.take_along_axis(tets[t_idx], TET_OUTWARD_FACES[k_idx], axis=1)
    return np.ascontiguousarray(tets), np.ascontiguousarray(hull)


def _orient_flat_tets(tets: np.ndarray, neighbors: np.ndarray, flat: np.ndarray) -> None:
    """Orient exactly flat tets in place so that each shared face gets opposite orientations from its tets."""
    fixed = np.ones(len(tets), dtype=bool)
    fixed[flat] = False
    pending = flat.tolist()
    while pending:
        still = []
        for t in pending:
            for k in range(4):
                u = int(neighbors[t, k])
                if u < 0 or not fixed[u]:
                    continue
                apex = tets[t, k]
                m = int(np.flatnonzero(neighbors[u] == t)[0])
                x, y, z = tets[u, TET_OUTWARD_FACES[m]]
                # u sees the shared face as (x, y, z) outward; t must see (x, z, y): t = (apex, x, z, y).
                order = [apex, x, z, y]
                old = tets[t].tolist()
                tets[t] = order
                neighbors[t] = [neighbors[t, old.index(v)] for v in order]
                fixed[t] = True
                break
            else:
                still.append(t)
        if len(still) == len(pending):  # isolated flat pocket: nothing to align with, keep as is
            break
        pending = still


def _orient_hull_faces(pts: np.ndarray, hull: np.ndarray) -> np.ndarray:
    """Orient convex hull triangles outward: the point set's centroid must lie on their inner side."""
    if not len(hull):
        return hull
    centre_idx = len(pts)
    pts_c = np.vstack([pts, pts.mean(axis=0, keepdims=True)])
    probe = np.column_stack([hull, np.full(len(hull), centre_idx)])
    signs = orientation(pts_c, probe)
    # (a, b, c) is outward iff the tet (a, b, c, centroid) has negative volume.
    flip = signs > 0
    hull = hull.copy()
    hull[flip] = hull[flip][:, [0, 2, 1]]
    return hull


def orientation(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Exact sign of ``det[p1 - p0, p2 - p0, p3 - p0]`` per tet.

    Args:
        points: (N, 3) float64.
        tets: (T, 4) integer indices.
    Returns:
        (T,) int8 in {-1, 0, 1}; float64 where its sign is certain, exact rational arithmetic otherwise.
    """
    p0 = points[tets[:, 0]]
    u = points[tets[:, 1]] - p0
    v = points[tets[:, 2]] - p0
    w = points[tets[:, 3]] - p0
    m0 = v[:, 1] * w[:, 2] - v[:, 2] * w[:, 1]
    m1 = v[:, 2] * w[:, 0] - v[:, 0] * w[:, 2]
    m2 = v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]
    det = u[:, 0] * m0 + u[:, 1] * m1 + u[:, 2] * m2
    permanent = (
        np.abs(u[:, 0]) * (np.abs(v[:, 1] * w[:, 2]) + np.abs(v[:, 2] * w[:, 1]))
        + np.abs(u[:, 1]) * (np.abs(v[:, 2] * w[:, 0]) + np.abs(v[:, 0] * w[:, 2]))
        + np.abs(u[:, 2]) * (np.abs(v[:, 0] * w[:, 1]) + np.abs(v[:, 1] * w[:, 0]))
    )
    signs = np.sign(det).astype(np.int8)
    uncertain = np.flatnonzero(~(np.abs(det) > _ORIENT_ERRBOUND * permanent))
    for t in uncertain.tolist():
        signs[t] = _exact_orientation(points[tets[t]])
    return signs


def _exact_orientation(corners: np.ndarray) -> int:
    """Sign of det[b - a, c - a, d - a] for the (4, 3) float64 corners, in exact integer arithmetic."""
    ratios = [float(x).as_integer_ratio() for x in corners.ravel().tolist()]
    scale = max(den for _, den in ratios)  # a power of two: every coordinate becomes an integer multiple of 1/scale
    a0, a1, a2, b0, b1, b2, c0, c1, c2, d0, d1, d2 = (num * (scale // den) for num, den in ratios)
    u0, u1, u2 = b0 - a0, b1 - a1, b2 - a2
    v0, v1, v2 = c0 - a0, c1 - a1, c2 - a2
    w0, w1, w2 = d0 - a0, d1 - a1, d2 - a2
    det = u0 * (v1 * w2 - v2 * w1) + u1 * (v2 * w0 - v0 * w2) + u2 * (v0 * w1 - v1 * w0)
    return (det > 0) - (det < 0)
