"""Metrics on shapes with known answers: a mesh against itself, concentric spheres, tilted and offset planes,
single triangles, boxes with holes, flipped faces, bow-ties, crossing triangles."""

from __future__ import annotations

import math

import manifold3d
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tetweave_codec.geometry.intersections import self_intersecting_faces
from tetweave_codec.metrics.common import MetricOptions
from tetweave_codec.metrics.fidelity import chamfer_distance, fidelity, prepare_mesh, prepare_reference
from tetweave_codec.metrics.manifold import topology
from tetweave_codec.metrics.quality import triangle_quality
from tetweave_codec.metrics.summary import evaluate, mesh_report

# 20K samples are ~0.03 apart on a [-0.9, 0.9]^3 box: widen the crease search accordingly
FAST = MetricOptions(n_samples=20_000, edge_radius=0.06)


def _mesh(solid: manifold3d.Manifold) -> tuple[np.ndarray, np.ndarray]:
    m = solid.to_mesh()
    return np.asarray(m.vert_properties, dtype=np.float64)[:, :3], np.asarray(m.tri_verts, dtype=np.int64)


def sphere(radius: float = 1.0, segments: int = 48):
    return _mesh(manifold3d.Manifold.sphere(radius, segments))


def box(size=(1.0, 1.0, 1.0), center=(0.0, 0.0, 0.0)):
    v, f = _mesh(manifold3d.Manifold.cube(list(size), center=True))
    return v + np.asarray(center), f


