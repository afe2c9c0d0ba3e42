"""Real spherical harmonics: counts, orthonormality, agreement with scipy, parity, torch/numpy agreement."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.special import sph_harm_y

from tetweave_codec.geometry.sh import (
    degree_from_num_coeffs,
    num_coeffs,
    sh_basis,
    sh_eval,
    sh_parity,
)


def _quadrature(n_theta: int = 12, n_phi: int = 24):
    """Gauss-Legendre in cos(theta) x uniform in phi: exact for polynomials of degree < 2 n_theta on S^2."""
    z, w = np.polynomial.legendre.leggauss(n_theta)
    phi = np.arange(n_phi) * 2 * np.pi / n_phi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz**2)
    dirs = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    weights = np.repeat(w, n_phi) * (2 * np.pi / n_phi)
    return dirs, weights


def _random_dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("degree,q", [(-1, 0), (0, 1), (1, 4), (2, 9), (3, 16)])
def test_num_coeffs(degree, q):
    assert num_coeffs(degree) == q
    assert degree_from_num_coeffs(q) == degree
    assert sh_basis(_random_dirs(5), degree).shape == (5, q)


@pytest.mark.parametrize("bad", [-2, 4, 1.5, True])
def test_bad_degree_rejected(bad):
    with pytest.raises(ValueError):
        num_coeffs(bad)


def test_bad_coefficient_count_rejected():
    with pytest.raises(ValueError):
        degree_from_num_coeffs(5)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_orthonormal_on_the_sphere(degree):
    dirs, w = _quadrature()
    basis = sh_basis(dirs, degree)
    gram = basis.T @ (basis * w[:, None])
    np.testing.assert_allclose(gram, np.eye(num_coeffs(degree)), atol=1e-12)


def test_matches_scipy_complex_harmonics():
    """Y_lm real (no Condon-Shortley phase) = sqrt(2) (-1)^m Re/Im of scipy's complex Y_l^|m|."""
    dirs = _random_dirs(200, seed=1)
    theta = np.arccos(np.clip(dirs[:, 2], -1, 1))
    phi = np.arctan2(dirs[:, 1], dirs[:, 0])
    basis = sh_basis(dirs, 3)
    for l in range(4):
        for m in range(-l, l + 1):
            y = sph_harm_y(l, abs(m), theta, phi)  # with Condon-Shortley phase (-1)^m
            if m > 0:
                expected = np.sqrt(2) * (-1) ** m * y.real
            elif m < 0:
                expected = np.sqrt(2) * (-1) ** m * y.imag
            else:
                expected = y.real
            np.testing.assert_allclose(basis[:, l * l + l + m], expected, atol=1e-12, err_msg=f"l={l} m={m}")


def test_parity_of_opposite_direction():
    dirs = _random_dirs(100, seed=2)
    np.testing.assert_allclose(sh_basis(-dirs, 3), sh_basis(dirs, 3) * sh_parity(3), atol=1e-15)
    assert sh_parity(2).tolist() == [1, -1, -1, -1, 1, 1, 1, 1, 1]


def test_direction_convention_polar_angle_from_z():
    # Y_10 is proportional to cos(theta): largest along +z, zero on the equator.
    up, east = np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]])
    assert sh_basis(up, 1)[0, 2] == pytest.approx(0.4886025119029199)
    assert sh_basis(east, 1)[0, 2] == 0.0
    assert sh_basis(east, 1)[0, 3] == pytest.approx(0.4886025119029199)  # Y_11 ~ x


def test_torch_and_numpy_agree_and_eval_is_linear():
    dirs = _random_dirs(64, seed=3)
    coeffs = np.random.default_rng(4).normal(size=(64, 16))
    b_np = sh_basis(dirs, 3)
    b_t = sh_basis(torch.tensor(dirs), 3)
    assert isinstance(b_t, torch.Tensor) and b_t.dtype == torch.float64
    np.testing.assert_allclose(b_t.numpy(), b_np, atol=1e-15)
    np.testing.assert_allclose(sh_eval(dirs, coeffs), (b_np * coeffs).sum(1), atol=1e-12)
    np.testing.assert_allclose(sh_eval(torch.tensor(dirs), torch.tensor(coeffs)).numpy(), (b_np * coeffs).sum(1))
    assert np.all(sh_eval(dirs, np.zeros((64, 0))) == 0)


def test_gradients_flow_through_torch_basis():
    dirs = torch.tensor(_random_dirs(8, seed=5), requires_grad=True)
    coeffs = torch.randn(8, 9, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda d, c: sh_eval(d, c), (dirs, coeffs))
