"""The decoder core's parse (decoder/container.c tw_parse with octree.c, predict.c, dequantize.c and the entropy
stages) against the Python reference, formats.tw.unpack.

* every committed exact-Delaunay v2 file parses to the same cells, points, s, c (float64 bit for bit), holes and
  header fields; files of earlier encoders (version 1, TetGen or Qhull v2) are refused as unsupported;
* the hostile corpus of benchmarks/fuzz.py (structure-aware mutations of v2 files, CRC recomputed) gives either a
  ContainerError in Python and an error in C, or the same parsed arrays -- and, built with AddressSanitizer and
  UndefinedBehaviorSanitizer, never a memory error, a leak or undefined behaviour;
* the s prediction's exact fallback for points over the search's work cap (a box hierarchy, where the reference
  uses scipy's k-d tree) gives the reference's neighbours.
"""

from __future__ import annotations

import ctypes
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
from core_lib import CORE, FLAGS, core_library, require_compiler

from tetweave_codec.benchmarks import fuzz
from tetweave_codec.errors import ContainerError
from tetweave_codec.formats import predict, tw
from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.common import BITS_EXACT, FLAG_HOLES, FLAG_S_PREDICTED, seal

REPO = Path(__file__).resolve().parent.parent
SOURCES = ["range.c", "attributes.c", "holes_section.c", "container.c", "octree.c", "predict.c", "dequantize.c"]
TW_OK, TW_ERROR_INVALID, TW_ERROR_UNSUPPORTED = 0, 1, 2
FUZZ_CASES = 1500
SANITIZER_CASES = 600
I64 = ctypes.POINTER(ctypes.c_int64)


class Error(ctypes.Structure):
    _fields_ = [("status", ctypes.c_int), ("message", ctypes.c_char * 256)]


class File(ctypes.Structure):
    """decoder/internal.h tw_file."""

    _fields_ = [
        *[(name, ctypes.c_int) for name in "version flags sh_degree q position_bits exact creases".split()],
        ("smoothing", ctypes.c_int),
        ("subdivision", ctypes.c_int),
        ("n", ctypes.c_uint32),
        ("scale", ctypes.c_double),
        ("offset", ctypes.c_double * 3),
        ("s_step", ctypes.c_double),
        ("c_steps", ctypes.c_double * 4),
        ("cells", ctypes.POINTER(ctypes.c_int32)),
        ("points", ctypes.POINTER(ctypes.c_double)),
        ("s", ctypes.POINTER(ctypes.c_double)),
        ("c", ctypes.POINTER(ctypes.c_double)),
        ("holes", I64),
        ("hole_count", ctypes.c_size_t),
        ("sizes", ctypes.c_size_t * 5),
    ]


@pytest.fixture(scope="module")
def lib():
    lib = core_library(SOURCES)
    lib.tw_parse.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.POINTER(File), ctypes.POINTER(Error)]
    lib.tw_file_free.argtypes = [ctypes.POINTER(File)]
    lib.tw_predict_s.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p, ctypes.c_void_p,
                                 ctypes.POINTER(Error)]  # fmt: skip
    lib.tw_neighbors_begin.argtypes = [ctypes.POINTER(ctypes.c_void_p), I64, I64, ctypes.c_int64, ctypes.c_int64,
                                       ctypes.c_int64, ctypes.c_int, ctypes.c_int64]  # fmt: skip
    lib.tw_neighbors_row.argtypes = [ctypes.c_void_p, ctypes.c_int64, I64, I64]
    lib.tw_neighbors_end.argtypes = [ctypes.c_void_p]
    lib.tw_point_tree_build.argtypes = [ctypes.POINTER(ctypes.c_void_p), I64, ctypes.c_int64]
    lib.tw_point_tree_neighbors.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64, I64, I64]
    lib.tw_point_tree_free.argtypes = [ctypes.c_void_p]
    return lib


