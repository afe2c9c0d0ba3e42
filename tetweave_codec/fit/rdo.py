"""Rate-distortion optimized s symbols: after the late stage, pick each point's s symbol among a few near the
plain quantizer's to minimize D + lambda * R (encoder only; the decoder and the format are unchanged).

The plain quantizer rounds every s on its own. But the file stores s as the residual against a prediction from
already-coded neighbours (formats/predict.py), and an s only matters through the mesh vertices it places on its
active edges: a symbol one step off may cost little error and save bits (a residual nearer 0 or in a smaller
bucket).

* D (distortion) of a point's candidate symbol: over the active edges (i, j) of the decoded mesh incident to the
  point, the squared displacement of the edge's vertex along the mesh's vertex normal, from where the plain
  symbols put it (the late stage's optimum), weighted by the vertex's area share (a third of its faces' areas;
  the Chamfer distance samples surfaces by area). The other end of the edge keeps its plain symbol (the table D
  (N, 2W+1) is computed for all points and offsets at once). Candidates never change a symbol's sign, so the
  active edges, faces and topology are those of the plain symbols.
  Measured and not kept: D as the distance of the vertices to the *input* surface's tangent planes (so that
  symbols could also correct the fit): on spot 10 KB it lowers that distance by 25 % but raises the Chamfer
  distance by 6-60 %, because the late stage puts vertices off the input on purpose (flat triangles between
  vertices on a curved surface: on convex parts the best vertices lie outside it).
* R (rate) of a residual r: the s stream's cost, ``-log2 P(bucket) + sign bit + raw bits`` with
  ``bucket = bit_length(|r|)`` (formats/attributes.py), P from the bucket histogram of the previous pass.
* Greedy in decoding order: a point's prediction reads its earlier neighbours' *chosen* symbols, exactly as the
  decoder computes it, so every residual priced is the one coded.
* lambda: at high rate a uniform quantizer of step D_s gives D ~ G D_s^2 / 12 and R ~ h - log2 D_s per point, so
  the slope of the whole s stream is -dD/dR = ln 2 / 6 * mean(G) D_s^2; G D_s^2 is read off the table's second
  difference. LAMBDA_SCALE scales it (measured in benchmarks/results/rdo.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tetweave_codec.formats import predict
from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.attributes import R_BUCKETS
from tetweave_codec.geometry.delaunay import tetrahedralize
from tetweave_codec.geometry.marching_tets import marching_tets_numpy
from tetweave_codec.geometry.sh import degree_from_num_coeffs, sh_basis
from tetweave_codec.geometry.triangles import face_areas, face_normals

# Candidate symbols: the plain symbol k0 and k0 + d for 0 < |d| <= WINDOW (same sign as k0 only).
WINDOW = 3
# Multiplier of the high-rate slope lambda = ln 2 / 6 * mean(G D_s^2) (see module docstring). Measured on the
# shared meshes at 10 and 20 KB (benchmarks/results/rdo.md, same fit and steps): x1 changes a few bytes; x3 saves
# 0.13-0.26 % of the bytes for +0.08-0.31 % Chamfer; x10 saves 0.3-0.8 % for +0.6-3.8 %.
LAMBDA_SCALE = 3.0
# Greedy passes: each prices residuals with the bucket histogram of the previous pass's residuals.
PASSES = 2


@dataclass
class SymbolRdo:
    """What the RDO of one finalized point set needs, computed once (positions only).

    points (N,3) float64 in canonical order; tets (T,4), hull (H,3): their Delaunay tetrahedralization with the
    decoder's backend; nbr (N,K) int64 and beta (N,K) float64: the s predictor (-1 / 0 for missing neighbours);
    """

    points: np.ndarray
    tets: np.ndarray
    hull: np.ndarray
    nbr: np.ndarray
    beta: np.ndarray
    lambda_scale: float = LAMBDA_SCALE


def prepare(points: np.ndarray, cells: np.ndarray, backend: str) -> SymbolRdo:
    """The fixed part of the RDO for grid points (N,3) with cells (N,3) in canonical order."""
    tri = tetrahedralize(np.asarray(points, dtype=np.float64), backend)
    nbr, d2 = predict.causal_neighbors(cells)
    beta = predict.predictor_weights(cells, nbr, d2)
    return SymbolRdo(np.asarray(points, dtype=np.float64), tri.tets, tri.hull_faces, nbr, beta)


def optimize_s_symbols(rdo: SymbolRdo, s_sym: np.ndarray, s_step: float, c_val: np.ndarray) -> np.ndarray:
    """RD-optimized s symbols (N,) int64 from the plain ones `s_sym` (N,) (same signs), with s step `s_step` and
    the dequantized c values (N,q) the file stores."""
    k0 = np.asarray(s_sym, dtype=np.int64)
    table = distortion_table(rdo, k0, s_step, c_val)
    lam = rdo.lambda_scale * slope(table)
    if not lam > 0 and not np.any(table[:, WINDOW, None] > table):
        return k0  # no surface, or bits are free: the plain symbols are optimal
    chosen = k0
    bits = bucket_bits(residuals(rdo.nbr, rdo.beta, k0))
    for _ in range(PASSES):
        chosen = _greedy(rdo.nbr, rdo.beta, k0, table, lam, bits)
        bits = bucket_bits(residuals(rdo.nbr, rdo.beta, chosen))
    return chosen


def distortion_table(rdo: SymbolRdo, k0: np.ndarray, s_step: float, c_val: np.ndarray) -> np.ndarray:
    """D (N, 2 WINDOW + 1) float64: distortion of point i with symbol k0_i + d - WINDOW, the other ends of its
    edges at k0; inf where the candidate would change the symbol's sign."""
    n = len(k0)
    s0 = Q.dequantize_s(k0, s_step)
    mt = marching_tets_numpy(rdo.points, rdo.tets, s0, c_val, hull_faces=rdo.hull)
    table = np.zeros((n, 2 * WINDOW + 1))
    offsets = np.arange(-WINDOW, WINDOW + 1)
    cand = k0[:, None] + offsets[None, :]
    table[(cand < 0) != (k0[:, None] < 0)] = np.inf
    edge = mt.edges[:, 0] != mt.edges[:, 1]  # hull cap vertices sit on points: no s moves them
    if not edge.any():
        return table
    fa = face_areas(mt.vertices, mt.faces)
    area = np.zeros(len(mt.vertices))
    np.add.at(area, mt.faces.reshape(-1), np.repeat(fa / 3.0, 3))
    normal = np.zeros_like(mt.vertices)  # area-weighted vertex normals of the decoded mesh
    np.add.at(normal, mt.faces.reshape(-1), np.repeat(face_normals(mt.vertices, mt.faces) * fa[:, None], 3, axis=0))
    i, j = mt.edges[edge, 0], mt.edges[edge, 1]
    w, nrm = area[edge], normal[edge]
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    p_i, p_j = rdo.points[i], rdo.points[j]
    along = ((p_j - p_i) * nrm).sum(1)  # normal displacement per unit of t
    a_i, a_j = _direction_factors(rdo.points, c_val, i, j)
    si, sj = a_i * s0[i], a_j * s0[j]  # directional s: si < 0 <= sj
    t0 = _t(si, sj)
    for col, d in enumerate(offsets):
        # vertex = p_i + t (p_j - p_i), t = si / (si - sj); move one end by d steps, the other stays
        si_d = a_i * (s0[i] + d * s_step)
        sj_d = a_j * (s0[j] + d * s_step)
        cost_i = w * (along * (_t(si_d, sj) - t0)) ** 2
        cost_j = w * (along * (_t(si, sj_d) - t0)) ** 2
        table[:, col] += np.bincount(i, cost_i, minlength=n) + np.bincount(j, cost_j, minlength=n)
    return table


