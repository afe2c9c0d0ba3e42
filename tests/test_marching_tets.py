"""Directional marching tets: case table, analytic sphere, SH behaviour, gradients, hull caps, properties."""

from __future__ import annotations

import manifold3d
import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tetweave_codec.geometry.delaunay import available_backends, tetrahedralize
from tetweave_codec.geometry.marching_tets import (
    TET_EDGES,
    TRIANGLE_TABLE,
    marching_tets,
    marching_tets_numpy,
)
from tetweave_codec.geometry.sh import num_coeffs

SPHERE_R = 0.6


# -----------------------------------------------------------------------------------------------------------
# helpers


def assert_closed_manifold(vertices: np.ndarray, faces: np.ndarray) -> None:
    """Closed, consistently oriented, edge- and vertex-manifold mesh (or empty); manifold3d agrees."""
    if len(faces) == 0:
        assert len(vertices) == 0
        return
    f = np.asarray(faces)
    assert f.min() >= 0 and f.max() < len(vertices)
    assert len(np.unique(f)) == len(vertices), "unreferenced vertices"
    assert np.all((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])), "degenerate face"
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    keys = directed[:, 0] * len(vertices) + directed[:, 1]
    assert len(np.unique(keys)) == len(keys), "a directed edge is used twice (orientation or non-manifold edge)"
    reverse = directed[:, 1] * len(vertices) + directed[:, 0]
    assert np.isin(reverse, keys).all(), "open boundary: an edge has no opposite half-edge"
    # Vertex-manifold: the link of every vertex (the edges opposite to it) is one single cycle.
    nxt: dict[tuple[int, int], int] = {}
    for a, b, c in f.tolist():
        nxt[(a, b)] = c
        nxt[(b, c)] = a
        nxt[(c, a)] = b
    link_start: dict[int, int] = {}
    link_count = np.bincount(f.ravel(), minlength=len(vertices))
    for a, b, _ in f.tolist():
        link_start.setdefault(a, b)
    for v, start in link_start.items():
        steps, u = 0, start
        while True:
            u = nxt[(v, u)]
            steps += 1
            if u == start or steps > link_count[v]:
                break
        assert steps == link_count[v], f"vertex {v} is not manifold (its faces form more than one fan)"
    mesh = manifold3d.Mesh(vert_properties=np.asarray(vertices, dtype=np.float32), tri_verts=f.astype(np.uint32))
    assert manifold3d.Manifold(mesh).status() == manifold3d.Error.NoError


def signed_volume(vertices, faces) -> float:
    v = vertices[faces]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def sphere_setup(n: int, seed: int = 0):
    pts = np.random.default_rng(seed).uniform(-1, 1, (n, 3))
    s = np.linalg.norm(pts, axis=1) - SPHERE_R
    return pts, s, tetrahedralize(pts)


def random_positive_tet(rng) -> np.ndarray:
    while True:
        p = rng.normal(size=(4, 3))
        det = np.linalg.det(p[1:] - p[0])
        if abs(det) > 0.05:
            return p if det > 0 else p[[1, 0, 2, 3]]


# -----------------------------------------------------------------------------------------------------------
# the case table


def test_triangle_table_covers_each_case_once():
    for code in range(16):
        inside = [(code >> k) & 1 for k in range(4)]
        active = {e for e, (a, b) in enumerate(TET_EDGES) if inside[a] != inside[b]}
        used = set(TRIANGLE_TABLE[code][TRIANGLE_TABLE[code] >= 0].tolist())
        assert used == active, f"case {code}"
        n_tris = (TRIANGLE_TABLE[code, :, 0] >= 0).sum()
        assert n_tris == {0: 0, 1: 1, 2: 2, 3: 1, 4: 0}[sum(inside)]


