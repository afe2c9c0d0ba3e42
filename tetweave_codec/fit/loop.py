"""The fit: gradient descent on points, s and c so that renders of the extracted mesh match the input's renders.

Paper §4 and Appendix A, with the changes that make it affordable on a CPU:

* Initialization from the known input (``initialize.initial_state``): points concentrated near the surface with
  base distances from the input's signed distance (sign from the winding number), instead of random points in a
  ball. The first extracted mesh is already close to the input, so hundreds of iterations do what thousands did.
* Main stage: AdamW on points, s and c; Delaunay recomputed every ``delaunay_every`` iterations, with the position
  gradients summed in between and applied once (so the grid stays valid between triangulations); loss = image terms
  + fairness + ODT + sign; error-driven resampling grows the point count to the target in a few steps.
* Finalize: keep the active points, round them to float16, drop float16 collisions, triangulate once, exactly as the
  decoder will.
* Late stage on that triangulation: positions fixed, only s and c, no fairness/ODT; then s and c are rounded to
  float16. The arrays returned are exactly what the container stores.

Everything random draws from generators seeded by ``seed``: the same input, options and seed give the same arrays on
the same device and thread count.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from tetweave_codec.errors import TetweaveError
from tetweave_codec.fit import losses
from tetweave_codec.fit.initialize import initial_state, random_state
from tetweave_codec.fit.resample import resample, voxel_importance
from tetweave_codec.fit.surface_loss import SurfaceTarget
from tetweave_codec.fit.targets import Targets, render_targets
from tetweave_codec.geometry.active import active_mask, one_ring_mask
from tetweave_codec.geometry.delaunay import resolve_backend, tetrahedralize
from tetweave_codec.geometry.marching_tets import marching_tets
from tetweave_codec.geometry.sh import num_coeffs
from tetweave_codec.render import render_maps

# Points live in the normalized frame ([-0.9, 0.9]^3 holds the input); the grid may extend a little beyond it so
# that outside points surround the surface, but nothing is gained farther out.
POSITION_BOUND = 1.2
# Smallest |s| written to the container: float16 keeps its sign (and marching tets never puts a vertex exactly on a
# grid point, which would give zero-area triangles).
MIN_ABS_S = 2.0**-14
# |c| above this saturates tanh for any direction; clamping keeps c finite in float16.
MAX_ABS_C = 64.0
# Voxel grid of the error-driven resampling (paper Appendix A: 32^3).
IMPORTANCE_RESOLUTION = 32
# Views rendered to estimate the resampling importance.
IMPORTANCE_VIEWS = 8


@dataclass(frozen=True)
class Schedule:
    """How long and how finely to fit. See `QUALITY` for the presets."""

    main_iters: int
    late_iters: int
    views_per_iter: int
    size: int  # render resolution (pixels per side)
    n_views: int  # target views rendered up front
    delaunay_every: int = 5  # paper's m
    resample_at: tuple[float, ...] = (0.15, 0.35, 0.55)  # fractions of the main stage
    start_fraction: float = 0.5  # initial points, as a fraction of the target count


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

    The image terms are the paper's weights scaled by 0.1. With the exact 3-D term present, renders at
    CPU-affordable resolutions mostly add pixel-scale noise: spot at 8K points (120 + 60 iterations) reached
    Chamfer 7.3e-4 with the paper's image weights, 5.1e-4 with a tenth of them and 4.3e-4 without them.
    """

    mask: float = 1.0
    depth: float = 25.0
    normals: float = 0.1
    fairness: float = 0.35
    odt: float = 0.1
    # The paper's 1.0 suppresses spurious surfaces grown from a random start. From the SDF start there are none,
    # and at 1.0 the term (whose gradient pulls |s| up on both ends of every active edge, i.e. vertices towards
    # edge midpoints) made a torus fit worse than its starting point (Chamfer 3.6e-3 -> 5.0e-3).
    sign: float = 0.02
    surface: float = 1000.0  # 3-D Chamfer against the input (surface_loss.py); 0 = the paper's renders only


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


