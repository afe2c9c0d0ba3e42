"""Decode levels (`tetweave decode --level control|smoothed|full`, `decoder.decode(..., level=)`): each level of
files with smoothing, subdivision, creases and holes is a closed 2-manifold (or a 2-manifold with the file's holes)
free of self-intersections, has the faces `tetweave info` announces, and "full" is the default decode."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from tetweave_codec.cli.main import main
from tetweave_codec.decoder import LEVELS, decode, decode_detailed, level_faces, mesh_from_points
from tetweave_codec.formats.common import FLAG_HOLES, FLAG_S_PREDICTED, smoothing_flags, subdivision_flags
from tetweave_codec.formats.tw import unpack
from tetweave_codec.formats.tw2 import pack_v2, quantize_file
from tetweave_codec.geometry.holes import face_ranks, pinched_vertices, without_pinches
from tetweave_codec.geometry.intersections import self_intersecting_faces
from tetweave_codec.geometry.marching_tets import check_manifold

OFFSET = np.array([1.0, -2.0, 0.5])


def _sphere(pts):
    return np.linalg.norm(pts, axis=1) - 0.6


def _torus(pts):
    ring = np.hypot(pts[:, 0], pts[:, 1]) - 0.55
    return np.hypot(ring, pts[:, 2]) - 0.22


def _box(pts):
    return np.abs(pts).max(axis=1) - 0.5


def make_file(sdf, n, smoothing, subdivision, creases=False, sh=-1, seed=0, bits=8) -> bytes:
    """A v2 file of random points with s = sdf (an analytic shape) and the given filter flags."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-0.9, 0.9, (n, 3))
    c = rng.normal(size=(n, (sh + 1) ** 2)) * 0.01 if sh >= 0 else None
    flags = FLAG_S_PREDICTED | smoothing_flags(smoothing) | subdivision_flags(subdivision)
    steps = [0.05] * (sh + 1)
    f, _ = quantize_file(
        pts, sdf(pts), c, sh, position_bits=bits, s_step=1e-3, c_band_steps=steps, scale=2.0, offset=OFFSET,
        flags=flags,
    )  # fmt: skip
    return pack_v2(replace(f, creases=creases))


def with_holes(data: bytes, z_cut: float) -> bytes:
    """`data` with a holes section: the control faces above z_cut (input frame), less any that would pinch."""
    control = decode_detailed(data, level="control")
    f0 = control.extracted_faces
    z = control.closed_vertices[f0].mean(axis=1)[:, 2]
    remove = without_pinches(f0, z > z_cut)
    assert 0 < remove.sum() < len(f0)
    ranks = np.sort(face_ranks(f0)[remove])
    tw = unpack(data)
    return pack_v2(replace(tw, flags=tw.flags | FLAG_HOLES, holes=ranks))


FILES = {
    "sphere, 1 step + 1 level": lambda: make_file(_sphere, 1500, 1, 1),
    "torus, 2 steps + 1 level, SH 1": lambda: make_file(_torus, 2500, 2, 1, sh=1, seed=1),
    "sphere, 3 steps + 2 levels": lambda: make_file(_sphere, 600, 3, 2, seed=2),
    "box, 1 step keeping creases": lambda: make_file(_box, 2000, 1, 0, creases=True, seed=3),
    "box, 1 step + 1 level keeping creases": lambda: make_file(_box, 1500, 1, 1, creases=True, seed=4),
    "subdivision only": lambda: make_file(_torus, 2000, 0, 1, seed=5),
    "sphere with a hole, 1 step + 1 level": lambda: with_holes(make_file(_sphere, 1500, 1, 1, seed=6), OFFSET[2] + 0.8),
}


def boundary_edges(faces: np.ndarray) -> int:
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return int((counts == 1).sum())


def assert_valid(v: np.ndarray, f: np.ndarray, holes: bool) -> None:
    """Closed (or, with holes, open along boundaries only), 2-manifold, oriented, no self-intersections."""
    assert len(f) > 0
    check_manifold(f, len(v), closed=not holes)
    if holes:
        assert boundary_edges(f) > 0 and not len(pinched_vertices(f, len(v)))
    assert len(np.unique(f)) == len(v)  # every vertex used
    assert not self_intersecting_faces(v, f).any()


@pytest.fixture(scope="module", params=list(FILES))
def case(request):
    return request.param, FILES[request.param]()