def parse(lib, data: bytes):
    """(status, message, parsed) of tw_parse; parsed: the header fields and copies of the arrays (None on error)."""
    f, err = File(), Error()
    status = lib.tw_parse(data, len(data), ctypes.byref(f), ctypes.byref(err))
    if status:
        assert not f.cells and not f.points and f.n == 0  # zeroed on failure: nothing to free
        return status, err.message.decode(), None
    n, q = f.n, f.q

    def array(ptr, shape):
        return np.ctypeslib.as_array(ptr, shape).copy() if n and shape[-1] else np.zeros(shape)

    out = {name: getattr(f, name) for name in "version flags sh_degree q position_bits exact creases".split()}
    out.update(smoothing=f.smoothing, subdivision=f.subdivision, n=n, scale=f.scale, s_step=f.s_step)
    out.update(offset=np.array(f.offset[:]), c_steps=tuple(f.c_steps[: f.sh_degree + 1]), sizes=tuple(f.sizes))
    out.update(cells=array(f.cells, (n, 3)), points=array(f.points, (n, 3)), s=array(f.s, (n,)))
    out["c"] = array(f.c, (n, q))
    out["holes"] = np.ctypeslib.as_array(f.holes, (f.hole_count,)).copy() if f.hole_count else None
    lib.tw_file_free(ctypes.byref(f))
    return status, "", out


def reference(data: bytes):
    """formats.tw.unpack's file, or None when it raises ContainerError (anything else fails the test)."""
    try:
        return tw.unpack(data)
    except ContainerError:
        return None


def assert_same(parsed: dict, ref) -> None:
    """The C parse equals the reference's file: arrays bit for bit, every header field."""
    assert parsed["version"] == 2 and ref.version == 2
    assert np.array_equal(parsed["cells"], ref.cells)
    assert parsed["points"].tobytes() == np.ascontiguousarray(ref.points).tobytes()
    assert parsed["s"].tobytes() == np.ascontiguousarray(ref.s).tobytes()
    assert parsed["c"].shape == ref.c.shape
    assert parsed["c"].tobytes() == np.ascontiguousarray(ref.c, dtype=np.float64).tobytes()
    if ref.holes is None:
        assert parsed["holes"] is None
    else:
        assert np.array_equal(parsed["holes"], ref.holes)
    assert (parsed["flags"], parsed["sh_degree"], parsed["position_bits"]) == (ref.flags, ref.sh_degree,
                                                                               ref.position_bits)  # fmt: skip
    assert (bool(parsed["exact"]), bool(parsed["creases"])) == (ref.exact, ref.creases)
    assert (parsed["smoothing"], parsed["subdivision"], parsed["n"]) == (ref.smoothing, ref.subdivision, ref.num_points)
    assert parsed["q"] == ref.c.shape[1]
    assert parsed["scale"] == ref.scale and parsed["offset"].tobytes() == np.asarray(ref.offset).tobytes()
    assert parsed["s_step"] == ref.s_step and parsed["c_steps"] == tuple(ref.c_band_steps)
    sizes = ref.sizes
    assert parsed["sizes"] == (sizes["header"], sizes["positions"], sizes["s"], sizes["c"], sizes["checksum"])


def committed_files() -> list[Path]:
    files = sorted((REPO / "benchmarks" / "results" / "files").glob("*/*.tw"))
    files += sorted((REPO / "tests").glob("**/*.tw"))
    assert files, "the repository's .tw files are missing"
    return files


def test_committed_files_parse_as_the_reference_does(lib):
    exact = 0
    for path in committed_files():
        data = path.read_bytes()
        ref = tw.unpack(data)
        status, message, parsed = parse(lib, data)
        if ref.version == 2 and ref.exact:
            assert status == TW_OK, f"{path.name}: {message}"
            assert_same(parsed, ref)
            exact += 1
        else:  # an earlier encoder's file: valid, decoded by the Python package only
            assert status == TW_ERROR_UNSUPPORTED, path.name
            assert "Python package" in message and ("TetGen" in message or "Qhull" in message)
    assert exact >= 16


