"""The C core's range decoder (decoder/range.c) and its s, c and holes sections (attributes.c, holes_section.c).

(a) Random streams of random models written by formats/entropy.Writer (constriction) decode to the same symbols
    with the C decoder, with entropy.Reader (constriction) and with tests/spec_range_decoder.py (written from
    formats/README.md alone), also truncated, extended with garbage or with words changed: the three agree on
    every symbol or fail at the same batch (and the C and spec decoders end in the same state).
(b) The s, c and holes sections of every committed version-2 file decode to the reference's symbols.
(c) Hostile sections (truncated, huge counts, bad models) are errors, never crashes or over-reads (a build with
    AddressSanitizer runs them too where the compiler has it).
"""

from __future__ import annotations

import ctypes
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
import spec_range_decoder as spec
from core_lib import CORE, FLAGS, compiler, core_library

from tetweave_codec.errors import ContainerError
from tetweave_codec.formats import attributes, entropy, holes, predict, quantize, tw2

REPO = Path(__file__).resolve().parent.parent
HARNESS = Path(__file__).resolve().parent / "core_range_harness.c"
SOURCES = ["range.c", "attributes.c", "holes_section.c", str(HARNESS)]
TOTAL = 1 << 24
OK, INVALID = 0, 1


class TwError(ctypes.Structure):
    _fields_ = [("status", ctypes.c_int), ("message", ctypes.c_char * 256)]


def _ptr(a: np.ndarray):
    return a.ctypes.data_as(ctypes.c_void_p)


@pytest.fixture(scope="module")
def lib():
    lib = core_library(SOURCES)
    vp, sz, ip = ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int
    err = ctypes.POINTER(TwError)
    lib.h_open.restype = vp
    lib.h_open.argtypes = [ctypes.c_char_p, sz]
    lib.h_close.argtypes = [vp]
    lib.h_histogram.argtypes = [vp, ctypes.c_char_p, sz, sz, vp, err]
    lib.h_weights.argtypes = [vp, vp, sz, sz, vp, err]
    lib.h_bits.argtypes = [vp, ip, sz, vp, err]
    lib.h_binary.argtypes = [vp, vp, sz, vp, err]
    lib.h_raw.argtypes = [vp, vp, sz, vp, err]
    lib.h_grouped.argtypes = [vp, vp, sz, ctypes.c_char_p, vp, ip, vp, err]
    lib.h_state.argtypes = [vp, vp]
    lib.tw_decode_s.argtypes = [ctypes.c_char_p, sz, ctypes.c_uint32, vp, err]
    lib.tw_decode_s_residuals.argtypes = [ctypes.c_char_p, sz, ctypes.c_uint32, vp, err]
    lib.tw_decode_c.argtypes = [ctypes.c_char_p, sz, ctypes.c_uint32, ip, vp, err]
    lib.tw_decode_holes.argtypes = [ctypes.c_char_p, sz, ctypes.c_uint32, vp, vp, err]
    lib.tw_decode_holes_bounded.argtypes = [ctypes.c_char_p, sz, ctypes.c_uint32, ctypes.c_uint64, vp, vp, err]
    return lib


# -----------------------------------------------------------------------------------------------------------
# (a) random streams


class Failed(Exception):
    """A decoder reported an invalid stream."""


