"""geometry.smoothing (the decoder's Taubin steps, `.tw` v2 flags bits 3-4) and the decoder's use of it: the
spec's arithmetic, torch == numpy (the fit optimizes what the decoder computes), planes stay planes, crossing
faces are restored, and smoothed files decode to closed, 2-manifold, self-intersection-free meshes that equal
what the encoder reported."""

from __future__ import annotations

import manifold3d
import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial import Delaunay

from tetweave_codec.decoder import decode_detailed, mesh_from_points
from tetweave_codec.errors import InputError
from tetweave_codec.formats.common import KNOWN_FLAGS_V2, smoothing_flags, smoothing_steps
from tetweave_codec.geometry import surface_filter
from tetweave_codec.geometry.intersections import self_intersecting_faces
from tetweave_codec.geometry.smoothing import TAUBIN_LAMBDA, TAUBIN_MU, mesh_edges, taubin
from tetweave_codec.geometry.subdivision import loop_and_midpoint
from tetweave_codec.geometry.surface_filter import FilterMap, restore_crossings


def test_one_step_is_the_spec_formula():
    """A tetrahedron: each vertex's neighbours are the other three, so a step maps v_i to
    v_i + f (mean of the others - v_i), for f = lambda then mu."""
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    expected = v.copy()
    for lam in (TAUBIN_LAMBDA, TAUBIN_MU):
        total = np.zeros_like(expected)
        for i in range(4):
            for j in range(4):  # ascending neighbours, from 0
                if j != i:
                    total[i] = total[i] + expected[j]
        expected = expected + lam * (total / 3.0 - expected)
    np.testing.assert_array_equal(taubin(v, f, 1), expected)
    assert taubin(v, f, 0) is v
    np.testing.assert_array_equal(v[0], [0, 0, 0])  # input untouched


def test_edges_are_each_undirected_edge_both_ways():
    f = np.array([[0, 1, 2], [0, 2, 3]])
    e = mesh_edges(f, 4)
    assert e.tolist() == [[0, 1], [0, 2], [0, 3], [1, 0], [1, 2], [2, 0], [2, 1], [2, 3], [3, 0], [3, 2]]
    np.testing.assert_array_equal(mesh_edges(torch.as_tensor(f), 4).numpy(), e)
    closed = trimesh.creation.icosphere(2)
    np.testing.assert_array_equal(
        mesh_edges(closed.faces, len(closed.vertices), closed=True), mesh_edges(closed.faces, len(closed.vertices))
    )


def test_torch_matches_numpy_and_has_gradients():
    m = trimesh.creation.icosphere(2)
    rng = np.random.default_rng(0)
    v = m.vertices + rng.normal(0, 0.02, m.vertices.shape)
    f = np.asarray(m.faces, np.int64)
    ref = taubin(v, f, 2)
    vt = torch.tensor(v, dtype=torch.float64, requires_grad=True)
    out = taubin(vt, torch.as_tensor(f), 2)
    np.testing.assert_allclose(out.detach().numpy(), ref, rtol=0, atol=1e-13)
    assert torch.autograd.gradcheck(lambda x: taubin(x, torch.as_tensor(f), 1), (vt,), eps=1e-6, atol=1e-8)


@pytest.mark.parametrize("steps", [1, 2])
def test_the_fits_operator_is_taubin_with_its_transpose_as_gradient(steps):
    """FilterMap without subdivision (scipy factors, the fit's CPU path) computes taubin's map; gradcheck checks
    the backward."""
    m = trimesh.creation.icosphere(2)
    f = torch.as_tensor(np.asarray(m.faces, np.int64))
    rng = np.random.default_rng(steps)
    v = torch.tensor(m.vertices + rng.normal(0, 0.02, m.vertices.shape), dtype=torch.float64, requires_grad=True)
    op = FilterMap(f, len(v), steps, 0)
    np.testing.assert_allclose(op(v).detach().numpy(), taubin(v, f, steps).detach().numpy(), rtol=0, atol=1e-13)
    assert torch.autograd.gradcheck(op, (v,), eps=1e-6, atol=1e-8)
    v32 = v.detach().float().requires_grad_()
    out = op(v32)
    assert out.dtype == torch.float32
    out.sum().backward()
    assert v32.grad is not None and torch.isfinite(v32.grad).all()


