"""The grid layout (fit.grid, `encode(layout="grid")`): the band's cells, the frame, encode / decode round trips."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from tetweave_codec import rate_control
from tetweave_codec.cli.main import main
from tetweave_codec.decoder import decode
from tetweave_codec.encoder import encode
from tetweave_codec.errors import InputError
from tetweave_codec.fit.grid import (
    GRID_BAND,
    GRID_SPREAD,
    MAX_LATTICE_BITS,
    MIN_LATTICE_BITS,
    GridBand,
    GridFrame,
    frame_for_cell,
    lattice_cell,
    max_frame_scale,
)
from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.tw import unpack
from tetweave_codec.meshio import normalize

manifold3d = pytest.importorskip("manifold3d")

FAST = {"quality": "fast", "iters": 40, "device": "cpu", "seed": 0}


def _mesh(m) -> tuple[np.ndarray, np.ndarray]:
    mesh = m.to_mesh()
    return np.asarray(mesh.vert_properties[:, :3], dtype=np.float64), np.asarray(mesh.tri_verts, dtype=np.int64)


def sphere(n: int = 64) -> tuple[np.ndarray, np.ndarray]:
    return _mesh(manifold3d.Manifold.sphere(1.0, n))


def torus() -> tuple[np.ndarray, np.ndarray]:
    return _mesh(manifold3d.Manifold.revolve(manifold3d.CrossSection.circle(0.35, 48).translate((1.0, 0.0)), 96))


def _check_manifold(v: np.ndarray, f: np.ndarray) -> None:
    m = manifold3d.Manifold(manifold3d.Mesh(vert_properties=v.astype(np.float32), tri_verts=f.astype(np.uint32)))
    assert m.status() == manifold3d.Error.NoError
    assert len(f) > 0


@given(st.floats(min_value=1e-4, max_value=0.5))
@settings(max_examples=200, deadline=None)
def test_frame_for_cell_gives_the_cell(cell):
    frame = frame_for_cell(cell)
    assert MIN_LATTICE_BITS <= frame.bits <= MAX_LATTICE_BITS
    assert frame.stored_bits == frame.bits + GRID_SPREAD and Q.check_bits(frame.stored_bits)
    assert 0 < frame.frame_scale <= max_frame_scale(frame.bits)
    if frame.bits < MAX_LATTICE_BITS:
        assert frame.cell == pytest.approx(cell, rel=1e-9)
    else:  # finer than the finest lattice holds: its largest scale
        assert frame.cell == pytest.approx(cell, rel=1e-9) or frame.frame_scale == max_frame_scale(frame.bits)
    if frame.bits > MIN_LATTICE_BITS:  # the coarsest lattice that keeps the band inside the grid
        assert lattice_cell(frame.bits - 1) / cell > max_frame_scale(frame.bits - 1)


def test_frame_for_cell_rejects_nonsense():
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError):
            frame_for_cell(bad)


@pytest.mark.parametrize("frame", [GridFrame(4, 1.0), GridFrame(6, 1.0), GridFrame(7, 0.8), GridFrame(7, 1.29)])
def test_band_cells_of_a_sphere_are_the_brute_force_band(frame):
    """Every cell whose centre lies within GRID_BAND cells of the unit sphere (radius 0.9 in the normalized frame),
    no other; s is the analytic signed distance (to the polygonal sphere's ~1e-3), in canonical order."""
    v, f = sphere(96)
    nv = normalize(v)[0]
    band = GridBand(nv, f)
    cells, s = band.cells(frame)
    k, cell = frame.frame_scale, lattice_cell(frame.bits)
    # brute force over the box around the sphere (grid frame), by the analytic distance
    lo = max(int(math.floor((-k - 2 * cell + Q.GRID_BOUND) / cell)), 0)
    hi = min(int(math.ceil((k + 2 * cell + Q.GRID_BOUND) / cell)), (1 << frame.bits) - 1)
    ax = np.arange(lo, hi + 1)
    grid = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3) << GRID_SPREAD  # stored cells
    radius = k * np.linalg.norm(nv, axis=1).max()  # the polygon's vertices lie on the sphere
    d = np.linalg.norm(Q.dequantize_positions(grid, frame.stored_bits), axis=1) - radius
    sure = grid[np.abs(d) < GRID_BAND * cell - 2e-3 * k]  # clear of the polygonal sphere's deviation
    maybe = grid[np.abs(d) < GRID_BAND * cell + 2e-3 * k]
    got = {tuple(c) for c in cells}
    assert {tuple(c) for c in sure} <= got <= {tuple(c) for c in maybe}
    centres = Q.dequantize_positions(cells, frame.stored_bits)
    analytic = np.linalg.norm(centres, axis=1) - radius
    np.testing.assert_allclose(s, analytic, atol=3e-3 * k)
    assert np.all(np.sign(s) == np.sign(analytic)) or np.all(np.abs(analytic[np.sign(s) != np.sign(analytic)]) < 3e-3)
    np.testing.assert_array_equal(Q.canonical_order(cells, frame.stored_bits), np.arange(len(cells)))
    again = GridBand(nv, f).cells(frame)
    np.testing.assert_array_equal(again[0], cells)
    np.testing.assert_array_equal(again[1], s)


def test_cell_for_points_hits_the_count():
    v, f = torus()
    band = GridBand(normalize(v)[0], f)
    for target in (800, 3000):
        cell = band.cell_for_points(target)
        got = band.count(frame_for_cell(cell))
        assert abs(math.log(got / target)) < 0.15


