"""Plain Draco at a matched Chamfer distance (tetweave_codec/bench/anchor.py): the encoder's context line."""

import numpy as np
import pytest
import trimesh

pytest.importorskip("DracoPy")

from tetweave_codec.bench.anchor import MAX_BITS, MIN_BITS, draco_at_chamfer  # noqa: E402
from tetweave_codec.metrics.fidelity import chamfer_distance  # noqa: E402

SAMPLES = 20_000


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.8)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    return v, f, lambda vb, fb: chamfer_distance(v, f, vb, fb, n_samples=SAMPLES, normalize=False)


def test_bracketed_size_lies_between_the_bracketing_depths(sphere):
    v, f, distance = sphere
    target = distance(*_draco_mesh(v, f, 10)) * 0.8  # between 10 and 11 bits (the error halves per bit)
    match = draco_at_chamfer(v, f, target, distance)
    assert match.bound is None and match.bytes is not None
    below = [(b, e) for b, e in match.settings.values() if e > target]
    above = [(b, e) for b, e in match.settings.values() if e <= target]
    assert below and above
    assert max(b for b, _ in below) <= match.bytes <= min(b for b, _ in above)
    assert len(match.settings) <= 5  # a bisection, not the whole range
    assert "same Chamfer distance" in match.describe(int(match.bytes) + 1)
    assert "LARGER" in match.describe(int(match.bytes * 2))
    assert "smaller" in match.describe(int(match.bytes / 2))


def test_error_coarser_than_min_bits_is_an_upper_bound(sphere):
    v, f, distance = sphere
    match = draco_at_chamfer(v, f, 1.0, distance)
    assert match.bytes is None and match.bound == "below" and list(match.settings) == [MIN_BITS]
    assert "at most" in match.describe(10)


def test_error_finer_than_max_bits_is_out_of_reach(sphere):
    v, f, distance = sphere
    match = draco_at_chamfer(v, f, 1e-12, distance)
    assert match.bytes is None and match.bound == "above" and set(match.settings) == {MIN_BITS, MAX_BITS}
    assert "misses" in match.describe(10)


def _draco_mesh(v, f, bits):
    from tetweave_codec.bench.baselines import draco_decode, draco_encode

    return draco_decode(draco_encode(v, f, bits, 7))
