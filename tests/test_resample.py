"""Tests of tetweave_codec.fit.resample: importance grids, sampling, point location, interpolation, resample."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import ConvexHull, Delaunay

from tetweave_codec.fit import resample as rs

LO = torch.tensor([-1.0, -1.0, -1.0])
HI = torch.tensor([1.0, 1.0, 1.0])


def _voxel_center(i: int, j: int, k: int, r: int) -> torch.Tensor:
    return LO + (torch.tensor([i, j, k], dtype=torch.float32) + 0.5) * (HI - LO) / r


def _in_hull(points: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(K,) bool, q inside the convex hull of points (independent of the code under test)."""
    eq = ConvexHull(points).equations
    return (q @ eq[:, :3].T + eq[:, 3] <= 0).all(1)


def _linear(x: np.ndarray) -> np.ndarray:
    return np.stack([2 * x[:, 0] - x[:, 1] + 3 * x[:, 2] + 1, -x[:, 0] + 0.5 * x[:, 2]], axis=1)


@pytest.fixture(scope="module")
def grid_points():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, size=(3000, 3))
    tets = Delaunay(pts).simplices.astype(np.int64)
    return pts, tets


# --- importance ---


def test_voxel_importance_known_splat():
    r = 4
    pts = torch.stack(
        [
            _voxel_center(0, 0, 0, r),
            _voxel_center(0, 0, 0, r) + 0.1,
            _voxel_center(3, 1, 2, r),
            torch.tensor([5.0, 0.0, 0.0]),  # outside: ignored
            HI,
        ]
    )  # on the max corner: last voxel
    err = torch.tensor([1.0, 3.0, 0.5, 100.0, 7.0])
    grid = rs.voxel_importance(pts, err, LO, HI, resolution=r)
    assert grid.shape == (r, r, r) and grid.dtype == torch.float32
    expected = torch.zeros(r, r, r)
    expected[0, 0, 0] = 2.0  # mean of 1 and 3
    expected[3, 1, 2] = 0.5
    expected[3, 3, 3] = 7.0
    torch.testing.assert_close(grid, expected)


def test_voxel_importance_matches_naive_mean():
    g = torch.Generator().manual_seed(1)
    pts = torch.rand(5000, 3, generator=g) * 1.8 - 0.9
    err = torch.rand(5000, generator=g)
    r = 8
    grid = rs.voxel_importance(pts, err, [-0.9, -0.9, -0.9], [0.9, 0.9, 0.9], resolution=r)
    ijk = np.clip(np.floor((pts.numpy().astype(np.float64) + 0.9) / 1.8 * r).astype(int), 0, r - 1)
    sums = np.zeros((r, r, r))
    counts = np.zeros((r, r, r))
    np.add.at(sums, tuple(ijk.T), err.numpy())
    np.add.at(counts, tuple(ijk.T), 1)
    naive = np.divide(sums, counts, out=np.zeros_like(sums), where=counts > 0)
    np.testing.assert_allclose(grid.numpy(), naive, rtol=1e-6)
    empty = rs.voxel_importance(torch.zeros(0, 3), torch.zeros(0), LO, HI, resolution=r)
    assert float(empty.abs().sum()) == 0.0


def test_sample_proportions_match_grid():
    r = 4
    grid = torch.zeros(r, r, r)
    cells = [(0, 0, 0), (1, 2, 3), (3, 3, 1)]
    weights = [1.0, 2.0, 5.0]
    for cell, w in zip(cells, weights, strict=True):
        grid[cell] = w
    k = 40000
    pts = rs.sample_from_importance(grid, LO, HI, k, torch.Generator().manual_seed(2))
    assert pts.shape == (k, 3) and pts.dtype == torch.float32
    ijk = torch.floor((pts - LO) / (HI - LO) * r).long()
    counts = {cell: int((ijk == torch.tensor(cell)).all(1).sum()) for cell in cells}
    assert sum(counts.values()) == k  # nothing lands in a zero voxel
    for cell, w in zip(cells, weights, strict=True):
        p = w / sum(weights)
        sigma = np.sqrt(k * p * (1 - p))
        assert abs(counts[cell] - k * p) < 4 * sigma


def test_sample_stratified_within_voxel():
    grid = torch.zeros(2, 2, 2)
    grid[1, 0, 1] = 1.0
    pts = rs.sample_from_importance(grid, LO, HI, 8, torch.Generator().manual_seed(3), dtype=torch.float64)
    # the voxel [0,1] x [-1,0] x [0,1] is split into 2^3 sub-cells, one point each
    lo = torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64)
    assert bool(((pts >= lo) & (pts <= lo + 1)).all())
    sub = torch.floor((pts - lo) * 2).long()
    codes = sub[:, 0] * 4 + sub[:, 1] * 2 + sub[:, 2]
    assert sorted(codes.tolist()) == list(range(8))


