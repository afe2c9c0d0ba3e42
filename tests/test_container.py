"""The `.tw` container (round trip, layout, validation, corruption) and decoding a container to a mesh."""

from __future__ import annotations

import struct
import sys
import warnings
import zlib

import numpy as np
import pytest

from tetweave_codec.decoder import DecodeWarning, decode, decode_detailed, mesh_from_points
from tetweave_codec.errors import ContainerError
from tetweave_codec.formats import tw
from tetweave_codec.formats.tw import HEADER_SIZE, MAGIC, TetWeaveFile, backend_flags, pack, unpack
from tetweave_codec.geometry.delaunay import available_backends


def make_file(n: int = 20, degree: int = 2, seed: int = 0, flags: int = 0, scale=2.5, offset=(1.0, -2.0, 0.5)):
    rng = np.random.default_rng(seed)
    q = (degree + 1) ** 2
    return TetWeaveFile(
        points=rng.uniform(-1, 1, (n, 3)).astype(np.float16),
        s=rng.normal(size=n).astype(np.float16),
        c=rng.normal(size=(n, q)).astype(np.float16),
        sh_degree=degree,
        scale=scale,
        offset=np.array(offset),
        flags=flags,
    )


def sphere_file(n: int = 4000, degree: int = 1, seed: int = 0, backend: str = "qhull") -> TetWeaveFile:
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1, 1, (n, 3))
    return TetWeaveFile(
        points=pts.astype(np.float16),
        s=(np.linalg.norm(pts, axis=1) - 0.6).astype(np.float16),
        c=(rng.normal(size=(n, (degree + 1) ** 2)) * 0.3).astype(np.float16),
        sh_degree=degree,
        scale=10.0,
        offset=np.array([100.0, 0.0, -5.0]),
        flags=backend_flags(backend),
    )


def reseal(data: bytearray) -> bytes:
    """Recompute the CRC of a deliberately edited file, so that only the semantic checks can reject it."""
    body = bytes(data[:-4])
    return body + struct.pack("<I", zlib.crc32(body))


# -----------------------------------------------------------------------------------------------------------
# round trip and layout


@pytest.mark.parametrize("degree", [-1, 0, 1, 2, 3])
@pytest.mark.parametrize("flags", [0, tw.FLAG_QHULL])
def test_round_trip_is_exact(degree, flags):
    f = make_file(degree=degree, flags=flags)
    data = pack(f)
    g = unpack(data)
    assert g.points.dtype == g.s.dtype == g.c.dtype == np.float16
    assert np.array_equal(g.points, f.points) and np.array_equal(g.s, f.s) and np.array_equal(g.c, f.c)
    assert (g.sh_degree, g.scale, g.flags) == (degree, 2.5, flags)
    assert np.array_equal(g.offset, f.offset)
    assert g.backend == ("qhull" if flags else "tetgen")
    assert pack(g) == data
    assert len(data) == HEADER_SIZE + tw.payload_size(20, degree) + 4


def test_round_trip_preserves_special_float16_values():
    vals = np.array([0.0, -0.0, 6.1e-5, 5.96e-8, -65504.0, 65504.0, 1 / 3], dtype=np.float16)
    n = len(vals)
    f = TetWeaveFile(np.stack([vals] * 3, 1), vals.copy(), vals[:, None].copy(), 0, 2.0**-64, np.zeros(3))
    g = unpack(pack(f))
    assert g.points.tobytes() == f.points.tobytes() and g.s.tobytes() == f.s.tobytes()  # incl. the sign of -0
    assert g.scale == 2.0**-64 and g.num_points == n  # the smallest scale a file may store


def test_empty_point_set_round_trips():
    empty = np.zeros((0, 3), np.float16)
    f = TetWeaveFile(empty, np.zeros(0, np.float16), np.zeros((0, 4), np.float16), 1, 1.0, np.zeros(3))
    g = unpack(pack(f))
    assert g.num_points == 0 and g.c.shape == (0, 4)


