"""Tests of tetweave_codec.fit.losses: known values, paper formulas, gradient checks, degenerate input."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from scipy.spatial import Delaunay

from tetweave_codec.fit import losses

REGULAR_TET = torch.tensor([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=torch.float64)


def _random_tets(n: int, seed: int) -> torch.Tensor:
    """(n,4,3) float64 random tetrahedra with a volume bounded away from zero."""
    g = torch.Generator().manual_seed(seed)
    v = torch.randn(n * 3, 4, 3, generator=g, dtype=torch.float64)
    det = torch.linalg.det(v[:, 1:] - v[:, :1])
    return v[det.abs() > 0.05][:n]


def _paper_odt(v: np.ndarray) -> float:
    """|M_S - M_T| of one tet (4,3) with the explicit formulas of the paper's Appendix B (Tonon 2005)."""
    a, b, c = v[1] - v[0], v[2] - v[0], v[3] - v[0]
    d = np.linalg.det(np.stack([a, b, c], axis=-1))
    volume = abs(d) / 6
    center = v[0] + (a @ a * np.cross(b, c) + b @ b * np.cross(c, a) + c @ c * np.cross(a, b)) / (2 * d)
    radius2 = np.sum((center - v[0]) ** 2)
    m_s = 2 / 5 * volume * radius2
    rel = v - center
    s = [
        np.sum(rel[:, k] ** 2) + sum(rel[i, k] * rel[j, k] for i in range(4) for j in range(i + 1, 4)) for k in range(3)
    ]
    ix, iy, iz = volume / 10 * (s[1] + s[2]), volume / 10 * (s[0] + s[2]), volume / 10 * (s[0] + s[1])
    return abs(m_s - (ix + iy + iz))


# --- ODT ---


def test_odt_matches_paper_formulas_on_random_tets():
    v = _random_tets(50, seed=1)
    points = v.reshape(-1, 3)
    tets = torch.arange(points.shape[0]).reshape(-1, 4)
    ours = losses.odt_energy(points, tets).numpy()
    paper = np.array([_paper_odt(t) for t in v.numpy()])
    assert paper.min() > 1e-6  # random tets are far from regular: the comparison is not 0 == 0
    np.testing.assert_allclose(ours, paper, rtol=1e-9)


def test_odt_relative_is_energy_over_sphere_moment():
    v = _random_tets(30, seed=2)
    points = v.reshape(-1, 3)
    tets = torch.arange(points.shape[0]).reshape(-1, 4)
    energy = losses.odt_energy(points, tets)
    rel = losses.odt_relative_energy(points, tets)
    # circumcenters from the linear system 2 (v_i - v_0) . x = |v_i|^2 - |v_0|^2, independent of _odt_terms
    edges = v[:, 1:] - v[:, :1]
    rhs = (v[:, 1:] ** 2).sum(-1) - (v[:, :1] ** 2).sum(-1)
    center = torch.linalg.solve(2 * edges, rhs)
    det = torch.linalg.det(v[:, 1:] - v[:, :1])
    assert torch.allclose(((v - center[:, None]) ** 2).sum(-1), ((v[:, 0] - center) ** 2).sum(-1)[:, None])
    m_s = 0.4 * det.abs() / 6 * ((v[:, 0] - center) ** 2).sum(-1)
    torch.testing.assert_close(rel, energy / m_s)
    assert bool((rel >= 0).all()) and bool((rel <= 4).all())


@pytest.mark.parametrize("reduction", losses.ODT_REDUCTIONS)
def test_odt_vanishes_for_regular_tet_any_pose(reduction):
    g = torch.Generator().manual_seed(0)
    rot, _ = torch.linalg.qr(torch.randn(3, 3, generator=g, dtype=torch.float64))
    points = 0.37 * REGULAR_TET @ rot.T + torch.tensor([0.3, -2.0, 5.0], dtype=torch.float64)
    value = losses.odt_loss(points, torch.tensor([[0, 1, 2, 3]]), reduction=reduction)
    assert abs(float(value)) < 1e-12