def test_planes_stay_planes_and_sphere_keeps_its_size():
    # a flat grid: every vertex stays in z = 0 whatever the steps
    t = np.linspace(0, 1, 9)
    x, y = np.meshgrid(t, t, indexing="ij")
    rng = np.random.default_rng(1)
    v = np.stack([x.ravel() + rng.normal(0, 0.01, x.size), y.ravel(), np.zeros(x.size)], axis=1)
    f = Delaunay(v[:, :2]).simplices.astype(np.int64)
    np.testing.assert_array_equal(taubin(v, f, 3)[:, 2], 0.0)
    # Taubin's pair of steps barely shrinks: a sphere's radius changes by well under 1 %
    s = trimesh.creation.icosphere(3)
    r = np.linalg.norm(taubin(s.vertices, np.asarray(s.faces), 1), axis=1)
    assert abs(r.mean() - 1.0) < 0.01


def test_crossing_faces_are_restored():
    """Two boxes side by side; a 'smoothed' version pushes one into the other: the vertices of the crossing
    faces go back, and the result crosses nothing."""
    a = manifold3d.Manifold.cube([1, 1, 1], True).to_mesh()
    va = np.asarray(a.vert_properties, float)[:, :3]
    fa = np.asarray(a.tri_verts, np.int64)
    v = np.concatenate([va, va + [1.2, 0, 0]])
    f = np.concatenate([fa, fa + len(va)])
    moved = v.copy()
    moved[len(va) :][va[:, 0] < 0] -= [0.5, 0, 0]  # box B's -x face into box A
    assert self_intersecting_faces(moved, f).any()
    out, restored, gave_up = restore_crossings(moved, v, f)
    assert not gave_up
    assert 0 < restored <= len(v)
    assert not self_intersecting_faces(out, f).any()
    # nothing crosses: the smoothed vertices are kept as they are
    same, none, _ = restore_crossings(v + 0.01, v, f)
    assert none == 0
    np.testing.assert_array_equal(same, v + 0.01)


def spec_restore(smoothed, original, faces):
    """formats/README.md "Smoothing" step 3 as written: full tests only."""
    v = np.array(smoothed, dtype=np.float64)
    restored = np.zeros(len(v), dtype=bool)
    for _ in range(surface_filter.MAX_CHECKS):
        bad = self_intersecting_faces(v, faces)
        if not bad.any():
            return v
        moved = np.zeros(len(v), dtype=bool)
        moved[faces[bad].reshape(-1)] = True
        v[moved] = original[moved]
        restored |= moved
    return np.array(original, dtype=np.float64)


@pytest.mark.parametrize("seed", range(6))
def test_restore_is_the_spec_even_when_the_original_crosses_itself(seed):
    """Hostile files can decode to an unsmoothed surface that already crosses itself (flat tets): the restricted
    later checks must still give the spec's answer (here: the original, since those crossings never go away)."""
    rng = np.random.default_rng(seed)
    a = trimesh.creation.icosphere(2)
    b = trimesh.creation.icosphere(2)
    original = np.concatenate([a.vertices, b.vertices + [rng.uniform(0.5, 2.5), 0, 0]])
    faces = np.concatenate([a.faces, b.faces + len(a.vertices)]).astype(np.int64)
    smoothed = original + rng.normal(0, 0.08, original.shape)
    out, restored, _ = restore_crossings(smoothed, original, faces)
    np.testing.assert_array_equal(out, spec_restore(smoothed, original, faces))
    if self_intersecting_faces(original, faces).any():
        np.testing.assert_array_equal(out, original)
    else:
        assert not self_intersecting_faces(out, faces).any()


