"""Encoder API: mesh -> normalized frame -> fit -> `.tw` bytes, plus the mesh a decoder will rebuild from them.

    result = encode(vertices, faces, points=16384, sh_degree=1, quality="default")
    open("mesh.tw", "wb").write(result.data)
    result.vertices, result.faces   # exactly what `tetweave_codec.decoder.decode(result.data)` returns

The reported mesh is produced by the decoder itself from the finished bytes, so "decode gives exactly the mesh the
encoder reported" holds by construction (and is tested).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
import torch

from tetweave_codec.errors import InputError
from tetweave_codec.fit.config import (
    DEFAULT_SMOOTHING,
    DEFAULT_SUBDIVISION,
    FitConfig,
    Quantization,
    default_quantization,
    scaled_schedule,
    schedule_for,
)
from tetweave_codec.fit.finish import Finalized, FinishResult, complete, finalize, finalize_cells, finish
from tetweave_codec.fit.loop import FitResult, deterministic_torch
from tetweave_codec.fit.step import FitContext, Params, ProgressFn
from tetweave_codec.formats.common import MAX_SUBDIVISION
from tetweave_codec.geometry.sh import check_degree
from tetweave_codec.geometry.smoothing import MAX_STEPS as MAX_SMOOTHING_STEPS
from tetweave_codec.geometry.triangles import face_areas

DEFAULT_POINTS = 16384
DEFAULT_SH_DEGREE = 1
# SH degree of CAD parts (`input_defaults`): none. fandisk, bytes x Chamfer of rate-controlled
# files against degree 1 (benchmarks/results/creases.md, session 7): 10 KB 0.87-0.92 (three seeds), 20 / 40 KB
# 0.97-0.99, 5 KB 0.85-1.10 (three seeds, noise); CSG parts at 1-2 KB median 0.93. On the smooth meshes degree 1
# stays (igea 10 KB 1.075 without it, spot 0.978-1.000, stanford-bunny 0.978-1.014).
CREASED_SH_DEGREE = -1
# Taubin steps of CAD parts (`input_defaults`): three crease-preserving steps (the smoothing keeps the
# extracted surface's creases, geometry.smoothing.crease_neighbours; three is the most the header holds), fitted
# through in the late stage only (FitConfig.main_filter); no subdivision (it raised the edge Chamfer 1.2-2.2x).
# fandisk, bytes x Chamfer against no smoothing at 5 / 10 / 20 / 40 KB (one thread, the same session): 1 step 0.880
# / 0.886 / 0.918 / 0.931, 2 steps 0.828 / 0.830 / 0.893 / 0.910, 3 steps 0.788 / 0.803 / 0.885 / 0.915, with the
# edge Chamfer lower than without smoothing at every size (benchmarks/results/creases.md, session 14).
CREASED_SMOOTHING = 3
# Crease density (`fit.features.crease_density`: crease length / sqrt(area)) from which an input with sharp creases is a
# CAD part and takes the settings above (`input_defaults`); below it, the smooth-mesh settings (one smoothing step, one
# Loop level, SH degree 1) with the creases kept. Shapes whose every face is bounded by creases lie above (a cube 4.90,
# a regular tetrahedron 4.56, boxes and prisms more; fandisk 8.83, the CSG parts of benchmarks/creases.py 5.8-10.3),
# shapes whose creases bound curved faces and organic models with a few sharp details below (a cylinder 2.89, a sphere
# cut by a plane 1.45, a capsule with a flat end 1.14, beast 1.02, cheburashka 0.50). Bytes x Chamfer of --size files,
# smooth settings with creases kept against the CAD settings, one thread, one run: the cut sphere 2 / 5 KB 0.94 / 0.94,
# the capsule 2 KB 0.86, the cylinder 2 KB 0.89, cheburashka 10 KB 0.84, beast 0.93, edge Chamfer 0.93-1.10x; above it
# the CAD settings win on fandisk (5 / 10 / 20 KB 1.15 / 1.04 / 1.46 with the smooth ones, edge Chamfer 1.4-3.1x), the
# cube and the fin (1.03-1.18), not on three boxes (0.65-0.77): benchmarks/results/creases.md, session 15. 4.0 keeps a
# margin below those shapes (cow, 4.49, stays with the CAD settings although it measured 0.92).
CAD_CREASE_DENSITY = 4.0
# Samples per mesh of the Chamfer distance in the summary: enough for ~1e-5 resolution in the normalized frame.
SUMMARY_CHAMFER_SAMPLES = 100_000
MAX_POINTS = 1 << 22
# Samples per mesh of the Chamfer distance that picks between plain and grown hole caps (Job.with_holes): their
# files differ by 5-35 % there, well above this count's noise.
HOLES_CHAMFER_SAMPLES = 30_000
# Where a file's points come from: "fit" places them by optimization (fit.loop), "grid" takes the cells of a band
# around the input (fit.grid), "best" encodes both (rate control only) and keeps the better file: the lower error
# for --size, the smaller file for --max-error. Same container, same decoder.
LAYOUTS = ("fit", "grid", "best")
# What becomes of an open input's holes: "close" (the decoded surface spans them: always watertight) or "keep"
# (the file lists the faces that span them, formats/holes.py, and the decoder removes them: a 2-manifold with
# the input's boundary). Closed inputs decode closed either way.
HOLES = ("close", "keep")


@dataclass
class EncodeResult:
    """What `encode` produced.

    data: the `.tw` file. vertices (V,3) float64 and faces (F,3) int64: the decoded mesh, in the input's frame.
    stats: points_kept, sh_degree, bytes, seconds per stage, chamfer (normalized frame; None if not measured), ...
    """

    data: bytes
    vertices: np.ndarray
    faces: np.ndarray
    stats: dict = field(default_factory=dict)


def resolve_device(device: str | torch.device) -> torch.device:
    """'auto' -> CUDA when available, else CPU."""
    if isinstance(device, torch.device):
        return device
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        raise InputError("device 'cuda' was asked for but no CUDA device is available")
    if device not in ("cpu", "cuda"):
        raise InputError(f"unknown device {device!r}; use auto, cpu or cuda")
    return torch.device(device)


def _validate(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """float64 vertices and int64 faces, or InputError (meshio's checks, plus a surface to fit)."""
    from tetweave_codec.meshio import validate_mesh

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    validate_mesh(v, f)
    if not face_areas(v, f).any():
        raise InputError("mesh: every triangle has zero area")
    if _is_planar(v[np.unique(f)]):
        raise InputError(
            "mesh: every vertex lies in one plane, so the surface encloses no volume; tetweave encodes closed or "
            "nearly closed shapes"
        )
    return v, f


# Relative thickness (smallest over largest singular value of the centred vertices) below which a mesh counts as
# planar: a float64 plane rotated off the axes measures ~1e-16; a sheet 1e-6 thick as 1e-6.
PLANAR_THICKNESS = 1e-9


def _is_planar(points: np.ndarray) -> bool:
    """Whether the points (V,3) lie in one plane, up to PLANAR_THICKNESS of their spread."""
    if len(points) < 4:
        return True
    sv = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)  # descending
    return bool(sv[-1] < PLANAR_THICKNESS * sv[0])


