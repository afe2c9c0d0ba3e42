"""Rate control: choose the point count and the quantization so that a file meets a size or an error target.

Two targets, each within about 1.5x the time of one fit at the chosen size:

* `encode_to_size(job, size)`: the file is at most `size` bytes and at least SIZE_FLOOR of it. The point count
  comes from a bytes-per-point model (BYTES_PER_POINT); after the main stage the position grid and the steps are
  chosen from the exact packed sizes of the finalized points (positions are exact; s and c are estimated from
  their values before the late stage); after the one late stage the steps are nudged, without another late
  stage, until the file lands in the band.
* `encode_to_error(job, max_error)`: the decoded mesh's Chamfer distance (the summary's metric) is at most
  `max_error`. The first fit's point count comes from a prior error model, err ~ PRIOR_ERROR_POINTS / N; its
  measured error corrects the count for a second fit where needed (err ~ N^-alpha), and the two fits' errors
  give alpha for a third in the rare case the second misses. Coarser steps are then tried (without another late
  stage) while the error stays below the target, to save bytes.

A target out of reach raises InputError (the CLI prints one line and exits 2 without writing a file).
"""

from __future__ import annotations

import math
from dataclasses import replace

from tetweave_codec.errors import InputError
from tetweave_codec.fit.config import Quantization, default_quantization
from tetweave_codec.fit.finish import FinishResult, complete, finalize, requantize
from tetweave_codec.fit.loop import deterministic_torch

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
MIN_FILE_BYTES = 200  # below this no useful TetWeave file exists (header alone: ~73 bytes)
# Prior of the error model err ~ PRIOR_ERROR_POINTS / N (normalized frame): N x Chamfer of default-quality fits
# (benchmarks/results/rate_control.md) is 1.6-1.9 on fandisk, 2.3-2.5 on spot, 4.8-6.1 on igea, 5.2-9.9 on
# stanford-bunny; the first fit aims at 3.5 and the next ones correct with the measured error.
PRIOR_ERROR_POINTS = 3.5
PRIOR_ALPHA = 0.8  # err ~ N^-alpha when only one fit is known (a little below 1: ask for a few more points)
ERROR_AIM = 0.85  # aim the predicted error at this fraction of the target
MARGIN = 0.6  # a first fit below this fraction of the target is followed by a smaller one
PRIOR_SPREAD = 4.0  # refuse without fitting when the prior asks for more than this many times MAX_RATE_POINTS
# Step multipliers tried on s (and c with them) around the default, from coarse to fine.
STEP_SCALES = (2.8, 2.0, 1.4, 1.0, 0.7, 0.5)


def bytes_per_point(points: int) -> float:
    """Model of the v2 bytes per fitted grid point at the default quantization (log-linear in the points)."""
    t = min(max(math.log2(max(points, 1) / 4096.0) / 2.0, -1.0), 2.0)
    return BYTES_PER_POINT_4K + (BYTES_PER_POINT_16K - BYTES_PER_POINT_4K) * t


