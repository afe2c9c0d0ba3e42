"""`.tw` version 2: quantizers, canonical order, octree + range-coded streams, container validation, hostile input."""

from __future__ import annotations

import struct
import zlib
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tetweave_codec.errors import ContainerError
from tetweave_codec.formats import entropy, octree, tw
from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.common import FLAG_OCTREE_CONTEXTS
from tetweave_codec.formats.tw2 import MAX_POINTS, TetWeaveFileV2, header_size, pack_v2, quantize_file, unpack_v2
from tetweave_codec.geometry.sh import num_coeffs


def reseal(data) -> bytes:
    body = bytes(data[:-4])
    return body + struct.pack("<I", zlib.crc32(body))


def random_file(n=40, degree=1, bits=10, seed=0, s_step=1e-3, c_step=0.2, flags=0) -> TetWeaveFileV2:
    rng = np.random.default_rng(seed)
    pts = rng.normal(scale=0.4, size=(n, 3))
    s = np.linalg.norm(pts, axis=1) - 0.5 + rng.normal(scale=0.02, size=n)
    c = rng.normal(scale=0.15, size=(n, num_coeffs(degree)))
    f, _ = quantize_file(
        pts, s, c, degree, position_bits=bits, s_step=s_step, c_band_steps=[c_step] * (degree + 1),
        scale=3.0, offset=(1.0, 2.0, -0.5), flags=flags,
    )  # fmt: skip
    return f


