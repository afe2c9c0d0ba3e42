"""Delaunay tetrahedralization of a bare point set: our own exact one by default, TetGen and scipy's Qhull as
alternatives (files that recorded them).

Backends, measured on a 2-core CPU (CPU time, medians of 7, timing noise +-30 %; 2026-12-06,
`benchmarks/delaunay_speed.py --repeats 7`, two runs: 64K float16-rounded points in a thin
sphere shell and in a cube, the 16-18K points of the four committed 40 KB bench files):

=========================  ===========  ===========  ==============  ==========================================
backend                    64K points   40 KB files  license         notes
=========================  ===========  ===========  ==============  ==========================================
``exact`` (ours, C)        0.14-0.15 s  31-37 ms     Apache-2.0      exact integer predicates, unique result
TetGen 1.6 (``tetgenpy``)  0.21-0.23 s  50-67 ms     AGPL-3.0        switches ``Qz``; optional extra ``tetgen``
scipy Qhull                2.2-2.5 s    0.36-0.57 s  BSD (Qhull)     ``Qbb Qc Qz Q12 Qt`` on perturbed points
=========================  ===========  ===========  ==============  ==========================================

"exact" is 1.44-1.91x faster than TetGen there (median 1.50x; the version of 56ef249 measured 1.27x in the same
runs; issue 54's target of 3x is not met: per point it evaluates ~39 insphere and ~22 orient3d predicates, makes
~25 new tets and links them through a local edge table, ~2 us in all).

``backend="auto"`` is ``"exact"``: always available (a required C extension, geometry/_delaunay_native.c, no
third-party code), specified below to the bit so that an independent decoder computes the same tets. TetGen is
imported lazily and only for the ``"tetgen"`` backend (``pip install 'tetweave[tetgen]'``); without it that
backend raises ImportError with the install hint.

The "exact" backend: definition
-------------------------------
Input: N integer points p_i = (x_i, y_i, z_i), i = 0..N-1, with 0 <= x_i, y_i, z_i < 2^MAX_BITS, MAX_BITS = 23
(`tetrahedralize_cells`; `tetrahedralize(points, "exact")` first snaps float points to that lattice, see
`snap_to_lattice`). Coordinates outside the range and N > 2^26 raise ValueError.

1. Duplicates. Of points with equal coordinates only the one with the lowest index i is a vertex; the others
   appear in no tet and no hull face.
2. Ranks and perturbation. The M distinct points are ranked r = 0..M-1 in ascending lexicographic order of
   (x, y, z). Each point is lifted to h(p) = x^2 + y^2 + z^2 + delta_r, where the delta_r are positive
   infinitesimals with delta_{M-1} >> delta_{M-2} >> ... >> delta_0 > 0 (e.g. delta_r = eps^(M - r), eps -> 0+):
   the point of larger rank is raised more, and its term dominates. The tetrahedralization is the regular
   triangulation of the points with these lifts (the projection of the lower convex hull of the lifted points):
   the Delaunay tetrahedralization where the points are in general position, unique for every input with at
   least 4 affinely independent points. Every distinct point is a vertex (a perturbation this small hides none).
3. Predicates, exact.
   orient3d(a, b, c, d) = sign det[b - a, c - a, d - a] (rows), no perturbation; (a, b, c, d) is positively
   oriented when orient3d > 0. Conflict of a point e with a positively oriented tet (a, b, c, d) (e inside its
   perturbed circumsphere): with O = det[b - a, c - a, d - a] and the lifts h,

       Phi = O h(e) - o_a h(a) - o_b h(b) - o_c h(c) - o_d h(d),
       o_a = det3(e, b, c, d), o_b = det3(a, e, c, d), o_c = det3(a, b, e, d), o_d = det3(a, b, c, e),

   det3 being the determinant orient3d takes the sign of (o_v / O are e's barycentric coordinates, so Phi / O is
   h(e) minus the lifted plane through a, b, c, d at e). e conflicts iff Phi < 0. Phi = Phi_0 + O delta(e)
   - o_a delta(a) - o_b delta(b) - o_c delta(c) - o_d delta(d), Phi_0 the same with |p|^2 for h. If Phi_0 != 0
   its sign decides (Phi_0 < 0: e strictly inside the circumsphere). Else go through the five points in
   descending rank: if the point is e, e does not conflict (its coefficient O > 0); if it is a vertex v, let
   o = orient3d of the tet with v replaced by e; if o != 0, e conflicts iff o > 0; if o = 0, go on (e itself is
   always reached). Translated to e (A = a - e, ...; rows): Phi_0 = -W with
   W = |A|^2 det[B,C,D] - |B|^2 det[A,C,D] + |C|^2 det[A,B,D] - |D|^2 det[A,B,C], so e is strictly inside iff
   W > 0.
4. Convex hull. An infinite vertex closes the hull: a hull triangle (a, b, c), oriented outward, is the finite
   face of a "ghost tet". A point q conflicts with it iff orient3d(a, b, c, q) > 0 (q strictly outside its
   plane), or orient3d(a, b, c, q) = 0 and q is inside the perturbed circumcircle of (a, b, c): in a coordinate
   plane where the projection (a', b', c') of the triangle is not degenerate (the implementation drops the axis
   of the largest |component| of (b - a) x (c - a), the lowest on ties; the result does not depend on the
   choice), with O2 = det[b' - a', c' - a'] and the same 3-D lifts h,

       Phi2 = O2 h(q) - o'_a h(a) - o'_b h(b) - o'_c h(c),
       o'_a = det2(q', b', c'), o'_b = det2(a', q', c'), o'_c = det2(a', b', q'),

   q conflicts iff sign(O2) Phi2 < 0 (h(q) below the lifted plane through a, b, c, at q). If the unperturbed part
   is 0, go through a, b, c, q in descending rank: q -> no conflict; a vertex v whose orient2d with v replaced by q
   is non-zero -> conflict iff that sign equals sign(O2); zero -> go on to the next point. This is rule 3
   restricted to the plane of a hull face, so the hull triangulation is the regular triangulation's (the 2-D
   regular triangulation of the points on each planar face of the hull).
5. Output. tets (T, 4) int64: every tet positively oriented (orient3d > 0 exactly; never flat), indices into the
   caller's array. Canonical order: each tet is permuted evenly (orientation kept) so that its smallest index
   comes first and the smallest of the other three second; tets sorted lexicographically. hull_faces (H, 3)
   int64: the hull triangles, oriented outward ((b - a) x (c - a) points away from the points), rotated
   cyclically so that the smallest index comes first, sorted lexicographically. Fewer than 4 distinct points, or
   all distinct points coplanar: (0, 4) and (0, 3), no error.

Exactness: coordinates in [0, 2^23 - 1] give differences < 2^23, 2x2 minors < 2^47 (int64, exact in binary64),
orient3d and every 3x3 determinant of differences < 3 * 2^23 * 2^47 < 2^72, lifts |d|^2 < 3 * 2^46 < 2^48,
W < 4 * 3 * 2^46 * 3 * 2^70 = 36 * 2^116 < 2^122 and the 2-D conflict value < 3 * 3 * 2^46 * 2^47 < 2^97:
128-bit integers (and binary64 behind forward error bounds) evaluate every predicate exactly. Algorithm (speed
only: any correct implementation gives the same arrays): Bowyer-Watson in BRIO / Hilbert order with a visibility
walk, filtered predicates; see the C file.

Other backends
--------------
License consequence of TetGen: AGPL-3.0; it is an optional extra, needed only to decode files whose header
records TetGen. Degenerate (cospherical) point sets have several Delaunay tetrahedralizations and TetGen and
Qhull may pick different ones (measured on float16-rounded point sets: uniform in a cube, in sphere and torus
shells, 27 sets of 2K-64K points: identical tets every time; points crowded on the float16 lattice and regular
lattices: different tets every time), which is why the container records the backend (flags bit 0) and the
decoder uses the same one.

Guarantees of `delaunay` / `tetrahedralize`:

* tets index the caller's point array (TetGen silently drops exact duplicate points and renumbers the rest; we
  map back, and of exactly coincident points only the first is referenced);
* a proper tetrahedralization of the distinct points: every distinct point is a vertex, each triangle is shared
  by at most two tets, seen in opposite orientations, and the unpaired triangles are the convex hull's;
* tets are positively oriented, ``det[p1 - p0, p2 - p0, p3 - p0] > 0``, decided with an exact predicate where
  float64 is not certain (for Qhull: the sign on the perturbed points, below; a tet whose corners are coplanar
  in true coordinates keeps that orientation, consistent with its neighbours; for "exact": on the lattice
  points, see `snap_to_lattice`);
* deterministic (all three are deterministic for the same input and options);
* fewer than 4 points, or points that span no volume (all (nearly) coplanar or collinear for TetGen and Qhull,
  exactly coplanar for "exact"), give no tets (shape (0, 4)).

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

BACKENDS = ("exact", "tetgen", "qhull")

# The "exact" backend's lattice (module docstring): integer coordinates in [0, 2^MAX_BITS), at most MAX_POINTS
# points (the C extension checks both again).
MAX_BITS = 23
MAX_POINTS = 2**26
TETGEN_INSTALL_HINT = "pip install 'tetweave[tetgen]' (TetGen is AGPL-3.0)"

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
    backend: "exact", "tetgen" or "qhull", the code that produced `tets`.
    """

    tets: np.ndarray
    hull_faces: np.ndarray
    backend: str


