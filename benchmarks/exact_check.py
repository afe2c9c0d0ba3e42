"""An independent self-intersection check: exact, and sharing no code with the decoder's predicate.

The decoder promises that no two faces of a decoded mesh meet except where they share vertices
(geometry/intersections.py decides that in floating point, fast). This module decides the same question another
way, for tests and the fuzz (`benchmarks/fuzz.py`): every float64 coordinate is a dyadic rational, so each
orientation below is evaluated exactly in Python integers where a floating-point filter with a proven error bound
cannot settle its sign.

What counts (closed triangles, so touching counts as much as crossing):

* faces sharing no vertex index: any common point;
* faces sharing exactly one vertex index: any common point other than that vertex (one face's edge opposite the
  shared vertex meets the other face: this covers folds, coplanar or not);
* faces sharing an edge: never (their only contact beyond the edge would be an exactly coplanar fold);
* faces whose three corners are exactly collinear (zero area) are not tested; `check` counts them.

Broad phase: a uniform grid over the faces' bounding boxes (numpy), then the boxes' overlap; narrow phase: a
float64 filter (all of one face's free corners strictly on one side of the other's plane, or every edge shown
to miss the other face, each sign beyond 2^-36 m^3, m the pair's largest coordinate spread, about 300 times the
worst rounding of an orientation of points that far apart), and exact integer predicates for the pairs it
leaves. Slow in pure Python only where many pairs are nearly touching; fine for tests' meshes (tens of
thousands of faces) and a few seconds for 320K faces.

    python -m tetweave_codec.benchmarks.exact_check FILE.tw [FILE.tw ...] [--level control|smoothed|full]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

import numpy as np

# |orient(a, b, c, d)| computed in float64 errs by at most ~384 u m^3 (u = 2^-53; eight roundings per term, six
# terms of |differences| <= m); signs beyond this bound are certain.
_FILTER = 2.0**-36


@dataclass
class CheckResult:
    """pairs (P, 2) int64: face pairs (lower index first) that meet other than at a shared vertex; degenerate:
    faces with exactly collinear corners (not tested); candidates: pairs with overlapping boxes and at most one
    shared vertex; exact: pairs the float filter left to the exact predicates."""

    pairs: np.ndarray
    degenerate: int
    candidates: int
    exact: int

    @property
    def faces(self) -> int:
        """Faces in at least one pair."""
        return len(np.unique(self.pairs)) if len(self.pairs) else 0


# ------------------------------------------------------------------------------------------------------------
# broad phase


def _box_pairs(lo: np.ndarray, hi: np.ndarray, cap: int = 20_000_000) -> np.ndarray:
    """(P, 2) pairs i < j of boxes lo/hi (n, 3) that overlap (closed), through a uniform grid."""
    n = len(lo)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    size = (hi - lo).max(axis=1)
    cell = float(np.percentile(size, 75))
    if not cell > 0:
        cell = float(size.max()) or 1.0
    while True:
        base = lo.min(axis=0)
        first = np.floor((lo - base) / cell).astype(np.int64)
        last = np.floor((hi - base) / cell).astype(np.int64)
        count = (last - first + 1).prod(axis=1)
        if count.sum() <= 16 * n + 100_000:
            break
        cell *= 2.0
    owner = np.repeat(np.arange(n), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    span = last - first + 1
    sx, sy = span[owner, 0], span[owner, 1]
    cx = first[owner, 0] + k % sx
    cy = first[owner, 1] + (k // sx) % sy
    cz = first[owner, 2] + k // (sx * sy)
    dim = last.max(axis=0) + 1
    key = (cx * dim[1] + cy) * dim[2] + cz
    order = np.lexsort((owner, key))
    key, owner = key[order], owner[order]
    cuts = np.flatnonzero(np.diff(key)) + 1
    starts = np.concatenate([[0], cuts])
    sizes = np.diff(np.concatenate([starts, [len(key)]]))
    out = []
    total = 0
    every = np.arange(len(key))
    later = np.repeat(starts + sizes, sizes) - 1 - every  # elements after each one in its cell
    pos = every[later > 0]
    # pairs within each cell: for each offset d, element e pairs with e + d while both are in the same cell
    for d in range(1, int(sizes.max())):
        pos = pos[later[pos] >= d]
        if not len(pos):
            break
        a, b = owner[pos], owner[pos + d]
        meet = np.all((lo[a] <= hi[b]) & (lo[b] <= hi[a]), axis=1)  # boxes that overlap, before the dedupe
        a, b = a[meet], b[meet]
        out.append(np.minimum(a, b) * n + np.maximum(a, b))  # one int64 key per pair
        total += len(pos)
        if total > cap:
            raise RuntimeError("exact_check: too many candidate pairs")
    if not out:
        return np.zeros((0, 2), np.int64)
    keys = np.sort(np.concatenate(out))
    if not len(keys):
        return np.zeros((0, 2), np.int64)
    keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])]
    return np.stack([keys // n, keys % n], axis=1)


# ------------------------------------------------------------------------------------------------------------
# float filter (vectorized): True where a pair is certainly apart


def _vol(a, b, c, d):
    """orient(a, b, c, d) = ((b - a) x (c - a)) . (d - a) in float64, rows of (P, 3)."""
    u, w, x = b - a, c - a, d - a
    return (
        x[:, 0] * (u[:, 1] * w[:, 2] - u[:, 2] * w[:, 1])
        + x[:, 1] * (u[:, 2] * w[:, 0] - u[:, 0] * w[:, 2])
        + x[:, 2] * (u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0])
    )


def _edge_misses(p, q, t, bound):
    """Segment pq certainly misses closed triangle t (P, 3, 3): both ends beyond `bound` on one side of its
    plane, or the line through p and q passes certainly outside it (mixed signs beyond `bound`)."""
    sp, sq = _vol(t[:, 0], t[:, 1], t[:, 2], p), _vol(t[:, 0], t[:, 1], t[:, 2], q)
    side = ((sp > bound) & (sq > bound)) | ((sp < -bound) & (sq < -bound))
    s = np.stack([_vol(p, q, t[:, i], t[:, (i + 1) % 3]) for i in range(3)], axis=1)
    outside = (s.max(axis=1) > bound) & (s.min(axis=1) < -bound)
    return side | outside


def _apart(ta, tb, free_a, free_b, m):
    """(P,) True where triangles ta, tb (P, 3, 3) certainly meet nowhere beyond their shared vertex. free_*:
    (P, 3) bool, the corners not shared (all of them for pairs sharing nothing); m (P,): the pair's largest
    coordinate spread (of the union of their boxes)."""
    bound = _FILTER * m * m * m
    apart = np.zeros(len(ta), bool)
    for x, y, free in ((ta, tb, free_a), (tb, ta, free_b)):
        o = np.stack([_vol(y[:, 0], y[:, 1], y[:, 2], x[:, i]) for i in range(3)], axis=1)
        pos = np.where(free, o > bound[:, None], True).all(axis=1)
        neg = np.where(free, o < -bound[:, None], True).all(axis=1)
        apart |= pos | neg
    # every relevant edge misses: pairs sharing nothing test all six edges, pairs sharing a vertex the two
    # opposite edges (an edge with a shared end is not tested: it meets the other face at that vertex)
    rest = ~apart
    if rest.any():
        ok = np.ones(rest.sum(), bool)
        for x, y, free in ((ta[rest], tb[rest], free_a[rest]), (tb[rest], ta[rest], free_b[rest])):
            for k in range(3):
                k2 = (k + 1) % 3
                use = free[:, k] & free[:, k2]
                miss = _edge_misses(x[:, k], x[:, k2], y, bound[rest])
                ok &= ~use | miss
        apart[np.flatnonzero(rest)[ok]] = True
    return apart


# ------------------------------------------------------------------------------------------------------------
# exact predicates on integers


def _ints(points) -> list[tuple[int, int, int]]:
    """Float64 points as integer triples on one common power-of-two scale (exact)."""
    ratios = [float(x).as_integer_ratio() for p in points for x in p]
    den = max(d for _, d in ratios)
    vals = [n * (den // d) for n, d in ratios]
    return [tuple(vals[3 * i : 3 * i + 3]) for i in range(len(points))]


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _cross(u, w):
    return (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])


def _dot(u, w):
    return u[0] * w[0] + u[1] * w[1] + u[2] * w[2]


def _orient(a, b, c, d) -> int:
    return _dot(_cross(_sub(b, a), _sub(c, a)), _sub(d, a))


def _sign(x: int) -> int:
    return (x > 0) - (x < 0)


def _cross2(o, a, b) -> int:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _in_closed_2d(p, t) -> bool:
    s = [_sign(_cross2(t[i], t[(i + 1) % 3], p)) for i in range(3)]
    return not (1 in s and -1 in s)


def _segments_meet_2d(p, q, r, s) -> bool:
    d1, d2 = _sign(_cross2(p, q, r)), _sign(_cross2(p, q, s))
    if d1 == 0 and d2 == 0:  # collinear: the two intervals overlap on both axes
        return all(max(min(p[k], q[k]), min(r[k], s[k])) <= min(max(p[k], q[k]), max(r[k], s[k])) for k in (0, 1))
    d3, d4 = _sign(_cross2(r, s, p)), _sign(_cross2(r, s, q))
    return d1 * d2 <= 0 and d3 * d4 <= 0


def segment_meets_triangle(p, q, a, b, c) -> bool:
    """Exact: the closed segment pq and the closed triangle abc (integer or Fraction coordinates, abc not
    collinear, p != q) have a common point."""
    sp, sq = _sign(_orient(a, b, c, p)), _sign(_orient(a, b, c, q))
    if sp * sq > 0:
        return False
    if sp == 0 and sq == 0:  # in the plane: drop the axis where the normal is largest
        n = _cross(_sub(b, a), _sub(c, a))
        drop = max(range(3), key=lambda k: abs(n[k]))
        keep = [k for k in range(3) if k != drop]

        def flat(x):
            return (x[keep[0]], x[keep[1]])

        t = (flat(a), flat(b), flat(c))
        p2, q2 = flat(p), flat(q)
        if _in_closed_2d(p2, t) or _in_closed_2d(q2, t):
            return True
        return any(_segments_meet_2d(p2, q2, t[i], t[(i + 1) % 3]) for i in range(3))
    s = [_sign(_orient(p, q, x, y)) for x, y in ((a, b), (b, c), (c, a))]
    return not (1 in s and -1 in s)


def triangles_meet(a, b, shared: tuple[int, int] | None = None) -> bool:
    """Exact: closed triangles a, b (three points each) meet; with `shared` = (i, j) (corner i of a is corner j
    of b, the same vertex), meet anywhere else than there."""
    if shared is None:
        return any(segment_meets_triangle(a[i], a[(i + 1) % 3], *b) for i in range(3)) or any(
            segment_meets_triangle(b[i], b[(i + 1) % 3], *a) for i in range(3)
        )
    i, j = shared
    return segment_meets_triangle(a[(i + 1) % 3], a[(i + 2) % 3], *b) or segment_meets_triangle(
        b[(j + 1) % 3], b[(j + 2) % 3], *a
    )


def _collinear(t) -> bool:
    return _cross(_sub(t[1], t[0]), _sub(t[2], t[0])) == (0, 0, 0)


# ------------------------------------------------------------------------------------------------------------


def check(vertices: np.ndarray, faces: np.ndarray) -> CheckResult:
    """Every pair of faces of (vertices (V, 3) float64, faces (F, 3)) that meet other than at a shared vertex
    (module docstring)."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if not np.isfinite(v).all():
        raise ValueError("exact_check: non-finite vertices")
    tri = v[f]
    # exactly collinear corners: an exact test per face where the float cross product is not clearly nonzero
    u, w = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    cr = np.abs(np.cross(u, w)).max(axis=1)
    m = (tri.max(axis=1) - tri.min(axis=1)).max(axis=1)
    unsure = np.flatnonzero(~(cr > 2.0**-40 * m * m))
    degenerate = np.zeros(len(f), bool)
    for i in unsure:
        degenerate[i] = _collinear(_ints(tri[i]))
    good = np.flatnonzero(~degenerate)
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    pairs = good[_box_pairs(lo[good], hi[good])] if len(good) > 1 else np.zeros((0, 2))
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    fa, fb = f[pairs[:, 0]], f[pairs[:, 1]]
    eq = fa[:, :, None] == fb[:, None, :]  # (P, 3, 3): corner i of a is corner j of b
    shared = eq.any(axis=2).sum(axis=1)
    pairs, eq = pairs[shared <= 1], eq[shared <= 1]
    free_a, free_b = ~eq.any(axis=2), ~eq.any(axis=1)
    i, j = pairs[:, 0], pairs[:, 1]
    spread = (np.maximum(hi[i], hi[j]) - np.minimum(lo[i], lo[j])).max(axis=1)
    apart = _apart(tri[i], tri[j], free_a, free_b, spread) if len(pairs) else np.zeros(0, bool)
    hits = []
    for k in np.flatnonzero(~apart):
        i, j = pairs[k]
        pts = _ints(np.concatenate([tri[i], tri[j]]))
        a, b = pts[:3], pts[3:]
        where = np.argwhere(eq[k])
        sh = (int(where[0, 0]), int(where[0, 1])) if len(where) else None
        if triangles_meet(a, b, sh):
            hits.append((i, j))
    found = np.array(sorted(hits), dtype=np.int64).reshape(-1, 2)
    return CheckResult(found, int(degenerate.sum()), len(pairs), int((~apart).sum()))


def main(argv: list[str] | None = None) -> int:
    from tetweave_codec.decoder import LEVELS, decode_detailed

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+")
    parser.add_argument("--level", choices=LEVELS, default="full")
    args = parser.parse_args(argv)
    bad = 0
    for path in args.files:
        with open(path, "rb") as fh:
            result = decode_detailed(fh.read(), level=args.level)
        r = check(result.vertices, result.faces)
        bad += len(r.pairs) > 0
        print(
            f"{path}: {len(result.faces)} faces, {len(r.pairs)} pairs meeting ({r.faces} faces), "
            f"{r.degenerate} degenerate, {r.candidates} candidates, {r.exact} exact"
        )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
