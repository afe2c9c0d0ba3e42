"""The decoder core's filter and holes (decoder/filter.c, loop.c, intersect.c, holes.c) against the Python reference
(geometry/surface_filter.filter_surface, geometry/holes.open_holes): the same vertices bit for bit, the same faces in
the same order, the same restored count and gave_up, the same refusals -- on the control surfaces of every committed
`.tw` file at each level the file has, with crease rules on Loop levels, on random closed surfaces whose filter
crosses itself (restores), on self-crossing control surfaces (refused) and on holes in the decoded surfaces."""

from __future__ import annotations

import ctypes
import subprocess
from pathlib import Path

import numpy as np
import pytest
from core_lib import core_library

from tetweave_codec.errors import ContainerError
from tetweave_codec.formats.tw import unpack
from tetweave_codec.geometry.delaunay import available_backends, tetrahedralize
from tetweave_codec.geometry.holes import face_ranks, open_holes
from tetweave_codec.geometry.marching_tets import marching_tets_numpy
from tetweave_codec.geometry.surface_filter import MAX_SUBDIVIDED_FACES, filter_surface

REPO = Path(__file__).resolve().parent.parent
TW_OK, TW_ERROR_INVALID, TW_ERROR_LIMIT, TW_ERROR_INTERNAL = 0, 1, 3, 6


class Surface(ctypes.Structure):
    _fields_ = [
        ("nv", ctypes.c_size_t),
        ("nf", ctypes.c_size_t),
        ("v", ctypes.POINTER(ctypes.c_double)),
        ("f", ctypes.POINTER(ctypes.c_int32)),
    ]


class Error(ctypes.Structure):
    _fields_ = [("status", ctypes.c_int), ("message", ctypes.c_char * 256)]


class CoreError(Exception):
    def __init__(self, status: int, message: str):
        super().__init__(f"{status}: {message}")
        self.status, self.message = status, message


@pytest.fixture(scope="module")
def lib():
    lib = core_library(["filter.c", "loop.c", "intersect.c", "holes.c"])
    surface_p = ctypes.POINTER(Surface)
    lib.tw_filter_surface.argtypes = [
        surface_p, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_double, ctypes.c_void_p, ctypes.c_int,
        surface_p, ctypes.POINTER(ctypes.c_uint64), ctypes.POINTER(ctypes.c_int), ctypes.POINTER(Error),
    ]  # fmt: skip
    lib.tw_open_holes.argtypes = [
        surface_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_size_t, surface_p,
        ctypes.POINTER(Error),
    ]  # fmt: skip
    lib.tw_face_ranks.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p]
    lib.tw_surface_free.argtypes = [surface_p]
    return lib


def _surface(v: np.ndarray, f: np.ndarray) -> tuple[Surface, tuple]:
    v = np.ascontiguousarray(v, dtype=np.float64).reshape(-1, 3)
    f = np.ascontiguousarray(f, dtype=np.int32).reshape(-1, 3)
    double_p, int_p = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int32)
    s = Surface(len(v), len(f), v.ctypes.data_as(double_p), f.ctypes.data_as(int_p))
    return s, (v, f)  # the arrays stay alive with the struct


def _take(lib, out: Surface) -> tuple[np.ndarray, np.ndarray]:
    v = np.ctypeslib.as_array(out.v, (out.nv, 3)).copy() if out.nv else np.zeros((0, 3))
    f = np.ctypeslib.as_array(out.f, (out.nf, 3)).astype(np.int64) if out.nf else np.zeros((0, 3), np.int64)
    lib.tw_surface_free(ctypes.byref(out))
    return v, f


def c_filter(lib, v, f, smoothing, subdivision, creases=False, scale=1.0, offset=None, threads=1):
    """tw_filter_surface: (vertices, faces int64, restored, gave_up), or CoreError."""
    s, keep = _surface(v, f)
    out, restored, gave_up, err = Surface(), ctypes.c_uint64(), ctypes.c_int(), Error()
    off = None if offset is None else np.ascontiguousarray(offset, dtype=np.float64)
    status = lib.tw_filter_surface(
        ctypes.byref(s), smoothing, subdivision, int(creases), float(scale), None if off is None else off.ctypes.data,
        threads, ctypes.byref(out), ctypes.byref(restored), ctypes.byref(gave_up), ctypes.byref(err),
    )  # fmt: skip
    if status != TW_OK:
        assert err.status == status and out.nv == 0 and out.nf == 0
        raise CoreError(status, err.message.decode())
    return (*_take(lib, out), restored.value, bool(gave_up.value))