def test_byte_layout_matches_the_spec():
    """formats/README.md promises these offsets; a decoder in another language relies on them."""
    f = make_file(n=3, degree=1, flags=1, scale=0.75, offset=(1.5, 2.5, -3.5))
    data = pack(f)
    assert data[:8] == b"\x89TWV\r\n\x1a\n" == MAGIC
    assert struct.unpack_from("<HHIIbBH", data, 8) == (1, 64, 1, 3, 1, 0, 0)
    assert struct.unpack_from("<d3dQ", data, 24) == (0.75, 1.5, 2.5, -3.5, 2 * 3 * (4 + 4))
    payload = np.frombuffer(data, "<f2", count=3 * 8, offset=64)
    assert np.array_equal(payload[:9].reshape(3, 3), f.points)
    assert np.array_equal(payload[9:12], f.s)
    assert np.array_equal(payload[12:].reshape(3, 4), f.c)
    assert struct.unpack_from("<I", data, len(data) - 4)[0] == zlib.crc32(data[:-4])


def test_pack_is_deterministic_and_casts_other_floats():
    f = make_file()
    assert pack(f) == pack(make_file())
    g = TetWeaveFile(f.points.astype(np.float32), f.s.astype(np.float64), f.c, 2, 2.5, f.offset)
    assert pack(g) == pack(f)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(points=np.zeros((20, 2), np.float16)), "points"),
        (dict(s=np.zeros(19, np.float16)), "s must be"),
        (dict(c=np.zeros((20, 4), np.float16)), "c must be"),
        (dict(sh_degree=4), "SH degree"),
        (dict(scale=0.0), "scale"),
        (dict(scale=1e305), "float64 range"),  # 65504 (largest float16) x 1e305 overflows
        (dict(scale=2.0**-65), r"outside \[2\^-64, 2\^64\]"),
        (dict(scale=2.0**65), r"outside \[2\^-64, 2\^64\]"),
        (dict(scale=1.0, offset=np.array([0.0, 2.0**24 + 2, 0.0])), "beyond 2\\^24"),
        (dict(scale=float("nan")), "scale"),
        (dict(offset=np.array([0, np.inf, 0])), "offset"),
        (dict(flags=2), "flags"),
        (dict(s=np.full(20, 1e6)), "not finite"),
        (dict(points=np.zeros((20, 3), np.int32)), "float"),
    ],
)
def test_pack_rejects_inconsistent_contents(change, message):
    f = make_file()
    fields = dict(points=f.points, s=f.s, c=f.c, sh_degree=2, scale=2.5, offset=f.offset, flags=0)
    fields.update(change)
    with pytest.raises(ValueError, match=message):
        pack(TetWeaveFile(**fields))


# -----------------------------------------------------------------------------------------------------------
# validation of damaged and malformed files


def test_every_truncation_is_rejected():
    data = pack(make_file())
    for k in range(len(data)):
        with pytest.raises(ContainerError):
            unpack(data[:k])


def test_truncation_messages():
    data = pack(make_file())
    with pytest.raises(ContainerError, match="truncated"):
        unpack(data[:-1])
    with pytest.raises(ContainerError, match="truncated"):
        unpack(data[:4])
    with pytest.raises(ContainerError, match="truncated"):
        unpack(data[:40])
    with pytest.raises(ContainerError, match="unexpected bytes"):
        unpack(data + b"\x00")


def test_random_byte_flips_are_rejected():
    data = pack(make_file(n=50, degree=3))
    rng = np.random.default_rng(1)
    for _ in range(3000):
        damaged = bytearray(data)
        pos = int(rng.integers(len(data)))
        damaged[pos] ^= int(rng.integers(1, 256))
        with pytest.raises(ContainerError):
            unpack(bytes(damaged))


