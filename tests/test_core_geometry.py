"""The C core's exact Delaunay (decoder/delaunay.c) and marching tets (decoder/marching.c) against the Python decoder.

(a) Every committed version-2 file of the exact Delaunay: tw_delaunay of the file's grid cells gives the arrays of
    geometry/delaunay.py `tetrahedralize(points, "exact")` (which snaps the dequantized points to the 2^23 lattice;
    tw_snap_to_lattice gives the same cells), and tw_marching_tets gives the control surface of
    `marching_tets_numpy` bit for bit (float64 vertices, faces, same order).
(b) Random small point sets, lattices with duplicates, and degenerate cases (all inside, all outside, coplanar,
    fewer than 4 points), at every SH degree.
(c) tw_tanh equals geometry/tanh.py's numpy transcription bit for bit and is within 2 ulp of tanh.
(d) Bad arguments (coordinates out of range, a hostile point count, hull indices out of range) are errors.
"""

from __future__ import annotations

import ctypes
import subprocess
from pathlib import Path

import numpy as np
import pytest
from core_lib import core_library

from tetweave_codec.formats import tw
from tetweave_codec.geometry import marching_tets as MT
from tetweave_codec.geometry.delaunay import snap_to_lattice, tetrahedralize, tetrahedralize_cells
from tetweave_codec.geometry.tanh import tanh as reference_tanh

REPO = Path(__file__).resolve().parent.parent
OK, ARGUMENT, INTERNAL = 0, 5, 6


class TwError(ctypes.Structure):
    _fields_ = [("status", ctypes.c_int), ("message", ctypes.c_char * 256)]


class TwTets(ctypes.Structure):
    _fields_ = [
        ("nt", ctypes.c_size_t),
        ("nh", ctypes.c_size_t),
        ("tets", ctypes.POINTER(ctypes.c_int32)),
        ("hull", ctypes.POINTER(ctypes.c_int32)),
    ]


class TwSurface(ctypes.Structure):
    _fields_ = [
        ("nv", ctypes.c_size_t),
        ("nf", ctypes.c_size_t),
        ("v", ctypes.POINTER(ctypes.c_double)),
        ("f", ctypes.POINTER(ctypes.c_int32)),
    ]


def _ptr(a: np.ndarray | None):
    return None if a is None else a.ctypes.data_as(ctypes.c_void_p)


@pytest.fixture(scope="module")
def lib():
    lib = core_library(["delaunay.c", "marching.c"])
    vp, sz, err = ctypes.c_void_p, ctypes.c_size_t, ctypes.POINTER(TwError)
    lib.tw_delaunay.argtypes = [vp, sz, ctypes.POINTER(TwTets), err]
    lib.tw_tets_free.argtypes = [ctypes.POINTER(TwTets)]
    lib.tw_snap_to_lattice.argtypes = [vp, sz, vp, err]
    surface = ctypes.POINTER(TwSurface)
    lib.tw_marching_tets.argtypes = [vp, vp, vp, ctypes.c_int, sz, ctypes.POINTER(TwTets), surface, err]
    lib.tw_surface_free.argtypes = [ctypes.POINTER(TwSurface)]
    lib.tw_tanh.argtypes = [ctypes.c_double]
    lib.tw_tanh.restype = ctypes.c_double
    lib.tw_manifold_defect.argtypes = [vp, sz, sz, ctypes.c_int, ctypes.POINTER(ctypes.c_int), err]
    return lib


def _array(ptr, count: int, dtype) -> np.ndarray:
    if count == 0:
        return np.zeros(0, dtype)
    return np.ctypeslib.as_array(ptr, shape=(count,)).astype(dtype, copy=True)


def c_delaunay(lib, cells: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, str]:
    c = np.ascontiguousarray(cells, dtype=np.int32).reshape(-1, 3)
    out, err = TwTets(), TwError()
    status = lib.tw_delaunay(_ptr(c), len(c), ctypes.byref(out), ctypes.byref(err))
    tets = _array(out.tets, 4 * out.nt, np.int64).reshape(-1, 4)
    hull = _array(out.hull, 3 * out.nh, np.int64).reshape(-1, 3)
    lib.tw_tets_free(ctypes.byref(out))
    return status, tets, hull, err.message.decode()


