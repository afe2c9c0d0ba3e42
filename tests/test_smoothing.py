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


def test_input_defaults_turn_filter_and_sh_off_for_cad_parts_only():
    from tetweave_codec.encoder import CREASED_SH_DEGREE, DEFAULT_SH_DEGREE, input_defaults
    from tetweave_codec.fit.config import DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION

    cube = manifold3d.Manifold.cube([2, 1, 1], True).to_mesh()
    chosen = input_defaults(np.asarray(cube.vert_properties)[:, :3] * 50, np.asarray(cube.tri_verts))
    assert chosen == (0, 0, CREASED_SH_DEGREE) == (0, 0, -1)
    ball = trimesh.creation.icosphere(3)
    smooth = (DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION, DEFAULT_SH_DEGREE)
    assert input_defaults(ball.vertices * 1e-3, ball.faces) == smooth
    assert input_defaults(ball.vertices, ball.faces) == (1, 1, 1)


def test_encode_reports_the_sh_degree_it_chose():
    from tetweave_codec.encoder import encode
    from tetweave_codec.formats.tw import unpack

    cube = manifold3d.Manifold.cube([2, 1, 1], True).to_mesh()
    v, f = np.asarray(cube.vert_properties)[:, :3], np.asarray(cube.tri_verts)
    result = encode(v, f, points=128, quality="fast", iters=4, measure=False, device="cpu")
    assert result.stats["sh_degree"] == -1 and unpack(result.data).sh_degree == -1
    result = encode(v, f, points=128, quality="fast", iters=4, measure=False, device="cpu", sh_degree=1)
    assert result.stats["sh_degree"] == 1 and unpack(result.data).sh_degree == 1
