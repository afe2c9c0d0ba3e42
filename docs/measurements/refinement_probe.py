"""Issue 40, stage 1: a measured prototype of a refinement layer on the decoded TetWeave surface.

Experiment scaffolding, outside the package on purpose (no format, codec or CLI change). A base `.tw` file is
decoded; its surface (the file's whole filtered output, `--source full`, or the Taubin-smoothed control mesh with
the file's Loop levels replaced by ours, `--source control`) is subdivided L times (`--rule loop`: the decoder's
Loop rule of geometry/subdivision.py, with the file's crease rules when it keeps creases; `--rule midpoint`), and
every vertex a level adds (and, with `--even`, every old vertex too) gets one scalar displacement along the unit
vertex normal of the subdivided surface:

* Target: where the normal line through the predicted vertex meets the input surface, found by Newton steps on
  the tangent plane of the input's closest point (a cheaper proxy for a two-sided ray cast: exact where the input
  is locally flat); targets farther than `BOUND_EDGES` mean edge lengths of the level are 0.
* Predictive (closed loop): a level subdivides the already displaced, *quantized* parent, so its targets are the
  residuals of everything coded before.
* Dead-zone uniform quantization, one step per level (step_l = step_1 * gain^(l-1)), then rate-distortion
  optimisation per coefficient: k in {0, round, round - 1} minimising a_i (e_i - k step)^2 + lambda * bits(k),
  a_i the vertex's area (Chamfer is area-weighted), lambda = kappa * step^2 * mean area of the level, bits from the
  level's own models (two passes).
* Entropy coding through constriction, like formats/entropy.py: per coded vertex a significance bit in one of
  9 contexts (parent significance: how many of the edge's two ends were significant at the level before, 0-2,
  times a curvature bucket: |Loop position - edge midpoint| along the normal, in steps: the decoder knows both),
  a sign bit in 2 contexts (the sign of that same curvature offset), |k| - 1 through a stored histogram (escape +
  Elias-gamma raw bits beyond it). Even vertices, with `--even`, have their own 9 contexts. Per level a header:
  step (float32), stream size (uint32), the context bytes, the sign bytes, the histogram (1 + A bytes); each level
  its own stream (a file cut after any level decodes).
* Self-intersections: after each level, `geometry.intersections.self_intersecting_faces`; the coefficients of the
  vertices of crossing faces are zeroed (counted) until none cross; where crossing faces have no coefficient left,
  the decoder's own fallback (`surface_filter.restore_crossings`, run by the decoder too) puts their vertices to
  the level's midpoint positions (counted; the parent surface itself).

`decode_layer` is the decoder side (it rebuilds the mesh from the coded bytes, and is what "decode time of the
layer" times); the encoder checks that it reproduces the encoder's mesh exactly.

Chamfer distance and normal consistency are those of `tetweave bench` (tetweave_codec.metrics.fidelity: 200,000
area-weighted samples per mesh, seed 0, the input's normalized frame), computed with the same sampling, tree and
formulas, without the edge metrics this probe does not report.

Commands (from the repository root):

    python docs/measurements/refinement_probe.py today --out R.jsonl
    python docs/measurements/refinement_probe.py run --mesh spot --budget 10240 --base FILE.tw [options] --out R.jsonl
    python docs/measurements/refinement_probe.py table R.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tetweave_codec.decoder import _extract, decode_detailed
from tetweave_codec.formats.entropy import (
    Reader,
    Writer,
    binary_weight_rows,
    fit_binary,
    fit_histogram,
    histogram_model,
    histogram_weights,
)
from tetweave_codec.geometry.closest import SurfaceTree
from tetweave_codec.geometry.intersections import self_intersecting_faces
from tetweave_codec.geometry.smoothing import crease_edges, mesh_edges, neighbours_along_creases, taubin
from tetweave_codec.geometry.subdivision import _apply_level, loop_level
from tetweave_codec.geometry.surface_filter import restore_crossings
from tetweave_codec.geometry.triangles import face_areas, face_cross, face_normals, sample_surface
from tetweave_codec.meshio import load_mesh
from tetweave_codec.metrics.fidelity import normalization, to_frame

MESHES = ("fandisk", "igea", "spot", "stanford-bunny")
BUDGETS = (5120, 10240, 20480, 40960)
N_SAMPLES = 200_000  # tetweave bench's --samples
SEED = 0  # tetweave bench's --seed
BOUND_EDGES = 2.0  # a target farther than this many mean edge lengths of its level is 0 (no hit within the bound)
NEWTON_STEPS = 2  # tangent-plane steps of the normal-line target after the closest point
MIN_COS = 0.3  # a Newton step needs the input's face to be within ~72 degrees of the normal line
CURV_EDGES = (0.5, 2.0)  # curvature buckets: |Loop - midpoint| along the normal, in quantization steps
MAG_ALPHABET = 16  # |k| - 1 symbols; the last one escapes to Elias-gamma raw bits
MAX_CHECKS = 16  # self-intersection rounds per level
HEADER_FIXED = 4 + 4 + 1  # step float32, stream size uint32, histogram size byte
LAST_SPLIT: dict = {}  # estimated bits of the last coded level: significance, sign, magnitude


@dataclass
class Config:
    source: str = "control"  # control | full
    rule: str = "loop"  # loop | midpoint
    levels: int = 2
    gain: float = 1.0  # step_l = step_1 * gain^(l-1)
    kappa: float = 0.12  # lambda = kappa * step^2 * mean vertex area of the level
    even: bool = False  # old vertices get displacements too
    distortion: str = "l2"  # l2: lambda = kappa step^2 mean area; l1: lambda = kappa step mean area


# ------------------------------------------------------------------------------------------------ metric


class Input:
    """The input mesh in its normalized frame (the metric's), its samples and its closest-point tree."""

    def __init__(self, path: str):
        v, f = load_mesh(path)
        self.scale, self.offset = normalization(v)
        self.vertices = to_frame(v, self.scale, self.offset)
        self.faces = np.asarray(f, dtype=np.int64)
        self.normals = face_normals(self.vertices, self.faces)
        self.tree = SurfaceTree(self.vertices, self.faces)
        self.points, self.sample_faces = sample_surface(self.vertices, self.faces, N_SAMPLES, SEED)


def metrics(inp: Input, v: np.ndarray, f: np.ndarray) -> dict:
    """Chamfer distance and normal consistency of mesh v (V,3), f (F,3) (normalized frame) against the input,
    as tetweave_codec.metrics.fidelity.fidelity computes them (same samples, same tree, same formulas)."""
    tree = SurfaceTree(v, f)
    normals = face_normals(v, f)
    pts, pf = sample_surface(v, f, N_SAMPLES, SEED)
    sq_ab, face_ab, _ = tree.query(inp.points)
    sq_ba, face_ba, _ = inp.tree.query(pts)
    d_ab, d_ba = np.sqrt(np.maximum(sq_ab, 0)), np.sqrt(np.maximum(sq_ba, 0))
    cos = np.abs(
        np.concatenate(
            [
                np.einsum("nd,nd->n", inp.normals[inp.sample_faces], normals[face_ab]),
                np.einsum("nd,nd->n", normals[pf], inp.normals[face_ba]),
            ]
        )
    )
    return {"chamfer": float(0.5 * (d_ab.mean() + d_ba.mean())), "normal_consistency": float(cos.mean())}


# ------------------------------------------------------------------------------------------------ base


@dataclass
class Base:
    vertices: np.ndarray  # (V,3) control mesh, normalized frame of the input
    faces: np.ndarray  # (F,3)
    creases: np.ndarray | None  # (E,) bool over the first Loop level's edges, or None
    file_bytes: int
    file_faces: int


def load_base(path: str, inp: Input, source: str) -> Base:
    """The surface a refinement layer starts from: the file's output (`full`) or its smoothed, unsubdivided
    control mesh (`control`), in the input's normalized frame; the crease flags when its faces are the extracted
    ones and the file keeps creases."""
    data = Path(path).read_bytes()
    res = decode_detailed(data)
    tw = res.container
    if source == "full" and tw.subdivision > 0:
        v = to_frame(res.closed_vertices, inp.scale, inp.offset)
        return Base(v, res.closed_faces, None, len(data), len(res.faces))
    ex = _extract(tw.points, tw.s, tw.c, tw.sh_degree, res.backend, {}, time.perf_counter, 0, 0)
    v0 = to_frame(ex.vertices * float(tw.scale) + tw.offset, inp.scale, inp.offset)
    f0 = ex.faces
    edges = mesh_edges(f0, len(v0), closed=True)
    smooth_edges, creases = edges, None
    if tw.creases:
        sharp = crease_edges(v0, f0, edges)
        smooth_edges = neighbours_along_creases(edges, sharp, len(v0))
        creases = sharp[edges[:, 0] < edges[:, 1]]
    v = taubin(v0, f0, tw.smoothing, edges=smooth_edges) if tw.smoothing > 0 else v0
    v, _, gave_up = restore_crossings(v, v0, f0)
    if gave_up:
        v = v0
    return Base(v, f0, creases, len(data), len(res.faces))


# ------------------------------------------------------------------------------------------------ geometry


def vertex_normals_areas(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted unit vertex normals (V,3) and vertex areas (V,) (a third of the adjacent faces' areas)."""
    cross = face_cross(v, f)
    n = np.zeros_like(v)
    for k in range(3):
        for a in range(3):
            n[:, a] += np.bincount(f[:, k], weights=cross[:, a], minlength=len(v))
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    n = n / np.maximum(norm, 1e-300)
    area = np.bincount(f.reshape(-1), weights=np.repeat(face_areas(v, f) / 3.0, 3), minlength=len(v))
    return n, area


def normal_targets(inp: Input, p: np.ndarray, n: np.ndarray, bound: float) -> np.ndarray:
    """Signed distance (m,) along unit normals n (m,3) from points p (m,3) to the input surface: the closest
    point's offset along n, then NEWTON_STEPS steps to the input's tangent plane along the normal line; 0 where
    the result is farther than `bound`."""
    _, face, c = inp.tree.query(p)
    e = np.einsum("nd,nd->n", c - p, n)
    for _ in range(NEWTON_STEPS):
        q = p + e[:, None] * n
        _, face, c = inp.tree.query(q)
        ns = inp.normals[face]
        cos = np.einsum("nd,nd->n", n, ns)
        ok = np.abs(cos) > MIN_COS
        step = np.where(ok, np.einsum("nd,nd->n", c - q, ns) / np.where(ok, cos, 1.0), 0.0)
        e = e + step
    e[~np.isfinite(e) | (np.abs(e) > bound)] = 0.0
    return e


@dataclass
class LevelGeometry:
    """What encoder and decoder both know about a level before its coefficients: the subdivided faces, the
    predicted vertices, their normals, which are coded, the context inputs."""

    faces: np.ndarray
    predicted: np.ndarray  # (V',3)
    midpoint: np.ndarray  # (V',3) the parent surface itself on these faces (fallback of crossing faces)
    normals: np.ndarray  # (V',3)
    areas: np.ndarray  # (V',)
    coded: np.ndarray  # (m,) vertex ids with a coefficient, ascending
    parent_sig: np.ndarray  # (m,) 0..2
    curv: np.ndarray  # (m,) signed |Loop - midpoint| along the normal
    even: np.ndarray  # (m,) bool
    edge_len: float
    topology: object


def level_geometry(v, f, parent_topology, creases, cfg: Config, prev_sig: np.ndarray | None) -> LevelGeometry:
    """Subdivide the (displaced) parent v (V,3), f (F,3) once by cfg.rule; prev_sig (V,) bool: significance of
    the parent's coefficients (None at the first level)."""
    if parent_topology is None:
        top = loop_level(f, len(v), creases=creases)
    else:
        top = loop_level(f, len(v), parent=parent_topology)
    loop_v = _apply_level(v, top, midpoint=False)
    mid_v = _apply_level(v, top, midpoint=True)
    pred = loop_v if cfg.rule == "loop" else mid_v
    normals, areas = vertex_normals_areas(pred, top.faces)
    n_old = len(v)
    coded = np.arange(len(pred)) if cfg.even else np.arange(n_old, len(pred))
    sig = np.zeros(n_old, dtype=np.int64) if prev_sig is None else prev_sig.astype(np.int64)
    ends = np.empty((len(coded), 2), dtype=np.int64)
    is_even = coded < n_old
    ends[is_even] = coded[is_even, None]
    ends[~is_even] = top.edges[coded[~is_even] - n_old]
    parent_sig = sig[ends[:, 0]] + sig[ends[:, 1]]
    curv = np.einsum("nd,nd->n", loop_v[coded] - mid_v[coded], normals[coded])
    e = top.edges
    edge_len = float(np.linalg.norm(pred[top.faces[:, 0]] - pred[top.faces[:, 1]], axis=1).mean())
    del e
    return LevelGeometry(top.faces, pred, mid_v, normals, areas, coded, parent_sig, curv, is_even, edge_len, top)


def contexts(geo: LevelGeometry, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Significance context (m,) in 0..17 and sign context (m,) in 0..1 of the coded vertices."""
    bucket = np.searchsorted(np.asarray(CURV_EDGES) * step, np.abs(geo.curv), side="right")
    ctx = geo.parent_sig * 3 + bucket + 9 * geo.even
    return ctx.astype(np.int64), (geo.curv > 0).astype(np.int64)


# ------------------------------------------------------------------------------------------------ coding


def _symbol_bits(p1: np.ndarray, ctx: np.ndarray, k: np.ndarray, mag_bits: np.ndarray) -> np.ndarray:
    """Estimated bits of coefficients k (m,) given P(significant) per context and bits per |k|-1 symbol."""
    p = p1[ctx]
    mag = np.minimum(np.abs(k) - 1, MAG_ALPHABET - 1)
    big = np.maximum(np.abs(k) - MAG_ALPHABET + 1, 1).astype(np.float64)
    esc = np.where(np.abs(k) - 1 >= MAG_ALPHABET - 1, 2 * np.floor(np.log2(big)) + 1 + 5, 0)
    sig_bits = -np.log2(np.where(k != 0, p, 1 - p))
    return sig_bits + np.where(k != 0, 1.0 + mag_bits[np.maximum(mag, 0)] + esc, 0.0)


def rdo_quantize(
    e: np.ndarray, a: np.ndarray, ctx: np.ndarray, step: float, lam: float, distortion: str = "l2"
) -> np.ndarray:
    """Coefficients k (m,) int64 for targets e (m,), areas a (m,): minimise a d(e - k step) + lam bits(k) over
    k in {0, round(e/step), round - 1 (toward 0)}, with models refitted from the previous pass (two passes).
    d is the square (distortion "l2") or the absolute value ("l1": Chamfer is a mean distance, not a squared
    one, so a few large targets matter less than many small ones)."""

    def d(x):
        return x**2 if distortion == "l2" else np.abs(x)

    r = np.rint(np.abs(e) / step).astype(np.int64)
    s = np.sign(e).astype(np.int64)
    k = s * r
    for _ in range(2):
        n_ctx = 18
        nz = np.bincount(ctx[k != 0], minlength=n_ctx) + 0.5
        tot = np.bincount(ctx, minlength=n_ctx) + 1.0
        p1 = np.clip(nz / tot, 1 / 256, 255 / 256)
        mags = np.minimum(np.abs(k[k != 0]) - 1, MAG_ALPHABET - 1)
        hist = np.bincount(mags, minlength=MAG_ALPHABET) + 0.5
        mag_bits = -np.log2(hist / hist.sum())
        best_k, best_j = np.zeros_like(k), a * d(e) + lam * _symbol_bits(p1, ctx, np.zeros_like(k), mag_bits)
        for cand in (r, np.maximum(r - 1, 0)):
            kk = s * cand
            j = a * d(e - kk * step) + lam * _symbol_bits(p1, ctx, kk, mag_bits)
            better = j < best_j
            best_k[better], best_j[better] = kk[better], j[better]
        k = best_k
    return k


def encode_level(k: np.ndarray, ctx: np.ndarray, sctx: np.ndarray, step: float, n_ctx: int) -> bytes:
    """One level's bytes: header (step, stream size, context / sign / histogram model bytes) and its stream."""
    sig = (k != 0).astype(np.int64)
    ctx_bytes = np.array([fit_binary(sig[ctx == c]) if (ctx == c).any() else 128 for c in range(n_ctx)])
    neg = (k < 0).astype(np.int64)
    sign_sel = [(sctx == c) & (k != 0) for c in range(2)]
    sign_bytes = np.array([fit_binary(neg[sel]) if sel.any() else 128 for sel in sign_sel])
    m = np.abs(k[k != 0]) - 1
    sym = np.minimum(m, MAG_ALPHABET - 1)
    alphabet = int(max(2, sym.max() + 1)) if len(sym) else 2
    hist = fit_histogram(sym, alphabet) if len(sym) else np.array([1, 1], np.uint8)
    w = Writer()
    w.encode_binary(sig, binary_weight_rows(ctx_bytes[ctx]))
    nzi = k != 0
    w.encode_binary(neg[nzi], binary_weight_rows(sign_bytes[sctx[nzi]]))
    if len(sym):
        w.encode(sym, histogram_model(hist))
        esc = m[sym == MAG_ALPHABET - 1] - (MAG_ALPHABET - 1) + 1  # >= 1: Elias gamma
        if len(esc):
            nb = np.floor(np.log2(esc)).astype(np.int64)
            w.encode_raw(nb, np.full(len(nb), 5))
            w.encode_raw(esc - (1 << nb), nb)
    stream = w.finish()
    sw = binary_weight_rows(sign_bytes[sctx[nzi]])
    LAST_SPLIT.clear()
    LAST_SPLIT.update(
        sig_bits=-float(
            np.log2(
                np.where(sig == 1, 1, 0) * binary_weight_rows(ctx_bytes[ctx])[:, 1] / 2**24
                + np.where(sig == 0, 1, 0) * binary_weight_rows(ctx_bytes[ctx])[:, 0] / 2**24
            ).sum()
        ),
        sign_bits=-float(np.log2((np.where(neg[nzi] == 1, sw[:, 1], sw[:, 0]) + 1) / 2**24).sum()),
        mag_bits=float(-np.log2((histogram_weights(hist)[sym] + 1) / 2**24).sum()) if len(sym) else 0.0,
    )
    header = struct.pack("<fIB", step, len(stream), len(hist))
    return header + bytes(ctx_bytes.astype(np.uint8)) + bytes(sign_bytes.astype(np.uint8)) + bytes(hist) + stream


def decode_level(data: bytes, at: int, geo_fn, n_ctx: int) -> tuple[np.ndarray, float, int, object]:
    """Inverse of `encode_level` at offset `at`; geo_fn(step) gives the level's geometry and contexts."""
    step, size, alphabet = struct.unpack_from("<fIB", data, at)
    at += HEADER_FIXED
    ctx_bytes = np.frombuffer(data, np.uint8, n_ctx, at).astype(np.int64)
    at += n_ctx
    sign_bytes = np.frombuffer(data, np.uint8, 2, at).astype(np.int64)
    at += 2
    hist = np.frombuffer(data, np.uint8, alphabet, at)
    at += alphabet
    geo, ctx, sctx = geo_fn(float(step))
    r = Reader(data[at : at + size], "refinement")
    at += size
    sig = r.decode_binary(binary_weight_rows(ctx_bytes[ctx]))
    nzi = sig != 0
    neg = r.decode_binary(binary_weight_rows(sign_bytes[sctx[nzi]]))
    sym = r.decode(histogram_model(hist), int(nzi.sum())) if nzi.any() else np.zeros(0, np.int64)
    m = sym.copy()
    escaped = sym == MAG_ALPHABET - 1
    if escaped.any():
        nb = r.decode_raw(np.full(int(escaped.sum()), 5))
        m[escaped] = (1 << nb) + r.decode_raw(nb) - 1 + (MAG_ALPHABET - 1)
    k = np.zeros(len(ctx), dtype=np.int64)
    k[nzi] = (m + 1) * np.where(neg == 1, -1, 1)
    _ = histogram_weights(hist)
    return k, float(step), at, geo


# ------------------------------------------------------------------------------------------------ layer


def apply_coefficients(geo: LevelGeometry, k: np.ndarray, step: float) -> np.ndarray:
    v = geo.predicted.copy()
    v[geo.coded] += (k * step)[:, None] * geo.normals[geo.coded]
    return v


def fix_crossings(geo: LevelGeometry, k: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Zero the coefficients of vertices of crossing faces until no crossing face has a coefficient left (at
    most MAX_CHECKS checks), then what the decoder does too: `surface_filter.restore_crossings` of the result
    against the level's midpoint positions (the parent surface itself). Returns (vertices, k, zeroed,
    restored)."""
    k = k.copy()
    v = apply_coefficients(geo, k, step)
    pos = np.full(len(v), -1, dtype=np.int64)
    pos[geo.coded] = np.arange(len(geo.coded))
    zeroed = 0
    interest = None
    for _ in range(MAX_CHECKS):
        bad = self_intersecting_faces(v, geo.faces, only=interest)
        if not bad.any():
            return v, k, zeroed, 0
        idx = pos[np.unique(geo.faces[bad])]
        idx = idx[idx >= 0]
        nonzero = idx[k[idx] != 0]
        if not len(nonzero):
            break
        k[nonzero] = 0
        zeroed += len(nonzero)
        changed = np.zeros(len(v), dtype=bool)
        changed[geo.coded[nonzero]] = True
        v = apply_coefficients(geo, k, step)
        interest = changed[geo.faces].any(axis=1) | bad
    v, restored, _ = restore_crossings(v, geo.midpoint, geo.faces)
    return v, k, zeroed, restored


def target_statistics(e: np.ndarray, a: np.ndarray) -> dict:
    """How sparse a level's targets e (m,) are, with vertex areas a (m,): kurtosis (3 for a Gaussian, large for
    a few big coefficients among many small), the share of the area-weighted squared error in the 10 % largest,
    the share of vertices without a target (no hit within the bound)."""
    w = a * e**2
    top = np.sort(w)[::-1][: max(1, len(w) // 10)]
    m2 = float(np.mean(e**2))
    return {
        "mean_abs_target": float(np.mean(np.abs(e))),
        "kurtosis": float(np.mean(e**4) / m2**2) if m2 > 0 else 0.0,
        "top10_energy": float(top.sum() / max(w.sum(), 1e-300)),
        "no_target": float(np.mean(e == 0)),
    }


def encode_layer(inp: Input, base: Base, cfg: Config, step1: float, keep_levels: bool = False) -> dict:
    """Encode the refinement layer of `base` with first-level step `step1`. Returns bytes per level, the final
    mesh, counts of zeroed / restored vertices and per-level statistics."""
    v, f = base.vertices, base.faces
    top, sig = None, None
    n_ctx = 18 if cfg.even else 9
    out = {"level_bytes": [], "zeroed": 0, "restored": 0, "levels": [], "data": b""}
    for level in range(cfg.levels):
        step = float(np.float32(step1 * cfg.gain**level))  # as the header stores it
        geo = level_geometry(v, f, top, base.creases if top is None else None, cfg, sig)
        p = geo.predicted[geo.coded]
        nrm = geo.normals[geo.coded]
        e = normal_targets(inp, p, nrm, BOUND_EDGES * geo.edge_len)
        a = geo.areas[geo.coded]
        ctx, sctx = contexts(geo, step)
        lam = cfg.kappa * step ** (2 if cfg.distortion == "l2" else 1) * float(a.mean())
        k = rdo_quantize(e, a, ctx, step, lam, cfg.distortion)
        v_new, k, zeroed, restored = fix_crossings(geo, k, step)
        data = encode_level(k, ctx, sctx, step, n_ctx)
        out["data"] += data
        out["level_bytes"].append(len(data))
        out["zeroed"] += zeroed
        out["restored"] += restored
        nz = k != 0
        out["levels"].append(
            {
                "coded": int(len(k)),
                "significant": int(nz.sum()),
                "bits_per_significant": 8.0 * len(data) / max(1, int(nz.sum())),
                "step": step,
                "rms_target": float(np.sqrt(np.mean(e**2))),
                "rms_residual": float(np.sqrt(np.mean((e - k * step) ** 2))),
                "edge_len": geo.edge_len,
                **target_statistics(e, a),
                **LAST_SPLIT,
            }
        )
        sig = np.zeros(len(v_new), dtype=bool)
        sig[geo.coded[nz]] = True
        v, f, top = v_new, geo.faces, geo.topology
    out["vertices"], out["faces"] = v, f
    return out


def decode_layer(base: Base, data: bytes, cfg: Config) -> tuple[np.ndarray, np.ndarray]:
    """The decoder: base control mesh + layer bytes -> refined mesh, checking each level for crossings."""
    v, f = base.vertices, base.faces
    top, sig, at = None, None, 0
    n_ctx = 18 if cfg.even else 9
    for _ in range(cfg.levels):

        def geo_fn(step, v=v, f=f, top=top, sig=sig):
            geo = level_geometry(v, f, top, base.creases if top is None else None, cfg, sig)
            ctx, sctx = contexts(geo, step)
            return geo, ctx, sctx

        k, step, at, geo = decode_level(data, at, geo_fn, n_ctx)
        # the encoder zeroed the coefficients of crossing faces; what still crosses goes to the parent surface
        v_new, _, _ = restore_crossings(apply_coefficients(geo, k, step), geo.midpoint, geo.faces)
        sig = np.zeros(len(v_new), dtype=bool)
        sig[geo.coded[k != 0]] = True
        v, f, top = v_new, geo.faces, geo.topology
    return v, f


def match_budget(inp: Input, base: Base, cfg: Config, target: int, tol: float = 0.03) -> tuple[float, dict, int]:
    """First-level step whose layer makes base + layer land in [1 - tol, 1] x target bytes (secant on log step
    against log bytes). Returns (step, encode result, evaluations)."""
    layer_target = target - base.file_bytes
    if layer_target <= 0:
        raise ValueError("base is larger than the budget")
    lo_t = (1 - tol) * target - base.file_bytes
    bv, bf = base.vertices, base.faces
    step = 0.1 * float(np.mean(np.linalg.norm(bv[bf[:, 0]] - bv[bf[:, 1]], axis=1)))
    tried = []
    best = None
    for it in range(9):
        res = encode_layer(inp, base, cfg, step)
        size = sum(res["level_bytes"])
        tried.append((step, size))
        if size <= layer_target and (best is None or size > best[1]):
            best = (step, size, res)
        if lo_t <= size <= layer_target:
            return step, res, it + 1
        below = [t for t in tried if t[1] <= layer_target]
        above = [t for t in tried if t[1] > layer_target]
        if below and above:
            s_lo = min(below, key=lambda t: t[0])  # smallest step still under the target
            s_hi = max(above, key=lambda t: t[0])
            x0, y0 = math.log(s_hi[0]), math.log(s_hi[1])
            x1, y1 = math.log(s_lo[0]), math.log(max(s_lo[1], 1))
            y = math.log(0.5 * (lo_t + layer_target))
            x = x0 + (y - y0) * (x1 - x0) / (y1 - y0) if y1 != y0 else 0.5 * (x0 + x1)
            x = min(max(x, min(x0, x1) + 0.1 * abs(x1 - x0)), max(x0, x1) - 0.1 * abs(x1 - x0))
            step = math.exp(x)
        else:
            # bytes fall roughly as log(1/step) per coefficient: move by the ratio, at most 4x per step
            ratio = (size / (0.5 * (lo_t + layer_target))) if size > 0 else 0.25
            step *= min(4.0, max(0.25, ratio ** (1.5)))
    if best is None:
        raise RuntimeError("no step fits the budget")
    return best[0], best[2], len(tried)


# ------------------------------------------------------------------------------------------------ commands


def today_file(mesh: str, budget: int) -> str:
    return f"benchmarks/results/files/{mesh}/size-{budget}-sh-auto.tw"


def cmd_today(args) -> None:
    rows = []
    for mesh in args.meshes.split(","):
        inp = Input(f"../shared/meshes/{mesh}.ply")
        for budget in BUDGETS:
            path = today_file(mesh, budget)
            res = decode_detailed(Path(path).read_bytes())
            v = to_frame(res.vertices, inp.scale, inp.offset)
            m = metrics(inp, v, res.faces)
            rows.append(
                {
                    "kind": "today",
                    "mesh": mesh,
                    "budget": budget,
                    "bytes": Path(path).stat().st_size,
                    "faces": len(res.faces),
                    **m,
                }
            )
            print(json.dumps(rows[-1]), flush=True)
    with open(args.out, "a") as fh:
        for r in rows:
            fh.write(json.dumps(r) + "\n")


def cmd_run(args) -> None:
    inp = None  # loaded on the first configuration not in the output file yet
    configs = []
    for source in args.source.split(","):
        for rule in args.rule.split(","):
            for levels in [int(x) for x in args.levels.split(",")]:
                for gain in [float(x) for x in args.gain.split(",")]:
                    for kappa in [float(x) for x in args.kappa.split(",")]:
                        for dist in args.distortion.split(","):
                            configs.append(Config(source, rule, levels, gain, kappa, args.even, dist))
    done = set()  # (base, configuration) already in the output file: a rerun resumes
    if Path(args.out).exists():
        for line in Path(args.out).read_text().splitlines():
            r = json.loads(line)
            if r.get("kind") == "refined" and r["mesh"] == args.mesh and r["budget"] == args.budget:
                done.add((r["base"], *(r.get(f, d) for f, d in asdict(Config()).items())))
    for base_path in args.base.split(","):
        bases = {}
        for cfg in configs:
            if (Path(base_path).name, *asdict(cfg).values()) in done:
                continue
            if inp is None:
                inp = Input(f"../shared/meshes/{args.mesh}.ply")
            if cfg.source not in bases:
                bases[cfg.source] = load_base(base_path, inp, cfg.source)
            base = bases[cfg.source]
            t0 = time.process_time()
            try:
                step, res, evals = match_budget(inp, base, cfg, args.budget)
            except (ValueError, RuntimeError) as exc:
                print(f"{base_path} {cfg}: {exc}", file=sys.stderr)
                continue
            enc_cpu = time.process_time() - t0
            t1 = time.process_time()
            dv, df = decode_layer(base, res["data"], cfg)
            dec_cpu = time.process_time() - t1
            if not (np.array_equal(df, res["faces"]) and np.array_equal(dv, res["vertices"])):
                print(f"{base_path} {cfg}: decoder mismatch", file=sys.stderr)
            m = metrics(inp, res["vertices"], res["faces"])
            row = {
                "kind": "refined", "mesh": args.mesh, "budget": args.budget, "base": Path(base_path).name,
                "base_bytes": base.file_bytes, "level_bytes": res["level_bytes"],
                "bytes": base.file_bytes + sum(res["level_bytes"]), "faces": len(res["faces"]),
                "zeroed": res["zeroed"], "restored": res["restored"], "step": step, "evals": evals,
                "encode_cpu_s": enc_cpu, "decode_layer_cpu_s": dec_cpu, "levels_stats": res["levels"],
                **asdict(cfg), **m,
            }  # fmt: skip
            print(json.dumps({k: v for k, v in row.items() if k != "levels_stats"}), flush=True)
            with open(args.out, "a") as fh:
                fh.write(json.dumps(row) + "\n")


IDEAL_STEP = 1e-7  # a step far below every target: the layer's coefficients are (almost) exact
ZERO_RATE_STEP = 1e3  # a step far above every target: no coefficient, the subdivided surface alone


def cmd_analyse(args) -> None:
    """Why the layer costs what it does, on one base: the subdivided surface without coefficients, with exact
    coefficients (the most L levels of normal displacement can give, at any rate), the targets' statistics, and
    the layer's own rate-distortion curve (layer bytes = the given fractions of the base's)."""
    inp = Input(f"../shared/meshes/{args.mesh}.ply")
    base = load_base(args.base, inp, args.source)
    row0 = {"kind": "analyse", "mesh": args.mesh, "base": Path(args.base).name, "base_bytes": base.file_bytes}
    for levels in [int(x) for x in args.levels.split(",")]:
        cfg = Config(args.source, args.rule, levels, args.gain, args.kappa, args.even)
        for name, step in (("zero_rate", ZERO_RATE_STEP), ("exact", IDEAL_STEP)):
            try:
                res = encode_layer(inp, base, cfg, step)
            except RuntimeError as exc:  # the crossing test cannot bound its work on the largest surfaces
                print(f"{name} L={levels}: {exc}", file=sys.stderr)
                continue
            m = metrics(inp, res["vertices"], res["faces"])
            row = {**row0, "what": name, **asdict(cfg), "faces": len(res["faces"]), "zeroed": res["zeroed"],
                   "levels_stats": res["levels"], **m}  # fmt: skip
            print(json.dumps(row), flush=True)
            with open(args.out, "a") as fh:
                fh.write(json.dumps(row) + "\n")
    cfg = Config(args.source, args.rule, args.curve_levels, args.gain, args.kappa, args.even)
    for frac in [float(x) for x in args.fractions.split(",")]:
        target = int(base.file_bytes * (1 + frac))
        try:
            step, res, _ = match_budget(inp, base, cfg, target)
        except (ValueError, RuntimeError) as exc:
            print(f"curve {frac}: {exc}", file=sys.stderr)
            continue
        m = metrics(inp, res["vertices"], res["faces"])
        row = {**row0, "what": "curve", **asdict(cfg), "layer_fraction": frac, "level_bytes": res["level_bytes"],
               "bytes": base.file_bytes + sum(res["level_bytes"]), "faces": len(res["faces"]), "step": step,
               "levels_stats": res["levels"], **m}  # fmt: skip
        print(json.dumps(row), flush=True)
        with open(args.out, "a") as fh:
            fh.write(json.dumps(row) + "\n")


def _entropy(p):
    p = np.clip(p, 1e-12, 1 - 1e-12)
    return -(p * np.log2(p) + (1 - p) * np.log2(1 - p))


def _conditional_entropy(bits: np.ndarray, given: np.ndarray) -> float:
    """H(bits | given) in bits per symbol, from the empirical frequencies (an ideal adaptive coder's rate)."""
    return float(sum((given == g).mean() * _entropy(bits[given == g].mean()) for g in np.unique(given)))


def cmd_contexts(args) -> None:
    """How much any context could save on level 1's significance map: its entropy alone, given the probe's
    contexts, and given the significance of the 4 other new vertices of the edge's two faces (not causal: an
    oracle no real coder reaches, so a bound), at plain rounding with the given step; and how often the sign of a
    significant coefficient is the sign of the Loop-minus-midpoint offset (the sign context)."""
    inp = Input(f"../shared/meshes/{args.mesh}.ply")
    base = load_base(args.base, inp, "control")
    cfg = Config("control", "loop", 1)
    geo = level_geometry(base.vertices, base.faces, None, base.creases, cfg, None)
    e = normal_targets(inp, geo.predicted[geo.coded], geo.normals[geo.coded], BOUND_EDGES * geo.edge_len)
    ctx, _ = contexts(geo, args.step)
    sig = np.rint(e / args.step) != 0
    # level 1's faces: every parent face's middle child (4f + 3) lists its three new vertices
    middle = geo.faces[3::4] - len(base.vertices)
    s3 = sig[middle]
    neighbours = np.zeros(len(sig), dtype=np.int64)
    for j in range(3):
        np.add.at(neighbours, middle[:, j], s3.sum(axis=1) - s3[:, j])
    row = {
        "kind": "contexts", "mesh": args.mesh, "base": Path(args.base).name, "step": args.step,
        "coded": len(sig), "significant": float(sig.mean()), "h_alone": float(_entropy(sig.mean())),
        "h_probe_contexts": _conditional_entropy(sig, ctx),
        "h_oracle_neighbours": _conditional_entropy(sig, neighbours),
        "h_both": _conditional_entropy(sig, ctx * 5 + neighbours),
        "sign_agrees_with_curvature": float(np.mean(np.sign(e[sig]) == np.sign(geo.curv[sig]))),
    }  # fmt: skip
    print(json.dumps(row), flush=True)
    with open(args.out, "a") as fh:
        fh.write(json.dumps(row) + "\n")


def _load_rows(paths: list[str]) -> tuple[dict, list[dict]]:
    today, refined = {}, []
    for path in paths:
        for line in Path(path).read_text().splitlines():
            r = json.loads(line)
            if r["kind"] == "today":
                today[(r["mesh"], r["budget"])] = r
            elif r["kind"] == "refined":
                refined.append(r)
    for r in refined:
        t = today[(r["mesh"], r["budget"])]
        r["ratio"] = r["bytes"] * r["chamfer"] / (t["bytes"] * t["chamfer"])
        r["fraction"] = round(r["base_bytes"] / r["budget"], 2)
    return today, refined


def config_key(r: dict, with_base: bool = True) -> str:
    """A configuration across points: base fraction class, source, rule, levels, gain (L > 1), kappa, even."""
    frac = "35%" if r["fraction"] < 0.4 else "50%" if r["fraction"] < 0.6 else "70%" if r["fraction"] < 0.78 else "85%"
    even = " +even" if r["even"] else ""
    gain = f", gain {r['gain']:g}" if r["levels"] > 1 else ""
    dist = r.get("distortion", "l2")
    what = f"{r['source']}, {r['rule']}, L={r['levels']}{gain}, {dist} kappa {r['kappa']:g}{even}"
    return f"base {frac}, {what}" if with_base else what


def cmd_table(args) -> None:
    """Markdown: the best refined row per mesh and budget against today's file, then the configurations'
    medians over the points where each ran."""
    today, refined = _load_rows(args.results)
    print(
        "| mesh | budget | base (B) | layer B per level | total B | CD | today B | today CD | B x CD ratio |"
        " NC (today) | faces (today) | layer decode CPU s | zeroed / to midpoint | configuration |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    best = {}
    for r in refined:
        key = (r["mesh"], r["budget"])
        if key not in best or r["ratio"] < best[key]["ratio"]:
            best[key] = r
    ratios = []
    for (mesh, budget), r in sorted(best.items()):
        t = today[(mesh, budget)]
        ratios.append(r["ratio"])
        print(
            f"| {mesh} | {budget // 1024} KB | {r['base_bytes']:,} ({r['fraction']:.0%}) | "
            f"{' + '.join(str(b) for b in r['level_bytes'])} | {r['bytes']:,} | {r['chamfer']:.3g} | {t['bytes']:,} | "
            f"{t['chamfer']:.3g} | **{r['ratio']:.2f}** | "
            f"{r['normal_consistency']:.4f} ({t['normal_consistency']:.4f}) | "
            f"{r['faces']:,} ({t['faces']:,}) | {r['decode_layer_cpu_s']:.2f} | {r['zeroed']} / {r['restored']} | "
            f"{config_key(r)} |"
        )
    if ratios:
        med, worst, low = np.median(ratios), max(ratios), min(ratios)
        print(
            f"\nBest per point: median ratio {med:.3f}, worst {worst:.3f}, best {low:.3f} over {len(ratios)} points.\n"
        )
        per_mesh = {}
        for (mesh, _), r in best.items():
            per_mesh.setdefault(mesh, []).append(r["ratio"])
        print(
            "Per mesh (best per point): "
            + "; ".join(f"{m} median {np.median(v):.2f}, worst {max(v):.2f}" for m, v in sorted(per_mesh.items()))
            + ".\n"
        )
    for with_base in (True, False):
        groups = {}
        for r in refined:
            pts = groups.setdefault(config_key(r, with_base), {})
            key = (r["mesh"], r["budget"])
            pts[key] = min(pts.get(key, np.inf), r["ratio"])  # without the base fraction: the better base
        title = "configuration" if with_base else "configuration, the better base fraction per point"
        print(f"\n| {title} | points | median ratio | worst ratio | worst mesh median |")
        print("|---|---|---|---|---|")
        for key, pts in sorted(groups.items(), key=lambda kv: (-len(kv[1]), np.median(list(kv[1].values())))):
            if len(pts) < args.min_points:
                continue
            mesh_med = {}
            for (mesh, _), v in pts.items():
                mesh_med.setdefault(mesh, []).append(v)
            worst_mesh = max(float(np.median(v)) for v in mesh_med.values())
            vals = list(pts.values())
            print(f"| {key} | {len(vals)} | {np.median(vals):.3f} | {max(vals):.3f} | {worst_mesh:.3f} |")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("today", help="re-measure today's committed bench files")
    t.add_argument("--meshes", default=",".join(MESHES))
    t.add_argument("--out", required=True)
    r = sub.add_parser("run", help="refine bases of one mesh to one budget, for a grid of configurations")
    r.add_argument("--mesh", required=True, choices=MESHES)
    r.add_argument("--budget", type=int, required=True)
    r.add_argument("--base", required=True, help="comma-separated base .tw files")
    r.add_argument("--source", default="control")
    r.add_argument("--rule", default="loop")
    r.add_argument("--levels", default="2")
    r.add_argument("--gain", default="1")
    r.add_argument("--kappa", default="0.12")
    r.add_argument("--even", action="store_true")
    r.add_argument("--distortion", default="l2", help="l2, l1 or both (comma-separated)")
    r.add_argument("--out", required=True)
    an = sub.add_parser("analyse", help="exact-coefficient floors, target statistics, the layer's RD curve")
    an.add_argument("--mesh", required=True, choices=MESHES)
    an.add_argument("--base", required=True)
    an.add_argument("--source", default="control")
    an.add_argument("--rule", default="loop")
    an.add_argument("--levels", default="1,2,3")
    an.add_argument("--gain", type=float, default=0.7)
    an.add_argument("--kappa", type=float, default=0.05)
    an.add_argument("--curve-levels", type=int, default=2)
    an.add_argument("--even", action="store_true")
    an.add_argument("--fractions", default="0.25,0.5,1,2")
    an.add_argument("--out", required=True)
    cx = sub.add_parser("contexts", help="entropy of level 1's significance map under contexts and an oracle")
    cx.add_argument("--mesh", required=True, choices=MESHES)
    cx.add_argument("--base", required=True)
    cx.add_argument("--step", type=float, required=True)
    cx.add_argument("--out", required=True)
    tb = sub.add_parser("table", help="markdown tables of result files")
    tb.add_argument("results", nargs="+")
    tb.add_argument("--min-points", type=int, default=1, help="list configurations run on at least this many")
    args = ap.parse_args(argv)
    commands = {"today": cmd_today, "run": cmd_run, "analyse": cmd_analyse, "contexts": cmd_contexts}
    (commands | {"table": cmd_table})[args.cmd](args)


if __name__ == "__main__":
    main()
