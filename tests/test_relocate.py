"""fit.relocate (removal cost, cheapest points) and the near-surface draw of fit.resample."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import Delaunay

from tetweave_codec.fit import resample as rs
from tetweave_codec.fit.relocate import cheapest_points, removal_cost, tet_edges

NORMAL = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])


def _cloud(n: int = 1500, seed: int = 0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1, 1, size=(n, 3))
    tets = Delaunay(pts).simplices.astype(np.int64)
    return pts, tets, rng


def _interior(pts: np.ndarray) -> np.ndarray:
    return (np.abs(pts) < 0.7).all(1)


def test_tet_edges_are_unique_sorted_pairs():
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    edges = tet_edges(tets, 5)
    assert edges.tolist() == sorted(edges.tolist())
    assert (edges[:, 0] < edges[:, 1]).all()
    assert len(edges) == 9  # 6 + 6 - 3 shared


def test_removal_cost_is_zero_for_a_linear_field_and_the_offset_for_a_bump():
    pts, tets, _ = _cloud()
    s = 2.0 * (pts @ NORMAL) + 0.1  # |grad s| = 2: costs are surface displacements s / |g|
    edges = tet_edges(tets, len(pts))
    cost = removal_cost(pts, s, edges)
    inner = _interior(pts)
    # the ridge on g biases the fit a little: ~1e-4 of a point spacing (~0.15 here) typically, 1e-3 at most
    assert np.median(cost[inner]) < 1e-4 and np.all(cost[inner] < 3e-3)
    adjacent = set(map(tuple, edges.tolist()))
    bumped = []
    for p in np.flatnonzero(inner).tolist():  # 20 interior points, no two neighbours
        if all((min(p, q), max(p, q)) not in adjacent for q in bumped):
            bumped.append(p)
        if len(bumped) == 20:
            break
    s2 = s.copy()
    s2[bumped] += 0.2  # moves the surface by 0.1 around each of these points
    cost2 = removal_cost(pts, s2, edges)
    assert np.all(np.abs(cost2[bumped] - 0.1) < 0.01)


def test_cheapest_points_prefers_low_cost_never_takes_neighbours_and_respects_candidates():
    pts, tets, rng = _cloud(seed=1)
    n = len(pts)
    s = pts @ NORMAL
    bumped = rng.random(n) < 0.5
    s = s + np.where(bumped, 0.05, 0.0) * rng.standard_normal(n)
    candidates = _interior(pts)
    candidates[:50] = False
    chosen = cheapest_points(pts, s, tets, candidates, budget=40)
    assert chosen.sum() == 40
    assert not chosen[~candidates].any()
    edges = tet_edges(tets, n)
    assert not (chosen[edges[:, 0]] & chosen[edges[:, 1]]).any()
    cost = removal_cost(pts, s, edges)
    # the chosen are among the cheapest candidates: their worst cost is below the median candidate's
    assert cost[chosen].max() < np.median(cost[candidates])
    assert not cheapest_points(pts, s, tets, candidates, budget=0).any()


def test_sample_near_surface_follows_importance_and_stays_in_the_shell():
    rng = np.random.default_rng(3)
    samples = np.concatenate([rng.uniform(-0.9, 0.9, size=(20000, 2)), np.zeros((20000, 1))], 1)  # plane z = 0
    normals = np.tile([0.0, 0.0, 1.0], (len(samples), 1))
    grid = torch.zeros(8, 8, 8)
    grid[4:] = 1.0  # x > 0 only
    grid[6:] = 3.0  # x > 0.5 three times denser per area
    near = rs.NearSurface(samples, normals, half_width=0.05, gap=0.25)
    lo, hi = torch.tensor([-1.0] * 3), torch.tensor([1.0] * 3)
    pts = rs.sample_near_surface(grid, lo, hi, near, 6000, torch.Generator().manual_seed(0)).numpy()
    assert pts.shape == (6000, 3)
    assert np.all(pts[:, 0] > -1e-9)
    z = np.abs(pts[:, 2])
    assert z.min() >= 0.25 * 0.05 - 1e-12 and z.max() <= 0.05 + 1e-12
    assert 0.3 < (pts[:, 2] > 0).mean() < 0.7
    dense, sparse = ((pts[:, 0] > 0.5).mean(), ((pts[:, 0] > 0) & (pts[:, 0] < 0.5)).mean())
    # per unit area: x in (0.5, 0.9) has 3x the weight of x in (0, 0.5)
    assert abs((dense / 0.4) / (sparse / 0.5) - 3.0) < 0.4
    again = rs.sample_near_surface(grid, lo, hi, near, 6000, torch.Generator().manual_seed(0)).numpy()
    assert np.array_equal(pts, again)
    none = rs.sample_near_surface(torch.zeros(8, 8, 8), lo, hi, near, 100, torch.Generator().manual_seed(1))
    assert none.shape == (100, 3)  # no importance anywhere: uniform over the samples
    assert rs.sample_near_surface(grid, lo, hi, near, 0, torch.Generator()).shape == (0, 3)


def test_sample_near_surface_stays_inside_a_thin_part():
    """With the input's tree, new points drawn from the top face of a plate thinner than the shell land inside
    the plate or above it, never below it (across the plate)."""
    manifold3d = pytest.importorskip("manifold3d")
    from tetweave_codec.geometry.closest import SurfaceTree
    from tetweave_codec.geometry.triangles import face_normals

    mesh = manifold3d.Manifold.cube([1.6, 0.02, 1.6], center=True).to_mesh()
    v, f = np.asarray(mesh.vert_properties[:, :3], np.float64), np.asarray(mesh.tri_verts, np.int64)
    rng = np.random.default_rng(0)
    samples = np.column_stack([rng.uniform(-0.7, 0.7, 3000), np.full(3000, 0.01), rng.uniform(-0.7, 0.7, 3000)])
    normals = np.tile([0.0, 1.0, 0.0], (3000, 1))
    lo, hi = torch.tensor([-1.0] * 3), torch.tensor([1.0] * 3)
    args = (torch.ones(4, 4, 4), lo, hi)
    plain = rs.NearSurface(samples, normals, half_width=0.1, gap=0.25)
    crossing = rs.sample_near_surface(*args, plain, 2000, torch.Generator().manual_seed(0)).numpy()
    assert (crossing[:, 1] < -0.01).mean() > 0.4  # without the tree: half go through the plate
    near = rs.NearSurface(samples, normals, 0.1, 0.25, SurfaceTree(v, f), face_normals(v, f))
    pts = rs.sample_near_surface(*args, near, 2000, torch.Generator().manual_seed(0)).numpy()
    assert np.all(pts[:, 1] > -0.01)
    assert 0.4 < (pts[:, 1] < 0.01).mean() < 0.6  # the inward half is inside
    np.testing.assert_array_equal(pts[crossing[:, 1] > 0.01], crossing[crossing[:, 1] > 0.01])


def test_distance_importance_peaks_where_the_mesh_leaves_the_input():
    """The 3-D importance of a resampling: highest in the voxels of a dent, ~0 where mesh and input agree."""
    import trimesh

    from tetweave_codec.fit import loop
    from tetweave_codec.fit.surface_loss import SurfaceTarget

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.8)
    target = SurfaceTarget(np.asarray(sphere.vertices), np.asarray(sphere.faces), n_samples=50_000, seed=0)
    dented = np.array(sphere.vertices, dtype=np.float64)
    cap = dented[:, 0] > 0.6  # push the +x cap inwards by up to 0.1
    dented[cap] *= (1.0 - 0.125 * (dented[cap, 0:1] - 0.6) / 0.2).clip(0.8, 1.0)

    class Ctx:  # the two fields _distance_errors reads
        surface = target
        generator = torch.Generator().manual_seed(0)

    vertices = torch.from_numpy(dented)
    world, error = loop._distance_errors(vertices, torch.from_numpy(np.asarray(sphere.faces)), Ctx)
    lo, hi = loop._padded_box(vertices)
    grid = rs.voxel_importance(world, error, lo, hi, loop.IMPORTANCE_RESOLUTION)
    r = grid.shape[0]
    assert grid.shape == (r, r, r) and (grid >= 0).all()
    centers = lo + (torch.stack(torch.meshgrid(*[torch.arange(r)] * 3, indexing="ij"), -1) + 0.5) * (hi - lo) / r
    top = centers[grid > 0.5 * grid.max()]
    assert len(top) > 0 and (top[:, 0] > 0.55).all()  # the peak is at the dent
    far = grid[centers[..., 0] < 0.0]
    assert float(far.max()) < 0.05 * float(grid.max())  # the rest of the sphere matches the input
