"""geometry.subdivision (the decoder's Loop levels, `.tw` v2 flags bits 5-6), geometry.surface_filter (smoothing
then subdivision, then no crossings) and their use by decoder and encoder: the spec's arithmetic, the fit's map
equals the decoder's, the refinement stays closed and oriented, files decode to what the encoder reported."""

from __future__ import annotations

import manifold3d
import numpy as np
import pytest
import torch
import trimesh

from tetweave_codec.decoder import decode_detailed, mesh_from_points
from tetweave_codec.errors import ContainerError, InputError
from tetweave_codec.formats.common import KNOWN_FLAGS_V2, subdivision_flags, subdivision_levels
from tetweave_codec.geometry import surface_filter
from tetweave_codec.geometry.intersections import self_intersecting_faces
from tetweave_codec.geometry.smoothing import taubin
from tetweave_codec.geometry.subdivision import (
    level_matrix,
    loop_and_midpoint,
    loop_level,
    loop_subdivide,
    midpoint_subdivide,
)
from tetweave_codec.geometry.surface_filter import FilterMap, filter_surface

TET_V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]])
TET_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def _is_manifold(v, f) -> bool:
    mesh = manifold3d.Mesh(vert_properties=np.asarray(v, np.float32), tri_verts=np.asarray(f, np.uint32))
    return manifold3d.Manifold(mesh).status() == manifold3d.Error.NoError


def test_one_level_is_the_spec_formula():
    """A tetrahedron: every vertex has 3 neighbours (beta 3/16), every edge two opposite corners (the other two
    vertices), edges in ascending (a, b) order become vertices 4, 5, ..."""
    v, f = loop_subdivide(TET_V, TET_F, 1)
    edges = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    assert len(v) == 4 + 6 and len(f) == 16
    for i in range(4):
        others = [j for j in range(4) if j != i]
        expected = (1 - 3 * 0.1875) * TET_V[i] + 0.1875 * ((0 + TET_V[others[0]] + TET_V[others[1]]) + TET_V[others[2]])
        np.testing.assert_array_equal(v[i], expected)
    for e, (a, b) in enumerate(edges):
        c, d = [j for j in range(4) if j not in (a, b)]
        np.testing.assert_array_equal(v[4 + e], 0.375 * (TET_V[a] + TET_V[b]) + 0.125 * (TET_V[c] + TET_V[d]))
    # face (0, 2, 1): m_02 = 5, m_21 = 7, m_10 = 4
    np.testing.assert_array_equal(f[:4], [[0, 5, 4], [5, 2, 7], [4, 7, 1], [5, 7, 4]])


def test_valence_above_three_uses_warrens_beta():
    m = trimesh.creation.icosphere(1)  # valences 5 and 6
    v, _ = loop_subdivide(m.vertices, m.faces, 1)
    level = loop_level(m.faces, len(m.vertices))
    for i in (0, 20):
        nbrs = np.unique(level.edges[(level.edges == i).any(1)])
        nbrs = nbrs[nbrs != i]
        k = len(nbrs)
        beta = 3.0 / (8.0 * k)
        total = np.zeros(3)
        for j in nbrs:
            total = total + m.vertices[j]
        np.testing.assert_array_equal(v[i], (1 - k * beta) * m.vertices[i] + beta * total)


@pytest.mark.parametrize("levels", [1, 2])
def test_refinement_stays_closed_oriented_and_smooth(levels):
    m = trimesh.creation.icosphere(2)
    v, f = loop_subdivide(m.vertices, m.faces, levels)
    assert len(f) == len(m.faces) * 4**levels
    t = trimesh.Trimesh(v, f, process=False)
    assert t.is_watertight and t.is_winding_consistent and t.volume > 0
    assert t.euler_number == m.euler_number
    assert _is_manifold(v, f)
    assert not self_intersecting_faces(v, f).any()
    # an approximating scheme: the limit surface is inside the convex control mesh, close to the sphere
    r = np.linalg.norm(v, axis=1)
    assert 0.97 < r.min() and r.max() <= 1.0 + 1e-12


