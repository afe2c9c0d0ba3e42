"""The decoder filter's compiled paths give the numpy references' bits: Taubin steps and Loop + midpoint levels
(geometry/_filter_native.c), the short self-intersection check of few marked faces (geometry/_intersect_native.c
`marked`), restores, and whole decodes of the committed files."""

from __future__ import annotations

import glob
from pathlib import Path

import numpy as np
import pytest

from tetweave_codec.geometry import intersections, smoothing, subdivision
from tetweave_codec.geometry.intersections import self_intersecting_faces
from tetweave_codec.geometry.surface_filter import filter_surface

REPO = Path(__file__).resolve().parent.parent
needs_filter = pytest.mark.skipif(smoothing._filter_native is None, reason="geometry/_filter_native.c not built")
needs_intersect = pytest.mark.skipif(intersections._intersect_native is None, reason="_intersect_native not built")


def marching_surface(seed: int, n: int = 1500, shape: str = "torus"):
    """A decoder's control surface of random points around an analytic shape: (vertices, faces)."""
    from tetweave_codec.geometry.delaunay import tetrahedralize
    from tetweave_codec.geometry.marching_tets import marching_tets_numpy

    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1, 1, (n, 3))
    if shape == "torus":
        s = np.hypot(np.hypot(pts[:, 0], pts[:, 1]) - 0.55, pts[:, 2]) - 0.25
    else:  # two spheres close together: thin gaps, where smoothing makes faces cross
        s = np.minimum(np.linalg.norm(pts - [0.36, 0, 0], axis=1), np.linalg.norm(pts + [0.36, 0, 0], axis=1)) - 0.35
    tz = tetrahedralize(pts, "auto")
    mt = marching_tets_numpy(pts, tz.tets, s, None, tz.hull_faces)
    return mt.vertices, mt.faces


def jitter(v: np.ndarray, f: np.ndarray, rng, share: float = 0.4) -> np.ndarray:
    """v moved at random by up to `share` of the median edge: a surface with crossing faces."""
    edge = np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1))
    return v + rng.uniform(-share, share, v.shape) * edge


@needs_filter
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_taubin_is_the_references(seed, monkeypatch):
    v, f = marching_surface(seed)
    edges = smoothing.mesh_edges(f, len(v), closed=True)
    fast = smoothing.taubin(v, f, 3, edges=edges)
    crease = smoothing.crease_neighbours(v, f, edges)
    fast_crease = smoothing.taubin(v, f, 2, edges=crease)
    monkeypatch.setattr(smoothing, "NATIVE", False)
    assert fast.tobytes() == smoothing.taubin(v, f, 3, edges=edges).tobytes()
    assert fast_crease.tobytes() == smoothing.taubin(v, f, 2, edges=crease).tobytes()


@needs_filter
def test_loop_refuses_what_is_not_a_closed_manifold():
    """An open mesh or a repeated half-edge: status 1 and the reference's result from loop_and_midpoint."""
    native = smoothing._filter_native
    v = np.random.default_rng(0).normal(size=(5, 3))
    for f in (np.array([[0, 1, 2], [0, 2, 3]]), np.array([[0, 1, 2], [0, 1, 2], [0, 2, 1], [0, 2, 1]])):
        half = np.ascontiguousarray(smoothing.mesh_edges(f, len(v), closed=True))
        size = len(v) + len(half) // 2
        out = np.empty((size, 3)), np.empty((size, 3)), np.empty((4 * len(f), 3), dtype=np.int64)
        assert native.loop(v, v, f, half, *out) == 1
        fast = subdivision.loop_and_midpoint(v, v, f, 1)
        ref = subdivision._refine(v, f, 1, midpoint=False)
        assert fast[0].tobytes() == ref[0].tobytes() and np.array_equal(fast[2], ref[1])