def encode(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    points: int = DEFAULT_POINTS,
    sh_degree: int | None = None,
    quality: str = "default",
    iters: int | None = None,
    device: str | torch.device = "auto",
    seed: int = 0,
    init: str = "sdf",
    progress: ProgressFn | None = None,
    measure: bool = True,
    container_version: int = 2,
    quantization: Quantization | None = None,
    size: int | None = None,
    max_error: float | None = None,
    smoothing: int | None = None,
    subdivision: int | None = None,
    layout: str = "fit",
    holes: str = "close",
    keep_creases: bool | None = None,
) -> EncodeResult:
    """Fit a TetWeave representation to a triangle mesh and return the `.tw` bytes and the decoded mesh.

    vertices (V,3), faces (F,3): any triangle mesh (open, multi-component and non-manifold inputs are fine).
    points: target grid points during the fit (passive ones are dropped before writing, so fewer are stored).
    sh_degree: -1 (none) or 0..3, directional distance coefficients per point (q = (degree+1)^2); None =
        `input_defaults`' choice.
    quality: "fast", "default" or "best" (see fit.QUALITY); iters overrides its main+late iteration count.
    measure: compute the Chamfer distance between the input and the decoded mesh for `stats`.
    container_version: 2 (quantized, entropy-coded; default) or 1 (raw float16).
    quantization: v2's position bits and steps; None = `fit.config.default_quantization(points)`.
    size: rate control, the file is at most `size` bytes and at least 85 % of it (points and quantization are
        chosen by rate_control.py; `points` and `quantization` are ignored).
    max_error: rate control, the decoded mesh's Chamfer distance to the input (normalized frame, the summary's
        metric) is at most `max_error`, at the smallest size rate control finds.
    smoothing: Taubin steps 0-3 the decoder applies to the surface (the fit optimizes the smoothed one); None =
        `input_defaults`' choice for container version 2, 0 for version 1 (which cannot store it).
    subdivision: Loop levels 0-2 the decoder applies after the smoothing (the fit optimizes the subdivided
        surface); None = `input_defaults`' choice for container version 2, 0 for version 1.
    keep_creases: the decoder's smoothing and subdivision keep the creases of the extracted surface (edges whose
        faces turn by more than 30 degrees; geometry.smoothing.crease_neighbours, Loop's crease rules) instead of
        rounding them; None = `input_defaults`' choice (on for inputs with sharp creases). Container version 2;
        nothing to keep without smoothing or subdivision.
    layout: where the points come from (see LAYOUTS): "fit" (placed by the fit, then snapped to the grid),
        "grid" (the cells of a lattice in a band around the input, fit.grid; container version 2 only; `points`
        sets the cell size: the band holds about that many points) or "best" (with `size` or `max_error` only:
        both, and the better file).
    holes: "close" (every output watertight) or "keep" (an open input's holes stay open: the decoder removes the
        faces that span them, listed in the file; container version 2 only). See HOLES.
    Deterministic: the same input, options, seed, device and thread count give the same bytes.
    """
    v, f = _validate(vertices, faces)
    if size is None and max_error is None and not 64 <= points <= MAX_POINTS:
        raise InputError(f"points must be between 64 and {MAX_POINTS}, got {points}")
    if sh_degree is not None:
        try:
            check_degree(sh_degree)
        except ValueError as exc:
            raise InputError(f"{exc} (-1 = none)") from None
    if container_version not in (1, 2):
        raise InputError(f"container version must be 1 or 2, got {container_version}")
    if (size is not None or max_error is not None) and container_version != 2:
        raise InputError("--size and --max-error need container version 2")
    if size is not None and max_error is not None:
        raise InputError("give either a size or a maximum error, not both")
    if layout not in LAYOUTS:
        raise InputError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    if layout != "fit" and (container_version != 2 or quantization is not None):
        raise InputError(f"the {layout} layout needs container version 2 and chooses its own quantization")
    if holes not in HOLES:
        raise InputError(f"holes must be one of {', '.join(HOLES)}, got {holes!r}")
    if holes == "keep" and container_version != 2:
        raise InputError("keeping holes open needs container version 2")
    if layout == "best" and size is None and max_error is None:
        raise InputError("the best layout compares the two layouts' files at a --size or --max-error")
    if smoothing is not None and not 0 <= smoothing <= MAX_SMOOTHING_STEPS:
        raise InputError(f"smoothing must be 0-{MAX_SMOOTHING_STEPS} steps, got {smoothing}")
    if smoothing and container_version != 2:
        raise InputError("smoothing needs container version 2")
    if subdivision is not None and not 0 <= subdivision <= MAX_SUBDIVISION:
        raise InputError(f"subdivision must be 0-{MAX_SUBDIVISION} levels, got {subdivision}")
    if subdivision and container_version != 2:
        raise InputError("subdivision needs container version 2")
    if keep_creases and container_version != 2:
        raise InputError("keeping creases in the smoothing needs container version 2")
    if smoothing is None or subdivision is None or sh_degree is None or keep_creases is None:
        chosen = input_defaults(v, f)
        if container_version != 2:  # version 1 stores neither filter
            chosen = chosen._replace(smoothing=0, subdivision=0, creases=False)
        smoothing = chosen.smoothing if smoothing is None else smoothing
        subdivision = chosen.subdivision if subdivision is None else subdivision
        sh_degree = chosen.sh_degree if sh_degree is None else sh_degree
        keep_creases = chosen.creases if keep_creases is None else keep_creases

    def make_job(layout: str) -> Job:
        return Job(
            v,
            f,
            sh_degree,
            schedule_for(quality, iters),
            quality,
            resolve_device(device),
            seed,
            init,
            progress,
            scale_iterations=iters is None,
            smoothing=smoothing,
            subdivision=subdivision,
            layout=layout,
            keep_holes=holes == "keep",
            creases=bool(keep_creases and (smoothing or subdivision)),
        )

    if layout == "best":
        return _best_layout(make_job, size, max_error)
    job = make_job(layout)
    if size is not None:
        from tetweave_codec.rate_control import encode_to_size

        return encode_to_size(job, int(size), measure=measure)
    if max_error is not None:
        from tetweave_codec.rate_control import encode_to_error

        return encode_to_error(job, float(max_error))
    if container_version == 1:
        ctx, params = job.main_stage(points, None)
        with deterministic_torch():
            fin = finish(params, ctx)
        return job.result(fin, ctx, points, measure=measure)
    ctx, fixed, quantization = job.stage(points, quantization)
    with deterministic_torch():
        fin = complete(fixed, ctx, quantization)
    return job.result(fin, ctx, points, measure=measure)


