"""metrics/unseen.py: the share of a decoded mesh's area no outside view sees, the encoder's self-check (issue 55,
item 3), against analytic truths built here; and its line in the encode summary and field in the batch manifest."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from tetweave_codec.bench.methods import Method
from tetweave_codec.cli.main import main
from tetweave_codec.geometry.triangles import face_areas
from tetweave_codec.metrics.unseen import (
    RESOLUTION,
    WARN_SHARE,
    SelfCheck,
    resolution_for,
    self_check,
    unseen_area_share,
    unseen_faces,
)
from tetweave_codec.runner.batch import summary_lines

trimesh = pytest.importorskip("trimesh")


def mesh_of(m) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def ball(radius: float = 0.9, centre=(0.0, 0.0, 0.0), subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray]:
    v, f = mesh_of(trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius))
    return v + np.asarray(centre, dtype=np.float64), f


def join(*parts):
    offsets = np.cumsum([0] + [len(v) for v, _ in parts])
    faces = [f + o for (_, f), o in zip(parts, offsets[:-1], strict=True)]
    return np.concatenate([v for v, _ in parts]), np.concatenate(faces)


def area(part) -> float:
    return float(face_areas(*part).sum())


def test_a_sphere_is_all_seen():
    v, f = ball(subdivisions=4)
    assert unseen_area_share(v, f) == 0.0
    assert not unseen_faces(v, f).any()


def test_a_small_sphere_inside_is_exactly_its_area_share():
    outer, inner = ball(0.9), ball(0.3, (0.2, -0.1, 0.05), subdivisions=2)
    v, f = join(outer, inner)
    unseen = unseen_faces(v, f)
    assert not unseen[: len(outer[1])].any() and unseen[len(outer[1]) :].all()  # face by face
    truth = area(inner) / (area(outer) + area(inner))
    assert unseen_area_share(v, f) == pytest.approx(truth, rel=1e-12)
    # either orientation of the inner shell (a hidden part or a cavity): the same faces
    assert unseen_area_share(v, np.concatenate([outer[1], inner[1][:, ::-1] + len(outer[0])])) == pytest.approx(truth)


def box_with_wall(wall_x: float) -> tuple[np.ndarray, np.ndarray, float]:
    """A 2 x 1 x 1 box of two triangles per side with an internal wall (a membrane, two triangles) across it at
    x = wall_x; the wall's analytic share of the area, 1 / (10 + 1)."""
    v, f = mesh_of(trimesh.creation.box(extents=(2.0, 1.0, 1.0)))
    wall_v = np.array([[wall_x, -0.5, -0.5], [wall_x, 0.5, -0.5], [wall_x, 0.5, 0.5], [wall_x, -0.5, 0.5]])
    wall_f = np.array([[0, 1, 2], [0, 2, 3]])
    v, f = join((v, f), (wall_v, wall_f))
    return v, f, 1.0 / 11.0


@pytest.mark.parametrize("wall_x", [0.0, 0.37])
def test_box_with_an_internal_wall_matches_the_area_ratio(wall_x):
    v, f, truth = box_with_wall(wall_x)
    assert len(f) == 14
    assert unseen_area_share(v, f) == pytest.approx(truth, abs=1e-9)


def test_membrane_as_a_decoder_leaves_it_a_thin_cavity():
    """A membrane the decoder keeps is a thin closed bubble inside the solid (the mesh is a closed 2-manifold):
    a box with a 0.02-thick slab cut out of its inside (manifold3d), share = the slab's area over the total."""
    manifold3d = pytest.importorskip("manifold3d")
    outer = manifold3d.Manifold.cube((2.0, 1.0, 1.0), center=True)
    slab = manifold3d.Manifold.cube((0.02, 0.8, 0.8), center=True).translate((0.3, 0.0, 0.0))
    mesh = (outer - slab).to_mesh()
    v = np.asarray(mesh.vert_properties[:, :3], dtype=np.float64)
    f = np.asarray(mesh.tri_verts, dtype=np.int64)
    slab_area = 2 * (0.8 * 0.8 + 0.02 * 0.8 + 0.02 * 0.8)
    truth = slab_area / (10.0 + slab_area)
    assert unseen_area_share(v, f) == pytest.approx(truth, rel=1e-5)


def test_frame_and_unused_vertices_do_not_matter():
    outer, inner = ball(0.9), ball(0.3, (0.2, -0.1, 0.05), subdivisions=2)
    v, f = join(outer, inner)
    share = unseen_area_share(v, f)
    moved = v * 37.5 + np.array([1e3, -20.0, 5.0])
    far = np.concatenate([moved, [[1e6, 1e6, 1e6]]])  # an unused vertex far away does not widen the frame
    assert unseen_area_share(far, f) == pytest.approx(share, rel=1e-9)


