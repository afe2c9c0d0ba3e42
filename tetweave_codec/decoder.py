"""Decoding: `.tw` container -> Delaunay tetrahedralization -> directional marching tets -> triangle mesh.

Everything here is numpy float64 and exactly deterministic for the same input on the same machine: the encoder
reports the mesh `decode` returns for its own output (call `decode` or `mesh_from_points` with the
float16-rounded arrays), so "what the encoder printed" and "what the decoder writes" are the same bytes.

The surface is closed where the inside region reaches the convex hull of the points (cap triangles on the
hull, see `marching_tets`), so every decoded mesh is watertight and 2-manifold, or empty (all s of one sign).
A version-2 file may ask for Taubin smoothing of that surface (flags bits 3-4, geometry/smoothing.py) and Loop
subdivision after it (bits 5-6, geometry/subdivision.py): the vertices of any face that these made cross another
are put back (geometry/surface_filter.py), so the mesh stays closed, 2-manifold and free of self-intersections.
A version-2 file of an open input may list faces that only cap the input's holes (flags bit 7, formats/holes.py):
they are removed last (geometry/holes.py), leaving a 2-manifold with boundary, still free of self-intersections.

Levels (`LEVELS`, the `level` keyword): a decoder may stop early. "control" is the marching-tets surface (the mesh
the file's points define, before any filter), "smoothed" applies the file's Taubin steps without its Loop levels,
"full" (the default) the file's whole filter. Each is checked the same way (the smoothed level's crossing faces go
back to the control surface), so every level is closed, 2-manifold and free of self-intersections, and the holes
section (whose ranks name faces of the control surface) opens the same holes in each. Faces: control and smoothed
have the control surface's F0 less the K listed faces, full 4^L times that (L Loop levels; F0 - K again on the
rare surface whose filter the decoder drops).

The decoder core (decoder/, C; `tetweave_codec._decoder_native`) runs `decode`, `decode_detailed` and
`level_faces` on every file of this version (container version 2, the exact Delaunay) in one call: bytes in,
arrays out, the same mesh as the Python pipeline below bit for bit (tests/test_core_decode.py), which stays the
reference (environment TETWEAVE_CORE=0) and decodes the files of earlier encoders (version 1, TetGen or Qhull),
which the core refuses. The core's path imports neither the entropy coder nor the container modules: a result's
`container` parses the file in Python only when a field beyond the header is asked for.
"""

from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from tetweave_codec.errors import ContainerError
from tetweave_codec.geometry.delaunay import available_backends, tetrahedralize
from tetweave_codec.geometry.holes import open_holes
from tetweave_codec.geometry.intersections import resolve_threads
from tetweave_codec.geometry.marching_tets import marching_tets_numpy
from tetweave_codec.geometry.sh import check_degree, num_coeffs
from tetweave_codec.geometry.surface_filter import filter_surface

try:
    from tetweave_codec import _decoder_native
except ImportError:  # a source tree whose extensions are not built: the Python pipeline
    _decoder_native = None

CORE = _decoder_native is not None and os.environ.get("TETWEAVE_CORE", "1") != "0"
LEVELS = ("control", "smoothed", "full")  # lightest first; "full" is the file's own filter
DEFAULT_LEVEL = "full"


def check_level(level: str) -> str:
    """`level` if it is one of LEVELS, else ValueError (callers convert to their error type)."""
    if level not in LEVELS:
        raise ValueError(f"unknown decode level {level!r}: use {', '.join(LEVELS)}")
    return level


def level_filter(smoothing: int, subdivision: int, level: str) -> tuple[int, int]:
    """The (Taubin steps, Loop levels) a decode at `level` applies, of a file's `smoothing` and `subdivision`."""
    check_level(level)
    if level == "control":
        return 0, 0
    return (smoothing, 0) if level == "smoothed" else (smoothing, subdivision)


class DecodeWarning(UserWarning):
    """Decoding works but may not reproduce the encoder's mesh exactly (its Delaunay backend is missing)."""


