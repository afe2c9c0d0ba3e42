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


# Decimation + Draco in the summary: the search over the fraction of faces kept stops when the two fractions that
# bracket the target are within this ratio (the size in between is read along log(bytes) ~ log(error), as above).
DECIMATE_BRACKET_RATIO = 1.3
MIN_KEEP = 1e-3  # below 0.1 % of the faces quadric decimation of a real input is no longer a useful shape
MAX_DECIMATE_TRIES = 7


@dataclass(frozen=True)
class DecimateMatch:
    """fast-simplification + Draco of the input at `chamfer`: `bytes` interpolated between the two fractions of
    faces kept that bracket it (at `bits`), or None when no fraction in [MIN_KEEP, 1] does (`bound` as in
    DracoMatch). `settings` maps each fraction tried to (faces, bytes, chamfer)."""

    chamfer: float
    bits: int
    bytes: float | None
    bound: str | None
    settings: dict[float, tuple[int, int, float]]

    def describe(self, file_bytes: int) -> str:
        """One line for the encoder's summary comparing `file_bytes` with this size."""
        if self.bytes is None:
            return f"decimation + Draco: no fraction of the faces brackets this Chamfer distance ({self.bound})"
        verdict = "smaller" if file_bytes <= self.bytes else "LARGER"
        return (
            f"fast-simplification + Draco ({self.bits} bits) at the same Chamfer distance: ~{self.bytes:,.0f} bytes; "
            f"this file is {file_bytes / self.bytes:.2f}x that ({verdict})"
        )


def decimate_bits(draco: DracoMatch) -> int:
    """The bit depth for decimation + Draco at draco.chamfer: about the coarsest depth at which plain Draco of the
    whole input stays within half that distance (the other half is left to the decimation). From the depths the
    plain Draco bisection measured: the coarsest one within the distance, or the next finer one when it is not
    within half (Draco's error about halves per bit); MAX_BITS when none is within."""
    within = [b for b, (_, err) in draco.settings.items() if err <= draco.chamfer]
    if not within:
        return MAX_BITS
    bits = min(within)
    return bits if draco.settings[bits][1] <= 0.5 * draco.chamfer else min(bits + 1, MAX_BITS)


def decimate_draco_at_chamfer(
    vertices: np.ndarray,
    faces: np.ndarray,
    chamfer: float,
    distance: Callable[[np.ndarray, np.ndarray], float],
    bits: int,
    start_faces: int,
    compression_level: int = DRACO_COMPRESSION_LEVEL,
) -> DecimateMatch:
    """fast-simplification + Draco's size for vertices (V,3), faces (F,3) at Chamfer distance `chamfer`.

    The fraction of faces kept starts at `start_faces` / F (the caller's guess: the tetweave file's decoded faces
    / 4 is close on most inputs), steps by 4x until two fractions bracket the target, then bisects in log(fraction)
    until they are within DECIMATE_BRACKET_RATIO: MAX_DECIMATE_TRIES decimations at most. `distance` as in
    `draco_at_chamfer`.
    """
    from tetweave_codec.bench.baselines import decimate

    n = max(len(faces), 1)
    settings: dict[float, tuple[int, int, float]] = {}

    def measure(keep: float) -> float:
        if keep not in settings:
            v, f = decimate(vertices, faces, keep)
            data = draco_encode(v, f, bits, compression_level)
            settings[keep] = (len(f), len(data), float(distance(*draco_decode(data))))
        return settings[keep][2]

    keep = float(np.clip(start_faces / n, MIN_KEEP, 1.0))
    lo = hi = None  # measure(lo) > chamfer >= measure(hi), lo < hi
    for _ in range(MAX_DECIMATE_TRIES):
        if measure(keep) > chamfer:
            lo = keep
            if hi is None:
                if keep >= 1.0:
                    break
                keep = min(keep * 4.0, 1.0)
                continue
        else:
            hi = keep
            if lo is None:
                if keep <= MIN_KEEP:
                    break
                keep = max(keep / 4.0, MIN_KEEP)
                continue
        if hi / lo <= DECIMATE_BRACKET_RATIO:
            break
        keep = float(np.sqrt(lo * hi))
    if lo is None or hi is None:
        return DecimateMatch(chamfer, bits, None, "below" if lo is None else "above", settings)
    # the fronts' bytes at the target: along the Pareto front of every fraction measured
    front = pareto_front([(s[2], s[1]) for s in settings.values()])
    return DecimateMatch(chamfer, bits, bytes_at(front, chamfer), None, settings)


def classical_context(prepared, file_bytes: int, chamfer: float, decoded_faces: int, n_samples: int) -> dict:
    """Plain Draco and fast-simplification + Draco of the prepared input (fit.prepared.PreparedInput, normalized
    frame) at the encode's Chamfer distance, measured with the summary's metric (`n_samples` per mesh).

    Returns {"draco": DracoMatch, "decimate": DecimateMatch, "lines": [str, str], "record": {...}}: the summary's
    two lines and the numbers a batch manifest keeps ("draco_bytes", "decimate_draco_bytes": None where no setting
    brackets the distance)."""

    def distance(v, f):
        return prepared.normalized_chamfer(v, f, n_samples)

    draco = draco_at_chamfer(prepared.normalized, prepared.faces, chamfer, distance)
    decimated = decimate_draco_at_chamfer(
        prepared.normalized, prepared.faces, chamfer, distance, decimate_bits(draco), max(decoded_faces // 4, 4)
    )
    return {
        "draco": draco,
        "decimate": decimated,
        "lines": [draco.describe(file_bytes), decimated.describe(file_bytes)],
        "record": {"draco_bytes": draco.bytes, "decimate_draco_bytes": decimated.bytes},
    }