@pytest.mark.parametrize("code", range(1, 15))
def test_every_case_faces_from_inside_to_outside(code):
    rng = np.random.default_rng(code)
    for _ in range(20):
        p = random_positive_tet(rng)
        inside = np.array([(code >> k) & 1 for k in range(4)], dtype=bool)
        s = np.where(inside, -rng.uniform(0.1, 1, 4), rng.uniform(0.1, 1, 4))
        res = marching_tets_numpy(p, np.array([[0, 1, 2, 3]]), s)
        v, f = res.vertices, res.faces
        normal = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]).sum(0)  # quad: vector area
        direction = p[~inside].mean(0) - p[inside].mean(0)
        assert normal @ direction > 0
        if len(f) == 1:  # single triangle: its plane separates inside from outside corners strictly
            n = np.cross(v[f[0, 1]] - v[f[0, 0]], v[f[0, 2]] - v[f[0, 0]])
            side = (p - v[f[0, 0]]) @ n
            assert np.all(side[inside] < 0) and np.all(side[~inside] > 0)
        else:  # the two triangles of a quad share their diagonal in opposite directions
            assert_shared_diagonal_opposite(f)
        # torch path gives the same triangles
        rt = marching_tets(torch.tensor(p), torch.tensor([[0, 1, 2, 3]]), torch.tensor(s))
        assert np.array_equal(rt.faces.numpy(), f)


def assert_shared_diagonal_opposite(f):
    e0 = {(f[0, k], f[0, (k + 1) % 3]) for k in range(3)}
    e1 = {(f[1, k], f[1, (k + 1) % 3]) for k in range(3)}
    assert len(e0 & e1) == 0 and len(e0 & {(b, a) for a, b in e1}) == 1


# -----------------------------------------------------------------------------------------------------------
# analytic sphere


@pytest.mark.parametrize("n", [2000, 8000, 32000])
def test_sphere_is_closed_outward_and_accurate(n):
    pts, s, tz = sphere_setup(n)
    res = marching_tets_numpy(pts, tz.tets, s, None, tz.hull_faces)
    v, f = res.vertices, res.faces
    assert_closed_manifold(v, f)
    euler = len(v) - len(f) * 3 // 2 + len(f)
    assert euler == 2  # one sphere
    # Outward: positive enclosed volume for a consistently oriented closed surface ...
    h = 2.0 / n ** (1 / 3)  # mean point spacing
    volume = 4 / 3 * np.pi * SPHERE_R**3
    assert signed_volume(v, f) > 0
    assert abs(signed_volume(v, f) / volume - 1) < 3.0 * h**2
    assert np.abs(np.linalg.norm(v, axis=1) - SPHERE_R).max() < 2.5 * h**2
    # ... and per face: a piecewise-linear surface may tilt a few tiny slivers over, never a visible area.
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    area = np.linalg.norm(normals, axis=1)
    outward = np.einsum("ij,ij->i", normals, v[f].mean(1)) > 0
    assert area[~outward].sum() < 1e-3 * area.sum()
    assert outward.mean() > 0.999


def test_sphere_error_shrinks_with_more_points():
    errors = []
    for n in (1000, 8000, 32000):
        pts, s, tz = sphere_setup(n, seed=1)
        v = marching_tets_numpy(pts, tz.tets, s).vertices
        errors.append(np.abs(np.linalg.norm(v, axis=1) - SPHERE_R).max())
    assert errors[0] > errors[1] > errors[2]


def test_vertices_are_linear_interpolation_of_s_without_sh():
    pts, s, tz = sphere_setup(3000, seed=2)
    res = marching_tets_numpy(pts, tz.tets, s)
    i, j = res.edges[:, 0], res.edges[:, 1]
    assert np.all(s[i] < 0) and np.all(s[j] >= 0)
    t = s[i] / (s[i] - s[j])
    np.testing.assert_allclose(res.vertices, pts[i] + t[:, None] * (pts[j] - pts[i]), atol=1e-14)
    # one vertex per unique active edge
    assert len(np.unique(np.sort(res.edges, 1), axis=0)) == len(res.edges)


# -----------------------------------------------------------------------------------------------------------
# directional distance (SH)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_zero_coefficients_equal_plain_s(degree):
    pts, s, tz = sphere_setup(3000, seed=3)
    plain = marching_tets_numpy(pts, tz.tets, s)
    zero = marching_tets_numpy(pts, tz.tets, s, np.zeros((len(pts), num_coeffs(degree))))
    assert np.array_equal(plain.faces, zero.faces) and np.array_equal(plain.edges, zero.edges)
    assert np.array_equal(plain.vertices, zero.vertices)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_coefficients_move_vertices_along_edges_only(degree):
    pts, s, tz = sphere_setup(3000, seed=4)
    c = np.random.default_rng(5).normal(size=(len(pts), num_coeffs(degree))) * 2.0
    plain = marching_tets_numpy(pts, tz.tets, s, None, tz.hull_faces)
    moved = marching_tets_numpy(pts, tz.tets, s, c, tz.hull_faces)
    assert np.array_equal(plain.faces, moved.faces) and np.array_equal(plain.edges, moved.edges)
    i, j = moved.edges[:, 0], moved.edges[:, 1]
    d = pts[j] - pts[i]
    t = np.einsum("ij,ij->i", moved.vertices - pts[i], d) / np.einsum("ij,ij->i", d, d)
    assert np.all((t > 0) & (t < 1))
    np.testing.assert_allclose(moved.vertices, pts[i] + t[:, None] * d, atol=1e-12)
    assert np.abs(moved.vertices - plain.vertices).max() > 1e-3
    assert_closed_manifold(moved.vertices, moved.faces)


