"""Lossless octree coding of quantized positions for `.tw` version 2.

The unique cells ``[0, 2**b)**3`` of a point set are the leaves of a depth-b octree. Traversal is breadth first:
level L = 0 (the root, one node) .. b - 1; each node of level L has an 8-bit occupancy code whose bit
``i = (bx << 2) | (by << 1) | bz`` says whether its child with the next bits (bx, by, bz) of x, y, z is occupied.
Nodes of a level are visited in ascending Morton order (children in ascending child index), so the leaves come
out in the canonical order of `formats.quantize.canonical_order`.

Each occupancy code is coded as two symbols (per level, all nodes of the level in one batch each):

1. its population count ``k`` (1..8) as the symbol ``k - 1`` with the level's stored histogram model (8 bytes);
2. its rank among the ``C(8, k)`` codes with k bits set, in ascending numeric order, with the uniform model over
   ``C(8, k)`` symbols (nothing for k = 8). Ranks are coded grouped by k = 1..7 (all nodes with k = 1 in
   level order, then k = 2, ...).

Measured on fitted files (formats/README.md, "Design measurements"), neighbour-count contexts did not pay for
their stored models, so there are none.
"""

from __future__ import annotations

from math import comb

import numpy as np

from tetweave_codec.errors import ContainerError

from . import entropy
from .quantize import check_bits, morton_keys

POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.int64)
# PATTERNS[k]: the occupancy codes with k bits set, ascending; RANK[code]: index of code in PATTERNS[popcount]
PATTERNS = [np.array([c for c in range(256) if POPCOUNT[c] == k], dtype=np.int64) for k in range(9)]
RANK = np.zeros(256, dtype=np.int64)
for _k in range(9):
    RANK[PATTERNS[_k]] = np.arange(len(PATTERNS[_k]))
MODEL_BYTES_PER_LEVEL = 8
_UNIFORM = {}


def uniform_model(size: int):
    """Uniform model over `size` >= 2 symbols: the histogram model of `size` equal bytes."""
    if size not in _UNIFORM:
        _UNIFORM[size] = entropy.histogram_model(np.ones(size, dtype=np.int64))
    return _UNIFORM[size]


def _levels(cells: np.ndarray, bits: int):
    """Occupancy codes per level (list of int64 arrays, nodes in Morton order)."""
    keys = morton_keys(cells).astype(np.int64)
    out = []
    for level in range(bits):
        child_keys = keys >> (3 * (bits - level - 1))
        parent = child_keys >> 3
        child = child_keys & 7
        start = np.ones(len(parent), dtype=bool)
        start[1:] = parent[1:] != parent[:-1]
        node = np.cumsum(start) - 1
        occ = np.zeros(int(node[-1]) + 1, dtype=np.int64)
        np.bitwise_or.at(occ, node, np.int64(1) << child)
        out.append(occ)
    return out


def encode(cells: np.ndarray, bits: int) -> tuple[bytes, bytes]:
    """Code unique cells given in canonical order. Returns (model bytes: bits x 8, coded words)."""
    bits = check_bits(bits)
    cells = np.asarray(cells, dtype=np.int64)
    if len(cells) == 0:
        return b"", b""
    keys = morton_keys(cells)
    if np.any(keys[1:] <= keys[:-1]):
        raise ValueError("cells must be unique and in canonical order (see quantize.merge_collisions)")
    levels = _levels(cells, bits)
    models = bytearray()
    writer = entropy.Writer()
    for occ in levels:
        pop = POPCOUNT[occ]
        hist = entropy.fit_histogram(pop - 1, 8)
        models += hist.tobytes()
        writer.encode(pop - 1, entropy.histogram_model(hist))
        rank = RANK[occ]
        for k in range(1, 8):
            sel = pop == k
            if sel.any():
                writer.encode(rank[sel], uniform_model(comb(8, k)))
    return bytes(models), writer.finish()


def decode(models: bytes, words: bytes, bits: int, num_points: int) -> np.ndarray:
    """Decode (N, 3) int64 cells in canonical order; raises ContainerError if the stream does not yield N leaves."""
    bits = check_bits(bits)
    if num_points == 0:
        return np.zeros((0, 3), dtype=np.int64)
    if len(models) != bits * MODEL_BYTES_PER_LEVEL:
        raise ContainerError("invalid .tw payload: wrong size of the position models")
    reader = entropy.Reader(words, "positions")
    table = np.frombuffer(models, dtype=np.uint8).reshape(bits, MODEL_BYTES_PER_LEVEL)
    keys = np.zeros(1, dtype=np.int64)  # Morton keys of the nodes of the current level
    for level in range(bits):
        n = len(keys)
        pop = reader.decode(entropy.histogram_model(table[level]), n) + 1
        total = int(pop.sum())
        if total > num_points:
            raise ContainerError(f"corrupted .tw file: the octree has more than {num_points} points")
        occ = np.full(n, 255, dtype=np.int64)
        for k in range(1, 8):
            sel = pop == k
            count = int(sel.sum())
            if count:
                occ[sel] = PATTERNS[k][reader.decode(uniform_model(comb(8, k)), count)]
        flags = np.unpackbits(occ.astype(np.uint8)[:, None], axis=1, bitorder="little").astype(bool)
        keys = ((keys[:, None] << 3) | np.arange(8, dtype=np.int64))[flags]
    if len(keys) != num_points:
        raise ContainerError(f"corrupted .tw file: the octree has {len(keys)} points, the header says {num_points}")
    return _cells_from_keys(keys, bits)


def _compact3(v: np.ndarray) -> np.ndarray:
    v = v & 0x9249249249249249
    v = (v | (v >> 2)) & 0x30C30C30C30C30C3
    v = (v | (v >> 4)) & 0xF00F00F00F00F00F
    v = (v | (v >> 8)) & 0x00FF0000FF0000FF
    v = (v | (v >> 16)) & 0x0000FFFF0000FFFF
    return v & 0xFFFF


def _cells_from_keys(keys: np.ndarray, bits: int) -> np.ndarray:
    k = keys.astype(np.uint64)
    out = np.empty((len(keys), 3), dtype=np.int64)
    for axis, shift in ((0, 2), (1, 1), (2, 0)):
        out[:, axis] = _compact3(k >> np.uint64(shift)).astype(np.int64)
    return out