def c_open_holes(lib, v, f, extracted, ranks, children):
    s, keep = _surface(v, f)
    ex = np.ascontiguousarray(extracted, dtype=np.int32)
    r = np.ascontiguousarray(ranks, dtype=np.int64)
    out, err = Surface(), Error()
    status = lib.tw_open_holes(
        ctypes.byref(s), ex.ctypes.data, len(ex), r.ctypes.data, len(r), children, ctypes.byref(out), ctypes.byref(err)
    )
    if status != TW_OK:
        raise CoreError(status, err.message.decode())
    return _take(lib, out)


def assert_same(ref, got):
    """A FilteredSurface and c_filter's tuple: the same bits, faces, counts."""
    v, f, restored, gave_up = got
    assert v.dtype == ref.vertices.dtype and v.shape == ref.vertices.shape
    assert v.tobytes() == ref.vertices.tobytes()
    assert np.array_equal(f, ref.faces)
    assert (restored, gave_up) == (ref.restored, ref.gave_up)


def committed_files() -> list[str]:
    try:
        out = subprocess.run(["git", "ls-files", "*.tw"], cwd=REPO, capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return sorted(str(p.relative_to(REPO)) for p in REPO.rglob("*.tw"))
    return sorted(out.stdout.split())


def control_surface(path: str):
    """(container, vertices, faces): the file's marching-tets surface in the normalized frame, as decoder._extract
    makes it (the file's Delaunay backend, else the first available one)."""
    tw = unpack((REPO / path).read_bytes())
    backend = tw.backend if tw.backend in available_backends() else available_backends()[0]
    pts = np.asarray(tw.points, dtype=np.float64)
    tz = tetrahedralize(pts, backend)
    c = None if tw.c is None or tw.sh_degree < 0 else np.asarray(tw.c, dtype=np.float64)
    mt = marching_tets_numpy(pts, tz.tets, np.asarray(tw.s, dtype=np.float64).reshape(-1), c, tz.hull_faces)
    return tw, mt.vertices, mt.faces


def marching_surface(seed: int, n: int = 1500, shape: str = "torus"):
    """A control surface of random points around an analytic shape (two close spheres: thin gaps where the filter
    makes faces cross, so restores run)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1, 1, (n, 3))
    if shape == "torus":
        s = np.hypot(np.hypot(pts[:, 0], pts[:, 1]) - 0.55, pts[:, 2]) - 0.25
    else:
        s = np.minimum(np.linalg.norm(pts - [0.36, 0, 0], axis=1), np.linalg.norm(pts + [0.36, 0, 0], axis=1)) - 0.35
    tz = tetrahedralize(pts, "auto")
    mt = marching_tets_numpy(pts, tz.tets, s, None, tz.hull_faces)
    return mt.vertices, mt.faces


FILES = committed_files()


@pytest.mark.parametrize("path", FILES)
def test_every_level_of_the_committed_files(lib, path):
    """Control, smoothed and full, in the output frame, threads 1 and 3: the reference's bits."""
    tw, v, f = control_surface(path)
    scale, offset = float(tw.scale), np.asarray(tw.offset, dtype=np.float64)
    for smoothing, subdivision in sorted({(0, 0), (tw.smoothing, 0), (tw.smoothing, tw.subdivision)}):
        ref = filter_surface(v, f, smoothing, subdivision, tw.creases, scale, offset)
        for threads in (1, 3):
            assert_same(ref, c_filter(lib, v, f, smoothing, subdivision, tw.creases, scale, offset, threads))


CREASE_FILES = [p for p in FILES if "5120" in p and ("fandisk" in p or "spot" in p)]


@pytest.mark.parametrize("path", CREASE_FILES)
@pytest.mark.parametrize("smoothing,subdivision", [(0, 1), (3, 1), (1, 2)])
def test_loop_levels_with_crease_rules(lib, path, smoothing, subdivision):
    """Crease-rule Loop levels (numpy in the reference; no committed file asks for them with its creases), with
    and without the output transform."""
    tw, v, f = control_surface(path)
    for creases in (True, False):
        ref = filter_surface(v, f, smoothing, subdivision, creases)
        assert_same(ref, c_filter(lib, v, f, smoothing, subdivision, creases, threads=1))
    ref = filter_surface(v, f, smoothing, subdivision, True, float(tw.scale), np.asarray(tw.offset))
    assert_same(ref, c_filter(lib, v, f, smoothing, subdivision, True, float(tw.scale), tw.offset, threads=3))


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("shape,smoothing,subdivision", [("spheres", 3, 1), ("torus", 1, 2), ("spheres", 2, 0)])
def test_random_surfaces(lib, seed, shape, smoothing, subdivision):
    """Small closed surfaces, some of whose filters cross and are restored; creases on and off."""
    v, f = marching_surface(seed, n=900 + 300 * seed, shape=shape)
    restored = 0
    for creases in (False, True):
        ref = filter_surface(v, f, smoothing, subdivision, creases, 1.7, np.array([0.25, -3.0, 1e-3]))
        restored += ref.restored
        for threads in (1, 3):
            assert_same(ref, c_filter(lib, v, f, smoothing, subdivision, creases, 1.7, [0.25, -3.0, 1e-3], threads))
    if shape == "spheres" and seed == 0:
        assert restored > 0  # the restore rounds ran


def test_restores_and_jittered_controls(lib):
    """Two spheres nearly touching (the filter makes their faces cross: restore rounds) and the same control surface
    moved at random by a share of an edge (it crosses itself: refused by both)."""
    outcomes = set()
    for seed, gap in ((11, 0.36), (12, 0.355), (13, 0.352)):
        rng = np.random.default_rng(seed)
        pts = rng.uniform(-1, 1, (2500, 3))
        s = np.minimum(np.linalg.norm(pts - [gap, 0, 0], axis=1), np.linalg.norm(pts + [gap, 0, 0], axis=1)) - 0.35
        tz = tetrahedralize(pts, "auto")
        mt = marching_tets_numpy(pts, tz.tets, s, None, tz.hull_faces)
        v, f = mt.vertices, mt.faces
        for smoothing, subdivision in ((3, 0), (3, 1), (1, 2)):
            ref = filter_surface(v, f, smoothing, subdivision)
            assert_same(ref, c_filter(lib, v, f, smoothing, subdivision, threads=2))
            outcomes.add("gave up" if ref.gave_up else "restored" if ref.restored else "clean")
        edge = np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1))
        moved = v + rng.uniform(-0.3, 0.3, v.shape) * edge
        with pytest.raises(ContainerError):
            filter_surface(moved, f, 3, 1)
        with pytest.raises(CoreError) as info:
            c_filter(lib, moved, f, 3, 1, threads=3)
        assert info.value.status == TW_ERROR_INVALID
    assert "restored" in outcomes


