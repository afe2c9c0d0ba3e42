"""--max-error: the decoded mesh's Chamfer distance (the summary's metric) is at most `max_error`.

The first fit's point count comes from the per-mesh prior err ~ P / N + F (rate_control.prior); the measured errors
steer at most MAX_ERROR_FITS - 1 more fits (shrink, grow, or interpolate between a fit that met the target and
one that missed it). Coarser steps are then tried (without another late stage) while the error stays below the
target, to save bytes. Inputs with sharp creases first try a feature-only fit (`_feature_only_trial`). The
measurements behind the constants: docs/measurements/rate_control_calibration.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tetweave_codec.errors import InputError
from tetweave_codec.fit.finish import FinishResult, complete, requantize
from tetweave_codec.fit.loop import deterministic_torch
from tetweave_codec.fit.step import FitContext
from tetweave_codec.formats.quantize import Quantization, default_quantization
from tetweave_codec.rate_control.prior import PRIOR_ERROR_POINTS, mesh_prior
from tetweave_codec.rate_control.size import MAX_RATE_POINTS, MIN_RATE_POINTS, scaled

if TYPE_CHECKING:
    from tetweave_codec.decoder import DecodeResult

PRIOR_ALPHA = 0.8  # err ~ N^-alpha when only one fit is known (a little below 1: ask for a few more points)
EXPONENT_RANGE = (0.3, 1.3)  # the measured exponent between two fits, clamped (reported in the stats)
ERROR_AIM = 0.9  # aim the predicted error at this fraction of the target (the per-mesh prior is close)
ERROR_AIM_SHRINK = 0.75  # a smaller fit aims lower: the error grows faster than 1/N at small counts
ERROR_AIM_BRACKET = 0.9  # between a fit that met the target and one that missed it
CLOSE_ENOUGH = 0.75  # a fit within [CLOSE_ENOUGH, 1] x the target ends the search
MAX_ERROR_FITS = 3
PRIOR_SPREAD = 4.0  # refuse without fitting when the prior asks for more than this many times MAX_RATE_POINTS
# The first fit is sized with this share of F: the decimation probe behind P already carries part of the holes'
# cost, so P / N + F counted it twice and overshot (stanford-bunny: first fits at 0.75-0.82 of the target, files
# +16 % / +58 % at 2e-3 / 1e-3); without F the bunny's 1e-3 fit missed.
FIRST_FIT_HOLE_SHARE = 0.5
# ...and the error it aims at is at least this share of the aim (a floor F close to the target asks for no more).
FIRST_FIT_MIN_AIM_SHARE = 0.5
# Bracketed search: stop when the two fits are within BRACKET_MIN_RATIO of each other in points, else interpolate
# in log-log, the step kept within BRACKET_STEP_RANGE of the bracket (never at its ends).
BRACKET_MIN_RATIO = 1.15
BRACKET_STEP_RANGE = (0.2, 0.8)
# Shrinking stops when the next fit would keep more than this share of the points of the smallest that met it.
SHRINK_MIN_SAVING = 0.85
# Growing asks for at least this factor more points than the largest fit that missed (and one more).
GROW_MIN_FACTOR = 1.2
# Step multipliers tried on the kept fit after the search (coarser than the default, finest first).
COARSER_STEP_SCALES = (1.4, 2.0, 2.8)
# Bounds of the point counts quoted in refusals (they only format numbers).
QUOTED_POINTS_LIMIT = 1e12
QUOTED_NEEDED_LIMIT = 1e9

# The feature-only fit: the feature-aware start at FEATURE_FIT_POINTS points (feature points, the box corners and
# the few fill points the crease clearance leaves), its points next to creases at plane distances, kept as the
# point set (no resampling or relocation), s steps FEATURE_FIT_STEP_SCALE x the default. Tried only when that
# start alone, decoded, is within FEATURE_FIT_START_SHARE of the target (a start costs ~1 s; a fit of 64 points
# ~25 s on one thread), and kept only when the fit meets it. An exact start does not stay exact through the usual
# fit (a cube at 64 points: start 3e-10, the usual main stage 2.8e-3, without resampling 1.6e-4), and the usual
# search sized a 1e-4 cube at ~13K points.
FEATURE_FIT_POINTS = 64
FEATURE_FIT_STEP_SCALE = 0.03
FEATURE_FIT_START_SHARE = 0.5


@dataclass
class Trial:
    """One full fit of a --max-error search at some point count: its context, finished symbols, bytes, the
    decoded mesh's Chamfer distance to the input and the decoder's result (`decoder.DecodeResult`)."""

    ctx: FitContext
    result: FinishResult
    data: bytes
    error: float
    decoded: DecodeResult


def encode_to_error(job, max_error: float):
    """The smallest file this fit finds whose decoded mesh is within `max_error` (Chamfer) of the input.

    A search over point counts in log-log space, at most MAX_ERROR_FITS fits: the first count comes from the prior
    err ~ P / N + F (rate_control.prior.mesh_prior); while every fit met the target the next shrinks (err ~ N^-1,
    aiming at ERROR_AIM_SHRINK of it), while none did the next grows (err ~ N^-PRIOR_ALPHA, aiming at ERROR_AIM);
    once one fit met it and one missed, the next interpolates between them. It stops when a fit lands in
    [CLOSE_ENOUGH, 1] x the target. Coarser steps are then tried on the smallest fit that met it.
    """
    if not (math.isfinite(max_error) and max_error > 0):
        raise InputError(f"the maximum error must be a positive number, got {max_error}")
    aim = ERROR_AIM * max_error
    if PRIOR_ERROR_POINTS / aim > PRIOR_SPREAD * MAX_RATE_POINTS:
        raise InputError(
            f"a maximum error of {max_error:.3g} is out of reach: meshes typically need about "
            f"{int(min(PRIOR_ERROR_POINTS / aim, QUOTED_POINTS_LIMIT)):,} points for it "
            f"(rate control fits at most {MAX_RATE_POINTS:,})"
        )
    runs: dict[int, Trial] = {}
    prior, floor = mesh_prior(job)
    first = prior / (aim - floor) if aim > floor else math.inf
    if first > MAX_RATE_POINTS:
        holes = f"its holes, capped by the fit, alone cost ~{floor:.2g}; " if floor > 0 else ""
        raise InputError(
            f"a maximum error of {max_error:.3g} is out of reach: this mesh needs about "
            f"{int(min(first, QUOTED_POINTS_LIMIT)):,} points for it by its prior ({holes}rate control fits at most "
            f"{MAX_RATE_POINTS:,})"
        )
    # After the refusals above: a target the prior puts out of reach is out of reach of 64 points too.
    feature_fit = _feature_only_trial(job, max_error)
    if feature_fit is not None:
        return _smallest_within(job, feature_fit, max_error, FEATURE_FIT_POINTS, "feature-only fit")
    n = _clamp_points(prior / max(aim - FIRST_FIT_HOLE_SHARE * floor, FIRST_FIT_MIN_AIM_SHARE * aim))
    for _ in range(MAX_ERROR_FITS):
        runs[n] = _fit_and_measure(job, n, default_quantization(n))
        met = sorted(k for k, r in runs.items() if r.error <= max_error)
        missed = sorted(k for k, r in runs.items() if r.error > max_error)
        if met and runs[met[0]].error >= CLOSE_ENOUGH * max_error:
            break
        if met and missed and missed[-1] < met[0]:  # bracketed: interpolate in log-log
            lo, hi = missed[-1], met[0]
            if hi <= lo * BRACKET_MIN_RATIO:
                break
            e_lo, e_hi = runs[lo].error, runs[hi].error
            t = math.log(e_lo / (ERROR_AIM_BRACKET * max_error)) / math.log(e_lo / e_hi)
            t = min(max(t, BRACKET_STEP_RANGE[0]), BRACKET_STEP_RANGE[1])
            nxt = int(round(math.exp(math.log(lo) + t * math.log(hi / lo))))
        elif met:  # every fit met it, with a margin: shrink
            nxt = _clamp_points(met[0] * runs[met[0]].error / (ERROR_AIM_SHRINK * max_error))
            if nxt >= met[0] * SHRINK_MIN_SAVING:
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
    return _smallest_within(job, runs[met[0]], max_error, met[0], f"error exponent {exponent:.2f}")


def _feature_only_trial(job, max_error: float) -> Trial | None:
    """The feature-only fit (FEATURE_FIT_POINTS) when the input has sharp creases, its start alone is near the
    target and the fit meets it; else None."""
    if job.layout != "fit" or job.settings.init != "sdf":
        return None
    from tetweave_codec.decoder import mesh_from_points
    from tetweave_codec.fit.initialize import initial_state_pinned

    prepared = job.input
    if not prepared.features.found:
        return None
    n = FEATURE_FIT_POINTS
    quant = scaled(default_quantization(n), FEATURE_FIT_STEP_SCALE)
    points, s, _, pinned = initial_state_pinned(
        prepared.normalized,
        prepared.faces,
        n,
        -1,
        job.settings.seed,
        True,
        quant.position_bits,
        quant.grid_scale,
        plane_distances=True,
        detected=prepared.features,
        tree=prepared.tree,
    )
    if not pinned.any():
        return None
    v, f = mesh_from_points(points.astype(np.float64), s, None, -1)
    if job.chamfer(v * prepared.scale + prepared.offset, f) > FEATURE_FIT_START_SHARE * max_error:
        return None
    trial = _fit_and_measure(job, n, quant, feature_only=True)
    return trial if trial.error <= max_error else None


def _clamp_points(n: float) -> int:
    return int(min(max(n, MIN_RATE_POINTS), MAX_RATE_POINTS))


def _needed(n: float, max_error: float, fitted: int, err: float) -> int:
    """`n` as a point count, or InputError when it is beyond what rate control fits (or no larger than `fitted`)."""
    if n > MAX_RATE_POINTS or fitted >= MAX_RATE_POINTS:
        raise InputError(
            f"a maximum error of {max_error:.3g} is out of reach: {fitted:,} points reached {err:.3g} and about "
            f"{int(min(n, QUOTED_NEEDED_LIMIT)):,} would be needed (rate control fits at most {MAX_RATE_POINTS:,})"
        )
    return max(int(n), int(fitted * GROW_MIN_FACTOR) + 1)


def _exponent(runs: dict[int, Trial], default: float) -> float:
    """err ~ N^-alpha between the two largest fits (clamped to EXPONENT_RANGE), or `default` with one fit."""
    if len(runs) < 2:
        return default
    (na, ra), (nb, rb) = sorted(runs.items())[-2:]
    alpha = math.log(max(ra.error, 1e-12) / max(rb.error, 1e-12)) / math.log(nb / na)
    return min(max(alpha, EXPONENT_RANGE[0]), EXPONENT_RANGE[1])


def _decoded(packed):
    """The decoder's result for a packed file: the one packing already made, else a decode."""
    from tetweave_codec.decoder import decode_detailed

    return packed.decoded if packed.decoded is not None else decode_detailed(packed.data)


