"""Delaunay tetrahedralization of a bare point set: TetGen by default, scipy's Qhull as permissive fallback.

Backends, measured on a 2-core CPU for 64K float16-rounded points in a thin shell (one run, timing noise
+-30 %):

=========================  ===========  ==============  ==========================================
backend                    64K points   license         notes
=========================  ===========  ==============  ==========================================
TetGen 1.6 (``tetgenpy``)  0.29-0.36 s  AGPL-3.0        switches ``Qz``; exact predicates
scipy Qhull                1.9-2.3 s    BSD (Qhull)     ``Qbb Qc Qz Q12 Qt`` on perturbed points, below
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
* a proper tetrahedralization of the distinct points: every distinct point is a vertex, each triangle is shared
  by at most two tets, seen in opposite orientations, and the unpaired triangles are the convex hull's;
* tets are positively oriented, ``det[p1 - p0, p2 - p0, p3 - p0] > 0``, decided with an exact predicate where
  float64 is not certain (for Qhull: the sign on the perturbed points, below; a tet whose corners are coplanar
  in true coordinates keeps that orientation, consistent with its neighbours);
* deterministic (both libraries are deterministic for the same input and options);
* fewer than 4 points, or points that span no volume (all (nearly) coplanar or collinear), give no tets
  (shape (0, 4)).

Qhull tie-break. TetGen decides every predicate exactly with a symbolic perturbation, so cospherical and
coplanar sets (lattice points: every cube of 8 cells is cospherical) come out as a proper tetrahedralization.
Qhull computes in floating point and merges near-degenerate facets of the lifted hull; scipy's mandatory ``Qt``
then triangulates each merged facet on its own, which emits flat tets and, where two cospherical cells share a
square, splits that square along different diagonals on its two sides (a non-conforming complex: marching
tets then returns meshes with unpaired and doubled edges -- measured on 12-31 of 40 lattice sets of 1-3K
points). So Qhull triangulates *perturbed* points: each coordinate moves by less than 2^(e - 25), with 2^e
the power of two just above the largest coordinate magnitude (in the normalized frame 2^-24 = 6e-8, 1.6e-3 of
the finest v2 grid cell), in a direction given by a fixed hash of the point's coordinate bits (so it depends
neither on the point order nor on the platform, and coincident points stay coincident). That separates every
degenerate configuration by far more than Qhull's roundoff (measured: lattice clusters of 3K points at 5-16
position bits are proper at perturbations 2^-16..2^-28, not always at 2^-32), while changing no choice between
configurations that are not degenerate except for tets whose volume is within ~3 * 2^-24 * edge^2 of zero.
The result is checked (`proper_tetrahedralization_error`); if Qhull ever misses, the perturbation is retried
16x and 256x larger (`QHULL_PERTURBATION_BITS`), and a `TopologyError` is raised if none is proper.
formats/README.md ("Decoding", step 2) specifies the perturbation for other decoders.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from tetweave_codec.errors import TopologyError

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

# Qhull tie-break: the perturbation of each coordinate is below 2^(e - k) for the first k of these that gives a
# proper tetrahedralization (2^e: the power of two just above the largest coordinate magnitude).
QHULL_PERTURBATION_BITS = (25, 21, 17)
# The hash gives each axis a 21-bit integer u in [0, 2^21), used as (u - 2^20 + 0.5) / 2^20 in (-1, 1).
_HASH_BITS_PER_AXIS = 21
_SPLITMIX_GAMMA = (
    0x9E3779B97F4A7C15  # splitmix64 (Steele, Lea, Flood 2014), the finalizer of java.util.SplittableRandom
)
_SPLITMIX_MUL1 = 0xBF58476D1CE4E5B9
_SPLITMIX_MUL2 = 0x94D049BB133111EB


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
    """Qhull on perturbed points (module docstring), the first proper result of `QHULL_PERTURBATION_BITS`."""
    from scipy.spatial import QhullError

    failures = []
    for bits in QHULL_PERTURBATION_BITS:
        perturbed = perturb_points(pts, bits)
        try:
            tets, neighbors = _qhull_tets(pts, perturbed)
        except QhullError as exc:  # a precision error: retried with a larger perturbation
            failures.append(f"Qhull failed ({str(exc).splitlines()[0][:80]})")
            continue
        problem = proper_tetrahedralization_error(perturbed, tets, neighbors)
        if problem is None:
            # Hull faces straight from the tets: exactly the faces marching tets sees.
            t_idx, k_idx = np.nonzero(neighbors < 0)
            hull = np.take_along_axis(tets[t_idx], TET_OUTWARD_FACES[k_idx], axis=1)
            return np.ascontiguousarray(tets), np.ascontiguousarray(hull)
        failures.append(problem)
    raise TopologyError(f"Qhull gave no proper tetrahedralization of {len(pts)} points: {failures[-1]}")


def _qhull_tets(pts: np.ndarray, perturbed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Qhull's tets of `perturbed`, oriented positively there (exact), and its neighbour table (-1: hull face).

    Points Qhull leaves out (its "coplanar" points) must be exact duplicates of a vertex, and tets refer to the
    first occurrence of a coordinate triple; else the result has -1 in `tets` (rejected as improper).
    """
    from scipy.spatial import Delaunay

    tri = Delaunay(perturbed)
    tets = tri.simplices.astype(np.int64)
    neighbors = tri.neighbors.astype(np.int64)
    if len(tri.coplanar):
        keys = pts.view(np.dtype((np.void, 24))).ravel()
        _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
        first_of = first[inverse.reshape(-1)]
        left_out, nearest = tri.coplanar[:, 0], tri.coplanar[:, 2]
        if np.any(first_of[left_out] != first_of[nearest]):
            return np.full((1, 4), -1, np.int64), np.full((1, 4), -1, np.int64)  # a distinct point was dropped
        tets = first_of[tets]
    flip = orientation(perturbed, tets) < 0
    tets[flip] = tets[flip][:, [1, 0, 2, 3]]
    neighbors[flip] = neighbors[flip][:, [1, 0, 2, 3]]
    return tets, neighbors