def _best_layout(make_job, size: int | None, max_error: float | None) -> EncodeResult:
    """Rate control in both layouts; the file with the lower Chamfer distance (--size) or the fewer bytes
    (--max-error). A layout that cannot meet the target is skipped; when neither can, the fit layout's error is
    raised. The stats say which layout won and what each gave ("layouts")."""
    from tetweave_codec.rate_control import encode_to_error, encode_to_size

    t0 = time.perf_counter()
    results: dict[str, EncodeResult] = {}
    failures: dict[str, InputError] = {}
    for name in ("fit", "grid"):
        try:
            job = make_job(name)
            if size is not None:
                results[name] = encode_to_size(job, int(size), measure=True)
            else:
                results[name] = encode_to_error(job, float(max_error))
        except InputError as exc:
            failures[name] = exc
    if not results:
        raise failures["fit"]
    if size is not None:
        best = min(results, key=lambda k: (results[k].stats["chamfer"], len(results[k].data)))
    else:
        best = min(results, key=lambda k: (len(results[k].data), results[k].stats["chamfer"]))
    chosen = results[best]
    tried = {k: {"bytes": len(r.data), "chamfer": r.stats["chamfer"]} for k, r in results.items()}
    tried.update({k: {"error": str(exc)} for k, exc in failures.items()})
    others = ", ".join(
        f"{k}: {t['bytes']:,} B at {t['chamfer']:.3g}" if "bytes" in t else f"{k}: {t['error']}"
        for k, t in tried.items()
        if k != best
    )
    stats = dict(chosen.stats, layouts=tried)
    stats["rate_control"] = f"best layout {best} ({chosen.stats['rate_control']}; {others})"
    stats["seconds"] = dict(stats["seconds"], total=time.perf_counter() - t0)
    return EncodeResult(chosen.data, chosen.vertices, chosen.faces, stats)


