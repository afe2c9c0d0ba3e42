"""Initial TetWeave state: points, base signed distances s and SH coefficients c before the fit starts.

The paper (Appendix A) starts from random points in a ball of radius sqrt(3) with random s, because in
multi-view reconstruction nothing is known about the shape. An encoder knows its input exactly, so
``initial_state`` starts
near the answer: most points sit in a thin shell around the input surface and s is the input's signed
distance, so Delaunay + marching tetrahedra of the initial state already reproduce the input up to the grid
resolution.
``random_state`` is the paper's start, kept for comparison (``benchmarks/init_compare.py``, in history at ffee759).

All positions are in the normalized frame: the input's bounding box fits [-0.9, 0.9]^3 and the points fill
[-BOX, BOX]^3. Inside the shape s < 0.
"""

from __future__ import annotations

import math

import igl
import numpy as np

from tetweave_codec.errors import InputError
from tetweave_codec.fit.features import (
    Features,
    crease_distance,
    detect_features,
    feature_points,
    polyhedral_distance,
    snap_to_grid,
)
from tetweave_codec.geometry.closest import SurfaceTree
from tetweave_codec.geometry.sh import check_degree, num_coeffs
from tetweave_codec.geometry.triangles import face_areas, face_normals, sample_surface

# Half side of the cube the initial points fill: the normalized input ([-0.9, 0.9]^3) plus a margin of 0.1, so
# that every camera ray that can hit the shape crosses grid points on both sides of the surface.
BOX = 1.0
# The first N_CORNERS points of ``initial_points`` are the corners of [-BOX, BOX]^3. Their convex hull is the
# whole cube, so Delaunay covers the domain and no surface can reach the hull; keep them through resampling.
N_CORNERS = 8
CORNERS = np.array([[x, y, z] for x in (-BOX, BOX) for y in (-BOX, BOX) for z in (-BOX, BOX)], np.float64)
# Winding number above which a query is inside. |w| rather than w, so that a mesh whose faces are all oriented
# inwards still gets negative s inside (w = -1 there).
INSIDE_WINDING = 0.5
# Fraction of the points spread uniformly over the cube (see ``initial_points``).
UNIFORM_FRACTION = 0.1
# Half width of the shell, in units of the expected surface point spacing sqrt(area / n_surface).
SHELL = 1.0
# Offsets from the surface are drawn with |t| in [SHELL_GAP, 1] * half width (see ``initial_points``).
SHELL_GAP = 0.25
# Smallest |s| a point gets (and a v1 file stores, see fit.finish): the smallest normal float16, so that float16
# keeps every sign (s = 0 would leave a grid point's side undefined).
MIN_ABS_S = 2.0**-14
# Feature-aware start (fit.features): spacing along the creases in units of the mean point spacing
# sqrt(area / n); at most this fraction of the points go to features (the spacing grows otherwise); shell points
# closer to a crease than CREASE_CLEARANCE crease spacings are dropped. 1 KB files (--size 1024), Chamfer at
# clearance 1.5 / 0.8: cube 1.39e-3 / 1.52e-3, three boxes 1.67e-2 / 4.94e-3 (0.5: 4.81e-3, 1.0: 1.11e-2),
# cube minus cylinder 6.61e-3 / 5.33e-3 (benchmarks/creases.py at ffee759).
CREASE_SPACING = 1.0
MAX_FEATURE_FRACTION = 0.5
CREASE_CLEARANCE = 0.8
# The crease spacing grows at most this many times to fit the feature points into their share of the budget
# (2-5 times where it fits at all).
MAX_SPACING_STEPS = 30
# Stratified surface sampling: candidates per sample, and bisection steps on the cell size (2^-12 relative).
OVERSAMPLE = 4
STRATIFY_BISECTIONS = 12
# A shell offset is halved, up to this many times, while the moved point's closest input face faces against the
# sample's normal (``keep_on_side``).
SIDE_HALVINGS = 4