def test_odt_reductions_relate():
    v = _random_tets(20, seed=3)
    points = v.reshape(-1, 3)
    tets = torch.arange(points.shape[0]).reshape(-1, 4)
    e = losses.odt_energy(points, tets)
    torch.testing.assert_close(losses.odt_loss(points, tets, "sum"), e.sum())
    torch.testing.assert_close(losses.odt_loss(points, tets, "mean"), e.mean())
    with pytest.raises(ValueError):
        losses.odt_loss(points, tets, "median")


def test_odt_invariant_to_vertex_order_and_orientation():
    v = _random_tets(10, seed=4)
    points = v.reshape(-1, 3)
    tets = torch.arange(points.shape[0]).reshape(-1, 4)
    flipped = tets[:, [1, 0, 3, 2]]
    torch.testing.assert_close(losses.odt_energy(points, tets), losses.odt_energy(points, flipped))


def test_odt_relative_independent_of_scale_and_count():
    rng = np.random.default_rng(0)
    values = []
    for n in (2000, 8000):
        x = rng.uniform(-1, 1, size=(n, 3))
        tets = torch.from_numpy(Delaunay(x).simplices.astype(np.int64))
        values.append(float(losses.odt_loss(torch.from_numpy(x), tets)))
        scaled = float(losses.odt_loss(torch.from_numpy(x * 0.01 + 3.0), tets))
        assert scaled == pytest.approx(values[-1], rel=1e-6)
    assert values[0] == pytest.approx(values[1], rel=0.15)
    assert 0.2 < values[0] < 2.0


@pytest.mark.parametrize("reduction", losses.ODT_REDUCTIONS)
def test_odt_gradcheck(reduction):
    v = _random_tets(6, seed=5)
    points = v.reshape(-1, 3).clone().requires_grad_(True)
    tets = torch.arange(points.shape[0]).reshape(-1, 4)
    assert torch.autograd.gradcheck(lambda p: losses.odt_loss(p, tets, reduction), (points,))


def test_odt_gradient_moves_towards_regular():
    points = (
        REGULAR_TET + 0.2 * torch.randn(4, 3, generator=torch.Generator().manual_seed(6), dtype=torch.float64)
    ).requires_grad_(True)
    tets = torch.tensor([[0, 1, 2, 3]])
    value = losses.odt_loss(points, tets)
    value.backward()
    before = float(value.detach())
    after = float(losses.odt_loss(points.detach() - 1e-3 * points.grad, tets))
    assert after < before


@pytest.mark.parametrize("reduction", losses.ODT_REDUCTIONS)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_odt_degenerate_tets_are_finite(reduction, dtype):
    points = torch.tensor(
        [
            [0, 0, 0],
            [1, 0, 0],
            [0, 1, 0],
            [1, 1, 0],  # flat, cocircular
            [0, 0, 0],
            [1, 0, 0],
            [0, 1, 0],
            [0.3, 0.2, 0],  # flat, not cocircular
            [0, 0, 0],
            [1, 0, 0],
            [2, 0, 0],
            [3, 0, 0],  # collinear
            [0.5, 0.5, 0.5],
            [0.5, 0.5, 0.5],
            [0.5, 0.5, 0.5],
            [0.5, 0.5, 0.5],  # coincident
            [0, 0, 0],
            [1, 0, 0],
            [0, 1, 0],
            [0.3, 0.2, 1e-9],  # almost flat
        ],
        dtype=dtype,
        requires_grad=True,
    )
    tets = torch.arange(points.shape[0]).reshape(-1, 4)
    value = losses.odt_loss(points, tets, reduction)
    value.backward()
    assert torch.isfinite(value)
    assert bool(torch.isfinite(points.grad).all())
    energy = losses.odt_relative_energy if reduction == "relative" else losses.odt_energy
    per_tet = energy(points, tets).detach()
    assert bool(torch.isfinite(per_tet).all())
    if reduction == "relative":
        assert bool((per_tet <= 4 + 1e-4).all())
        assert float(per_tet[1]) == pytest.approx(4.0, rel=1e-4)  # flat tet: circumcenter at infinity


