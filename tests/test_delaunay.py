"""Delaunay tetrahedralization: validity, orientation, hull faces, duplicates, degenerate inputs, backends."""

from __future__ import annotations

import sys
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

from tetweave_codec.errors import TopologyError
from tetweave_codec.geometry import delaunay as dl
from tetweave_codec.geometry.delaunay import TET_OUTWARD_FACES, delaunay, orientation, resolve_backend, tetrahedralize

BACKENDS = dl.available_backends()


def _volumes(points, tets):
    a, b, c, d = (points[tets[:, k]] for k in range(4))
    return np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a)) / 6.0


def _directed_faces(tets):
    """Outward faces of all tets, each rotated so its smallest index comes first: (4T, 3)."""
    f = tets[:, TET_OUTWARD_FACES].reshape(-1, 3)
    r = np.argmin(f, axis=1)
    idx = (r[:, None] + np.arange(3)) % 3
    return np.take_along_axis(f, idx, axis=1)


def assert_valid_complex(points, tets, hull):
    """Positive tets; a face is shared by at most two tets, oppositely oriented; hull = unpaired faces."""
    assert tets.dtype == np.int64 and tets.shape[1] == 4
    assert np.all(orientation(points, tets) >= 0)
    directed = _directed_faces(tets)
    keys = {tuple(f) for f in directed.tolist()}
    assert len(keys) == len(directed), "a face has the same orientation in two tets"
    unpaired = [f for f in keys if (f[0], f[2], f[1]) not in keys]
    hull_keys = {tuple(f) for f in _directed_faces_of(hull).tolist()}
    assert hull_keys == set(unpaired)


def _directed_faces_of(tris):
    r = np.argmin(tris, axis=1)
    idx = (r[:, None] + np.arange(3)) % 3
    return np.take_along_axis(tris, idx, axis=1)


def _lattice(k: int = 5) -> np.ndarray:
    g = np.arange(k) / (k - 1.0)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)


@pytest.mark.parametrize("backend", BACKENDS)
def test_random_points_valid_and_fill_the_hull(backend):
    pts = np.random.default_rng(0).uniform(-1, 1, (500, 3))
    tz = tetrahedralize(pts, backend)
    assert tz.backend == backend
    assert_valid_complex(pts, tz.tets, tz.hull_faces)
    vols = _volumes(pts, tz.tets)
    assert np.all(vols > 0)
    hull = ConvexHull(pts)
    assert vols.sum() == pytest.approx(hull.volume, rel=1e-12)
    assert len(tz.hull_faces) == len(hull.simplices)
    assert set(np.unique(tz.tets)) == set(range(len(pts)))


@pytest.mark.parametrize("backend", BACKENDS)
def test_empty_circumspheres(backend):
    pts = np.random.default_rng(1).normal(size=(150, 3))
    if backend == "exact":  # it triangulates the points snapped to its lattice: check those
        from tetweave_codec.geometry.delaunay import MAX_BITS, snap_to_lattice

        bound = 4.0  # the power of two above these points' largest magnitude (snap_to_lattice)
        assert 2.0 < np.abs(pts).max() <= bound
        pts = snap_to_lattice(pts) * (2 * bound / 2**MAX_BITS) - bound
    tets = delaunay(pts, backend)
    a = pts[tets[:, 0]]
    m = np.stack([pts[tets[:, k]] - a for k in (1, 2, 3)], 1)  # (T, 3, 3)
    rhs = 0.5 * (m**2).sum(-1)
    centre = a + np.linalg.solve(m, rhs[..., None])[..., 0]
    radius2 = ((centre - a) ** 2).sum(-1)
    dist2 = ((pts[None, :, :] - centre[:, None, :]) ** 2).sum(-1)
    dist2[np.arange(len(tets))[:, None], tets] = np.inf
    assert np.all(dist2 >= radius2[:, None] * (1 - 1e-9))


