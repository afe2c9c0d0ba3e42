"""Which points a resampling moves: the passive ones, and the active ones the surface needs least.

The paper's resampling (fit.resample) only relocates passive points. From the SDF start almost every point is
active or next to one (at 4K points 119 of 4,096 moved at the first event, 6 at the second), so the density stays
what the initial shell made it: uniform over the area, whatever the error. Moving part of the active points too
lets the measured error decide where the points go while the main stage can still settle them.

A point's cost of removal is the displacement of the surface if its s were replaced by the weighted
least-squares linear fit of its Delaunay neighbours' s, ``|s_i - a_i| / |g_i|`` (normalized units), with
a_i + g_i . (p - p_i) that fit (weights 1 / d^2, a small ridge on g): where s is locally linear the neighbours
reproduce the point's surface. The cheapest points go, no two neighbours in one event (each score assumes the
others stay).
"""

from __future__ import annotations

import numpy as np

from tetweave_codec.geometry.marching_tets import TET_EDGES

# Ridge on the gradient of the neighbours' linear fit, relative to the sum of weights times the mean squared edge.
RIDGE = 1e-3


def tet_edges(tets: np.ndarray, n: int) -> np.ndarray:
    """Unique undirected edges (E,2) int64, i < j, of tets (T,4) over n points."""
    tets = np.asarray(tets, dtype=np.int64)
    pairs = tets[:, TET_EDGES].reshape(-1, 2)
    lo, hi = pairs.min(1), pairs.max(1)
    key = np.unique(lo * n + hi)
    return np.stack([key // n, key % n], 1)


def removal_cost(points: np.ndarray, s: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Surface displacement (N,) if point i's s were replaced by its neighbours' linear fit (inf: no fit).

    points (N,3), s (N,), edges (E,2) of the triangulation.
    """
    n = len(points)
    i = np.concatenate([edges[:, 0], edges[:, 1]])
    j = np.concatenate([edges[:, 1], edges[:, 0]])
    d = points[j] - points[i]
    d2 = (d * d).sum(1)
    w = 1.0 / np.maximum(d2, 1e-300)
    x = np.concatenate([np.ones((len(d), 1)), d], 1)  # (2E,4): [1, d]
    m = np.zeros((n, 4, 4))
    np.add.at(m, i, w[:, None, None] * x[:, :, None] * x[:, None, :])
    rhs = np.zeros((n, 4))
    np.add.at(rhs, i, (w * s[j])[:, None] * x)
    count = np.bincount(i, minlength=n)
    mean_d2 = np.bincount(i, d2, minlength=n) / np.maximum(count, 1)
    ridge = RIDGE * m[:, 0, 0] * mean_d2
    for axis in (1, 2, 3):
        m[:, axis, axis] += ridge
    ok = count >= 4
    out = np.full(n, np.inf)
    if ok.any():
        sol = np.linalg.solve(m[ok], rhs[ok][..., None])[..., 0]
        grad = np.linalg.norm(sol[:, 1:], axis=1)
        out[ok] = np.abs(s[ok] - sol[:, 0]) / np.maximum(grad, 1e-12)
    return out


def cheapest_points(
    points: np.ndarray,
    s: np.ndarray,
    tets: np.ndarray,
    candidates: np.ndarray,
    budget: int,
) -> np.ndarray:
    """Up to `budget` of the `candidates` (N,) bool with the lowest `removal_cost`, no two sharing an edge.

    points (N,3), s (N,), tets (T,4). Returns (N,) bool, the chosen points.
    """
    n = len(points)
    chosen = np.zeros(n, dtype=bool)
    if budget <= 0 or not candidates.any():
        return chosen
    edges = tet_edges(tets, n)
    cost = removal_cost(np.asarray(points, np.float64), np.asarray(s, np.float64), edges)
    order = np.flatnonzero(candidates & np.isfinite(cost))
    order = order[np.argsort(cost[order], kind="stable")]
    both = np.concatenate([edges, edges[:, ::-1]])
    both = both[np.lexsort((both[:, 1], both[:, 0]))]
    start = np.searchsorted(both[:, 0], np.arange(n + 1))  # neighbours of p: both[start[p]:start[p + 1], 1]
    blocked = np.zeros(n, dtype=bool)
    taken = 0
    for p in order.tolist():
        if taken >= budget:
            break
        if blocked[p]:
            continue
        chosen[p] = True
        blocked[both[start[p] : start[p + 1], 1]] = True
        taken += 1
    return chosen