def points_for_size(size: int) -> int:
    """The grid point count whose file should be about SIZE_AIM * size bytes."""
    n = SIZE_AIM * size / bytes_per_point(4096)
    for _ in range(4):  # fixed point of n = aim / bytes_per_point(n)
        n = SIZE_AIM * size / bytes_per_point(int(n))
    return int(n)


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
    points = points_for_size(size)
    if points > MAX_RATE_POINTS:
        largest = int(MAX_RATE_POINTS * bytes_per_point(MAX_RATE_POINTS))
        raise InputError(
            f"a size of {size:,} bytes needs more than the {MAX_RATE_POINTS:,} points rate control fits "
            f"(~{largest:,} bytes); use --points for larger files"
        )
    points = max(points, MIN_RATE_POINTS)
    base = default_quantization(points)
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
                candidates.append((est, bits, scale, quant))
        fitting = [c for c in candidates if c[0] <= SIZE_AIM * size]
        # Prefer the default grid when it fits at some step, since a finer grid buys little error (see
        # default_quantization); otherwise the largest estimate under the aim; otherwise the smallest file.
        on_default = [c for c in fitting if c[1] == base.position_bits and c[2] <= 2.0]
        if on_default:
            chosen = max(on_default, key=lambda c: c[0])
        elif fitting:
            chosen = max(fitting, key=lambda c: c[0])
        else:
            chosen = min(candidates, key=lambda c: c[0])
        _, bits, scale, quant = chosen
        fin = finals[bits]
        result = complete(fin, ctx, quant)
    data = job.pack(result, ctx)
    # Nudge the steps (no refit) into [SIZE_FLOOR * size, size].
    result, data = _fit_band(job, ctx, result, data, size)
    if not SIZE_FLOOR * size <= len(data) <= size:
        raise InputError(
            f"could not meet a size of {size:,} bytes: the closest file has {len(data):,} bytes "
            f"({result.s.shape[0]:,} points); try another size or --points"
        )
    extra = {"target_bytes": size, "rate_control": f"{points} points, b {bits}, steps x{scale:g}"}
    return job.result(result, ctx, points, measure=measure, data=data, extra=extra)


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

    One fit at the count the prior err ~ PRIOR_ERROR_POINTS / N predicts; a second fit where the first missed
    (count from the measured error and PRIOR_ALPHA) or met the target with a wide margin (a smaller file); a
    third only where the second missed, with the exponent measured between the two fits. Then coarser steps.
    """
    from tetweave_codec.decoder import decode

    if not (math.isfinite(max_error) and max_error > 0):
        raise InputError(f"the maximum error must be a positive number, got {max_error}")
    aim = ERROR_AIM * max_error
    if PRIOR_ERROR_POINTS / aim > PRIOR_SPREAD * MAX_RATE_POINTS:
        raise InputError(
            f"a maximum error of {max_error:.3g} is out of reach: meshes typically need about "
            f"{int(min(PRIOR_ERROR_POINTS / aim, 1e12)):,} points for it "
            f"(rate control fits at most {MAX_RATE_POINTS:,})"
        )
    n0 = _clamp_points(PRIOR_ERROR_POINTS / aim)
    runs = {n0: _fit_and_measure(job, n0, default_quantization(n0), decode)}
    e0 = runs[n0][3]
    if e0 <= max_error:
        best = n0
        if e0 < MARGIN * max_error:  # comfortably met: a smaller fit probably meets it too
            n1 = _clamp_points(n0 * (e0 / aim) ** (1.0 / PRIOR_ALPHA))
            if n1 < 0.8 * n0:
                runs[n1] = _fit_and_measure(job, n1, default_quantization(n1), decode)
                if runs[n1][3] <= max_error:
                    best = n1
        return _smallest_within(job, runs[best], max_error, best, decode, _exponent(runs, PRIOR_ALPHA))
    n1 = _needed(n0 * (e0 / aim) ** (1.0 / PRIOR_ALPHA), max_error, n0, e0)
    runs[n1] = _fit_and_measure(job, n1, default_quantization(n1), decode)
    if runs[n1][3] <= max_error:
        return _smallest_within(job, runs[n1], max_error, n1, decode, _exponent(runs, PRIOR_ALPHA))
    alpha = _exponent(runs, PRIOR_ALPHA)
    e1 = runs[n1][3]
    n2 = _needed(n1 * (e1 / aim) ** (1.0 / alpha), max_error, n1, e1)
    run = _fit_and_measure(job, n2, default_quantization(n2), decode)
    if run[3] > max_error:
        raise InputError(f"could not reach a maximum error of {max_error:.3g}: {n2:,} points reached {run[3]:.3g}")
    return _smallest_within(job, run, max_error, n2, decode, alpha)


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


def _exponent(runs: dict, default: float) -> float:
    """err ~ N^-alpha between the two largest fits (clamped to [0.3, 1.3]), or `default` with one fit."""
    if len(runs) < 2:
        return default
    (na, ra), (nb, rb) = sorted(runs.items())[-2:]
    alpha = math.log(max(ra[3], 1e-12) / max(rb[3], 1e-12)) / math.log(nb / na)
    return min(max(alpha, 0.3), 1.3)


def _fit_and_measure(job, points: int, quant: Quantization, decode):
    """One full fit at `points`: (ctx, result, data, error, decoded mesh)."""
    ctx, params = job.main_stage(points, quant)
    with deterministic_torch():
        fin = finalize(params, ctx, quant.position_bits)
        result = complete(fin, ctx, quant)
    data = job.pack(result, ctx)
    out = decode(data)
    return ctx, result, data, job.chamfer(*out), out


def _smallest_within(job, run, max_error: float, points: int, decode, alpha: float):
    """Coarser steps on the same fit (no refit) while the error stays within the target; the smallest file."""
    ctx, result, data, err, out = run
    quant = result.quantization
    best = (result, data, err, out)
    for scale in (1.4, 2.0, 2.8):
        trial = requantize(
            result.points, result.cells, result.latent_s, result.latent_c, _scaled(quant, scale), job.sh_degree
        )
        trial_data = job.pack(trial, ctx)
        if len(trial_data) >= len(best[1]):
            continue
        trial_out = decode(trial_data)
        trial_err = job.chamfer(*trial_out)
        if trial_err > max_error:
            break
        best = (trial, trial_data, trial_err, trial_out)
    result, data, err, out = best
    extra = {"target_error": max_error, "rate_control": f"{points} points, error exponent {alpha:.2f}"}
    return job.result(result, ctx, points, data=data, decoded=out, chamfer=err, extra=extra)
