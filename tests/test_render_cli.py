"""Tests of `tetweave render`: PNG previews of meshes and .tw files, bad input handling."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner
from PIL import Image

from tetweave_codec.cli.main import main


def _run(*args):
    return CliRunner().invoke(main, ["render", *args])


def _tiles(png, size: int, n: int, pad: int = 4):
    """Split a grid PNG written by image_grid into its n (size, size, 3) views."""
    img = np.asarray(Image.open(png))
    cols = int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / cols))
    assert img.shape == (rows * size + pad * (rows + 1), cols * size + pad * (cols + 1), 3)
    return [
        img[
            pad + r * (size + pad) : pad + r * (size + pad) + size,
            pad + c * (size + pad) : pad + c * (size + pad) + size,
        ]
        for r, c in (divmod(i, cols) for i in range(n))
    ]


def test_render_a_mesh_to_a_png_beside_it(tmp_path):
    mesh = tmp_path / "box.ply"
    trimesh.creation.box(extents=(1.0, 0.6, 0.3)).export(mesh)
    result = _run(str(mesh), "--views", "3", "--size", "48", "--threads", "1")
    assert result.exit_code == 0, result.output
    png = tmp_path / "box.ply.png"
    assert png.is_file() and "wrote" in result.output
    for tile in _tiles(png, 48, 3):
        covered = (tile < 250).any(-1)
        assert 0.05 < covered.mean() < 0.9  # the object fills part of every view, normalized to the frame
        assert not covered[0].any() and not covered[:, 0].any()  # with a white margin around it
    # same input, same bytes
    again = tmp_path / "again.png"
    assert _run(str(mesh), "--views", "3", "--size", "48", "-o", str(again)).exit_code == 0
    assert again.read_bytes() == png.read_bytes()


def test_normal_shading_colours_opposite_sides_differently(tmp_path):
    mesh = tmp_path / "ball.obj"
    trimesh.creation.icosphere(3).export(mesh)
    out = tmp_path / "n.png"
    result = _run(str(mesh), "--views", "1", "--size", "64", "--shading", "normals", "-o", str(out))
    assert result.exit_code == 0, result.output
    (tile,) = _tiles(out, 64, 1)
    left, right = tile[32, 12].astype(int), tile[32, 52].astype(int)
    assert np.abs(left - right).max() > 60


def test_render_a_tw_file(tmp_path):
    tw_module = pytest.importorskip("tetweave_codec.formats.tw")
    pytest.importorskip("tetweave_codec.decoder")
    g = np.random.default_rng(0)
    points = g.uniform(-1.0, 1.0, (600, 3))
    s = np.linalg.norm(points, axis=1) - 0.6  # a sphere of radius 0.6
    tw = tw_module.TetWeaveFile(
        points=points.astype(np.float16),
        s=s.astype(np.float16),
        c=np.zeros((600, 1), np.float16),
        sh_degree=0,
        scale=2.0,
        offset=np.zeros(3),
    )
    path = tmp_path / "ball.tw"
    path.write_bytes(tw_module.pack(tw))
    result = _run(str(path), "--views", "2", "--size", "40")
    assert result.exit_code == 0, result.output
    # the decoded ball, normalized to radius ~0.9 and seen from distance 3 with a 45-degree field of view, is a disc
    # of radius tan(asin(0.9 / 3)) / tan(22.5 deg) = 0.76 half-widths: pi 0.76^2 / 4 = 45 % of the view
    radius = 20 * math.tan(math.asin(0.9 / 3)) / math.tan(math.radians(22.5))
    yy, xx = np.mgrid[0:40, 0:40] + 0.5
    dist = np.hypot(xx - 20, yy - 20)
    for tile in _tiles(tmp_path / "ball.tw.png", 40, 2):
        covered = (tile < 250).any(-1)
        assert covered.mean() == pytest.approx(math.pi * radius**2 / 1600, abs=0.06)
        assert covered[dist < radius - 2].all() and not covered[dist > radius + 2].any()


@pytest.mark.parametrize(
    "content, suffix", [(None, ".ply"), (b"not a mesh", ".ply"), (b"TW garbage", ".tw"), (b"", ".obj")]
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, content, suffix):
    path = tmp_path / f"bad{suffix}"
    if content is not None:
        path.write_bytes(content)
    result = _run(str(path), "--size", "32")
    assert result.exit_code == 2
    assert len(result.output.strip().splitlines()) == 1 and "error" in result.output
    assert "Traceback" not in result.output
    assert not (tmp_path / f"bad{suffix}.png").exists()


def test_output_must_be_png(tmp_path):
    mesh = tmp_path / "box.ply"
    trimesh.creation.box().export(mesh)
    result = _run(str(mesh), "-o", str(tmp_path / "x.jpg"))
    assert result.exit_code == 2 and not (tmp_path / "x.jpg").exists()