class InputDefaults(NamedTuple):
    """What `encode` picks for an input when not told: the decoder's Taubin steps and Loop levels, the SH degree."""

    smoothing: int
    subdivision: int
    sh_degree: int
    creases: bool = False  # the smoothing keeps the surface's creases


def input_defaults(vertices: np.ndarray, faces: np.ndarray) -> InputDefaults:
    """The settings `encode` picks for a mesh. Without sharp creases (`fit.features.detect_features(...).found`):
    (DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION, DEFAULT_SH_DEGREE, no creases kept). CAD parts (sharp creases with a
    crease density of at least CAD_CREASE_DENSITY): (CREASED_SMOOTHING, 0, CREASED_SH_DEGREE, creases kept). Other
    inputs with sharp creases (curved faces between a few creases, organic models with sharp details): the smooth
    settings with the creases kept. Why: the plain smoothing and subdivision round every crease the fit reproduces
    (on CSG parts smoothing doubled the edge Chamfer distance at 1-2 KB, benchmarks/results/smoothing.md), while on
    scans and smooth shapes they save bytes at equal error (benchmarks/results/subdivision.md); crease-preserving
    smoothing saves CAD parts bytes without rounding their edges, Loop subdivision even with crease rules still
    raised their edge Chamfer (see CREASED_SMOOTHING); the SH coefficients cost CAD parts more than they buy (see
    CREASED_SH_DEGREE); where the creases bound only a small part of the surface, the smooth settings with the
    creases kept win (see CAD_CREASE_DENSITY). vertices (V,3) in any frame (the creases are looked for in the
    normalized frame, as the fit's start does)."""
    from tetweave_codec.fit.features import crease_density, detect_features
    from tetweave_codec.meshio import normalize

    normalized = normalize(vertices)[0]
    features = detect_features(normalized, faces)
    if not features.found:
        return InputDefaults(DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION, DEFAULT_SH_DEGREE)
    if crease_density(features, normalized, faces) >= CAD_CREASE_DENSITY:
        return InputDefaults(CREASED_SMOOTHING, 0, CREASED_SH_DEGREE, creases=True)
    return InputDefaults(DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION, DEFAULT_SH_DEGREE, creases=True)