def shell_file(n=600, bits=9, seed=0, flags=FLAG_OCTREE_CONTEXTS | 2) -> TetWeaveFileV2:
    """Points near a sphere, like a fitted shape: the octree's middle levels have occupied face neighbours."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    pts = 0.8 * d / np.linalg.norm(d, axis=1, keepdims=True) + rng.normal(scale=0.01, size=(n, 3))
    s = np.linalg.norm(pts, axis=1) - 0.8
    f, _ = quantize_file(
        pts, s, rng.normal(scale=0.2, size=(n, 4)), 1, position_bits=bits, s_step=1e-3, c_band_steps=[0.2, 0.2],
        flags=flags,
    )  # fmt: skip
    return f


def assert_same(f: TetWeaveFileV2, g: TetWeaveFileV2):
    assert np.array_equal(f.cells, g.cells) and np.array_equal(f.s_sym, g.s_sym) and np.array_equal(f.c_sym, g.c_sym)
    assert (f.position_bits, f.sh_degree, f.flags, f.creases) == (g.position_bits, g.sh_degree, g.flags, g.creases)
    assert f.s_step == g.s_step and tuple(f.c_band_steps) == tuple(g.c_band_steps)
    assert f.scale == g.scale and np.array_equal(f.offset, g.offset)


def assert_valid(g: TetWeaveFileV2):
    """Invariants of anything unpack returns."""
    n, q = g.num_points, num_coeffs(g.sh_degree)
    assert g.cells.shape == (n, 3) and g.s_sym.shape == (n,) and g.c_sym.shape == (n, q)
    assert n == 0 or (g.cells.min() >= 0 and g.cells.max() < 2**g.position_bits)
    keys = Q.morton_keys(g.cells)
    assert np.all(keys[1:] > keys[:-1])
    assert np.isfinite(g.points).all() and np.isfinite(g.s).all() and np.isfinite(g.c).all()
    assert np.all(g.s != 0)


# -----------------------------------------------------------------------------------------------------------
# quantizers


def test_position_quantizer_cell_centres_and_clamping():
    for bits in (6, 10, 16):
        n = 2**bits
        k = np.array([[0, 1, n - 1], [n // 2, n // 2 - 1, 7]])
        x = Q.dequantize_positions(k, bits)
        assert np.array_equal(x, ((2 * k + 1 - n) * 1.2) / n)
        np.testing.assert_allclose(x, -1.2 + (k + 0.5) * Q.cell_size(bits), rtol=0, atol=1e-15)
        assert np.array_equal(Q.quantize_positions(x, bits), k)
        every = Q.dequantize_positions(np.repeat(np.arange(n)[:, None], 3, axis=1), bits)
        assert np.array_equal(every[::-1], -every)  # the grid is exactly symmetric about 0 (x 1.2 rounds evenly)
    far = np.array([[-5.0, 5.0, 1.2], [-1.2, 1.19999, 0.0]])
    assert Q.quantize_positions(far, 10).tolist() == [[0, 1023, 1023], [0, 1023, 512]]
    with pytest.raises(ValueError):
        Q.quantize_positions(far, 5)
    with pytest.raises(ValueError):
        Q.quantize_positions(far, 17)


@given(st.lists(st.floats(-1.2, 1.2, allow_nan=False), min_size=3, max_size=30), st.integers(6, 16))
@settings(max_examples=50, deadline=None)
def test_position_error_is_at_most_half_a_cell(xs, bits):
    p = np.array(xs[: len(xs) // 3 * 3]).reshape(-1, 3)
    back = Q.dequantize_positions(Q.quantize_positions(p, bits), bits)
    assert np.abs(back - p).max() <= Q.cell_size(bits) / 2 * (1 + 1e-9) + 1e-15


def test_fractional_grid_spans_the_bits_between_two_integer_grids():
    for eff in (6.0, 7.25, 8.5, 8.875, 9.0, 12.6, 16.0):
        bits, scale = Q.fractional_grid(eff)
        assert 0.5 < scale <= 1.0 and isinstance(bits, int)
        assert bits + np.log2(scale) == pytest.approx(round(eff * 8) / 8, abs=1e-12)
        assert Q.fractional_grid(eff) == (bits, scale)  # a pure function of its argument
    assert Q.fractional_grid(9.0) == (9, 1.0) and Q.fractional_grid(8.5) == (9, 2.0**-0.5)
    for bad in (5.0, 16.25):  # the stored grid itself has 6..16 bits (5.5 is 6 bits at scale 2^-0.5)
        with pytest.raises(ValueError):
            Q.fractional_grid(bad)
    for bad in (0.49, 1.01, float("nan")):
        with pytest.raises(ValueError):
            Q.quantize_positions(np.zeros((1, 3)), 9, bad)


@given(st.lists(st.floats(-1.2, 1.2, allow_nan=False), min_size=3, max_size=30), st.integers(6, 16), st.floats(0.5, 1))
@settings(max_examples=50, deadline=None)
def test_scaled_grid_error_is_at_most_half_a_scaled_cell(xs, bits, scale):
    """Positions stored as scale x p: back in the fit's frame within half a cell / scale, and the cells are those
    of the plain grid applied to scale x p (what a decoder with the transform divided by the scale sees)."""
    p = np.array(xs[: len(xs) // 3 * 3]).reshape(-1, 3)
    cells = Q.quantize_positions(p, bits, scale)
    assert np.array_equal(cells, Q.quantize_positions(p * scale, bits))
    back = Q.dequantize_positions(cells, bits, scale)
    assert np.abs(back - p).max() <= Q.cell_size(bits) / scale / 2 * (1 + 1e-9) + 1e-15
    np.testing.assert_allclose(back * scale, Q.dequantize_positions(cells, bits), rtol=1e-15, atol=1e-15)


def test_s_quantizer_preserves_the_sign_and_never_gives_zero():
    s = np.array([-1.0, -1e-9, -0.0, 0.0, 1e-9, 0.00049, 0.0005, -0.0005, 3.0, 1e9, -1e9])
    k = Q.quantize_s(s, 5e-4)
    v = Q.dequantize_s(k, 5e-4)
    assert np.array_equal(k < 0, s < 0) and np.array_equal(v < 0, s < 0) and np.all(v != 0)
    assert k.min() == -Q.S_SYMBOL_LIMIT and k.max() == Q.S_SYMBOL_LIMIT - 1
    step = Q.stored_step(5e-4)
    assert step == float(np.float32(5e-4))
    inner = np.abs(s) < 100
    assert np.abs(v - s)[inner].max() <= step / 2 * (1 + 1e-12)  # mid-rise: at most half a step off
    ok = np.abs(s) < 1
    assert np.all(np.abs(v[ok] - s[ok]) <= step)


def test_c_quantizer_bands_and_limits():
    steps = Q.c_steps(2, [0.1, 0.2, 0.3])
    assert steps.shape == (9,)
    assert np.allclose(steps, np.float32([0.1, 0.2, 0.2, 0.2, 0.3, 0.3, 0.3, 0.3, 0.3]))
    assert Q.c_steps(-1, []).shape == (0,)
    c = np.array([[0.05, 0.31, -0.29, 0.0, 1e9, -1e9, 0.15, 0.45, -0.45]])
    k = Q.quantize_c(c, steps)
    assert k[0, :4].tolist() == [0, 2, -1, 0] and k[0, 4] == Q.C_SYMBOL_LIMIT and k[0, 5] == -Q.C_SYMBOL_LIMIT
    assert np.array_equal(Q.dequantize_c(k, steps), k * steps)
    with pytest.raises(ValueError):
        Q.c_steps(1, [0.1])
    with pytest.raises(ValueError):
        Q.c_steps(0, [0.0])


def test_quantizers_accept_torch_tensors():
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(1)
    p = rng.uniform(-1.3, 1.3, (50, 3))
    s = rng.normal(scale=0.1, size=50)
    c = rng.normal(scale=0.3, size=(50, 4))
    steps = Q.c_steps(1, [0.1, 0.2])
    for bits in (6, 11):
        kt = Q.quantize_positions(torch.tensor(p), bits)
        assert kt.dtype == torch.int64 and np.array_equal(kt.numpy(), Q.quantize_positions(p, bits))
        assert np.array_equal(Q.dequantize_positions(kt, bits).numpy(), Q.dequantize_positions(kt.numpy(), bits))
    ks = Q.quantize_s(torch.tensor(s), 1e-3)
    assert np.array_equal(ks.numpy(), Q.quantize_s(s, 1e-3))
    assert np.array_equal(Q.dequantize_s(ks, 1e-3).numpy(), Q.dequantize_s(ks.numpy(), 1e-3))
    kc = Q.quantize_c(torch.tensor(c), steps)
    assert np.array_equal(kc.numpy(), Q.quantize_c(c, steps))
    assert np.array_equal(Q.dequantize_c(kc, steps).numpy(), Q.dequantize_c(kc.numpy(), steps))


def test_canonical_order_is_morton_with_x_most_significant():
    cells = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 0], [1, 1, 1], [2, 0, 0]])
    order = Q.canonical_order(cells, 6)
    assert cells[order].tolist() == [[0, 0, 0], [0, 0, 1], [0, 1, 0], [1, 0, 0], [1, 1, 1], [2, 0, 0]]
    rng = np.random.default_rng(0)
    c = rng.integers(0, 2**16, (500, 3))
    keys = sorted(
        (sum(((int(x) >> i & 1) << 2 | (int(y) >> i & 1) << 1 | (int(z) >> i & 1)) << (3 * i) for i in range(16)), j)
        for j, (x, y, z) in enumerate(c)
    )
    assert np.array_equal(Q.canonical_order(c, 16), [j for _, j in keys])


def test_merge_collisions_keeps_the_first_occurrence():
    cells = np.array([[3, 3, 3], [0, 0, 1], [3, 3, 3], [0, 0, 0], [0, 0, 1]])
    unique, first = Q.merge_collisions(cells)
    assert unique.tolist() == [[0, 0, 0], [0, 0, 1], [3, 3, 3]]
    assert first.tolist() == [3, 1, 0]
    pts = Q.dequantize_positions(cells, 8)
    f, kept = quantize_file(pts, np.arange(5) - 2.5, None, -1, position_bits=8, s_step=1.0, c_band_steps=[])
    assert kept.tolist() == [3, 1, 0] and f.s_sym.tolist() == [0, -2, -3]


# -----------------------------------------------------------------------------------------------------------
# round trip


@st.composite
def v2_files(draw):
    bits = draw(st.integers(6, 16))
    degree = draw(st.integers(-1, 3))
    n = draw(st.integers(0, 120))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    clustered = draw(st.booleans())
    if clustered:  # a few dense clusters: multi-child octree nodes
        centre = rng.integers(0, 2**bits, (3, 3))
        cells = centre[rng.integers(0, 3, n)] + rng.integers(-3, 4, (n, 3))
        cells = np.clip(cells, 0, 2**bits - 1)
    else:
        cells = rng.integers(0, 2**bits, (n, 3))
    cells, _ = Q.merge_collisions(cells)
    n = len(cells)
    big = draw(st.booleans())
    s_lim = Q.S_SYMBOL_LIMIT if big else 300
    c_lim = Q.C_SYMBOL_LIMIT if big else 5
    s_sym = rng.integers(-s_lim, s_lim, n)
    c_sym = rng.integers(-c_lim, c_lim + 1, (n, num_coeffs(degree)))
    if big and n:
        s_sym[0], s_sym[-1] = -Q.S_SYMBOL_LIMIT, Q.S_SYMBOL_LIMIT - 1
        if c_sym.size:
            c_sym[0, 0], c_sym[-1, -1] = -Q.C_SYMBOL_LIMIT, Q.C_SYMBOL_LIMIT
    perm = rng.permutation(n)  # pack_v2 sorts
    steps = tuple(float(np.float32(x)) for x in rng.uniform(1e-3, 1, degree + 1))
    f = TetWeaveFileV2(
        cells[perm], s_sym[perm], c_sym[perm], bits, float(np.float32(draw(st.floats(1e-6, Q.MAX_S_STEP)))), steps,
        degree, draw(st.floats(1e-6, 1e6)), rng.normal(size=3), draw(st.integers(0, 7)),
        creases=draw(st.booleans()),
    )  # fmt: skip
    return f, perm


@given(v2_files())
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_round_trip_of_symbols_is_exact(case):
    f, perm = case
    data = pack_v2(f)
    g = tw.unpack(data)
    assert isinstance(g, TetWeaveFileV2) and g.version == 2
    order = np.argsort(perm)  # back to canonical order
    expected = TetWeaveFileV2(
        f.cells[order], f.s_sym[order], f.c_sym[order], f.position_bits, f.s_step, f.c_band_steps, f.sh_degree,
        f.scale, f.offset, f.flags, creases=f.creases,
    )  # fmt: skip
    assert_same(g, expected)
    assert_valid(g)
    assert pack_v2(g) == data
    assert sum(g.sizes.values()) == len(data)
    assert g.sizes["header"] == header_size(f.sh_degree)


def test_real_fitted_shape_round_trip_and_dequantized_arrays():
    f = random_file(n=3000, degree=2, bits=11)
    g = tw.unpack(pack_v2(f))
    assert_same(f, g)
    assert g.points.dtype == g.s.dtype == g.c.dtype == np.float64
    assert np.array_equal(g.points, Q.dequantize_positions(g.cells, 11))
    assert np.array_equal(g.s, (g.s_sym + 0.5) * g.s_step)
    assert np.array_equal(g.c, g.c_sym * Q.c_steps(2, g.c_band_steps))
    assert g.backend == "exact" and g.exact and tw.unpack(pack_v2(random_file(flags=1))).backend == "qhull"
    assert tw.unpack(pack_v2(replace(f, exact=False))).backend == "tetgen"


def test_pack_v2_rejects_bad_contents():
    f = random_file(n=10)
    bad = [
        dict(cells=np.vstack([f.cells, f.cells[:1]]), s_sym=np.append(f.s_sym, 0), c_sym=np.vstack([f.c_sym] * 2)[:11]),
        dict(cells=f.cells + 2**10),
        dict(s_sym=f.s_sym[:-1]),
        dict(s_sym=np.full(10, Q.S_SYMBOL_LIMIT)),
        dict(c_sym=np.full((10, 4), Q.C_SYMBOL_LIMIT + 1)),
        dict(c_band_steps=(0.1,)),
        dict(s_step=0.0),
        dict(position_bits=5),
        dict(scale=-1.0),
        dict(s_sym=np.full(10, Q.S_SYMBOL_LIMIT), flags=2),
        dict(flags=128),  # bit 7 is reserved (3-4: smoothing steps, 5-6: subdivision levels)
        dict(flags=96),  # subdivision levels 3: invalid
    ]
    fields = dict(f.__dict__)
    fields.pop("sizes", None)
    for change in bad:
        with pytest.raises(ValueError):
            pack_v2(TetWeaveFileV2(**{**fields, **change}))


def test_entropy_models_are_the_documented_integers():
    w = entropy.histogram_weights([3, 0, 255, 1])
    free = 2**24 - 4
    assert w.sum() == free and w[1] == 0 and w[0] == 3 * free // 259
    assert np.array_equal(entropy.binary_weights(64), [192 * 65536 - 1, 64 * 65536 - 1])
    # the coder really uses (w + 1) / 2**24: the compressed size matches the ideal code length
    rng = np.random.default_rng(0)
    sym = rng.choice(4, 20000, p=(w + 1) / 2**24)
    wr = entropy.Writer()
    wr.encode(sym, entropy.histogram_model([3, 0, 255, 1]))
    nbytes = len(wr.finish())
    assert abs(nbytes * 8 - entropy.model_bits(sym, w)) < 64
    with pytest.raises(ContainerError):
        entropy.histogram_weights([0, 0])
    with pytest.raises(ContainerError):
        entropy.binary_weights(0)


def test_per_symbol_binary_models_code_exactly_like_the_fixed_models():
    """encode_binary (one weight row per bit) must give the same words as the documented fixed binary models."""
    rng = np.random.default_rng(2)
    for _ in range(50):
        v = rng.integers(1, 256, int(rng.integers(1, 300)))
        bits = (rng.random(len(v)) < v / 256).astype(np.int64)
        fixed = entropy.Writer()
        for b, vv in zip(bits, v, strict=True):
            fixed.encode_bits([b], int(vv))
        rows = entropy.Writer()
        rows.encode_binary(bits, entropy.binary_weight_rows(v))
        words = rows.finish()
        assert words == fixed.finish()
        assert np.array_equal(entropy.Reader(words, "x").decode_binary(entropy.binary_weight_rows(v)), bits)
    with pytest.raises(ContainerError):
        entropy.binary_weight_rows([1, 0])


@given(st.integers(1, 10), st.integers(1, 400), st.integers(0, 2**32 - 1))
@settings(max_examples=40, deadline=None)
def test_face_neighbours_match_a_brute_force_search(level, n, seed):
    rng = np.random.default_rng(seed)
    cells = np.unique(rng.integers(0, 2**level, (n, 3)) // rng.integers(1, 3), axis=0)
    keys = np.sort(Q.morton_keys(cells).astype(np.int64))
    cells = octree._cells_from_keys(keys)
    got = octree.face_neighbours(keys, level)
    present = set(map(tuple, cells.tolist()))
    steps = ((-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), (0, 0, -1), (0, 0, 1))
    expected = [[tuple(np.add(c, d).tolist()) in present for d in steps] for c in cells.tolist()]
    assert np.array_equal(got, np.array(expected, dtype=bool).reshape(-1, 6))


def test_context_coded_octree_round_trips_and_codes_middle_levels_bitwise():
    f = shell_file()
    cells = f.cells[Q.canonical_order(f.cells)]
    plain = octree.encode(cells, 9)
    models, words = octree.encode(cells, 9, contexts=True)
    mask = int.from_bytes(models[:2], "little")
    assert mask and not mask & 1  # some levels bit-coded, never the root (one node, no neighbours)
    assert len(models) == octree.model_size(models + words, 9, len(cells), contexts=True)
    assert len(models) + len(words) < sum(map(len, plain))
    assert octree.contexts_pay(f.cells, 9)
    scattered, _ = Q.merge_collisions(np.random.default_rng(1).integers(0, 2**12, (200, 3)))
    assert not octree.contexts_pay(scattered, 12)  # no neighbours anywhere: the encoder keeps the plain coding
    assert np.array_equal(octree.decode(models, words, 9, len(cells), contexts=True), cells)
    for n in (len(cells) - 1, len(cells) + 1):
        with pytest.raises(ContainerError, match="octree"):
            octree.decode(models, words, 9, n, contexts=True)
    g = tw.unpack(pack_v2(f))
    assert_same(f, g) and g.flags & FLAG_OCTREE_CONTEXTS


@given(st.integers(6, 12), st.integers(1, 400), st.integers(1, 40), st.integers(0, 2**32 - 1))
@settings(max_examples=40, deadline=None)
def test_context_coded_octree_round_trips_dense_and_sparse_sets(bits, n, spread, seed):
    """Blobs of every density (spread = cells around a few centres): whatever levels are bit-coded, exact cells."""
    rng = np.random.default_rng(seed)
    centre = rng.integers(0, 2**bits, (int(rng.integers(1, 5)), 3))
    cells = centre[rng.integers(0, len(centre), n)] + rng.integers(-spread, spread + 1, (n, 3))
    cells, _ = Q.merge_collisions(np.clip(cells, 0, 2**bits - 1))
    models, words = octree.encode(cells, bits, contexts=True)
    assert np.array_equal(octree.decode(models, words, bits, len(cells), contexts=True), cells)


def test_context_coded_octree_models_are_validated():
    f = shell_file()
    cells = f.cells[Q.canonical_order(f.cells)]
    models, words = octree.encode(cells, 9, contexts=True)
    mask = int.from_bytes(models[:2], "little")
    with pytest.raises(ContainerError, match="beyond"):
        octree.model_size((mask | 1 << 9).to_bytes(2, "little") + models[2:] + words, 9, len(cells), True)
    for size in range(len(models)):
        with pytest.raises(ContainerError, match="shorter"):
            octree.model_size(models[:size], 9, len(cells), True)
    level = (mask & -mask).bit_length() - 1  # first bit-coded level: its 12 bytes follow 8 per earlier level
    bad = bytearray(models)
    bad[2 + 8 * level] = 0
    with pytest.raises(ContainerError, match="binary model"):
        octree.decode(bytes(bad), words, 9, len(cells), contexts=True)


def test_files_without_the_new_flags_keep_their_bytes():
    """Golden digests of files written before flag bit 2 existed: the plain codings must not change (TetGen
    files: the exact Delaunay's bit 6 of byte 12 is the only other change, `test_exact_bit_...`)."""
    import hashlib

    digests = {
        0: "398ecd0cabdab3d6fd6f88093ff9959f93b2d2ca47b6f2a82afb07dd4b76547f",
        2: "1991eef63264eb9d5bd9fed91b02bb3d032028ab5e8eeaac26cffcc0346a0cfa",
    }
    for flags, digest in digests.items():
        f = replace(random_file(n=300, degree=1, bits=10, seed=5, flags=flags), exact=False)
        assert hashlib.sha256(pack_v2(f)).hexdigest() == digest


def test_octree_never_yields_more_points_than_announced():
    cells, _ = Q.merge_collisions(np.random.default_rng(0).integers(0, 64, (30, 3)))
    models, words = octree.encode(cells, 6)
    assert np.array_equal(octree.decode(models, words, 6, len(cells)), cells)
    for n in (1, len(cells) - 1, len(cells) + 1):
        with pytest.raises(ContainerError, match="octree"):
            octree.decode(models, words, 6, n)


# -----------------------------------------------------------------------------------------------------------
# hostile input


@pytest.mark.parametrize("flags", [0, 2, 6])
def test_every_truncation_is_rejected(flags):
    data = pack_v2(shell_file(n=60, bits=7, flags=flags) if flags & 4 else random_file(n=30, degree=1, flags=flags))
    for size in range(len(data)):
        with pytest.raises(ContainerError):
            tw.unpack(data[:size])


def test_random_byte_flips_with_a_valid_checksum_decode_or_raise_container_error():
    cases = ((40, 1, 10, 0), (12, 3, 6, 0), (25, -1, 16, 0), (40, 1, 10, 2), (30, 0, 8, 3))
    files = [pack_v2(random_file(n=n, degree=d, bits=b, seed=n, flags=fl)) for n, d, b, fl in cases]
    files.append(pack_v2(shell_file(n=150, bits=8)))  # bit-coded octree levels
    rng = np.random.default_rng(7)
    outcomes = {"ok": 0, "error": 0}
    for trial in range(3000):
        data = bytearray(files[trial % len(files)])
        for _ in range(int(rng.integers(1, 4))):
            pos = int(rng.integers(8, len(data) - 4)) if rng.random() < 0.9 else int(rng.integers(0, 12))
            if rng.random() < 0.5:
                data[pos] ^= 1 << int(rng.integers(8))
            else:
                data[pos] = int(rng.integers(256))
        try:
            g = tw.unpack(reseal(data))
        except ContainerError as exc:
            assert "\n" not in str(exc)
            outcomes["error"] += 1
            continue
        outcomes["ok"] += 1
        if isinstance(g, TetWeaveFileV2):
            assert_valid(g)
    assert outcomes["ok"] > 100 and outcomes["error"] > 100  # both paths exercised


@given(
    degree=st.integers(-3, 5),
    bits=st.integers(0, 20),
    n=st.one_of(st.integers(0, 200), st.integers(0, 2**32 - 1)),
    flags=st.integers(0, 255),
    steps=st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=5, max_size=5),
    payload=st.binary(max_size=300),
    split=st.lists(st.integers(0, 300), min_size=3, max_size=3),
)
@settings(max_examples=300, deadline=None)
def test_random_headers_and_payloads_decode_or_raise_container_error(degree, bits, n, flags, steps, payload, split):
    d = max(-1, min(3, degree))
    sizes = sorted(min(x, len(payload)) for x in split)
    section_sizes = (sizes[0], sizes[1] - sizes[0], len(payload) - sizes[1])
    header = struct.pack("<8sHBbBI4df", tw.MAGIC, 2, flags, degree, bits, n, 2.0, 0.0, 0.0, 0.0, abs(steps[0]))
    header += struct.pack(f"<{d + 1}f", *[abs(x) for x in steps[: d + 1]])
    header += struct.pack("<3I", *section_sizes)
    body = header + payload
    try:
        g = tw.unpack(body + struct.pack("<I", zlib.crc32(body)))
    except ContainerError:
        return
    assert_valid(g)


