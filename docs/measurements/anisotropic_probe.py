"""Issue 48, stage 1: anisotropic point placement from the input's curvature tensor, measured (encoder only).

Experiment scaffolding, outside the package on purpose (no format, codec or CLI change): the encoder of the
commit it runs against is used unchanged, with three of its functions swapped in by monkeypatching:

* the start's surface samples (`fit.initialize._sample_surface_stratified`, which `initial_points` and the
  feature-aware start both call): candidates drawn with density rho ~ 1/(h_1 h_2), then thinned to a maximal
  independent set under the anisotropic metric (below); the shell offsets across the surface are today's;
* the resampling (`fit.loop.resample`): the new points' surface samples are drawn with probability
  importance x rho (the error-driven density kept on top), thinned the same way against each other and against
  the kept points, then offset into the shell as today (`keep_on_side` included); s from the input as today;
* optionally the ODT term (`fit.losses.odt_loss`, which `fit.step` calls through the module): `--odt metric`
  measures each tet after mapping it by the metric's square root (the mean of its corners' metric tensors),
  `--odt off-aniso` drops the tets whose metric is anisotropic (ratio > ANISO_OFF), `--odt iso` is today's.

Metric. The input's curvature tensor is Cohen-Steiner and Morvan's normal-cycle estimate: every interior edge
e with dihedral angle beta adds |beta| |e| (e e^T) (split into pieces shorter than half a cell), summed over a
cubic cell and its 26 neighbours and divided by the input's area there (area-weighted samples): smoothed over
~3 cells, the cell being the current mean spacing h0 = sqrt(area / n_surface) x CELL. Projected on a sample's
tangent plane its eigenvalues are |k| across the two eigen-directions (along e: the curvature across e); a
sharp crease is the limit of high curvature across it. Spacing along direction i ~ 1/sqrt(|k_i| + eps),
eps = EPS x the area mean of the larger |k| (the floor for flat regions); the ratio long / short is capped at
MAX_RATIO and the density 1/(h_1 h_2) between 1/MAX_DENSITY and MAX_DENSITY times its area mean. Across the
surface the metric's spacing is min(h_1, h_2, h0) (points on the two sides of a thin part do not block each
other). `--mode isodensity` keeps the density of that metric with isotropic spacing (the control: density
alone); `--mode today` is the encoder unchanged.

Thinning: candidates (OVERSAMPLE_A x the points wanted), pairs within their own metric radius from a k-d tree,
conflict where delta^T (G_i + G_j)/2 delta < alpha^2; a greedy maximal independent set in a random priority
order (Luby rounds, equal to the sequential greedy set), alpha bisected so that the set holds at least the
points wanted; the first ones in priority order are kept.

Measured per encode (`run`): bytes, Chamfer distance and normal consistency as `tetweave bench` computes them
(tetweave_codec.metrics.fidelity: 200,000 area-weighted samples, seed 0, the normalized frame), points stored,
decoded faces, CPU time (user + system of this process), and the anisotropy of the last fit's tets that cross the
surface at the start of its main stage and after it, and of the file's marching-tets (control) triangles: per
element the RMS extent of its edges along the metric's long direction over that along its short direction,
median over the elements whose metric ratio is at least 2 (the target's median beside it).

Commands (from the repository root, one thread, niced):

    nice -n 19 python docs/measurements/anisotropic_probe.py synth --out DIR       # the synthetic inputs (PLY)
    nice -n 19 python docs/measurements/anisotropic_probe.py run --mesh ../shared/meshes/fandisk.ply \
        --size 5120 --mode aniso --odt metric --out R.jsonl [--save DIR]
    python docs/measurements/anisotropic_probe.py table R.jsonl
    python docs/measurements/anisotropic_probe.py picture --mesh M.ply --files A.tw B.tw --out P.png
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

N_SAMPLES = 200_000  # tetweave bench's --samples
SEED = 0  # tetweave bench's --seed
CELL = 1.0  # smoothing cell of the curvature tensor, in units of the current mean spacing h0
EPS = 0.05  # flat floor of |k|, relative to the area mean of the larger |k|
MAX_RATIO = 4.0  # cap of the spacing ratio long / short
MAX_DENSITY = 4.0  # cap of the density relative to its mean (both ways)
OVERSAMPLE_A = 6  # candidates per point wanted
ANISO_OFF = 2.0  # --odt off-aniso: tets whose metric ratio is above this get no ODT
REGION_RATIO = 2.0  # anisotropy statistics over elements whose metric ratio is at least this
MIN_ELEMENTS = 20  # the table shows them where at least this many elements are in that region

OPTS = {"mode": "aniso", "odt": "iso", "eps": EPS, "max_ratio": MAX_RATIO}
STATE: dict = {}


def cpu_seconds() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


# ------------------------------------------------------------------------------------------------ metric field


class CurvatureField:
    """Smoothed |curvature| tensor of a triangle mesh (normalized frame) on cubic cells of a given size."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        from tetweave_codec.geometry.triangles import face_areas, face_normals, sample_surface

        v = np.asarray(vertices, np.float64)
        f = np.asarray(faces, np.int64)
        fn = face_normals(v, f)
        he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        hf = np.tile(np.arange(len(f)), 3)
        key = np.sort(he, axis=1)
        order = np.lexsort((key[:, 1], key[:, 0]))
        ks = key[order]
        same = (ks[1:] == ks[:-1]).all(1)
        a, b = order[:-1][same], order[1:][same]  # two half-edges of one edge (manifold pairs)
        cos = np.clip(np.einsum("nd,nd->n", fn[hf[a]], fn[hf[b]]), -1.0, 1.0)
        beta = np.arccos(cos)
        e = v[key[a, 1]] - v[key[a, 0]]
        length = np.linalg.norm(e, axis=1)
        ok = length > 0
        self.p0, self.e, self.beta, self.length = v[key[a, 0]][ok], e[ok], beta[ok], length[ok]
        self.area = float(face_areas(v, f).sum())
        self.samples, sface = sample_surface(v, f, 200_000, 1)
        self.sample_normals = fn[sface]
        self.cache: dict[float, tuple] = {}

    @staticmethod
    def _keys(points: np.ndarray, cell: float) -> np.ndarray:
        ijk = np.floor(points / cell).astype(np.int64) + (1 << 20)
        return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]

    def _cells(self, cell: float):
        if cell in self.cache:
            return self.cache[cell]
        pieces = np.maximum(1, np.ceil(self.length / (0.5 * cell)).astype(np.int64))
        idx = np.repeat(np.arange(len(pieces)), pieces)
        start = np.cumsum(pieces) - pieces
        t = (np.arange(len(idx)) - start[idx] + 0.5) / pieces[idx]
        mid = self.p0[idx] + t[:, None] * self.e[idx]
        u = self.e[idx] / self.length[idx, None]
        w = self.beta[idx] * self.length[idx] / pieces[idx]
        tens = w[:, None, None] * u[:, :, None] * u[:, None, :]
        k_e = self._keys(mid, cell)
        k_a = self._keys(self.samples, cell)
        keys = np.unique(np.concatenate([k_e, k_a]))
        tsum = np.zeros((len(keys), 3, 3))
        np.add.at(tsum, np.searchsorted(keys, k_e), tens)
        asum = np.zeros(len(keys))
        np.add.at(asum, np.searchsorted(keys, k_a), self.area / len(self.samples))
        # 27-neighbourhood box filter
        t27 = np.zeros_like(tsum)
        a27 = np.zeros_like(asum)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    nk = keys + (dx << 42) + (dy << 21) + dz
                    pos = np.clip(np.searchsorted(keys, nk), 0, len(keys) - 1)
                    hit = keys[pos] == nk
                    t27[hit] += tsum[pos[hit]]
                    a27[hit] += asum[pos[hit]]
        out = (keys, t27 / np.maximum(a27, 1e-30)[:, None, None])
        self.cache[cell] = out
        return out

    def principal(self, points: np.ndarray, normals: np.ndarray, cell: float):
        """Per point: unit tangent directions d1, d2 (n,3) and |k| along them (n,), (n,)."""
        keys, tens = self._cells(cell)
        k = self._keys(points, cell)
        pos = np.clip(np.searchsorted(keys, k), 0, len(keys) - 1)
        hit = keys[pos] == k
        t = np.where(hit[:, None, None], tens[pos], 0.0)
        n = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
        helper = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
        t1 = np.cross(n, helper)
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
        t2 = np.cross(n, t1)
        basis = np.stack([t1, t2], axis=2)  # (n,3,2)
        m = np.einsum("nia,nij,njb->nab", basis, t, basis)
        lam, vec = np.linalg.eigh(m)  # ascending
        ea = np.einsum("nia,na->ni", basis, vec[:, :, 0])  # eigen-direction of the smaller value
        eb = np.einsum("nia,na->ni", basis, vec[:, :, 1])
        # eigenvalue along e = |curvature across e| = |k| in the direction n x e
        k_along_ea = np.abs(lam[:, 1])  # curvature in direction ea is the value of eb
        k_along_eb = np.abs(lam[:, 0])
        return ea, eb, k_along_ea, k_along_eb


