"""The grid layout: the points of a lattice in a band around the input surface, none placed by the fit.

The fit layout (fit.loop) places points by optimization and then snaps them to the container's 2^b grid; each
point costs its position (~10 bits at the default grid) and its s (~6-7 bits). The grid layout places no point:
it takes every cell of a lattice whose point lies within GRID_BAND lattice cells of the input surface, with s the
signed distance there, and leaves the rest to the late stage (s and c fitted through the decoder's filter on
those fixed points, fit.finish). A dense band of cells is cheap to code (1.5-2 bits per point in the octree), so
the same bytes buy about twice the points. The container is the same: a decoder cannot tell the layouts apart.

The cell size is continuous: the lattice has 2^bits cells per axis over [-GRID_BOUND, GRID_BOUND]^3 of the grid
frame, the normalized frame scaled by `frame_scale` k (the file's transform divides it out: original = grid frame
x scale / k + offset), so a lattice cell measures ``lattice_cell(bits) / k`` in the normalized frame. The lattice
is stored GRID_SPREAD bits finer (cell X as X << GRID_SPREAD). Lattice points are cospherical in eights; the
Delaunay backends resolve that exactly (geometry.delaunay), and the finish drops points of flat tets as for any
grid.

Measured against the fit layout and the classical pipelines in docs/measurements/grid_layout.md: fewer bytes at
equal error on evenly detailed scans (igea, stanford-bunny), more on most other meshes; about half the encode
time.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from tetweave_codec.fit.initialize import signed_distance
from tetweave_codec.formats import quantize as Q
from tetweave_codec.geometry.closest import SurfaceTree
from tetweave_codec.geometry.triangles import face_areas, sample_surface

# Cells whose centre lies within this many cell sizes of the input surface (both sides). Thinner bands leave
# long Delaunay edges between inside and outside points far from the surface, whose crossings are spurious
# sheets (spot at b 7, band 0.6: 1.7 % of the vertices 0.06-0.27 away); 0.9 costs the same bytes at equal error
# as 1.2 (stanford-bunny, b 6).
GRID_BAND = 0.9
# The s step in lattice cells (grid frame). Bytes x Chamfer of --size files against the fit layout's (fit_ab, one
# thread; stanford-bunny 10k, spot 10k, igea 10k, stanford-bunny 5k, spot 20k, igea 5k), at 0.02 / 0.025 / 0.03:
# 0.91 1.23 0.92 1.07 1.03 0.86 / 0.93 1.13 0.95 1.00 1.12 0.85 / 0.93 1.17 0.90 1.05 1.22 0.83 (medians 0.98 /
# 0.97 / 0.99): within the +-15 % by which one cell size differs from the next on spot. 300 late iterations
# instead of 150 changed nothing (0.99-1.04). Refining the worst 5-10 % of the lattice one level (commit cb804e8)
# gave 0.91-1.11 against none: not kept.
GRID_S_STEP = 0.025
# The lattice is stored GRID_SPREAD bits finer than its own cells: lattice cell X is stored as cell X << GRID_SPREAD
# of the 2^(bits + GRID_SPREAD) grid (its lower corner's child), which keeps the geometry (a shift of all points)
# and changes the s prediction: its ridge (formats/predict.py, RIDGE_ABSOLUTE) is in squared stored cells, and at
# one cell between neighbours it held the predicted planes too flat. The band of spot at lattice b 6 (10,562 points,
# s its signed distance, the same steps), packed at spread 0 / 1 / 2 / 3: 9,532 / 8,541 / 8,057 / 8,077 bytes (s
# 7,459 / 6,396 / 5,840 / 5,788, positions 1,986 / 2,058 / 2,130 / 2,202: the octree's contexts learn the lone
# child).
GRID_SPREAD = 2
# Largest frame scale k: the input lies in [-0.9 k, 0.9 k]^3 of the grid frame (meshio.normalize), and its band
# (GRID_BAND lattice cells beyond it, plus one cell for where a point sits in its cell) must stay inside the grid's
# [-GRID_BOUND, GRID_BOUND]^3 (`max_frame_scale`); at most this in any case.
MAX_FRAME_SCALE = 1.3
NORMALIZED_EXTENT = 0.9
# Surface samples per squared cell when looking for the band's cells (each sample's cell and its 26 neighbours
# are candidates): dense enough that every cell the surface crosses holds samples.
SAMPLES_PER_CELL = 8.0
MAX_SAMPLES = 4_000_000
# Estimates (band query + pack) of rate control's search for the cell size of a --size file.
GRID_SIZE_SEARCH_STEPS = 8
_NEIGHBOURS = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)], dtype=np.int64)


MIN_LATTICE_BITS = Q.POSITION_BITS_MIN - GRID_SPREAD
MAX_LATTICE_BITS = Q.POSITION_BITS_MAX - GRID_SPREAD


def lattice_cell(bits: int) -> float:
    """Edge of a lattice cell of `bits` bits per axis in the grid frame: 2 GRID_BOUND / 2^bits."""
    return 2.0 * Q.GRID_BOUND / float(1 << bits)


class GridFrame(NamedTuple):
    """A grid layout's resolution: a lattice of 2^`bits` cells per axis over [-GRID_BOUND, GRID_BOUND]^3 in the grid
    frame = normalized frame x `frame_scale`, stored on the grid of `stored_bits` = bits + GRID_SPREAD."""

    bits: int
    frame_scale: float

    @property
    def stored_bits(self) -> int:
        return self.bits + GRID_SPREAD

    @property
    def cell(self) -> float:
        """Lattice cell edge in the normalized frame."""
        return lattice_cell(self.bits) / self.frame_scale


def max_frame_scale(bits: int) -> float:
    """The largest frame scale at lattice `bits` whose band stays inside the grid (see MAX_FRAME_SCALE)."""
    room = Q.GRID_BOUND - (GRID_BAND + 1.0) * lattice_cell(bits)
    return min(MAX_FRAME_SCALE, room / NORMALIZED_EXTENT)


def frame_for_cell(cell: float) -> GridFrame:
    """The grid frame whose lattice cells measure `cell` in the normalized frame: the coarsest lattice bits whose
    frame scale lattice_cell(bits) / cell stays within `max_frame_scale` (bits in MIN_LATTICE_BITS..
    MAX_LATTICE_BITS; a cell too coarse for the coarsest lattice gets a larger cell at that lattice's largest
    scale)."""
    if not (math.isfinite(cell) and cell > 0):
        raise ValueError(f"cell size must be positive, got {cell}")
    for bits in range(MIN_LATTICE_BITS, MAX_LATTICE_BITS + 1):
        k = lattice_cell(bits) / cell
        if k <= max_frame_scale(bits):
            return GridFrame(bits, k)
    return GridFrame(MAX_LATTICE_BITS, max_frame_scale(MAX_LATTICE_BITS))


class GridBand:
    """The input surface (normalized frame), prepared for band queries at any cell size. tree: a SurfaceTree of
    these very vertices and faces when the caller has one (fit.prepared), else built here."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, seed: int = 0, tree: SurfaceTree | None = None):
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.tree = SurfaceTree(self.vertices, self.faces) if tree is None else tree
        self.area = float(face_areas(self.vertices, self.faces).sum())
        self.seed = seed
        self._last: tuple | None = None  # ((frame, band), (cells, s)) of the last `cells` query

    def cells(self, frame: GridFrame, band: float = GRID_BAND) -> tuple[np.ndarray, np.ndarray]:
        """The band's points as stored cells in canonical order, and the grid-frame signed distance at them (the
        last query's result is kept: rate control asks for the same frame again before the late stage).

        Returns cells (N,3) int64 of the 2^stored_bits grid (lattice cells X << GRID_SPREAD) and s (N,) float64
        (negative inside; grid-frame units, i.e. normalized distances x frame_scale). A lattice cell is in the band
        when its point (the stored cell's centre) lies within `band` lattice cells of the surface; candidates are
        the lattice cells of dense surface samples and their neighbours (a cell the surface barely clips and no
        sample hits may be missed: the set is that of the samples, deterministic for the seed).
        """
        if self._last is not None and self._last[0] == (frame, band):
            return self._last[1]
        bits, k = frame
        top = (1 << bits) - 1
        cell = lattice_cell(bits)  # grid frame
        n = int(min(MAX_SAMPLES, max(1000, SAMPLES_PER_CELL * self.area * (k / cell) ** 2)))
        samples, _ = sample_surface(self.vertices, self.faces, n, self.seed)
        side = top + 3  # keys of cells padded by one on each side, so that neighbours never wrap
        lattice = np.floor((np.concatenate([samples, self.vertices]) * k + Q.GRID_BOUND) / cell)
        own = np.clip(lattice, 0, top).astype(np.int64) + 1
        keys = np.unique((own[:, 0] * side + own[:, 1]) * side + own[:, 2])
        offsets = (_NEIGHBOURS[:, 0] * side + _NEIGHBOURS[:, 1]) * side + _NEIGHBOURS[:, 2]
        keys = np.unique((keys[:, None] + offsets[None]).ravel())
        cand = np.stack([keys // (side * side), (keys // side) % side, keys % side], axis=1) - 1
        cand = cand[((cand >= 0) & (cand <= top)).all(axis=1)] << GRID_SPREAD
        centres = Q.dequantize_positions(cand, frame.stored_bits) / k
        sq, _, _ = self.tree.query(centres)
        dist = np.sqrt(np.maximum(sq, 0.0))  # normalized frame
        near = dist * k < band * cell
        cand = cand[near]
        s = signed_distance(centres[near], self.vertices, self.faces, distance=dist[near]) * k
        order = Q.canonical_order(cand, frame.stored_bits)
        self._last = ((frame, band), (cand[order], s[order]))
        return self._last[1]

    def count(self, frame: GridFrame, band: float = GRID_BAND) -> int:
        return len(self.cells(frame, band)[0])

    def cell_for_points(self, points: int, band: float = GRID_BAND) -> float:
        """The cell size (normalized frame) whose band holds about `points` cells: a few counts, secant steps in
        log-log (the count falls about as cell^-2)."""
        cell = math.sqrt(2.0 * band * self.area / max(points, 1))
        for _ in range(6):
            got = self.count(frame_for_cell(cell), band)
            if got == 0 or abs(math.log(got / points)) < 0.02:
                break
            cell *= math.sqrt(got / points)
        return cell
