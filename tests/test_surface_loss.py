"""The fit's 3-D Chamfer term (fit/surface_loss.py) and its differentiable area sampler (geometry/triangles.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from tetweave_codec.fit import surface_loss
from tetweave_codec.fit.surface_loss import SurfaceTarget
from tetweave_codec.geometry.triangles import sample_surface_torch


def _sphere(subdivisions: int = 3, radius: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def _loss(target: SurfaceTarget, v: np.ndarray, f: np.ndarray, seed: int = 0) -> torch.Tensor:
    vt = torch.tensor(v, dtype=torch.float64, requires_grad=True)
    return target.loss(vt, torch.from_numpy(f), torch.Generator().manual_seed(seed)).chamfer


def test_sampler_follows_area_and_stays_on_faces():
    # two triangles in the plane z = 0 with areas 1/2 and 3/2: a quarter of the samples in the first
    v = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [1, 3, 0]], dtype=torch.float64)
    f = torch.tensor([[0, 1, 2], [1, 3, 4]])
    p, face = sample_surface_torch(v, f, 20_000, torch.Generator().manual_seed(1))
    assert p.shape == (20_000, 3)
    assert torch.all(p[:, 2] == 0)
    in_first = (p[:, 0] + p[:, 1] <= 1.0 + 1e-12).double().mean().item()
    assert in_first == pytest.approx(0.25, abs=0.015)
    assert torch.equal(face == 0, p[:, 0] + p[:, 1] <= 1.0 + 1e-12)  # each sample lies on the face it names


def test_sampler_is_deterministic_and_differentiable():
    v, f = _sphere(1)
    vt = torch.tensor(v, requires_grad=True)
    ft = torch.from_numpy(f)
    a, _ = sample_surface_torch(vt, ft, 500, torch.Generator().manual_seed(3))
    b, _ = sample_surface_torch(vt, ft, 500, torch.Generator().manual_seed(3))
    assert torch.equal(a, b)
    a.sum().backward()
    # each sample's corner weights sum to 1, so d(sum of samples)/d(vertices) sums to the sample count per axis
    assert vt.grad.sum(0).tolist() == pytest.approx([500.0] * 3)


def test_sampler_on_zero_area_mesh_is_finite():
    v = torch.zeros(3, 3, dtype=torch.float64)
    p, _ = sample_surface_torch(v, torch.tensor([[0, 1, 2]]), 10, torch.Generator().manual_seed(0))
    assert torch.isfinite(p).all()


def test_loss_measures_the_offset_of_a_scaled_sphere():
    v, f = _sphere(4, radius=0.5)
    target = SurfaceTarget(v, f, n_samples=20_000, seed=0)
    assert _loss(target, v, f).item() < 2e-5  # the input itself
    # every point of a sphere of radius 0.51 is 0.01 from the input (up to the facets' sagitta, ~1e-4 here)
    assert _loss(target, v * 1.02, f).item() == pytest.approx(0.01, rel=0.03)


def test_loss_gradient_pulls_the_mesh_back():
    v, f = _sphere(3, radius=0.5)
    target = SurfaceTarget(v, f, n_samples=20_000, seed=0)
    vt = torch.tensor(v * 1.05, requires_grad=True)
    target.loss(vt, torch.from_numpy(f), torch.Generator().manual_seed(0)).chamfer.backward()
    radial = (vt.grad * torch.from_numpy(v)).sum(-1)
    assert (radial > 0).float().mean().item() > 0.95  # descending moves (almost) every vertex inwards


def test_loss_counts_face_interiors_not_only_vertices():
    # An icosahedron inscribed in a sphere has its vertices on the sphere but its faces well inside it: a
    # vertex-only mesh -> input term would see no error in that direction, half the symmetric distance.
    import igl

    from tetweave_codec.geometry.triangles import sample_surface

    v, f = _sphere(5, radius=0.5)
    target = SurfaceTarget(v, f, n_samples=50_000, seed=0)
    ico = trimesh.creation.icosphere(subdivisions=0, radius=0.5)
    iv, jf = np.asarray(ico.vertices, dtype=np.float64), np.asarray(ico.faces, dtype=np.int64)
    on_ico, _ = sample_surface(iv, jf, 50_000, 1)
    mesh_to_input = np.mean(0.5 - np.linalg.norm(on_ico, axis=1))
    on_sphere, _ = sample_surface(v, f, 50_000, 2)
    input_to_mesh = np.mean(np.sqrt(igl.point_mesh_squared_distance(on_sphere, iv, jf)[0]))
    expected = 0.5 * (mesh_to_input + input_to_mesh)
    assert _loss(target, iv, jf).item() == pytest.approx(expected, rel=0.05)


def test_reused_tree_matches_a_fresh_one(monkeypatch):
    v, f = _sphere(3)
    target = SurfaceTarget(v, f, n_samples=20_000, seed=0)
    moved = v * 1.001
    _loss(target, v, f, seed=0)  # builds the tree on v
    reused = _loss(target, moved, f, seed=1).item()  # same faces: found on v, measured on `moved`
    monkeypatch.setattr(surface_loss, "TREE_REUSE_CALLS", 0)
    fresh = _loss(SurfaceTarget(v, f, n_samples=20_000, seed=0), moved, f, seed=1).item()
    assert reused == pytest.approx(fresh, rel=1e-3)


def test_tree_is_rebuilt_when_faces_change():
    v, f = _sphere(2)
    target = SurfaceTarget(v, f, n_samples=5_000, seed=0)
    _loss(target, v, f)
    first = target._mesh_tree
    _loss(target, v, f[::-1].copy())
    assert target._mesh_tree is not first
    for _ in range(surface_loss.TREE_REUSE_CALLS + 1):
        _loss(target, v, f[::-1].copy())
    assert target._mesh_tree.calls <= surface_loss.TREE_REUSE_CALLS


def test_fit_without_image_weights_never_renders(monkeypatch):
    from tetweave_codec.fit import step
    from tetweave_codec.fit.config import Weights

    assert not Weights().uses_images()
    assert Weights.paper().uses_images()

    def fail(*args, **kwargs):
        raise AssertionError("rendered with every image weight at 0")

    monkeypatch.setattr(step, "render_maps", fail)
    from tetweave_codec.encoder import encode

    v, f = _sphere(3, radius=0.6)
    result = encode(v, f, points=256, quality="fast", iters=6, device="cpu", seed=0)
    assert result.stats["bytes"] > 0


def _square(angle: float = 0.0, half: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """A square (4 vertices, 2 faces) in the plane z = 0, tilted by `angle` radians about the x axis."""
    v = np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]], dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    v = v @ np.array([[1, 0, 0], [0, c, s], [0, -s, c]])
    return v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


@pytest.mark.parametrize("angle", [0.0, 0.2, 0.6])
def test_normal_term_is_one_minus_cosine_of_the_tilt(angle):
    v, f = _square()
    target = SurfaceTarget(v, f, n_samples=5_000, seed=0)
    tv, tf = _square(angle)
    terms = target.loss(torch.tensor(tv), torch.from_numpy(tf), torch.Generator().manual_seed(0))
    assert terms.normals.item() == pytest.approx(1.0 - np.cos(angle), abs=1e-9)
    # flipped winding (inward normals) costs nothing: the term is orientation-agnostic like the metric
    flipped = target.loss(torch.tensor(tv), torch.from_numpy(tf[:, ::-1].copy()), torch.Generator().manual_seed(0))
    assert flipped.normals.item() == pytest.approx(terms.normals.item(), abs=1e-9)


def test_normal_term_gradient_untilts_the_mesh():
    v, f = _square()
    target = SurfaceTarget(v, f, n_samples=5_000, seed=0)
    tv, tf = _square(0.3)
    vt = torch.tensor(tv, requires_grad=True)
    target.loss(vt, torch.from_numpy(tf), torch.Generator().manual_seed(0)).normals.backward()
    stepped = (vt - 0.05 * vt.grad / vt.grad.norm()).detach()
    after = target.loss(stepped, torch.from_numpy(tf), torch.Generator().manual_seed(0)).normals.item()
    assert after < 1.0 - np.cos(0.3) - 1e-4


def test_normal_term_gradient_is_bounded_on_a_sliver():
    # a face of doubled area 1e-12 (a needle): its unit normal's gradient would be ~1e12; the term bounds it
    from tetweave_codec.fit.surface_loss import MIN_NORMAL_CROSS, _unit_normals

    v = torch.tensor([[0.0, 0.0, 0.0], [1e-6, 0.0, 0.0], [0.0, 1e-6, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    v = v.double().requires_grad_(True)
    f = torch.tensor([[0, 1, 2], [0, 3, 4]])
    n = _unit_normals(v, f)
    assert torch.allclose(n[1], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))  # a normal face: unit
    assert n[0].norm().item() == pytest.approx(1e-12 / MIN_NORMAL_CROSS)  # the sliver: scaled, not normalized
    n[:, 2].sum().backward()
    assert torch.isfinite(v.grad).all() and v.grad.abs().max().item() < 1e4
