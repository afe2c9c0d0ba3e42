"""The per-mesh prior of rate control: how many points an input needs for an error, before any fit.

err ~ P / N + F (normalized frame, N grid points). P = PRIOR_BASE + PRIOR_DETAIL_SLOPE * max(0, D - PRIOR_DETAIL_KNEE),
where D (`input_detail`) = M x the Chamfer distance of a quadric decimation of the input to M =
PRIOR_PROBE_VERTICES vertices: a fit of a smooth or piecewise-flat surface has an error ~ PRIOR_BASE / N of its
own (its grid spacing), and detail a thousand vertices cannot hold (scanned skin, bumps) costs extra points in
proportion. F (`hole_cap_error`): the decoded mesh is closed, so every hole of an open input is capped, which adds
a floor whatever N. The constants were calibrated on the four development meshes with benchmarks/rate_control.py
(docs/measurements/rate_control_calibration.md); the search (rate_control.error) corrects a wrong prior with the
measured errors.
"""

from __future__ import annotations

import math

import numpy as np

# Prior of the error model err ~ PRIOR_ERROR_POINTS / N before the input is looked at: N x Chamfer of default
# fits is 1.6-1.9 on fandisk, 2.3-2.5 on spot, 4.8-6.1 on igea, 5.2-9.9 on stanford-bunny. Only the out-of-reach
# check before any work (and an input whose decimation leaves nothing) uses it.
PRIOR_ERROR_POINTS = 3.5
PRIOR_PROBE_VERTICES = 1000  # M: vertices of the decimation probe (~1 s on 270K faces)
PRIOR_PROBE_SAMPLES = 20_000  # Chamfer samples of the probe (its resolution ~1e-5 is far below the targets)
PRIOR_BASE = 1.22
PRIOR_DETAIL_KNEE = 1.0
PRIOR_DETAIL_SLOPE = 1.3
# A subdivided fit (fit.config.FitConfig.subdivision > 0) is smooth between its points: its own error (the
# PRIOR_BASE part) is lower, its detail part the same. Chamfer at equal points, one Loop level against none:
# spot 0.67-0.81, stanford-bunny 0.89-0.95, igea 0.90-1.02 (docs/measurements/subdivision.md).
SUBDIVIDED_BASE_FACTOR = 0.8
# A flat cap of radius r sits r / CAP_MEAN_DEPTH_DIVISOR from its rim on average (points of a disc: mean distance
# r/3 to its boundary), and the decoded mesh's samples are half of a Chamfer distance (CHAMFER_SIDE_SHARE).
CAP_MEAN_DEPTH_DIVISOR = 3.0
CHAMFER_SIDE_SHARE = 0.5


def mesh_prior(job) -> tuple[float, float]:
    """(P, F) of the per-mesh prior err ~ P / N + F of this job's input; F = 0 when the job keeps holes open."""
    prepared = job.input
    return prior_error_points(job), 0.0 if prepared.rim is not None else hole_cap_error(
        prepared.normalized, prepared.faces
    )


def prior_error_points(job) -> float:
    """P of the per-mesh prior err ~ P / N + F (see the module docstring), from `input_detail`."""
    base = PRIOR_BASE * (SUBDIVIDED_BASE_FACTOR if job.settings.subdivision else 1.0)
    detail = input_detail(job)
    if not math.isfinite(detail):
        return PRIOR_ERROR_POINTS
    return base + PRIOR_DETAIL_SLOPE * max(0.0, detail - PRIOR_DETAIL_KNEE)


def input_detail(job) -> float:
    """D of the prior: PRIOR_PROBE_VERTICES x the Chamfer distance (normalized frame) of a quadric decimation of
    the input to that many vertices (fast_simplification, deterministic); 0 for an input already that coarse, inf
    when the decimation leaves nothing. Computed once per input (`job.input.detail`)."""
    prepared = job.input
    if prepared.detail is not None:
        return prepared.detail
    import fast_simplification

    v, f = prepared.normalized, prepared.faces
    if len(v) <= 2 * PRIOR_PROBE_VERTICES:  # already coarse: no detail beyond what a fit resolves
        prepared.detail = 0.0
        return prepared.detail
    reduction = 1.0 - 2.0 * PRIOR_PROBE_VERTICES / len(f)
    dv, df = fast_simplification.simplify(
        np.ascontiguousarray(v, dtype=np.float32), np.ascontiguousarray(f, dtype=np.int32), reduction
    )
    if not len(df):
        prepared.detail = math.inf
        return prepared.detail
    prepared.detail = len(dv) * prepared.normalized_chamfer(dv, df, PRIOR_PROBE_SAMPLES)
    return prepared.detail


def hole_cap_error(vertices: np.ndarray, faces: np.ndarray) -> float:
    """F of the prior: the Chamfer distance the caps of the input's holes add (0 for a closed mesh).

    vertices (V,3) in the normalized frame, faces (F,3). Each boundary loop (edges of one face only) is capped by
    a fan around its centroid: area A, radius r = sqrt(A / pi); a flat disc's points lie r/3 from its rim on
    average, and the decoded mesh's samples are half of the Chamfer distance: F = 0.5 * sum(A r / 3) / area
    (stanford-bunny: 5 holes, 2.2 % of its area, F = 4.3e-4, where its fits stalled at 5.95e-4 with 19K points).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from tetweave_codec.fit.features import unique_rows
    from tetweave_codec.geometry.triangles import face_areas, triangle_cross

    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, _, counts = unique_rows(edges)
    rim = unique[counts == 1]
    if not len(rim):
        return 0.0
    n = len(vertices)
    graph = coo_matrix((np.ones(len(rim)), (rim[:, 0], rim[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    loop = label[rim[:, 0]]
    loops = np.unique(loop)
    area = float(face_areas(vertices, faces).sum())
    if area <= 0:
        return 0.0
    total = 0.0
    for k in loops:
        e = rim[loop == k]
        centre = vertices[np.unique(e)].mean(0)
        fan = np.stack([np.broadcast_to(centre, (len(e), 3)), vertices[e[:, 0]], vertices[e[:, 1]]], axis=1)
        cap = 0.5 * np.linalg.norm(triangle_cross(fan), axis=1).sum()
        total += cap * math.sqrt(cap / math.pi) / CAP_MEAN_DEPTH_DIVISOR
    return float(CHAMFER_SIDE_SHARE * total / area)
