"""geometry.closest: SurfaceTree gives libigl's exact answers in the caller's order, whatever the batch size."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from tetweave_codec.geometry.closest import PAD_FROM, PARALLEL_MIN_QUERIES, SurfaceTree
from tetweave_codec.geometry.triangles import closest_on_triangles


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def _igl(v, f, p):
    import igl

    tree = igl.AABB()
    tree.init(v, f)
    sq, face, cp = tree.squared_distance(v, f, np.ascontiguousarray(p, np.float64))
    return np.asarray(sq).reshape(-1), np.asarray(face, np.int64).reshape(-1), np.asarray(cp).reshape(-1, 3)


@pytest.mark.parametrize("n", [0, 1, 2, 37, PAD_FROM, PARALLEL_MIN_QUERIES - 1, PARALLEL_MIN_QUERIES + 5])
def test_same_answers_as_libigl_in_caller_order(sphere, n):
    v, f = sphere
    p = np.random.default_rng(n).normal(size=(n, 3)) * 1.5
    sq, face, cp = SurfaceTree(v, f).query(p)
    assert sq.shape == (n,) and face.shape == (n,) and cp.shape == (n, 3) and face.dtype == np.int64
    if n == 0:
        return
    ref_sq, ref_face, ref_cp = _igl(v, f, p)
    np.testing.assert_array_equal(sq, ref_sq)
    np.testing.assert_array_equal(cp, ref_cp)
    np.testing.assert_array_equal(face, ref_face)  # each answer depends on its point alone, ties included


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-3, 3)] * 3), min_size=1, max_size=40))
def test_distances_match_brute_force(points):
    # two triangles: distances checked against a brute-force point-triangle distance
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float64)
    f = np.array([[0, 1, 2], [0, 3, 1]], np.int64)
    p = np.array(points, np.float64)
    sq, _, _ = SurfaceTree(v, f).query(p)
    dist = np.array([min(_point_triangle(q, v[t]) for t in f) for q in p])
    np.testing.assert_allclose(np.sqrt(sq), dist, atol=1e-9)


def _point_triangle(q: np.ndarray, tri: np.ndarray) -> float:
    """Distance from q to a triangle: the plane foot if inside, else the nearest of the three edges."""
    a, b, c = tri
    n = np.cross(b - a, c - a)
    foot = q - np.dot(q - a, n) / np.dot(n, n) * n
    inside = all(np.dot(np.cross(y - x, foot - x), n) >= 0 for x, y in ((a, b), (b, c), (c, a)))
    if inside:
        return float(np.linalg.norm(q - foot))
    seg = []
    for x, y in ((a, b), (b, c), (c, a)):
        t = np.clip(np.dot(q - x, y - x) / np.dot(y - x, y - x), 0.0, 1.0)
        seg.append(np.linalg.norm(q - (x + t * (y - x))))
    return float(min(seg))


def test_a_mesh_without_faces_is_an_error_not_a_crash():
    tree = SurfaceTree(np.zeros((3, 3)), np.zeros((0, 3), np.int64))
    assert tree.query(np.zeros((0, 3)))[0].shape == (0,)
    with pytest.raises(ValueError, match="without faces"):
        tree.query(np.ones((2, 3)))


def test_identical_points_and_a_flat_batch(sphere):
    v, f = sphere
    p = np.tile([[0.3, -0.2, 2.0]], (5, 1))  # zero-extent box: the order falls back to the identity
    sq, face, cp = SurfaceTree(v, f).query(p)
    assert np.all(sq == sq[0]) and np.all(face == face[0]) and np.all(cp == cp[0])


def test_a_tree_without_faces_is_an_error_not_a_crash():
    tree = SurfaceTree(np.zeros((3, 3)), np.zeros((0, 3), np.int64))
    assert tree.query(np.zeros((0, 3)))[0].shape == (0,)
    with pytest.raises(ValueError, match="without faces"):
        tree.query(np.ones((2, 3)))


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(-3, 3), min_size=9, max_size=9),
    st.lists(st.tuples(*[st.floats(-3, 3)] * 3), min_size=1, max_size=20),
)
def test_closest_on_triangles_matches_brute_force(corners, points):
    tri = np.array(corners, np.float64).reshape(3, 3)
    if np.linalg.norm(np.cross(tri[1] - tri[0], tri[2] - tri[0])) < 1e-6:
        return  # the brute force's plane foot needs a proper triangle
    p = np.array(points, np.float64)
    cp, bary = closest_on_triangles(p, np.repeat(tri[None], len(p), axis=0))
    dist = np.array([_point_triangle(q, tri) for q in p])
    np.testing.assert_allclose(np.linalg.norm(p - cp, axis=1), dist, atol=1e-9)
    assert np.all(bary >= -1e-12) and np.allclose(bary.sum(1), 1.0)
    np.testing.assert_allclose(bary @ tri, cp, atol=1e-12)


def test_closest_on_degenerate_triangles_stays_on_them():
    tri = np.array([[[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 0, 0], [0, 0, 0], [0, 0, 0]]], np.float64)
    cp, bary = closest_on_triangles(np.array([[1.5, 1.0, 0.0], [1.0, 1.0, 1.0]]), tri)
    np.testing.assert_allclose(cp, [[1.5, 0, 0], [0, 0, 0]], atol=1e-12)
    assert np.all(np.isfinite(bary)) and np.allclose(bary.sum(1), 1.0)