def _t(si: np.ndarray, sj: np.ndarray) -> np.ndarray:
    denom = si - sj
    return np.where(denom != 0, si / np.where(denom != 0, denom, 1.0), 0.5)


def _direction_factors(points, c, i, j) -> tuple[np.ndarray, np.ndarray]:
    """(1 + tanh(SH)) of end i towards j and of end j towards i (ones without SH)."""
    if c is None or c.shape[-1] == 0:
        return np.ones(len(i)), np.ones(len(i))
    degree = degree_from_num_coeffs(int(c.shape[-1]))
    d = points[j] - points[i]
    length = np.sqrt((d * d).sum(-1, keepdims=True))
    d = d / np.where(length > 0, length, 1.0)
    sh_i = (sh_basis(d, degree) * c[i]).sum(1)
    sh_j = (sh_basis(-d, degree) * c[j]).sum(1)
    return 1.0 + np.tanh(sh_i), 1.0 + np.tanh(sh_j)


def slope(table: np.ndarray) -> float:
    """The high-rate lambda, ln 2 / 6 * mean over points of G D_s^2 = (D(+1) + D(-1) - 2 D(0)) / 2, from the
    points whose three middle candidates are all allowed."""
    mid = table[:, WINDOW - 1 : WINDOW + 2]
    ok = np.isfinite(mid).all(1)
    if not ok.any():
        return 0.0
    g = np.maximum(0.5 * (mid[ok, 0] + mid[ok, 2] - 2.0 * mid[ok, 1]), 0.0)
    return math.log(2.0) / 6.0 * float(g.sum()) / len(table)


