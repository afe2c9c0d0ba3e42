"""What every metric shares: `MetricOptions` and the mesh-array helpers."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MetricOptions:
    """Parameters of the metrics; distances in units of the normalized frame (see the module docstring)."""

    n_samples: int = 200_000  # surface samples per mesh (Chamfer, Hausdorff, NC, F1, edges)
    seed: int = 0
    f1_thresholds: tuple[float, ...] = (0.001, 0.005)
    normal_angle_deg: float = 5.0
    edge_radius: float = 0.02  # ≈2 sample spacings at 200K samples on a [-0.9, 0.9]^3 box (area 19.4)
    edge_dot: float = 0.2
    edge_neighbors: int = 32
    edge_f1_threshold: float = 0.005
    quality_threshold: float = 4.0  # AR and RR
    small_angle_deg: float = 10.0
    self_intersections: bool = True
    hausdorff_vertices: bool = True  # also query the mesh vertices for the Hausdorff distance

    @classmethod
    def for_samples(cls, n_samples: int, **kwargs) -> MetricOptions:
        """Options at `n_samples`, with `edge_radius` scaled as 1/sqrt(n_samples) from 0.02 at 200K, so that a
        crease search sees as many neighbours whatever the sample count."""
        radius = cls.edge_radius * math.sqrt(cls.n_samples / n_samples)
        return cls(n_samples=n_samples, **({"edge_radius": radius} | kwargs))


def as_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contiguous float64 vertices (V,3) and int64 faces (F,3); ValueError on a face index out of range."""
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError("face index out of range")
    return v, f


def sorted_unique(x: np.ndarray) -> np.ndarray:
    """Sorted unique values of an integer array. numpy 2.4's `np.unique` without extra outputs hashes, which
    is ~60x slower than sorting on millions of int64 keys (measured: 5 s against 0.08 s for 5M)."""
    x = np.sort(np.asarray(x).reshape(-1))
    return x[np.concatenate([[True], x[1:] != x[:-1]])] if len(x) else x