def _field(vertices: np.ndarray, faces: np.ndarray) -> CurvatureField:
    key = (vertices.shape, float(vertices[:5].sum()), faces.shape)
    if STATE.get("field_key") != key:
        STATE["field_key"] = key
        STATE["field"] = CurvatureField(vertices, faces)
    return STATE["field"]


def metric_tensors(field: CurvatureField, points, normals, h0: float, mode: str | None = None):
    """Per point the metric G (n,3,3) (unit metric length = the local spacing, mean spacing ~h0), the density rho
    (n,) relative to its mean, and the spacing ratio long / short (n,); plus d1 (n,3), the long direction."""
    mode = mode or OPTS["mode"]
    ea, eb, ka, kb = field.principal(points, normals, CELL * h0)
    # the floor: from the field's own scale (area mean of the larger |k| at this smoothing)
    if "kref" not in STATE or STATE.get("kref_h0") != h0:
        _, _, ska, skb = field.principal(field.samples[::10], field.sample_normals[::10], CELL * h0)
        STATE["kref"] = float(np.maximum(ska, skb).mean())
        STATE["kref_h0"] = h0
    eps = OPTS["eps"] * max(STATE["kref"], 1e-6)
    ha = 1.0 / np.sqrt(ka + eps)
    hb = 1.0 / np.sqrt(kb + eps)
    r = OPTS["max_ratio"]
    ha = np.minimum(ha, r * hb)
    hb = np.minimum(hb, r * ha)
    if mode == "isodensity":
        ha = hb = np.sqrt(ha * hb)
    rho = 1.0 / (ha * hb)
    mean_rho = STATE.get("mean_rho_h0", {}).get(h0)
    if mean_rho is None:
        _, _, ska, skb = field.principal(field.samples[::10], field.sample_normals[::10], CELL * h0)
        sha = np.minimum(1.0 / np.sqrt(ska + eps), r / np.sqrt(skb + eps))
        shb = np.minimum(1.0 / np.sqrt(skb + eps), r / np.sqrt(ska + eps))
        mean_rho = float((1.0 / (sha * shb)).mean())
        STATE.setdefault("mean_rho_h0", {})[h0] = mean_rho
    rel = np.clip(rho / mean_rho, 1.0 / MAX_DENSITY, MAX_DENSITY)
    # rescale: density rel / h0^2 (mean spacing h0), the ratio kept
    factor = h0 / np.sqrt(rel * ha * hb)
    ha, hb = ha * factor, hb * factor
    hn = np.minimum(np.minimum(ha, hb), h0)
    n = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    g = (
        ea[:, :, None] * ea[:, None, :] / ha[:, None, None] ** 2
        + eb[:, :, None] * eb[:, None, :] / hb[:, None, None] ** 2
        + n[:, :, None] * n[:, None, :] / hn[:, None, None] ** 2
    )
    ratio = np.maximum(ha, hb) / np.minimum(ha, hb)
    long_dir = np.where((ha >= hb)[:, None], ea, eb)
    return g, rel, ratio, long_dir, np.maximum(ha, hb)