def test_grid_encode_round_trip_is_closed_manifold_and_deterministic():
    v, f = torus()
    a = encode(v, f, points=2000, layout="grid", **FAST)
    b = encode(v, f, points=2000, layout="grid", **FAST)
    assert a.data == b.data
    dv, df = decode(a.data)
    np.testing.assert_array_equal(dv, a.vertices)
    np.testing.assert_array_equal(df, a.faces)
    _check_manifold(dv, df)
    assert a.stats["chamfer"] < 3e-3
    tw = unpack(a.data)
    # the stored grid is the band's, in the frame the transform undoes: positions come back in the input's units
    assert tw.position_bits >= Q.POSITION_BITS_MIN
    assert np.allclose(dv.min(axis=0), v.min(axis=0), atol=0.05) and np.allclose(
        dv.max(axis=0), v.max(axis=0), atol=0.05
    )


def test_grid_late_stage_keeps_the_band_signs():
    """No s changes sign in the late stage: the stored symbols' signs are the band's inside / outside."""
    import torch

    from tetweave_codec.fit.config import QUALITY
    from tetweave_codec.fit.finish import complete
    from tetweave_codec.fit.loop import deterministic_torch
    from tetweave_codec.job import FitSettings, grid_layout_stage, make_job

    v, f = torus()
    settings = FitSettings(1, QUALITY["fast"], "fast", torch.device("cpu"), smoothing=1, subdivision=1)
    job = make_job(v, f, settings, layout="grid")
    ctx, fixed, quant = grid_layout_stage(job, frame_for_cell(job.grid_band().cell_for_points(1500)))
    assert fixed.keep_signs and ctx.frame_scale == frame_for_cell(job.grid_band().cell_for_points(1500)).frame_scale
    with deterministic_torch():
        result = complete(fixed, ctx, quant)
    np.testing.assert_array_equal(result.s_sym < 0, fixed.s < 0)
    np.testing.assert_array_equal(result.cells, fixed.cells)


@pytest.mark.parametrize("size", [3000, 7000])
def test_grid_size_target_lands_in_the_band(size):
    v, f = torus()
    result = encode(v, f, size=size, layout="grid", **FAST)
    assert rate_control.SIZE_FLOOR * size <= len(result.data) <= size
    assert "grid layout" in result.stats["rate_control"]
    dv, df = decode(result.data)
    np.testing.assert_array_equal(dv, result.vertices)
    _check_manifold(dv, df)


def test_grid_max_error_target_is_met():
    v, f = sphere()
    result = encode(v, f, max_error=2e-3, layout="grid", **FAST)
    assert result.stats["chamfer"] <= 2e-3
    _check_manifold(result.vertices, result.faces)


def test_grid_layout_rejects_what_it_cannot_do():
    v, f = sphere()
    with pytest.raises(InputError, match="layout"):
        encode(v, f, layout="voxels", **FAST)
    with pytest.raises(InputError, match="grid layout"):
        encode(v, f, layout="grid", container_version=1, **FAST)


def test_cli_grid_layout(tmp_path):
    v, f = sphere(32)
    import trimesh

    src = tmp_path / "s.ply"
    trimesh.Trimesh(v, f).export(src)
    out = tmp_path / "s.tw"
    res = CliRunner().invoke(main, ["encode", str(src), "-o", str(out), "--layout", "grid", "--points", "1k",
                                    "--quality", "fast", "--iters", "20", "--device", "cpu", "-q"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert out.exists()
    bad = tmp_path / "b.tw"
    res = CliRunner().invoke(main, ["encode", str(src), "-o", str(bad), "--layout", "grid", "--s-step", "1e-3", "-q"])
    assert res.exit_code == 2
    assert "grid layout" in res.output and "Traceback" not in res.output
    assert not bad.exists()


def test_grid_size_beyond_its_point_cap_is_refused_before_any_fit(monkeypatch):
    """The grid layout has its own cap (its late stage is cheaper than a fit); beyond it, one clear error."""
    v, f = torus()
    monkeypatch.setattr("tetweave_codec.rate_control.size.GRID_MAX_RATE_POINTS", 500)
    monkeypatch.setattr("tetweave_codec.fit.finish.late_stage", lambda *a, **k: pytest.fail("no fit expected"))
    with pytest.raises(InputError, match="grid layout"):
        encode(v, f, size=20000, layout="grid", **FAST)


def test_best_layout_keeps_the_better_file():
    """--layout best: both layouts at the size, the lower Chamfer distance kept, both reported."""
    v, f = torus()
    size = 4000
    fit = encode(v, f, size=size, layout="fit", **FAST)
    grid = encode(v, f, size=size, layout="grid", **FAST)
    best = encode(v, f, size=size, layout="best", **FAST)
    winner = fit if fit.stats["chamfer"] <= grid.stats["chamfer"] else grid
    assert best.data == winner.data
    assert best.stats["layout"] == winner.stats["layout"]
    assert best.stats["layouts"] == {
        "fit": {"bytes": len(fit.data), "chamfer": fit.stats["chamfer"]},
        "grid": {"bytes": len(grid.data), "chamfer": grid.stats["chamfer"]},
    }
    assert best.stats["rate_control"].startswith(f"best layout {winner.stats['layout']}")
    dv, df = decode(best.data)
    np.testing.assert_array_equal(dv, best.vertices)
    np.testing.assert_array_equal(df, best.faces)


def test_best_layout_needs_a_target_and_survives_one_failing_layout(monkeypatch):
    v, f = torus()
    with pytest.raises(InputError, match="best layout"):
        encode(v, f, points=1000, layout="best", **FAST)
    # the grid layout cannot meet this size (cap): the fit layout's file is kept, the grid's failure reported
    monkeypatch.setattr("tetweave_codec.rate_control.size.GRID_MAX_RATE_POINTS", 100)
    best = encode(v, f, size=3000, layout="best", **FAST)
    assert best.stats["layout"] == "fit" and "grid layout" in best.stats["layouts"]["grid"]["error"]
