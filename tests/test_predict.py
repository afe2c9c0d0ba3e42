"""s prediction (formats/predict.py): exact neighbours, encoder and decoder agree bit for bit, and it predicts."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tetweave_codec.formats import predict
from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.tw2 import pack_v2, quantize_file, unpack_v2


def canonical_cells(cells: np.ndarray) -> np.ndarray:
    cells, _ = Q.merge_collisions(cells)
    return cells[Q.canonical_order(cells)]


def brute_force_neighbors(cells: np.ndarray, k: int, widths=None):
    """The definition in formats/README.md, point by point: the k nearest earlier points by (d2, j) among the points
    strictly closer than the W-th nearest point (itself included), for the first W with min(i, k) of them."""
    widths = widths or predict.QUERY_WIDTHS
    n = len(cells)
    idx = np.full((n, k), -1)
    d2 = np.zeros((n, k), dtype=np.int64)
    for i in range(n):
        dd = ((cells - cells[i]) ** 2).sum(-1)
        ranked = np.sort(dd)
        for w in widths:
            q = min(w, n)
            bound = ranked[q - 1]
            valid = [j for j in range(i) if dd[j] < bound or q == n]
            if len(valid) >= min(i, k) or w == widths[-1] or q == n:
                break
        order = sorted(valid, key=lambda j: (dd[j], j))[:k]
        idx[i, : len(order)] = order
        d2[i, : len(order)] = dd[order]
    return idx, d2


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 300), spread=st.sampled_from([2, 5, 40, 4096]))
@settings(max_examples=40, deadline=None)
def test_causal_neighbors_are_the_exact_nearest_earlier_points_with_index_ties(seed, n, spread):
    # small spreads put many points at equal integer distances: the tie rule decides
    rng = np.random.default_rng(seed)
    cells = canonical_cells(rng.integers(0, spread, (n, 3)))
    idx, d2 = predict.causal_neighbors(cells)
    ref_idx, ref_d2 = brute_force_neighbors(cells, predict.K_NEIGHBORS)
    assert np.array_equal(idx, ref_idx) and np.array_equal(d2, ref_d2)


@pytest.mark.parametrize("widths", [(4, 8, 16), (3, 24)])
def test_points_whose_earlier_points_are_far_get_the_last_widths_neighbours(widths):
    # two clusters far apart and a point between them: with small widths many points run out of candidates
    rng = np.random.default_rng(1)
    a = rng.integers(0, 8, (200, 3))
    b = rng.integers(1000, 1008, (200, 3))
    cells = canonical_cells(np.concatenate([a, b, [[500, 500, 500]]]))
    saved = predict.QUERY_WIDTHS
    try:
        predict.QUERY_WIDTHS = widths
        idx, d2 = predict.causal_neighbors(cells)
        r = predict.residuals(cells, np.arange(len(cells)) % 7 - 3)
        assert np.array_equal(predict.reconstruct(cells, r), np.arange(len(cells)) % 7 - 3)
    finally:
        predict.QUERY_WIDTHS = saved
    ref_idx, ref_d2 = brute_force_neighbors(cells, predict.K_NEIGHBORS, widths)
    assert np.array_equal(idx, ref_idx) and np.array_equal(d2, ref_d2)
    assert (idx[predict.K_NEIGHBORS :] == -1).any()  # the fallback was exercised


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 200), big=st.booleans())
@settings(max_examples=60, deadline=None)
def test_decoder_reconstructs_exactly_what_the_encoder_predicted(seed, n, big):
    rng = np.random.default_rng(seed)
    cells = canonical_cells(rng.integers(0, 2**10, (n, 3)))
    lim = Q.S_SYMBOL_LIMIT if big else 50
    s_sym = rng.integers(-lim, lim, len(cells))
    if big and len(cells):
        s_sym[0], s_sym[-1] = -Q.S_SYMBOL_LIMIT, Q.S_SYMBOL_LIMIT - 1
    r = predict.residuals(cells, s_sym)
    assert np.array_equal(predict.reconstruct(cells, r), s_sym)


def test_a_linear_field_is_predicted_to_within_the_rounding():
    # s = signed distance to a plane: exactly linear, so after the first few points the plane fit is exact up to
    # the rounding of the neighbours' symbols -- this fails if the weights or the offsets' signs are wrong
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.5, 0.5, (4000, 3))
    n = np.array([0.3, -0.5, 0.81])
    n /= np.linalg.norm(n)
    cells = canonical_cells(Q.quantize_positions(pts, 10))
    s_sym = Q.quantize_s(Q.dequantize_positions(cells, 10) @ n + 0.05, 1e-3)  # the field at the stored positions
    r = predict.residuals(cells, s_sym)
    assert np.abs(r[20:]).max() <= 2 and np.abs(r[20:]).mean() < 0.3
    assert np.abs(s_sym).mean() > 50  # the raw symbols are large: the prediction does the work


@pytest.mark.parametrize("degree", [-1, 1])
def test_a_sphere_costs_far_fewer_s_bits_with_prediction(degree):
    rng = np.random.default_rng(2)
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = d * rng.uniform(0.45, 0.55, (3000, 1))  # a shell around the sphere of radius 0.5
    s = np.linalg.norm(pts, axis=1) - 0.5
    c = np.zeros((3000, (degree + 1) ** 2))
    kw = dict(position_bits=11, s_step=2e-4, c_band_steps=[0.2] * (degree + 1))
    plain, _ = quantize_file(pts, s, c, degree, flags=0, **kw)
    predicted, _ = quantize_file(pts, s, c, degree, flags=2, **kw)
    a, b = unpack_v2(pack_v2(plain)), unpack_v2(pack_v2(predicted))
    assert np.array_equal(a.s_sym, b.s_sym)
    assert b.sizes["s"] < 0.75 * a.sizes["s"]  # measured 0.67


def test_corrupted_residuals_give_out_of_range_symbols_not_a_crash():
    # a corrupted stream can hold residuals far outside the symbol range: reconstruct must stay finite and return
    # symbols that the caller's range check rejects, and the points before the bad residual must be unaffected
    rng = np.random.default_rng(3)
    cells = canonical_cells(rng.integers(0, 64, (300, 3)))
    s_sym = rng.integers(-40, 40, len(cells))
    r = predict.residuals(cells, s_sym)
    r[100] = 2**62
    out = predict.reconstruct(cells, r)
    assert np.array_equal(out[:100], s_sym[:100])
    assert out[100] >= Q.S_SYMBOL_LIMIT


@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(0, 160),
    spread=st.sampled_from([3, 6, 300]),
    per_cell=st.sampled_from([0.5, 2.0, 4.0, 50.0]),
    cap=st.sampled_from([4, 40, 1 << 16]),
    pad=st.sampled_from([1, 16]),
    entries=st.sampled_from([64, 1 << 20]),
)
@settings(max_examples=60, deadline=None)
def test_any_grid_tuning_gives_the_rules_neighbours(seed, n, spread, per_cell, cap, pad, entries):
    # the grid's first level, row padding, batch size and candidate cap (beyond which the k-d tree answers) are
    # speed choices only: whatever they are, the neighbours are the rule's, with a small bound rank that cuts
    rng = np.random.default_rng(seed)
    cells = canonical_cells(rng.integers(0, spread, (n, 3)))
    names = ("QUERY_WIDTHS", "GRID_POINTS_PER_CELL", "GRID_MAX_CANDIDATES", "PAD_ROWS_ABOVE", "QUERY_ENTRIES")
    saved = [getattr(predict, name) for name in names]
    try:
        for name, value in zip(names, ((4, 8, 16), per_cell, cap, pad, entries), strict=True):
            setattr(predict, name, value)
        idx, d2 = predict.causal_neighbors(cells)
    finally:
        for name, value in zip(names, saved, strict=True):
            setattr(predict, name, value)
    ref_idx, ref_d2 = brute_force_neighbors(cells, predict.K_NEIGHBORS, (4, 8, 16))
    assert np.array_equal(idx, ref_idx) and np.array_equal(d2, ref_d2)


def test_a_sparse_point_beside_a_dense_cluster_is_exact_and_bounded():
    # hostile layout: a full 20^3 block (8000 points, more than the bound rank 4096) and points scattered around it
    # whose earlier points are all far: the bound cuts their neighbour lists, and the grid hands the points whose
    # block is too big to the k-d tree
    block = np.stack(np.meshgrid(*[np.arange(20) + 100] * 3, indexing="ij"), -1).reshape(-1, 3)
    rng = np.random.default_rng(5)
    cells = canonical_cells(np.concatenate([block, rng.integers(60, 160, (300, 3))]))
    idx, d2 = predict.causal_neighbors(cells)
    saved = predict.GRID_MAX_CANDIDATES
    try:
        predict.GRID_MAX_CANDIDATES = 1000
        small_cap = predict.causal_neighbors(cells)
    finally:
        predict.GRID_MAX_CANDIDATES = saved
    assert np.array_equal(idx, small_cap[0]) and np.array_equal(d2, small_cap[1])
    rows = np.concatenate([np.arange(0, len(cells), 97), np.flatnonzero((idx == -1).any(axis=1))[:40]])
    for i in np.unique(rows):  # the rule, point by point, for a sample (the full brute force takes too long)
        dd = ((cells - cells[i]) ** 2).sum(-1)
        bound = np.sort(dd)[predict.QUERY_WIDTHS[-1] - 1]
        valid = [j for j in range(i) if dd[j] < bound]
        order = sorted(valid, key=lambda j: (dd[j], j))[: predict.K_NEIGHBORS]
        assert idx[i, : len(order)].tolist() == order and (idx[i, len(order) :] == -1).all()
    assert ((idx == -1).sum(axis=1) > 0)[predict.K_NEIGHBORS :].any()  # the bound did cut somewhere


def test_cells_out_of_canonical_order_are_refused():
    with pytest.raises(ValueError, match="canonical"):
        predict.causal_neighbors(np.array([[0, 0, 1], [0, 0, 0]]))