def test_sample_uniform_density_is_uniform():
    """A constant grid gives uniform points: each octant of the box gets 1/8 of them."""
    pts = rs.sample_from_importance(torch.ones(8, 8, 8), LO, HI, 16000, torch.Generator().manual_seed(4))
    octant = (pts[:, 0] > 0).long() * 4 + (pts[:, 1] > 0).long() * 2 + (pts[:, 2] > 0).long()
    counts = torch.bincount(octant, minlength=8).double()
    assert float((counts - 2000).abs().max()) < 4 * np.sqrt(2000 * 7 / 8)


def test_sample_deterministic_and_degenerate_grid():
    grid = torch.rand(6, 6, 6, generator=torch.Generator().manual_seed(5))
    a = rs.sample_from_importance(grid, LO, HI, 500, torch.Generator().manual_seed(6))
    b = rs.sample_from_importance(grid, LO, HI, 500, torch.Generator().manual_seed(6))
    c = rs.sample_from_importance(grid, LO, HI, 500, torch.Generator().manual_seed(7))
    assert torch.equal(a, b) and not torch.equal(a, c)
    zero = rs.sample_from_importance(torch.zeros(4, 4, 4), LO, HI, 100, torch.Generator().manual_seed(0))
    assert zero.shape == (100, 3) and bool(((zero >= LO) & (zero <= HI)).all())
    assert rs.sample_from_importance(grid, LO, HI, 0, torch.Generator()).shape == (0, 3)


# --- point location and interpolation ---


def test_tet_neighbors_match_qhull():
    rng = np.random.default_rng(8)
    d = Delaunay(rng.uniform(size=(400, 3)))
    np.testing.assert_array_equal(rs.tet_neighbors(d.simplices), d.neighbors)


def test_locate_in_tets(grid_points):
    pts, tets = grid_points
    rng = np.random.default_rng(9)
    q = rng.uniform(-0.95, 0.95, size=(2000, 3))
    tet, bary, nearest = rs.locate_in_tets(pts, tets, q)
    inside = _in_hull(pts, q)
    np.testing.assert_array_equal(tet >= 0, inside)
    found = tet >= 0
    assert np.all(bary[found] >= 0)
    np.testing.assert_allclose(bary[found].sum(1), 1.0)
    rebuilt = np.einsum("ki,kid->kd", bary[found], pts[tets[tet[found]]])
    np.testing.assert_allclose(rebuilt, q[found], atol=1e-12)
    dist = np.linalg.norm(pts[None] - q[:50, None], axis=2)
    np.testing.assert_array_equal(nearest[:50], dist.argmin(1))


def test_interpolate_reproduces_linear_functions(grid_points):
    pts, tets = grid_points
    rng = np.random.default_rng(10)
    q = rng.uniform(-0.9, 0.9, size=(3000, 3))
    inside = _in_hull(pts, q)
    assert inside.mean() > 0.9
    out = rs.interpolate_in_tets(pts, tets, _linear(pts), q)
    np.testing.assert_allclose(out[inside], _linear(q)[inside], atol=1e-12)
    # torch values: result on their dtype/device; 1-D values stay 1-D
    out_t = rs.interpolate_in_tets(
        torch.from_numpy(pts), torch.from_numpy(tets), torch.from_numpy(_linear(pts)[:, 0]).float(), torch.from_numpy(q)
    )
    assert out_t.dtype == torch.float32 and out_t.shape == (3000,)
    np.testing.assert_allclose(out_t.numpy()[inside], _linear(q)[inside, 0], atol=1e-5)


def test_interpolate_outside_takes_nearest_point(grid_points):
    pts, tets = grid_points
    q = np.array([[3.0, 0.0, 0.0], [0.0, -2.5, 1.0]])
    out = rs.interpolate_in_tets(pts, tets, _linear(pts), q)
    nearest = np.linalg.norm(pts[None] - q[:, None], axis=2).argmin(1)
    np.testing.assert_array_equal(out, _linear(pts)[nearest])


def test_interpolate_with_a_delaunay_grid():
    from tetweave_codec.geometry.delaunay import delaunay

    rng = np.random.default_rng(11)
    d = rng.normal(size=(2000, 3))
    pts = d / np.linalg.norm(d, axis=1, keepdims=True) * (0.7 + 0.05 * rng.uniform(-1, 1, (2000, 1)))
    pts[:200] = rng.uniform(-1, 1, (200, 3))
    tets = delaunay(pts)
    q = pts[rng.choice(2000, 1000)] + rng.normal(scale=0.01, size=(1000, 3))
    inside = _in_hull(pts, q)
    out = rs.interpolate_in_tets(pts, tets, _linear(pts), q)
    np.testing.assert_allclose(out[inside], _linear(q)[inside], atol=1e-10)