def test_directional_distance_formula_and_direction_convention():
    """One edge by hand: s_hat_i uses SH of c_i at dir(i -> j), s_hat_j SH of c_j at dir(j -> i)."""
    pts = np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    s = np.array([-0.5, 1.0, 1.0, 1.0])
    c = np.zeros((4, 4))
    c[0, 3] = 0.7  # point 0: Y_11 ~ x, positive towards point 1
    c[1, 3] = 0.4  # point 1: at dir(1 -> 0) = -x this contributes -0.4 * C1
    res = marching_tets_numpy(pts, np.array([[0, 1, 2, 3]]), s, c)
    k = int(np.flatnonzero((res.edges == [0, 1]).all(1))[0])
    c1 = 0.4886025119029199
    sh_i = (1 + np.tanh(0.7 * c1)) * -0.5
    sh_j = (1 + np.tanh(-0.4 * c1)) * 1.0
    expected = (sh_j * pts[0] - sh_i * pts[1]) / (sh_j - sh_i)
    np.testing.assert_allclose(res.vertices[k], expected, atol=1e-15)


def test_saturated_tanh_stays_finite():
    pts = np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    s = np.array([-0.5, 1.0, 1.0, 1.0])
    c = np.full((4, 1), -1e4)  # 1 + tanh(...) == 0 at every point: both s_hat vanish
    res = marching_tets_numpy(pts, np.array([[0, 1, 2, 3]]), s, c)
    assert np.isfinite(res.vertices).all()


# -----------------------------------------------------------------------------------------------------------
# torch path: agreement and gradients


def test_torch_matches_numpy():
    pts, s, tz = sphere_setup(4000, seed=6)
    s[np.random.default_rng(7).uniform(size=len(s)) < 0.02] *= -1  # add some hull-touching inside points
    c = np.random.default_rng(8).normal(size=(len(pts), 9))
    ref = marching_tets_numpy(pts, tz.tets, s, c, tz.hull_faces)
    out = marching_tets(*(torch.tensor(a) for a in (pts, tz.tets, s, c, tz.hull_faces)))
    assert np.array_equal(out.faces.numpy(), ref.faces)
    assert np.array_equal(out.edges.numpy(), ref.edges)
    assert np.array_equal(out.face_tets.numpy(), ref.face_tets)
    np.testing.assert_allclose(out.vertices.numpy(), ref.vertices, atol=1e-12)
    out32 = marching_tets(
        torch.tensor(pts, dtype=torch.float32), torch.tensor(tz.tets), torch.tensor(s, dtype=torch.float32)
    )
    assert out32.vertices.dtype == torch.float32


@pytest.mark.parametrize("with_hull", [False, True])
def test_gradients_match_finite_differences(with_hull):
    rng = np.random.default_rng(9)
    pts = rng.uniform(-1, 1, (40, 3))
    s = np.linalg.norm(pts, axis=1) - 0.8
    s = np.where(np.abs(s) < 0.05, 0.05 * np.sign(s + 1e-12), s)  # keep the topology fixed under perturbation
    if with_hull:
        s[np.argmax(pts[:, 0])] = -0.3  # an inside hull point: cap vertices depend on its position
    tz = tetrahedralize(pts)
    tets = torch.tensor(tz.tets)
    hull = torch.tensor(tz.hull_faces) if with_hull else None
    p = torch.tensor(pts, requires_grad=True)
    sd = torch.tensor(s, requires_grad=True)
    c = torch.tensor(rng.normal(size=(40, 4)) * 0.5, requires_grad=True)
    assert torch.autograd.gradcheck(lambda p, sd, c: marching_tets(p, tets, sd, c, hull).vertices, (p, sd, c))


# -----------------------------------------------------------------------------------------------------------
# hull caps, empty output


