"""Entropy coding of the per-point symbols of `.tw` version 2: s (base signed distance) and c (SH coefficients).

Both streams code points in canonical order (the octree decoder's leaf order). Layouts and models are specified in
formats/README.md ("s stream", "c stream"); the short version:

s stream -- models: 4 sign bytes, then a histogram (1 length byte A, A bytes) of magnitude buckets.

1. signs ``t_i = 1 if k_i < 0`` (inside), two passes: even indices i = 0, 2, 4, ... with binary model ``v_even``;
   then odd indices with context ``t_{i-1} + t_{i+1}`` (``2 * t_{i-1}`` for the last index when N is even),
   grouped by context 0, 1, 2 with binary models ``v_odd[ctx]``. Sign model bytes are in 8..248.
2. magnitudes ``m = k`` (k >= 0) or ``-k - 1`` (k < 0), as bucket ``e = bit_length(m)`` (0..20) with the
   histogram model, all points in order;
3. the ``e - 1`` bits of ``m - 2**(e - 1)`` below the leading one (points with e >= 2) as fair bits, bit planes
   from the most significant: plane p codes bit p of every point with ``e - 1 > p``, in point order.

s stream with prediction (flag bit 1 of the header; formats/predict.py) -- models: one histogram (A, A bytes) of
residual buckets. The residuals ``r = k - prediction`` of all points in order:

1. bucket ``e = bit_length(|r|)`` (0..22) with the histogram model;
2. the sign of each nonzero residual as a fair bit (1 = negative);
3. the raw bits below the leading one, bit planes as above.

c stream -- models: one histogram (A, A bytes) per SH band l = 0..d. For each band, the symbols of the band's
coefficients in coefficient-major order (all points of coefficient l*l, then l*l + 1, ...):

1. bucket ``e = bit_length(|k|)`` (0..16) of each symbol with the band's histogram model;
2. the sign of each nonzero symbol as a fair bit (1 = negative);
3. the raw bits below the leading one as for s.
"""

from __future__ import annotations

import numpy as np

from tetweave_codec.errors import ContainerError
from tetweave_codec.geometry.sh import num_coeffs

from . import entropy, predict
from .quantize import C_SYMBOL_LIMIT, S_SYMBOL_LIMIT

S_BUCKETS = 21  # bit_length(m) for m < 2**20
R_BUCKETS = 23  # bit_length(|r|) for residuals |r| < 2**21 + 1 (both symbols in [-2**20, 2**20))
C_BUCKETS = 17  # bit_length(|k|) for |k| <= 2**15
SIGN_MODEL_MIN, SIGN_MODEL_MAX = 8, 248


def bit_length(m: np.ndarray) -> np.ndarray:
    """Number of bits of each non-negative int64 (0 for 0), exactly (integer arithmetic)."""
    m = np.asarray(m, dtype=np.int64)
    if m.size and (m.min() < 0 or m.max() >= 2**53):
        raise ValueError("bit_length needs values in [0, 2**53)")
    return np.frexp(m.astype(np.float64))[1].astype(np.int64)  # exact: m = f * 2**e, 0.5 <= f < 1


def _raw_bits(m: np.ndarray, e: np.ndarray):
    nbits = np.maximum(e - 1, 0)
    rest = np.where(e >= 1, m - np.left_shift(np.int64(1), np.maximum(e - 1, 0)), 0)
    return rest, nbits


def _from_raw(rest: np.ndarray, e: np.ndarray) -> np.ndarray:
    return np.where(e >= 1, np.left_shift(np.int64(1), np.maximum(e - 1, 0)) + rest, 0)


def _sign_contexts(t_even: np.ndarray, n: int) -> np.ndarray:
    """Context of every odd index from the signs of the even indices (see module docstring)."""
    n_odd = n // 2
    left = t_even[:n_odd]
    right = t_even[1 : n_odd + 1]
    if len(right) < n_odd:  # N even: the last odd index has no right neighbour
        right = np.append(right, left[-1:])
    return left + right


def _histogram_bytes(hist: np.ndarray) -> bytes:
    return bytes([len(hist)]) + hist.astype(np.uint8).tobytes()


def _fit_trimmed(symbols: np.ndarray, alphabet: int) -> np.ndarray:
    top = max(int(symbols.max()) + 1 if symbols.size else 1, 2)
    return entropy.fit_histogram(symbols, min(top, alphabet))