def test_self_crossing_control_surfaces_are_refused(lib):
    """A control surface that crosses itself: ContainerError in the reference, TW_ERROR_INVALID here, with or
    without a filter (the dropped filter's surface is checked too)."""
    v, f = marching_surface(2, n=900)
    crossing = v.copy()
    crossing[f[0]] = crossing[f[len(f) // 2]] + 1e-3 * np.arange(9).reshape(3, 3)  # one face inside another's place
    for smoothing, subdivision in ((0, 0), (1, 0), (2, 1)):
        with pytest.raises(ContainerError):
            filter_surface(crossing, f, smoothing, subdivision)
        with pytest.raises(CoreError) as info:
            c_filter(lib, crossing, f, smoothing, subdivision)
        assert info.value.status == TW_ERROR_INVALID and "invalid .tw file" in info.value.message


def test_too_many_subdivided_faces_are_refused(lib):
    v, f = marching_surface(1, n=600)
    levels = 1
    while len(f) * 4**levels <= MAX_SUBDIVIDED_FACES:
        levels += 1
    with pytest.raises(ContainerError, match="subdivision levels"):
        filter_surface(v, f, 1, levels)
    with pytest.raises(CoreError) as info:
        c_filter(lib, v, f, 1, levels)
    assert info.value.status == TW_ERROR_LIMIT and "subdivision levels" in info.value.message
    with pytest.raises(CoreError):
        c_filter(lib, v, f, 0, 40)  # 4^40 faces: no overflow


def test_what_is_not_a_closed_manifold_is_refused(lib):
    """The core filters marching tets' checked output only: an open surface or a repeated face is an internal
    error, not a guess."""
    v = np.random.default_rng(0).normal(size=(5, 3))
    for f in (np.array([[0, 1, 2], [0, 2, 3]]), np.array([[0, 1, 2], [0, 1, 2], [0, 2, 1], [0, 2, 1]])):
        with pytest.raises(CoreError) as info:
            c_filter(lib, v, f, 1, 1)
        assert info.value.status == TW_ERROR_INTERNAL
    with pytest.raises(CoreError):
        c_filter(lib, v, np.array([[0, 1, 7], [1, 0, 7], [0, 7, 1], [7, 0, 1]]), 1, 0)  # an index out of range


def test_empty_and_tiny_surfaces(lib):
    """No faces (any filter), one face (no filter: nothing to check it against)."""
    v = np.arange(9.0).reshape(3, 3)
    for f, smoothing, subdivision in ((np.zeros((0, 3), np.int64), 2, 1), (np.array([[0, 1, 2]]), 0, 0)):
        ref = filter_surface(v, f, smoothing, subdivision, False, 2.0, np.array([1.0, 2.0, 3.0]))
        assert_same(ref, c_filter(lib, v, f, smoothing, subdivision, False, 2.0, [1.0, 2.0, 3.0]))


def test_face_ranks(lib):
    rng = np.random.default_rng(3)
    f = rng.integers(0, 40, (3000, 3))
    f = np.concatenate([f, f[:500, ::-1], f[:200]])[rng.permutation(3700)]  # repeated faces: ties by index
    out = np.zeros(len(f), np.int64)
    assert lib.tw_face_ranks(np.ascontiguousarray(f, np.int32).ctypes.data, len(f), out.ctypes.data) == 0
    assert np.array_equal(out, face_ranks(f))


def hole_cases(f0: np.ndarray, rng) -> list[np.ndarray]:
    """Rank sets of the extracted faces f0: scattered faces, a vertex's whole star (one hole), two stars sharing a
    vertex's neighbourhood, and two faces meeting at one vertex only (a pinch: refused)."""
    ranks = face_ranks(f0)
    cases = [np.sort(rng.choice(len(f0), size=k, replace=False)) for k in (1, 7, len(f0) // 50)]
    star = np.flatnonzero((f0 == f0[0, 0]).any(axis=1))
    cases.append(np.sort(ranks[star]))
    ring = np.flatnonzero(np.isin(f0, f0[star].reshape(-1)).any(axis=1))
    cases.append(np.sort(ranks[ring]))
    u = np.argmax(np.bincount(f0.reshape(-1)))  # the vertex of most faces: two of its fan that share only u
    around = np.flatnonzero((f0 == u).any(axis=1))
    pinch = [(a, b) for a in around for b in around if a < b and len(set(f0[a]) & set(f0[b])) == 1]
    cases.append(np.sort(ranks[list(pinch[0])]))
    cases.append(np.array([len(f0)], np.int64))  # a rank past the surface
    return cases


@pytest.mark.parametrize("path", [p for p in FILES if "5120" in p or "10240" in p][:6])
def test_holes_of_the_committed_files(lib, path):
    """open_holes on the decoded surface (full level) with several rank sets: the same mesh or the same refusal."""
    tw, v, f = control_surface(path)
    rng = np.random.default_rng(len(f))
    out = filter_surface(v, f, tw.smoothing, tw.subdivision, tw.creases, float(tw.scale), np.asarray(tw.offset))
    children = 1 if out.gave_up else 4**tw.subdivision
    outcomes = set()
    for ranks in hole_cases(f, rng):
        try:
            ref_v, ref_f = open_holes(out.vertices, out.faces, f, ranks, children)
        except ContainerError as exc:
            with pytest.raises(CoreError) as info:
                c_open_holes(lib, out.vertices, out.faces, f, ranks, children)
            assert info.value.status == TW_ERROR_INVALID
            assert info.value.message.split(":")[0] == str(exc).split(":")[0]
            outcomes.add("refused")
            continue
        got_v, got_f = c_open_holes(lib, out.vertices, out.faces, f, ranks, children)
        assert got_v.tobytes() == ref_v.tobytes() and np.array_equal(got_f, ref_f)
        outcomes.add("opened")
    assert outcomes == {"opened", "refused"}


def test_a_build_without_threads_gives_the_same_surface(lib):
    """-DTW_NO_THREADS (the WebAssembly build): threads run on the calling thread, the same bits."""
    single = core_library(["filter.c", "loop.c", "intersect.c", "holes.c"], defines=("TW_NO_THREADS",))
    single.tw_filter_surface.argtypes = lib.tw_filter_surface.argtypes
    single.tw_surface_free.argtypes = lib.tw_surface_free.argtypes
    tw, v, f = control_surface(CREASE_FILES[-1])
    ref = filter_surface(v, f, 2, 1, False, float(tw.scale), np.asarray(tw.offset))
    assert_same(ref, c_filter(single, v, f, 2, 1, False, float(tw.scale), tw.offset, threads=4))
