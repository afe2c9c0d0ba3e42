"""Fit settings: schedules (the `--quality` presets), loss weights, step sizes and `FitConfig`.

Plain frozen dataclasses; every value that changes what the encoder writes is held by `FitConfig` (its
quantization a formats.quantize.Quantization, whose defaults live there), so "same options, same bytes" can be
read off one object.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from tetweave_codec.errors import TetweaveError
from tetweave_codec.formats.quantize import Quantization


@dataclass(frozen=True)
class Schedule:
    """How long and how finely to fit. See `QUALITY` for the presets."""

    main_iters: int
    late_iters: int
    views_per_iter: int
    size: int  # render resolution (pixels per side)
    n_views: int  # target views rendered up front
    delaunay_every: int = 5  # paper's m
    # Resampling (fractions of the main stage), initial points as a fraction of the target count, and the start of
    # the settle phase (positions take LearningRates.points_settle). From the SDF start every point can be placed
    # at once; growing the set (0.5 -> 1 over three events at 0.15 / 0.35 / 0.55, settle at 0.6) left the points
    # less time to settle. Measured at equal points (container v2, bytes x Chamfer, lower is better), 4K points
    # fandisk / spot / stanford-bunny: grown 3.42 / 4.60 / 11.94; all points from the start, two relocations at
    # 0.15 / 0.3, settle at 0.4: 3.05 / 3.62 / 9.83 (kept); settle at 0.3 (0.1 / 0.2): 2.85 / 3.56 / 10.48; at
    # 0.5 (0.2 / 0.4): 2.98 / 3.85 / 10.03; start 0.75 with settle at 0.45: 3.07 / 3.99 / 10.45. 16K points:
    # spot 5.06 -> 4.32; stanford-bunny seed 0 19.66 -> 27.41 but seed 1 (Chamfer) 6.29e-4 -> 5.17e-4 -- the
    # bunny's hole caps (2-3 % of its area, 60-78 % of the mesh-to-input distance) vary from fit to fit. With
    # `relocate` moving active points too, three events at 0.1 / 0.2 / 0.3 (docs/measurements/relocation.md).
    resample_at: tuple[float, ...] = (0.1, 0.2, 0.3)
    start_fraction: float = 1.0
    settle_at: float = 0.4
    # Fraction of the target point count each resampling also moves among the active points and their
    # neighbours, the cheapest to remove first (fit.relocate); 0 = only passive points move (the paper). See
    # docs/measurements/relocation.md.
    relocate: float = 0.15
    # Input surface samples per call of the 3-D term (and mesh samples, at least as many); None: the term's own
    # fit.surface_loss.INPUT_SAMPLES. Fewer only for the default encode of a tiny input (encoder.SMALL_INPUT_SAMPLES).
    surface_samples: int | None = None


# Iteration counts are far below the paper's 5000 + 2000: the SDF start begins near the answer, and the 3-D term
# converges in a few hundred steps (see benchmarks/encode_speed.py). "default" is sized for 16K points in about
# 3 minutes on 2 CPU cores.
QUALITY: dict[str, Schedule] = {
    "fast": Schedule(main_iters=80, late_iters=40, views_per_iter=2, size=128, n_views=32),
    "default": Schedule(main_iters=250, late_iters=150, views_per_iter=2, size=160, n_views=64),
    "best": Schedule(main_iters=800, late_iters=400, views_per_iter=4, size=256, n_views=96),
}


@dataclass(frozen=True)
class Weights:
    """Loss weights (paper Appendix A: mask 10, depth 250, normals 1, fairness 0.35, ODT 0.1, sign 1).

    The image terms are off. With the exact 3-D term present, renders at CPU-affordable resolutions mostly add
    pixel-scale noise: spot at 8K points (120 + 60 iterations) reached Chamfer 7.3e-4 with the paper's image
    weights, 5.1e-4 with a tenth of them and 4.3e-4 without them. With them off and the 3-D term on, the input is
    not rendered at all: the error-driven resampling measures the distance to the input instead of comparing
    normal maps (fit.loop._importance; `uses_images`).
    """

    # Off: the renders cost a quarter of the fit's CPU time, and with the 3-D term sampling the mesh by area
    # (surface_loss.py) the fit without them beat the fit before on all four meshes (renders with area samples
    # were not measured). One run at 10 KB, bytes x Chamfer relative to the fit before (these weights at
    # 1 / 25 / 0.1, the 3-D term at the vertices), CPU time in brackets: images off and area samples 0.875 (0.77x)
    # spot, 0.958 (0.76x) fandisk, 0.873 (0.75x) igea, 0.932 (0.75x) stanford-bunny; images off alone 1.01 spot,
    # 1.10 fandisk (docs/measurements/encode_speed.md).
    mask: float = 0.0
    depth: float = 0.0
    normals: float = 0.0
    fairness: float = 0.35
    odt: float = 0.1
    # The paper's 1.0 suppresses spurious surfaces grown from a random start. From the SDF start there are none,
    # and at 1.0 the term (whose gradient pulls |s| up on both ends of every active edge, i.e. vertices towards
    # edge midpoints) made a torus fit worse than its starting point (Chamfer 3.6e-3 -> 5.0e-3).
    sign: float = 0.02
    surface: float = 1000.0  # 3-D Chamfer against the input (surface_loss.py); 0 = the paper's renders only
    # Normal error against the input at the 3-D term's sample pairs (surface_loss.py), used only with `surface`.
    # One run at 10 KB, bytes x Chamfer against 0: 10 -> spot 0.963, igea 0.963 (normal consistency +0.0009 /
    # +0.0029, edge Chamfer 0.30x / 0.37x); 40 -> 0.995 / 0.997 (NC +0.0011 / +0.0038).
    surface_normals: float = 10.0

    def uses_images(self) -> bool:
        """Whether the loss renders the mesh (any image term weighted); else the iterations skip rasterization."""
        return self.mask > 0 or self.depth > 0 or self.normals > 0

    @classmethod
    def paper(cls) -> Weights:
        """The paper's weights (Appendix A), renders only: the single source of "paper's weights"."""
        return cls(
            mask=10.0, depth=250.0, normals=1.0, fairness=0.35, odt=0.1, sign=1.0, surface=0.0, surface_normals=0.0
        )


