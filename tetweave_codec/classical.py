"""The classical pipelines a user has without tetweave, and their size at a given Chamfer distance.

The codecs: plain Draco (DracoPy: positions quantized to a bit depth over the bounding cube, connectivity with
Edgebreaker; the compression level always set, DRACO_COMPRESSION_LEVEL, as DracoPy's default is 1, not the
command-line tool's 7) and fast-simplification's quadric decimation (`decimate`). `tetweave bench` runs them as
method families (bench/baselines.py, beside MeshLab's decimation); `tetweave encode`'s summary and the batch
manifest put each file in context with them (`encode_context`).

Plain Draco of an input at a given Chamfer distance: Draco quantizes the input's positions to a bit depth and keeps
its connectivity; its Chamfer distance roughly halves per bit. The size at an error e is read the way `tetweave
bench` reads any family (`metrics.rate_distortion.bytes_at`: log(bytes) against log(error), linear between the two
bit depths that bracket e, never extrapolated), on the bit depths a bisection visits: about four Draco encodes and
Chamfer estimates instead of nine (`draco_at_chamfer`). fast-simplification + Draco there: a bracket search over
the fraction of faces kept at four bit depths (`decimate_draco_at_chamfer`).

    data = draco_encode(vertices, faces, 11, DRACO_COMPRESSION_LEVEL);  vertices, faces = draco_decode(data)
    context = encode_context(result)   # {"draco", "decimate", "lines", "record"} | None (encoder.EncodeResult)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tetweave_codec.metrics.rate_distortion import bytes_at, pareto_front

DRACO_COMPRESSION_LEVEL = 7  # `draco_encoder`'s default (-cl 7); DracoPy defaults to 1


def draco_encode(vertices: np.ndarray, faces: np.ndarray, quantization_bits: int, compression_level: int) -> bytes:
    import DracoPy

    return bytes(
        DracoPy.encode(
            np.ascontiguousarray(vertices, dtype=np.float64),
            np.ascontiguousarray(faces, dtype=np.uint32),
            quantization_bits=quantization_bits,
            compression_level=compression_level,
        )
    )


def draco_decode(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    import DracoPy

    mesh = DracoPy.decode(data)
    vertices = np.asarray(mesh.points, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    return vertices, faces


def decimate(vertices: np.ndarray, faces: np.ndarray, keep: float) -> tuple[np.ndarray, np.ndarray]:
    """Quadric decimation to about `keep` (0..1] of the faces: vertices (V',3) float64, faces (F',3) int64."""
    import fast_simplification

    if not 0.0 < keep <= 1.0:
        raise ValueError(f"keep must be in (0, 1], got {keep}")
    if keep == 1.0:
        return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    v, f = fast_simplification.simplify(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
        target_reduction=1.0 - keep,
    )
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


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
DECIMATE_BRACKET_RATIO = 1.5
MIN_KEEP = 1e-3  # below 0.1 % of the faces quadric decimation of a real input is no longer a useful shape
MAX_DECIMATE_TRIES = 7  # decimations per bit depth's search (each search reuses the decimations of the others)
# Bit depths searched around decimate_bits' choice: which depth wins depends on how the error splits between the
# decimation and the quantization (fandisk's flat faces leave most of it to the quantization: 2 bits coarser than
# the choice; spot's few faces leave it to the decimation). Measured on the committed bench files
# (docs/measurements/summary_context.md).
DECIMATE_BITS_AROUND = (-2, -1, 0, 1)
# Chamfer samples per mesh while searching (the summary's own metric uses more): the search only has to bracket the
# target, and the mean distance is an unbiased estimate at any sample count (~2 % noise here).
SEARCH_SAMPLES = 10_000


@dataclass(frozen=True)
class DecimateMatch:
    """fast-simplification + Draco of the input at `chamfer`: `bytes` read off the Pareto front of every (fraction
    of faces kept, bit depth) measured, or None when the front does not reach it (`bound`: "below" = even MIN_KEEP
    is within it, "above" = even all the faces at the finest depth miss it). `bits` is the depth of the cheapest
    file within the distance; `settings` maps each (fraction, bits) tried to (faces, bytes, chamfer)."""

    chamfer: float
    bits: int
    bytes: float | None
    bound: str | None
    settings: dict[tuple[float, int], tuple[int, int, float]]

    def describe(self, file_bytes: int) -> str:
        """One line for the encoder's summary comparing `file_bytes` with this size."""
        if self.bytes is None:
            return f"fast-simplification + Draco: no fraction of the faces reaches this Chamfer distance ({self.bound})"
        verdict = "smaller" if file_bytes <= self.bytes else "LARGER"
        return (
            f"fast-simplification + Draco ({self.bits} bits) at the same Chamfer distance: ~{self.bytes:,.0f} bytes; "
            f"this file is {file_bytes / self.bytes:.2f}x that ({verdict})"
        )


