"""One optimization step, shared by every stage of the fit: parameters, triangulation, extraction, loss, backward.

`FitContext` is what all stages of one fit share (settings, targets, RNG, progress); `Params` holds the optimized
tensors; `Grid` a Delaunay triangulation on their device.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from tetweave_codec.fit import losses
from tetweave_codec.fit.config import FitConfig, LearningRates
from tetweave_codec.fit.optim import Adam
from tetweave_codec.fit.surface_loss import INPUT_SAMPLES, SurfaceTarget
from tetweave_codec.fit.targets import Targets
from tetweave_codec.geometry.delaunay import tetrahedralize
from tetweave_codec.geometry.marching_tets import Topology, marching_tets, marching_tets_topology
from tetweave_codec.geometry.smoothing import crease_edges, edge_faces, mesh_edges
from tetweave_codec.geometry.surface_filter import FilterMap
from tetweave_codec.render import render_maps

ProgressFn = Callable[[str, int, int, dict], None]


def noop_progress(stage: str, done: int, total: int, info: dict) -> None:
    pass


@dataclass
class FitContext:
    """What every stage of one fit shares.

    config: the settings. targets: renders of the input (None when no loss or resampling looks at them).
    surface: the 3-D Chamfer term (None when weighted 0). backend: the Delaunay backend the decoder will use.
    generator: the one RNG of the fit (seeded by config.seed). history: (stage, iteration, loss) samples.
    seconds: wall time per stage. topology: the last marching-tets topology (see `extract`). frame_scale: the fit's
    frame is the normalized frame scaled by it (1 but for the grid layout, fit.grid; the file's transform divides
    it out).
    """

    config: FitConfig
    targets: Targets | None
    surface: SurfaceTarget | None
    backend: str
    device: torch.device
    generator: torch.Generator
    progress: ProgressFn = noop_progress
    history: list[tuple[str, int, float]] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    topology: TopologyCache = field(default_factory=lambda: TopologyCache())
    frame_scale: float = 1.0

    def random_views(self) -> Tensor | None:
        """Indices of this iteration's target views (None when the fit renders nothing)."""
        if self.targets is None:
            return None
        n = self.config.schedule.views_per_iter
        return torch.randperm(len(self.targets), generator=self.generator)[:n].to(self.device)