def test_files_of_earlier_encoders_are_unsupported(lib):
    rng = np.random.default_rng(3)
    v1 = tw.pack(tw.TetWeaveFile(rng.normal(size=(20, 3)).astype(np.float16), rng.normal(size=20).astype(np.float16),
                                 np.zeros((20, 0), np.float16), -1, 2.0, np.zeros(3), 0))  # fmt: skip
    assert tw.unpack(v1).version == 1
    status, message, _ = parse(lib, v1)
    assert status == TW_ERROR_UNSUPPORTED and "version-1" in message and "Python package" in message
    names = {"exact": 0, "qhull": 0, "tetgen": 0}
    for name, data in fuzz.seed_files(seed=1, max_points=200, holes=False):
        backend = next(b for b in names if b in name) if "tiny" not in name else None
        ref = tw.unpack(data)
        status, message, parsed = parse(lib, data)
        if ref.exact:
            assert status == TW_OK, f"{name}: {message}"
            assert_same(parsed, ref)
        else:
            assert status == TW_ERROR_UNSUPPORTED, name
            assert ("Qhull" if ref.flags & 1 else "TetGen") in message
        if backend:
            names[backend] += 1
    assert min(names.values()) > 0


MAGIC = b"\x89TWV\r\n\x1a\n"


@pytest.mark.parametrize("data", [b"", b"\x89TW", MAGIC, MAGIC + b"\x02\x00", b"not a tw file", MAGIC + b"\x03\x00"])
def test_short_and_foreign_bytes_are_invalid(lib, data):
    assert reference(data) is None
    status, message, _ = parse(lib, data)
    assert status == TW_ERROR_INVALID and message and "\n" not in message


@pytest.mark.parametrize("flags", [0, FLAG_S_PREDICTED, FLAG_HOLES, FLAG_HOLES | FLAG_S_PREDICTED])
def test_zero_points(lib, flags):
    # N = 0 with every section empty is a valid (empty) file, except with a holes section, whose K needs 4 bytes
    count = 4 if flags & FLAG_HOLES else 3
    header = struct.pack("<8sHBbBI4df", MAGIC, 2, flags, -1, 6 | BITS_EXACT, 0, 1.0, 0.0, 0.0, 0.0, 1e-3)
    data = seal(header + bytes(4 * count))
    ref = reference(data)
    status, message, parsed = parse(lib, data)
    if flags & FLAG_HOLES:
        assert ref is None and status == TW_ERROR_INVALID and message
    else:
        assert ref is not None and status == TW_OK
        assert_same(parsed, ref)


def hostile_corpus(count: int, start: int = 0):
    """(bytes, mutations) of fuzz.py's cases on its seed files (exact ones mostly) and two real files."""
    seeds = [data for _, data in fuzz.seed_files(seed=0, max_points=300, backends=("exact", "exact", "tetgen"))]
    real = sorted((REPO / "benchmarks" / "results" / "files").glob("*/size-5120-*.tw"))[:2]
    seeds += [p.read_bytes() for p in real]
    for i in range(start, start + count):
        _, data, applied = fuzz.mutate(np.random.default_rng([58, i]), seeds)
        yield data, applied


def test_hostile_files_give_the_references_answer(lib):
    outcomes = {"rejected": 0, "same": 0, "unsupported": 0}
    for data, applied in hostile_corpus(FUZZ_CASES):
        ref = reference(data)
        status, message, parsed = parse(lib, data)
        if ref is None:
            assert status in (TW_ERROR_INVALID, TW_ERROR_UNSUPPORTED), (applied, status, message)
            if status == TW_ERROR_UNSUPPORTED:  # only an earlier encoder's file may say so
                assert data[8] == 1 or not data[12] & BITS_EXACT, applied
            assert message and "\n" not in message
            outcomes["rejected"] += 1
        elif ref.version == 2 and ref.exact:
            assert status == TW_OK, (applied, message)
            assert_same(parsed, ref)
            outcomes["same"] += 1
        else:
            assert status == TW_ERROR_UNSUPPORTED, applied
            outcomes["unsupported"] += 1
    # the corpus exercises both sides: files rejected behind a valid CRC and mutated files that still decode
    assert outcomes["rejected"] > FUZZ_CASES // 4 and outcomes["same"] > FUZZ_CASES // 20, outcomes