def test_midpoint_reference_is_the_surface_itself():
    m = trimesh.creation.icosphere(1)
    v, f = midpoint_subdivide(m.vertices, m.faces, 2)
    np.testing.assert_array_equal(v[: len(m.vertices)], m.vertices)
    t = trimesh.Trimesh(v, f, process=False)
    assert np.isclose(t.area, m.area, rtol=1e-12) and np.isclose(t.volume, m.volume, rtol=1e-12)
    v_loop, f_loop = loop_subdivide(m.vertices, m.faces, 2)
    np.testing.assert_array_equal(f, f_loop)
    both = loop_and_midpoint(m.vertices, m.vertices, m.faces, 2)
    np.testing.assert_array_equal(both[0], v_loop)
    np.testing.assert_array_equal(both[1], v)
    np.testing.assert_array_equal(both[2], f)


@pytest.mark.parametrize("midpoint", [False, True])
def test_level_matrix_is_the_level(midpoint):
    m = trimesh.creation.icosphere(2)
    rng = np.random.default_rng(0)
    x = m.vertices + rng.normal(0, 0.05, m.vertices.shape)
    level = loop_level(m.faces, len(x))
    ref = midpoint_subdivide(x, m.faces, 1)[0] if midpoint else loop_subdivide(x, m.faces, 1)[0]
    np.testing.assert_allclose(level_matrix(level, midpoint) @ x, ref, rtol=0, atol=1e-14)


@pytest.mark.parametrize(("steps", "levels"), [(0, 1), (1, 1), (1, 2), (2, 0)])
def test_the_fits_map_is_the_decoders_filter(steps, levels):
    """FilterMap (the fit's differentiable map) equals smoothing then subdivision of the decoder, to float
    rounding, with the same faces; gradcheck checks its backward (the transposed factors)."""
    m = trimesh.creation.icosphere(1)
    f = torch.as_tensor(np.asarray(m.faces, np.int64))
    rng = np.random.default_rng(steps + 3 * levels)
    x = m.vertices + rng.normal(0, 0.02, m.vertices.shape)
    op = FilterMap(f, len(x), steps, levels)
    v = torch.tensor(x, dtype=torch.float64, requires_grad=True)
    out = op(v)
    ref_v, ref_f = loop_subdivide(taubin(x, np.asarray(m.faces), steps), np.asarray(m.faces), levels)
    np.testing.assert_allclose(out.detach().numpy(), ref_v, rtol=0, atol=1e-13)
    np.testing.assert_array_equal(op.faces_out.numpy(), ref_f)
    assert torch.autograd.gradcheck(op, (v,), eps=1e-6, atol=1e-8)
    v32 = v.detach().float().requires_grad_()
    out32 = op(v32)
    assert out32.dtype == torch.float32
    out32.sum().backward()
    assert torch.isfinite(v32.grad).all()


def test_the_fits_map_off_the_cpu_is_the_same_map():
    """The CUDA path (index_add over (row, column, weight) factors) computes the same map and is differentiable;
    checked here on CPU tensors."""
    m = trimesh.creation.icosphere(1)
    op = FilterMap(np.asarray(m.faces), len(m.vertices), 1, 1)
    factors = surface_filter._indexed(op.matrices, torch.float64, torch.device("cpu"))
    x = torch.tensor(m.vertices, dtype=torch.float64, requires_grad=True)
    y = surface_filter._apply_indexed(x, factors)
    np.testing.assert_allclose(y.detach().numpy(), op(x).detach().numpy(), rtol=0, atol=1e-13)
    assert torch.autograd.gradcheck(lambda t: surface_filter._apply_indexed(t, factors), (x,), eps=1e-6, atol=1e-8)


