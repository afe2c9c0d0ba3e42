"""Fidelity of a decoded mesh against its input: Chamfer and Hausdorff distances, normals, F1, edge metrics.

Frame. Every distance is measured in the *normalized frame of the input*: the input is centred (bounding-box
centre) and scaled uniformly so that its longest bounding-box side is 1.8 (it fits [-0.9, 0.9]^3); the
decoded mesh is moved by the *same* transform (never by its own), so a decoded mesh that is shifted or scaled
is penalised. Distances are therefore in units of "1/1.8 of the input's longest side". `chamfer_distance(...,
normalize=False)` and the per-mesh helpers measure in whatever frame they are given.

Samples. A mesh is sampled with `n_samples` points, area-weighted (each triangle is picked with probability
proportional to its area, then a uniform point in it; `geometry.triangles.sample_surface`), from
`numpy.random.default_rng(seed)`. The same seed gives the same samples, so a mesh compared with itself gives
exactly 0 / 1 everywhere. Each sample carries the unit normal of the face it lies on.

Point-to-surface distance. d(p, M) is the exact Euclidean distance from point p to the closest point of the
triangles of M (libigl's AABB tree through `geometry.closest.SurfaceTree`; measured on Igea, 268K faces and 200K
queries: 0.85 s query + 0.25 s tree, exact, against 3.1 s and 1 wrong answer in 17K for a cKDTree over
triangle centroids with exact point-triangle distances to the 8 nearest candidates).

Fidelity metrics (A = input, B = decoded; S_A, S_B their sample sets; both directions are pooled or
averaged):

- ``chamfer``: CD = ½ (mean_{p∈S_A} d(p, B) + mean_{q∈S_B} d(q, A)), point-to-SURFACE (not squared).
  Sample-to-sample Chamfer has a noise floor (≈2e-3 at 200K samples) far above Draco's error at 11 bits, so
  it is never used here.
- ``hausdorff``: max(max_{p∈S_A ∪ V_A} d(p, B), max_{q∈S_B ∪ V_B} d(q, A)); V_* are the referenced vertices.
  A sampled lower bound of the true Hausdorff distance.
- ``normal_consistency``: NC = mean over S_A ∪ S_B of |n(p) · n(closest face of the other mesh)|,
  orientation-agnostic as in NDC / FlexiCubes (1 = perfect). Orientation is checked by ``oriented`` /
  ``watertight`` instead.
- ``inaccurate_normals_pct``: IN>5° = 100 · fraction of S_A ∪ S_B whose angle arccos(|n(p) · n(closest
  face)|) exceeds `normal_angle_deg` (5°).
- ``f1@τ`` for τ in `f1_thresholds` (0.001, 0.005): precision P = fraction of S_B with d(q, A) < τ, recall R
  = fraction of S_A with d(p, B) < τ, F1 = 2PR / (P + R) (0 when P + R = 0).
- ``edge_chamfer`` / ``edge_f1``: paper Appendix C. Edge points as in the reference implementation of NDC
  (Chen et al. 2022, ``eval_cd_nc_f1_ecd_ef1.py``, which the paper follows): a sample p is an *edge point*
  when some other sample of the same mesh within `edge_radius` (among its `edge_neighbors` nearest) has
  |n(p) · n(q)| < `edge_dot` (0.2, a crease sharper than ≈78°; the paper's text says "average dot product",
  NDC's code says "any neighbour", which we use). E_A, E_B are the edge points and EF(M) the *edge faces* of
  M, the faces that carry at least one of its edge points. ECD = ½ (mean_{p∈E_A} d(p, EF(B)) +
  mean_{q∈E_B} d(q, EF(A))), point-to-surface like the headline Chamfer; edge F1 as above from the same
  distances at `edge_f1_threshold` (0.005). When A has no edge points ECD = 0 and EF1 = 1 (NDC's
  convention); when only B has none, ECD = inf and EF1 = 0. Why not NDC's point-to-point distances between
  E_A and E_B: their sampling noise swamps the signal (fandisk against itself with another seed at 200K
  samples: ECD 3.1e-3, EF1 0.87, the same as Draco at 14 bits); point-to-edge-face distances give 5.8e-6 and
  0.9997 there, and 2.9e-5 / 2.0e-4 / 1.5e-3 for Draco at 14 / 11 / 8 bits. On smooth scans (Igea) only a
  few hundred samples are edge points and these two metrics are mostly noise. `edge_radius` (0.02) must
  exceed the sample spacing sqrt(area / n_samples) (≈0.01 at 200K samples on a [-0.9, 0.9]^3 box), else
  most samples have no neighbour to compare with; raise it when using fewer samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from tetweave_codec.geometry.closest import SurfaceTree
from tetweave_codec.geometry.triangles import face_normals, sample_surface
from tetweave_codec.metrics.common import MetricOptions, as_mesh, sorted_unique


@dataclass
class SampledMesh:
    """A mesh prepared for repeated point-to-surface queries, with its surface samples.

    vertices (V,3) float64, faces (F,3) int64, normals (F,3) unit face normals (0 for degenerate faces),
    points (n,3) samples, sample_faces (n,) face of each sample, edge_mask (n,) bool edge points (NDC test),
    tree: the closest-point tree over (vertices, faces).
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    points: np.ndarray
    sample_faces: np.ndarray
    edge_mask: np.ndarray
    tree: SurfaceTree


