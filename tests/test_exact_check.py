"""The independent exact self-intersection check (benchmarks/exact_check.py): known configurations, and its
float filter never hiding a pair that the exact predicates alone find (near-degenerate random soups)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tetweave_codec.benchmarks import exact_check as X

TRI = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def pairs_of(v, f):
    return [tuple(p) for p in X.check(np.asarray(v, float), np.asarray(f)).pairs]


def two(b):
    """Triangle TRI (vertices 0-2) and triangle b (vertices 3-5), sharing no index."""
    return np.vstack([TRI, np.asarray(b, float)]), [[0, 1, 2], [3, 4, 5]]


def test_crossing_touching_and_apart():
    assert pairs_of(*two([[0.2, 0.2, -1], [0.2, 0.2, 1], [0.3, 0.25, 1]])) == [(0, 1)]  # an edge through the face
    assert pairs_of(*two([[0.2, 0.2, 0], [0.2, 0.2, 1], [0.3, 0.25, 1]])) == [(0, 1)]  # a corner on the face
    assert pairs_of(*two([[1.0, 0.0, 0], [2, 0, 1], [2, 1, 1]])) == [(0, 1)]  # corners at one place, two indices
    assert pairs_of(*two([[0.5, 0.5, 0], [1, 1, 0], [1, 2, 0]])) == [(0, 1)]  # coplanar, touching at an edge
    assert pairs_of(*two([[0.2, 0.2, 0], [0.3, 0.2, 0], [0.2, 0.3, 0]])) == [(0, 1)]  # coplanar, inside
    assert pairs_of(*two([[0.2, 0.2, 2**-40], [0.2, 0.2, 1], [0.3, 0.25, 1]])) == []  # a corner just above
    assert pairs_of(*two([[0.51, 0.5, 0], [1, 1, 0], [1, 2, 0]])) == []  # coplanar, just apart
    x = 0.5 + 2**-53  # the corner lies beyond the hypotenuse x + y = 1 by one ulp
    assert pairs_of(*two([[x, 0.5, 0], [1, 1, 0], [1, 2, 0]])) == []


def test_shared_vertex_and_edge():
    v = np.vstack([TRI, [[0.3, 0.3, 0.0], [-1.0, -0.5, 0.0], [0.0, 0.0, 1.0]]])
    assert pairs_of(v, [[0, 1, 2], [0, 3, 5]]) == [(0, 1)]  # the opposite edge of face 1 reaches into face 0
    assert pairs_of(v, [[0, 1, 2], [0, 4, 5]]) == []  # meet only at vertex 0
    assert pairs_of(v, [[0, 1, 2], [0, 1, 3]]) == []  # a shared edge: never counted, folded or not
    folded = np.vstack([TRI, [[0.5, 0.2, 0.0], [0.1, 0.5, 0.0]]])  # coplanar fold around vertex 0
    assert pairs_of(folded, [[0, 1, 2], [0, 3, 4]]) == [(0, 1)]


def test_degenerate_faces_are_counted_not_tested():
    v = np.vstack([TRI, [[0.2, 0.2, -1], [0.2, 0.2, 0], [0.2, 0.2, 1]]])
    r = X.check(v, np.array([[0, 1, 2], [3, 4, 5]]))
    assert r.degenerate == 1 and len(r.pairs) == 0


def brute_force(v, f):
    """Every pair through the exact predicates alone (no boxes, no filter)."""
    out = []
    for i, j in itertools.combinations(range(len(f)), 2):
        pts = X._ints(np.concatenate([v[f[i]], v[f[j]]]))  # one common scale
        a, b = pts[:3], pts[3:]
        if X._collinear(a) or X._collinear(b):
            continue
        shared = [(p, q) for p in range(3) for q in range(3) if f[i][p] == f[j][q]]
        if len(shared) > 1:
            continue
        if X.triangles_meet(a, b, shared[0] if shared else None):
            out.append((i, j))
    return out


@st.composite
def near_degenerate_soups(draw):
    """A few faces on a small lattice, some corners nudged by an ulp or two: corners on other faces' planes,
    coplanar neighbours, crease-like corners, shared vertices."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n = draw(st.integers(4, 9))
    v = rng.integers(-2, 3, size=(n, 3)).astype(np.float64) * 0.25 + draw(st.sampled_from([0.0, 300.0, -7.5]))
    nudge = rng.integers(-2, 3, size=(n, 3)) * (rng.random((n, 3)) < 0.3)
    # an ulp of the coordinate (of 2^-30 at 0: faces whose area underflows binary64, ~1e-154, are degenerate to
    # the decoder's check, n . n = 0, and exactly valid to the exact one; decoded faces never come near that)
    v = v + nudge * np.spacing(np.abs(v) + 2.0**-30)
    faces = []
    for _ in range(draw(st.integers(2, 6))):
        tri = rng.choice(n, 3, replace=False)
        faces.append(tri)
    return v, np.array(faces)


