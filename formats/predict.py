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

A compiled fast path (formats/_native.c, a binding over the C decoder core's decoder/predict.c, built by setup.py
when a C compiler is there) runs the neighbour search, the weights and the sequential pass; this module stays the
reference, and the fallback whenever the extension is absent or `NATIVE` is False (environment TETWEAVE_NATIVE=0).
Both must give the same neighbours, weights and symbols bit for bit (tests/test_native.py): the C code is built with
-ffp-contract=off and without -ffast-math. The points over the search's work bound go to `_tree_rows` here; the C
decoder answers them itself by an exact search over a box hierarchy of the Morton-ordered cells (the same
neighbours: tests/test_core_container.py).
"""

from __future__ import annotations

import math
import os

import numpy as np

from .quantize import S_SYMBOL_LIMIT, morton_keys

try:  # the compiled fast path (optional; identical output)
    from . import _native
except ImportError:  # not built (no C compiler at install time): the numpy/Python code below
    _native = None
# Whether causal_neighbors and reconstruct use the compiled path. Measured (fandisk 40 KB, 18K points, CPU time):
# see docs/measurements/decode_native.md.
NATIVE = _native is not None and os.environ.get("TETWEAVE_NATIVE", "1") != "0"

K_NEIGHBORS = 8
# Candidate widths W: a point's neighbours are its K nearest earlier points among the points strictly closer than
# its W-th nearest point (itself included), for the first W in this list that yields min(i, K) of them, else the
# last W's (fewer than K: the first points of a region in Morton order, whose earlier points are all far). This
# bounds the work per point, whatever the file.
QUERY_WIDTHS = (24, 96, 512, 4096)
# Equivalently (what the search below relies on): a point's neighbours are its K nearest earlier points among the
# points strictly closer than its QUERY_WIDTHS[-1]-th nearest point (all points if fewer). Whenever some W yields
# min(i, K) of them, they are the K nearest earlier points, which all lie below every wider bound too; when none
# does, the last width decides.
#
# The search (`causal_neighbors`) runs on the Morton-ordered cells: at level L (cells of side 2**L) the points of a
# cell are one index range, so a point's candidates are the 3x3x3 cells around its own (each a range; only cells
# of smaller Morton key, and its own cell's points before it, are earlier). Every point within the block's reach
# R (at least 2**L) is in it, which makes the selection exact once the K-th nearest earlier candidate lies within
# R; points that are not settled try the next level. Measured on the 40 KB files of the shared meshes (18K points,
# CPU time, median of 5, against the k-d tree of scipy in the same run): 0.5-0.6x the k-d tree's time.
_OFFSETS = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)], dtype=np.int64)
_OWN = 13  # the (0, 0, 0) offset in _OFFSETS
# First level: the finest whose occupied cells hold this many points on average. Measured (fandisk 40 KB, ratio
# to the k-d tree in one run): 2 -> 1.0, 4 -> 0.55, 8 -> 0.65.
GRID_POINTS_PER_CELL = 4.0
# Cells are searched in groups of equal row count (padded above PAD_ROWS_ABOVE rows to a power of two) and widths
# within 2**(1/WIDTH_STEPS) of each other: few numpy calls per level, little padding. Measured best of 1-3 / 4-32.
WIDTH_STEPS = 2
PAD_ROWS_ABOVE = 16
QUERY_ENTRIES = 1 << 20  # candidate pairs per numpy batch (memory bound: about 50 MB)
# Work bound against hostile files: a point whose block holds more candidates than this at the level it has
# reached (a sparse point next to a dense cluster) is answered by a k-d tree query of QUERY_WIDTHS[-1] points
# instead (scipy, imported only then; never on the shared meshes' files). Per point the grid does at most
# (levels <= 16) x GRID_MAX_CANDIDATES work.
GRID_MAX_CANDIDATES = 1 << 16
_RESIDUAL_BOUND = 1 << 40  # |residual| bound in `reconstruct` (corrupted files only)
_NO_KEY = np.iinfo(np.int64).max  # sort key of a candidate that is not an earlier point below the bound
# Ridge on the plane's gradient, in squared cells per unit weight: keeps the fit defined with fewer than four or
# coplanar neighbours. Measured (bits per point of the residuals, fandisk / stanford-bunny 40 KB files): 0.1 ->
# 5.83 / 5.78; 1.0 -> 6.19 / 5.78; a ridge of 10 % of the neighbours' spread -> 6.94 / 6.06. Weights 1/d^2 beat
# 1/d (5.83 vs 5.88 on fandisk) and 8 neighbours beat 6 and 12.
RIDGE_ABSOLUTE = 0.1


def causal_neighbors(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The K_NEIGHBORS nearest earlier points of each point (the rule of formats/README.md, exactly).

    Args:
        cells: (N,3) int64 unique cells in canonical order (strictly ascending Morton code; ValueError if not).
    Returns:
        idx (N,K) int64 neighbour indices (-1 where point i has fewer than K earlier points), d2 (N,K) int64
        squared distances in cells (0 where idx is -1); each row sorted by (d2, index).
    """
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    n = len(cells)
    idx = np.full((n, K_NEIGHBORS), -1, dtype=np.int64)
    d2 = np.zeros((n, K_NEIGHBORS), dtype=np.int64)
    if n < 2:
        return idx, d2
    morton = morton_keys(cells).astype(np.int64)  # < 2**48
    if np.any(morton[1:] <= morton[:-1]):
        raise ValueError("cells must be unique and in canonical order (ascending Morton code)")
    if NATIVE and 0 <= int(cells.min()) and int(cells.max()) < 1 << 16:  # beyond 16 bits Morton codes alias
        over = np.empty(n, dtype=np.int64)
        n_over = _native.neighbors(
            np.ascontiguousarray(cells), morton, idx, d2, over, K_NEIGHBORS, QUERY_WIDTHS[-1], _first_level(morton),
            GRID_MAX_CANDIDATES,
        )  # fmt: skip
        if n_over:
            _tree_rows(cells, over[:n_over], idx, d2)
        return idx, d2
    axes = [np.ascontiguousarray(cells[:, a]) for a in range(3)]
    rows, over = np.arange(n), []
    level = _first_level(morton)
    while len(rows):
        rows, too_many = _grid_level(cells, axes, morton, level, rows, idx, d2)
        over.append(too_many)
        level += 1
    over = np.sort(np.concatenate(over))
    if len(over):
        _tree_rows(cells, over, idx, d2)
    return idx, d2