@dataclass
class Reference:
    """An input mesh prepared once for comparisons: sampled in its own normalized frame.

    `original = normalized * scale + offset`.
    """

    mesh: SampledMesh
    scale: float
    offset: np.ndarray


def normalization(vertices: np.ndarray) -> tuple[float, np.ndarray]:
    """(scale, offset) of `meshio.normalize`: `original = normalized * scale + offset` (bbox centre, longest
    side 1.8)."""
    from tetweave_codec.meshio import normalize

    _, scale, offset = normalize(np.asarray(vertices, dtype=np.float64))
    return float(scale), np.asarray(offset, dtype=np.float64)


def to_frame(vertices: np.ndarray, scale: float, offset: np.ndarray) -> np.ndarray:
    """Vertices (V,3) moved into the frame of (scale, offset): (vertices - offset) / scale, float64."""
    return (np.asarray(vertices, dtype=np.float64) - offset) / scale


def _edge_mask(points: np.ndarray, normals: np.ndarray, radius: float, dot: float, k: int) -> np.ndarray:
    """NDC edge points: some neighbour within `radius` (among the k nearest) has |n_p · n_q| < dot."""
    if len(points) < 2:
        return np.zeros(len(points), dtype=bool)
    k = min(k + 1, len(points))  # the query returns the point itself first
    dist, idx = cKDTree(points).query(points, k=k, distance_upper_bound=radius)
    valid = np.isfinite(dist)
    idx = np.where(valid, idx, 0)
    cos = np.abs(np.einsum("nd,nkd->nk", normals, normals[idx]))
    return np.any(valid & (cos < dot), axis=1)


def prepare_mesh(vertices: np.ndarray, faces: np.ndarray, options: MetricOptions | None = None) -> SampledMesh:
    """Sample a mesh (in the frame given) and build its AABB tree; see `SampledMesh`."""
    opts = options or MetricOptions()
    v, f = as_mesh(vertices, faces)
    normals = face_normals(v, f)
    points, sample_faces = sample_surface(v, f, opts.n_samples, opts.seed)
    edge = _edge_mask(points, normals[sample_faces], opts.edge_radius, opts.edge_dot, opts.edge_neighbors)
    tree = SurfaceTree(v, f)
    return SampledMesh(v, f, normals, points, sample_faces, edge, tree)


def prepare_reference(vertices: np.ndarray, faces: np.ndarray, options: MetricOptions | None = None) -> Reference:
    """Normalize an input mesh by its own transform and sample it (done once per input in a benchmark)."""
    scale, offset = normalization(vertices)
    return Reference(prepare_mesh(to_frame(vertices, scale, offset), faces, options), scale, offset)


def point_surface_distance(points: np.ndarray, mesh: SampledMesh) -> tuple[np.ndarray, np.ndarray]:
    """Exact distance (n,) from each point to the surface of `mesh`, and the closest face (n,) int64."""
    sq, face, _ = mesh.tree.query(points)
    return np.sqrt(np.maximum(sq, 0.0)), face


def chamfer_distance(
    va: np.ndarray,
    fa: np.ndarray,
    vb: np.ndarray,
    fb: np.ndarray,
    n_samples: int = 200_000,
    seed: int = 0,
    *,
    normalize: bool = True,
) -> float:
    """Symmetric point-to-surface Chamfer distance between meshes A (va (V,3), fa (F,3)) and B.

    ½ (mean over samples of A of their distance to B + mean over samples of B of their distance to A), with
    `n_samples` area-weighted samples per mesh. With `normalize` (default) both meshes are first moved by A's
    normalization (A's bbox into [-0.9, 0.9]^3), so the result is in A's normalized frame whatever A's units;
    otherwise it is in the frame given.
    """
    va, fa = as_mesh(va, fa)
    vb, fb = as_mesh(vb, fb)
    if normalize:
        scale, offset = normalization(va)
        va, vb = to_frame(va, scale, offset), to_frame(vb, scale, offset)
    return chamfer_to_reference(prepare_points(va, fa, n_samples, seed), vb, fb, n_samples, seed)