def test_odt_empty():
    points = torch.rand(5, 3, requires_grad=True)
    value = losses.odt_loss(points, torch.zeros((0, 4), dtype=torch.long))
    value.backward()
    assert value.item() == 0.0 and bool((points.grad == 0).all())


# --- fairness ---


def test_fairness_equilateral_is_zero():
    v = torch.tensor([[0.0, 0, 0], [1, 0, 0], [0.5, math.sqrt(3) / 2, 0]], dtype=torch.float64)
    assert float(losses.fairness_loss(v, torch.tensor([[0, 1, 2]]))) == pytest.approx(0.0, abs=1e-14)


def test_fairness_right_isoceles_by_hand():
    # angles pi/2, pi/4, pi/4: ((pi/6)^2 + 2 (pi/12)^2) / 3 = pi^2 / 72
    v = torch.tensor([[0.0, 0, 0], [2, 0, 0], [0, 2, 0]], dtype=torch.float64)
    value = float(losses.fairness_loss(v, torch.tensor([[0, 1, 2]])))
    assert value == pytest.approx(math.pi**2 / 72, rel=1e-12)


def test_fairness_mean_over_faces():
    v = torch.tensor([[0.0, 0, 0], [2, 0, 0], [0, 2, 0], [1, 0, 0], [1.5, math.sqrt(3) / 2, 0]], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 2], [0, 3, 4]])
    angles = losses.triangle_angles(v, faces)
    torch.testing.assert_close(angles.sum(-1), torch.full((2,), math.pi, dtype=torch.float64))
    expected = ((angles - math.pi / 3) ** 2).mean()
    torch.testing.assert_close(losses.fairness_loss(v, faces), expected)


def test_fairness_gradcheck():
    g = torch.Generator().manual_seed(7)
    v = torch.randn(6, 3, generator=g, dtype=torch.float64, requires_grad=True)
    faces = torch.tensor([[0, 1, 2], [2, 3, 4], [1, 4, 5], [0, 5, 3]])
    assert torch.autograd.gradcheck(lambda x: losses.fairness_loss(x, faces), (v,))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fairness_degenerate_no_nan(dtype):
    v = torch.tensor(
        [
            [0, 0, 0],
            [1, 0, 0],
            [2, 0, 0],  # collinear
            [3, 3, 3],
            [3, 3, 3],
            [4, 3, 3],  # two coincident vertices
            [5, 5, 5],
            [5, 5, 5],
            [5, 5, 5],  # all coincident
            [0, 1, 0],
            [1, 1, 0],
            [0, 2, 0],
        ],
        dtype=dtype,
        requires_grad=True,
    )
    faces = torch.arange(12).reshape(-1, 3)
    value = losses.fairness_loss(v, faces)
    value.backward()
    assert torch.isfinite(value) and bool(torch.isfinite(v.grad).all())
    # collinear face (0, 0, pi) and the right isosceles face are kept, the ones with zero-length edges skipped
    expected = ((2 * (math.pi / 3) ** 2 + (2 * math.pi / 3) ** 2) / 3 + math.pi**2 / 72) / 2
    assert value.item() == pytest.approx(expected, rel=1e-5)


def test_fairness_empty_and_all_degenerate():
    v = torch.zeros(3, 3, requires_grad=True)
    for faces in (torch.zeros((0, 3), dtype=torch.long), torch.tensor([[0, 1, 2]])):
        value = losses.fairness_loss(v, faces)
        value.backward()
        assert value.item() == 0.0 and bool(torch.isfinite(v.grad).all())


# --- sign ---


def test_sign_loss_known_value():
    s = torch.tensor([-0.5, 0.25, 1.0, 2.0], dtype=torch.float64)
    edges = torch.tensor([[0, 1], [1, 2], [2, 0], [3, 2]])  # sign changes on (0,1) and (2,0)
    sig = torch.sigmoid

    def bce(p, y):
        return -(y * math.log(p) + (1 - y) * math.log(1 - p))

    expected = (
        bce(float(sig(s[0])), 1) + bce(float(sig(s[1])), 0) + bce(float(sig(s[2])), 0) + bce(float(sig(s[0])), 1)
    ) / 2
    assert float(losses.sign_loss(s, edges)) == pytest.approx(expected, rel=1e-12)


