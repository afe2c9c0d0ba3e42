"""`tetweave decode` and `tetweave info` through click's CliRunner, plus one real subprocess call."""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tetweave_codec.cli.main import main
from tetweave_codec.decoder import decode as decode_bytes
from tetweave_codec.formats.tw import TetWeaveFile, pack
from tetweave_codec.meshio import load_mesh

OFFSET = np.array([3.0, -1.0, 7.0])


def write_sphere(path: Path, n: int = 2000, sign: float = 1.0) -> bytes:
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (n, 3))
    s = sign * (np.linalg.norm(pts, axis=1) - 0.6)
    c = rng.normal(size=(n, 4)) * 0.2
    # flags 1: Qhull, the version-1 backend every install has (TetGen is an optional extra)
    data = pack(TetWeaveFile(pts.astype(np.float16), s.astype(np.float16), c.astype(np.float16), 1, 5.0, OFFSET, 1))
    path.write_bytes(data)
    return data


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def assert_clean_failure(result, *, message: str = ""):
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tetweave: error:"), lines
    assert "Traceback" not in result.output
    assert message in result.stderr


@pytest.fixture
def tw_file(tmp_path) -> Path:
    path = tmp_path / "shape.tw"
    write_sphere(path)
    return path


def test_decode_writes_beside_the_input_by_default(tw_file):
    result = run("decode", tw_file)
    assert result.exit_code == 0, result.output
    out = tw_file.with_name("shape.decoded.obj")
    assert out.is_file()
    v, f = load_mesh(out)
    ref_v, ref_f = decode_bytes(tw_file.read_bytes())
    assert np.array_equal(f, ref_f)
    np.testing.assert_allclose(v, ref_v, atol=1e-7)
    assert f"{len(ref_v):,} vertices, {len(ref_f):,} faces" in result.stdout
    assert "Delaunay" in result.stdout and "marching tets" in result.stdout
    assert tw_file.read_bytes()[:4] == b"\x89TWV"  # the input is untouched


@pytest.mark.parametrize("ext", ["ply", "stl", "off", "glb"])
def test_decode_output_format_from_extension(tw_file, tmp_path, ext):
    out = tmp_path / f"mesh.{ext}"
    result = run("decode", tw_file, "-o", out)
    assert result.exit_code == 0, result.output
    v, f = load_mesh(out)
    assert len(f) == len(decode_bytes(tw_file.read_bytes())[1])
    # original frame: the sphere of radius 0.6 * 5 around OFFSET
    assert np.abs(np.linalg.norm(v - OFFSET, axis=1) - 3.0).max() < 0.3


def test_decode_with_explicit_backend(tw_file, tmp_path):
    result = run("decode", tw_file, "-o", tmp_path / "q.ply", "--delaunay", "qhull")
    assert result.exit_code == 0 and "with qhull" in result.stdout


def test_empty_mesh_warns_and_writes_an_empty_file(tmp_path):
    path = tmp_path / "outside.tw"
    write_sphere(path, sign=0.0)  # s = 0 everywhere counts as outside
    out = tmp_path / "outside.ply"
    result = run("decode", path, "-o", out)
    assert result.exit_code == 0
    assert "warning" in result.stderr and "empty" in result.stderr
    assert out.is_file() and "0 vertices, 0 faces" in result.stdout


def test_info_reports_the_header(tw_file):
    result = run("info", tw_file)
    assert result.exit_code == 0, result.output
    out = result.stdout
    for needle in (".tw version 1", "points      2,000", "SH degree   1 (4 per point)", "qhull", "header 64",
                   "payload 32,000", "checksum 4", "32,068 total", "points box"):  # fmt: skip
        assert needle in out, (needle, out)


def test_info_with_mesh(tw_file):
    result = run("info", tw_file, "--mesh")
    assert result.exit_code == 0
    v, f = decode_bytes(tw_file.read_bytes())
    assert f"{len(v):,} vertices, {len(f):,} faces" in result.stdout and "mesh box" in result.stdout