def test_restore_gives_up_when_the_check_cannot_bound_its_work(monkeypatch):
    def too_many(*args, **kwargs):
        raise RuntimeError("self-intersection test: too many candidate face pairs")

    monkeypatch.setattr(surface_filter, "self_intersecting_faces", too_many)
    v = np.random.default_rng(0).normal(size=(4, 3))
    out, restored, gave_up = restore_crossings(v + 1, v, np.array([[0, 1, 2], [0, 2, 3]]))
    assert gave_up
    np.testing.assert_array_equal(out, v)
    assert restored == 4


def test_flags_bits_3_and_4_hold_the_steps():
    for k in range(4):
        assert smoothing_steps(smoothing_flags(k)) == k
        assert smoothing_flags(k) & ~KNOWN_FLAGS_V2 == 0
    with pytest.raises(ValueError):
        smoothing_flags(4)
    assert (1 << 7) & KNOWN_FLAGS_V2 and not smoothing_flags(3) & (1 << 7)  # bit 7 is the holes section's


def test_mesh_from_points_smooths_and_stays_closed():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-1, 1, (600, 3))
    s = np.linalg.norm(pts, axis=1) - 0.7
    v0, f0 = mesh_from_points(pts, s, None, -1)
    v1, f1 = mesh_from_points(pts, s, None, -1, smoothing=1)
    np.testing.assert_array_equal(f0, f1)
    assert not np.array_equal(v0, v1)
    # the low-pass filter irons out the jagged marching-tets surface: less area for the same enclosed shape
    assert trimesh.Trimesh(v1, f1).area < trimesh.Trimesh(v0, f0).area
    mesh = manifold3d.Manifold(manifold3d.Mesh(vert_properties=v1.astype(np.float32), tri_verts=f1.astype(np.uint32)))
    assert mesh.status() == manifold3d.Error.NoError
    assert not self_intersecting_faces(v1, f1).any()


@pytest.mark.parametrize("steps", [0, 1])
def test_encoded_smoothing_decodes_to_the_reported_mesh(steps):
    from tetweave_codec.encoder import encode

    torch.set_num_threads(1)
    m = trimesh.creation.icosphere(2)
    r = encode(m.vertices, m.faces, points=256, quality="fast", iters=30, device="cpu", smoothing=steps, subdivision=0)
    d = decode_detailed(r.data)
    assert d.container.smoothing == steps
    np.testing.assert_array_equal(d.vertices, r.vertices)
    np.testing.assert_array_equal(d.faces, r.faces)
    assert not self_intersecting_faces(d.vertices, d.faces).any()
    mesh = manifold3d.Mesh(vert_properties=d.vertices.astype(np.float32), tri_verts=d.faces.astype(np.uint32))
    assert manifold3d.Manifold(mesh).status() == manifold3d.Error.NoError


def test_encoder_refuses_bad_smoothing():
    from tetweave_codec.encoder import encode

    m = trimesh.creation.icosphere(1)
    with pytest.raises(InputError, match="smoothing"):
        encode(m.vertices, m.faces, points=128, smoothing=4)
    with pytest.raises(InputError, match="version 2"):
        encode(m.vertices, m.faces, points=128, smoothing=1, container_version=1)


def test_input_defaults_keep_creases_and_drop_subdivision_and_sh_for_cad_parts_only():
    from tetweave_codec.encoder import (
        CAD_CREASE_DENSITY,
        CREASED_SH_DEGREE,
        CREASED_SMOOTHING,
        DEFAULT_SH_DEGREE,
        input_defaults,
    )
    from tetweave_codec.fit.config import DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION
    from tetweave_codec.fit.features import crease_density, detect_features
    from tetweave_codec.meshio import normalize

    cube = manifold3d.Manifold.cube([2, 1, 1], True).to_mesh()
    chosen = input_defaults(np.asarray(cube.vert_properties)[:, :3] * 50, np.asarray(cube.tri_verts))
    assert chosen == (CREASED_SMOOTHING, 0, CREASED_SH_DEGREE, True) == (3, 0, -1, True)
    ball = trimesh.creation.icosphere(3)
    smooth = (DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION, DEFAULT_SH_DEGREE, False)
    assert input_defaults(ball.vertices * 1e-3, ball.faces) == smooth
    assert input_defaults(ball.vertices, ball.faces) == (1, 1, 1, False)
    # a sphere cut by a plane: one long crease around a curved surface, the smooth settings with the crease kept
    cut = manifold3d.Manifold.sphere(1.0, 48) - manifold3d.Manifold.cube([4, 4, 4], True).translate([0, 0, 2.6])
    mesh = cut.to_mesh()
    v, f = np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts)
    normalized = normalize(v)[0]
    features = detect_features(normalized, f)
    assert features.found and 0 < crease_density(features, normalized, f) < CAD_CREASE_DENSITY
    assert input_defaults(v, f) == (DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION, DEFAULT_SH_DEGREE, True) == (1, 1, 1, True)