def test_multi_byte_corruption_and_garbage_are_rejected():
    data = pack(make_file(n=50, degree=1))
    rng = np.random.default_rng(2)
    for _ in range(500):
        damaged = bytearray(data)
        for pos in rng.integers(len(data), size=int(rng.integers(2, 20))):
            damaged[int(pos)] = int(rng.integers(256))
        if bytes(damaged) == data:
            continue
        with pytest.raises(ContainerError):
            unpack(bytes(damaged))
    for size in (0, 1, 7, 8, 63, 64, 68, 1000):
        with pytest.raises(ContainerError):
            unpack(rng.integers(0, 256, size, dtype=np.uint8).tobytes())
        with pytest.raises(ContainerError):
            unpack((MAGIC + rng.integers(0, 256, size, dtype=np.uint8).tobytes())[: max(size, 8)])


def test_other_file_types_are_not_tw():
    for data in (b"ply\nformat ascii 1.0\n", b"", b"\x89PNG\r\n\x1a\n" + bytes(100), b"v 0 0 0\n" * 20):
        with pytest.raises(ContainerError, match="not a .tw file|truncated"):
            unpack(data)


@pytest.mark.parametrize(
    "offset, fmt, value, message",
    [
        (8, "<H", 3, "unsupported .tw version 3"),
        (8, "<H", 0, "unsupported .tw version 0"),
        (10, "<H", 65, "header size"),
        (12, "<I", 6, "unknown flags"),
        (20, "<b", 4, "SH degree"),
        (21, "<B", 1, "payload codec"),
        (22, "<H", 7, "reserved"),
        (24, "<d", 0.0, "scale"),
        (24, "<d", -1.0, "scale"),
        (24, "<d", float("inf"), "scale"),
        (24, "<d", 1e305, "float64 range"),
        (24, "<d", 1e-30, "outside"),
        (32, "<d", 1e10, "beyond 2"),
        (32, "<d", float("nan"), "offset"),
        (16, "<I", 21, "payload"),
    ],
)
def test_semantic_checks_behind_a_valid_checksum(offset, fmt, value, message):
    damaged = bytearray(pack(make_file()))
    struct.pack_into(fmt, damaged, offset, value)
    with pytest.raises(ContainerError, match=message):
        unpack(reseal(damaged))


@pytest.mark.parametrize("where", [64, 64 + 2 * 60, 64 + 2 * 80])  # a position, an s, a c value
@pytest.mark.parametrize("bits", [0x7C00, 0x7E00, 0xFC00])  # +inf, NaN, -inf
def test_non_finite_payload_is_rejected(where, bits):
    damaged = bytearray(pack(make_file()))
    struct.pack_into("<H", damaged, where, bits)
    with pytest.raises(ContainerError, match="non-finite"):
        unpack(reseal(damaged))


def test_checksum_message():
    damaged = bytearray(pack(make_file()))
    damaged[100] ^= 1
    with pytest.raises(ContainerError, match="checksum"):
        unpack(bytes(damaged))


# -----------------------------------------------------------------------------------------------------------
# decoding


def test_decode_restores_the_input_frame_and_is_deterministic():
    f = sphere_file()
    data = pack(f)
    v, faces = decode(data)
    v_norm, faces_norm = mesh_from_points(f.points, f.s, f.c, f.sh_degree, backend=f.backend)
    assert np.array_equal(faces, faces_norm)
    np.testing.assert_allclose(v, v_norm * 10.0 + np.array([100.0, 0.0, -5.0]), rtol=0, atol=1e-12)
    v2, faces2 = decode(data)
    assert v.tobytes() == v2.tobytes() and faces.tobytes() == faces2.tobytes()
    assert v.dtype == np.float64 and faces.dtype == np.int64
    radius = np.linalg.norm((v - [100.0, 0.0, -5.0]) / 10.0, axis=1)
    assert np.abs(radius - 0.6).max() < 0.05


def test_decode_detailed_reports_stages():
    res = decode_detailed(pack(sphere_file(n=500)))
    assert set(res.seconds) == {"unpack", "delaunay", "marching_tets", "smoothing"}
    assert res.seconds["smoothing"] < 0.01 and res.restored == 0  # a version-1 file is never smoothed
    assert res.backend in available_backends() and res.num_tets > 0
    assert res.container.num_points == 500


