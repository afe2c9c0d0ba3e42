"""Fuzzing of the "exact" Delaunay backend (geometry/_delaunay_native.c) against an independent exact checker.

The checker (`check`) is written from the definition in geometry/delaunay.py's docstring and shares no code with
the C extension: Python integers throughout (numpy object arrays), no floating point. For integer points `cells`
and the backend's `tets` and `hull_faces` it checks:

* shape and canonical order (rule 5): each tet an even permutation with its smallest index first and the smallest
  of the other three second, tets sorted; hull faces rotated smallest first, sorted;
* vertices: exactly the first occurrence of every distinct point (rule 1) when the points span a volume, else
  no tets and no hull faces;
* every tet positively oriented, det[b - a, c - a, d - a] > 0 exactly;
* a proper complex: no oriented triangle in two tets, the triangles of one tet only (unpaired) are exactly the
  hull faces (so interior triangles are in two tets with opposite orientations);
* the hull faces are outward and supporting: no point strictly outside the plane of any of them;
* volume: the sum of the tets' volumes equals the convex hull's (exact, 6 x volume in integers, enclosed by the
  supporting hull faces; and within a relative 1e-9 of the volume of scipy Qhull's facets, a floating-point
  code that may miss slivers of nearly flat hull parts);
* regular under the perturbation (rules 2-4): for every interior triangle, the opposite vertex of one tet does not
  conflict with the other tet (Phi with the rank-ordered symbolic terms); for every hull edge between two coplanar
  hull faces, the opposite point is not inside the other face's perturbed circumcircle. Locally regular
  everywhere + a proper triangulation of the hull with every point a vertex = the regular triangulation.

Point sets (case i uses ``numpy.random.default_rng([seed, i])``, so ``--only i`` replays one): lattice subsets,
small full grids, cospherical sets (integer points on x^2 + y^2 + z^2 = r^2, scaled and shifted), coplanar and
collinear sets with a few points off the plane, clusters, uniform random points, points on the extremes 0 and
2^23 - 1, each with duplicates added in a third of the cases and shuffled.

    python -m tetweave_codec.benchmarks.delaunay_fuzz --cases 10000
    python -m tetweave_codec.benchmarks.delaunay_fuzz --only 1234 -v
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

MAX_COORD = (1 << 23) - 1
KINDS = ("lattice", "grid", "cospherical", "coplanar", "collinear", "cluster", "random", "extremes")

# ------------------------------------------------------------------------------------------------------------
# exact arithmetic on Python integers


def _obj(a) -> np.ndarray:
    return np.asarray(a, dtype=np.int64).astype(object)


def det3(u: np.ndarray, v: np.ndarray, w: np.ndarray):
    """det of the rows u, v, w: (..., 3) object arrays -> (...)."""
    return (
        u[..., 0] * (v[..., 1] * w[..., 2] - v[..., 2] * w[..., 1])
        - u[..., 1] * (v[..., 0] * w[..., 2] - v[..., 2] * w[..., 0])
        + u[..., 2] * (v[..., 0] * w[..., 1] - v[..., 1] * w[..., 0])
    )


def orient_det(a, b, c, d):
    """det[b - a, c - a, d - a] for (..., 3) object arrays."""
    return det3(b - a, c - a, d - a)


def _sign(x) -> int:
    return (x > 0) - (x < 0)


def conflicts(pa, pb, pc, pd, pe, ranks) -> bool:
    """Rule 3: does e conflict with the positively oriented tet (a, b, c, d)? p*: 3-tuples of ints; ranks: the
    five lexicographic ranks (a, b, c, d, e)."""
    pts = [pa, pb, pc, pd, pe]
    lift = [p[0] * p[0] + p[1] * p[1] + p[2] * p[2] for p in pts]

    def od(x):
        return orient_det(*(_obj(q) for q in x))

    o = od(pts[:4])
    repl = []
    for k in range(4):
        q = pts[:4]
        q = q[:k] + [pe] + q[k + 1 :]
        repl.append(od(q))
    phi0 = o * lift[4] - sum(repl[k] * lift[k] for k in range(4))
    if phi0 != 0:
        return phi0 < 0
    for k in sorted(range(5), key=lambda i: -ranks[i]):
        if k == 4:
            return False
        if repl[k] != 0:
            return repl[k] > 0
    raise AssertionError("not reached")


def conflicts_coplanar(pa, pb, pc, pq, ranks) -> bool:
    """Rule 4: q on the plane of the triangle (a, b, c): inside its perturbed circumcircle?"""
    a, b, c, q = (tuple(int(v) for v in p) for p in (pa, pb, pc, pq))
    u = [b[i] - a[i] for i in range(3)]
    v = [c[i] - a[i] for i in range(3)]
    n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
    drop = max(range(3), key=lambda i: (abs(n[i]), -i))
    i, j = [k for k in range(3) if k != drop]

    def o2(x, y, z):
        return (y[i] - x[i]) * (z[j] - x[j]) - (y[j] - x[j]) * (z[i] - x[i])

    def h(p):
        return p[0] * p[0] + p[1] * p[1] + p[2] * p[2]

    big = o2(a, b, c)
    assert big != 0
    repl = [o2(q, b, c), o2(a, q, c), o2(a, b, q)]
    phi0 = big * h(q) - repl[0] * h(a) - repl[1] * h(b) - repl[2] * h(c)
    s = _sign(big)
    if phi0 != 0:
        return s * phi0 < 0
    for k in sorted(range(4), key=lambda t: -ranks[t]):
        if k == 3:
            return False
        if repl[k] != 0:
            return _sign(repl[k]) == s
    raise AssertionError("not reached")


# ------------------------------------------------------------------------------------------------------------
# the checker


def distinct_points(cells: np.ndarray) -> tuple[list[int], dict[int, int]]:
    """(first, rank): the lowest index of each distinct point, and the lexicographic rank of each of those."""
    first: dict[tuple, int] = {}
    for i, p in enumerate(map(tuple, np.asarray(cells).tolist())):
        first.setdefault(p, i)
    order = sorted(first)
    return sorted(first.values()), {first[p]: r for r, p in enumerate(order)}


def spans_volume(cells: np.ndarray, first: list[int]) -> bool:
    pts = [tuple(int(v) for v in cells[i]) for i in first]
    if len(pts) < 4:
        return False
    a, b = pts[0], pts[1]
    u = [b[k] - a[k] for k in range(3)]
    c = None
    for p in pts[2:]:
        v = [p[k] - a[k] for k in range(3)]
        if u[1] * v[2] - u[2] * v[1] or u[2] * v[0] - u[0] * v[2] or u[0] * v[1] - u[1] * v[0]:
            c = p
            break
    if c is None:
        return False
    return any(orient_det(_obj(a), _obj(b), _obj(c), _obj(p)) != 0 for p in pts)


def canonical_tets(tets: np.ndarray) -> np.ndarray:
    """Rule 5's canonical form of positively oriented tets (even permutations only), sorted."""
    out = []
    even = [(0, 1, 2, 3), (1, 0, 3, 2), (2, 3, 0, 1), (3, 2, 1, 0)]
    for t in np.asarray(tets).tolist():
        w = [t[i] for i in even[int(np.argmin(t))]]
        rest = w[1:]
        j = int(np.argmin(rest))
        out.append([w[0]] + rest[j:] + rest[:j])
    out.sort()
    return np.array(out, dtype=np.int64).reshape(-1, 4)