@given(near_degenerate_soups())
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_filter_hides_nothing(case):
    v, f = case
    assert pairs_of(v, f) == brute_force(v, f)


@st.composite
def crease_corners(draw):
    """Two planes meeting at a crease, faces on both, corners nudged by ulps at a magnitude of 300 (the
    issue's CAD part): faces on neighbouring planes, corners on other faces' planes, coplanar neighbours."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n = 10
    u = rng.integers(0, 4, size=n) * 0.25
    w = rng.integers(-3, 4, size=n) * 0.25
    on_b = rng.random(n) < 0.5  # plane z = 0 (w along y) or plane y = 0 (w along z): a 90-degree crease at x
    v = np.stack([u, np.where(on_b, 0.0, w), np.where(on_b, w, 0.0)], axis=1) + 300.0
    v += rng.integers(-1, 2, size=(n, 3)) * (rng.random((n, 3)) < 0.3) * np.spacing(300.0)
    faces = np.array([rng.choice(n, 3, replace=False) for _ in range(draw(st.integers(2, 8)))])
    return v, faces


@pytest.mark.parametrize("native", [True, False], ids=["native", "reference"])
@given(case=st.one_of(near_degenerate_soups(), crease_corners()))
# derandomize: the same 200 cases on every run (CI included); random exploration is the fuzz script's job. A
# random run found the sliver below, which the predicate misses (SLIVER_MISSED).
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
def test_the_decoders_predicate_flags_every_exact_contact(native, case):
    """geometry/intersections.py is conservative: every face in a pair the exact check finds is flagged."""
    from tetweave_codec.geometry import intersections as I

    if native and I._intersect_native is None:
        pytest.skip("C extension not built")
    v, f = case
    saved = I.NATIVE
    try:
        I.NATIVE = native
        flags = I.self_intersecting_faces(v, f)
    finally:
        I.NATIVE = saved
    exact = X.check(v, f).pairs
    assert flags[exact.reshape(-1)].all()


# A face 4e-25 wide (vertices 3 and 7 differ by 4e-25 in x) whose exact contact with face 2 the decoder's predicate
# does not flag (native and reference alike; found by a random run of the test above on 2026-12-06, present since
# at least 0a60d8a). Its area (n . n ~ 1e-50) is above zero, so it is tested, but every tolerance of the pair
# test is relative to the faces' sizes and this contact lies ~1e-25 from the sliver's plane. Marching tets places
# no two vertices of a decoded face that close; kept as a known gap of the conservative claim.
SLIVER_MISSED = (
    np.array(
        [[0.5, 0.0, -0.5], [0.25, -0.25, 0.25], [0.5, -0.5, 0.5], [0.0, -0.25, -0.25], [0.0, -0.5, 0.0],
         [0.0, -0.25, 0.25], [-0.25, 0.25, 0.5], [-4.13590306e-25, -0.25, -0.25], [-0.5, -0.25, 0.0]]
    ),
    np.array([[2, 7, 3], [7, 5, 0], [4, 0, 6]]),
)  # fmt: skip


@pytest.mark.xfail(strict=True, reason="known gap: a 4e-25-wide sliver's contact is not flagged")
def test_a_sliver_contact_is_flagged():
    from tetweave_codec.geometry import intersections as I

    v, f = SLIVER_MISSED
    exact = X.check(v, f).pairs
    assert len(exact)  # the contact is real
    assert I.self_intersecting_faces(v, f)[exact.reshape(-1)].all()