class _Models:
    """Cursor over the model bytes of a stream (raises ContainerError when they run out or are invalid)."""

    def __init__(self, data: bytes, what: str):
        self.data, self.pos, self.what = data, 0, what

    def take(self, count: int) -> np.ndarray:
        if self.pos + count > len(self.data):
            raise ContainerError(f"invalid .tw payload: the {self.what} models are truncated")
        out = np.frombuffer(self.data, dtype=np.uint8, count=count, offset=self.pos).astype(np.int64)
        self.pos += count
        return out

    def histogram(self, max_alphabet: int) -> np.ndarray:
        (a,) = self.take(1)
        if not 2 <= a <= max_alphabet:
            raise ContainerError(f"invalid .tw payload: bad {self.what} histogram size {a}")
        return self.take(int(a))


def model_size_s(data: bytes) -> int:
    """Byte size of the model part at the start of an s section (ContainerError if it does not fit)."""
    if len(data) < 5:
        raise ContainerError("invalid .tw payload: the s models are truncated")
    return 5 + data[4]


def model_size_c(data: bytes, sh_degree: int) -> int:
    pos = 0
    for _ in range(sh_degree + 1):
        if pos >= len(data):
            raise ContainerError("invalid .tw payload: the c models are truncated")
        pos += 1 + data[pos]
    return pos


# -----------------------------------------------------------------------------------------------------------
# s


def _s_symbols(s_sym: np.ndarray) -> np.ndarray:
    """s symbols as int64, ValueError outside [-S_SYMBOL_LIMIT, S_SYMBOL_LIMIT)."""
    k = np.asarray(s_sym, dtype=np.int64)
    if k.size and (k.min() < -S_SYMBOL_LIMIT or k.max() > S_SYMBOL_LIMIT - 1):
        raise ValueError(f"s symbols must lie in [{-S_SYMBOL_LIMIT}, {S_SYMBOL_LIMIT - 1}]")
    return k


def _no_s(section: bytes) -> np.ndarray:
    """The s symbols of zero points (a non-empty section is invalid)."""
    if section:
        raise ContainerError("invalid .tw payload: s data for zero points")
    return np.zeros(0, dtype=np.int64)


def encode_s(s_sym: np.ndarray) -> bytes:
    """s section (models + coded words) for symbols in canonical order; empty for N = 0."""
    k = _s_symbols(s_sym)
    n = len(k)
    if n == 0:
        return b""
    t = (k < 0).astype(np.int64)
    t_even, t_odd = t[0::2], t[1::2]
    ctx = _sign_contexts(t_even, n)
    sign_models = [entropy.fit_binary(t_even)] + [entropy.fit_binary(t_odd[ctx == c]) for c in range(3)]
    sign_models = [min(SIGN_MODEL_MAX, max(SIGN_MODEL_MIN, v)) for v in sign_models]
    m = np.where(k < 0, -k - 1, k)
    e = bit_length(m)
    hist = _fit_trimmed(e, S_BUCKETS)
    w = entropy.Writer()
    w.encode_bits(t_even, sign_models[0])
    w.encode_grouped(t_odd, ctx, [entropy.binary_model(v) for v in sign_models[1:]])
    w.encode(e, entropy.histogram_model(hist))
    w.encode_raw(*_raw_bits(m, e))
    return bytes(sign_models) + _histogram_bytes(hist) + w.finish()