def test_every_model_byte_at_its_extremes_gives_the_references_answer(lib):
    # the models of each section (octree histograms and context bytes, the mask, sign and bucket models), each
    # set to 0, 1 and 255 behind a valid CRC: e.g. a zero context byte of a bit-coded level is refused even when
    # no bit uses that context (entropy.binary_weight_rows), an all-zero histogram always
    seeds = [d for n, d in fuzz.seed_files(seed=2, max_points=120, holes=False) if "exact" in n and "ctx" in n][:3]
    seeds.append(sorted((REPO / "benchmarks" / "results" / "files").glob("spot/size-5120-*.tw"))[0].read_bytes())
    checked = {"rejected": 0, "same": 0}
    for seed in seeds:
        parts = fuzz.split(seed)
        for k, section in enumerate(parts.sections):
            for at in range(min(len(section), 2 + 12 * 16 if k == 0 else 40)):
                for value in (0, 1, 255):
                    mutated = fuzz.Parts(bytearray(parts.header), list(parts.sections))
                    mutated.sections[k] = section[:at] + bytes([value]) + section[at + 1 :]
                    data = fuzz.assemble(mutated)
                    ref = reference(data)
                    status, message, parsed = parse(lib, data)
                    if ref is None:
                        assert status == TW_ERROR_INVALID, (k, at, value, status, message)
                        checked["rejected"] += 1
                    else:
                        assert status == TW_OK, (k, at, value, message)
                        assert_same(parsed, ref)
                        checked["same"] += 1
    assert checked["rejected"] > 100 and checked["same"] > 100, checked


def sanitizer_harness(tmp_path: Path) -> Path | None:
    """tests/core_parse_harness.c with the core's sources under ASan + UBSan (None when the compiler lacks them)."""
    cc = require_compiler()
    exe = tmp_path / "parse_harness"
    flags = [f for f in FLAGS if f not in ("-shared", "-fPIC", "-O2")] + ["-O1", "-g", "-fno-omit-frame-pointer"]
    sanitize = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
    sources = [CORE / "common.c", *(CORE / s for s in SOURCES), REPO / "tests" / "core_parse_harness.c"]
    run = subprocess.run([cc, *flags, *sanitize, "-o", str(exe), *map(str, sources), "-lm"], capture_output=True,
                         text=True)  # fmt: skip
    return exe if run.returncode == 0 else None


