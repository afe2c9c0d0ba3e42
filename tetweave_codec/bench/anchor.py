"""Plain Draco of an input at a given Chamfer distance: the size a user gets without tetweave.

`tetweave encode` puts its file in context with this number (the issue 41 summary line). Draco quantizes the
input's positions to a bit depth and keeps its connectivity; its Chamfer distance roughly halves per bit. The size
at an error e is read the way `tetweave bench` reads any family (`metrics.rate_distortion.bytes_at`: log(bytes)
against log(error), linear between the two bit depths that bracket e, never extrapolated), on the bit depths
a bisection visits: about four Draco encodes and Chamfer estimates instead of nine.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tetweave_codec.bench.baselines import DRACO_COMPRESSION_LEVEL, draco_decode, draco_encode
from tetweave_codec.metrics.rate_distortion import bytes_at, pareto_front

MIN_BITS = 8  # Draco's coarsest useful depth here: at 7 bits most inputs collapse into visible steps
MAX_BITS = 16  # past 16 bits Draco's files grow with no error left to remove at the Chamfer metric's resolution


@dataclass(frozen=True)
class DracoMatch:
    """Plain Draco of the input at `chamfer`: `bytes` interpolated between the bracketing bit depths, or None
    when no depth in [MIN_BITS, MAX_BITS] brackets it: then `bound` says which side ("below" = even MIN_BITS is
    more accurate, so Draco's file is at most `settings[MIN_BITS]`'s bytes; "above" = even MAX_BITS misses it).
    `settings` maps each bit depth tried to (bytes, chamfer)."""

    chamfer: float
    bytes: float | None
    bound: str | None
    settings: dict[int, tuple[int, float]]

    def describe(self, file_bytes: int) -> str:
        """One line for the encoder's summary comparing `file_bytes` with this Draco size."""
        if self.bytes is not None:
            verdict = "smaller" if file_bytes <= self.bytes else "LARGER"
            return (
                f"plain Draco of the input at the same Chamfer distance: ~{self.bytes:,.0f} bytes; this file is "
                f"{file_bytes / self.bytes:.2f}x that ({verdict})"
            )
        if self.bound == "below":
            size = self.settings[MIN_BITS][0]
            return (
                f"plain Draco of the input is already within this Chamfer distance at {MIN_BITS} bits: at most "
                f"{size:,} bytes; this file is {file_bytes / size:.2f}x that"
                + (" (LARGER)" if file_bytes > size else "")
            )
        size = self.settings[MAX_BITS][0]
        return f"plain Draco of the input misses this Chamfer distance even at {MAX_BITS} bits ({size:,} bytes)"


def draco_at_chamfer(
    vertices: np.ndarray,
    faces: np.ndarray,
    chamfer: float,
    distance: Callable[[np.ndarray, np.ndarray], float],
    compression_level: int = DRACO_COMPRESSION_LEVEL,
) -> DracoMatch:
    """Plain Draco's size for vertices (V,3), faces (F,3) at Chamfer distance `chamfer`.

    `distance(vertices (V',3), faces (F',3)) -> float` is the caller's Chamfer distance of a decoded Draco mesh to
    the input, in the frame the vertices are given in (the encoder passes its prepared reference, so the number is
    the one its own summary reports). Bisection on the bit depth: Draco's error falls as its bit depth rises.
    """
    settings: dict[int, tuple[int, float]] = {}

    def measure(bits: int) -> float:
        if bits not in settings:
            data = draco_encode(vertices, faces, bits, compression_level)
            settings[bits] = (len(data), float(distance(*draco_decode(data))))
        return settings[bits][1]

    if measure(MIN_BITS) <= chamfer:
        return DracoMatch(chamfer, None, "below", settings)
    if measure(MAX_BITS) > chamfer:
        return DracoMatch(chamfer, None, "above", settings)
    lo, hi = MIN_BITS, MAX_BITS  # measure(lo) > chamfer >= measure(hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if measure(mid) > chamfer:
            lo = mid
        else:
            hi = mid
    front = pareto_front([(settings[b][1], settings[b][0]) for b in (lo, hi)])
    return DracoMatch(chamfer, bytes_at(front, chamfer), None, settings)