def test_encode_reports_the_sh_degree_it_chose():
    from tetweave_codec.encoder import encode
    from tetweave_codec.formats.tw import unpack

    cube = manifold3d.Manifold.cube([2, 1, 1], True).to_mesh()
    v, f = np.asarray(cube.vert_properties)[:, :3], np.asarray(cube.tri_verts)
    result = encode(v, f, points=128, quality="fast", iters=4, measure=False, device="cpu")
    assert result.stats["sh_degree"] == -1 and unpack(result.data).sh_degree == -1
    result = encode(v, f, points=128, quality="fast", iters=4, measure=False, device="cpu", sh_degree=1)
    assert result.stats["sh_degree"] == 1 and unpack(result.data).sh_degree == 1


# --- crease-preserving smoothing (bit 7 of the position-bits byte; geometry.smoothing.crease_neighbours) ---


def _box(divisions: int = 6, size=(2.0, 1.0, 1.0)) -> trimesh.Trimesh:
    """A closed box whose faces are grids of divisions x divisions quads (interior vertices to smooth)."""
    box = trimesh.creation.box(extents=size)
    for _ in range(int(np.log2(divisions))):
        box = box.subdivide()
    box.merge_vertices()
    return box


def _plane_distances(v: np.ndarray, size) -> np.ndarray:
    """Distance of each vertex to the nearest of the box's six planes (0 on the surface)."""
    half = np.asarray(size) / 2
    return np.min(np.abs(np.abs(v) - half), axis=1)


def test_crease_edges_of_a_cube_are_its_twelve_edges():
    from tetweave_codec.geometry.smoothing import crease_edges

    cube = trimesh.creation.box()
    e = mesh_edges(cube.faces, 8, closed=True)
    sharp = crease_edges(cube.vertices, cube.faces, e)
    assert sharp.sum() == 24  # 12 edges, both directions; the 6 face diagonals are flat
    lengths = np.linalg.norm(cube.vertices[e[:, 0]] - cube.vertices[e[:, 1]], axis=1)
    np.testing.assert_allclose(lengths[sharp], 1.0)
    # both directions of an edge agree
    key = {tuple(x): s for x, s in zip(e.tolist(), sharp, strict=True)}
    assert all(key[(b, a)] == s for (a, b), s in key.items())


def test_crease_threshold_is_thirty_degrees():
    """Two triangles hinged on an edge, closed by their mirror image: the hinge is a crease above 30 degrees."""
    from tetweave_codec.geometry.smoothing import CREASE_COS, crease_edges

    assert CREASE_COS == np.cos(np.radians(30.0))
    for angle, expected in ((25.0, False), (35.0, True)):
        t = np.radians(angle)
        v = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -np.cos(t), np.sin(t)]])
        f = np.array([[0, 1, 2], [1, 0, 3], [0, 2, 3], [1, 3, 2]])  # a closed tetrahedron
        e = mesh_edges(f, 4, closed=True)
        sharp = crease_edges(v, f, e)
        hinge = np.all(np.sort(e, axis=1) == [0, 1], axis=1)
        assert sharp[hinge].all() == expected