def signed_distance(
    queries: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    tree: SurfaceTree | None = None,
    distance: np.ndarray | None = None,
) -> np.ndarray:
    """Signed distance from points to a triangle mesh, negative inside.

    The magnitude is the exact Euclidean distance to the closest triangle (``tree``, the mesh's SurfaceTree,
    built here when not given: callers that query the same mesh again pass theirs); the sign comes
    from the generalized winding number w (libigl's fast winding number): inside where |w| > INSIDE_WINDING.
    The winding number degrades gracefully on open scans (holes), multiple components, self-intersections and
    non-manifold edges, where pseudonormal signs break down. libigl's own ``signed_distance(...,
    FAST_WINDING_NUMBER)`` is not used: it returns (1 - 2|w|) * distance, which is off by the winding number's
    approximation error (0.3 % measured) and is 0 where w = 0.5.

    Args:
        queries: (M,3) float positions.
        vertices: (V,3) float mesh vertices.
        faces: (F,3) int triangles.
        tree: a SurfaceTree of (vertices, faces), or None.
        distance: (M,) the unsigned distances of the queries when the caller has them (no tree query then).
    Returns:
        (M,) float64 signed distances in the units of ``vertices``.
    """
    q = np.ascontiguousarray(queries, dtype=np.float64).reshape(-1, 3)
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if q.shape[0] == 0:
        return np.zeros(0)
    if f.shape[0] == 0:
        raise InputError("cannot compute a signed distance to a mesh without faces")
    if distance is None:
        sq_dist, _, _ = (tree or SurfaceTree(v, f)).query(q)
        dist = np.sqrt(np.maximum(sq_dist, 0.0))
    else:
        dist = np.asarray(distance, dtype=np.float64).reshape(-1)
    winding = igl.fast_winding_number(v, f, q)
    return np.where(np.abs(winding) > INSIDE_WINDING, -dist, dist)


def _sample_surface(
    vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, float]:
    """Area-weighted random points on the surface: positions (n,3), face normals (n,3), total area."""
    total = float(face_areas(vertices, faces).sum())
    if not np.isfinite(total) or total <= 0.0:
        raise InputError("the mesh has no surface area (all faces are degenerate)")
    pos, face = sample_surface(vertices, faces, n, rng)
    return pos, face_normals(vertices, faces)[face], total


def _cell_keys(points: np.ndarray, size: float) -> np.ndarray:
    """(n,) int64 key of the cubic cell of side ``size`` that holds each point (21 bits per axis)."""
    ijk = np.floor(points / size).astype(np.int64) + (1 << 20)
    ijk = np.clip(ijk, 0, (1 << 21) - 1)
    return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]


def _sample_surface_stratified(
    vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, float]:
    """Surface samples with at most one per cell of a cubic grid: fewer clumps and holes than random samples.

    Draws OVERSAMPLE * n random samples, then picks the cell size (bisection) at which at least n cells are
    occupied, keeps the first sample (in random order) of each occupied cell and n of those at random.
    Measured on the shared meshes at 4K / 16K points against plain random samples: the initial state's Chamfer
    distance drops by 15-20 % and the share of triangle angles below 10 degrees from 4 % to 3 %.

    Returns positions (n,3), face normals (n,3), total area.
    """
    pos, normals, area = _sample_surface(vertices, faces, OVERSAMPLE * n, rng)
    spacing = math.sqrt(area / n)
    lo, hi = 0.1 * spacing, 10.0 * spacing
    if len(np.unique(_cell_keys(pos, lo))) < n:  # too few distinct samples (tiny n or degenerate input)
        pick = rng.choice(len(pos), size=n, replace=False)
        return pos[pick], normals[pick], area
    for _ in range(STRATIFY_BISECTIONS):
        mid = math.sqrt(lo * hi)
        if len(np.unique(_cell_keys(pos, mid))) >= n:
            lo = mid
        else:
            hi = mid
    _, first = np.unique(_cell_keys(pos, lo), return_index=True)
    pick = np.sort(first)[rng.permutation(len(first))[:n]]
    return pos[pick], normals[pick], area


def keep_on_side(
    samples: np.ndarray, normals: np.ndarray, offsets: np.ndarray, tree: SurfaceTree, face_normals: np.ndarray
) -> np.ndarray:
    """Shell offsets (n,) along the unit normals (n,3) of surface samples (n,3), each halved (up to SIDE_HALVINGS
    times) while the moved point's closest input face (``tree``; its unit normals face_normals (F,3)) faces
    against the sample's normal.

    A part thinner than the shell (a fin, an ear, a sheet) is crossed by a full offset: the point lands outside on
    the far side (or past the medial axis inside), where the input's signed distance gives it the sign of the
    wrong side, so no grid point lies inside the part and Delaunay joins same-sign points across it (the paper's
    stated limitation). Halved, the offset stays on its own side: inside the part, nearer to its own face.
    Orientation-agnostic (compares the two normals' directions only), so inconsistent winding is fine; degenerate
    faces (zero normals) never trigger it.
    """
    offsets = np.array(offsets, dtype=np.float64)
    todo = np.arange(len(samples))
    for _ in range(SIDE_HALVINGS):
        if len(todo) == 0:
            break
        _, face, _ = tree.query(samples[todo] + offsets[todo, None] * normals[todo])
        todo = todo[np.einsum("nd,nd->n", face_normals[face], normals[todo]) < 0.0]
        offsets[todo] *= 0.5
    return offsets


