"""geometry.triangles: cross products, areas and normals (numpy and torch agree), area-weighted surface samples."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tetweave_codec.geometry.triangles import (
    face_areas,
    face_cross,
    face_normals,
    sample_surface,
    triangle_cross,
    unit_vectors,
)

# a right triangle in z = 0 (area 2, normal +z), the same one flipped (normal -z), a tilted one, a degenerate one
VERTICES = np.array(
    [[0, 0, 0], [2, 0, 0], [0, 2, 0], [1, 0, 0], [0, 1, 1], [3, 3, 3], [4, 4, 4], [5, 5, 5]], dtype=np.float64
)
FACES = np.array([[0, 1, 2], [0, 2, 1], [0, 3, 4], [5, 6, 7]])


def test_known_areas_and_normals():
    np.testing.assert_allclose(face_areas(VERTICES, FACES), [2.0, 2.0, np.sqrt(2) / 2, 0.0])
    n = face_normals(VERTICES, FACES)
    np.testing.assert_allclose(n[:3], [[0, 0, 1], [0, 0, -1], [0, -1 / np.sqrt(2), 1 / np.sqrt(2)]])
    assert np.array_equal(n[3], [0.0, 0.0, 0.0])  # degenerate: zero, not NaN
    np.testing.assert_allclose(face_cross(VERTICES, FACES)[0], [0, 0, 4])  # twice the area along the normal
    np.testing.assert_array_equal(triangle_cross(VERTICES[FACES]), face_cross(VERTICES, FACES))


def test_torch_matches_numpy_and_is_differentiable():
    v = torch.tensor(VERTICES, requires_grad=True)
    f = torch.from_numpy(FACES)
    for fn in (face_cross, face_areas, face_normals):
        out = fn(v, f)
        assert isinstance(out, torch.Tensor)
        np.testing.assert_allclose(out.detach().numpy(), fn(VERTICES, FACES), atol=1e-12)
    torch.testing.assert_close(triangle_cross(v[f]), face_cross(v, f))
    face_areas(v, f)[0].backward()
    # d area / d apex of the right triangle: half the length of the opposite edge, pointing away from it
    torch.testing.assert_close(v.grad[2], torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    z = unit_vectors(torch.zeros(2, 3))
    assert torch.equal(z, torch.zeros(2, 3))


def test_sample_surface_is_area_weighted_and_on_the_faces():
    v = np.array([[0, 0, 0], [3, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1]], dtype=float)
    f = np.array([[0, 1, 2], [3, 4, 5]])  # areas 1.5 and 0.5
    p, face = sample_surface(v, f, 40_000, seed=1)
    assert np.mean(face == 0) == pytest.approx(0.75, abs=0.01)
    assert np.allclose(p[face == 0, 2], 0) and np.allclose(p[face == 1, 2], 1)
    assert np.all(p[face == 0, 0] / 3 + p[face == 0, 1] <= 1 + 1e-12)
    # uniform inside a face: the mean of the samples is the centroid
    np.testing.assert_allclose(p[face == 1].mean(0), v[3:].mean(0), atol=0.01)
    with pytest.raises(ValueError):
        sample_surface(v, np.array([[0, 0, 1]]), 10)


def test_sample_surface_seed_or_generator():
    v, f = VERTICES, FACES[:3]
    a, fa = sample_surface(v, f, 100, seed=7)
    b, fb = sample_surface(v, f, 100, seed=np.random.default_rng(7))
    assert np.array_equal(a, b) and np.array_equal(fa, fb)
    rng = np.random.default_rng(7)
    first, _ = sample_surface(v, f, 100, rng)
    second, _ = sample_surface(v, f, 100, rng)  # the generator advanced
    assert not np.array_equal(first, second)
    assert not np.isin(3, sample_surface(VERTICES, FACES, 1000, seed=0)[1])  # a zero-area face is never picked