def c_surface(lib, points, s, c, degree, tets, hull) -> tuple[int, np.ndarray, np.ndarray, str]:
    pts = np.ascontiguousarray(points, dtype=np.float64)
    s = np.ascontiguousarray(s, dtype=np.float64)
    coeffs = None if c is None else np.ascontiguousarray(c, dtype=np.float64)
    t32 = np.ascontiguousarray(tets, dtype=np.int32).reshape(-1, 4)
    h32 = np.ascontiguousarray(hull, dtype=np.int32).reshape(-1, 3)
    tz = TwTets(len(t32), len(h32), t32.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)),
                h32.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)))  # fmt: skip
    out, err = TwSurface(), TwError()
    status = lib.tw_marching_tets(_ptr(pts), _ptr(s), _ptr(coeffs), degree, len(pts), ctypes.byref(tz),
                                  ctypes.byref(out), ctypes.byref(err))  # fmt: skip
    v = _array(out.v, 3 * out.nv, np.float64).reshape(-1, 3)
    f = _array(out.f, 3 * out.nf, np.int64).reshape(-1, 3)
    lib.tw_surface_free(ctypes.byref(out))
    return status, v, f, err.message.decode()


def assert_same_surface(lib, points, s, c, degree):
    """tw_delaunay + tw_marching_tets on the lattice cells of `points` equal the Python decoder's two stages."""
    tz = tetrahedralize(points, "exact")
    status, tets, hull, message = c_delaunay(lib, snap_to_lattice(points))
    assert status == OK, message
    assert np.array_equal(tets, tz.tets) and np.array_equal(hull, tz.hull_faces)
    ref = MT.marching_tets_numpy(points, tz.tets, s, c, tz.hull_faces)
    status, v, f, message = c_surface(lib, points, s, c, degree, tets, hull)
    assert status == OK, message
    assert v.shape == ref.vertices.shape and np.array_equal(v, ref.vertices)
    assert f.shape == ref.faces.shape and np.array_equal(f, ref.faces)
    return ref


def _exact_files() -> list[str]:
    out = subprocess.run(["git", "ls-files", "*.tw"], cwd=REPO, capture_output=True, text=True, check=True)
    names = []
    for name in out.stdout.split():
        f = tw.unpack((REPO / name).read_bytes())
        if f.version == 2 and f.backend == "exact":
            names.append(name)
    return names


EXACT_FILES = _exact_files()


def test_there_are_committed_exact_files():
    assert len(EXACT_FILES) >= 8


@pytest.mark.parametrize("name", EXACT_FILES)
def test_committed_file_tets_and_control_surface(lib, name):
    f = tw.unpack((REPO / name).read_bytes())
    points = f.points
    c = f.c if f.c.shape[1] else None
    # the Python decoder snaps the dequantized points to the lattice; the C decoder may take the grid cells
    lattice = snap_to_lattice(points)
    snapped = np.zeros_like(lattice, dtype=np.int32)
    err = TwError()
    pts = np.ascontiguousarray(points)
    assert lib.tw_snap_to_lattice(_ptr(pts), len(points), _ptr(snapped), ctypes.byref(err)) == OK
    assert np.array_equal(snapped, lattice)
    tz = tetrahedralize(points, "exact")
    for cells in (f.cells, lattice):
        status, tets, hull, message = c_delaunay(lib, cells)
        assert status == OK, message
        assert np.array_equal(tets, tz.tets) and np.array_equal(hull, tz.hull_faces)
    ref = assert_same_surface(lib, points, f.s, c, f.sh_degree)
    assert len(ref.faces) > 1000


@pytest.mark.parametrize("seed", range(12))
def test_random_sets_every_degree(lib, seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 400))
    if seed % 3 == 0:  # a small lattice: cospherical and coplanar subsets, duplicates
        points = rng.integers(0, 5, (n, 3)).astype(np.float64) * 0.3 - 0.6
    else:
        points = rng.uniform(-1.1, 1.1, (n, 3))
    degree = seed % 5 - 1
    q = (degree + 1) ** 2
    s = np.linalg.norm(points, axis=1) - rng.uniform(0.3, 0.9)
    c = rng.normal(0, 0.5 if seed % 2 else 4.0, (n, q)) if q else None  # 4.0: tanh saturates on some edges
    assert_same_surface(lib, points, s, c, degree)


@pytest.mark.parametrize("case", ["all inside", "all outside", "coplanar", "three points", "collinear"])
def test_degenerate_sets(lib, case):
    rng = np.random.default_rng(7)
    points = rng.uniform(-1, 1, (50, 3))
    s = rng.uniform(0.1, 1, 50)
    if case == "all inside":
        s = -s
    elif case == "coplanar":
        points[:, 2] = 0.25
        s[::2] *= -1
    elif case == "three points":
        points, s = points[:3], -s[:3]
    elif case == "collinear":
        points[:, 1:] = 0.0
        s[::2] *= -1
    c = rng.normal(0, 0.3, (len(points), 4))
    ref = assert_same_surface(lib, points, s, c, 1)
    if case == "all inside":  # closed by the hull caps alone
        assert len(ref.faces) and (ref.edges[:, 0] == ref.edges[:, 1]).all()
    else:
        assert len(ref.faces) == 0