def test_every_level_is_valid_and_has_the_announced_faces(case):
    name, data = case
    tw = unpack(data)
    holes = tw.holes is not None
    counts = level_faces(data)
    meshes = {level: decode_detailed(data, level=level) for level in LEVELS}
    for level, res in meshes.items():
        assert_valid(res.vertices, res.faces, holes)
        assert len(res.faces) == counts[level], (name, level)
        assert res.level == level
    control, smoothed, full = (meshes[k] for k in LEVELS)
    # control: the marching-tets surface itself; smoothed: same faces, vertices moved by the Taubin steps only
    np.testing.assert_array_equal(control.faces, smoothed.faces)
    if tw.smoothing:
        assert not np.array_equal(control.vertices, smoothed.vertices)
    else:
        np.testing.assert_array_equal(control.vertices, smoothed.vertices)
    assert len(full.faces) == 4**tw.subdivision * len(control.faces)
    # the default decode is the full level, bit for bit
    v, f = decode(data)
    np.testing.assert_array_equal(v, full.vertices)
    np.testing.assert_array_equal(f, full.faces)
    if holes:  # the same holes at every level: Loop halves each boundary edge per level
        edges = [boundary_edges(m.faces) for m in meshes.values()]
        assert edges[0] == edges[1] and edges[2] == 2**tw.subdivision * edges[0]


def test_mesh_from_points_levels_match_decode():
    data = make_file(_torus, 1500, 1, 1, seed=7)
    tw = unpack(data)
    for level in LEVELS:
        v, f = mesh_from_points(tw.points, tw.s, tw.c, tw.sh_degree, tw.backend, tw.smoothing, tw.subdivision,
                                tw.creases, level=level)  # fmt: skip
        ref = decode_detailed(data, level=level)
        np.testing.assert_array_equal(f, ref.faces)
        np.testing.assert_array_equal(v * float(tw.scale) + tw.offset, ref.vertices)


def test_unknown_level_is_refused():
    data = make_file(_sphere, 500, 1, 1)
    with pytest.raises(ValueError, match="level"):
        decode(data, level="coarse")
    with pytest.raises(ValueError, match="level"):
        mesh_from_points(np.zeros((4, 3)), np.ones(4), None, -1, level="")


def test_cli_levels_and_info(tmp_path):
    path = tmp_path / "torus.tw"
    path.write_bytes(make_file(_torus, 2000, 1, 1, seed=8))
    counts = level_faces(path.read_bytes())
    runner = CliRunner()
    info = runner.invoke(main, ["info", str(path)])
    assert info.exit_code == 0, info.output
    line = next(x for x in info.output.splitlines() if x.startswith("faces"))
    assert f"control {counts['control']:,}" in line and f"full {counts['full']:,}" in line
    for level in LEVELS:
        out = tmp_path / f"{level}.ply"
        result = runner.invoke(main, ["decode", str(path), "-o", str(out), "--level", level])
        assert result.exit_code == 0, result.output
        assert f"{counts[level]:,} faces" in result.output
        assert ("not applied" in result.output) == (level != "full")
    bad = runner.invoke(main, ["decode", str(path), "-o", str(tmp_path / "x.ply"), "--level", "coarse"])
    assert bad.exit_code == 2 and "coarse" in bad.output and "Traceback" not in bad.output
    assert not (tmp_path / "x.ply").exists()


def test_levels_of_an_encoded_open_shape(tmp_path):
    """A real encode (tiny fit) of an open shape with --holes keep: every level keeps the holes and stays valid."""
    pytest.importorskip("torch")
    from tetweave_codec.encoder import encode

    # a UV sphere without its top cap: open, one boundary loop
    rows, cols = 24, 48
    theta = np.linspace(0, np.pi, rows + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, cols, endpoint=False)
    ring = np.stack(np.meshgrid(theta, phi, indexing="ij"), -1).reshape(-1, 2)
    v = np.concatenate([np.stack([np.sin(ring[:, 0]) * np.cos(ring[:, 1]), np.sin(ring[:, 0]) * np.sin(ring[:, 1]),
                                  np.cos(ring[:, 0])], 1), [[0, 0, -1.0]]])  # fmt: skip
    faces = []
    for i in range(rows - 2):
        for j in range(cols):
            a, b = i * cols + j, i * cols + (j + 1) % cols
            faces += [[a, a + cols, b], [b, a + cols, b + cols]]
    bottom = len(v) - 1
    last = (rows - 2) * cols
    faces += [[last + j, bottom, last + (j + 1) % cols] for j in range(cols)]
    f = np.array(faces, dtype=np.int64)
    f = f[v[f].mean(1)[:, 2] < 0.6]
    result = encode(v, f, points=512, sh_degree=0, quality="fast", iters=30, device="cpu", seed=0, holes="keep")
    tw = unpack(result.data)
    if tw.holes is None:
        pytest.skip("the tiny fit kept no hole")
    counts = level_faces(result.data)
    for level in LEVELS:
        res = decode_detailed(result.data, level=level)
        assert_valid(res.vertices, res.faces, True)
        assert len(res.faces) == counts[level]
    np.testing.assert_array_equal(decode(result.data)[1], result.faces)