def test_hull_caps_close_a_half_space():
    """s = x - 0.2 is linear, so marching tets is exact: the result is the hull clipped at x = 0.2."""
    from scipy.spatial import ConvexHull

    pts = np.random.default_rng(10).uniform(-1, 1, (3000, 3))
    s = pts[:, 0] - 0.2
    tz = tetrahedralize(pts)
    open_ = marching_tets_numpy(pts, tz.tets, s)
    closed = marching_tets_numpy(pts, tz.tets, s, None, tz.hull_faces)
    assert len(closed.faces) > len(open_.faces)
    assert np.array_equal(closed.faces[: len(open_.faces)], open_.faces)
    assert_closed_manifold(closed.vertices, closed.faces)
    expected = ConvexHull(np.concatenate([pts[s < 0], open_.vertices])).volume
    assert signed_volume(closed.vertices, closed.faces) == pytest.approx(expected, rel=1e-9)
    caps = closed.face_tets == -1
    assert caps.sum() == len(closed.faces) - len(open_.faces)
    cap_vertices = closed.edges[:, 0] == closed.edges[:, 1]
    assert np.all(s[closed.edges[cap_vertices, 0]] < 0)


@pytest.mark.parametrize("sign", [-1.0, 1.0])
def test_one_sign_gives_empty_mesh(sign):
    pts = np.random.default_rng(11).uniform(-1, 1, (200, 3))
    tz = tetrahedralize(pts)
    s = np.full(len(pts), sign)
    for hull in (None, tz.hull_faces):
        res = marching_tets_numpy(pts, tz.tets, s, None, hull)
        if sign < 0 and hull is not None:
            assert_closed_manifold(res.vertices, res.faces)  # everything inside: the hull itself
            assert len(res.faces) == len(tz.hull_faces)
        else:
            assert res.vertices.shape == (0, 3) and res.faces.shape == (0, 3)
        args = [torch.tensor(a) for a in (pts, tz.tets, s)]
        out = marching_tets(*args, None, None if hull is None else torch.tensor(hull))
        assert np.array_equal(out.faces.numpy(), res.faces)
        np.testing.assert_allclose(out.vertices.numpy(), res.vertices)


def test_no_tets():
    res = marching_tets_numpy(np.zeros((3, 3)), np.zeros((0, 4), np.int64), np.array([-1.0, 1.0, 1.0]))
    assert res.vertices.shape == (0, 3) and res.faces.shape == (0, 3) and res.edges.shape == (0, 2)


# -----------------------------------------------------------------------------------------------------------
# property test

coords = st.integers(min_value=0, max_value=4)  # a small lattice: duplicates and cospherical sets galore


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    points=st.lists(st.tuples(coords, coords, coords), min_size=0, max_size=40),
    signs=st.lists(st.sampled_from([-1.0, -0.25, 0.0, 0.5, 1.0]), min_size=40, max_size=40),
    jitter=st.booleans(),
    backend=st.sampled_from(available_backends()),
    sh=st.booleans(),
)
def test_random_point_sets_give_closed_manifolds(points, signs, jitter, backend, sh):
    pts = np.array(points, dtype=np.float64).reshape(-1, 3)
    if jitter:
        pts = pts + np.random.default_rng(len(pts)).uniform(-0.3, 0.3, pts.shape)
    s = np.array(signs[: len(pts)])
    c = np.random.default_rng(0).normal(size=(len(pts), 4)) if sh else None
    tz = tetrahedralize(pts, backend)
    res = marching_tets_numpy(pts, tz.tets, s, c, tz.hull_faces)
    assert np.isfinite(res.vertices).all()
    assert_closed_manifold(res.vertices, res.faces)
    if len(res.faces):
        assert signed_volume(res.vertices, res.faces) >= -1e-9


@pytest.mark.parametrize("backend", available_backends())
@pytest.mark.parametrize("seed", range(5))
def test_degenerate_lattice_with_random_signs(backend, seed):
    """Lattice points are cospherical everywhere (Qhull emits flat tets): the output must still be closed."""
    g = np.arange(5) / 4.0
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    s = np.random.default_rng(seed).choice([-1.0, 0.5], size=len(pts))
    tz = tetrahedralize(pts, backend)
    res = marching_tets_numpy(pts, tz.tets, s, None, tz.hull_faces)
    assert len(res.faces) > 0
    assert_closed_manifold(res.vertices, res.faces)


