"""--size: the file is at most `size` bytes and at least SIZE_FLOOR of it.

The point count comes from a bytes-per-point model (`bytes_per_point`), at steps made finer for inputs a coarse
decimation already holds (CAD parts: `step_factor` of the prior's detail measure); after the main stage the
position grid and the steps are chosen from the exact packed sizes of the finalized points (positions are exact;
s and c are estimated from their values before the late stage); after the one late stage the steps are nudged,
without another late stage, until the file lands in the band. The grid layout searches the cell size instead
(`_grid_to_size`). Measurements behind the constants: docs/measurements/rate_control_calibration.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from tetweave_codec.errors import InputError
from tetweave_codec.fit.finish import FinishResult, complete, finalize, requantize
from tetweave_codec.fit.loop import deterministic_torch
from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.quantize import Quantization, default_quantization
from tetweave_codec.rate_control.prior import input_detail

# v2 bytes per fitted grid point at the default quantization (kept fraction x bits per kept point / 8), after s
# prediction and with the grid one bit coarser (formats.quantize.default_quantization), measured with
# benchmarks/bitstream.py on the four development meshes.
BYTES_PER_POINT_4K = 2.1
BYTES_PER_POINT_16K = 1.95
SIZE_FLOOR = 0.85  # the smallest acceptable fraction of a size target
SIZE_AIM = 0.93  # where the estimate before the late stage aims, inside [SIZE_FLOOR, 1]
MIN_RATE_POINTS = 128
MAX_RATE_POINTS = 65536  # the largest fit rate control runs (several minutes on 2 CPU cores)
# The largest grid-layout --size file's point count: its late stage alone (~3 s per 1K points on 2 cores) is
# cheaper than a fit, and its points are ~2x denser in bytes (a 40 KB fandisk needs 70K+).
GRID_MAX_RATE_POINTS = 262144
MIN_FILE_BYTES = 200  # below this no useful TetWeave file exists (header alone: ~73 bytes)
# Position grids tried after the main stage: the default one and one bit either side, within the container's range.
GRID_BITS_AROUND = (-1, 0, 1)
MIN_POSITION_BITS, MAX_POSITION_BITS = 6, 16
# Step multipliers tried on s (and c with them) around the default, from coarse to fine.
STEP_SCALES = (2.8, 2.0, 1.4, 1.0, 0.7, 0.5)
# The largest step multiplier `_choose` takes before a grid one bit coarser: igea 20 KB (9,479 points, b 9) fitted
# only at steps x2.8 on the default grid, where b 8 at x1 gave 3 % fewer bytes and 1 % less error from the same
# main stage. None: the default grid at any multiplier up to DEFAULT_GRID_MAX_STEP_SCALE first.
BALANCED_STEP_SCALE: float | None = 1.4
DEFAULT_GRID_MAX_STEP_SCALE = 2.0
# Precision of --size files of shapes a coarse decimation already holds (piecewise-flat and CAD parts): the s and
# c steps are multiplied by k <= 1, log2 k = PRECISION_SLOPE * (D - PRECISION_KNEE) of the prior's detail measure D
# (rate_control.prior.input_detail), at least log2 MIN_STEP_FACTOR: k = 1 from spot's D (1.30) up, fandisk (0.17)
# gets 0.40. Such fits are accurate enough that the s step, not the point count, sets their error; the point count
# pays for the finer steps, S_BYTES_PER_HALVING bytes per point per halving. The factor ramps in between
# PRECISION_RAMP_POINTS (log scale): below, fewer points cost the creases more than finer steps buy. --max-error
# keeps the default steps.
PRECISION_KNEE = 1.27
PRECISION_SLOPE = 1.2
MIN_STEP_FACTOR = 0.35
PRECISION_RAMP_POINTS = (6144, 8192)
S_BYTES_PER_HALVING = 0.19
# `points_for_size` iterates n = aim / bytes_per_point(n) to its fixed point in this many steps.
POINTS_FIXED_POINT_STEPS = 8
# Nudging into the band after the late stage (`_fit_band`): each try multiplies (coarser) or divides (finer) the
# steps by BAND_STEP_FACTOR, at most BAND_COARSER_TRIES coarser or BAND_FINER_TRIES finer tries.
BAND_STEP_FACTOR = 1.15
BAND_COARSER_TRIES = 40
BAND_FINER_TRIES = 20
# The grid layout's cell search stops when the estimate is within this relative distance (log) of the aim.
GRID_SIZE_TOLERANCE = 0.02


@dataclass(frozen=True)
class Candidate:
    """A quantization tried on the finalized points of a --size fit: `estimate` bytes of the file it would pack
    (s and c estimated from their values before the late stage), at `position_bits` and steps `scale` x the
    default."""

    estimate: int
    position_bits: int
    scale: float
    quantization: Quantization


def bytes_per_point(points: int) -> float:
    """Model of the v2 bytes per fitted grid point at the default quantization (log-linear in the points)."""
    t = min(max(math.log2(max(points, 1) / 4096.0) / 2.0, -1.0), 2.0)
    return BYTES_PER_POINT_4K + (BYTES_PER_POINT_16K - BYTES_PER_POINT_4K) * t


def step_factor(detail: float, points: int) -> float:
    """The factor k <= 1 on the default s and c steps of a --size fit of `points` points of an input whose prior
    detail measure is `detail` (see PRECISION_KNEE); 1 for inf (unknown) and below the ramp."""
    full = min(max(PRECISION_SLOPE * (detail - PRECISION_KNEE), math.log2(MIN_STEP_FACTOR)), 0.0)
    lo, hi = PRECISION_RAMP_POINTS
    ramp = min(max(math.log2(max(points, 1) / lo) / math.log2(hi / lo), 0.0), 1.0)
    return 2.0 ** (full * ramp)


def points_for_size(size: int, detail: float = math.inf) -> int:
    """The grid point count whose file should be about SIZE_AIM * size bytes, at the steps of `step_factor`
    (the default steps when `detail` is not given)."""

    def per_point(n: int) -> float:
        return bytes_per_point(n) - S_BYTES_PER_HALVING * math.log2(step_factor(detail, n))

    n = SIZE_AIM * size / per_point(4096)
    for _ in range(POINTS_FIXED_POINT_STEPS):  # fixed point of n = aim / per_point(n)
        n = SIZE_AIM * size / per_point(int(n))
    return int(n)


def size_quantization(points: int, size: int, detail: float) -> Quantization:
    """The quantization a --size fit of `points` points starts from: `default_quantization(points)` with steps x
    `step_factor`, on a grid no coarser than that of the point count at the default steps (the finer steps take
    points away; fandisk 5 KB: 1,958 points on a grid one bit coarser, +39 % bytes x Chamfer)."""
    base = default_quantization(points)
    bits = max(base.position_bits, default_quantization(points_for_size(size)).position_bits)
    return scaled(base, step_factor(detail, points), bits)


def scaled(quant: Quantization, scale: float, bits: int | None = None) -> Quantization:
    """quant with its s and c steps multiplied by `scale` (and other position bits), each kept within what the
    container stores (formats.quantize: [MIN_STEP, MAX_S_STEP] and [MIN_STEP, MAX_C_STEP] as float32). The one
    place rate control proposes steps: a step the container refuses would end the encode after its fit."""
    return replace(
        quant,
        position_bits=quant.position_bits if bits is None else bits,
        s_step=_storable(quant.s_step * scale, Q.MAX_S_STEP),
        c_band_steps=tuple(_storable(st * scale, Q.MAX_C_STEP) for st in quant.c_band_steps),
    )


def _storable(step: float, largest: float) -> float:
    """`step` clamped into [MIN_STEP, largest]; both ends are float32 numbers, so the file's float32 rounding of the
    step stays inside too."""
    return min(max(float(step), Q.MIN_STEP), largest)


def encode_to_size(job, size: int, *, measure: bool = True):
    """The best file of at most `size` bytes (and at least SIZE_FLOOR * size) this fit can make."""
    if size < MIN_FILE_BYTES:
        raise InputError(f"a size of {size:,} bytes is below the smallest useful .tw file ({MIN_FILE_BYTES} bytes)")
    if job.layout == "grid":
        return _grid_to_size(job, size, measure)
    detail = input_detail(job)
    points = points_for_size(size, detail)
    if points > MAX_RATE_POINTS:
        largest = int(MAX_RATE_POINTS * bytes_per_point(MAX_RATE_POINTS))
        raise InputError(
            f"a size of {size:,} bytes needs more than the {MAX_RATE_POINTS:,} points rate control fits "
            f"(~{largest:,} bytes); use --points for larger files"
        )
    points = max(points, MIN_RATE_POINTS)
    ctx, result, packed, label = _fit_for_size(job, size, points, detail)
    _check_band(result, packed, size)
    extra = {"target_bytes": size, "rate_control": label}
    return job.result(result, ctx, points, measure=measure, data=packed.data, decoded=packed.decoded, extra=extra)


def _fit_for_size(job, size: int, points: int, detail: float):
    """One --size fit of `points` points: main stage, the quantization chosen from exact packed sizes (`choose`),
    the late stage and `_fit_band`'s nudging. Returns (context, FinishResult, packing.Packed, rate-control label)."""
    base = size_quantization(points, size, detail)
    ctx, params = job.main_stage(points, base)
    sh_degree = job.settings.sh_degree

    # Positions are final once snapped: their section's size is exact. Try the default grid and one bit either
    # side, with s and c steps scaled, and keep the largest estimate below SIZE_AIM * size.
    with deterministic_torch():
        candidates = []
        finals = {}
        for bits in (base.position_bits + d for d in GRID_BITS_AROUND):
            if not MIN_POSITION_BITS <= bits <= MAX_POSITION_BITS:
                continue
            fin = finalize(params, ctx, bits)
            finals[bits] = fin
            for scale in STEP_SCALES:
                quant = scaled(base, scale, bits)
                est = len(job.pack(requantize(fin.points, fin.cells, fin.s, fin.c, quant, sh_degree), ctx))
                candidates.append(Candidate(est, bits, scale, quant))
        chosen = choose(candidates, base, size)
        bits, scale = chosen.position_bits, chosen.scale
        result = complete(finals[bits], ctx, chosen.quantization)
    result, packed = _fit_band(job, ctx, result, job.packed(result, ctx), size)
    return ctx, result, packed, f"{points} points, b {bits}, steps x{scale:g}"