def test_backends_agree_in_general_position():
    if "tetgen" not in BACKENDS:
        pytest.skip("tetgenpy not installed")
    pts = np.random.default_rng(2).uniform(-1, 1, (400, 3))
    a = {tuple(t) for t in np.sort(delaunay(pts, "tetgen"), 1).tolist()}
    b = {tuple(t) for t in np.sort(delaunay(pts, "qhull"), 1).tolist()}
    assert a == b


@pytest.mark.parametrize("backend", BACKENDS)
def test_cospherical_lattice_is_consistently_oriented(backend):
    """A lattice is maximally degenerate: tets of 4 coplanar points (flat) exist and must still be oriented."""
    pts = _lattice(5)
    tz = tetrahedralize(pts, backend)
    assert_valid_complex(pts, tz.tets, tz.hull_faces)
    assert _volumes(pts, tz.tets).sum() == pytest.approx(1.0, abs=1e-12)
    if backend == "qhull":
        assert np.any(orientation(pts, tz.tets) == 0), "expected tets of coplanar lattice points"


@pytest.mark.parametrize("backend", BACKENDS)
def test_exact_duplicates_map_to_first_occurrence(backend):
    rng = np.random.default_rng(3)
    base = rng.uniform(-1, 1, (300, 3))
    pts = np.concatenate([base, base[:100], base[50:80]])
    perm = rng.permutation(len(pts))
    pts = pts[perm]
    tz = tetrahedralize(pts, backend)
    assert tz.tets.max() < len(pts)
    used = np.unique(tz.tets)
    assert len(used) == 300
    _, first = np.unique(pts, axis=0, return_index=True)
    assert set(used.tolist()) == set(first.tolist())
    assert_valid_complex(pts, tz.tets, tz.hull_faces)
    # Same tets as on the deduplicated input, mapped back.
    ref = tetrahedralize(pts[np.sort(first)], backend)
    mapped = np.sort(first)[ref.tets]
    assert {tuple(t) for t in np.sort(mapped, 1).tolist()} == {tuple(t) for t in np.sort(tz.tets, 1).tolist()}


@pytest.mark.parametrize("backend", BACKENDS)
def test_near_duplicates_neither_stall_nor_crash(backend):
    rng = np.random.default_rng(4)
    base = rng.uniform(-1, 1, (2000, 3))
    pts = np.concatenate([base, base[:500] + rng.normal(size=(500, 3)) * 1e-12, base[500:700] + 1e-15])
    start = time.perf_counter()
    tz = tetrahedralize(pts, backend)
    assert time.perf_counter() - start < 20
    assert len(tz.tets) > 0 and tz.tets.max() < len(pts)
    inverted = orientation(pts, tz.tets) < 0
    if backend == "qhull":
        # Qhull triangulates points moved by < 2^-24 (the tie-break): tets with two corners closer than that may
        # be inverted in true coordinates, but only those, and they are positive where Qhull saw them.
        assert np.all(orientation(dl.perturb_points(pts), tz.tets) > 0)
        corners = pts[tz.tets[inverted]]
        gaps = np.linalg.norm(corners[:, :, None] - corners[:, None, :], axis=-1) + np.eye(4) * 10
        assert np.all(gaps.min(axis=(1, 2)) < 2.0**-23)
    else:
        assert not inverted.any()


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(
    "pts",
    [
        np.zeros((0, 3)),
        np.random.default_rng(5).uniform(size=(1, 3)),
        np.random.default_rng(5).uniform(size=(2, 3)),
        np.random.default_rng(5).uniform(size=(3, 3)),
        np.repeat([[0.1, 0.2, 0.3]], 6, axis=0),
        np.c_[np.random.default_rng(6).uniform(size=(40, 2)), np.zeros(40)],  # coplanar
        np.c_[np.random.default_rng(7).uniform(size=40), np.zeros((40, 2))],  # collinear
        np.concatenate([np.eye(3), np.eye(3), np.eye(3)]),  # 3 distinct points, repeated
    ],
    ids=["empty", "one", "two", "three", "identical", "coplanar", "collinear", "three-distinct"],
)
def test_degenerate_inputs_give_no_tets(backend, pts):
    tz = tetrahedralize(pts, backend)
    assert tz.tets.shape == (0, 4) and tz.hull_faces.shape == (0, 3)