def test_crease_preserving_smoothing_keeps_a_cube_exact_and_flattens_its_faces():
    """Corners (three crease edges) stay, crease vertices move along their crease, face vertices are smoothed
    within the plane: a noisy box comes back closer to its planes while every crease and corner stays put; the
    plain filter rounds the edges."""
    size = (2.0, 1.0, 1.0)
    box = _box(8, size)
    v = np.asarray(box.vertices, dtype=np.float64)
    f = np.asarray(box.faces, dtype=np.int64)
    on_plane = (np.abs(np.abs(v) - np.asarray(size) / 2) < 1e-9).sum(axis=1)
    rng = np.random.default_rng(0)
    noisy = v.copy()
    interior = on_plane == 1  # vertices on one face only: push them off their plane a little
    normal_axis = np.argmin(np.abs(np.abs(v) - np.asarray(size) / 2), axis=1)
    noisy[interior, normal_axis[interior]] += rng.normal(0, 0.01, interior.sum())
    out = surface_filter.filter_surface(noisy, f, 2, 0, creases=True)
    assert not out.gave_up
    np.testing.assert_array_equal(out.vertices[on_plane == 3], v[on_plane == 3])  # corners never move
    crease = on_plane == 2
    np.testing.assert_allclose(_plane_distances(out.vertices[crease], size), 0.0, atol=1e-12)  # still on the edge
    assert _plane_distances(out.vertices[interior], size).mean() < 0.7 * _plane_distances(noisy[interior], size).mean()
    plain = surface_filter.filter_surface(noisy, f, 2, 0)
    assert _plane_distances(plain.vertices[on_plane >= 2], size).max() > 0.01  # the plain filter rounds them


@pytest.mark.parametrize("levels", [0, 1])
def test_the_fits_crease_map_is_the_decoders_filter(levels):
    """FilterMap with creases (the fit's differentiable filter) computes filter_surface(creases=True) on a
    marching-tets surface with creases (a box's), with and without a Loop level, and its backward is the
    transposed map."""
    from tetweave_codec.geometry.smoothing import crease_edges, crease_neighbours

    rng = np.random.default_rng(1)
    pts = rng.uniform(-1, 1, (1500, 3))
    s = np.max(np.abs(pts) / [0.8, 0.5, 0.6], axis=1) - 1.0  # a box's (non-Euclidean) distance: sharp edges
    v0, f0 = mesh_from_points(pts, s, None, -1)
    e = mesh_edges(f0, len(v0), closed=True)
    edges = crease_neighbours(v0, f0, e)
    assert 0 < len(edges) < len(e)
    ref = surface_filter.filter_surface(v0, f0, 1, levels, creases=True)
    vt = torch.tensor(v0, dtype=torch.float64, requires_grad=True)
    sharp = crease_edges(v0, f0, e)
    op = FilterMap(torch.as_tensor(f0), len(v0), 1, levels, sharp)
    # the decoder's filter before its crossing check (FilterMap leaves the check out)
    expected = taubin(v0, f0, 1, edges=edges)
    if levels:
        expected = loop_and_midpoint(expected, v0, f0, levels, neighbours=e, creases=sharp[e[:, 0] < e[:, 1]])[0]
    np.testing.assert_allclose(op(vt).detach().numpy(), expected, rtol=0, atol=1e-13)
    moved = np.abs(ref.vertices - expected).max(axis=1) > 0
    assert moved.sum() <= ref.restored  # the decoder's result differs only where it put vertices back
    # backward = the transposed map: <op(x), y> == <x, op^T(y)> for random x, y
    y = torch.as_tensor(rng.normal(size=ref.vertices.shape))
    (op(vt) * y).sum().backward()
    x = rng.normal(size=v0.shape)
    lhs = float((op(torch.as_tensor(x)) * y).sum())
    rhs = float((torch.as_tensor(x) * vt.grad).sum())
    assert abs(lhs - rhs) <= 1e-9 * max(1.0, abs(lhs))