class FileHeader(NamedTuple):
    """A decoded file's header fields: what a caller reports without parsing the sections again."""

    num_points: int
    sh_degree: int
    flags: int
    creases: bool
    smoothing: int  # the file's Taubin steps (a decode at a lower level applies fewer: DecodeResult.smoothing)
    subdivision: int  # the file's Loop levels
    scale: float
    offset: np.ndarray


def _header_of(tw) -> FileHeader:
    return FileHeader(
        tw.num_points, tw.sh_degree, int(tw.flags), bool(getattr(tw, "creases", False)), tw.smoothing,
        tw.subdivision, float(tw.scale), np.asarray(tw.offset, dtype=np.float64),
    )  # fmt: skip


@dataclass
class DecodeResult:
    """Output of `decode_detailed`.

    vertices: (V, 3) float64 in the input mesh's frame. faces: (F, 3) int64, outward.
    parsed: the parsed file (formats.tw.TetWeaveFile for version 1, formats.tw2.TetWeaveFileV2 for version 2;
        both expose `points`, `s`, `c`, which the decoder converts to float64 -- v2's are its dequantized values),
        or None after a decode by the core: `container` parses `data` then, on first use.
    backend: Delaunay backend actually used.
    seconds: wall time per stage: "unpack", "delaunay", "marching_tets", "smoothing" (smoothing, subdivision and
        their self-intersection check; 0 for files without either), "holes"; a decode by the core has one stage,
        "decode" (the whole call).
    num_tets: size of the tetrahedralization.
    restored: vertices the self-intersection check put back to their unsmoothed place (all of the unsubdivided
        surface's when the filter was dropped).
    extracted_faces: (F0, 3) int64 faces of the surface the marching tets extracted (before smoothing,
        subdivision and holes; what a holes section's ranks name), over the first vertices of the closed surface.
    closed_vertices, closed_faces: the surface before the holes were opened (the same arrays as vertices and faces
        for a file without a holes section), in the input mesh's frame.
    level: the level decoded (LEVELS); smoothing, subdivision: the Taubin steps and Loop levels it applied.
    """

    vertices: np.ndarray
    faces: np.ndarray
    parsed: object
    backend: str
    seconds: dict[str, float] = field(default_factory=dict)
    num_tets: int = 0
    restored: int = 0
    extracted_faces: np.ndarray | None = None
    closed_vertices: np.ndarray | None = None
    closed_faces: np.ndarray | None = None
    level: str = DEFAULT_LEVEL
    smoothing: int = 0
    subdivision: int = 0
    header: FileHeader | None = None
    data: bytes | None = field(default=None, repr=False)

    @property
    def container(self):
        """The parsed file (see `parsed`); a decode by the core parses it here, once, when it is asked for."""
        if self.parsed is None:
            from tetweave_codec.formats.tw import unpack

            self.parsed = unpack(self.data)
        return self.parsed


# the core's status codes (decoder/tetweave_decoder.h tw_status) -> what the Python pipeline raises
_CORE_UNSUPPORTED = 2


def _core_error(status: int, message: str) -> Exception:
    from tetweave_codec.errors import TopologyError

    if status == 4:
        return MemoryError(message)
    if status == 5:
        return ValueError(message)
    if status == 6:
        return TopologyError(message)
    return ContainerError(message)  # 1 invalid, 3 more faces than the decoder's cap


def _array(raw: bytes, dtype, columns: int) -> np.ndarray:
    return np.frombuffer(raw, dtype=dtype).reshape(-1, columns)


def _core_decode(data: bytes, level: str, threads: int, clock) -> DecodeResult | None:
    """decode_detailed by the core, or None for a file the core does not decode (an earlier encoder's)."""
    t0 = clock()
    status, message, r = _decoder_native.decode(data, LEVELS.index(level), threads)
    seconds = {"decode": clock() - t0}
    if status == _CORE_UNSUPPORTED:
        return None
    if status:
        raise _core_error(status, message)
    vertices = _array(r["vertices"], np.float64, 3)
    faces = _array(r["faces"], np.int32, 3).astype(np.int64)
    if "closed_faces" in r:
        closed_v = _array(r["closed_vertices"], np.float64, 3)
        closed_f = _array(r["closed_faces"], np.int32, 3).astype(np.int64)
    else:
        closed_v, closed_f = vertices, faces
    extracted = _array(r["extracted_faces"], np.int32, 3).astype(np.int64)
    header = FileHeader(
        r["points"], r["sh_degree"], r["flags"], bool(r["creases"]), r["file_smoothing"], r["file_subdivision"],
        r["scale"], np.asarray(r["offset"], dtype=np.float64),
    )  # fmt: skip
    return DecodeResult(
        vertices, faces, None, "exact", seconds, r["tets"], r["restored"], extracted, closed_v, closed_f, level,
        r["smoothing"], r["subdivision"], header, data,
    )  # fmt: skip


