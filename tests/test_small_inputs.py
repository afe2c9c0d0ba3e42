"""Tiny and bad inputs as a new user gives them (issue 55, "Bad input and small inputs"): a closed 2-manifold out,
or one clear line and exit 2, never an internal error; tiny inputs take the fast default fit; rate control never
proposes a step the container refuses, and an unreachable --size says the smallest size it reached."""

from __future__ import annotations

import struct

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from tetweave_codec.cli.main import main
from tetweave_codec.decoder import decode
from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.quantize import Quantization
from tetweave_codec.geometry.marching_tets import check_manifold

TET_V = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
TET_F = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]


def _obj(path, vertices, faces) -> str:
    """An OBJ with the given vertices and polygon faces (0-based index lists of any length)."""
    lines = ["v " + " ".join(repr(float(x)) for x in v) for v in vertices]
    lines += ["f " + " ".join(str(i + 1) for i in face) for face in faces]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _encode(args) -> tuple:
    """`tetweave encode ARGS`: (result, the stderr lines that are not progress lines)."""
    res = CliRunner().invoke(main, ["encode", *args])
    lines = [line for line in res.stderr.splitlines() if line.strip() and not line.startswith("tetweave encode:")]
    return res, lines


def _assert_closed_file(res, out) -> np.ndarray:
    assert res.exit_code == 0, res.output
    v, f = decode(out.read_bytes())
    assert len(f) > 0
    check_manifold(f, len(v))  # TopologyError unless every edge has exactly two faces, consistently oriented
    return v


# --- item 1: a tetrahedron, two non-coplanar triangles, polygon OBJs -------------------------------------------


def test_summary_context_of_a_tetrahedron_decimated_to_nothing():
    """fast-simplification turns a tetrahedron's 4 faces into none at small fractions: such a decimation is no file
    (Draco refused it with numpy's 'zero-size array' ValueError, the encode's exit 1), not a crash."""
    pytest.importorskip("DracoPy")
    from tetweave_codec.classical import decimate_draco_at_chamfer

    v, f = np.array(TET_V, float), np.array(TET_F)

    def distance(vb, fb):
        return 1e-3

    match = decimate_draco_at_chamfer(v, f, 1e-2, distance, 8, 4)
    assert match.bytes is not None or match.bound in ("below", "above")
    assert all(faces > 0 or np.isinf(err) for faces, _, err in match.settings.values())


@pytest.mark.parametrize(
    "name, vertices, faces",
    [
        ("tetrahedron", TET_V, TET_F),
        ("two_triangles", [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 1, 2], [0, 3, 1]]),
        (
            "quad_cube",
            [[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)],
            [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]],
        ),
        (
            "hexagonal_prism",  # two hexagons and six quads
            [[np.cos(a), np.sin(a), z] for z in (0.0, 1.0) for a in np.linspace(0, 2 * np.pi, 7)[:-1]],
            [[5, 4, 3, 2, 1, 0], [6, 7, 8, 9, 10, 11]] + [[i, (i + 1) % 6, (i + 1) % 6 + 6, i + 6] for i in range(6)],
        ),
    ],
)
def test_tiny_inputs_encode_to_a_closed_mesh(tmp_path, name, vertices, faces):
    src, out = _obj(tmp_path / f"{name}.obj", vertices, faces), tmp_path / f"{name}.tw"
    res, _ = _encode([src, "-o", str(out)])
    _assert_closed_file(res, out)
    assert "Draco" in res.stdout  # the summary's classical context was measured


# --- item 2: an unreachable --size --------------------------------------------------------------------------------


def test_rate_control_steps_stay_within_the_container():
    from tetweave_codec.rate_control.size import scaled

    base = Quantization(position_bits=7, s_step=0.05, c_band_steps=(0.9, 0.9, 0.9, 0.9))
    for scale in (1e-300, 1e-40, 1.0, 1.15**40, 1e300):
        quant = scaled(base, scale)
        assert Q.step_problem("s step", float(np.float32(quant.s_step)), Q.MAX_S_STEP) is None
        for step in quant.c_band_steps:
            assert Q.step_problem("c step", float(np.float32(step)), Q.MAX_C_STEP) is None
    assert scaled(base, 2.0).s_step == 0.1  # inside the range: the plain product