def _bad_files(tmp_path: Path, good: bytes) -> dict[str, tuple[Path, str]]:
    files = {}

    def put(name, data, message):
        p = tmp_path / name
        p.write_bytes(data)
        files[name] = (p, message)

    put("truncated.tw", good[: len(good) // 2], "truncated")
    put("header-only.tw", good[:40], "truncated")
    flipped = bytearray(good)
    flipped[500] ^= 0x10
    put("corrupted.tw", bytes(flipped), "checksum")
    newer = bytearray(good)
    struct.pack_into("<H", newer, 8, 3)  # 1 and 2 are read
    body = bytes(newer[:-4])
    put("version3.tw", body + struct.pack("<I", zlib.crc32(body)), "unsupported .tw version 3")
    put("mesh.tw", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "not a .tw file")
    put("empty.tw", b"", "not a .tw file")
    return files


@pytest.mark.parametrize("command", ["decode", "info"])
def test_bad_containers_fail_cleanly(tmp_path, command):
    good = write_sphere(tmp_path / "good.tw")
    for name, (path, message) in _bad_files(tmp_path, good).items():
        out = tmp_path / f"{name}.ply"
        out.write_bytes(b"previous content")
        args = ("decode", path, "-o", out) if command == "decode" else ("info", path)
        result = run(*args)
        assert_clean_failure(result, message=message)
        assert out.read_bytes() == b"previous content", name


def test_missing_input_and_directories(tmp_path):
    assert_clean_failure(run("decode", tmp_path / "missing.tw"), message="no such file")
    assert_clean_failure(run("info", tmp_path / "missing.tw"), message="no such file")
    (tmp_path / "dir.tw").mkdir()
    assert_clean_failure(run("info", tmp_path / "dir.tw"))


def test_bad_outputs_fail_before_writing(tw_file, tmp_path):
    assert_clean_failure(run("decode", tw_file, "-o", tmp_path / "out.xyz"), message="unsupported output format")
    assert_clean_failure(run("decode", tw_file, "-o", tmp_path / "no" / "dir.obj"), message="does not exist")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shape.tw"]


def test_output_equal_to_input_is_refused(tmp_path):
    path = tmp_path / "shape.obj"  # a .tw file with a mesh extension: -o shape.obj would overwrite it
    data = write_sphere(path)
    assert_clean_failure(run("decode", path, "-o", path), message="overwrite")
    assert path.read_bytes() == data


def test_failed_write_leaves_no_partial_file(tw_file, tmp_path, monkeypatch):
    def full_disk(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    out = tmp_path / "out.obj"
    assert_clean_failure(run("decode", tw_file, "-o", out), message="No space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shape.tw"]


def test_help_shows_defaults():
    result = run("decode", "--help")
    assert result.exit_code == 0 and ".decoded.obj" in result.output and "default: file" in result.output
    assert run("info", "--help").exit_code == 0


def test_installed_command_in_a_subprocess(tw_file, tmp_path):
    exe = shutil.which("tetweave")
    if exe is None:
        pytest.skip("the tetweave console script is not installed")
    out = tmp_path / "sub.ply"
    done = subprocess.run([exe, "decode", str(tw_file), "-o", str(out)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert out.is_file() and "faces" in done.stdout
    bad = tmp_path / "bad.tw"
    bad.write_bytes(tw_file.read_bytes()[:100])
    done = subprocess.run([exe, "info", str(bad)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [done.stderr.strip()] and "truncated" in done.stderr
    assert "Traceback" not in done.stderr


def test_directories_as_input_or_output(tw_file, tmp_path):
    (tmp_path / "dir.tw").mkdir()  # a directory is a batch of the .tw files in it: -o DIR needed, none found
    assert_clean_failure(run("decode", tmp_path / "dir.tw"), message="need -o DIR")
    assert_clean_failure(run("decode", tmp_path / "dir.tw", "-o", tmp_path / "o"), message="no input files found")
    (tmp_path / "dir.obj").mkdir()
    assert_clean_failure(run("decode", tw_file, "-o", tmp_path / "dir.obj"), message="is a directory")


@pytest.mark.parametrize("ext", [".ply", ".obj"])
def test_decoding_works_without_torch(tmp_path, ext):
    """The decode path is numpy only: `tetweave decode` runs, and gives the right mesh, where torch cannot be
    imported at all (sys.modules["torch"] = None makes every `import torch` raise ImportError); PLY and OBJ are
    written without trimesh, whose import costs more than a decode."""
    import sys

    tw = tmp_path / "shape.tw"
    write_sphere(tw)
    out = tmp_path / f"shape{ext}"
    code = (
        "import sys; sys.modules['torch'] = None; sys.modules['trimesh'] = None; "
        "from tetweave_codec.cli.main import main; "
        f"main(['decode', {str(tw)!r}, '-o', {str(out)!r}])"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    v, f = load_mesh(out)
    ref_v, ref_f = decode_bytes(tw.read_bytes())
    assert len(f) > 100 and np.array_equal(f, ref_f)
    np.testing.assert_allclose(v, ref_v, atol=1e-6)
    # the sphere of radius 0.6 * 5 around OFFSET
    assert np.abs(np.linalg.norm(v - OFFSET, axis=1) - 3.0).max() < 0.3


def test_batch_decoding_works_without_torch(tmp_path):
    """Several .tw files (a folder and an @list) decode in parallel worker processes where torch cannot be
    imported: a `torch` package that raises on import comes first on PYTHONPATH, so the spawned workers cannot
    import it either. Outputs mirror the inputs' relative paths and equal the single-file decode."""
    import sys

    blocker = tmp_path / "blocker" / "torch"
    blocker.mkdir(parents=True)
    (blocker / "__init__.py").write_text("raise ImportError('torch is blocked in this test')\n")
    src = tmp_path / "in"
    (src / "sub").mkdir(parents=True)
    write_sphere(src / "a.tw")
    write_sphere(src / "sub" / "b.tw", sign=-1.0)
    (src / "sub" / "bad.tw").write_bytes(b"TWV\x00 truncated")
    out = tmp_path / "out"
    code = (
        "import sys; from tetweave_codec.cli.main import main; "
        f"main(['decode', {str(src)!r}, '-o', {str(out)!r}, '--jobs', '2', '--format', 'ply'])"
    )
    env = {**os.environ, "PYTHONPATH": str(blocker.parent)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 1, done.stderr  # the truncated file fails, the others are written
    assert "3 files: 2 ok, 0 skipped, 1 failed" in done.stdout
    assert "sub/bad.tw" in done.stderr and "Traceback" not in done.stderr
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == ["a.ply", "sub", "sub/b.ply"]
    for rel in ("a", "sub/b"):
        v, f = load_mesh(out / f"{rel}.ply")
        ref_v, ref_f = decode_bytes((src / f"{rel}.tw").read_bytes())
        assert len(f) > 100 and np.array_equal(f, ref_f)
        np.testing.assert_allclose(v, ref_v, atol=1e-6)
    check = subprocess.run([sys.executable, "-c", "import torch"], capture_output=True, text=True, env=env)
    assert check.returncode != 0  # the blocker works


@pytest.mark.parametrize("levels", [0, 1])
def test_decode_of_a_smoothed_file_reports_its_smoothing(tmp_path, levels):
    from tetweave_codec.formats.common import FLAG_S_PREDICTED, smoothing_flags, subdivision_flags
    from tetweave_codec.formats.tw2 import pack_v2, quantize_file

    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (1500, 3))
    s = np.linalg.norm(pts, axis=1) - 0.6
    flags = FLAG_S_PREDICTED | smoothing_flags(2) | subdivision_flags(levels)
    f, _ = quantize_file(
        pts, s, None, -1, position_bits=8, s_step=1e-3, c_band_steps=[], scale=2.0, offset=OFFSET, flags=flags
    )
    path = tmp_path / "smooth.tw"
    path.write_bytes(pack_v2(f))
    result = run("decode", path, "-o", tmp_path / "out.ply")
    assert result.exit_code == 0, result.output
    assert "2 smoothing steps" in result.output
    assert ("1 subdivision level" in result.output) == (levels == 1)
    info = run("info", path)
    assert info.exit_code == 0 and ("1 Loop subdivision level" in info.output) == (levels == 1)
    v, faces = load_mesh(tmp_path / "out.ply")
    ref_v, ref_f = decode_bytes(path.read_bytes())
    assert np.array_equal(faces, ref_f) and np.allclose(v, ref_v, rtol=0, atol=1e-5)


@pytest.mark.parametrize("chosen", [None, "3"])
def test_decode_starts_numpy_with_one_blas_thread_unless_the_user_chose(tw_file, tmp_path, chosen):
    """A fresh `tetweave decode` process sets OPENBLAS_NUM_THREADS=1 before numpy's first import (its idle pool
    only costs CPU there); a value the user set is kept."""
    import sys

    code = (
        "import os, sys\n"
        "from tetweave_codec.cli.main import main\n"
        f"try:\n    main(['decode', {str(tw_file)!r}, '-o', {str(tmp_path / 'out.ply')!r}])\n"
        "except SystemExit:\n    pass\n"
        "print(os.environ.get('OPENBLAS_NUM_THREADS'), 'numpy' in sys.modules)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    if chosen:
        env["OPENBLAS_NUM_THREADS"] = chosen
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split()[-2:] == [chosen or "1", "True"]
