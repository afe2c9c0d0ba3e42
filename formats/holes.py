"""The holes section of a version-2 `.tw` file (flags bit 7): which faces of the closed surface the decoder removes.

A TetWeave surface is always closed. When the input mesh is open (a scan with holes), the encoder may list the
faces that only cap the input's holes; the decoder removes them (and every face Loop subdivision made of them),
so that the output keeps the input's holes as boundaries. The faces are named by their *rank* in the canonical
order of the extracted surface (`geometry.holes.face_ranks`: marching tets and hull caps, before smoothing and
subdivision), sorted, strictly increasing.

Section layout (formats/README.md, "Holes section"):

    uint32 K (1 <= K <= MAX_HOLE_FACES)
    1 + A bytes: histogram model of the gap buckets (A = 2..GAP_BUCKETS)
    coded words: K gap buckets e_i = bit_length(g_i) with that model, then the raw bits of each gap (e_i - 1
    bits below its leading one), where g_0 = r_0 and g_i = r_i - r_{i-1} - 1.

The encoder and decoder here are mirror images; `decode_holes` bounds K before allocating anything and raises
ContainerError on every malformed section.
"""

from __future__ import annotations

import struct

import numpy as np

from tetweave_codec.errors import ContainerError

from . import entropy
from .attributes import _from_raw, _histogram_bytes, _Models, _raw_bits, bit_length

GAP_BUCKETS = 33  # bit_length(g) for gaps g < 2**32
MAX_RANK = 2**32 - 1  # ranks are below the surface's face count, which the decoder caps far below this
# K per point: a closed marching-tets surface has at most 4 faces per tet (two per tet, plus hull caps), and
# Delaunay tetrahedralizations of encoder-made points have ~6.5 tets per point; 64 bounds hostile files' K.
MAX_HOLE_FACES_PER_POINT = 64


def max_hole_faces(num_points: int) -> int:
    """The largest K a file of `num_points` points may announce."""
    return MAX_HOLE_FACES_PER_POINT * max(int(num_points), 1)


def encode_holes(ranks: np.ndarray) -> bytes:
    """The holes section of face ranks (K,) int, strictly increasing, in [0, MAX_RANK]; ValueError otherwise."""
    r = np.asarray(ranks, dtype=np.int64).reshape(-1)
    if len(r) == 0:
        raise ValueError("a holes section lists at least one face")
    if r[0] < 0 or r[-1] > MAX_RANK or (len(r) > 1 and np.any(np.diff(r) <= 0)):
        raise ValueError("hole face ranks must be strictly increasing and in [0, 2**32)")
    gaps = np.diff(r, prepend=-1) - 1
    e = bit_length(gaps)
    top = max(int(e.max()) + 1, 2)
    hist = entropy.fit_histogram(e, top)
    w = entropy.Writer()
    w.encode(e, entropy.histogram_model(hist))
    w.encode_raw(*_raw_bits(gaps, e))
    return struct.pack("<I", len(r)) + _histogram_bytes(hist) + w.finish()


def decode_holes(section: bytes, num_points: int) -> np.ndarray:
    """Face ranks (K,) int64, strictly increasing, of a holes section; ContainerError when malformed."""
    if len(section) < 4:
        raise ContainerError("invalid .tw payload: the holes section is truncated")
    (k,) = struct.unpack_from("<I", section, 0)
    if not 1 <= k <= max_hole_faces(num_points):
        raise ContainerError(f"invalid .tw payload: {k} hole faces for {num_points} points")
    models = _Models(section[4:], "holes")
    hist = models.histogram(GAP_BUCKETS)
    r = entropy.Reader(section[4 + models.pos :], "holes")
    e = r.decode(entropy.histogram_model(hist), int(k))
    gaps = _from_raw(r.decode_raw(np.maximum(e - 1, 0)), e)
    ranks = np.cumsum(gaps + 1) - 1
    if ranks[-1] > MAX_RANK:
        raise ContainerError("invalid .tw payload: hole face rank out of range")
    return ranks