def decimate_bits(draco: DracoMatch) -> int:
    """The central bit depth for decimation + Draco at draco.chamfer: about the coarsest depth at which plain Draco
    of the whole input stays within half that distance (the other half is left to the decimation). From the depths
    the plain Draco bisection measured: the coarsest one within the distance, or the next finer one when it is not
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
    around: tuple[int, ...] = DECIMATE_BITS_AROUND,
) -> DecimateMatch:
    """fast-simplification + Draco's size for vertices (V,3), faces (F,3) at Chamfer distance `chamfer`.

    For each bit depth bits + `around` (clipped to [MIN_BITS, MAX_BITS]; finest first) the fraction of faces kept
    starts at `start_faces` / F (the caller's guess) or at the previous depth's bracket, steps by 4x (2x from a
    previous bracket) until two fractions bracket the target, then bisects in log(fraction) until they are within
    DECIMATE_BRACKET_RATIO (MAX_DECIMATE_TRIES steps at most); a fraction is decimated once for every depth. The
    size is read off the Pareto front of every (fraction, depth) measured. `distance` as in `draco_at_chamfer`.
    """
    n = max(len(faces), 1)
    depths = sorted({min(max(bits + d, MIN_BITS), MAX_BITS) for d in around}, reverse=True)
    meshes: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    settings: dict[tuple[float, int], tuple[int, int, float]] = {}

    def measure(keep: float, depth: int) -> float:
        if (keep, depth) not in settings:
            if keep not in meshes:
                meshes[keep] = decimate(vertices, faces, keep)
            v, f = meshes[keep]
            if not len(f):  # a tiny input (a tetrahedron) decimates to nothing: no file, no shape (Draco refuses it)
                settings[(keep, depth)] = (0, 0, math.inf)
            else:
                data = draco_encode(v, f, depth, compression_level)
                settings[(keep, depth)] = (len(f), len(data), float(distance(*draco_decode(data))))
        return settings[(keep, depth)][2]

    keep = float(np.clip(start_faces / n, MIN_KEEP, 1.0))
    step = 4.0  # the first depth's search starts from a guess; the next ones from a bracket one bit away
    for depth in depths:
        lo = hi = None  # measure(lo) > chamfer >= measure(hi), lo < hi
        for _ in range(MAX_DECIMATE_TRIES):
            if measure(keep, depth) > chamfer:
                lo = keep
                if hi is None:
                    if keep >= 1.0:
                        break
                    keep = min(keep * step, 1.0)
                    continue
            else:
                hi = keep
                if lo is None:
                    if keep <= MIN_KEEP:
                        break
                    keep = max(keep / step, MIN_KEEP)
                    continue
            if hi / lo <= DECIMATE_BRACKET_RATIO:
                break
            keep = float(np.sqrt(lo * hi))
        keep = hi if hi is not None else keep  # a coarser depth needs at least as many faces
        step = 2.0
    front = pareto_front([(s[2], s[1]) for s in settings.values()])
    size = bytes_at(front, chamfer)
    if size is None:
        bound = "below" if front and chamfer > front[-1][0] else "above"
        return DecimateMatch(chamfer, bits, None, bound, settings)
    within = [(s[1], key[1]) for key, s in settings.items() if s[2] <= chamfer]
    return DecimateMatch(chamfer, min(within)[1], size, None, settings)


def classical_context(prepared, file_bytes: int, chamfer: float, decoded_faces: int, n_samples: int) -> dict:
    """Plain Draco and fast-simplification + Draco of the input as the user gave it (`prepared.source`, every
    face) at the encode's Chamfer distance `chamfer` to the surface the fit took (`prepared`, fit.prepared.
    PreparedInput, normalized frame; the visible surface when the encode fitted it), measured with `n_samples` per
    mesh; the searches measure their candidates with SEARCH_SAMPLES (fewer when `n_samples` is smaller).

    Returns {"draco": DracoMatch, "decimate": DecimateMatch, "lines": [str, str], "record": {...}}: the summary's
    two lines and the numbers a batch manifest keeps ("draco_bytes", "decimate_draco_bytes": None where no setting
    reaches the distance)."""
    samples = min(n_samples, SEARCH_SAMPLES)
    # A user with a messy input (hidden parts, inner walls, overlaps) compresses all of it with a classical codec:
    # its bytes include the hidden faces, and its error counts against what a viewer sees, as tetweave's does.
    given = prepared.source

    def distance(v, f):
        return prepared.normalized_chamfer(v, f, samples)

    def distance_in_input_frame(v, f):
        return prepared.chamfer(v, f, samples)

    draco = draco_at_chamfer(given.normalized, given.faces, chamfer, distance)
    # decimated in the input's own frame, as a user decimates their file: fast-simplification's collapse thresholds
    # are absolute, so the frame changes its result (fandisk, 10 % of the faces, 11 bits: Chamfer 2.6e-4 in its own
    # frame, 3.2e-4 in the normalized one); Draco's quantization is relative to the bounding box, the same in both
    decimated = decimate_draco_at_chamfer(
        given.vertices,
        given.faces,
        chamfer,
        distance_in_input_frame,
        decimate_bits(draco),
        max(decoded_faces // 4, 4),
    )
    lines = [draco.describe(file_bytes), decimated.describe(file_bytes)]
    if given is not prepared:
        lines = [line + VISIBLE_NOTE.format(faces=len(given.faces)) for line in lines]
    return {
        "draco": draco,
        "decimate": decimated,
        "lines": lines,
        "record": {"draco_bytes": draco.bytes, "decimate_draco_bytes": decimated.bytes},
    }


# Said after each context line when the encode fitted the visible surface: what the classical file holds and what
# its error is measured against.
VISIBLE_NOTE = " (of all {faces:,} input faces, hidden ones included; error to the visible surface)"


def encode_context(result) -> dict | None:
    """`classical_context` of an encode's result (encoder.EncodeResult) with the summary's metric, or None when
    the result has nothing to compare (no Chamfer distance, no prepared input or no faces): the one call of the
    encode summary and of the batch manifest."""
    st = result.stats
    if st["chamfer"] is None or result.prepared is None or not st["faces"]:
        return None
    from tetweave_codec.packing import SUMMARY_CHAMFER_SAMPLES

    return classical_context(result.prepared, st["bytes"], st["chamfer"], st["faces"], SUMMARY_CHAMFER_SAMPLES)
