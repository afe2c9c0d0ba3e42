"""The "exact" Delaunay backend (geometry/_delaunay_native.c) against its definition (geometry/delaunay.py's
docstring): an independent exact checker (benchmarks/delaunay_fuzz.py, Python integers), a second, deliberately
simple implementation written from the definition alone (`brute_force`, below: every 4-subset whose perturbed
circumsphere holds no other point), TetGen on points in general position, property tests and hostile inputs."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tetweave_codec.benchmarks.delaunay_fuzz import check, make_points
from tetweave_codec.errors import TopologyError
from tetweave_codec.formats import quantize as Q
from tetweave_codec.geometry import delaunay as dl
from tetweave_codec.geometry.delaunay import snap_to_lattice, tetrahedralize, tetrahedralize_cells

TOP = (1 << dl.MAX_BITS) - 1

# ------------------------------------------------------------------------------------------------------------
# the second implementation: brute force from the definition


def _det(u, v, w):
    return (
        u[..., 0] * (v[..., 1] * w[..., 2] - v[..., 2] * w[..., 1])
        - u[..., 1] * (v[..., 0] * w[..., 2] - v[..., 2] * w[..., 0])
        + u[..., 2] * (v[..., 0] * w[..., 1] - v[..., 1] * w[..., 0])
    )


def brute_force(cells) -> tuple[np.ndarray, np.ndarray]:
    """(tets, hull_faces) in the canonical order, from rules 1-5 by exhaustion: O(M^5)."""
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    seen: dict[tuple, int] = {}
    for i, p in enumerate(map(tuple, cells.tolist())):
        seen.setdefault(p, i)
    ids = np.array(sorted(seen.values()), dtype=np.int64)  # rule 1: first occurrences
    rank = {seen[p]: r for r, p in enumerate(sorted(seen))}  # rule 2: lexicographic ranks
    m = len(ids)
    empty = np.zeros((0, 4), np.int64), np.zeros((0, 3), np.int64)
    if m < 4:
        return empty
    pts = cells[ids]
    pts = pts - pts.min(0)  # a translation changes no predicate; small coordinates fit int64 below
    small = int(pts.max()) < (1 << 11)  # |Phi| < 90 * c^5 < 2^63 for c < 2^11
    P = pts if small else pts.astype(object)
    rk = np.array([rank[i] for i in ids.tolist()])
    quads = np.array(list(itertools.combinations(range(m), 4)), dtype=np.int64)
    vol = _det(P[quads[:, 1]] - P[quads[:, 0]], P[quads[:, 2]] - P[quads[:, 0]], P[quads[:, 3]] - P[quads[:, 0]])
    nonzero = np.array([v != 0 for v in vol], dtype=bool)
    quads, vol = quads[nonzero], vol[nonzero]
    neg = np.array([v < 0 for v in vol], dtype=bool)
    quads[neg] = quads[neg][:, [1, 0, 2, 3]]  # positively oriented
    lift = (P * P).sum(1)
    empty_sphere = np.ones(len(quads), dtype=bool)
    corners = [P[quads[:, k]] for k in range(4)]
    o = _det(corners[1] - corners[0], corners[2] - corners[0], corners[3] - corners[0])
    for e in range(m):
        pe = np.broadcast_to(P[e], corners[0].shape)
        repl = []
        for k in range(4):
            c = list(corners)
            c[k] = pe
            repl.append(_det(c[1] - c[0], c[2] - c[0], c[3] - c[0]))
        phi = o * lift[e] - sum(repl[k] * lift[quads[:, k]] for k in range(4))
        inside = np.array([v < 0 for v in phi], dtype=bool)
        for j in np.flatnonzero(np.array([v == 0 for v in phi], dtype=bool)).tolist():
            if e in quads[j]:
                continue
            # rule 3's symbolic terms: in descending rank, e -> outside, a vertex with o != 0 -> inside iff o > 0
            order = sorted([(rk[quads[j, k]], k) for k in range(4)] + [(rk[e], 4)], reverse=True)
            for _, k in order:
                if k == 4:
                    break
                if repl[k][j] != 0:
                    inside[j] = repl[k][j] > 0
                    break
        inside[(quads == e).any(1)] = False
        empty_sphere &= ~inside
    tets = ids[quads[empty_sphere]]
    faces: dict[tuple, int] = {}
    for t in tets.tolist():
        for f in ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)):  # outward faces of a positive tet
            tri = tuple(t[i] for i in f)
            faces[min(tri[r:] + tri[:r] for r in range(3))] = 1
    hull = [f for f in faces if min((f[0], f[2], f[1])[r:] + (f[0], f[2], f[1])[:r] for r in range(3)) not in faces]
    even = [p for p in itertools.permutations(range(4)) if _parity(p) == 0]
    canon = sorted(min(tuple(t[i] for i in p) for p in even) for t in tets.tolist())
    return np.array(canon, np.int64).reshape(-1, 4), np.array(sorted(hull), np.int64).reshape(-1, 3)


def _parity(p) -> int:
    return sum(1 for i in range(len(p)) for j in range(i + 1, len(p)) if p[i] > p[j]) % 2


def _grid(*dims) -> np.ndarray:
    return np.stack(np.meshgrid(*[np.arange(d) for d in dims], indexing="ij"), -1).reshape(-1, 3)


def _sphere(r: int) -> np.ndarray:
    g = np.arange(-r, r + 1)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    keep = x * x + y * y + z * z == r * r
    return np.stack([x[keep], y[keep], z[keep]], 1) + r


def _assert_same(cells):
    tz = tetrahedralize_cells(cells)
    assert check(cells, tz.tets, tz.hull_faces) == []
    ref_tets, ref_hull = brute_force(cells)
    np.testing.assert_array_equal(tz.tets, ref_tets)
    np.testing.assert_array_equal(tz.hull_faces, ref_hull)
    return tz


# ------------------------------------------------------------------------------------------------------------
# identical to the brute force


@pytest.mark.parametrize(
    "dims", [(2, 2, 2), (3, 3, 3), (3, 3, 2), (4, 3, 2), (2, 2, 5), (3, 2, 1), (4, 4, 1), (1, 1, 6), (2, 1, 1)]
)
@pytest.mark.parametrize("scale, shift", [(1, 0), (1 << 20, 12345), (3, 7)])
def test_lattices_match_brute_force(dims, scale, shift):
    cells = _grid(*dims) * scale + shift
    tz = _assert_same(cells)
    assert (len(tz.tets) > 0) == (min(dims) > 1)


@pytest.mark.parametrize("r", [1, 2, 3, 5])
@pytest.mark.parametrize("centre", [False, True])
def test_cospherical_sets_match_brute_force(r, centre):
    cells = _sphere(r)
    if centre:
        cells = np.vstack([cells, [[r, r, r]]])
    cells = cells[np.random.default_rng(r).permutation(len(cells))][:40]
    _assert_same(cells)


def test_coplanar_points_on_the_hull_match_brute_force():
    rng = np.random.default_rng(5)
    base = np.column_stack([_grid(5, 4, 1)[:, :2], np.zeros(20, np.int64)])  # a 5 x 4 grid on the plane z = 0
    for _ in range(4):
        top = rng.integers(0, 5, (3, 3)) + [0, 0, 1]
        _assert_same(np.vstack([base, top]))
    # a tilted plane x + y + z = 6 of lattice points plus one apex each side
    g = _grid(7, 7, 7)
    plane = g[g.sum(1) == 6]
    _assert_same(np.vstack([plane, [[0, 0, 0]]]))
    _assert_same(np.vstack([plane, [[0, 0, 0], [4, 4, 4]]]))


def test_duplicates_match_brute_force_and_use_the_first():
    rng = np.random.default_rng(6)
    cells = _grid(3, 3, 2)
    cells = np.vstack([cells, cells[rng.integers(0, 18, 10)]])
    cells = cells[rng.permutation(len(cells))]
    tz = _assert_same(cells)
    _, first = np.unique(cells, axis=0, return_index=True)
    assert set(np.unique(tz.tets).tolist()) == set(first.tolist())


@pytest.mark.parametrize("seed", range(6))
def test_random_sets_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    if seed < 3:
        cells = rng.integers(0, TOP + 1, (12, 3))  # large coordinates: the brute force in Python integers
    else:
        cells = rng.integers(0, 4, (22, 3))  # small, crowded: many degeneracies
    _assert_same(cells)


@pytest.mark.parametrize(
    "cells",
    [
        np.zeros((0, 3), np.int64),
        [[1, 2, 3]],
        [[1, 2, 3], [4, 5, 6]],
        [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
        [[0, 0, 0], [1, 1, 1], [2, 2, 2], [5, 5, 5], [7, 7, 7]],  # collinear
        _grid(4, 4, 1),  # coplanar only
        [[0, 0, 0]] * 10,  # coincident
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [1, 0, 0]],  # 3 distinct
    ],
)
def test_degenerate_inputs_give_empty_results(cells):
    tz = tetrahedralize_cells(np.asarray(cells, dtype=np.int64).reshape(-1, 3))
    assert tz.tets.shape == (0, 4) and tz.hull_faces.shape == (0, 3) and tz.backend == "exact"
    assert brute_force(cells)[0].shape == (0, 4)


def test_checker_rejects_another_delaunay_tetrahedralization():
    """The checker is strict: TetGen's tets of a lattice (a valid Delaunay tetrahedralization under TetGen's own
    tie-break) differ from the definition's, and the checker says so."""
    pytest.importorskip("tetgenpy")
    flagged = 0
    for dims in [(3, 3, 3), (4, 3, 2), (4, 4, 3)]:
        cells = _grid(*dims)
        tg = tetrahedralize(cells.astype(np.float64), "tetgen")
        ours = tetrahedralize_cells(cells)
        tets = np.array(sorted(map(tuple, _even_min_first(tg.tets).tolist())), np.int64)
        if not np.array_equal(tets, ours.tets):
            hull = np.array(
                sorted(tuple(f[np.argmin(f) :].tolist() + f[: np.argmin(f)].tolist()) for f in tg.hull_faces)
            )
            assert check(cells, tets, hull) != []
            flagged += 1
    assert flagged


