"""The compiled fast paths against their numpy/Python references: the s prediction (formats/_native.c against
formats/predict.py) and marching tets' topology (geometry/_mt_native.c against geometry/marching_tets.py).

Both must give the same neighbours (idx, d2), the same weights (bit for bit), the same symbols, on any point set
and whatever the residuals, and the same marching tets output and manifold verdicts; the reference must still run
when the extension is off or absent.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tetweave_codec.errors import TopologyError
from tetweave_codec.formats import predict
from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.tw2 import unpack_v2
from tetweave_codec.geometry import marching_tets as MT
from tetweave_codec.geometry.delaunay import tetrahedralize
from tetweave_codec.geometry.marching_tets import check_manifold, marching_tets_numpy

needs_native = pytest.mark.skipif(predict._native is None, reason="C extension not built")


def canonical_cells(cells: np.ndarray) -> np.ndarray:
    cells, _ = Q.merge_collisions(cells)
    return cells[Q.canonical_order(cells)]


def both_paths(func, *args):
    """func(*args) with the compiled path on, then with the reference; returns (native, reference)."""
    saved = predict.NATIVE
    try:
        predict.NATIVE = True
        native = func(*args)
        predict.NATIVE = False
        reference = func(*args)
    finally:
        predict.NATIVE = saved
    return native, reference


def assert_same_prediction(cells: np.ndarray, residual: np.ndarray) -> None:
    (idx, d2), (ref_idx, ref_d2) = both_paths(predict.causal_neighbors, cells)
    assert np.array_equal(idx, ref_idx) and np.array_equal(d2, ref_d2)
    beta, ref_beta = both_paths(predict.predictor_weights, cells, ref_idx, ref_d2)
    assert beta.dtype == ref_beta.dtype and beta.shape == ref_beta.shape
    assert beta.tobytes() == ref_beta.tobytes()  # bit for bit, signed zeros included
    sym, ref_sym = both_paths(predict.reconstruct, cells, residual)
    assert sym.dtype == ref_sym.dtype and np.array_equal(sym, ref_sym)


def assert_round_trip(cells: np.ndarray, s_sym: np.ndarray) -> None:
    """The encoder's residuals (numpy reference) decode to the same symbols on both paths: a prediction one ulp
    off flips floor(a) for some points of a smooth field."""
    residual = both_paths(predict.residuals, cells, s_sym)[1]
    sym, ref_sym = both_paths(predict.reconstruct, cells, residual)
    assert np.array_equal(ref_sym, s_sym) and np.array_equal(sym, s_sym)


def reference_sums(idx: np.ndarray, beta: np.ndarray, s_sym: np.ndarray) -> np.ndarray:
    """The predictions a (N,) float64 of formats/README.md step 3, written out in Python floats (binary64)."""
    u = (s_sym.astype(np.float64) + 0.5).tolist() + [0.0]
    out = []
    for row, b in zip(idx.tolist(), beta.tolist(), strict=True):
        a = b[0] * u[row[0]]
        for j, bj in zip(row[1:], b[1:], strict=True):
            a = a + bj * u[j]
        out.append(a)
    return np.array(out, dtype=np.float64)


@needs_native
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 300), kind=st.sampled_from(["uniform", "surface", "lattice"]))
@settings(max_examples=40, deadline=None)
def test_native_sums_are_the_references_bit_for_bit(seed, n, kind):
    # the sums a themselves, not only floor(a): an operation reordered or fused changes their last bits
    rng = np.random.default_rng(seed)
    cells = layout(kind, n, rng)
    s_sym = smooth_field(cells, rng) + rng.integers(-3, 4, len(cells))
    idx, d2 = predict.causal_neighbors(cells)
    beta = predict.predictor_weights(cells, idx, d2)
    residual = predict.residuals(cells, s_sym)
    out, pred = np.empty(len(cells), dtype=np.int64), np.empty(len(cells))
    lo, hi = -float(Q.S_SYMBOL_LIMIT), float(Q.S_SYMBOL_LIMIT - 1)
    predict._native.reconstruct(idx, beta, residual, out, lo, hi, 1 << 40, pred)
    assert np.array_equal(out, s_sym)
    assert pred.tobytes() == reference_sums(np.where(idx >= 0, idx, len(cells)), beta, s_sym).tobytes()


def smooth_field(cells: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """s symbols of a random plane (a signed distance), scaled so that the predictions land near integers often."""
    normal = rng.normal(size=3)
    scale = rng.choice([0.05, 0.5, 1.0, 3.0]) / max(np.linalg.norm(normal), 1e-9)
    s = np.floor(cells @ normal * scale + rng.uniform(-1, 1))
    return np.clip(s - np.median(s) if len(s) else s, -Q.S_SYMBOL_LIMIT, Q.S_SYMBOL_LIMIT - 1).astype(np.int64)


def layout(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """A point set (canonical, unique cells) of one of the shapes that stress the search differently."""
    if kind == "uniform":
        cells = rng.integers(0, 1 << int(rng.integers(2, 17)), (n, 3))
    elif kind == "clustered":  # a few tight clusters far apart: the first points of each find only far ones
        centers = rng.integers(0, 1 << 16, (int(rng.integers(1, 6)), 3))
        cells = centers[rng.integers(0, len(centers), n)] + rng.integers(-6, 7, (n, 3))
    elif kind == "lattice":  # many equal distances: the (d2, index) tie rule decides
        side = max(2, round(n ** (1 / 3)) + 1)
        cells = np.stack(np.meshgrid(*[np.arange(side) * int(rng.integers(1, 4))] * 3, indexing="ij"), -1)
        cells = cells.reshape(-1, 3)[:n] + 1000
    elif kind == "surface":  # points near a sphere, like a fitted file's
        d = rng.normal(size=(n, 3))
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
        cells = np.rint(30000 + d * 20000 * rng.uniform(0.97, 1.03, (n, 1))).astype(np.int64)
    else:  # "sparse-dense": a full block (dense) and scattered points around it (sparse)
        m = min(n, 1000)
        side = round(m ** (1 / 3)) + 1
        block = np.stack(np.meshgrid(*[np.arange(side) + 500] * 3, indexing="ij"), -1).reshape(-1, 3)[:m]
        cells = np.concatenate([block, rng.integers(400, 620, (n - len(block), 3))])
    return canonical_cells(np.clip(cells, 0, (1 << 16) - 1))


@needs_native
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(0, 400),
    kind=st.sampled_from(["uniform", "clustered", "lattice", "surface", "sparse-dense"]),
    huge=st.booleans(),
)
@settings(max_examples=80, deadline=None)
def test_native_and_reference_agree_on_any_point_set(seed, n, kind, huge):
    rng = np.random.default_rng(seed)
    cells = layout(kind, n, rng)
    residual = rng.integers(-40, 40, len(cells))
    if huge and len(cells):  # corrupted residuals: far outside the symbol range, both signs
        hit = rng.integers(0, len(cells), 1 + len(cells) // 10)
        residual[hit] = rng.choice([2**62, -(2**62), 2**40 + 1, -(2**21), 2**20], len(hit))
    assert_same_prediction(cells, residual)
    assert_round_trip(cells, smooth_field(cells, rng))


@needs_native
@pytest.mark.parametrize("n", [0, 1, 2, 3, 8, 9])
def test_native_and_reference_agree_on_tiny_sets(n):
    cells = canonical_cells(np.random.default_rng(n).integers(0, 5, (n, 3)))
    assert_same_prediction(cells, np.arange(len(cells)) % 5 - 2)


@needs_native
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(0, 200),
    spread=st.sampled_from([3, 6, 300]),
    widths=st.sampled_from([(4, 8, 16), (3, 24), (24, 96, 512, 4096)]),
    per_cell=st.sampled_from([0.5, 4.0, 50.0]),
    cap=st.sampled_from([1, 30, 1 << 16]),
)
@settings(max_examples=60, deadline=None)
def test_native_bound_rank_and_work_cap_give_the_references_neighbours(seed, n, spread, widths, per_cell, cap):
    # a small bound rank (QUERY_WIDTHS[-1]) cuts many neighbour lists; a small cap sends points to the k-d tree
    rng = np.random.default_rng(seed)
    cells = canonical_cells(rng.integers(0, spread, (n, 3)))
    names = ("QUERY_WIDTHS", "GRID_POINTS_PER_CELL", "GRID_MAX_CANDIDATES")
    saved = [getattr(predict, name) for name in names]
    try:
        for name, value in zip(names, (widths, per_cell, cap), strict=True):
            setattr(predict, name, value)
        (idx, d2), (ref_idx, ref_d2) = both_paths(predict.causal_neighbors, cells)
    finally:
        for name, value in zip(names, saved, strict=True):
            setattr(predict, name, value)
    assert np.array_equal(idx, ref_idx) and np.array_equal(d2, ref_d2)


@needs_native
def test_native_sparse_points_beside_a_dense_block_match_with_and_without_the_cap():
    # 8000 points in a full block (more than the bound rank 4096) and sparse points around: the bound cuts, and
    # with a small cap the points whose block is too big are answered by the k-d tree
    block = np.stack(np.meshgrid(*[np.arange(20) + 100] * 3, indexing="ij"), -1).reshape(-1, 3)
    rng = np.random.default_rng(5)
    cells = canonical_cells(np.concatenate([block, rng.integers(60, 160, (300, 3))]))
    (idx, d2), (ref_idx, ref_d2) = both_paths(predict.causal_neighbors, cells)
    assert np.array_equal(idx, ref_idx) and np.array_equal(d2, ref_d2)
    assert ((idx == -1).sum(axis=1) > 0)[predict.K_NEIGHBORS :].any()  # the bound did cut somewhere
    saved = predict.GRID_MAX_CANDIDATES
    calls = []
    tree_rows = predict._tree_rows
    try:
        predict.GRID_MAX_CANDIDATES = 1000
        predict._tree_rows = lambda *a: calls.append(len(a[1])) or tree_rows(*a)
        predict.NATIVE = True
        capped = predict.causal_neighbors(cells)
    finally:
        predict.GRID_MAX_CANDIDATES, predict._tree_rows, predict.NATIVE = saved, tree_rows, True
    assert calls and calls[0] > 0  # the k-d tree answered some points
    assert np.array_equal(capped[0], ref_idx) and np.array_equal(capped[1], ref_d2)


FILES = Path(os.environ.get("TETWEAVE_DECODE_FILES") or Path.home() / ".cache" / "tetweave" / "decode_speed")


@needs_native
@pytest.mark.skipif(not list(FILES.glob("*.tw")), reason=f"no real .tw files in {FILES}")
def test_native_and_reference_agree_on_the_real_files():
    for path in sorted(FILES.glob("*.tw"))[:8]:
        tw = unpack_v2(path.read_bytes())  # decoded by the compiled path (the default)
        saved = predict.NATIVE
        try:
            predict.NATIVE = False
            ref = unpack_v2(path.read_bytes())
        finally:
            predict.NATIVE = saved
        assert np.array_equal(tw.s_sym, ref.s_sym), path.name
        assert_same_prediction(tw.cells, predict.residuals(tw.cells, tw.s_sym))
        assert_round_trip(tw.cells, tw.s_sym)


def test_the_reference_path_runs_when_the_extension_is_off(monkeypatch):
    # with NATIVE off nothing may reach the extension (here: an object that fails on any use)
    class Absent:
        def __getattr__(self, name):
            raise AssertionError(f"the compiled path was used: {name}")

    rng = np.random.default_rng(7)
    cells = canonical_cells(rng.integers(0, 64, (500, 3)))
    s_sym = rng.integers(-30, 30, len(cells))
    monkeypatch.setattr(predict, "_native", Absent())
    monkeypatch.setattr(predict, "NATIVE", False)
    r = predict.residuals(cells, s_sym)
    assert np.array_equal(predict.reconstruct(cells, r), s_sym)
    monkeypatch.setattr(predict, "NATIVE", True)
    with pytest.raises(AssertionError, match="compiled path"):
        predict.reconstruct(cells, r)  # the guard itself works


def test_the_extension_is_built_where_a_c_compiler_is():
    # `pip install -e .` builds it (setup.py, optional); a missing build on a machine with gcc is a bug
    if shutil.which("gcc") is None and shutil.which("cc") is None:
        pytest.skip("no C compiler")
    assert predict._native is not None
    assert predict.NATIVE or os.environ.get("TETWEAVE_NATIVE") == "0"


@needs_native
def test_native_rejects_malformed_arrays_instead_of_reading_out_of_bounds():
    native = predict._native
    n, k = 10, predict.K_NEIGHBORS
    cells = canonical_cells(np.random.default_rng(0).integers(0, 9, (n, 3)))
    n = len(cells)
    morton = Q.morton_keys(cells).astype(np.int64)
    idx, d2 = np.full((n, k), -1), np.zeros((n, k), dtype=np.int64)
    over = np.empty(n, dtype=np.int64)
    with pytest.raises(ValueError):  # too short an output
        native.neighbors(cells, morton, idx[:-1], d2, over, k, 4096, 0, 1 << 16)
    with pytest.raises(ValueError):  # wrong dtype
        native.neighbors(cells.astype(np.int32), morton, idx, d2, over, k, 4096, 0, 1 << 16)
    with pytest.raises(ValueError):  # not in canonical order
        native.neighbors(cells[::-1].copy(), morton[::-1].copy(), idx, d2, over, k, 4096, 0, 1 << 16)
    with pytest.raises(ValueError):  # coordinates beyond 16 bits
        native.neighbors(cells + (1 << 16), morton, idx, d2, over, k, 4096, 0, 1 << 16)
    beta = np.zeros((n, k))
    out = np.empty(n, dtype=np.int64)
    res = np.zeros(n, dtype=np.int64)
    for bad in (n, 5, -2):  # a neighbour index that is not an earlier point
        idx_bad = np.full((n, k), -1)
        idx_bad[5, 0] = bad
        with pytest.raises(ValueError):
            native.reconstruct(idx_bad, beta, res, out, -1.0, 1.0, 1 << 40)
    idx_far = np.full((n, k), -1)
    idx_far[5, 0] = n
    with pytest.raises(ValueError):  # weights: a neighbour beyond the points
        native.weights(cells, idx_far, np.ones((n, k), dtype=np.int64), beta, 0.1)
    idx_near = np.full((n, k), -1)
    idx_near[5, 0] = 0
    with pytest.raises(ValueError):  # weights: a neighbour at distance 0 (the cells are unique)
        native.weights(cells, idx_near, d2, beta, 0.1)
    with pytest.raises(ValueError):  # beta of the wrong length
        native.reconstruct(np.full((n, k), -1), beta[:-1], res, out, -1.0, 1.0, 1 << 40)
    nan_beta = np.full((n, k), np.nan)
    idx_ok = np.full((n, k), -1)
    idx_ok[1:, 0] = 0
    with pytest.raises(ValueError, match="NaN"):  # as Python's math.floor
        native.reconstruct(idx_ok, nan_beta, res, out, -1.0, 1.0, 1 << 40)


# ------------------------------------------------------------------------------------------------------------
# marching tets topology (geometry/_mt_native.c against geometry/marching_tets.py)

needs_mt_native = pytest.mark.skipif(MT._mt_native is None, reason="C extension not built")


def both_mt_paths(func, *args, **kwargs):
    """func(*args) with marching tets' compiled path on, then off; returns (native, reference) or the exceptions."""
    out = []
    saved = MT.NATIVE
    try:
        for flag in (True, False):
            MT.NATIVE = flag
            try:
                out.append(func(*args, **kwargs))
            except TopologyError as error:
                out.append(error)
    finally:
        MT.NATIVE = saved
    return out