@pytest.mark.skipif("tetgen" not in available_backends(), reason="needs tetgenpy")
def test_decode_uses_the_recorded_backend():
    """On a lattice the backends triangulate differently; the file's flag decides which mesh comes out. Qhull's
    tie-break (hash-perturbed points) leaves tets that are flat in the stored coordinates on this fully degenerate
    lattice, and its surface crosses itself there: the decoder's final check refuses that file instead of returning
    it, which shows the flag was followed all the same."""
    from tetweave_codec.errors import ContainerError

    g = np.arange(6) / 4.0 - 0.5  # exact in float16
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    s = np.random.default_rng(3).choice([-0.25, 0.75], size=len(pts))
    c = np.zeros((len(pts), 0))
    arrays = (pts.astype(np.float16), s.astype(np.float16), c.astype(np.float16))
    v_ref, f_ref = mesh_from_points(pts, s, None, -1, backend="tetgen")
    v, faces = decode(pack(TetWeaveFile(*arrays, -1, 1.0, np.zeros(3), backend_flags("tetgen"))))
    assert np.array_equal(faces, f_ref) and np.array_equal(v, v_ref)
    with pytest.raises(ContainerError, match="cross or touch"):
        mesh_from_points(pts, s, None, -1, backend="qhull")
    with pytest.raises(ContainerError, match="cross or touch"):
        decode(pack(TetWeaveFile(*arrays, -1, 1.0, np.zeros(3), backend_flags("qhull"))))


def test_decode_warns_and_falls_back_when_the_backend_is_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "tetgenpy", None)
    data = pack(sphere_file(n=600, backend="tetgen"))
    with pytest.warns(DecodeWarning, match="not installed.*tetweave\\[tetgen\\]"):
        res = decode_detailed(data)
    assert res.backend == "exact" and len(res.faces) > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        decode_detailed(pack(sphere_file(n=600, backend="qhull")))


@pytest.mark.parametrize("sign", [-1.0, 1.0])
def test_one_sign_decodes_to_an_empty_or_hull_mesh(sign):
    f = sphere_file(n=300)
    f = TetWeaveFile(f.points, np.full(300, sign, np.float16), f.c, f.sh_degree, f.scale, f.offset, f.flags)
    v, faces = decode(pack(f))
    if sign > 0:
        assert v.shape == (0, 3) and faces.shape == (0, 3)
    else:  # everything inside: the surface is the convex hull of the points
        assert len(faces) > 0


def test_tiny_and_empty_files_decode_to_empty_meshes():
    for n in (0, 1, 3):
        v, faces = decode(pack(make_file(n=n)))
        assert v.shape == (0, 3) and faces.shape == (0, 3)


def test_mesh_from_points_validates_shapes():
    f = sphere_file(n=100, degree=2)
    with pytest.raises(ValueError):
        mesh_from_points(f.points, f.s, f.c, 1)
    with pytest.raises(ValueError):
        mesh_from_points(f.points, f.s[:-1], f.c, 2)
    v, faces = mesh_from_points(f.points, f.s, None, -1)
    assert len(faces) > 0


def test_readme_example_is_what_pack_writes():
    """The hex dump in formats/README.md is the exact encoding of its example."""
    from pathlib import Path

    readme = Path(__file__).resolve().parent.parent / "formats" / "README.md"
    block = readme.read_text().split("## Example", 1)[1].split("```")[1]
    hex_bytes = []
    for line in block.strip().splitlines():
        hex_bytes += line[6:].split("   ")[0].split()  # drop the offset column and the comment
    hexdump = bytes.fromhex("".join(hex_bytes))
    points = np.array([[0.5, -0.25, 1.0], [0, 0, -1]], np.float16)
    s = np.array([-0.125, 2.0], np.float16)
    c = np.array([[0.0], [1.0]], np.float16)
    f = TetWeaveFile(points, s, c, 0, 2.0, np.array([1.0, 0.0, -3.0]), 0)
    assert hexdump == pack(f)