@pytest.mark.parametrize("flags", [0, 2])
def test_random_streams_behind_valid_headers(flags):
    """Valid header, positions and models; random coded words for s and c: the stream decoders are exercised."""
    from tetweave_codec.formats import attributes

    f = random_file(n=50, degree=2, flags=flags)
    data = pack_v2(f)
    hsize = header_size(2)
    pos_size, s_size, c_size = struct.unpack_from("<3I", data, hsize - 12)
    pos = data[hsize : hsize + pos_size]
    s_sec = data[hsize + pos_size : hsize + pos_size + s_size]
    c_sec = data[hsize + pos_size + s_size : hsize + pos_size + s_size + c_size]
    s_models = s_sec[: attributes.model_size_s(s_sec) if flags == 0 else 1 + s_sec[0]]
    c_models = c_sec[: attributes.model_size_c(c_sec, 2)]
    rng = np.random.default_rng(3)
    ok = 0
    for _ in range(300):
        words = [rng.integers(0, 256, 4 * int(rng.integers(0, 60)), dtype=np.uint8).tobytes() for _ in range(2)]
        sections = (pos, s_models + words[0], c_models + words[1])
        body = data[: hsize - 12] + struct.pack("<3I", *map(len, sections)) + b"".join(sections)
        try:
            g = tw.unpack(body + struct.pack("<I", zlib.crc32(body)))
        except ContainerError:
            continue
        ok += 1
        assert_valid(g)
    assert ok > 250  # random words are valid streams (they decode to some symbols)


