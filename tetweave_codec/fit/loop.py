"""The fit: gradient descent on points, s and c so that the extracted mesh matches the input.

Paper §4 and Appendix A, with the changes that make it affordable on a CPU:

* Initialization from the known input (``initialize.initial_state``): points concentrated near the surface with
  base distances from the input's signed distance (sign from the winding number), instead of random points in a
  ball. The first extracted mesh is already close to the input, so hundreds of iterations do what thousands did.
* Main stage (here): AdamW on points, s and c; Delaunay recomputed every ``delaunay_every`` iterations, with the
  position gradients summed in between and applied once (so the grid stays valid between triangulations); loss =
  3-D surface term + fairness + ODT + sign (+ the paper's image terms when weighted, off by default: see
  config.Weights); error-driven resampling grows the point count to the target in a few steps.
* Finish (``finish.py``): the points are fixed to what the container can store and triangulated once, exactly as
  the decoder will; a late stage optimizes only s and c on that triangulation (with the container's quantization in
  the loop for v2); the arrays returned are exactly what the container stores.

Everything random draws from one generator seeded by ``seed``: the same input, options and seed give the same
arrays on the same device and thread count.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from tetweave_codec.errors import TetweaveError
from tetweave_codec.fit.config import FitConfig
from tetweave_codec.fit.finish import FinishResult, finish
from tetweave_codec.fit.initialize import (
    MIN_ABS_S,
    N_CORNERS,
    SHELL,
    SHELL_GAP,
    UNIFORM_FRACTION,
    initial_state_pinned,
    random_state,
    signed_distance,
)
from tetweave_codec.fit.optim import set_deterministic
from tetweave_codec.fit.prepared import PreparedInput
from tetweave_codec.fit.relocate import cheapest_points
from tetweave_codec.fit.resample import NearSurface, resample, voxel_importance
from tetweave_codec.fit.step import (
    FitContext,
    Grid,
    Params,
    ProgressFn,
    backward,
    extract,
    noop_progress,
    regularized_loss,
    triangulate,
)
from tetweave_codec.fit.surface_loss import SurfaceTarget
from tetweave_codec.fit.targets import render_targets
from tetweave_codec.formats.quantize import GRID_BOUND
from tetweave_codec.geometry.active import active_mask, one_ring_mask
from tetweave_codec.geometry.closest import SurfaceTree
from tetweave_codec.geometry.delaunay import available_backends, resolve_backend
from tetweave_codec.geometry.sh import check_degree, num_coeffs
from tetweave_codec.geometry.triangles import sample_surface
from tetweave_codec.render import render_maps

# Voxel grid of the error-driven resampling (paper Appendix A: 32^3).
IMPORTANCE_RESOLUTION = 32
# Views rendered to estimate the resampling importance.
IMPORTANCE_VIEWS = 8
# Samples per direction of the 3-D importance (`_distance_errors`).
IMPORTANCE_SAMPLES = 100_000


@dataclass
class FitResult:
    """What the container stores and what it took to get there.

    finish: the stored arrays (float16 for v1, integer symbols for v2), see finish.FinishResult.
    backend: Delaunay backend of the final triangulation; the decoder must use the same.
    stage_seconds: wall time per stage. history: (stage, iteration, loss) samples.
    smoothing: Taubin steps of the decoder, subdivision: its Loop levels (both stored in version-2 flags);
    creases: the smoothing keeps the extracted surface's creases (version 2, bit 7 of the position-bits byte).
    """

    finish: FinishResult
    sh_degree: int
    backend: str
    stage_seconds: dict[str, float]
    history: list[tuple[str, int, float]]
    smoothing: int = 0
    subdivision: int = 0
    creases: bool = False


def _importance(params: Params, grid: Grid, ctx: FitContext) -> tuple[Tensor, Tensor, Tensor] | None:
    """Voxel importance: the current mesh's distance to the input where the 3-D term is on (`_distance_errors`),
    else the normal-map error of renders (paper eq. importance).

    Returns (grid (R,R,R), bbox_min (3,), bbox_max (3,)) or None when the current mesh is empty.
    """
    with torch.no_grad():
        smoothing, subdivision = ctx.config.stage_filter(main=True)
        mt = extract(
            params.points, params.s, params.c, grid, smoothing=smoothing, subdivision=subdivision,
            creases=ctx.config.creases,
        )  # fmt: skip
        if mt.faces.shape[0] == 0:
            return None
        if ctx.surface is not None:
            world, error = _distance_errors(mt.vertices, mt.faces, ctx)
        else:
            n = min(IMPORTANCE_VIEWS, len(ctx.targets))
            views = torch.randperm(len(ctx.targets), generator=ctx.generator)[:n].to(ctx.device)
            cams, target_maps = ctx.targets.select(views)
            maps = render_maps(mt.vertices, mt.faces, cams, ctx.config.schedule.size)
            on_mesh = maps.fragments.face_id >= 0
            error = (maps.normals - target_maps.normals).abs().sum(-1)[on_mesh]  # L1 normal error per pixel
            world = cams.backproject(maps.depth)[on_mesh]  # the pixels' surface points
        lo, hi = _padded_box(mt.vertices)
        importance = voxel_importance(world, error, lo, hi, resolution=IMPORTANCE_RESOLUTION)
        return importance, lo, hi


def _padded_box(vertices: Tensor) -> tuple[Tensor, Tensor]:
    """The importance grid's box: the bounding box of vertices (V,3) grown by 2 % of its largest side."""
    lo = vertices.min(0).values
    hi = vertices.max(0).values
    pad = 0.02 * (hi - lo).max().clamp_min(1e-3)
    return lo - pad, hi + pad


