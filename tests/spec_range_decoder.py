"""A range decoder written only from formats/README.md ("Entropy coder": "Range decoder", "Models").

Pure Python integers, no numpy and no constriction: tests/test_core_range.py checks it against constriction's
decoder on random streams, which shows that the specification alone is enough to decode the format's streams.
"""

from __future__ import annotations

MASK = (1 << 64) - 1
PRECISION = 24
TOTAL = 1 << PRECISION


class StreamInvalid(Exception):
    """Step 3 of the specification: x >= 2^24 (no encoder writes such a stream)."""


def weights_cumulative(w: list[int]) -> list[int]:
    """c_0 .. c_A of integer weights w (A >= 2, each >= 0, sum 2^24 - A): c_i = sum(w_j, j < i) + i."""
    a = len(w)
    if not 2 <= a <= 255 or min(w) < 0 or sum(w) != TOTAL - a:
        raise ValueError("bad model")
    c = [0]
    for wi in w:
        c.append(c[-1] + wi + 1)
    assert c[a] == TOTAL and c[0] == 0 and all(c[i] == sum(w[:i]) + i for i in range(a))
    return c


def binary_cumulative(v: int) -> list[int]:
    """Binary model of byte v (1..255): w = ((256 - v) * 2^16 - 1, v * 2^16 - 1)."""
    if not 1 <= v <= 255:
        raise ValueError("bad binary model")
    return weights_cumulative([(256 - v) * 65536 - 1, v * 65536 - 1])


def histogram_cumulative(v: list[int]) -> list[int]:
    """Histogram model of bytes v: w_i = floor(v_i (2^24 - A) / V), remainder to the first largest v_i."""
    a = len(v)
    total = sum(v)
    if not 2 <= a <= 255 or total <= 0 or min(v) < 0 or max(v) > 255:
        raise ValueError("bad histogram model")
    free = TOTAL - a
    w = [vi * free // total for vi in v]
    w[v.index(max(v))] += free - sum(w)
    return weights_cumulative(w)


FAIR = binary_cumulative(128)


class SpecRangeDecoder:
    """State lower, range, point and next over little-endian uint32 words; words past the end read as 0."""

    def __init__(self, data: bytes):
        if len(data) % 4:
            raise ValueError("not a whole number of 32-bit words")
        self.words = [int.from_bytes(data[i : i + 4], "little") for i in range(0, len(data), 4)]
        self.lower = 0
        self.range = MASK  # 2^64 - 1
        self.point = (self._word(0) << 32) + self._word(1)
        self.next = 2

    def _word(self, j: int) -> int:
        return self.words[j] if j < len(self.words) else 0

    def decode(self, c: list[int]) -> int:
        assert self.range >= 1 << 32  # the specification's claim: range >= 2^32 before every symbol
        scale = self.range >> PRECISION  # step 1
        x = ((self.point - self.lower) & MASK) // scale  # step 2
        if x >= TOTAL:  # step 3
            raise StreamInvalid
        i = 0  # step 4: c_i <= x < c_{i+1}
        while c[i + 1] <= x:
            i += 1
        self.lower = (self.lower + scale * c[i]) & MASK  # step 5
        self.range = scale * (c[i + 1] - c[i])
        assert self.range <= MASK
        if self.range < 1 << 32:  # step 6
            self.lower = (self.lower << 32) & MASK
            self.range = self.range << 32
            self.point = ((self.point << 32) + self._word(self.next)) & MASK
            self.next += 1
        assert (self.point - self.lower) & MASK < self.range  # the claim behind step 3
        return i

    def decode_many(self, c: list[int], count: int) -> list[int]:
        return [self.decode(c) for _ in range(count)]

    def decode_raw(self, nbits: list[int]) -> list[int]:
        """Raw bits by plane: plane p = max(b) - 1 .. 0, bit p of every value with b_i > p, in order."""
        values = [0] * len(nbits)
        for p in range(max(nbits, default=0) - 1, -1, -1):
            for i, b in enumerate(nbits):
                if b > p:
                    values[i] = (values[i] << 1) | self.decode(FAIR)
        return values

    def decode_grouped(self, ctx: list[int], models: list[list[int]]) -> list[int]:
        """Symbols with context 0 first (batch order), then context 1, ...; others stay 0."""
        out = [0] * len(ctx)
        for k, c in enumerate(models):
            for i, x in enumerate(ctx):
                if x == k:
                    out[i] = self.decode(c)
        return out