@dataclass(frozen=True)
class FitConfig:
    points: int = 16384
    sh_degree: int = 1
    schedule: Schedule = QUALITY["default"]
    weights: Weights = field(default_factory=Weights)
    lr: LearningRates = field(default_factory=LearningRates)
    init: str = "sdf"  # "sdf" (from the input) or "random" (the paper's ball)
    backend: str = "auto"  # Delaunay backend, see delaunay.resolve_backend
    seed: int = 0


@dataclass
class FitResult:
    """The container's arrays and what it took to get them.

    points (N,3) float16, s (N,) float16, c (N,q) float16: exactly what is stored.
    stage_seconds: wall time per stage. history: (stage, iteration, loss) samples.
    """

    points: np.ndarray
    s: np.ndarray
    c: np.ndarray
    sh_degree: int
    backend: str  # Delaunay backend of the final triangulation; the decoder must use the same
    stage_seconds: dict[str, float]
    history: list[tuple[str, int, float]]


ProgressFn = Callable[[str, int, int, dict], None]


def _noop_progress(stage: str, done: int, total: int, info: dict) -> None:
    pass


class _Params:
    """The optimized tensors and their optimizers; rebuilt whenever the point set changes."""

    def __init__(
        self,
        points: np.ndarray,
        s: np.ndarray,
        c: np.ndarray,
        device: torch.device,
        lr: LearningRates,
        optimize_points: bool = True,
    ):
        self.points = torch.tensor(
            np.asarray(points), dtype=torch.float32, device=device, requires_grad=optimize_points
        )
        self.s = torch.tensor(np.asarray(s), dtype=torch.float32, device=device, requires_grad=True)
        self.c = torch.tensor(np.asarray(c), dtype=torch.float32, device=device, requires_grad=True)
        self.opt_sc = torch.optim.AdamW(
            [{"params": [self.s], "lr": lr.s}, {"params": [self.c], "lr": lr.c}], weight_decay=0.0
        )
        self.opt_p = torch.optim.AdamW([self.points], lr=lr.points, weight_decay=0.0) if optimize_points else None

    def numpy(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return (
            self.points.detach().cpu().numpy().astype(np.float64),
            self.s.detach().cpu().numpy(),
            self.c.detach().cpu().numpy(),
        )


class _Grid(NamedTuple):
    """A Delaunay triangulation on the points' device: tets (T,4) long, hull (H,3) long outward hull faces."""

    tets: Tensor
    hull: Tensor


def _triangulate(points: Tensor, backend: str) -> _Grid:
    """Delaunay of the current points with the decoder's backend."""
    tri = tetrahedralize(points.detach().cpu().numpy().astype(np.float64), backend)
    return _Grid(torch.from_numpy(tri.tets).to(points.device), torch.from_numpy(tri.hull_faces).to(points.device))


def _extract(params: _Params, grid: _Grid):
    """The mesh exactly as the decoder extracts it (hull caps included), differentiable."""
    return marching_tets(params.points, grid.tets, params.s, params.c, hull_faces=grid.hull)


def _regularized_loss(
    params: _Params,
    grid: _Grid,
    targets: Targets,
    views: Tensor,
    schedule: Schedule,
    weights: Weights,
    with_grid_terms: bool,
    surface: SurfaceTarget | None,
    generator: torch.Generator,
    odt_factor: float = 1.0,
) -> tuple[Tensor, dict[str, float]]:
    """Total loss of one iteration and its parts (floats, for logging).

    odt_factor scales the ODT term; 0 skips it. Positions stay fixed between triangulations, so the ODT value
    and gradient are the same on all m iterations of a period: the main stage evaluates it once per period with
    factor m instead of m times (saves ~90 ms per iteration at 16K points).
    """
    mt = _extract(params, grid)
    parts: dict[str, float] = {}
    total = losses.sign_loss(params.s, mt.edges) * weights.sign
    parts["sign"] = float(total.detach())
    if mt.faces.shape[0] > 0:
        cams, target_maps = targets.select(views)
        maps = render_maps(mt.vertices, mt.faces, cams, schedule.size)
        recon, recon_parts = _image_loss(maps, target_maps, weights)
        total = total + recon
        parts.update(recon_parts)
        if surface is not None and weights.surface > 0:
            chamfer = surface.loss(mt.vertices, mt.faces, generator)
            total = total + weights.surface * chamfer
            parts["surface"] = float(chamfer.detach())
        if with_grid_terms:
            fair = losses.fairness_loss(mt.vertices, mt.faces) * weights.fairness
            total = total + fair
            parts["fairness"] = float(fair.detach())
    if with_grid_terms and odt_factor > 0:
        odt = losses.odt_loss(params.points, grid.tets) * (weights.odt * odt_factor)
        total = total + odt
        parts["odt"] = float(odt.detach())
    parts["total"] = float(total.detach())
    return total, parts


def _image_loss(maps, target_maps, weights: Weights) -> tuple[Tensor, dict[str, float]]:
    """Paper's L_recons, with depth and normals compared only where both the target and the render see a surface.

    The paper masks depth and normals by the target's mask alone; then a target pixel that the current mesh misses
    compares the target's depth with the background's 0, an error of ~3 units that outweighs every interior pixel
    and mostly pushes silhouettes around, which the (antialiased) mask term already does. Depth is compared with
    |.| as in the paper's reference code (for which lambda_D = 250 was tuned), normals with |.|^2.
    """
    both = target_maps.mask * (maps.fragments.face_id >= 0).to(target_maps.mask.dtype)
    mask = losses.mask_loss(maps.mask, target_maps.mask) * weights.mask
    depth = losses.depth_loss(maps.depth, target_maps.depth, both, norm="l2") * weights.depth
    normals = losses.normal_loss(maps.normals, target_maps.normals, both) * weights.normals
    total = mask + depth + normals
    return total, {"mask": float(mask.detach()), "depth": float(depth.detach()), "normals": float(normals.detach())}


def _importance(
    params: _Params, grid: _Grid, targets: Targets, schedule: Schedule, generator: torch.Generator
) -> tuple[Tensor, Tensor, Tensor] | None:
    """Voxel importance from the normal-map error of the current mesh (paper eq. importance).

    Returns (grid (R,R,R), bbox_min (3,), bbox_max (3,)) or None when the current mesh is empty.
    """
    with torch.no_grad():
        mt = _extract(params, grid)
        if mt.faces.shape[0] == 0:
            return None
        n = min(IMPORTANCE_VIEWS, len(targets))
        views = torch.randperm(len(targets), generator=generator)[:n].to(params.points.device)
        cams, target_maps = targets.select(views)
        maps = render_maps(mt.vertices, mt.faces, cams, schedule.size)
        on_mesh = maps.fragments.face_id >= 0
        error = (maps.normals - target_maps.normals).abs().sum(-1)  # (B,H,W) L1 normal error
        world = cams.backproject(maps.depth)  # (B,H,W,3) surface points
        lo = mt.vertices.min(0).values
        hi = mt.vertices.max(0).values
        pad = 0.02 * (hi - lo).max().clamp_min(1e-3)
        lo, hi = lo - pad, hi + pad
        grid = voxel_importance(world[on_mesh], error[on_mesh], lo, hi, resolution=IMPORTANCE_RESOLUTION)
        return grid, lo, hi


def _resample(
    params: _Params,
    grid: _Grid,
    targets: Targets,
    n_target: int,
    schedule: Schedule,
    generator: torch.Generator,
    lr: LearningRates,
) -> _Params:
    """Relocate passive points and grow the set to `n_target` by error-driven sampling (paper §4.3-4.4)."""
    with torch.no_grad():
        imp = _importance(params, grid, targets, schedule, generator)
        if imp is None:
            return params
        importance, lo, hi = imp
        keep = one_ring_mask(grid.tets, active_mask(grid.tets, params.s))
        n_target = max(n_target, int(keep.sum()))
        points, s, c = resample(
            params.points, params.s, params.c, grid.tets, keep, importance, (lo, hi), n_target, generator
        )
        points = points.clamp(-POSITION_BOUND, POSITION_BOUND)
    return _Params(points.cpu().numpy(), s.cpu().numpy(), c.cpu().numpy(), params.points.device, lr)


def _backward(loss: Tensor, params: _Params) -> None:
    """Backpropagate, dropping non-finite gradient entries.

    A vertex on an edge whose two directional distances are both within float32 rounding of zero has an unbounded
    derivative; one such edge must not poison every parameter through Adam's moments, so its gradient is zeroed
    (the next triangulation or step moves it away from the degenerate spot).
    """
    if not bool(torch.isfinite(loss)):
        return
    loss.backward()
    for t in (params.points, params.s, params.c):
        if t.grad is not None:
            torch.nan_to_num_(t.grad, nan=0.0, posinf=0.0, neginf=0.0)


def _main_stage(
    params: _Params,
    targets: Targets,
    surface: SurfaceTarget | None,
    config: FitConfig,
    backend: str,
    generator: torch.Generator,
    progress: ProgressFn,
    history: list,
) -> _Params:
    sch = config.schedule
    n_events = len(sch.resample_at)
    # Resampling happens right before a re-triangulation, so round each event to a multiple of m.
    events = {}
    n_start = len(params.s)
    for k, frac in enumerate(sch.resample_at):
        it = int(round(frac * sch.main_iters / sch.delaunay_every)) * sch.delaunay_every
        if 0 < it < sch.main_iters:
            events[it] = n_start + math.ceil((config.points - n_start) * (k + 1) / n_events)
    grid = None
    for it in range(sch.main_iters):
        if it % sch.delaunay_every == 0 or grid is None:
            grid = _triangulate(params.points, backend)
            if it in events:
                params = _resample(params, grid, targets, events[it], sch, generator, config.lr)
                grid = _triangulate(params.points, backend)
        views = torch.randperm(len(targets), generator=generator)[: sch.views_per_iter].to(params.points.device)
        period_end = (it + 1) % sch.delaunay_every == 0 or it + 1 == sch.main_iters
        loss, parts = _regularized_loss(
            params,
            grid,
            targets,
            views,
            sch,
            config.weights,
            with_grid_terms=True,
            surface=surface,
            generator=generator,
            odt_factor=float(sch.delaunay_every) if period_end else 0.0,
        )
        _backward(loss, params)
        params.opt_sc.step()
        params.opt_sc.zero_grad(set_to_none=True)
        if period_end:
            # Gradients of the positions were summed over the last m iterations (paper §4.5).
            params.opt_p.step()
            params.opt_p.zero_grad(set_to_none=True)
            with torch.no_grad():
                params.points.clamp_(-POSITION_BOUND, POSITION_BOUND)
        history.append(("main", it, parts["total"]))
        progress("main", it + 1, sch.main_iters, {"loss": parts["total"], "points": len(params.s)})
    return params


def _finalize_points(params: _Params, backend: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keep the active points, round them to float16 and drop float16 collisions (first occurrence wins).

    Returns points16 (N,3) float16, s (N,) float32, c (N,q) float32.
    """
    grid = _triangulate(params.points, backend)
    with torch.no_grad():
        keep = active_mask(grid.tets, params.s).cpu().numpy()
    points, s, c = params.numpy()
    points16 = points[keep].astype(np.float16)
    _, first = np.unique(points16.view(np.uint16).reshape(-1, 3), axis=0, return_index=True)
    order = np.sort(first)
    return points16[order], s[keep][order], c[keep][order]


def _late_stage(
    points16: np.ndarray,
    s: np.ndarray,
    c: np.ndarray,
    targets: Targets,
    surface: SurfaceTarget | None,
    config: FitConfig,
    backend: str,
    device: torch.device,
    generator: torch.Generator,
    progress: ProgressFn,
    history: list,
) -> tuple[np.ndarray, np.ndarray]:
    """Optimize s and c on the final (float16) points and their one triangulation; returns float32 s, c."""
    sch = config.schedule
    params = _Params(points16.astype(np.float32), s, c, device, config.lr, optimize_points=False)
    grid = _triangulate(params.points, backend)
    for it in range(sch.late_iters):
        views = torch.randperm(len(targets), generator=generator)[: sch.views_per_iter].to(device)
        loss, parts = _regularized_loss(
            params,
            grid,
            targets,
            views,
            sch,
            config.weights,
            with_grid_terms=False,
            surface=surface,
            generator=generator,
        )
        _backward(loss, params)
        params.opt_sc.step()
        params.opt_sc.zero_grad(set_to_none=True)
        history.append(("late", it, parts["total"]))
        progress("late", it + 1, sch.late_iters, {"loss": parts["total"], "points": len(s)})
    _, s_out, c_out = params.numpy()
    return s_out, c_out


def _round_sc(s: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """float16 s and c, with |s| kept above MIN_ABS_S so that no sign is lost to rounding."""
    sign = np.where(s < 0, -1.0, 1.0)
    s16 = (sign * np.maximum(np.abs(s), MIN_ABS_S)).astype(np.float16)
    c16 = np.clip(c, -MAX_ABS_C, MAX_ABS_C).astype(np.float16)
    return s16, c16


def fit(
    vertices: np.ndarray,
    faces: np.ndarray,
    config: FitConfig,
    device: torch.device | str = "cpu",
    progress: ProgressFn | None = None,
) -> FitResult:
    """Fit a TetWeave representation to a mesh in the normalized frame.

    vertices (V,3) float64 in [-0.9, 0.9]^3, faces (F,3) int64. Returns the float16 arrays to store.
    Raises TetweaveError if the fit ends with no surface at all.
    """
    # CPU index backward (index_put_ with accumulate) sums duplicates in a thread-dependent order when large: the
    # surface term's gradients differed in the last bits between runs with 2 threads. Deterministic kernels make
    # "same input, options and seed -> same bytes" hold; the previous setting is restored afterwards.
    was_deterministic = torch.are_deterministic_algorithms_enabled()
    was_warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        return _fit(vertices, faces, config, torch.device(device), progress or _noop_progress)
    finally:
        torch.use_deterministic_algorithms(was_deterministic, warn_only=was_warn_only)


def _fit(
    vertices: np.ndarray, faces: np.ndarray, config: FitConfig, device: torch.device, progress: ProgressFn
) -> FitResult:
    sch = config.schedule
    if config.sh_degree not in (0, 1, 2, 3):
        raise TetweaveError(f"SH degree must be 0..3, got {config.sh_degree}")
    times: dict[str, float] = {}
    history: list[tuple[str, int, float]] = []
    generator = torch.Generator().manual_seed(config.seed)
    backend = resolve_backend(config.backend)

    t0 = time.perf_counter()
    progress("targets", 0, 1, {})
    targets = render_targets(vertices, faces, sch.n_views, sch.size, device=device)
    surface = SurfaceTarget(vertices, faces, seed=config.seed) if config.weights.surface > 0 else None
    times["targets"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    n_start = max(64, min(config.points, int(round(config.points * sch.start_fraction))))
    if config.init == "sdf":
        points, s, c = initial_state(vertices, faces, n_start, config.sh_degree, config.seed)
    elif config.init == "random":
        points, s, c = random_state(n_start, config.sh_degree, config.seed)
    else:
        raise TetweaveError(f"unknown initialization {config.init!r}")
    assert c.shape[1] == num_coeffs(config.sh_degree)
    params = _Params(points, s, c, device, config.lr)
    times["init"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    params = _main_stage(params, targets, surface, config, backend, generator, progress, history)
    times["main"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    points16, s, c = _finalize_points(params, backend)
    if len(points16) < 4:
        raise TetweaveError("the fit produced no surface (is the input a closed or nearly closed shape?)")
    times["finalize"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    s, c = _late_stage(points16, s, c, targets, surface, config, backend, device, generator, progress, history)
    times["late"] = time.perf_counter() - t0
    s16, c16 = _round_sc(s, c)
    return FitResult(points16, s16, c16, config.sh_degree, backend, times, history)


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
