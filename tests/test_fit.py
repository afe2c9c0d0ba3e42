"""The fit's own logic, without a fit: schedules (`config.schedule_for`), the v1 float16 rounding of s and c
(`finish.round_float16`) and the point collisions `finish.finish` resolves before the late stage."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tetweave_codec.errors import TetweaveError
from tetweave_codec.fit import finish as fin
from tetweave_codec.fit.config import QUALITY, FitConfig, LearningRates, Schedule, schedule_for
from tetweave_codec.fit.initialize import MIN_ABS_S
from tetweave_codec.fit.step import FitContext, Params
from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.quantize import Quantization
from tetweave_codec.geometry.delaunay import resolve_backend

# --- config.schedule_for ---


@pytest.mark.parametrize("quality", sorted(QUALITY))
def test_schedule_for_returns_the_preset(quality):
    assert schedule_for(quality) is QUALITY[quality]


def test_schedule_for_splits_iters_like_the_preset():
    default = QUALITY["default"]  # 250 main + 150 late
    assert (default.main_iters, default.late_iters) == (250, 150)
    sch = schedule_for("default", 80)
    assert (sch.main_iters, sch.late_iters) == (50, 30)  # 80 * 250 / 400 = 50
    assert sch.size == default.size and sch.n_views == default.n_views  # only the iteration counts change
    best = schedule_for("best", 1001)  # 800 + 400: 1001 * 2 / 3 = 667.3 -> 667 main, the rest late
    assert (best.main_iters, best.late_iters) == (667, 334)
    two = schedule_for("fast", 2)
    assert (two.main_iters, two.late_iters) == (1, 1)  # never an empty stage


@pytest.mark.parametrize(
    ("quality", "iters", "message"), [("ultra", None, "unknown quality"), ("fast", 1, "at least 2")]
)
def test_schedule_for_errors(quality, iters, message):
    with pytest.raises(TetweaveError, match=message) as err:
        schedule_for(quality, iters)
    if quality == "ultra":
        assert all(name in str(err.value) for name in QUALITY)  # lists the choices


# --- finish.round_float16 ---


def test_round_float16_keeps_every_sign():
    s = np.array([0.0, -0.0, 1e-9, -1e-9, -3e-5, 3e-5, 0.5, -0.5, 2.0**-14, -(2.0**-14)], dtype=np.float32)
    c = np.array([[0.1, -100.0, 100.0]] * len(s), dtype=np.float32)
    s16, c16 = fin.round_float16(s, c)
    assert s16.dtype == np.float16 and c16.dtype == np.float16
    assert np.all(np.abs(s16.astype(np.float64)) >= MIN_ABS_S) and fin.V1_MIN_ABS_S == MIN_ABS_S == 2.0**-14
    # the sign of s < 0 survives; 0 (and -0.0) count as outside, as in marching_tets
    np.testing.assert_array_equal(np.sign(s16), [1, 1, 1, -1, -1, 1, 1, -1, 1, -1])
    np.testing.assert_array_equal(s16[6:], np.float16([0.5, -0.5, 2.0**-14, -(2.0**-14)]))  # larger |s| kept
    np.testing.assert_array_equal(c16[0], np.float16([0.1, -64.0, 64.0]))  # c clamped to +-V1_MAX_ABS_C
    assert np.float16(2.0**-14) > 0 and np.float16(2.0**-14 / 2**11) == 0  # below the floor float16 loses it


# --- finish.finish: collisions ---

CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)


def _state():
    """Corners outside (s = 1) and inner points inside; points 1 and 2 are 1e-5 apart at x = 0.125, where float16's
    spacing is 2^-13, so float16 rounding (and any position grid coarser than 1e-5) merges them."""
    inner = np.array([[0.3, -0.2, 0.1], [0.125, 0.25, 0.375], [0.125 + 1e-5, 0.25, 0.375], [-0.3, 0.25, -0.2]])
    points = np.concatenate([inner, CORNERS])
    s = np.array([-0.5, -0.4, -0.3, -0.6] + [1.0] * 8, dtype=np.float32)
    c = np.arange(len(points), dtype=np.float32)[:, None] * 0.01  # tags each point (SH degree 0)
    return points, s, c


def _finish(quantization):
    points, s, c = _state()
    no_late_stage = Schedule(main_iters=0, late_iters=0, views_per_iter=1, size=8, n_views=1)
    config = FitConfig(points=16, sh_degree=0, schedule=no_late_stage, quantization=quantization)
    device, generator = torch.device("cpu"), torch.Generator().manual_seed(0)
    ctx = FitContext(config, None, None, resolve_backend("auto"), device, generator)  # no targets: never rendered
    params = Params(points.astype(np.float32), s, c, ctx.device, LearningRates())
    return fin.finish(params, ctx), points, s, c


def test_v1_drops_float16_duplicates_first_occurrence_wins():
    result, points, s, c = _finish(None)
    assert result.version == 1 and result.points.dtype == np.float16
    stored = result.points.astype(np.float64)
    assert len(np.unique(result.points.view(np.uint16).reshape(-1, 3), axis=0)) == len(stored)  # no duplicates
    assert len(stored) == len(points) - 1  # exactly the colliding pair merged, every other (active) point kept
    # the kept copy is the first one (index 1): its s and c, not point 2's; the original order is kept
    np.testing.assert_array_equal(stored, points[[0, 1, 3, *range(4, 12)]].astype(np.float32).astype(np.float16))
    np.testing.assert_array_equal(result.s, fin.round_float16(s[[0, 1, 3, *range(4, 12)]], c[:1])[0])
    np.testing.assert_array_equal(result.c[:3, 0], np.float16([0.0, 0.01, 0.03]))


def test_v2_merges_points_of_one_cell_first_occurrence_wins():
    quant = Quantization(position_bits=8, s_step=1e-3, c_band_steps=(0.01, 0.2, 0.2, 0.2))
    result, points, s, c = _finish(quant)
    assert result.version == 2 and len(result.points) == len(points) - 1
    cells = Q.quantize_positions(points.astype(np.float32).astype(np.float64), 8)
    assert np.array_equal(cells[1], cells[2])  # the pair shares a cell
    # canonical order; the merged cell carries point 1's values (s = -0.4, c = 0.01), not point 2's
    assert np.array_equal(result.cells, Q.merge_collisions(cells)[0])
    row = int(np.nonzero((result.cells == cells[1]).all(1))[0][0])
    assert result.s[row] == pytest.approx(-0.4, abs=1e-3) and result.c[row, 0] == pytest.approx(0.01, abs=0.01)
    np.testing.assert_allclose(result.points, Q.dequantize_positions(result.cells, 8))


def test_flat_tets_by_the_exact_determinant():
    cells = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1]], dtype=np.int64)
    tets = np.array([[0, 1, 2, 3], [0, 1, 2, 4], [4, 3, 2, 1]])
    assert fin.flat_tets(cells, tets).tolist() == [True, False, False]
    big = np.array([[0, 0, 0], [65535, 0, 0], [0, 65535, 0], [65535, 65535, 1]], dtype=np.int64)
    assert fin.flat_tets(big, np.array([[0, 1, 2, 3]])).tolist() == [False]  # |det| ~ 2^32: no overflow


@pytest.mark.parametrize("seed", [2, 5, 32])
def test_finalize_leaves_no_flat_tet_on_lattice_points(seed):
    """TetGen returns zero-volume tets for some subsets of a lattice (28 of 200 random 4^3 subsets); marching
    tets would write zero-area triangles across their neighbours. The finish drops points until there are none.
    The exact Delaunay (the encoder's) never makes one."""
    from tetweave_codec.geometry.delaunay import available_backends, tetrahedralize

    rng = np.random.default_rng(seed)
    grid = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = (grid[rng.random(len(grid)) < 0.6] + 100).astype(np.int64)
    exact = tetrahedralize(Q.dequantize_positions(cells, 9), "exact").tets
    assert len(exact) and not fin.flat_tets(cells, exact).any()
    assert fin._drop_flat_tets(cells, np.arange(len(cells)), 9, "exact")[0].tolist() == cells.tolist()
    if "tetgen" not in available_backends():
        pytest.skip("the TetGen half needs tetgenpy")
    before = tetrahedralize(Q.dequantize_positions(cells, 9), "tetgen").tets
    assert fin.flat_tets(cells, before).any()  # the case this guards against
    first = np.arange(len(cells)) * 10
    kept, kept_first = fin._drop_flat_tets(cells, first, 9, "tetgen")
    after = tetrahedralize(Q.dequantize_positions(kept, 9), "tetgen").tets
    assert not fin.flat_tets(kept, after).any()
    assert len(cells) - 4 <= len(kept) < len(cells)
    kept_rows = [i for i, cell in enumerate(cells) if (kept == cell).all(1).any()]
    assert kept_first.tolist() == first[kept_rows].tolist()  # `first` follows the kept points, in order