def choose(candidates: list[Candidate], base: Quantization, size: int) -> Candidate:
    """The quantization a --size fit is finished with: steps at most BALANCED_STEP_SCALE x the default, on the
    default grid if it fits there, else on another (in practice one bit coarser); failing that the default grid
    up to DEFAULT_GRID_MAX_STEP_SCALE (a finer grid buys little error, see default_quantization), then the largest
    estimate under the aim, then the smallest file."""
    fitting = [c for c in candidates if c.estimate <= SIZE_AIM * size]
    if BALANCED_STEP_SCALE is not None:
        balanced = [c for c in fitting if c.scale <= BALANCED_STEP_SCALE]
        on_default = [c for c in balanced if c.position_bits == base.position_bits]
        if on_default or balanced:
            return max(on_default or balanced, key=lambda c: c.estimate)
    on_default = [
        c for c in fitting if c.position_bits == base.position_bits and c.scale <= DEFAULT_GRID_MAX_STEP_SCALE
    ]
    if on_default:
        return max(on_default, key=lambda c: c.estimate)
    if fitting:
        return max(fitting, key=lambda c: c.estimate)
    return min(candidates, key=lambda c: c.estimate)


def _grid_to_size(job, size: int, measure: bool):
    """--size with the grid layout (fit.grid): the cell size whose band, s its signed distance quantized with the
    grid's steps, packs closest below SIZE_AIM * size (secant steps in log-log: bytes fall about as cell^-2; each
    estimate is a band query and a pack, no fit), then the late stage and the step nudging of `_fit_band`."""
    from tetweave_codec.fit.grid import GRID_SIZE_SEARCH_STEPS, frame_for_cell
    from tetweave_codec.geometry.delaunay import resolve_backend
    from tetweave_codec.geometry.sh import num_coeffs
    from tetweave_codec.job import grid_layout_stage, grid_quantization

    band = job.grid_band()
    backend = resolve_backend("auto")
    aim = SIZE_AIM * size
    settings = job.settings

    def estimate(cell: float) -> tuple[int, int]:
        frame = frame_for_cell(cell)
        cells, s = band.cells(frame)
        if len(cells) < 4:
            return 0, len(cells)
        quant = grid_quantization(frame, len(cells))
        c = np.zeros((len(cells), num_coeffs(settings.sh_degree)))
        fin = requantize(Q.dequantize_positions(cells, frame.stored_bits), cells, s, c, quant, settings.sh_degree)
        data = job.packer.pack_as(
            fin, backend, frame.frame_scale, settings.smoothing, settings.subdivision, settings.creases
        )
        return len(data), len(cells)

    cell = math.sqrt(band.area / max(aim, 1.0))  # ~1 byte per point, ~2 band cells per cell^2 of area
    tried: dict[float, tuple[int, int]] = {}
    for _ in range(GRID_SIZE_SEARCH_STEPS):
        tried[cell] = estimate(cell)
        est = tried[cell][0]
        if est <= 0 or abs(math.log(est / aim)) < GRID_SIZE_TOLERANCE:
            break
        cell *= math.sqrt(est / aim)
    under = [c for c, (est, n) in tried.items() if 0 < est <= aim and n <= GRID_MAX_RATE_POINTS]
    cell = max(under, key=lambda c: tried[c][0]) if under else min(tried, key=lambda c: abs(tried[c][0] - aim))
    points = tried[cell][1]
    if points > GRID_MAX_RATE_POINTS:
        raise InputError(
            f"a size of {size:,} bytes needs more than the {GRID_MAX_RATE_POINTS:,} points rate control fits in "
            "the grid layout; use --points for larger files"
        )
    ctx, fin, quant = grid_layout_stage(job, frame_for_cell(cell))
    with deterministic_torch():
        result = complete(fin, ctx, quant)
    result, packed = _into_band(job, ctx, result, job.packed(result, ctx), size)
    extra = {
        "target_bytes": size,
        "rate_control": f"grid layout, {points} points, b {quant.position_bits}, frame x{ctx.frame_scale:.4g}",
    }
    return job.result(result, ctx, points, measure=measure, data=packed.data, decoded=packed.decoded, extra=extra)


