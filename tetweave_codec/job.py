"""One encode's parts: its prepared input, its fit settings, its layout's stage and its packager.

`Job` puts them together for the encode paths (a fixed point count in encoder.py, rate control's several fits in
rate_control/): each fit of a job starts from the same `fit.prepared.PreparedInput` (normalized once, creases,
tree and surface samples computed once), runs the layout's stage (`fit_layout_stage`: the main stage, then the
points snapped to the position grid; `grid_layout_stage`: the cells of a band around the input), is finished by
the caller (fit.finish) and packed by the job's `packing.Packer`; `Job.result` reports the kept file.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from tetweave_codec.fit.config import FitConfig, Schedule, scaled_schedule
from tetweave_codec.fit.finish import Finalized, FinishResult, finalize, finalize_cells
from tetweave_codec.fit.loop import deterministic_torch
from tetweave_codec.fit.prepared import PreparedInput
from tetweave_codec.fit.step import FitContext, Params, ProgressFn
from tetweave_codec.formats.quantize import Quantization, default_quantization
from tetweave_codec.packing import SUMMARY_CHAMFER_SAMPLES, Packed, Packer


@dataclass
class EncodeResult:
    """What `encode` produced.

    data: the `.tw` file. vertices (V,3) float64 and faces (F,3) int64: the decoded mesh, in the input's frame.
    stats: points_kept, sh_degree, bytes, seconds per stage, chamfer (normalized frame; None if not measured), ...
    prepared: the encode's prepared input (its normalized mesh and Chamfer reference), for comparisons measured
    with the summary's own metric (`classical`, the CLI's plain-Draco line).
    """

    data: bytes
    vertices: np.ndarray
    faces: np.ndarray
    stats: dict = field(default_factory=dict)
    prepared: PreparedInput | None = field(default=None, repr=False)


@dataclass(frozen=True)
class FitSettings:
    """What every fit of one encode shares (`config` makes a fit's FitConfig at a point count).

    schedule: the quality preset's iterations; scale_iterations: run `fit.config.scaled_schedule` of it for each
    point count (off when the caller fixed the iterations). smoothing, subdivision: the decoder's Taubin steps and
    Loop levels (stored in the file); creases: the smoothing keeps the surface's creases (stored in the file).
    """

    sh_degree: int
    schedule: Schedule
    quality: str = "default"
    device: torch.device = torch.device("cpu")
    seed: int = 0
    init: str = "sdf"
    scale_iterations: bool = True
    smoothing: int = 0
    subdivision: int = 0
    creases: bool = False

    def config(self, points: int, quantization: Quantization | None, feature_only: bool = False) -> FitConfig:
        """The fit's settings at `points`. feature_only: the start is kept as the point set (no resampling, no
        relocation) and its points next to creases take plane distances (rate control's feature-only fit)."""
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
            plane_distances=feature_only,
        )