def _separate_duplicates(points: np.ndarray, rng: np.random.Generator, scale: float) -> np.ndarray:
    """Nudge points whose float32 values coincide (the first one stays) until all float32 rows differ."""
    points = points.copy()
    for _ in range(100):
        p32 = np.ascontiguousarray(points.astype(np.float32))
        _, first = np.unique(p32.view(np.dtype((np.void, 12))).ravel(), return_index=True)
        if len(first) == len(points):
            return points
        dup = np.ones(len(points), dtype=bool)
        dup[first] = False
        points[dup] += rng.normal(scale=scale, size=(int(dup.sum()), 3))
    raise RuntimeError("could not separate duplicate points")  # pragma: no cover - needs ~2^-24 collisions


def initial_points(
    vertices: np.ndarray,
    faces: np.ndarray,
    n: int,
    rng: np.random.Generator,
    shell: float = SHELL,
    uniform_fraction: float = UNIFORM_FRACTION,
    shell_gap: float = SHELL_GAP,
    tree: SurfaceTree | None = None,
) -> np.ndarray:
    """Points concentrated in a thin shell around the surface, plus a sparse uniform fill of [-BOX, BOX]^3.

    Layout (n points in all, distinct in float32):

    * the N_CORNERS corners of the cube: the Delaunay grid then covers the whole cube, the hull is far from
      the surface and every corner is outside;
    * ``round(uniform_fraction * n)`` points uniform in the cube. 10 % gives every region of the cube a grid
      point (spacing ~0.17 at 16K points), so that tetrahedra far from the surface stay small enough not to
      reach across thin parts, and leaves 90 % of the budget where the surface is: only points next to the
      surface (active points and their neighbours) shape the mesh, the others are relocated by the first
      resampling anyway. (The paper's ball of random points spends almost all of its points far from the
      surface.) Measured on spot / fandisk at 16K: 5 % / 10 % / 20 % give initial Chamfer distances within
      +-10 % of each other;
    * the rest on the surface, area-weighted and stratified (see ``_sample_surface_stratified``), each moved
      along its face normal by t * half_width, with |t| uniform in [shell_gap, 1] and a random sign, where
      half_width = shell * sqrt(area / n_surface) is about the distance between neighbouring samples. The
      shell is then about one point thick on each side of the surface: edges crossing the surface are short
      (the grid resolves the surface at the sampling density) and the tetrahedra stay well-shaped. Measured
      (spot, fandisk; 4K and 16K points): shell = 1 has the lowest initial Chamfer distance among 0.5, 0.75,
      1, 1.25, 2 (2 is 20-50 % worse, 0.5 up to 20 % worse). The gap keeps points off the surface itself: a
      point at distance ~0 puts extracted vertices onto grid points and makes slivers; shell_gap = 0.25 halves
      the share of triangle angles below 10 degrees (7.5 % -> 4 %) for a Chamfer distance 2-5 % higher.
      Offsets that would cross a part thinner than the shell are halved until they stay on their own side
      (``keep_on_side``), so that thin parts get grid points inside them.

    Args:
        vertices: (V,3) float mesh vertices in the normalized frame.
        faces: (F,3) int triangles (any orientation, open or not).
        n: number of points, >= N_CORNERS + 1.
        rng: numpy Generator (the only source of randomness).
        shell: half width of the shell in units of the surface sample spacing.
        uniform_fraction: fraction of points spread uniformly in the cube.
        shell_gap: smallest |offset| as a fraction of the half width, in [0, 1).
        tree: a SurfaceTree of (vertices, faces) to reuse, or None (built here).
    Returns:
        (n,3) float64 points inside [-BOX, BOX]^3.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if n <= N_CORNERS:
        raise ValueError(f"need more than {N_CORNERS} points, got {n}")
    if not 0.0 <= uniform_fraction <= 1.0 or not 0.0 <= shell_gap < 1.0 or shell < 0.0:
        raise ValueError("uniform_fraction must be in [0, 1], shell_gap in [0, 1) and shell >= 0")
    n_uniform = min(int(round(uniform_fraction * n)), n - N_CORNERS)
    n_surface = n - N_CORNERS - n_uniform
    parts = [CORNERS, rng.uniform(-BOX, BOX, size=(n_uniform, 3))]
    spacing = 1.0
    if n_surface > 0:
        pos, normals, area = _sample_surface_stratified(vertices, faces, n_surface, rng)
        spacing = math.sqrt(area / n_surface)
        t = rng.uniform(shell_gap, 1.0, size=n_surface) * rng.choice([-1.0, 1.0], size=n_surface)
        offsets = keep_on_side(
            pos, normals, shell * spacing * t, tree or SurfaceTree(vertices, faces), face_normals(vertices, faces)
        )
        parts.append(pos + offsets[:, None] * normals)
    points = np.clip(np.concatenate(parts), -BOX, BOX)
    points = _separate_duplicates(points, rng, scale=1e-4 * spacing)
    return np.clip(points, -BOX, BOX)


def initial_state(
    vertices: np.ndarray,
    faces: np.ndarray,
    n: int,
    sh_degree: int,
    seed: int,
    features: bool = True,
    position_bits: int | None = None,
    grid_scale: float = 1.0,
    **kwargs: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start of the fit from the known input: ``initial_points`` with s = the input's signed distance, c = 0.

    s is the exact signed distance, neither clipped nor scaled: marching tetrahedra places a vertex where s,
    interpolated linearly along an edge, vanishes, which is exactly on the surface wherever the surface is
    flat across the edge; a scaled or clipped s would move those vertices. Distances are in the same units as
    the positions, so the fit's step size on s (paper: 2e-3) moves surface vertices by about the same length,
    and far points with large |s| are never on an active edge. c = 0 makes the directional distance equal to s
    (1 + tanh(0) = 1). s is computed at the float32 positions that are returned, so that the state is
    consistent.

    With ``features`` and an input with sharp creases (``fit.features.detect_features``), part of the points
    are placed around the creases and corners so that no tet straddles a crease (``fit.features``), with s the
    distance to the face planes they see; shell points closer than CREASE_CLEARANCE spacings to a crease are
    dropped (they would make tets that see both faces). Inputs without creases get exactly the points of
    before.

    Args:
        vertices: (V,3) mesh vertices in the normalized frame.
        faces: (F,3) triangles.
        n: number of points.
        sh_degree: degree d (-1 = none, 0..3) of the SH coefficients, q = num_coeffs(d) per point.
        seed: seed of the numpy Generator that draws the points.
        features: place points around sharp creases when the input has some.
        position_bits: the container's position grid, if known: feature points are snapped to its cell centres
            (``fit.features.snap_to_grid``), on the grid of the frame x grid_scale (``formats.quantize.Quantization``).
        **kwargs: forwarded to ``initial_points`` (shell, uniform_fraction, shell_gap).
    Returns:
        points (m,3) float32, s (m,) float32, c (m,q) float32 (zeros), m <= n; the first N_CORNERS points are
        the cube's corners, the feature points (if any) follow them.
    """
    points, s, c, _ = initial_state_pinned(
        vertices, faces, n, sh_degree, seed, features, position_bits, grid_scale, **kwargs
    )
    return points, s, c


