"""The interface every compression method of `tetweave bench` implements, and the tetweave method itself.

A method turns a mesh into bytes and bytes back into a mesh; the benchmark times both, counts the bytes and
measures the decoded mesh against the input. Baselines (Draco, decimation + Draco) live in `baselines.py`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable

import numpy as np

# Method family names: the one home of these strings (baselines, report, `tetweave bench --methods`).
# decimate+draco is fast-simplification's quadric collapse; mlab+draco is MeshLab's (optimal placement, planar
# quadrics), the decimator a practitioner reaches for first and the strongest classical pipeline measured.
DRACO, DECIMATE_DRACO, MLAB_DRACO, TETWEAVE = "draco", "decimate+draco", "mlab+draco", "tetweave"
FAMILIES = (DRACO, DECIMATE_DRACO, MLAB_DRACO, TETWEAVE)
CLASSICAL = (DRACO, DECIMATE_DRACO, MLAB_DRACO)


class Method(ABC):
    """One compression method at one setting.

    family: the method family, one of FAMILIES; the summary compares families.
    setting: short label of the parameters within the family, e.g. "q11" or "16384 pts sh1".
    curve: label of the rate-distortion curve this setting belongs to (settings that vary along one axis).
    """

    family: str = ""

    @property
    @abstractmethod
    def setting(self) -> str: ...

    @property
    def curve(self) -> str:
        return self.family

    @property
    def name(self) -> str:
        return f"{self.family} {self.setting}"

    def params(self) -> dict:
        """Parameters as CSV columns (quantization_bits, keep_fraction, points, sh_degree)."""
        return {}

    @abstractmethod
    def encode(self, vertices: np.ndarray, faces: np.ndarray) -> bytes:
        """Compress a mesh, vertices (V,3) float64 and faces (F,3) int64, in the input's own frame."""

    @abstractmethod
    def decode(self, data: bytes) -> tuple[np.ndarray, np.ndarray]:
        """Rebuild (vertices (V,3) float64, faces (F,3) int64), in the input's frame, from `encode`'s
        bytes."""

    def info(self, data: bytes) -> dict:
        """Extra CSV columns read back from the compressed bytes (e.g. points stored)."""
        return {}

    def reused_seconds(self) -> float:
        """Seconds of work that the last `encode` reused rather than did (a decimation shared by several
        quantizations, a fit run earlier in a worker process); the benchmark adds them to the setting's encode
        time so that every row states its whole cost."""
        return 0.0

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name}>"


class TetweaveMethod(Method):
    """tetweave: fit with `tetweave_codec.encoder.encode`, rebuild with `tetweave_codec.decoder.decode`.

    points: grid points during the fit; sh_degree 0..3, or None for the encoder's choice (`input_defaults`: 1,
    none on CAD parts); quality/iters/device/seed as in `tetweave encode`.
    size: a target file size in bytes (rate control, `tetweave encode --size`) instead of a point count.
    layout: where the points come from, "fit", "grid" or "best" (`tetweave encode --layout`; best needs `size`;
    the curve and settings name every layout but the fit, whose names stay as they were).
    holes: "close" or "keep" (`tetweave encode --holes`; "keep" is named in the curve and settings as keep-holes).
    surface: "auto", "visible" or "all" (`tetweave encode --surface`; the bench measures every method against the
    surface it resolves to, `batch.bench_target`, so it is not part of the labels).
    progress: optional fit progress callback, passed to the encoder unchanged.
    """

    family = TETWEAVE

    def __init__(
        self,
        points: int,
        sh_degree: int | None = None,
        quality: str = "default",
        iters: int | None = None,
        device: str = "auto",
        seed: int = 0,
        progress: Callable | None = None,
        size: int | None = None,
        layout: str = "fit",
        holes: str = "close",
        surface: str = "auto",
    ) -> None:
        self.size = None if size is None else int(size)
        self.surface = surface
        self.layout = layout
        self.holes = holes
        self.points = int(points)
        self.sh_degree = None if sh_degree is None else int(sh_degree)
        self.quality = quality
        self.iters = iters
        self.device = device
        self.seed = seed
        self.progress = progress

    @property
    def _sh(self) -> str:
        sh = "sh auto" if self.sh_degree is None else f"sh{self.sh_degree}"
        sh = sh if self.layout == "fit" else f"{sh} {self.layout}"
        return sh if self.holes == "close" else f"{sh} keep-holes"

    @property
    def setting(self) -> str:
        if self.size is not None:
            return f"size {self.size} {self._sh}"
        return f"{self.points} pts {self._sh}"

    @property
    def curve(self) -> str:
        return f"tetweave {self._sh}" + (" --size" if self.size is not None else "")

    def params(self) -> dict:
        degree = "auto" if self.sh_degree is None else self.sh_degree
        return {
            "points": self.points,
            "sh_degree": degree,
            "target_bytes": self.size or "",
            "layout": self.layout,
            "holes": self.holes,
        }

    def encode(self, vertices: np.ndarray, faces: np.ndarray) -> bytes:
        from tetweave_codec.encoder import encode
        from tetweave_codec.options import EncodeOptions

        degree = self.sh_degree
        options = EncodeOptions(  # the options `tetweave encode` builds, validated the same way
            points=self.points,
            sh_degree="auto" if degree is None else ("none" if degree < 0 else str(degree)),
            quality=self.quality,
            iters=self.iters,
            device=str(getattr(self.device, "type", self.device)),  # a torch.device or its name
            seed=self.seed,
            measure=False,  # the benchmark measures the decoded mesh itself
            size=self.size,
            layout=self.layout,
            holes=self.holes,
            surface=self.surface,
        )
        result = encode(vertices, faces, options=options, progress=self.progress)
        self.points_used = result.stats["points_target"]
        return result.data

    def decode(self, data: bytes) -> tuple[np.ndarray, np.ndarray]:
        from tetweave_codec.decoder import decode

        return decode(data)

    def info(self, data: bytes) -> dict:
        from tetweave_codec.formats.tw import unpack

        info = {"points_stored": int(len(unpack(data).s))}
        if self.size is not None:  # rate control chose the grid points
            info["points"] = getattr(self, "points_used", "")
        return info