@needs_filter
@pytest.mark.parametrize("levels", [1, 2])
def test_loop_and_midpoint_levels_are_the_references(levels, monkeypatch):
    v, f = marching_surface(3, n=900)
    moved = smoothing.taubin(v, f, 1)
    fast = subdivision.loop_and_midpoint(moved, v, f, levels)
    monkeypatch.setattr(subdivision, "NATIVE", False)
    slow = subdivision.loop_and_midpoint(moved, v, f, levels)
    for a, b in zip(fast, slow, strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@needs_intersect
@pytest.mark.parametrize("seed", range(6))
def test_the_short_check_of_marked_faces_is_the_full_checks(seed):
    """`marked` (few faces marked) against `faces` on surfaces that do cross (vertices moved at random by a
    fraction of an edge), with random marks (some on crossing faces)."""
    v, f = marching_surface(seed, n=1200, shape="spheres")
    rng = np.random.default_rng(seed)
    v = jitter(v, f, rng)
    full = self_intersecting_faces(v, f)
    assert full.any()
    for share in (0.002, 0.02, 0.1):
        only = rng.random(len(f)) < share
        only[np.flatnonzero(full)[: 1 + seed]] = True
        flags = np.zeros(len(f), np.uint8)
        status = intersections._intersect_native.marked(v, f, flags, only.view(np.uint8))
        ref = np.zeros(len(f), np.uint8)
        assert intersections._intersect_native.faces(v, f, ref, only.view(np.uint8)) == 0
        assert status == 0
        np.testing.assert_array_equal(flags, ref)
        assert ref.any()


@needs_intersect
def test_the_short_check_declines_where_the_grid_is_not_its_first_size(monkeypatch):
    """A lattice too fine for the dense count (one huge face among tiny ones): undecided, and the public check then
    runs the full one, whose answer stands."""
    v, f = marching_surface(4, n=600)
    big = np.array([[-50.0, -50, -50], [50, -50, 50], [0, 50, 0]])
    v2 = np.concatenate([v, big])
    f2 = np.concatenate([f, [[len(v), len(v) + 1, len(v) + 2]]])
    only = np.zeros(len(f2), bool)
    only[:3] = True
    flags = np.zeros(len(f2), np.uint8)
    assert intersections._intersect_native.marked(v2, f2, flags, only.view(np.uint8)) == 2
    ref = np.zeros(len(f2), np.uint8)
    assert intersections._intersect_native.faces(v2, f2, ref, only.view(np.uint8)) == 0
    np.testing.assert_array_equal(self_intersecting_faces(v2, f2, only), ref.astype(bool))


@pytest.mark.parametrize("shape,steps,levels", [("spheres", 3, 1), ("torus", 1, 2), ("spheres", 2, 0)])
def test_filter_surface_is_the_references(shape, steps, levels, monkeypatch):
    v, f = marching_surface(5, n=1500, shape=shape)
    fast = filter_surface(v, f, steps, levels)
    for module in (smoothing, subdivision, intersections):
        monkeypatch.setattr(module, "NATIVE", False)
    slow = filter_surface(v, f, steps, levels)
    assert fast.restored == slow.restored and fast.gave_up == slow.gave_up
    assert fast.vertices.tobytes() == slow.vertices.tobytes() and fast.faces.tobytes() == slow.faces.tobytes()


@pytest.mark.parametrize("seed", range(4))
def test_restore_crossings_is_the_references(seed, monkeypatch):
    """Many crossing faces, several rounds of restores (the later rounds take the short check)."""
    from tetweave_codec.geometry.surface_filter import restore_crossings

    v, f = marching_surface(seed, n=1500, shape="spheres")
    rng = np.random.default_rng(seed)
    moved = jitter(v, f, rng, share=0.3 + 0.1 * seed)
    fast = restore_crossings(moved, v, f)
    monkeypatch.setattr(intersections, "NATIVE", False)
    slow = restore_crossings(moved, v, f)
    assert fast[1:] == slow[1:] and fast[1] > 0
    assert fast[0].tobytes() == slow[0].tobytes()


@pytest.mark.parametrize("path", sorted(glob.glob(str(REPO / "benchmarks/results/files/*/size-5120-sh-auto.tw"))))
def test_committed_files_decode_to_the_references_bits(path, monkeypatch):
    """The compiled filter and check against the numpy reference on the committed default files (5 KB: the
    reference's numpy check takes seconds on the larger ones)."""
    from tetweave_codec.decoder import decode

    data = Path(path).read_bytes()
    fast = decode(data)
    for module in (smoothing, subdivision, intersections):
        monkeypatch.setattr(module, "NATIVE", False)
    slow = decode(data)
    assert fast[0].tobytes() == slow[0].tobytes() and fast[1].tobytes() == slow[1].tobytes()


def double_fan(k: int, turns: int, height) -> tuple[np.ndarray, np.ndarray]:
    """k faces around vertex 0 whose link winds `turns` times around it, at heights height(angle)."""
    angle = 2 * np.pi * turns * np.arange(k) / k
    v = np.concatenate([[[0.0, 0, 0]], np.stack([np.cos(angle), np.sin(angle), height(angle)], 1)])
    return v, np.array([[0, 1 + i, 1 + (i + 1) % k] for i in range(k)])


def stars_and_faces(v, f, only, children):
    """(status, flags) of `stars` and the flags of `faces` (status 0)."""
    native = intersections._intersect_native
    fast, ref = np.zeros(len(f), np.uint8), np.zeros(len(f), np.uint8)
    status = native.stars(v, f, fast, only.view(np.uint8), children)
    assert native.faces(v, f, ref, only.view(np.uint8)) == 0
    return status, fast, ref


@needs_intersect
@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("share", [0.0, 0.05, 0.4])
def test_the_patch_check_of_a_loop_level_is_the_full_checks(seed, share):
    """`stars` on Loop levels of control surfaces, smoothed and jittered (0: most patches shown free of crossings;
    0.4 of an edge: folds inside patches, crossings between the two spheres), all faces or some marked, against
    `faces`; the same with children=1 (patches around every vertex)."""
    v0, f0 = marching_surface(seed, n=1000, shape="spheres" if seed % 2 else "torus")
    rng = np.random.default_rng(seed)
    moved = jitter(smoothing.taubin(v0, f0, 1), f0, rng, share) if share else smoothing.taubin(v0, f0, 1)
    v, _, f = subdivision.loop_and_midpoint(moved, v0, f0, 1)
    crossing = 0
    for children in (4, 1):
        for only in (np.ones(len(f), bool), rng.random(len(f)) < 0.3):
            status, fast, ref = stars_and_faces(v, f, only, children)
            assert status == 0
            np.testing.assert_array_equal(fast, ref)
            crossing += int(ref.sum())
    assert crossing > 0 or share < 0.4


@needs_intersect
@pytest.mark.parametrize("k", [9, 11, 14])
def test_a_fan_that_winds_twice_is_tested_not_passed(k):
    """Every face of a twice-wound fan keeps its orientation along the summed normal; only the winding count tells
    that its faces overlap, and those that cross (sharing vertex 0 alone) must be flagged as `faces` flags them."""
    v, f = double_fan(k, 2, lambda a: 0.5 * np.cos(a / 2))
    status, fast, ref = stars_and_faces(v, f, np.ones(len(f), bool), 1)
    assert status == 0 and ref.sum() == 2
    np.testing.assert_array_equal(fast, ref)
    v, f = double_fan(k, 1, lambda a: 0.1 * np.cos(a))  # once: a clean fan
    status, fast, ref = stars_and_faces(v, f, np.ones(len(f), bool), 1)
    assert status == 0 and not ref.any() and not fast.any()


@needs_intersect
def test_the_patch_check_declines_runs_that_are_not_loop_children():
    """Faces shuffled out of their runs of four: undecided with children=4 (flags all 0), and the public check
    then answers as `faces` does."""
    v0, f0 = marching_surface(5, n=800, shape="spheres")
    v, _, f = subdivision.loop_and_midpoint(jitter(v0, f0, np.random.default_rng(5)), v0, f0, 1)
    f = f[np.random.default_rng(0).permutation(len(f))]
    only = np.ones(len(f), bool)
    status, fast, ref = stars_and_faces(v, f, only, 4)
    assert status == 2 and not fast.any() and ref.any()
    np.testing.assert_array_equal(self_intersecting_faces(v, f, children=4), ref.astype(bool))
    assert stars_and_faces(v, f, only, 1)[0] == 0  # as plain faces: decided


@needs_filter
@pytest.mark.parametrize("seed", [0, 1])
def test_crease_edges_are_the_references(seed, monkeypatch):
    """The compiled crease test of a closed mesh (smooth, and jittered: many creases), and the reference's answer
    for an open mesh (declined by the compiled path)."""
    v, f = marching_surface(seed)
    rng = np.random.default_rng(seed)
    meshes = [(v, f), (jitter(v, f, rng), f), (v, f[:-7])]
    fast = []
    for mv, mf in meshes:
        e = smoothing.mesh_edges(mf, len(mv), closed=len(mf) == len(f))
        fast.append((e, smoothing.crease_edges(mv, mf, e)))
    assert 0 < fast[0][1].sum() < fast[1][1].sum()
    monkeypatch.setattr(smoothing, "NATIVE", False)
    for (mv, mf), (e, sharp) in zip(meshes, fast, strict=True):
        np.testing.assert_array_equal(sharp, smoothing.crease_edges(mv, mf, e))


@needs_intersect
@pytest.mark.parametrize("seed", range(2))
def test_threaded_patch_check_and_restores_are_single_threaded(seed):
    """`stars` of a Loop level (children 4), the full grid and the restore rounds (`marked`) on 2 and 4 threads flag
    and restore exactly what one thread does, on a surface large enough that every loop splits into chunks (two
    spheres with thin gaps, smoothed, jittered by 0.3 of an edge: folds inside patches and crossings between
    them)."""
    from tetweave_codec.geometry.surface_filter import restore_crossings

    v0, f0 = marching_surface(seed, n=12_000, shape="spheres")
    rng = np.random.default_rng(seed)
    moved = jitter(smoothing.taubin(v0, f0, 1), f0, rng, 0.3)
    v, reference, f = subdivision.loop_and_midpoint(moved, v0, f0, 1)
    assert len(f) > 12_000
    native = intersections._intersect_native
    for only in (np.ones(len(f), bool), rng.random(len(f)) < 0.3):
        single = np.zeros(len(f), np.uint8)
        assert native.stars(v, f, single, only.view(np.uint8), 4, 1) == 0
        assert single.any()
        for threads in (2, 4):
            out = np.zeros(len(f), np.uint8)
            assert native.stars(v, f, out, only.view(np.uint8), 4, threads) == 0
            np.testing.assert_array_equal(out, single)
            full = np.zeros(len(f), np.uint8)
            assert native.faces(v, f, full, only.view(np.uint8), threads) == 0
            np.testing.assert_array_equal(full, single)
    one = restore_crossings(v, reference, f, children=4, threads=1)
    assert one[1] > 0 and not one[2]  # vertices restored over several checks, then clean
    for threads in (2, 4):
        many = restore_crossings(v, reference, f, children=4, threads=threads)
        assert many[0].tobytes() == one[0].tobytes() and many[1:] == one[1:]