def test_tanh_is_the_reference_sequence(lib):
    rng = np.random.default_rng(3)
    x = np.concatenate([
        rng.standard_normal(20000) * 3, rng.uniform(-1e-6, 1e-6, 2000), np.exp(rng.uniform(-60, 4, 4000)),
        [0.0, -0.0, 2.0**-27, -(2.0**-27), np.nextafter(2.0**-27, 0), 19.999999, 20.0, -20.0, 1e308, np.inf, -np.inf],
    ])  # fmt: skip
    ours = np.array([lib.tw_tanh(float(v)) for v in x])
    ref = reference_tanh(x)
    assert np.array_equal(ours.view(np.int64), ref.view(np.int64))
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.prec = 160
    sample = x[::7]
    exact = np.array([float(mpmath.tanh(mpmath.mpf(float(v)))) for v in sample])
    ulps = np.abs(np.abs(reference_tanh(sample)).view(np.int64) - np.abs(exact).view(np.int64))
    assert ulps.max() <= 2


def test_bad_arguments_are_errors(lib):
    status, *_, message = c_delaunay(lib, np.array([[0, 0, 1 << 23]] * 4))
    assert status == ARGUMENT and "2^23" in message
    status, *_, message = c_delaunay(lib, np.array([[0, 0, -1]] * 4))
    assert status == ARGUMENT
    # a hostile count is refused before anything is read
    out, err = TwTets(), TwError()
    one = np.zeros(3, np.int32)
    assert lib.tw_delaunay(_ptr(one), (1 << 26) + 1, ctypes.byref(out), ctypes.byref(err)) == ARGUMENT
    assert b"at most" in err.message
    points = np.random.default_rng(0).uniform(-1, 1, (20, 3))
    tz = tetrahedralize(points)
    s = np.linalg.norm(points, axis=1) - 0.5
    status, *_, message = c_surface(lib, points, s, None, -1, tz.tets, np.array([[0, 1, 99]]))
    assert status == ARGUMENT
    status, *_, message = c_surface(lib, points, s, None, -1, np.array([[0, 1, 2, 20]]), tz.hull_faces)
    assert status == ARGUMENT
    status, *_, message = c_surface(lib, points, s, None, 4, tz.tets, tz.hull_faces)
    assert status == ARGUMENT


def test_broken_tets_are_internal_errors(lib):
    # the tets of a proper tetrahedralization with one tet removed: an open surface where the sphere crosses it
    points = np.random.default_rng(1).uniform(-1, 1, (200, 3))
    tz = tetrahedralize(points)
    s = np.linalg.norm(points, axis=1) - 0.5
    mixed = [t for t, row in enumerate(tz.tets) if 0 < (s[row] < 0).sum() < 4]
    tets = np.delete(tz.tets, mixed[0], axis=0)
    status, _, _, message = c_surface(lib, points, s, None, -1, tets, tz.hull_faces)
    assert status == INTERNAL and "twin" in message
    with pytest.raises(Exception, match="twin"):
        MT.marching_tets_numpy(points, tets, s, None, tz.hull_faces)


@pytest.mark.parametrize("seed", range(20))
def test_manifold_defect_matches_check_manifold(lib, seed):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1, 1, (60, 3))
    tz = tetrahedralize(points)
    faces = MT.marching_tets_numpy(points, tz.tets, np.linalg.norm(points, axis=1) - 0.6, None, tz.hull_faces).faces
    faces = faces.copy()
    nv = int(faces.max()) + 1
    kind = seed % 4
    i = int(rng.integers(len(faces)))
    if kind == 0:
        faces = np.delete(faces, i, axis=0)
    elif kind == 1:
        faces = np.concatenate([faces, faces[i : i + 1]])
    elif kind == 2:
        faces[i] = faces[i, [0, 2, 1]]
    elif seed % 8 == 3:
        faces[i, 1] = faces[i, 0]
    for closed in (True, False):
        f32 = np.ascontiguousarray(faces, dtype=np.int32)
        defect, err = ctypes.c_int(), TwError()
        assert lib.tw_manifold_defect(_ptr(f32), len(f32), nv, closed, ctypes.byref(defect), ctypes.byref(err)) == OK
        saved = MT.NATIVE
        MT.NATIVE = False
        try:
            MT.check_manifold(faces, nv, closed=closed)
            expected = 0
        except Exception as error:
            expected = 1 + [m in str(error) for m in MT._MANIFOLD_ERRORS].index(True)
        finally:
            MT.NATIVE = saved
        assert defect.value == expected


def test_tets_from_cells_equal_tetrahedralize_cells(lib):
    rng = np.random.default_rng(5)
    for bits in (1, 3, 8, 23):
        cells = rng.integers(0, 1 << bits, (int(rng.integers(0, 500)), 3))
        ref = tetrahedralize_cells(cells)
        status, tets, hull, message = c_delaunay(lib, cells)
        assert status == OK, message
        assert np.array_equal(tets, ref.tets) and np.array_equal(hull, ref.hull_faces)
