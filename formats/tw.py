"""The `.tw` container: a TetWeave point cloud (positions, base SDF s, SH coefficients c).

`unpack` reads both versions: 1 (raw float16 arrays, below; `pack`) and 2 (quantized and entropy coded, see
formats/tw2.py; `pack_v2`, `quantize_file`).

Version 1:

Byte layout (all little-endian; full specification with examples in formats/README.md):

======  ====  =======  ==============================================================================
offset  size  type     field
======  ====  =======  ==============================================================================
0       8     bytes    magic ``89 54 57 56 0D 0A 1A 0A`` (``\\x89TWV\\r\\n\\x1a\\n``)
8       2     uint16   format version = 1
10      2     uint16   header size = 64
12      4     uint32   flags; bit 0: Delaunay backend of the encoder (0 = TetGen, 1 = Qhull); others 0
16      4     uint32   N, number of points
20      1     int8     SH degree d in -1..3 (-1: no SH); q = (d + 1)^2 coefficients per point
21      1     uint8    payload codec (0 = raw float16 arrays; other values reserved for entropy coding)
22      2     uint16   reserved, 0
24      8     float64  scale    } original = normalized * scale + offset
32      24    float64  offset x, y, z
56      8     uint64   payload size P in bytes (raw: 2 * N * (4 + q))
64      P     payload  raw: positions float16 (N, 3) row-major, s float16 (N,), c float16 (N, q) row-major
64 + P  4     uint32   CRC-32 (zlib / ISO-HDLC polynomial) of bytes [0, 64 + P)
======  ====  =======  ==============================================================================

`unpack` validates everything (magic, version, sizes against the file length, checksum, header fields, finite
values) and raises `ContainerError` -- and only that -- with a one-line message.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from tetweave_codec.errors import ContainerError
from tetweave_codec.geometry.sh import check_degree, num_coeffs

from .common import (  # noqa: F401 -- re-exported for readers of version 1
    CHECKSUM_SIZE,
    COORDINATE_BOUND_V1,
    FLAG_QHULL,
    KNOWN_FLAGS,
    MAGIC,
    backend_flags,
    backend_name,
    check_envelope,
    checked_fields,
    read_flags,
    read_sh_degree,
    read_transform,
    require_size,
    seal,
)
from .tw2 import TetWeaveFileV2, pack_v2, quantize_file  # noqa: F401 -- version 2, re-exported

VERSION = 1
HEADER_FORMAT = "<8sHHIIbBHd3dQ"
HEADER_SIZE = struct.calcsize(HEADER_FORMAT)  # 64
CODEC_RAW = 0

MAX_POINTS = 2**32 - 1

assert HEADER_SIZE == 64


@dataclass(frozen=True, eq=False)
class TetWeaveFile:
    """Contents of a `.tw` file.

    points: (N, 3) float16 positions in the normalized frame.
    s: (N,) float16 base signed distance (s < 0 inside).
    c: (N, q) float16 SH coefficients, q = (sh_degree + 1) ** 2 (q = 0 for sh_degree -1).
    sh_degree: -1..3.
    scale, offset: float and (3,) float64; ``original = normalized * scale + offset``.
    flags: bit field, see FLAG_*; `backend` reads the Delaunay backend from it.
    """

    points: np.ndarray
    s: np.ndarray
    c: np.ndarray
    sh_degree: int
    scale: float
    offset: np.ndarray
    flags: int = 0
    codec: int = field(default=CODEC_RAW)

    version = VERSION  # class attribute (not a field): the container version of this kind of contents

    @property
    def num_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def backend(self) -> str:
        """Delaunay backend the encoder used ("tetgen" or "qhull"); the decoder must use the same."""
        return backend_name(self.flags)

    @property
    def smoothing(self) -> int:
        """Version 1 files are never smoothed."""
        return 0

    @property
    def subdivision(self) -> int:
        """Version 1 files are never subdivided."""
        return 0

    @property
    def creases(self) -> bool:
        """Version 1 files have no filter whose creases to keep."""
        return False

    @property
    def holes(self) -> None:
        """Version 1 files have no holes section (as a version-2 file without one)."""
        return None


def payload_size(num_points: int, sh_degree: int) -> int:
    """Raw payload size in bytes for N points and an SH degree: 2 * N * (4 + q)."""
    return 2 * num_points * (4 + num_coeffs(sh_degree))


def pack(tw: TetWeaveFile) -> bytes:
    """Serialize a TetWeaveFile (version 1, raw codec). Raises ValueError on inconsistent contents."""
    degree = check_degree(tw.sh_degree)
    q = num_coeffs(degree)
    points = _as_f16(tw.points, "points")
    s = _as_f16(tw.s, "s")
    n = points.shape[0] if points.ndim == 2 else -1
    c = _as_f16(tw.c, "c") if q else np.zeros((max(n, 0), 0), np.float16)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {points.shape}")
    if s.shape != (n,):
        raise ValueError(f"s must be ({n},), got {s.shape}")
    if c.shape != (n, q):
        raise ValueError(f"c must be ({n}, {q}) for SH degree {degree}, got {c.shape}")
    if n > MAX_POINTS:
        raise ValueError(f"at most {MAX_POINTS} points fit a .tw file")
    scale, offset, flags = checked_fields(tw.scale, tw.offset, tw.flags)
    if tw.codec != CODEC_RAW:
        raise ValueError(f"payload codec {tw.codec} is not implemented (only {CODEC_RAW} = raw)")
    payload = b"".join(a.astype("<f2").tobytes() for a in (points, s, c))
    fields = (MAGIC, VERSION, HEADER_SIZE, flags, n, degree, CODEC_RAW, 0, scale, *offset, len(payload))
    return seal(struct.pack(HEADER_FORMAT, *fields) + payload)


def _as_f16(a, name: str) -> np.ndarray:
    arr = np.asarray(a)
    if arr.dtype != np.float16:
        if not np.issubdtype(arr.dtype, np.floating):
            raise ValueError(f"{name} must be a float array, got {arr.dtype}")
        with np.errstate(over="ignore"):  # overflow to inf is reported just below
            arr = arr.astype(np.float16)
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} has values that are not finite in float16 (|x| > 65504 or NaN)")
    return arr


def unpack(data: bytes | bytearray | memoryview) -> TetWeaveFile | TetWeaveFileV2:
    """Parse and validate a `.tw` file of version 1 (TetWeaveFile) or 2 (`tw2.TetWeaveFileV2`).

    Raises ContainerError (only) with a one-line message.
    """
    buf = bytes(data)
    size = len(buf)
    if size < len(MAGIC):
        if buf and MAGIC.startswith(buf):
            raise ContainerError(f"truncated .tw file: {size} bytes")
        raise ContainerError("not a .tw file (too short for the magic bytes)")
    if buf[: len(MAGIC)] != MAGIC:
        raise ContainerError("not a .tw file (wrong magic bytes)")
    if size < 10:
        raise ContainerError(f"truncated .tw file: {size} bytes")
    (version,) = struct.unpack_from("<H", buf, 8)
    if version == 2:
        from .tw2 import unpack_v2

        return unpack_v2(buf)
    if version != VERSION:
        raise ContainerError(f"unsupported .tw version {version} (this tetweave reads versions 1 and 2)")
    require_size(buf, HEADER_SIZE + CHECKSUM_SIZE, "the header alone")
    (_, _, header_size, flags, n, degree, codec, reserved, scale, ox, oy, oz, psize) = struct.unpack_from(
        HEADER_FORMAT, buf, 0
    )
    check_envelope(buf, HEADER_SIZE + psize + CHECKSUM_SIZE)
    # The checksum matched, so the remaining checks catch files written wrongly rather than damaged ones.
    if header_size != HEADER_SIZE:
        raise ContainerError(f"invalid .tw header: header size {header_size}, version 1 has {HEADER_SIZE}")
    flags = read_flags(flags, KNOWN_FLAGS)
    degree = read_sh_degree(degree)
    if codec != CODEC_RAW:
        raise ContainerError(f"unsupported .tw payload codec {codec} (this tetweave reads {CODEC_RAW} = raw)")
    if reserved != 0:
        raise ContainerError("invalid .tw header: reserved field is not zero")
    scale, offset = read_transform(scale, (ox, oy, oz), COORDINATE_BOUND_V1)
    if psize != payload_size(n, degree):
        raise ContainerError(
            f"invalid .tw header: payload of {psize} bytes, {n} points at SH degree {degree} need "
            f"{payload_size(n, degree)}"
        )
    q = num_coeffs(degree)
    arrays = np.frombuffer(buf, dtype="<f2", count=psize // 2, offset=HEADER_SIZE).astype(np.float16)
    points = arrays[: 3 * n].reshape(n, 3).copy()
    s = arrays[3 * n : 4 * n].copy()
    c = arrays[4 * n :].reshape(n, q).copy()
    for name, arr in (("point coordinates", points), ("signed distances", s), ("SH coefficients", c)):
        if not np.isfinite(arr).all():
            raise ContainerError(f"invalid .tw payload: non-finite {name}")
    return TetWeaveFile(points, s, c, degree, scale, offset, flags, int(codec))