def _has_tetgen() -> bool:
    """Whether tetgenpy is installed, without importing it: encode and decode of files that do not name TetGen
    never load an AGPL module (tests/test_license.py)."""
    import importlib.util
    import sys

    if "tetgenpy" in sys.modules:  # imported already, or hidden (None) by a test
        return sys.modules["tetgenpy"] is not None
    return importlib.util.find_spec("tetgenpy") is not None


def available_backends() -> tuple[str, ...]:
    """Backends usable in this environment, in order of preference ("exact" always first)."""
    return BACKENDS if _has_tetgen() else tuple(b for b in BACKENDS if b != "tetgen")


def resolve_backend(backend: str = "auto") -> str:
    """Map "auto" to "exact"; validate explicit names (ValueError; ImportError for "tetgen" without tetgenpy)."""
    if backend == "auto":
        return BACKENDS[0]
    if backend not in BACKENDS:
        raise ValueError(f"unknown Delaunay backend {backend!r}; choose one of auto, {', '.join(BACKENDS)}")
    if backend == "tetgen" and not _has_tetgen():
        raise ImportError(f"the Delaunay backend 'tetgen' needs the tetgenpy package: {TETGEN_INSTALL_HINT}")
    return backend


def delaunay(points: np.ndarray, backend: str = "auto") -> np.ndarray:
    """Delaunay tetrahedralization.

    Args:
        points: (N, 3) finite coordinates (any float dtype; computed in float64).
        backend: "auto" (= "exact"), "exact", "tetgen" or "qhull".
    Returns:
        tets (T, 4) int64, positively oriented, indices into `points`.
    """
    return tetrahedralize(points, backend).tets