def test_sign_loss_symmetric_in_edge_direction():
    g = torch.Generator().manual_seed(8)
    s = torch.randn(20, generator=g, dtype=torch.float64)
    edges = torch.randint(0, 20, (50, 2), generator=g)
    torch.testing.assert_close(losses.sign_loss(s, edges), losses.sign_loss(s, edges.flip(1)))


def test_sign_loss_gradcheck():
    g = torch.Generator().manual_seed(9)
    signs = torch.tensor([1.0, -1.0], dtype=torch.float64).repeat(6)
    s = (torch.rand(12, generator=g, dtype=torch.float64) + 0.2) * signs
    s.requires_grad_(True)
    edges = torch.randint(0, 12, (40, 2), generator=g)
    assert torch.autograd.gradcheck(lambda x: losses.sign_loss(x, edges), (s,))


def test_sign_loss_gradient_pulls_towards_neighbour_sign():
    s = torch.tensor([-0.3, 0.4], requires_grad=True)
    losses.sign_loss(s, torch.tensor([[0, 1]])).backward()
    assert s.grad[0] < 0 and s.grad[1] > 0  # descent raises s0 (towards outside) and lowers s1


def test_sign_loss_no_change_is_zero():
    s = torch.tensor([1.0, 2.0, 3.0], requires_grad=True)
    value = losses.sign_loss(s, torch.tensor([[0, 1], [1, 2]]))
    value.backward()
    assert value.item() == 0.0 and bool((s.grad == 0).all())


# --- images ---


def _render(mask, depth, normals, face_id) -> SimpleNamespace:
    """A stand-in for render.RenderMaps: the fields image_loss reads."""
    return SimpleNamespace(
        mask=torch.tensor(mask, dtype=torch.float64),
        depth=torch.tensor(depth, dtype=torch.float64),
        normals=torch.tensor(normals, dtype=torch.float64),
        fragments=SimpleNamespace(face_id=torch.tensor(face_id)),
    )


def _target(mask, depth, normals) -> SimpleNamespace:
    return SimpleNamespace(
        mask=torch.tensor(mask, dtype=torch.float64),
        depth=torch.tensor(depth, dtype=torch.float64),
        normals=torch.tensor(normals, dtype=torch.float64),
    )


UNIT = SimpleNamespace(mask=1.0, depth=1.0, normals=1.0)
X, Y, Z = [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]


def _three_pixels():
    """One view of 1 x 3 pixels: both see a surface at pixel 0, only the target at 1, only the render at 2."""
    maps = _render([[[0.75, 0.0, 0.5]]], [[[2.0, 0.0, 5.0]]], [[[Z, [0.0] * 3, X]]], [[[0, -1, 3]]])
    target = _target([[[1.0, 1.0, 0.0]]], [[[2.5, 3.0, 0.0]]], [[[Y, Z, [0.0] * 3]]])
    return maps, target


def test_image_loss_by_hand():
    maps, target = _three_pixels()
    total, parts = losses.image_loss(maps, target, SimpleNamespace(mask=2.0, depth=3.0, normals=5.0))
    mask = (0.25 + 1.0 + 0.5) / 3  # L1 over all pixels, whoever sees what
    depth = (math.sqrt(0.5**2 + 1e-8) + 2 * math.sqrt(1e-8)) / 3  # |.| (sqrt(x + 1e-8)) at pixel 0 only
    normals = 2.0 / 3  # |Z - Y|^2 = 2 at pixel 0 only
    assert parts["mask"] == pytest.approx(2.0 * mask, rel=1e-12)
    assert parts["depth"] == pytest.approx(3.0 * depth, rel=1e-12)
    assert parts["normals"] == pytest.approx(5.0 * normals, rel=1e-12)
    assert all(type(v) is float for v in parts.values())
    assert float(total) == pytest.approx(2.0 * mask + 3.0 * depth + 5.0 * normals, rel=1e-12)