def test_filter_falls_back_to_the_unfiltered_surface(monkeypatch):
    """A filtered surface the check cannot bound its work on: the unfiltered surface, itself checked; where that
    check cannot bound its work either, the file is refused (no unchecked mesh comes back)."""
    checked = surface_filter.self_intersecting_faces
    m = trimesh.creation.icosphere(1)

    def too_many_above(limit):
        def check(v, f, *args, **kwargs):
            if len(f) > limit:
                raise RuntimeError("self-intersection test: too many candidate face pairs")
            return checked(v, f, *args, **kwargs)

        return check

    out = filter_surface(m.vertices, m.faces, 1, 1)
    assert len(out.faces) == 4 * len(m.faces) and not out.gave_up and out.restored == 0
    monkeypatch.setattr(surface_filter, "self_intersecting_faces", too_many_above(len(m.faces)))
    out = filter_surface(m.vertices, m.faces, 1, 1, scale=2.0, offset=np.array([1.0, 0.0, -1.0]))
    assert out.gave_up
    np.testing.assert_array_equal(out.vertices, m.vertices * 2.0 + [1.0, 0.0, -1.0])
    np.testing.assert_array_equal(out.faces, m.faces)
    monkeypatch.setattr(surface_filter, "self_intersecting_faces", too_many_above(0))
    for steps, levels in ((1, 1), (0, 0)):
        with pytest.raises(ContainerError, match="work bound"):
            filter_surface(m.vertices, m.faces, steps, levels)


def test_a_file_asking_for_too_large_a_surface_is_refused(monkeypatch):
    monkeypatch.setattr(surface_filter, "MAX_SUBDIVIDED_FACES", 100)
    m = trimesh.creation.icosphere(1)  # 80 faces: 320 after one level
    with pytest.raises(ContainerError, match="subdivision"):
        filter_surface(m.vertices, m.faces, 0, 1)
    assert len(filter_surface(m.vertices, m.faces, 1, 0).faces) == 80


def test_crossing_subdivided_faces_go_back_to_the_reference():
    """Two boxes 0.02 apart, subdivided; a stand-in for an over-eager filter moves part of A into B. The vertices
    of crossing faces go back to the reference (the midpoint refinement of the boxes) until nothing crosses; the
    refined faces stay."""
    a = trimesh.creation.box((1, 1, 1))
    b = trimesh.creation.box((1, 1, 1))
    b.vertices += [1.02, 0, 0]
    v = np.concatenate([a.vertices, b.vertices])
    f = np.concatenate([a.faces, b.faces + len(a.vertices)]).astype(np.int64)
    sub_v, sub_f = loop_subdivide(v, f, 1)
    ref_v, _ = midpoint_subdivide(v, f, 1)
    in_a = np.zeros(len(sub_v), bool)
    in_a[sub_f[: 4 * len(a.faces)].reshape(-1)] = True
    pushed = sub_v.copy()
    pushed[in_a & (sub_v[:, 0] > 0.2)] += [0.3, 0, 0]
    assert self_intersecting_faces(pushed, sub_f).any()
    out, restored, gave_up = surface_filter.restore_crossings(pushed, ref_v, sub_f)
    assert not gave_up and 0 < restored < len(out)
    assert not self_intersecting_faces(out, sub_f).any()


def test_mesh_from_points_subdivides_and_stays_closed():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-1, 1, (600, 3))
    s = np.linalg.norm(pts, axis=1) - 0.7
    v0, f0 = mesh_from_points(pts, s, None, -1)
    for levels in (1, 2):
        v, f = mesh_from_points(pts, s, None, -1, smoothing=1, subdivision=levels)
        assert len(f) == len(f0) * 4**levels
        assert _is_manifold(v, f)
        assert not self_intersecting_faces(v, f).any()
        # this jagged, unfitted surface crosses itself once subdivided: the check put vertices back
        assert not np.array_equal(v[: len(v0)], v0)


def test_flags_bits_5_and_6_hold_the_levels():
    for k in range(3):
        assert subdivision_levels(subdivision_flags(k)) == k
        assert subdivision_flags(k) & ~KNOWN_FLAGS_V2 == 0
    with pytest.raises(ValueError):
        subdivision_flags(3)