class Job:
    """One encode's fixed inputs (the mesh, its normalized frame, the fit settings) and the steps every encode
    path shares: main stage, packing, decoding and the summary. Rate control (rate_control.py) runs several fits
    of one Job."""

    def __init__(
        self,
        v,
        f,
        sh_degree,
        schedule,
        quality,
        device,
        seed,
        init,
        progress,
        scale_iterations=True,
        smoothing=0,
        subdivision=0,
        layout="fit",
        keep_holes=False,
        creases=False,
    ):
        """scale_iterations: run `fit.config.scaled_schedule` of `schedule` for each point count (off when the
        caller fixed the iterations). smoothing, subdivision: the decoder's Taubin steps and Loop levels (stored
        in the file); creases: the smoothing keeps the surface's creases (stored in the file). layout: "fit" or
        "grid" (LAYOUTS). keep_holes: every packed file of an open input lists
        the faces that span its holes (HOLES "keep")."""
        from tetweave_codec.meshio import normalize

        self.t_start = time.perf_counter()
        self.v, self.f = v, f
        self.normalized, self.scale, self.offset = normalize(v)
        self.sh_degree, self.schedule, self.quality = sh_degree, schedule, quality
        self.device, self.seed, self.init, self.progress = device, seed, init, progress
        self.scale_iterations = scale_iterations
        self.smoothing, self.subdivision, self.creases = smoothing, subdivision, bool(creases)
        self.layout = layout
        self.seconds: dict[str, float] = {}
        self.detail: float | None = None  # rate_control.input_detail, once asked for
        self._band = None
        self.rim = None
        if keep_holes:
            from tetweave_codec.fit.holes import input_rim

            self.rim = input_rim(self.normalized, self.f)

    def config(self, points: int, quantization: Quantization | None, feature_only: bool = False) -> FitConfig:
        """The fit's settings at `points`. feature_only: the start is kept as the point set (no resampling, no
        relocation) and its points next to creases take plane distances (rate_control's feature-only fit)."""
        schedule = scaled_schedule(self.schedule, points) if self.scale_iterations else self.schedule
        if feature_only:
            schedule = replace(schedule, resample_at=(), relocate=0.0)
        return FitConfig(
            points=points,
            sh_degree=self.sh_degree,
            schedule=schedule,
            init=self.init,
            seed=self.seed,
            quantization=quantization,
            smoothing=self.smoothing,
            subdivision=self.subdivision,
            creases=self.creases,
            main_filter=not self.creases,
            plane_distances=feature_only,
        )

    def main_stage(
        self, points: int, quantization: Quantization | None, feature_only: bool = False
    ) -> tuple[FitContext, Params]:
        """Targets, start and main stage of a fit at `points` (`fit.loop.fit_main`); its context and parameters."""
        from tetweave_codec.fit.loop import fit_main

        config = self.config(points, quantization, feature_only)
        return fit_main(self.normalized, self.f, config, self.device, self.progress)

    def stage(
        self, points: int, quantization: Quantization | None = None, feature_only: bool = False
    ) -> tuple[FitContext, Finalized, Quantization]:
        """The fixed point set of a version-2 file of about `points` points, before the late stage: its context, the
        Finalized points and their quantization. Fit layout: the main stage, then the grid of `quantization`
        (default_quantization(points) when None). Grid layout: the band whose cells hold about `points` points.
        feature_only: see `config`."""
        if self.layout == "grid":
            from tetweave_codec.fit.grid import frame_for_cell

            return self.grid_stage(frame_for_cell(self.grid_band().cell_for_points(points)))
        quantization = default_quantization(points) if quantization is None else quantization
        ctx, params = self.main_stage(points, quantization, feature_only)
        with deterministic_torch():
            fixed = finalize(params, ctx, quantization.position_bits, quantization.grid_scale)
        return ctx, fixed, quantization

    def grid_band(self):
        """The input prepared for the grid layout's band queries (`fit.grid.GridBand`), built once per job."""
        from tetweave_codec.fit.grid import GridBand

        if self._band is None:
            t0 = time.perf_counter()
            self._band = GridBand(self.normalized, self.f, seed=self.seed)
            self.seconds["band"] = time.perf_counter() - t0
        return self._band

    def grid_quantization(self, frame, points: int) -> Quantization:
        """The grid layout's quantization at `frame` (fit.grid.GridFrame): its stored bits, s step GRID_S_STEP lattice
        cells (grid frame), the default c steps for `points`."""
        from tetweave_codec.fit.grid import GRID_S_STEP, lattice_cell

        base = default_quantization(points)
        return Quantization(frame.stored_bits, GRID_S_STEP * lattice_cell(frame.bits), base.c_band_steps)

    def grid_stage(self, frame) -> tuple[FitContext, Finalized, Quantization]:
        """The grid layout's fixed points at `frame` (fit.grid.GridFrame), s the signed distance, c zero; the
        context is that of a fit in the grid frame (the normalized frame x frame.frame_scale)."""
        from tetweave_codec.fit.loop import prepare
        from tetweave_codec.fit.step import noop_progress
        from tetweave_codec.geometry.sh import num_coeffs

        t0 = time.perf_counter()
        cells, s = self.grid_band().cells(frame)
        quant = self.grid_quantization(frame, len(cells))
        with deterministic_torch():
            ctx = prepare(
                self.normalized * frame.frame_scale,
                self.f,
                self.config(len(cells), quant),
                self.device,
                self.progress or noop_progress,
            )
        ctx.frame_scale = frame.frame_scale
        c = np.zeros((len(cells), num_coeffs(self.sh_degree)), dtype=np.float32)
        fixed = finalize_cells(cells, s.astype(np.float32), c, frame.stored_bits, ctx.backend)
        ctx.seconds["grid"] = time.perf_counter() - t0
        return ctx, fixed, quant

    def pack(self, fin: FinishResult, ctx: FitContext) -> bytes:
        """The file of `fin`, with the holes section when the job keeps an open input's holes."""
        cfg = ctx.config
        data = self.pack_as(fin, ctx.backend, ctx.frame_scale, cfg.smoothing, cfg.subdivision, cfg.creases)
        return data if self.rim is None else self.with_holes(data)

    def with_holes(self, data: bytes) -> bytes:
        """`data` (a version-2 file without holes) with a holes section listing the faces of its decoded surface
        that span the input's holes (fit.holes); `data` itself when there are none. When the caps grown into their
        far neighbours (`fit.holes.cap_faces(grow=True)`) differ from the plain ones, the file whose decoded mesh
        is closer to the input (Chamfer distance, HOLES_CHAMFER_SAMPLES) is kept: growing them follows a cap that
        sags into the shape (stanford-bunny 40 KB: Chamfer 3.7e-4 -> 2.4e-4) but can cut into the surface around
        the rim (10 KB: 6.1e-4 -> 6.5e-4)."""
        from dataclasses import replace

        from tetweave_codec.decoder import decode_detailed
        from tetweave_codec.fit.holes import hole_ranks
        from tetweave_codec.formats.common import FLAG_HOLES
        from tetweave_codec.formats.tw import pack_v2, unpack
        from tetweave_codec.metrics import chamfer_distance

        t0 = time.perf_counter()
        full = decode_detailed(data)
        closed = (full.closed_vertices - self.offset) / self.scale
        tw = unpack(data)
        files = []
        for grow in (False, True):
            ranks = hole_ranks(self.rim, closed, full.extracted_faces, grow)
            if len(ranks) and not any(np.array_equal(ranks, r) for r, _ in files):
                files.append((ranks, pack_v2(replace(tw, flags=tw.flags | FLAG_HOLES, holes=ranks, sizes=None))))
        if len(files) > 1:
            errors = []
            for _, candidate in files:
                out = decode_detailed(candidate)
                errors.append(
                    chamfer_distance(self.v, self.f, out.vertices, out.faces, HOLES_CHAMFER_SAMPLES, seed=self.seed)
                )
            files = [files[int(np.argmin(errors))]]
        self.seconds["holes"] = self.seconds.get("holes", 0.0) + time.perf_counter() - t0
        return files[0][1] if files else data

    def pack_as(
        self, fin: FinishResult, backend: str, frame_scale: float, smoothing: int, subdivision: int, creases: bool
    ) -> bytes:
        """The bytes of `fin` for a fit in the frame normalized x frame_scale (the transform divides it out)."""
        result = FitResult(fin, self.sh_degree, backend, {}, [], smoothing, subdivision, creases)
        return pack_result(result, self.scale / frame_scale, self.offset)

    def _kept_filter(self, data: bytes, full, chamfer: float | None):
        """(bytes, DecodeResult, Chamfer or None) of the file to keep, given `full`, the decoder's result for `data`.
        When the decoder had to drop a subdivided file's whole filter (its crossing check did not settle: the result
        is the unsmoothed, unsubdivided surface of a fit made for the subdivided one), the same points with the
        subdivision bits cleared (the smoothing alone, with its own check) are kept instead if they decode closer to
        the input. Same bytes."""
        from dataclasses import replace

        from tetweave_codec.decoder import decode_detailed
        from tetweave_codec.formats.common import FLAG_SUBDIVISION
        from tetweave_codec.formats.tw import pack_v2, unpack

        if not full.container.subdivision or not len(full.faces) or full.restored != len(full.vertices):
            return data, full, chamfer
        tw = unpack(data)
        alt = pack_v2(replace(tw, flags=tw.flags & ~FLAG_SUBDIVISION, sizes=None))
        alt_full = decode_detailed(alt)
        err = self.chamfer(full.vertices, full.faces) if chamfer is None else chamfer
        alt_err = self.chamfer(alt_full.vertices, alt_full.faces)
        if alt_err < err:
            return alt, alt_full, alt_err
        return data, full, err

    def chamfer(self, out_v: np.ndarray, out_f: np.ndarray) -> float:
        """The summary's error: Chamfer distance to the input in its normalized frame (SUMMARY_CHAMFER_SAMPLES)."""
        from tetweave_codec.metrics import chamfer_distance

        if not len(out_f):
            return float("inf")
        return chamfer_distance(self.v, self.f, out_v, out_f, n_samples=SUMMARY_CHAMFER_SAMPLES, seed=self.seed)

    def result(
        self,
        fin: FinishResult,
        ctx: FitContext,
        points: int,
        *,
        measure: bool = True,
        data: bytes | None = None,
        decoded=None,
        chamfer: float | None = None,
        extra: dict | None = None,
    ) -> EncodeResult:
        """The EncodeResult of a finished fit: bytes, the decoder's mesh and the summary statistics. decoded: the
        `decoder.DecodeResult` of `data` when the caller has it (rate control), else the file is decoded here."""
        from tetweave_codec.decoder import decode_detailed

        t0 = time.perf_counter()
        data = self.pack(fin, ctx) if data is None else data
        full = decode_detailed(data) if decoded is None else decoded
        if self.subdivision:
            data, full, chamfer = self._kept_filter(data, full, chamfer)
        out_v, out_f = full.vertices, full.faces
        seconds = {**self.seconds, **ctx.seconds}
        seconds["extract"] = time.perf_counter() - t0
        seconds["total"] = time.perf_counter() - self.t_start
        stats = {
            "bytes": len(data),
            "points_kept": int(len(fin.s)),
            "container_version": fin.version,
            "quantization": fin.quantization,
            "points_target": points,
            "sh_degree": self.sh_degree,
            "layout": self.layout,
            "quality": self.quality,
            "device": str(self.device),
            "vertices": int(len(out_v)),
            "faces": int(len(out_f)),
            "hole_faces": _hole_faces(full.container),
            "seconds": seconds,
            "chamfer": chamfer,
        }
        stats.update(extra or {})
        if measure and chamfer is None and len(out_f):
            stats["chamfer"] = self.chamfer(out_v, out_f)
        return EncodeResult(data, out_v, out_f, stats)


