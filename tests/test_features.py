"""Tests of tetweave_codec.fit.features: crease detection, feature points and the feature-aware start."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tetweave_codec.decoder import mesh_from_points
from tetweave_codec.fit import features as fe
from tetweave_codec.fit import initialize as ini
from tetweave_codec.meshio import normalize

manifold3d = pytest.importorskip("manifold3d")

# Chamfer bound of the small cube fit below (512 points, "fast", 40 iterations): between the feature-aware fit
# and the plain one.
CUBE_CHAMFER_BOUND = 5e-3


def _mesh(solid) -> tuple[np.ndarray, np.ndarray]:
    m = solid.to_mesh()
    return np.asarray(m.vert_properties[:, :3], np.float64), np.asarray(m.tri_verts, np.int64)


def _normalized(solid) -> tuple[np.ndarray, np.ndarray]:
    v, f = _mesh(solid)
    return normalize(v)[0], f


_CUBE = _normalized(manifold3d.Manifold.cube([1.0, 1.0, 1.0], center=True))


@pytest.fixture(scope="module")
def cube():
    """The unit cube in the fit's normalized frame: [-0.9, 0.9]^3."""
    v, f = _mesh(manifold3d.Manifold.cube([1.0, 1.0, 1.0], center=True))
    return normalize(v)[0], f


def _cube_error(vertices: np.ndarray, reduce=np.max) -> float:
    """Largest (or mean) distance of points (V,3) from the surface of [-0.9, 0.9]^3 (points on or near it)."""
    return float(reduce(np.abs(np.abs(vertices).max(1) - 0.9)))


def test_detect_cube_creases(cube):
    feat = fe.detect_features(*cube)
    assert len(feat.edges) == 12 and len(feat.corners) == 8
    assert feat.found and feat.length == pytest.approx(12 * 1.8, rel=1e-6)
    # each corner sees three face planes, the axes
    for normals in feat.corner_normals:
        assert len(normals) == 3
        np.testing.assert_allclose(np.abs(normals).sum(0), 1.0, atol=1e-6)
    # the dihedral threshold: the cube's creases are 90 degrees
    assert len(fe.detect_features(*cube, angle_deg=95.0).edges) == 0


def test_crease_density_separates_polyhedra_from_curved_parts(cube):
    # a cube: 12 edges of 1.8 over sqrt(6 x 1.8^2)
    assert fe.crease_density(fe.detect_features(*cube), *cube) == pytest.approx(12 / np.sqrt(6), rel=1e-6)
    # a cylinder as tall as it is wide: two rims of 2 pi r over sqrt(6 pi r^2), less the facets' rounding
    cyl = _normalized(manifold3d.Manifold.cylinder(2.0, 1.0, 1.0, 96, True))
    assert fe.crease_density(fe.detect_features(*cyl), *cyl) == pytest.approx(4 * np.pi / np.sqrt(6 * np.pi), rel=0.01)
    sphere = trimesh.creation.icosphere(subdivisions=3)
    flat = fe.detect_features(np.asarray(sphere.vertices), np.asarray(sphere.faces))
    assert fe.crease_density(flat, sphere.vertices, sphere.faces) == 0.0


def test_no_creases_on_smooth_shapes():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
    feat = fe.detect_features(np.asarray(sphere.vertices), np.asarray(sphere.faces))
    assert len(feat.edges) == 0 and not feat.found
    # a spike makes a few sharp edges, but a feature-aware start needs long crease chains: still none
    fine = trimesh.creation.icosphere(subdivisions=4, radius=0.8)
    spiked = np.asarray(fine.vertices).copy()
    spiked[0] *= 1.1  # 10 sharp edges, 0.82 long in all
    assert len(fe.detect_features(spiked, np.asarray(fine.faces), min_chain_length=0.0).edges) > 0
    feat = fe.detect_features(spiked, np.asarray(fine.faces))
    assert len(feat.edges) == 0 and not feat.found
    pts, s, planes = fe.feature_points(feat, 0.1)
    assert pts.shape == (0, 3) and s.shape == (0,) and len(planes) == 0


