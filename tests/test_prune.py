"""Point pruning (fit/prune.py): exact on linear fields, bounded, never two neighbours in one pass."""

from __future__ import annotations

import numpy as np

from tetweave_codec.fit import prune as P
from tetweave_codec.geometry.delaunay import resolve_backend, tetrahedralize


def _cloud(n: int = 400, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (n, 3))


def test_linear_field_scores_zero_and_curved_one_does_not():
    points = _cloud()
    edges = P.tet_edges(tetrahedralize(points, resolve_backend("auto")).tets, len(points))
    plane = points @ np.array([0.3, -0.5, 0.8]) + 0.1
    inner = np.linalg.norm(points, axis=1) < 0.6  # away from the hull, where the ridge matters least
    score = P.linear_scores(points, plane, edges)
    assert np.median(score[inner]) < 1e-3
    sphere = np.linalg.norm(points, axis=1) - 0.5
    assert np.median(P.linear_scores(points, sphere, edges)[inner]) > 10 * np.median(score[inner])


def test_prune_mask_is_bounded_and_independent():
    points = _cloud(seed=1)
    s = np.linalg.norm(points, axis=1) - 0.5
    backend = resolve_backend("auto")
    assert P.prune_mask(points, s, backend, 0.0).all()
    keep = P.prune_mask(points, s, backend, 0.1)
    removed = np.flatnonzero(~keep)
    assert 0 < len(removed) <= 40
    edges = P.tet_edges(tetrahedralize(points, backend).tets, len(points))
    assert not (~keep[edges[:, 0]] & ~keep[edges[:, 1]]).any()  # no edge loses both ends
    np.testing.assert_array_equal(keep, P.prune_mask(points, s, backend, 0.1))  # deterministic


def test_prune_threshold_limits_removal():
    points = _cloud(seed=2)
    s = np.linalg.norm(points, axis=1) - 0.5
    backend = resolve_backend("auto")
    edges = P.tet_edges(tetrahedralize(points, backend).tets, len(points))
    score = P.linear_scores(points, s, edges)
    assert P.prune_mask(points, s, backend, 0.5, max_score=0.0).all() or (score <= 0).any()
    tau = float(np.percentile(score, 3))
    keep = P.prune_mask(points, s, backend, 0.5, max_score=tau)
    assert (score[~keep] <= tau).all() and (~keep).sum() <= (score <= tau).sum()