def _even_min_first(tets):
    even = [p for p in itertools.permutations(range(4)) if _parity(p) == 0]
    return np.array([min(tuple(t[i] for i in p) for p in even) for t in np.asarray(tets).tolist()], np.int64)


# ------------------------------------------------------------------------------------------------------------
# larger sets: the independent checker, TetGen, properties


@pytest.mark.parametrize("kind", ["lattice", "grid", "cospherical", "coplanar", "cluster", "random", "extremes"])
def test_mixed_sets_pass_the_checker(kind):
    rng = np.random.default_rng(7)
    for _ in range(30):
        cells = make_points(rng, kind)
        tz = tetrahedralize_cells(cells)
        assert check(cells, tz.tets, tz.hull_faces) == []


def test_larger_lattice_and_shell_pass_the_checker():
    rng = np.random.default_rng(8)
    cells = _grid(6, 6, 6)[rng.random(216) < 0.8] * 1024
    tz = tetrahedralize_cells(cells)
    assert check(cells, tz.tets, tz.hull_faces) == []
    g = _grid(14, 14, 14) - 6.5
    r = np.sqrt((g**2).sum(1))
    cells = (g[(r > 5) & (r < 6.5)] + 6.5).astype(np.int64)  # a lattice shell: cospherical everywhere
    tz = tetrahedralize_cells(cells)
    assert check(cells, tz.tets, tz.hull_faces, qhull=False) == []