@pytest.mark.parametrize("bits", [None, 7, 8])
def test_feature_points_reproduce_the_cube(cube, bits):
    """Feature points alone, each s the distance to the planes it sees: the cube's surface exactly, also on the
    container's position grid (axis-aligned faces)."""
    feat = fe.detect_features(*cube)
    pts, s, planes = fe.feature_points(feat, 0.2)
    assert len(pts) > 0 and np.all(np.isfinite(s)) and np.all(s != 0)
    if bits is not None:
        pts, s = fe.snap_to_grid(pts, s, planes, bits)
        from tetweave_codec.formats import quantize as Q

        np.testing.assert_array_equal(Q.dequantize_positions(Q.quantize_positions(pts, bits), bits), pts)
    v, f = mesh_from_points(pts, s, None, -1)
    assert len(f) > 0
    assert _cube_error(v) < 1e-9
    # every face of the cube is covered: its area is the cube's
    area = trimesh.Trimesh(v, f, process=False).area
    assert area == pytest.approx(6 * 1.8**2, rel=1e-6)


def test_feature_start_beats_the_plain_start_on_the_cube(cube):
    """The start itself (before any fit): feature-aware is close to exact, the plain SDF start chamfers."""
    v, f = cube
    err = {}
    for features in (False, True):
        p, s, c, pinned = ini.initial_state_pinned(v, f, 900, -1, 0, features=features, position_bits=7)
        assert bool(pinned.any()) == features and not pinned[: ini.N_CORNERS].any()
        mv, mf = mesh_from_points(p.astype(np.float64), s, None, -1)
        err[features] = _cube_error(mv, np.mean)
    # measured: 1.6e-4 and 3.1e-3 (random shell points chamfer every crease)
    assert err[True] < 5e-4 and err[False] > 5 * err[True]


def test_feature_start_is_unchanged_without_creases():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.8)
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    a = ini.initial_state_pinned(v, f, 600, 1, 3, features=True, position_bits=7)
    b = ini.initial_state(v, f, 600, 1, 3, features=False)
    for x, y in zip(a[:3], b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert not a[3].any()


def test_crease_distance(cube):
    feat = fe.detect_features(*cube)
    q = np.array([[0.0, 0.0, 0.0], [0.9, 0.9, 0.0], [0.5, 0.9, 0.9]])
    np.testing.assert_allclose(fe.crease_distance(feat, q), [0.9 * np.sqrt(2), 0.0, 0.0], atol=1e-9)


@settings(max_examples=80, deadline=None)
@given(
    arrays(np.int64, st.tuples(st.integers(0, 60), st.integers(1, 3)), elements=st.integers(-3, 3)),
    st.booleans(),
)
def test_unique_rows_is_numpys_unique(rows, as_float):
    """unique_rows gives np.unique(axis=0)'s rows, inverse and counts (ints, and floats with signed zeros)."""
    if as_float:
        rows = rows.astype(np.float64) * 0.5
        rows[rows == 0] = np.where(np.arange((rows == 0).sum()) % 2 == 0, 0.0, -0.0)
    want = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
    got = fe.unique_rows(rows)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1].reshape(-1))
    np.testing.assert_array_equal(got[2], want[2])


@settings(max_examples=60, deadline=None)
@given(
    arrays(np.float64, (40, 3), elements=st.floats(-1.0, 1.0, allow_nan=False)),
)
def test_polyhedral_distance_is_the_cube_plane_function(q):
    """On a convex polytope the plane distance at crease and corner feet makes the signed distance
    max_i (n_i . p - a_i) everywhere: the one piecewise-linear function that tets of any size reproduce."""
    feat = fe.detect_features(*_CUBE)
    sdf = ini.signed_distance(q, *_CUBE)
    got = fe.polyhedral_distance(feat, q, sdf)
    np.testing.assert_allclose(got, np.abs(q).max(1) - 0.9, atol=1e-9)
    # never farther from the Euclidean distance than |sdf|, same sign
    assert np.all(np.sign(got) == np.sign(sdf)) and np.all(np.abs(got) <= np.abs(sdf) + 1e-12)


