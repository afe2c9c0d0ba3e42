"""Classical baselines of `tetweave bench`: Draco, and decimation followed by Draco.

Draco is the real library through DracoPy (positions quantized to `quantization_bits` over the bounding cube,
connectivity with Edgebreaker). DracoPy's default compression level is 1, not the command-line tool's 7: the
level is always set explicitly here. Decimation is fast-simplification's quadric edge collapse, which at low
rates beats quantizing the full mesh harder (fewer vertices to code at a given error).
"""

from __future__ import annotations

import numpy as np

from tetweave_codec.benchmarks.methods import DECIMATE_DRACO, DRACO, Method

DRACO_BITS = (8, 10, 11, 12, 14, 16)
DRACO_COMPRESSION_LEVEL = 7  # `draco_encoder`'s default (-cl 7); DracoPy defaults to 1
DECIMATE_KEEP = (0.20, 0.10, 0.05, 0.02)  # fraction of the input's faces kept
DECIMATE_BITS = (11, 14)


def draco_encode(vertices: np.ndarray, faces: np.ndarray, quantization_bits: int, compression_level: int) -> bytes:
    import DracoPy

    return bytes(
        DracoPy.encode(
            np.ascontiguousarray(vertices, dtype=np.float64),
            np.ascontiguousarray(faces, dtype=np.uint32),
            quantization_bits=quantization_bits,
            compression_level=compression_level,
        )
    )


def draco_decode(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    import DracoPy

    mesh = DracoPy.decode(data)
    vertices = np.asarray(mesh.points, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    return vertices, faces


def decimate(vertices: np.ndarray, faces: np.ndarray, keep: float) -> tuple[np.ndarray, np.ndarray]:
    """Quadric decimation to about `keep` (0..1] of the faces: vertices (V',3) float64, faces (F',3) int64."""
    import fast_simplification

    if not 0.0 < keep <= 1.0:
        raise ValueError(f"keep must be in (0, 1], got {keep}")
    if keep == 1.0:
        return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    v, f = fast_simplification.simplify(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
        target_reduction=1.0 - keep,
    )
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


class DracoMethod(Method):
    """Draco on the full mesh at `quantization_bits` position bits."""

    family = DRACO

    def __init__(self, quantization_bits: int, compression_level: int = DRACO_COMPRESSION_LEVEL) -> None:
        if not 1 <= quantization_bits <= 30:
            raise ValueError(f"Draco quantization must be 1..30 bits, got {quantization_bits}")
        self.quantization_bits = int(quantization_bits)
        self.compression_level = int(compression_level)

    @property
    def setting(self) -> str:
        return f"q{self.quantization_bits}"

    def params(self) -> dict:
        return {"quantization_bits": self.quantization_bits}

    def encode(self, vertices: np.ndarray, faces: np.ndarray) -> bytes:
        return draco_encode(vertices, faces, self.quantization_bits, self.compression_level)

    def decode(self, data: bytes) -> tuple[np.ndarray, np.ndarray]:
        return draco_decode(data)


class DecimateDracoMethod(Method):
    """Decimate to `keep` of the faces, then Draco at `quantization_bits` (one curve per bit depth)."""

    family = DECIMATE_DRACO

    def __init__(self, keep: float, quantization_bits: int, compression_level: int = DRACO_COMPRESSION_LEVEL) -> None:
        if not 0.0 < keep <= 1.0:
            raise ValueError(f"keep must be in (0, 1], got {keep}")
        self.keep = float(keep)
        self.quantization_bits = int(quantization_bits)
        self.compression_level = int(compression_level)

    @property
    def setting(self) -> str:
        return f"{100 * self.keep:g}% q{self.quantization_bits}"

    @property
    def curve(self) -> str:
        return f"decimate+draco q{self.quantization_bits}"

    def params(self) -> dict:
        return {"quantization_bits": self.quantization_bits, "keep_fraction": self.keep}

    def encode(self, vertices: np.ndarray, faces: np.ndarray) -> bytes:
        v, f = decimate(vertices, faces, self.keep)
        return draco_encode(v, f, self.quantization_bits, self.compression_level)

    def decode(self, data: bytes) -> tuple[np.ndarray, np.ndarray]:
        return draco_decode(data)


def draco_methods(bits=DRACO_BITS, compression_level: int = DRACO_COMPRESSION_LEVEL) -> list[Method]:
    return [DracoMethod(b, compression_level) for b in bits]


def decimate_draco_methods(
    keep=DECIMATE_KEEP, bits=DECIMATE_BITS, compression_level: int = DRACO_COMPRESSION_LEVEL
) -> list[Method]:
    return [DecimateDracoMethod(k, b, compression_level) for b in bits for k in keep]
