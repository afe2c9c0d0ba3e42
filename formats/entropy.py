"""Entropy coding for `.tw` version 2: constriction's range coder with exact integer models.

Coder: ``constriction.stream.queue.RangeEncoder`` / ``RangeDecoder`` (constriction >= 0.4, its default preset:
32-bit words, 64-bit state, 24-bit probability precision). A stream is the coder's compressed words, written as
little-endian uint32. Symbols are decoded in the order they were encoded (a queue, not a stack).

Models: every model is a categorical distribution given by **integer weights** ``w_i >= 0`` with
``sum(w) = 2**24 - A`` (A = alphabet size >= 2); symbol ``i`` has the fixed-point probability
``(w_i + 1) / 2**24`` and left cumulative ``sum(w_j, j < i) + i``. These weights are handed to constriction as
float64 values (``Categorical(weights, perfect=False)``); integers below 2**24 are exact in float64 and the
normalization of constriction's fast quantizer is then exactly 1, so the fixed-point model *is* the integer one
(see formats/README.md, "Models"). No floating-point arithmetic of ours enters a model.

Two model kinds are built from the bytes stored in a file:

* `binary_model(v)`: one byte ``v`` in 1..255, ``P(1) = v / 256``: ``w = ((256 - v) * 2**16 - 1, v * 2**16 - 1)``.
* `histogram_model(v)`: A bytes ``v_i`` (0..255, not all 0), ``w_i = floor(v_i * (2**24 - A) / V)`` with
  ``V = sum(v)``; the remainder ``2**24 - A - sum(w)`` goes to the first symbol of largest ``v_i``.

Contexts: `encode_grouped` / `decode_grouped` code a batch whose per-symbol context is known to both sides before
the batch: the symbols of context 0 first (in batch order), then those of context 1, and so on.
`encode_binary` / `decode_binary` code a batch of bits in batch order, each with its own binary model (rows of
`binary_weight_rows`, e.g. the model of each bit's context): constriction's `Categorical(perfect=False)` with
one row of weights per symbol, which quantizes each row exactly like the fixed model of the same weights
(tests/test_bitstream.py compares the words).
Every call of constriction codes an array, never a Python loop over symbols.

Untrusted input: `Reader` wraps the decoder so that every failure (exceptions and Rust panics of constriction)
becomes ContainerError; decoding reads at most the words it was given (constriction pads missing words with
zeros), so a hostile stream can only produce wrong symbols, which the callers validate.
"""

from __future__ import annotations

import constriction
import numpy as np

from tetweave_codec.errors import ContainerError

PRECISION = 24
TOTAL = 1 << PRECISION
_CATEGORICAL = constriction.stream.model.Categorical
HALF = None  # the model of a fair bit, built lazily


def _model(weights: np.ndarray):
    return _CATEGORICAL(weights.astype(np.float64), perfect=False)


def histogram_weights(v) -> np.ndarray:
    """Integer weights (A,) int64 of a stored uint8 histogram ``v`` (see module docstring)."""
    v = np.asarray(v, dtype=np.int64).reshape(-1)
    a = len(v)
    total = int(v.sum())
    if a < 2 or a > 255 or total <= 0 or v.min() < 0 or v.max() > 255:
        raise ContainerError("invalid .tw payload: bad histogram model")
    free = TOTAL - a
    w = (v * free) // total
    w[int(np.argmax(v))] += free - int(w.sum())
    return w


def histogram_model(v):
    """constriction model of a stored uint8 histogram (A >= 2 entries)."""
    return _model(histogram_weights(v))


def binary_weights(v: int) -> np.ndarray:
    """Integer weights (2,) int64 of the binary model of byte v (1..255)."""
    return binary_weight_rows([v])[0].astype(np.int64)


def binary_weight_rows(v) -> np.ndarray:
    """Weights (n, 2) float64 of the binary models of bytes ``v`` (n,) in 1..255 (as `binary_weights`, per row)."""
    v = np.asarray(v, dtype=np.int64).reshape(-1)
    if v.size and (v.min() < 1 or v.max() > 255):
        raise ContainerError("invalid .tw payload: bad binary model")
    return np.stack([(256 - v) * 65536 - 1, v * 65536 - 1], axis=1).astype(np.float64)


_PER_SYMBOL = None  # constriction's categorical family with per-symbol weights, built lazily


def _per_symbol():
    global _PER_SYMBOL
    if _PER_SYMBOL is None:
        _PER_SYMBOL = _CATEGORICAL(perfect=False)
    return _PER_SYMBOL


def binary_model(v: int):
    """constriction model of a bit with ``P(1) = v / 256`` (v in 1..255)."""
    return _model(binary_weights(v))


def fair_bit():
    global HALF
    if HALF is None:
        HALF = binary_model(128)
    return HALF


def model_bits(symbols: np.ndarray, weights: np.ndarray) -> float:
    """Ideal code length in bits of `symbols` under integer weights (for measurements and tests)."""
    p = (weights[np.asarray(symbols, dtype=np.int64)] + 1) / TOTAL
    return float(-np.log2(p).sum())


# -----------------------------------------------------------------------------------------------------------
# choosing stored models from data (encoder side only: need not be exact or documented)


def fit_histogram(symbols: np.ndarray, alphabet: int) -> np.ndarray:
    """uint8 histogram (alphabet,) for `symbols`: counts scaled so the largest is 255, nonzero counts >= 1."""
    counts = np.bincount(np.asarray(symbols, dtype=np.int64), minlength=alphabet)[:alphabet].astype(np.float64)
    if counts.sum() == 0:
        counts[0] = 1.0
    v = np.where(counts > 0, np.maximum(1.0, np.round(255.0 * counts / counts.max())), 0.0)
    best = _refine_histogram(counts, v.astype(np.int64))
    return best.astype(np.uint8)