def _into_band(job, ctx, result: FinishResult, packed, size: int):
    """(FinishResult, packing.Packed) nudged by `_fit_band` into [SIZE_FLOOR * size, size]; InputError when that
    fails."""
    result, packed = _fit_band(job, ctx, result, packed, size)
    _check_band(result, packed, size)
    return result, packed


def _check_band(result: FinishResult, packed, size: int) -> None:
    """InputError (one line) unless the packed file is in [SIZE_FLOOR * size, size]; above it, the smallest file
    reached (`_fit_band`: the coarsest steps the container stores). A size near that number is not promised: another
    target chooses another quantization before the late stage, and the coarsest file of spot's 128-point fit was
    338 bytes at --size 200, 356 at --size 338 (2026-12-06)."""
    if len(packed.data) > size:
        raise InputError(
            f"could not meet a size of {size:,} bytes: the smallest file this input reached has {len(packed.data):,} "
            f"bytes ({result.s.shape[0]:,} points at the coarsest steps the container stores); ask for a larger size"
        )
    if len(packed.data) < SIZE_FLOOR * size:
        raise InputError(
            f"could not meet a size of {size:,} bytes: the closest file has {len(packed.data):,} bytes "
            f"({result.s.shape[0]:,} points); try another size or --points"
        )


def _fit_band(job, ctx, result: FinishResult, packed, size: int):
    """Requantize s and c (latent values, no refit) with scaled steps until the file is in [floor, size]."""
    quant = result.quantization
    sh_degree = job.settings.sh_degree

    def requantized(scale: float):
        trial = requantize(
            result.points, result.cells, result.latent_s, result.latent_c, scaled(quant, scale), sh_degree
        )
        return trial, job.packed(trial, ctx)

    if len(packed.data) > size:
        scale = 1.0
        smallest = (result, packed)
        for _ in range(BAND_COARSER_TRIES):  # coarser until it fits
            scale *= BAND_STEP_FACTOR
            if scaled(quant, scale) == scaled(quant, scale / BAND_STEP_FACTOR):
                break  # every step at the container's largest: nothing coarser to try
            trial, trial_packed = requantized(scale)
            if len(trial_packed.data) <= size:
                return trial, trial_packed
            if len(trial_packed.data) < len(smallest[1].data):
                smallest = (trial, trial_packed)
        return smallest
    best = (result, packed)
    scale = 1.0
    for _ in range(BAND_FINER_TRIES):  # finer while it still fits, until above the floor
        if len(best[1].data) >= SIZE_FLOOR * size:
            break
        scale /= BAND_STEP_FACTOR
        trial, trial_packed = requantized(scale)
        if len(trial_packed.data) > size:
            break
        best = (trial, trial_packed)
    return best
