"""Rate control: choose the point count and the quantization so that a file meets a size or an error target.

Two targets, each within about 1.5x the time of one fit at the chosen size:

* `encode_to_size(job, size)`: the file is at most `size` bytes and at least SIZE_FLOOR of it. The point count
  comes from a bytes-per-point model (BYTES_PER_POINT), at steps made finer for inputs a coarse decimation
  already holds (CAD parts: `step_factor` of the prior's detail measure); after the main stage the position grid
  and the steps are chosen from the exact packed sizes of the finalized points (positions are exact; s and c are
  estimated from their values before the late stage); after the one late stage the steps are nudged, without
  another late stage, until the file lands in the band.
* `encode_to_error(job, max_error)`: the decoded mesh's Chamfer distance (the summary's metric) is at most
  `max_error`. The first fit's point count comes from a per-mesh prior, err ~ P / N with P from the Chamfer
  distance of a quick decimation of the input (prior_error_points); the measured errors steer at most two more
  fits (shrink, grow, or interpolate between a fit that met the target and one that missed it). Coarser steps
  are then tried (without another late stage) while the error stays below the target, to save bytes.

A target out of reach raises InputError (the CLI prints one line and exits 2 without writing a file).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from tetweave_codec.errors import InputError
from tetweave_codec.fit.config import Quantization, default_quantization
from tetweave_codec.fit.finish import FinishResult, complete, finalize, requantize
from tetweave_codec.fit.loop import deterministic_torch
from tetweave_codec.fit.step import FitContext
from tetweave_codec.formats import quantize as Q

if TYPE_CHECKING:
    from tetweave_codec.decoder import DecodeResult

# v2 bytes per fitted grid point at the default quantization (kept fraction x bits per kept point / 8), measured
# with benchmarks/bitstream.py on the four development meshes before s prediction: 2.42-2.64 at 4K points,
# 2.19-2.54 at 16K; s prediction saves 1.2-1.5 bits per kept point at 4K and 1.6-2.4 at 16K (0.15-0.2 bytes).
# With the grid one bit coarser (fit.config.default_quantization) the model is 12 % lower.
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
# Prior of the error model err ~ PRIOR_ERROR_POINTS / N (normalized frame) before the input is looked at: N x
# Chamfer of default-quality fits (benchmarks/results/rate_control.md) is 1.6-1.9 on fandisk, 2.3-2.5 on spot,
# 4.8-6.1 on igea, 5.2-9.9 on stanford-bunny. Only the out-of-reach check before any work uses it; the first fit
# uses the per-mesh prior below.
PRIOR_ERROR_POINTS = 3.5
# Per-mesh prior err ~ P / N + F. P = PRIOR_BASE + PRIOR_DETAIL_SLOPE * max(0, D - PRIOR_DETAIL_KNEE), where D =
# M x the Chamfer distance of a quadric decimation of the input to M = PRIOR_PROBE_VERTICES vertices (~1 s on 270K
# faces). Why: a TetWeave fit of a smooth or piecewise-flat surface has an error ~ 1.5-2 / N of its own (its grid
# spacing; fandisk and spot, whose decimations are near exact, D = 0.17 and 1.3, fit at N x Chamfer 1.4-2.2);
# detail a thousand vertices cannot hold (scanned skin, bumps: igea D = 2.1, bunny D = 2.3) costs TetWeave extra
# points in proportion (igea 3.3-4.1, bunny 3.0-3.2 once F is taken off). F (hole_cap_error): the decoded mesh is
# closed, so every hole of an open input is capped; a flat cap of area A and radius r sits ~r/3 from the rim on
# average, which adds 0.5 * sum(A r / 3) / area to the Chamfer distance whatever N (stanford-bunny: 5 holes, 2.2 %
# of its area, F = 4.3e-4, where its fits stalled at 5.95e-4 with 19K points). Calibrated on the four development
# meshes with benchmarks/rate_control.py; the search below corrects a wrong prior with the measured errors.
# Recalibrated after the fit improved (normal term, iterations scaled with the points, relocation: issue 14): the
# first fits of that table then landed at 0.45-0.62 of the target (fandisk 2e-3 / 1e-3 / 5e-4: N x Chamfer 1.17 /
# 1.06 / 0.84 against P = 1.70; igea 2e-3: 2.38 against 3.69) and every search took a second, smaller fit (2.0-2.1x
# one fit's time for 14-34 % fewer bytes). x 0.65 then overshot at the large counts (igea 5e-4: err falls as
# N^-0.8 there) and the bunny's holes made its 1e-3 fit miss; x 0.72, and the first fit sized with half of F
# (FIRST_FIT_HOLE_SHARE; benchmarks/results/rate_control.md).
PRIOR_PROBE_VERTICES = 1000
# A subdivided fit (fit.config.FitConfig.subdivision > 0) is smooth between its points: its own error (the
# PRIOR_BASE part) is lower, its detail part the same. Chamfer at equal points, one Loop level against none:
# spot 0.67-0.81, stanford-bunny 0.89-0.95, igea 0.90-1.02 (benchmarks/results/subdivision.md).
SUBDIVIDED_BASE_FACTOR = 0.8
PRIOR_PROBE_SAMPLES = 20_000  # Chamfer samples of the probe (its resolution ~1e-5 is far below the targets)
PRIOR_BASE = 1.22
PRIOR_DETAIL_KNEE = 1.0
PRIOR_DETAIL_SLOPE = 1.3
FIRST_FIT_HOLE_SHARE = 0.5
PRIOR_ALPHA = 0.8  # err ~ N^-alpha when only one fit is known (a little below 1: ask for a few more points)
ERROR_AIM = 0.9  # aim the predicted error at this fraction of the target (the per-mesh prior is close)
ERROR_AIM_SHRINK = 0.75  # a smaller fit aims lower: the error grows faster than 1/N at small counts
ERROR_AIM_BRACKET = 0.9  # between a fit that met the target and one that missed it
CLOSE_ENOUGH = 0.75  # a fit within [CLOSE_ENOUGH, 1] x the target ends the search
MAX_ERROR_FITS = 3
PRIOR_SPREAD = 4.0  # refuse without fitting when the prior asks for more than this many times MAX_RATE_POINTS
# Step multipliers tried on s (and c with them) around the default, from coarse to fine.
STEP_SCALES = (2.8, 2.0, 1.4, 1.0, 0.7, 0.5)
# The largest step multiplier `_choose` takes before a grid one bit coarser: see `_choose`. None: the default grid
# at any multiplier up to 2.0 first (the rule before session 11).
BALANCED_STEP_SCALE: float | None = 1.4
# Precision of --size files of shapes a coarse decimation already holds (piecewise-flat and CAD parts): the s and
# c steps are multiplied by a factor k <= 1 of the prior's detail measure D (input_detail; fandisk 0.17, spot
# 1.30, igea 2.10, stanford-bunny 2.31, a cube 0): log2 k = PRECISION_SLOPE * (D - PRECISION_KNEE), at least
# log2 MIN_STEP_FACTOR, so k = 1 (the default steps) from spot's D up and fandisk gets k = 0.40. Why: such fits are
# accurate enough that the s step, not the point count, sets their error. fandisk at a fixed 9,479-point fit:
# steps x2 / x1 / x0.5 of the default gave 18.5 / 19.6 / 20.6 KB at Chamfer 1.30e-4 / 9.2e-5 / 7.7e-5, where 40 %
# more points buy ~30 %. The point count pays for the finer steps: S_BYTES_PER_HALVING per halving (measured
# 0.12-0.32 bytes per point on the shared meshes). The factor ramps in between PRECISION_RAMP_POINTS[0] and [1]
# fit points (log scale): below, fewer points cost the creases more than finer steps buy (fandisk 5 / 10 KB with
# k = 0.4: Chamfer within noise, edge Chamfer +61 % / +54 %; CSG parts at 1-2 KB: edge Chamfer worse at 5 of 7,
# though the cube at 2 KB fell from 7.6e-4 to 3.0e-5). --max-error keeps the default steps (measured on fandisk: -11 %
# bytes at 1e-4 but +5.5 % at 2e-4, where the finer fit met the target by a margin the search does not spend).
# benchmarks/results/rate_control.md, "Session 10".
PRECISION_KNEE = 1.27
PRECISION_SLOPE = 1.2
MIN_STEP_FACTOR = 0.35
PRECISION_RAMP_POINTS = (6144, 8192)
S_BYTES_PER_HALVING = 0.19


# --max-error on inputs with sharp creases first tries a feature-only fit: the feature-aware start at
# FEATURE_FIT_POINTS points (feature points, the box corners and the few fill points the crease clearance leaves),
# its points next to creases at plane distances, kept as the point set (no resampling or relocation), s steps
# FEATURE_FIT_STEP_SCALE x the default. Tried only when that start alone, decoded, is within FEATURE_FIT_START_SHARE
# of the target (a start costs ~1 s; a fit of 64 points ~25 s on one thread), and kept only when the fit meets it.
# Why: an exact start does not stay exact through the usual fit. A cube at 64 points: start Chamfer 3e-10 (26
# points), main stage with the resampling to 64 points 2.8e-3, without it 1.6e-4; the s step's rounding costs the
# rest (steps x1 / x0.25 / x0.1 / x0.03 / x0.01: 175 / 181 / 186 / 192 / 193 B at 4.9e-4 / 4.0e-4 / 1.6e-4 / 5.5e-5
# / 3.6e-5). The usual search sized a 1e-4 cube at ~13K points. Parts whose start is not near exact (three boxes:
# 8e-2 at 64 points; fandisk) skip it (benchmarks/results/creases.md, "Session 13").
FEATURE_FIT_POINTS = 64
FEATURE_FIT_STEP_SCALE = 0.03
FEATURE_FIT_START_SHARE = 0.5


@dataclass(frozen=True)
class Candidate:
    """A quantization tried on the finalized points of a --size fit: `estimate` bytes of the file it would pack
    (s and c estimated from their values before the late stage), at `position_bits` and steps `scale` x the
    default."""

    estimate: int
    position_bits: int
    scale: float
    quantization: Quantization


@dataclass
class Trial:
    """One full fit of a --max-error search at some point count: its context, finished symbols, bytes, the
    decoded mesh's Chamfer distance to the input and the decoder's result (`decoder.DecodeResult`)."""

    ctx: FitContext
    result: FinishResult
    data: bytes
    error: float
    decoded: DecodeResult


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
    for _ in range(8):  # fixed point of n = aim / per_point(n)
        n = SIZE_AIM * size / per_point(int(n))
    return int(n)


def size_quantization(points: int, size: int, detail: float) -> Quantization:
    """The quantization a --size fit of `points` points starts from: `default_quantization(points)` with steps x
    `step_factor`, on a grid no coarser than that of the point count at the default steps (the finer steps take
    points away; fandisk 5 KB: 1,958 points on a grid one bit coarser, +39 % bytes x Chamfer)."""
    base = default_quantization(points)
    bits = max(base.position_bits, default_quantization(points_for_size(size)).position_bits)
    return _scaled(base, step_factor(detail, points), bits)


def _scaled(quant: Quantization, scale: float, bits: int | None = None) -> Quantization:
    """quant with its s and c steps multiplied by `scale` (and other position bits)."""
    return replace(
        quant,
        position_bits=quant.position_bits if bits is None else bits,
        s_step=quant.s_step * scale,
        c_band_steps=tuple(st * scale for st in quant.c_band_steps),
    )


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
    base = size_quantization(points, size, detail)
    ctx, params = job.main_stage(points, base)

    # Positions are final once snapped: their section's size is exact. Try the default grid and one bit either
    # side, with s and c steps scaled, and keep the largest estimate below SIZE_AIM * size.
    with deterministic_torch():
        candidates = []
        finals = {}
        for bits in (base.position_bits - 1, base.position_bits, base.position_bits + 1):
            if not 6 <= bits <= 16:
                continue
            fin = finalize(params, ctx, bits)
            finals[bits] = fin
            for scale in STEP_SCALES:
                quant = _scaled(base, scale, bits)
                est = len(job.pack(requantize(fin.points, fin.cells, fin.s, fin.c, quant, job.sh_degree), ctx))
                candidates.append(Candidate(est, bits, scale, quant))
        chosen = _choose(candidates, base, size, finals, ctx, job)
        bits, scale = chosen.position_bits, chosen.scale
        result = complete(finals[bits], ctx, chosen.quantization)
    data = job.pack(result, ctx)
    result, data = _into_band(job, ctx, result, data, size)
    extra = {"target_bytes": size, "rate_control": f"{points} points, b {bits}, steps x{scale:g}"}
    return job.result(result, ctx, points, measure=measure, data=data, extra=extra)


def _choose(candidates: list[Candidate], base: Quantization, size: int, finals, ctx, job) -> Candidate:
    """The quantization a --size fit is finished with."""
    fitting = [c for c in candidates if c.estimate <= SIZE_AIM * size]
    if BALANCED_STEP_SCALE is not None:
        # Steps at most BALANCED_STEP_SCALE x the default, on the default grid if it fits there, else on another
        # (in practice one bit coarser): igea 20 KB (9,479 points, b 9) fitted only at steps x2.8 on the default
        # grid, where b 8 at x1 gave 3 % fewer bytes and 1 % less error from the same main stage.
        balanced = [c for c in fitting if c.scale <= BALANCED_STEP_SCALE]
        on_default = [c for c in balanced if c.position_bits == base.position_bits]
        if on_default or balanced:
            return max(on_default or balanced, key=lambda c: c.estimate)
    # Prefer the default grid when it fits at some step, since a finer grid buys little error (see
    # default_quantization); otherwise the largest estimate under the aim; otherwise the smallest file.
    on_default = [c for c in fitting if c.position_bits == base.position_bits and c.scale <= 2.0]
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

    band = job.grid_band()
    backend = resolve_backend("auto")
    aim = SIZE_AIM * size

    def estimate(cell: float) -> tuple[int, int]:
        frame = frame_for_cell(cell)
        cells, s = band.cells(frame)
        if len(cells) < 4:
            return 0, len(cells)
        quant = job.grid_quantization(frame, len(cells))
        c = np.zeros((len(cells), num_coeffs(job.sh_degree)))
        fin = requantize(Q.dequantize_positions(cells, frame.stored_bits), cells, s, c, quant, job.sh_degree)
        return len(job.pack_as(fin, backend, frame.frame_scale, job.smoothing, job.subdivision, job.creases)), len(
            cells
        )

    cell = math.sqrt(band.area / max(aim, 1.0))  # ~1 byte per point, ~2 band cells per cell^2 of area
    tried: dict[float, tuple[int, int]] = {}
    for _ in range(GRID_SIZE_SEARCH_STEPS):
        tried[cell] = estimate(cell)
        est = tried[cell][0]
        if est <= 0 or abs(math.log(est / aim)) < 0.02:
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
    ctx, fin, quant = job.grid_stage(frame_for_cell(cell))
    with deterministic_torch():
        result = complete(fin, ctx, quant)
    data = job.pack(result, ctx)
    result, data = _into_band(job, ctx, result, data, size)
    extra = {
        "target_bytes": size,
        "rate_control": f"grid layout, {points} points, b {quant.position_bits}, frame x{ctx.frame_scale:.4g}",
    }
    return job.result(result, ctx, points, measure=measure, data=data, extra=extra)


def _into_band(job, ctx, result: FinishResult, data: bytes, size: int) -> tuple[FinishResult, bytes]:
    """Nudge the steps (no refit) into [SIZE_FLOOR * size, size] (`_fit_band`); InputError when that fails."""
    result, data = _fit_band(job, ctx, result, data, size)
    if not SIZE_FLOOR * size <= len(data) <= size:
        raise InputError(
            f"could not meet a size of {size:,} bytes: the closest file has {len(data):,} bytes "
            f"({result.s.shape[0]:,} points); try another size or --points"
        )
    return result, data


def _fit_band(job, ctx, result: FinishResult, data: bytes, size: int) -> tuple[FinishResult, bytes]:
    """Requantize s and c (latent values, no refit) with scaled steps until the file is in [floor, size]."""
    quant = result.quantization
    best = (result, data) if len(data) <= size else None
    if len(data) > size:
        scale = 1.0
        for _ in range(40):  # coarser until it fits
            scale *= 1.15
            trial = requantize(
                result.points, result.cells, result.latent_s, result.latent_c, _scaled(quant, scale), job.sh_degree
            )
            trial_data = job.pack(trial, ctx)
            if len(trial_data) <= size:
                return trial, trial_data
        return result, data
    scale = 1.0
    for _ in range(20):  # finer while it still fits, until above the floor
        if len(best[1]) >= SIZE_FLOOR * size:
            break
        scale /= 1.15
        trial = requantize(
            result.points, result.cells, result.latent_s, result.latent_c, _scaled(quant, scale), job.sh_degree
        )
        trial_data = job.pack(trial, ctx)
        if len(trial_data) > size:
            break
        best = (trial, trial_data)
    return best


def encode_to_error(job, max_error: float):
    """The smallest file this fit finds whose decoded mesh is within `max_error` (Chamfer) of the input.

    A search over point counts in log-log space, at most MAX_ERROR_FITS fits: the first count comes from the prior
    err ~ prior_error_points(job) / N; while every fit met the target the next shrinks (err ~ N^-1, aiming at
    ERROR_AIM_SHRINK of it), while none did the next grows (err ~ N^-PRIOR_ALPHA, aiming at ERROR_AIM); once one
    fit met it and one missed, the next interpolates between them. It stops when a fit lands in
    [CLOSE_ENOUGH, 1] x the target. Coarser steps are then tried on the smallest fit that met it.
    """
    from tetweave_codec.decoder import decode_detailed

    if not (math.isfinite(max_error) and max_error > 0):
        raise InputError(f"the maximum error must be a positive number, got {max_error}")
    aim = ERROR_AIM * max_error
    if PRIOR_ERROR_POINTS / aim > PRIOR_SPREAD * MAX_RATE_POINTS:
        raise InputError(
            f"a maximum error of {max_error:.3g} is out of reach: meshes typically need about "
            f"{int(min(PRIOR_ERROR_POINTS / aim, 1e12)):,} points for it "
            f"(rate control fits at most {MAX_RATE_POINTS:,})"
        )
    runs: dict[int, Trial] = {}
    prior, floor = mesh_prior(job)
    first = prior / (aim - floor) if aim > floor else math.inf
    if first > MAX_RATE_POINTS:
        holes = f"its holes, capped by the fit, alone cost ~{floor:.2g}; " if floor > 0 else ""
        raise InputError(
            f"a maximum error of {max_error:.3g} is out of reach: this mesh needs about "
            f"{int(min(first, 1e12)):,} points for it by its prior ({holes}rate control fits at most "
            f"{MAX_RATE_POINTS:,})"
        )
    # After the refusals above: a target the prior puts out of reach is out of reach of 64 points too.
    feature_fit = _feature_only_trial(job, max_error, decode_detailed)
    if feature_fit is not None:
        return _smallest_within(job, feature_fit, max_error, FEATURE_FIT_POINTS, decode_detailed, "feature-only fit")
    # The first fit is sized with part of F: P's decimation probe already carries part of the holes' cost, so
    # P / N + F counted it twice and overshot (stanford-bunny: first fits at 0.75-0.82 of the target, files +16 % /
    # +58 % at 2e-3 / 1e-3); without F the bunny's 1e-3 fit missed once P was recalibrated.
    n = _clamp_points(prior / max(aim - FIRST_FIT_HOLE_SHARE * floor, 0.5 * aim))
    for _ in range(MAX_ERROR_FITS):
        runs[n] = _fit_and_measure(job, n, default_quantization(n), decode_detailed)
        met = sorted(k for k, r in runs.items() if r.error <= max_error)
        missed = sorted(k for k, r in runs.items() if r.error > max_error)
        if met and runs[met[0]].error >= CLOSE_ENOUGH * max_error:
            break
        if met and missed and missed[-1] < met[0]:  # bracketed: interpolate in log-log
            lo, hi = missed[-1], met[0]
            if hi <= lo * 1.15:
                break
            e_lo, e_hi = runs[lo].error, runs[hi].error
            t = math.log(e_lo / (ERROR_AIM_BRACKET * max_error)) / math.log(e_lo / e_hi)
            nxt = int(round(math.exp(math.log(lo) + min(max(t, 0.2), 0.8) * math.log(hi / lo))))
        elif met:  # every fit met it, with a margin: shrink
            nxt = _clamp_points(met[0] * runs[met[0]].error / (ERROR_AIM_SHRINK * max_error))
            if nxt >= met[0] * 0.85:
                break
        else:  # none met it: grow
            top = missed[-1]
            nxt = _needed(top * (runs[top].error / aim) ** (1.0 / PRIOR_ALPHA), max_error, top, runs[top].error)
        if nxt in runs:
            break
        n = nxt
    met = sorted(k for k, r in runs.items() if r.error <= max_error)
    if not met:
        top = max(runs)
        raise InputError(
            f"could not reach a maximum error of {max_error:.3g}: {top:,} points reached {runs[top].error:.3g}"
        )
    exponent = _exponent(runs, PRIOR_ALPHA)
    return _smallest_within(job, runs[met[0]], max_error, met[0], decode_detailed, f"error exponent {exponent:.2f}")


def _feature_only_trial(job, max_error: float, decode) -> Trial | None:
    """The feature-only fit (FEATURE_FIT_POINTS) when the input has sharp creases, its start alone is near the
    target and the fit meets it; else None."""
    if job.layout != "fit" or job.init != "sdf":
        return None
    from tetweave_codec.decoder import mesh_from_points
    from tetweave_codec.fit.features import detect_features
    from tetweave_codec.fit.initialize import initial_state_pinned

    if not detect_features(job.normalized, job.f).found:
        return None
    n = FEATURE_FIT_POINTS
    quant = _scaled(default_quantization(n), FEATURE_FIT_STEP_SCALE)
    points, s, _, pinned = initial_state_pinned(
        job.normalized, job.f, n, -1, job.seed, True, quant.position_bits, quant.grid_scale, plane_distances=True
    )
    if not pinned.any():
        return None
    v, f = mesh_from_points(points.astype(np.float64), s, None, -1)
    if job.chamfer(v * job.scale + job.offset, f) > FEATURE_FIT_START_SHARE * max_error:
        return None
    trial = _fit_and_measure(job, n, quant, decode, feature_only=True)
    return trial if trial.error <= max_error else None


def mesh_prior(job) -> tuple[float, float]:
    """(P, F) of the per-mesh prior err ~ P / N + F of this job's input (see PRIOR_BASE)."""
    return prior_error_points(job), 0.0 if job.rim is not None else hole_cap_error(job.normalized, job.f)