def _first_level(morton: np.ndarray) -> int:
    """The finest level whose occupied cells hold GRID_POINTS_PER_CELL points on average (or a single cell)."""
    level = 0
    while True:
        coarse = morton >> (3 * level)
        occupied = 1 + np.count_nonzero(coarse[1:] != coarse[:-1])
        if len(morton) >= GRID_POINTS_PER_CELL * occupied or occupied == 1:
            return level
        level += 1


def _grid_level(cells, axes, morton, level, rows, idx, d2) -> tuple[np.ndarray, np.ndarray]:
    """Settle `rows` (ascending) with the 3x3x3 blocks of level `level`; fills idx/d2 for those settled.

    Returns (rows left for the next level, rows whose block exceeds GRID_MAX_CANDIDATES)."""
    n = len(cells)
    coarse = morton >> (3 * level)
    starts = np.concatenate([[0], np.flatnonzero(coarse[1:] != coarse[:-1]) + 1, [n]])
    keys = coarse[starts[:-1]]  # occupied cells, ascending; cell c holds points starts[c] .. starts[c+1]-1
    cell_of_row = np.searchsorted(keys, coarse[rows])
    first = np.ones(len(rows), dtype=bool)
    first[1:] = cell_of_row[1:] != cell_of_row[:-1]
    row_start = np.flatnonzero(first)  # the rows of cell u are rows[row_start[u] : row_start[u] + count[u]]
    count = np.diff(np.append(row_start, len(rows)))
    u_of_row = np.cumsum(first) - 1
    corner = cells[starts[cell_of_row[row_start]]] >> level  # (U,3) cell coordinates
    near = corner[:, None, :] + _OFFSETS[None, :, :]  # (U,27,3)
    inside = (near >= 0).all(axis=2)
    near_key = morton_keys(np.where(inside[..., None], near, 0).reshape(-1, 3)).astype(np.int64)
    near_key = near_key.reshape(len(corner), len(_OFFSETS))
    pos = np.minimum(np.searchsorted(keys, near_key), len(keys) - 1)
    seg_a = starts[pos]
    seg_len = np.where(inside & (keys[pos] == near_key), starts[pos + 1] - seg_a, 0)
    total = seg_len.sum(axis=1)
    # reach: every point within it of the row (per axis) lies in the block; no cells below coordinate 0
    side = 1 << level
    offset = cells[rows] & (side - 1)
    below = np.where(corner[u_of_row] == 0, 1 << 40, side + offset)
    reach = np.minimum(below, 2 * side - 1 - offset).min(axis=1)
    # Below QUERY_WIDTHS[-1] points in the block no point of it can have that many within its K-th nearest
    # earlier distance: only earlier candidates matter. Above it ("dense") all do: the bound may cut.
    dense = total >= QUERY_WIDTHS[-1]
    lens = np.where(dense[:, None] | (near_key < near_key[:, _OWN : _OWN + 1]), seg_len, 0)
    last_row = rows[row_start + count - 1]
    lens[:, _OWN] = np.where(dense, seg_len[:, _OWN], last_row - seg_a[:, _OWN])
    width = lens.sum(axis=1)
    big = width > GRID_MAX_CANDIDATES
    too_many = rows[big[u_of_row]]
    # groups of cells with the same padded row count and similar widths
    pad = np.where(count <= PAD_ROWS_ABOVE, count, 1 << np.ceil(np.log2(np.maximum(count, 1))).astype(np.int64))
    bucket = np.floor(np.log2(np.maximum(width, 1)) * WIDTH_STEPS).astype(np.int64)
    group = (dense * (1 << 40)) + pad * (1 << 20) + bucket
    order = np.argsort(group, kind="stable")
    order = order[~big[order]]
    bounds = np.flatnonzero(np.diff(group[order], prepend=-1, append=-2)).tolist()
    left = [rows[:0]]
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        g = order[a:b]
        p = int(pad[g[0]])
        step = max(1, QUERY_ENTRIES // (p * max(int(width[g].max()), K_NEIGHBORS)))
        for c in range(0, len(g), step):
            u = g[c : c + step]
            block = _Block(seg_a[u], lens[u], width[u], total[u] == n, bool(dense[u[0]]))
            left.append(_settle(axes, rows, row_start[u], count[u], p, block, reach, idx, d2))
    return np.sort(np.concatenate(left)), too_many


class _Block:
    """Candidates of a group of cells: per cell the index ranges [a, a + len) of its 27 slots (G,27), their
    total (G,), whether the block holds every point (G,) and whether all candidates (not only earlier) are in."""

    def __init__(self, seg_a, lens, width, everything, dense):
        self.seg_a, self.lens, self.width, self.everything, self.dense = seg_a, lens, width, everything, dense


def _settle(axes, rows, row_start, count, p, block, reach, idx, d2) -> np.ndarray:
    """Select the neighbours of the rows of a group of G cells (p row slots each); returns the rows not settled."""
    n, k = len(axes[0]), K_NEIGHBORS
    g = len(row_start)
    w = block.width
    cols = max(int(w.max()), k)
    # candidate index matrix (G, cols), padded with n (never earlier than a row, never a point)
    seg = block.lens.ravel()
    total = int(seg.sum())
    cand_flat = np.repeat(block.seg_a.ravel() - (np.cumsum(seg) - seg), seg) + np.arange(total)
    cand = np.full((g, cols), n, dtype=np.int64)
    cand[np.repeat(np.arange(g), w), np.arange(total) - np.repeat(np.cumsum(w) - w, w)] = cand_flat
    safe = np.minimum(cand, n - 1)
    real = np.arange(p) < count[:, None]  # (G,p): slots beyond a cell's row count are padding
    slot = np.where(real, row_start[:, None] + np.arange(p), 0)
    me = np.where(real, rows[slot], -1)  # -1: no candidate counts as earlier
    dd = None
    for x in axes:  # (G,p,cols) squared distances, exact int64
        diff = x[safe][:, None, :] - x[me][:, :, None]
        dd = diff * diff if dd is None else dd + diff * diff
    # one int64 key per candidate orders by (d2, index) -- d2 < 2**34 and n <= 2**22 keep it below 2**56 --
    # and selecting the keys themselves yields both outputs: index = key % n, d2 = key // n
    key = np.where(cand[:, None, :] < me[:, :, None], dd * n + cand[:, None, :], _NO_KEY).reshape(g * p, cols)
    if cols > k:
        key.partition(k - 1, axis=1)
    top = np.sort(key[:, :k], axis=1)
    me, real = me.ravel(), real.ravel()
    r2 = np.square(reach[slot.ravel()])
    everything = np.repeat(block.everything, p)
    ok = top != _NO_KEY
    top_d2 = np.where(ok, top // n, 0)
    # settled: its min(i, K) nearest earlier points lie within the reach (so no point outside beats them), or the
    # block holds every point
    settled = ((ok & (top_d2 <= r2[:, None])).sum(axis=1) >= np.minimum(me, k)) | everything
    bound_rank = QUERY_WIDTHS[-1]
    if block.dense and n > bound_rank:
        # the bound B (the bound_rank-th smallest distance over all points) is exact when it lies within the
        # reach (or the block holds every point); then the point is settled whatever its earlier neighbours
        dist = np.where(cand[:, None, :] < n, dd, _NO_KEY).reshape(g * p, cols)
        kth = np.partition(dist, bound_rank - 1, axis=1)[:, bound_rank - 1] if cols >= bound_rank else None
        if kth is not None:
            exact = ((kth <= r2) | everything) & (kth != _NO_KEY)
            settled |= exact
            ok &= top_d2 < np.where(exact, kth, _NO_KEY)[:, None]
    done = np.flatnonzero(settled & real)
    idx[me[done]] = np.where(ok[done], top[done] % n, -1)
    d2[me[done]] = np.where(ok[done], top_d2[done], 0)
    return me[~settled & real]


def _tree_rows(cells: np.ndarray, rows: np.ndarray, idx: np.ndarray, d2: np.ndarray) -> None:
    """Neighbours of `rows` from one k-d tree query of QUERY_WIDTHS[-1] points each (the work bound's fallback)."""
    from scipy.spatial import cKDTree  # only for hostile files: 0.7 s of import that real files never pay

    n, k = len(cells), K_NEIGHBORS
    points = cells.astype(np.float64)
    tree = cKDTree(points, balanced_tree=False, compact_nodes=False)
    q = min(QUERY_WIDTHS[-1], n)
    for a in range(0, len(rows), max(1, QUERY_ENTRIES // q)):
        sub = rows[a : a + max(1, QUERY_ENTRIES // q)]
        dist, cand = tree.query(points[sub], k=q)
        cand = cand.reshape(len(sub), q)
        # the squared distances are integers below 2**50: squaring the rounded root and rounding restores them
        cd2 = np.rint(np.square(dist.reshape(len(sub), q))).astype(np.int64)
        # every point strictly closer than the q-th smallest distance is among the candidates, whichever tied
        # points the tree returned: the selection below it is exact
        valid = cand < sub[:, None]
        if q < n:
            valid &= cd2 < cd2[:, -1:]
        key = np.where(valid, cd2 * n + cand, _NO_KEY)
        key.sort(axis=1)
        sel = key[:, :k]
        ok = sel != _NO_KEY
        idx[sub, : sel.shape[1]] = np.where(ok, sel % n, -1)
        d2[sub, : sel.shape[1]] = np.where(ok, sel // n, 0)


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
    if NATIVE:
        beta = np.empty((n, k))
        _native.weights(np.ascontiguousarray(cells), np.ascontiguousarray(idx), np.ascontiguousarray(d2), beta,
                        RIDGE_ABSOLUTE)  # fmt: skip
        return beta
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
    residual = np.ascontiguousarray(residual, dtype=np.int64)
    n = len(residual)
    idx, beta = _predictor(cells)
    if NATIVE:
        out = np.empty(n, dtype=np.int64)
        _native.reconstruct(
            idx, beta, residual, out, -float(S_SYMBOL_LIMIT), float(S_SYMBOL_LIMIT - 1), _RESIDUAL_BOUND
        )
        return out
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