# -----------------------------------------------------------------------------------------------------------
# quantized (lattice) point sets: maximally cospherical, the case that broke the Qhull backend (issue 16)


def lattice_points(bits: int, count: int, seed: int) -> np.ndarray:
    """`count` distinct cell centres of a 2^bits lattice over [-1.2, 1.2]^3 (as the v2 container stores them)."""
    m = 1 << bits
    rng = np.random.default_rng(seed)
    idx = rng.choice(m**3, size=min(count, m**3), replace=False)
    cells = np.stack(np.unravel_index(idx, (m, m, m)), 1)
    return ((2 * cells + 1 - m) * 1.2) / m


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    bits=st.integers(4, 7),
    count=st.integers(4, 1500),
    seed=st.integers(0, 2**32 - 1),
    smooth=st.booleans(),
    sh=st.sampled_from([-1, 1]),
    backend=st.sampled_from(available_backends()),
)
def test_lattice_subsets_give_closed_manifolds(bits, count, seed, smooth, sh, backend):
    pts = lattice_points(bits, count, seed)
    rng = np.random.default_rng(seed)
    if smooth:  # a sphere of random centre and radius: large connected surfaces
        s = np.linalg.norm(pts - rng.uniform(-0.5, 0.5, 3), axis=1) - rng.uniform(0.2, 1.0)
    else:  # independent signs: surfaces around single points, the hardest case for the complex's consistency
        s = rng.normal(size=len(pts)) + rng.uniform(-1, 1)
    c = rng.normal(size=(len(pts), num_coeffs(sh))) if sh >= 0 else None
    tz = tetrahedralize(pts, backend)
    res = marching_tets_numpy(pts, tz.tets, s, c, tz.hull_faces)
    assert_closed_manifold(res.vertices, res.faces)