def _refine_histogram(counts: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A few greedy +-1 tweaks of the stored bytes that lower the actual code length (cheap, encoder only)."""
    if len(v) < 2:
        return v

    def cost(vv):
        if vv.sum() <= 0:
            return np.inf
        w = histogram_weights(vv)
        return float(-(counts * np.log2((w + 1) / TOTAL)).sum())

    best = cost(v)
    for _ in range(2):
        improved = False
        for i in np.flatnonzero(counts):
            for d in (-1, 1):
                t = v.copy()
                t[i] = min(255, max(1, t[i] + d))
                c = cost(t)
                if c < best - 1e-9:
                    best, v, improved = c, t, True
        if not improved:
            break
    return v


def fit_binary(bits: np.ndarray) -> int:
    """Stored byte v (1..255) for P(1) = v / 256 that minimizes the code length of `bits`."""
    bits = np.asarray(bits)
    n1 = int(bits.sum())
    n0 = int(bits.size) - n1
    v = np.arange(1, 256)
    cost = -(n1 * np.log2(v / 256.0) + n0 * np.log2(1.0 - v / 256.0))
    return int(v[int(np.argmin(cost))])


# -----------------------------------------------------------------------------------------------------------
# coders


class Writer:
    """Range encoder of one stream."""

    def __init__(self):
        self._enc = constriction.stream.queue.RangeEncoder()

    def encode(self, symbols, model) -> None:
        sym = np.ascontiguousarray(symbols, dtype=np.int32).reshape(-1)
        if sym.size:
            self._enc.encode(sym, model)

    def encode_bits(self, bits, v: int) -> None:
        self.encode(bits, binary_model(v) if v != 128 else fair_bit())

    def encode_binary(self, bits, rows: np.ndarray) -> None:
        """Bits (n,) in batch order, bit j with the binary model of weights ``rows[j]`` (`binary_weight_rows`)."""
        bits = np.ascontiguousarray(bits, dtype=np.int32).reshape(-1)
        if bits.size:
            self._enc.encode(bits, _per_symbol(), rows)

    def encode_raw(self, values, nbits) -> None:
        """Raw bits of `values`, bit planes from the most significant (each value has its own bit count)."""
        values = np.asarray(values, dtype=np.int64)
        nbits = np.asarray(nbits, dtype=np.int64)
        if not values.size:
            return
        for plane in range(int(nbits.max()) - 1, -1, -1):
            sel = nbits > plane
            self.encode((values[sel] >> plane) & 1, fair_bit())

    def encode_grouped(self, symbols, ctx, models) -> None:
        symbols = np.asarray(symbols)
        ctx = np.asarray(ctx, dtype=np.int64)
        for c, model in enumerate(models):
            sel = ctx == c
            if sel.any():
                self.encode(symbols[sel], model)

    def finish(self) -> bytes:
        return self._enc.get_compressed().astype("<u4").tobytes()


class Reader:
    """Range decoder of one stream; every failure becomes ContainerError."""

    def __init__(self, data: bytes, what: str):
        if len(data) % 4:
            raise ContainerError(f"invalid .tw payload: {what} stream is not a whole number of 32-bit words")
        self.what = what
        words = np.frombuffer(data, dtype="<u4").astype(np.uint32)
        try:
            self._dec = constriction.stream.queue.RangeDecoder(words)
        except BaseException as exc:  # noqa: B036 -- constriction panics derive from BaseException
            _reraise(exc, what)

    def decode(self, model, count: int) -> np.ndarray:
        if count <= 0:
            return np.zeros(0, dtype=np.int64)
        try:
            out = self._dec.decode(model, int(count))
        except BaseException as exc:  # noqa: B036
            _reraise(exc, self.what)
        return np.asarray(out, dtype=np.int64)

    def decode_bits(self, count: int, v: int) -> np.ndarray:
        return self.decode(binary_model(v) if v != 128 else fair_bit(), count)

    def decode_binary(self, rows: np.ndarray) -> np.ndarray:
        """Bits (n,) int64 coded by `Writer.encode_binary` with the weights ``rows`` (n, 2)."""
        if not len(rows):
            return np.zeros(0, dtype=np.int64)
        try:
            out = self._dec.decode(_per_symbol(), rows)
        except BaseException as exc:  # noqa: B036
            _reraise(exc, self.what)
        return np.asarray(out, dtype=np.int64)

    def decode_raw(self, nbits) -> np.ndarray:
        nbits = np.asarray(nbits, dtype=np.int64)
        values = np.zeros(nbits.shape, dtype=np.int64)
        if not nbits.size:
            return values
        for plane in range(int(nbits.max()) - 1, -1, -1):
            sel = nbits > plane
            values[sel] = (values[sel] << 1) | self.decode(fair_bit(), int(sel.sum()))
        return values

    def decode_grouped(self, ctx, models) -> np.ndarray:
        ctx = np.asarray(ctx, dtype=np.int64)
        out = np.zeros(ctx.shape, dtype=np.int64)
        for c, model in enumerate(models):
            sel = ctx == c
            count = int(sel.sum())
            if count:
                out[sel] = self.decode(model, count)
        return out


def _reraise(exc: BaseException, what: str):
    if isinstance(exc, (KeyboardInterrupt, SystemExit, GeneratorExit)):
        raise exc
    if isinstance(exc, ContainerError):
        raise exc
    raise ContainerError(f"corrupted .tw file: the {what} stream does not decode ({type(exc).__name__})") from None