def test_random_context_coded_positions_behind_valid_headers():
    """Flag bit 2: random level masks, model bytes and words for the positions; only ContainerError or a valid file."""
    f = shell_file(n=200, bits=8)
    data = pack_v2(f)
    hsize = header_size(1)
    pos_size = struct.unpack_from("<I", data, hsize - 12)[0]
    rest = data[hsize + pos_size : -4]
    rng = np.random.default_rng(11)
    outcomes = {"ok": 0, "error": 0}
    for _ in range(400):
        mask = int(rng.integers(0, 1 << 8))
        models = mask.to_bytes(2, "little") + bytes(
            int(x) for x in rng.integers(1, 256, 8 * 8 + 4 * bin(mask).count("1"))
        )
        words = rng.integers(0, 256, 4 * int(rng.integers(0, 80)), dtype=np.uint8).tobytes()
        sizes = (len(models) + len(words), *struct.unpack_from("<2I", data, hsize - 8))
        body = data[: hsize - 12] + struct.pack("<3I", *sizes) + models + words + rest
        try:
            g = tw.unpack(body + struct.pack("<I", zlib.crc32(body)))
        except ContainerError as exc:
            assert "\n" not in str(exc)
            outcomes["error"] += 1
            continue
        outcomes["ok"] += 1
        assert_valid(g)
    assert outcomes["error"] > 300