def _hole_faces(container) -> int:
    """Faces a file's holes section removes (0 without one, and in version 1)."""
    holes = container.holes
    return 0 if holes is None else int(len(holes))


def pack_result(result: FitResult, scale: float, offset: np.ndarray) -> bytes:
    """The `.tw` bytes of a fit: version 1 or 2 after `result.finish.version`."""
    from tetweave_codec.formats import octree
    from tetweave_codec.formats.common import (
        FLAG_OCTREE_CONTEXTS,
        FLAG_S_PREDICTED,
        smoothing_flags,
        subdivision_flags,
    )
    from tetweave_codec.formats.tw import TetWeaveFile, TetWeaveFileV2, backend_flags, pack, pack_v2

    fin = result.finish
    shared = {
        "sh_degree": result.sh_degree,
        "scale": float(scale),
        "offset": np.asarray(offset, dtype=np.float64),
        "flags": backend_flags(result.backend),
    }
    if fin.version == 1:
        if result.smoothing or result.subdivision or result.creases:
            raise ValueError("container version 1 cannot store smoothing or subdivision")
        return pack(TetWeaveFile(points=fin.points, s=fin.s, c=fin.c, **shared))
    shared["flags"] |= smoothing_flags(result.smoothing) | subdivision_flags(result.subdivision)
    q = fin.quantization
    # The cells hold grid_scale x the fit's positions: the transform divides it out (s and c are unchanged: a
    # marching-tets surface depends on the positions only through the edges' endpoints, on s only through ratios).
    shared["scale"] = float(scale) / q.grid_scale
    steps = tuple(q.c_band_steps[: result.sh_degree + 1])
    shared["flags"] |= FLAG_S_PREDICTED
    if octree.contexts_pay(fin.cells, q.position_bits):  # the new coding only where it saves bytes
        shared["flags"] |= FLAG_OCTREE_CONTEXTS
    return pack_v2(
        TetWeaveFileV2(
            cells=fin.cells,
            s_sym=fin.s_sym,
            c_sym=fin.c_sym,
            position_bits=q.position_bits,
            s_step=q.s_step,
            c_band_steps=steps,
            creases=bool(result.creases and (result.smoothing or result.subdivision)),
            **shared,
        )
    )
