"""Rate-distortion helpers: Pareto fronts of (error, bytes) settings and sizes at a matched error.

A method family's settings give points (Chamfer distance, bytes). Its *front* is the Pareto subset (no other
setting of the family is both smaller and more accurate), sorted by error. The family's size at an error e is read
off its front by linear interpolation of log(bytes) against log(error); outside the front's error range it is
unknown (never extrapolated). `tetweave bench` compares families this way (tetweave_codec/bench/report.py: the verdict).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def pareto_front(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """Non-dominated (error, bytes) points with error > 0, sorted by error (bytes then strictly decrease)."""
    pts = sorted((e, b) for e, b in points if e > 0 and b > 0)
    front: list[tuple[float, float]] = []
    for e, b in pts:
        if not front or b < front[-1][1]:
            if front and e == front[-1][0]:
                continue
            front.append((e, b))
    return front


def bytes_at(front: Sequence[tuple[float, float]], error: float) -> float | None:
    """Size on a front at `error`, log-log interpolated; None outside the front's error range."""
    if not front or error <= 0:
        return None
    errors = np.log([e for e, _ in front])
    sizes = np.log([b for _, b in front])
    x = math.log(error)
    tol = 1e-9
    if x < errors[0] - tol or x > errors[-1] + tol:
        return None
    return float(math.exp(np.interp(x, errors, sizes)))