def test_n_above_the_format_limit_is_rejected_before_decoding():
    data = bytearray(pack_v2(random_file(n=5)))
    struct.pack_into("<I", data, 13, MAX_POINTS + 1)
    with pytest.raises(ContainerError, match="at most"):
        tw.unpack(reseal(data))


@pytest.mark.parametrize(
    "offset, fmt, value, message",
    [
        (10, "<B", 96, "subdivision levels"),
        (11, "<b", 4, "SH degree"),
        (12, "<B", 5, "position bits"),
        (12, "<B", 17, "position bits"),
        (12, "<B", 9 | 1 << 5, "position bits"),  # bits 5-6 of the position-bits byte are 0
        (12, "<B", 17 | 1 << 6, "position bits"),  # nor the exact Delaunay's bit
        (12, "<B", 9 | 1 << 5 | 1 << 6, "position bits"),
        (12, "<B", 17 | 1 << 7, "position bits"),  # the creases bit does not make b 17 valid
        (17, "<d", 0.0, "scale"),
        (17, "<d", float("inf"), "scale"),
        (17, "<d", 1.7e308, "float64 range"),  # 1.2 x 1.7e308 overflows: decoded vertices would be infinite
        (25, "<d", float("nan"), "offset"),
        (49, "<f", 0.0, "s step"),
        (49, "<f", float("nan"), "s step"),
        (53, "<f", -1.0, "c step"),
        # values no encoder writes (formats/README.md, "Validation"): steps that saturate tanh or dwarf the grid,
        # a scale whose products under- or overflow, an offset whose ulp is coarser than the grid's detail
        (49, "<f", 1.0000001, "s step"),
        (49, "<f", 3.4e38, "s step"),
        (53, "<f", 4.0000005, "c step"),
        (53, "<f", 1e38, "c step"),
        (57, "<f", 3.4e38, "c step"),  # band 1
        (17, "<d", 2.0**-65, "scale"),
        (17, "<d", 2.0**65, "scale"),
        (25, "<d", 2.0**26, "offset beyond"),  # random_file's scale 3: 2^24 x 3 is the largest offset
    ],
)
def test_semantic_checks_behind_a_valid_checksum(offset, fmt, value, message):
    data = bytearray(pack_v2(random_file(n=20, degree=1)))
    struct.pack_into(fmt, data, offset, value)
    with pytest.raises(ContainerError, match=message):
        tw.unpack(reseal(data))


