"""An independent ray caster (numpy only): which points of a surface a viewer outside sees.

A point on a surface is seen when, for some of DIRECTIONS directions on a Fibonacci sphere, the ray from it
towards a viewer far away in that direction leaves every triangle behind (none hit at a distance above `eps`; the
point's own face is skipped). Orientation plays no part: open sheets are seen from both sides, closed parts only
from outside (a ray from inside always leaves through a face). A crevice open only within a cone narrower than
the directions' spacing (about 2 / sqrt(DIRECTIONS) radians) counts as hidden.

Per direction the triangles are projected onto the plane across it and binned in a uniform grid (a triangle into
every cell its projected box covers; triangles covering more than BIG_CELLS cells are tested against every ray);
a ray is tested against its cell's triangles: inside the projected triangle (edge functions, edges inclusive) and
its plane's depth there beyond the ray's origin. Shares nothing with tetweave_codec (fit.visible renders
offscreen buffers; this casts exact rays).

    seen = visible(vertices, faces, points, point_faces)       # (P,) bool
    points, faces_of = visible_samples(vertices, faces, n)      # area-uniform samples a viewer sees
"""

from __future__ import annotations

import numpy as np

DIRECTIONS = 64
BIG_CELLS = 256
PAIR_CHUNK = 4_000_000  # (ray, triangle) pairs tested at once