def prior_error_points(job) -> float:
    """P of the per-mesh prior err ~ P / N + F (see PRIOR_BASE), from `input_detail`."""
    base = PRIOR_BASE * (SUBDIVIDED_BASE_FACTOR if job.subdivision else 1.0)
    detail = input_detail(job)
    if not math.isfinite(detail):
        return PRIOR_ERROR_POINTS
    return base + PRIOR_DETAIL_SLOPE * max(0.0, detail - PRIOR_DETAIL_KNEE)


def input_detail(job) -> float:
    """D of the prior: PRIOR_PROBE_VERTICES x the Chamfer distance (normalized frame) of a quadric decimation of
    the input to that many vertices (fast_simplification, deterministic); 0 for an input already that coarse, inf
    when the decimation leaves nothing. Computed once per job (`job.detail`)."""
    if job.detail is not None:
        return job.detail
    import fast_simplification

    from tetweave_codec.metrics import chamfer_distance

    v, f = job.normalized, job.f
    if len(v) <= 2 * PRIOR_PROBE_VERTICES:  # already coarse: no detail beyond what a fit resolves
        job.detail = 0.0
        return job.detail
    reduction = 1.0 - 2.0 * PRIOR_PROBE_VERTICES / len(f)
    dv, df = fast_simplification.simplify(
        np.ascontiguousarray(v, dtype=np.float32), np.ascontiguousarray(f, dtype=np.int32), reduction
    )
    if not len(df):
        job.detail = math.inf
        return job.detail
    cd = chamfer_distance(v, f, dv, df, n_samples=PRIOR_PROBE_SAMPLES, seed=job.seed, normalize=False)
    job.detail = len(dv) * cd
    return job.detail