def test_largest_steps_scale_and_offset_are_valid():
    """The ends of the stored ranges are in them: what a writer can store, a reader takes."""
    f = random_file(n=20, degree=1, s_step=Q.MAX_S_STEP, c_step=Q.MAX_C_STEP)
    g = tw.unpack(pack_v2(f))
    assert g.s_step == Q.MAX_S_STEP and g.c_band_steps == (Q.MAX_C_STEP,) * 2
    for scale, offset in ((2.0**-64, 2.0**-40), (2.0**64, -(2.0**88))):
        h = tw.unpack(pack_v2(TetWeaveFileV2(**{**_fields(f), "scale": scale, "offset": np.array([offset, 0, 0])})))
        assert h.scale == scale and h.offset[0] == offset
    with pytest.raises(ValueError, match="c step"):
        pack_v2(random_file(n=20, degree=1, c_step=4.5))


def _fields(f) -> dict:
    fields = dict(f.__dict__)
    fields.pop("sizes", None)
    return fields


def test_checksum_trailing_bytes_and_version_dispatch():
    data = pack_v2(random_file(n=20))
    damaged = bytearray(data)
    damaged[60] ^= 4
    with pytest.raises(ContainerError, match="checksum"):
        tw.unpack(bytes(damaged))
    with pytest.raises(ContainerError, match="unexpected bytes"):
        tw.unpack(data + b"\0")
    for version in (0, 3, 65535):
        bad = bytearray(data)
        struct.pack_into("<H", bad, 8, version)
        with pytest.raises(ContainerError, match=f"unsupported .tw version {version} .*versions 1 and 2"):
            tw.unpack(reseal(bad))
    with pytest.raises(ContainerError):
        unpack_v2(data[:30])