@dataclass(frozen=True)
class LearningRates:
    """AdamW step sizes.

    The paper uses 3e-4 (points), 2e-3 (s), 3e-3 (c) from a random start. Adam moves each parameter by about its
    step size per iteration whatever the gradient's scale, and from the SDF start s is already within a fraction
    of the grid spacing of its optimum, so those steps only add jitter (torus, 2K points: Chamfer 4.9e-3 with
    the paper's steps, 3.6e-3 with these).
    """

    points: float = 1e-4
    s: float = 5e-4
    c: float = 1e-3
    # Position step once resampling is over (Schedule.settle_at): 25x the step before. With 1e-4 throughout, the
    # points barely moved after the last resampling; with this, Chamfer at the same point count fell from
    # 7.90e-4 to 5.53e-4 (spot 4K), 9.54e-4 to 3.99e-4 (fandisk 4K) and 2.24e-4 to 1.78e-4 (spot 16K), container
    # v2 at the default quantization (1.25e-3 and 5e-3 were worse on spot 16K and fandisk 4K).
    points_settle: float = 2.5e-3

    @classmethod
    def paper(cls) -> LearningRates:
        """The paper's step sizes (Appendix A)."""
        return cls(points=3e-4, s=2e-3, c=3e-3, points_settle=3e-4)


@dataclass(frozen=True)
class FitConfig:
    points: int = 16384
    sh_degree: int = 1
    schedule: Schedule = QUALITY["default"]
    weights: Weights = field(default_factory=Weights)
    lr: LearningRates = field(default_factory=LearningRates)
    init: str = "sdf"  # "sdf" (from the input) or "random" (the paper's ball)
    # "sdf" start: place pinned points around sharp creases when the input has some (fit.features)
    features: bool = True
    # "sdf" start with feature points: the other points next to a crease take plane distances as s
    # (fit.features.polyhedral_distance; rate_control's feature-only fit)
    plane_distances: bool = False
    backend: str = "auto"  # Delaunay backend, see delaunay.resolve_backend
    seed: int = 0
    # None: container v1 (float16 positions, s and c); else container v2 with this quantization.
    quantization: Quantization | None = field(default_factory=Quantization)
    # Taubin steps the decoder applies to the surface (container v2 flags bits 3-4, geometry/smoothing.py); the fit
    # optimizes the smoothed surface.
    smoothing: int = 0
    # Loop subdivision levels the decoder applies after the smoothing (v2 flags bits 5-6,
    # geometry/subdivision.py); the fit optimizes the subdivided surface.
    subdivision: int = 0
    # The decoder's smoothing and subdivision keep the creases of the extracted surface
    # (geometry.smoothing.crease_neighbours, Loop's crease rules; container v2, position-bits byte bit 7); the fit
    # optimizes through the same filter.
    creases: bool = False
    # Whether the main stage fits through the decoder's filter too (else only the late stage does, on the fixed points).
    # Off: the main stage places points and signs, which the unfiltered surface (a quarter of the faces with one Loop
    # level) shows as well; its tree, extraction and backward pass cost a quarter. One thread, bytes x Chamfer against
    # through the filter: spot 0.996, igea 0.988, stanford-bunny 0.955 (--size 10k), stanford-bunny 1.043 (--max-error
    # 1e-3); CPU in docs/measurements/encode_speed.md (2026-12-05), with the levers not kept (half the 3-D term's
    # samples in this stage too: about 0.85x the CPU again, but bytes x Chamfer 1.07x on fandisk and 1.09x on
    # stanford-bunny at --max-error 1e-3). With creases it was off before: the creases of a surface whose points move
    # come and go at every iteration; fandisk, bytes x Chamfer against no smoothing, 5 / 10 / 20 KB: both stages 0.99 /
    # 0.88 / 0.93, the late stage alone 0.88 / 0.89 / 0.92 at less CPU (docs/measurements/creases.md, 2026-12-02).
    main_filter: bool = False

    def stage_filter(self, main: bool) -> tuple[int, int]:
        """(Taubin steps, Loop levels) a stage fits through: the decoder's, except in a main stage without
        `main_filter`."""
        if main and not self.main_filter:
            return 0, 0
        return self.smoothing, self.subdivision


