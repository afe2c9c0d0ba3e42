"""Same options, same bytes: SHA-256 of a few encodes with fixed options, pinned.

Refactors of the encoder (how the input is prepared, how rate control and packing are organised) must not change
a single byte of what an encode writes. Each case encodes a small analytic shape generated here with fixed options
(`--points`, `--size`, `--max-error`, both layouts, holes kept on an open shape) on one torch thread and compares
the file's SHA-256, and the summary's Chamfer estimate, with the values recorded when the case was written.

The values hold for the torch version they were recorded with (PINNED_TORCH): other builds may round differently
in the fit (a different file, not a wrong one), so the cases are skipped there. To record new values after an
intended change of the bytes: `TETWEAVE_PRINT_HASHES=1 python -m pytest tests/test_encode_hashes.py -s`.
"""

from __future__ import annotations

import hashlib
import os

import numpy as np
import pytest
import torch

from tetweave_codec.encoder import encode

manifold3d = pytest.importorskip("manifold3d")

PINNED_TORCH = "2.13.0"
# Short fits: the "fast" preset cut to a few iterations (bytes, not quality, are what is pinned).
FAST = {"quality": "fast", "iters": 30, "device": "cpu", "seed": 0}


def _mesh(m) -> tuple[np.ndarray, np.ndarray]:
    mesh = m.to_mesh()
    return np.asarray(mesh.vert_properties[:, :3], dtype=np.float64), np.asarray(mesh.tri_verts, dtype=np.int64)


def torus() -> tuple[np.ndarray, np.ndarray]:
    """Major radius 1, minor radius 0.35: smooth, closed (the smooth-mesh defaults: smoothing and subdivision)."""
    return _mesh(manifold3d.Manifold.revolve(manifold3d.CrossSection.circle(0.35, 32).translate((1.0, 0.0)), 64))


def sphere() -> tuple[np.ndarray, np.ndarray]:
    return _mesh(manifold3d.Manifold.sphere(1.0, 48))


def cut_sphere() -> tuple[np.ndarray, np.ndarray]:
    """A unit sphere without its faces above z = 0.6: open, one boundary loop."""
    v, f = sphere()
    return v, f[v[f].mean(1)[:, 2] < 0.6]


def csg_part() -> tuple[np.ndarray, np.ndarray]:
    """A box with a spherical bite: sharp creases bounding every face (the CAD defaults, feature points)."""
    box = manifold3d.Manifold.cube((2.0, 1.4, 1.0), center=True)
    return _mesh(box - manifold3d.Manifold.sphere(0.8, 48).translate((1.0, 0.7, 0.5)))


def cube() -> tuple[np.ndarray, np.ndarray]:
    return _mesh(manifold3d.Manifold.cube((1.0, 1.0, 1.0), center=True))


# name -> (shape, encode options, SHA-256 of the file, the summary's Chamfer distance as float.hex)
CASES = {
    "points_fit": (
        torus, {"points": 1024, "sh_degree": 1},
        "42f29cc0191d7f14bad5d7142f19270539e5d0d095d81f2bb850f78d27291a27", "0x1.13cfcc90c5272p-9",
    ),
    "points_grid": (
        torus, {"points": 1024, "layout": "grid"},
        "f44f294a28489b5b944331235f0abfe3fdef21a217fdf7ca5dea926220861824", "0x1.35aedb004dcd8p-9",
    ),
    "points_holes_keep": (
        cut_sphere, {"points": 1024, "sh_degree": 0, "holes": "keep"},
        "3e571680c827c1db49f1321f4d78b13700818641498f0a3b35294c1b40054e5f", "0x1.bde9dddd727f2p-10",
    ),
    "size_fit_cad": (
        csg_part, {"size": 2500},
        "f86674f4f93e2c0e112ff916256333d0b6b4c978ed2c358e9412f03ea23eb440", "0x1.5137042826cbdp-10",
    ),
    "size_grid": (
        torus, {"size": 3000, "layout": "grid"},
        "4abe0486c83d96c0cfb21154e824f1e76bb4be8808b9ffc5611550fe8afe5eb2", "0x1.8834ec935a14bp-11",
    ),
    "max_error_fit": (
        sphere, {"max_error": 4e-3},
        "188e349b3dbcde058666e219e1e6353a3777a34ecb5c32b9782b9de29cf93fb5", "0x1.34ec7c7515218p-9",
    ),
    "max_error_holes_keep": (
        cut_sphere, {"max_error": 5e-3, "holes": "keep"},
        "19eee4d68de7187020cee33b631f429f51ae5ecb6e0766c30e7e7e0ebd1fbdae", "0x1.460454a3a2c8ap-8",
    ),
}  # fmt: skip
SLOW_CASES = {
    "size_holes_keep": (
        cut_sphere, {"size": 3000, "holes": "keep"},
        "19fc822c62c21e6ca17b167bbded49f1e4a9bca650a4c6e8536cb1ab9b18e6d7", "0x1.b775b531e83aep-10",
    ),
    "max_error_best": (
        torus, {"max_error": 4e-3, "layout": "best"},
        "44ecf3ce05dbb86744f9a4e3c8b8fe88f52641a38cf2cef5356d2ab998210af7", "0x1.578cd6de151bdp-9",
    ),
    "max_error_feature_only": (
        cube, {"max_error": 1e-4, "iters": None},
        "30a1e380f9d448c95b97967ab7df8579a157c580c73e276c63af2e3b2e0ce8ad", "0x1.6e29853f0309ep-14",
    ),
}  # fmt: skip


@pytest.fixture
def one_thread():
    """One torch thread: the bytes depend on the thread count (deterministic for a given count)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _check(name: str, case) -> None:
    if torch.__version__.split("+")[0] != PINNED_TORCH:
        pytest.skip(f"hashes recorded with torch {PINNED_TORCH}, this is {torch.__version__}")
    shape, options, digest, chamfer = case
    result = encode(*shape(), **{**FAST, **options})
    got = hashlib.sha256(result.data).hexdigest()
    got_chamfer = float(result.stats["chamfer"]).hex()
    if os.environ.get("TETWEAVE_PRINT_HASHES"):
        print(f'\n    "{name}": ..., "{got}", "{got_chamfer}"),  # {len(result.data)} B')
        return
    assert (got, got_chamfer) == (digest, chamfer), f"{name}: {len(result.data)} bytes"


@pytest.mark.parametrize("name", list(CASES))
def test_fixed_options_give_the_pinned_bytes(name, one_thread):
    _check(name, CASES[name])


@pytest.mark.slow
@pytest.mark.parametrize("name", list(SLOW_CASES))
def test_fixed_options_give_the_pinned_bytes_slow(name, one_thread):
    _check(name, SLOW_CASES[name])