def residuals(nbr: np.ndarray, beta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Prediction residuals (N,) int64 of symbols k (N,) with the predictor nbr, beta (as predict.residuals)."""
    u = k.astype(np.float64) + 0.5
    acc = np.zeros(len(k))
    for j in range(nbr.shape[1]):
        acc = np.where(nbr[:, j] >= 0, acc + beta[:, j] * u[np.maximum(nbr[:, j], 0)], acc)
    lim = float(Q.S_SYMBOL_LIMIT)
    return k - np.floor(np.clip(acc, -lim, lim - 1)).astype(np.int64)


def bucket_bits(residual: np.ndarray) -> np.ndarray:
    """Bits (R_BUCKETS,) of a residual's bucket, sign and raw bits, the buckets priced by their frequencies in
    `residual` (an unseen bucket costs as if seen once)."""
    e = _bit_length(np.abs(residual))
    counts = np.bincount(e, minlength=R_BUCKETS)[:R_BUCKETS].astype(np.float64)
    counts = np.maximum(counts, 1.0)
    buckets = np.arange(R_BUCKETS)
    return -np.log2(counts / counts.sum()) + (buckets > 0) + np.maximum(buckets - 1, 0)


def _bit_length(m: np.ndarray) -> np.ndarray:
    return np.frexp(np.asarray(m, dtype=np.float64))[1].astype(np.int64)


def _greedy(nbr, beta, k0, table, lam, bucket_cost) -> np.ndarray:
    """One pass in decoding order; returns the chosen symbols (N,) int64."""
    n = len(k0)
    idx_l = np.where(nbr >= 0, nbr, n).tolist()
    beta_l = beta.tolist()
    k0_l = k0.tolist()
    cost_l = table.tolist()
    bits = bucket_cost.tolist()
    lo, hi = -float(Q.S_SYMBOL_LIMIT), float(Q.S_SYMBOL_LIMIT - 1)
    floor = math.floor
    u = [0.0] * (n + 1)
    out = [0] * n
    span = range(-WINDOW, WINDOW + 1)
    for i, row_idx, row_beta, k, costs in zip(range(n), idx_l, beta_l, k0_l, cost_l, strict=True):
        a = 0.0
        for jj, b in zip(row_idx, row_beta, strict=True):  # the decoder's order of the slots
            a = a + b * u[jj]
        pred = floor(lo if a < lo else hi if a > hi else a)
        best, best_k = math.inf, k
        for col, d in enumerate(span):
            dist = costs[col]
            if dist == math.inf:
                continue
            r = k + d - pred
            e = abs(r).bit_length()
            total = dist + lam * (bits[e] if e < len(bits) else 64.0)
            if total < best or (total == best and abs(d) < abs(best_k - k)):
                best, best_k = total, k + d
        out[i] = best_k
        u[i] = best_k + 0.5
    return np.asarray(out, dtype=np.int64)