def _fit_and_measure(job, points: int, quant: Quantization, feature_only: bool = False) -> Trial:
    """One full fit at `points`, packed, decoded and measured."""
    ctx, fin, quant = job.stage(points, quant, feature_only)
    with deterministic_torch():
        result = complete(fin, ctx, quant)
    packed = job.packed(result, ctx)
    out = _decoded(packed)
    return Trial(ctx, result, packed.data, job.chamfer(out.vertices, out.faces), out)


def _smallest_within(job, run: Trial, max_error: float, points: int, note: str):
    """Coarser steps on the same fit (no refit) while the error stays within the target; the smallest file."""
    ctx, result = run.ctx, run.result
    quant = result.quantization
    best = (result, run.data, run.error, run.decoded)
    for scale in COARSER_STEP_SCALES:
        trial = requantize(
            result.points, result.cells, result.latent_s, result.latent_c, scaled(quant, scale), job.settings.sh_degree
        )
        packed = job.packed(trial, ctx)
        if len(packed.data) >= len(best[1]):
            continue
        trial_out = _decoded(packed)
        trial_err = job.chamfer(trial_out.vertices, trial_out.faces)
        if trial_err > max_error:
            break
        best = (trial, packed.data, trial_err, trial_out)
    result, data, err, out = best
    extra = {"target_error": max_error, "rate_control": f"{points} points, {note}"}
    return job.result(result, ctx, points, data=data, decoded=out, chamfer=err, extra=extra)