def _distance_errors(vertices: Tensor, faces: Tensor, ctx: FitContext) -> tuple[Tensor, Tensor]:
    """Sample points (P,3) and their point-to-surface distances (P,), both directions: area samples of the mesh
    (vertices (V,3), faces (F,3)) to the input, and input samples to the mesh; tensors like `vertices`.

    The metric's own error, where renders at 160 px see normals only at pixel scale. Measured alone it is within
    the fit's seed-to-seed spread (it decides where the few passive points go); with relocation it decides where
    a sixth of the points go (docs/measurements/relocation.md).
    """
    v = vertices.detach().cpu().numpy().astype(np.float64)
    f = faces.detach().cpu().numpy().astype(np.int64)
    seed = int(torch.randint(0, 2**31 - 1, (1,), generator=ctx.generator))
    on_mesh, _ = sample_surface(v, f, IMPORTANCE_SAMPLES, seed)
    cp, _ = ctx.surface.closest_points(on_mesh)
    q = ctx.surface.samples[:: max(1, len(ctx.surface.samples) // IMPORTANCE_SAMPLES)]
    d_q, _, _ = SurfaceTree(v, f).query(q)
    world = np.concatenate([on_mesh, q])
    error = np.concatenate([np.linalg.norm(on_mesh - cp, axis=1), np.sqrt(np.maximum(d_q, 0.0))])
    return torch.from_numpy(world).to(vertices), torch.from_numpy(error).to(vertices)


def _resample(params: Params, grid: Grid, n_target: int, ctx: FitContext) -> Params:
    """Relocate the passive points and the active ones cheapest to remove (`Schedule.relocate`, fit.relocate) and
    grow the set to `n_target` by error-driven sampling (paper §4.3-4.4)."""
    with torch.no_grad():
        imp = _importance(params, grid, ctx)
        if imp is None:
            return params
        importance, lo, hi = imp
        keep = one_ring_mask(grid.tets, active_mask(grid.tets, params.s))
        relocate = ctx.config.schedule.relocate
        if relocate > 0:
            movable = keep.cpu().numpy().copy()
            movable[:N_CORNERS] = False
            if params.pinned is not None:
                movable &= ~params.pinned.cpu().numpy()
            points_np, s_np = params.points.detach().cpu().numpy(), params.s.detach().cpu().numpy()
            moved = cheapest_points(points_np, s_np, grid.tets.cpu().numpy(), movable, int(relocate * n_target))
            keep = keep & ~torch.from_numpy(moved).to(keep.device)
        pinned = None
        if params.pinned is not None:
            # feature points stay where they were placed (fit.features); kept points come first, in order
            keep = keep | params.pinned.to(keep.device)
            pinned = params.pinned.cpu().numpy()[keep.cpu().numpy()]
        n_target = max(n_target, int(keep.sum()))
        near = None
        if ctx.surface is not None:  # in a shell around the input, as the initial points
            n_surface = max(1.0, (1.0 - UNIFORM_FRACTION) * n_target)
            near = NearSurface(
                ctx.surface.samples,
                ctx.surface.sample_normals,
                SHELL * math.sqrt(ctx.surface.area / n_surface),
                SHELL_GAP,
                ctx.surface.tree,
                ctx.surface.face_normals,
            )
        points, s, c = resample(
            params.points, params.s, params.c, grid.tets, keep, importance, (lo, hi), n_target, ctx.generator, near
        )
        points = points.clamp(-GRID_BOUND, GRID_BOUND)
        n_new = len(points) - min(int(keep.sum()), n_target)
        if near is not None and n_new > 0:
            # A point next to the surface takes the input's signed distance, as at the start: s interpolated in the
            # old tets is wrong by up to the old tets' error there and can put it on the wrong side.
            new = points[-n_new:].cpu().numpy().astype(np.float64)
            sdf = signed_distance(new, ctx.surface.vertices, ctx.surface.faces, ctx.surface.tree)
            sdf[sdf == 0] = MIN_ABS_S
            s = torch.cat([s[:-n_new], torch.from_numpy(sdf).to(s)])
        if pinned is not None:
            pinned = np.concatenate([pinned, np.zeros(len(points) - len(pinned), dtype=bool)])
    return Params(points.cpu().numpy(), s.cpu().numpy(), c.cpu().numpy(), ctx.device, ctx.config.lr, pinned=pinned)


def _resample_events(sch, n_start: int, n_target: int) -> dict[int, int]:
    """Iteration -> point count after resampling; events sit right before a re-triangulation (multiples of m)."""
    events = {}
    for k, frac in enumerate(sch.resample_at):
        it = int(round(frac * sch.main_iters / sch.delaunay_every)) * sch.delaunay_every
        if 0 < it < sch.main_iters:
            events[it] = n_start + math.ceil((n_target - n_start) * (k + 1) / len(sch.resample_at))
    return events


def main_stage(params: Params, ctx: FitContext) -> Params:
    """Optimize points, s and c; returns the final parameters (positions still free floats)."""
    sch = ctx.config.schedule
    events = _resample_events(sch, len(params.s), ctx.config.points)
    settle_from = int(round(sch.settle_at * sch.main_iters / sch.delaunay_every)) * sch.delaunay_every
    grid = None
    for it in range(sch.main_iters):
        if it % sch.delaunay_every == 0 or grid is None:
            grid = triangulate(params.points, ctx.backend)
            if it in events:
                params = _resample(params, grid, events[it], ctx)
                grid = triangulate(params.points, ctx.backend)
            if it >= settle_from:
                for group in params.opt_p.param_groups:
                    group["lr"] = ctx.config.lr.points_settle
        views = ctx.random_views()
        period_end = (it + 1) % sch.delaunay_every == 0 or it + 1 == sch.main_iters
        loss, parts = regularized_loss(
            ctx,
            params.points,
            params.s,
            params.c,
            grid,
            views,
            with_grid_terms=True,
            odt_factor=float(sch.delaunay_every) if period_end else 0.0,
        )
        backward(loss, params)
        params.opt_sc.step()
        params.opt_sc.zero_grad(set_to_none=True)
        if period_end:
            # Gradients of the positions were summed over the last m iterations (paper §4.5).
            params.opt_p.step()
            params.opt_p.zero_grad(set_to_none=True)
            with torch.no_grad():
                params.points.clamp_(-GRID_BOUND, GRID_BOUND)
        ctx.history.append(("main", it, parts["total"]))
        ctx.progress("main", it + 1, sch.main_iters, {"loss": parts["total"], "points": len(params.s)})
    return params


def fit(
    vertices: np.ndarray,
    faces: np.ndarray,
    config: FitConfig,
    device: torch.device | str = "cpu",
    progress: ProgressFn | None = None,
) -> FitResult:
    """Fit a TetWeave representation to a mesh in the normalized frame.

    vertices (V,3) float64 in [-0.9, 0.9]^3, faces (F,3) int64. Returns the arrays to store (config.quantization
    None: float16 for container v1; else integer symbols for container v2).
    Raises TetweaveError if the fit ends with no surface at all.
    """
    ctx, params = fit_main(vertices, faces, config, device, progress)
    with deterministic_torch():
        result = finish(params, ctx)
    return FitResult(
        result, config.sh_degree, ctx.backend, ctx.seconds, ctx.history, config.smoothing, config.subdivision,
        config.creases,
    )  # fmt: skip


def fit_main(
    vertices: np.ndarray,
    faces: np.ndarray,
    config: FitConfig,
    device: torch.device | str = "cpu",
    progress: ProgressFn | None = None,
    prepared: PreparedInput | None = None,
) -> tuple[FitContext, Params]:
    """prepare -> start -> main stage: the part of a fit every encode path shares (`fit`, the encoder's Job,
    rate control, benchmarks/bitstream.py); each then finishes it its own way (fit.finish). Returns the context
    (targets, timings) and the parameters after the main stage. prepared: the input prepared once per encode
    (fit.prepared; its `normalized` and `faces` are `vertices` and `faces`), whose tree, creases and surface
    samples the fit then reuses instead of computing them again."""
    with deterministic_torch():
        ctx = prepare(vertices, faces, config, torch.device(device), progress or noop_progress, prepared)
        params = start(vertices, faces, ctx, prepared)
        t0 = time.perf_counter()
        params = main_stage(params, ctx)
        ctx.seconds["main"] = time.perf_counter() - t0
    return ctx, params


class deterministic_torch:
    """Context manager: deterministic torch kernels inside, the previous setting restored afterwards.

    CPU index backward (index_put_ with accumulate) sums duplicates in a thread-dependent order when large: the
    surface term's gradients differed in the last bits between runs with 2 threads. Deterministic kernels make
    "same input, options and seed -> same bytes" hold.
    """

    def __enter__(self):
        self._was = (
            torch.are_deterministic_algorithms_enabled(),
            torch.is_deterministic_algorithms_warn_only_enabled(),
        )
        set_deterministic(True, warn_only=True)
        return self

    def __exit__(self, *exc):
        set_deterministic(self._was[0], warn_only=self._was[1])
        return False


def prepare(
    vertices: np.ndarray,
    faces: np.ndarray,
    config: FitConfig,
    device: torch.device,
    progress: ProgressFn,
    prepared: PreparedInput | None = None,
) -> FitContext:
    """Validate the settings and set up the 3-D term (and the renders, when a loss looks at them): the context
    every stage shares. prepared: see `fit_main` (its surface samples and tree are reused)."""
    try:
        check_degree(config.sh_degree)
    except ValueError as exc:
        raise TetweaveError(str(exc)) from None
    t0 = time.perf_counter()
    progress("targets", 0, 1, {})
    surface = None
    if config.weights.surface > 0:
        if prepared is not None:
            surface = prepared.surface_target(config.seed)
        else:
            surface = SurfaceTarget(vertices, faces, seed=config.seed)
    targets = None
    if surface is None or config.weights.uses_images():  # else nothing looks at renders of the input
        targets = render_targets(vertices, faces, config.schedule.n_views, config.schedule.size, device=device)
    ctx = FitContext(
        config=config,
        targets=targets,
        surface=surface,
        backend=_fit_backend(config),
        device=device,
        generator=torch.Generator().manual_seed(config.seed),
        progress=progress,
    )
    ctx.seconds["targets"] = time.perf_counter() - t0
    return ctx


def _fit_backend(config: FitConfig) -> str:
    """The Delaunay backend of a fit: the decoder's ("auto": the exact Delaunay); container version 1 records only
    TetGen or Qhull, so "auto" there is the first of those installed."""
    if config.quantization is None and config.backend == "auto":
        return next(b for b in available_backends() if b != "exact")
    return resolve_backend(config.backend)


def start(vertices: np.ndarray, faces: np.ndarray, ctx: FitContext, prepared: PreparedInput | None = None) -> Params:
    """The initial points, s and c (SDF start near the input, or the paper's random ball). prepared: see
    `fit_main` (its creases and tree are reused)."""
    config = ctx.config
    t0 = time.perf_counter()
    n_start = max(64, min(config.points, int(round(config.points * config.schedule.start_fraction))))
    pinned = None
    if config.init == "sdf":
        quant = config.quantization
        points, s, c, pinned = initial_state_pinned(
            vertices,
            faces,
            n_start,
            config.sh_degree,
            config.seed,
            features=config.features,
            position_bits=None if quant is None else quant.position_bits,
            grid_scale=1.0 if quant is None else quant.grid_scale,
            plane_distances=config.plane_distances,
            detected=None if prepared is None or not config.features else prepared.features,
            tree=None if prepared is None else prepared.tree,
        )
    elif config.init == "random":
        points, s, c = random_state(n_start, config.sh_degree, config.seed)
    else:
        raise TetweaveError(f"unknown initialization {config.init!r}")
    assert c.shape[1] == num_coeffs(config.sh_degree)
    ctx.seconds["init"] = time.perf_counter() - t0
    return Params(points, s, c, ctx.device, config.lr, pinned=pinned)