def fibonacci_directions(n: int = DIRECTIONS) -> np.ndarray:
    """(n,3) unit vectors spread evenly over the sphere."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(1.0 - z * z)
    a = np.pi * (3.0 - np.sqrt(5.0)) * k
    return np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


def _basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(d, u)


class Caster:
    """Rays against the triangles (vertices (V,3), faces (F,3)); `blocked` per direction."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.v = np.asarray(vertices, dtype=np.float64)
        self.f = np.asarray(faces, dtype=np.int64)
        lo, hi = self.v.min(axis=0), self.v.max(axis=0)
        self.size = float(np.linalg.norm(hi - lo))
        self.cells = int(np.clip(1.5 * np.sqrt(len(self.f)), 16, 2048))

    def blocked(self, origins: np.ndarray, direction: np.ndarray, skip: np.ndarray | None = None,
                eps: float | None = None) -> np.ndarray:  # fmt: skip
        """(P,) bool: the ray origins (P,3) + t direction (unit) hits a triangle at t > eps (default 1e-7 of the
        mesh's diagonal), triangles skip (P,) (-1: none) not counted."""
        eps = 1e-7 * self.size if eps is None else eps
        d = np.asarray(direction, dtype=np.float64)
        u, w = _basis(d)
        pu, pw, pd = self.v @ u, self.v @ w, self.v @ d
        tu, tw, td = pu[self.f], pw[self.f], pd[self.f]  # (F,3)
        area2 = (tu[:, 1] - tu[:, 0]) * (tw[:, 2] - tw[:, 0]) - (tu[:, 2] - tu[:, 0]) * (tw[:, 1] - tw[:, 0])
        live = np.abs(area2) > 1e-14 * self.size**2  # edge-on triangles occlude nothing
        ou, ow, od = origins @ u, origins @ w, origins @ d
        skip = np.full(len(origins), -1, dtype=np.int64) if skip is None else np.asarray(skip, dtype=np.int64)
        lo_u, lo_w = pu.min(), pw.min()
        cell = max(pu.max() - lo_u, pw.max() - lo_w) / self.cells * (1 + 1e-9)
        n = self.cells
        i0 = np.clip(((tu.min(axis=1) - lo_u) / cell).astype(np.int64), 0, n - 1)
        i1 = np.clip(((tu.max(axis=1) - lo_u) / cell).astype(np.int64), 0, n - 1)
        j0 = np.clip(((tw.min(axis=1) - lo_w) / cell).astype(np.int64), 0, n - 1)
        j1 = np.clip(((tw.max(axis=1) - lo_w) / cell).astype(np.int64), 0, n - 1)
        span = (i1 - i0 + 1) * (j1 - j0 + 1)
        big = np.flatnonzero(live & (span > BIG_CELLS))
        small = np.flatnonzero(live & (span <= BIG_CELLS))
        # every (cell, triangle) of the small triangles, sorted by cell (CSR)
        cnt = span[small]
        tri = np.repeat(small, cnt)
        local = np.arange(len(tri)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        width = (i1 - i0 + 1)[tri]
        ci = i0[tri] + local % width
        cj = j0[tri] + local // width
        key = ci * n + cj
        order = np.argsort(key, kind="stable")
        tri, key = tri[order], key[order]
        start = np.searchsorted(key, np.arange(n * n + 1))
        # each ray's cell (rays outside the grid meet no small triangle)
        ri = np.floor((ou - lo_u) / cell).astype(np.int64)
        rj = np.floor((ow - lo_w) / cell).astype(np.int64)
        inside = (ri >= 0) & (ri < n) & (rj >= 0) & (rj < n)
        rc = np.where(inside, ri * n + rj, 0)
        count = np.where(inside, start[rc + 1] - start[rc], 0)
        hit = np.zeros(len(origins), dtype=bool)
        rays = np.arange(len(origins))
        for chunk in _chunks(count):
            c = count[chunk]
            ray = np.repeat(rays[chunk], c)
            k = np.arange(len(ray)) - np.repeat(np.cumsum(c) - c, c)
            t = tri[start[rc[ray]] + k]
            hit |= self._test(ray, t, tu, tw, td, area2, ou, ow, od, skip, eps, len(origins))
        for b in np.array_split(big, max(1, len(big) * len(origins) // PAIR_CHUNK + 1)):
            if not len(b):
                continue
            ray = np.repeat(rays, len(b))
            t = np.tile(b, len(origins))
            hit |= self._test(ray, t, tu, tw, td, area2, ou, ow, od, skip, eps, len(origins))
        return hit

    @staticmethod
    def _test(ray, t, tu, tw, td, area2, ou, ow, od, skip, eps, n_rays) -> np.ndarray:
        """(n_rays,) bool: some pair (ray, t) is a hit beyond eps."""
        x, y = ou[ray], ow[ray]
        a = area2[t]
        su, sw = tu[t], tw[t]
        # barycentric weights of (x, y) in the projected triangle, signed by its winding
        l0 = ((su[:, 1] - x) * (sw[:, 2] - y) - (su[:, 2] - x) * (sw[:, 1] - y)) / a
        l1 = ((su[:, 2] - x) * (sw[:, 0] - y) - (su[:, 0] - x) * (sw[:, 2] - y)) / a
        l2 = 1.0 - l0 - l1
        tol = -1e-12
        ok = (l0 >= tol) & (l1 >= tol) & (l2 >= tol) & (t != skip[ray])
        depth = l0 * td[t, 0] + l1 * td[t, 1] + l2 * td[t, 2]
        ok &= depth > od[ray] + eps
        out = np.zeros(n_rays, dtype=bool)
        out[ray[ok]] = True
        return out


def _chunks(count: np.ndarray):
    """Index ranges of rays whose candidate pairs sum to at most PAIR_CHUNK (at least one ray each)."""
    total = np.concatenate([[0], np.cumsum(count)])
    lo, n = 0, len(count)
    while lo < n:
        hi = int(np.searchsorted(total, total[lo] + PAIR_CHUNK, side="right")) - 1
        hi = min(max(hi, lo + 1), n)
        yield np.arange(lo, hi)
        lo = hi


def visible(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, point_faces: np.ndarray | None = None,
            directions: int = DIRECTIONS, caster: Caster | None = None) -> np.ndarray:  # fmt: skip
    """(P,) bool: points (P,3) on the mesh (on faces point_faces (P,), skipped by their own rays) that a viewer
    sees from some direction (module docstring)."""
    caster = caster or Caster(vertices, faces)
    seen = np.zeros(len(points), dtype=bool)
    for d in fibonacci_directions(directions):
        todo = np.flatnonzero(~seen)
        if not len(todo):
            break
        skip = None if point_faces is None else point_faces[todo]
        seen[todo] = ~caster.blocked(points[todo], d, skip)
    return seen


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int = 0):
    """(points (n,3), face (n,)): area-uniform random points on the triangles (numpy's Generator, `seed`)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    rng = np.random.default_rng(seed)
    face = rng.choice(len(f), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    pts = (1 - s)[:, None] * a[face] + (s * (1 - r2))[:, None] * b[face] + (s * r2)[:, None] * c[face]
    return pts, face


def visible_samples(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int = 0, directions: int = DIRECTIONS):
    """(points (P,3), face (P,), seen (n,)): of n area-uniform samples of the mesh, those a viewer sees (P <= n;
    uniform over the seen area), their faces, and which of the n were seen."""
    pts, face = sample_surface(vertices, faces, n, seed)
    seen = visible(vertices, faces, pts, face, directions)
    return pts[seen], face[seen], seen
