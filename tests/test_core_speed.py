"""The decoder core's fast paths give what the plain ones give (decoder/intersect.c's selections).

The crossing check's cell size is twice the median face extent (intersections._candidate_pairs' np.median); the
core selects it by a radix selection on the bits of the extents where they allow (no NaN, no sign bit), else by
Hoare's selection. Here both against numpy on extents with ties, zeros, infinities, spreads of magnitudes, and the
inputs the radix path refuses.
"""

from __future__ import annotations

import ctypes
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

from tests.core_lib import CORE, FLAGS, require_compiler

HARNESS = Path(__file__).resolve().parent / "core_select_harness.c"


@pytest.fixture(scope="module")
def lib():
    cc = require_compiler()
    out = Path(tempfile.mkdtemp(prefix="twselect")) / "libtwselect.so"
    cmd = [cc, *FLAGS, f"-I{CORE}", "-o", str(out), str(HARNESS), str(CORE / "common.c"), "-lm", "-pthread"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    lib = ctypes.CDLL(str(out))
    lib.tw_test_first_cell.restype = ctypes.c_double
    lib.tw_test_first_cell.argtypes = [ctypes.c_void_p, ctypes.c_int64]
    lib.tw_test_kth.restype = ctypes.c_double
    lib.tw_test_kth.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64, ctypes.c_int,
                                ctypes.POINTER(ctypes.c_int)]  # fmt: skip
    return lib


def reference_cell(extent: np.ndarray) -> float:
    """intersections._candidate_pairs' first cell size."""
    cell = 2.0 * float(np.median(extent))
    if not cell > 0:
        cell = float(extent.max()) or 1.0
    return cell


def cases(rng) -> list[np.ndarray]:
    out = []
    for n in (1, 2, 3, 4, 5, 64, 65, 1000, 1001, 40000):
        out.append(rng.uniform(0, 1, n))
        out.append(np.exp(rng.uniform(-40, 5, n)))  # magnitudes spread over many exponents
        out.append(rng.integers(0, 4, n).astype(np.float64) * 0.125)  # few distinct values, zeros among them
        out.append(np.full(n, 0.3))
        out.append(1e-3 + rng.integers(0, 3, n) * np.finfo(float).eps * 1e-3)  # ties one ulp apart
    out.append(np.zeros(6))
    out.append(np.array([0.0, 0.0, 0.0, 5.0]))
    out.append(np.array([np.inf, 1.0, 2.0, np.inf]))
    out.append(np.array([5e-324, 0.0, 1e-320, 2.0, 3.0]))  # subnormals
    return out


def test_first_cell_is_the_reference_median(lib):
    rng = np.random.default_rng(7)
    for ext in cases(rng):
        ext = np.ascontiguousarray(ext, dtype=np.float64)
        got = lib.tw_test_first_cell(ext.ctypes.data, len(ext))
        assert got == reference_cell(ext), (len(ext), ext[:8])


def test_kth_value_is_the_order_statistic(lib):
    rng = np.random.default_rng(8)
    radix = ctypes.c_int()
    for ext in cases(rng):
        ext = np.ascontiguousarray(ext, dtype=np.float64)
        for k in sorted({0, len(ext) // 2, len(ext) - 1, int(rng.integers(0, len(ext)))}):
            want = np.partition(ext, k)[k]
            for hoare in (0, 1):
                got = lib.tw_test_kth(ext.ctypes.data, len(ext), k, hoare, ctypes.byref(radix))
                assert got == want and np.signbit(got) == np.signbit(want)
            assert radix.value == 1


def test_values_the_radix_path_refuses(lib):
    """Negative values, -0 and NaN: radix_kth declines, the comparison path answers (as before)."""
    radix = ctypes.c_int()
    for ext in (np.array([1.0, -2.0, 3.0]), np.array([0.0, -0.0, 1.0, 2.0]), np.array([1.0, np.nan, 2.0, 0.5])):
        got = lib.tw_test_kth(ext.ctypes.data, len(ext), 1, 1, ctypes.byref(radix))
        assert radix.value == 0
        assert got == lib.tw_test_kth(ext.ctypes.data, len(ext), 1, 0, ctypes.byref(radix))
    ext = np.array([3.0, -0.0, 1.0, 2.0])
    assert lib.tw_test_first_cell(ext.ctypes.data, len(ext)) == reference_cell(ext)