# --- resample ---


def _state(grid_points):
    pts, tets = grid_points
    lin = _linear(pts)
    points = torch.from_numpy(pts).float()
    s = torch.from_numpy(lin[:, 0]).float()
    c = torch.from_numpy(np.concatenate([lin[:, 1:], -lin[:, :1], np.zeros((len(pts), 2))], 1)).float()
    return points, s, c, torch.from_numpy(tets)


def test_resample_keeps_and_fills(grid_points):
    points, s, c, tets = _state(grid_points)
    keep = torch.zeros(len(points), dtype=torch.bool)
    keep[::3] = True
    grid = torch.zeros(8, 8, 8)
    grid[2:6, 2:6, 2:6] = torch.rand(4, 4, 4, generator=torch.Generator().manual_seed(12)) + 0.1
    lo, hi = torch.tensor([-0.8, -0.8, -0.8]), torch.tensor([0.8, 0.8, 0.8])
    n_target = 2500
    p2, s2, c2 = rs.resample(points, s, c, tets, keep, grid, (lo, hi), n_target, torch.Generator().manual_seed(13))
    n_keep = int(keep.sum())
    assert p2.shape == (n_target, 3) and s2.shape == (n_target,) and c2.shape == (n_target, 4)
    assert p2.dtype == points.dtype and s2.dtype == s.dtype and c2.dtype == c.dtype
    assert torch.equal(p2[:n_keep], points[keep]) and torch.equal(s2[:n_keep], s[keep])
    assert torch.equal(c2[:n_keep], c[keep])
    new = p2[n_keep:].double()
    # new points lie in the voxels with importance, i.e. in [-0.4, 0.4]^3
    assert bool((new.abs() <= 0.4 + 1e-6).all())
    # s and c are barycentric interpolations of the old (linear) values
    lin = _linear(new.numpy())
    np.testing.assert_allclose(s2[n_keep:].numpy(), lin[:, 0], atol=1e-5)
    np.testing.assert_allclose(c2[n_keep:, 0].numpy(), lin[:, 1], atol=1e-5)
    np.testing.assert_allclose(c2[n_keep:, 1].numpy(), -lin[:, 0], atol=1e-5)
    assert not c2[n_keep:, 2:].any()
    # deterministic given the generator
    again = torch.Generator().manual_seed(13)
    p3, s3, c3 = rs.resample(points, s, c, tets, keep, grid, (lo, hi), n_target, again)
    assert torch.equal(p2, p3) and torch.equal(s2, s3) and torch.equal(c2, c3)


def test_resample_over_budget_keeps_a_random_subset_in_order(grid_points):
    points, s, c, tets = _state(grid_points)
    keep = torch.ones(len(points), dtype=torch.bool)
    p2, s2, c2 = rs.resample(
        points, s, c, tets, keep, torch.ones(4, 4, 4), (LO, HI), 500, torch.Generator().manual_seed(14)
    )
    assert p2.shape == (500, 3)
    # every returned point is an old one (nothing new drawn), in the original order, each at most once
    index = {tuple(p): i for i, p in enumerate(points.tolist())}
    kept = torch.tensor([index[tuple(p)] for p in p2.tolist()])
    assert torch.equal(kept, torch.sort(kept).values) and len(set(kept.tolist())) == 500
    assert torch.equal(s2, s[kept]) and torch.equal(c2, c[kept])
    # a random subset: not simply the first 500
    assert int(kept.max()) >= 500


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_resample_cuda_matches_cpu(grid_points):
    points, s, c, tets = _state(grid_points)
    keep = torch.zeros(len(points), dtype=torch.bool)
    keep[::2] = True
    grid = torch.rand(8, 8, 8, generator=torch.Generator().manual_seed(15))
    cpu = rs.resample(points, s, c, tets, keep, grid, (LO, HI), 2000, torch.Generator().manual_seed(16))
    gpu = rs.resample(
        points.cuda(),
        s.cuda(),
        c.cuda(),
        tets.cuda(),
        keep.cuda(),
        grid.cuda(),
        (LO.cuda(), HI.cuda()),
        2000,
        torch.Generator().manual_seed(16),
    )
    for a, b in zip(cpu, gpu, strict=True):
        assert b.device.type == "cuda"
        torch.testing.assert_close(a, b.cpu())
    imp_cpu = rs.voxel_importance(points, s.abs(), LO, HI, 8)
    imp_gpu = rs.voxel_importance(points.cuda(), s.abs().cuda(), LO.cuda(), HI.cuda(), 8)
    torch.testing.assert_close(imp_cpu, imp_gpu.cpu())