# Taubin steps of `tetweave encode` (container v2; on CAD parts encoder.input_defaults takes
# crease-preserving steps instead, encoder.CREASED_SMOOTHING). Measured with benchmarks/fit_ab.py (at ffee759)
# (docs/measurements/smoothing.md): bytes x Chamfer against no smoothing, 1 step: spot 0.82-0.87, stanford-bunny
# 0.94-0.99, igea 0.96-1.01, fandisk 0.95-1.06 (16 cases, median 0.96); 2 steps helped spot more (0.78) but cost
# igea 11 % and fandisk 5 %.
DEFAULT_SMOOTHING = 1
# Loop levels of `tetweave encode` after the smoothing (none on CAD parts). Measured with
# fit_ab.py at ffee759 (docs/measurements/subdivision.md): bytes x Chamfer against the smoothing alone, one level:
# spot 0.66-0.82, stanford-bunny 0.89-0.95, igea 0.91-0.98 (9 cases, median 0.90) for 1.2-1.8x the CPU time; two
# levels gained 0.4-3 % more for 2-3x the time again.
DEFAULT_SUBDIVISION = 1

# The presets are sized for ITERATION_POINTS points; smaller fits run up to MAX_ITERATION_SCALE times more
# iterations (scale sqrt(ITERATION_POINTS / points)), which costs about the time the smaller fit saves per
# iteration. Measured, rate-controlled (bytes x Chamfer against the preset's 400 iterations, one run each):
# igea 10 KB (4K points) 700 / 1000 iterations 0.885 / 0.858, spot 10 KB 0.877 / 0.899, stanford-bunny 20 KB
# (8.6K points) 700: 0.949, spot 40 KB (18K points) 700: 0.914 -- the fits were not converged, but 1.6x the
# iterations at 18K points would cost 1.6x the encode time where the 40 KB files already take 80-120 s.
ITERATION_POINTS = 16384
MAX_ITERATION_SCALE = 1.75


def scaled_schedule(schedule: Schedule, points: int) -> Schedule:
    """`schedule` with its main and late iterations scaled for a fit of `points` points (see ITERATION_POINTS)."""
    scale = min(MAX_ITERATION_SCALE, max(1.0, math.sqrt(ITERATION_POINTS / max(points, 1))))
    if scale == 1.0:
        return schedule
    return replace(
        schedule,
        main_iters=int(round(schedule.main_iters * scale)),
        late_iters=int(round(schedule.late_iters * scale)),
    )


def schedule_for(quality: str, iters: int | None = None) -> Schedule:
    """The preset `quality`, with the main+late iterations scaled to `iters` in total when given."""
    if quality not in QUALITY:
        raise TetweaveError(f"unknown quality {quality!r}; choose one of {', '.join(QUALITY)}")
    sch = QUALITY[quality]
    if iters is None:
        return sch
    if iters < 2:
        raise TetweaveError(f"--iters must be at least 2, got {iters}")
    main = max(1, int(round(iters * sch.main_iters / (sch.main_iters + sch.late_iters))))
    return replace(sch, main_iters=main, late_iters=max(1, iters - main))