def test_encoded_subdivision_decodes_to_the_reported_mesh():
    from tetweave_codec.encoder import encode

    torch.set_num_threads(1)
    m = trimesh.creation.icosphere(2)
    r = encode(m.vertices, m.faces, points=256, quality="fast", iters=30, device="cpu", smoothing=1, subdivision=1)
    d = decode_detailed(r.data)
    assert (d.container.smoothing, d.container.subdivision) == (1, 1)
    np.testing.assert_array_equal(d.vertices, r.vertices)
    np.testing.assert_array_equal(d.faces, r.faces)
    assert not self_intersecting_faces(d.vertices, d.faces).any()
    assert _is_manifold(d.vertices, d.faces)


def test_level_three_is_rejected_by_reader_and_writer():
    import zlib

    from tetweave_codec.encoder import encode
    from tetweave_codec.formats.common import SUBDIVISION_SHIFT
    from tetweave_codec.formats.tw import unpack

    m = trimesh.creation.icosphere(1)
    data = bytearray(encode(m.vertices, m.faces, points=128, quality="fast", iters=5, device="cpu").data)
    data[10] |= 3 << SUBDIVISION_SHIFT
    data[-4:] = zlib.crc32(bytes(data[:-4])).to_bytes(4, "little")
    with pytest.raises(ContainerError, match="subdivision"):
        unpack(bytes(data))


def test_encoder_refuses_bad_subdivision():
    from tetweave_codec.encoder import encode

    m = trimesh.creation.icosphere(1)
    with pytest.raises(InputError, match="subdivision"):
        encode(m.vertices, m.faces, points=128, subdivision=3)
    with pytest.raises(InputError, match="version 2"):
        encode(m.vertices, m.faces, points=128, subdivision=1, container_version=1, smoothing=0)


def test_encoder_keeps_the_smoothing_alone_when_the_decoder_drops_the_subdivided_filter(monkeypatch):
    """A decoder whose crossing check never settles on subdivided surfaces (simulated) returns the unfiltered
    surface; the encoder then keeps whichever of that and the same points with the subdivision bits cleared (the
    smoothing alone) decodes closer to the input, and reports exactly what its file decodes to."""
    from tetweave_codec import decoder
    from tetweave_codec.encoder import SUMMARY_CHAMFER_SAMPLES, encode
    from tetweave_codec.metrics import chamfer_distance

    real = decoder.filter_surface

    def never_settles(vertices, faces, smoothing, subdivision, creases=False, scale=1.0, offset=None, threads=1):
        if subdivision:
            v = np.asarray(vertices, np.float64)
            out = v if offset is None else v * float(scale) + offset  # the output frame, as the decoder's
            return surface_filter.FilteredSurface(out, np.asarray(faces, np.int64), len(v), True)
        return real(vertices, faces, smoothing, subdivision, creases, scale, offset, threads)

    monkeypatch.setattr(decoder, "filter_surface", never_settles)
    monkeypatch.setattr(decoder, "CORE", False)  # the simulated filter is the Python pipeline's (the core has its own)
    torch.set_num_threads(1)
    m = trimesh.creation.icosphere(3)
    r = encode(m.vertices, m.faces, points=512, quality="fast", iters=40, device="cpu", smoothing=1, subdivision=1)
    d = decode_detailed(r.data)
    np.testing.assert_array_equal(d.vertices, r.vertices)
    np.testing.assert_array_equal(d.faces, r.faces)
    c = d.container

    def error(smoothing):
        v, f = decoder.mesh_from_points(c.points, c.s, c.c, c.sh_degree, d.backend, smoothing)
        v = v * c.scale + c.offset
        return chamfer_distance(m.vertices, m.faces, v, f, n_samples=SUMMARY_CHAMFER_SAMPLES, seed=0)

    assert r.stats["chamfer"] == pytest.approx(min(error(0), error(1)), rel=1e-12)
    assert c.smoothing == 1 and c.subdivision == (0 if error(1) < error(0) else 1)