def test_version_1_files_still_decode():
    rng = np.random.default_rng(0)
    f1 = tw.TetWeaveFile(
        rng.uniform(-1, 1, (20, 3)).astype(np.float16), rng.normal(size=20).astype(np.float16),
        rng.normal(size=(20, 4)).astype(np.float16), 1, 2.0, np.zeros(3),
    )  # fmt: skip
    g = tw.unpack(tw.pack(f1))
    assert isinstance(g, tw.TetWeaveFile) and g.version == 1
    assert np.array_equal(g.points, f1.points) and np.array_equal(g.c, f1.c)


def test_empty_file_round_trip():
    f = random_file(n=0, degree=3)
    data = pack_v2(f)
    assert len(data) == header_size(3) + 4
    g = tw.unpack(data)
    assert g.num_points == 0 and g.c_sym.shape == (0, 16) and g.points.shape == (0, 3)


def test_decode_and_info_read_version_2(tmp_path):
    from click.testing import CliRunner

    from tetweave_codec.cli.info import info
    from tetweave_codec.decoder import decode_detailed, mesh_from_points

    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (1500, 3))
    f, _ = quantize_file(
        pts, np.linalg.norm(pts, axis=1) - 0.6, rng.normal(scale=0.1, size=(1500, 4)), 1, position_bits=10,
        s_step=1e-3, c_band_steps=[0.1, 0.2], scale=2.0, offset=(1.0, 0.0, 0.0),
    )  # fmt: skip
    data = pack_v2(f)
    res = decode_detailed(data)
    v_ref, f_ref = mesh_from_points(f.points, f.s, f.c, 1, backend=res.backend)
    assert len(res.faces) > 0 and np.array_equal(res.faces, f_ref)
    np.testing.assert_allclose(res.vertices, v_ref * 2.0 + [1.0, 0.0, 0.0], rtol=0, atol=1e-12)
    path = tmp_path / "x.tw"
    path.write_bytes(data)
    out = CliRunner().invoke(info, [str(path)])
    assert out.exit_code == 0, out.output
    for word in ("version 2", "10 bits/axis", "s step 0.001", "positions", "bits/point", "checksum    4"):
        assert word in out.output