def decode_s(section: bytes, n: int) -> np.ndarray:
    if n == 0:
        return _no_s(section)
    models = _Models(section, "s")
    sign_models = models.take(4)
    if sign_models.min() < SIGN_MODEL_MIN or sign_models.max() > SIGN_MODEL_MAX:
        raise ContainerError("invalid .tw payload: bad s sign model")
    hist = models.histogram(S_BUCKETS)
    r = entropy.Reader(section[models.pos :], "s")
    t_even = r.decode_bits((n + 1) // 2, int(sign_models[0]))
    ctx = _sign_contexts(t_even, n)
    t_odd = r.decode_grouped(ctx, [entropy.binary_model(int(v)) for v in sign_models[1:]])
    e = r.decode(entropy.histogram_model(hist), n)
    rest = r.decode_raw(np.maximum(e - 1, 0))
    m = _from_raw(rest, e)
    t = np.empty(n, dtype=np.int64)
    t[0::2], t[1::2] = t_even, t_odd
    if m.max() > S_SYMBOL_LIMIT - 1:  # cannot happen with <= 21 buckets; kept as a guard
        raise ContainerError("invalid .tw payload: s symbol out of range")
    return np.where(t == 1, -m - 1, m)


def _encode_signed(v: np.ndarray, alphabet: int, w: entropy.Writer) -> bytes:
    """Bucket (histogram model, returned as model bytes), sign of nonzero values (fair), raw bits of signed ints."""
    m = np.abs(v)
    e = bit_length(m)
    hist = _fit_trimmed(e, alphabet)
    w.encode(e, entropy.histogram_model(hist))
    w.encode((v[m > 0] < 0).astype(np.int64), entropy.fair_bit())
    w.encode_raw(*_raw_bits(m, e))
    return _histogram_bytes(hist)


def _decode_signed(hist: np.ndarray, count: int, r: entropy.Reader) -> np.ndarray:
    e = r.decode(entropy.histogram_model(hist), count)
    nonzero = e > 0
    neg = r.decode(entropy.fair_bit(), int(nonzero.sum()))
    m = _from_raw(r.decode_raw(np.maximum(e - 1, 0)), e)
    sign = np.ones(len(m), dtype=np.int64)
    sign[np.flatnonzero(nonzero)[neg == 1]] = -1
    return sign * m


def encode_s_predicted(s_sym: np.ndarray, cells: np.ndarray) -> bytes:
    """s section coded as residuals of the neighbour prediction (flag bit 1); cells (N,3) in canonical order."""
    k = _s_symbols(s_sym)
    if len(k) == 0:
        return b""
    w = entropy.Writer()
    models = _encode_signed(predict.residuals(cells, k), R_BUCKETS, w)
    return models + w.finish()


def decode_s_predicted(section: bytes, cells: np.ndarray) -> np.ndarray:
    n = len(cells)
    if n == 0:
        return _no_s(section)
    models = _Models(section, "s")
    hist = models.histogram(R_BUCKETS)
    r = entropy.Reader(section[models.pos :], "s")
    k = predict.reconstruct(cells, _decode_signed(hist, n, r))
    if k.min() < -S_SYMBOL_LIMIT or k.max() > S_SYMBOL_LIMIT - 1:
        raise ContainerError("invalid .tw payload: s symbol out of range")
    return k


# -----------------------------------------------------------------------------------------------------------
# c


def _bands(sh_degree: int):
    return [(l * l, (l + 1) * (l + 1)) for l in range(sh_degree + 1)]


def encode_c(c_sym: np.ndarray, sh_degree: int) -> bytes:
    """c section for (N, q) symbols in canonical order; empty when N = 0 or q = 0."""
    k = np.asarray(c_sym, dtype=np.int64)
    if k.size == 0:
        return b""
    if np.abs(k).max() > C_SYMBOL_LIMIT:
        raise ValueError(f"c symbols must lie in [{-C_SYMBOL_LIMIT}, {C_SYMBOL_LIMIT}]")
    models = bytearray()
    w = entropy.Writer()
    for j0, j1 in _bands(sh_degree):
        models += _encode_signed(k[:, j0:j1].T.reshape(-1), C_BUCKETS, w)  # coefficient-major
    return bytes(models) + w.finish()


def decode_c(section: bytes, n: int, sh_degree: int) -> np.ndarray:
    q = num_coeffs(sh_degree)
    if n == 0 or q == 0:
        if section:
            raise ContainerError("invalid .tw payload: c data without coefficients")
        return np.zeros((n, q), dtype=np.int64)
    models = _Models(section, "c")
    hists = [models.histogram(C_BUCKETS) for _ in range(sh_degree + 1)]
    r = entropy.Reader(section[models.pos :], "c")
    out = np.empty((n, q), dtype=np.int64)
    for (j0, j1), hist in zip(_bands(sh_degree), hists, strict=True):
        v = _decode_signed(hist, n * (j1 - j0), r)
        if np.abs(v).max() > C_SYMBOL_LIMIT:
            raise ContainerError("invalid .tw payload: c symbol out of range")
        out[:, j0:j1] = v.reshape(j1 - j0, n).T
    return out