def perturb_points(points: np.ndarray, bits: int = QHULL_PERTURBATION_BITS[0]) -> np.ndarray:
    """The Qhull tie-break: points moved by a fixed hash of their coordinates (formats/README.md, Decoding).

    Args:
        points: (N, 3) float64, finite.
        bits: k; every coordinate moves by less than 2^(e - k), with 2^(e - 1) <= max |coordinate| < 2^e.
    Returns:
        (N, 3) float64: ``p + u * 2^(e - k - 20)`` (one rounding), u in (-2^20, 2^20) per axis from the hash.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if not len(pts):
        return pts.copy()
    _, e = np.frexp(np.abs(pts).max())
    h = _coordinate_hash(pts)
    mask = np.uint64((1 << _HASH_BITS_PER_AXIS) - 1)
    u = np.stack([(h >> np.uint64(_HASH_BITS_PER_AXIS * a)) & mask for a in range(3)], 1).astype(np.float64)
    half = float(1 << (_HASH_BITS_PER_AXIS - 1))
    return pts + (u - (half - 0.5)) * np.ldexp(1.0, int(e) - bits - (_HASH_BITS_PER_AXIS - 1))


def _coordinate_hash(pts: np.ndarray) -> np.ndarray:
    """(N,) uint64: splitmix64(bits(x) ^ splitmix64(bits(y) ^ splitmix64(bits(z)))), bits of ``coordinate + 0.0``."""
    raw = (pts + 0.0).view(np.uint64)  # + 0.0 turns -0.0 into +0.0: equal coordinates, equal bits
    h = _splitmix64(raw[:, 2])
    h = _splitmix64(raw[:, 1] ^ h)
    return _splitmix64(raw[:, 0] ^ h)


def _splitmix64(z: np.ndarray) -> np.ndarray:
    """splitmix64's output function on uint64 arrays (arithmetic modulo 2^64)."""
    z = z + np.uint64(_SPLITMIX_GAMMA)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(_SPLITMIX_MUL1)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(_SPLITMIX_MUL2)
    return z ^ (z >> np.uint64(31))


def proper_tetrahedralization_error(points: np.ndarray, tets: np.ndarray, neighbors: np.ndarray) -> str | None:
    """None if `tets` with its neighbour table is a proper, consistently oriented tetrahedralization, else why not.

    Args:
        points: (N, 3) float64, the coordinates the tets are oriented in.
        tets: (T, 4) int64. neighbors: (T, 4) int64, neighbors[t, k] the tet across the face opposite corner k,
            -1 on the boundary (scipy's convention).
    Checks (vectorized, O(T)): every tet has positive exact orientation; each neighbour relation is mutual; the
    two tets see their shared face with opposite orientations (so they lie on its two sides, not overlapping);
    the face opposite corner k of t is the same vertex triple in the neighbour (a conforming complex).
    """
    if len(tets) == 0:
        return None
    if tets.min() < 0:
        return "a distinct point is not a vertex"
    if not np.all(orientation(points, tets) > 0):
        return "a tet is flat"
    t_idx, k_idx = np.nonzero(neighbors >= 0)
    u = neighbors[t_idx, k_idx]
    back = neighbors[u] == t_idx[:, None]  # (M, 4): which face of u points back to t
    if not np.all(back.sum(1) == 1):
        return "a neighbour relation is not mutual"
    m_idx = np.argmax(back, axis=1)
    mine = _rotate_min_first(np.take_along_axis(tets[t_idx], TET_OUTWARD_FACES[k_idx], axis=1))
    theirs = _rotate_min_first(np.take_along_axis(tets[u], TET_OUTWARD_FACES[m_idx], axis=1))
    if not np.array_equal(mine, theirs[:, [0, 2, 1]]):
        return "two neighbouring tets do not share their face in opposite orientations (non-conforming)"
    return None


def _rotate_min_first(tris: np.ndarray) -> np.ndarray:
    """(M, 3) oriented triangles rotated (cyclic order kept) so that the smallest index comes first."""
    r = np.argmin(tris, axis=1)
    return np.take_along_axis(tris, (r[:, None] + np.arange(3)) % 3, axis=1)


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
