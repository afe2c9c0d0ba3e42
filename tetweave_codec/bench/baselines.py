"""Classical baselines of `tetweave bench`: Draco, and decimation followed by Draco, as method families.

Draco is the real library through DracoPy (positions quantized to `quantization_bits` over the bounding cube,
connectivity with Edgebreaker; the codecs and fast-simplification's decimation are tetweave_codec.classical's,
which the encode summary uses too). DracoPy's default compression level is 1, not the command-line tool's 7: the
level is always set explicitly here. Decimation at low rates beats quantizing the full mesh harder (fewer
vertices to code at a given error); two decimators:

- decimate+draco: fast-simplification's quadric edge collapse (vertices placed at the collapsed edge's ends or
  midpoint; fast, weaker);
- mlab+draco: MeshLab's quadric edge collapse through pymeshlab (optimal vertex placement, normal and boundary
  preservation, quality threshold 0.3: `MLAB_QUADRIC`), the decimator a practitioner reaches for first, run in the
  input's normalized frame (its options include absolute tolerances) and mapped back. Planar quadrics are OFF:
  measured on the four development meshes at 5 % and 20 % of the faces, `planarquadric=True` gave 1.1-10x the
  Chamfer distance of `False` (fandisk 20 %: 1.1e-4 vs 1.1e-5; igea 5 % at its own scale: 3.8e-3 vs 3.2e-4;
  spot 5 %: 2.1e-3 vs 1.8e-3), so the strongest configuration leaves them off.
  pymeshlab is GPL-3 and only a benchmark extra (`pip install "tetweave[bench]"`); encode and decode never need it.

A decimation is computed once per (mesh, fraction) and shared by the settings that quantize it at several bit
depths (`DecimationCache`); each row still states the decimation's time in its encode time.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable

import numpy as np

from tetweave_codec.bench.methods import DECIMATE_DRACO, DRACO, MLAB_DRACO, Method
from tetweave_codec.classical import DRACO_COMPRESSION_LEVEL, decimate, draco_decode, draco_encode

# Every bit depth from 8 to 16: the full mesh's front at high rates runs through each of them (fandisk at CD 5e-5
# lies between 12 and 13 bits).
DRACO_BITS = tuple(range(8, 17))
DECIMATE_KEEP = (0.20, 0.10, 0.05, 0.02)  # fraction of the input's faces kept
DECIMATE_BITS = (11, 14)
# Fractions of the faces kept: eight per octave from 50 % down to 0.5 % (54 settings, 3 significant digits). The
# verdict interpolates each family's front in log-log between its settings, and a sparse sweep overstates the
# classical bytes between them (a front through few points lies above the one a practitioner reaches by choosing
# the fraction). Measured on the committed tetweave files of igea and stanford-bunny (5-40 KB; tetweave bytes /
# the best classical bytes at the file's Chamfer distance): 7 fractions (0.5 / 1 / 2 / 5 / 10 / 20 / 50 %) 0.92 /
# 0.71 / 0.89 / 0.65 and 1.09 / 1.25 / 1.49 / 2.57, four per octave 1.07 / 0.87 / 0.91 / 0.91 and 1.08 / 1.26 /
# 1.72 / 2.80, eight per octave below 14 % 1.07 / 1.00 / 0.91 / 0.91 and 1.11 / 1.31 / 1.72 / 2.78, where
# neighbouring front points are 5-8 % apart in Chamfer distance (docs/measurements/bench_history.md, "How dense the
# classical sweep is").
MLAB_KEEP = tuple(float(f"{0.5 * 2 ** (-k / 8):.3g}") for k in range(54))
MLAB_BITS = (9, 10, 11, 12)
# MeshLab's "Quadric Edge Collapse Decimation" as strong as we could configure it (quality threshold 0.3, optimal
# placement, boundary and normal preservation, clean-up afterwards; planar quadrics off: see the module doc).
MLAB_QUADRIC = {
    "qualitythr": 0.3,
    "preserveboundary": True,
    "preservenormal": True,
    "optimalplacement": True,
    "planarquadric": False,
    "autoclean": True,
}
MLAB_MISSING = 'mlab+draco needs pymeshlab: pip install "tetweave[bench]"'


def mlab_available() -> bool:
    """Whether pymeshlab (the mlab+draco baseline) can be imported."""
    import importlib.util

    return importlib.util.find_spec("pymeshlab") is not None


def mlab_decimate(vertices: np.ndarray, faces: np.ndarray, keep: float) -> tuple[np.ndarray, np.ndarray]:
    """MeshLab quadric decimation (`MLAB_QUADRIC`, in the input's normalized frame) to about `keep` (0..1] of the
    faces: vertices (V',3) float64 in the input's frame, faces (F',3) int64. Raises ImportError with an install
    hint when pymeshlab is missing."""
    if not 0.0 < keep <= 1.0:
        raise ValueError(f"keep must be in (0, 1], got {keep}")
    if keep == 1.0:
        return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    try:
        import pymeshlab
    except ImportError:
        raise ImportError(MLAB_MISSING) from None
    from tetweave_codec.meshio import normalize

    normalized, scale, offset = normalize(np.asarray(vertices, dtype=np.float64))
    meshes = pymeshlab.MeshSet()
    meshes.add_mesh(
        pymeshlab.Mesh(
            vertex_matrix=np.ascontiguousarray(normalized), face_matrix=np.ascontiguousarray(faces, dtype=np.int32)
        )
    )
    meshes.meshing_decimation_quadric_edge_collapse(targetfacenum=max(4, round(keep * len(faces))), **MLAB_QUADRIC)
    out = meshes.current_mesh()
    v = np.asarray(out.vertex_matrix(), dtype=np.float64) * scale + offset
    return v, np.asarray(out.face_matrix(), dtype=np.int64)


Decimator = Callable[[np.ndarray, np.ndarray, float], tuple[np.ndarray, np.ndarray]]


class DecimationCache:
    """The decimations of the current mesh, one per kept fraction, shared by the settings that quantize them.

    Holds only the mesh last asked for (identified by a digest of its arrays), so memory stays bounded over a
    batch of meshes.
    """

    def __init__(self, decimator: Decimator) -> None:
        self.decimator = decimator
        self._digest = b""
        self._entries: dict[float, tuple[np.ndarray, np.ndarray, float]] = {}

    def get(self, vertices: np.ndarray, faces: np.ndarray, keep: float) -> tuple[np.ndarray, np.ndarray, float, bool]:
        """(vertices, faces, seconds the decimation took, whether it was reused from an earlier call)."""
        digest = hashlib.blake2b(np.ascontiguousarray(vertices).tobytes(), digest_size=16)
        digest.update(np.ascontiguousarray(faces).tobytes())
        if digest.digest() != self._digest:
            self._digest, self._entries = digest.digest(), {}
        if keep in self._entries:
            return (*self._entries[keep], True)
        t0 = time.perf_counter()
        v, f = self.decimator(vertices, faces, keep)
        self._entries[keep] = (v, f, time.perf_counter() - t0)
        return v, f, self._entries[keep][2], False


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
    """Decimate to `keep` of the faces with fast-simplification, then Draco at `quantization_bits` (one curve
    per bit depth). cache: a DecimationCache shared with the other settings of the same decimator."""

    family = DECIMATE_DRACO

    def __init__(
        self,
        keep: float,
        quantization_bits: int,
        compression_level: int = DRACO_COMPRESSION_LEVEL,
        cache: DecimationCache | None = None,
    ) -> None:
        if not 0.0 < keep <= 1.0:
            raise ValueError(f"keep must be in (0, 1], got {keep}")
        self.keep = float(keep)
        self.quantization_bits = int(quantization_bits)
        self.compression_level = int(compression_level)
        self.cache = cache or DecimationCache(self.decimator())
        self._reused = 0.0

    @staticmethod
    def decimator() -> Decimator:
        return decimate

    @property
    def setting(self) -> str:
        return f"{100 * self.keep:g}% q{self.quantization_bits}"

    @property
    def curve(self) -> str:
        return f"{self.family} q{self.quantization_bits}"

    def params(self) -> dict:
        return {"quantization_bits": self.quantization_bits, "keep_fraction": self.keep}

    def encode(self, vertices: np.ndarray, faces: np.ndarray) -> bytes:
        v, f, seconds, reused = self.cache.get(vertices, faces, self.keep)
        self._reused = seconds if reused else 0.0
        return draco_encode(v, f, self.quantization_bits, self.compression_level)

    def reused_seconds(self) -> float:
        return self._reused

    def decode(self, data: bytes) -> tuple[np.ndarray, np.ndarray]:
        return draco_decode(data)


class MlabDracoMethod(DecimateDracoMethod):
    """Decimate to `keep` of the faces with MeshLab's quadric edge collapse (`MLAB_QUADRIC`), then Draco at
    `quantization_bits`: the strongest classical pipeline."""

    family = MLAB_DRACO

    @staticmethod
    def decimator() -> Decimator:
        return mlab_decimate


def draco_methods(bits=DRACO_BITS, compression_level: int = DRACO_COMPRESSION_LEVEL) -> list[Method]:
    return [DracoMethod(b, compression_level) for b in bits]


def decimate_draco_methods(
    keep=DECIMATE_KEEP, bits=DECIMATE_BITS, compression_level: int = DRACO_COMPRESSION_LEVEL
) -> list[Method]:
    return _decimate_methods(DecimateDracoMethod, keep, bits, compression_level)


def mlab_draco_methods(
    keep=MLAB_KEEP, bits=MLAB_BITS, compression_level: int = DRACO_COMPRESSION_LEVEL
) -> list[Method]:
    return _decimate_methods(MlabDracoMethod, keep, bits, compression_level)


def _decimate_methods(kind: type[DecimateDracoMethod], keep, bits, compression_level: int) -> list[Method]:
    """Every (fraction, bit depth) setting of one decimator, sharing one DecimationCache."""
    cache = DecimationCache(kind.decimator())
    return [kind(k, b, compression_level, cache) for b in bits for k in keep]