def test_hostile_files_under_sanitizers(lib, tmp_path):
    exe = sanitizer_harness(tmp_path)
    if exe is None:
        pytest.skip("the C compiler cannot build with -fsanitize=address,undefined")
    corpus = tmp_path / "corpus"
    corpus.mkdir()
    paths, expected = [], []
    cases = list(hostile_corpus(SANITIZER_CASES, start=FUZZ_CASES))
    cases += [(p.read_bytes(), ["committed"]) for p in committed_files()]
    for i, (data, _) in enumerate(cases):
        path = corpus / f"{i:05d}.tw"
        path.write_bytes(data)
        paths.append(str(path))
        status, _, parsed = parse(lib, data)
        expected.append((status, parsed["n"] if parsed else 0, len(parsed["holes"]) if parsed and parsed["holes"]
                         is not None else 0))  # fmt: skip
    run = subprocess.run([str(exe), *paths], capture_output=True, text=True, timeout=600,
                         env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=0", "PATH": "/usr/bin:/bin"})  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    lines = run.stdout.split("\n")[: len(paths)]
    got = [tuple(int(x) for x in line.split()[:3]) for line in lines]
    assert got == expected  # the sanitized build answers as the optimized one
    assert sum(1 for s, _, _ in got if s == TW_OK) > 20


# -----------------------------------------------------------------------------------------------------------
# the s prediction's fallback for points over the work cap


def canonical(cells: np.ndarray) -> np.ndarray:
    cells, _ = Q.merge_collisions(np.clip(cells, 0, (1 << 16) - 1))
    return np.ascontiguousarray(cells[Q.canonical_order(cells)], dtype=np.int64)


def tree_neighbours(lib, cells: np.ndarray, rows, bound_rank: int, k: int = predict.K_NEIGHBORS):
    tree = ctypes.c_void_p()
    assert lib.tw_point_tree_build(ctypes.byref(tree), cells.ctypes.data_as(I64), len(cells)) == TW_OK
    idx = np.full((len(cells), k), -1, dtype=np.int64)
    d2 = np.zeros((len(cells), k), dtype=np.int64)
    try:
        for i in rows:
            row_idx, row_d2 = idx[i], d2[i]
            rc = lib.tw_point_tree_neighbors(tree, int(i), k, bound_rank, row_idx.ctypes.data_as(I64),
                                             row_d2.ctypes.data_as(I64))  # fmt: skip
            assert rc == TW_OK
    finally:
        lib.tw_point_tree_free(tree)
    return idx, d2


@pytest.mark.parametrize("kind", ["uniform", "clustered", "lattice", "sparse-dense"])
@pytest.mark.parametrize("bound_rank", [3, 24, 96, 4096])
def test_tree_fallback_gives_the_k_d_trees_neighbours(lib, kind, bound_rank, monkeypatch):
    rng = np.random.default_rng([bound_rank, len(kind)])
    if kind == "uniform":
        cells = rng.integers(0, 1 << int(rng.integers(3, 17)), (700, 3))
    elif kind == "clustered":
        centers = rng.integers(0, 1 << 16, (4, 3))
        cells = centers[rng.integers(0, 4, 700)] + rng.integers(-6, 7, (700, 3))
    elif kind == "lattice":  # many equal distances: the (d2, index) rule and the strict bound decide
        cells = np.stack(np.meshgrid(*[np.arange(9) * 2] * 3, indexing="ij"), -1).reshape(-1, 3) + 500
    else:
        block = np.stack(np.meshgrid(*[np.arange(8) + 500] * 3, indexing="ij"), -1).reshape(-1, 3)
        cells = np.concatenate([block, rng.integers(400, 620, (200, 3))])
    cells = canonical(cells)
    n = len(cells)
    idx, d2 = tree_neighbours(lib, cells, range(n), bound_rank)
    monkeypatch.setattr(predict, "QUERY_WIDTHS", (bound_rank,))
    ref_idx = np.full((n, predict.K_NEIGHBORS), -1, dtype=np.int64)
    ref_d2 = np.zeros_like(ref_idx)
    predict._tree_rows(cells, np.arange(n), ref_idx, ref_d2)
    assert np.array_equal(idx, ref_idx) and np.array_equal(d2, ref_d2)


def test_points_over_the_work_cap_predict_as_the_reference(lib):
    # a dense block of more points than the cap (2^16) and sparse points beyond it, later in Morton order: the
    # grid search gives up on them (their 3x3x3 block holds the dense block) and the exact fallback answers
    block = np.stack(np.meshgrid(*[np.arange(41)] * 3, indexing="ij"), -1).reshape(-1, 3)
    rng = np.random.default_rng(11)
    cells = canonical(np.concatenate([block, rng.integers(700, 1100, (40, 3))]))
    n = len(cells)
    morton = Q.morton_keys(cells).astype(np.int64)
    search = ctypes.c_void_p()
    assert lib.tw_neighbors_begin(ctypes.byref(search), cells.ctypes.data_as(I64), morton.ctypes.data_as(I64), n,
                                  predict.K_NEIGHBORS, predict.QUERY_WIDTHS[-1], predict._first_level(morton),
                                  predict.GRID_MAX_CANDIDATES) == TW_OK  # fmt: skip
    idx, d2 = np.zeros(predict.K_NEIGHBORS, np.int64), np.zeros(predict.K_NEIGHBORS, np.int64)
    over = [i for i in range(len(block) - 5, n) if lib.tw_neighbors_row(search, i, idx.ctypes.data_as(I64),
                                                                        d2.ctypes.data_as(I64)) == 1]  # fmt: skip
    lib.tw_neighbors_end(search)
    assert len(over) > 5  # the case the test is about
    s_sym = np.clip(np.rint(np.linalg.norm(cells - 600, axis=1) - 300), -(2**20), 2**20 - 1).astype(np.int64)
    residual = predict.residuals(cells, s_sym)  # the reference, whose neighbour search sends `over` to scipy
    out = np.zeros(n, dtype=np.int32)
    err = Error()
    res32 = np.ascontiguousarray(residual, dtype=np.int32)
    cells32 = np.ascontiguousarray(cells, dtype=np.int32)
    status = lib.tw_predict_s(cells32.ctypes.data, n, res32.ctypes.data, out.ctypes.data, ctypes.byref(err))
    assert status == TW_OK, err.message
    assert np.array_equal(out, s_sym)