def hole_cap_error(vertices: np.ndarray, faces: np.ndarray) -> float:
    """F of the prior: the Chamfer distance the caps of the input's holes add (0 for a closed mesh).

    vertices (V,3) in the normalized frame, faces (F,3). Each boundary loop (edges of one face only) is capped by
    a fan around its centroid: area A, radius r = sqrt(A / pi); a flat disc's points lie r/3 from its rim on
    average, and the decoded mesh's samples are half of the Chamfer distance: F = 0.5 * sum(A r / 3) / area.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from tetweave_codec.fit.features import unique_rows
    from tetweave_codec.geometry.triangles import face_areas, triangle_cross

    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, _, counts = unique_rows(edges)
    rim = unique[counts == 1]
    if not len(rim):
        return 0.0
    n = len(vertices)
    graph = coo_matrix((np.ones(len(rim)), (rim[:, 0], rim[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    loop = label[rim[:, 0]]
    loops = np.unique(loop)
    area = float(face_areas(vertices, faces).sum())
    if area <= 0:
        return 0.0
    total = 0.0
    for k in loops:
        e = rim[loop == k]
        centre = vertices[np.unique(e)].mean(0)
        fan = np.stack([np.broadcast_to(centre, (len(e), 3)), vertices[e[:, 0]], vertices[e[:, 1]]], axis=1)
        cap = 0.5 * np.linalg.norm(triangle_cross(fan), axis=1).sum()
        total += cap * math.sqrt(cap / math.pi) / 3.0
    return float(0.5 * total / area)


def _clamp_points(n: float) -> int:
    return int(min(max(n, MIN_RATE_POINTS), MAX_RATE_POINTS))


def _needed(n: float, max_error: float, fitted: int, err: float) -> int:
    """`n` as a point count, or InputError when it is beyond what rate control fits (or no larger than `fitted`)."""
    if n > MAX_RATE_POINTS or fitted >= MAX_RATE_POINTS:
        raise InputError(
            f"a maximum error of {max_error:.3g} is out of reach: {fitted:,} points reached {err:.3g} and about "
            f"{int(min(n, 1e9)):,} would be needed (rate control fits at most {MAX_RATE_POINTS:,})"
        )
    return max(int(n), int(fitted * 1.2) + 1)


def _exponent(runs: dict[int, Trial], default: float) -> float:
    """err ~ N^-alpha between the two largest fits (clamped to [0.3, 1.3]), or `default` with one fit."""
    if len(runs) < 2:
        return default
    (na, ra), (nb, rb) = sorted(runs.items())[-2:]
    alpha = math.log(max(ra.error, 1e-12) / max(rb.error, 1e-12)) / math.log(nb / na)
    return min(max(alpha, 0.3), 1.3)


def _fit_and_measure(job, points: int, quant: Quantization, decode, feature_only: bool = False) -> Trial:
    """One full fit at `points`, packed, decoded (`decode`: bytes -> DecodeResult) and measured."""
    ctx, fin, quant = job.stage(points, quant, feature_only)
    with deterministic_torch():
        result = complete(fin, ctx, quant)
    data = job.pack(result, ctx)
    out = decode(data)
    return Trial(ctx, result, data, job.chamfer(out.vertices, out.faces), out)


def _smallest_within(job, run: Trial, max_error: float, points: int, decode, note: str):
    """Coarser steps on the same fit (no refit) while the error stays within the target; the smallest file."""
    ctx, result = run.ctx, run.result
    quant = result.quantization
    best = (result, run.data, run.error, run.decoded)
    for scale in (1.4, 2.0, 2.8):
        trial = requantize(
            result.points, result.cells, result.latent_s, result.latent_c, _scaled(quant, scale), job.sh_degree
        )
        trial_data = job.pack(trial, ctx)
        if len(trial_data) >= len(best[1]):
            continue
        trial_out = decode(trial_data)
        trial_err = job.chamfer(trial_out.vertices, trial_out.faces)
        if trial_err > max_error:
            break
        best = (trial, trial_data, trial_err, trial_out)
    result, data, err, out = best
    extra = {"target_error": max_error, "rate_control": f"{points} points, {note}"}
    return job.result(result, ctx, points, data=data, decoded=out, chamfer=err, extra=extra)