def tetrahedralize(points: np.ndarray, backend: str = "auto") -> Tetrahedralization:
    """Delaunay tetrahedralization with the convex hull faces; see `Tetrahedralization`.

    "exact" triangulates `snap_to_lattice(points)` (`tetrahedralize_cells`); the others the float64 points.
    """
    backend = resolve_backend(backend)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points must be finite")
    if backend == "exact":
        return tetrahedralize_cells(snap_to_lattice(pts))
    if _spans_no_volume(pts):
        return Tetrahedralization(np.zeros((0, 4), np.int64), np.zeros((0, 3), np.int64), backend)
    if backend == "tetgen":
        tets, hull = _tetgen(pts)
    else:
        tets, hull = _qhull(pts)
    return Tetrahedralization(tets, hull, backend)


def snap_to_lattice(points: np.ndarray) -> np.ndarray:
    """Lattice cells of float points for the "exact" backend: (N, 3) int64 in [0, 2^MAX_BITS).

    ``K = floor((x + B) / (2 B) * 2^MAX_BITS + 1/2)`` clamped to ``[0, 2^MAX_BITS - 1]``, B = quantize.GRID_BOUND:
    the nearest of 2^23 lattice values over [-B, B] (in float64, one rounding per operation). Rounding to the
    nearest rather than down: a v2 file's cell centre at b bits, ``((2k + 1 - 2^b) B) / 2^b``, sits exactly on the
    lattice value ``k * 2^(23 - b) + 2^(22 - b)``, and float64 error (~1e-9 here) could put it below that integer;
    so every position grid of 6..16 bits maps to the lattice exactly (tests/test_delaunay_exact.py), its tets are
    those of `tetrahedralize_cells(cells)`, and the map is monotone (lexicographic ranks are kept). Points beyond
    [-B, B] (never the fit's, which it clamps there) take B = the power of two at or above their largest
    magnitude instead, so that no point is clamped onto another.
    """
    from tetweave_codec.formats.quantize import GRID_BOUND

    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("points must be finite")
    bound = GRID_BOUND
    largest = float(np.abs(pts).max()) if pts.size else 0.0
    if largest > GRID_BOUND:
        bound = float(np.ldexp(1.0, int(np.frexp(largest)[1])))  # 2^e > largest (frexp: largest < 2^e)
    t = (pts + bound) / (2.0 * bound) * float(1 << MAX_BITS)
    return np.clip(np.floor(t + 0.5), 0, (1 << MAX_BITS) - 1).astype(np.int64)


def tetrahedralize_cells(cells: np.ndarray) -> Tetrahedralization:
    """The "exact" backend on integer points: the tetrahedralization the module docstring defines.

    Args:
        cells: (N, 3) integers in [0, 2^MAX_BITS), N <= MAX_POINTS (else ValueError).
    Returns:
        Tetrahedralization(tets (T, 4) int64, hull_faces (H, 3) int64, "exact"), in the canonical order. A
        TopologyError if a tet came out flat (an internal inconsistency; never expected).
    """
    from tetweave_codec.geometry import _delaunay_native

    c = np.asarray(cells)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"cells must have shape (N, 3), got {c.shape}")
    if c.size and not np.issubdtype(c.dtype, np.integer):
        raise ValueError(f"cells must be integers, got {c.dtype}")
    if len(c) > MAX_POINTS:
        raise ValueError(f"at most {MAX_POINTS} points can be tetrahedralized, got {len(c)}")
    if c.size and (c.min() < 0 or c.max() >= (1 << MAX_BITS)):
        raise ValueError(f"cell coordinates must lie in [0, 2^{MAX_BITS}), got {c.min()}..{c.max()}")
    c = np.ascontiguousarray(c, dtype=np.int64)
    try:
        tets, hull = _delaunay_native.tetrahedralize(c)
    except RuntimeError as exc:  # "flat tet ..." or "walk ...": the predicates disagreed with the construction
        raise TopologyError(f"exact Delaunay of {len(c)} points failed: {exc}") from exc
    return Tetrahedralization(
        np.frombuffer(tets, dtype=np.int64).reshape(-1, 4), np.frombuffer(hull, dtype=np.int64).reshape(-1, 3), "exact"
    )


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