def test_same_tets_as_tetgen_in_general_position():
    pytest.importorskip("tetgenpy")
    rng = np.random.default_rng(9)
    cells = rng.integers(0, TOP + 1, (3000, 3))
    ours = tetrahedralize_cells(cells)
    tg = tetrahedralize(cells.astype(np.float64), "tetgen")
    assert {tuple(t) for t in np.sort(ours.tets, 1).tolist()} == {tuple(t) for t in np.sort(tg.tets, 1).tolist()}
    assert {tuple(sorted(f)) for f in ours.hull_faces.tolist()} == {tuple(sorted(f)) for f in tg.hull_faces.tolist()}


def _coordinate_tets(cells, tets):
    return {frozenset(tuple(cells[i]) for i in t) for t in np.asarray(tets).tolist()}


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.tuples(*[st.integers(0, 3)] * 3), min_size=0, max_size=40),
    st.randoms(use_true_random=False),
)
def test_relabelling_gives_the_same_tets(points, rnd):
    """Point order permutation invariance: the same tets (as point sets) after any relabelling."""
    cells = np.array(points, dtype=np.int64).reshape(-1, 3)
    perm = list(range(len(cells)))
    rnd.shuffle(perm)
    a = tetrahedralize_cells(cells)
    b = tetrahedralize_cells(cells[perm])
    cl = [tuple(p) for p in cells.tolist()]
    pl = [tuple(p) for p in cells[perm].tolist()]
    assert _coordinate_tets(cl, a.tets) == _coordinate_tets(pl, b.tets)
    assert check(cells, a.tets, a.hull_faces, qhull=False) == []


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(*[st.integers(0, 5)] * 3), min_size=4, max_size=14, unique=True))
def test_small_crowded_sets_match_brute_force(points):
    _assert_same(np.array(points, dtype=np.int64))


