"""Plain Draco and fast-simplification + Draco at a matched Chamfer distance (tetweave_codec/classical.py): the
encoder's context lines."""

import numpy as np
import pytest
import trimesh

pytest.importorskip("DracoPy")

from tetweave_codec.classical import (  # noqa: E402
    DECIMATE_BRACKET_RATIO,
    MAX_BITS,
    MAX_DECIMATE_TRIES,
    MIN_BITS,
    MIN_KEEP,
    DracoMatch,
    decimate,
    decimate_bits,
    decimate_draco_at_chamfer,
    draco_at_chamfer,
    draco_decode,
    draco_encode,
)
from tetweave_codec.metrics.fidelity import chamfer_distance  # noqa: E402
from tetweave_codec.metrics.rate_distortion import bytes_at, pareto_front  # noqa: E402

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
    return draco_decode(draco_encode(v, f, bits, 7))


def test_decimation_search_brackets_the_target_and_matches_a_dense_sweep(sphere):
    """The bracket search lands where a dense sweep of 40 fractions at the same depths (what `tetweave bench`
    reads a front from) puts fast-simplification + Draco at the target, within 10 %, from a few decimations."""
    v, f, distance = sphere
    target = distance(*_draco_mesh(*decimate(v, f, 0.07), 12))
    match = decimate_draco_at_chamfer(v, f, target, distance, bits=12, start_faces=len(f) // 40)
    assert match.bound is None and match.bytes is not None and match.bits in (10, 11, 12, 13)
    keeps = {k for k, _ in match.settings}
    assert len(keeps) <= 4 * MAX_DECIMATE_TRIES and {b for _, b in match.settings} == {10, 11, 12, 13}
    over = [k for (k, b), s in match.settings.items() if b == 12 and s[2] > target]
    within = [k for (k, b), s in match.settings.items() if b == 12 and s[2] <= target]
    assert over and within and min(within) / max(over) <= DECIMATE_BRACKET_RATIO
    dense = []
    for keep in np.geomspace(0.01, 0.5, 40):
        vd, fd = decimate(v, f, keep)
        for bits in (10, 11, 12, 13):
            data = draco_encode(vd, fd, bits, 7)
            dense.append((distance(*draco_decode(data)), len(data)))
    expected = bytes_at(pareto_front(dense), target)
    assert abs(match.bytes / expected - 1) < 0.10, (match.bytes, expected)
    assert f"fast-simplification + Draco ({match.bits} bits)" in match.describe(int(match.bytes))
    assert "LARGER" in match.describe(int(match.bytes * 2)) and "smaller" in match.describe(int(match.bytes / 2))


def test_decimation_search_outside_its_range_says_so(sphere):
    v, f, distance = sphere
    coarse = decimate_draco_at_chamfer(v, f, 1.0, distance, bits=12, start_faces=200)
    assert coarse.bytes is None and coarse.bound == "below" and min(k for k, _ in coarse.settings) == MIN_KEEP
    fine = decimate_draco_at_chamfer(v, f, 1e-12, distance, bits=12, start_faces=200)
    assert fine.bytes is None and fine.bound == "above" and max(k for k, _ in fine.settings) == 1.0
    assert "no fraction" in fine.describe(10)


def test_decimation_bits_leave_half_the_error_to_the_decimation():
    settings = {8: (100, 4e-3), 12: (300, 2e-4), 10: (200, 9e-4), 11: (250, 4.5e-4)}
    assert decimate_bits(DracoMatch(1e-3, 210.0, None, settings)) == 11  # 10 is within, not within half
    assert decimate_bits(DracoMatch(5e-4, 260.0, None, settings)) == 12  # 11 is within, not within half
    assert decimate_bits(DracoMatch(1e-2, None, "below", {8: (100, 4e-3)})) == 8  # within half at MIN_BITS
    assert decimate_bits(DracoMatch(1e-5, None, "above", settings)) == MAX_BITS


def test_context_of_a_visible_surface_encode_compresses_the_whole_input():
    """When the encode fitted the visible surface (a ball with a hidden ball inside), the summary's plain Draco and
    fast-simplification + Draco compress the input as given, every face (their bytes include the hidden ball), and
    measure their error against the visible surface (the outer ball), as the encode's own Chamfer distance is; on
    the clean ball (auto -> all) nothing changes."""
    from tetweave_codec.classical import classical_context
    from tetweave_codec.fit.prepared import prepare_input
    from tetweave_codec.fit.visible import choose_surface

    outer = trimesh.creation.icosphere(subdivisions=3, radius=0.9)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    vo, fo = np.asarray(outer.vertices), np.asarray(outer.faces, dtype=np.int64)
    v = np.concatenate([vo, np.asarray(inner.vertices) + [0.1, 0.0, 0.0]])
    f = np.concatenate([fo, np.asarray(inner.faces, dtype=np.int64) + len(vo)])
    given = prepare_input(v, f)
    choice = choose_surface(given.normalized, given.faces, "auto")
    assert choice.mode == "visible"
    prepared = given.on_visible_surface(choice.surface, choice.reason)
    assert prepared.source is given and given.source is given and len(prepared.faces) == len(fo)
    context = classical_context(prepared, 5000, 0.05, 20_000, SAMPLES)
    clean = prepare_input(vo, fo)
    for bits, (size, error) in context["draco"].settings.items():
        data = draco_encode(given.normalized, f, bits, 7)
        assert size == len(data) > len(draco_encode(clean.normalized, fo, bits, 7))
        assert error == prepared.normalized_chamfer(*draco_decode(data), min(SAMPLES, 10_000))
        # the hidden ball's faces (1/9 of the decoded area, ~0.55 inside) are error against the visible surface
        assert error > 0.02 > given.normalized_chamfer(*draco_decode(data), min(SAMPLES, 10_000))
    for (keep, bits), (faces, size, error) in list(context["decimate"].settings.items())[:3]:
        vd, fd = decimate(given.vertices, f, keep)  # the whole input, in its own frame
        data = draco_encode(vd, fd, bits, 7)
        assert (faces, size) == (len(fd), len(data))
        assert error == prepared.chamfer(*draco_decode(data), min(SAMPLES, 10_000))
    assert all("hidden ones included; error to the visible surface" in line for line in context["lines"])
    assert f"of all {len(f):,} input faces" in context["lines"][0]
    # the clean input: the lines of before, without the note
    lines = classical_context(clean, 5000, 1e-3, 20_000, SAMPLES)["lines"]
    assert not any("visible surface" in line for line in lines)
