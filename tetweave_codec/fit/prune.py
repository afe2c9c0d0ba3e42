"""Point pruning before the late stage: drop points whose s the neighbours' linear field already reproduces
("bits that buy no error"); the late stage then refits s and c on the smaller triangulation.

A fitted s is close to a signed distance, locally linear. Where a point's s lies on the plane through its Delaunay
neighbours' s, the marching-tets surface barely needs it: after its removal the tets around it are replaced by
tets over its neighbours, whose linear interpolation of s places the surface where the point did. Its score is
that displacement, ``|s_i - a_i| / |g_i|`` (normalized units), with a_i + g_i . (p - p_i) the weighted
least-squares linear fit of the neighbours' s (weights 1 / d^2, a small ridge on g). Points are removed in order
of score, no two neighbours in one pass (their scores assume the other stays), up to a fraction of the points.

Positions cost ~10 bits per point and s ~7, so every removed point frees ~17 bits for the rest of the file.
Measured (benchmarks/results/rdo.md, 10 KB files, 5 % pruned): bytes x Chamfer +5.3 / +2.1 / -2.1 / +1.6 % on
spot / igea / fandisk / stanford-bunny; on curved shapes even points within 0.05 cells of their neighbours' plane
carry error (their c and the late stage's placement go with them). Off by default (FitConfig.prune_fraction).
"""

from __future__ import annotations

import numpy as np

from tetweave_codec.geometry.delaunay import tetrahedralize

# Ridge on the gradient of the neighbours' linear fit, relative to the sum of weights times the mean squared edge.
RIDGE = 1e-3
_TET_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))


def tet_edges(tets: np.ndarray, n: int) -> np.ndarray:
    """Unique undirected edges (E,2) int64, i < j, of tets (T,4) over n points."""
    tets = np.asarray(tets, dtype=np.int64)
    pairs = np.concatenate([tets[:, [a, b]] for a, b in _TET_EDGES])
    lo, hi = pairs.min(1), pairs.max(1)
    key = np.unique(lo * n + hi)
    return np.stack([key // n, key % n], 1)


def linear_scores(points: np.ndarray, s: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Surface displacement (N,) if point i's s were replaced by its neighbours' linear fit (inf: no fit)."""
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
    m[:, 1, 1] += ridge
    m[:, 2, 2] += ridge
    m[:, 3, 3] += ridge
    ok = count >= 4
    out = np.full(n, np.inf)
    if ok.any():
        sol = np.linalg.solve(m[ok], rhs[ok][..., None])[..., 0]
        grad = np.linalg.norm(sol[:, 1:], axis=1)
        out[ok] = np.abs(s[ok] - sol[:, 0]) / np.maximum(grad, 1e-12)
    return out


def prune_mask(
    points: np.ndarray, s: np.ndarray, backend: str, fraction: float, max_score: float = np.inf
) -> np.ndarray:
    """Points (N,) bool to keep: at most `fraction` of them removed, lowest score first and only scores up to
    `max_score` (normalized units), no two neighbours."""
    n = len(points)
    keep = np.ones(n, dtype=bool)
    budget = int(fraction * n)
    if budget <= 0 or n < 8:
        return keep
    edges = tet_edges(tetrahedralize(np.asarray(points, dtype=np.float64), backend).tets, n)
    score = linear_scores(np.asarray(points, dtype=np.float64), np.asarray(s, dtype=np.float64), edges)
    order = np.argsort(score, kind="stable")
    order = order[score[order] <= max_score]
    blocked = np.zeros(n, dtype=bool)
    both = np.concatenate([edges, edges[:, ::-1]])
    both = both[np.lexsort((both[:, 1], both[:, 0]))]
    start = np.searchsorted(both[:, 0], np.arange(n + 1))  # the neighbours of p: both[start[p]:start[p + 1], 1]
    removed = 0
    for p in order.tolist():
        if removed >= budget:
            break
        if blocked[p]:
            continue
        keep[p] = False
        blocked[both[start[p] : start[p + 1], 1]] = True
        removed += 1
    return keep
