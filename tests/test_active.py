"""Active points, their one-ring and passive points."""

from __future__ import annotations

import numpy as np
import torch

from tetweave_codec.geometry.active import active_mask, mixed_tets, one_ring_mask, passive_mask
from tetweave_codec.geometry.delaunay import tetrahedralize
from tetweave_codec.geometry.marching_tets import marching_tets_numpy


def test_hand_example():
    # Three tets in a chain: 0-1-2-3, 1-2-3-4, 2-3-4-5; point 6 is in no tet.
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4], [2, 3, 4, 5]])
    s = np.array([-1.0, 1.0, 1.0, 1.0, 1.0, 1.0, -1.0])
    assert mixed_tets(tets, s).tolist() == [True, False, False]
    assert active_mask(tets, s).tolist() == [True, True, True, True, False, False, False]
    ring = one_ring_mask(tets, active_mask(tets, s))
    assert ring.tolist() == [True, True, True, True, True, True, False]
    assert passive_mask(tets, s).tolist() == [False] * 6 + [True]
    # s == 0 counts as outside, like marching tets
    assert not active_mask(tets, np.zeros(7)).any()


def test_active_points_are_the_endpoints_of_active_edges():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (3000, 3))
    s = np.linalg.norm(pts, axis=1) - 0.5
    tets = tetrahedralize(pts).tets
    edges = marching_tets_numpy(pts, tets, s).edges
    expected = np.zeros(len(pts), dtype=bool)
    expected[edges.ravel()] = True
    assert np.array_equal(active_mask(tets, s), expected)
    assert 0 < expected.sum() < len(pts)


def test_one_ring_is_exactly_the_tet_neighbourhood():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1, 1, (1500, 3))
    s = pts[:, 2] - 0.1
    tets = tetrahedralize(pts).tets
    active = active_mask(tets, s)
    ring = one_ring_mask(tets, active)
    assert np.all(ring[active])
    neighbours = {(a, b) for t in tets.tolist() for a in t for b in t if a != b}
    for p in np.flatnonzero(ring & ~active).tolist():
        assert any(active[q] for (a, q) in neighbours if a == p)
    touching = {b for (a, b) in neighbours if active[a]}
    assert set(np.flatnonzero(ring).tolist()) == touching | set(np.flatnonzero(active).tolist())
    assert np.array_equal(passive_mask(tets, s), ~ring)


def test_torch_and_numpy_agree():
    rng = np.random.default_rng(2)
    pts = rng.uniform(-1, 1, (800, 3))
    s = np.linalg.norm(pts, axis=1) - 0.6
    tets = tetrahedralize(pts).tets
    a_np = active_mask(tets, s)
    a_t = active_mask(torch.tensor(tets), torch.tensor(s, requires_grad=True))
    assert a_t.dtype == torch.bool and np.array_equal(a_t.numpy(), a_np)
    r_t = one_ring_mask(torch.tensor(tets), a_t)
    assert np.array_equal(r_t.numpy(), one_ring_mask(tets, a_np))
    assert not torch.equal(r_t, a_t)  # the ring really grows
    assert np.array_equal(passive_mask(torch.tensor(tets), torch.tensor(s)).numpy(), passive_mask(tets, s))
