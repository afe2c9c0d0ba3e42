"""Quantization of TetWeave point clouds for `.tw` version 2 -- the one owner of every quantizer.

Both the fit (straight-through rounding) and the container writer call these functions, so the encoder optimizes
exactly the values the decoder reconstructs. Every function accepts numpy arrays or torch tensors and returns
the same kind (torch is never imported here: tensors are recognised by duck typing, ``x.floor()`` etc.).

Quantizers (the exact decoder-side formulas are specified in formats/README.md, "Dequantization"):

* positions: a uniform grid of ``2**b`` cells per axis over the fixed cube ``[-GRID_BOUND, GRID_BOUND]**3``,
  ``b`` in ``POSITION_BITS_MIN..POSITION_BITS_MAX``. Symbol ``k = floor((x + 1.2) / cell)`` clamped to
  ``[0, 2**b - 1]``; value = the cell centre ``((2k + 1 - 2**b) * 1.2) / 2**b`` (float64, one rounding).
* s (base signed distance): sign-preserving mid-rise quantizer, ``k = floor(s / step)``, value
  ``(k + 0.5) * step``. The value is never 0 and ``value < 0 <=> k < 0 <=> s < 0`` (inside stays inside).
  Symbols are clamped to ``[-S_SYMBOL_LIMIT, S_SYMBOL_LIMIT - 1]``.
* c (SH coefficients): mid-tread quantizer per coefficient, ``k = round(c / step_j)`` (half to even), value
  ``k * step_j``, with one step per SH band ``l`` (coefficient ``j`` has band ``floor(sqrt(j))``). Symbols are
  clamped to ``[-C_SYMBOL_LIMIT, C_SYMBOL_LIMIT]``.

The encoder's side: `Quantization` (b, the s step, the c band steps and the fractional grid's scale of one encode)
and `default_quantization` (container v2's defaults for a fit of N points, a plain function of the options).

Canonical order: the order in which the octree decoder yields the points, i.e. ascending Morton code with the
child index ``(bx << 2) | (by << 1) | bz`` at every level (x most significant). Every per-point attribute of a
version-2 file is stored in this order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tetweave_codec.geometry.sh import check_degree, num_coeffs

GRID_BOUND = 1.2  # the fit clamps points to [-GRID_BOUND, GRID_BOUND]^3
POSITION_BITS_MIN = 6
POSITION_BITS_MAX = 16
S_SYMBOL_LIMIT = 2**20  # s symbols lie in [-2**20, 2**20 - 1]; magnitude (k or -k-1) < 2**20
C_SYMBOL_LIMIT = 2**15  # c symbols lie in [-2**15, 2**15]
MIN_STEP = 2.0**-126  # steps are normal float32 numbers > 0
# The largest steps a version-2 file may store (formats/README.md, "Validation"); a real encode writes s steps
# below 0.03 and c steps below 3 (`default_quantization` at 64 points, x 2.8 for rate control's coarser
# steps). A c step of 4 keeps coefficients of symbol +-1 from saturating tanh at SH degree 1 (4 x (Y_0 + |Y_1|) <=
# 4.5, 1 + tanh >= 2.5e-4; a step of 16 already put vertices within 1e-15 of the points); a c step
# near float32's largest makes every nonzero coefficient saturate it, which puts decoded vertices on the points.
MAX_S_STEP = 1.0
MAX_C_STEP = 4.0
# Fractional position grids (`fractional_grid`): scales in [MIN_GRID_SCALE, 1], effective bits in steps of
# 1 / FRACTIONAL_BITS_DENOMINATOR.
MIN_GRID_SCALE = 0.5
FRACTIONAL_BITS_DENOMINATOR = 8


def _is_tensor(x) -> bool:
    return type(x).__module__.startswith("torch")


def check_bits(bits: int) -> int:
    """Return `bits` if it is a supported position resolution (6..16 bits per axis), else raise ValueError."""
    if isinstance(bits, bool) or not isinstance(bits, (int, np.integer)):
        raise ValueError(f"position bits must be an integer, got {bits!r}")
    if not POSITION_BITS_MIN <= int(bits) <= POSITION_BITS_MAX:
        raise ValueError(f"position bits must be in {POSITION_BITS_MIN}..{POSITION_BITS_MAX}, got {bits}")
    return int(bits)


def cell_size(bits: int) -> float:
    """Edge length of a position cell: ``2 * GRID_BOUND / 2**bits`` (exact: 2.4 scaled by a power of two)."""
    return 2.0 * GRID_BOUND / float(1 << check_bits(bits))


# -----------------------------------------------------------------------------------------------------------
# positions


def check_grid_scale(scale: float) -> float:
    """Return `scale` if it is a valid grid scale (see `quantize_positions`), else raise ValueError."""
    scale = float(scale)
    if not MIN_GRID_SCALE <= scale <= 1.0:
        raise ValueError(f"the grid scale must be in [{MIN_GRID_SCALE}, 1], got {scale}")
    return scale


def fractional_grid(effective_bits: float) -> tuple[int, float]:
    """(bits, scale) of a grid of `effective_bits` = bits + log2(scale) per axis, scale in (1/2, 1].

    A scale below 1 is a continuous resolution between two integer grids: the points, multiplied by `scale`
    before they are stored on the 2**bits grid, cover part of the grid's cube, and the file's transform divides
    the scale out again (formats/README.md: the decoder sees an ordinary file). Effective bits are rounded to
    1/FRACTIONAL_BITS_DENOMINATOR so that the same request always gives the same grid.
    """
    t = round(float(effective_bits) * FRACTIONAL_BITS_DENOMINATOR) / FRACTIONAL_BITS_DENOMINATOR
    bits = int(np.ceil(t))
    return check_bits(bits), check_grid_scale(2.0 ** (t - bits))


def quantize_positions(points, bits: int, scale: float = 1.0):
    """Cell index of each point: ``floor((scale * x + GRID_BOUND) / cell)`` clamped to ``[0, 2**bits - 1]``.

    points: (N, 3) float array or tensor. scale: the grid scale (1: the plain grid; below 1 a coarser
    effective grid, `fractional_grid`). Returns int64 (N, 3) (a long tensor for tensor input).
    """
    top = (1 << check_bits(bits)) - 1
    cell = cell_size(bits)
    if _is_tensor(points):
        if scale != 1.0:
            points = points * check_grid_scale(scale)
        return ((points + GRID_BOUND) / cell).floor().clamp(0, top).long()
    p = np.asarray(points, dtype=np.float64)
    if scale != 1.0:
        p = p * check_grid_scale(scale)
    if not np.isfinite(p).all():
        raise ValueError("points must be finite")
    return np.clip(np.floor((p + GRID_BOUND) / cell), 0, top).astype(np.int64)


def dequantize_positions(cells, bits: int, scale: float = 1.0):
    """Cell centres: ``((2k + 1 - 2**bits) * 1.2) / 2**bits`` in float64 (bit-exact, see formats/README.md),
    divided by the grid scale when it is not 1 (the fit's frame; the decoder always uses scale 1).

    cells: (N, 3) integer array or tensor. Returns float64 (N, 3) (a float64 tensor for tensor input).
    """
    n = 1 << check_bits(bits)
    if _is_tensor(cells):
        import torch

        k = cells.to(torch.float64)
        out = ((2.0 * k + (1.0 - n)) * GRID_BOUND) / n
    else:
        k = np.asarray(cells, dtype=np.int64)
        if k.size and (k.min() < 0 or k.max() >= n):
            raise ValueError(f"cell indices must be in [0, {n - 1}]")
        out = ((2 * k + (1 - n)).astype(np.float64) * GRID_BOUND) / n
    return out if scale == 1.0 else out / check_grid_scale(scale)


def _spread3(v: np.ndarray) -> np.ndarray:
    """Insert two zero bits between the low 16 bits of each value (bit i -> bit 3i)."""
    v = v.astype(np.uint64) & np.uint64(0xFFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x00FF0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0xF00F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x30C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x9249249249249249)
    return v


def morton_keys(cells) -> np.ndarray:
    """Morton code of each cell (uint64): bits of x, y, z interleaved, x most significant within each level."""
    k = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    return (_spread3(k[:, 0]) << np.uint64(2)) | (_spread3(k[:, 1]) << np.uint64(1)) | _spread3(k[:, 2])


def canonical_order(cells, bits: int | None = None) -> np.ndarray:
    """Permutation that sorts cells into the octree decoder's order (ascending Morton code, stable).

    cells: (N, 3) integer array in ``[0, 2**bits)`` (bits only validates the range). Returns int64 (N,).
    Equal cells keep their input order.
    """
    k = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    if bits is not None:
        top = 1 << check_bits(bits)
        if k.size and (k.min() < 0 or k.max() >= top):
            raise ValueError(f"cell indices must be in [0, {top - 1}]")
    return np.argsort(morton_keys(k), kind="stable").astype(np.int64)


def merge_collisions(cells) -> tuple[np.ndarray, np.ndarray]:
    """Merge points that fall into the same cell; the first occurrence (lowest input index) wins.

    Returns (unique_cells (M, 3) int64 in canonical order, first (M,) int64: input index of each kept cell's
    first occurrence). ``cells[first] == unique_cells``; gather every per-point attribute with ``first``.
    """
    k = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    keys = morton_keys(k)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    keep = np.ones(len(order), dtype=bool)
    keep[1:] = sorted_keys[1:] != sorted_keys[:-1]
    first = order[keep].astype(np.int64)
    return k[first], first


# -----------------------------------------------------------------------------------------------------------
# base signed distance s


def quantize_s(s, step: float):
    """Mid-rise symbols ``floor(s / step)`` clamped to ``[-S_SYMBOL_LIMIT, S_SYMBOL_LIMIT - 1]`` (s < 0 <=> k < 0)."""
    step = _check_step(step, "s step")
    if _is_tensor(s):
        return (s / step).floor().clamp(-S_SYMBOL_LIMIT, S_SYMBOL_LIMIT - 1).long()
    x = np.asarray(s, dtype=np.float64)
    if not np.isfinite(x).all():
        raise ValueError("s must be finite")
    return np.clip(np.floor(x / step), -S_SYMBOL_LIMIT, S_SYMBOL_LIMIT - 1).astype(np.int64)


def dequantize_s(sym, step: float):
    """Values ``(k + 0.5) * step`` in float64 (never 0; negative exactly when k < 0)."""
    step = _check_step(step, "s step")
    if _is_tensor(sym):
        import torch

        return (sym.to(torch.float64) + 0.5) * step
    return (np.asarray(sym, dtype=np.int64).astype(np.float64) + 0.5) * step


# -----------------------------------------------------------------------------------------------------------
# SH coefficients c


def sh_band(j: int) -> int:
    """SH band l of coefficient index j (``l = floor(sqrt(j))``)."""
    return int(np.floor(np.sqrt(j) + 1e-9))


def c_steps(sh_degree: int, band_steps) -> np.ndarray:
    """Per-coefficient steps (q,) float64 from one step per band ``l = 0..sh_degree`` (q = num_coeffs)."""
    degree = check_degree(sh_degree)
    steps = np.asarray(band_steps, dtype=np.float64).reshape(-1)
    if steps.shape != (degree + 1,):
        raise ValueError(f"need {degree + 1} band steps for SH degree {degree}, got {steps.shape[0]}")
    steps = np.array([_check_step(st, "c step") for st in steps], dtype=np.float64)
    bands = np.array([sh_band(j) for j in range(num_coeffs(degree))], dtype=np.int64)
    return steps[bands]


def quantize_c(c, steps):
    """Symbols ``round(c / step_j)`` (half to even) clamped to ``[-C_SYMBOL_LIMIT, C_SYMBOL_LIMIT]``.

    c: (N, q); steps: (q,) from `c_steps`. Returns int64 (N, q) (long tensor for tensor input).
    """
    st = np.asarray(steps, dtype=np.float64).reshape(-1)
    if _is_tensor(c):
        import torch

        st_t = torch.as_tensor(st, dtype=c.dtype, device=c.device)
        return (c / st_t).round().clamp(-C_SYMBOL_LIMIT, C_SYMBOL_LIMIT).long()
    x = np.asarray(c, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != st.shape[0]:
        raise ValueError(f"c must be (N, {st.shape[0]}), got {x.shape}")
    if not np.isfinite(x).all():
        raise ValueError("c must be finite")
    return np.clip(np.round(x / st), -C_SYMBOL_LIMIT, C_SYMBOL_LIMIT).astype(np.int64)


def dequantize_c(sym, steps):
    """Values ``k * step_j`` in float64, (N, q)."""
    st = np.asarray(steps, dtype=np.float64).reshape(-1)
    if _is_tensor(sym):
        import torch

        return sym.to(torch.float64) * torch.as_tensor(st, dtype=torch.float64, device=sym.device)
    k = np.asarray(sym, dtype=np.int64)
    if k.ndim != 2 or k.shape[1] != st.shape[0]:
        raise ValueError(f"c symbols must be (N, {st.shape[0]}), got {k.shape}")
    return k.astype(np.float64) * st


def stored_step(step) -> float:
    """A step as the container stores it: rounded to float32 (every quantizer here uses this value)."""
    with np.errstate(over="ignore"):
        st = float(np.float32(float(step)))
    if not (np.isfinite(st) and st >= MIN_STEP):
        raise ValueError(f"steps must be finite and >= {MIN_STEP:g} (as float32), got {step}")
    return st


def step_problem(name: str, step: float, largest: float) -> str | None:
    """Why a stored s or c step (float32 widened) is invalid in a version-2 file, or None: it must be finite, at
    least MIN_STEP and at most `largest` (MAX_S_STEP or MAX_C_STEP)."""
    if not (np.isfinite(step) and MIN_STEP <= step <= largest):
        return f"{name} {step:g} (must be finite, in [2^-126, {largest:g}])"
    return None


def _check_step(step, name: str) -> float:
    try:
        return stored_step(step)
    except ValueError:
        raise ValueError(f"{name} must be finite and >= {MIN_STEP:g} (as float32), got {step}") from None


@dataclass(frozen=True)
class Quantization:
    """How the container v2 quantizes what the fit found (the functions above apply it).

    position_bits: b, 2^b grid cells per axis over the fixed cube (GRID_BOUND).
    s_step: step of the sign-preserving mid-rise quantizer of s (normalized-frame units).
    c_band_steps: step of the SH coefficients of band l = 0, 1, 2, 3.
    grid_scale: k in [1/2, 1]: the points are stored as k x their normalized positions, on the 2^b grid (the
    file's transform divides k out), an effective resolution of b + log2 k bits between two integer grids
    (`fractional_grid`).
    """

    position_bits: int = 9
    s_step: float = 3e-4
    c_band_steps: tuple[float, float, float, float] = (0.2, 0.2, 0.2, 0.2)
    grid_scale: float = 1.0


def default_quantization(points: int) -> Quantization:
    """Container v2's defaults for a fit of `points` grid points: a plain function of the options.

    Chosen with benchmarks/bitstream.py --sweep (quantization-aware finish after the settle phase; bits per kept
    point with headers; Chamfer relative to the same fit stored as v1):

    =========  =====================  =====================  =====================
    4K points  fandisk                spot                   stanford-bunny
    =========  =====================  =====================  =====================
    b 8        20.7 bits, 1.91x       20.9 bits, 1.10x       22.4 bits, 1.08x
    b 9        23.6 bits, 1.61x       24.0 bits, 1.04x       25.4 bits, 1.05x
    b 10       26.7 bits, 1.54x       27.0 bits, 1.05x       28.5 bits, 1.02x
    b 9 s 4e-4 24.4 bits, 1.46x       24.7 bits, 1.04x       26.2 bits, 1.05x
    b 9 c 0.3  22.4 bits, 1.67x       22.6 bits, 1.09x       23.9 bits, 1.06x
    =========  =====================  =====================  =====================

    (s step 7e-4 and c step 0.2 unless given.) At 16K: fandisk b 9 / 10 / 11 (s 3e-4): 20.3 / 23.3 / 26.3 bits,
    1.32x / 1.17x / 1.13x; b 10 with s 2e-4: 24.0 bits, 1.08x; spot b 9 / 10 / 11: 1.06x / 1.03x / 1.02x, s 2e-4
    1.01x. Each grid bit costs 3 bits per point; s steps matter on CAD shapes (fandisk), whose fits are the most
    accurate; c steps of 0.3 instead of 0.2 save 1.4 bits per point at 4K for 1-5 % of error.

    Those tables compare errors at equal points. At equal *bytes* a grid one bit coarser than the tables suggest
    wins: rate-controlled files (`encode(size=..)`, s prediction on), bytes x Chamfer (lower is better), the
    grid from floor(9.5 + ...) against floor(8.5 + ...) with the bytes-per-point model lowered by 12 % so that
    the saved position bits buy points: spot 10 KB 5.38 -> 4.89, spot 40 KB 5.90 -> 5.43, fandisk 20 KB 3.69 ->
    3.47, stanford-bunny 20 KB 15.99 -> 15.83, fandisk 5 KB 3.99 -> 4.05 (rate control kept b 8 there). Two bits
    coarser was mixed (spot 10 KB 4.74, fandisk 20 KB 3.88, bunny 20 KB 14.67).
    """
    ratio = max(points, 1) / 4096.0
    bits = int(min(16, max(6, math.floor(8.5 + 0.5 * math.log2(ratio)))))
    c_step = 0.3 * ratio**-0.3
    return Quantization(position_bits=bits, s_step=5e-4 * ratio**-0.66, c_band_steps=(c_step,) * 4)