def initial_state_pinned(
    vertices: np.ndarray,
    faces: np.ndarray,
    n: int,
    sh_degree: int,
    seed: int,
    features: bool = True,
    position_bits: int | None = None,
    grid_scale: float = 1.0,
    plane_distances: bool = False,
    detected: Features | None = None,
    tree: SurfaceTree | None = None,
    **kwargs: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``initial_state`` plus a (m,) bool mask of the feature points, which the fit keeps in place.

    With ``plane_distances`` (and feature points), every other point whose closest input point lies on a crease
    or a corner takes its plane distance (``fit.features.polyhedral_distance``) instead of the Euclidean one.
    detected: ``detect_features(vertices, faces)`` when the caller has it (used with ``features``); tree: a
    SurfaceTree of (vertices, faces) when the caller has one (fit.prepared: both computed once per encode)."""
    check_degree(sh_degree)  # ValueError
    rng = np.random.default_rng(seed)
    feat = (detected if detected is not None else detect_features(vertices, faces)) if features else None
    tree = SurfaceTree(vertices, faces) if tree is None else tree
    state = None
    if feat is not None and feat.found:
        state = _feature_state(
            vertices, faces, n, rng, feat, position_bits, grid_scale, tree, plane_distances, **kwargs
        )
    if state is None:
        points = initial_points(vertices, faces, n, rng, tree=tree, **kwargs).astype(np.float32)
        s = signed_distance(points, vertices, faces, tree).astype(np.float32)
        n_feat = 0
    else:
        points, s, n_feat = state
    s[s == 0] = MIN_ABS_S  # the outside sign
    c = np.zeros((len(points), num_coeffs(sh_degree)), dtype=np.float32)
    pinned = np.zeros(len(points), dtype=bool)
    pinned[N_CORNERS : N_CORNERS + n_feat] = True
    return points, s, c, pinned


def _feature_state(
    vertices: np.ndarray,
    faces: np.ndarray,
    n: int,
    rng: np.random.Generator,
    feat: Features,
    position_bits: int | None,
    grid_scale: float,
    tree: SurfaceTree,
    plane_distances: bool,
    **kwargs: float,
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """Feature points (with plane-distance s) + the usual layout minus shell points near creases.

    Returns points (m,3) float32, s (m,) float32 and the number of feature points (they follow the corners), or
    None when the feature points cannot fit into MAX_FEATURE_FRACTION of n (the caller starts without them)."""
    area = float(face_areas(vertices, faces).sum())
    spacing = CREASE_SPACING * math.sqrt(area / max(n, 1))
    fpts, fs, planes = feature_points(feat, spacing)
    budget = MAX_FEATURE_FRACTION * n
    for _ in range(MAX_SPACING_STEPS):
        if len(fpts) <= budget:
            break
        spacing *= math.sqrt(len(fpts) / budget)
        fpts, fs, planes = feature_points(feat, spacing)
    if len(fpts) > budget:
        # Many corners and few points: the corners' pairs alone exceed the budget (a wider spacing removes none
        # of them; this loop once ran forever there). Part of the corners would be worse than none: a start
        # with the pairs of only some corners lost the whole surface of three boxes at 128 points.
        return None
    if position_bits is not None:
        fpts, fs = snap_to_grid(fpts, fs, planes, position_bits, grid_scale)
    # A point can see its planes from the wrong side (saddle corners, thin parts, a face pair reaching into
    # another part of the shape): keep only those whose plane distance has the input's sign.
    agree = np.sign(fs) == np.sign(signed_distance(fpts, vertices, faces, tree))
    fpts, fs = fpts[agree], fs[agree]
    rest = initial_points(vertices, faces, max(n - len(fpts), N_CORNERS + 1), rng, tree=tree, **kwargs)
    far = crease_distance(feat, rest) >= CREASE_CLEARANCE * spacing
    far[:N_CORNERS] = True
    rest = rest[far]
    points = np.concatenate([rest[:N_CORNERS], fpts, rest[N_CORNERS:]]).astype(np.float32)
    points = _separate_duplicates(points, rng, scale=1e-4 * spacing).astype(np.float32)
    s = signed_distance(points, vertices, faces, tree)
    if plane_distances:
        s = polyhedral_distance(feat, points, s)
    s[N_CORNERS : N_CORNERS + len(fpts)] = fs
    return points, s.astype(np.float32), len(fpts)


def random_state(
    n: int, sh_degree: int, seed: int, radius: float = math.sqrt(3.0), sdf: str = "random"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The paper's initialization (Appendix A and its reference code), for comparison.

    Points uniform in the ball of radius sqrt(3) (the cube [-1, 1]^3's circumscribed ball): a uniform
    direction times radius * U^(1/3). s as in the reference code, ``sdf="random"``: U[0, 1) - 0.1, i.e. about
    10 % of the points inside at random; or ``sdf="sphere"``: |p| - 0.5, a sphere guess. c = 0.

    Args:
        n: number of points.
        sh_degree: SH degree d (-1 = none, 0..3), q = num_coeffs(d).
        seed: seed of the numpy Generator.
        radius: radius of the ball.
        sdf: ``"random"`` or ``"sphere"``.
    Returns:
        points (n,3) float32, s (n,) float32, c (n,q) float32 (zeros).
    """
    check_degree(sh_degree)  # ValueError
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = direction * (radius * rng.random(n) ** (1.0 / 3.0))[:, None]
    points = _separate_duplicates(points, rng, scale=1e-6).astype(np.float32)
    if sdf == "random":
        s = rng.random(n) - 0.1
    elif sdf == "sphere":
        s = np.linalg.norm(points.astype(np.float64), axis=1) - 0.5
    else:
        raise ValueError(f"sdf must be 'random' or 'sphere', got {sdf!r}")
    s = s.astype(np.float32)
    s[s == 0] = MIN_ABS_S
    c = np.zeros((n, num_coeffs(sh_degree)), dtype=np.float32)
    return points, s, c
