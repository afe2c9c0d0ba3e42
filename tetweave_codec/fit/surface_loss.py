"""A differentiable 3-D Chamfer term against the known input surface (what a compressor's known input allows).

The paper fits through renders because in reconstruction only images exist. A compressor has the input mesh
itself, and renders at CPU-affordable resolutions (128-256 px, ~0.01-0.02 normalized units per pixel) cannot see
errors smaller than a fraction of a pixel, which is exactly the range that decides file size against Draco. This
term measures the point-to-surface Chamfer distance directly, in both directions:

* mesh -> input: points p drawn uniformly by area on the extracted mesh (as many as it has vertices, at least
  `per_call`; barycentric coordinates held fixed so that p moves with its face's corners) to their closest point
  cp(p) on the input (libigl AABB tree, built once);
* input -> mesh: a random subset of fixed input surface samples q to their closest point on the current mesh,
  expressed with barycentric coordinates b of the closest face so that it moves with the mesh's vertices.

Closest points and barycentrics are found without gradient and then held fixed (the usual Chamfer linearization);
the distances are differentiable w.r.t. the mesh vertices, hence w.r.t. points, s and c through marching tets.
The loss is the mean of sqrt(d^2 + eps^2), i.e. the Chamfer distance itself (not squared), so its scale is the
metric's.

The same closest faces give a normal term, the bench's normal consistency turned into a loss: 1 - |n_mesh . n_in|
averaged over both sample sets, with n_mesh the unit normal of the mesh face a sample lies on (mesh -> input) or
is closest to (input -> mesh) and n_in that of the input face. Orientation-agnostic like the metric, so inputs
with inconsistent winding are fine. It costs no query (the faces come with the closest points).
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from tetweave_codec.geometry.closest import SurfaceTree
from tetweave_codec.geometry.triangles import (
    draw_surface_samples,
    face_areas,
    face_cross,
    face_normals,
    points_from_barycentrics,
    sample_surface,
    unit_vectors,
)

# Smoothing of sqrt at 0 (normalized units): far below any distance the fit resolves.
_EPS = 1e-6
# Input surface samples per call (`SurfaceTarget.loss`'s per_call). As many as the control mesh has vertices
# (2x-3x more at 8K-18K points) bought 1.5-2.5 % of bytes x Chamfer on spot and igea at 20-40 KB for 17-33 % more
# CPU, and lost 5 % on the bunny (docs/measurements/encode_speed.md, 2026-12-01): not kept.
INPUT_SAMPLES = 8_000
# Calls for which the current mesh's AABB tree is reused while the mesh keeps the same faces (see `_MeshTree`).
TREE_REUSE_CALLS = 4


# Twice the area (normalized units^2) below which a mesh face's normal is scaled by this constant instead of its own
# length: a unit normal's gradient grows as 1 / |cross|, and marching tets makes faces down to ~1e-11 (fandisk, 4K
# points); none above it changes. 1e-9 is the doubled area of a triangle with sides ~4e-5, a hundredth of a cell.
MIN_NORMAL_CROSS = 1e-9


def _unit_normals(vertices: Tensor, faces: Tensor) -> Tensor:
    """Unit face normals (F,3) of the mesh, differentiable, with a bounded gradient on near-degenerate faces."""
    cross = face_cross(vertices, faces)
    big = (cross * cross).sum(-1, keepdim=True) > MIN_NORMAL_CROSS**2
    return torch.where(big, unit_vectors(cross), cross / MIN_NORMAL_CROSS)


class SurfaceLoss(NamedTuple):
    """The two terms of `SurfaceTarget.loss`, 0-dim tensors: the symmetric Chamfer distance (normalized units) and
    the normal error 1 - mean |cos| between mesh and input normals at the same sample pairs (0 = aligned)."""

    chamfer: Tensor
    normals: Tensor


class SurfaceTarget:
    """The input surface, prepared for repeated distance queries.

    vertices (V,3) float64 and faces (F,3) int64 in the normalized frame; n_samples input surface samples are
    drawn once from `seed`; each `loss` call uses `per_call` of them (a fresh random subset from `generator`).
    tree: a SurfaceTree of these very vertices and faces when the caller has one (fit.prepared), else built here.
    """

    def __init__(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        n_samples: int = 200_000,
        seed: int = 0,
        tree: SurfaceTree | None = None,
    ):
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.tree = SurfaceTree(self.vertices, self.faces) if tree is None else tree
        samples, face = sample_surface(self.vertices, self.faces, n_samples, seed)
        # In face order, and each call's subset in this order: nearby queries share their walk down the mesh's tree.
        order = np.argsort(face, kind="stable")
        self.samples = samples[order]
        self.area = float(face_areas(self.vertices, self.faces).sum())
        self.face_normals = face_normals(self.vertices, self.faces)  # (F,3) unit, zero rows for degenerate faces
        self.sample_normals = self.face_normals[face[order]]  # (n_samples,3)
        self._mesh_tree: _MeshTree | None = None

    def fresh(self) -> SurfaceTarget:
        """This input's term for another fit: the same samples and tree, no cached tree of a fitted mesh (a fit
        reuses the tree of its own mesh for a few calls, `_tree_for`; another fit must not see it)."""
        other = copy.copy(self)
        other._mesh_tree = None
        return other

    def closest_points(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest points (n,3) on the input surface to `points` (n,3) and the input face (n,) int64 of each."""
        _, face, cp = self.tree.query(points)
        return cp, face

    def loss(
        self,
        vertices: Tensor,
        faces: Tensor,
        generator: torch.Generator,
        per_call: int = INPUT_SAMPLES,
        min_samples: int | None = None,
    ) -> SurfaceLoss:
        """Symmetric point-to-surface Chamfer distance and normal error between the mesh (vertices (V,3), faces
        (F,3)) and the input.

        Mesh -> input uses max(min_samples, per_call) points (min_samples None: V). Differentiable w.r.t.
        `vertices`. Returns 0-dim tensors on their device.
        """
        import igl

        v_np = vertices.detach().cpu().numpy().astype(np.float64)
        f_np = faces.detach().cpu().numpy().astype(np.int64)
        # Mesh -> input on points drawn by area over the faces, as the metric samples it. Measured at the vertices
        # (before), a flat face spanning a curved input cost nothing between its corners. With the renders off,
        # vertices -> area samples changed bytes x Chamfer at 10 KB by 0.87x on spot and fandisk in one run
        # (docs/measurements/encode_speed.md).
        n_samples = max(len(v_np) if min_samples is None else int(min_samples), per_call)
        sample_face, bary = draw_surface_samples(vertices, faces, n_samples, generator)
        on_faces = points_from_barycentrics(vertices, faces, sample_face, bary)
        cp, input_face = self.closest_points(on_faces.detach().cpu().numpy().astype(np.float64))
        to_input = torch.sqrt(((on_faces - torch.from_numpy(cp).to(vertices)) ** 2).sum(-1) + _EPS**2).mean()
        n_in = torch.from_numpy(self.face_normals[input_face]).to(vertices)
        # normals of the sampled faces only (a subdivided mesh has 4-16x the faces of its samples)
        normals_to_input = 1.0 - (_unit_normals(vertices, faces[sample_face]) * n_in).sum(-1).abs().mean()

        # with replacement: a permutation of all 200K samples per call cost 1 ms (2 % of the encode) for 8K of them
        pick = np.sort(torch.randint(len(self.samples), (per_call,), generator=generator).numpy())
        q = self.samples[pick]
        tree = self._tree_for(v_np, f_np)
        _, face, closest = tree.tree.query(q)
        # Barycentrics on the tree's mesh (possibly a few steps old, same faces), applied to the current corners.
        tri = tree.tree.vertices[f_np[face]]
        bary = igl.barycentric_coordinates(
            closest, np.ascontiguousarray(tri[:, 0]), np.ascontiguousarray(tri[:, 1]), np.ascontiguousarray(tri[:, 2])
        )
        bary = np.nan_to_num(bary, nan=1.0 / 3.0)
        mesh_face = torch.from_numpy(face).to(faces.device)
        on_mesh = points_from_barycentrics(vertices, faces, mesh_face, torch.from_numpy(bary).to(vertices))
        q_t = torch.from_numpy(q).to(vertices)
        to_mesh = torch.sqrt(((on_mesh - q_t) ** 2).sum(-1) + _EPS**2).mean()
        n_q = torch.from_numpy(self.sample_normals[pick]).to(vertices)
        normals_to_mesh = 1.0 - (_unit_normals(vertices, faces[mesh_face]) * n_q).sum(-1).abs().mean()
        return SurfaceLoss(0.5 * (to_input + to_mesh), 0.5 * (normals_to_input + normals_to_mesh))

    def _tree_for(self, v_np: np.ndarray, f_np: np.ndarray) -> _MeshTree:
        """An AABB tree of the current mesh (vertices (V,3), faces (F,3)), reused while the faces stay the same.

        Building the tree costs ~52 ms for a 74K-face mesh (libigl, one thread). Between re-triangulations only s
        and c change, so the faces often stay the same and the vertices move a little along their edges: for up to
        TREE_REUSE_CALLS calls the closest faces are found on the mesh the tree was built for and their barycentric
        coordinates applied to the current vertices (the linearization the term makes anyway).
        """
        cached = self._mesh_tree
        if cached is not None and cached.calls < TREE_REUSE_CALLS and np.array_equal(cached.tree.faces, f_np):
            cached.calls += 1
            return cached
        self._mesh_tree = _MeshTree(SurfaceTree(v_np, f_np))
        return self._mesh_tree


class _MeshTree:
    """The tree of one extracted mesh (its vertices and faces in `tree`) and how many later calls reused it."""

    def __init__(self, tree: SurfaceTree):
        self.tree = tree
        self.calls = 0