class Params:
    """The optimized tensors and their optimizers; rebuilt whenever the point set changes."""

    def __init__(
        self,
        points: np.ndarray,
        s: np.ndarray,
        c: np.ndarray,
        device: torch.device,
        lr: LearningRates,
        optimize_points: bool = True,
        pinned: np.ndarray | None = None,
    ):
        # (N,) bool: points whose positions the optimizer leaves alone (feature points, fit.features)
        self.pinned = (
            None if pinned is None or not np.any(pinned) else torch.as_tensor(np.asarray(pinned, bool), device=device)
        )
        self.points = torch.tensor(
            np.asarray(points), dtype=torch.float32, device=device, requires_grad=optimize_points
        )
        self.s = torch.tensor(np.asarray(s), dtype=torch.float32, device=device, requires_grad=True)
        self.c = torch.tensor(np.asarray(c), dtype=torch.float32, device=device, requires_grad=True)
        self.opt_sc = Adam([{"params": [self.s], "lr": lr.s}, {"params": [self.c], "lr": lr.c}])
        self.opt_p = Adam([{"params": [self.points], "lr": lr.points}]) if optimize_points else None

    def numpy(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """points (N,3) float64, s (N,) float32, c (N,q) float32."""
        return (
            self.points.detach().cpu().numpy().astype(np.float64),
            self.s.detach().cpu().numpy(),
            self.c.detach().cpu().numpy(),
        )


class Grid(NamedTuple):
    """A Delaunay triangulation on the points' device: tets (T,4) long, hull (H,3) long outward hull faces."""

    tets: Tensor
    hull: Tensor


def triangulate(points: Tensor | np.ndarray, backend: str, device: torch.device | None = None) -> Grid:
    """Delaunay of points (N,3) with the decoder's backend (float64 on the CPU, as the decoder computes it)."""
    if isinstance(points, Tensor):
        device = points.device if device is None else device
        points = points.detach().cpu().numpy()
    tri = tetrahedralize(np.asarray(points, dtype=np.float64), backend)
    return Grid(torch.from_numpy(tri.tets).to(device), torch.from_numpy(tri.hull_faces).to(device))


def extract(
    points: Tensor,
    s: Tensor,
    c: Tensor,
    grid: Grid,
    cache: TopologyCache | None = None,
    smoothing: int = 0,
    subdivision: int = 0,
    with_base: bool = False,
    creases: bool = False,
):
    """The mesh exactly as the decoder extracts it (hull caps included, `smoothing` Taubin steps, crease-preserving
    with `creases`, then `subdivision` Loop levels), differentiable. The decoder's putting back of crossing faces is
    left out: it touches a handful of vertices, rarely, and has no gradient.

    With a `cache`, the marching-tets topology of the previous call, and the filter built for it, are reused when
    the grid and every sign of s are the same (the result is identical either way). A subdivided mesh's
    face_tets repeat each face's tet for its 4^L faces. with_base: return (mesh, marching tets' own mesh before
    the filter)."""
    if cache is None:
        cache = TopologyCache()
    with torch.no_grad():
        inside = s.detach() < 0
        if cache.tets is not grid.tets or cache.inside is None or not torch.equal(cache.inside, inside):
            cache.tets, cache.inside = grid.tets, inside
            cache.topology = marching_tets_topology(grid.tets, inside, grid.hull)
            cache.filter = cache.edges = None
    mt = marching_tets(points, grid.tets, s, c, hull_faces=grid.hull, topology=cache.topology)
    out = mt
    if (smoothing > 0 or subdivision > 0) and mt.faces.shape[0] > 0:
        f = cache.filter
        sharp = None
        if creases:
            # the decoder finds the creases on the surface it extracts: so does the fit, at every call (the
            # topology may stay while the vertices move), and the map is rebuilt when they change
            faces_np = mt.faces.cpu().numpy()
            if cache.edges is None:
                cache.edges = mesh_edges(faces_np, mt.vertices.shape[0])
                cache.sides = edge_faces(faces_np, cache.edges, mt.vertices.shape[0])
            vertices_np = mt.vertices.detach().cpu().numpy().astype(np.float64)
            sharp = crease_edges(vertices_np, faces_np, cache.edges, cache.sides)
        if (
            f is None
            or (f.smoothing, f.subdivision) != (smoothing, subdivision)
            or (f.sharp is None) != (sharp is None)
            or (sharp is not None and not np.array_equal(f.sharp, sharp))
        ):
            f = cache.filter = FilterMap(mt.faces, mt.vertices.shape[0], smoothing, subdivision, sharp, cache.edges)
        out = mt._replace(vertices=f(mt.vertices))
        if subdivision > 0:
            out = out._replace(faces=f.faces_out, face_tets=mt.face_tets.repeat_interleave(4**subdivision))
    return (out, mt) if with_base else out


@dataclass
class TopologyCache:
    """The last marching-tets topology of a fit, for the tets tensor (T,4) and inside flags (N,) it came from."""

    tets: Tensor | None = None
    inside: Tensor | None = None
    topology: Topology | None = None
    filter: FilterMap | None = None  # the decoder's filter of the topology's faces, built on first use
    edges: np.ndarray | None = None  # the topology's directed edges (E,2), for crease-preserving smoothing
    sides: np.ndarray | None = None  # and the two faces of each (`smoothing.edge_faces`)


def regularized_loss(
    ctx: FitContext,
    points: Tensor,
    s: Tensor,
    c: Tensor,
    grid: Grid,
    views: Tensor | None,
    with_grid_terms: bool,
    odt_factor: float = 1.0,
) -> tuple[Tensor, dict[str, float]]:
    """Total loss of one iteration and its parts (floats, for logging).

    points (N,3), s (N,), c (N,q): the values to extract from (the latent ones, or their quantized stand-ins).
    odt_factor scales the ODT term; 0 skips it. Positions stay fixed between triangulations, so the ODT value
    and gradient are the same on all m iterations of a period: the main stage evaluates it once per period with
    factor m instead of m times (saves ~90 ms per iteration at 16K points).
    """
    weights = ctx.config.weights
    cfg = ctx.config
    smoothing, subdivision = cfg.stage_filter(main=with_grid_terms)
    mt, base = extract(points, s, c, grid, ctx.topology, smoothing, subdivision, True, cfg.creases)
    parts: dict[str, float] = {}
    total = losses.sign_loss(s, mt.edges) * weights.sign
    parts["sign"] = float(total.detach())
    if mt.faces.shape[0] > 0:
        if weights.uses_images():
            cams, target_maps = ctx.targets.select(views)
            maps = render_maps(mt.vertices, mt.faces, cams, ctx.config.schedule.size)
            recon, recon_parts = losses.image_loss(maps, target_maps, weights)
            total = total + recon
            parts.update(recon_parts)
        if ctx.surface is not None and weights.surface > 0:
            # a subdivided mesh is drawn from as densely as its control mesh: 4^L times the samples would cost
            # 4^L times the queries for a surface that is smoother, not more detailed
            surface = ctx.surface.loss(
                mt.vertices,
                mt.faces,
                ctx.generator,
                per_call=cfg.schedule.surface_samples or INPUT_SAMPLES,
                min_samples=base.vertices.shape[0],
            )
            total = total + weights.surface * surface.chamfer + weights.surface_normals * surface.normals
            parts["surface"] = float(surface.chamfer.detach())
            parts["surface_normals"] = float(surface.normals.detach())
        if with_grid_terms:
            # the fairness of marching tets' own triangles (a subdivided mesh's are fair by construction)
            fair_mesh = base if subdivision > 0 else mt
            fair = losses.fairness_loss(fair_mesh.vertices, fair_mesh.faces) * weights.fairness
            total = total + fair
            parts["fairness"] = float(fair.detach())
    if with_grid_terms and odt_factor > 0:
        odt = losses.odt_loss(points, grid.tets) * (weights.odt * odt_factor)
        total = total + odt
        parts["odt"] = float(odt.detach())
    parts["total"] = float(total.detach())
    return total, parts


def backward(loss: Tensor, params: Params) -> None:
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
    if params.pinned is not None and params.points.grad is not None:
        params.points.grad[params.pinned] = 0.0