@pytest.mark.parametrize("backend", BACKENDS)
def test_deterministic(backend):
    pts = np.random.default_rng(8).normal(size=(3000, 3)).astype(np.float16).astype(np.float64)
    a, b = tetrahedralize(pts, backend), tetrahedralize(pts, backend)
    assert np.array_equal(a.tets, b.tets) and np.array_equal(a.hull_faces, b.hull_faces)


def test_single_tet_orientation_fixed():
    pts = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1.0]])
    for backend in BACKENDS:
        tets = delaunay(pts, backend)
        assert tets.shape == (1, 4) and _volumes(pts, tets)[0] > 0


def test_orientation_is_exact_where_float_is_not():
    # Nearly coplanar: float64 cannot tell the sign, the exact fallback can.
    eps = 2.0**-60
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1.0 / 3, 1.0 / 3, eps], [1.0 / 3, 1.0 / 3, -eps]])
    signs = orientation(pts, np.array([[0, 1, 2, 3], [0, 1, 2, 4], [0, 2, 1, 3], [0, 1, 2, 2]]))
    assert signs.tolist() == [1, -1, -1, 0]


def test_input_validation():
    with pytest.raises(ValueError):
        delaunay(np.zeros((5, 2)))
    with pytest.raises(ValueError):
        delaunay(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, np.nan]]))
    with pytest.raises(ValueError):
        resolve_backend("cgal")


def test_exact_and_qhull_without_tetgenpy(monkeypatch):
    monkeypatch.setitem(sys.modules, "tetgenpy", None)  # makes `import tetgenpy` raise ImportError
    assert dl.available_backends() == ("exact", "qhull")
    assert resolve_backend("auto") == "exact"
    with pytest.raises(ImportError):
        resolve_backend("tetgen")
    pts = np.random.default_rng(9).uniform(size=(50, 3))
    assert tetrahedralize(pts).backend == "exact" and tetrahedralize(pts, "qhull").backend == "qhull"


# -----------------------------------------------------------------------------------------------------------
# the Qhull tie-break (issue 16): perturbed coordinates, checked result


def test_perturbation_matches_the_specification():
    """The worked example of formats/README.md ("Decoding", step 2): hash, 2^(e - 25) bound, one rounding."""
    pts = np.array([[0.5, -0.25, 1.0], [-0.0, 0.0, 0.0]])
    assert [int(h) for h in dl._coordinate_hash(pts)] == [0xAA8C01ACFF9FF10D, 0x238275BC38FCBE91]
    moved = dl.perturb_points(pts)
    # max |coordinate| = 1 = 0.5 * 2^1, so e = 1 and the unit is 2^(1 - 25 - 20) = 2^-44.
    expected_u = [[1044749.5, -169987.5, -351487.5], [835217.5, -138808.5, -466786.5]]
    assert ((moved - pts) * 2.0**44).tolist() == expected_u
    assert moved[0].tolist() == [
        float.fromhex(x) for x in ("0x1.000001fe21bp-1", "-0x1.000000a600ep-2", "0x1.ffffff54601p-1")
    ]


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-3, 1.0, 1.2, 700.0]))
def test_perturbation_depends_on_coordinates_only(seed, scale):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-scale, scale, (200, 3))
    pts[::7] = pts[1::7][: len(pts[::7])]  # coincident points
    moved = dl.perturb_points(pts)
    perm = rng.permutation(len(pts))
    assert np.array_equal(dl.perturb_points(pts[perm]), moved[perm])
    _, e = np.frexp(np.abs(pts).max())
    assert np.all(np.abs(moved - pts) <= 2.0 ** (int(e) - 25))
    same = np.all(pts[:, None] == pts[None], -1)
    assert np.array_equal(same, np.all(moved[:, None] == moved[None], -1))


