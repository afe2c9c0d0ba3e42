"""An independent judge of a decoded mesh against an asset's truth (nothing of tetweave_codec.metrics or .fit).

Everything is measured in the messy input's frame as the encoder normalizes it (bounding box centred, its longest
side 1.8), so that the numbers compare with the encoder summary's Chamfer distance.

- `Truth`: area-uniform samples of what a viewer sees and the surface that holds them. CAD assets: samples of the
  kernel's outside surface, which is that surface. The character: the samples of its parts that rays from
  outside reach (raycast.visible_samples), and the parts' faces holding a seen sample or a seen centroid.
- `chamfer`: symmetric mean distance: truth samples to the decoded mesh and decoded samples (raycast's own
  sampler) to the truth surface; each distance is the exact point-triangle distance to the nearest of the faces
  of the K nearest dense samples of the other side (scipy's cKDTree; trimesh's point-triangle distance).
- `hidden_share`: the share of the decoded area that no outside ray reaches (raycast.visible on its samples).
- `closed`: trimesh's watertight (every edge on two faces) and winding-consistent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tetweave_codec.benchmarks.assets import raycast

SAMPLES = 100_000
DENSE = 300_000
NEAREST = 8
TRUTH_SAMPLES = 200_000  # the character's samples before the visibility test
HIDDEN_SAMPLES = 20_000


@dataclass(frozen=True)
class Truth:
    """points (P,3): area-uniform samples of the truth; vertices (V,3), faces (F,3): the surface that holds them;
    all in the normalized frame (scale, centre: normalized = (x - centre) * scale)."""

    points: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    scale: float
    centre: np.ndarray


def frame(vertices: np.ndarray) -> tuple[float, np.ndarray]:
    """(scale, centre) of the encoder's normalization of a mesh: bounding box centred, longest side 1.8."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    return 1.8 / float((hi - lo).max()), 0.5 * (lo + hi)


def truth_of(asset, seed: int = 0) -> Truth:
    """The judge's truth of an asset (assets.Asset), in the frame of its parts."""
    scale, centre = frame(asset.parts.vertices)
    if asset.truth is not None:
        v = (asset.truth[0] - centre) * scale
        f = asset.truth[1]
        points, _ = raycast.sample_surface(v, f, SAMPLES, seed)
        return Truth(points, v, f, scale, centre)
    v = (asset.parts.vertices - centre) * scale
    f = asset.parts.faces
    caster = raycast.Caster(v, f)
    points, face = raycast.sample_surface(v, f, TRUTH_SAMPLES, seed)
    seen = raycast.visible(v, f, points, face, caster=caster)
    centroids = v[f].mean(axis=1)
    seen_faces = raycast.visible(v, f, centroids, np.arange(len(f)), caster=caster)
    keep = np.zeros(len(f), dtype=bool)
    keep[face[seen]] = True
    keep |= seen_faces
    return Truth(points[seen][:SAMPLES], v, f[keep], scale, centre)


def distances(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, seed: int = 0) -> np.ndarray:
    """(P,) each point's distance to the mesh: the nearest of the faces of its NEAREST nearest dense samples (and
    face centroids) of the mesh, exact point-triangle distances."""
    from scipy.spatial import cKDTree
    from trimesh.triangles import closest_point

    dense, dface = raycast.sample_surface(vertices, faces, DENSE, seed + 7)
    dense = np.concatenate([dense, vertices[faces].mean(axis=1)])
    dface = np.concatenate([dface, np.arange(len(faces))])
    _, near = cKDTree(dense).query(points, k=NEAREST)
    cand = dface[near]  # (P,K)
    tri = vertices[faces[cand.reshape(-1)]]
    q = np.repeat(points, NEAREST, axis=0)
    d = np.linalg.norm(closest_point(tri, q) - q, axis=1).reshape(-1, NEAREST)
    return d.min(axis=1)


def chamfer(truth: Truth, vertices: np.ndarray, faces: np.ndarray, seed: int = 0) -> dict:
    """The decoded mesh (vertices in the input's frame, faces) against the truth: {"chamfer", "to_output" (truth
    samples to the output), "to_truth" (output samples to the truth)}."""
    v = (np.asarray(vertices, dtype=np.float64) - truth.centre) * truth.scale
    f = np.asarray(faces, dtype=np.int64)
    forward = distances(truth.points, v, f, seed).mean()
    points, _ = raycast.sample_surface(v, f, SAMPLES, seed + 1)
    backward = distances(points, truth.vertices, truth.faces, seed + 2).mean()
    return {"chamfer": float(0.5 * (forward + backward)), "to_output": float(forward), "to_truth": float(backward)}


def hidden_share(vertices: np.ndarray, faces: np.ndarray, seed: int = 0, n: int = HIDDEN_SAMPLES) -> float:
    """The share of the mesh's area that no outside ray reaches (raycast.visible of n area samples)."""
    v = np.asarray(vertices, dtype=np.float64)
    _, _, seen = raycast.visible_samples(v, faces, n, seed)
    return float(1.0 - seen.mean())


def closed(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """trimesh: watertight and winding-consistent."""
    import trimesh

    m = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64), process=False)
    return bool(m.is_watertight and m.is_winding_consistent)
