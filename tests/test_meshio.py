"""Mesh loading (validated), normalization, atomic writing."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from tetweave_codec import meshio
from tetweave_codec.errors import InputError
from tetweave_codec.meshio import load_mesh, normalize, save_mesh, write_bytes_atomic


def icosphere():
    m = trimesh.creation.icosphere(subdivisions=2, radius=3.0)
    return np.asarray(m.vertices, dtype=np.float64) + [10.0, -4.0, 2.0], np.asarray(m.faces, dtype=np.int64)


@pytest.mark.parametrize("ext", [".obj", ".ply", ".off", ".glb", ".stl"])
def test_save_then_load_round_trip(tmp_path, ext):
    v, f = icosphere()
    path = tmp_path / f"sphere{ext}"
    save_mesh(path, v, f)
    v2, f2 = load_mesh(path)
    assert v2.dtype == np.float64 and f2.dtype == np.int64
    assert len(f2) == len(f)
    if ext == ".stl":  # three vertices per triangle, float32
        np.testing.assert_allclose(v2[f2], v[f], atol=1e-5)
    else:
        assert np.array_equal(f2, f)
        tol = {".obj": 1e-8, ".off": 1e-8, ".ply": 1e-5, ".glb": 1e-5}[ext]  # PLY/GLB store float32
        np.testing.assert_allclose(v2, v, atol=tol, rtol=0)
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]


def test_obj_keeps_precision_for_tiny_meshes(tmp_path):
    v, f = icosphere()
    v = v * 1e-6
    save_mesh(tmp_path / "tiny.obj", v, f)
    v2, _ = load_mesh(tmp_path / "tiny.obj")
    np.testing.assert_allclose(v2, v, rtol=1e-7, atol=0)


def test_scene_is_merged_with_transforms(tmp_path):
    box = trimesh.creation.box()
    scene = trimesh.Scene()
    scene.add_geometry(box, node_name="a")
    moved = np.eye(4)
    moved[:3, 3] = [5.0, 0.0, 0.0]
    scene.add_geometry(box, node_name="b", transform=moved)
    path = tmp_path / "two.glb"
    scene.export(path)
    v, f = load_mesh(path)
    assert len(f) == 2 * len(box.faces)
    assert v[:, 0].max() == pytest.approx(5.5)
    assert v[:, 0].min() == pytest.approx(-0.5)


def test_shared_real_mesh(shared_meshes):
    v, f = load_mesh(shared_meshes / "spot.ply")
    assert v.shape == (11533, 3) and f.shape == (23062, 3)


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("empty.obj", b"# nothing here\n", "no triangles"),
        ("points.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no triangles"),
        ("nan.obj", b"v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "non-finite"),
        ("inf.obj", b"v 0 0 inf\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "non-finite"),
        ("range.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "cannot read|out of range"),
        ("point.obj", b"v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n", "single point"),
        ("garbage.ply", b"ply\nformat nonsense\n\x00\x01\x02", "cannot read"),
        ("garbage.glb", b"glTF\x02\x00\x00\x00garbage", "cannot read"),
        ("garbage.stl", b"\x00" * 10, "cannot read|no triangles"),
        ("mesh.xyz", b"1 2 3\n", "unsupported mesh format"),
        ("noext", b"v 0 0 0\n", "unsupported mesh format"),
    ],
)
def test_bad_inputs_raise_input_error(tmp_path, name, content, message):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError, match=message):
        load_mesh(path)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_mesh(tmp_path / "missing.obj")
    (tmp_path / "dir.obj").mkdir()
    with pytest.raises(InputError, match="not a regular file"):
        load_mesh(tmp_path / "dir.obj")


def test_out_of_range_faces_in_ply_rejected(tmp_path):
    v, f = icosphere()
    path = tmp_path / "bad.ply"
    save_mesh(path, v, f)
    mesh = trimesh.load(path, process=False)
    faces = np.asarray(mesh.faces).copy()
    faces[0, 0] = len(v) + 5
    header = f"ply\nformat ascii 1.0\nelement vertex {len(v)}\n"
    header += "property float x\nproperty float y\nproperty float z\n"
    header += f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    body = "".join(f"{a} {b} {c}\n" for a, b, c in v) + "".join(f"3 {a} {b} {c}\n" for a, b, c in faces)
    path.write_text(header + body)
    with pytest.raises(InputError):
        load_mesh(path)


def test_normalize_fits_the_cube_and_inverts():
    v, _ = icosphere()
    v = v * [1.0, 2.0, 0.5]
    n, scale, offset = normalize(v)
    assert n.min(0).min() >= -0.9 - 1e-12 and n.max(0).max() <= 0.9 + 1e-12
    extent = n.max(0) - n.min(0)
    assert extent.max() == pytest.approx(1.8)
    np.testing.assert_allclose((n.max(0) + n.min(0)) / 2, 0, atol=1e-12)
    np.testing.assert_allclose(n * scale + offset, v, atol=1e-12)
    np.testing.assert_allclose(meshio.denormalize(n, scale, offset), v, atol=1e-12)
    assert offset.shape == (3,) and isinstance(scale, float)


@pytest.mark.parametrize("bad", [np.zeros((0, 3)), np.ones((4, 3)), np.array([[0, 0, np.nan], [1, 1, 1]])])
def test_normalize_rejects_degenerate_input(bad):
    with pytest.raises(InputError):
        normalize(bad)


def test_save_rejects_unknown_extension_without_writing(tmp_path):
    v, f = icosphere()
    with pytest.raises(InputError, match="unsupported output format"):
        save_mesh(tmp_path / "out.xyz", v, f)
    assert list(tmp_path.iterdir()) == []


def test_empty_mesh_can_be_written(tmp_path):
    for ext in meshio.WRITE_FORMATS:
        save_mesh(tmp_path / f"empty{ext}", np.zeros((0, 3)), np.zeros((0, 3), np.int64))
        assert (tmp_path / f"empty{ext}").stat().st_size > 0
    assert "v " not in (tmp_path / "empty.obj").read_text()


def test_atomic_write_replaces_or_leaves_untouched(tmp_path, monkeypatch):
    target = tmp_path / "out.bin"
    write_bytes_atomic(target, b"first")
    assert target.read_bytes() == b"first"
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask
    write_bytes_atomic(target, b"second")
    assert target.read_bytes() == b"second"

    def broken_fsync(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError):
        write_bytes_atomic(target, b"third, never complete")
    assert target.read_bytes() == b"second"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]


def test_write_into_missing_directory_raises_oserror(tmp_path):
    with pytest.raises(OSError):
        write_bytes_atomic(tmp_path / "missing" / "out.bin", b"x")
    with pytest.raises(OSError):
        save_mesh(Path(tmp_path / "missing" / "out.obj"), *icosphere())
