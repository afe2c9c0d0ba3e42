"""What every `.tw` version shares: the magic, the flag bits, the envelope (sizes and checksum) and the checks of
the header fields both versions store (SH degree, flags, the transform back to the input).

Readers raise `ContainerError` and writers `ValueError` from the same predicates, so a file a writer accepts is
a file a reader accepts.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from tetweave_codec.errors import ContainerError
from tetweave_codec.geometry.sh import SH_DEGREE_MAX, SH_DEGREE_NONE, check_degree

MAGIC = b"\x89TWV\r\n\x1a\n"  # bytes 0-7 of every version; the uint16 version follows at offset 8
CHECKSUM_SIZE = 4  # CRC-32 (zlib) of every byte before it, the file's last 4 bytes
FLAG_QHULL = 1 << 0  # the encoder's Delaunay backend was Qhull (else TetGen, or the exact Delaunay: BITS_EXACT)
FLAG_S_PREDICTED = 1 << 1  # version 2: the s stream holds residuals of the neighbour prediction (formats/predict.py)
FLAG_OCTREE_CONTEXTS = 1 << 2  # version 2: octree levels may be coded bit by bit with neighbour contexts (octree.py)
# version 2, bits 3-4: the number of Taubin smoothing steps the decoder applies (geometry/smoothing.py), 0-3
SMOOTHING_SHIFT = 3
FLAG_SMOOTHING = 0b11 << SMOOTHING_SHIFT
# version 2, bits 5-6: the number of Loop subdivision levels the decoder applies after the smoothing
# (geometry/subdivision.py), 0-2; 3 is rejected
SUBDIVISION_SHIFT = 5
FLAG_SUBDIVISION = 0b11 << SUBDIVISION_SHIFT
MAX_SUBDIVISION = 2
# version 2, bit 7: the file has a holes section (formats/holes.py): faces of the closed surface the decoder removes,
# so that an open input's holes stay open; the header then has a fourth section size
FLAG_HOLES = 1 << 7
KNOWN_FLAGS = FLAG_QHULL  # version 1
# version 2, the position-bits byte (offset 12): b in its bits 0-4; bit 7 asks for crease-preserving smoothing
# (geometry/smoothing.py, crease_neighbours); bit 6 says the points are triangulated by the exact Delaunay of the
# spec (geometry/delaunay.py, backend "exact"; flags bit 0 is then 0); bit 5 is 0. The flags byte had no bit left;
# a decoder that predates a bit reads b > 16 and rejects the file instead of decoding it wrongly.
BITS_CREASES = 1 << 7
BITS_EXACT = 1 << 6
KNOWN_FLAGS_V2 = FLAG_QHULL | FLAG_S_PREDICTED | FLAG_OCTREE_CONTEXTS | FLAG_SMOOTHING | FLAG_SUBDIVISION | FLAG_HOLES
# Largest normalized coordinate of version 1 (any finite float16); version 2's is the grid's, quantize.GRID_BOUND.
COORDINATE_BOUND_V1 = float(np.finfo(np.float16).max)


def smoothing_flags(steps: int) -> int:
    """Flags bits recording `steps` (0-3) Taubin smoothing steps of the decoded surface (version 2)."""
    if not 0 <= int(steps) <= FLAG_SMOOTHING >> SMOOTHING_SHIFT:
        raise ValueError(f"smoothing steps must be 0-{FLAG_SMOOTHING >> SMOOTHING_SHIFT}, got {steps}")
    return int(steps) << SMOOTHING_SHIFT


def smoothing_steps(flags: int) -> int:
    """The Taubin smoothing steps a file's flags ask for (0 for version 1, whose reader rejects the bits)."""
    return (int(flags) & FLAG_SMOOTHING) >> SMOOTHING_SHIFT


def subdivision_flags(levels: int) -> int:
    """Flags bits recording `levels` (0-2) Loop subdivision levels of the decoded surface (version 2)."""
    if not 0 <= int(levels) <= MAX_SUBDIVISION:
        raise ValueError(f"subdivision levels must be 0-{MAX_SUBDIVISION}, got {levels}")
    return int(levels) << SUBDIVISION_SHIFT


def subdivision_levels(flags: int) -> int:
    """The Loop subdivision levels a file's flags ask for (0 for version 1; 3 is invalid: `flags_problem`)."""
    return (int(flags) & FLAG_SUBDIVISION) >> SUBDIVISION_SHIFT


def backend_flags(backend: str) -> int:
    """Flags bits recording the Delaunay backend: "tetgen" (0) or "qhull" (bit 0); "exact" is 0 here and recorded
    by BITS_EXACT in a version-2 file's position-bits byte (`backend_bits`); version 1 cannot record it."""
    if backend in ("tetgen", "exact"):
        return 0
    if backend == "qhull":
        return FLAG_QHULL
    raise ValueError(f"unknown Delaunay backend {backend!r}")


def backend_bits(backend: str) -> int:
    """Position-bits byte bits recording the Delaunay backend of a version-2 file (BITS_EXACT for "exact")."""
    backend_flags(backend)  # validates the name
    return BITS_EXACT if backend == "exact" else 0


def backend_name(flags: int, exact: bool = False) -> str:
    """The Delaunay backend recorded in a file: "exact" with BITS_EXACT (version 2), else "qhull" or "tetgen" after
    flags bit 0; the decoder must use the same."""
    if exact:
        return "exact"
    return "qhull" if flags & FLAG_QHULL else "tetgen"


