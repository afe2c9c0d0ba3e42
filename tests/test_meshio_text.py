"""The compiled OBJ / OFF rows (tetweave_codec/_text_native.c) are the bytes of meshio's %-formatting: random
coordinates at every scale, the values whose decimal expansions end in an exact tie, negative zero, values that
round to zero, huge values and the digit counts the writer uses; whole OBJ and OFF files of a mesh."""

from __future__ import annotations

import numpy as np
import pytest

from tetweave_codec import meshio

needs_native = pytest.mark.skipif(meshio._text_native is None, reason="tetweave_codec/_text_native.c not built")


def reference(prefix: str, values: np.ndarray, fmt: str) -> bytes:
    return meshio._rows_text(prefix, " ".join([fmt] * values.shape[1]), values).encode("ascii")


def awkward_values(rng: np.random.Generator) -> np.ndarray:
    """(R,3) float64: random values at scales 1e-12 to 1e19, exact decimal ties at 9-12 digits (k / 2^j), signed
    zeros, values just around 0.5 ulp of the last digit, and powers of two."""
    scales = 10.0 ** rng.integers(-12, 20, 3000)
    random = rng.normal(size=3000) * scales
    ties = rng.integers(-(2**20), 2**20, 3000) / 2.0 ** rng.integers(0, 45, 3000)
    edges = np.array([0.0, -0.0, 5e-10, -5e-10, 4.9999999999e-10, 1e-300, -1e-300, 2.0**63, 2.0**64, -(2.0**70)])
    powers = np.ldexp(1.0, np.arange(-60, 66))
    values = np.concatenate([random, ties, edges, powers, -powers])
    return values[: len(values) // 3 * 3].reshape(-1, 3)


@needs_native
@pytest.mark.parametrize("digits", [0, 3, 9, 10, 12, 17, 18, 25])
def test_float_rows_are_the_reference_bytes(digits):
    values = awkward_values(np.random.default_rng(digits))
    for prefix in ("v ", ""):
        assert meshio._text_native.float_rows(values, prefix.encode(), digits) == reference(
            prefix, values, f"%.{digits}f"
        )


@needs_native
def test_int_rows_are_the_reference_bytes():
    rng = np.random.default_rng(1)
    values = np.concatenate([rng.integers(-(2**62), 2**62, (500, 3)), rng.integers(0, 10**6, (500, 3))])
    values = np.concatenate([values, [[0, -1, 2**63 - 2], [-(2**63), 5, 9]]])
    for offset in (0, 1):
        shifted = values[values[:, 2] < 2**63 - 1 - offset] if offset else values
        assert meshio._text_native.int_rows(shifted, b"f ", offset) == reference("f ", shifted + offset, "%d")
    with pytest.raises(OverflowError):
        meshio._text_native.int_rows(np.array([[2**63 - 1, 0, 0]]), b"f ", 1)


@needs_native
@pytest.mark.parametrize("file_type", ["obj", "off"])
def test_whole_text_files_are_the_reference_bytes(file_type, monkeypatch):
    rng = np.random.default_rng(2)
    v = rng.normal(size=(400, 3)) * 3.7
    f = rng.integers(0, 400, (700, 3))
    fast = meshio.mesh_bytes(v, f, file_type)
    monkeypatch.setattr(meshio, "NATIVE", False)
    assert fast == meshio.mesh_bytes(v, f, file_type)
    assert meshio.mesh_bytes(v[:0], f[:0], file_type) == meshio.mesh_bytes(v[:0], f[:0], file_type)
