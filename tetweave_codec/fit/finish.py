"""The fit's finish: fix the points to what the container stores, triangulate once as the decoder will, then
optimize only s and c on that triangulation, and hand back exactly the values the container writes.

* Container v2 (``config.quantization`` set): active points are snapped to the position grid of
  ``formats.quantize`` (colliding points merged, first occurrence wins) and put in the canonical (octree) order;
  the late stage optimizes latent s and c through the container's quantizers with straight-through rounding (the
  forward pass sees the dequantized values, the gradient passes to the latent ones), so the optimized mesh is the
  decoded one; finally s and c are quantized to integer symbols.
* Container v1 (``config.quantization`` None): active points rounded to float16 (float16 collisions dropped),
  plain late stage, then s and c rounded to float16 with |s| >= 2^-14 so that no sign is lost.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from tetweave_codec.fit.initialize import MIN_ABS_S
from tetweave_codec.fit.step import FitContext, Params, backward, regularized_loss, triangulate
from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.quantize import Quantization
from tetweave_codec.geometry.active import active_mask

# Smallest |s| a v1 file stores: float16 keeps its sign (and marching tets never puts a vertex exactly on a grid
# point, which would give zero-area triangles). The smallest normal float16, initialize.MIN_ABS_S.
V1_MIN_ABS_S = MIN_ABS_S
# Rounds of `_drop_flat_tets` (each triangulates once); on the shared meshes one round removed every flat tet.
MAX_FLAT_TET_ROUNDS = 8
# |s| floor of a late stage that keeps the signs (float32, far below any s step).
SIGN_FLOOR = 1e-7
# |c| above this saturates tanh for any direction; clamping keeps c finite in float16.
V1_MAX_ABS_C = 64.0


@dataclass
class FinishResult:
    """The values a container stores, and the decoded values they stand for.

    version 1: points (N,3), s (N,), c (N,q) are float16 arrays; cells, s_sym, c_sym are None.
    version 2: cells (N,3) int64 in canonical order, s_sym (N,) int64, c_sym (N,q) int64 and `quantization`;
    points (N,3), s (N,), c (N,q) are their dequantized float64 values.
    latent_s (N,), latent_c (N,q): the late stage's float32 values before quantization (so that other steps can
    be tried without another late stage, see `requantize`).
    """

    version: int
    points: np.ndarray
    s: np.ndarray
    c: np.ndarray
    quantization: Quantization | None = None
    cells: np.ndarray | None = None
    s_sym: np.ndarray | None = None
    c_sym: np.ndarray | None = None
    latent_s: np.ndarray | None = None
    latent_c: np.ndarray | None = None


@dataclass
class Finalized:
    """The point set fixed to what the container stores, in storage order, before the late stage.

    points (N,3) float64: the decoded positions in the fit's frame (the positions the decoder triangulates,
    divided by grid_scale). s (N,), c (N,q): latent values. stored (N,3) float16 (v1) or cells (N,3) int64 in
    canonical order (v2) on the 2^position_bits grid of the frame x grid_scale (`formats.quantize.Quantization`).
    keep_signs: the signs of s are the input's inside / outside (the grid layout's band, fit.grid), which the late
    stage keeps.
    """

    points: np.ndarray
    s: np.ndarray
    c: np.ndarray
    stored: np.ndarray | None = None
    cells: np.ndarray | None = None
    position_bits: int | None = None
    keep_signs: bool = False
    grid_scale: float = 1.0

    def stored_points(self) -> np.ndarray:
        """(N,3) float64: exactly the positions the decoder triangulates (the grid's cell centres for v2)."""
        if self.cells is None or self.grid_scale == 1.0:
            return self.points
        return Q.dequantize_positions(self.cells, self.position_bits)


def finish(params: Params, ctx: FitContext) -> FinishResult:
    """Finalize the point set for the container and run the late stage. Raises TetweaveError with no surface."""
    quant = ctx.config.quantization
    if quant is None:
        return complete(finalize(params, ctx, None), ctx, quant)
    return complete(finalize(params, ctx, quant.position_bits, quant.grid_scale), ctx, quant)


def finalize(params: Params, ctx: FitContext, position_bits: int | None, grid_scale: float = 1.0) -> Finalized:
    """Keep the active points and fix them to the container's positions: float16 (position_bits None, v1) or the
    2^b grid of the frame x grid_scale (v2; colliding points merged, first occurrence wins, canonical order)."""
    from tetweave_codec.errors import TetweaveError

    t0 = time.perf_counter()
    grid = triangulate(params.points, ctx.backend)
    with torch.no_grad():
        keep = active_mask(grid.tets, params.s).cpu().numpy()
    points, s, c = params.numpy()
    points, s, c = points[keep], s[keep], c[keep]
    cells = stored = None
    if position_bits is None:
        stored = points.astype(np.float16)
        _, first = np.unique(stored.view(np.uint16).reshape(-1, 3), axis=0, return_index=True)
        first = np.sort(first)
        stored = stored[first]
        fixed = stored.astype(np.float64)
    else:
        cells, first = Q.merge_collisions(Q.quantize_positions(points, position_bits, grid_scale))
        cells, first = _drop_flat_tets(cells, first, position_bits, ctx.backend)
        fixed = Q.dequantize_positions(cells, position_bits, grid_scale)
    if len(fixed) < 4:
        raise TetweaveError("the fit produced no surface (is the input a closed or nearly closed shape?)")
    ctx.seconds["finalize"] = ctx.seconds.get("finalize", 0.0) + time.perf_counter() - t0
    return Finalized(fixed, s[first], c[first], stored, cells, position_bits, grid_scale=grid_scale)


def finalize_cells(cells: np.ndarray, s: np.ndarray, c: np.ndarray, position_bits: int, backend: str) -> Finalized:
    """A Finalized of points given as distinct grid cells (N,3) in canonical order, with latent s (N,) and c (N,q)
    (the grid layout, fit.grid): the points of flat tets dropped as in `finalize`."""
    from tetweave_codec.errors import TetweaveError

    cells, first = _drop_flat_tets(np.asarray(cells, dtype=np.int64), np.arange(len(cells)), position_bits, backend)
    if len(cells) < 4:
        raise TetweaveError("the grid holds no surface (is the input a closed or nearly closed shape?)")
    points = Q.dequantize_positions(cells, position_bits)
    return Finalized(points, np.asarray(s)[first], np.asarray(c)[first], None, cells, position_bits, keep_signs=True)


def flat_tets(cells: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Mask (T,) of the tets (T,4) whose four integer grid cells (N,3) are coplanar, by the exact determinant.

    Cells are below 2^16, so the edge vectors are below 2^17 and the determinant below 6 * 2^51: exact in int64.
    """
    c = np.asarray(cells, dtype=np.int64)
    a = c[tets[:, 0]]
    e1, e2, e3 = c[tets[:, 1]] - a, c[tets[:, 2]] - a, c[tets[:, 3]] - a
    det = (
        e1[:, 0] * (e2[:, 1] * e3[:, 2] - e2[:, 2] * e3[:, 1])
        - e1[:, 1] * (e2[:, 0] * e3[:, 2] - e2[:, 2] * e3[:, 0])
        + e1[:, 2] * (e2[:, 0] * e3[:, 1] - e2[:, 1] * e3[:, 0])
    )
    return det == 0


def _drop_flat_tets(
    cells: np.ndarray, first: np.ndarray, position_bits: int, backend: str
) -> tuple[np.ndarray, np.ndarray]:
    """Remove points until the decoder's triangulation of the grid cells (N,3) has no flat tet; `first` (N,)
    follows.

    Grid points are often coplanar in fours (the feature-aware start puts many on the planes of a CAD part), and
    TetGen can return a zero-volume tet for them; marching tets then writes zero-area triangles lying across their
    neighbours, which breaks the no-self-intersection guarantee (fandisk with the feature start: 3 such faces of
    8,888 at 5 KB). Dropping the last point (canonical order) of each flat tet and triangulating again removes
    them; the late stage, which runs after, adapts s and c to the remaining points. Deterministic.
    """
    from tetweave_codec.geometry.delaunay import tetrahedralize

    for _ in range(MAX_FLAT_TET_ROUNDS):
        if len(cells) < 5:
            break
        tets = tetrahedralize(Q.dequantize_positions(cells, position_bits), backend).tets
        flat = flat_tets(cells, tets)
        if not flat.any():
            break
        drop = np.zeros(len(cells), dtype=bool)
        drop[tets[flat].max(axis=1)] = True
        cells, first = cells[~drop], first[~drop]
    return cells, first


def complete(fin: Finalized, ctx: FitContext, quant: Quantization | None) -> FinishResult:
    """The late stage on finalized points, then the stored values (float16 for v1, symbols for v2)."""
    t0 = time.perf_counter()
    if quant is not None and (quant.position_bits, quant.grid_scale) != (fin.position_bits, fin.grid_scale):
        raise ValueError("the quantization's position grid differs from the finalized grid")
    quantizer = None if quant is None else _Quantizer(quant, ctx.config.sh_degree)
    s, c = late_stage(
        fin.points, fin.s, fin.c, ctx, quantizer, keep_signs=fin.keep_signs, triangulated=fin.stored_points()
    )
    ctx.seconds["late"] = ctx.seconds.get("late", 0.0) + time.perf_counter() - t0
    if quant is None:
        s16, c16 = round_float16(s, c)
        return FinishResult(1, fin.stored, s16, c16, latent_s=s, latent_c=c)
    return requantize(fin.points, fin.cells, s, c, quant, ctx.config.sh_degree)


def requantize(
    points: np.ndarray,
    cells: np.ndarray,
    s: np.ndarray,
    c: np.ndarray,
    quant: Quantization,
    sh_degree: int,
) -> FinishResult:
    """A v2 FinishResult for latent s (N,), c (N,q) on fixed grid points with the steps of `quant` (no refit)."""
    quantizer = _Quantizer(quant, sh_degree)
    s_sym, c_sym = quantizer.symbols(s, c)
    s_val, c_val = quantizer.values(s_sym, c_sym)
    return FinishResult(2, points, s_val, c_val, quant, cells, s_sym, c_sym, latent_s=s, latent_c=c)


class _Quantizer:
    """The container's s and c quantizers, as numpy symbols and as straight-through torch stand-ins."""

    def __init__(self, quant: Quantization, sh_degree: int):
        self.s_step = Q.stored_step(quant.s_step)
        self.c_steps = Q.c_steps(sh_degree, quant.c_band_steps[: sh_degree + 1])

    def symbols(self, s: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return Q.quantize_s(s, self.s_step), Q.quantize_c(np.asarray(c).reshape(len(s), -1), self.c_steps)

    def values(self, s_sym: np.ndarray, c_sym: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return Q.dequantize_s(s_sym, self.s_step), Q.dequantize_c(c_sym, self.c_steps)

    def straight_through(self, s: Tensor, c: Tensor) -> tuple[Tensor, Tensor]:
        """Dequantized values in the forward pass, identity gradient to the latent s and c."""
        s_np = s.detach().cpu().numpy().astype(np.float64)
        c_np = c.detach().cpu().numpy().astype(np.float64)
        s_val, c_val = self.values(*self.symbols(s_np, c_np))
        s_q = torch.as_tensor(s_val, dtype=s.dtype, device=s.device)
        c_q = torch.as_tensor(c_val.reshape(c.shape), dtype=c.dtype, device=c.device)
        return s + (s_q - s).detach(), c + (c_q - c).detach()


def late_stage(
    points: np.ndarray,
    s: np.ndarray,
    c: np.ndarray,
    ctx: FitContext,
    quantizer: _Quantizer | None = None,
    keep_signs: bool = False,
    triangulated: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Optimize s and c on fixed points (N,3) float64 and their one triangulation; returns latent s, c (float32).

    The triangulation is computed from the float64 points in the given order, exactly as the decoder computes it:
    from `triangulated` (N,3) when given, the same points in the stored frame (a scaled grid, whose positions
    divided by the grid scale are not exactly the decoder's; Delaunay is scale-invariant, its float predicates on
    cospherical grid points are not).
    keep_signs: no s changes sign (each is clamped to its side after every step). The grid layout's signs are the
    input's inside and outside; a flip there made a sheet between band points across empty space (spot, b 6:
    119 flips, 210 vertices 0.01-0.085 from the input, Chamfer 2.7e-4 -> 8.3e-4).
    """
    sch = ctx.config.schedule
    params = Params(points.astype(np.float32), s, c, ctx.device, ctx.config.lr, optimize_points=False)
    grid = triangulate(points if triangulated is None else triangulated, ctx.backend, ctx.device)
    base_lrs = [g["lr"] for g in params.opt_sc.param_groups]
    inside = torch.as_tensor(np.asarray(s) < 0, device=params.s.device) if keep_signs else None
    for it in range(sch.late_iters):
        if quantizer is not None:
            # Adam moves every latent value by about its step size per iteration: with the s step of the
            # quantizer near lr.s, symbols flip back and forth to the end. A cosine decay lets them settle (spot
            # 4K, b 9, s step 5e-4: Chamfer 7.83e-4 -> 7.66e-4, c 0.6 bits/point cheaper); v1 gained nothing.
            for group, lr in zip(params.opt_sc.param_groups, base_lrs, strict=True):
                group["lr"] = lr * 0.5 * (1.0 + math.cos(math.pi * it / sch.late_iters))
        views = ctx.random_views()
        s_in, c_in = (params.s, params.c) if quantizer is None else quantizer.straight_through(params.s, params.c)
        loss, parts = regularized_loss(ctx, params.points, s_in, c_in, grid, views, with_grid_terms=False)
        backward(loss, params)
        params.opt_sc.step()
        params.opt_sc.zero_grad(set_to_none=True)
        if inside is not None:
            with torch.no_grad():
                params.s.copy_(torch.where(inside, params.s.clamp(max=-SIGN_FLOOR), params.s.clamp(min=SIGN_FLOOR)))
        ctx.history.append(("late", it, parts["total"]))
        ctx.progress("late", it + 1, sch.late_iters, {"loss": parts["total"], "points": len(s)})
    _, s_out, c_out = params.numpy()
    return s_out, c_out


def round_float16(s: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Container v1's s and c: float16, with |s| kept above V1_MIN_ABS_S so that no sign is lost to rounding."""
    sign = np.where(s < 0, -1.0, 1.0)
    s16 = (sign * np.maximum(np.abs(s), V1_MIN_ABS_S)).astype(np.float16)
    c16 = np.clip(c, -V1_MAX_ABS_C, V1_MAX_ABS_C).astype(np.float16)
    return s16, c16