# The transform a file may store (formats/README.md, "Validation"): what a real encode writes (the input's
# half-extent / 0.9 and its bounding box's centre) with room to spare. A scale beyond these ranges makes the
# self-intersection check's products under- or overflow; an offset beyond MAX_OFFSET_RATIO x scale leaves the
# transform's rounding (an ulp of the offset) above 2^-28 x scale, within 2^-12 of the finest grid cell
# (2.4 x 2^-16 x scale), where it would move decoded vertices through each other.
MIN_SCALE = 2.0**-64
MAX_SCALE = 2.0**64
MAX_OFFSET_RATIO = 2.0**24


def _transform_problem(scale: float, offset: np.ndarray, bound: float) -> str | None:
    """Why scale / offset cannot be stored (None if they can): scale finite and > 0, offset 3 finite numbers,
    ``bound * scale + |offset_i|`` finite in float64, so that every decoded vertex is finite in the input's frame,
    scale in [MIN_SCALE, MAX_SCALE] and every |offset_i| <= MAX_OFFSET_RATIO * scale."""
    if not (np.isfinite(scale) and scale > 0):
        return f"scale {scale} (must be finite and > 0)"
    if offset.shape != (3,) or not np.isfinite(offset).all():
        return "offset must be 3 finite numbers"
    with np.errstate(over="ignore"):
        reach = bound * scale + np.abs(offset)
    if not np.isfinite(reach).all():
        return f"scale {scale:g} and offset take the points beyond the float64 range"
    if not MIN_SCALE <= scale <= MAX_SCALE:
        return f"scale {scale:g} outside [2^-64, 2^64] (no encoder writes it)"
    if (np.abs(offset) > MAX_OFFSET_RATIO * scale).any():
        return f"offset beyond 2^24 x scale {scale:g} (the transform would round away the decoded surface's detail)"
    return None


def checked_fields(
    scale, offset, flags, known: int = KNOWN_FLAGS, bound: float = COORDINATE_BOUND_V1
) -> tuple[float, np.ndarray, int]:
    """scale (float > 0), offset (3,) float64 and flags as a writer stores them; ValueError when invalid.

    bound: the version's largest normalized coordinate (`COORDINATE_BOUND_V1`, `quantize.GRID_BOUND`)."""
    scale = float(scale)
    offset = np.asarray(offset, dtype=np.float64).reshape(-1)
    problem = _transform_problem(scale, offset, bound)
    if problem:
        raise ValueError(problem)
    flags = int(flags)
    if flags & ~known or flags < 0:
        raise ValueError(f"unknown flags 0x{flags:x}")
    return scale, offset, flags


def read_transform(scale: float, offset_xyz, bound: float) -> tuple[float, np.ndarray]:
    """A reader's scale and (3,) float64 offset from the header's doubles; ContainerError when invalid.

    bound: the version's largest normalized coordinate (`COORDINATE_BOUND_V1`, `quantize.GRID_BOUND`)."""
    scale = float(scale)
    offset = np.array(offset_xyz, dtype=np.float64)
    problem = _transform_problem(scale, offset, bound)
    if problem:
        raise ContainerError(f"invalid .tw header: {problem}")
    return scale, offset


def read_flags(flags: int, known: int) -> int:
    """A reader's flags; ContainerError when a bit outside `known` is set."""
    if flags & ~known:
        raise ContainerError(f"invalid .tw header: unknown flags 0x{flags & ~known:x}")
    return int(flags)


def read_sh_degree(degree: int) -> int:
    """A reader's SH degree (`sh.check_degree`, the one home of the rule); ContainerError when out of range."""
    try:
        return check_degree(int(degree))
    except ValueError:
        raise ContainerError(
            f"invalid .tw header: SH degree {degree} (expected {SH_DEGREE_NONE}..{SH_DEGREE_MAX})"
        ) from None


def require_size(buf: bytes, needed: int, what: str) -> None:
    """ContainerError "truncated" unless the file has at least `needed` bytes (`what` names the part)."""
    if len(buf) < needed:
        raise ContainerError(f"truncated .tw file: {len(buf)} bytes, {what} needs {needed}")


def check_envelope(buf: bytes, expected: int) -> None:
    """The whole-file checks of every version, in order: at least `expected` bytes (what the header announces),
    no bytes after them, and the CRC-32 (zlib) of every byte before the last 4 equals the stored checksum.

    Args:
        buf: the file's bytes. expected: header + sections + checksum, as the header announces.
    Raises ContainerError with a one-line message.
    """
    size = len(buf)
    if size < expected:
        raise ContainerError(f"truncated .tw file: {size} bytes, the header announces {expected}")
    if size > expected:
        raise ContainerError(f"corrupted .tw file: {size - expected} unexpected bytes after the checksum")
    (stored_crc,) = struct.unpack_from("<I", buf, size - CHECKSUM_SIZE)
    if zlib.crc32(memoryview(buf)[: size - CHECKSUM_SIZE]) != stored_crc:
        raise ContainerError("corrupted .tw file: checksum mismatch")


def seal(body: bytes) -> bytes:
    """`body` followed by its CRC-32 (zlib), little-endian: how every version ends."""
    return body + struct.pack("<I", zlib.crc32(body))