def test_exact_bit_is_bit_6_of_the_position_bits_byte():
    """The exact Delaunay is bit 6 of byte 12 (formats/README.md): what the encoder writes; a file without it names
    TetGen or Qhull in flags bit 0, and the two together are refused on both sides."""
    f = random_file(n=40, degree=1, bits=9)
    exact = pack_v2(f)
    legacy = pack_v2(replace(f, exact=False))
    assert exact[12] == 9 | 1 << 6 and legacy[12] == 9
    assert exact[:12] == legacy[:12] and exact[13:-4] == legacy[13:-4]  # that byte and the checksum only
    assert tw.unpack(exact).backend == "exact" and tw.unpack(legacy).backend == "tetgen"
    with pytest.raises(ValueError, match="Qhull"):
        pack_v2(replace(f, flags=f.flags | 1, exact=True))
    both = bytearray(exact)
    both[10] |= 1
    with pytest.raises(ContainerError, match="two Delaunay backends"):
        tw.unpack(reseal(both))


def test_creases_bit_is_bit_7_of_the_position_bits_byte():
    """Crease-preserving smoothing is bit 7 of byte 12 (formats/README.md): b keeps bits 0-4, and a file without
    the bit keeps its bytes."""
    f = random_file(n=40, degree=1, bits=9)
    plain = pack_v2(f)
    assert plain[12] == 9 | 1 << 6 and not tw.unpack(plain).creases
    marked = pack_v2(replace(f, creases=True))
    assert marked[12] == 9 | 1 << 6 | 1 << 7
    assert marked[:12] == plain[:12] and marked[13:-4] == plain[13:-4]  # that byte and the checksum only
    g = tw.unpack(marked)
    assert g.creases and g.position_bits == 9
    assert_same(g, replace(tw.unpack(plain), creases=True))