@dataclass
class Job:
    """One encode: the prepared input, the fit settings, the layout ("fit" or "grid", encoder.LAYOUTS), the
    progress callback and the packager. Rate control runs several fits of one job; seconds collects the timings
    that are not a fit's own (the grid band, the holes)."""

    input: PreparedInput
    settings: FitSettings
    layout: str = "fit"
    progress: ProgressFn | None = None
    seconds: dict = field(default_factory=dict)
    t_start: float = field(default_factory=time.perf_counter)
    packer: Packer = field(init=False)
    _band: object = field(default=None, init=False, repr=False)

    def __post_init__(self):
        self.packer = Packer(self.input, self.settings.sh_degree, self.seconds)

    def main_stage(
        self, points: int, quantization: Quantization | None, feature_only: bool = False
    ) -> tuple[FitContext, Params]:
        """Start and main stage of a fit at `points` (`fit.loop.fit_main`); its context and parameters."""
        from tetweave_codec.fit.loop import fit_main

        config = self.settings.config(points, quantization, feature_only)
        prepared = self.input
        return fit_main(
            prepared.normalized, prepared.faces, config, self.settings.device, self.progress, prepared=prepared
        )

    def stage(
        self, points: int, quantization: Quantization | None = None, feature_only: bool = False
    ) -> tuple[FitContext, Finalized, Quantization]:
        """The layout's fixed point set of a version-2 file of about `points` points, before the late stage: its
        context, the Finalized points and their quantization (`fit_layout_stage` or `grid_layout_stage`)."""
        if self.layout == "grid":
            from tetweave_codec.fit.grid import frame_for_cell

            return grid_layout_stage(self, frame_for_cell(self.grid_band().cell_for_points(points)))
        return fit_layout_stage(self, points, quantization, feature_only)

    def grid_band(self):
        """The input prepared for the grid layout's band queries (`fit.grid.GridBand`), built once per job."""
        from tetweave_codec.fit.grid import GridBand

        if self._band is None:
            t0 = time.perf_counter()
            prepared = self.input
            self._band = GridBand(prepared.normalized, prepared.faces, seed=self.settings.seed, tree=prepared.tree)
            self.seconds["band"] = time.perf_counter() - t0
        return self._band

    def packed(self, fin: FinishResult, ctx: FitContext) -> Packed:
        """The file of a finished fit (`packing.Packer.pack`), with its decoded mesh when packing knows it."""
        return self.packer.pack(fin, ctx)

    def pack(self, fin: FinishResult, ctx: FitContext) -> bytes:
        """The bytes of a finished fit."""
        return self.packer.pack(fin, ctx).data

    def chamfer(self, out_v: np.ndarray, out_f: np.ndarray) -> float:
        """The summary's error: Chamfer distance to the input in its normalized frame (SUMMARY_CHAMFER_SAMPLES) of a
        mesh in the input's frame; inf for an empty mesh."""
        if not len(out_f):
            return float("inf")
        return self.input.chamfer(out_v, out_f, SUMMARY_CHAMFER_SAMPLES)

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
        `decoder.DecodeResult` of `data` when the caller has it (rate control, packing), else the file is decoded
        here."""
        from tetweave_codec.decoder import decode_detailed

        t0 = time.perf_counter()
        if data is None:
            packed = self.packed(fin, ctx)
            data, decoded = packed.data, packed.decoded
        full = decode_detailed(data) if decoded is None else decoded
        settings = self.settings
        if settings.subdivision:
            data, full, chamfer = self.packer.kept_filter(data, full, chamfer, self.chamfer)
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
            "sh_degree": settings.sh_degree,
            "layout": self.layout,
            "quality": settings.quality,
            "device": str(settings.device),
            "vertices": int(len(out_v)),
            "faces": int(len(out_f)),
            "hole_faces": _hole_faces(full.container),
            "seconds": seconds,
            "chamfer": chamfer,
            "surface": self.input.surface,
            "surface_reason": self.input.surface_reason,
        }
        stats.update(extra or {})
        if measure and chamfer is None and len(out_f):
            stats["chamfer"] = self.chamfer(out_v, out_f)
        return EncodeResult(data, out_v, out_f, stats, self.input)


def fit_layout_stage(
    job: Job, points: int, quantization: Quantization | None, feature_only: bool = False
) -> tuple[FitContext, Finalized, Quantization]:
    """The fit layout's fixed points: the main stage at `points`, then the points snapped to the grid of
    `quantization` (default_quantization(points) when None). feature_only: see `FitSettings.config`."""
    quantization = default_quantization(points) if quantization is None else quantization
    ctx, params = job.main_stage(points, quantization, feature_only)
    with deterministic_torch():
        fixed = finalize(params, ctx, quantization.position_bits, quantization.grid_scale)
    return ctx, fixed, quantization


def grid_quantization(frame, points: int) -> Quantization:
    """The grid layout's quantization at `frame` (fit.grid.GridFrame): its stored bits, s step GRID_S_STEP lattice
    cells (grid frame), the default c steps for `points`."""
    from tetweave_codec.fit.grid import GRID_S_STEP, lattice_cell

    base = default_quantization(points)
    return Quantization(frame.stored_bits, GRID_S_STEP * lattice_cell(frame.bits), base.c_band_steps)


def grid_layout_stage(job: Job, frame) -> tuple[FitContext, Finalized, Quantization]:
    """The grid layout's fixed points at `frame` (fit.grid.GridFrame), s the signed distance, c zero; the context
    is that of a fit in the grid frame (the normalized frame x frame.frame_scale, whose 3-D term is built for that
    frame)."""
    from tetweave_codec.fit.loop import prepare
    from tetweave_codec.fit.step import noop_progress
    from tetweave_codec.geometry.sh import num_coeffs

    t0 = time.perf_counter()
    cells, s = job.grid_band().cells(frame)
    quant = grid_quantization(frame, len(cells))
    prepared, settings = job.input, job.settings
    with deterministic_torch():
        ctx = prepare(
            prepared.normalized * frame.frame_scale,
            prepared.faces,
            settings.config(len(cells), quant),
            settings.device,
            job.progress or noop_progress,
        )
    ctx.frame_scale = frame.frame_scale
    c = np.zeros((len(cells), num_coeffs(settings.sh_degree)), dtype=np.float32)
    fixed = finalize_cells(cells, s.astype(np.float32), c, frame.stored_bits, ctx.backend)
    ctx.seconds["grid"] = time.perf_counter() - t0
    return ctx, fixed, quant


def _hole_faces(container) -> int:
    """Faces a file's holes section removes (0 without one, and in version 1)."""
    holes = container.holes
    return 0 if holes is None else int(len(holes))


def make_job(
    vertices: np.ndarray,
    faces: np.ndarray,
    settings: FitSettings,
    *,
    layout: str = "fit",
    keep_holes: bool = False,
    progress: ProgressFn | None = None,
) -> Job:
    """A job of an input not prepared yet (vertices (V,3), faces (F,3), already valid): tests and scripts that
    drive rate control or a stage directly; `encoder.encode` prepares the input itself and shares it."""
    from tetweave_codec.fit.prepared import prepare_input

    prepared = prepare_input(vertices, faces, seed=settings.seed, keep_holes=keep_holes)
    return Job(prepared, settings, layout, progress)