class CReader:
    """entropy.Reader's calls over the C decoder (through tests/core_range_harness.c)."""

    def __init__(self, lib, data: bytes):
        self.lib, self.data = lib, data  # the bytes stay alive as long as the decoder
        self.rc = lib.h_open(data, len(data) // 4)
        assert self.rc

    def close(self):
        self.lib.h_close(self.rc)

    def _check(self, status: int, err: TwError):
        if status:
            assert status == INVALID and err.status == INVALID, (status, err.message)
            assert err.message.startswith(b"corrupted .tw file: the test stream does not decode"), err.message
            raise Failed

    def histogram(self, v: np.ndarray, count: int) -> np.ndarray:
        out, err = np.zeros(count, np.uint8), TwError()
        self._check(self.lib.h_histogram(self.rc, bytes(v.astype(np.uint8)), len(v), count, _ptr(out), err), err)
        return out.astype(np.int64)

    def weights(self, w: np.ndarray, count: int) -> np.ndarray:
        w = np.ascontiguousarray(w, np.int64)
        out, err = np.zeros(count, np.uint8), TwError()
        self._check(self.lib.h_weights(self.rc, _ptr(w), len(w), count, _ptr(out), err), err)
        return out.astype(np.int64)

    def bits(self, v: int, count: int) -> np.ndarray:
        out, err = np.zeros(count, np.uint8), TwError()
        self._check(self.lib.h_bits(self.rc, v, count, _ptr(out), err), err)
        return out.astype(np.int64)

    def binary(self, v: np.ndarray) -> np.ndarray:
        v = np.ascontiguousarray(v, np.uint8)
        out, err = np.zeros(len(v), np.uint8), TwError()
        self._check(self.lib.h_binary(self.rc, _ptr(v), len(v), _ptr(out), err), err)
        return out.astype(np.int64)

    def raw(self, nbits: np.ndarray) -> np.ndarray:
        nb = np.ascontiguousarray(nbits, np.uint8)
        out, err = np.zeros(len(nb), np.uint32), TwError()
        self._check(self.lib.h_raw(self.rc, _ptr(nb), len(nb), _ptr(out), err), err)
        return out.astype(np.int64)

    def grouped(self, ctx: np.ndarray, hists: list[np.ndarray]) -> np.ndarray:
        c = np.ascontiguousarray(ctx, np.uint8)
        offsets = np.cumsum([0] + [len(h) for h in hists]).astype(np.uintp)
        blob = b"".join(bytes(h.astype(np.uint8)) for h in hists)
        out, err = np.zeros(len(c), np.uint8), TwError()
        status = self.lib.h_grouped(self.rc, _ptr(c), len(c), blob, _ptr(offsets), len(hists), _ptr(out), err)
        self._check(status, err)
        return out.astype(np.int64)

    def state(self) -> tuple[int, ...]:
        out = np.zeros(4, np.uint64)
        self.lib.h_state(self.rc, _ptr(out))
        return tuple(int(x) for x in out)


def _random_weights(rng, a: int) -> np.ndarray:
    """Integer weights >= 0 summing to 2^24 - a, some of them zero, some tiny, some dominant."""
    kind = rng.integers(3)
    if kind == 0:
        raw = rng.integers(0, 1000, a).astype(np.float64)
    elif kind == 1:
        raw = rng.exponential(1.0, a) ** 4
    else:
        raw = np.zeros(a)
        raw[rng.integers(a)] = 1.0
    raw[rng.random(a) < 0.2] = 0.0
    if raw.sum() == 0:
        raw[0] = 1.0
    free = TOTAL - a
    w = np.floor(raw / raw.sum() * free).astype(np.int64)
    w[int(np.argmax(raw))] += free - int(w.sum())
    return w


def _random_histogram(rng, a: int) -> np.ndarray:
    v = rng.integers(0, 256, a)
    if rng.random() < 0.3:
        v[rng.random(a) < 0.6] = 0
    if rng.random() < 0.2:
        v = np.zeros(a, np.int64)
        v[rng.integers(a)] = rng.integers(1, 256)
    if v.sum() == 0:
        v[rng.integers(a)] = 1
    return v


def _symbols(rng, weights: np.ndarray, count: int) -> np.ndarray:
    """Symbols drawn from the model's probabilities (w + 1) / 2^24, sometimes uniform (improbable ones too)."""
    p = (weights + 1) / TOTAL
    if rng.random() < 0.2:
        return rng.integers(0, len(weights), count)
    return rng.choice(len(weights), size=count, p=p / p.sum())


def _random_ops(rng) -> list[tuple]:
    """A batch sequence: (kind, model parameters, symbols) for each of 1..6 batches."""
    ops = []
    for _ in range(rng.integers(1, 7)):
        kind = rng.choice(["histogram", "weights", "bits", "binary", "raw", "grouped"])
        count = int(rng.integers(0, 60))
        if kind == "histogram":
            v = _random_histogram(rng, int(rng.integers(2, 256 if rng.random() < 0.1 else 34)))
            ops.append((kind, v, _symbols(rng, entropy.histogram_weights(v), count)))
        elif kind == "weights":
            w = _random_weights(rng, int(rng.integers(2, 256 if rng.random() < 0.1 else 24)))
            ops.append((kind, w, _symbols(rng, w, count)))
        elif kind == "bits":
            v = int(rng.integers(1, 256))
            ops.append((kind, v, (rng.random(count) < (v / 256 if rng.random() < 0.8 else 0.5)).astype(np.int64)))
        elif kind == "binary":
            v = rng.integers(1, 256, count)
            ops.append((kind, v, (rng.random(count) < v / 256).astype(np.int64)))
        elif kind == "raw":
            nbits = rng.integers(0, 32 if rng.random() < 0.3 else 8, count)
            values = np.array([int(rng.integers(0, 1 << int(b))) if b else 0 for b in nbits], np.int64)
            ops.append((kind, nbits, values))
        else:
            hists = [_random_histogram(rng, int(rng.integers(2, 12))) for _ in range(int(rng.integers(1, 4)))]
            ctx = rng.integers(0, len(hists), count)
            sym = np.zeros(count, np.int64)
            for c, h in enumerate(hists):
                sel = ctx == c
                sym[sel] = _symbols(rng, entropy.histogram_weights(h), int(sel.sum()))
            ops.append((kind, (ctx, hists), sym))
    return ops


def _encode(ops) -> bytes:
    w = entropy.Writer()
    for kind, model, sym in ops:
        if kind == "histogram":
            w.encode(sym, entropy.histogram_model(model))
        elif kind == "weights":
            w.encode(sym, entropy._model(model))
        elif kind == "bits":
            w.encode_bits(sym, model)
        elif kind == "binary":
            w.encode_binary(sym, entropy.binary_weight_rows(model))
        elif kind == "raw":
            w.encode_raw(sym, model)
        else:
            ctx, hists = model
            w.encode_grouped(sym, ctx, [entropy.histogram_model(h) for h in hists])
    return w.finish()


def _decode_python(data: bytes, ops) -> list:
    """Batches decoded by entropy.Reader (constriction) until the first failure (then the string 'failed')."""
    r = entropy.Reader(data, "test")
    out = []
    for kind, model, sym in ops:
        try:
            if kind == "histogram":
                got = r.decode(entropy.histogram_model(model), len(sym))
            elif kind == "weights":
                got = r.decode(entropy._model(model), len(sym))
            elif kind == "bits":
                got = r.decode_bits(len(sym), model)
            elif kind == "binary":
                got = r.decode_binary(entropy.binary_weight_rows(model))
            elif kind == "raw":
                got = r.decode_raw(model)
            else:
                ctx, hists = model
                got = r.decode_grouped(ctx, [entropy.histogram_model(h) for h in hists])
        except ContainerError:
            out.append("failed")
            break
        out.append([int(x) for x in got])
    return out


def _decode_c(lib, data: bytes, ops) -> tuple[list, list]:
    """Batches decoded by the C decoder, and its state after each batch."""
    r = CReader(lib, data)
    out, states = [], []
    try:
        for kind, model, sym in ops:
            try:
                if kind == "histogram":
                    got = r.histogram(model, len(sym))
                elif kind == "weights":
                    got = r.weights(model, len(sym))
                elif kind == "bits":
                    got = r.bits(model, len(sym))
                elif kind == "binary":
                    got = r.binary(model)
                elif kind == "raw":
                    got = r.raw(model)
                else:
                    got = r.grouped(*model)
            except Failed:
                out.append("failed")
                break
            out.append([int(x) for x in got])
            states.append(r.state())
    finally:
        r.close()
    return out, states


def _decode_spec(data: bytes, ops) -> tuple[list, list]:
    """Batches decoded by the specification's decoder, and its state after each batch."""
    d = spec.SpecRangeDecoder(data)
    out, states = [], []
    for kind, model, sym in ops:
        try:
            if kind == "histogram":
                got = d.decode_many(spec.histogram_cumulative([int(x) for x in model]), len(sym))
            elif kind == "weights":
                got = d.decode_many(spec.weights_cumulative([int(x) for x in model]), len(sym))
            elif kind == "bits":
                got = d.decode_many(spec.binary_cumulative(model), len(sym))
            elif kind == "binary":
                got = [d.decode(spec.binary_cumulative(int(v))) for v in model]
            elif kind == "raw":
                got = d.decode_raw([int(b) for b in model])
            else:
                ctx, hists = model
                got = d.decode_grouped(
                    [int(c) for c in ctx], [spec.histogram_cumulative(list(map(int, h))) for h in hists]
                )
        except spec.StreamInvalid:
            out.append("failed")
            break
        out.append(list(got))
        states.append((d.lower, d.range, d.point, min(d.next, len(d.words))))
    return out, states


def _damaged(rng, data: bytes) -> bytes:
    """The stream truncated, extended with garbage, or with a few words replaced (whole words, as in a file)."""
    words = bytearray(data)
    n = len(words) // 4
    kind = rng.integers(4)
    if kind == 0 and n:
        return bytes(words[: 4 * int(rng.integers(0, n))])
    if kind == 1:
        return bytes(words) + rng.integers(0, 256, 4 * int(rng.integers(1, 4)), dtype=np.uint8).tobytes()
    if kind == 2 and n:
        for _ in range(int(rng.integers(1, 3))):
            j = int(rng.integers(n))
            words[4 * j : 4 * j + 4] = rng.integers(0, 256, 4, dtype=np.uint8).tobytes()
        return bytes(words)
    return b"\xff" * 4 * int(rng.integers(1, 4)) + bytes(words)  # a point past every interval: step 3


def _compare(lib, data: bytes, ops, expected: list | None = None) -> bool:
    py = _decode_python(data, ops)
    c, c_states = _decode_c(lib, data, ops)
    s, s_states = _decode_spec(data, ops)
    assert c == py, "C decoder != constriction"
    assert s == py, "specification decoder != constriction"
    assert c_states == s_states, "C decoder state != specification decoder state"
    if expected is not None:
        assert py == expected
    return "failed" in py


def test_random_streams(lib):
    rng = np.random.default_rng(20260611)
    failures = 0
    for _ in range(1500):
        ops = _random_ops(rng)
        data = _encode(ops)
        _compare(lib, data, ops, [[int(x) for x in sym] for _, _, sym in ops])
        for _ in range(2):
            failures += _compare(lib, _damaged(rng, data), ops)
    assert failures > 50  # the damaged streams do reach step 3 (and agree there)


def test_empty_and_one_word_streams(lib):
    """Missing words read as 0: an empty stream, one word, two words all decode (the same symbols everywhere)."""
    rng = np.random.default_rng(5)
    ops = [("histogram", np.array([3, 0, 200, 7]), np.zeros(40, np.int64)), ("raw", np.full(10, 31), np.zeros(10))]
    for n in range(4):
        for _ in range(20):
            _compare(lib, rng.integers(0, 256, 4 * n, dtype=np.uint8).tobytes(), ops)


def test_histogram_weights_match(lib):
    """tw_model_histogram = entropy.histogram_weights (checked through decoding every quantile boundary)."""
    rng = np.random.default_rng(7)
    for _ in range(300):
        v = _random_histogram(rng, int(rng.integers(2, 256)))
        assert spec.histogram_cumulative(list(map(int, v)))[1:-1] == list(
            np.cumsum(entropy.histogram_weights(v) + 1)[:-1]
        )
        w = entropy.histogram_weights(v)
        # a stream whose first point is exactly the left end of each symbol decodes to that symbol
        for i in rng.choice(len(v), size=min(len(v), 5), replace=False):
            left = int(np.sum(w[:i])) + int(i)
            point = left * ((2**64 - 1) >> 24)
            data = struct.pack("<II", point >> 32, point & 0xFFFFFFFF)
            r = CReader(lib, data)
            try:
                assert r.histogram(v, 1)[0] == i
            finally:
                r.close()


def test_bad_models(lib):
    r = CReader(lib, b"\0" * 8)
    try:
        for v, a in (([0, 0, 0], 3), ([5], 1), ([1] * 256, 256)):
            err = TwError()
            out = np.zeros(1, np.uint8)
            assert lib.h_histogram(r.rc, bytes(v), a, 1, _ptr(out), err) == INVALID
            assert b"bad histogram model" in err.message
        for w in ([TOTAL - 1], [1, TOTAL - 2], [-1, TOTAL - 1], [TOTAL - 3, 0, 0, 0]):
            err = TwError()
            w = np.array(w, np.int64)
            assert lib.h_weights(r.rc, _ptr(w), len(w), 1, _ptr(out), err) == INVALID
        for v in (0, 256, -3):
            err = TwError()
            assert lib.h_bits(r.rc, v, 1, _ptr(out), err) == INVALID
            assert b"bad binary model" in err.message
        err = TwError()
        nb = np.array([33], np.uint8)
        raw = np.zeros(1, np.uint32)
        assert lib.h_raw(r.rc, _ptr(nb), 1, _ptr(raw), err) == 5  # TW_ERROR_ARGUMENT
    finally:
        r.close()


# -----------------------------------------------------------------------------------------------------------
# (b) sections of real files


def _v2_files() -> list[Path]:
    names = subprocess.run(["git", "ls-files", "*.tw"], cwd=REPO, capture_output=True, text=True).stdout.split()
    out = []
    for name in names:
        data = (REPO / name).read_bytes()
        if struct.unpack_from("<H", data, 8)[0] == 2:
            out.append(REPO / name)
    return out


def _sections(buf: bytes) -> dict:
    """The section bytes of a version-2 file (as unpack_v2 finds them)."""
    flags, degree = buf[10], struct.unpack_from("<b", buf, 11)[0]
    with_holes = bool(flags & 0x80)
    hsize = tw2.header_size(degree, with_holes)
    count = 3 + int(with_holes)
    sizes = struct.unpack_from(f"<{count}I", buf, hsize - 4 * count)
    starts = np.cumsum((hsize, *sizes))
    names = ["positions", "s", "c", "holes"][:count]
    return {name: buf[int(starts[i]) : int(starts[i + 1])] for i, name in enumerate(names)}


def c_s(lib, section: bytes, n: int):
    out, err = np.zeros(max(n, 1), np.int32), TwError()
    status = lib.tw_decode_s(section, len(section), n, _ptr(out), err)
    return status, out[:n].astype(np.int64), err


def c_residuals(lib, section: bytes, n: int):
    out, err = np.zeros(max(n, 1), np.int32), TwError()
    status = lib.tw_decode_s_residuals(section, len(section), n, _ptr(out), err)
    return status, out[:n].astype(np.int64), err


def c_c(lib, section: bytes, n: int, degree: int):
    q = (degree + 1) ** 2
    out, err = np.zeros(max(n * q, 1), np.int32), TwError()
    status = lib.tw_decode_c(section, len(section), n, degree, _ptr(out), err)
    return status, out[: n * q].reshape(n, q).astype(np.int64), err


def c_holes(lib, section: bytes, n: int, faces: int | None = None):
    """tw_decode_holes, or tw_decode_holes_bounded with the surface's face count `faces`."""
    ptr, count, err = ctypes.POINTER(ctypes.c_int64)(), ctypes.c_size_t(0), TwError()
    out = (ctypes.byref(ptr), ctypes.byref(count), err)
    if faces is None:
        status = lib.tw_decode_holes(section, len(section), n, *out)
    else:
        status = lib.tw_decode_holes_bounded(section, len(section), n, faces, *out)
    if status:
        assert not ptr and count.value == 0
        return status, None, err
    ranks = np.ctypeslib.as_array(ptr, shape=(count.value,)).copy()
    ctypes.CDLL(None).free(ctypes.cast(ptr, ctypes.c_void_p))
    return status, ranks, err


def _python_residuals(section: bytes, n: int) -> np.ndarray:
    models = attributes._Models(section, "s")
    hist = models.histogram(attributes.R_BUCKETS)
    return attributes._decode_signed(hist, n, entropy.Reader(section[models.pos :], "s"))


@pytest.mark.parametrize("path", _v2_files(), ids=lambda p: p.parent.name + "/" + p.name)
def test_real_file_sections(lib, path):
    buf = path.read_bytes()
    f = tw2.unpack_v2(buf)
    sec = _sections(buf)
    n = len(f.cells)
    # s: predicted in every committed file -> the residuals; the plain coding of the same symbols too
    if f.flags & 0x02:
        status, r, err = c_residuals(lib, sec["s"], n)
        assert status == OK, err.message
        assert np.array_equal(r, _python_residuals(sec["s"], n))
        assert np.array_equal(r, predict.residuals(f.cells, f.s_sym))
    else:
        status, k, err = c_s(lib, sec["s"], n)
        assert status == OK and np.array_equal(k, f.s_sym), err.message
    plain = attributes.encode_s(f.s_sym)
    status, k, err = c_s(lib, plain, n)
    assert status == OK, err.message
    assert np.array_equal(k, f.s_sym)
    # c (SH degree 1 or none)
    status, k, err = c_c(lib, sec["c"], n, f.sh_degree)
    assert status == OK, err.message
    assert np.array_equal(k, f.c_sym.reshape(n, -1))
    # holes: none is committed; a section of ranks spread over ~6 faces per point, and the file's own if any
    rng = np.random.default_rng(n)
    ranks = np.sort(rng.choice(6 * n, size=max(1, n // 50), replace=False))
    for section in [holes.encode_holes(ranks)] + ([sec["holes"]] if "holes" in sec else []):
        status, got, err = c_holes(lib, section, n)
        assert status == OK, err.message
        assert np.array_equal(got, holes.decode_holes(section, n))


def test_c_all_degrees_and_holes_extremes(lib):
    rng = np.random.default_rng(3)
    for degree in (0, 1, 2, 3):
        for n in (1, 2, 7, 300):
            q = (degree + 1) ** 2
            k = rng.integers(-(2**15), 2**15 + 1, (n, q)) >> rng.integers(0, 16, (n, q))
            section = attributes.encode_c(k, degree)
            status, got, err = c_c(lib, section, n, degree)
            assert status == OK and np.array_equal(got, k), err.message
    for n in (1, 2, 3, 4, 5, 1001):
        s = rng.integers(-(2**20), 2**20, n) >> rng.integers(0, 21, n)
        status, got, err = c_s(lib, attributes.encode_s(s), n)
        assert status == OK and np.array_equal(got, s), err.message
    for ranks in ([0], [2**32 - 1], [0, 1, 2, 3], [5, 2**31, 2**32 - 2, 2**32 - 1], list(range(0, 64 * 4, 1))):
        section = holes.encode_holes(np.array(ranks))
        status, got, err = c_holes(lib, section, 4)
        assert status == OK and np.array_equal(got, holes.decode_holes(section, 4)), err.message


def test_holes_bounded_by_the_surface(lib):
    """With the surface's F0 known, K > F0 is refused before decoding, and a rank >= F0 as geometry/holes.py does."""
    ranks = np.array([3, 4, 90, 1000])
    section = holes.encode_holes(ranks)
    for faces in (0, 1001, 5000):
        status, got, err = c_holes(lib, section, 100, faces)
        assert status == OK and np.array_equal(got, ranks), err.message
    status, _, err = c_holes(lib, section, 100, 1000)  # rank 1000 is not below F0
    assert status == INVALID and b"hole face rank 1000 but the surface has 1000 faces" in err.message
    status, _, err = c_holes(lib, section, 100, 3)  # K = 4 > F0: refused before any allocation
    assert status == INVALID and b"4 hole faces for a surface of 3 faces" in err.message
    huge = struct.pack("<I", 2**28) + bytes([2, 255, 0])  # 2^28 faces coded in no words: allowed for 2^22 points
    status, _, err = c_holes(lib, huge, 2**22, 10**6)
    assert status == INVALID and b"for a surface of 1000000 faces" in err.message


# -----------------------------------------------------------------------------------------------------------
# (c) hostile sections


def _python_outcome(fn):
    try:
        return fn()
    except ContainerError:
        return None


def _cells(rng, n: int) -> np.ndarray:
    """n distinct cells of a 64^3 grid in canonical (Morton) order."""
    cells = np.unique(rng.integers(0, 64, (3 * n, 3)), axis=0)[:n]
    return cells[quantize.canonical_order(cells)]


def _agree(lib, kind: str, section: bytes, n: int, degree: int = 1):
    """C and Python either both refuse `section` or decode the same symbols."""
    if kind == "s":
        status, got, err = c_s(lib, section, n)
        ref = _python_outcome(lambda: attributes.decode_s(section, n))
    elif kind == "r":
        status, got, err = c_residuals(lib, section, n)
        ref = _python_outcome(lambda: _python_residuals(section, n) if n else attributes._no_s(section))
    elif kind == "c":
        status, got, err = c_c(lib, section, n, degree)
        ref = _python_outcome(lambda: attributes.decode_c(section, n, degree))
    else:
        status, got, err = c_holes(lib, section, n)
        ref = _python_outcome(lambda: holes.decode_holes(section, n))
    if ref is None:
        assert status == INVALID, (kind, len(section), status)
        assert err.message.startswith((b"invalid .tw payload", b"corrupted .tw file")), err.message
    else:
        assert status == OK, (kind, err.message)
        assert np.array_equal(got, np.asarray(ref).reshape(got.shape)), kind


def test_truncated_and_damaged_sections(lib):
    rng = np.random.default_rng(11)
    n = 97
    s = rng.integers(-(2**20), 2**20, n) >> rng.integers(0, 21, n)
    c = rng.integers(-(2**15), 2**15 + 1, (n, 4)) >> rng.integers(0, 16, (n, 4))
    ranks = np.sort(rng.choice(6 * n, size=30, replace=False))
    cells = _cells(rng, n)
    sections = {
        "s": attributes.encode_s(s),
        "r": attributes.encode_s_predicted(s, cells),
        "c": attributes.encode_c(c, 1),
        "holes": holes.encode_holes(ranks),
    }
    for kind, section in sections.items():
        for cut in range(len(section) + 1):  # every prefix
            _agree(lib, kind, section[:cut], n)
        for _ in range(300):  # bytes changed anywhere, models included
            b = bytearray(section)
            for _ in range(int(rng.integers(1, 4))):
                b[int(rng.integers(len(b)))] = int(rng.integers(256))
            _agree(lib, kind, bytes(b), n)
        _agree(lib, kind, section + b"\0\0\0\0" * 3, n)  # extra words are ignored
        _agree(lib, kind, section + b"\0", n)  # not whole words


def test_hostile_counts_and_models(lib):
    # zero points / no coefficients with data
    _agree(lib, "s", b"\x80" * 12, 0)
    _agree(lib, "r", b"\x02\x01\x01\0\0\0\0", 0)
    _agree(lib, "c", b"\x02\x01\x01", 5, -1)
    _agree(lib, "c", b"", 0, 2)
    status, _, _ = c_c(lib, b"", 5, -1)
    assert status == OK
    # histogram sizes 0, 1, over the limit; all-zero histograms; sign models out of 8..248
    for a in (0, 1, 22, 255):
        _agree(lib, "s", bytes([128] * 4 + [a] + [1] * a) + b"\0" * 8, 10)
    for a in (0, 1, 24):
        _agree(lib, "r", bytes([a] + [1] * a) + b"\0" * 8, 10)
    for a in (0, 1, 18):
        _agree(lib, "c", bytes([a] + [1] * a + [2, 1, 1]) + b"\0" * 8, 10)
    _agree(lib, "s", bytes([128] * 4 + [3, 0, 0, 0]) + b"\0" * 8, 10)
    _agree(lib, "c", bytes([2, 0, 0, 2, 1, 1]) + b"\0" * 8, 10)
    for v in (7, 249, 0, 255):
        _agree(lib, "s", bytes([128, 128, v, 128, 2, 1, 1]) + b"\0" * 8, 10)
    # holes: K = 0, K above 64 max(N, 1), K = 2^32 - 1 (refused before any allocation), ranks past 2^32
    for k, n in ((0, 10), (641, 10), (640, 10), (65, 0), (64, 0), (2**32 - 1, 2**22)):
        _agree(lib, "holes", struct.pack("<I", k) + bytes([2, 255, 0]) + b"\0" * 8, n)
    # 64 gaps of bucket 32 (2^31 + rest each): the ranks pass 2^32 -> out of range
    hist = [0] * 32 + [1]
    _agree(lib, "holes", struct.pack("<I", 64) + bytes([33, *hist]) + b"\xff" * 64, 1)
    # a huge N with a tiny c section: refused (or decoded) without reading past it
    _agree(lib, "c", bytes([2, 255, 0]), 4096, 0)


ASAN_DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include "internal.h"
/* argv[1]: a file of records: kind byte, uint32 n, int8 degree, uint32 size, size bytes. Each section is copied
 * into a heap block of exactly its size so that any over-read trips AddressSanitizer. */
int main(int argc, char **argv) {
    FILE *f = fopen(argv[1], "rb");
    if (!f || argc < 2) return 2;
    unsigned char head[10];
    int records = 0;
    while (fread(head, 1, 10, f) == 10) {
        unsigned n = head[1] | head[2] << 8 | head[3] << 16 | (unsigned)head[4] << 24;
        int degree = (signed char)head[5];
        size_t size = head[6] | head[7] << 8 | head[8] << 16 | (size_t)head[9] << 24;
        unsigned char *sec = malloc(size ? size : 1);
        if (fread(sec, 1, size, f) != size) return 3;
        tw_error err = {0, ""};
        size_t q = degree >= 0 ? (size_t)(degree + 1) * (degree + 1) : 0;
        int32_t *out = malloc(((size_t)n * (q > 1 ? q : 1) + 1) * sizeof(int32_t));
        int64_t *ranks = NULL;
        size_t count = 0;
        if (head[0] == 's') tw_decode_s(sec, size, n, out, &err);
        if (head[0] == 'r') tw_decode_s_residuals(sec, size, n, out, &err);
        if (head[0] == 'c') tw_decode_c(sec, size, n, degree, out, &err);
        if (head[0] == 'h') tw_decode_holes(sec, size, n, &ranks, &count, &err);
        free(ranks);
        free(out);
        free(sec);
        records++;
    }
    printf("%d\n", records);
    return 0;
}
"""


def test_hostile_sections_under_sanitizers(tmp_path):
    """The damaged sections of the tests above, decoded by a build with AddressSanitizer + UBSan: no report."""
    cc = compiler()
    if cc is None:
        pytest.skip("no C compiler")
    driver = tmp_path / "driver.c"
    driver.write_text(ASAN_DRIVER)
    exe = tmp_path / "driver"
    flags = [f for f in FLAGS if f not in ("-fPIC", "-shared")]
    cmd = [cc, *flags, "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all", f"-I{CORE}", "-o", str(exe)]
    cmd += [str(driver), *(str(CORE / name) for name in ("common.c", "range.c", "attributes.c", "holes_section.c"))]
    built = subprocess.run(cmd, capture_output=True, text=True)
    if built.returncode:
        pytest.skip(f"no sanitizer build here: {built.stderr.strip().splitlines()[-1:]}")
    rng = np.random.default_rng(13)
    n = 61
    s = rng.integers(-(2**20), 2**20, n) >> rng.integers(0, 21, n)
    c = rng.integers(-(2**15), 2**15 + 1, (n, 9)) >> rng.integers(0, 16, (n, 9))
    cells = _cells(rng, n)
    base = {
        b"s": attributes.encode_s(s),
        b"r": attributes.encode_s_predicted(s, cells),
        b"c": attributes.encode_c(c, 2),
        b"h": holes.encode_holes(np.sort(rng.choice(6 * n, size=25, replace=False))),
    }
    records = []
    for kind, section in base.items():
        variants = [section[:cut] for cut in range(len(section) + 1)]
        for _ in range(200):
            b = bytearray(section)
            for _ in range(int(rng.integers(1, 5))):
                b[int(rng.integers(len(b)))] = int(rng.integers(256))
            variants.append(bytes(b))
        for v in variants:
            for count in (n, 0, 1, 5000):
                records.append(kind + struct.pack("<IbI", count, 2, len(v)) + v)
    records.append(b"h" + struct.pack("<IbI", 2**22, 0, 7) + struct.pack("<I", 2**32 - 1) + bytes([2, 255, 0]))
    corpus = tmp_path / "corpus"
    corpus.write_bytes(b"".join(records))
    run = subprocess.run([str(exe), str(corpus)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert int(run.stdout) == len(records)
