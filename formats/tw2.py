"""The `.tw` container, version 2: quantized positions, s and c, entropy coded (octree + range coder).

Byte layout (little-endian, no padding; full specification in formats/README.md, "Version 2"):

======  =========  =======  ==========================================================================
offset  size       type     field
======  =========  =======  ==========================================================================
0       8          bytes    magic ``89 54 57 56 0D 0A 1A 0A`` (as version 1)
8       2          uint16   version = 2
10      1          uint8    flags; bit 0: Delaunay backend (0 = TetGen or exact, 1 = Qhull); bit 1: s predicted;
                            bit 2: octree context-coded; bits 3-4: smoothing steps 0-3;
                            bits 5-6: subdivision levels 0-2; bit 7: holes section
11      1          int8     SH degree d in -1..3
12      1          uint8    bits 0-4: position bits b in 6..16; bit 6: the exact Delaunay (formats/README.md,
                            "Decoding" step 2; flags bit 0 then 0); bit 7: crease-preserving smoothing; bit 5: 0
13      4          uint32   N, number of points (<= MAX_POINTS)
17      8          float64  scale    } original = normalized * scale + offset
25      24         float64  offset x, y, z
49      4          float32  s step
53      4 (d + 1)  float32  c step of SH band l = 0..d
H - 12  12 (16)    uint32   byte sizes of the sections: positions, s, c (, holes when flags bit 7)
                            (H = 65 + 4 (d + 1), plus 4 with flags bit 7)
H       ...        bytes    positions section, s section, c section (, holes section)
end-4   4          uint32   CRC-32 (zlib) of every byte before it
======  =========  =======  ==========================================================================

`unpack_v2` validates everything and raises `ContainerError` -- and only that -- with a one-line message.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from tetweave_codec.errors import ContainerError
from tetweave_codec.geometry.sh import SH_DEGREE_NONE, check_degree, num_coeffs

from . import attributes, common, holes, octree
from . import quantize as Q
from .common import (
    BITS_CREASES,
    BITS_EXACT,
    CHECKSUM_SIZE,
    FLAG_HOLES,
    FLAG_QHULL,
    FLAG_S_PREDICTED,
    KNOWN_FLAGS_V2,
    MAGIC,
    MAX_SUBDIVISION,
    backend_name,
    check_envelope,
    checked_fields,
    read_flags,
    read_sh_degree,
    read_transform,
    require_size,
    seal,
    smoothing_steps,
    subdivision_levels,
)

VERSION = 2
FIXED_FORMAT = "<8sHBbBI4df"
FIXED_SIZE = struct.calcsize(FIXED_FORMAT)  # 53
MAX_POINTS = 2**22  # format limit: entropy-coded points have no minimum size, so N bounds every allocation
SECTIONS = ("positions", "s", "c")
HOLES_SECTION = "holes"  # the fourth section, present with flags bit 7

assert FIXED_SIZE == 53


def header_size(sh_degree: int, with_holes: bool = False) -> int:
    """Header bytes for an SH degree: 53 + 4 (d + 1) + 12, plus 4 (the holes section's size) with flags bit 7."""
    return FIXED_SIZE + 4 * (sh_degree + 1) + 4 * (len(SECTIONS) + int(with_holes))


@dataclass(frozen=True, eq=False)
class TetWeaveFileV2:
    """Contents of a version-2 `.tw` file: integer symbols plus the quantizer parameters.

    cells: (N, 3) int64 position cells in [0, 2**position_bits), unique, canonical order (`pack_v2` sorts).
    s_sym: (N,) int64 s symbols (`quantize.quantize_s`), same order.
    c_sym: (N, q) int64 c symbols (`quantize.quantize_c`), q = num_coeffs(sh_degree).
    position_bits: b in 6..16. s_step: float (stored as float32). c_band_steps: d + 1 floats (float32).
    sh_degree: -1..3. scale, offset: ``original = normalized * scale + offset``. flags: bit 0 = Qhull, bit 1 = s
    coded as prediction residuals, bit 2 = octree levels context-coded (what the encoder writes), bits 3-4 =
    Taubin smoothing steps of the decoded surface (`smoothing`), bits 5-6 = Loop subdivision levels after it
    (`subdivision`), bit 7 = a holes section (`holes`).
    creases: the smoothing keeps the creases of the extracted surface (bit 7 of the position-bits byte).
    holes: (K,) int64 strictly increasing face ranks the decoder removes (formats/holes.py), K >= 1, exactly when
    flags bit 7 is set; None (or empty) otherwise.
    sizes: byte size of each part of the file it was read from ("header", "positions", "s", "c",
    "checksum"), or None for a file built in memory.

    `points`, `s`, `c` are the dequantized float64 arrays (what the decoder triangulates).
    """

    cells: np.ndarray
    s_sym: np.ndarray
    c_sym: np.ndarray
    position_bits: int
    s_step: float
    c_band_steps: tuple
    sh_degree: int
    scale: float
    offset: np.ndarray
    flags: int = 0
    sizes: dict | None = field(default=None, compare=False)
    holes: np.ndarray | None = None
    creases: bool = False
    exact: bool | None = None

    version = VERSION

    def __post_init__(self):
        if self.exact is None:
            object.__setattr__(self, "exact", not int(self.flags) & FLAG_QHULL)

    @property
    def num_points(self) -> int:
        return int(self.cells.shape[0])

    @property
    def backend(self) -> str:
        return backend_name(self.flags, self.exact)

    @property
    def smoothing(self) -> int:
        """Taubin smoothing steps the decoder applies to the extracted surface (flags bits 3-4)."""
        return smoothing_steps(self.flags)

    @property
    def subdivision(self) -> int:
        """Loop subdivision levels the decoder applies after the smoothing (flags bits 5-6)."""
        return subdivision_levels(self.flags)

    @cached_property
    def points(self) -> np.ndarray:
        return Q.dequantize_positions(self.cells, self.position_bits)

    @cached_property
    def s(self) -> np.ndarray:
        return Q.dequantize_s(self.s_sym, self.s_step)

    @cached_property
    def c(self) -> np.ndarray:
        return Q.dequantize_c(self.c_sym, self.c_steps)

    @property
    def c_steps(self) -> np.ndarray:
        """Per-coefficient steps (q,) float64."""
        return Q.c_steps(self.sh_degree, self.c_band_steps)


def quantize_file(
    points,
    s,
    c,
    sh_degree: int,
    *,
    position_bits: int,
    s_step: float,
    c_band_steps,
    scale: float = 1.0,
    offset=(0.0, 0.0, 0.0),
    flags: int = 0,
    exact: bool | None = None,
) -> tuple[TetWeaveFileV2, np.ndarray]:
    """Quantize float arrays into a TetWeaveFileV2 (collisions merged, first occurrence wins; canonical order).
    exact: the exact Delaunay (None: unless flags bit 0 names Qhull).

    Returns (file, kept): ``kept`` (M,) int64 are the input indices of the stored points, in file order.
    """
    degree = int(sh_degree)
    q = num_coeffs(degree)
    cells, kept = Q.merge_collisions(Q.quantize_positions(points, position_bits))
    s_sym = Q.quantize_s(np.asarray(s, dtype=np.float64).reshape(-1)[kept], s_step)
    if q:
        c_arr = np.asarray(c, dtype=np.float64).reshape(-1, q)[kept]
        c_sym = Q.quantize_c(c_arr, Q.c_steps(degree, c_band_steps))
    else:
        c_sym = np.zeros((len(kept), 0), dtype=np.int64)
    steps = tuple(Q.stored_step(x) for x in np.asarray(c_band_steps, dtype=np.float64).reshape(-1))
    f = TetWeaveFileV2(
        cells, s_sym, c_sym, int(position_bits), Q.stored_step(s_step), steps, degree, float(scale),
        np.asarray(offset, dtype=np.float64), int(flags),
        exact=exact,
    )  # fmt: skip
    return f, kept


# -----------------------------------------------------------------------------------------------------------
# writing


def pack_v2(f: TetWeaveFileV2) -> bytes:
    """Serialize a TetWeaveFileV2. Points are sorted into canonical order here (with their s and c);
    duplicate cells raise ValueError (merge them first: `quantize.merge_collisions` or `quantize_file`).
    Raises ValueError on inconsistent contents."""
    degree = check_degree(f.sh_degree)
    q = num_coeffs(degree)
    bits = Q.check_bits(f.position_bits)
    cells = np.asarray(f.cells, dtype=np.int64)
    if cells.ndim != 2 or cells.shape[1] != 3:
        raise ValueError(f"cells must be (N, 3), got {cells.shape}")
    n = len(cells)
    if n > MAX_POINTS:
        raise ValueError(f"at most {MAX_POINTS} points fit a version-2 .tw file")
    s_sym = np.asarray(f.s_sym, dtype=np.int64)
    c_sym = np.asarray(f.c_sym, dtype=np.int64)
    if q == 0 and c_sym.size == 0:
        c_sym = np.zeros((n, 0), np.int64)
    if s_sym.shape != (n,):
        raise ValueError(f"s_sym must be ({n},), got {s_sym.shape}")
    if c_sym.shape != (n, q):
        raise ValueError(f"c_sym must be ({n}, {q}) for SH degree {degree}, got {c_sym.shape}")
    if n and (cells.min() < 0 or cells.max() >= (1 << bits)):
        raise ValueError(f"cells must lie in [0, {(1 << bits) - 1}] for {bits} position bits")
    order = Q.canonical_order(cells)
    cells, s_sym, c_sym = cells[order], s_sym[order], c_sym[order]
    keys = Q.morton_keys(cells)
    if n > 1 and np.any(keys[1:] == keys[:-1]):
        raise ValueError("duplicate cells: merge them first (quantize.merge_collisions)")
    s_step = Q.stored_step(f.s_step)
    band_steps = [Q.stored_step(x) for x in np.asarray(f.c_band_steps, dtype=np.float64).reshape(-1)]
    if len(band_steps) != degree + 1:
        raise ValueError(f"need {degree + 1} c band steps for SH degree {degree}, got {len(band_steps)}")
    for problem in _step_problems(s_step, band_steps):
        raise ValueError(problem)
    scale, offset, flags = checked_fields(f.scale, f.offset, f.flags, KNOWN_FLAGS_V2, Q.GRID_BOUND)
    if f.exact and flags & FLAG_QHULL:
        raise ValueError("a file triangulated by the exact Delaunay has flags bit 0 (Qhull) clear")
    if subdivision_levels(flags) > MAX_SUBDIVISION:
        raise ValueError(f"subdivision levels must be 0-{MAX_SUBDIVISION}, got {subdivision_levels(flags)}")
    hole_ranks = np.zeros(0, np.int64) if f.holes is None else np.asarray(f.holes, dtype=np.int64).reshape(-1)
    if bool(flags & FLAG_HOLES) != bool(len(hole_ranks)):
        raise ValueError("flags bit 7 and a non-empty holes list go together")
    models, words = octree.encode(cells, bits, contexts=bool(flags & common.FLAG_OCTREE_CONTEXTS))
    if flags & FLAG_S_PREDICTED:
        s_section = attributes.encode_s_predicted(s_sym, cells)
    else:
        s_section = attributes.encode_s(s_sym)
    sections = (models + words, s_section, attributes.encode_c(c_sym, degree) if n else b"")
    if len(hole_ranks):
        if n == 0:
            raise ValueError("a holes section needs points")
        sections += (holes.encode_holes(hole_ranks),)
    bits_byte = bits | (BITS_CREASES if f.creases else 0) | (BITS_EXACT if f.exact else 0)
    header = struct.pack(FIXED_FORMAT, MAGIC, VERSION, flags, degree, bits_byte, n, scale, *offset, s_step)
    header += struct.pack(f"<{degree + 1}f", *band_steps)
    header += struct.pack(f"<{len(sections)}I", *(len(x) for x in sections))
    return seal(header + b"".join(sections))


def _step_problems(s_step: float, band_steps) -> list[str]:
    """Why the stored steps cannot be in a file (empty when they can): `quantize.step_problem` of each."""
    found = [Q.step_problem("s step", s_step, Q.MAX_S_STEP)]
    found += [Q.step_problem("c step", x, Q.MAX_C_STEP) for x in band_steps]
    return [x for x in found if x]


# -----------------------------------------------------------------------------------------------------------
# reading


def unpack_v2(buf: bytes) -> TetWeaveFileV2:
    """Parse and validate a version-2 file (magic and version already checked). Raises ContainerError only."""
    require_size(buf, header_size(SH_DEGREE_NONE) + CHECKSUM_SIZE, "a version-2 header")
    (_, _, flags, degree, bits_byte, n, scale, ox, oy, oz, s_step) = struct.unpack_from(FIXED_FORMAT, buf, 0)
    creases, exact = bool(bits_byte & BITS_CREASES), bool(bits_byte & BITS_EXACT)
    bits = bits_byte & ~(BITS_CREASES | BITS_EXACT)
    degree = read_sh_degree(degree)
    with_holes = bool(flags & FLAG_HOLES)
    hsize = header_size(degree, with_holes)
    count = len(SECTIONS) + int(with_holes)
    require_size(buf, hsize + CHECKSUM_SIZE, "the header alone")
    band_steps = struct.unpack_from(f"<{degree + 1}f", buf, FIXED_SIZE)
    section_sizes = struct.unpack_from(f"<{count}I", buf, hsize - 4 * count)
    check_envelope(buf, hsize + sum(section_sizes) + CHECKSUM_SIZE)
    # Behind a valid checksum: the remaining checks catch files written wrongly (or forged) rather than damaged.
    flags = read_flags(flags, KNOWN_FLAGS_V2)
    if exact and flags & FLAG_QHULL:
        raise ContainerError("invalid .tw header: two Delaunay backends (exact, and Qhull in flags bit 0)")
    if subdivision_levels(flags) > MAX_SUBDIVISION:
        raise ContainerError(
            f"invalid .tw header: {subdivision_levels(flags)} subdivision levels (expected 0..{MAX_SUBDIVISION})"
        )
    if not Q.POSITION_BITS_MIN <= bits <= Q.POSITION_BITS_MAX:
        raise ContainerError(
            f"invalid .tw header: {bits} position bits (expected {Q.POSITION_BITS_MIN}..{Q.POSITION_BITS_MAX})"
        )
    if n > MAX_POINTS:
        raise ContainerError(f"invalid .tw header: {n} points (a version-2 file holds at most {MAX_POINTS})")
    scale, offset = read_transform(scale, (ox, oy, oz), Q.GRID_BOUND)
    for problem in _step_problems(s_step, band_steps):
        raise ContainerError(f"invalid .tw header: {problem}")
    q = num_coeffs(degree)
    if n == 0 and any(section_sizes):
        raise ContainerError("invalid .tw header: sections for zero points")
    if n and q == 0 and section_sizes[2]:
        raise ContainerError("invalid .tw header: a c section without SH coefficients")
    starts = np.cumsum((hsize, *section_sizes))
    sec = [buf[int(starts[i]) : int(starts[i + 1])] for i in range(count)]
    contexts = bool(flags & common.FLAG_OCTREE_CONTEXTS)
    model_bytes = octree.model_size(sec[0], int(bits), int(n), contexts)
    cells = octree.decode(sec[0][:model_bytes], sec[0][model_bytes:], int(bits), int(n), contexts)
    if flags & FLAG_S_PREDICTED:
        s_sym = attributes.decode_s_predicted(sec[1], cells)
    else:
        s_sym = attributes.decode_s(sec[1], int(n))
    c_sym = attributes.decode_c(sec[2], int(n), int(degree))
    hole_ranks = holes.decode_holes(sec[3], int(n)) if with_holes else None
    names = SECTIONS + ((HOLES_SECTION,) if with_holes else ())
    sizes = {"header": hsize, **dict(zip(names, section_sizes, strict=True)), "checksum": CHECKSUM_SIZE}
    return TetWeaveFileV2(
        cells, s_sym, c_sym, int(bits), float(s_step), tuple(float(x) for x in band_steps), degree,
        scale, offset, flags, sizes, hole_ranks, creases, exact,
    )  # fmt: skip