def square(n: int = 8, size: float = 2.0):
    """A flat n x n grid in the z = 0 plane, [-size/2, size/2]^2, faces pointing +z."""
    t = np.linspace(-size / 2, size / 2, n + 1)
    x, y = np.meshgrid(t, t, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    i = i.ravel()
    f = np.concatenate([np.stack([i, i + n + 1, i + n + 2], 1), np.stack([i, i + n + 2, i + 1], 1)])
    return v, f


# ----------------------------------------------------------------------------------------------------------
# Fidelity
# ----------------------------------------------------------------------------------------------------------


def test_mesh_against_itself_is_perfect():
    v, f = box()
    r = evaluate(prepare_reference(v, f, FAST), v, f, FAST)
    assert r["chamfer"] == pytest.approx(0.0, abs=1e-12)
    assert r["hausdorff"] == pytest.approx(0.0, abs=1e-12)
    assert r["f1@0.001"] == 1.0 and r["f1@0.005"] == 1.0
    assert r["normal_consistency"] == pytest.approx(1.0)
    assert r["inaccurate_normals_pct"] == 0.0
    assert r["edge_chamfer"] == pytest.approx(0.0, abs=1e-12) and r["edge_f1"] == 1.0
    assert r["watertight"] and r["two_manifold"] and r["manifold3d_ok"]
    assert r["self_intersect_pct"] == 0.0


def test_sphere_against_scaled_sphere_is_the_radius_difference():
    v, f = sphere(1.0)
    # the same tessellation scaled about the centre: each face moves along its normal by 0.05 * its distance
    cd = chamfer_distance(v, f, 1.05 * v, f, n_samples=20_000, normalize=False)
    assert cd == pytest.approx(0.05, rel=0.01)
    # normalized: the first sphere's bbox (longest side ~2) becomes 1.8, so distances scale by 1.8 / side
    side = float((v.max(0) - v.min(0)).max())
    assert chamfer_distance(v, f, 1.05 * v, f, n_samples=20_000) == pytest.approx(0.05 * 1.8 / side, rel=0.01)
    r = evaluate(prepare_reference(v, f, FAST), 1.05 * v, f, FAST)
    assert r["hausdorff"] == pytest.approx(0.05 * 1.8 / side, rel=0.01)
    assert r["f1@0.001"] == 0.0 and r["f1@0.005"] == 0.0


def test_sphere_against_independent_tessellation():
    """A finer sphere of radius 1.02: the Chamfer is the radius gap up to the coarse mesh's chord error."""
    v, f = sphere(1.0, 96)
    v2, f2 = sphere(1.02, 128)
    cd = chamfer_distance(v, f, v2, f2, n_samples=50_000, normalize=False)
    assert 0.017 < cd < 0.023


def test_chamfer_is_symmetric_deterministic_and_similarity_invariant():
    va, fa = sphere(1.0, 32)
    vb, fb = box((1.6, 1.6, 1.6))
    ab = chamfer_distance(va, fa, vb, fb, n_samples=10_000, seed=3)
    assert ab == chamfer_distance(va, fa, vb, fb, n_samples=10_000, seed=3)
    raw_ab = chamfer_distance(va, fa, vb, fb, n_samples=10_000, seed=3, normalize=False)
    assert raw_ab == chamfer_distance(vb, fb, va, fa, n_samples=10_000, seed=3, normalize=False)
    assert ab == pytest.approx(raw_ab / (float((va.max(0) - va.min(0)).max()) / 1.8))
    # normalized: moving and scaling both meshes together changes nothing
    moved = chamfer_distance(7.0 * va + 3.0, fa, 7.0 * vb + 3.0, fb, n_samples=10_000, seed=3)
    assert moved == pytest.approx(ab, rel=1e-9)
    assert chamfer_distance(va, fa, vb, fb, n_samples=10_000, seed=4) == pytest.approx(ab, rel=0.02)


def test_chamfer_uses_the_first_mesh_frame():
    """The decoded mesh is normalized with the input's transform: a shift is measured, not normalized away."""
    v, f = box((1.8, 1.8, 1.8))  # already in the normalized frame
    shifted = v + np.array([0.01, 0.0, 0.0])
    cd = chamfer_distance(v, f, shifted, f, n_samples=20_000)
    # only the two x faces (1/3 of the area) are 0.01 away; the other faces slide within their planes
    assert cd == pytest.approx(0.01 / 3, rel=0.05)


def test_tilted_plane_normals_and_offset_plane_f1():
    v, f = square()
    for deg, inaccurate in ((3.0, 0.0), (10.0, 100.0)):
        t = math.radians(deg)
        rot = np.array([[1, 0, 0], [0, math.cos(t), -math.sin(t)], [0, math.sin(t), math.cos(t)]])
        a, b = prepare_mesh(v, f, FAST), prepare_mesh(v @ rot.T, f, FAST)
        r = fidelity(a, b, FAST)
        assert r["normal_consistency"] == pytest.approx(math.cos(t), abs=1e-9)
        assert r["inaccurate_normals_pct"] == inaccurate
    a, b = prepare_mesh(v, f, FAST), prepare_mesh(v + [0.0, 0.0, 0.003], f, FAST)
    r = fidelity(a, b, FAST)
    assert r["chamfer"] == pytest.approx(0.003) and r["hausdorff"] == pytest.approx(0.003)
    assert r["f1@0.001"] == 0.0 and r["f1@0.005"] == 1.0


def test_hausdorff_catches_a_single_raised_vertex():
    v, f = square(8)
    raised = v.copy()
    centre = np.argmin(np.linalg.norm(v, axis=1))
    raised[centre, 2] = 0.2
    r = fidelity(prepare_mesh(v, f, FAST), prepare_mesh(raised, f, FAST), FAST)
    assert r["hausdorff"] == pytest.approx(0.2, abs=1e-9)
    assert 0 < r["chamfer"] < 0.01


def test_edge_points_lie_on_the_box_creases():
    v, f = box((1.8, 1.8, 1.8))
    mesh = prepare_mesh(v, f, FAST)
    edge = mesh.points[mesh.edge_mask]
    band = 12 * 1.8 * 2 * FAST.edge_radius / (6 * 1.8**2)  # area within edge_radius of a crease / total area
    assert 0.5 * band < len(edge) / len(mesh.points) < 1.05 * band
    near_face = np.abs(edge) > 0.9 - FAST.edge_radius - 1e-9
    assert np.all(near_face.sum(axis=1) >= 2)  # within edge_radius of two faces: next to a crease
    assert not prepare_mesh(*sphere(), FAST).edge_mask.any()  # smooth: no crease


def test_edge_metrics_sharp_against_smooth():
    vb, fb = box((1.8, 1.8, 1.8))
    vs, fs = sphere(1.0, 48)
    a, b = prepare_mesh(vb, fb, FAST), prepare_mesh(vs, fs, FAST)
    r = fidelity(a, b, FAST)
    assert r["edge_chamfer"] == math.inf and r["edge_f1"] == 0.0  # the sphere lost every crease
    r = fidelity(b, a, FAST)
    assert r["edge_chamfer"] == 0.0 and r["edge_f1"] == 1.0  # nothing to reproduce
    # a slightly shrunk box keeps its creases: edge distance ~ the shift of the crease lines
    c = prepare_mesh(0.99 * vb, fb, FAST)
    r = fidelity(a, c, FAST)
    assert 0.003 < r["edge_chamfer"] < 0.02 and r["edge_f1"] == 0.0
    r = fidelity(a, prepare_mesh(0.999 * vb, fb, FAST), FAST)
    assert r["edge_chamfer"] < 0.002 and r["edge_f1"] == 1.0


# ----------------------------------------------------------------------------------------------------------
# Triangle quality
# ----------------------------------------------------------------------------------------------------------

EQUILATERAL = np.array([[0, 0, 0], [1, 0, 0], [0.5, math.sqrt(3) / 2, 0]])
RIGHT_ISOSCELES = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
NEEDLE = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.05, 0]])  # base 1, height 0.05