def canonical_faces(faces: np.ndarray) -> np.ndarray:
    out = []
    for f in np.asarray(faces).tolist():
        j = int(np.argmin(f))
        out.append(f[j:] + f[:j])
    out.sort()
    return np.array(out, dtype=np.int64).reshape(-1, 3)


def _qhull_volume6(pts: np.ndarray) -> int | None:
    """6 x the convex hull's volume from scipy's Qhull facets, exactly (cones from one point); None if Qhull fails."""
    try:
        from scipy.spatial import ConvexHull, QhullError
    except ImportError:  # pragma: no cover
        return None
    try:
        hull = ConvexHull(pts.astype(np.float64))
    except (QhullError, ValueError):
        return None
    P = _obj(pts)
    s = hull.simplices
    o = P[0]
    return int(sum(abs(v) for v in det3(P[s[:, 0]] - o, P[s[:, 1]] - o, P[s[:, 2]] - o)))


def check(cells: np.ndarray, tets: np.ndarray, hull: np.ndarray, qhull: bool = True) -> list[str]:
    """Problems of (tets, hull) as the "exact" tetrahedralization of `cells` (empty list: correct)."""
    cells = np.asarray(cells, dtype=np.int64)
    tets = np.asarray(tets)
    hull = np.asarray(hull)
    if tets.ndim != 2 or tets.shape[1] != 4 or hull.ndim != 2 or hull.shape[1] != 3:
        return [f"bad shapes {tets.shape} {hull.shape}"]
    first, rank = distinct_points(cells)
    if not spans_volume(cells, first):
        return [] if len(tets) == 0 and len(hull) == 0 else ["tets for a set that spans no volume"]
    problems = []
    if not np.array_equal(np.unique(tets), np.array(first, dtype=np.int64)):
        problems.append("the tets' vertices are not the first occurrences of the distinct points")
        return problems
    if not np.array_equal(canonical_tets(tets), tets):
        problems.append("tets not in canonical order")
    if not np.array_equal(canonical_faces(hull), hull):
        problems.append("hull faces not in canonical order")
    P = _obj(cells)
    vol = orient_det(P[tets[:, 0]], P[tets[:, 1]], P[tets[:, 2]], P[tets[:, 3]])
    if not all(v > 0 for v in vol):
        problems.append(f"{sum(1 for v in vol if v <= 0)} tets not positively oriented")
        return problems
    # proper complex
    faces = {}
    outward = [(1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)]
    for t, tet in enumerate(tets.tolist()):
        for k, (i, j, m) in enumerate(outward):
            f = (tet[i], tet[j], tet[m])
            r = f.index(min(f))
            f = f[r:] + f[:r]
            if f in faces:
                problems.append(f"triangle {f} oriented the same way in two tets")
                return problems
            faces[f] = (t, tet[k])
    unpaired = {f for f in faces if (f[0], f[2], f[1]) not in faces}
    hull_set = {tuple(f) for f in hull.tolist()}
    if unpaired != hull_set or len(hull_set) != len(hull):
        problems.append(f"hull faces ({len(hull)}) are not the unpaired triangles ({len(unpaired)})")
        return problems
    # supporting, outward hull faces
    ids = np.array(first, dtype=np.int64)
    a, b, c = P[hull[:, 0]][:, None], P[hull[:, 1]][:, None], P[hull[:, 2]][:, None]
    side = orient_det(a, b, c, P[ids][None, :])
    if any(v > 0 for v in side.ravel()):
        problems.append("a point lies strictly outside a hull face")
        return problems
    # volume
    total = int(sum(vol))
    o = P[ids[0]]
    hull6 = int(sum(det3(P[hull[:, 0]] - o, P[hull[:, 1]] - o, P[hull[:, 2]] - o)))
    if total != hull6:
        problems.append(f"6 x volume {total} != {hull6} enclosed by the hull faces")
    if qhull:
        q6 = _qhull_volume6(cells[ids])
        # Qhull computes in floating point: its facets of nearly flat hull parts (points 1 apart at 2^23) may
        # miss a sliver, so its volume is compared to a relative 1e-9 only
        if q6 is not None and abs(q6 - total) > 1e-9 * total:
            problems.append(f"6 x volume {total} != {q6} of Qhull's convex hull")
    # regularity: interior triangles
    tl = tets.tolist()
    cl = [tuple(int(v) for v in p) for p in cells.tolist()]
    for f, (t, _opp) in faces.items():
        twin = (f[0], f[2], f[1])
        if twin not in faces or f > twin:
            continue
        _, e = faces[twin]
        tet = tl[t]
        if conflicts(*(cl[v] for v in tet), cl[e], [rank[v] for v in tet] + [rank[e]]):
            problems.append(f"tet {tet} conflicts with {e} across {f} (not locally Delaunay)")
            return problems
    # regularity on the hull: coplanar neighbouring hull faces
    edges = {}
    for f in hull.tolist():
        for k in range(3):
            edges[(f[k], f[(k + 1) % 3])] = f[(k + 2) % 3]
    for (u, v), w in edges.items():
        x = edges.get((v, u))
        if x is None:
            problems.append("hull faces do not form a closed surface")
            return problems
        if u > v:
            continue
        if orient_det(*(_obj(cl[i]) for i in (u, v, w, x))) == 0:
            if conflicts_coplanar(cl[u], cl[v], cl[w], cl[x], [rank[u], rank[v], rank[w], rank[x]]):
                problems.append(f"hull face {(u, v, w)} has {x} inside its perturbed circumcircle")
                return problems
    return problems


