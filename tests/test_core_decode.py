"""The decoder core (decoder/, `tetweave_codec._decoder_native`) against the Python pipeline of decoder.py.

Every committed `.tw` file of this version decodes to the same vertices and faces (float64 and int64, bit for bit)
through the core as through the Python reference (decoder.CORE off), at every level and on 1 and 3 threads; the
detail the encoder uses (the closed surface, the extracted faces, restored vertices, tets) agrees too; files of
earlier encoders go to the Python pipeline; bad input is the same error class."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tetweave_codec import decoder
from tetweave_codec.errors import ContainerError

ROOT = Path(__file__).resolve().parent.parent
FILES = sorted(
    p for p in subprocess.run(["git", "ls-files", "*.tw"], cwd=ROOT, capture_output=True, text=True).stdout.split()
)

pytestmark = pytest.mark.skipif(not decoder.CORE, reason="the decoder core's extension is not built")


def reference(data: bytes, level: str, threads: int = 1, monkeypatch=None):
    monkeypatch.setattr(decoder, "CORE", False)
    try:
        return decoder.decode_detailed(data, level=level, threads=threads)
    finally:
        monkeypatch.setattr(decoder, "CORE", True)


@pytest.mark.parametrize("name", FILES)
def test_every_committed_file_every_level_is_the_reference(name, monkeypatch):
    data = (ROOT / name).read_bytes()
    for level in decoder.LEVELS:
        ref = reference(data, level, 1, monkeypatch)
        for threads in (1, 3):
            got = decoder.decode_detailed(data, level=level, threads=threads)
            if ref.backend != "exact":  # an earlier encoder's file: the core refuses it, the Python path decodes it
                assert "delaunay" in got.seconds and got.backend == ref.backend
            assert got.vertices.dtype == np.float64 and got.faces.dtype == np.int64
            assert np.array_equal(got.vertices, ref.vertices), (name, level, threads)
            assert np.array_equal(got.faces, ref.faces), (name, level, threads)
            assert np.array_equal(got.closed_vertices, ref.closed_vertices)
            assert np.array_equal(got.closed_faces, ref.closed_faces)
            assert np.array_equal(got.extracted_faces, ref.extracted_faces)
            assert (got.restored, got.num_tets, got.smoothing, got.subdivision) == (
                ref.restored, ref.num_tets, ref.smoothing, ref.subdivision,
            )  # fmt: skip
            for field in ("num_points", "smoothing", "subdivision", "creases", "sh_degree", "flags", "scale"):
                assert getattr(got.header, field) == getattr(ref.header, field), field
            assert np.array_equal(got.header.offset, ref.header.offset)


def test_core_results_parse_the_rest_of_the_file_on_demand():
    data = (ROOT / next(n for n in FILES if "legacy" not in n)).read_bytes()
    got = decoder.decode_detailed(data)
    assert got.parsed is None and got.header.num_points > 0
    assert got.container.points.shape == (got.container.num_points, 3)  # parsed by formats.tw.unpack now
    assert got.container.holes is None or len(got.container.holes) >= 0


def test_decode_path_imports_no_entropy_coder():
    """A fresh interpreter decodes a file through the core without loading constriction or the container modules."""
    name = next(n for n in FILES if "legacy" not in n)
    code = (
        "import sys; from tetweave_codec.decoder import decode; "
        f"v, f = decode(open({str(ROOT / name)!r}, 'rb').read()); assert len(f); "
        "bad = [m for m in ('constriction', 'torch', 'tetweave_codec.formats.entropy') if m in sys.modules]; "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


@pytest.mark.parametrize(
    "mutate",
    [
        lambda d: d[:20],
        lambda d: d[:-1],
        lambda d: d + b"\0",
        lambda d: d[:12] + bytes([d[12] ^ 0x1F]) + d[13:],
        lambda d: b"",
    ],
)
def test_bad_files_are_container_errors(mutate):
    data = (ROOT / next(n for n in FILES if "legacy" not in n)).read_bytes()
    with pytest.raises(ContainerError):
        decoder.decode(mutate(data))


def test_bad_arguments():
    data = (ROOT / FILES[0]).read_bytes()
    with pytest.raises(ValueError):
        decoder.decode(data, level="coarse")
    with pytest.raises(ValueError):
        decoder.decode(data, threads=-1)