# ------------------------------------------------------------------------------------------------------------
# float points: the lattice of a v2 grid


@pytest.mark.parametrize("bits", range(Q.POSITION_BITS_MIN, Q.POSITION_BITS_MAX + 1))
def test_v2_cell_centres_snap_exactly(bits):
    k = np.arange(1 << bits, dtype=np.int64)
    cells = np.stack([k, k[::-1], k], 1)
    expected = cells * (1 << (dl.MAX_BITS - bits)) + (1 << (dl.MAX_BITS - 1 - bits))
    np.testing.assert_array_equal(snap_to_lattice(Q.dequantize_positions(cells, bits)), expected)
    rng = np.random.default_rng(bits)
    sub = np.unique(rng.integers(0, 1 << bits, (400, 3)), axis=0)
    sub = sub[rng.permutation(len(sub))]
    a = tetrahedralize(Q.dequantize_positions(sub, bits), "exact")
    b = tetrahedralize_cells(sub)
    np.testing.assert_array_equal(a.tets, b.tets)
    np.testing.assert_array_equal(a.hull_faces, b.hull_faces)


def test_snap_widens_its_cube_for_points_beyond_the_grid():
    inside = np.array([[-1.2, 1.2, 0.0]])
    np.testing.assert_array_equal(snap_to_lattice(inside), [[0, TOP, 1 << 22]])
    pts = np.array([[-5.0, 0.0, 5.0], [-1.2, 1.2, 0.0]])  # beyond 1.2: the lattice spans [-8, 8] instead
    np.testing.assert_array_equal(snap_to_lattice(pts), [[(3 << 19), 1 << 22, (13 << 19)], [3565158, 4823450, 1 << 22]])
    assert len(np.unique(snap_to_lattice(np.array([[9.0, 0, 0], [10.0, 0, 0]])), axis=0)) == 2  # nothing clamped


def test_backends_and_auto():
    assert dl.BACKENDS[0] == "exact" and dl.available_backends()[0] == "exact"
    assert dl.resolve_backend("auto") == "exact"
    with pytest.raises(ValueError):
        dl.resolve_backend("cgal")


def test_tetgen_missing_gives_an_install_hint(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "tetgenpy", None)  # hidden: `import tetgenpy` raises ImportError
    assert "tetgen" not in dl.available_backends()
    with pytest.raises(ImportError, match="tetweave\\[tetgen\\]"):
        tetrahedralize(np.random.default_rng(0).random((10, 3)), "tetgen")
    assert tetrahedralize(np.random.default_rng(0).random((10, 3))).backend == "exact"


# ------------------------------------------------------------------------------------------------------------
# hostile inputs