def test_mesh_from_points_keeps_creases_closed_and_uncrossed():
    rng = np.random.default_rng(2)
    pts = rng.uniform(-1, 1, (1200, 3))
    s = np.max(np.abs(pts) / [0.8, 0.5, 0.6], axis=1) - 1.0
    v0, f0 = mesh_from_points(pts, s, None, -1)
    v1, f1 = mesh_from_points(pts, s, None, -1, smoothing=1, creases=True)
    v2, _ = mesh_from_points(pts, s, None, -1, smoothing=1)
    np.testing.assert_array_equal(f0, f1)
    assert not np.array_equal(v0, v1) and not np.array_equal(v1, v2)
    mesh = manifold3d.Manifold(manifold3d.Mesh(vert_properties=v1.astype(np.float32), tri_verts=f1.astype(np.uint32)))
    assert mesh.status() == manifold3d.Error.NoError
    assert not self_intersecting_faces(v1, f1).any()


def test_a_cad_part_is_encoded_with_crease_preserving_smoothing_and_decodes_to_the_report():
    """The encoder's default for inputs with sharp creases: one crease-preserving step, fitted through in the late
    stage; the file carries the bit, decodes to exactly the reported mesh, closed, 2-manifold, uncrossed. With
    --round-creases (keep_creases=False) the same input gets the plain filter."""
    from tetweave_codec.encoder import encode
    from tetweave_codec.formats.tw import unpack

    torch.set_num_threads(1)
    part = manifold3d.Manifold.cube([1, 1, 1], True) - manifold3d.Manifold.cylinder(1.2, 0.3, 0.3, 32).translate(
        [0, 0, -0.6]
    )
    mesh = part.to_mesh()
    v, f = np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts)
    r = encode(v, f, points=600, quality="fast", iters=40, device="cpu")
    tw = unpack(r.data)
    assert (tw.smoothing, tw.subdivision, tw.creases) == (3, 0, True)
    d = decode_detailed(r.data)
    np.testing.assert_array_equal(d.vertices, r.vertices)
    np.testing.assert_array_equal(d.faces, r.faces)
    assert not self_intersecting_faces(d.vertices, d.faces).any()
    out = manifold3d.Mesh(vert_properties=d.vertices.astype(np.float32), tri_verts=d.faces.astype(np.uint32))
    assert manifold3d.Manifold(out).status() == manifold3d.Error.NoError
    rounded = encode(v, f, points=600, quality="fast", iters=40, device="cpu", keep_creases=False)
    assert (unpack(rounded.data).smoothing, unpack(rounded.data).creases) == (3, False)
    with pytest.raises(InputError, match="version 2"):
        encode(v, f, points=600, keep_creases=True, container_version=1)
    # the creases bit also asks for Loop's crease rules: a subdivided file without smoothing keeps it
    sub = encode(v, f, points=600, quality="fast", iters=40, device="cpu", smoothing=0, subdivision=1)
    assert (unpack(sub.data).smoothing, unpack(sub.data).subdivision, unpack(sub.data).creases) == (0, 1, True)
    d = decode_detailed(sub.data)
    np.testing.assert_array_equal(d.vertices, sub.vertices)
    assert not self_intersecting_faces(d.vertices, d.faces).any()
    plain = encode(v, f, points=600, quality="fast", iters=40, device="cpu", smoothing=0, subdivision=0)
    assert not unpack(plain.data).creases  # nothing to keep without a filter


@pytest.mark.parametrize("levels", [1, 2])
def test_crease_loop_subdivision_keeps_a_box_a_box(levels):
    """Loop's crease rules: on a box, crease edges' new vertices are midpoints, crease vertices move along their
    crease, corners stay and face vertices stay in their plane: the subdivided box is the box, at one level and
    two (the halves of a crease edge are creases). Plain Loop rounds it."""
    size = (2.0, 1.0, 1.0)
    box = _box(4, size)
    v, f = np.asarray(box.vertices, dtype=np.float64), np.asarray(box.faces, dtype=np.int64)
    out = surface_filter.filter_surface(v, f, 0, levels, creases=True)
    assert not out.gave_up and len(out.faces) == len(f) * 4**levels
    np.testing.assert_allclose(_plane_distances(out.vertices, size), 0.0, atol=1e-12)
    corners = np.abs(np.abs(out.vertices) - np.asarray(size) / 2).max(axis=1) < 1e-12
    assert corners.sum() == 8
    plain = surface_filter.filter_surface(v, f, 0, levels)
    assert _plane_distances(plain.vertices, size).max() > 0.02