def test_polyhedral_distance_concave_crease_and_no_features():
    """Inside a concave crease (an L-shaped union of two boxes) the plane distance is min(d1, d2); shapes
    without creases keep the Euclidean distance."""
    solid = manifold3d.Manifold.cube([2.0, 1.0, 1.0]) + manifold3d.Manifold.cube([1.0, 2.0, 1.0])
    v, f = _mesh(solid)
    feat = fe.detect_features(v, f)
    # inside, next to the concave edge x = 1, y = 1 (z = 0.5): foot on the edge, both planes behind the point
    q = np.array([[0.9, 0.8, 0.5], [1.05, 1.1, 0.5]])
    sdf = ini.signed_distance(q, v, f)
    assert sdf[0] < 0 and sdf[1] > 0
    got = fe.polyhedral_distance(feat, q, sdf)
    np.testing.assert_allclose(got[0], min(0.9 - 1.0, 0.8 - 1.0), atol=1e-9)  # the planes x = 1 and y = 1
    np.testing.assert_allclose(got[1], sdf[1], atol=1e-12)  # outside a concave crease: a face's foot, unchanged
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.8)
    smooth = fe.detect_features(np.asarray(sphere.vertices), np.asarray(sphere.faces))
    np.testing.assert_array_equal(fe.polyhedral_distance(smooth, q, sdf), sdf)


def test_small_feature_start_with_plane_distances_is_the_cube(cube):
    """With plane distances for every point next to a crease (rate_control's feature-only fit), the start at 64
    points is the cube (measured 5.8e-9 mean vertex error; with Euclidean distances, 4.9e-2: an outside point's
    Euclidean distance near a crease makes every tet there cut the crease off)."""
    v, f = cube
    for plane, bound in ((True, 1e-6), (False, None)):
        p, s, c, pinned = ini.initial_state_pinned(v, f, 64, -1, 0, True, 7, plane_distances=plane)
        mv, mf = mesh_from_points(p.astype(np.float64), s, None, -1)
        err = _cube_error(mv, np.mean)
        if bound is not None:
            assert err < bound
        else:
            assert err > 1e-3


def test_feature_start_with_many_corners_and_few_points():
    """More corner pairs than half the points: the crease spacing stops growing (it once looped forever) and
    the start is the plain one; with more points the feature points keep to their share."""
    m = manifold3d.Manifold
    v, f = _normalized(
        m.cube([1.2, 0.4, 0.4], center=True)
        + m.cube([0.4, 1.2, 0.4], center=True)
        + m.cube([0.4, 0.4, 1.2], center=True).translate([0.3, 0.2, 0.1])
    )
    feat = fe.detect_features(v, f)
    assert feat.found and 2 * len(feat.corners) > 75
    p, s, c, pinned = ini.initial_state_pinned(v, f, 150, -1, 0, features=True, position_bits=7)
    plain = ini.initial_state(v, f, 150, -1, 0, features=False)
    assert not pinned.any()
    np.testing.assert_array_equal(p, plain[0])
    np.testing.assert_array_equal(s, plain[1])
    p, s, c, pinned = ini.initial_state_pinned(v, f, 400, -1, 0, features=True, position_bits=7)
    assert 0 < pinned.sum() <= 200 and np.all(np.isfinite(s))


def test_encode_cube_closed_deterministic_and_sharp(monkeypatch):
    """A feature-aware fit of a cube: closed 2-manifold, the same bytes twice, the decoded mesh exactly the
    reported one, and a Chamfer distance the plain start does not reach (the plain start is main's encoder:
    no crease is long enough for it)."""
    from tetweave_codec.decoder import decode
    from tetweave_codec.encoder import encode
    from tetweave_codec.metrics import topology

    v, f = _mesh(manifold3d.Manifold.cube([1.0, 1.0, 1.0], center=True))
    opts = {"points": 512, "sh_degree": 1, "quality": "fast", "iters": 40, "device": "cpu", "seed": 0}
    a = encode(v, f, **opts)
    b = encode(v, f, **opts)
    assert a.data == b.data
    dv, df = decode(a.data)
    np.testing.assert_array_equal(dv, a.vertices)
    np.testing.assert_array_equal(df, a.faces)
    m = manifold3d.Manifold(manifold3d.Mesh(vert_properties=dv.astype(np.float32), tri_verts=df.astype(np.uint32)))
    assert m.status() == manifold3d.Error.NoError
    topo = topology(dv, df)
    assert topo["boundary_edges"] == 0 and topo["nonmanifold_edges"] == 0
    monkeypatch.setattr(fe, "MIN_CREASE_LENGTH", np.inf)
    plain = encode(v, f, **opts)
    # measured when written: 3.3e-3 with features, 7.5e-3 without
    assert a.stats["chamfer"] < CUBE_CHAMFER_BOUND < plain.stats["chamfer"]
