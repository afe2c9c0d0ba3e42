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

With header flag bit 2 (`FLAG_OCTREE_CONTEXTS`, formats/README.md "Positions section, context-coded") each level
is coded either as above or bit by bit with neighbour contexts, as in MPEG G-PCC's geometry coder: the 8 child
bits of a node in child order, bit i with the binary model of context ``3 * a + min(o, 2)``, where a (0..3) counts
the occupied face neighbours of the node (same level) on the side of child i and o the occupied children before
i. The encoder picks the cheaper coding per level (levels 2 to b - 3 of a fitted file, 8-30 % fewer bits each; the
deepest levels, single-child nodes in empty neighbourhoods, stay with population count + rank). Every pass of
one child bit over a level is one batch, so the decoder's work is a few numpy operations per level.
"""

from __future__ import annotations

from math import comb

import numpy as np

from tetweave_codec.errors import ContainerError

from . import entropy
from .quantize import canonical_order, check_bits, morton_keys

POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.int64)
# PATTERNS[k]: the occupancy codes with k bits set, ascending; RANK[code]: index of code in PATTERNS[popcount]
PATTERNS = [np.array([c for c in range(256) if POPCOUNT[c] == k], dtype=np.int64) for k in range(9)]
RANK = np.zeros(256, dtype=np.int64)
for _k in range(9):
    RANK[PATTERNS[_k]] = np.arange(len(PATTERNS[_k]))
RANK_BITS = np.log2([comb(8, k) for k in range(9)])  # code length of a rank (uniform) per population count
MODEL_BYTES_PER_LEVEL = 8
# Context-coded octree (flag bit 2): a uint16 mask of the levels coded bit by bit, then per level its models
LEVEL_MASK_BYTES = 2
NEIGHBOUR_CLASSES = 4  # occupied face neighbours on the side of a child: 0..3
CHILD_CLASSES = 3  # occupied children coded before it: 0, 1, 2 or more
CONTEXTS = NEIGHBOUR_CLASSES * CHILD_CLASSES  # binary model bytes of a bit-coded level
DENSE_LEVEL_MAX = 7  # face_neighbours uses a table of 8**level flags (2 MiB at level 7) up to this level
# face neighbours in the order -x, +x, -y, +y, -z, +z; child i = (bx << 2) | (by << 1) | bz touches the
# neighbour 2 * axis + bit on each axis (axis 0, 1, 2 = x, y, z)
CHILD_SIDES = np.array([[(i >> 2) & 1, 2 + ((i >> 1) & 1), 4 + (i & 1)] for i in range(8)], dtype=np.int64)
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


def face_neighbours(keys: np.ndarray, level: int) -> np.ndarray:
    """Which face neighbours of each node are nodes too.

    keys: (n,) int64 ascending Morton codes of the nodes of octree level `level` (coordinates in [0, 2**level)).
    Returns (n, 6) bool, neighbours in the order -x, +x, -y, +y, -z, +z.
    """
    keys = np.asarray(keys, dtype=np.int64)
    n = len(keys)
    out = np.zeros((n, 6), dtype=bool)
    table = None
    if level <= DENSE_LEVEL_MAX:  # a lookup table over all 8**level keys is faster than a sorted search
        table = np.zeros(1 << (3 * level), dtype=bool)
        table[keys] = True
    for axis, shift in enumerate((2, 1, 0)):  # x, y, z: the key bits 3j + shift hold the axis' coordinate
        bits = np.int64(sum(1 << (3 * j + shift) for j in range(level)))
        coord, rest = keys & bits, keys & ~bits
        # +-1 on one axis of a Morton code: borrow or carry through that axis' bits only; none at the grid's faces
        for side, (query, edge) in enumerate(
            ((((coord - 1) & bits) | rest, coord == 0), ((((keys | ~bits) + 1) & bits) | rest, coord == bits))
        ):
            if table is not None:
                found = table[query & ((1 << (3 * level)) - 1)]  # wrapped keys are at an edge, masked below
            else:
                found = keys[np.minimum(np.searchsorted(keys, query), n - 1)] == query
            out[:, 2 * axis + side] = found & ~edge
    return out


def side_contexts(neighbours: np.ndarray) -> np.ndarray:
    """CHILD_CLASSES x (occupied face neighbours on the side of child i): (n, 8) int64 from (n, 6) neighbours."""
    return CHILD_CLASSES * neighbours[:, CHILD_SIDES].sum(axis=2, dtype=np.int64)


def _bit_passes(occ: np.ndarray, neighbours: np.ndarray):
    """Encoder side: (coded mask, contexts, bits) of the 8 child passes of a bit-coded level."""
    bits = (occ[:, None] >> np.arange(8)) & 1
    side = side_contexts(neighbours)
    before = np.zeros(len(occ), dtype=np.int64)
    out = []
    for child in range(8):
        # the last child of a node with no other child is occupied: not coded
        coded = before > 0 if child == 7 else np.ones(len(occ), dtype=bool)
        out.append((coded, side[:, child] + np.minimum(before, CHILD_CLASSES - 1), bits[:, child]))
        before = before + bits[:, child]
    return out


def _level_models(occ: np.ndarray, neighbours: np.ndarray | None):
    """Encoder side: the cheaper coding of one level -> (is_bitwise, model bytes, bits as estimated)."""
    pop = POPCOUNT[occ]
    hist = entropy.fit_histogram(pop - 1, 8)
    cost = entropy.model_bits(pop - 1, entropy.histogram_weights(hist)) + 8 * MODEL_BYTES_PER_LEVEL
    cost += float(RANK_BITS[pop].sum())
    if neighbours is None:
        return False, hist.tobytes(), cost
    passes = _bit_passes(occ, neighbours)
    ctx = np.concatenate([c[m] for m, c, _ in passes])
    bit = np.concatenate([b[m] for m, _, b in passes])
    table = np.array([entropy.fit_binary(bit[ctx == c]) if np.any(ctx == c) else 128 for c in range(CONTEXTS)])
    bit_cost = 8 * CONTEXTS + sum(
        entropy.model_bits(bit[ctx == c], entropy.binary_weights(v)) for c, v in enumerate(table)
    )
    if bit_cost < cost:
        return True, table.astype(np.uint8).tobytes(), bit_cost
    return False, hist.tobytes(), cost


def encode(cells: np.ndarray, bits: int, contexts: bool = False) -> tuple[bytes, bytes]:
    """Code unique cells given in canonical order. Returns (model bytes, coded words).

    contexts=False: b x 8 model bytes (population count + rank on every level). contexts=True (flag bit 2): the
    uint16 mask of bit-coded levels, then per level 8 or CONTEXTS model bytes, whichever coding is cheaper.
    """
    bits = check_bits(bits)
    cells = np.asarray(cells, dtype=np.int64)
    if len(cells) == 0:
        return b"", b""
    keys = morton_keys(cells)
    if np.any(keys[1:] <= keys[:-1]):
        raise ValueError("cells must be unique and in canonical order (see quantize.merge_collisions)")
    keys = keys.astype(np.int64)
    models = bytearray()
    mask = 0
    writer = entropy.Writer()
    for level, occ in enumerate(_levels(cells, bits)):
        neighbours = None
        if contexts:
            node_keys = np.unique(keys >> (3 * (bits - level)))
            neighbours = face_neighbours(node_keys, level)
        bitwise, level_models, _ = _level_models(occ, neighbours)
        models += level_models
        if bitwise:
            mask |= 1 << level
            rows = entropy.binary_weight_rows(np.frombuffer(level_models, dtype=np.uint8))
            for coded, ctx, bit in _bit_passes(occ, neighbours):
                writer.encode_binary(bit[coded], rows[ctx[coded]])
            continue
        pop = POPCOUNT[occ]
        writer.encode(pop - 1, entropy.histogram_model(np.frombuffer(level_models, dtype=np.uint8)))
        rank = RANK[occ]
        for k in range(1, 8):
            sel = pop == k
            if sel.any():
                writer.encode(rank[sel], uniform_model(comb(8, k)))
    if contexts:
        models = bytearray(mask.to_bytes(LEVEL_MASK_BYTES, "little")) + models
    return bytes(models), writer.finish()


def contexts_pay(cells: np.ndarray, bits: int) -> bool:
    """Whether the context-coded octree (flag bit 2) is smaller than the plain one for these unique cells (N, 3)."""
    cells = np.asarray(cells, dtype=np.int64)
    cells = cells[canonical_order(cells, bits)]
    plain, coded = (sum(map(len, encode(cells, bits, contexts))) for contexts in (False, True))
    return coded < plain


def model_size(section: bytes, bits: int, num_points: int, contexts: bool = False) -> int:
    """Byte size of the models at the start of a positions section (ContainerError if they do not fit)."""
    if num_points == 0:
        return 0
    size = bits * MODEL_BYTES_PER_LEVEL
    if contexts:
        if len(section) < LEVEL_MASK_BYTES:
            raise ContainerError("invalid .tw payload: the positions section is shorter than its models")
        mask = int.from_bytes(section[:LEVEL_MASK_BYTES], "little")
        if mask >> bits:
            raise ContainerError("invalid .tw payload: bit-coded octree levels beyond the position bits")
        size = LEVEL_MASK_BYTES + size + bin(mask).count("1") * (CONTEXTS - MODEL_BYTES_PER_LEVEL)
    if len(section) < size:
        raise ContainerError("invalid .tw payload: the positions section is shorter than its models")
    return size


def decode(models: bytes, words: bytes, bits: int, num_points: int, contexts: bool = False) -> np.ndarray:
    """Decode (N, 3) int64 cells in canonical order; raises ContainerError if the stream does not yield N leaves.

    `models` must be the model bytes exactly (`model_size` of the section), `contexts` as for `encode`.
    """
    bits = check_bits(bits)
    if num_points == 0:
        return np.zeros((0, 3), dtype=np.int64)
    if len(models) != model_size(models, bits, num_points, contexts):
        raise ContainerError("invalid .tw payload: wrong size of the position models")
    mask, pos = 0, 0
    if contexts:
        mask, pos = int.from_bytes(models[:LEVEL_MASK_BYTES], "little"), LEVEL_MASK_BYTES
    reader = entropy.Reader(words, "positions")
    keys = np.zeros(1, dtype=np.int64)  # Morton keys of the nodes of the current level
    for level in range(bits):
        width = CONTEXTS if mask >> level & 1 else MODEL_BYTES_PER_LEVEL
        table = np.frombuffer(models, dtype=np.uint8, count=width, offset=pos).astype(np.int64)
        pos += width
        if mask >> level & 1:
            occ, total = _decode_bitwise(reader, table, keys, level)
        else:
            occ, total = _decode_popcount(reader, table, len(keys))
        if total > num_points:
            raise ContainerError(f"corrupted .tw file: the octree has more than {num_points} points")
        flags = np.unpackbits(occ.astype(np.uint8)[:, None], axis=1, bitorder="little").astype(bool)
        keys = ((keys[:, None] << 3) | np.arange(8, dtype=np.int64))[flags]
    if len(keys) != num_points:
        raise ContainerError(f"corrupted .tw file: the octree has {len(keys)} points, the header says {num_points}")
    return _cells_from_keys(keys)


def _decode_popcount(reader: entropy.Reader, hist: np.ndarray, n: int) -> tuple[np.ndarray, int]:
    """Occupancy codes (n,) of a level coded as population count + rank, and their total population."""
    pop = reader.decode(entropy.histogram_model(hist), n) + 1
    occ = np.full(n, 255, dtype=np.int64)
    for k in range(1, 8):
        sel = pop == k
        count = int(sel.sum())
        if count:
            occ[sel] = PATTERNS[k][reader.decode(uniform_model(comb(8, k)), count)]
    return occ, int(pop.sum())


def _decode_bitwise(reader: entropy.Reader, table: np.ndarray, keys: np.ndarray, level: int):
    """Occupancy codes of a bit-coded level (context models `table`, CONTEXTS bytes), and their population."""
    rows = entropy.binary_weight_rows(table)  # ContainerError for a byte 0
    side = side_contexts(face_neighbours(keys, level))
    occ = np.zeros(len(keys), dtype=np.int64)
    before = np.zeros(len(keys), dtype=np.int64)
    for child in range(8):
        ctx = side[:, child] + np.minimum(before, CHILD_CLASSES - 1)
        if child < 7:
            bit = reader.decode_binary(rows[ctx])
        else:
            bit = np.ones(len(keys), dtype=np.int64)
            coded = before > 0
            bit[coded] = reader.decode_binary(rows[ctx[coded]])
        occ |= bit << child
        before += bit
    return occ, int(before.sum())


def _compact3(v: np.ndarray) -> np.ndarray:
    v = v & 0x9249249249249249
    v = (v | (v >> 2)) & 0x30C30C30C30C30C3
    v = (v | (v >> 4)) & 0xF00F00F00F00F00F
    v = (v | (v >> 8)) & 0x00FF0000FF0000FF
    v = (v | (v >> 16)) & 0x0000FFFF0000FFFF
    return v & 0xFFFF


def _cells_from_keys(keys: np.ndarray) -> np.ndarray:
    """(n, 3) int64 cells of Morton codes (inverse of `quantize.morton_keys`)."""
    k = keys.astype(np.uint64)
    out = np.empty((len(keys), 3), dtype=np.int64)
    for axis, shift in ((0, 2), (1, 1), (2, 0)):
        out[:, axis] = _compact3(k >> np.uint64(shift)).astype(np.int64)
    return out