# ------------------------------------------------------------------------------------------------ thinning


def metric_mis(points, g, reach, wanted: int, rng, fixed_points=None, fixed_g=None, fixed_reach=None):
    """Indices (<= wanted) of candidates (m,3) with metrics g (m,3,3), a greedy maximal independent set in a
    random priority order under conflict delta^T (G_i + G_j)/2 delta < alpha^2, alpha bisected so that at least
    `wanted` are selected (fixed points, which block their neighbours, count as selected already)."""
    m = len(points)
    if wanted >= m:
        return np.arange(m)
    allp = points if fixed_points is None else np.concatenate([fixed_points, points])
    allg = g if fixed_g is None else np.concatenate([fixed_g, g])
    allr = reach if fixed_reach is None else np.concatenate([fixed_reach, reach])
    nf = 0 if fixed_points is None else len(fixed_points)
    alpha_max = 1.2
    tree = cKDTree(allp)
    lists = tree.query_ball_point(allp, r=alpha_max * allr, return_sorted=False)
    cnt = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
    i = np.repeat(np.arange(len(allp)), cnt)
    j = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists]) if len(i) else np.zeros(0, np.int64)
    keep = i < j
    i, j = i[keep], j[keep]
    i, j = np.concatenate([i, j]), np.concatenate([j, i])
    key = np.unique(i * len(allp) + j)
    i, j = key // len(allp), key % len(allp)
    d = allp[j] - allp[i]
    gm = 0.5 * (allg[i] + allg[j])
    dist = np.sqrt(np.einsum("ni,nij,nj->n", d, gm, d))
    prio = np.empty(len(allp))
    prio[:nf] = -1.0  # fixed points first
    prio[nf:] = rng.permutation(m).astype(np.float64)

    def mis(alpha: float) -> np.ndarray:
        sel = dist < alpha
        a, b = i[sel], j[sel]
        state = np.zeros(len(allp), np.int8)  # 0 undecided, 1 in, -1 out
        state[:nf] = 1  # fixed points are in and block their neighbours
        out = np.zeros(len(allp), bool)
        out[b[a < nf]] = True
        state[out & (state == 0)] = -1
        while True:
            und = state == 0
            if not und.any():
                break
            act = und[a] & und[b]
            lowest = np.full(len(allp), np.inf)
            np.minimum.at(lowest, a[act], prio[b[act]])
            win = und & (prio < lowest)
            state[win] = 1
            blocked = np.zeros(len(allp), bool)
            blocked[b[win[a]]] = True
            state[blocked & (state == 0)] = -1
        return state == 1

    lo, hi = 0.0, alpha_max
    best = np.ones(len(allp), bool)
    for _ in range(14):
        mid = 0.5 * (lo + hi)
        chosen = mis(mid)
        if chosen[nf:].sum() >= wanted:
            lo, best = mid, chosen
        else:
            hi = mid
    idx = np.nonzero(best[nf:])[0]
    return idx[np.argsort(prio[nf + idx], kind="stable")[:wanted]]


# ------------------------------------------------------------------------------------------------ patches


def patched_stratified(vertices, faces, n, rng):
    """fit.initialize._sample_surface_stratified under the metric: (positions, normals, area)."""
    from tetweave_codec.geometry.closest import SurfaceTree
    from tetweave_codec.geometry.triangles import face_areas, face_normals, sample_surface

    field = _field(vertices, faces)
    fnorm = face_normals(vertices, faces)
    if STATE.get("tree_key") != STATE["field_key"]:
        STATE["tree"] = SurfaceTree(vertices, faces)
        STATE["face_normals"] = fnorm
        STATE["tree_key"] = STATE["field_key"]
        STATE.pop("kref", None)
        STATE.pop("mean_rho_h0", None)
    area = float(face_areas(vertices, faces).sum())
    h0 = math.sqrt(area / n)
    pos, face = sample_surface(vertices, faces, 4 * OVERSAMPLE_A * n, rng)
    nrm = fnorm[face]
    _, rel, _, _, _ = metric_tensors(field, pos, nrm, h0)
    p = rel / rel.sum()
    pick = rng.choice(len(pos), size=OVERSAMPLE_A * n, replace=False, p=p)
    pos, nrm = pos[pick], nrm[pick]
    g, _, ratio, _, reach = metric_tensors(field, pos, nrm, h0)
    sel = metric_mis(pos, g, reach, n, rng)
    _set_odt_reference(field, pos, nrm, h0)
    return pos[sel], nrm[sel], area


def _set_odt_reference(field, pos, nrm, h0):
    g, _, ratio, _, _ = metric_tensors(field, pos, nrm, h0)
    scale = h0**2  # metric in units of the mean spacing (ODT's energy is scale free anyway)
    STATE["odt_ref"] = (cKDTree(pos), g * scale, ratio, h0)