def test_image_loss_compares_depth_and_normals_only_where_both_see_a_surface():
    maps, target = _three_pixels()
    _, parts = losses.image_loss(maps, target, UNIT)
    # errors where only one side sees a surface change nothing (the mask term handles silhouettes)
    maps.depth[0, 0, 1:] = torch.tensor([100.0, -7.0], dtype=torch.float64)
    maps.normals[0, 0, 1:] = -maps.normals[0, 0, 1:] + 3.0
    target.depth[0, 0, 2], target.normals[0, 0, 2] = 9.0, torch.tensor(X, dtype=torch.float64)
    _, moved = losses.image_loss(maps, target, UNIT)
    assert moved == parts
    # an error where both see the surface does count
    maps.depth[0, 0, 0] = 2.25
    _, closer = losses.image_loss(maps, target, UNIT)
    assert closer["depth"] == pytest.approx((math.sqrt(0.25**2 + 1e-8) + 2e-4) / 3, rel=1e-12)
    # the paper's masking by the target alone would have compared pixel 1 (depth 0 against 3): not what we do
    paper = float(losses.depth_loss(maps.depth, target.depth, target.mask, norm="l2"))
    assert paper > closer["depth"] + 0.9


def test_image_loss_perfect_match_leaves_only_the_depth_epsilon():
    maps, target = _three_pixels()
    same = _render(target.mask.tolist(), target.depth.tolist(), target.normals.tolist(), [[[0, 1, -1]]])
    total, parts = losses.image_loss(same, target, SimpleNamespace(mask=10.0, depth=250.0, normals=1.0))
    assert parts["mask"] == 0.0 and parts["normals"] == 0.0
    assert parts["depth"] == pytest.approx(250.0 * 1e-4, rel=1e-9)  # sqrt(0 + 1e-8) per pixel
    assert float(total) == pytest.approx(parts["depth"])


def test_image_loss_is_linear_in_the_weights():
    g = torch.Generator().manual_seed(0)
    b, h, w = 2, 6, 5
    maps = _render(
        torch.rand(b, h, w, generator=g).tolist(),
        torch.rand(b, h, w, generator=g).tolist(),
        torch.nn.functional.normalize(torch.randn(b, h, w, 3, generator=g), dim=-1).tolist(),
        torch.randint(-1, 4, (b, h, w), generator=g).tolist(),
    )
    target = _target(
        (torch.rand(b, h, w, generator=g) > 0.4).double().tolist(),
        torch.rand(b, h, w, generator=g).tolist(),
        torch.nn.functional.normalize(torch.randn(b, h, w, 3, generator=g), dim=-1).tolist(),
    )
    _, unit = losses.image_loss(maps, target, UNIT)
    assert min(unit.values()) > 0
    weights = SimpleNamespace(mask=0.5, depth=25.0, normals=0.0)
    total, parts = losses.image_loss(maps, target, weights)
    for key in ("mask", "depth", "normals"):
        assert parts[key] == pytest.approx(getattr(weights, key) * unit[key], rel=1e-12)
    assert float(total) == pytest.approx(sum(parts.values()), rel=1e-12)


def test_image_loss_gradients_flow_where_the_terms_look():
    maps, target = _three_pixels()
    for name in ("mask", "depth", "normals"):
        getattr(maps, name).requires_grad_(True)
    total, _ = losses.image_loss(maps, target, UNIT)
    total.backward()
    assert bool((maps.mask.grad != 0).all())  # every pixel's coverage is compared
    assert maps.depth.grad[0, 0, 0] != 0 and bool((maps.depth.grad[0, 0, 1:] == 0).all())
    assert bool((maps.normals.grad[0, 0, 0] != 0).any()) and bool((maps.normals.grad[0, 0, 1:] == 0).all())
    # descent on the depth moves the render towards the target's 2.5
    assert maps.depth.grad[0, 0, 0] < 0


def test_sign_loss_zero_counts_as_outside():
    s = torch.tensor([0.0, -1.0, 0.0, 2.0])
    expected = losses.sign_loss(torch.tensor([1e-30, -1.0]), torch.tensor([[0, 1]]))
    torch.testing.assert_close(losses.sign_loss(s, torch.tensor([[0, 1], [2, 3]])), expected)