@needs_mt_native
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(0, 300),
    lattice=st.booleans(),
    sh=st.booleans(),
    hull=st.booleans(),
    inside_fraction=st.sampled_from([0.0, 0.1, 0.5, 1.0]),
)
@settings(max_examples=40, deadline=None)
def test_native_marching_tets_topology_equals_the_reference(seed, n, lattice, sh, hull, inside_fraction):
    rng = np.random.default_rng(seed)
    pts = rng.integers(0, 6, (n, 3)).astype(np.float64) if lattice else rng.uniform(-1, 1, (n, 3))
    pts = np.unique(pts, axis=0)
    if len(pts) < 5:
        return
    tz = tetrahedralize(pts)
    s = np.where(rng.random(len(pts)) < inside_fraction, -1.0, 1.0) * rng.uniform(0.1, 1, len(pts))
    c = rng.normal(0, 0.3, (len(pts), 4)) if sh else None
    native, reference = both_mt_paths(marching_tets_numpy, pts, tz.tets, s, c, tz.hull_faces if hull else None)
    for a, b in zip(native, reference, strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)
        assert a.flags.writeable and a.flags.c_contiguous


@needs_mt_native
@given(seed=st.integers(0, 2**32 - 1), edits=st.integers(1, 4), closed=st.booleans())
@settings(max_examples=60, deadline=None)
def test_native_check_manifold_finds_the_references_defect(seed, edits, closed):
    # a closed mesh from marching tets, then random damage: faces dropped, repeated, flipped or collapsed
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1, 1, (60, 3))
    tz = tetrahedralize(pts)
    s = np.linalg.norm(pts, axis=1) - 0.6
    faces = marching_tets_numpy(pts, tz.tets, s, None, tz.hull_faces).faces.copy()
    nv = int(faces.max()) + 1 if len(faces) else 0
    for _ in range(edits):
        if not len(faces):
            break
        i = int(rng.integers(len(faces)))
        kind = int(rng.integers(4))
        if kind == 0:
            faces = np.delete(faces, i, axis=0)
        elif kind == 1:
            faces = np.concatenate([faces, faces[i : i + 1]])
        elif kind == 2:
            faces[i] = faces[i, [0, 2, 1]]
        else:
            faces[i, 1] = faces[i, 0]
    native, reference = both_mt_paths(check_manifold, faces, nv, closed=closed)
    assert type(native) is type(reference) and str(native) == str(reference)


@needs_mt_native
def test_native_marching_tets_rejects_out_of_range_tets():
    inside = np.array([True, False, False, False])
    table = MT._ACTIVE_INT
    for bad in (4, -1):
        with pytest.raises(ValueError):
            MT._mt_native.topology(np.array([[0, 1, 2, bad]]), inside, 4, table, MT.TRIANGLE_TABLE)
    with pytest.raises(ValueError):  # tets not (T, 4)
        MT._mt_native.topology(np.array([0, 1, 2]), inside, 4, table, MT.TRIANGLE_TABLE)
    # faces out of range: left to the reference (which decides as before)
    assert MT._mt_native.manifold(np.array([[0, 1, 7]]), 4, True) == -1
