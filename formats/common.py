"""What every `.tw` version shares: the magic, the flag bits, and the checks of the transform back to the input."""

from __future__ import annotations

import numpy as np

MAGIC = b"\x89TWV\r\n\x1a\n"  # bytes 0-7 of every version; the uint16 version follows at offset 8
CHECKSUM_SIZE = 4  # CRC-32 (zlib) of every byte before it, the file's last 4 bytes
FLAG_QHULL = 1 << 0  # the encoder's Delaunay backend was Qhull (else TetGen)
FLAG_S_PREDICTED = 1 << 1  # version 2: the s stream holds residuals of the neighbour prediction (formats/predict.py)
FLAG_OCTREE_CONTEXTS = 1 << 2  # version 2: octree levels may be coded bit by bit with neighbour contexts (octree.py)
KNOWN_FLAGS = FLAG_QHULL  # version 1
KNOWN_FLAGS_V2 = FLAG_QHULL | FLAG_S_PREDICTED | FLAG_OCTREE_CONTEXTS


def backend_flags(backend: str) -> int:
    """Flags bits recording the Delaunay backend ("tetgen" or "qhull")."""
    if backend == "tetgen":
        return 0
    if backend == "qhull":
        return FLAG_QHULL
    raise ValueError(f"unknown Delaunay backend {backend!r}")


def backend_name(flags: int) -> str:
    """The Delaunay backend ("tetgen" or "qhull") recorded in a file's flags; the decoder must use the same."""
    return "qhull" if flags & FLAG_QHULL else "tetgen"


def checked_fields(scale, offset, flags, known: int = KNOWN_FLAGS) -> tuple[float, np.ndarray, int]:
    """scale (float > 0), offset (3,) float64 and flags as a writer stores them; ValueError when invalid."""
    scale = float(scale)
    offset = np.asarray(offset, dtype=np.float64).reshape(-1)
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be finite and > 0, got {scale}")
    if offset.shape != (3,) or not np.isfinite(offset).all():
        raise ValueError("offset must be 3 finite numbers")
    flags = int(flags)
    if flags & ~known or flags < 0:
        raise ValueError(f"unknown flags 0x{flags:x}")
    return scale, offset, flags
