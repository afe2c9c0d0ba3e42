"""Prediction of s from already-coded neighbours (`.tw` v2 flag bit 1; formats/README.md "s section, predicted").

A fitted s is close to a signed distance, which is locally linear: a plane fitted to the s of a point's nearby
points predicts its s to a fraction of the spread of s itself. Measured on fitted files (bits per point of the s
stream, order-0 entropy): fandisk 40 KB 8.28 -> 5.83, stanford-bunny 40 KB 7.44 -> 5.78.

Everything here is exact and reproducible by an independent decoder:

* Neighbours (`causal_neighbors`): for the point of canonical index i, the K_NEIGHBORS points j < i nearest to it
  in integer cell coordinates, ties broken by the smaller j, searched among the points strictly closer than its
  W-th nearest point (see QUERY_WIDTHS; fewer neighbours when there are fewer there). Squared distances are
  int64, so the selection is exact.
* Prediction: a weighted least-squares plane through the neighbours' values u_j = k_j + 1/2 (mid-rise symbols k
  stand for (k + 1/2) steps), evaluated at the point. Its value is linear in the u_j with weights that depend on
  the positions only (`predictor_weights`), so the decoder computes them for all points at once and then runs
  one cheap sequential pass (`reconstruct`): a = sum of beta_j u_j over the neighbour slots in order, predicted
  symbol floor(a) clamped to the symbol range, symbol = prediction + residual. All arithmetic is IEEE 754
  binary64 with every operation rounded, in the order written here (numpy applies each elementwise operation
  separately, with no fused multiply-add; Python floats are binary64).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from .quantize import S_SYMBOL_LIMIT

K_NEIGHBORS = 8
# Candidate widths W: a point's neighbours are its K nearest earlier points among the points strictly closer than
# its W-th nearest point (itself included), for the first W in this list that yields min(i, K) of them, else the
# last W's (fewer than K: the first points of a region in Morton order, whose earlier points are all far). This
# bounds the work per point, whatever the file.
QUERY_WIDTHS = (24, 96, 512, 4096)
# Equivalently (what the search below relies on): a point's neighbours are its K nearest earlier points among the
# points strictly closer than its QUERY_WIDTHS[-1]-th nearest point (all points if fewer). Whenever some W yields
# min(i, K) of them, they are the K nearest earlier points, which all lie below every wider bound too; when none
# does, the last width decides. So any sequence of query sizes that ends with the last width finds the same
# neighbours. These cost the least of those measured: on the 40 KB fandisk file (18K points), the share of points
# whose min(i, K) nearest earlier points lie strictly within their q nearest points is 0.78 / 0.94 / 0.99 / 0.999
# for q = 24 / 40 / 64 / 128, and the candidates queried per point fall from 50 (QUERY_WIDTHS) to 41.
SEARCH_WIDTHS = (24, 40, 64, 128, 512)
QUERY_ENTRIES = 1 << 22  # candidates per k-d tree query call (memory bound)
_RESIDUAL_BOUND = 1 << 40  # |residual| bound in `reconstruct` (corrupted files only)
_NO_KEY = np.iinfo(np.int64).max  # sort key of a candidate that is not an earlier point below the bound
# Ridge on the plane's gradient, in squared cells per unit weight: keeps the fit defined with fewer than four or
# coplanar neighbours. Measured (bits per point of the residuals, fandisk / stanford-bunny 40 KB files): 0.1 ->
# 5.83 / 5.78; 1.0 -> 6.19 / 5.78; a ridge of 10 % of the neighbours' spread -> 6.94 / 6.06. Weights 1/d^2 beat
# 1/d (5.83 vs 5.88 on fandisk) and 8 neighbours beat 6 and 12.
RIDGE_ABSOLUTE = 0.1


def causal_neighbors(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The K_NEIGHBORS nearest earlier points of each point.

    Args:
        cells: (N,3) int64 unique cells in canonical order.
    Returns:
        idx (N,K) int64 neighbour indices (-1 where point i has fewer than K earlier points), d2 (N,K) int64
        squared distances in cells (0 where idx is -1); each row sorted by (d2, index).
    """
    cells = np.asarray(cells, dtype=np.int64)
    n = len(cells)
    k = K_NEIGHBORS
    idx = np.full((n, k), -1, dtype=np.int64)
    d2 = np.zeros((n, k), dtype=np.int64)
    if n < 2:
        return idx, d2
    points = cells.astype(np.float64)
    # unbalanced, non-compact: builds 2x faster; which tree answers does not matter (see _select)
    tree = cKDTree(points, balanced_tree=False, compact_nodes=False)
    todo = np.arange(n)
    widths = [w for w in SEARCH_WIDTHS if w < QUERY_WIDTHS[-1]] + [QUERY_WIDTHS[-1]]
    for width in widths:
        q = min(width, n)
        last = width == widths[-1] or q == n
        step = max(1, QUERY_ENTRIES // q)
        left = [_select(tree, points, todo[a : a + step], q, last, idx, d2) for a in range(0, len(todo), step)]
        todo = np.concatenate(left) if left else todo[:0]
        if len(todo) == 0:
            break
    return idx, d2


def _select(tree, points, rows, q, last, idx, d2) -> np.ndarray:
    """Fill idx/d2 for `rows` from their q nearest points; returns the rows left for a wider query."""
    n, k = len(points), idx.shape[1]
    dist, cand = tree.query(points[rows], k=q, workers=-1)
    cand = cand.reshape(len(rows), q)
    # the squared distances are integers below 2**50: squaring the rounded root and rounding restores them exactly
    cd2 = np.rint(np.square(dist.reshape(len(rows), q))).astype(np.int64)
    # Every point strictly closer than the q-th smallest distance D is among the candidates, whichever tied points
    # the tree returned: the selection below D is exact. The tree sorts by distance, so D is the last column.
    valid = cand < rows[:, None]
    if q < n:
        valid &= cd2 < cd2[:, -1:]
    # One int64 key per candidate orders by (d2, index) -- d2 < 2**34 and n <= 2**22 keep it below 2**56 -- and
    # sorting the keys themselves (no argsort and gathers) yields both outputs: index = key % n, d2 = key // n.
    key = np.where(valid, cd2 * n + cand, _NO_KEY)
    key.sort(axis=1)
    kk = min(k, q)
    sel = key[:, :kk]
    ok = sel != _NO_KEY
    done = (ok.sum(axis=1) >= np.minimum(rows, k)) | last
    sel, ok = sel[done], ok[done]
    idx[rows[done], :kk] = np.where(ok, sel % n, -1)
    d2[rows[done], :kk] = np.where(ok, sel // n, 0)
    return rows[~done]


def predictor_weights(cells: np.ndarray, idx: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """Weights beta (N,K) float64 of the linear predictor: predicted value = sum_j beta[i, j] * u[idx[i, j]].

    The weighted least-squares plane u ~ a + g . d through the neighbours (offsets d_j = cell_j - cell_i, weights
    w_j = 1 / d2_j, a ridge RIDGE_ABSOLUTE * sum(w) on g) has its value at the point, a, linear in the
    neighbours' values u_j: a = sum_j beta_j u_j with beta_j = w_j (1 / W - h . (d_j - m)), where W = sum w_j,
    m = sum w_j d_j / W, C = sum w_j (d_j - m)(d_j - m)^T + ridge I and h = C^-1 m. beta depends on the positions
    only, so the decoder computes it before any s. Every operation is a binary64 operation in the order written
    here (part of the format); missing neighbours (idx -1) get beta 0.
    """
    cells = np.asarray(cells, dtype=np.int64)
    n, k = idx.shape
    # slot-major (K, N) arrays, one contiguous row per slot: the sums below run over the slots in order
    have = (idx >= 0).T
    safe = np.where(have, idx.T, 0)
    d = [(cells[safe, a] - cells[:, a]).astype(np.float64) for a in range(3)]  # exact: integers below 2**17
    w = np.where(have, 1.0 / np.where(have, d2.T, 1).astype(np.float64), 0.0)
    sw = _slot_sum(w)
    safe_sw = np.where(sw > 0, sw, 1.0)
    m = [_slot_sum(w * d[a]) / safe_sw for a in range(3)]
    e = [d[a] - m[a] for a in range(3)]
    # C is symmetric and e_a * e_b == e_b * e_a exactly: the 6 distinct entries are all there is to compute
    c = {(a, b): _slot_sum(w * (e[a] * e[b])) for a in range(3) for b in range(a, 3)}
    ridge = RIDGE_ABSOLUTE * sw
    m00, m01, m02 = c[0, 0] + ridge, c[0, 1], c[0, 2]
    m11, m12, m22 = c[1, 1] + ridge, c[1, 2], c[2, 2] + ridge
    # h = C^-1 m by the adjugate (C is symmetric positive definite when W > 0)
    a00 = m11 * m22 - m12 * m12
    a01 = m02 * m12 - m01 * m22
    a02 = m01 * m12 - m02 * m11
    a11 = m00 * m22 - m02 * m02
    a12 = m01 * m02 - m00 * m12
    a22 = m00 * m11 - m01 * m01
    det = (m00 * a00 + m01 * a01) + m02 * a02
    safe_det = np.where(sw > 0, det, 1.0)
    h0 = ((a00 * m[0] + a01 * m[1]) + a02 * m[2]) / safe_det
    h1 = ((a01 * m[0] + a11 * m[1]) + a12 * m[2]) / safe_det
    h2 = ((a02 * m[0] + a12 * m[1]) + a22 * m[2]) / safe_det
    inv_w = 1.0 / safe_sw
    he = (h0 * e[0] + h1 * e[1]) + h2 * e[2]
    beta = w * (inv_w - he)
    return np.ascontiguousarray(np.where(have, beta, 0.0).T)


def _slot_sum(x: np.ndarray) -> np.ndarray:
    """(K, N) -> (N,): ((0 + x_0) + x_1) + ... one slot at a time (numpy's reductions may reorder the additions)."""
    acc = np.zeros(x.shape[1])
    for row in x:
        acc = acc + row
    return acc


def _predicted_symbol(a: np.ndarray) -> np.ndarray:
    """floor(a) clamped to the s symbol range, as int64."""
    return np.floor(np.clip(a, -float(S_SYMBOL_LIMIT), float(S_SYMBOL_LIMIT - 1))).astype(np.int64)


def _predictor(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Neighbour indices (N,K) and their weights beta (N,K): everything the positions alone determine."""
    idx, d2 = causal_neighbors(cells)
    return idx, predictor_weights(cells, idx, d2)


def residuals(cells: np.ndarray, s_sym: np.ndarray) -> np.ndarray:
    """Encoder side: s symbols (N,) int64 in canonical order -> prediction residuals (N,) int64."""
    s_sym = np.asarray(s_sym, dtype=np.int64)
    idx, beta = _predictor(cells)
    u = s_sym.astype(np.float64) + 0.5  # mid-rise: symbol k stands for (k + 1/2) steps
    acc = np.zeros(len(s_sym))
    for j in range(idx.shape[1]):  # the decoder's order: neighbour slots 0..K-1, missing ones skipped
        acc = np.where(idx[:, j] >= 0, acc + beta[:, j] * u[np.maximum(idx[:, j], 0)], acc)
    return s_sym - _predicted_symbol(acc)


def reconstruct(cells: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Decoder side: residuals (N,) int64 -> s symbols (N,) int64 (not range-checked; the caller checks)."""
    residual = np.asarray(residual, dtype=np.int64)
    n = len(residual)
    idx, beta = _predictor(cells)
    # A corrupted residual can leave the symbol range; bounding it here keeps every u finite (the caller rejects
    # the symbols). Missing neighbours (idx -1, beta 0) read u[n] = 0.0, which adds +0.0: the sum is unchanged.
    res_l = np.clip(residual, -_RESIDUAL_BOUND, _RESIDUAL_BOUND).tolist()
    idx_l = np.where(idx >= 0, idx, n).tolist()
    beta_l = beta.tolist()
    lo, hi = -float(S_SYMBOL_LIMIT), float(S_SYMBOL_LIMIT - 1)
    floor = math.floor
    u = [0.0] * (n + 1)
    # Sequential: each prediction reads earlier points only. The sum is written out for K_NEIGHBORS = 8 (a constant
    # of the format): Python evaluates it left to right, ((b0 u0 + b1 u1) + b2 u2) + ..., the reference order, and
    # costs a third of a loop over the slots.
    for i, (j0, j1, j2, j3, j4, j5, j6, j7), (b0, b1, b2, b3, b4, b5, b6, b7), r in zip(
        range(n), idx_l, beta_l, res_l, strict=True
    ):
        a = b0 * u[j0] + b1 * u[j1] + b2 * u[j2] + b3 * u[j3] + b4 * u[j4] + b5 * u[j5] + b6 * u[j6] + b7 * u[j7]
        u[i] = floor(lo if a < lo else hi if a > hi else a) + r + 0.5
    return np.floor(np.array(u[:n])).astype(np.int64)  # u = k + 1/2 exactly (|k| < 2**41)