def test_unreachable_size_is_one_line_and_exit_2(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=2)
    src, out = _obj(tmp_path / "sphere.obj", sphere.vertices, sphere.faces), tmp_path / "sphere.tw"
    res, lines = _encode([src, "-o", str(out), "--size", "200", "--quality", "fast", "--iters", "20"])
    assert res.exit_code == 2, res.output
    assert len(lines) == 1 and "internal error" not in lines[0], lines
    assert "the smallest file this input reached has" in lines[0]
    assert not out.exists()


# --- item 3: tiny inputs are fast --------------------------------------------------------------------------------


def test_tiny_input_takes_the_small_fit():
    from tetweave_codec.encoder import DEFAULT_POINTS, MIN_DEFAULT_POINTS, default_points, small_input

    assert small_input(12, 0) and small_input(500, 1)
    assert not small_input(5_000, 1) and default_points(5_000, 1) > MIN_DEFAULT_POINTS
    assert not small_input(10**6, 0) and default_points(10**6, 0) == DEFAULT_POINTS


def test_tiny_input_default_encode_runs_the_preset_iterations():
    """A 12-face cube's default encode runs the "default" preset's 250 + 150 iterations (not the 1.75x scaled 438 +
    262 of a 256-point fit) and a rate option keeps the scaled ones: the pinned rate-controlled files keep their
    bytes."""
    from tetweave_codec.encoder import encode
    from tetweave_codec.fit.config import QUALITY

    box = trimesh.creation.box()
    totals = {}

    def progress(stage, done, total, info):
        totals[stage] = total

    result = encode(box.vertices, box.faces, device="cpu", progress=progress, measure=False)
    preset = QUALITY["default"]
    assert totals["main"] == preset.main_iters and totals["late"] == preset.late_iters
    v, f = decode(result.data)
    check_manifold(f, len(v))


# --- a new user's bad inputs --------------------------------------------------------------------------------------


def _binary_stl_one_triangle(path) -> str:
    row = struct.pack("<12fH", 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0)
    path.write_bytes(bytes(80) + struct.pack("<I", 1) + row)
    return str(path)


def _point_cloud_ply(path) -> str:
    trimesh.PointCloud(np.random.default_rng(0).normal(size=(50, 3))).export(str(path))
    return str(path)


BAD_INPUTS = {
    "nan.obj": lambda p: p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"),
    "degenerate.obj": lambda p: p.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\nf 1 1 4\nf 4 4 4\n"),
    "empty.obj": lambda p: p.write_text(""),
    "not_a_mesh.obj": lambda p: p.write_text("hello\nthis is not a mesh\n"),
    "one_triangle.stl": _binary_stl_one_triangle,
    "point_cloud.ply": _point_cloud_ply,
    "flat_quad.obj": lambda p: p.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n"),
}


@pytest.mark.parametrize("name", list(BAD_INPUTS))
def test_bad_input_is_one_line_and_exit_2(tmp_path, name):
    src, out = tmp_path / name, tmp_path / "out.tw"
    BAD_INPUTS[name](src)
    res, lines = _encode([str(src), "-o", str(out)])
    assert res.exit_code == 2, res.output
    assert len(lines) == 1 and lines[0].startswith("tetweave: error: "), lines
    assert "internal error" not in lines[0]
    assert not out.exists()


def test_glb_with_two_meshes_encodes_to_a_closed_mesh(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box(), node_name="box")
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    scene.add_geometry(ball, node_name="ball", transform=trimesh.transformations.translation_matrix([2.0, 0, 0]))
    src, out = tmp_path / "two.glb", tmp_path / "two.tw"
    scene.export(str(src))
    res, _ = _encode([str(src), "-o", str(out)])
    v = _assert_closed_file(res, out)
    assert np.ptp(v[:, 0]) > 2.5  # both parts are there (the box from -0.5, the ball to 2.5)
