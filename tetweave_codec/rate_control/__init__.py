"""Rate control: choose the point count and the quantization so that a file meets a size or an error target.

* `encode_to_size(job, size)` (size.py): the file is at most `size` bytes and at least SIZE_FLOOR of it; one fit,
  whose quantization is chosen from the exact packed sizes of its points.
* `encode_to_error(job, max_error)` (error.py): the decoded mesh's Chamfer distance is at most `max_error`; up to
  MAX_ERROR_FITS fits, the first sized by the per-mesh prior.
* prior.py: that prior, err ~ P / N + F, from a quick decimation of the input and its holes.

Time: one fit when the prior lands (the common case; 1.0-1.14x the time of that fit alone), two or three when
it misses (a --max-error search that takes a second fit: 1.85-2.1x), so not "within 1.5x one fit" for every input
(docs/measurements/rate_control.md; the calibration: docs/measurements/rate_control_calibration.md). A target out of
reach raises InputError (the CLI prints one line and exits 2 without writing a file).
"""

from __future__ import annotations

from tetweave_codec.rate_control.error import (
    CLOSE_ENOUGH,
    ERROR_AIM,
    FEATURE_FIT_POINTS,
    MAX_ERROR_FITS,
    PRIOR_ALPHA,
    Trial,
    encode_to_error,
)
from tetweave_codec.rate_control.prior import (
    PRIOR_BASE,
    PRIOR_DETAIL_KNEE,
    PRIOR_DETAIL_SLOPE,
    PRIOR_ERROR_POINTS,
    hole_cap_error,
    input_detail,
    mesh_prior,
    prior_error_points,
)
from tetweave_codec.rate_control.size import (
    BALANCED_STEP_SCALE,
    MAX_RATE_POINTS,
    MIN_RATE_POINTS,
    MIN_STEP_FACTOR,
    PRECISION_KNEE,
    PRECISION_RAMP_POINTS,
    SIZE_AIM,
    SIZE_FLOOR,
    STEP_SCALES,
    Candidate,
    bytes_per_point,
    choose,
    encode_to_size,
    points_for_size,
    size_quantization,
    step_factor,
)

__all__ = [
    "BALANCED_STEP_SCALE",
    "MIN_STEP_FACTOR",
    "PRECISION_KNEE",
    "PRECISION_RAMP_POINTS",
    "CLOSE_ENOUGH",
    "ERROR_AIM",
    "FEATURE_FIT_POINTS",
    "MAX_ERROR_FITS",
    "MAX_RATE_POINTS",
    "MIN_RATE_POINTS",
    "PRIOR_ALPHA",
    "PRIOR_BASE",
    "PRIOR_DETAIL_KNEE",
    "PRIOR_DETAIL_SLOPE",
    "PRIOR_ERROR_POINTS",
    "SIZE_AIM",
    "SIZE_FLOOR",
    "STEP_SCALES",
    "Candidate",
    "Trial",
    "bytes_per_point",
    "choose",
    "encode_to_error",
    "encode_to_size",
    "hole_cap_error",
    "input_detail",
    "mesh_prior",
    "points_for_size",
    "prior_error_points",
    "size_quantization",
    "step_factor",
]