@pytest.mark.parametrize(
    ("tri", "aspect", "radius", "angle"),
    [
        (EQUILATERAL, 2 / math.sqrt(3), 2.0, 60.0),
        (RIGHT_ISOSCELES, 2.0, 1 + math.sqrt(2), 45.0),
        (NEEDLE, 20.0, None, math.degrees(math.atan(0.1))),
    ],
)
def test_single_triangle_quality(tri, aspect, radius, angle):
    q = triangle_quality(tri, np.array([[0, 1, 2]]))
    assert q["aspect_ratio"][0] == pytest.approx(aspect)
    if radius is None:  # R/r from the side lengths a = 1, b = c = sqrt(0.25 + 0.0025)
        b = math.hypot(0.5, 0.05)
        area, s = 0.025, (1 + 2 * b) / 2
        radius = (1 * b * b / (4 * area)) / (area / s)
    assert q["radius_ratio"][0] == pytest.approx(radius)
    assert q["min_angle_deg"][0] == pytest.approx(angle)


def test_degenerate_triangle_is_worst_quality():
    q = triangle_quality(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float), np.array([[0, 1, 2]]))
    assert q["aspect_ratio"][0] == math.inf and q["radius_ratio"][0] == math.inf and q["min_angle_deg"][0] == 0


def test_quality_percentages():
    v = np.concatenate([EQUILATERAL, NEEDLE + [0, 0, 1], RIGHT_ISOSCELES + [0, 0, 2]])
    f = np.arange(9).reshape(3, 3)
    r = mesh_report(v, f)
    assert r["aspect_ratio_gt4_pct"] == pytest.approx(100 / 3)
    assert r["radius_ratio_gt4_pct"] == pytest.approx(100 / 3)
    assert r["small_angle_lt10_pct"] == pytest.approx(100 / 3)
    assert r["n_vertices"] == 9 and r["n_faces"] == 3


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-10, 10, allow_nan=False), min_size=9, max_size=9),
    st.floats(0.01, 100),
)
def test_quality_is_similarity_invariant_and_bounded_by_equilateral(coords, scale):
    tri = np.asarray(coords).reshape(3, 3)
    q = triangle_quality(tri, np.array([[0, 1, 2]]))
    if not np.isfinite(q["aspect_ratio"][0]) or q["aspect_ratio"][0] > 1e6:
        return  # (near-)degenerate: invariance is ill-conditioned
    assert q["aspect_ratio"][0] >= 2 / math.sqrt(3) - 1e-9
    assert q["radius_ratio"][0] >= 2.0 - 1e-9
    assert 0 <= q["min_angle_deg"][0] <= 60.0 + 1e-9
    rot, _ = np.linalg.qr(np.array([[1.0, 2, 3], [0, 1, 4], [5, 6, 0]]))
    q2 = triangle_quality(scale * tri @ rot.T + 1.5, np.array([[0, 1, 2]]))
    for key in q:
        assert q2[key][0] == pytest.approx(q[key][0], rel=1e-6)


# ----------------------------------------------------------------------------------------------------------
# Topology
# ----------------------------------------------------------------------------------------------------------


def test_closed_box_is_watertight():
    t = topology(*box())
    assert t["watertight"] and t["two_manifold"] and t["oriented"] and t["manifold3d_ok"]
    assert t["boundary_edges"] == 0 and t["nonmanifold_edges"] == 0


def test_mesh_with_a_hole_is_not_watertight():
    v, f = sphere(1.0, 24)
    t = topology(v, f[1:])
    assert not t["watertight"] and not t["manifold3d_ok"]
    assert t["two_manifold"] and t["boundary_edges"] == 3


def test_flipped_face_is_not_oriented():
    v, f = box()
    f = f.copy()
    f[0] = f[0, ::-1]
    t = topology(v, f)
    assert not t["oriented"] and not t["watertight"] and not t["manifold3d_ok"]
    assert t["two_manifold"] and t["boundary_edges"] == 0