def test_extreme_coordinates():
    corners = _grid(2, 2, 2) * TOP
    cells = np.vstack([corners, [[TOP // 2] * 3, [0, 0, 1], [1, 0, 0], [TOP, TOP, TOP - 1]]])
    tz = _assert_same(cells)
    assert len(tz.tets) > 0


def test_a_million_points_on_a_line_is_fast_and_empty():
    n = 1 << 20
    t = np.arange(n, dtype=np.int64)
    cells = np.stack([t * 7, t * 3 + 5, t * 2], 1)
    start = time.perf_counter()
    tz = tetrahedralize_cells(cells)
    assert time.perf_counter() - start < 5.0
    assert tz.tets.shape == (0, 4)


def test_many_coplanar_and_coincident_points_are_fast_and_empty():
    rng = np.random.default_rng(10)
    plane = np.column_stack([rng.integers(0, TOP, (200_000, 2)), np.full(200_000, 77)])
    start = time.perf_counter()
    assert tetrahedralize_cells(plane).tets.shape == (0, 4)
    assert tetrahedralize_cells(np.full((200_000, 3), 5)).tets.shape == (0, 4)
    assert time.perf_counter() - start < 5.0


def _skew_lines(n: int, step: int = 1000) -> np.ndarray:
    t = np.arange(n, dtype=np.int64)
    a = np.stack([t * step, np.zeros(n, np.int64), np.zeros(n, np.int64)], 1)
    b = np.stack([np.full(n, n * step // 2), t * step + n * step // 2, np.full(n, n * step)], 1)
    return np.vstack([a, b])


def test_quadratic_tetrahedralizations_are_made_or_refused_in_bounded_memory():
    """Points on two skew lines: (n - 1)^2 tets. Small ones come out (checked); past max(64 N + 4096, 2^22) tets a
    MemoryError, after bounded work."""
    cells = _skew_lines(40)
    tz = tetrahedralize_cells(cells)
    assert len(tz.tets) == 39 * 39
    assert check(cells, tz.tets, tz.hull_faces) == []
    start = time.perf_counter()
    with pytest.raises(MemoryError, match="skew lines"):
        tetrahedralize_cells(_skew_lines(3000))
    assert time.perf_counter() - start < 10.0


@pytest.mark.parametrize(
    "cells",
    [
        [[0, 0, -1], [1, 1, 1], [2, 2, 2], [3, 3, 4]],
        [[0, 0, 1 << 23], [1, 1, 1], [2, 2, 2], [3, 3, 4]],
        np.zeros((4, 3)),  # floats
        np.zeros((4, 2), np.int64),
    ],
)
def test_bad_input_raises_value_error(cells):
    with pytest.raises(ValueError):
        tetrahedralize_cells(np.asarray(cells))


def test_too_many_points_raise_value_error_before_any_work():
    cells = np.broadcast_to(np.zeros(3, np.int64), (dl.MAX_POINTS + 1, 3))  # no memory behind it
    with pytest.raises(ValueError, match="at most"):
        tetrahedralize_cells(cells)


def test_native_module_checks_its_input():
    from tetweave_codec.geometry import _delaunay_native as native

    with pytest.raises(ValueError):
        native.tetrahedralize(np.zeros((4, 3), np.float64))
    with pytest.raises(ValueError):
        native.tetrahedralize(np.array([[0, 0, 1 << 23]] * 4, np.int64))
    tets, hull = native.tetrahedralize(np.ascontiguousarray(_grid(2, 2, 2)))
    assert len(tets) == 6 * 32 and len(hull) == 12 * 24  # 6 tets of a cube, 12 hull triangles


def test_flat_tet_would_be_a_topology_error(monkeypatch):
    from tetweave_codec.geometry import _delaunay_native as native

    def broken(cells):
        raise RuntimeError("flat tet: a new tet has no volume (inconsistent predicates)")

    monkeypatch.setattr(native, "tetrahedralize", broken)
    with pytest.raises(TopologyError, match="flat tet"):
        tetrahedralize_cells(_grid(2, 2, 2))
