"""Files of earlier encoders, which recorded TetGen as their Delaunay backend, still decode.

tests/data/legacy_tetgen_bunny_5k.tw is the stanford-bunny 5 KB bench file written by the TetGen encoder (0a60d8a,
benchmarks/results/files/ before the exact Delaunay). With the `tetgen` extra it decodes with TetGen, as encoded;
without it, with the exact Delaunay and a warning that names the extra. Either way the mesh is closed, 2-manifold and
free of self-intersections by the independent exact check.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from tetweave_codec.benchmarks import exact_check
from tetweave_codec.decoder import DecodeWarning, decode_detailed
from tetweave_codec.formats.tw import unpack
from tetweave_codec.geometry.delaunay import available_backends
from tetweave_codec.geometry.marching_tets import check_manifold

LEGACY = Path(__file__).parent / "data" / "legacy_tetgen_bunny_5k.tw"


def _assert_clean(result) -> None:
    check_manifold(result.faces, len(result.vertices))
    assert len(exact_check.check(result.vertices, result.faces).pairs) == 0


def test_the_file_records_tetgen():
    f = unpack(LEGACY.read_bytes())
    assert f.backend == "tetgen" and not f.exact and f.num_points > 1000


@pytest.mark.skipif("tetgen" not in available_backends(), reason="needs the tetgen extra")
def test_with_tetgen_it_decodes_as_encoded():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = decode_detailed(LEGACY.read_bytes(), level="smoothed")
    assert result.backend == "tetgen"
    _assert_clean(result)


def test_without_tetgen_it_decodes_with_the_exact_delaunay_and_says_so(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "tetgenpy", None)
    with pytest.warns(DecodeWarning, match=r"tetweave\[tetgen\]"):
        result = decode_detailed(LEGACY.read_bytes(), level="smoothed")
    assert result.backend == "exact" and len(result.faces) > 5000
    _assert_clean(result)