# ------------------------------------------------------------------------------------------------------------
# point sets


def _sphere_points(r: int) -> np.ndarray:
    g = np.arange(-r, r + 1)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    keep = x * x + y * y + z * z == r * r
    return np.stack([x[keep], y[keep], z[keep]], 1)


def make_points(rng: np.random.Generator, kind: str) -> np.ndarray:
    """One point set of `kind` (KINDS), (N, 3) int64 in [0, 2^23), N of 0..~60."""
    if kind == "lattice":
        k = int(rng.integers(2, 5))
        g = np.stack(np.meshgrid(*[np.arange(k)] * 3, indexing="ij"), -1).reshape(-1, 3)
        pts = g[rng.random(len(g)) < rng.uniform(0.3, 1.0)]
        scale = int(rng.choice([1, 2, 7, 1 << 10, 1 << 20]))
    elif kind == "grid":
        dims = rng.integers(1, 5, 3)
        pts = np.stack(np.meshgrid(*[np.arange(d) for d in dims], indexing="ij"), -1).reshape(-1, 3)
        scale = int(rng.choice([1, 3, 1 << 12, 1 << 20]))
    elif kind == "cospherical":
        r = int(rng.choice([1, 2, 3, 5, 7, 9]))
        pts = _sphere_points(r)
        if len(pts) > 40:
            pts = pts[rng.choice(len(pts), 40, replace=False)]
        if rng.random() < 0.3:
            pts = np.vstack([pts, [[0, 0, 0]]])  # the centre too
        scale = int(rng.choice([1, 2, 1 << 10, 1 << 18]))
        pts = pts + r
    elif kind == "coplanar":
        n = int(rng.integers(3, 30))
        uv = rng.integers(0, 6, (n, 2))
        u, v = rng.integers(-2, 3, 3), rng.integers(-2, 3, 3)
        pts = uv[:, :1] * u + uv[:, 1:] * v
        off = int(rng.integers(0, 4))
        if off:
            pts = np.vstack([pts, rng.integers(-10, 10, (off, 3))])
        pts = pts - pts.min(0)
        scale = int(rng.choice([1, 5, 1 << 15]))
    elif kind == "collinear":
        n = int(rng.integers(1, 20))
        pts = np.arange(n)[:, None] * rng.integers(-3, 4, 3)
        off = int(rng.integers(0, 3))
        if off:
            pts = np.vstack([pts, rng.integers(-5, 5, (off, 3))])
        pts = pts - pts.min(0)
        scale = int(rng.choice([1, 1 << 16]))
    elif kind == "cluster":
        n = int(rng.integers(4, 50))
        centre = rng.integers(0, MAX_COORD, 3)
        spread = int(rng.choice([1, 2, 3, 100, 1 << 20]))
        pts = np.clip(centre + rng.integers(-spread, spread + 1, (n, 3)), 0, MAX_COORD)
        scale = 1
    elif kind == "extremes":
        n = int(rng.integers(4, 30))
        pts = rng.choice([0, 1, MAX_COORD - 1, MAX_COORD, MAX_COORD // 2], (n, 3))
        scale = 1
    else:
        n = int(rng.integers(0, 50))
        pts = rng.integers(0, MAX_COORD + 1, (n, 3))
        scale = 1
    pts = np.asarray(pts, dtype=np.int64).reshape(-1, 3) * scale
    span = int(pts.max()) if len(pts) else 0
    if span > MAX_COORD:
        pts = pts // (span // MAX_COORD + 1)
    if len(pts) and span * 2 < MAX_COORD and rng.random() < 0.5:
        pts = pts + rng.integers(0, MAX_COORD - span, 3)  # a translation changes no predicate
    if len(pts) and rng.random() < 0.33:
        pts = np.vstack([pts, pts[rng.integers(0, len(pts), int(rng.integers(1, 6)))]])
    return pts[rng.permutation(len(pts))]


def run_case(seed: int, i: int, verbose: bool = False) -> tuple[str, list[str], int]:
    from tetweave_codec.errors import TopologyError
    from tetweave_codec.geometry.delaunay import tetrahedralize_cells

    rng = np.random.default_rng([seed, i])
    kind = KINDS[int(rng.integers(len(KINDS)))]
    pts = make_points(rng, kind)
    try:
        tz = tetrahedralize_cells(pts)
    except (TopologyError, ValueError, MemoryError) as exc:
        return kind, [f"{type(exc).__name__}: {exc}"], len(pts)
    problems = check(pts, tz.tets, tz.hull_faces)
    if verbose:
        print(f"case {i}: {kind}, {len(pts)} points, {len(tz.tets)} tets, {len(tz.hull_faces)} hull faces")
        print(repr(pts.tolist()))
    return kind, problems, len(pts)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", type=int, default=None, help="run one case (its index) and print it")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    cases = [args.only] if args.only is not None else range(args.cases)
    start = time.perf_counter()
    failures = 0
    per_kind: dict[str, int] = {}
    points = 0
    for i in cases:
        kind, problems, n = run_case(args.seed, i, args.verbose or args.only is not None)
        per_kind[kind] = per_kind.get(kind, 0) + 1
        points += n
        if problems:
            failures += 1
            print(f"FAIL case {i} ({kind}, {n} points): {'; '.join(problems[:3])}")
    kinds = ", ".join(f"{k} {per_kind[k]}" for k in KINDS if k in per_kind)
    print(
        f"{len(cases)} point sets ({kinds}; {points} points), {failures} failures, "
        f"{time.perf_counter() - start:.1f} s (seed {args.seed})"
    )
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