def chamfer_to_reference(a: SampledMesh, vb: np.ndarray, fb: np.ndarray, n_samples: int, seed: int = 0) -> float:
    """`chamfer_distance` between a mesh A prepared once (`prepare_points`, its samples and tree reused for every
    comparison: an encode's input) and mesh B (vb (V,3), fb (F,3)), both in the frame given; B is sampled with
    `n_samples` points from `seed`, as A was."""
    vb, fb = as_mesh(vb, fb)
    b = prepare_points(vb, fb, n_samples, seed)
    d_ab, _ = point_surface_distance(a.points, b)
    d_ba, _ = point_surface_distance(b.points, a)
    return float(0.5 * (d_ab.mean() + d_ba.mean()))


def prepare_points(
    vertices: np.ndarray, faces: np.ndarray, n_samples: int, seed: int = 0, tree: SurfaceTree | None = None
) -> SampledMesh:
    """A mesh (vertices (V,3), faces (F,3), in the frame given) with `n_samples` area-weighted samples from `seed`
    and its AABB tree (`tree` when the caller has one of these very arrays): one side of a Chamfer distance.
    No normals or edge points (see `prepare_mesh` for those)."""
    v, f = as_mesh(vertices, faces)
    points, sample_faces = sample_surface(v, f, n_samples, seed)
    empty = np.zeros(len(points), dtype=bool)
    return SampledMesh(v, f, np.zeros((0, 3)), points, sample_faces, empty, tree or SurfaceTree(v, f))


def _f1(precision: float, recall: float) -> float:
    return 0.0 if precision + recall == 0 else 2.0 * precision * recall / (precision + recall)


def _edge_faces_tree(mesh: SampledMesh) -> SampledMesh:
    """The sub-mesh of faces carrying at least one edge point, ready for point-to-surface queries."""
    faces = mesh.faces[sorted_unique(mesh.sample_faces[mesh.edge_mask])]
    tree = SurfaceTree(mesh.vertices, faces)
    empty = np.zeros(0, dtype=bool)
    return SampledMesh(mesh.vertices, faces, mesh.normals, np.zeros((0, 3)), np.zeros(0, np.int64), empty, tree)


def _edge_metrics(a: SampledMesh, b: SampledMesh, threshold: float) -> tuple[float, float]:
    ea, eb = a.points[a.edge_mask], b.points[b.edge_mask]
    if len(ea) == 0:
        return 0.0, 1.0
    if len(eb) == 0:
        return float("inf"), 0.0
    d_ab, _ = point_surface_distance(ea, _edge_faces_tree(b))
    d_ba, _ = point_surface_distance(eb, _edge_faces_tree(a))
    ecd = 0.5 * (d_ab.mean() + d_ba.mean())
    return float(ecd), _f1(float(np.mean(d_ba < threshold)), float(np.mean(d_ab < threshold)))


def fidelity(a: SampledMesh, b: SampledMesh, options: MetricOptions | None = None) -> dict[str, float]:
    """Fidelity of B (decoded) against A (reference), both already in one frame (see the module docstring)."""
    opts = options or MetricOptions()
    d_ab, face_ab = point_surface_distance(a.points, b)
    d_ba, face_ba = point_surface_distance(b.points, a)
    hausdorff = max(d_ab.max(), d_ba.max())
    if opts.hausdorff_vertices:
        for src, dst in ((a, b), (b, a)):
            used = sorted_unique(src.faces)
            hausdorff = max(hausdorff, point_surface_distance(src.vertices[used], dst)[0].max())
    cos = np.abs(
        np.concatenate(
            [
                np.einsum("nd,nd->n", a.normals[a.sample_faces], b.normals[face_ab]),
                np.einsum("nd,nd->n", b.normals[b.sample_faces], a.normals[face_ba]),
            ]
        )
    )
    out = {
        "chamfer": float(0.5 * (d_ab.mean() + d_ba.mean())),
        "hausdorff": float(hausdorff),
        "normal_consistency": float(cos.mean()),
        "inaccurate_normals_pct": float(100.0 * np.mean(cos < np.cos(np.radians(opts.normal_angle_deg)))),
    }
    for tau in opts.f1_thresholds:
        out[f"f1@{tau:g}"] = _f1(float(np.mean(d_ba < tau)), float(np.mean(d_ab < tau)))
    out["edge_chamfer"], out["edge_f1"] = _edge_metrics(a, b, opts.edge_f1_threshold)
    return out