def patched_resample(points, s, c, tets, keep, grid, bbox, n_target, generator, near=None):
    """fit.loop.resample with the new points' surface samples thinned under the metric."""
    import torch

    from tetweave_codec.fit import resample as rs
    from tetweave_codec.fit.initialize import SHELL, keep_on_side

    if near is None:
        return rs.resample(points, s, c, tets, keep, grid, bbox, n_target, generator, near)
    device = points.device
    keep = rs._as_tensor(keep, device).bool()
    kept = torch.nonzero(keep).squeeze(1)
    if len(kept) > n_target:
        rank = torch.rand(len(kept), generator=generator, device=generator.device, dtype=torch.float64)
        kept = torch.sort(kept[torch.argsort(rank, descending=True, stable=True)[:n_target]]).values
    n_new = n_target - len(kept)
    field = STATE["field"]
    h0 = near.half_width / SHELL
    seed = int(torch.randint(0, 2**31 - 1, (1,), generator=generator))
    rng = np.random.default_rng(seed)
    if n_new > 0:
        r = grid.shape[0]
        samples = torch.as_tensor(near.samples, dtype=torch.float64)
        values = torch.nan_to_num(grid.to(torch.float64).reshape(-1), nan=0.0, posinf=0.0)
        flat, inside = rs._voxel_index(
            samples, rs._as_tensor(bbox[0], "cpu", torch.float64), rs._as_tensor(bbox[1], "cpu", torch.float64), r
        )
        imp = torch.where(inside, values[flat].clamp_min(0.0), torch.zeros_like(values[flat])).numpy()
        if not (imp > 0).any():
            imp = np.ones_like(imp)
        rel = _sample_density(field, near, h0)
        w = imp * rel
        m = min(OVERSAMPLE_A * n_new, int((w > 0).sum()))
        pick = rng.choice(len(w), size=m, replace=False, p=w / w.sum())
        pos, nrm = near.samples[pick], near.normals[pick]
        g, _, _, _, reach = metric_tensors(field, pos, nrm, h0)
        kp = points.detach().cpu().numpy().astype(np.float64)[kept.cpu().numpy()]
        _, kface, kcp = STATE["tree"].query(kp)
        kn = STATE["face_normals"][kface]
        kg, _, _, _, kreach = metric_tensors(field, kcp, kn, h0)
        sel = metric_mis(pos, g, reach, n_new, rng, kp, kg, kreach)
        if len(sel) < n_new:  # too few candidates: top up at random as today
            extra = rng.choice(len(near.samples), size=n_new - len(sel), p=w / w.sum())
            pos = np.concatenate([pos[sel], near.samples[extra]])
            nrm = np.concatenate([nrm[sel], near.normals[extra]])
        else:
            pos, nrm = pos[sel], nrm[sel]
        t = rng.uniform(near.gap, 1.0, size=n_new) * rng.choice([-1.0, 1.0], size=n_new)
        off = keep_on_side(pos, nrm, near.half_width * t, near.tree, near.face_normals)
        new_points = torch.from_numpy(pos + off[:, None] * nrm).to(points.dtype)
    else:
        new_points = points[:0].detach()
    _set_odt_reference(field, near.samples[:: max(1, len(near.samples) // 50_000)],
                       near.normals[:: max(1, len(near.samples) // 50_000)], h0)  # fmt: skip
    values = torch.cat([s.detach().reshape(-1, 1), c.detach().reshape(len(s), -1)], dim=1)
    new_values = rs.interpolate_in_tets(points, tets, values, new_points)
    out_points = torch.cat([points.detach()[kept], new_points.to(device)])
    out_s = torch.cat([s.detach()[kept], new_values[:, 0].to(s.dtype)])
    out_c = torch.cat([c.detach().reshape(len(s), -1)[kept], new_values[:, 1:].to(c.dtype)])
    return out_points, out_s, out_c


def _sample_density(field, near, h0):
    key = (id(near.samples), h0)
    if STATE.get("dens_key") != key:
        _, rel, _, _, _ = metric_tensors(field, near.samples, near.normals, h0)
        STATE["dens_key"] = key
        STATE["dens"] = rel
    return STATE["dens"]


def _tet_metric(points_np: np.ndarray, tets_np: np.ndarray):
    """Per tet: the mean of its corners' metric tensors (3,3) and its ratio; identity far from the surface."""
    tree, g_ref, ratio_ref, h0 = STATE["odt_ref"]
    d, nn = tree.query(points_np)
    g = g_ref[nn].copy()
    rat = ratio_ref[nn].copy()
    far = d > 2.0 * h0
    g[far] = np.eye(3)
    rat[far] = 1.0
    return g[tets_np].mean(1), rat[tets_np].max(1)


def patched_odt_loss(points, tets, reduction: str = "relative"):
    import torch

    from tetweave_codec.fit import losses

    if OPTS["odt"] == "iso" or "odt_ref" not in STATE or tets.shape[0] == 0 or reduction != "relative":
        return ORIGINAL["odt_loss"](points, tets, reduction)
    with torch.no_grad():
        gt, rat = _tet_metric(points.detach().cpu().numpy().astype(np.float64), tets.cpu().numpy())
    if OPTS["odt"] == "off-aniso":
        mask = torch.from_numpy(rat <= ANISO_OFF)
        e = losses.odt_relative_energy(points, tets)
        return (e * mask.to(e)).mean()
    # metric: map each tet by L^T with L L^T = G (x^T G x = |L^T x|^2)
    lt = torch.from_numpy(np.linalg.cholesky(gt + 1e-12 * np.eye(3))).to(points).transpose(1, 2)  # (T,3,3)
    corners = points[tets]  # (T,4,3)
    mapped = torch.einsum("tij,tkj->tki", lt, corners)
    flat = mapped.reshape(-1, 3)
    idx = torch.arange(len(flat), device=points.device).reshape(-1, 4)
    return losses.odt_relative_energy(flat, idx).mean()


ORIGINAL: dict = {}


def install(mode: str, odt: str) -> None:
    from tetweave_codec.fit import initialize, loop, losses

    OPTS["mode"], OPTS["odt"] = mode, odt
    ORIGINAL.setdefault("stratified", initialize._sample_surface_stratified)
    ORIGINAL.setdefault("resample", loop.resample)
    ORIGINAL.setdefault("odt_loss", losses.odt_loss)
    ORIGINAL.setdefault("main_stage", loop.main_stage)
    loop.main_stage = recording_main_stage
    if mode == "today":
        return
    initialize._sample_surface_stratified = patched_stratified
    loop.resample = patched_resample
    losses.odt_loss = patched_odt_loss


# ------------------------------------------------------------------------------------------------ anisotropy


def recording_main_stage(params, ctx):
    """fit.loop.main_stage, recording the tets' anisotropy at its start and end (the last fit's kept)."""
    before = _active_anisotropy(params.points.detach().numpy(), params.s.detach().numpy(), ctx)
    out = ORIGINAL["main_stage"](params, ctx)
    after = _active_anisotropy(out.points.detach().numpy(), out.s.detach().numpy(), ctx)
    STATE["aniso_fit"] = {"start": before, "end": after, "points": len(out.s)}
    return out


def _frame(points: np.ndarray):
    """Long direction, metric ratio and normals at the input's closest points of `points`."""
    if "eval" not in STATE:
        return None
    field, tree, fnorm, h0 = STATE["eval"]
    _, face, cp = tree.query(points)
    _, _, ratio, long_dir, _ = metric_tensors(field, cp, fnorm[face], h0, mode="aniso")
    return long_dir, ratio, fnorm[face]


def _element_ratio(corners: np.ndarray, long_dir, normals) -> np.ndarray:
    """RMS edge extent along long_dir over that along normal x long_dir, per element (E,k,3)."""
    short = np.cross(normals, long_dir)
    k = corners.shape[1]
    ii, jj = np.triu_indices(k, 1)
    e = corners[:, jj] - corners[:, ii]
    a = np.sqrt((np.einsum("nkd,nd->nk", e, long_dir) ** 2).mean(1))
    b = np.sqrt((np.einsum("nkd,nd->nk", e, short) ** 2).mean(1))
    return a / np.maximum(b, 1e-30)


def _active_anisotropy(points: np.ndarray, s: np.ndarray, ctx) -> dict:
    from tetweave_codec.geometry.delaunay import delaunay

    _eval_state(ctx.surface.vertices, ctx.surface.faces, ctx.surface.area, len(s))
    tets = delaunay(points.astype(np.float64))
    neg = s[tets] < 0
    active = neg.any(1) & ~neg.all(1)
    t = tets[active]
    corners = points[t].astype(np.float64)
    fr = _frame(corners.mean(1))
    return _stats(_element_ratio(corners, fr[0], fr[2]), fr[1])


def _stats(measured: np.ndarray, target: np.ndarray) -> dict:
    region = target >= REGION_RATIO
    if not region.any():
        return {"n": 0}
    return {
        "n": int(region.sum()),
        "share": float(region.mean()),
        "measured": float(np.median(measured[region])),
        "target": float(np.median(target[region])),
        "elsewhere": float(np.median(measured[~region])) if (~region).any() else None,
    }


def _eval_state(vertices, faces, area, n_points):
    from tetweave_codec.fit.initialize import UNIFORM_FRACTION
    from tetweave_codec.geometry.closest import SurfaceTree
    from tetweave_codec.geometry.triangles import face_normals

    h0 = math.sqrt(area / max(1.0, (1.0 - UNIFORM_FRACTION) * n_points))
    field = _field(vertices, faces)
    if STATE.get("tree_key") != STATE["field_key"]:
        STATE["tree"] = SurfaceTree(vertices, faces)
        STATE["face_normals"] = face_normals(vertices, faces)
        STATE["tree_key"] = STATE["field_key"]
        STATE.pop("kref", None)
        STATE.pop("mean_rho_h0", None)
    STATE["eval"] = (field, STATE["tree"], STATE["face_normals"], h0)


def control_anisotropy(data: bytes, scale: float, offset: np.ndarray) -> dict:
    """The file's marching-tets triangles (decode level control), in the metric's frame of the last fit."""
    from tetweave_codec.decoder import decode
    from tetweave_codec.metrics.fidelity import to_frame

    v, f = decode(data, level="control")
    v = to_frame(v, scale, offset)
    corners = v[f]
    fr = _frame(corners.mean(1))
    if fr is None:
        return {}
    out = _stats(_element_ratio(corners, fr[0], fr[2]), fr[1])
    out["faces"] = len(f)
    return out


# ------------------------------------------------------------------------------------------------ run


def metrics(inp, v: np.ndarray, f: np.ndarray) -> dict:
    """Chamfer distance and normal consistency as tetweave_codec.metrics.fidelity computes them (see
    docs/measurements/refinement_probe.py `metrics`)."""
    from tetweave_codec.geometry.closest import SurfaceTree
    from tetweave_codec.geometry.triangles import face_normals, sample_surface

    tree = SurfaceTree(v, f)
    normals = face_normals(v, f)
    pts, pf = sample_surface(v, f, N_SAMPLES, SEED)
    sq_ab, face_ab, _ = tree.query(inp["points"])
    sq_ba, face_ba, _ = inp["tree"].query(pts)
    d_ab, d_ba = np.sqrt(np.maximum(sq_ab, 0)), np.sqrt(np.maximum(sq_ba, 0))
    cos = np.abs(
        np.concatenate(
            [
                np.einsum("nd,nd->n", inp["normals"][inp["sample_faces"]], normals[face_ab]),
                np.einsum("nd,nd->n", normals[pf], inp["normals"][face_ba]),
            ]
        )
    )
    return {"chamfer": float(0.5 * (d_ab.mean() + d_ba.mean())), "normal_consistency": float(cos.mean())}


def stored_points(data: bytes) -> int:
    from tetweave_codec.formats.tw import unpack

    return len(unpack(data).s)


def cmd_run(args) -> None:
    import torch

    torch.set_num_threads(1)
    from tetweave_codec.decoder import decode
    from tetweave_codec.encoder import encode
    from tetweave_codec.geometry.closest import SurfaceTree
    from tetweave_codec.geometry.triangles import face_normals, sample_surface
    from tetweave_codec.meshio import load_mesh
    from tetweave_codec.metrics.fidelity import normalization, to_frame
    from tetweave_codec.options import EncodeOptions

    OPTS["eps"], OPTS["max_ratio"] = args.eps, args.max_ratio
    install(args.mode, args.odt)
    v, f = load_mesh(args.mesh)
    options = EncodeOptions(
        points=args.points, sh_degree="auto", quality=args.quality, device="cpu", seed=0, measure=False,
        size=args.size,
    )  # fmt: skip
    c0, w0 = cpu_seconds(), time.perf_counter()
    result = encode(v, f, options=options)
    cpu, wall = cpu_seconds() - c0, time.perf_counter() - w0
    scale, offset = normalization(v)
    vn = to_frame(v, scale, offset)
    fi = np.asarray(f, np.int64)
    inp = {"tree": SurfaceTree(vn, fi), "normals": face_normals(vn, fi)}
    inp["points"], inp["sample_faces"] = sample_surface(vn, fi, N_SAMPLES, SEED)
    dv, df = decode(result.data)
    m = metrics(inp, to_frame(dv, scale, offset), df)
    row = {
        "mesh": Path(args.mesh).stem,
        "size": args.size,
        "points_arg": args.points,
        "mode": args.mode,
        "odt": args.odt if args.mode != "today" else "iso",
        "eps": args.eps,
        "max_ratio": args.max_ratio,
        "quality": args.quality,
        "bytes": len(result.data),
        **m,
        "bxc": len(result.data) * m["chamfer"],
        "points": stored_points(result.data),
        "points_target": result.stats.get("points_target"),
        "faces": int(len(df)),
        "cpu_s": round(cpu, 1),
        "wall_s": round(wall, 1),
        "aniso_fit": STATE.get("aniso_fit"),
        "aniso_control": control_anisotropy(result.data, scale, offset),
    }
    print(json.dumps(row), flush=True)
    with open(args.out, "a") as fh:
        fh.write(json.dumps(row) + "\n")
    if args.save:
        Path(args.save).mkdir(parents=True, exist_ok=True)
        name = f"{row['mesh']}-{args.size or args.points}-{args.mode}-{row['odt']}.tw"
        (Path(args.save) / name).write_bytes(result.data)


# ------------------------------------------------------------------------------------------------ synthetic


def synthetic_meshes() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Closed, finely and evenly tessellated inputs a user would recognise (units: the normalized frame)."""
    import trimesh
    from trimesh import creation, remesh

    def fine(mesh, edge):
        v, f = remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=edge)
        m = trimesh.Trimesh(v, f, process=True)
        m.merge_vertices()
        return m

    out = {}
    out["cylinder"] = _cylinder(0.08, 1.8, 128, 91)
    tor = creation.torus(major_radius=0.7, minor_radius=0.07, major_sections=256, minor_sections=32)
    out["torus"] = (tor.vertices, tor.faces)
    # box 1.8 x 1.0 x 0.6 with every edge filleted at radius 0.1: a fine box's points pushed onto the rounded box
    half = np.array([0.9, 0.5, 0.3])
    rad = 0.1
    box = fine(creation.box(extents=2 * half), 0.03)
    p = box.vertices.copy()
    inner = np.clip(p, -(half - rad), half - rad)
    d = p - inner
    p = inner + rad * d / np.linalg.norm(d, axis=1, keepdims=True)
    out["filleted-box"] = (p, box.faces)
    # a fin: a thin swept plate, 1.6 long, 0.6 high, 0.06 thick at the root, an ellipsoid bent into a shark fin
    sph = creation.icosphere(subdivisions=5)
    q = sph.vertices * np.array([0.8, 0.5, 0.03])
    q[:, 0] += 0.5 * (q[:, 1] + 0.5) ** 2  # sweep back with height
    q[:, 2] *= 1.0 - 0.6 * (q[:, 1] + 0.5)  # thinner towards the tip
    out["fin"] = (q, sph.faces)
    return out


def _cylinder(radius: float, length: float, around: int, rings: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed capped cylinder along z: a grid of rings x around, each cap a fan around its centre."""
    a = 2 * np.pi * np.arange(around) / around
    z = np.linspace(-length / 2, length / 2, rings)
    v = np.stack([np.tile(radius * np.cos(a), rings), np.tile(radius * np.sin(a), rings), np.repeat(z, around)], axis=1)
    faces = []
    for r in range(rings - 1):
        i = r * around + np.arange(around)
        j = r * around + (np.arange(around) + 1) % around
        faces += [np.stack([i, j, j + around], 1), np.stack([i, j + around, i + around], 1)]
    c0, c1 = len(v), len(v) + 1
    v = np.concatenate([v, [[0, 0, -length / 2], [0, 0, length / 2]]])
    k = np.arange(around)
    faces.append(np.stack([np.full(around, c0), (k + 1) % around, k], 1))
    top = (rings - 1) * around
    faces.append(np.stack([np.full(around, c1), top + k, top + (k + 1) % around], 1))
    return v, np.concatenate(faces)


def cmd_synth(args) -> None:
    from tetweave_codec.meshio import save_mesh

    Path(args.out).mkdir(parents=True, exist_ok=True)
    for name, (v, f) in synthetic_meshes().items():
        save_mesh(str(Path(args.out) / f"{name}.ply"), np.asarray(v, np.float64), np.asarray(f, np.int64))
        print(name, len(v), len(f))


# ------------------------------------------------------------------------------------------------ table


def cmd_table(args) -> None:
    by_key = {}
    for r in (json.loads(x) for p in args.files for x in open(p) if x.strip()):
        by_key[(r["mesh"], r["size"], r["points_arg"], r["mode"], r["odt"])] = r  # a repeated run: the last
    rows = list(by_key.values())
    today = {(r["mesh"], r["size"]): r for r in rows if r["mode"] == "today"}
    print("| mesh | size | mode | ODT | bytes | Chamfer | NC | bytes x CD / today | points | faces | CPU s |"
          " tets ratio start / end (target) | control tris |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in sorted(rows, key=lambda r: (r["mesh"], r["size"] or 0, r["mode"] != "today", r["mode"], r["odt"])):
        t = today.get((r["mesh"], r["size"]))
        ratio = f"{r['bxc'] / t['bxc']:.3f}" if t else "-"
        af = r.get("aniso_fit") or {}
        st, en = af.get("start", {}), af.get("end", {})
        fit_s = (
            f"{st.get('measured', float('nan')):.2f} / {en.get('measured', float('nan')):.2f} "
            f"({en.get('target', float('nan')):.2f})"
            if st.get("n", 0) >= MIN_ELEMENTS and en.get("n", 0) >= MIN_ELEMENTS
            else "-"
        )
        ac = r.get("aniso_control") or {}
        ctl = f"{ac['measured']:.2f}" if ac.get("n", 0) >= MIN_ELEMENTS else "-"
        print(
            f"| {r['mesh']} | {r['size']} | {r['mode']} | {r['odt']} | {r['bytes']:,} | {r['chamfer']:.3e} | "
            f"{r['normal_consistency']:.4f} | {ratio} | {r['points']:,} | {r['faces']:,} | {r['cpu_s']:.0f} | "
            f"{fit_s} | {ctl} |"
        )


# ------------------------------------------------------------------------------------------------ pictures


def cmd_picture(args) -> None:
    """Points and marching-tets triangles of files: cylinder unrolled (axis x angle), others in 3-D."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from tetweave_codec.decoder import decode
    from tetweave_codec.formats.tw import unpack
    from tetweave_codec.meshio import load_mesh
    from tetweave_codec.metrics.fidelity import normalization, to_frame

    v, _ = load_mesh(args.mesh)
    scale, offset = normalization(v)
    n = len(args.files)
    unrolled = Path(args.mesh).stem == "cylinder"
    fig = plt.figure(figsize=(4.2 * n, 3.6 if unrolled else 4.2), dpi=args.dpi)
    for k, path in enumerate(args.files):
        data = Path(path).read_bytes()
        cv, cf = decode(data, level="control")
        cv = to_frame(cv, scale, offset)
        tw = unpack(data)
        pts = to_frame(_stored_points(tw) * tw.scale + np.asarray(tw.offset), scale, offset)
        title = args.titles[k] if args.titles else Path(path).stem
        if unrolled:
            ax = fig.add_subplot(1, n, k + 1)
            # axis of the cylinder: the normalized frame's longest extent
            axis = int(np.argmax(np.ptp(cv, axis=0)))
            o = [i for i in range(3) if i != axis]
            near = np.abs(np.hypot(pts[:, o[0]], pts[:, o[1]]) - 0.08) < 0.05
            sel = near & (np.abs(pts[:, axis]) < 0.45)
            arc = 0.08 * np.arctan2(pts[sel, o[1]], pts[sel, o[0]])  # arc length on the input's radius
            ax.scatter(
                pts[sel, axis],
                arc,
                s=3,
                c=np.where(pts[sel, o[0]] ** 2 + pts[sel, o[1]] ** 2 > 0.0064, "C3", "C0"),
                zorder=3,
            )
            tri = cf[(np.abs(cv[cf][:, :, axis]).max(1) < 0.45)]
            a = 0.08 * np.arctan2(cv[:, o[1]], cv[:, o[0]])
            tri = tri[np.ptp(a[tri], axis=1) < 0.08 * np.pi]  # not across the seam
            seg = np.stack([np.stack([cv[tri[:, k], axis], a[tri[:, k]]], 1) for k in (0, 1, 2, 0)], 1)
            ax.add_collection(LineCollection(np.concatenate([seg[:, k : k + 2] for k in range(3)]), lw=0.3, colors="k"))
            ax.set_xlabel("along the axis")
            ax.set_ylabel("around (arc length)")
            ax.set_xlim(-0.3, 0.3)
            ax.set_ylim(-0.08 * np.pi, 0.08 * np.pi)
            ax.set_aspect("equal")
            ax.set_title(f"{title}: {len(pts):,} points; red outside, blue inside", fontsize=8)
        else:
            ax = fig.add_subplot(1, n, k + 1, projection="3d")
            poly = Poly3DCollection(cv[cf], facecolor=(0.85, 0.85, 0.9), edgecolor="k", linewidths=0.1)
            ax.add_collection3d(poly)
            lim = args.lim
            ax.set_xlim(-lim, lim)
            ax.set_ylim(-lim, lim)
            ax.set_zlim(-lim, lim)
            ax.view_init(elev=args.elev, azim=args.azim)
            ax.set_axis_off()
            ax.set_title(f"{title}\n{len(pts):,} points, {len(cf):,} control triangles", fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out)
    from PIL import Image

    Image.open(args.out).convert("RGB").quantize(colors=32).save(args.out, optimize=True)  # small PNG


def _stored_points(tw) -> np.ndarray:
    """The file's grid points in the normalized frame."""
    return np.asarray(tw.points, np.float64)


def cut_ratios(points: np.ndarray, ratio: float) -> float:
    """Median extent ratio (x over y, over `ratio`... reported raw) of the pieces of the plane z = 0 cut by the
    Delaunay tets of `points` (3-D): each tet with corners on both sides gives the crossing points of its edges."""
    from scipy.spatial import Delaunay

    tets = Delaunay(points).simplices
    side = points[tets, 2] > 0
    cross = side.any(1) & ~side.all(1)
    t = tets[cross]
    pts = points[t]  # (T,4,3)
    ii, jj = np.triu_indices(4, 1)
    a, b = pts[:, ii], pts[:, jj]
    za, zb = a[..., 2], b[..., 2]
    on = (za > 0) != (zb > 0)
    lam = za / np.where(on, za - zb, 1.0)
    q = a + lam[..., None] * (b - a)  # (T,6,3), valid where `on`
    qx = np.where(on, q[..., 0], np.nan)
    qy = np.where(on, q[..., 1], np.nan)
    ex = np.nanmax(qx, 1) - np.nanmin(qx, 1)
    ey = np.nanmax(qy, 1) - np.nanmin(qy, 1)
    centre = (np.abs(np.nanmean(qx, 1)) < 0.3) & (np.abs(np.nanmean(qy, 1)) < 0.3)
    return float(np.median(ex[centre] / np.maximum(ey[centre], 1e-12)))


def cmd_delaunay(args) -> None:
    """Does isotropic Delaunay keep an anisotropic point set's anisotropy? A flat patch (the plane z = 0, 1 x 1),
    points spaced h sqrt(r) along x and h / sqrt(r) along y, each offset across by U[SHELL_GAP, 1] x h with a random
    sign as the encoder's shell (width h, or `short`: h / sqrt(r)); the median x / y extent of the
    marching-tets pieces of the cut (r for an ideal stretched lattice)."""
    from tetweave_codec.fit.initialize import SHELL_GAP

    rng = np.random.default_rng(0)
    h = 0.03
    rows = []
    for r, shell in ((1.0, "h"), (2.0, "h"), (4.0, "h"), (4.0, "short")):
        hx, hy = h * math.sqrt(r), h / math.sqrt(r)
        width = h if shell == "h" else hy
        for kind in args.kinds.split(","):
            if kind == "metric blue noise":
                cand = rng.uniform(-0.7, 0.7, size=(40_000, 2))
                g = np.zeros((len(cand), 3, 3))
                g[:, 0, 0], g[:, 1, 1], g[:, 2, 2] = 1 / hx**2, 1 / hy**2, 1 / hy**2
                n_want = int(1.4 * 1.4 / (hx * hy))
                c3 = np.concatenate([cand, np.zeros((len(cand), 1))], 1)
                sel = metric_mis(c3, g, np.full(len(cand), hx), n_want, rng)
                xy = cand[sel]
            elif kind == "hex lattice":  # what Lloyd in a constant metric converges to: a stretched hexagonal lattice
                step = math.sqrt(2.0 / math.sqrt(3.0))  # unit density in the metric's coordinates
                gi, gj = np.meshgrid(np.arange(-60, 61), np.arange(-60, 61), indexing="ij")
                u = step * (gi + 0.5 * (gj % 2))
                w = step * math.sqrt(3.0) / 2.0 * gj
                xy = np.stack([u.ravel() * hx, w.ravel() * hy], 1)
                xy = xy[(np.abs(xy) < 0.7).all(1)]
            else:
                gx, gy = np.meshgrid(np.arange(-0.7, 0.7, hx), np.arange(-0.7, 0.7, hy), indexing="ij")
                xy = np.stack([gx.ravel(), gy.ravel()], 1)
                if kind == "jittered lattice":
                    xy = xy + rng.uniform(-0.15, 0.15, size=xy.shape) * np.array([hx, hy])
            z = rng.uniform(SHELL_GAP, 1.0, len(xy)) * width * rng.choice([-1.0, 1.0], len(xy))
            pts = np.concatenate([xy, z[:, None]], 1)
            rows.append((r, kind, len(pts), cut_ratios(pts, r)))
            print(f"| {r:g} | {shell} | {kind} | {len(pts)} | {rows[-1][3]:.2f} |", flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--mesh", required=True)
    r.add_argument("--size", type=int, default=None)
    r.add_argument("--points", type=int, default=None)
    r.add_argument("--mode", choices=("today", "aniso", "isodensity"), default="aniso")
    r.add_argument("--odt", choices=("iso", "metric", "off-aniso"), default="iso")
    r.add_argument("--eps", type=float, default=EPS)
    r.add_argument("--max-ratio", type=float, default=MAX_RATIO)
    r.add_argument("--quality", default="default")
    r.add_argument("--out", required=True)
    r.add_argument("--save", default=None)
    s = sub.add_parser("synth")
    s.add_argument("--out", required=True)
    t = sub.add_parser("table")
    t.add_argument("files", nargs="+")
    p = sub.add_parser("picture")
    p.add_argument("--mesh", required=True)
    p.add_argument("--files", nargs="+", required=True)
    p.add_argument("--titles", nargs="*")
    p.add_argument("--out", required=True)
    p.add_argument("--elev", type=float, default=25.0)
    p.add_argument("--azim", type=float, default=-60.0)
    p.add_argument("--dpi", type=int, default=110)
    p.add_argument("--lim", type=float, default=0.9)
    d = sub.add_parser("delaunay")
    d.add_argument("--kinds", default="metric blue noise,jittered lattice,lattice,hex lattice")
    args = ap.parse_args(argv)
    {"run": cmd_run, "synth": cmd_synth, "table": cmd_table, "picture": cmd_picture, "delaunay": cmd_delaunay}[
        args.cmd
    ](args)


if __name__ == "__main__":
    sys.exit(main())