def torus_lattice(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The issue-16 recipe: 1-3K random cells of a 2^5 lattice, s = signed distance to a torus (R 0.6, r 0.25)."""
    pts = lattice_points(5, int(np.random.default_rng(seed).integers(1000, 3001)), seed)
    ring = np.hypot(pts[:, 0], pts[:, 1]) - 0.6
    return pts, np.hypot(ring, pts[:, 2]) - 0.25


@pytest.mark.parametrize("backend", available_backends())
def test_torus_on_a_lattice_is_closed(backend):
    """Before the Qhull tie-break, 12-31 of 40 such draws gave doubled directed edges with Qhull (TetGen 0)."""
    for seed in range(8):
        pts, s = torus_lattice(seed)
        tz = tetrahedralize(pts, backend)
        res = marching_tets_numpy(pts, tz.tets, s, None, tz.hull_faces)
        assert len(res.faces) > 0
        assert_closed_manifold(res.vertices, res.faces)


# -----------------------------------------------------------------------------------------------------------
# the consistency check: a non-conforming tetrahedralization raises instead of giving a broken mesh


def _two_cubes(conforming: bool) -> tuple[np.ndarray, np.ndarray]:
    """Two unit cubes sharing the square x = 1, each split into 6 tets around its main diagonal (Kuhn).

    The first cube's diagonal runs (0,0,0)-(1,1,1), so its side of the shared square is split along
    (1,0,0)-(1,1,1); the second's runs (1,0,0)-(2,1,1) (conforming: the same split) or (1,1,0)-(2,0,1)
    (mirrored in y: the square is split along (1,0,1)-(1,1,0) on that side -- a non-conforming complex).
    """
    g = np.array([[x, y, z] for x in range(3) for y in range(2) for z in range(2)], dtype=np.float64)
    index = {tuple(p): i for i, p in enumerate(g.astype(int).tolist())}
    tets = []
    for x0, mirror in ((0, False), (1, not conforming)):
        for perm in ([0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]):
            path, p = [], [0, 0, 0]
            path.append(tuple(p))
            for axis in perm:
                p = list(p)
                p[axis] = 1
                path.append(tuple(p))
            corners = [(x0 + q[0], 1 - q[1] if mirror else q[1], q[2]) for q in path]
            tets.append([index[c] for c in corners])
    tets = np.array(tets, dtype=np.int64)
    a, b, c, d = (g[tets[:, k]] for k in range(4))
    neg = np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a)) < 0
    tets[neg] = tets[neg][:, [1, 0, 2, 3]]
    return g, tets


def _hull_faces_of(pts: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Outward faces on the bounding box of `pts` that no other tet shares in the opposite orientation."""
    from tetweave_codec.geometry.delaunay import TET_OUTWARD_FACES

    def key(f):
        return tuple(np.roll(f, -int(np.argmin(f))).tolist())

    faces = tets[:, TET_OUTWARD_FACES].reshape(-1, 3)
    keys = {key(f) for f in faces}
    lo, hi = pts.min(0), pts.max(0)
    on_box = [f for f in faces if np.any(np.all(pts[f] == lo, 0) | np.all(pts[f] == hi, 0))]
    return np.array([f for f in on_box if key(f[[0, 2, 1]]) not in keys], dtype=np.int64)


def test_conforming_cubes_give_a_closed_mesh():
    pts, tets = _two_cubes(conforming=True)
    s = np.full(len(pts), 1.0)
    s[[4, 5, 6, 7]] = -1.0  # the four corners of the shared square are inside
    res = marching_tets_numpy(pts, tets, s, None, _hull_faces_of(pts, tets))
    assert_closed_manifold(res.vertices, res.faces)


@pytest.mark.parametrize("broken", ["non-conforming", "overlapping"])
def test_non_conforming_tetrahedralization_raises(broken):
    from tetweave_codec.errors import TopologyError

    pts, tets = _two_cubes(conforming=broken != "non-conforming")
    if broken == "overlapping":  # one tet twice: its faces are claimed twice in the same orientation
        tets = np.concatenate([tets, tets[:1]])
    s = np.full(len(pts), 1.0)
    s[[4, 6]] = -1.0  # (1,0,0) and (1,1,0): the surface crosses the shared square's diagonals
    with pytest.raises(TopologyError):
        marching_tets_numpy(pts, tets, s, None, _hull_faces_of(pts, tets))


def test_check_manifold_accepts_closed_meshes_and_names_each_defect():
    from tetweave_codec.errors import TopologyError
    from tetweave_codec.geometry.marching_tets import check_manifold

    tetra = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], dtype=np.int64)  # closed, oriented
    check_manifold(tetra, 4)
    check_manifold(tetra[1:], 4, closed=False)  # open but edge-manifold: fine without the closed requirement
    check_manifold(np.zeros((0, 3), np.int64), 0)
    broken = {
        "twin": tetra[1:],  # a hole
        "twice": np.concatenate([tetra, tetra[:1]]),  # a face twice: its directed edges are used twice
        "degenerate": np.concatenate([tetra, [[0, 0, 1]]]),
    }
    flipped = tetra.copy()
    flipped[0] = flipped[0, [0, 2, 1]]  # inconsistent orientation: edges used twice in one direction
    broken["flipped"] = flipped
    for what, faces in broken.items():
        with pytest.raises(TopologyError, match="twin" if what == "twin" else "twice|degenerate"):
            check_manifold(faces, 4)


def test_cached_topology_gives_the_same_mesh_and_follows_sign_changes():
    from tetweave_codec.fit.step import TopologyCache, extract, triangulate

    rng = np.random.default_rng(5)
    pts = rng.uniform(-1, 1, (300, 3))
    grid = triangulate(pts, "exact")
    p = torch.tensor(pts, dtype=torch.float64, requires_grad=True)
    s0 = np.linalg.norm(pts, axis=1) - 0.6
    flipped = s0.copy()
    k = int(np.argmin(np.abs(s0)))
    flipped[k] = -s0[k]
    cache = TopologyCache()
    reused = []
    for s_np in (s0, s0 * 1.01, flipped):
        s = torch.tensor(s_np, requires_grad=True)
        s_ref = torch.tensor(s_np, requires_grad=True)
        before = cache.topology
        got = extract(p, s, None, grid, cache)
        ref = extract(p, s_ref, None, grid)
        for a, b in zip(got, ref, strict=True):
            assert torch.equal(a, b)
        got.vertices.sum().backward()
        ref.vertices.sum().backward()
        assert torch.equal(s.grad, s_ref.grad)
        reused.append(cache.topology is before)
    assert reused == [False, True, False]  # reused exactly when no sign changed
    # a new triangulation (a new tets tensor) is never served from the cache
    other = triangulate(pts[::-1].copy(), "exact")
    out = extract(p, torch.tensor(s0), None, other, cache)
    assert torch.equal(out.faces, extract(p, torch.tensor(s0), None, other).faces)
