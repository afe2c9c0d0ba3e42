"""Closest points on a triangle mesh: one home for the bounding-volume trees every distance query uses.

`SurfaceTree` (libigl's AABB tree, float64) is exact and serves the metrics, the initialization and the fit's
input surface. `FitSurfaceTree` serves the fit's *current* mesh, rebuilt whenever marching tets changes its faces
(hundreds of times per encode): FCPW's float32 BVH builds 4x faster than libigl's tree (a 74K-face mesh: 13 ms
against 52 ms, one thread) and picks the closest face; the closest point and its distance are then computed in
float64 on that face. Float32 can pick a face whose distance is within ~1e-7 (relative) of the closest one, an
error far below anything the fit resolves; the metrics never use it. FCPW is an optional dependency (the `fast`
extra: it has no wheel for every platform and Python); without it `FitSurfaceTree` is libigl's exact tree.

`SurfaceTree(vertices (V,3), faces (F,3))` builds the tree once; `query(points (n,3))` returns the squared distance
(n,), the closest face (n,) int64 and the closest point (n,3) of each query point, exactly as
`igl.AABB.squared_distance` would, in the caller's order. Two things make the same answers cheaper:

* queries run in Morton order of the points (then scattered back), so that consecutive queries share their walk
  down the tree: a random order took 1.9x the time of a spatially sorted one on Igea (268K faces, 34K points near
  the surface, 2 threads);
* libigl runs a batch in parallel only from `PARALLEL_MIN_QUERIES` points on (igl::parallel_for's threshold),
  so a batch of `PAD_FROM` points or more is padded with copies of its last point up to that count: 8,000 points
  ran serially at 1.75 us each, 10,001 in parallel at 0.97 us on 2 cores (9.7 ms in all, what ~5,600 serial
  queries cost: smaller batches are faster unpadded). The padding's answers are dropped.

Each point's answer is independent of the others, so neither changes a result.
"""

from __future__ import annotations

import numpy as np

from tetweave_codec.formats.quantize import morton_keys
from tetweave_codec.geometry.triangles import closest_on_triangles

# Batches below this many points run on one thread in libigl (igl::parallel_for's min_parallel in AABB).
PARALLEL_MIN_QUERIES = 10_001
# Smallest batch worth padding to PARALLEL_MIN_QUERIES (see the module docstring).
PAD_FROM = 5_600
# Morton cells per axis over the query points' bounding box; finer gains nothing once a cell holds a few points.
_ORDER_CELLS = 1024


class SurfaceTree:
    """An AABB tree of a triangle mesh: vertices (V,3) float64 and faces (F,3) int64, kept as given."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        import igl

        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
        self._tree = igl.AABB()
        self._tree.init(self.vertices, self.faces)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Squared distance (n,), closest face (n,) int64 and closest point (n,3) on the mesh of each of points
        (n,3), in the order given. ValueError when the mesh has no faces."""
        p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        n = len(p)
        if n == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        if len(self.faces) == 0:  # libigl's query of an empty tree crashes the process
            raise ValueError("cannot find closest points on a mesh without faces")
        order = _spatial_order(p)
        batch = p[order]
        if PAD_FROM <= n < PARALLEL_MIN_QUERIES:
            batch = np.concatenate([batch, np.repeat(batch[-1:], PARALLEL_MIN_QUERIES - n, axis=0)])
        sq, face, closest = self._tree.squared_distance(self.vertices, self.faces, batch)
        out_sq = np.empty(n)
        out_face = np.empty(n, dtype=np.int64)
        out_closest = np.empty((n, 3))
        out_sq[order] = np.asarray(sq).reshape(-1)[:n]
        out_face[order] = np.asarray(face, dtype=np.int64).reshape(-1)[:n]
        out_closest[order] = np.asarray(closest).reshape(-1, 3)[:n]
        return out_sq, out_face, out_closest


class FitSurfaceTree:
    """A float32 BVH (FCPW) of a triangle mesh, vertices (V,3) and faces (F,3) kept as given (float64, int64).

    `query` answers like `SurfaceTree.query`: squared distance (n,), closest face (n,) int64 and closest point (n,3),
    the last two computed in float64 on the face the BVH found (see the module docstring).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
        fcpw = self._fcpw = fcpw_module()
        self._exact = SurfaceTree(self.vertices, self.faces) if fcpw is None else None
        if fcpw is None:
            return
        self._scene = fcpw.scene_3D()
        if len(self.faces):
            self._scene.set_object_count(1)
            self._scene.set_object_vertices(np.asfortranarray(self.vertices, dtype=np.float32), 0)
            self._scene.set_object_triangles(np.asfortranarray(self.faces, dtype=np.int32), 0)
            # the centre split of the longest axis: 2.3x faster to build than the surface-area heuristics, whose
            # faster queries do not pay for it at a few thousand queries per tree
            self._scene.build(fcpw.aggregate_type.bvh_longest_axis_center, True)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Squared distance (n,), closest face (n,) int64 and closest point (n,3) on the mesh of each of points
        (n,3), in the order given. ValueError when the mesh has no faces."""
        if self._exact is not None:
            return self._exact.query(points)
        p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        n = len(p)
        if n == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        if len(self.faces) == 0:
            raise ValueError("cannot find closest points on a mesh without faces")
        found = self._fcpw.interaction_3D_list()
        self._scene.find_closest_points(np.asfortranarray(p, dtype=np.float32), np.full(n, np.inf, np.float32), found)
        face = np.fromiter((i.primitive_index for i in found), dtype=np.int64, count=n)
        if face.min() < 0 or face.max() >= len(self.faces):  # FCPW found nothing (NaN, infinity): the exact tree
            return SurfaceTree(self.vertices, self.faces).query(p)
        closest, _ = closest_on_triangles(p, self.vertices[self.faces[face]])
        return ((p - closest) ** 2).sum(1), face, closest


def fcpw_module():
    """The `fcpw` module, or None when it is not installed (or too old to have the API used here)."""
    try:
        import fcpw
    except ImportError:
        return None
    needed = ("scene_3D", "interaction_3D_list", "aggregate_type")
    if not all(hasattr(fcpw, name) for name in needed) or not hasattr(fcpw.aggregate_type, "bvh_longest_axis_center"):
        return None
    return fcpw


def _spatial_order(points: np.ndarray) -> np.ndarray:
    """Permutation (n,) putting points (n,3) in Morton order of a _ORDER_CELLS^3 grid over their bounding box."""
    lo = points.min(0)
    span = float((points.max(0) - lo).max())
    if not np.isfinite(span) or span <= 0:
        return np.arange(len(points))
    cells = ((points - lo) * ((_ORDER_CELLS - 1) / span)).astype(np.int64)
    return np.argsort(morton_keys(cells), kind="stable")