def _lattice_cluster(bits: int, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A dense random cluster of a 2^bits lattice: (cells (M, 3) int64, their centres over [-1.2, 1.2]^3 as the v2
    container dequantizes them, float64)."""
    rng = np.random.default_rng(seed)
    m = 1 << bits
    width = max(2, round(count ** (1 / 3) * 1.3))
    cells = np.unique(rng.integers(0, m - width, 3) + rng.integers(0, width, (count, 3)), axis=0)
    return cells, ((2 * cells + 1 - m) * 1.2) / m


@pytest.mark.parametrize("bits", [5, 10, 16])
def test_qhull_is_proper_on_lattice_clusters(bits):
    """Unperturbed, Qhull gives 120-650 flat tets on each of these (and non-conforming squares)."""
    cells, pts = _lattice_cluster(bits, 2000, bits)
    tz = tetrahedralize(pts, "qhull")
    moved = dl.perturb_points(pts)
    assert_valid_complex(moved, tz.tets, tz.hull_faces)
    assert np.all(orientation(moved, tz.tets) > 0)
    # Nothing inverted on the lattice: the perturbation is far below the cell. (The float64 centres are off the
    # lattice by the rounding of x 1.2, so tets of coplanar cells can have a float64 volume of either sign.)
    assert np.all(orientation(cells.astype(np.float64), tz.tets) >= 0)
    assert len(np.unique(tz.tets)) == len(pts)
    assert _volumes(pts, tz.tets).sum() == pytest.approx(ConvexHull(pts).volume, rel=1e-9)


def test_qhull_retries_with_a_larger_perturbation(monkeypatch):
    _, pts = _lattice_cluster(8, 1500, 1)
    monkeypatch.setattr(dl, "QHULL_PERTURBATION_BITS", (80,))  # 2^-79: below float64 resolution, no effect
    with pytest.raises(TopologyError, match="no proper tetrahedralization"):
        tetrahedralize(pts, "qhull")
    monkeypatch.setattr(dl, "QHULL_PERTURBATION_BITS", (80, 25))
    tz = tetrahedralize(pts, "qhull")
    assert_valid_complex(dl.perturb_points(pts, 25), tz.tets, tz.hull_faces)


def test_proper_tetrahedralization_error_finds_each_defect():
    from scipy.spatial import Delaunay

    pts = np.random.default_rng(10).uniform(-1, 1, (60, 3))
    tri = Delaunay(pts)
    tets, nbr = tri.simplices.astype(np.int64), tri.neighbors.astype(np.int64)
    neg = orientation(pts, tets) < 0
    tets[neg], nbr[neg] = tets[neg][:, [1, 0, 2, 3]], nbr[neg][:, [1, 0, 2, 3]]
    assert dl.proper_tetrahedralization_error(pts, tets, nbr) is None
    flipped = tets.copy()
    flipped[0] = flipped[0, [1, 0, 2, 3]]
    assert "flat" in dl.proper_tetrahedralization_error(pts, flipped, nbr)
    t, k = np.argwhere(nbr >= 0)[0]
    one_sided = nbr.copy()
    one_sided[nbr[t, k]][nbr[nbr[t, k]] == t] = -1
    assert "mutual" in dl.proper_tetrahedralization_error(pts, tets, one_sided)
    # Tet t claims a neighbour across face k that does not hold that face.
    other = next(u for u in range(len(tets)) if u != t and t not in nbr[u] and u not in nbr[t])
    wrong = nbr.copy()
    wrong[t, k] = other
    wrong[other, np.argmax(nbr[other] < 0) if (nbr[other] < 0).any() else 0] = t
    assert dl.proper_tetrahedralization_error(pts, tets, wrong) is not None
    assert "not a vertex" in dl.proper_tetrahedralization_error(pts, np.full((1, 4), -1), np.full((1, 4), -1))