def test_bow_tie_vertex_and_fin_edge_are_not_manifold():
    va, fa = box()
    vb, fb = box(center=(1.0, 1.0, 1.0))  # touches the first box at the corner (0.5, 0.5, 0.5)
    corner_b = np.argmin(np.linalg.norm(vb - 0.5, axis=1))
    corner_a = np.argmin(np.linalg.norm(va - 0.5, axis=1))
    fb2 = fb + len(va)
    fb2[fb == corner_b] = corner_a  # weld the two boxes at one vertex
    t = topology(np.concatenate([va, vb]), np.concatenate([fa, fb2]))
    assert t["nonmanifold_edges"] == 0 and not t["two_manifold"] and not t["watertight"]
    fin = np.concatenate([fa, [[fa[0, 0], fa[0, 1], len(va)]]])  # a third face on an existing edge
    t = topology(np.concatenate([va, [[3.0, 3.0, 3.0]]]), fin)
    assert t["nonmanifold_edges"] == 1 and not t["two_manifold"]


def test_unwelded_mesh_is_not_watertight():
    v, f = box()
    soup_v = v[f].reshape(-1, 3)
    t = topology(soup_v, np.arange(len(soup_v)).reshape(-1, 3))
    assert not t["watertight"] and t["boundary_edges"] == 3 * len(f)


# ----------------------------------------------------------------------------------------------------------
# Self-intersections
# ----------------------------------------------------------------------------------------------------------


def test_crossing_triangles_are_flagged():
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, -1], [0.5, 0.5, 1], [1.5, 1.5, 0.2]], float)
    assert self_intersecting_faces(v, np.array([[0, 1, 2], [3, 4, 5]])).tolist() == [True, True]
    far = v.copy()
    far[3:] += [5.0, 0, 0]
    assert not self_intersecting_faces(far, np.array([[0, 1, 2], [3, 4, 5]])).any()


def test_touching_is_flagged_and_adjacent_triangles_are_not():
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, 0], [0.5, 0.5, 1], [1.5, 0.5, 1]], float)
    # the second triangle touches the first one's interior at a vertex without crossing it: a contact counts
    # (issue 49; formats/README.md "Crossing faces")
    assert self_intersecting_faces(v, np.array([[0, 1, 2], [3, 4, 5]])).all()
    # fans around a shared vertex and pairs sharing an edge
    assert not self_intersecting_faces(*sphere(1.0, 32)).any()
    assert not self_intersecting_faces(*box()).any()


def test_fold_around_a_shared_vertex_is_flagged():
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [1.0, 0.3, -0.5], [0.3, 1.0, 0.5]], float)
    # both triangles use vertex 0; the second one's far edge (3, 4) pierces the first triangle
    assert self_intersecting_faces(v, np.array([[0, 1, 2], [0, 3, 4]])).tolist() == [True, True]


def test_coplanar_overlap_is_flagged():
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0.5, 0.5, 0], [2.5, 0.5, 0], [0.5, 2.5, 0]], float)
    assert self_intersecting_faces(v, np.array([[0, 1, 2], [3, 4, 5]])).all()
    # an exact duplicate with its own vertices
    dup = np.concatenate([v[:3], v[:3]])
    assert self_intersecting_faces(dup, np.array([[0, 1, 2], [3, 4, 5]])).all()
    apart = v.copy()
    apart[3:] += [3.0, 0, 0]
    assert not self_intersecting_faces(apart, np.array([[0, 1, 2], [3, 4, 5]])).any()


def test_overlapping_boxes_flag_only_the_crossing_faces():
    va, fa = box()
    vb, fb = box(center=(0.5, 0.3, 0.2))
    v, f = np.concatenate([va, vb]), np.concatenate([fa, fb + len(va)])
    flagged = self_intersecting_faces(v, f)
    assert 0 < flagged.sum() < len(f)
    assert mesh_report(v, f)["self_intersect_pct"] == pytest.approx(100 * flagged.mean())
    # the faces of box A on its -x, -y, -z sides are far from box B
    far = np.all(va[fa][:, :, 0] < -0.4, axis=1)
    assert not flagged[: len(fa)][far].any()


def test_self_intersections_scale_to_a_dense_sphere():
    v, f = sphere(1.0, 512)  # 131K faces
    assert len(f) > 100_000
    assert not self_intersecting_faces(v, f).any()
