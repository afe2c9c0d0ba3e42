"""One encode's input, prepared once and shared by every fit, every rate-control candidate and the final report.

An encode looks at its input in many places: the defaults it picks (sharp creases?), the start of each fit (the
creases again, closest points, signed distances), the fit's 3-D term (closest points, surface samples), the grid
layout's band, rate control's prior, the holes' caps, and the Chamfer distance of every candidate file. Each of
those used to normalize the input, detect its creases or build its AABB tree for itself: up to six crease
detections and one tree per fit and per Chamfer estimate in a `--max-error` encode. `PreparedInput` computes each
once, on first use, from the same arrays, so every consumer gets exactly what it computed before (the same
samples from the same seeds: the same bytes).

    prepared = prepare_input(vertices, faces, seed=0, keep_holes=False)
    prepared.features          # fit.features.detect_features of the normalized input
    prepared.tree              # geometry.closest.SurfaceTree of the normalized input
    prepared.surface_target(seed)      # the fit's 3-D term (fit.surface_loss.SurfaceTarget), fresh per fit
    prepared.chamfer(v, f, n_samples)  # Chamfer distance of a mesh in the input's frame (metrics)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from tetweave_codec.fit.features import Features, detect_features
from tetweave_codec.fit.holes import InputRim
from tetweave_codec.geometry.closest import SurfaceTree


@dataclass
class PreparedInput:
    """The input mesh and what an encode derives from it, each computed once (on first use).

    vertices (V,3) float64 and faces (F,3) int64 as given; normalized (V,3) = (vertices - offset) / scale, the
    frame every fit works in (meshio.normalize); seed: the encode's seed (surface samples of the metrics). rim: the
    input's boundary prepared for hole caps (fit.holes.InputRim) when the encode keeps holes open and the input
    has some, else None. detail: rate control's detail measure D (rate_control.prior.input_detail), once measured.
    surface: "all" (the input's faces) or "visible" (`on_visible_surface`: vertices, faces and normalized are then
    the visible surface's, in the input's frame); surface_reason: why (the summary's phrase). given: on the
    visible surface, the input as the user gave it (every face, hidden ones included: what a classical codec
    compresses, classical.py); None when this is that input (`source`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    normalized: np.ndarray
    scale: float
    offset: np.ndarray
    seed: int = 0
    rim: InputRim | None = None
    detail: float | None = None
    surface: str = "all"
    surface_reason: str = ""
    given: PreparedInput | None = None
    # auto kept every face though the input's outside surface differs from it (open or inconsistently oriented
    # pieces beside or without closed parts): the self-check may try that surface (encoder._checked)
    outside_differs: bool = False
    _targets: dict = field(default_factory=dict, repr=False)
    _references: dict = field(default_factory=dict, repr=False)

    @cached_property
    def features(self) -> Features:
        """Sharp creases and corners of the normalized input (fit.features.detect_features)."""
        return detect_features(self.normalized, self.faces)

    @cached_property
    def tree(self) -> SurfaceTree:
        """AABB tree of the normalized input: the fit's start, its 3-D term, the grid band and the metrics."""
        return SurfaceTree(self.normalized, self.faces)

    def surface_target(self, seed: int):
        """The fit's 3-D term against the normalized input (fit.surface_loss.SurfaceTarget, its samples drawn from
        `seed`): the samples and the tree are shared, the per-fit cache of the fit's own mesh starts empty."""
        from tetweave_codec.fit.surface_loss import SurfaceTarget

        if seed not in self._targets:
            self._targets[seed] = SurfaceTarget(self.normalized, self.faces, seed=seed, tree=self.tree)
        return self._targets[seed].fresh()

    def reference(self, n_samples: int):
        """The normalized input as one side of a Chamfer distance (metrics.fidelity.prepare_points): `n_samples`
        surface samples drawn from the encode's seed and the shared tree."""
        from tetweave_codec.metrics.fidelity import prepare_points

        if n_samples not in self._references:
            self._references[n_samples] = prepare_points(
                self.normalized, self.faces, n_samples, self.seed, tree=self.tree
            )
        return self._references[n_samples]

    def chamfer(self, vertices: np.ndarray, faces: np.ndarray, n_samples: int) -> float:
        """Chamfer distance (normalized frame) between the input and a mesh, vertices (V,3) in the input's own
        frame and faces (F,3); exactly `metrics.chamfer_distance(self.vertices, self.faces, vertices, faces,
        n_samples, seed)`."""
        from tetweave_codec.metrics.fidelity import chamfer_to_reference, to_frame

        return chamfer_to_reference(
            self.reference(n_samples), to_frame(vertices, self.scale, self.offset), faces, n_samples, self.seed
        )

    def on_visible_surface(self, visible, reason: str) -> PreparedInput:
        """The same encode's input with the visible surface (fit.visible.VisibleSurface, normalized frame) in place
        of the input's faces: the frame (scale, offset) stays the input's, so the file's transform is the same;
        every consumer (start, 3-D term, band, metrics, rate control) then sees the visible surface."""
        from tetweave_codec.fit.holes import input_rim

        normalized = np.asarray(visible.vertices, dtype=np.float64)
        faces = np.asarray(visible.faces, dtype=np.int64)
        vertices = normalized * self.scale + self.offset
        rim = input_rim(normalized, faces) if self.rim is not None else None
        return PreparedInput(
            vertices, faces, normalized, self.scale, self.offset, self.seed, rim, None, "visible", reason, self.source
        )

    @property
    def source(self) -> PreparedInput:
        """The input as the user gave it: this one, or the one whose visible surface this is."""
        return self if self.given is None else self.given

    def normalized_chamfer(self, vertices: np.ndarray, faces: np.ndarray, n_samples: int) -> float:
        """As `chamfer`, for a mesh already in the normalized frame."""
        from tetweave_codec.metrics.fidelity import chamfer_to_reference

        return chamfer_to_reference(self.reference(n_samples), vertices, faces, n_samples, self.seed)


def prepare_input(vertices: np.ndarray, faces: np.ndarray, *, seed: int = 0, keep_holes: bool = False) -> PreparedInput:
    """The input normalized (meshio.normalize), with its rim when `keep_holes` (fit.holes.input_rim); the rest is
    computed when first asked for. vertices (V,3), faces (F,3), already validated."""
    from tetweave_codec.fit.holes import input_rim
    from tetweave_codec.meshio import normalize

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    normalized, scale, offset = normalize(v)
    rim = input_rim(normalized, f) if keep_holes else None
    return PreparedInput(v, f, normalized, float(scale), np.asarray(offset, dtype=np.float64), seed, rim)