def mesh_from_points(
    points: np.ndarray,
    s: np.ndarray,
    c: np.ndarray | None,
    sh_degree: int,
    backend: str = "auto",
    smoothing: int = 0,
    subdivision: int = 0,
    creases: bool = False,
    level: str = DEFAULT_LEVEL,
    threads: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Extract the TetWeave surface of a point cloud (in the frame of `points`).

    Args:
        points: (N, 3) positions (float16-rounded values for a faithful preview of a `.tw` file).
        s: (N,) base signed distance, s < 0 inside.
        c: (N, q) SH coefficients, q = (sh_degree + 1) ** 2; None or (N, 0) when sh_degree is -1.
        sh_degree: -1..3.
        backend: Delaunay backend, "auto", "exact", "tetgen" or "qhull" (must match the container's).
        smoothing: Taubin steps 0-3 (the container's flags bits 3-4).
        subdivision: Loop levels 0-2 after the smoothing (flags bits 5-6).
        creases: crease-preserving smoothing (bit 7 of the position-bits byte).
        level: "control", "smoothed" or "full" (the module docstring; ValueError for another name).
        threads: threads of the self-intersection check (1: this thread; 0: every core); the same mesh on any count.
    Returns:
        vertices (V, 3) float64, faces (F, 3) int64 (outward; both empty when s has one sign only).
    """
    smoothing, subdivision = level_filter(smoothing, subdivision, level)
    result = _extract(
        points, s, c, sh_degree, backend, {}, time.perf_counter, smoothing, subdivision, creases, threads=threads
    )
    return result.vertices, result.faces


class _Extracted(NamedTuple):
    vertices: np.ndarray
    faces: np.ndarray
    tz: object
    restored: int
    extracted_faces: np.ndarray
    children: int  # faces per extracted face: 4^L, or 1 when the filter was dropped


def _extract(
    points, s, c, sh_degree, backend, seconds, clock, smoothing=0, subdivision=0, creases=False, scale=1.0, offset=None,
    threads=1,
) -> _Extracted:  # fmt: skip
    """The closed surface and how it was made, timing each stage into `seconds`; its vertices in the output frame
    `v * scale + offset` (the frame of `points` when offset is None)."""
    check_degree(sh_degree)
    pts = np.asarray(points, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64).reshape(-1)
    q = num_coeffs(sh_degree)
    if pts.ndim != 2 or pts.shape[1] != 3 or s.shape != (len(pts),):
        raise ValueError(f"expected points (N, 3) and s (N,), got {pts.shape} and {s.shape}")
    if c is None or q == 0:
        coeffs = None
    else:
        coeffs = np.asarray(c, dtype=np.float64)
        if coeffs.shape != (len(pts), q):
            raise ValueError(f"c must be ({len(pts)}, {q}) for SH degree {sh_degree}, got {coeffs.shape}")
    t0 = clock()
    tz = tetrahedralize(pts, backend)
    t1 = clock()
    mt = marching_tets_numpy(pts, tz.tets, s, coeffs, tz.hull_faces)
    t2 = clock()
    out = filter_surface(mt.vertices, mt.faces, smoothing, subdivision, creases, scale, offset, threads)
    seconds["delaunay"] = t1 - t0
    seconds["marching_tets"] = t2 - t1
    seconds["smoothing"] = clock() - t2
    children = 1 if out.gave_up else 4**subdivision
    return _Extracted(out.vertices, out.faces, tz, out.restored, mt.faces, children)


def decode(
    data: bytes, backend: str | None = None, level: str = DEFAULT_LEVEL, threads: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Decode a `.tw` file to a triangle mesh in the original input's frame.

    Args:
        data: the file's bytes.
        backend: None (the backend recorded in the file) or an explicit override.
        level: "control", "smoothed" or "full" (default: the file's whole filter; the module docstring).
        threads: threads of the self-intersection check, the filter's largest part (1: this thread, as in a
            batch of one file per core; 0: every core this process may use). The same bytes on any count.
    Returns:
        vertices (V, 3) float64, faces (F, 3) int64.
    Raises:
        ContainerError: malformed, truncated, corrupted or unsupported file. ValueError: an unknown level or a
        negative thread count.
    """
    result = decode_detailed(data, backend, level=level, threads=threads)
    return result.vertices, result.faces


def level_faces(data: bytes, backend: str | None = None) -> dict[str, int | None]:
    """Faces of a decode at each level (LEVELS -> count), from the control surface alone (unpack, Delaunay and
    marching tets: no filter, no crossing check).

    control and smoothed: F0 - K (smoothing moves vertices only; the K faces of the holes section go); full:
    (F0 - K) * 4^L, as Loop subdivision splits each face in four per level and the holes take a face's 4^L
    children with it. Exact except where the decoder drops the filter of a surface it cannot keep free of
    crossings within MAX_CHECKS checks (never seen on an encoder's file; full then has F0 - K, what `decode` tells),
    and None for full where the decoder refuses the file (more than MAX_SUBDIVIDED_FACES subdivided faces).
    ContainerError as `decode`."""
    from tetweave_codec.geometry.surface_filter import MAX_SUBDIVIDED_FACES

    result = decode_detailed(data, backend, level="control")
    control = len(result.faces)
    levels = result.header.subdivision
    full: int | None = control * 4**levels
    if levels and len(result.extracted_faces) * 4**levels > MAX_SUBDIVIDED_FACES:
        full = None
    return {"control": control, "smoothed": control, "full": full}


def decode_detailed(
    data: bytes, backend: str | None = None, clock=time.perf_counter, level: str = DEFAULT_LEVEL, threads: int = 1
) -> DecodeResult:
    """`decode` plus the parsed container, the backend used and per-stage timings measured with `clock`."""
    check_level(level)
    threads = resolve_threads(threads)  # ValueError before any work
    if CORE and backend in (None, "exact"):
        result = _core_decode(bytes(data), level, threads, clock)
        if result is not None:
            return result
    from tetweave_codec.formats.tw import unpack

    seconds: dict[str, float] = {}
    t0 = clock()
    tw = unpack(data)
    seconds["unpack"] = clock() - t0
    fallback = False
    if backend is None:
        backend = tw.backend
        if backend not in available_backends():
            fallback = True
            warnings.warn(
                f"this file was triangulated with {backend}, which is not installed; decoding with "
                f"{available_backends()[0]} (the mesh may differ where points are cospherical; "
                f"pip install 'tetweave[tetgen]' reproduces the encoder's mesh)",
                DecodeWarning,
                stacklevel=2,
            )
            backend = available_backends()[0]
    smoothing, subdivision = level_filter(tw.smoothing, tw.subdivision, level)
    try:
        ex = _extract(
            tw.points, tw.s, tw.c, tw.sh_degree, backend, seconds, clock, smoothing, subdivision, tw.creases,
            float(tw.scale), np.asarray(tw.offset, dtype=np.float64), threads,
        )  # fmt: skip
    except ContainerError as exc:
        if not fallback:
            raise
        hint = f"this file needs {tw.backend}: pip install 'tetweave[tetgen]'"
        raise ContainerError(f"{exc} with {backend}; {hint}") from exc
    closed_v = ex.vertices
    vertices, faces = closed_v, ex.faces
    holes = tw.holes
    if holes is not None and len(holes):
        t0 = clock()
        vertices, faces = open_holes(closed_v, ex.faces, ex.extracted_faces, holes, ex.children)
        seconds["holes"] = clock() - t0
    return DecodeResult(
        vertices, faces, tw, ex.tz.backend, seconds, len(ex.tz.tets), ex.restored, ex.extracted_faces, closed_v,
        ex.faces, level, smoothing, subdivision, _header_of(tw), data,
    )  # fmt: skip
