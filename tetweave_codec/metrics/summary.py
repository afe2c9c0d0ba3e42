"""All metrics of one mesh, or of a decoded mesh against its prepared input, as one flat dict (the benchmark's row).

Counts: ``n_vertices`` (referenced vertices) and ``n_faces``; percentages of faces for the quality thresholds
(``aspect_ratio_gt4_pct``, ``radius_ratio_gt4_pct``, ``small_angle_lt10_pct``, ``self_intersect_pct``); the
topology flags of `manifold.topology`; the fidelity metrics of `fidelity.fidelity`.
"""

from __future__ import annotations

import numpy as np

from tetweave_codec.geometry.intersections import self_intersecting_faces
from tetweave_codec.metrics.common import MetricOptions, as_mesh, sorted_unique
from tetweave_codec.metrics.fidelity import Reference, fidelity, prepare_mesh, to_frame
from tetweave_codec.metrics.manifold import topology
from tetweave_codec.metrics.quality import triangle_quality


def mesh_report(vertices: np.ndarray, faces: np.ndarray, options: MetricOptions | None = None) -> dict:
    """Frame-independent quality of one mesh: counts, triangle quality, topology, self-intersections."""
    opts = options or MetricOptions()
    v, f = as_mesh(vertices, faces)
    q = triangle_quality(v, f)
    n_faces = max(len(f), 1)
    out: dict = {"n_vertices": int(len(sorted_unique(f))), "n_faces": int(len(f))}
    out["aspect_ratio_gt4_pct"] = float(100.0 * np.sum(q["aspect_ratio"] > opts.quality_threshold) / n_faces)
    out["radius_ratio_gt4_pct"] = float(100.0 * np.sum(q["radius_ratio"] > opts.quality_threshold) / n_faces)
    out["small_angle_lt10_pct"] = float(100.0 * np.sum(q["min_angle_deg"] < opts.small_angle_deg) / n_faces)
    if opts.self_intersections:
        out["self_intersect_pct"] = float(100.0 * self_intersecting_faces(v, f).sum() / n_faces)
    else:
        out["self_intersect_pct"] = float("nan")
    out.update(topology(v, f))
    return out


def evaluate(
    reference: Reference, vertices: np.ndarray, faces: np.ndarray, options: MetricOptions | None = None
) -> dict:
    """All metrics of a decoded mesh (original frame) against a prepared input: fidelity + `mesh_report`.

    Raises ValueError if the decoded mesh is empty or has zero area.
    """
    opts = options or MetricOptions()
    v, f = as_mesh(vertices, faces)
    if len(f) == 0:
        raise ValueError("the decoded mesh has no faces")
    candidate = prepare_mesh(to_frame(v, reference.scale, reference.offset), f, opts)
    out = fidelity(reference.mesh, candidate, opts)
    out.update(mesh_report(v, f, opts))
    return out