def test_same_faces_as_the_fit_renders_and_at_the_fit_resolution():
    """The shortcut (only faces that cover no pixel centre get the centroid test) is the renders' faces_seen."""
    from tetweave_codec.meshio import normalize
    from tetweave_codec.render.visibility import render

    v, f = join(ball(0.9), ball(0.3, (0.2, -0.1, 0.05), subdivisions=2), ball(0.15, (0.0, 0.95, 0.0), 1))
    normalized, _, _ = normalize(v)
    seen, _ = render(normalized, f, 32, RESOLUTION).faces_seen()
    assert np.array_equal(unseen_faces(v, f, resolution=RESOLUTION), ~seen.any(axis=0))
    assert unseen_area_share(v, f, resolution=384) == pytest.approx(unseen_area_share(v, f), abs=1e-3)


def test_resolution_and_nothing_to_measure():
    assert resolution_for(10) == 128 and resolution_for(40_000) == 224 and resolution_for(10**6) == RESOLUTION
    assert unseen_area_share(np.zeros((3, 3)), np.array([[0, 1, 2]])) == 0.0  # no area
    assert self_check(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)) is None


def test_summary_lines_and_warning():
    quiet = SelfCheck(0.0002, 0.31)
    assert quiet.line() == "decoded area no outside view sees: 0.02 % (self-check, 0.3s)"
    assert quiet.warning("all") is None
    loud = SelfCheck(0.25, 0.4)
    assert loud.warns and loud.share > WARN_SHARE
    assert loud.warning("all").endswith("membranes or hidden parts were kept; try --surface visible")
    assert "try --surface" not in loud.warning("visible")


def test_batch_summary_names_the_files_that_warn():
    records = [
        {"status": "ok", "output": "a.tw", "unseen_area_share": 0.2},
        {"status": "ok", "output": "b.tw", "unseen_area_share": 0.0},
        {"status": "ok", "output": "c.tw", "unseen_area_share": None},
    ]
    lines = summary_lines(records, 1.0)
    assert any(line.startswith("warning: 1 of 2 files keep over 1 % ") and line.endswith(": a.tw") for line in lines)
    assert not any("warning" in line for line in summary_lines(records[1:], 1.0))


class StoresAsIs(Method):
    """A bench method of `family` whose decoded mesh is its input (known exactly)."""

    def __init__(self, family: str) -> None:
        self.family = family

    @property
    def setting(self) -> str:
        return "as is"

    def encode(self, vertices, faces) -> bytes:
        self._mesh = (vertices, faces)
        return b"x" * 100

    def decode(self, data):
        return self._mesh


def test_bench_records_the_self_check_for_tetweave_rows(tmp_path):
    from tetweave_codec.bench import report
    from tetweave_codec.bench.batch import run_mesh
    from tetweave_codec.bench.rows import COLUMNS
    from tetweave_codec.metrics.common import MetricOptions

    outer, inner = ball(0.9), ball(0.3, (0.2, -0.1, 0.05), subdivisions=2)
    v, f = join(outer, inner)
    options = MetricOptions.for_samples(5_000)
    result = run_mesh("balls", v, f, [StoresAsIs("tetweave"), StoresAsIs("draco")], options, surface="all")
    _, fit, classical = result.rows
    assert fit["unseen_area_pct"] == pytest.approx(100 * area(inner) / (area(outer) + area(inner)))
    assert classical["unseen_area_pct"] == "" and "unseen_area_pct" in COLUMNS
    report.write_csv(result.rows, tmp_path / "results.csv")
    (back,) = [r for r in report.read_csv(tmp_path / "results.csv") if r["family"] == "tetweave"]
    assert float(back["unseen_area_pct"]) == pytest.approx(fit["unseen_area_pct"], rel=1e-5)
    assert "unseen %" in "\n".join(report.mesh_table(result.rows))


def hollow_ball(path):
    """A ball with a ball-shaped cavity (the inner shell reversed): --surface all keeps the cavity, which no
    outside view sees (the inner area 0.25 / 1.25 = 20 % of the decoded area)."""
    outer, inner = ball(1.0), ball(0.5)
    v, f = join(outer, (inner[0], inner[1][:, ::-1]))
    trimesh.Trimesh(v, f, process=False).export(path)


FIT = ["--points", "512", "--iters", "20", "--sh-degree", "0", "--quality", "fast", "--surface", "all"]


def test_cli_summary_line_warning_and_manifest_field(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    hollow_ball(src / "hollow.ply")
    res = CliRunner().invoke(main, ["encode", str(src / "hollow.ply"), "-o", str(tmp_path / "one.tw"), "-q", *FIT])
    assert res.exit_code == 0, res.output
    line = next(s for s in res.output.splitlines() if s.startswith("decoded area no outside view sees: "))
    share = float(line.split(": ")[1].split(" %")[0]) / 100
    assert 0.15 < share < 0.25
    assert "membranes or hidden parts were kept; try --surface visible" in res.output
    assert "self-check" in res.output.splitlines()[-1]  # its time in the time line
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["encode", str(src), "-o", str(out), "--jobs", "1", "-q", *FIT])
    assert res.exit_code == 0, res.output
    (record,) = [json.loads(s) for s in (out / "manifest.jsonl").read_text().splitlines()]
    assert record["status"] == "ok" and record["unseen_area_share"] == pytest.approx(share, abs=5e-5)
    assert "warning: 1 of 1 files keep over 1 % " in res.output
